"""Any batch of pixels, of any cameras, through a Mitsuba path tracer: a Monte Carlo estimate of each pixel
whose gradient comes from the integrator's own adjoint pass (path replay), with a primal independent of it.

``pixels(index, du, dv) -> (o, d)`` casts a ray through the point ``(du, dv)`` of pixel ``index`` (e.g.
:meth:`mitsnerf.math.rays.PixelRays.rays`). Each of the ``spp`` paths of a pixel draws its own point in the pixel,
so a pixel's estimate is of its box-filtered value, as Mitsuba's film is::

    I_p = 1/spp sum_{k < spp} L(ray_p(u_k, v_k)),   (u_k, v_k) ~ U[0, 1)^2

:func:`render_pixels` returns ``I_p`` (Array3f (P,)) at ``spp`` paths per pixel from seed ``seed``, attached to
the scene parameters ``params`` through a :class:`drjit.CustomOp`: a loss of it back-propagates with
``dr.backward``, and the op's backward pass renders ``spp_grad`` *other* paths per pixel (seed ``seed_grad``,
so their random numbers are independent of the primal's) in the integrator's primal-then-adjoint replay, with
the adjoint radiance ``dLoss/dI_p / spp_grad`` on each path. For ``Loss = f(I)`` the expected gradient is then
``E[f'(I)] E[dI]``: where ``f'`` is linear in ``I`` (L2) that is the gradient of ``f(E[I])`` plus
``f'``'s own noise, where the same paths gave both (``seed_grad = seed``) it carries the covariance of
``I`` and ``dI`` (the bias :func:`correlated_bias` measures).

This is what ``mi.render(scene, params, spp=, spp_grad=, seed_grad=)`` does for one whole sensor; here the
pixels are any ``P`` pixels of any cameras. The integrator must follow Mitsuba's ``RBIntegrator.sample``
signature (``prbvolpath``, ``mitsnerf_drt``); the camera rays start outside every medium.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr


@dataclass(frozen=True)
class PathBatch:
    """What a batch of pixels is traced with: the scene, its integrator, the pixels' indices and their rays."""

    scene: Any
    integrator: Any
    index: Any
    """UInt32 (P,): the pixels, as ``pixels`` numbers them."""
    pixels: Any
    """``(index, du, dv) -> (o, d)``: the ray through point ``(du, dv)`` of each pixel."""

    @property
    def size(self) -> int:
        return dr.width(self.index)


def path_rays(batch: PathBatch, sampler, spp: int):
    """``(ray, lane)``: ``spp`` rays per pixel, pixel-major (lane ``j`` belongs to pixel ``j // spp``), each
    through a point of its pixel drawn from ``sampler`` (seeded for ``P * spp`` lanes)."""
    import mitsuba as mi

    lane = dr.arange(mi.UInt32, batch.size * spp) // spp
    index = dr.gather(mi.UInt32, batch.index, lane)
    du_dv = sampler.next_2d()
    o, d = batch.pixels(index, du_dv.x, du_dv.y)
    return mi.Ray3f(mi.Point3f(o), mi.Vector3f(d)), lane


def seeded_sampler(seed: int, lanes: int):
    """An independent sampler seeded with ``seed`` for ``lanes`` parallel samples."""
    import mitsuba as mi

    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(int(seed) & 0xFFFFFFFF, int(lanes))
    return sampler


def pixel_means(L, spp: int):
    """The mean of each run of ``spp`` consecutive lanes: Array3f (P * spp,) -> (P,).

    >>> from drjit.llvm import Array3f
    >>> pixel_means(Array3f([1, 3, 5, 7], [0, 0, 2, 2], [1, 1, 1, 1]), 2)
    [[2, 0, 1],
     [6, 2, 1]]
    """
    return type(L)(*(dr.block_sum(L[c], spp) / spp for c in range(3)))


def trace_primal(batch: PathBatch, spp: int, seed: int):
    """``I`` (Array3f (P,)): each pixel's mean over ``spp`` paths of seed ``seed``, without derivatives."""
    import mitsuba as mi

    with dr.suspend_grad():
        sampler = seeded_sampler(seed, batch.size * spp)
        ray, _ = path_rays(batch, sampler, spp)
        L, _, _, _ = batch.integrator.sample(mode=dr.ADMode.Primal, scene=batch.scene, sampler=sampler, ray=ray,
                                             depth=mi.UInt32(0), δL=None, δaovs=None, state_in=None,
                                             active=mi.Bool(True))
        return pixel_means(mi.Color3f(L), spp)


def trace_adjoint(batch: PathBatch, spp: int, seed: int, grad_I) -> None:
    """Back-propagate ``grad_I`` (Array3f (P,), ``dLoss/dI``) into the scene's differentiated parameters through
    ``spp`` paths per pixel of seed ``seed``: their primal, then the integrator's adjoint replay of the same paths
    with ``grad_I / spp`` on each."""
    import mitsuba as mi

    with dr.suspend_grad():
        sampler = seeded_sampler(seed, batch.size * spp)
        ray, lane = path_rays(batch, sampler, spp)
        grad_L = mi.Spectrum(dr.gather(mi.Color3f, mi.Color3f(grad_I), lane) / spp)
        _, _, _, state = batch.integrator.sample(mode=dr.ADMode.Primal, scene=batch.scene, sampler=sampler.clone(),
                                                 ray=ray, depth=mi.UInt32(0), δL=None, δaovs=None, state_in=None,
                                                 active=mi.Bool(True))
        batch.integrator.sample(mode=dr.ADMode.Backward, scene=batch.scene, sampler=sampler, ray=ray,
                                depth=mi.UInt32(0), δL=grad_L, δaovs=None, state_in=state, active=mi.Bool(True))
        dr.eval()


class _PixelsOp(dr.CustomOp):
    """:func:`render_pixels` as a Dr.Jit custom operation (its inputs: the detached parameters, so that the op
    joins the AD graph; the attached ones are reached by the integrator's own ``dr.backward``)."""

    def eval(self, batch, _params, spp, seed):
        self.batch, self.spp, self.seed = batch, spp, seed
        return trace_primal(batch, spp[0], seed[0])

    def backward(self):
        trace_adjoint(self.batch, self.spp[1], self.seed[1], self.grad_out())

    def name(self):
        return "PixelsOp"


def render_pixels(batch: PathBatch, params: dict, *, spp: int, spp_grad: int, seed: int, seed_grad: int):
    """``I`` (Array3f (P,)): each pixel of ``batch`` at ``spp`` paths (seed ``seed``), differentiable with respect
    to ``params`` (a dict of the scene's attached parameters, e.g. ``{"sigma_t": tensor}``) through ``spp_grad``
    paths of seed ``seed_grad`` (see the module docstring; ``seed_grad == seed`` makes them the same paths when
    ``spp_grad == spp``: biased, for measuring only)."""
    return dr.custom(_PixelsOp, batch, params, (int(spp), int(spp_grad)), (int(seed), int(seed_grad)))
