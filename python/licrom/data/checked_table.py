"""A TOML table read with every value checked as it is read, and every key never read refused.

The scene file's reader (:mod:`licrom.data.scene_file`): each value is checked against its accepted range as it is
read, and the error names the key and the accepted values.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from typing import Any

from ..errors import ConfigError
from ..scene.sweep import check_friction

__all__ = ["MISSING", "Table", "checked_integer", "checked_number"]

MISSING: Any = object()
"""The default of a required key."""


def _interval(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    if hi == math.inf:
        return f"{'>' if lo_open else '>='} {lo:g}"
    return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"


class Table:
    """One TOML table being read: each value is checked as it is read; keys never read are refused."""

    def __init__(self, data: Any, path: str) -> None:
        if not isinstance(data, dict):
            raise ConfigError(f"{path} must be a table, got {_kind(data)}")
        self.data = data
        self.path = path
        self.read: list[str] = []

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str, default: Any = MISSING) -> Any:
        self.read.append(name)
        if name not in self.data:
            if default is MISSING:
                raise ConfigError(f"{self.key(name)} is required")
            return default
        return self.data[name]

    def absent(self, name: str, default: Any) -> bool:
        """True when ``name`` is not given and has a default (which is then used unchecked)."""
        if name in self.data or default is MISSING:
            return False
        self.read.append(name)
        return True

    def number(self, name: str, default: Any = MISSING, lo: float = -math.inf, hi: float = math.inf,
               lo_open: bool = False, hi_open: bool = False, unit: str = "") -> Any:
        if self.absent(name, default):
            return default
        return checked_number(self.raw(name), self.key(name), lo, hi, lo_open, hi_open, unit)

    def integer(self, name: str, default: Any = MISSING, lo: int = 1) -> Any:
        if self.absent(name, default):
            return default
        return checked_integer(self.raw(name), self.key(name), lo)

    def vector(self, name: str, default: Any = MISSING, unit: str = "") -> Any:
        if self.absent(name, default):
            return default
        value = self.raw(name)
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            raise ConfigError(f"{self.key(name)} must be 3 numbers{f' ({unit})' if unit else ''}, got {value!r}")
        return tuple(checked_number(v, f"{self.key(name)}[{i}]", unit=unit) for i, v in enumerate(value))  # type: ignore[return-value]

    def friction(self, name: str, default: Any = MISSING) -> Any:
        """A Coulomb coefficient (:func:`licrom.scene.sweep.check_friction`)."""
        if self.absent(name, default):
            return default
        return check_friction(self.raw(name), self.key(name))

    def numbers(self, name: str, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False, hi_open: bool = False,
                unit: str = "", check: Callable[[Any, str], float] | None = None) -> tuple[float, ...] | None:
        """A non-empty list of numbers in the range, each read by ``check(value, key)`` (default: :func:`checked_number` in the range)."""
        value = self.raw(name, None)
        if value is None:
            return None
        if not isinstance(value, list) or not value:
            raise ConfigError(f"{self.key(name)} must be a non-empty list of numbers {_interval(lo, hi, lo_open, hi_open)}, got {value!r}")
        check = check or partial(checked_number, lo=lo, hi=hi, lo_open=lo_open, hi_open=hi_open, unit=unit)
        return tuple(check(v, f"{self.key(name)}[{i}]") for i, v in enumerate(value))

    def string(self, name: str, default: Any = MISSING, choices: tuple[str, ...] | None = None) -> str:
        value = self.raw(name, default)
        if not isinstance(value, str) or (choices is not None and value not in choices):
            accepted = f"one of {', '.join(repr(c) for c in choices)}" if choices else "a string"
            raise ConfigError(f"{self.key(name)} must be {accepted}, got {value!r}")
        return value

    def table(self, name: str, required: bool = False) -> Table:
        return Table(self.raw(name, MISSING if required else {}), self.key(name))

    def tables(self, name: str) -> list[Table] | None:
        value = self.raw(name, None)
        if value is None:
            return None
        if not isinstance(value, list):
            raise ConfigError(f"{self.key(name)} must be an array of tables ([[{name}]]), got {_kind(value)}")
        return [Table(item, f"{self.key(name)}[{i}]") for i, item in enumerate(value)]

    def done(self) -> None:
        unknown = [k for k in self.data if k not in self.read]
        if unknown:
            where = self.path or "the top level"
            raise ConfigError(f"unknown key {self.key(unknown[0])}; accepted keys in {where}: {', '.join(dict.fromkeys(self.read))}")


def checked_integer(value: Any, key: str, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise ConfigError(f"{key} must be an integer >= {lo}, got {value!r}")
    return value


def _kind(value: Any) -> str:
    return {dict: "a table", list: "a list", str: "a string", bool: "a boolean"}.get(type(value), type(value).__name__)


def checked_number(value: Any, key: str, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False, hi_open: bool = False,
            unit: str = "") -> float:
    accepted = "" if (lo, hi) == (-math.inf, math.inf) else " " + _interval(lo, hi, lo_open, hi_open)
    what = f"a number{accepted}{f' ({unit})' if unit else ''}"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{key} must be {what}, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi):
        raise ConfigError(f"{key} must be {what}, got {value!r}")
    return v
