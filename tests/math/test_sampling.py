import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.math.sampling import sample_pdf, stratified_t


def _np(x):
    return np.asarray(x, dtype=np.float64)


def test_stratified_samples_lie_in_their_strata_and_deltas_reach_t_f():
    R, N = 50, 16
    rng = np.random.default_rng(0)
    t_n = rng.uniform(0.0, 1.0, R).astype(np.float32)
    t_f = t_n + rng.uniform(0.1, 2.0, R).astype(np.float32)
    u = rng.uniform(0.0, 1.0, R * N).astype(np.float32)
    t, delta = stratified_t(mi.Float(t_n), mi.Float(t_f), N, mi.Float(u))
    t, delta = _np(t).reshape(R, N), _np(delta).reshape(R, N)
    i = np.arange(N)
    lo = t_n[:, None] + i / N * (t_f - t_n)[:, None]
    hi = t_n[:, None] + (i + 1) / N * (t_f - t_n)[:, None]
    assert np.all(t >= lo - 1e-5) and np.all(t <= hi + 1e-5)
    # delta_i = t_{i+1} - t_i, the last one runs to t_f
    np.testing.assert_allclose(delta[:, :-1], np.diff(t, axis=1), atol=1e-5)
    np.testing.assert_allclose(delta[:, -1], t_f - t[:, -1], atol=1e-5)
    np.testing.assert_allclose(t[:, 0] + delta.sum(1), t_f, atol=1e-5)


def test_stratified_is_uniform_within_each_stratum():
    # With random u, t_i is uniform on its stratum: mean at the midpoint, variance (L/N)^2/12.
    R, N = 20000, 4
    u = mi.Float(np.random.default_rng(1).uniform(0, 1, R * N).astype(np.float32))
    t, _ = stratified_t(dr.zeros(mi.Float, R), dr.full(mi.Float, 1.0, R), N, u)
    t = _np(t).reshape(R, N)
    np.testing.assert_allclose(t.mean(0), (np.arange(N) + 0.5) / N, atol=3e-3)
    np.testing.assert_allclose(t.var(0), (1 / N) ** 2 / 12, rtol=0.05)


def test_stratified_rejects_bad_arguments():
    with pytest.raises(ValueError):
        stratified_t(mi.Float(0.0), mi.Float(1.0), 0)
    with pytest.raises(ValueError):
        stratified_t(mi.Float(0.0, 0.0), mi.Float(1.0, 1.0), 4, mi.Float([0.5] * 7))
    with pytest.raises(ValueError, match="seed, midpoint"):
        stratified_t(mi.Float(0.0), mi.Float(1.0), 4, quadrature="trapezoid")


def test_midpoint_rule_places_the_same_samples_and_gives_each_its_whole_stratum():
    R, N = 30, 8
    rng = np.random.default_rng(2)
    t_n = rng.uniform(0.0, 1.0, R).astype(np.float32)
    t_f = t_n + rng.uniform(0.1, 2.0, R).astype(np.float32)
    u = mi.Float(rng.uniform(0.0, 1.0, R * N).astype(np.float32))
    t_seed, _ = stratified_t(mi.Float(t_n), mi.Float(t_f), N, u)
    t, delta = stratified_t(mi.Float(t_n), mi.Float(t_f), N, u, quadrature="midpoint")
    np.testing.assert_array_equal(_np(t), _np(t_seed))
    delta = _np(delta).reshape(R, N)
    np.testing.assert_allclose(delta, np.repeat(((t_f - t_n) / N)[:, None], N, axis=1), rtol=1e-6)
    np.testing.assert_allclose(delta.sum(1), t_f - t_n, rtol=1e-5)  # the strata tile [t_n, t_f]


def test_midpoint_rule_is_second_order_where_the_seed_rule_is_first():
    # sigma(t) = 1 + 2 t on [0, 1] (dense at the exit): tau = 2. The midpoint rule is exact for a
    # linear sigma; the seed's rule is it minus (h/2) sigma(t_{N-1}) = (h/2)(3 - h), first order.
    for n in (8, 32):
        h = 1.0 / n
        errors = {}
        for rule in ("seed", "midpoint"):
            t, delta = stratified_t(mi.Float(0.0), mi.Float(1.0), n, quadrature=rule)
            errors[rule] = float(np.sum((1 + 2 * _np(t)) * _np(delta))) - 2.0
        assert errors["seed"] == pytest.approx(-(h / 2) * (3 - h), rel=1e-4)
        assert abs(errors["midpoint"]) < 1e-5


def _sample_pdf_numpy(bins, weights, u, eps):
    """Reference: NeRF's sample_pdf (piecewise-linear CDF inversion), one ray at a time."""
    out = []
    for b, w, uu in zip(bins, weights, u):
        p = (w + eps) / (w + eps).sum()
        cdf = np.concatenate([[0.0], np.cumsum(p)])
        k = np.clip(np.searchsorted(cdf, uu, side="right") - 1, 0, len(w) - 1)
        frac = np.clip((uu - cdf[k]) / p[k], 0, 1)
        out.append(b[k] + frac * (b[k + 1] - b[k]))
    return np.array(out)


def test_sample_pdf_matches_numpy_reference():
    rng = np.random.default_rng(3)
    R, K, M = 64, 13, 9
    bins = np.sort(rng.uniform(0, 2, (R, K + 1)), axis=1).astype(np.float32)
    weights = (rng.uniform(0, 1, (R, K)) ** 4).astype(np.float32)
    weights[0] = 0.0  # an empty ray falls back to uniform through eps
    u = np.sort(rng.uniform(0, 1, (R, M)), axis=1).astype(np.float32)
    got = sample_pdf(mi.Float(bins.ravel()), mi.Float(weights.ravel()), K, M, mi.Float(u.ravel()), eps=1e-5)
    want = _sample_pdf_numpy(bins.astype(np.float64), weights.astype(np.float64), u.astype(np.float64), 1e-5)
    np.testing.assert_allclose(_np(got).reshape(R, M), want, atol=2e-4)


def test_sample_pdf_concentrates_where_the_weight_is():
    bins = mi.Float(np.linspace(0, 1, 11, dtype=np.float32))
    w = np.zeros(10, np.float32)
    w[7] = 1.0
    t = _np(sample_pdf(bins, mi.Float(w), 10, 32, eps=1e-6))
    assert np.all((t >= 0.7 - 1e-4) & (t <= 0.8 + 1e-4))
    assert np.all(np.diff(t) >= 0)
