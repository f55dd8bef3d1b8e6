"""Every score of renders of a split's views, each by one rule: what a run, a benchmark cell, the oracle and
``mitsnerf score`` report (:func:`score_views`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from mitsnerf.scoring.density import Density, density_scores, optical_depth_scores
from mitsnerf.scoring.images import error_budget, image_scores
from mitsnerf.scoring.reference import Reference
from mitsnerf.scoring.variance import WITHOUT_MC, headline, without_variance


def score_views(preds: np.ndarray, ref: Reference, density: Density | None = None, *, oracle: dict | None = None,
                density_resolution: int = 0, od_samples: int = 0,
                variance: np.ndarray | None = None) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Every score of renders ``preds`` (V, H, W, 3) of ``ref``'s views: ``(metrics, density slices)``.

    ``metrics``: :func:`mitsnerf.scoring.images.image_scores`; with ``variance`` (V, H, W, 3), the renders' own
    Monte Carlo variance per pixel, also :func:`mitsnerf.scoring.variance.without_variance`
    (``psnr_test_medium_without_mc``); the noise floor (``noise_floor_psnr``, ``noise_floor_psnr_medium``, ...);
    with ``oracle`` (the oracle's own metrics at the same footprint) ``oracle_psnr_test_medium`` (and
    ``oracle_psnr_test_medium_without_mc``) and the :func:`mitsnerf.scoring.images.error_budget` of the
    :func:`headline` figures; with a true grid, the :func:`mitsnerf.scoring.density.density_scores` and
    :func:`mitsnerf.scoring.density.optical_depth_scores` of ``density`` (a note without one).
    """
    if preds.shape != ref.images.shape:
        raise ValueError(f"renders have shape {preds.shape}, the references {ref.images.shape}")
    metrics = image_scores(preds, ref.images, ref.masks)
    if variance is not None:
        metrics.update(without_variance(preds, ref.images, ref.masks, variance))
    floor = ref.noise_floor or {}
    for key in ("psnr", "psnr_medium", "psnr_per_view", "psnr_srgb", "psnr_medium_srgb"):
        metrics[f"noise_floor_{key}"] = floor.get(key)
    oracle = oracle or {}
    metrics["oracle_psnr_test"] = oracle.get("psnr_test")
    metrics["oracle_psnr_test_medium"] = oracle.get("psnr_test_medium")
    metrics["oracle_psnr_test_medium" + WITHOUT_MC] = oracle.get("psnr_test_medium" + WITHOUT_MC)
    metrics.update(error_budget(headline(metrics), headline(oracle), floor.get("psnr_medium")))
    dens, slices = density_figures(density, ref, density_resolution, od_samples)
    metrics.update(dens)
    return metrics, slices


def density_figures(density: Density | None, ref: Reference, resolution: int = 0,
                    od_samples: int = 0) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The density part of :func:`score_views`: ``(metrics, slices)``. With a true grid, the
    :func:`mitsnerf.scoring.density.density_scores` of ``density`` against it (and ``density_rel_l1_reduced``,
    ``density_rel_mass_reduced`` against an anisotropic medium's reduced extinction, None otherwise) and its
    :func:`mitsnerf.scoring.density.optical_depth_scores` along ``ref``'s rays: every key None (and a note)
    without a ``density``; without a true grid only ``density_note``."""
    if ref.sigma_t is None:
        return {"density_note": "the dataset has no true sigma_t grid"}, {}
    metrics, slices = density_scores(density, ref.sigma_t, ref.box, resolution)
    reduced = (density_scores(density, ref.reduced_sigma_t, ref.box, resolution)[0]
               if ref.reduced_sigma_t is not None else {})
    for key in ("density_rel_l1", "density_rel_mass"):  # None: an isotropic medium (nothing ambiguous)
        metrics[f"{key}_reduced"] = reduced.get(key)
    metrics.update(optical_depth_scores(density, ref.sigma_t, ref.box, ref.cameras, ref.pixel_center, od_samples))
    return metrics, slices
