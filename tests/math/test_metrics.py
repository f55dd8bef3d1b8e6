"""Image and grid metrics against closed forms, known noise levels and skimage reference values."""

import mitsnerf  # noqa: F401  (sets up LLVM before anything imports drjit)

import math

import numpy as np
import pytest

from mitsnerf.math.color import linear_to_srgb, srgb_to_linear
from mitsnerf.math.metrics import density_error, mse, psnr, ssim


def _structured_pair():
    """Deterministic (14, 12, 3) images; their SSIM was computed once with skimage 0.26.0."""
    i, j, c = np.meshgrid(np.arange(14), np.arange(12), np.arange(3), indexing="ij")
    a = ((7 * i + 3 * j + 5 * c) % 11) / 10.0
    b = np.abs(np.sin(0.7 * i + 0.3 * j * j + c)) * 0.8 + 0.1 * a
    return a, b


def _noisy(sigma, shape=(256, 256, 3), seed=0):
    rng = np.random.default_rng(seed)
    clean = rng.uniform(0.2, 0.8, size=shape)
    return clean, clean + rng.normal(0.0, sigma, size=shape)


# --- colour -------------------------------------------------------------------------------------

def test_srgb_round_trip_and_knee_continuity():
    x = np.linspace(-0.1, 1.5, 1001)
    assert np.allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-12)
    knee = 0.0031308
    assert abs(linear_to_srgb(knee - 1e-12) - linear_to_srgb(knee + 1e-12)) < 1e-7
    assert linear_to_srgb(np.float32(0.5)).dtype == np.float32


# --- mse / psnr ---------------------------------------------------------------------------------

def test_psnr_of_known_noise_level():
    clean, noisy = _noisy(0.01)
    assert psnr(clean, noisy) == pytest.approx(40.0, abs=0.1)
    clean, noisy = _noisy(0.1, seed=1)
    assert psnr(clean, noisy) == pytest.approx(20.0, abs=0.1)
    assert psnr(2 * clean, 2 * noisy, max_val=2.0) == pytest.approx(psnr(clean, noisy), abs=1e-9)


def test_psnr_identical_is_inf():
    a = np.random.default_rng(0).random((4, 5, 3))
    assert psnr(a, a) == math.inf
    assert mse(a, a) == 0.0


def test_masked_psnr_counts_only_selected_pixels():
    a = np.zeros((4, 6, 3))
    b = np.zeros((4, 6, 3))
    b[:, :3] = 0.1   # left half off by 0.1 -> mse 0.01 -> 20 dB
    b[:, 3:] = 0.5   # right half far off, masked out
    mask = np.zeros((4, 6), dtype=bool)
    mask[:, :3] = True
    assert psnr(a, b, mask=mask) == pytest.approx(20.0, abs=1e-9)
    assert mse(a, b) == pytest.approx(0.5 * (0.01 + 0.25))
    with pytest.raises(ValueError, match="no pixels"):
        psnr(a, b, mask=np.zeros((4, 6), dtype=bool))
    with pytest.raises(ValueError, match="mask shape"):
        psnr(a, b, mask=np.ones((6, 4), dtype=bool))


def test_batches_give_one_value_per_view():
    a = np.zeros((2, 3, 3, 1))
    b = np.stack([np.full((3, 3, 1), 0.1), np.full((3, 3, 1), 0.01)])
    assert np.allclose(psnr(a, b), [20.0, 40.0])
    mask = np.ones((2, 3, 3), dtype=bool)
    assert np.allclose(mse(a, b, mask=mask), [1e-2, 1e-4])
    with pytest.raises(ValueError, match="differ in shape"):
        mse(a, b[:1])


# --- ssim ---------------------------------------------------------------------------------------

def test_ssim_identical_is_one():
    a = np.random.default_rng(0).random((20, 17, 3))
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)


def test_ssim_of_constant_images_has_closed_form():
    c1 = (0.01 * 1.0) ** 2
    for p, q in [(0.5, 0.4), (0.9, 0.1), (0.0, 0.2)]:
        expected = (2 * p * q + c1) / (p * p + q * q + c1)
        assert ssim(np.full((13, 12, 3), p), np.full((13, 12, 3), q)) == pytest.approx(expected, rel=1e-10)


def test_ssim_matches_skimage_reference():
    a, b = _structured_pair()
    # skimage.metrics.structural_similarity(a, b, channel_axis=-1, gaussian_weights=True, sigma=1.5,
    #                                       use_sample_covariance=False, data_range=1.0)
    assert ssim(a, b) == pytest.approx(0.07635982638272061, abs=1e-12)
    assert ssim(a, 0.5 * a + 0.2) == pytest.approx(0.7970244277850261, abs=1e-12)


def test_ssim_matches_direct_2d_window_sum():
    """Independent of the separable filter: explicit 11x11 weighted sums at each valid pixel."""
    a, b = _structured_pair()
    a, b = a[..., :1], b[..., :1]
    g = np.exp(-0.5 * ((np.arange(11) - 5) / 1.5) ** 2)
    w2 = np.outer(g, g) / np.outer(g, g).sum()
    c1, c2 = 0.01**2, 0.03**2
    vals = []
    for r in range(a.shape[0] - 10):
        for c in range(a.shape[1] - 10):
            pa, pb = a[r : r + 11, c : c + 11, 0], b[r : r + 11, c : c + 11, 0]
            ma, mb = (w2 * pa).sum(), (w2 * pb).sum()
            va, vb = (w2 * pa * pa).sum() - ma**2, (w2 * pb * pb).sum() - mb**2
            cov = (w2 * pa * pb).sum() - ma * mb
            vals.append((2 * ma * mb + c1) * (2 * cov + c2) / ((ma**2 + mb**2 + c1) * (va + vb + c2)))
    assert ssim(a, b) == pytest.approx(np.mean(vals), abs=1e-12)


def test_ssim_decreases_with_noise():
    values = [ssim(*_noisy(s, shape=(48, 48, 3), seed=3)) for s in (0.0, 0.01, 0.05, 0.2)]
    assert values[0] == pytest.approx(1.0)
    assert all(x > y for x, y in zip(values, values[1:]))
    assert values[-1] < 0.7  # noise variance 0.04 against signal variance 0.03


def test_ssim_rejects_small_images():
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(np.zeros((10, 20, 3)), np.zeros((10, 20, 3)))


# --- density ------------------------------------------------------------------------------------

def test_density_error_of_true_and_scaled_grid():
    t = np.random.default_rng(0).uniform(0.0, 5.0, size=(6, 6, 6))
    e = density_error(t, t)
    assert e["rel_l1"] == 0.0 and e["rel_l2"] == 0.0 and e["psnr"] == math.inf
    e = density_error(0.8 * t, t)
    assert e["rel_l1"] == pytest.approx(0.2, rel=1e-12)
    assert e["rel_l2"] == pytest.approx(0.2, rel=1e-12)
    expected_psnr = 10 * math.log10(t.max() ** 2 / (0.04 * np.mean(t * t)))
    assert e["psnr"] == pytest.approx(expected_psnr, rel=1e-12)
    with pytest.raises(ValueError, match="all zero"):
        density_error(t, np.zeros_like(t))
