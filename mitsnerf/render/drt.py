"""``mitsnerf_drt``: a differentiable volumetric path tracer whose density gradient comes from differential ratio
tracking (after Nimier-David et al. 2022, "Unbiased Inverse Volume Rendering with Differential Trackers").

The scene: one box (any shape, its bounding box is used) with a ``null`` BSDF around a ``heterogeneous`` medium
whose ``sigma_t`` (one channel, or three: a chromatic extinction) and ``albedo`` (three, at a resolution of its
own) are grids filling the box, lit by environment, directional or point emitters; nothing else. Free flights
use a coarse majorant grid (:mod:`mitsnerf.render.tracking`) instead of the grid's global maximum.

**Primal** (``mi.render``): a path tracer. Along each segment ``[t_0, t_1]`` of the box, tentative collisions at
rate ``sigma_bar``; a collision is real with probability ``P = mean_c sigma_t,c / sigma_bar`` (the channel mean:
every path carries all three channels, none is sampled). A real collision multiplies the throughput by
``albedo_c sigma_t,c / mean(sigma_t)``, a null one by ``(sigma_bar - sigma_t,c) / (sigma_bar - mean(sigma_t))``
(both 1 and ``albedo`` for a grey medium: plain delta tracking). At a real collision: next-event estimation of
the emitters (shadow transmittance by ratio tracking, ``prod (1 - sigma_t,c / sigma_bar)``; the environment
multiple-importance-weighted against phase sampling, power heuristic) and a phase-sampled new direction; an
escaping ray adds the environment. Russian roulette after ``rr_depth`` scatterings; ``max_depth`` as Mitsuba's
``volpath`` counts it.

**Gradient** (``mi.render(..., params)`` then ``dr.backward``; path replay: the adjoint pass retraces each
path with the same random numbers, knowing the primal radiance). Per segment, with ``T`` the transmittance from
its start, ``L_s`` the in-scattered radiance and ``L(t)`` the radiance arriving at ``t`` along the segment,
the derivative of the radiance ``L(x)`` leaving it splits into::

    dL = int T sigma_t d(albedo) L_s dt  +  int T albedo d(sigma_t) L_s dt  -  int T d(sigma_t) L(t) dt  + (recursion)
          (1) albedo                      (2) in-scattering                  (3) attenuation

1. at the primal's real collision ``t*`` (density ``sigma_t T``): ``(d albedo / albedo)(t*) x`` the radiance
   that the rest of the path carries;
2. **differential ratio tracking**: a ratio-tracking walk over the whole segment (its own random numbers) gives
   tentative points ``t_i`` with ``T_i = prod_{j<i} (1 - sigma_t(t_j) / sigma_bar(t_j))``; a reservoir keeps one,
   ``y``, with probability ``w_i / W``, ``w_i = mean_c T_c,i / sigma_bar(t_i)``, ``W = sum_i w_i``, so that
   ``W (T_c,y / mean T_y) g(y)`` estimates ``int T_c g`` with distances drawn in proportion to the *unweighted*
   transmittance. The free-flight alternative (``drt = false``) estimates (2) at ``t*`` as
   ``(d sigma_t / sigma_t)(t*) x`` the same radiance, whose variance grows without bound where ``sigma_t``
   nears 0 and which never sees a voxel the tracker cannot collide in. ``L_s(y)`` needs a path of its own
   (next-event estimation and a continued path from ``y``); to stay linear in the path length, one segment per
   camera path is chosen, by a second reservoir with weights ``mean_c beta_c W`` (``beta``: the throughput
   before the segment), and only there is ``L_s(y)`` traced;
3. with ``C`` the radiance of the path from the segment on, ``E[C 1(t* > t)] = T(t) L(t)`` (the path survives to
   ``t``, and its continuation from there is a valid estimate of ``L(t)``), so (3) is
   ``-E[C int_0^t* d(sigma_t)]``; the same walk's points before ``t*`` (a Poisson process independent of the
   path) give that integral by a reservoir with weights ``1 / sigma_bar``.

Every walk plays Russian roulette once its mean transmittance falls below :data:`ROULETTE_BELOW` (the gradient
walk only beyond ``t*``). The shadow rays of next-event estimation add ``-K int d(sigma_t)`` over their points,
with the ratio-tracking product of the *other* points (``sum_i (d sigma_t(u_i) / sigma_bar_i) prod_{j != i}
(1 - r_j)``, unbiased for ``T int d sigma_t``; one point kept by a reservoir). The phase function and the emitters
are not differentiated. A chromatic ``sigma_t``: each channel's extinction gets its gradient from that channel's
estimates (the walks' products and the path's radiance per channel); a grey one, from the sum over channels.

Parameters: ``max_depth`` (-1: unlimited), ``rr_depth`` (5), ``majorant_cell`` (voxels per majorant cell along
each axis, 4), ``majorant_floor`` (the least majorant, world units^-1, 0), ``drt`` (true). ``integrator.free``:
an optional (R, R, R) bool grid of the voxels that may change; cells reading none of them get no floor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import drjit as dr
import numpy as np

from mitsnerf.math.box import Box
from mitsnerf.render.tracking import exponential, majorant_grid, trilinear, walk_start, walk_step

NAME = "mitsnerf_drt"

#: Plugin classes already registered, by Mitsuba variant (each derives from its variant's ``RBIntegrator``).
_CLASSES: dict[str, type] = {}


def ratio_factor(sigma_t, sigma_bar):
    """Ratio tracking's factor at a tentative collision: ``1 - sigma_t / sigma_bar`` (per channel).

    >>> from drjit.llvm import Float
    >>> ratio_factor(Float(1.0, 3.0), Float(4.0))
    [0.75, 0.25]
    """
    return 1.0 - sigma_t / sigma_bar


ROULETTE_BELOW = 0.1
"""A walk whose mean transmittance falls below this goes on with probability ``mean T / ROULETTE_BELOW`` (its
products divided by that probability): unbiased, and far fewer points deep inside a dense medium."""


def walk_roulette(transmittance, u, active):
    """``(keep, scale)`` of Russian roulette on a walk's transmittance (:data:`ROULETTE_BELOW`); ``u`` uniform.

    >>> from drjit.llvm import Array3f, Bool, Float
    >>> walk_roulette(Array3f(0.5, 0.02, 0.01), Float(0.9), Bool(True))         # mean 0.18: no roulette
    ([True], [1])
    >>> walk_roulette(Array3f(0.02, 0.02, 0.02), Float(0.1, 0.3), Bool(True))   # survives with probability 0.2
    ([True, False], [5])
    """
    mean = dr.mean(transmittance)
    rr = active & (mean < ROULETTE_BELOW)
    q = dr.maximum(mean / ROULETTE_BELOW, 1e-6)
    return ~rr | (u < q), dr.select(rr, dr.rcp(q), 1.0)


def drt_weight(transmittance, sigma_bar):
    """The reservoir weight of a point of differential ratio tracking: ``mean_c T_c / sigma_bar``, the unweighted
    transmittance up to the point over the majorant (the density of its tentative collisions).

    >>> from drjit.llvm import Array3f, Float
    >>> drt_weight(Array3f(0.2, 0.4, 0.6), Float(2.0))
    [0.2]
    """
    return dr.mean(transmittance) / sigma_bar


class GridMedium:
    """The scene's medium as the tracker reads it: the grids (flat, attached when differentiated), the box,
    the majorant grid and the phase function."""

    def __init__(self, mi: Any, scene, cell: int, floor: float, free) -> None:
        shapes = [s for s in scene.shapes() if s.interior_medium() is not None]
        if len(shapes) != 1:
            raise ValueError(f"{NAME}: the scene needs exactly one shape with an interior medium, found {len(shapes)}")
        medium = shapes[0].interior_medium()
        p = mi.traverse(medium)
        if "sigma_t.data" not in p or "albedo.data" not in p:
            raise ValueError(f"{NAME}: the medium needs gridvolume sigma_t and albedo (heterogeneous), "
                             f"found parameters {sorted(p.keys())}")
        sigma, albedo = p["sigma_t.data"], p["albedo.data"]
        self.mi, self.res, self.channels = mi, int(sigma.shape[0]), int(sigma.shape[-1])
        self.albedo_res = int(albedo.shape[0])
        if tuple(albedo.shape) != (self.albedo_res,) * 3 + (3,) or self.channels not in (1, 3):
            raise ValueError(f"{NAME}: grids must be (R, R, R, 1 or 3) and (A, A, A, 3), got {tuple(sigma.shape)} "
                             f"and {tuple(albedo.shape)}")
        self.scale = float(p["scale"]) if "scale" in p else 1.0
        self.sigma, self.albedo_data = sigma.array, albedo.array
        bbox = shapes[0].bbox()
        lo, hi = [float(v) for v in bbox.min], [float(v) for v in bbox.max]
        self.box = Box((lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]))
        self.lo, self.size = mi.ScalarPoint3f(self.box.lo), mi.ScalarVector3f(self.box.size)
        self.cells = max(1, -(-self.res // int(cell)))
        values = np.asarray(dr.detach(sigma), dtype=np.float32).reshape(self.res, self.res, self.res, -1)
        self.majorant = mi.Float(majorant_grid(values * self.scale, self.cells, floor, free).ravel())
        self.phase = medium.phase_function()

    def sigma_t(self, p, active=True):
        """The extinction at ``p`` (Spectrum)."""
        local = (p - self.lo) / self.size
        return self.mi.Spectrum(trilinear(self.mi, self.sigma, self.res, self.channels, local, active) * self.scale)

    def albedo(self, p, active=True):
        """The albedo at ``p`` (Spectrum)."""
        local = (p - self.lo) / self.size
        return self.mi.Spectrum(trilinear(self.mi, self.albedo_data, self.albedo_res, 3, local, active))

    def interval(self, o, d):
        """``(t_0, t_1, hit)`` of the rays in the box (``t_0 = 0`` inside it)."""
        return self.box.intersect(o, d)

    def walk(self, o, d, t0, t1, tau):
        return walk_start(self.mi, o, d, t0, t1, self.lo, self.size, self.cells, tau)

    def step(self, w, active):
        return walk_step(self.mi, w, self.majorant, self.cells, active)


@dataclass
class PathState:
    """One path's state between segments (a Dr.Jit PyTree: the path loop's state)."""

    o: Any
    d: Any
    beta: Any
    """Spectrum: the throughput up to ``o``."""
    L: Any
    """Spectrum: the radiance gathered (primal), or still to come (adjoint: the primal's, less what was passed)."""
    depth: Any
    """UInt32: scattering events so far."""
    direct: Any
    """Bool: no scattering yet (an environment seen directly gets no MIS weight)."""
    last_pdf: Any
    """Float: the phase pdf of the direction ``d`` (MIS of an environment hit)."""
    active: Any


@dataclass
class Pick:
    """The point kept for the in-scattering gradient of one camera path (reservoir over its segments)."""

    w: Any
    """Float: the sum of the segments' weights."""
    y: Any
    d: Any
    depth: Any
    pref: Any
    """Spectrum: the kept point's factor ``beta W (T_c / mean T) / w_segment``."""


@dataclass
class Rng:
    """A PCG32 stream with a sampler's ``next_1d`` / ``next_2d`` (the adjoint pass's own random numbers)."""

    pcg: Any

    def next_1d(self, active=True):
        return self.pcg.next_float32(active)

    def next_2d(self, active=True):
        import mitsuba as mi

        return mi.Point2f(self.pcg.next_float32(active), self.pcg.next_float32(active))


class Settings:
    """What the tracer needs of the integrator (a plain object: Dr.Jit's loops leave it alone)."""

    def __init__(self, max_depth: int, rr_depth: int, drt: bool) -> None:
        self.max_depth, self.rr_depth, self.drt = max_depth, rr_depth, drt


@dr.syntax
def track(med: GridMedium, sampler, o, d, t0, t1, active):
    """Delta tracking of ``o + t d`` over ``[t0, t1]``: ``(scattered, t, weight)``, ``weight`` the product of the
    null and real collisions' spectral weights without the albedo (1 for a grey medium)."""
    import mitsuba as mi

    w = med.walk(o, d, t0, t1, exponential(sampler.next_1d(active)))
    weight = mi.Spectrum(1.0)
    scattered = mi.Bool(False)
    going = mi.Bool(active)
    while going:
        hit, sigma_bar, done = med.step(w, going)
        sigma = med.sigma_t(o + w.t * d, hit)
        mean = dr.mean(sigma)
        real = hit & (sampler.next_1d(hit) * sigma_bar < mean)
        null = hit & ~real
        if dr.hint(med.channels == 3, mode="scalar"):
            weight[real] *= sigma / mean
            weight[null] *= (sigma_bar - sigma) / (sigma_bar - mean)
        scattered |= real
        going &= ~(real | done)
        w.tau[null] = exponential(sampler.next_1d(null))
    return scattered, w.t, weight


@dr.syntax
def drt_walk(med: GridMedium, rng, o, d, t0, t1, t_star, active):
    """The ratio-tracking walk of a segment's gradients (its own random numbers): ``(p_a, w_a, p_b, w_b, r_b)``:
    the attenuation's point among those before ``t_star`` (weights ``1 / sigma_bar``, sum ``w_a``) and the
    in-scattering's point over the segment (weights :func:`drt_weight`, sum ``w_b``, ``r_b = T_c / mean T``
    there)."""
    import mitsuba as mi

    w = med.walk(o, d, t0, t1, exponential(rng.next_1d(active)))
    T = mi.Spectrum(1.0)
    w_a, w_b = mi.Float(0.0), mi.Float(0.0)
    p_a, p_b = mi.Point3f(0.0), mi.Point3f(0.0)
    r_b = mi.Spectrum(0.0)
    going = mi.Bool(active)
    while going:
        hit, sigma_bar, done = med.step(w, going)
        p = o + w.t * d
        before = hit & (w.t < t_star)
        w_a[before] += dr.rcp(sigma_bar)
        take_a = before & (rng.next_1d(before) * w_a < dr.rcp(sigma_bar))
        p_a[take_a] = p
        wi = drt_weight(T, sigma_bar)
        cand = hit & (wi > 0)
        w_b[cand] += wi
        take_b = cand & (rng.next_1d(cand) * w_b < wi)
        p_b[take_b] = p
        r_b[take_b] = T / dr.mean(T)
        T[hit] *= ratio_factor(med.sigma_t(p, hit), sigma_bar)
        past = hit & (w.t >= t_star)  # the attenuation's points are all behind: roulette may end the walk
        keep, scale = walk_roulette(T, rng.next_1d(past), past)
        T *= scale
        w.tau[hit] = exponential(rng.next_1d(hit))
        going &= ~done & keep
    return p_a, w_a, p_b, w_b, r_b


@dr.syntax
def shadow(med: GridMedium, sampler, rng, o, d, t1, active, adjoint: bool):
    """Ratio tracking from ``o`` along ``d`` to ``t1``: ``(T, Q, w, u)``, ``T = prod (1 - sigma_t / sigma_bar)``;
    in the adjoint, one point ``u`` kept with weights ``1 / sigma_bar`` (sum ``w``) and ``Q`` the product of the
    other points' factors."""
    import mitsuba as mi

    w = med.walk(o, d, mi.Float(0.0), t1, exponential(sampler.next_1d(active)))
    T, Q = mi.Spectrum(1.0), mi.Spectrum(0.0)
    w_s = mi.Float(0.0)
    u = mi.Point3f(0.0)
    going = mi.Bool(active)
    while going:
        hit, sigma_bar, done = med.step(w, going)
        p = o + w.t * d
        f = ratio_factor(med.sigma_t(p, hit), sigma_bar)
        if dr.hint(adjoint, mode="scalar"):
            w_s[hit] += dr.rcp(sigma_bar)
            take = hit & (rng.next_1d(hit) * w_s < dr.rcp(sigma_bar))
            Q = dr.select(take, T, dr.select(hit, Q * f, Q))
            u[take] = p
        T[hit] *= f
        keep, scale = walk_roulette(T, sampler.next_1d(hit), hit)
        T = dr.select(keep, T * scale, 0.0)
        Q = dr.select(keep, Q * scale, 0.0)
        w.tau[hit] = exponential(sampler.next_1d(hit))
        going &= ~done & keep
    return T, Q, w_s, u


def _backward(value) -> None:
    """Back-propagate ``value``'s adjoint to whichever grids are differentiated (none is not an error)."""
    dr.backward(value, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)


def _interaction(mi: Any, p, d):
    """A medium interaction at ``p`` reached along ``d`` (what the phase function and emitter sampling read)."""
    mei = dr.zeros(mi.MediumInteraction3f, dr.width(p))
    mei.p = mi.Point3f(p)
    mei.wi = -d
    mei.sh_frame = mi.Frame3f(mei.wi)
    mei.t = mi.Float(0.0)
    return mei


def _pass(s: PathState, contrib, mask, adjoint: bool) -> None:
    """Add a contribution to the primal's radiance, or take it from what the adjoint has still to pass."""
    s.L[mask] += -contrib if adjoint else contrib


def escape(scene, s: PathState, mask, adjoint: bool) -> None:
    """The environment seen by the rays ``mask`` leaving the box (MIS-weighted against emitter sampling after a
    scattering)."""
    import mitsuba as mi
    from mitsuba.ad.integrators.common import mis_weight

    env = scene.environment()
    if env is None:
        return
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(s.d))
    si.wi = -s.d
    si.t = mi.Float(dr.inf)
    ref = dr.zeros(mi.Interaction3f, dr.width(s.d))
    ref.p = s.o
    ds = mi.DirectionSample3f(scene, si, ref)
    pdf = scene.pdf_emitter_direction(ref, ds, mask & ~s.direct)
    weight = dr.select(s.direct, 1.0, mis_weight(s.last_pdf, pdf))
    _pass(s, s.beta * env.eval(si, mask) * weight, mask, adjoint)


def scatter(scene, med: GridMedium, sampler, rng, s: PathState, p, active, adjoint: bool, grad_L) -> None:
    """At the scattering points ``p`` (lanes ``active``, throughput already weighted): next-event estimation
    (and in the adjoint the shadow rays' gradient), then a phase-sampled direction (in place)."""
    import mitsuba as mi
    from mitsuba.ad.integrators.common import mis_weight

    mei = _interaction(mi, p, s.d)
    ctx = mi.PhaseFunctionContext(None)
    ds, emitted = scene.sample_emitter_direction(mei, sampler.next_2d(active), False, active)
    ok = active & (ds.pdf > 0)
    _, t_exit, _ = med.interval(p, ds.d)
    T, Q, w_s, u = shadow(med, sampler, rng, p, ds.d, dr.minimum(ds.dist, t_exit), ok, adjoint)
    value, pdf = med.phase.eval_pdf(ctx, mei, ds.d, ok)
    K = dr.select(ok, s.beta * value * emitted * dr.select(ds.delta, 1.0, mis_weight(ds.pdf, pdf)), 0.0)
    _pass(s, K * T, ok, adjoint)
    if adjoint:
        with dr.resume_grad():
            sigma = med.sigma_t(u, ok & (w_s > 0))
            _backward(-grad_L * dr.detach(dr.select(ok, K * w_s * Q, 0.0)) * sigma)
    wo, weight, pdf = med.phase.sample(ctx, mei, sampler.next_1d(active), sampler.next_2d(active), active)
    go = active & (pdf > 0)
    s.beta[go] *= weight
    s.o[go] = p
    s.d[go] = wo
    s.last_pdf[go] = pdf
    s.direct &= ~go
    s.active = go


def roulette(ig: Settings, sampler, s: PathState) -> None:
    """Russian roulette from ``rr_depth`` scatterings on: continue with probability ``min(max_c beta_c, 0.99)``."""
    rr = s.active & (s.depth > ig.rr_depth)
    q = dr.minimum(dr.max(s.beta), 0.99)
    survive = sampler.next_1d(rr) < q
    s.beta[rr & survive] *= dr.rcp(q)
    s.active &= ~rr | survive


def segment_gradients(ig: Settings, med: GridMedium, rng, s: PathState, t0, t1, scattered, t, on, grad_L,
                      pick: Pick) -> None:
    """The adjoint's work on one segment: the attenuation's gradient (3), and the segment offered to the
    in-scattering reservoir (2). ``s`` is at the segment's start."""
    t_star = dr.select(scattered, t, t1)
    p_a, w_a, p_b, w_b, r_b = drt_walk(med, rng, s.o, s.d, t0, t1, t_star, on)
    with dr.resume_grad():
        sigma = med.sigma_t(p_a, on & (w_a > 0))
        _backward(-grad_L * dr.detach(dr.select(on, s.L * w_a, 0.0)) * sigma)
    if not ig.drt:
        return
    offer = on & (w_b > 0) & (s.depth + 1 < ig.max_depth)
    w_seg = dr.select(offer, dr.mean(s.beta) * w_b, 0.0)
    pick.w += w_seg
    take = offer & (rng.next_1d(offer) * pick.w < w_seg)
    pick.y[take] = p_b
    pick.d[take] = s.d
    pick.depth[take] = s.depth
    pick.pref[take] = s.beta * w_b * r_b / w_seg


def _albedo_gradient(ig: Settings, med: GridMedium, s: PathState, p, vertex, grad_L) -> None:
    """Term (1) at real collisions ``p`` (and, without differential ratio tracking, term (2) there):
    ``(d w / w) x`` the radiance still to pass, ``w`` the albedo (times ``sigma_t``)."""
    with dr.resume_grad():
        w = med.albedo(p, vertex)
        if not ig.drt:
            w = w * med.sigma_t(p, vertex)
        _backward(grad_L * w * dr.detach(dr.select(vertex & (w > 0), s.L / w, 0.0)))


@dr.syntax
def trace(ig: Settings, scene, med: GridMedium, sampler, rng, s: PathState, grad_L, pick: Pick | None):
    """Follow the paths ``s`` to their end (in place): the primal (``pick`` None), or the adjoint, which
    back-propagates ``grad_L`` (the adjoint radiance) and fills ``pick``."""
    import mitsuba as mi

    adjoint = pick is not None
    while dr.hint(s.active, label="mitsnerf_drt path"):
        t0, t1, hit = med.interval(s.o, s.d)
        on = s.active & hit
        scattered, t, weight = track(med, sampler, s.o, s.d, t0, t1, on)
        if dr.hint(adjoint, mode="scalar"):
            segment_gradients(ig, med, rng, s, t0, t1, scattered, t, on, grad_L, cast(Pick, pick))
        s.beta[on] *= weight
        escape(scene, s, s.active & ~scattered, adjoint)
        vertex = on & scattered
        s.depth[vertex] += 1
        vertex &= s.depth < ig.max_depth
        p = s.o + t * s.d
        if dr.hint(adjoint, mode="scalar"):
            _albedo_gradient(ig, med, s, p, vertex, grad_L)
        s.beta[vertex] *= med.albedo(p, vertex)
        s.active = mi.Bool(vertex)
        scatter(scene, med, sampler, rng, s, p, vertex, adjoint, grad_L)
        roulette(ig, sampler, s)
    return s


def in_scatter_gradient(ig: Settings, scene, med: GridMedium, rng, pick: Pick, grad_L) -> None:
    """Term (2) at each camera path's kept point ``y``: ``L_s(y)`` by a path of its own from ``y`` (next-event
    estimation and a phase-sampled continuation), then ``W ... albedo(y) L_s(y) d sigma_t(y)``."""
    import mitsuba as mi

    kept = pick.w > 0
    sub = PathState(mi.Point3f(pick.y), mi.Vector3f(pick.d), mi.Spectrum(1.0), mi.Spectrum(0.0),
                    mi.UInt32(pick.depth + 1), mi.Bool(False), mi.Float(0.0), mi.Bool(kept))
    scatter(scene, med, rng, rng, sub, pick.y, kept, False, None)
    sub = trace(ig, scene, med, rng, rng, sub, None, None)
    factor = dr.select(kept, pick.w * pick.pref * med.albedo(pick.y, kept) * sub.L, 0.0)
    with dr.resume_grad():
        sigma = med.sigma_t(pick.y, kept)
        _backward(grad_L * dr.detach(factor) * sigma)


def sample_paths(ig: Settings, scene, med: GridMedium, sampler, ray, grad_L, state_in, active):
    """The integrator's ``sample``: ``(L, valid, L)`` of the camera rays ``ray`` (primal: ``grad_L`` None), or
    the adjoint pass, which back-propagates ``grad_L`` and needs the primal radiance ``state_in``."""
    import mitsuba as mi

    adjoint = grad_L is not None
    n = dr.width(ray.o)
    seed = sampler.next_1d(active)  # drawn by both passes, so that their paths stay the same
    rng = None
    if adjoint:
        rng = Rng(mi.PCG32(n, initstate=mi.UInt64(mi.UInt32(seed * 4294967295.0)),
                           initseq=dr.arange(mi.UInt64, n)))
    _, _, valid = med.interval(ray.o, ray.d)
    s = PathState(mi.Point3f(ray.o), mi.Vector3f(ray.d), mi.Spectrum(1.0),
                  mi.Spectrum(state_in) if adjoint else mi.Spectrum(0.0), mi.UInt32(0), mi.Bool(True),
                  mi.Float(0.0), mi.Bool(active))
    pick = Pick(mi.Float(0.0), mi.Point3f(0.0), mi.Vector3f(0.0), mi.UInt32(0), mi.Spectrum(0.0)) if adjoint else None
    s = trace(ig, scene, med, sampler, rng, s, grad_L, pick)
    if pick is not None and ig.drt:
        in_scatter_gradient(ig, scene, med, rng, pick, grad_L)
    return s.L, valid & active, s.L


def _make_class():
    import mitsuba as mi
    from mitsuba.ad.integrators.common import RBIntegrator

    class DifferentialRatioTrackingIntegrator(RBIntegrator):
        """The ``mitsnerf_drt`` integrator; see :mod:`mitsnerf.render.drt`."""

        def __init__(self, props):
            super().__init__(props)
            if not mi.is_rgb:
                raise ValueError(f"{NAME}: needs an RGB variant, got {mi.variant()}")
            self.majorant_cell = int(props.get("majorant_cell", 4))
            self.majorant_floor = float(props.get("majorant_floor", 0.0))
            self.drt = bool(props.get("drt", True))
            if self.majorant_cell < 1 or self.majorant_floor < 0:
                raise ValueError(f"{NAME}: majorant_cell must be >= 1 and majorant_floor >= 0, got "
                                 f"{self.majorant_cell} and {self.majorant_floor}")
            self.free: Any = None
            """Optional (R, R, R) bool grid of the voxels that may change (the majorant floor only reaches them)."""

        def settings(self) -> Settings:
            return Settings(int(self.max_depth), int(self.rr_depth), self.drt)

        def medium(self, scene) -> GridMedium:
            return GridMedium(mi, scene, self.majorant_cell, self.majorant_floor, self.free)

        def sample(self, mode, scene, sampler, ray, δL, state_in, active, **kwargs):  # noqa: N803 (Mitsuba's name)
            if mode == dr.ADMode.Forward:
                raise RuntimeError(f"{NAME}: forward-mode derivatives are not supported; use reverse mode "
                                   "(dr.backward of a loss of mi.render(scene, params))")
            adjoint = mode == dr.ADMode.Backward
            L, valid, state = sample_paths(self.settings(), scene, self.medium(scene), sampler, ray,
                                           δL if adjoint else None, state_in, active)
            return L, valid, [], state

        def to_string(self):
            return (f"DifferentialRatioTrackingIntegrator[max_depth={self.max_depth}, rr_depth={self.rr_depth}, "
                    f"majorant_cell={self.majorant_cell}, majorant_floor={self.majorant_floor}, drt={self.drt}]")

    return DifferentialRatioTrackingIntegrator


def register() -> type:
    """Register ``mitsnerf_drt`` for the current Mitsuba variant (idempotent); returns the class."""
    from mitsnerf.render.mitsuba_plugin import register_once

    return register_once(NAME, _make_class, _CLASSES)
