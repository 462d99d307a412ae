"""Threads of the BLAS bundled by numpy's and scipy's wheels (OpenBLAS), limited for the length of a block.

On two cores shared with other work OpenBLAS's threads spin while they wait for each other: an SVD of the
demo's 800 x 800 snapshot matrix took 2.7-3.9 s of CPU with two threads and 0.2 s with one. Where the BLAS
is not one of these wheels' OpenBLAS (another build, macOS, Windows) the limit is not applied.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import importlib.util
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["blas_threads", "numpy_blas_threads"]


@functools.cache
def _openblas() -> tuple[tuple[Any, Any], ...]:
    """(get, set) thread-count functions of each OpenBLAS that numpy's and scipy's wheels ship."""
    found = []
    for package in ("numpy", "scipy"):
        spec = importlib.util.find_spec(package)
        if spec is None or spec.origin is None:
            continue
        for path in sorted((Path(spec.origin).parent.parent / f"{package}.libs").glob("libscipy_openblas*.so*")):
            try:
                lib = ctypes.CDLL(str(path))  # the library the package loaded (or will load): one handle
            except OSError:
                continue
            for suffix in ("64_", ""):  # 64-bit integer builds (numpy), 32-bit ones (scipy)
                get = getattr(lib, f"scipy_openblas_get_num_threads{suffix}", None)
                put = getattr(lib, f"scipy_openblas_set_num_threads{suffix}", None)
                if get is not None and put is not None:
                    get.restype, put.argtypes = ctypes.c_int, [ctypes.c_int]
                    found.append((get, put))
                    break
    return tuple(found)


@contextlib.contextmanager
def blas_threads(count: int | None) -> Iterator[None]:
    """At most ``count`` BLAS threads inside the block (None: leave them as they are); restored after it."""
    libraries = _openblas() if count is not None else ()
    before = [get() for get, _ in libraries]
    for _, put in libraries:
        put(count)
    try:
        yield
    finally:
        for (_, put), n in zip(libraries, before):
            put(n)


def numpy_blas_threads() -> int | None:
    """Threads of numpy's BLAS (its wheel's OpenBLAS) now, for :func:`blas_threads` to restore later; None where it is not that OpenBLAS."""
    libraries = _openblas()
    return libraries[0][0]() if libraries else None
