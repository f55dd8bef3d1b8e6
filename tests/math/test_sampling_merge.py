"""Hierarchical sampling's merge of coarse and fine distances, and the deltas of the merged set."""

import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.math.sampling import deltas_from_sorted_t, merge_sorted_t, sample_pdf, stratified_t


def _np(x):
    return np.asarray(x, dtype=np.float64)


def test_merge_and_deltas_match_numpy_sort_and_diff():
    rng = np.random.default_rng(5)
    R, NA, NB = 40, 7, 12
    t_n = rng.uniform(0, 1, R).astype(np.float32)
    t_f = (t_n + rng.uniform(0.2, 2, R)).astype(np.float32)
    t_a, _ = stratified_t(mi.Float(t_n), mi.Float(t_f), NA, mi.Float(rng.uniform(0, 1, R * NA).astype(np.float32)))
    a = _np(t_a).reshape(R, NA)
    b = np.sort(rng.uniform(t_n[:, None], t_f[:, None], (R, NB)), axis=1).astype(np.float32)
    b[3, 2:5] = a[3, 1]  # ties between the two sets and within one set
    merged = merge_sorted_t(t_a, NA, mi.Float(b.ravel()), NB)
    want = np.sort(np.concatenate([a, b], axis=1), axis=1)
    np.testing.assert_array_equal(_np(merged).reshape(R, NA + NB), want)

    delta = _np(deltas_from_sorted_t(merged, mi.Float(t_f), NA + NB)).reshape(R, NA + NB)
    want_delta = np.concatenate([np.diff(want, axis=1), t_f[:, None] - want[:, -1:]], axis=1)
    np.testing.assert_allclose(delta, want_delta, atol=1e-6)
    assert np.all(delta >= 0)
    np.testing.assert_allclose(want[:, 0] + delta.sum(1), t_f, atol=1e-5)


def test_importance_samples_merged_with_coarse_ones_stay_sorted():
    # The NeRF path: coarse strata, weights on their intervals, inverse-CDF samples, merge.
    R, NC, NF = 16, 8, 16
    rng = np.random.default_rng(2)
    t_n, t_f = mi.Float(np.zeros(R, np.float32)), mi.Float(np.full(R, 2.0, np.float32))
    t_c, delta_c = stratified_t(t_n, t_f, NC, mi.Float(rng.uniform(0, 1, R * NC).astype(np.float32)))
    edges = np.concatenate([_np(t_c).reshape(R, NC), np.full((R, 1), 2.0)], axis=1).astype(np.float32)
    w = rng.uniform(0, 1, (R, NC)).astype(np.float32) ** 3
    u = ((np.arange(NF) + rng.uniform(0, 1, (R, NF))) / NF).astype(np.float32)
    t_fine = sample_pdf(mi.Float(edges.ravel()), mi.Float(w.ravel()), NC, NF, mi.Float(u.ravel()))
    merged = _np(merge_sorted_t(t_c, NC, t_fine, NF)).reshape(R, NC + NF)
    assert np.all(np.diff(merged, axis=1) >= 0)
    assert np.all((merged >= 0) & (merged <= 2.0))


def test_merge_rejects_mismatched_sizes():
    with pytest.raises(ValueError):
        merge_sorted_t(mi.Float(0.1, 0.2), 2, mi.Float(0.3, 0.4, 0.5), 2)
