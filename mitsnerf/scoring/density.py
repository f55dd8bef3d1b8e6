"""How close is a learned density to the true one? On the voxel centres of the box, and as optical depth
along every test pixel's ray.

**Density scores** (:func:`density_scores`, :func:`optical_depth_scores`) of a learned density
``x -> sigma`` against the true ``sigma_t``: on the voxel centres of the box
(:func:`mitsnerf.math.metrics.density_error`), and as optical depth along every test pixel's ray. A
chromatic ``sigma_t`` is scored channel by channel, a grey density standing for every colour
(:func:`broadcast_channels`). For an anisotropic medium the same scores are also given against its
similarity-scaled extinction (:func:`reduced_extinction`), which an emission-absorption fit may land on as
well.

The densities are queried here too: the true grid as Mitsuba looks it up (:func:`true_density`), any
``x -> sigma`` at points (:func:`query_density`) and integrated along rays (:func:`ray_optical_depths`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from mitsnerf.math.box import Box, optical_depth
from mitsnerf.math.metrics import density_error
from mitsnerf.math.rays import camera_rays_numpy, host, to_array3f
from mitsnerf.scoring.numbers import finite

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


# --------------------------------------------------------------------------- densities at points and along rays


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
