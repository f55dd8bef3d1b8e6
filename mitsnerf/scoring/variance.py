"""Scores without a render's own Monte Carlo variance: what a Monte Carlo estimate would score were it exact.

A render ``A`` that is a Monte Carlo estimate (the oracle's in-scattered light from volpath, a path tracer's image)
of an image ``E[A]``, scored against references ``R`` independent of it (noisy or not), has

    MSE(A, R) = MSE(E[A], R) + Var_mc,        Var_mc = mean over the pixels of Var(A_p)

so its own variance lowers its PSNR by what more samples would remove. Two renders ``A``, ``B`` of the same
estimate with independent samples give it (:func:`pair_variance`): ``E (A_p - B_p)^2 = 2 Var(A_p)``, so
``Var(A_p) ~ (A_p - B_p)^2 / 2``; an estimate that keeps its own error patterns gives ``Var(A_p)`` directly
(:func:`mitsnerf.oracle.field.image_variance`). Per view, on its medium pixels (:func:`without_variance`)::

    MSE_without = MSE(A, R) - mean Var(A_p),        PSNR_without = -10 log10(MSE_without)

(the MSE of values clipped to ``[0, 1]`` as :func:`mitsnerf.scoring.images.image_scores`'s, the variance of the
unclipped render), then the mean over views as its medium PSNR. ``MSE_without <= 0`` in a view (the variance
estimate explains all the error measured there) leaves it unbounded: the figure is None and ``mc_note`` says why.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mitsnerf.scoring.numbers import mean_of

WITHOUT_MC = "_without_mc"
"""The suffix of a figure with the render's own Monte Carlo variance removed (``psnr_test_medium_without_mc``)."""


def headline(metrics: dict, key: str = "psnr_test_medium") -> Any:
    """``metrics[key]`` less its own Monte Carlo variance where that was measured (``key + "_without_mc"``), else
    ``metrics[key]`` itself: the figure a ceiling and a row are compared on.

    >>> headline({"psnr_test_medium": 44.56, "psnr_test_medium_without_mc": 46.01}), headline({"psnr_test_medium": 3})
    (46.01, 3)
    """
    without = metrics.get(key + WITHOUT_MC)
    return without if without is not None else metrics.get(key)


def pair_variance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``Var(A_p)`` per pixel and channel of one of two renders ``a``, ``b`` of the same estimate with independent
    samples: ``(a - b)^2 / 2`` (unbiased: ``E (a - b)^2 = 2 Var``), float64 in the shape of ``a``.

    >>> pair_variance(np.array([1.0, 3.0]), np.array([2.0, 0.0])).tolist()
    [0.5, 4.5]
    """
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    return 0.5 * np.square(d)


def _view_without(pred: np.ndarray, ref: np.ndarray, mask: np.ndarray, var: np.ndarray) -> tuple[float, float]:
    """``(MSE of the clipped values, mean Var)`` over one view's ``mask`` pixels and every channel."""
    sq = np.square(np.clip(pred, 0.0, 1.0) - np.clip(ref, 0.0, 1.0))
    return float(sq[mask].mean()), float(np.asarray(var, np.float64)[..., :3][mask].mean())


def without_variance(preds: np.ndarray, refs: np.ndarray, masks: np.ndarray | None, variance: np.ndarray,
                     prefix: str = "psnr_test") -> dict[str, Any]:
    """The medium PSNR of ``preds`` (V, H, W, 3) against ``refs`` less its Monte Carlo ``variance`` (V, H, W, 3), per
    pixel (module docstring). Keys: ``psnr_test_medium_without_mc`` (mean over views; None when unbounded) and its
    ``_per_view``, ``mc_var_test_medium`` (the variance's mean over every view's medium pixels) and ``mc_note``
    (None, or why the figure is unbounded); ``{}`` without ``masks``.

    >>> ref = np.zeros((1, 2, 2, 3)); pred = ref + 0.1               # MSE 1e-2: 20 dB
    >>> s = without_variance(pred, ref, np.ones((1, 2, 2), bool), np.full(ref.shape, 0.009))
    >>> round(s["psnr_test_medium_without_mc"], 6), round(s["mc_var_test_medium"], 6), s["mc_note"]  # 1e-2 - 9e-3
    (30.0, 0.009, None)
    """
    if masks is None:
        return {}
    per_view: list[float | None] = []
    variances, unbounded = [], []
    for v, (p, r, m, var) in enumerate(zip(preds, refs, masks, variance)):
        if not m.any():
            per_view.append(None)
            continue
        mse, mc = _view_without(p[..., :3], r[..., :3], m, var)
        variances.append(mc)
        per_view.append(-10.0 * math.log10(mse - mc) if mse > mc else None)
        if mse <= mc:
            unbounded.append(f"view {v}: Monte Carlo variance {mc:.3g} >= MSE {mse:.3g}")
    note = ("unbounded without its Monte Carlo variance (the variance estimate is all of the error measured: "
            + "; ".join(unbounded) + ")") if unbounded else None
    return {f"{prefix}_medium{WITHOUT_MC}": None if unbounded else mean_of(per_view),
            f"{prefix}_medium{WITHOUT_MC}_per_view": per_view,
            "mc_var_test_medium": float(np.mean(variances)) if variances else None, "mc_note": note}
