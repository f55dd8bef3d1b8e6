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
"""

from __future__ import annotations

import os
import signal
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from mitsnerf.bench.cells import Cell

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
        futures = {pool.submit(_pool_task, cell, threads): cell for cell in cells}
        for future in cf.as_completed(futures):
            cell = futures[future]
            try:
                record, artefacts = future.result()
            except CELL_ERRORS as exc:
                on_error(cell, _message(exc), "".join(traceback.format_exception(exc)))
                continue
            on_done(cell, record, artefacts)
    except BaseException as exc:
        in_flight = list((pool._processes or {}).values())  # (no public handle before Python 3.14)
        pool.shutdown(wait=False, cancel_futures=True)  # Ctrl-C: do not wait for queued cells
        if isinstance(exc, KeyboardInterrupt):
            _stop_cells_in_flight(in_flight, exc)
        raise
    pool.shutdown(wait=True)


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
            workers: int = 0, threads: int = 0) -> None:
    """Run the cells as Ray tasks: on the cluster at ``address``, else on a local instance.

    ``workers``: at most that many cells in flight (0: as many as the cluster schedules);
    ``threads``: CPUs (and Dr.Jit threads) per cell (0: 1). A local instance started here is
    shut down at the end; a cluster is only disconnected from.
    """
    try:
        import ray
    except ImportError:
        from mitsnerf.errors import UsageError

        raise UsageError("--executor ray", "Ray is not installed; pip install 'mitsnerf[ray]' "
                                           "(or: pip install 'ray[default]')") from None

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
        queue = list(cells)
        limit = workers or len(queue)
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
    except BaseException:
        for ref in list(in_flight):
            ray.cancel(ref, force=True)
        raise
    finally:
        if started_here:
            ray.shutdown()


def check_options(executor: str, workers: int = 0, threads: int = 0, address: str | None = None) -> None:
    """A :class:`~mitsnerf.errors.UsageError` (a ValueError naming the CLI option) for settings the
    executor cannot honour."""
    from mitsnerf.errors import UsageError

    if executor not in EXECUTORS:
        raise UsageError("--executor", f"must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    if address is not None and executor != "ray":
        raise UsageError("--address", "only with --executor ray")
    if workers < 0 or threads < 0:
        raise UsageError("--workers, --cpus-per-cell", "must be >= 0")
    if executor == "sequential" and workers > 1:
        raise UsageError("--workers", "the sequential executor runs one cell at a time (use --executor pool or ray)")
    if executor == "ray" and not ray_available():
        raise UsageError(
            "--executor ray", "Ray is not installed; pip install 'mitsnerf[ray]' (or: pip install 'ray[default]')"
        )


def run_cells(executor: str, cells: Sequence[Cell], on_done: OnDone, on_error: OnError, *, progress: bool = True,
              workers: int = 0, threads: int = 0, address: str | None = None,
              on_start: Callable[[Cell], None] | None = None) -> None:
    """Dispatch to the named executor (one of :data:`EXECUTORS`); ``on_start`` (sequential only)
    is called before each cell."""
    check_options(executor, workers, threads, address)
    if executor == "sequential":
        run_sequential(cells, on_done, on_error, progress=progress, threads=threads, on_start=on_start)
    elif executor == "pool":
        run_pool(cells, on_done, on_error, workers=workers, threads=threads)
    elif executor == "ray":
        run_ray(cells, on_done, on_error, address=address, workers=workers, threads=threads)
    else:  # pragma: no cover (check_options)
        raise ValueError(f"--executor: unknown {executor!r}")
