"""Memory limits: every size is checked against what this machine can hold before anything is allocated.

A size (points per step, the rank, a network width, a mesh resolution, ...) comes with an
estimate of the bytes it will need; :func:`check_memory` compares that estimate with
:func:`memory_limit` and raises :class:`~licrom.errors.ConfigError` naming the argument,
the estimate and the limit, instead of a process that grows until the kernel kills it.

The limit is :data:`MEMORY_FRACTION` of the machine's physical memory. The environment
variable ``LICROM_MEMORY_LIMIT`` replaces it: a number of bytes, optionally with a
``K``, ``M``, ``G`` or ``T`` suffix (powers of 1024; ``LICROM_MEMORY_LIMIT=64G``), for a
machine shared with other jobs or a GPU smaller than the host's memory.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Mapping
from decimal import Decimal
from typing import Any

from .errors import ConfigError

__all__ = ["ENV_VAR", "MEMORY_FRACTION", "blame", "check_memory", "format_bytes", "format_size", "memory_limit"]

ENV_VAR = "LICROM_MEMORY_LIMIT"
# Of the physical memory; the rest is left to the OS, the interpreter and what estimates miss.
MEMORY_FRACTION = 0.8
_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
_SPEC = re.compile(r"^\s*(\d+(?:\.\d*)?)\s*([KMGT]?)(?:I?B)?\s*$", re.IGNORECASE)


def format_bytes(n: int) -> str:
    """``n`` bytes for a message: ``'1.5 GiB'``; beyond PiB in powers of ten (any Python int, no overflow)."""
    n = int(n)
    for power, unit in enumerate(("B", "KiB", "MiB", "GiB", "TiB", "PiB")):
        if n < 1024 ** (power + 1):
            return f"{n} B" if power == 0 else f"{n / 1024**power:.3g} {unit}"
    return f"{Decimal(n):.3g} B"  # Decimal: a float of a huge int would overflow


def format_size(value: Any) -> str:
    """``repr(value)``, with an integer of over 20 digits in powers of ten (``1.181e+21``): a message stays one line."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**20:
        return f"{Decimal(value):.4g}"
    return repr(value)


def memory_limit() -> tuple[int, str]:
    """The byte limit every size estimate is checked against, and where it comes from (for messages).

    Raises:
        ConfigError: ``LICROM_MEMORY_LIMIT`` is set but is not a number of bytes.
    """
    text = os.environ.get(ENV_VAR, "").strip()
    if text:
        m = _SPEC.match(text)
        limit = 0 if m is None else int(Decimal(m.group(1)) * _UNITS[m.group(2).upper()])
        if limit < 1:
            raise ConfigError(f"{ENV_VAR} must be a number of bytes >= 1, optionally with a K, M, G or T suffix "
                              f"(powers of 1024), got {text!r}")
        return limit, f"{ENV_VAR}={text}"
    try:
        physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):  # not POSIX: assume a workstation
        physical = 16 * 2**30
    return int(MEMORY_FRACTION * physical), (f"{MEMORY_FRACTION:.0%} of this machine's {format_bytes(physical)} of physical "
                                             f"memory; set {ENV_VAR} to change it")


def check_memory(argument: str, value: Any, estimate: int, what: str) -> None:
    """Raise ConfigError when ``estimate`` bytes are over :func:`memory_limit`.

    Args:
        argument: the argument to blame (``"TrainConfig.points_per_frame"``).
        value: its value.
        estimate: bytes the argument will make licrom allocate (a Python int: any size).
        what: what those bytes hold, for the message.
    """
    limit, source = memory_limit()
    if estimate > limit:
        raise ConfigError(f"{argument}={format_size(value)} needs about {format_bytes(estimate)} ({what}), over the "
                          f"memory limit of {format_bytes(limit)} ({source})")


def blame(estimate: Callable[[Mapping[str, Any]], int], sizes: Mapping[str, Any], baseline: Mapping[str, Any]) -> str:
    """The size whose return to its ``baseline`` value lowers ``estimate(sizes)`` the most: the one to name in a message."""
    def without(name: str) -> int:
        return estimate({**sizes, name: baseline[name]})

    return min(baseline, key=without)
