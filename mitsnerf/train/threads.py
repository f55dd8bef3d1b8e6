"""Deterministic training: one Dr.Jit thread, so every gradient sum is added in one order.

Multi-threaded, the adjoint of a grid lookup (voxel, ngp, mitsuba-inverse) is a scatter-add whose
additions land in the order the threads happen to run, so two runs of the same config differ in the
last bits after a step and drift apart slowly from there. ``nerf`` sums its gradients in a fixed
order and is bit-identical with any thread count. On one thread every method is bit-identical run
to run (and resumed runs equal straight ones), at the cost of the other cores.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def one_thread(enabled: bool = True) -> Iterator[None]:
    """Inside the block Dr.Jit runs on one thread (``enabled``); the thread count is restored after."""
    if not enabled:
        yield
        return
    import drjit as dr

    before = dr.thread_count()
    dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(before)
