"""What one run costs in memory, whatever ran before it in the same process: ``mitsnerf train``'s run and every
benchmark cell (:func:`mitsnerf.runs.fit.fit` measures both, into ``metrics.json``).

Two figures per run, both counted from the moment its scene is loaded (:func:`start`) to its end (training and
the evaluation of its test views):

- ``peak_memory_mb``, the run's own: the high-water mark of Dr.Jit's allocator (every array of the model, the
  optimiser's state, the ray batches, the renders and scores; host memory on the LLVM backend, device memory on
  CUDA), after releasing the allocator's cache of freed blocks and clearing its statistics at the start. What is
  still alive then (the loaded scene) counts in every run alike; what earlier runs used and freed counts in
  none. So it is the same whatever the order of a sweep's cells (``tests/bench/test_memory.py``). Memory outside
  Dr.Jit (numpy arrays, the interpreter, compiled kernels) is not in it.
- ``peak_rss_mb``: the resident set's high-water mark of the process (``VmHWM``), reset to the current resident
  set at the start where Linux allows (``/proc/self/clear_refs``; ``peak_rss_reset``), else the process's since it
  began (``getrusage``). It includes the process's baseline (interpreter, libraries, compiled kernels, the loaded
  scene), which depends on what ran before, so it compares runs only when each had its own process.

A resumed run counts from its resumption: the peaks of the process that continued it.
"""

from __future__ import annotations

import gc
import sys
from pathlib import Path

MIB = 1024.0 * 1024.0
PEAK_MEMORY_NOTE = ("peak_memory_mb: Dr.Jit's allocator high-water mark during the run (host memory on LLVM, device "
                    "memory on CUDA), its cache released and statistics cleared at the start: the run's own, whatever "
                    "the order of the cells; peak_rss_mb: the process's resident high-water mark, reset at the run's "
                    "start where Linux allows (peak_rss_reset), else since the process began, the process's "
                    "baseline included")


def _backend():
    import drjit as dr
    import mitsuba as mi

    return dr.backend_v(mi.Float)


def start() -> bool:
    """Start counting a run's peaks: free what the allocator caches, clear its statistics and reset the resident
    high-water mark (returns whether that reset was possible)."""
    import drjit as dr

    gc.collect()
    dr.sync_thread()
    dr.flush_malloc_cache()
    dr.detail.malloc_clear_statistics()
    return reset_rss_peak()


def reset_rss_peak(clear_refs: Path = Path("/proc/self/clear_refs")) -> bool:
    """Reset the process's resident high-water mark to its current resident set (Linux >= 4.0); False elsewhere."""
    try:
        clear_refs.write_text("5")
    except OSError:
        return False
    return True


def peak_memory_mb() -> float:
    """Dr.Jit's allocator high-water mark (MiB) since :func:`start`, on the backend of Mitsuba's variant."""
    import drjit as dr

    dr.sync_thread()
    return dr.detail.malloc_watermark(_backend()) / MIB


def peak_rss_mb(status: Path = Path("/proc/self/status")) -> float | None:
    """The process's resident high-water mark in MiB: ``VmHWM`` where ``/proc`` has it, else ``getrusage``'s (None
    where neither exists).

    >>> import tempfile
    >>> f = Path(tempfile.mkdtemp()) / "status"
    >>> _ = f.write_text("Name:\\tpython\\nVmHWM:\\t  2048 kB\\nVmRSS:\\t 1024 kB\\n")
    >>> peak_rss_mb(f)
    2.0
    """
    try:
        for line in status.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource
    except ImportError:  # pragma: no cover (Windows)
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / MIB if sys.platform == "darwin" else peak / 1024.0


def peaks(rss_reset: bool) -> dict[str, float | bool | None]:
    """The run's figures since :func:`start` (which returned ``rss_reset``), as ``metrics.json`` records them:
    ``peak_memory_mb``, ``peak_rss_mb`` and ``peak_rss_reset``."""
    return {"peak_memory_mb": peak_memory_mb(), "peak_rss_mb": peak_rss_mb(), "peak_rss_reset": rss_reset}
