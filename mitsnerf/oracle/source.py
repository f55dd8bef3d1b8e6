"""The in-scattered radiance ``J`` that makes emission-absorption equal to volpath, estimated with Mitsuba.

For an isotropic phase function ``p = 1 / (4 pi)`` the radiance volpath renders along a ray is
exactly the emission-absorption integral with ``sigma = sigma_t``::

    L(o, d) = int_{t_n}^{t_f} T(t) sigma_t(x_t) J(x_t) dt + T(t_f) L_bg(d),
    J(x)    = albedo(x) (1 / 4 pi) int_{S^2} L_in(x, w) dw = albedo(x) Lbar(x),

multiple scattering and the sun's transmitted light included. ``Lbar`` (the mean radiance over
the sphere) splits in two:

- ``Lbar_mc(x) = E_w[L_volpath(x, w)]``, ``w`` uniform on the sphere (pdf ``1 / 4 pi``): volpath
  started at ``x`` *inside* the medium (``integrator.sample(..., medium=box medium)``) returns
  everything that arrives from direction ``w``, environment and multiple scattering included, but
  never the unscattered light of a delta light (a sampled direction never meets a sun or a point);
  its first segment is attenuated by the medium, and an environment met directly at depth 0 counts
  with weight 1, as for a camera ray. Estimated from ``spp`` independent samples per point, with
  the standard error ``se = s / sqrt(spp)`` (``s``: the samples' standard deviation).
- ``Lbar_delta(x) = (1 / 4 pi) sum_l E_l(x) T_l(x)``: a directional light of irradiance ``E``
  (``T`` marched along ``-direction`` to the box exit), a point light of intensity ``I`` at ``q``
  (``E = I / |q - x|^2``, ``T`` marched to ``q``), the single-scatter source :mod:`mitsnerf.verify`
  computes with shadow rays; deterministic (midpoint rule, :func:`mitsnerf.math.box.march_transmittance`).

A scene rendered with ``max_depth = D`` (camera segment plus ``D - 1`` scatterings) needs the
in-scattered radiance of paths of depth ``D - 1`` from the scattering point:
:func:`inner_max_depth`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mitsnerf.math.box import Box, march_transmittance
from mitsnerf.math.rays import to_array3f
from mitsnerf.scene.lights import delta_lights, light_terms

FOUR_PI = 4.0 * math.pi
SAMPLES_PER_PASS = 1 << 20
"""Volpath samples launched at once (points x directions); a pass of points is seeded by its index."""


def inner_max_depth(max_depth: int) -> int | None:
    """The volpath depth of paths from a scattering point for a scene rendered at ``max_depth``.

    ``-1`` (unlimited) stays ``-1``; ``D >= 2`` gives ``D - 1``; ``D = 1`` (emitters seen directly,
    no scattering) gives None: nothing in-scatters, ``J = 0``.

    >>> inner_max_depth(-1), inner_max_depth(2), inner_max_depth(1)
    (-1, 1, None)
    """
    if max_depth == -1:
        return -1
    return None if max_depth <= 1 else max_depth - 1


def box_medium(scene):
    """The interior medium of the scene's one shape that has one (the medium box)."""
    media = [s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None]
    if len(media) != 1:
        raise ValueError(f"expected exactly one shape with an interior medium, found {len(media)}")
    return media[0]


def _pass_samples(scene, medium, o: np.ndarray, spp: int, seed: int,
                  warp: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(P, spp, 3)`` float64 volpath radiance of ``spp`` directions from each point of ``o`` (P, 3), and
    those directions ``w`` (P, spp, 3) (where the radiance arrives from): uniform on the sphere, or
    ``warp(u)`` of the sampler's numbers ``u`` (P, spp, 2)."""
    import drjit as dr
    import mitsuba as mi

    n = len(o) * spp
    sampler = mi.load_dict({"type": "independent", "sample_count": 1})
    sampler.seed(seed, n)
    idx = np.repeat(np.arange(len(o)), spp)
    with dr.suspend_grad():
        u = sampler.next_2d()
        if warp is None:
            w = mi.warp.square_to_uniform_sphere(u)
        else:
            host_u = np.stack([np.asarray(c, np.float64) for c in u], -1).reshape(len(o), spp, 2)
            w = to_array3f(mi.Vector3f, warp(host_u).reshape(n, 3))
        ray = mi.RayDifferential3f(mi.Ray3f(to_array3f(mi.Point3f, o[idx]), w))
        L, _, _ = scene.integrator().sample(scene, sampler, ray, medium=medium, active=True)

    def host(v) -> np.ndarray:
        return np.stack([np.asarray(c, dtype=np.float64) for c in v], axis=-1).reshape(len(o), spp, 3)

    return host(L), host(w)


def mean_radiance(scene, points: np.ndarray, spp: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``Lbar_mc`` at ``points`` (M, 3) inside the medium box: mean and standard error, float64 (M, 3).

    ``mean = (1/spp) sum_k L_volpath(x, w_k)``, ``se = sqrt(sum_k (L_k - mean)^2 / (spp - 1) / spp)``
    with ``w_k`` uniform on the sphere; points in passes of :data:`SAMPLES_PER_PASS` samples,
    pass ``i`` seeded ``seed * 1000003 + i``.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> from mitsnerf.scene.to_mitsuba import medium_box
    >>> furnace = mi.load_dict({"type": "scene", "integrator": {"type": "volpath"},
    ...     "box": medium_box(np.full((2, 2, 2), 3.0, np.float32), 1.0, UNIT_BOX),
    ...     "env": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}})
    >>> mean, se = mean_radiance(furnace, np.zeros((1, 3)), 4096)   # albedo 1 in radiance 1: exactly 1
    >>> bool(abs(mean[0, 0] - 1.0) < 5 * se[0, 0] + 1e-6)
    True
    """
    if spp < 2:
        raise ValueError(f"mean_radiance: need spp >= 2 for a standard error, got {spp}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    medium = box_medium(scene)
    mean, se = np.zeros((len(points), 3)), np.zeros((len(points), 3))
    per = max(1, SAMPLES_PER_PASS // spp)
    for i, start in enumerate(range(0, len(points), per)):
        values, _ = _pass_samples(scene, medium, points[start:start + per], spp, seed * 1000003 + i)
        mean[start:start + per] = values.mean(axis=1)
        se[start:start + per] = values.std(axis=1, ddof=1) / math.sqrt(spp)
    return mean, se


@dataclass(frozen=True)
class RadianceSH:
    """:func:`radiance_sh`'s estimate at M points: float64 arrays."""

    mean: np.ndarray
    """``(M, K, 3)`` coefficients ``L_lm``, ``K = (order + 1)^2``."""
    se: np.ndarray
    """``(M, K, 3)`` each coefficient's standard error."""
    errors: np.ndarray
    """``(replicas, M, K, 3)`` error patterns with the estimate's own covariance between coefficients:
    ``sqrt(1 / (spp (spp - 1))) sum_k e_k (X_k - mean)`` with random signs ``e_k``, ``X_k`` sample ``k``'s
    coefficients; ``E[e e^T] = Cov(mean)``, so a linear function of the coefficients rendered from a pattern
    has, squared, the function's Monte Carlo variance in expectation."""


def radiance_sh(scene, points: np.ndarray, spp: int, order: int, seed: int = 0, replicas: int = 1) -> RadianceSH:
    """The spherical-harmonic coefficients of the radiance volpath brings to ``points`` (M, 3), ``L_lm(x) =
    int L(x, w) Y_lm(w) dw``, estimated from the same uniform directions as :func:`mean_radiance`:
    ``4 pi / spp sum_k L_k Y_lm(w_k)``, with standard errors and ``replicas`` error patterns (:class:`RadianceSH`).
    Coefficient 0 is ``sqrt(4 pi) Lbar_mc``, with the same samples (the same seeds) as :func:`mean_radiance`.
    """
    if spp < 2:
        raise ValueError(f"radiance_sh: need spp >= 2 for a standard error, got {spp}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    medium = box_medium(scene)
    k = (order + 1) ** 2
    mean, se = np.zeros((len(points), k, 3)), np.zeros((len(points), k, 3))
    errors = np.zeros((replicas, len(points), k, 3))
    rng = np.random.default_rng(seed)
    per = max(1, SAMPLES_PER_PASS // spp)
    step = max(1, (1 << 22) // (spp * k))  # points per slice of the (P, spp, K, 3) products
    for i, start in enumerate(range(0, len(points), per)):
        values, w = _pass_samples(scene, medium, points[start:start + per], spp, seed * 1000003 + i)
        for lo in range(0, len(values), step):
            terms = FOUR_PI * sh_basis(w[lo:lo + step], order)[:, :, :, None] * values[lo:lo + step, :, None, :]
            rows = slice(start + lo, start + lo + len(terms))
            mean[rows], se[rows] = terms.mean(axis=1), terms.std(axis=1, ddof=1) / math.sqrt(spp)
            signs = rng.choice(np.array([-1.0, 1.0]), size=(replicas, len(terms), spp))
            deviation = terms - mean[rows][:, None]
            errors[:, rows] = np.einsum("rps,pskc->rpkc", signs, deviation) / math.sqrt(spp * (spp - 1))
    return RadianceSH(mean, se, errors)


def sh_basis(w: np.ndarray, order: int) -> np.ndarray:
    """Orthonormal real spherical harmonics (Dr.Jit's ``sh_eval``) of unit directions ``w`` (..., 3):
    float64 (..., (order + 1)^2), coefficient ``l (l + 1) + m``.

    >>> sh_basis(np.array([[0.0, 0.0, 1.0]]), 1).round(4).tolist()    # Y_00 = 1 / sqrt(4 pi); Y_10 = sqrt(3 / 4 pi) z
    [[0.2821, -0.0, 0.4886, -0.0]]
    """
    import drjit as dr
    import mitsuba as mi

    flat = np.asarray(w, dtype=np.float64).reshape(-1, 3)
    basis = dr.sh_eval(to_array3f(mi.Array3f, flat), order)
    out = np.stack([np.broadcast_to(np.asarray(y, dtype=np.float64), (len(flat),)) for y in basis], axis=-1)
    return out.reshape(np.shape(w)[:-1] + (len(basis),))


def phase_weighted_radiance(scene, points: np.ndarray, d: np.ndarray, spp: int, g: float,
                            seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``int p(w . d) L(x, w) dw`` at each point ``x`` for its own direction ``d`` ((M, 3) each), the
    radiance volpath brings scattered towards ``-d`` by Henyey-Greenstein's phase function: the mean of
    ``spp`` volpath samples from directions drawn from ``p(w . d)`` (:func:`mitsnerf.math.phase.sample_hg`,
    weight 1: no heavy tail for a peaked lobe); mean and standard error, float64 (M, 3)."""
    from mitsnerf.math.phase import sample_hg

    if spp < 2:
        raise ValueError(f"phase_weighted_radiance: need spp >= 2 for a standard error, got {spp}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
    medium = box_medium(scene)
    mean, se = np.zeros((len(points), 3)), np.zeros((len(points), 3))
    per = max(1, SAMPLES_PER_PASS // spp)
    for i, start in enumerate(range(0, len(points), per)):
        lobe = d[start:start + per, None, :]

        def around_lobe(u: np.ndarray, lobe: np.ndarray = lobe) -> np.ndarray:
            return sample_hg(np.broadcast_to(lobe, u.shape[:2] + (3,)), u, g)

        values, _ = _pass_samples(scene, medium, points[start:start + per], spp, seed * 1000003 + i, around_lobe)
        mean[start:start + per] = values.mean(axis=1)
        se[start:start + per] = values.std(axis=1, ddof=1) / math.sqrt(spp)
    return mean, se


def delta_irradiance(lights: Sequence[Any], density, points: np.ndarray, box: Box, m: int,
                     chunk: int = 1 << 16) -> np.ndarray:
    """``E_l T_l`` at ``points`` (M, 3) for each delta light ``l`` of :func:`delta_lights`: float64 (M, n, 3),
    the light's irradiance there after the medium between (``density``: ``x -> sigma_t``, ``m`` midpoints; a
    chromatic ``density`` (Array3f) attenuates each colour channel by its own ``T``)."""
    import drjit as dr
    import mitsuba as mi

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    found = delta_lights(lights)
    out = np.zeros((len(points), len(found), 3))
    with dr.suspend_grad():
        for start in range(0, len(points), chunk):
            x = to_array3f(mi.Array3f, points[start:start + chunk])
            for j, (w, irradiance, s_max) in enumerate(light_terms(found, x)):
                e = irradiance * march_transmittance(density, x, w, m, box, s_max)
                out[start:start + chunk, j] = np.stack([np.asarray(c, dtype=np.float64) for c in e], axis=-1)
    return out


def delta_radiance(lights: Sequence[Any], density, points: np.ndarray, box: Box, m: int,
                   chunk: int = 1 << 16) -> np.ndarray:
    """``Lbar_delta = (1 / 4 pi) sum_l E_l T_l`` at ``points`` (M, 3): float64 (M, 3) (module docstring).

    ``lights``: the scene spec's lights (directional and point lights count, environments not);
    ``density``: ``x -> sigma_t``; ``m`` midpoints per march to a light.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> from mitsnerf.scene.spec import DirectionalLight
    >>> sun = DirectionalLight(direction=(0.0, 0.0, -1.0), irradiance=(4 * math.pi, 0.0, 0.0))
    >>> delta_radiance([sun], lambda x: 2.0 + 0.0 * x.x, np.zeros((1, 3)), UNIT_BOX, 8).round(6)  # e^-1
    array([[0.367879, 0.      , 0.      ]])
    """
    return delta_irradiance(lights, density, points, box, m, chunk).sum(axis=1) / FOUR_PI


def needed_voxels(sigma_t: np.ndarray, resolution: int) -> np.ndarray:
    """Bool ``(R, R, R)``: the voxels of an ``R^3`` grid over the box that a trilinear lookup can
    use at a point where the trilinear ``sigma_t`` (its own ``R_s^3`` grid) is not zero.

    ``sigma_t(x) > 0`` only closer than one voxel ``h_s`` (per axis) to a non-zero voxel centre
    (a trilinear weight ``1 - |x - c| / h_s``), and a lookup at ``x`` reads centres closer than
    ``h``, so voxel ``v`` is needed when a non-zero ``sigma_t`` centre is closer than ``h + h_s`` in
    every axis (the border voxels a clamped lookup repeats are within that distance too).

    >>> s = np.zeros((8, 8, 8)); s[0, 0, 0] = 1.0              # centre at 1/16 per axis
    >>> int(needed_voxels(s, 8).sum()), int(needed_voxels(s, 16).sum())  # 2 and 4 per axis
    (8, 64)
    """
    rs = sigma_t.shape[0]
    nonzero = np.asarray(sigma_t) > 0
    occupied = (nonzero.any(axis=-1) if nonzero.ndim == 4 else nonzero).astype(np.int64)  # chromatic: any channel
    sat = np.zeros((rs + 1,) * 3, dtype=np.int64)
    sat[1:, 1:, 1:] = occupied.cumsum(0).cumsum(1).cumsum(2)
    centre = (np.arange(resolution) + 0.5) / resolution
    reach = 1.0 / resolution + 1.0 / rs
    lo = np.clip(np.ceil((centre - reach) * rs - 0.5 + 1e-9), 0, rs).astype(np.int64)
    hi = np.clip(np.floor((centre + reach) * rs - 0.5 - 1e-9) + 1, 0, rs).astype(np.int64)
    z0, y0, x0 = np.ix_(lo, lo, lo)
    z1, y1, x1 = np.ix_(hi, hi, hi)
    count = (sat[z1, y1, x1] - sat[z0, y1, x1] - sat[z1, y0, x1] - sat[z1, y1, x0]
             + sat[z0, y0, x1] + sat[z0, y1, x0] + sat[z1, y0, x0] - sat[z0, y0, x0])
    return count > 0


@dataclass(frozen=True)
class SourceGrids:
    """``Lbar`` on voxel-centre grids over the box (``[z, y, x, rgb]``, float32), as estimated.

    ``mc``/``mc_se``: volpath's part and its standard error (zero where not needed:
    :func:`needed_voxels`); ``delta``: the delta lights' direct term. ``J = albedo (mc + delta)``.
    """

    mc: np.ndarray
    mc_se: np.ndarray
    delta: np.ndarray
    spp: int
    points: int
    """Grid points volpath was run from."""
    seconds: dict


def estimate_grids(scene, lights, sigma_t: np.ndarray, box: Box, resolution: int, delta_resolution: int,
                   spp: int, seed: int = 0) -> SourceGrids:
    """:class:`SourceGrids` of a scene (``scene``: the Mitsuba scene with volpath at :func:`inner_max_depth`)."""
    from mitsnerf.scoring.density import true_density
    from mitsnerf.scoring.medium import mask_samples

    t0 = time.perf_counter()
    need = needed_voxels(sigma_t, resolution)
    centres = box.voxel_centres(resolution)[need]
    mc, se = np.zeros((resolution,) * 3 + (3,)), np.zeros((resolution,) * 3 + (3,))
    if scene is not None and len(centres):
        mc[need], se[need] = mean_radiance(scene, centres, spp, seed)
    t1 = time.perf_counter()
    delta = np.zeros((delta_resolution,) * 3 + (3,))
    need_d = needed_voxels(sigma_t, delta_resolution)
    if scene is not None and need_d.any():
        delta[need_d] = delta_radiance(lights, true_density(sigma_t, box), box.voxel_centres(delta_resolution)[need_d],
                                       box, mask_samples(sigma_t, box))
    seconds = {"volpath": t1 - t0, "delta_lights": time.perf_counter() - t1}
    f32 = np.float32
    return SourceGrids(mc.astype(f32), se.astype(f32), delta.astype(f32), spp, int(len(centres)), seconds)
