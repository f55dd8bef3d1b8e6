import numpy as np
import pytest

from mitsnerf.verify.stats import (bonferroni, compare, correlation_z, decide, holm, ks_uniform, two_sided_p,
                                   weighted_holm, z_test)


def _holm_by_definition(p, alpha):
    """Holm as stated: reject H_(1..k-1), k the first sorted index with p_(k) > alpha / (m - k + 1)."""
    order = np.argsort(p, kind="stable")
    reject = np.zeros(len(p), bool)
    for rank, i in enumerate(order):
        if p[i] > alpha / (len(p) - rank):
            break
        reject[i] = True
    return reject


def test_holm_matches_its_definition_and_is_between_bonferroni_and_unadjusted():
    rng = np.random.default_rng(0)
    for _ in range(200):
        p = rng.uniform(0, 0.05, rng.integers(1, 12)) ** rng.uniform(0.5, 3)
        got = holm(p, 0.05)
        np.testing.assert_array_equal(got, _holm_by_definition(p, 0.05))
        assert np.all(bonferroni(p, 0.05) <= got) and np.all(got <= (p <= 0.05))


def _weighted_holm_by_definition(p, w, alpha):
    """Reject in order of p/w while p_(k) <= alpha w_(k) / (sum of the weights not yet rejected)."""
    order = np.argsort(np.asarray(p) / w, kind="stable")
    reject = np.zeros(len(p), bool)
    remaining = float(np.sum(w))
    for i in order:
        if p[i] > alpha * w[i] / remaining:
            break
        reject[i] = True
        remaining -= w[i]
    return reject


def test_weighted_holm_matches_its_definition_and_equal_weights_are_holm():
    rng = np.random.default_rng(3)
    for _ in range(200):
        m = rng.integers(1, 12)
        p = rng.uniform(0, 0.05, m) ** rng.uniform(0.5, 3)
        w = rng.uniform(0.1, 2.0, m)
        np.testing.assert_array_equal(weighted_holm(p, w, 0.05), _weighted_holm_by_definition(p, w, 0.05))
        np.testing.assert_array_equal(weighted_holm(p, np.full(m, 0.3), 0.05), holm(p, 0.05))
    with pytest.raises(ValueError, match="positive"):
        weighted_holm([0.1, 0.2], [1.0, 0.0], 0.05)


def test_one_family_holds_its_alpha_over_pixels_and_channel_means_of_several_comparisons():
    # Two comparisons per family (as a scenario with two quadrature rules); under H0 the whole
    # family rejects anything in at most alpha of the runs.
    rng = np.random.default_rng(4)
    n, alpha, runs = 256, 0.05, 400
    truth = rng.uniform(0.2, 1.0, (6, 6, 3))
    false_alarms = 0
    for _ in range(runs):
        tests = []
        for _ in range(2):
            samples = truth + 0.5 * truth * rng.standard_normal((n, 6, 6, 3))
            tests.append(z_test(truth, samples.mean(0), samples.var(0, ddof=1), n))
        false_alarms += not decide(tests, alpha).passed
    assert false_alarms / runs <= alpha + 3 * np.sqrt(alpha * (1 - alpha) / runs)


def test_a_family_counts_every_test_and_a_measured_variance_widens_the_errors():
    m = np.full((2, 2, 3), 0.5)
    v = np.full_like(m, 0.25)
    f = decide([z_test(m, m, v, 64), z_test(m, m, v, 64, label="b")], 0.01)
    assert f.n_tests == 2 * (12 + 3) and f.n_pixel_tests == 24 and f.passed
    narrow = z_test(m + 0.05, m, v, 64)
    wide = z_test(m + 0.05, m, v, 64, measured_var=np.full_like(m, 0.25), measured_n=16)
    assert abs(wide.z_mean) < abs(narrow.z_mean)
    with pytest.raises(ValueError, match="measured_n"):
        z_test(m, m, v, 64, measured_var=v)


def test_ks_and_correlation_tests_hold_their_level_and_see_broken_jitter():
    rng = np.random.default_rng(5)
    p = np.array([ks_uniform(rng.random(300))[1] for _ in range(500)])
    assert np.mean(p < 0.05) <= 0.05 + 3 * np.sqrt(0.05 * 0.95 / 500)
    z = np.array([correlation_z(rng.random(400), rng.random(400)) for _ in range(500)])
    assert np.mean(np.abs(z) > 1.96) <= 0.05 + 3 * np.sqrt(0.05 * 0.95 / 500)
    assert ks_uniform(0.5 * rng.random(300))[1] < 1e-10  # only the lower half of each stratum
    x = rng.random(400)
    assert correlation_z(x, x) == pytest.approx(np.sqrt(400))
    assert correlation_z(np.zeros(10), x[:10]) == np.inf


def test_compare_holds_the_false_alarm_rate_and_sees_small_shared_biases():
    # 300 images of 8x8x3 pixels, each pixel the mean of n samples of a known distribution.
    rng = np.random.default_rng(1)
    n, alpha = 256, 0.05
    truth = rng.uniform(0.2, 1.0, (8, 8, 3))
    sd = 0.5 * truth
    false_alarms = detected = 0
    for _ in range(300):
        samples = truth + sd * rng.standard_normal((n, 8, 8, 3))
        mean, var = samples.mean(0), samples.var(0, ddof=1)
        false_alarms += not compare(truth, mean, var, n, alpha).passed
        # A 1% bias of every pixel: 0.3 se per pixel, ~2.7 se in each channel's image mean.
        detected += not compare(truth * 1.01, mean, var, n, alpha).passed
    assert false_alarms / 300 <= alpha + 3 * np.sqrt(alpha * (1 - alpha) / 300)  # one family: at most alpha
    assert detected / 300 >= 0.5


def test_a_pixel_whose_samples_were_all_equal_is_not_a_certain_rejection():
    # All n samples escaped (0/1 estimator at T = 0.9995): variance 0, but an error of a fraction
    # of one sample's worth must not reject, while a large one still does.
    n = 1024
    mean, var = np.ones((1, 1, 3)), np.zeros((1, 1, 3))
    assert compare(np.full((1, 1, 3), 0.9995), mean, var, n, 0.01).passed
    assert not compare(np.full((1, 1, 3), 0.99), mean, var, n, 0.01).passed


def test_compare_rejects_mismatched_shapes_and_too_few_samples():
    a = np.zeros((2, 2, 3))
    with pytest.raises(ValueError, match="shapes differ"):
        compare(a, a[:1], a, 16, 0.01)
    with pytest.raises(ValueError, match="at least 2"):
        compare(a, a, a, 1, 0.01)


def test_two_sided_p_values():
    np.testing.assert_allclose(two_sided_p([0.0, 1.959964, 3.290527]), [1.0, 0.05, 0.001], rtol=1e-5)
