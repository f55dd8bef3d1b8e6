"""The training sampler's jitter, checked statistically (the ``sampler_jitter`` case).

Training draws ``u`` for each step from that step's generator
(:func:`mitsnerf.train.schedule.step_rng`, ``rng.random(Float, R * N)``) and places samples with
:func:`mitsnerf.render.volume.sample_rays`. For the verification camera's rays through the box,
with ``t_n, t_f`` from the float64 numpy slab test (``Box.intersect_numpy``, not the sampler's),
``h = (t_f - t_n) / N`` and the fraction ``f_i = (t_i - t_n) / h - i`` of the way through its
stratum:

Exact (float32 tolerance): every ``f_i`` in ``[0, 1]``; the seed's rule's intervals
``delta_i = t_{i+1} - t_i`` (last ``t_f - t_{N-1}``); the midpoint rule's ``delta_i = h``.

Statistical, one Holm family at ``alpha``:

- the ``f`` of one step are ``U[0, 1)``: Kolmogorov-Smirnov over all samples;
- the same for every stratum index: ``z_i = (mean_r f_ri - 1/2) / sqrt(1 / (12 R))``;
- independent within a ray: ``r sqrt(M)`` of the pairs ``(f_i, f_{i+1})``;
- independent across steps: ``r sqrt(M)`` of ``(f_i at step a, f_i at step b)``.

Samples all at their strata's left edges (jitter ignored) fail the first with ``D = 1``; the
same jitter at every step fails the last with ``r = 1``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from mitsnerf.math.box import UNIT_BOX
from mitsnerf.verify.cases import JitterCase, Quality
from mitsnerf.verify.stats import correlation_z, holm, ks_uniform, two_sided_p


@dataclass(frozen=True)
class JitterResult:
    """The statistics of :func:`check_jitter`, the tests Holm rejected and the exact checks that failed."""

    n_rays: int
    n_samples: int
    ks_d: float
    ks_p: float
    worst_stratum_z: float
    neighbour_z: float
    steps_z: float
    n_tests: int
    rejected: tuple[str, ...]
    max_interval_error: float
    failures: tuple[str, ...]
    seconds: float

    @property
    def passed(self) -> bool:
        return not self.failures and not self.rejected


def training_jitter(seed: int, step: int, size: int):
    """``u`` (Float (size,)) exactly as the training loop draws it at ``step``."""
    import mitsuba as mi

    from mitsnerf.train.schedule import step_rng

    return step_rng(seed, step).random(mi.Float, size)


def _samples(o: np.ndarray, d: np.ndarray, n: int, u, quadrature: str) -> tuple[np.ndarray, np.ndarray]:
    """``(t, delta)`` (R, N) of the package's sampler, float64 copies."""
    import mitsuba as mi

    from mitsnerf.render.volume import sample_rays

    s, _ = sample_rays(mi.Array3f(*o.astype(np.float32).T), mi.Array3f(*d.astype(np.float32).T), n, UNIT_BOX, u,
                       quadrature)
    shape = (len(o), n)
    return np.asarray(s.t, dtype=np.float64).reshape(shape), np.asarray(s.delta, dtype=np.float64).reshape(shape)


def _interval_errors(t, delta, delta_mid, t_n, t_f, n) -> dict[str, float]:
    """Largest deviations (in units of the ray's span) of the exact properties of the samples."""
    span = (t_f - t_n)[:, None]
    h = span / n
    f = (t - t_n[:, None]) / h - np.arange(n)
    seed = np.concatenate([t[:, 1:], t_f[:, None]], axis=1) - t
    return {
        "sample outside its stratum": float(np.max(np.maximum(-f, f - 1.0) * h / span)),
        "seed delta != t_{i+1} - t_i": float(np.max(np.abs(delta - seed) / span)),
        "midpoint delta != h": float(np.max(np.abs(delta_mid - h) / span)),
    }


def check_jitter(case: JitterCase, quality: Quality) -> JitterResult:
    """Run the exact and statistical checks of the module docstring."""
    start = time.perf_counter()
    o, d = quality.camera().pixel_rays()
    t_n, t_f, _ = UNIT_BOX.intersect_numpy(o, d)
    hit = t_f - t_n > 0.1  # rays with a span of float32 resolution to spare
    o, d, t_n, t_f = o[hit], d[hit], t_n[hit], t_f[hit]
    n = quality.n_samples
    fractions = []
    errors: dict[str, float] = {}
    for step in case.steps:
        u = training_jitter(quality.seed, step, len(o) * n)
        t, delta = _samples(o, d, n, u, "seed")
        _, delta_mid = _samples(o, d, n, u, "midpoint")
        for key, value in _interval_errors(t, delta, delta_mid, t_n, t_f, n).items():
            errors[key] = max(errors.get(key, 0.0), value)
        fractions.append(np.clip((t - t_n[:, None]) / ((t_f - t_n)[:, None] / n) - np.arange(n), 0.0, 1.0))
    failures = [f"{key}: {value:.2e} of the span > {case.rtol:g}" for key, value in errors.items() if value > case.rtol]

    f0, f1 = fractions
    ks_d, ks_p = ks_uniform(f0)
    stratum_z = (f0.mean(axis=0) - 0.5) / np.sqrt(1.0 / (12.0 * len(f0)))
    neighbour_z = correlation_z(f0[:, :-1], f0[:, 1:])
    steps_z = correlation_z(f0, f1)
    labels = ["KS uniform"] + [f"stratum {i} mean" for i in range(n)] + ["neighbours independent", "steps independent"]
    p = np.concatenate([[ks_p], np.ravel(two_sided_p(stratum_z)), [two_sided_p(neighbour_z), two_sided_p(steps_z)]])
    rejected = tuple(label for label, r in zip(labels, holm(p, quality.alpha)) if r)
    worst = float(stratum_z[np.argmax(np.abs(stratum_z))])
    return JitterResult(len(o), n, ks_d, ks_p, worst, neighbour_z, steps_z, len(p), rejected,
                        max(errors.values()), tuple(failures), time.perf_counter() - start)
