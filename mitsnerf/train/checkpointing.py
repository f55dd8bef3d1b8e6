"""When training writes its checkpoint, and how it stops on a signal.

- every ``checkpoint_every`` steps, while the loss looks healthy (so the file left after a
  diverging run is the last good one);
- at the end;
- when interrupted: SIGINT (Ctrl-C), SIGTERM and SIGHUP (what ``timeout``, systemd, Slurm and
  Ray send) all stop training at the next Python instruction; the state after the last
  *completed* step is written and :class:`mitsnerf.errors.Interrupted` is raised with a message
  that says how to continue.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from mitsnerf.errors import Interrupted

STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


def _raise_interrupted(signum, frame) -> None:
    raise Interrupted(signum, f"stopped by {signal.Signals(signum).name}")


@contextmanager
def stop_signals() -> Iterator[None]:
    """Inside the block, SIGTERM and SIGHUP raise :class:`Interrupted` as Ctrl-C raises
    KeyboardInterrupt (only in the main thread, where Python delivers signals)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, _raise_interrupted) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def signal_number(exc: KeyboardInterrupt) -> int:
    """The signal behind an interrupt: its own for :class:`Interrupted`, SIGINT for Ctrl-C."""
    return exc.signum if isinstance(exc, Interrupted) else int(signal.SIGINT)


def interrupted_message(exc: KeyboardInterrupt, checkpoint: Path, step: int, while_: str = "") -> Interrupted:
    """The :class:`Interrupted` of ``exc`` saying which checkpoint is saved and how to continue."""
    signum = signal_number(exc)
    return Interrupted(signum, f"stopped by {signal.Signals(signum).name}{while_}; checkpoint of step {step} saved to "
                               f"{checkpoint}; continue with mitsnerf train --resume --out {checkpoint.parent}")


class CheckpointPolicy:
    """Decides which steps are saved; ``checkpointer`` None (no run directory) saves nothing."""

    def __init__(self, checkpointer, every: int) -> None:
        self.checkpointer = checkpointer
        self.every = int(every)

    def due(self, step: int, healthy: bool) -> bool:
        return self.checkpointer is not None and bool(self.every) and step % self.every == 0 and healthy

    def where(self) -> str:
        return self.checkpointer.describe() if self.checkpointer is not None else "no checkpoint (no run directory)"

    def interrupted(self, exc: KeyboardInterrupt, save) -> Interrupted:
        """Save through ``save()`` (the last completed step) and the exception to raise instead."""
        signum = signal_number(exc)
        name = signal.Signals(signum).name
        if self.checkpointer is None:
            return Interrupted(signum, f"stopped by {name}; no run directory, nothing saved")
        return interrupted_message(exc, self.checkpointer.path, save())
