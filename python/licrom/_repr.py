"""Readable ``repr`` of the data classes that hold arrays: shapes instead of every number."""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np

__all__ = ["concise_repr"]


def _short(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"array({value.dtype}, shape={value.shape})"
    if isinstance(value, (list, tuple)) and len(value) > 4:
        return f"[{len(value)} items]"
    return repr(value)


def concise_repr(obj: Any) -> str:
    """``Name(field=value, ...)`` of a dataclass with arrays shown by dtype and shape and long lists by length."""
    parts = (f"{f.name}={_short(getattr(obj, f.name))}" for f in fields(obj) if f.repr)
    return f"{type(obj).__name__}({', '.join(parts)})"
