"""A run directory before training: what it holds, whether this run may write it, and its lock.

``mitsnerf train --out RUN`` (and each benchmark cell) claims ``RUN`` before any work starts
(:func:`claim_run_dir`): it must be a writable directory (or creatable) whose parent is writable
(a finished run is renamed into place whole); it is locked for the whole training
(``.RUN.lock`` beside it, holding the writer's pid), so a second writer is refused at once; and
what is already there decides what may happen:

========================= ================ ====================== =====================
RUN holds                 plain ``train``   ``--resume``            ``--force``
========================= ================ ====================== =====================
nothing (or is missing)   trains           refused: no checkpoint  trains
an interrupted run        refused          continues it            starts over
a finished run            refused          continues it (with      replaces it
                                            more ``--steps``)
other files, no run       refused          refused                 refused
========================= ================ ====================== =====================

An interrupted run is a ``checkpoint.npz`` without ``metrics.json``; a finished one has
``metrics.json``. Entries a run does not write (renders, exports, notes) are kept by every
rewrite of the directory (:func:`mitsnerf.runs.fit.write_run`).
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from mitsnerf.errors import CLI, OutputError, Placeholder, UsageError, Words
from mitsnerf.outputs import check_output_dir, exclusive_lock
from mitsnerf.train.checkpoint import CHECKPOINT_FILE

#: What a run writes in its directory (:func:`mitsnerf.runs.fit.write_run`); a fresh run removes these.
RUN_FILES = ("config.json", "params.npz", "history.json", "metrics.json", CHECKPOINT_FILE, "test")


@dataclass(frozen=True)
class RunDirState:
    kind: str
    """``"new"`` (missing or empty), ``"interrupted"``, ``"finished"`` or ``"foreign"`` (files, no run)."""
    detail: str = ""
    """For messages: the run's method and step, or the entries of a foreign directory."""


def _run_detail(path: Path) -> str:
    """``nerf, 120 steps`` from ``metrics.json``, ``""`` where it cannot be read."""
    try:
        m = json.loads((path / "metrics.json").read_text(encoding="utf-8"))
        return f"{m['method']}, {m['steps']} steps"
    except (OSError, ValueError, KeyError, TypeError):
        return ""


def inspect_run_dir(path: str | os.PathLike) -> RunDirState:
    """What ``path`` holds (see the module's table)."""
    path = Path(path)
    if not path.is_dir():
        return RunDirState("new")
    names = sorted(p.name for p in path.iterdir())
    if (path / "metrics.json").is_file():
        return RunDirState("finished", _run_detail(path))
    if (path / CHECKPOINT_FILE).is_file():
        return RunDirState("interrupted")
    if not names:
        return RunDirState("new")
    shown = ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")
    return RunDirState("foreign", shown)


def check_run_dir(path: str | os.PathLike, *, resume: bool, force: bool, words: Words = CLI,
                  option: str | None = None) -> RunDirState:
    """Refuse ``path`` for this run (an :class:`~mitsnerf.errors.OutputError`) per the module's table, advising
    the settings in ``words`` (:data:`~mitsnerf.errors.CLI`: ``--force``; :data:`~mitsnerf.errors.API`:
    ``force=True``); returns its state. ``option`` names the output (default: ``words``' ``out``).
    (Writability and the lock: :func:`claim_run_dir`.)"""
    path, option = Path(path), option or words.name("out")
    state = inspect_run_dir(path)
    if state.kind == "foreign":
        raise OutputError(path, option, f"not a mitsnerf run directory (holds {state.detail}); "
                                        "pick a new or empty directory")
    if resume and state.kind == "new":
        raise OutputError(path, option, f"no {CHECKPOINT_FILE} to resume from (train into it without "
                                        f"{words(resume=True)})")
    if not resume and not force and state.kind == "finished":
        what = f" ({state.detail})" if state.detail else ""
        raise OutputError(path, option, f"holds a finished run{what}; pass {words(force=True)} to replace it, "
                                        f"or {words(resume=True, steps=Placeholder('N'))} to train it on")
    if not resume and not force and state.kind == "interrupted":
        raise OutputError(path, option, f"holds an interrupted run ({CHECKPOINT_FILE}); pass {words(resume=True)} "
                                        f"to continue it or {words(force=True)} to start over")
    return state


def check_renamable(path: Path, words: Words = CLI, option: str | None = None) -> None:
    """Refuse a run directory that cannot be renamed into place: ``.``, ``..``, ``""``, the current
    directory or one above it, or ``/`` (a run is built beside its directory and renamed onto it)."""
    here, full = Path.cwd().resolve(), path.resolve()
    if path.name in ("", ".", "..") or full == here or full in here.parents:
        raise OutputError(None, option or words.name("out"),
                          f"{str(path)!r} is the current directory or one above it: a run is written beside its "
                          f"directory and renamed into place; name a new one, e.g. {words(out='run')}")


def check_outside_dataset(out: Path, dataset: Path, words: Words = CLI, what: str = "a run",
                          example: str = "runs/NAME", option: str = "out") -> None:
    """Refuse an output (``what``: a run, renders, an export, a scores file; set by ``option``, ``example`` a place
    to advise) inside (or at) the dataset directory: its files would change a hashed dataset. The one rule of every
    command that writes what it makes of a dataset."""
    if Path(out).resolve().is_relative_to(Path(dataset).resolve()):
        raise UsageError(words.name(option), f"{out} is inside the dataset {dataset}: {what} there would change the "
                                             f"dataset's files; put it outside, e.g. {words(**{option: example})}")


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of run directory ``path``: ``.NAME.lock`` beside it (the directory itself is
    renamed into place when the run finishes, so its lock cannot live inside it)."""
    path = Path(path).resolve()
    return path.parent / f".{path.name}.lock"


def remove_run_files(path: Path) -> None:
    """Delete what a run wrote in ``path`` (a fresh run starting over), keeping everything else."""
    import shutil

    for name in RUN_FILES:
        p = path / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


@contextlib.contextmanager
def claim_run_dir(path: str | os.PathLike, *, resume: bool = False, force: bool = False, words: Words = CLI,
                  option: str | None = None) -> Iterator[RunDirState]:
    """Check that ``path`` can be written, take its lock (refused at once if another process holds
    it), then check what it holds (:func:`check_run_dir`, its advice in ``words``) and hold the lock for the
    block. Yields the state. A run started over (``--force``) removes the old one's files only when training
    starts (:func:`mitsnerf.runs.fit.fit`), so a refusal on the way (a bad dataset) loses nothing."""
    path, option = Path(path), option or words.name("out")
    check_renamable(path, words, option)
    check_output_dir(path, option, replaced=True)
    with exclusive_lock(lock_path(path), wait=False, what=path):
        yield check_run_dir(path, resume=resume, force=force, words=words, option=option)
