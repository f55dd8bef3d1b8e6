"""Atomic writes: a file or directory either appears complete under its final name or not at all.

Everything is first written to a temporary sibling named ``.<name>.tmp-<random>``
(same directory, hence same filesystem) and then renamed with ``os.replace`` /
``os.rename``, which POSIX makes atomic. A crash can leave such temporaries
behind, never a half-written ``<name>``; :func:`clean_stale_temps` removes them.
:func:`atomic_files` does the same for a group of files in one directory (all or none).

A full disk or quota (``ENOSPC``, ``EDQUOT``) while writing is a
:class:`~mitsnerf.errors.DiskFullError` naming the path being written and what was kept: the
previous file or directory as it was, or nothing (the temporaries are removed).

>>> import tempfile
>>> d = Path(tempfile.mkdtemp())
>>> atomic_write_json(d / "a.json", {"b": 1, "a": [1.5]})
>>> (d / "a.json").read_text()
'{\\n  "b": 1,\\n  "a": [\\n    1.5\\n  ]\\n}\\n'
>>> with atomic_dir(d / "out") as tmp:
...     _ = (tmp / "x.txt").write_text("done")
>>> sorted(p.name for p in d.iterdir())
['a.json', 'out']
>>> shutil.rmtree(d)
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mitsnerf.errors import DiskFullError

_TMP_TAG = ".tmp-"


def _temp_name(final: Path, kind: str = "") -> Path:
    return final.parent / f".{final.name}{_TMP_TAG}{kind}{secrets.token_hex(6)}"


def _kept(path: Path) -> str:
    return "the previous file is kept" if path.exists() else "no file was written"


def _disk_full(exc: BaseException, path: Path, kept: str, inside: Path | None = None) -> DiskFullError | None:
    """The DiskFullError to raise for ``exc`` while writing ``path`` (None: ``exc`` is no full disk); a file
    being written under the temporary ``inside`` is named relative to it."""
    full = DiskFullError.of(exc)
    if full is None:
        return None
    writing = None
    if inside is not None and full.path.is_relative_to(inside) and full.path != inside:
        writing = full.path.relative_to(inside).as_posix()
    return DiskFullError(path, full.reason, kept, writing)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a fresh temporary file path next to ``path``; on success move it onto ``path``.

    For writers that insist on a file name (OpenEXR). The temporary is removed if
    the body raises (any exception, ``KeyboardInterrupt`` included) or writes nothing.
    """
    path = Path(path)
    tmp = _temp_name(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        _remove(tmp)
        full = _disk_full(exc, path, _kept(path))
        if full is None:
            raise
        raise full from exc


@contextmanager
def atomic_files(directory: str | os.PathLike, names: Sequence[str]) -> Iterator[dict[str, Path]]:
    """Write the files ``names`` in ``directory`` all or none: yields ``{name: temporary path}`` (siblings
    of the final files) for the body to write, then renames each onto its name. If the body raises, the
    temporaries are removed (and ``directory`` too if this created it and it is empty); the files already
    there are left as they were.
    """
    directory = Path(directory)
    created = not directory.is_dir()
    directory.mkdir(parents=True, exist_ok=True)
    temps = {name: _temp_name(directory / name) for name in names}
    try:
        yield temps
        for name, tmp in temps.items():
            os.replace(tmp, directory / name)
    except BaseException as exc:
        for tmp in temps.values():
            _remove(tmp)
        if created and not any(directory.iterdir()):
            directory.rmdir()
        full = DiskFullError.of(exc)
        if full is None:
            raise
        writing = next((n for n, t in temps.items() if full.path == t), None)
        kept = f"none of {', '.join(names)} was written; the files there before are kept"
        raise DiskFullError(directory, full.reason, kept, writing) from exc


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary sibling, fsync, ``os.replace``).

    The file gets the usual permissions (``0o666`` less the umask).
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as JSON (indent 2, keys in insertion order, trailing newline) atomically.

    NaN and infinities are not JSON: they raise ``ValueError`` and nothing is written.
    """
    text = json.dumps(obj, indent=2, allow_nan=False) + "\n"
    atomic_write_text(path, text)


@contextmanager
def atomic_dir(final: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Build a directory in a temporary sibling and rename it to ``final`` when the body succeeds.

    Yields the temporary directory ``.<final.name>.tmp-<random>`` (created empty,
    permissions ``0o777`` less the umask). If the body raises (``KeyboardInterrupt``
    included) the temporary is deleted and ``final`` is left as it was. If ``final``
    exists, ``overwrite=False`` raises ``FileExistsError`` (before the body runs,
    and again at the end if it appeared meanwhile); ``overwrite=True`` replaces it:
    the old directory is renamed away, the new one renamed in, then the old one
    deleted (put back if the second rename fails).
    """
    final = Path(final)
    if not overwrite and (final.exists() or final.is_symlink()):
        raise FileExistsError(f"{final} already exists (pass overwrite=True to replace it)")
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_name(final)
    os.mkdir(tmp, 0o777)
    try:
        yield tmp
        if final.exists() or final.is_symlink():
            if not overwrite:
                raise FileExistsError(f"{final} appeared while it was being written")
            old = _temp_name(final, "old-")
            os.rename(final, old)
            try:
                os.rename(tmp, final)
            except BaseException:
                os.rename(old, final)
                raise
            _remove(old)
        else:
            os.rename(tmp, final)
    except BaseException as exc:
        _remove(tmp)
        full = _disk_full(
            exc, final, f"{final} is left as it was" if final.exists() else f"{final} was not created", tmp
        )
        if full is None:
            raise
        raise full from exc


def clean_stale_temps(parent: str | os.PathLike, min_age_s: float = 0.0) -> list[Path]:
    """Remove leftover temporaries ``.*.tmp-*`` (files or directories) directly inside ``parent``.

    Only call it when no other writer is working in ``parent``, or pass
    ``min_age_s`` to spare temporaries modified within the last ``min_age_s``
    seconds. Returns the removed paths, sorted.
    """
    parent = Path(parent)
    if not parent.is_dir():
        return []
    now = time.time()
    removed = []
    for p in sorted(parent.glob(f".*{_TMP_TAG}*")):
        try:
            if min_age_s > 0 and now - p.lstat().st_mtime < min_age_s:
                continue
        except FileNotFoundError:
            continue
        _remove(p)
        removed.append(p)
    return removed
