"""When training writes its checkpoint, and how it stops on a signal.

- every ``checkpoint_every`` steps, while the loss looks healthy (so the file left after a
  diverging run is the last good one);
- at the end;
- when interrupted: SIGINT (Ctrl-C), SIGTERM and SIGHUP (what ``timeout``, systemd, Slurm and
  Ray send) all stop training at the next Python instruction; the state after the last
  *completed* step is written and :class:`mitsnerf.errors.Interrupted` is raised with a message
  that says how to continue.

The next Python instruction may be inside a finalizer (``__del__``, a weakref callback, a
generator the garbage collector closes), which cannot propagate an exception: Python would print
the stop as "Exception ignored in ..." and run on. Inside :func:`stop_signals` such a stop is
signalled again, and raised at the next instruction outside the finalizer; one that arrives while
a module is imported is raised once the import is over, and one that arrives while an archive is
written (an ``.npz``: a checkpoint, a run's export) once the archive is complete.
"""

from __future__ import annotations

import _thread
import inspect
import signal
import sys
import threading
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from mitsnerf.errors import CLI, Interrupted, Words

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: The frames of an import in progress: a stop raised there can leave a C extension half initialised (matplotlib's
#: ft2font then aborts the interpreter's teardown: exit status 134, not 143), so it waits for the import to end.
IMPORT_MACHINERY = frozenset({"<frozen importlib._bootstrap>", "<frozen importlib._bootstrap_external>"})
#: The code of an archive being written (or read): a stop raised there leaves the zip with an open writing handle, whose
#: finalizer then prints a traceback ("Can't close the ZIP file while there is an open writing handle"), and the
#: archive (a checkpoint in the making) unreadable. The stop waits for ``np.savez`` to return.
ARCHIVE_WRITERS = frozenset({zipfile.__file__, inspect.getfile(inspect.unwrap(np.savez))})
#: Where a stop waits.
DEFERRED_IN = IMPORT_MACHINERY | ARCHIVE_WRITERS
#: How soon a stop handed back is signalled again.
HAND_BACK_SECONDS = 0.01


class _Stops:
    """The handler and ``sys.unraisablehook`` of one :func:`stop_signals` block.

    The handler raises KeyboardInterrupt for SIGINT and :class:`Interrupted` for the others. A stop
    raised in a finalizer reaches :meth:`hook` instead of the code that was running; it is handed
    back: signalled again from a timer thread (``_thread.interrupt_main``), so the handler raises it
    in the main thread's next instruction, outside the finalizer (handed back again if that is in
    one too). A stop arriving during an import, or while an archive is written, is handed back
    until the import is over or the archive complete. The block
    waits for its hand-backs before it ends.
    """

    def __init__(self, previous_hook) -> None:
        self.previous_hook = previous_hook
        self.pending: list[threading.Timer] = []

    def handler(self, signum, frame) -> None:
        while frame is not None:
            if frame.f_code is _Stops.hook.__code__ or frame.f_code.co_filename in DEFERRED_IN:
                self.hand_back(signum)  # lost in the hook; in an import it breaks the module, in a zip the archive
                return
            frame = frame.f_back
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise Interrupted(signum, f"stopped by {signal.Signals(signum).name}")

    def hook(self, unraisable) -> None:
        stop = unraisable.exc_value
        if isinstance(stop, KeyboardInterrupt) and threading.current_thread() is threading.main_thread():
            self.hand_back(signal_number(stop))
            return
        self.previous_hook(unraisable)

    def hand_back(self, signum: int) -> None:
        timer = threading.Timer(HAND_BACK_SECONDS, _thread.interrupt_main, (signum,))
        timer.daemon = True
        self.pending.append(timer)
        timer.start()

    def settle(self) -> None:
        """Wait for the hand-backs (the last one's stop is raised here, while the handler is still set)."""
        while self.pending:
            self.pending.pop(0).join()


@contextmanager
def stop_signals() -> Iterator[None]:
    """Inside the block, SIGTERM and SIGHUP raise :class:`Interrupted` as Ctrl-C raises
    KeyboardInterrupt, also when the signal lands in a finalizer, and after the import in progress
    (only in the main thread, where Python delivers signals; see :class:`_Stops`)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    stops = _Stops(sys.unraisablehook)
    previous = {s: signal.signal(s, stops.handler) for s in STOP_SIGNALS}
    sys.unraisablehook = stops.hook
    try:
        try:
            yield
        finally:
            stops.settle()
    finally:
        sys.unraisablehook = stops.previous_hook
        for s, handler in previous.items():
            signal.signal(s, handler)


def signal_number(exc: KeyboardInterrupt) -> int:
    """The signal behind an interrupt: its own for :class:`Interrupted`, SIGINT for Ctrl-C."""
    return exc.signum if isinstance(exc, Interrupted) else int(signal.SIGINT)


def interrupted_message(exc: KeyboardInterrupt, checkpoint: Path, step: int, while_: str = "",
                        words: Words = CLI) -> Interrupted:
    """The :class:`Interrupted` of ``exc`` saying which checkpoint is saved and how to continue (in ``words``)."""
    signum = signal_number(exc)
    again = words.command("train", resume=True, out=checkpoint.parent)
    return Interrupted(signum, f"stopped by {signal.Signals(signum).name}{while_}; checkpoint of step {step} saved to "
                               f"{checkpoint}; continue with {again}")


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
        return interrupted_message(exc, self.checkpointer.path, save(), words=self.checkpointer.words)
