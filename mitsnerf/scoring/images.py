"""How close are renders to their references? Image scores, the noise floor, the error budget.

**Image scores** (:func:`image_scores`) of renders against references ``(V, H, W, 3)``:

- ``linear``: PSNR/SSIM of linear radiance clipped to ``[0, 1]`` (max value 1);
- ``srgb``: the same values clipped, then sRGB-encoded (what a viewer sees);
- ``medium``: PSNR over the medium pixels only (:func:`mitsnerf.scoring.medium.medium_masks`); means are
  over the views that have any.

**Noise floor** (:func:`noise_floor`): the same PSNRs between two independent ground-truth
renders of the test views (``test``, ``test_ref``); a noise-free model scores about 3 dB above it.

**Error budget** (:func:`error_budget`): a method's medium PSNR next to the oracle's and the
floor, and the gaps between them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mitsnerf.math.color import linear_to_srgb
from mitsnerf.math.metrics import SSIM_WINDOW, psnr, ssim
from mitsnerf.scoring.medium import MEDIUM_OPACITY
from mitsnerf.scoring.numbers import finite, mean_of


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
