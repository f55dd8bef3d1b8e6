"""The oracle against volpath on the same rays: the multiple-scattering generalisation of single scattering.

:class:`PointSource` is a field whose colour is ``J`` estimated by Mitsuba at exactly the points
the integrator asks for (no grid, so no interpolation error): ``J(x) = albedo(x) (Lbar_mc(x) +
Lbar_delta(x))`` (:mod:`mitsnerf.oracle.source`), each point with its own independent volpath
samples. Rendered by :func:`mitsnerf.render.volume.render_rays` it must equal volpath's radiance
along every ray up to the quadrature's error and the Monte Carlo noise of both sides:

    C_p = sum_i w_i J_i + T_N bg,        Var(C_p) = sum_i w_i^2 se_i^2      (w_i = T_i (1 - e^{-sigma_i delta_i}))

because the ``J_i`` are independent. :func:`agreement` then tests, per pixel and channel,
``z = (C_p - m_p) / sqrt(Var(C_p) + s_p^2 / n)`` against volpath's mean ``m_p`` and per-sample
variance ``s_p^2`` of ``n`` samples (Bonferroni over all pixel tests at a family-wise ``alpha``),
and each channel's image mean (what sees a small error shared by all pixels).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.math.box import Box
from mitsnerf.math.composite import is_chromatic, weights
from mitsnerf.math.rays import host
from mitsnerf.oracle.source import delta_irradiance, delta_radiance, mean_radiance, phase_weighted_radiance
from mitsnerf.render.volume import render_rays, sample_rays
from mitsnerf.scene.lights import delta_lights, toward_light

ROUNDING = 1e-5
"""Relative rounding allowed between two float32 renders (added to the standard error)."""


@dataclass(frozen=True)
class PointSource:
    """Field ``(x, d) -> (J(x), sigma_t(x))`` with ``J`` estimated by volpath at the points themselves.

    ``scene``: the Mitsuba scene with volpath at :func:`~mitsnerf.oracle.source.inner_max_depth`
    (None: nothing in-scatters, ``J = 0``); ``medium``: a :class:`~mitsnerf.fields.grid.GridField`
    of the true ``sigma_t`` with the albedo as colour; ``lights``: the spec's lights (the delta ones
    count); ``spp`` directions per point; ``m_light`` midpoints per march to a light. Points where
    ``sigma_t = 0`` get ``J = 0`` (their weight is zero). The estimate is deterministic in ``seed``
    and the points; the last one is kept, so :func:`render_with_variance` pays for it once.
    """

    scene: Any
    medium: Any
    lights: Sequence[Any]
    box: Box
    spp: int
    m_light: int
    seed: int = 0
    g: float = 0.0
    """Henyey-Greenstein's ``g`` of the medium (0: isotropic, ``J(x)``; else the view-dependent colour
    ``c(x, d) = albedo [int p(w . d) L(x, w) dw + sum_l p(w_l . d) E_l T_l]``, :mod:`mitsnerf.math.phase`)."""
    _last: dict = field(default_factory=dict, compare=False, repr=False)

    def estimate(self, x, d=None) -> tuple[Any, np.ndarray, Any]:
        """``(J Array3f (M,), se of J float64 (M, 3), sigma_t Float (M,) (Array3f: chromatic))`` at points ``x`` seen
        along ``d`` (Array3f (M,); needed when ``g != 0``)."""
        import mitsuba as mi

        pts = np.stack([np.asarray(c, dtype=np.float64) for c in x], axis=-1)
        dirs = None if self.g == 0.0 else np.stack([np.asarray(c, dtype=np.float64) for c in d], axis=-1)
        key = pts.tobytes() + (b"" if dirs is None else dirs.tobytes())
        if self._last.get("key") != key:
            albedo, sigma = self.medium(x, x)
            alb = np.stack([np.asarray(c, dtype=np.float64) for c in albedo], axis=-1)
            positive = host(sigma) > 0
            active = np.asarray(positive.any(axis=-1) if positive.ndim == 2 else positive)  # chromatic: any channel
            lbar, se = np.zeros_like(pts), np.zeros_like(pts)
            if self.scene is not None and active.any():
                lbar[active], se[active] = self._in_scattered(pts[active], None if dirs is None else dirs[active])
            self._last.clear()
            self._last.update(key=key, J=alb * lbar, se=alb * se)
        J = self._last["J"]
        return mi.Array3f(*(J[:, k].astype(np.float32) for k in range(3))), self._last["se"], self.medium.density(x)

    def _in_scattered(self, pts: np.ndarray, dirs: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The radiance scattered towards the camera per unit albedo, and its standard error (M, 3)."""
        if dirs is None:
            lbar, se = mean_radiance(self.scene, pts, self.spp, self.seed)
            return lbar + delta_radiance(self.lights, self.medium.density, pts, self.box, self.m_light), se
        from mitsnerf.math.phase import hg, scattering_cosine

        mean, se = phase_weighted_radiance(self.scene, pts, dirs, self.spp, self.g, self.seed)
        irradiance = delta_irradiance(self.lights, self.medium.density, pts, self.box, self.m_light)
        for j, light in enumerate(delta_lights(self.lights)):
            mean += hg(scattering_cosine(toward_light(light, pts), dirs), self.g)[:, None] * irradiance[:, j]
        return mean, se

    def __call__(self, x, d):
        J, _, sigma = self.estimate(x, d)
        return J, sigma

    def forget(self) -> None:
        """Drop the kept estimate: the next one is computed afresh (by the code as it is now)."""
        self._last.clear()


def render_with_variance(source: PointSource, o, d, n_samples: int, box: Box,
                         background=None) -> tuple[np.ndarray, np.ndarray]:
    """``(C (R, 3), Var(C) (R, 3))`` float64 of rays ``o``, ``d`` (Array3f (R,)): ``render_rays`` with
    ``source`` at the stratum midpoints, and ``sum_i w_i^2 se_i^2`` on the same samples."""
    source.forget()  # estimated on these rays by the code as it is now (a bug planted since must show)
    with dr.suspend_grad():
        comp = render_rays(source, o, d, n_samples, box=box, background=background)
        s, _ = sample_rays(o, d, n_samples, box)
        _, se, sigma = source.estimate(s.x, s.d)
        w, _ = weights(sigma, s.delta, n_samples)
        w_k = [w[k] for k in range(3)] if is_chromatic(w) else [w] * 3  # chromatic: each channel's weights
        var = [np.asarray(dr.block_sum(w_k[k] * w_k[k] * type(w_k[k])(se[:, k] ** 2), n_samples), dtype=np.float64)
               for k in range(3)]
    mean = np.stack([np.asarray(c, dtype=np.float64) for c in comp.rgb], axis=-1)
    return mean, np.stack(var, axis=-1)


@dataclass(frozen=True)
class Agreement:
    """z per pixel and channel, z of each channel's image mean, and the decision at ``alpha``."""

    z: np.ndarray
    z_means: np.ndarray
    critical: float
    """|z| above which a pixel test rejects (Bonferroni over every pixel and channel)."""
    critical_mean: float
    rel_mean_error: np.ndarray
    """Per channel: |sum_p (C_p - m_p)| / sum_p |m_p|."""

    @property
    def rejected(self) -> int:
        return int((np.abs(self.z) > self.critical).sum())

    @property
    def passed(self) -> bool:
        return self.rejected == 0 and bool(np.all(np.abs(self.z_means) <= self.critical_mean))

    def summary(self) -> str:
        return (f"max |z| {np.abs(self.z).max():.2f} (critical {self.critical:.2f}), {self.rejected}/{self.z.size} "
                f"rejected; channel-mean z {np.array2string(self.z_means, precision=2)} (critical "
                f"{self.critical_mean:.2f}); rel. mean error {self.rel_mean_error.max():.2e}")


def agreement(mean: np.ndarray, var: np.ndarray, ref_mean: np.ndarray, ref_var: np.ndarray, ref_n: int,
              alpha: float = 1e-3) -> Agreement:
    """z-tests of an image ``mean`` with variance ``var`` against ``ref_n`` volpath samples per pixel
    (``ref_mean``, per-sample ``ref_var``), all arrays ``(..., 3)``; half of ``alpha`` to the pixel
    tests (Bonferroni), half to the three channel means.

    >>> rng = np.random.default_rng(0); m = np.full((8, 8, 3), 0.5)
    >>> agreement(m + 0.01 * rng.standard_normal(m.shape), np.full(m.shape, 1e-4), m, np.zeros(m.shape), 100).passed
    True
    >>> agreement(m + 0.02, np.full(m.shape, 1e-4), m, np.zeros(m.shape), 100).passed   # 2 sigma everywhere
    False
    """
    diff = np.asarray(mean, np.float64) - np.asarray(ref_mean, np.float64)
    # Both sides render in float32: a pixel without noise on either side (rays that miss the medium
    # see the background exactly) differs by rounding, ~1e-7 relative; ROUNDING keeps it a z of ~0.01.
    rounding = ROUNDING * np.maximum(np.abs(mean), np.abs(ref_mean))
    se2 = np.maximum(var, 0.0) + np.maximum(ref_var, 0.0) / ref_n + rounding**2
    axes = tuple(range(diff.ndim - 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(se2 > 0, diff / np.sqrt(se2), np.where(diff == 0, 0.0, np.inf))
        z_means = diff.sum(axis=axes) / np.sqrt(se2.sum(axis=axes))
        rel = np.abs(diff.sum(axis=axes)) / np.abs(ref_mean).sum(axis=axes)
    normal = NormalDist()
    critical = normal.inv_cdf(1.0 - alpha / 4.0 / z.size)
    critical_mean = normal.inv_cdf(1.0 - alpha / 4.0 / z_means.size)
    return Agreement(z, np.nan_to_num(z_means), critical, critical_mean, np.nan_to_num(rel))
