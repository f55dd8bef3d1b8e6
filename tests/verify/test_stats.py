import numpy as np
import pytest

from mitsnerf.verify.stats import bonferroni, compare, holm, two_sided_p


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
    assert false_alarms / 300 <= 2 * alpha  # Holm and the channel means together: at most ~alpha
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
