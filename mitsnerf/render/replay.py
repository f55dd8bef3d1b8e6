"""The emission-absorption quadrature with path replay backpropagation: training at the march's memory.

:func:`render_rays_replay` computes what :func:`mitsnerf.render.volume.render_rays` computes (the same
jittered samples, the same quadrature, the same :class:`~mitsnerf.math.composite.Composite`), but as one
``dr.while_loop`` per ray, as :func:`mitsnerf.render.march.march_rays`, and differentiates it without
keeping the sampler's, the field's or the compositing's R x N arrays: its gradient is a
``dr.CustomOp`` whose backward pass replays the march front to back with the adjoint radiance
(Mitsuba's ``prb`` integrators, "path replay backpropagation", for this quadrature), re-evaluating the
field at each sample with gradients on and propagating them to the field's parameters right there
(``dr.backward_from`` inside the loop). Memory per ray is constant; the price is a second field
evaluation per sample.

The quadrature (``i = 0 .. N-1``; :func:`mitsnerf.math.sampling.stratified_t`, the seed's rule)::

    t_i      = t_n + (i + u_i) h,  h = (t_f - t_n) / N
    delta_i  = t_{i+1} - t_i,  delta_{N-1} = t_f - t_{N-1}     (the midpoint rule: delta_i = h)
    alpha_i  = 1 - exp(-sigma_i delta_i),   T_i = exp(-sum_{j<i} sigma_j delta_j),   w_i = T_i alpha_i
    rgb      = sum_i w_i c_i + T_N b,   opacity = 1 - T_N,   depth = sum_i w_i t_i,   T_final = T_N

The adjoint. A loss ``L`` of the outputs gives per ray ``g_rgb = dL/d rgb`` (3), ``g_o = dL/d opacity``,
``g_z = dL/d depth``, ``g_T = dL/d T_final``. Write ``s_i = g_rgb . c_i + g_z t_i`` (the adjoint-weighted
colour of sample i) and ``B = g_rgb . b + g_T - g_o`` (of what lies behind the last sample); then the
outputs' part of ``L`` is, to first order, ``A = sum_i w_i s_i + T_N B``
(``= g_rgb . rgb + g_z depth + (g_T - g_o) T_N``), and since ``dw_i / dsigma_i = delta_i T_{i+1}``,
``dT_j / dsigma_i = -delta_i T_j`` for ``j > i``::

    dL/dc_i     = g_rgb w_i
    dL/dsigma_i = delta_i (T_{i+1} s_i - A_i^after),     A_i^after = sum_{j>i} w_j s_j + T_N B
                                                                    = A - sum_{j<=i} w_j s_j

The forward pass keeps, per ray, ``sum_i w_i c_i`` and ``sum_i w_i t_i`` in float64 and ``T_N``; the
replay carries ``T_i`` and the running ``sum_{j<=i} w_j s_j`` (float64, from the same float32 ``w_j`` and
colours), so ``A_i^after`` is a difference of float64 sums: in float32 a nearly opaque ray lost up to 4 of
its 7 digits there; in float64 the gradient is as close to a float64 finite difference as render_rays'
(tests/render/test_replay.py: both within 1e-6 of the largest entry). It hands
``(dL/dc_i, dL/dsigma_i)`` to the field's derivative. Gradients reach the field's parameters only (the
sample positions, rays, jitter and background are constants here, as they carry no gradient in training),
and only reverse mode is implemented. Rays that miss the box leave the loop at once (every ``delta`` of
theirs is 0: nothing to add, nothing to differentiate).

The field's derivative, two ways (``adjoint``):

- ``texture`` (:class:`~mitsnerf.fields.protocols.TextureField`: the ground truth's ``GridField`` and
  ``voxel``'s ``VoxelField``): the lookups are detached leaves, the field's pointwise head is differentiated
  with respect to them by AD inside the loop, and their adjoints are scattered into the grids' gradients with
  the lookup's trilinear weights (:class:`Trilinear`), every channel of a corner as one packet. The
  gradients go back through the custom operation's inputs, the textures' tensors.
- ``generic``: any field whose evaluation a symbolic loop can record and differentiate (Dr.Jit array
  operations: textures, the hash grid of ``drjit.nn`` with cooperative-vector MLPs; not tensors of the
  batch's width, as the ngp field's default MLP path). It is evaluated with gradients on and
  ``dr.backward_from`` runs in the loop, so the gradients reach whatever it reads; those arrays must be
  passed as ``params``, the operation's inputs, through which the AD graph reaches it at all.

With an occupancy grid (:mod:`mitsnerf.fields.occupancy`) the samples it skips get ``sigma = 0`` and
colour 0, as in :func:`mitsnerf.render.skipping.render_rays_skipping`, by the same rule evaluated per
sample in the loop (:meth:`mitsnerf.fields.occupancy.OccupancyGrid.march_keep`). The field is evaluated
(and differentiated) under a symbolic ``if`` on that mask, so a SIMD packet of rays none of whose current
samples is kept skips it, and a ray leaves the loop at the grid's early stop.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import drjit as dr

from mitsnerf.fields.occupancy import OccupancyGrid
from mitsnerf.fields.protocols import TextureField
from mitsnerf.math.box import Box
from mitsnerf.math.composite import Composite, one_minus_exp_neg
from mitsnerf.math.sampling import QUADRATURES
from mitsnerf.render.volume import background_radiance


def sample_interval(i, n: int, t_n, t_f, u, u_next, quadrature: str):
    """Sample ``i``'s distance and interval ``(t_i, delta_i)`` (:func:`mitsnerf.math.sampling.stratified_t`
    written for one sample of every ray: the same operations, so the same floats)."""
    Float = type(t_n)
    span = t_f - t_n
    fi = Float(i)
    t = t_n + (fi + u) / n * span
    if quadrature == "midpoint":
        return t, span / n
    t_next = dr.select(i + 1 == n, t_f, t_n + (fi + 1 + u_next) / n * span)
    return t, t_next - t


def transmittance(tau, sigma, delta):
    """``(T_i, alpha_i)`` of a sample from the optical depth ``tau`` in front of it."""
    return dr.exp(-tau), one_minus_exp_neg(sigma * delta)


def sigma_adjoint(delta, T_next, s, after):
    """``dL/dsigma_i = delta_i (T_{i+1} s_i - A_i^after)`` (module docstring)."""
    return delta * (T_next * s - after)


class _Rays:
    """What both loops share: the rays, their intervals, the jitter, the occupancy rule."""

    def __init__(self, o, d, n: int, box: Box, u, grid: OccupancyGrid | None, quadrature: str) -> None:
        Float = type(o.x)
        self.o, self.d, self.n, self.grid, self.quadrature = o, d, n, grid, quadrature
        self.Float, self.UInt32 = Float, dr.uint32_array_t(Float)
        self.Float64, self.Array3f64 = dr.float64_array_t(Float), dr.float64_array_t(type(o))
        self.width = dr.width(o)
        self.t_n, self.t_f, self.hit = box.intersect(o, d)
        self.u = u
        self.base = dr.arange(self.UInt32, self.width) * n

    def jitter(self, i):
        """``(u_i, u_{i+1})`` of every ray (0.5 without jitter)."""
        if self.u is None:
            return 0.5, 0.5
        u_i = dr.gather(self.Float, self.u, self.base + i)
        u_next = dr.gather(self.Float, self.u, self.base + i + 1, i + 1 < self.n)
        return u_i, u_next

    def sample(self, i, tau_est):
        """Sample ``i``: ``(t, delta, x, keep, tau_est')`` (keep: the occupancy grid evaluates it; None: all)."""
        u_i, u_next = self.jitter(i)
        t, delta = sample_interval(i, self.n, self.t_n, self.t_f, u_i, u_next, self.quadrature)
        x = self.o + t * self.d
        if self.grid is None:
            return t, delta, x, None, tau_est
        keep, tau_est = self.grid.march_keep(x, delta, tau_est)
        return t, delta, x, keep, tau_est

    def loop(self, state, body, label: str):
        """``dr.while_loop`` over the samples ``i = 0 .. N-1`` of each ray, ``body(i, tau_est, *state)``, while
        one may still reach the field: not on rays that miss the box (every ``delta`` of theirs is 0: nothing to
        add, nothing to differentiate), nor behind the grid's early stop (:meth:`OccupancyGrid.stop_depth
        <mitsnerf.fields.occupancy.OccupancyGrid.stop_depth>`: the estimate ``tau_est`` only grows)."""
        n = dr.opaque(self.UInt32, self.n)
        hit = self.hit
        stop = None if self.grid is None else self.grid.stop_depth()

        def cond(i, tau_est, *_):
            go = (i < n) & hit
            return go if stop is None else go & (tau_est < stop)

        zero = dr.zeros(self.Float, self.width)
        return dr.while_loop((self.UInt32(0), zero, *state), cond, body, label=label)[2:]

    def where_kept(self, keep, add, state):
        """``add(*state)`` on the samples the grid keeps (a symbolic ``if``: a SIMD packet of samples it skips
        all of runs none of it), ``state`` unchanged elsewhere (a skipped sample is empty: it adds nothing)."""
        if keep is None:
            return add(*state)
        return dr.if_stmt(tuple(state), keep, add, lambda *s: s, label="replay_kept")


class _GenericAdjoint:
    """A field's own derivative: evaluated with gradients on in the loop and ``dr.backward_from`` there, so the
    gradients reach whatever the field reads (the arrays passed as the operation's ``params``)."""

    def __init__(self, field) -> None:
        self.field = field

    def evaluate(self, x, d):
        """``(c, sigma)`` (the forward march: gradients are suspended)."""
        return self.field(x, d)

    def attached(self, x, d):
        """``(c, sigma, state)``, differentiable with respect to the field's parameters."""
        return (*self.field(x, d), None)

    def scatter(self, state) -> None:
        """Nothing: ``dr.backward_from`` reached the parameters."""

    def gradients(self):
        return None


class _TextureAdjoint:
    """A :class:`~mitsnerf.fields.protocols.TextureField`'s derivative, by hand: the head is differentiated at
    each sample with respect to the texture lookups (loop-local AD), and their adjoints are scattered into one
    gradient array per grid with the lookup's weights (:class:`Trilinear`, one set of corners for the grids
    of one resolution). The same values as the textures' own derivative, which scatters channel by channel:
    2-2.5x slower for the 12-channel SH grid of ``voxel`` (64^3, random rays, this CPU). The lookups stay the
    textures' (gathering the channels by hand measured 2.5x slower than ``Texture3f.eval`` at 12 channels)."""

    def __init__(self, field) -> None:
        self.field = field
        self.textures = tuple(field.textures())
        self.tensors = [tex.tensor() for tex in self.textures]
        Float = dr.leaf_t(type(self.tensors[0]))
        self.grads = [dr.zeros(Float, dr.width(t.array)) if dr.grad_enabled(t) else None for t in self.tensors]

    def lookups(self, x):
        p = self.field.box.to_unit(x)
        return p, [tex.eval(p) for tex in self.textures]

    def evaluate(self, x, d):
        return self.field.head(self.lookups(x)[1], x, d)

    def attached(self, x, d):
        p, values = self.lookups(x)
        leaves = []
        for v, grad in zip(values, self.grads):
            v = [dr.detach(c) for c in v]
            if grad is not None:
                dr.enable_grad(v)
            leaves.append(v)
        c, sigma = self.field.head(leaves, x, d)
        return c, sigma, (p, leaves)

    def scatter(self, state) -> None:
        p, leaves = state
        corners: dict = {}
        for grad, t, v in zip(self.grads, self.tensors, leaves):
            if grad is not None:
                res = (t.shape[2], t.shape[1], t.shape[0])
                corners.setdefault(res, Trilinear(p, res)).scatter(grad, [dr.grad(c) for c in v])

    def gradients(self):
        return [None if g is None else type(t)(g, shape=t.shape) for g, t in zip(self.grads, self.tensors)]


class Trilinear:
    """The 8 corners and weights of a trilinear lookup at unit positions ``p`` in a grid of resolution ``res``
    (x, y, z), as a ``dr.Texture3f`` with ``use_accel=False``, linear filtering and clamped borders does it
    (Dr.Jit's ``tex_eval``: ``p * res - 1/2``, weights multiplied in the order x, y, z, corners summed in
    order with ``fma``); :meth:`lookup` reads a flat (Z, Y, X, C) array there, :meth:`scatter` is its adjoint.

    >>> import drjit as dr, mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> g = dr.zeros(mi.Float, 2 * 2 * 2)  # a 2^3 grid, 1 channel
    >>> at = Trilinear(mi.Point3f(0.5, 0.5, 0.5), (2, 2, 2))
    >>> at.scatter(g, [mi.Float(8.0)]); g  # the centre: 1/8 to each voxel
    [1, 1, 1, 1, 1, 1, 1, 1]
    >>> at.lookup(g, 1)
    [[1]]
    """

    def __init__(self, p, res) -> None:
        Float = type(p.x)
        Int32, UInt32 = dr.int32_array_t(Float), dr.uint32_array_t(Float)
        pos_f = [dr.fma(p[k], res[k], -0.5) for k in range(3)]
        pos_i = [Int32(dr.floor(f)) for f in pos_f]
        w1 = [f - Float(i) for f, i in zip(pos_f, pos_i)]
        w = [(1.0 - a, a) for a in w1]
        self.voxels, self.weights = [], []
        for corner in range(8):
            bits = [(corner >> k) & 1 for k in range(3)]
            coord = [dr.clip(pos_i[k] + bits[k], 0, res[k] - 1) for k in range(3)]
            self.weights.append(w[0][bits[0]] * w[1][bits[1]] * w[2][bits[2]])
            self.voxels.append(UInt32((coord[2] * res[1] + coord[1]) * res[0] + coord[0]))
        self.Float, self.width = Float, dr.width(p)
        self.ArrayXf = sys.modules[Float.__module__].ArrayXf
        self.mode = dr.ReduceMode.Expand if dr.backend_v(Float) == dr.JitBackend.LLVM else dr.ReduceMode.Auto

    def lookup(self, array, channels: int) -> list:
        """The C = ``channels`` interpolated values (a list of Floats) of the flat (Z, Y, X, C) ``array``."""
        out = [self.Float(0.0)] * channels
        for voxel, weight in zip(self.voxels, self.weights):
            if channels == 1:
                v = [dr.gather(self.Float, array, voxel)]
            else:
                v = dr.gather(self.ArrayXf, array, voxel, shape=(channels, self.width))
            out = [dr.fma(v[ch], weight, out[ch]) for ch in range(channels)]
        return out

    def scatter(self, target, values) -> None:
        """Add ``values`` (one Float per channel) into the flat (Z, Y, X, C) ``target`` with the lookup's
        weights: the C channels of a corner as one packet; on the LLVM backend each thread adds into a copy of
        its own (``ReduceMode.Expand``), no atomics."""
        for voxel, weight in zip(self.voxels, self.weights):
            if len(values) == 1:
                dr.scatter_reduce(dr.ReduceOp.Add, target, values[0] * weight, voxel, mode=self.mode)
            else:
                packet = self.ArrayXf(*(v * weight for v in values))
                dr.scatter_reduce(dr.ReduceOp.Add, target, packet, voxel, mode=self.mode)


def _forward(rays: _Rays, adjoint, bg):
    """The march: per ray ``(rgb, opacity, depth, T_final, kept)`` (kept: samples that reached the field), and
    the samples' colour and depth sums in float64 (what the replay subtracts its running sums from)."""
    Float, Float64, Array3f64 = rays.Float, rays.Float64, rays.Array3f64
    zeros = dr.zeros(Float, rays.width)

    def body(i, tau_est, tau, rgb, depth, kept):
        t, delta, x, keep, tau_est = rays.sample(i, tau_est)

        def add(tau, rgb, depth, kept):
            c, sigma = adjoint.evaluate(x, rays.d)
            T, alpha = transmittance(tau, sigma, delta)
            w = Float64(T * alpha)
            return tau + sigma * delta, rgb + w * Array3f64(c), depth + w * Float64(t), kept + 1

        return i + 1, tau_est, *rays.where_kept(keep, add, (tau, rgb, depth, kept))

    state = (zeros, dr.zeros(Array3f64, rays.width), dr.zeros(Float64, rays.width), dr.zeros(rays.UInt32, rays.width))
    tau, rgb64, depth64, kept = rays.loop(state, body, "replay_forward")
    T_final = dr.exp(-tau)
    rgb = type(rays.o)(rgb64) + T_final * bg
    return (rgb, one_minus_exp_neg(tau), Float(depth64), T_final, kept), (rgb64, depth64)


def _replay(rays: _Rays, adjoint, front, behind, g_rgb, g_depth) -> None:
    """The backward march: at each sample, ``(dL/dc_i, dL/dsigma_i)`` into the field's derivative.

    ``front``: ``sum_i w_i s_i`` (float64, from the forward sums), ``behind``: ``T_N B``. The running sum
    ``sum_{j<=i} w_j s_j`` is kept in float64 from the same float32 ``w_j`` and colours, so ``front`` minus it
    is the samples-behind sum without cancellation (in float32 a ray that is nearly opaque lost up to 4 of
    its 7 digits there)."""
    Float, Float64, Array3f64 = rays.Float, rays.Float64, rays.Array3f64
    g_rgb64, g_depth64 = Array3f64(g_rgb), Float64(g_depth)

    def body(i, tau_est, tau, acc):
        t, delta, x, keep, tau_est = rays.sample(i, tau_est)

        def add(tau, acc):
            with dr.resume_grad():
                c, sigma, state = adjoint.attached(x, rays.d)
                c_d, sigma_d = dr.detach(c), dr.detach(sigma)
                T, alpha = transmittance(tau, sigma_d, delta)
                w = T * alpha
                acc = acc + Float64(w) * (dr.dot(g_rgb64, Array3f64(c_d)) + g_depth64 * Float64(t))
                tau_next = tau + sigma_d * delta
                s = dr.dot(g_rgb, c_d) + g_depth * t
                g_sigma = sigma_adjoint(delta, dr.exp(-tau_next), s, Float(front - acc) + behind)
                dr.backward_from(g_sigma * sigma + dr.dot(g_rgb * w, c))
                adjoint.scatter(state)
            return tau_next, acc

        return i + 1, tau_est, *rays.where_kept(keep, add, (tau, acc))

    rays.loop((dr.zeros(Float, rays.width), dr.zeros(Float64, rays.width)), body, "replay_backward")


class _ReplayOp(dr.CustomOp):
    """The forward march, and its derivative by replay (module docstring)."""

    def eval(self, params, rays: _Rays, adjoint, bg):
        self.rays, self.adjoint, self.bg = rays, adjoint, bg
        with dr.suspend_grad():
            out, self.sums = _forward(rays, adjoint, bg)
            # one kernel for all, whichever is evaluated first (the backward pass reads the sums and T_N)
            dr.schedule(out, self.sums)
        self.T_final = out[3]
        return out

    def forward(self):
        raise NotImplementedError("render_rays_replay: forward-mode derivatives are not implemented")

    def backward(self):
        g_rgb, g_opacity, g_depth, g_T, _ = self.grad_out()
        rays = self.rays
        Float, Array3f = rays.Float, type(rays.o)
        g_rgb = Array3f(g_rgb) + dr.zeros(Array3f, rays.width)
        g_depth = Float(g_depth) + dr.zeros(Float, rays.width)
        rgb64, depth64 = self.sums
        front = dr.dot(rays.Array3f64(g_rgb), rgb64) + rays.Float64(g_depth) * depth64
        behind = self.T_final * (dr.dot(g_rgb, Array3f(self.bg)) + g_T - g_opacity)
        dr.make_opaque(front, behind, g_rgb, g_depth)
        with dr.suspend_grad():
            _replay(rays, self.adjoint, front, behind, g_rgb, g_depth)
        grads = self.adjoint.gradients()
        if grads is not None:
            self.set_grad_in("params", grads)

    def name(self):
        return "render_rays_replay"


ADJOINTS = ("auto", "texture", "generic")
"""How :func:`render_rays_replay` differentiates the field at a sample: ``texture`` (a
:class:`~mitsnerf.fields.protocols.TextureField`: the head by AD, the lookups by hand), ``generic`` (the
field's own AD), ``auto`` (``texture`` where the field is one)."""


def render_rays_replay(
    field: Callable[[Any, Any], tuple[Any, Any]],
    o,
    d,
    n_samples: int,
    *,
    box: Box,
    params: Any = None,
    u=None,
    background=None,
    grid: OccupancyGrid | None = None,
    quadrature: str = "seed",
    adjoint: str = "auto",
    stats: dict | None = None,
) -> Composite:
    """:func:`mitsnerf.render.volume.render_rays` (or, with ``grid``, the skipping renderer) as a march
    whose gradient is replayed (module docstring); the same :class:`~mitsnerf.math.composite.Composite`.

    Args:
        field: callable ``(x, d) -> (rgb, sigma)`` that a symbolic loop can call.
        o, d: Array3f (R,), ray origins and unit directions.
        n_samples: N, samples per ray.
        box: the scene box.
        params: the generic path's inputs: the differentiable arrays ``field`` reads (a mapping, sequence or
            array; e.g. a model's parameters); None: no gradient. The texture path takes the textures' tensors.
        u: Float (R*N,) jitter in [0, 1) (ray-major, as render_rays'), or None for stratum midpoints.
        background: callable ``d -> Array3f``, a constant, or None (black); no gradient.
        grid: an occupancy grid whose skipped samples count as empty, or None.
        quadrature: ``"seed"`` or ``"midpoint"``.
        adjoint: ``"auto"``, ``"texture"`` or ``"generic"`` (:data:`ADJOINTS`).
        stats: a dict that receives ``"kept"``: UInt32 (R,), the samples of each ray that reached the field
            (the grid's mask of render_rays_skipping, counted; N per ray that hits the box without a grid).

    Example: the slab of render_rays' docstring, and its gradient with respect to sigma::

        >>> import drjit as dr, mitsuba as mi
        >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
        >>> from mitsnerf.math.box import UNIT_BOX
        >>> s = mi.Float(2.0); dr.enable_grad(s)
        >>> slab = lambda x, d: (mi.Array3f(1.0) + 0 * x.x, s + 0 * x.x)
        >>> out = render_rays_replay(slab, mi.Array3f(0, 0, -2), mi.Array3f(0, 0, 1), 8, box=UNIT_BOX,
        ...                          params=s, u=dr.zeros(mi.Float, 8))
        >>> out.opacity  # 1 - exp(-2)
        [0.864665]
        >>> dr.backward(out.opacity); dr.grad(s)  # d(1 - exp(-s))/ds = exp(-2)
        [0.135335]
    """
    if n_samples < 1:
        raise ValueError(f"render_rays_replay: n_samples must be >= 1, got {n_samples}")
    if quadrature not in QUADRATURES:
        raise ValueError(f"render_rays_replay: quadrature must be one of {', '.join(QUADRATURES)}, got {quadrature!r}")
    if adjoint not in ADJOINTS:
        raise ValueError(f"render_rays_replay: adjoint must be one of {', '.join(ADJOINTS)}, got {adjoint!r}")
    if u is not None and dr.width(u) != dr.width(o) * n_samples:
        raise ValueError(f"render_rays_replay: u has {dr.width(u)} entries, expected R*N = {dr.width(o) * n_samples}")
    if getattr(field, "sigma_channels", 1) != 1:
        raise ValueError("render_rays_replay: the replayed march carries one extinction per ray; a field with one "
                         "per colour channel renders through render_rays")
    textured = adjoint == "texture" or (adjoint == "auto" and isinstance(field, TextureField))
    with dr.suspend_grad():
        rays = _Rays(dr.detach(o), dr.detach(d), n_samples, box, None if u is None else dr.detach(u), grid, quadrature)
        bg = background_radiance(background, rays.d)
        if callable(background):
            bg = dr.detach(bg)
    if textured:
        how: Any = _TextureAdjoint(field)
        inputs = how.tensors
    else:
        how = _GenericAdjoint(field)
        inputs = params if params is not None else {}
    rgb, opacity, depth, T_final, kept = dr.custom(_ReplayOp, inputs, rays, how, bg)
    if stats is not None:
        stats["kept"] = kept
    return Composite(rgb=rgb, opacity=opacity, depth=depth, T_final=T_final)
