"""Deterministic training: one Dr.Jit thread, so every gradient sum is added in one order.

Multi-threaded, the adjoint of a grid lookup (voxel, ngp, mitsuba-inverse) is a scatter-add whose
additions land in the order the threads happen to run, so two runs of the same config differ in the
last bits after a step and drift apart slowly from there. ``nerf`` sums its gradients in a fixed
order and is bit-identical with any thread count. On one thread every method is bit-identical run
to run (and resumed runs equal straight ones), at the cost of the other cores.

That holds on the LLVM backend only. On CUDA the scatter-adds are float atomics whose order the GPU's
scheduling decides, one thread or not: :func:`nondeterminism` says so, and a deterministic run there is
refused rather than promised (measured on an H200: a resumed 6-step run ends 1.5e-8 to 1.2e-7 away from
the run never stopped, where LLVM on one thread gives 0).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


def nondeterminism(variant: str | None = None) -> str | None:
    """Why training on ``variant`` cannot repeat bit for bit even on one thread, or ``None`` where one
    thread makes every method bit-identical. ``variant`` defaults to Mitsuba's active variant (else the
    one :func:`mitsnerf.env.default_variant` would pick).

    >>> nondeterminism("llvm_ad_rgb") is None
    True
    >>> nondeterminism("cuda_ad_rgb").startswith("cuda_ad_rgb adds gradients with float atomics")
    True
    """
    if variant is None:
        import mitsuba as mi

        from mitsnerf.env import default_variant

        variant = mi.variant() or default_variant()
    if variant.startswith("cuda"):
        return (f"{variant} adds gradients with float atomics in an order the GPU decides, so no run on it "
                "repeats bit for bit; MITSNERF_VARIANT=llvm_ad_rgb trains bit-identically on one thread")
    return None


def refuse_nondeterministic(deterministic: bool, option: str = "deterministic", why_asked: str = "") -> None:
    """Raise :class:`mitsnerf.errors.UsageError` naming ``option`` if ``deterministic`` is asked for on a backend
    that cannot keep it (:func:`nondeterminism`); ``why_asked`` tells a user who did not ask (a resumed run).
    Called before anything is written, so that a refused run leaves nothing behind."""
    why = nondeterminism() if deterministic else None
    if why is not None:
        from mitsnerf.errors import UsageError

        raise UsageError(option, why_asked + why)


@contextmanager
def one_thread(enabled: bool = True) -> Iterator[None]:
    """Inside the block Dr.Jit runs on one thread (``enabled``); the thread count is restored after.

    Raises :class:`mitsnerf.errors.UsageError` (a ``ValueError``) if ``enabled`` on a backend where one
    thread does not make training bit-identical (:func:`nondeterminism`): a deterministic run is refused there,
    never promised."""
    if not enabled:
        yield
        return
    refuse_nondeterministic(True)
    import drjit as dr

    before = dr.thread_count()
    dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(before)
