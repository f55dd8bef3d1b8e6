"""numpy ``.npy`` and ``.npz`` files read safely: never unpickled, and every way a file can be wrong
(missing, truncated, another format, garbage) is one :class:`~mitsnerf.errors.DatasetError` naming
the file and saying what was expected, instead of numpy's "contains pickled (object) data" or
zipfile's ``BadZipFile``.

>>> import tempfile
>>> d = Path(tempfile.mkdtemp())
>>> np.save(d / "a.npy", np.zeros(3, np.float32)); read_npy(d / "a.npy", "grid").tolist()
[0.0, 0.0, 0.0]
>>> _ = (d / "b.npz").write_bytes(b"not an archive")
>>> read_npz(d / "b.npz", "checkpoint")
Traceback (most recent call last):
...
mitsnerf.errors.DatasetError: ...b.npz: not a readable checkpoint: not a numpy .npz archive (truncated, or ...
"""

from __future__ import annotations

import errno
import os
import stat
import zipfile
from pathlib import Path
from typing import IO

import numpy as np

from mitsnerf.errors import DatasetError

#: What numpy and zipfile raise on a damaged or foreign file (a pickle numpy refuses is a ValueError).
_READ_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError)


def _problem(path: Path, exc: BaseException, kind: str) -> str:
    """Why ``path`` is not a ``kind`` file, in words a user can act on."""
    head = b""
    if path.is_file():
        with open(path, "rb") as f:
            head = f.read(8)
    if kind == "npz" and not head.startswith(b"PK"):
        return "not a numpy .npz archive (truncated, or another kind of file)"
    if kind == "npy" and not head.startswith(b"\x93NUMPY"):
        return "not a numpy .npy file (another kind of file, or garbage)"
    if isinstance(exc, (zipfile.BadZipFile, EOFError)):
        return f"a damaged {kind} file (truncated?): {exc}"
    return f"a damaged {kind} file: {exc}"


def file_problem(path: str | os.PathLike, what: str = "file") -> str | None:
    """Why ``path`` cannot be opened as a regular file (no such file, a broken symlink, a symlink loop, a
    directory, a device or pipe), in words a user can act on (``what`` the file should be); None when it can be.

    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> file_problem(d / "none.npy"), file_problem(d)
    ('no such file', 'is a directory, not a file')
    >>> os.symlink(d / "b", d / "a"); os.symlink(d / "a", d / "b"); file_problem(d / "a")
    'a symlink loop (a link that leads back to itself)'
    """
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symlink loop (a link that leads back to itself)"
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            return (f"a broken symlink (to {os.readlink(path)}, which does not exist)" if path.is_symlink()
                    else f"no such {what}")
        return f"cannot be read: {exc.strerror or exc}"
    if stat.S_ISDIR(mode):
        return f"is a directory, not a {what}"
    if not stat.S_ISREG(mode):
        return "not a regular file (a device, pipe or socket)"
    return None


def read_npy_header(f: IO[bytes]) -> tuple[tuple[int, ...], np.dtype]:
    """The shape and dtype an ``.npy`` stream's header declares, read without its data (``f`` at the
    stream's start, left at the data's); a ValueError if it is no ``.npy`` header.

    >>> import io
    >>> buffer = io.BytesIO(); np.save(buffer, np.zeros((2, 3), np.float32)); _ = buffer.seek(0)
    >>> read_npy_header(buffer)
    ((2, 3), dtype('float32'))
    """
    version = np.lib.format.read_magic(f)
    if version not in ((1, 0), (2, 0), (3, 0)):  # 3.0 differs from 2.0 only in the header's text encoding
        raise ValueError(f"unknown .npy format version {version[0]}.{version[1]}")
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, _, dtype = read(f)
    return tuple(int(n) for n in shape), dtype


def _check_file(path: Path, what: str) -> None:
    if not path.exists():
        raise DatasetError(path, None, f"{what} not found")
    if not path.is_file():
        raise DatasetError(path, None, f"a {what} must be a file, this is a directory")


def read_npz(path: str | os.PathLike, what: str = "array archive") -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file (read whole, ``allow_pickle=False``); ``what`` names it in errors."""
    path = Path(path)
    _check_file(path, what)
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except _READ_ERRORS as exc:
        raise DatasetError(path, None, f"not a readable {what}: {_problem(path, exc, 'npz')}") from None


def read_npy(path: str | os.PathLike, what: str = "array") -> np.ndarray:
    """The array of an ``.npy`` file (``allow_pickle=False``); ``what`` names it in errors."""
    path = Path(path)
    _check_file(path, what)
    try:
        arr = np.load(path, allow_pickle=False)
    except _READ_ERRORS as exc:
        raise DatasetError(path, None, f"not a readable {what}: {_problem(path, exc, 'npy')}") from None
    if not isinstance(arr, np.ndarray):
        raise DatasetError(path, None, f"not a readable {what}: an .npz archive, expected one .npy array")
    return arr
