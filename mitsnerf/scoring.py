"""Every score mitsnerf reports, each computed once, by one rule.

Dataset generation (the noise floor), :func:`mitsnerf.runs.fit.fit`, the benchmark and
``mitsnerf score`` all score through this module.

**Medium pixels** (:func:`medium_masks`): a pixel sees the medium when the true medium's opacity
``1 - exp(-tau)`` along the ray through its sample point exceeds :data:`MEDIUM_OPACITY`, with
``tau`` the optical depth of the true ``sigma_t`` (trilinear, Mitsuba's lookup) by the midpoint
rule at two samples per voxel length of the box's diagonal. Background pixels are exact in the
ground truth and inflate whole-image PSNR (by 8-9 dB on the default cloud), so the medium scores
are the ones that tell methods apart.

**Image scores** (:func:`image_scores`) of renders against references ``(V, H, W, 3)``:

- ``linear``: PSNR/SSIM of linear radiance clipped to ``[0, 1]`` (max value 1);
- ``srgb``: the same values clipped, then sRGB-encoded (what a viewer sees);
- ``medium``: PSNR over the medium pixels only; means are over the views that have any.

**Density scores** (:func:`density_scores`, :func:`optical_depth_scores`) of a learned density
``x -> sigma`` against the true ``sigma_t``: on the voxel centres of the box
(:func:`mitsnerf.math.metrics.density_error`), and as optical depth along every test pixel's ray.

**Noise floor** (:func:`noise_floor`): the same PSNRs between two independent ground-truth
renders of the test views (``test``, ``test_ref``); a noise-free model scores about 3 dB above it.

**Error budget** (:func:`error_budget`): a method's medium PSNR next to the oracle's and the
floor, and the gaps between them.

**The medium alone** (:func:`transmittance_agreement`): the alpha of the dataset's renders of the
medium without the environment against the exact ``1 - T`` they estimate, a z-test per view with the
exact binomial variance; (:func:`composite_agreement`) those renders composited over the environment
against full images rendered on their own, and (:func:`view_agreement`) any two pairs of independent
renders of the same views, per view: statistical tests on two independent pairs of renders.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mitsnerf.data.images import over
from mitsnerf.math.box import Box, optical_depth
from mitsnerf.math.color import linear_to_srgb
from mitsnerf.math.metrics import SSIM_WINDOW, density_error, psnr, ssim
from mitsnerf.math.rays import camera_rays_numpy, host, to_array3f

MEDIUM_OPACITY = 1e-3
"""Opacity along a pixel's ray above which the pixel sees the medium."""
NO_DENSITY = "no queryable density (model.field().density)"

Density = Callable[[Any], Any]
"""``x -> sigma``: Dr.Jit Array3f (M,) -> Float (M,), or Array3f (M,) for a chromatic extinction."""


def broadcast_channels(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two grids (or per-ray arrays) of which one may have a trailing colour axis (chromatic) and the other
    not: the grey one is repeated over the three channels, so a grey density stands for every colour.

    >>> a, b = broadcast_channels(np.ones((2, 2)), np.ones((2, 2, 3)))
    >>> a.shape, b.shape
    ((2, 2, 3), (2, 2, 3))
    """
    if a.ndim == b.ndim:
        return a, b
    if a.ndim < b.ndim:
        return np.broadcast_to(a[..., None], b.shape), b
    return a, np.broadcast_to(b[..., None], a.shape)


def grey(sigma_t: np.ndarray, channel_axis: bool) -> np.ndarray:
    """The channels' mean of a chromatic ``sigma_t`` (``channel_axis``: it has a trailing RGB axis), else itself."""
    return np.asarray(sigma_t).mean(axis=-1) if channel_axis else np.asarray(sigma_t)


def finite(x) -> float | None:
    """``float(x)``, or None for None, NaN and infinities (JSON has no such numbers)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def mean_of(values: Sequence[float | None]) -> float | None:
    """The mean of the values that are not None (None if there are none)."""
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


# --------------------------------------------------------------------------- densities along rays


def true_density(sigma_t: np.ndarray, box: Box) -> Density:
    """The true ``sigma_t`` grid (R, R, R) over ``box`` as ``x -> sigma`` (trilinear, clamped: Mitsuba's lookup);
    a chromatic (R, R, R, 3) grid gives an Array3f ``sigma``."""
    from mitsnerf.fields.grid import GridField

    return GridField.from_arrays(sigma_t, box).density


def query_density(fn: Density, points: np.ndarray, chunk: int = 1 << 18) -> np.ndarray:
    """``fn`` at ``points`` ``(M, 3)``, in chunks, without gradients: float64 ``(M,)`` (``(M, 3)`` chromatic)."""
    import drjit as dr
    import mitsuba as mi

    with dr.suspend_grad():
        parts = [host(fn(to_array3f(mi.Array3f, points[start:start + chunk])))
                 for start in range(0, len(points), chunk)]
    return np.concatenate(parts) if parts else np.empty(0)


def ray_optical_depths(fn: Density, o: np.ndarray, d: np.ndarray, box: Box, n: int,
                       chunk_samples: int = 1 << 20) -> np.ndarray:
    """``tau = int_{t_n}^{t_f} sigma dt`` (M,) of numpy rays (M, 3) through ``box``, ``n`` midpoints each
    (``(M, 3)`` for a chromatic ``fn``)."""
    import drjit as dr
    import mitsuba as mi

    per = max(1, chunk_samples // n)
    with dr.suspend_grad():
        parts = [host(optical_depth(fn, to_array3f(mi.Array3f, o[s:s + per]), to_array3f(mi.Array3f, d[s:s + per]),
                                    box, n)) for s in range(0, len(o), per)]
    return np.concatenate(parts) if parts else np.zeros(0)


def mask_samples(sigma_t: np.ndarray, box: Box) -> int:
    """Midpoint samples per ray of the medium mask: two per voxel length along the box's diagonal."""
    voxel = min(box.size) / sigma_t.shape[0]
    return int(math.ceil(2.0 * box.diagonal / voxel))


def medium_masks(sigma_t: np.ndarray, box: Box, cameras, pixel_center: float = 0.5,
                 opacity: float = MEDIUM_OPACITY) -> np.ndarray:
    """(V, H, W) bool: pixels whose ray through their sample point crosses the true medium (module docstring)."""
    fn = true_density(sigma_t, box)
    n = mask_samples(sigma_t, box)
    masks = []
    for cam in cameras:
        o, d = camera_rays_numpy([cam], pixel_center)
        alpha = -np.expm1(-ray_optical_depths(fn, o, d, box, n))
        alpha = alpha.mean(axis=-1) if alpha.ndim == 2 else alpha  # chromatic: the channels' mean opacity
        masks.append((alpha > opacity).reshape(cam.height, cam.width))
    return np.stack(masks)


# --------------------------------------------------------------------------- images


def image_scores(preds: np.ndarray, refs: np.ndarray, masks: np.ndarray | None = None, prefix: str = "psnr_test",
                 with_ssim: bool = True) -> dict[str, Any]:
    """Per-view and mean PSNR/SSIM of ``preds`` against ``refs`` (both ``(V, H, W, 3)`` linear).

    Keys (with the default prefix): ``psnr_test``, ``psnr_test_srgb``, ``ssim_test``,
    ``ssim_test_srgb``, ``psnr_test_medium``, ``psnr_test_medium_srgb``, each with a
    ``_per_view`` list. Medium scores need ``masks`` (``(V, H, W)`` bool); views without
    medium pixels get None. SSIM is None for images under 11x11 pixels (left out with
    ``with_ssim=False``).

    >>> ref = np.full((1, 12, 12, 3), 0.5); pred = ref + 0.01
    >>> s = image_scores(pred, ref)
    >>> round(s["psnr_test"], 6), round(s["ssim_test_srgb"], 3)
    (40.0, 1.0)
    """
    ssim_prefix = prefix.replace("psnr", "ssim")
    lin_p, lin_r = np.clip(preds, 0.0, 1.0), np.clip(refs, 0.0, 1.0)
    enc = {"": (lin_p, lin_r), "_srgb": (linear_to_srgb(lin_p), linear_to_srgb(lin_r))}
    out: dict[str, Any] = {}
    small = min(preds.shape[1:3]) < SSIM_WINDOW or not with_ssim
    for tag, (p, r) in enc.items():
        per_psnr = [finite(v) for v in np.atleast_1d(psnr(p, r))]
        out[f"{prefix}{tag}"], out[f"{prefix}{tag}_per_view"] = mean_of(per_psnr), per_psnr
        if with_ssim:
            per_ssim = [None] * len(p) if small else [finite(v) for v in np.atleast_1d(ssim(p, r))]
            out[f"{ssim_prefix}{tag}"], out[f"{ssim_prefix}{tag}_per_view"] = mean_of(per_ssim), per_ssim
        if masks is not None:
            per_med = [finite(psnr(pv, rv, mask=m)) if m.any() else None for pv, rv, m in zip(p, r, masks)]
            out[f"{prefix}_medium{tag}"], out[f"{prefix}_medium{tag}_per_view"] = mean_of(per_med), per_med
    return out


def noise_floor(test: np.ndarray, ref: np.ndarray, masks: np.ndarray) -> dict[str, Any]:
    """The PSNRs between two independent ground-truth renders of the same views (the manifest's ``noise_floor``)."""
    s = image_scores(test[..., :3], ref[..., :3], masks, prefix="psnr", with_ssim=False)
    return {
        "psnr": s["psnr"],
        "psnr_medium": s["psnr_medium"],
        "psnr_per_view": s["psnr_per_view"],
        "psnr_medium_per_view": s["psnr_medium_per_view"],
        "psnr_srgb": s["psnr_srgb"],
        "psnr_medium_srgb": s["psnr_medium_srgb"],
        "medium_pixel_fraction": float(masks.mean()),
        "medium_mask": (f"pixels whose ray through the pixel centre has opacity 1 - exp(-tau) > {MEDIUM_OPACITY:g} "
                        "through the true sigma_t (trilinear); views without such pixels are skipped"),
        "method": "mean over test views of PSNR(test, test_ref), linear RGB clipped to [0, 1], max_val 1",
    }


def png_noise_floor(test: np.ndarray, test_ref: np.ndarray, masks: np.ndarray) -> dict[str, Any]:
    """The noise floor of renders handed over as 8-bit sRGB PNG: :func:`noise_floor` of the second
    ground-truth render ``test_ref`` quantised as a PNG (:func:`mitsnerf.data.images.png_quantised`)
    against ``test``. A PNG render cannot score above it as an EXR render cannot above the floor.
    """
    from mitsnerf.data.images import png_quantised

    floor = noise_floor(png_quantised(test_ref[..., :3]), test[..., :3], masks)
    floor["method"] = ("mean over test views of PSNR(png(test_ref), test), test_ref quantised to 8-bit sRGB as a "
                       "PNG and decoded, linear RGB clipped to [0, 1], max_val 1")
    return floor


def _pair_statistics(a: np.ndarray, b: np.ndarray, c1: np.ndarray, c2: np.ndarray) -> dict[str, Any]:
    """:func:`composite_agreement`'s test of ``E[a] = E[c]`` from two independent pairs (any shape)."""
    d = (a + b) / 2 - (c1 + c2) / 2
    w = ((a - b) ** 2 + (c1 - c2) ** 2) / 4
    total = float(w.sum())
    if total <= 0:
        return {"z_mean": None, "ratio": None, "ratio_sd": None, "passed": bool(np.all(d == 0)), "pixels": int(d.size)}
    z, ratio, sd = (
        float(d.sum() / math.sqrt(total)),
        float((d**2).sum() / total),
        math.sqrt(3 * float((w**2).sum())) / total,
    )
    return {"z_mean": z, "ratio": ratio, "ratio_sd": sd, "passed": abs(z) < 4 and ratio < 1 + 4 * sd,
            "pixels": int(d.size)}


def _channels(x) -> np.ndarray:
    """The sum of the RGB channels, float64 (the channels of a pixel share its paths: not independent)."""
    return np.asarray(x[..., :3], np.float64).sum(axis=-1)


def composite_agreement(full: np.ndarray, full_ref: np.ndarray, medium: np.ndarray, medium_ref: np.ndarray,
                        background: np.ndarray) -> dict[str, Any]:
    """Do the medium-alone renders, composited over the environment, reproduce the full images?

    ``full``, ``full_ref``: two independent renders of the same views (``(V, H, W, >=3)``, the
    ``test`` and ``test_ref`` splits); ``medium``, ``medium_ref``: two independent medium-alone
    renders (premultiplied RGBA); ``background``: ``(V, H, W, 3)``, the environment each pixel
    sees (:func:`mitsnerf.render.background.pixel_background`). Per pixel, on the sum of the
    channels (the channels of a pixel share its paths, so they are not independent; pixels are),
    with ``C_1``, ``C_2`` the two composites (:func:`composite`)::

        D = (full + full_ref) / 2 - (C_1 + C_2) / 2
        W = ((full - full_ref)^2 + (C_1 - C_2)^2) / 4                     (E[W] = Var D under H0)
        z_mean = sum D / sqrt(sum W)        ratio = sum D^2 / sum W,  ratio_sd = sqrt(3 sum W^2) / sum W

    Under ``H0: E[C] = E[full]`` per pixel, ``z_mean`` is about standard normal (a shared bias
    moves it) and ``ratio`` about 1 (a per-pixel disagreement raises it; ``ratio_sd`` is its
    standard deviation for Gaussian noise). ``passed``: ``|z_mean| < 4`` and ``ratio < 1 + 4 ratio_sd``.
    """
    def composited(rgba):
        return _channels(over(rgba[..., :3], rgba[..., 3:4], background))

    return _pair_statistics(_channels(full), _channels(full_ref), composited(medium), composited(medium_ref))


#: The family-wise error rate of the per-view checks (:func:`view_agreement`, :func:`transmittance_agreement`).
FAMILY_ALPHA = 1e-3


def critical_z(tests: int, alpha: float = FAMILY_ALPHA) -> float:
    """The |z| a family of ``tests`` z-tests rejects beyond, holding the family-wise error rate at ``alpha``
    (Bonferroni: each two-sided test at ``alpha / tests``).

    >>> round(critical_z(1, 0.05), 3), round(critical_z(16), 2)
    (1.96, 4.0)
    """
    from statistics import NormalDist

    return NormalDist().inv_cdf(1.0 - alpha / (2.0 * max(1, tests)))


def ratio_z(ratio: float, ratio_sd: float) -> float:
    """A dispersion ratio (mean 1, standard deviation ``ratio_sd`` under H0) as a z-score, its right skew
    taken into account: the ratio read as ``chi^2_k / k`` with ``k = 2 / ratio_sd^2`` (the same variance),
    through the Wilson-Hilferty cube root (``(ratio^(1/3) - (1 - 2 / 9k)) / sqrt(2 / 9k)``, about standard
    normal). A sum of squares over a few hundred pixels is skewed; read as ``(ratio - 1) / ratio_sd`` its
    4-sigma tail came out over ten times too likely on simulated binomial alpha maps.

    >>> round(ratio_z(1.0, 0.1), 3), round(ratio_z(1.4, 0.1), 2)
    (0.033, 3.59)
    """
    if not ratio_sd > 0:
        return 0.0
    w = 2.0 / (9.0 * (2.0 / ratio_sd**2))
    return (max(ratio, 0.0) ** (1.0 / 3.0) - (1.0 - w)) / math.sqrt(w)


def view_agreement(x: np.ndarray, x_ref: np.ndarray, y: np.ndarray, y_ref: np.ndarray,
                   alpha: float = FAMILY_ALPHA) -> dict[str, Any]:
    """Do two estimators agree in expectation, view by view? ``x``, ``x_ref`` and ``y``, ``y_ref``: two pairs of
    independent renders of the same views (``(V, H, W, >=3)``, e.g. images composed by the one-pass ground
    truth and images rendered directly). :func:`composite_agreement`'s ``z_mean`` and ``ratio`` on each view
    alone (``views``), the ``2 V`` tests held at the family-wise error rate ``alpha`` (:func:`critical_z`):
    a view passes when ``|z_mean| < c`` and the ratio's :func:`ratio_z` ``< c``; ``passed`` when every view does."""
    a, b, c1, c2 = (_channels(v) for v in (x, x_ref, y, y_ref))
    c = critical_z(2 * len(a), alpha)
    views: list[dict[str, Any]] = []
    for i in range(len(a)):
        v = _pair_statistics(a[i], b[i], c1[i], c2[i])
        if v["z_mean"] is not None:
            v["ratio_z"] = ratio_z(v["ratio"], v["ratio_sd"])
            v["passed"] = abs(v["z_mean"]) < c and v["ratio_z"] < c
        views.append(v)
    return {"passed": all(v["passed"] for v in views), "critical_z": c, "views": views,
            "max_abs_z": max((abs(v["z_mean"]) for v in views if v["z_mean"] is not None), default=None),
            "max_ratio_z": max((v["ratio_z"] for v in views if "ratio_z" in v), default=None)}


def transmittance_agreement(alpha: np.ndarray, transmittance: np.ndarray, spp: int,
                            family_alpha: float = FAMILY_ALPHA) -> dict[str, Any]:
    """Is the alpha of medium-alone renders an estimate of ``1 - T``? A test per view with the exact variance.

    ``alpha``: ``(V, H, W)``, the fraction of each pixel's ``spp`` samples whose camera ray collided in the
    medium (:mod:`mitsnerf.scene.render`); ``transmittance``: ``(V, H, W)``, each pixel's mean ``T``
    (:func:`mitsnerf.scene.transmittance.pixel_transmittance`). A sample lands uniformly in its pixel and
    collides with probability ``1 - T`` of its ray, so it collides with probability ``p = 1 - mean T``,
    independently of the others: ``spp alpha`` is binomial, ``Var alpha = p (1 - p) / spp`` exactly, and
    the fourth central moment ``mu_4 = p q (1 + 3 (spp - 2) p q) / spp^3`` (``q = 1 - p``). Per view, with
    ``D = alpha - p``::

        z = sum D / sqrt(sum Var)      ratio = sum D^2 / sum Var,      ratio_sd = sqrt(sum (mu_4 - Var^2)) / sum Var

    The ``2 V`` tests are one family held at the error rate ``family_alpha`` (:func:`critical_z` ``c``): a
    view passes when ``|z| < c``, the ratio's :func:`ratio_z` ``< c`` and no pixel of ``p = 0`` (a ray that misses
    the medium) has alpha above 1e-6 (``impossible``). The check has power against a transmittance off by a
    shared factor (``z``) and against one right on average but wrong per pixel (``ratio``: a shifted
    pixel centre, the footprint ignored).
    """
    a = np.asarray(alpha, np.float64)
    p = np.clip(1.0 - np.asarray(transmittance, np.float64), 0.0, 1.0)
    q, n = 1.0 - p, float(spp)
    var = p * q / n
    mu4 = p * q * (1.0 + 3.0 * (n - 2.0) * p * q) / n**3
    d = a - p
    c = critical_z(2 * len(a), family_alpha)
    views: list[dict[str, Any]] = []
    for i in range(len(a)):
        total = float(var[i].sum())
        impossible = int(((var[i] == 0) & (np.abs(d[i]) > 1e-6)).sum())
        if total <= 0:
            views.append({"z": None, "ratio": None, "ratio_sd": None, "ratio_z": None, "impossible": impossible,
                          "passed": impossible == 0})
            continue
        z, ratio = float(d[i].sum() / math.sqrt(total)), float((d[i] ** 2).sum() / total)
        sd = math.sqrt(float(np.maximum(mu4[i] - var[i] ** 2, 0.0).sum())) / total
        rz = ratio_z(ratio, sd)
        views.append({"z": z, "ratio": ratio, "ratio_sd": sd, "ratio_z": rz, "impossible": impossible,
                      "passed": abs(z) < c and rz < c and impossible == 0})
    zs = [abs(v["z"]) for v in views if v["z"] is not None]
    return {"passed": all(v["passed"] for v in views), "spp": int(spp), "critical_z": c, "views": views,
            "max_abs_z": max(zs, default=None),
            "max_ratio_z": max((v["ratio_z"] for v in views if v["ratio_z"] is not None), default=None)}


def near_far_coverage(sigma_t: np.ndarray, box: Box, cameras, near: float, far: float,
                      pixel_center: float = 0.5) -> float | None:
    """The fraction of the true optical depth along the pixel rays of ``cameras`` that lies within
    ``[near, far]`` of the camera (a reader with a fixed near/far sees only that part), by the
    midpoint rule with :func:`mask_samples` samples per chord of the box; None when no ray meets
    the medium.
    """
    fn, n = true_density(grey(sigma_t, sigma_t.ndim == 4), box), mask_samples(sigma_t, box)
    u = (np.arange(n) + 0.5) / n
    inside = total = 0.0
    for cam in cameras:  # one view at a time: (H W, n, 3) points
        o, d = (a.astype(np.float64) for a in camera_rays_numpy([cam], pixel_center))
        t_n, t_f, hit = box.intersect_numpy(o, d)
        t = t_n[hit, None] + u[None] * (t_f - t_n)[hit, None]
        points = o[hit, None] + t[..., None] * d[hit, None]
        tau = query_density(fn, points.reshape(-1, 3)).reshape(t.shape) * ((t_f - t_n)[hit, None] / n)
        inside, total = inside + float(tau[(t >= near) & (t <= far)].sum()), total + float(tau.sum())
    return inside / total if total > 0 else None


# --------------------------------------------------------------------------- density fields


def _slices(grid: np.ndarray) -> dict[str, np.ndarray]:
    """The central z, y and x slices of a grid; a chromatic one's channels' mean (one image per slice)."""
    grid = grey(grid, grid.ndim == 4)
    r = grid.shape[0] // 2
    return {"z": grid[r].astype(np.float32), "y": grid[:, r].astype(np.float32), "x": grid[:, :, r].astype(np.float32)}


def density_scores(fn: Density | None, sigma_t: np.ndarray, box: Box,
                   resolution: int = 0) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Learned (``fn``) against true density on the voxel centres of an ``R^3`` grid over ``box`` (0: the true
    grid's R). A chromatic ``sigma_t`` (R, R, R, 3) is scored channel by channel, a grey learned density
    standing for all three (:func:`broadcast_channels`), and so is a chromatic learned density against a grey
    truth.

    Returns ``(scores, slices)``: ``density_rel_l1``, ``density_rel_l2``, ``density_rel_mass`` (signed, see
    :func:`mitsnerf.math.metrics.density_error`), ``density_psnr``,
    ``density_resolution`` (None values and ``density_note`` when ``fn`` is None), and the
    central ``z``, ``y`` and ``x`` slices of both grids (``true_z``, ``learned_z``, ...).
    """
    r = int(resolution or sigma_t.shape[0])
    points = box.voxel_centres(r).reshape(-1, 3)
    truth = (np.asarray(sigma_t, dtype=np.float64) if r == sigma_t.shape[0]
             else query_density(true_density(sigma_t, box), points).reshape((r, r, r) + sigma_t.shape[3:]))
    slices = {f"true_{a}": s for a, s in _slices(truth).items()}
    if fn is None:
        return {"density_rel_l1": None, "density_rel_l2": None, "density_rel_mass": None, "density_psnr": None,
                "density_resolution": r, "density_note": NO_DENSITY}, slices
    learned = query_density(fn, points)
    learned = learned.reshape((r, r, r) + learned.shape[1:])
    err = density_error(*broadcast_channels(learned, truth))
    slices.update({f"learned_{a}": s for a, s in _slices(learned).items()})
    return {"density_rel_l1": finite(err["rel_l1"]), "density_rel_l2": finite(err["rel_l2"]),
            "density_rel_mass": finite(err["rel_mass"]),
            "density_psnr": finite(err["psnr"]), "density_resolution": r, "density_note": None}, slices


def optical_depth_scores(fn: Density | None, sigma_t: np.ndarray, box: Box, cameras, pixel_center: float = 0.5,
                         n_samples: int = 0) -> dict[str, Any]:
    """Optical depth of the learned against the true density along every pixel ray of ``cameras``.

    ``n_samples`` midpoints per ray (0: twice the true grid's resolution). Keys: ``tau_rel_l1``
    (``sum |tau_l - tau_t| / sum tau_t``), ``tau_rmse``, ``transmittance_mae`` (mean
    ``|exp(-tau_l) - exp(-tau_t)|`` over rays that meet the box), ``tau_samples``, ``tau_rays``.
    """
    n = int(n_samples or 2 * sigma_t.shape[0])
    o, d = camera_rays_numpy(cameras, pixel_center)
    empty = {"tau_rel_l1": None, "tau_rmse": None, "transmittance_mae": None, "tau_samples": n, "tau_rays": len(o)}
    _, _, hit = box.intersect_numpy(o, d)
    if fn is None or not hit.any():
        return empty
    tau_true = ray_optical_depths(true_density(sigma_t, box), o[hit], d[hit], box, n)
    tau_learned = ray_optical_depths(fn, o[hit], d[hit], box, n)
    if tau_true.sum() <= 0:
        return empty
    tau_learned, tau_true = broadcast_channels(tau_learned, tau_true)
    diff = tau_learned - tau_true
    return {
        "tau_rel_l1": finite(np.abs(diff).sum() / tau_true.sum()),
        "tau_rmse": finite(np.sqrt(np.mean(diff**2))),
        "transmittance_mae": finite(np.mean(np.abs(np.exp(-tau_learned) - np.exp(-tau_true)))),
        "tau_samples": n,
        "tau_rays": int(hit.sum()),
    }


# --------------------------------------------------------------------------- the error budget


def error_budget(medium_psnr: float | None, oracle_medium: float | None, floor_medium: float | None) -> dict[str, Any]:
    """A result's medium PSNR against the oracle's (the best any emission-absorption model can do
    on the dataset) and the noise floor: ``gap_to_oracle = oracle - result`` (dB the method
    leaves on the table), ``oracle_to_floor = floor - oracle`` (what the representation itself
    costs, plus the reference noise).

    >>> error_budget(38.0, 43.5, 44.0)
    {'gap_to_oracle': 5.5, 'oracle_to_floor': 0.5, 'gap_to_floor': 6.0}
    """
    def gap(a, b):
        return None if a is None or b is None else round(float(a) - float(b), 6)

    return {"gap_to_oracle": gap(oracle_medium, medium_psnr), "oracle_to_floor": gap(floor_medium, oracle_medium),
            "gap_to_floor": gap(floor_medium, medium_psnr)}


# --------------------------------------------------------------------------- a dataset's references


@dataclass(frozen=True)
class Reference:
    """What renders of one split are scored against, and everything known about that split."""

    images: np.ndarray
    """(V, H, W, 3) linear RGB, the split's ground truth."""
    cameras: tuple
    pixel_center: float
    box: Box
    sigma_t: np.ndarray | None
    """The true extinction grid (None for foreign data)."""
    masks: np.ndarray | None
    """(V, H, W) medium pixels (None without a true grid)."""
    noise_floor: dict | None
    """The manifest's ``noise_floor`` (None without ``test_ref``)."""
    reduced_sigma_t: np.ndarray | None = None
    """An anisotropic medium's similarity-scaled extinction (:func:`reduced_extinction`); None otherwise."""


def reduced_extinction(sigma_t: np.ndarray, albedo: np.ndarray, g: float) -> np.ndarray:
    """The similarity-scaled extinction ``sigma_t (1 - albedo g)``, albedo averaged over RGB: with the scaled albedo
    ``albedo (1 - g) / (1 - albedo g)`` and an isotropic phase it renders nearly the same images as the medium of
    Henyey-Greenstein ``g`` (exactly in the diffusion limit), so an emission-absorption density fitted to the
    images may land on it as well as on ``sigma_t``: the density scores are given against both.

    A chromatic ``sigma_t`` (R, R, R, 3) is scaled per channel by that channel's albedo.

    >>> reduced_extinction(np.full((1, 1, 1), 10.0), np.full((1, 1, 1, 3), 0.8), 0.5).tolist()
    [[[6.0]]]
    >>> reduced_extinction(np.full((1, 1, 1, 3), 10.0), np.array([[[[0.0, 0.5, 1.0]]]]), 0.5).tolist()
    [[[[10.0, 7.5, 5.0]]]]
    """
    sigma = np.asarray(sigma_t, dtype=np.float64)
    a = np.asarray(albedo, dtype=np.float64)
    a = a.reshape(sigma.shape) if sigma.ndim == 4 else a.reshape(sigma.shape + (-1,)).mean(axis=-1)
    return (sigma * (1.0 - a * float(g))).astype(np.float32)


def _reduced_sigma_t(dataset, sigma_t: np.ndarray | None) -> np.ndarray | None:
    """The dataset's :func:`reduced_extinction` when its spec's medium is Henyey-Greenstein with ``g != 0``."""
    from mitsnerf.data.arrays import read_npy
    from mitsnerf.data.dataset import true_grid_path

    phase = (((dataset.manifest or {}).get("spec") or {}).get("volume") or {}).get("phase") or {}
    g = float(phase.get("g", 0.0)) if phase.get("type") == "hg" else 0.0
    albedo = true_grid_path(dataset.root, "albedo")
    if sigma_t is None or g == 0.0 or not albedo.exists():
        return None
    return reduced_extinction(sigma_t, read_npy(albedo, "numpy grid"), g)


def load_true_sigma_t(root) -> np.ndarray | None:
    """The ground-truth ``sigma_t`` grid of a generated dataset (None for foreign data)."""

    from mitsnerf.data.arrays import read_npy
    from mitsnerf.data.dataset import true_grid_path

    path = true_grid_path(root)
    if not path.exists():
        return None
    return read_npy(path, "numpy grid")


def reference(dataset, split: str = "test") -> Reference:
    """The :class:`Reference` of a :class:`mitsnerf.data.dataset.Dataset` split (masks from its true grid)."""
    views = dataset.views(split)
    sigma_t = load_true_sigma_t(dataset.root)
    masks = medium_masks(sigma_t, dataset.box, views.cameras, views.pixel_center) if sigma_t is not None else None
    floor = (dataset.manifest or {}).get("noise_floor") if split == "test" else None
    return Reference(views.images, tuple(views.cameras), views.pixel_center, dataset.box, sigma_t, masks, floor,
                     _reduced_sigma_t(dataset, sigma_t))


def score_views(preds: np.ndarray, ref: Reference, density: Density | None = None, *, oracle: dict | None = None,
                density_resolution: int = 0, od_samples: int = 0) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Every score of renders ``preds`` (V, H, W, 3) of ``ref``'s views: ``(metrics, density slices)``.

    ``metrics``: :func:`image_scores`; the noise floor (``noise_floor_psnr``,
    ``noise_floor_psnr_medium``, ...); with ``oracle`` (the oracle's own metrics at the same
    footprint) ``oracle_psnr_test_medium`` and the :func:`error_budget`; with a true grid, the
    :func:`density_scores` and :func:`optical_depth_scores` of ``density`` (a note without one).
    """
    if preds.shape != ref.images.shape:
        raise ValueError(f"renders have shape {preds.shape}, the references {ref.images.shape}")
    metrics = image_scores(preds, ref.images, ref.masks)
    floor = ref.noise_floor or {}
    for key in ("psnr", "psnr_medium", "psnr_per_view", "psnr_srgb", "psnr_medium_srgb"):
        metrics[f"noise_floor_{key}"] = floor.get(key)
    oracle_medium = (oracle or {}).get("psnr_test_medium")
    metrics["oracle_psnr_test"] = (oracle or {}).get("psnr_test")
    metrics["oracle_psnr_test_medium"] = oracle_medium
    metrics.update(error_budget(metrics.get("psnr_test_medium"), oracle_medium, floor.get("psnr_medium")))
    slices: dict[str, np.ndarray] = {}
    if ref.sigma_t is None:
        metrics["density_note"] = "the dataset has no true sigma_t grid"
        return metrics, slices
    dens, slices = density_scores(density, ref.sigma_t, ref.box, density_resolution)
    metrics.update(dens)
    reduced = (density_scores(density, ref.reduced_sigma_t, ref.box, density_resolution)[0]
               if ref.reduced_sigma_t is not None else {})
    for key in ("density_rel_l1", "density_rel_mass"):  # None: an isotropic medium (nothing ambiguous)
        metrics[f"{key}_reduced"] = reduced.get(key)
    metrics.update(optical_depth_scores(density, ref.sigma_t, ref.box, ref.cameras, ref.pixel_center, od_samples))
    return metrics, slices
