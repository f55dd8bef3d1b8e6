"""What a benchmark cell measures: image scores in two encodings, and, since the true volume
is known, the error of the learned density field.

Image scores (:func:`image_scores`) compare renders and references ``(V, H, W, 3)``:

- ``linear``: PSNR/SSIM of linear radiance clipped to ``[0, 1]`` (max value 1);
- ``srgb``: the same values clipped, then sRGB-encoded (what a viewer sees);
- ``medium``: PSNR over the pixels whose centre ray crosses the true medium
  (:func:`mitsnerf.run.medium_masks`); background pixels are exact in the ground truth and
  inflate whole-image PSNR (by about 5 dB on the default cloud).

Density scores (:func:`density_scores`, :func:`optical_depth_scores`) query the learned
``model.field().density(x)`` (``None`` with a note when a method has none):

- on the ``R^3`` voxel centres of the box: :func:`mitsnerf.math.metrics.density_error`
  (relative L1, L2, and PSNR with the true maximum as peak);
- along every test pixel's centre ray over its ``[t_n, t_f]`` in the box: the optical depth
  ``tau = int sigma dt`` of the learned and the true ``sigma_t`` by the same midpoint rule,
  compared as ``tau_rel_l1 = sum |tau_l - tau_t| / sum tau_t``, ``tau_rmse`` and the mean
  absolute error of the transmittance ``exp(-tau)`` over rays that meet the box.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from mitsnerf.math.color import linear_to_srgb
from mitsnerf.math.metrics import SSIM_WINDOW, density_error, psnr, ssim

NO_DENSITY = "no queryable density (model.field().density)"


def finite(x) -> float | None:
    """``float(x)``, or None for None, NaN and infinities (JSON has no such numbers)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _mean(values: Sequence[float | None]) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


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
        per_ssim = [None] * len(p) if small else [finite(v) for v in np.atleast_1d(ssim(p, r))]
        out[f"{prefix}{tag}"], out[f"{prefix}{tag}_per_view"] = _mean(per_psnr), per_psnr
        if with_ssim:
            out[f"{ssim_prefix}{tag}"], out[f"{ssim_prefix}{tag}_per_view"] = _mean(per_ssim), per_ssim
        if masks is not None:
            per_med = [finite(psnr(pv, rv, mask=m)) if m.any() else None for pv, rv, m in zip(p, r, masks)]
            out[f"{prefix}_medium{tag}"], out[f"{prefix}_medium{tag}_per_view"] = _mean(per_med), per_med
    return out


# --------------------------------------------------------------------------- density field


def voxel_centres(resolution: int) -> np.ndarray:
    """World positions ``(R^3, 3)`` of the voxel centres of an ``R^3`` grid over the box, in
    ``[z, y, x]`` order (x fastest), so ``values.reshape(R, R, R)`` is indexed ``[z, y, x]``.

    >>> voxel_centres(2)[:3].tolist()
    [[-0.25, -0.25, -0.25], [0.25, -0.25, -0.25], [-0.25, 0.25, -0.25]]
    """
    c = (np.arange(resolution) + 0.5) / resolution - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)


def density_fn(model):
    """The model's ``x -> sigma`` (Dr.Jit Array3f -> Float), or None if it has none."""
    try:
        field = model.field()
    except NotImplementedError:
        return None
    fn = getattr(field, "density", None)
    return fn if callable(fn) else None


def query_density(fn, points: np.ndarray, chunk: int = 1 << 18) -> np.ndarray:
    """``fn`` at ``points`` ``(M, 3)``, in chunks, without gradients: float64 ``(M,)``."""
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.render.rays import to_array3f

    out = np.empty(len(points), dtype=np.float64)
    with dr.suspend_grad():
        for start in range(0, len(points), chunk):
            x = to_array3f(mi.Array3f, points[start:start + chunk])
            out[start:start + chunk] = np.asarray(fn(x), dtype=np.float64)
    return out


def true_density_fn(sigma_t: np.ndarray):
    """The true ``sigma_t`` grid as ``x -> sigma`` (trilinear, clamped: Mitsuba's lookup)."""
    from mitsnerf.fields.grid import GridField

    return GridField.from_arrays(sigma_t).density


def density_scores(model, sigma_t: np.ndarray, resolution: int = 0) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Learned against true density on the voxel centres of an ``R^3`` grid (0: the true grid's).

    Returns ``(scores, slices)``: scores ``density_rel_l1``, ``density_rel_l2``,
    ``density_psnr``, ``density_resolution`` (all None and ``density_note`` set when the
    model has no density), and the central ``z``, ``y`` and ``x`` slices of both grids
    (``true_z``, ``learned_z``, ...) for the report.
    """
    r = int(resolution or sigma_t.shape[0])
    points = voxel_centres(r)
    truth = (np.asarray(sigma_t, dtype=np.float64) if r == sigma_t.shape[0]
             else query_density(true_density_fn(sigma_t), points).reshape(r, r, r))
    slices = {f"true_{a}": s for a, s in _slices(truth).items()}
    fn = density_fn(model)
    if fn is None:
        return {"density_rel_l1": None, "density_rel_l2": None, "density_psnr": None,
                "density_resolution": r, "density_note": NO_DENSITY}, slices
    learned = query_density(fn, points).reshape(r, r, r)
    err = density_error(learned, truth)
    slices.update({f"learned_{a}": s for a, s in _slices(learned).items()})
    return {"density_rel_l1": finite(err["rel_l1"]), "density_rel_l2": finite(err["rel_l2"]),
            "density_psnr": finite(err["psnr"]), "density_resolution": r, "density_note": None}, slices


def _slices(grid: np.ndarray) -> dict[str, np.ndarray]:
    r = grid.shape[0] // 2
    return {"z": grid[r].astype(np.float32), "y": grid[:, r].astype(np.float32), "x": grid[:, :, r].astype(np.float32)}


def ray_box(o: np.ndarray, d: np.ndarray, lo=(-0.5, -0.5, -0.5), hi=(0.5, 0.5, 0.5)) -> tuple[np.ndarray, np.ndarray]:
    """``(t_n, t_f)`` of rays ``(M, 3)`` through the box; ``t_n = t_f`` for rays that miss.

    >>> t_n, t_f = ray_box(np.array([[0.0, 0.0, -2.0]]), np.array([[0.0, 0.0, 1.0]]))
    >>> t_n.tolist(), t_f.tolist()
    ([1.5], [2.5])
    """
    o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        a, b = (np.asarray(lo) - o) * inv, (np.asarray(hi) - o) * inv
    t_n = np.nanmax(np.minimum(a, b), axis=1).clip(min=0.0)
    t_f = np.nanmin(np.maximum(a, b), axis=1)
    return t_n, np.maximum(t_f, t_n)


def optical_depths(fn, o: np.ndarray, d: np.ndarray, n_samples: int, chunk_samples: int = 1 << 18) -> np.ndarray:
    """``tau = int_{t_n}^{t_f} sigma(o + t d) dt`` (M,) by the midpoint rule with ``n_samples`` per ray."""
    t_n, t_f = ray_box(o, d)
    length = t_f - t_n
    tau = np.zeros(len(o))
    hit = np.nonzero(length > 0)[0]
    per = max(1, chunk_samples // n_samples)
    frac = (np.arange(n_samples) + 0.5) / n_samples
    for start in range(0, len(hit), per):
        idx = hit[start:start + per]
        t = t_n[idx, None] + frac[None, :] * length[idx, None]
        x = (o[idx, None, :] + t[..., None] * d[idx, None, :]).reshape(-1, 3)
        sigma = query_density(fn, x).reshape(len(idx), n_samples)
        tau[idx] = sigma.sum(axis=1) * length[idx] / n_samples
    return tau


def optical_depth_scores(model, sigma_t: np.ndarray, cameras, pixel_center: float = 0.5, n_samples: int = 0) -> dict[str, Any]:
    """Optical depth of the learned against the true density along every pixel ray of ``cameras``.

    ``n_samples`` midpoints per ray (0: twice the true grid's resolution). Keys:
    ``tau_rel_l1``, ``tau_rmse``, ``transmittance_mae``, ``tau_samples``, ``tau_rays``.
    """
    from mitsnerf.render.rays import camera_rays_numpy

    n = int(n_samples or 2 * sigma_t.shape[0])
    fn = density_fn(model)
    o, d = camera_rays_numpy(cameras, pixel_center)
    o, d = o.astype(np.float64), d.astype(np.float64)
    empty = {"tau_rel_l1": None, "tau_rmse": None, "transmittance_mae": None, "tau_samples": n, "tau_rays": len(o)}
    if fn is None:
        return empty
    tau_true = optical_depths(true_density_fn(sigma_t), o, d, n)
    tau_learned = optical_depths(fn, o, d, n)
    t_n, t_f = ray_box(o, d)
    hit = t_f > t_n
    if not hit.any() or tau_true.sum() <= 0:
        return empty
    diff = tau_learned - tau_true
    return {
        "tau_rel_l1": finite(np.abs(diff).sum() / tau_true.sum()),
        "tau_rmse": finite(np.sqrt(np.mean(diff[hit] ** 2))),
        "transmittance_mae": finite(np.mean(np.abs(np.exp(-tau_learned[hit]) - np.exp(-tau_true[hit])))),
        "tau_samples": n,
        "tau_rays": int(hit.sum()),
    }
