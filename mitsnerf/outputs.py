"""Output locations, checked before any work starts, and exclusive locks on what one process writes.

A command that writes a directory (a run, renders, an export, a dataset root, benchmark results)
first calls :func:`check_output_dir`: the path must not be a file, nor lie under one, and the
directory it will be in must be writable. Writability is tested by creating and removing a file
there rather than by ``os.access``, which says yes to root even where writes fail (a read-only
mount, a process without ``CAP_DAC_OVERRIDE``). A problem is one
:class:`~mitsnerf.errors.OutputError` naming the path.

:func:`exclusive_lock` serialises writers of one thing (a dataset, a run directory) through
``flock`` on a lock file that records the holder's process id; the kernel releases it when the
process dies, however it dies.

:func:`data_cache` is where datasets (and their oracles) are kept when no location is given: one
directory per user, shared by every working directory, as pip, Hugging Face and torch keep theirs.

:func:`progress_log` is how a command that can run for minutes says what it is doing: one line per step
of its work on stderr, whether or not stderr is a terminal (progress bars are drawn only on one), so that a
log file shows where the time went.

>>> import tempfile
>>> d = Path(tempfile.mkdtemp())
>>> check_output_dir(d / "new" / "run", "--out")       # to be created: its parent's parent is writable
>>> (d / "f").write_text("x")
1
>>> check_output_dir(d / "f", "--out")
Traceback (most recent call last):
...
mitsnerf.errors.OutputError: ...f: --out: exists and is not a directory
>>> with exclusive_lock(d / ".run.lock", wait=False, what=d / "run"):
...     pass
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import secrets
import stat
import sys
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

from mitsnerf.errors import OutputError

DATA_ENV = "MITSNERF_DATA"
"""The environment variable that names the dataset cache (:func:`data_cache`)."""


def data_cache(environ: Mapping[str, str] | None = None) -> tuple[Path, str]:
    """``(directory, what chose it)``: where datasets and their oracles are cached when no location is given.
    ``$MITSNERF_DATA``, else ``$XDG_CACHE_HOME/mitsnerf`` (an absolute ``XDG_CACHE_HOME`` only, as the XDG
    base-directory rules say), else ``~/.cache/mitsnerf``.

    >>> data_cache({"MITSNERF_DATA": "/scratch/d", "XDG_CACHE_HOME": "/c"})
    (PosixPath('/scratch/d'), '$MITSNERF_DATA')
    >>> data_cache({"XDG_CACHE_HOME": "/c"})
    (PosixPath('/c/mitsnerf'), '$XDG_CACHE_HOME')
    >>> data_cache({"XDG_CACHE_HOME": "relative", "HOME": "/home/u"})
    (PosixPath('/home/u/.cache/mitsnerf'), '~/.cache')
    """
    env = os.environ if environ is None else environ
    if env.get(DATA_ENV):
        return Path(os.path.expanduser(env[DATA_ENV])), f"${DATA_ENV}"
    xdg = env.get("XDG_CACHE_HOME", "")
    if os.path.isabs(xdg):
        return Path(xdg) / "mitsnerf", "$XDG_CACHE_HOME"
    home = env.get("HOME") or str(Path.home())
    return Path(home) / ".cache" / "mitsnerf", "~/.cache"


def directory_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(bytes, files)`` of the regular files under ``path`` (links not followed; (0, 0) if it is missing).

    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> (d / "a").write_bytes(b"12345")
    5
    >>> directory_size(d), directory_size(d / "missing")
    ((5, 1), (0, 0))
    """
    total = files = 0
    for root, _, names in os.walk(os.fspath(path)):
        for name in names:
            try:
                st = os.lstat(os.path.join(root, name))
            except OSError:  # removed meanwhile (a writer's temporary)
                continue
            if stat.S_ISREG(st.st_mode):
                total, files = total + st.st_size, files + 1
    return total, files


def _existing_ancestor(path: Path, option: str) -> Path:
    """The nearest existing directory at or above ``path``; an OutputError if a file is in the way."""
    for p in (path, *path.parents):
        if p.is_dir():
            return p
        if p.exists() or p.is_symlink():
            if p == path:
                raise OutputError(path, option, "exists and is not a directory")
            raise OutputError(path, option, f"{p} is a file, not a directory")
    return Path.cwd()  # pragma: no cover (a relative path's parents end at '.')


def probe_writable(directory: Path) -> str | None:
    """None if a file can be created (and removed) in ``directory``, else the reason it cannot."""
    probe = directory / f".mitsnerf-probe-{secrets.token_hex(6)}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        return exc.strerror or errno.errorcode.get(exc.errno or 0, "not writable")
    os.close(fd)
    probe.unlink(missing_ok=True)
    return None


def check_output_dir(path: str | os.PathLike, option: str, *, replaced: bool = False) -> None:
    """Refuse ``path`` as an output directory (``option`` names the flag) unless it can be written:
    not a file, nothing but directories above it, and writable (an existing directory itself, else
    the nearest existing directory above it, where it will be created). ``replaced``: the directory
    is renamed into place whole (a run), so its parent must be writable too."""
    path = Path(path)
    where = _existing_ancestor(path, option)
    targets = [where]
    if where == path and replaced and path.resolve().parent != path.resolve():
        targets.append(path.resolve().parent)
    for d in targets:
        reason = probe_writable(d)
        if reason is not None:
            raise OutputError(path, option, f"cannot be written: {reason}" if d == path
                              else f"cannot write in {d}: {reason}")


def check_output_file(path: str | os.PathLike, option: str) -> None:
    """Refuse ``path`` as an output file (``option`` names the flag) unless it can be written: not a
    directory, and its directory writable (or creatable)."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(path, option, "is a directory; name a file")
    where = _existing_ancestor(path.parent, option)
    reason = probe_writable(where)
    if reason is not None:
        raise OutputError(path, option, f"cannot write in {where}: {reason}")


def _holder(f) -> str:
    f.seek(0)
    text = f.read().decode("utf-8", "replace").strip()
    return f"pid {text}" if text.isdigit() else "another process"


def _same_file(f, path: Path) -> bool:
    """Whether ``path`` still names the file ``f`` has open (a finished holder unlinks it)."""
    try:
        return os.stat(path).st_ino == os.fstat(f.fileno()).st_ino
    except FileNotFoundError:
        return False


def _acquire(lock_path: Path, wait: bool, what, on_wait: Callable[[str], None] | None):
    """The open, locked lock file (see :func:`exclusive_lock`)."""
    while True:
        f = open(lock_path, "a+b")
        try:
            try:
                fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _holder(f)
                if not wait:
                    raise OutputError(what, None, f"{holder} is writing it now (lock {lock_path.name}); "
                                                  "wait for it to finish or pick another output") from None
                if on_wait is not None:
                    on_wait(holder)
                    on_wait = None  # said once
                fcntl.flock(f.fileno(), fcntl.LOCK_EX)
            if _same_file(f, lock_path):
                return f
        except BaseException:
            f.close()
            raise
        f.close()  # the holder we waited for removed the file: lock the new one


@contextlib.contextmanager
def exclusive_lock(lock_path: str | os.PathLike, *, wait: bool, what: str | os.PathLike,
                   on_wait: Callable[[str], None] | None = None) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``lock_path`` (created as needed, holding this pid) for the block.

    Taken: ``wait=False`` raises :class:`~mitsnerf.errors.OutputError` naming ``what`` and the
    holder's pid; ``wait=True`` calls ``on_wait(holder)`` and blocks until it is free. The file is
    removed when the block ends (still locked, so a process that opened it meanwhile sees that it
    was unlinked and locks a new one instead).
    """
    lock_path = Path(lock_path)
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    f = _acquire(lock_path, wait, what, on_wait)
    try:
        f.truncate(0)
        f.write(str(os.getpid()).encode())
        f.flush()
        yield
    finally:
        lock_path.unlink(missing_ok=True)
        f.close()  # releases the lock


def progress_log(progress: bool = True) -> Callable[[str], None]:
    """Where a long command's progress lines go (``mitsnerf bench``'s, ``generate``'s ...): each line to stderr,
    flushed, terminal or not; nowhere when ``progress`` is off (``--no-progress``, the API's default).

    >>> progress_log(False)("nothing is printed")
    """
    if not progress:
        return lambda line: None
    return lambda line: print(line, file=sys.stderr, flush=True)
