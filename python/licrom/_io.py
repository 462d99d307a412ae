"""File helpers shared by every format licrom writes: atomic writes and checked reads."""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import zipfile
import zlib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .errors import FileFormatError

__all__ = ["atomic_path", "check_version", "load_npz", "save_npz"]


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only on success.

    A crash or exception while writing leaves ``path`` untouched (or absent) and
    removes the temporary file, so readers never see a half-written file.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or target.suffix, dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp creates 0600 files; give the result the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def save_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], header: Mapping[str, Any]) -> None:
    """Atomically write ``arrays`` plus a JSON ``header`` into one compressed ``.npz`` file."""
    payload = dict(arrays)
    payload["header_json"] = np.array(json.dumps(dict(header)))
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **payload)


def load_npz(path: str | os.PathLike, kind: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read a file written by :func:`save_npz`; return ``(header, arrays)``.

    Raises:
        FileFormatError: the file is missing, truncated, not an ``.npz`` written by
            licrom, or holds a different ``kind`` of data.
    """
    p = Path(path)
    if not p.is_file():
        raise FileFormatError(f"{kind} file not found: '{p}'")
    with open(p, "rb") as fh:
        if fh.read(4) != b"PK\x03\x04":  # every .npz is a zip archive
            raise FileFormatError(f"'{p}' is not a licrom {kind} file: it is not an .npz (zip) archive")
    try:
        with np.load(p, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, KeyError, io.UnsupportedOperation) as exc:
        raise FileFormatError(f"'{p}' is not a readable licrom {kind} file (truncated or corrupt: {exc})") from exc
    if "header_json" not in arrays:
        raise FileFormatError(f"'{p}' is an .npz file but not a licrom {kind} file (it has no licrom header)")
    try:
        header = json.loads(str(arrays.pop("header_json")))
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"'{p}' has a corrupt licrom header: {exc}") from exc
    if header.get("kind") != kind:
        raise FileFormatError(f"'{p}' holds a licrom '{header.get('kind')}' file, expected a '{kind}' file")
    return header, arrays


def check_version(found: Any, supported: int, what: str) -> None:
    """Raise FileFormatError unless ``found`` is the ``supported`` format version."""
    if found != supported:
        raise FileFormatError(
            f"{what} has format version {found!r}; this licrom reads version {supported} only"
        )
