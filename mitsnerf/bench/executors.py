"""Where cells run: in this process one after another (the default), in a local process pool,
or as Ray tasks on a cluster.

Every executor calls :func:`mitsnerf.bench.worker.run_cell` and hands each finished cell
to ``on_done(cell, record, artefacts)`` (or a failed one to ``on_error(cell, message,
details)``) in the driver, which writes it at once, so an interrupted sweep keeps every
finished cell. Timings are comparable only between cells that had the machine to
themselves: the sequential executor on an otherwise idle machine. The pool and Ray run
cells side by side; each cell then gets ``cpus_per_cell`` Dr.Jit threads.

- ``sequential``: in-process; the peak-memory figure is the process's high-water mark, so
  it includes the cells (and ground-truth renders) that ran before in the same process.
- ``pool``: ``concurrent.futures.ProcessPoolExecutor`` with ``spawn`` and one cell per
  worker process (Python >= 3.11; reused processes before), so each cell's peak memory is its own.
- ``ray``: one Ray task per cell (``num_cpus = cpus_per_cell``, ``max_calls = 1``: a fresh
  worker process each), on the cluster at ``address`` or a local instance started for the
  sweep (``ray.init()``). Nodes need the same mitsnerf installed; datasets missing on a node
  are generated there (cached per node); the results come back to the driver.

A row whose settings name another row's result (``"@LABEL"``, :mod:`mitsnerf.bench.references`) runs after
it: the sequential executor takes the cells in their planned order (a row after the rows it names); the pool
and Ray run the pending cells in dependency waves (:func:`~mitsnerf.bench.references.dependency_waves`: wave
``k + 1`` starts when every cell of wave ``k`` has finished), so a sweep without such rows is one wave, as
before. The referring cell reads the referred cell's ``run/`` where it runs: on a Ray cluster, the results
folder must be one every node shares (else the cell fails, saying so).
"""

from __future__ import annotations

import os
import signal
import sys
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

from mitsnerf.bench.cells import Cell
from mitsnerf.bench.references import dependency_waves
from mitsnerf.errors import CLI, UsageError, Words

EXECUTORS = ("sequential", "pool", "ray")
OnDone = Callable[[Cell, dict, bytes], None]
OnError = Callable[[Cell, str, str], None]
#: Exceptions that fail one cell (recorded as ``error.json``, retried by the next run; the sweep goes
#: on). ``KeyboardInterrupt`` and ``SystemExit`` stop the sweep.
CELL_ERRORS = (Exception,)


def _message(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def run_sequential(cells: Sequence[Cell], on_done: OnDone, on_error: OnError, *, progress: bool = True,
                   threads: int = 0, on_start: Callable[[Cell], None] | None = None) -> None:
    """Run the cells one after another in this process, each scene loaded once (:class:`~mitsnerf.bench.worker.
    SceneLoads`)."""
    from mitsnerf.bench.worker import SceneLoads, run_cell

    loads = SceneLoads()
    for cell in cells:
        if on_start is not None:
            on_start(cell)
        try:
            record, artefacts = run_cell(cell, progress=progress, threads=threads, executor="sequential", loads=loads)
        except CELL_ERRORS as exc:
            on_error(cell, _message(exc), traceback.format_exc())
            continue
        on_done(cell, record, artefacts)


def _pool_task(cell: Cell, threads: int) -> tuple[dict, bytes]:
    from mitsnerf.bench.worker import run_cell

    return run_cell(cell, progress=False, threads=threads, executor="pool", fresh_process=sys.version_info >= (3, 11))


def run_pool(cells: Sequence[Cell], on_done: OnDone, on_error: OnError, *, workers: int = 0, threads: int = 0) -> None:
    """Run the cells in ``workers`` spawned processes (0: one per two cores, at least one)."""
    import concurrent.futures as cf
    import multiprocessing as mp

    workers = workers or max(1, (os.cpu_count() or 2) // 2)
    threads = threads or max(1, (os.cpu_count() or 1) // workers)
    kwargs: dict[str, Any] = {"max_workers": workers, "mp_context": mp.get_context("spawn")}
    if sys.version_info >= (3, 11):
        kwargs["max_tasks_per_child"] = 1
    pool = cf.ProcessPoolExecutor(**kwargs)
    try:
        for wave in dependency_waves(cells):
            _pool_wave(pool, wave, threads, on_done, on_error)
    except BaseException as exc:
        in_flight = list((pool._processes or {}).values())  # (no public handle before Python 3.14)
        pool.shutdown(wait=False, cancel_futures=True)  # Ctrl-C: do not wait for queued cells
        if isinstance(exc, KeyboardInterrupt):
            _stop_cells_in_flight(in_flight, exc)
        raise
    pool.shutdown(wait=True)


def _pool_wave(pool, cells: Sequence[Cell], threads: int, on_done: OnDone, on_error: OnError) -> None:
    """Run ``cells`` (one wave: none refers to another) on ``pool``; return when every one has finished."""
    import concurrent.futures as cf

    futures = {pool.submit(_pool_task, cell, threads): cell for cell in cells}
    for future in cf.as_completed(futures):
        cell = futures[future]
        try:
            record, artefacts = future.result()
        except CELL_ERRORS as exc:
            on_error(cell, _message(exc), "".join(traceback.format_exception(exc)))
            continue
        on_done(cell, record, artefacts)


def _stop_cells_in_flight(workers, exc: KeyboardInterrupt) -> None:
    """Pass a SIGTERM or SIGHUP that stopped the sweep on to the pool's workers, so each cell in training saves
    its checkpoint and stops (the next run continues it) rather than running to its end while the driver, stopped,
    waits to exit. Ctrl-C at a terminal reaches the workers by itself (one process group): not sent twice."""
    from mitsnerf.train.checkpointing import signal_number

    signum = signal_number(exc)
    if signum == signal.SIGINT:
        return
    for process in workers:
        if process.is_alive():
            os.kill(process.pid, signum)


def _ray_task(cell: Cell, threads: int) -> tuple[dict, bytes]:
    from mitsnerf.bench.worker import run_cell

    return run_cell(cell, progress=False, threads=threads, executor="ray", fresh_process=True)


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def run_ray(cells: Sequence[Cell], on_done: OnDone, on_error: OnError, *, address: str | None = None,
            workers: int = 0, threads: int = 0, words: Words = CLI) -> None:
    """Run the cells as Ray tasks: on the cluster at ``address``, else on a local instance.

    ``workers``: at most that many cells in flight (0: as many as the cluster schedules);
    ``threads``: CPUs (and Dr.Jit threads) per cell (0: 1). A local instance started here is
    shut down at the end; a cluster is only disconnected from.
    """
    try:
        import ray
    except ImportError:
        raise UsageError(words(executor="ray"), NO_RAY) from None

    threads = threads or 1
    started_here = not ray.is_initialized()
    if started_here:
        init: dict[str, Any] = {"address": address, "include_dashboard": False, "log_to_driver": True,
                "ignore_reinit_error": True}
        if address is None:
            init["num_cpus"] = max(os.cpu_count() or 1, threads)
        ray.init(**init)
    in_flight: dict = {}
    try:
        task = ray.remote(num_cpus=threads, max_calls=1)(_ray_task)
        for wave in dependency_waves(cells):
            _ray_wave(ray, task, wave, workers or len(wave), threads, in_flight, on_done, on_error)
    except BaseException:
        for ref in list(in_flight):
            ray.cancel(ref, force=True)
        raise
    finally:
        if started_here:
            ray.shutdown()


def _ray_wave(ray, task, cells: Sequence[Cell], limit: int, threads: int, in_flight: dict, on_done: OnDone,
              on_error: OnError) -> None:
    """Run ``cells`` (one wave: none refers to another) as Ray tasks, at most ``limit`` at once, tracked in
    ``in_flight`` (the caller cancels what is left there on an interrupt); return when every one has finished."""
    queue = list(cells)
    while queue or in_flight:
        while queue and len(in_flight) < limit:
            cell = queue.pop(0)
            in_flight[task.remote(cell, threads)] = cell
        done, _ = ray.wait(list(in_flight), num_returns=1)
        for ref in done:
            cell = in_flight.pop(ref)
            try:
                record, artefacts = ray.get(ref)
            except CELL_ERRORS as exc:
                cause = getattr(exc, "cause", None) or exc
                on_error(cell, _message(cause), str(exc))
                continue
            on_done(cell, record, artefacts)


def _is_main_guard(node) -> bool:
    """Whether an ``ast`` node is ``if __name__ == "__main__":`` (either side of the ``==``)."""
    import ast

    test = node.test if isinstance(node, ast.If) else None
    if not isinstance(test, ast.Compare) or len(test.ops) != 1 or not isinstance(test.ops[0], ast.Eq):
        return False
    sides = [test.left, test.comparators[0]]
    return any(isinstance(a, ast.Name) and a.id == "__name__" for a in sides) and \
        any(isinstance(b, ast.Constant) and b.value == "__main__" for b in sides)


def _guarded(source: str, line: int) -> bool:
    """Whether line ``line`` of a module's ``source`` lies in the body of an ``if __name__ == "__main__":``.

    >>> _guarded("import x\\nif __name__ == '__main__':\\n    x.run()\\n", 3), _guarded("import x\\nx.run()\\n", 2)
    (True, False)
    """
    import ast

    return any(isinstance(node, ast.If) and _is_main_guard(node)
               and node.body[0].lineno <= line <= (node.body[-1].end_lineno or line)
               for node in ast.walk(ast.parse(source)))


def unguarded_main_line() -> str | None:
    """``FILE:LINE`` of the statement of the ``__main__`` script running now when it is not under ``if __name__
    == "__main__":``, else None (guarded; or no script to import again: a notebook, the REPL, ``python -c``,
    ``python -m PACKAGE``).

    A process pool started with ``spawn`` imports that script again in every worker (as ``__mp_main__``), so
    the statement would run again there: the worker would do the caller's work again and, reaching the pool,
    stop while it bootstraps (multiprocessing's ``RuntimeError: An attempt has been made to start a new process
    before the current process has finished its bootstrapping phase``), leaving the pool broken and each cell
    failed with no reason. Read from the caller's stack and the script's source: what the worker would do,
    known before it is started."""
    import sys

    main = sys.modules.get("__main__")
    spec_name = getattr(getattr(main, "__spec__", None), "name", None) or ""
    path = getattr(main, "__file__", None)
    if main is None or path is None or spec_name == "__main__" or spec_name.endswith(".__main__"):
        return None  # what multiprocessing's spawn does not import again (spawn._fixup_main_from_name)
    frame: FrameType | None = sys._getframe(1)
    module_frame = None
    while frame is not None:
        if frame.f_globals is vars(main) and frame.f_code.co_name == "<module>":
            module_frame = frame
        frame = frame.f_back
    if module_frame is None:
        return None
    try:
        source = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    try:
        guarded = _guarded(source, module_frame.f_lineno)
    except (SyntaxError, ValueError):  # not Python as read here: nothing can be said
        return None
    return None if guarded else f"{path}:{module_frame.f_lineno}"


def check_main_guard(words: Words = CLI) -> None:
    """A :class:`~mitsnerf.errors.UsageError` naming the script line and the ``if __name__ == "__main__":`` guard
    when a ``spawn`` pool started here would run the caller's script again (:func:`unguarded_main_line`)."""
    where = unguarded_main_line()
    if where is not None:
        raise UsageError(words(executor="pool"), f"its workers start by spawn, which imports the script again, and "
                                                 f"{where} (this call) is not under 'if __name__ == \"__main__\":', "
                                                 "so every worker would run it again and fail while it starts; put "
                                                 "the call under that guard (a notebook needs nothing)")


NO_RAY = "Ray is not installed; pip install 'mitsnerf[ray]' (or: pip install 'ray[default]')"


def check_options(executor: str, workers: int = 0, threads: int = 0, address: str | None = None,
                  words: Words = CLI) -> None:
    """A :class:`~mitsnerf.errors.UsageError` (a ValueError naming the option in ``words``: ``--workers``, or
    ``workers`` from the Python API) for settings the executor cannot honour."""
    if executor not in EXECUTORS:
        raise UsageError(words.name("executor"), f"must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    if address is not None and executor != "ray":
        raise UsageError(words.name("address"), f"only with {words(executor='ray')}")
    for name, value in (("workers", workers), ("cpus_per_cell", threads)):
        if value < 0:
            raise UsageError(words.name(name), f"must be >= 0, got {value}")
    if executor == "sequential" and workers > 1:
        raise UsageError(words.name("workers"), "the sequential executor runs one cell at a time (use "
                                                f"{words(executor='pool')} or {words(executor='ray')})")
    if executor == "ray" and not ray_available():
        raise UsageError(words(executor="ray"), NO_RAY)
    if executor == "pool":
        check_main_guard(words)


def run_cells(executor: str, cells: Sequence[Cell], on_done: OnDone, on_error: OnError, *, progress: bool = True,
              workers: int = 0, threads: int = 0, address: str | None = None,
              on_start: Callable[[Cell], None] | None = None, words: Words = CLI) -> None:
    """Dispatch to the named executor (one of :data:`EXECUTORS`); ``on_start`` (sequential only)
    is called before each cell; ``words``: how refusals name the options (:class:`mitsnerf.errors.Words`)."""
    check_options(executor, workers, threads, address, words)
    if executor == "sequential":
        run_sequential(cells, on_done, on_error, progress=progress, threads=threads, on_start=on_start)
    elif executor == "pool":
        run_pool(cells, on_done, on_error, workers=workers, threads=threads)
    elif executor == "ray":
        run_ray(cells, on_done, on_error, address=address, workers=workers, threads=threads, words=words)
    else:  # pragma: no cover (check_options)
        raise ValueError(f"--executor: unknown {executor!r}")
