"""File helpers shared by every format licrom writes: atomic writes and checked reads.

Every write goes to a hidden temporary file beside its destination (named
``.<name>.licrom-tmp-<pid>-<random><suffix>``, or ``.licrom-tmp-<pid>-<random><suffix>``
where a long ``<name>`` would not fit the file system's limit on names; patterns only this
module creates) and
is moved onto the destination when complete. A process killed mid-write leaves that
temporary file behind; the next write of any licrom process into the same folder removes
the ones older than itself whose writing process is gone.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import math
import os
import re
import stat
import struct
import tempfile
import time
import zipfile
import zlib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .errors import FileFormatError, LicromError, OutputError

__all__ = ["atomic_path", "check_version", "existing_file", "load_npz", "make_dir", "name_too_long", "output_error", "remove_stale_temporaries", "save_npz"]

_TMP_TAG = ".licrom-tmp-"
_TMP_NAME = re.compile(r"^\.(?:.*\.)?" + re.escape(_TMP_TAG[1:]) + r"(\d+)-")
# The longest name most file systems allow (bytes), when the folder's own limit cannot be read.
_NAME_MAX = 255
_PATH_MAX = 4096
# A temporary file keeps its destination's suffix up to this length (writers that pick the format by it).
_MAX_TMP_SUFFIX = 32
# Temporary files created before this moment belong to an earlier process.
_PROCESS_START = time.time()
_SWEPT: set[Path] = set()

# Deflate expands at most ~1032:1; a member claiming more than this is corrupt (or a zip bomb).
_MAX_INFLATION = 1100


def output_error(path: str | os.PathLike, exc: OSError) -> OutputError:
    """The :class:`OutputError` for an ``OSError`` raised while writing ``path``, with the remedy."""
    code = exc.errno
    if code == errno.ENOSPC or code == errno.EDQUOT:
        why = "no space left on the device (free some space or write elsewhere)"
    elif code in (errno.EACCES, errno.EPERM, errno.EROFS):
        why = "permission denied: the folder is read-only or not yours (choose another output path or fix its permissions)"
    elif code == errno.EISDIR:
        why = "it is a directory (give a file path)"
    elif code in (errno.ENOTDIR, errno.EEXIST):
        why = "a part of the path is a file, not a folder"
    elif code == errno.ENAMETOOLONG:
        why = (f"a name in the path is over the file system's limit of {_NAME_MAX} bytes per name "
               f"({_PATH_MAX} per path): choose a shorter name")
    else:
        why = exc.strerror or str(exc)
    return OutputError(f"cannot write '{path}': {why}", errno=code)


def make_dir(path: str | os.PathLike) -> Path:
    """Create the folder ``path`` (and its parents) if needed.

    Raises:
        OutputError: it cannot be created (read-only parent, a file in the way, ...).
    """
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(p, exc) from exc
    return p


def _writer_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # an older file with our pid was left by an earlier process
    if os.name != "posix":
        return True  # no cheap liveness test: never remove another process's file
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def remove_stale_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Remove this module's temporary files in ``folder`` left by killed writers; return them.

    A file counts as stale when it is older than the current process and the process that
    wrote it (its pid is in the name) is no longer running.
    """
    removed = []
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            m = _TMP_NAME.match(entry.name)
            if m is None or not entry.is_file(follow_symlinks=False):
                continue
            with contextlib.suppress(OSError):
                if entry.stat().st_mtime < _PROCESS_START and not _writer_alive(int(m.group(1))):
                    os.unlink(entry.path)
                    removed.append(Path(entry.path))
    return removed


def _name_max(folder: Path) -> int:
    """The longest file name (bytes) the file system of ``folder`` allows."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return _NAME_MAX


def name_too_long(p: Path) -> str | None:
    """Why ``p`` is too long for the file system (a name in it, or the whole path), naming the limit; else None."""
    for part in p.parts:
        n = len(os.fsencode(part))
        if n > _NAME_MAX:
            what = "its name" if part == p.name else f"the folder name '{part[:40]}...' in it"
            return f"{what} is {n} bytes long, over the file system's limit of {_NAME_MAX} bytes per name (choose a shorter name)"
    n = len(os.fsencode(os.path.abspath(p)))
    if n >= _PATH_MAX:
        return f"the path is {n} bytes long, over the file system's limit of {_PATH_MAX} bytes per path (choose a shorter path)"
    return None


def existing_file(path: str | os.PathLike, kind: str) -> Path:
    """``path`` as a :class:`Path` to read a ``kind`` file from: a path the file system can hold, of a file that is there.

    Raises:
        FileFormatError: the path is too long (:func:`name_too_long`), or there is no file at it.
    """
    p = Path(path)
    too_long = name_too_long(p)
    if too_long:
        raise FileFormatError(f"cannot read {kind} file '{p}': {too_long}")
    if not p.is_file():
        raise FileFormatError(f"{kind} file not found: '{p}'")
    return p


_NOT_REGULAR = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
                (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))


def _existing_mode(target: Path) -> int | None:
    """The permission bits of the regular file at ``target`` (None when absent or a symlink, replaced as new).

    Raises:
        OutputError: ``target`` is a directory, or not a regular file (FIFO, socket, device), which an
            atomic replace would turn into one.
    """
    try:
        st = os.lstat(target)
    except OSError:
        return None  # absent, or its folder is not one: creating the folder names the problem
    if stat.S_ISLNK(st.st_mode):
        if target.is_dir():
            raise OutputError(f"cannot write '{target}': it is a directory (give a file path)", errno=errno.EISDIR)
        return None  # the link itself is replaced, not followed
    if stat.S_ISDIR(st.st_mode):
        raise OutputError(f"cannot write '{target}': it is a directory (give a file path)", errno=errno.EISDIR)
    for test, what in _NOT_REGULAR:
        if test(st.st_mode):
            raise OutputError(f"cannot write '{target}': it is {what}, not a regular file; licrom writes regular "
                              "files only (give the path of a regular file, or of one that does not exist yet)")
    return stat.S_IMODE(st.st_mode)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "", sync: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only on success.

    A crash or exception while writing leaves ``path`` untouched (or absent) and
    removes the temporary file, so readers never see a half-written file. The first
    write into a folder also removes stale temporary files of killed writers there.
    ``sync``: flush the file to the disk before the move (``os.fsync``, a few ms each);
    False for many small files that are cheap to write again (a VTU series' frames), where
    only a power loss, not a crash of the writer, could leave one of them empty.

    The result keeps the permission bits of the file it replaces (a new file gets those
    of a plain ``open()``). A symlink at ``path`` is replaced, not followed.

    Raises:
        OutputError: ``path`` is a directory or not a regular file (FIFO, socket, device),
            or writing failed for lack of space or permission (any ``OSError`` of the write).
    """
    target = Path(path)
    too_long = name_too_long(target)
    if too_long:
        raise OutputError(f"cannot write '{target}': {too_long}", errno=errno.ENAMETOOLONG)
    mode = _existing_mode(target)
    make_dir(target.parent)
    folder = target.parent.resolve()
    if folder not in _SWEPT:
        remove_stale_temporaries(folder)
        _SWEPT.add(folder)
    suffix = suffix or target.suffix
    if len(os.fsencode(suffix)) > _MAX_TMP_SUFFIX:
        suffix = ""
    prefix = f".{target.name}{_TMP_TAG}{os.getpid()}-"
    if len(os.fsencode(prefix + suffix)) + 8 > _name_max(target.parent):  # mkstemp adds 8 random characters
        prefix = f"{_TMP_TAG}{os.getpid()}-"  # a long name: a short temporary one, so any legal name works
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=target.parent)
        os.close(fd)
    except OSError as exc:
        raise output_error(target, exc) from exc
    tmp = Path(tmp_name)
    try:
        yield tmp
        if sync:
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
        # mkstemp creates 0600 files: give the result the mode of the file it replaces, or
        # for a new file the permissions a plain open() would.
        if mode is None:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    except LicromError:
        raise
    except OSError as exc:
        raise output_error(target, exc) from exc
    finally:
        tmp.unlink(missing_ok=True)


def save_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], header: Mapping[str, Any]) -> None:
    """Atomically write ``arrays`` plus a JSON ``header`` into one compressed ``.npz`` file."""
    payload = dict(arrays)
    payload["header_json"] = np.array(json.dumps(dict(header)))
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **payload)


_READ_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, KeyError, io.UnsupportedOperation,
                NotImplementedError, RuntimeError, struct.error, OverflowError)


def _check_members(p: Path, kind: str) -> None:
    """Validate every ``.npy`` header of the archive against the bytes that hold it, before anything is allocated."""
    size = p.stat().st_size
    with zipfile.ZipFile(p) as zf:
        for info in zf.infolist():
            where = f"'{p}' (member {info.filename!r})"
            if info.compress_size > size or info.file_size > _MAX_INFLATION * info.compress_size + 1024:
                raise FileFormatError(f"{where} is not a licrom {kind} file: it declares {info.file_size} bytes "
                                      f"stored in {info.compress_size} bytes of a {size}-byte file")
            with zf.open(info) as fh:
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, _fortran, dtype = np.lib.format.read_array_header_1_0(fh)
                else:
                    shape, _fortran, dtype = np.lib.format.read_array_header_2_0(fh)
                body = info.file_size - fh.tell()
            if dtype.hasobject:
                raise FileFormatError(f"{where} holds Python objects; licrom files hold plain numbers and text only")
            declared = math.prod(int(d) for d in shape) * dtype.itemsize
            if declared != body:
                raise FileFormatError(f"{where} declares an array of shape {tuple(shape)} and dtype {dtype} "
                                      f"({declared} bytes) but holds {body} bytes (truncated or corrupt)")


def load_npz(path: str | os.PathLike, kind: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read a file written by :func:`save_npz`; return ``(header, arrays)``.

    Array headers are checked against the bytes that hold them before any array is read,
    so a corrupt or hostile file cannot make this allocate more than it stores.

    Raises:
        FileFormatError: the file is missing, truncated, not an ``.npz`` written by
            licrom, or holds a different ``kind`` of data.
    """
    p = existing_file(path, kind)
    try:
        with open(p, "rb") as fh:
            if fh.read(4) != b"PK\x03\x04":  # every .npz is a zip archive
                raise FileFormatError(f"'{p}' is not a licrom {kind} file: it is not an .npz (zip) archive")
        _check_members(p, kind)
        with np.load(p, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except FileFormatError:
        raise
    except _READ_ERRORS as exc:
        raise FileFormatError(f"'{p}' is not a readable licrom {kind} file (truncated or corrupt: {exc})") from exc
    if "header_json" not in arrays:
        raise FileFormatError(f"'{p}' is an .npz file but not a licrom {kind} file (it has no licrom header)")
    try:
        header = json.loads(str(arrays.pop("header_json")))
    except (json.JSONDecodeError, RecursionError) as exc:
        raise FileFormatError(f"'{p}' has a corrupt licrom header: {exc}") from exc
    if not isinstance(header, dict):
        raise FileFormatError(f"'{p}' has a corrupt licrom header: a JSON {type(header).__name__}, expected an object")
    if header.get("kind") != kind:
        raise FileFormatError(f"'{p}' holds a licrom '{header.get('kind')}' file, expected a '{kind}' file")
    return header, arrays


def check_version(found: Any, supported: int | tuple[int, ...], what: str) -> None:
    """Raise FileFormatError unless ``found`` is a ``supported`` format version (an integer; ``true`` is not 1)."""
    versions = supported if isinstance(supported, tuple) else (supported,)
    if isinstance(found, bool) or found not in versions:
        accepted = " or ".join(str(v) for v in versions)
        raise FileFormatError(f"{what} has format version {found!r}; this licrom reads version {accepted} only")
