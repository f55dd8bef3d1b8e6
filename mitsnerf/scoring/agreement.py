"""Do two estimators of the same images agree in expectation? The statistical tests of dataset verification.

**The medium alone** (:func:`transmittance_agreement`): the alpha of the dataset's renders of the
medium without the environment against the exact ``1 - T`` they estimate, a z-test per view with the
exact binomial variance; (:func:`composite_agreement`) those renders composited over the environment
against full images rendered on their own, and (:func:`view_agreement`) any two pairs of independent
renders of the same views, per view: statistical tests on two independent pairs of renders. A family of
per-view tests is held at one family-wise error rate (:func:`critical_z`), a dispersion ratio read as a
z-score with its skew taken into account (:func:`ratio_z`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mitsnerf.data.images import over


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
    with ``C_1``, ``C_2`` the two composites (:func:`mitsnerf.data.images.over`)::

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
