"""Scores against known values: image scores in both encodings, density and optical-depth errors, masks, the budget."""

from __future__ import annotations

import numpy as np
import pytest

from mitsnerf.fields.grid import GridField
from mitsnerf.math.box import UNIT_BOX, Box
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.math.color import linear_to_srgb
from mitsnerf.math.metrics import psnr
from mitsnerf.scoring.density import NO_DENSITY, density_scores, optical_depth_scores, ray_optical_depths
from mitsnerf.scoring.images import error_budget, image_scores
from mitsnerf.scoring.medium import medium_masks


def grid_density(sigma_t, scale=1.0):
    """The density of a given grid (scaled by ``scale``), as a trained model's field would give it."""
    return GridField.from_arrays(np.asarray(sigma_t, np.float32) * scale, UNIT_BOX).density


def _cameras():
    return [Camera.from_fov(look_at(np.array(p, float)), 12, 12, 40.0) for p in ((0, 0, 2.2), (2.0, 0.5, 0.8))]


def test_image_scores_of_a_known_noise_level_in_both_encodings():
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.2, 0.8, size=(2, 16, 16, 3))
    noisy = ref + rng.choice([-0.01, 0.01], size=ref.shape)  # mse exactly 1e-4
    s = image_scores(noisy, ref)
    assert s["psnr_test"] == pytest.approx(40.0) and s["psnr_test_per_view"] == pytest.approx([40.0, 40.0])
    expected = np.mean(psnr(linear_to_srgb(noisy), linear_to_srgb(ref)))  # sRGB compresses [0.2, 0.8] on average
    assert s["psnr_test_srgb"] == pytest.approx(expected) and s["psnr_test_srgb"] > 40
    same = image_scores(ref, ref)
    assert same["ssim_test"] == pytest.approx(1.0) and same["ssim_test_srgb"] == pytest.approx(1.0)
    assert same["psnr_test"] is None  # inf is not JSON; tables show '-'


def test_image_scores_clip_and_mask_the_medium():
    ref = np.full((2, 12, 12, 3), 0.5)
    pred = ref.copy()
    pred[0, :6] += 0.1  # the error lies in the top half of view 0
    pred[1] = 5.0       # clipped to 1 before scoring
    masks = np.zeros((2, 12, 12), bool)
    masks[0, :6] = True
    s = image_scores(pred, ref, masks)
    assert s["psnr_test_medium_per_view"][0] == pytest.approx(20.0)
    assert s["psnr_test_per_view"][0] == pytest.approx(20.0 + 10 * np.log10(2))
    assert s["psnr_test_per_view"][1] == pytest.approx(-20 * np.log10(0.5))
    assert s["psnr_test_medium_per_view"][1] is None and s["psnr_test_medium"] == pytest.approx(20.0)


def test_density_error_of_the_true_grid_is_zero(blob_grid):
    scores, slices = density_scores(grid_density(blob_grid), blob_grid, UNIT_BOX)
    assert scores["density_rel_l1"] < 1e-5 and scores["density_rel_l2"] < 1e-5 and scores["density_psnr"] > 90
    np.testing.assert_allclose(slices["learned_z"], slices["true_z"], atol=1e-4)
    tau = optical_depth_scores(grid_density(blob_grid), blob_grid, UNIT_BOX, _cameras(), n_samples=32)
    assert tau["tau_rel_l1"] < 1e-5 and tau["transmittance_mae"] < 1e-6 and tau["tau_rays"] > 0


def test_a_scaled_density_has_relative_error_of_the_scale(blob_grid):
    scores, _ = density_scores(grid_density(blob_grid, 1.5), blob_grid, UNIT_BOX, resolution=16)
    assert scores["density_rel_l1"] == pytest.approx(0.5, rel=1e-4) and scores["density_resolution"] == 16
    assert scores["density_rel_mass"] == pytest.approx(0.5, rel=1e-4)  # signed: more mass than the truth
    shrunk, _ = density_scores(grid_density(blob_grid, 0.75), blob_grid, UNIT_BOX, resolution=16)
    assert shrunk["density_rel_mass"] == pytest.approx(-0.25, rel=1e-4)
    tau = optical_depth_scores(grid_density(blob_grid, 1.5), blob_grid, UNIT_BOX, _cameras(), n_samples=32)
    assert tau["tau_rel_l1"] == pytest.approx(0.5, rel=1e-4)


def test_optical_depth_of_a_homogeneous_box_is_its_chord():
    grid = np.full((4, 4, 4), 2.0, np.float32)
    o = np.array([[0.0, 0.0, -2.0], [0.3, -2.0, 0.1], [0.0, 0.0, 3.0], [2.0, 2.0, 2.0]])
    d = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])  # the last one misses
    tau = ray_optical_depths(grid_density(grid), o, d, UNIT_BOX, 8)
    np.testing.assert_allclose(tau, [2.0, 2.0, 2.0, 0.0], rtol=1e-6)


def test_a_model_without_density_reports_none_and_says_so(blob_grid):
    scores, slices = density_scores(None, blob_grid, UNIT_BOX)
    assert scores["density_rel_l1"] is None and scores["density_note"] == NO_DENSITY
    assert "true_z" in slices and "learned_z" not in slices
    assert optical_depth_scores(None, blob_grid, UNIT_BOX, _cameras())["tau_rel_l1"] is None


def test_voxel_centres_follow_the_grid_convention():
    r = 4
    p = UNIT_BOX.voxel_centres(r)
    k, j, i = 1, 2, 3  # voxel [z, y, x] = [k, j, i] has its centre at ((i+.5)/R - .5, (j+.5)/R - .5, (k+.5)/R - .5)
    np.testing.assert_allclose(p[k, j, i], [(i + 0.5) / r - 0.5, (j + 0.5) / r - 0.5, (k + 0.5) / r - 0.5])


def test_voxel_centres_and_optical_depths_follow_a_box_of_any_size():
    box = Box((-1.5, -1.0, 0.0), (1.5, 1.0, 4.0))
    p = box.voxel_centres(2)
    np.testing.assert_allclose(p[1, 0, 1], [0.75, -0.5, 3.0])  # [z, y, x] = [1, 0, 1]
    o, d = np.array([[0.0, 0.0, -3.0]]), np.array([[0.0, 0.0, 1.0]])
    tau = ray_optical_depths(lambda x: 0.5 + 0.0 * x.x, o, d, box, 16)
    np.testing.assert_allclose(tau, [0.5 * 4.0], rtol=1e-6)  # the chord through the box is 4 long


def test_medium_masks_mark_exactly_the_pixels_whose_ray_meets_the_medium():
    grid = np.zeros((8, 8, 8), np.float32)
    grid[3:5, 3:5, 3:5] = 20.0  # a dense cube of side 1/4 at the centre
    cam = Camera.from_fov(look_at(np.array([0.0, -3.0, 0.0])), 9, 9, 30.0)
    mask = medium_masks(grid, UNIT_BOX, [cam])[0]
    assert mask[4, 4] and not mask[0, 0] and not mask[8, 8] and 0 < mask.sum() < mask.size


def test_error_budget_gaps_are_differences_and_none_without_an_oracle():
    assert error_budget(38.0, 43.5, 44.0) == {"gap_to_oracle": 5.5, "oracle_to_floor": 0.5, "gap_to_floor": 6.0}
    assert error_budget(38.0, None, 44.0)["gap_to_oracle"] is None


def test_optical_depth_and_medium_mask_of_a_uniform_box():
    grid = np.full((8, 8, 8), 2.0, np.float32)  # uniform: tau = 2 * chord length
    o = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 3.0], [3.0, 3.0, 3.0], [0.2, -3.0, 0.1]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [-1.0, -1.0, -1.0], [0.0, 1.0, 0.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tau = ray_optical_depths(grid_density(grid), o, d, UNIT_BOX, 28)
    # float32 Dr.Jit arithmetic (the lookups and the sum of 28 terms): relative error ~1e-7 per term
    np.testing.assert_allclose(tau, [2.0, 0.0, 2.0 * np.sqrt(3.0), 2.0], rtol=1e-5)
    cam = Camera.from_fov(look_at((0.0, -3.0, 0.0)), 16, 12, 40.0)
    mask = medium_masks(grid, UNIT_BOX, [cam])[0]
    _, dirs = cam.pixel_rays()
    # the box's face y = -0.5 spans |x|, |z| <= 0.5 at distance 2.5 along the axis
    t = 2.5 / dirs[:, 1]
    hits = (np.abs(dirs[:, 0] * t) <= 0.5) & (np.abs(dirs[:, 2] * t) <= 0.5)
    assert np.array_equal(mask.ravel(), hits)
    assert not medium_masks(np.zeros((8, 8, 8), np.float32), UNIT_BOX, [cam]).any()


def test_an_anisotropic_medium_is_also_scored_against_its_reduced_extinction(blob_grid):
    """g = 0.5, albedo 0.8: sigma_t (1 - 0.4) renders alike; a density that found it scores 0 there, 0.4 against
    sigma_t; an isotropic medium's reduced scores are None."""
    from mitsnerf.scoring.density import reduced_extinction
    from mitsnerf.scoring.reference import Reference
    from mitsnerf.scoring.views import score_views

    cams = _cameras()
    images = np.zeros((len(cams), 12, 12, 3))
    reduced = reduced_extinction(blob_grid, np.full(blob_grid.shape + (3,), 0.8), 0.5)
    ref = Reference(images, tuple(cams), 0.5, UNIT_BOX, blob_grid, None, None, reduced)
    scores, _ = score_views(images, ref, grid_density(blob_grid, 0.6), density_resolution=16)
    assert scores["density_rel_l1_reduced"] < 1e-4 and scores["density_rel_l1"] == pytest.approx(0.4, rel=1e-3)
    assert scores["density_rel_mass_reduced"] == pytest.approx(0.0, abs=1e-4)
    isotropic = Reference(images, tuple(cams), 0.5, UNIT_BOX, blob_grid, None, None)
    assert score_views(images, isotropic, grid_density(blob_grid))[0]["density_rel_l1_reduced"] is None


# --------------------------------------------------------------------------- the one-pass ground truth's checks


def _transmittance_map(rng, shape=(3, 24, 24)) -> np.ndarray:
    """A mean-transmittance map with clear pixels (T = 1), thin and thick medium."""
    t = np.clip(rng.uniform(-0.3, 1.4, size=shape), 0.0, 1.0)
    t[:, :4] = 1.0
    return t


@pytest.mark.parametrize("spp", [4, 64, 2048])
def test_transmittance_agreement_holds_its_error_rate_on_binomial_alpha(spp):
    """Alpha drawn as the film makes it (binomial over spp samples): rejected at about the family's rate."""
    from mitsnerf.scoring.agreement import transmittance_agreement

    rng = np.random.default_rng(spp)
    t = _transmittance_map(rng)
    rejected = sum(not transmittance_agreement(rng.binomial(spp, 1 - t) / spp, t, spp)["passed"] for _ in range(300))
    assert rejected <= 2  # family alpha 1e-3: 0.3 expected


def test_transmittance_agreement_rejects_a_shared_bias_a_per_pixel_error_and_impossible_alpha():
    from mitsnerf.scoring.agreement import transmittance_agreement

    rng = np.random.default_rng(7)
    t = _transmittance_map(rng)
    alpha = rng.binomial(2048, 1 - t) / 2048
    good = transmittance_agreement(alpha, t, 2048)
    assert good["passed"] and good["critical_z"] == pytest.approx(3.76, abs=0.01) and len(good["views"]) == 3
    assert not transmittance_agreement(alpha, np.clip(t * 1.02, 0, 1), 2048)["passed"]  # z
    shuffled = t.copy()
    shuffled[:, 4:] = np.roll(t[:, 4:], 1, axis=2)  # right on average, wrong per pixel
    bad = transmittance_agreement(alpha, shuffled, 2048)
    assert not bad["passed"] and bad["max_ratio_z"] > bad["critical_z"]
    stray = alpha.copy()
    stray[0, 0, 0] = 1 / 2048  # a clear pixel (T = 1) whose ray collided
    assert transmittance_agreement(stray, t, 2048)["views"][0]["impossible"] == 1


@pytest.mark.parametrize("spp", [4, 64, 2048])
def test_transmittance_agreement_of_the_mean_of_channel_renders_holds_its_error_rate_and_its_variance(spp):
    """A chromatic medium rendered per colour channel: alpha the mean of three independent binomial alphas, each
    estimating its channel's 1 - T_k. With the per-channel transmittances the check holds its error rate and its
    dispersion ratio is about 1 (read as one binomial of the mean T, the variance is too large: ratio about 1/3,
    a per-pixel error of a few times the noise would pass); a 4% shared bias is rejected at 2048 spp."""
    from mitsnerf.scoring.agreement import transmittance_agreement

    rng = np.random.default_rng(spp + 1)
    t = np.stack([_transmittance_map(rng) ** f for f in (0.5, 1.0, 2.0)], axis=-1)  # (V, H, W, 3): T_k

    def alpha():
        return np.mean([rng.binomial(spp, 1 - t[..., k]) / spp for k in range(3)], axis=0)

    checks = [transmittance_agreement(alpha(), t, spp) for _ in range(300)]
    assert sum(not c["passed"] for c in checks) <= 2  # family alpha 1e-3: 0.3 expected
    ratios = [v["ratio"] for c in checks for v in c["views"]]
    assert 0.95 < np.mean(ratios) < 1.05
    grey = [v["ratio"] for v in transmittance_agreement(alpha(), t.mean(-1), spp)["views"]]
    assert np.mean(grey) < 0.6
    if spp == 2048:
        biased = np.clip(alpha() * 1.04, 0, 1)
        assert not transmittance_agreement(biased, t, spp)["passed"]


def test_view_agreement_is_per_view_and_has_power():
    from mitsnerf.scoring.agreement import view_agreement

    rng = np.random.default_rng(3)
    truth = rng.uniform(0.2, 1.0, size=(4, 16, 16, 3))
    noisy = [truth + rng.normal(0, 0.05, truth.shape) for _ in range(4)]
    check = view_agreement(*noisy)
    assert check["passed"] and len(check["views"]) == 4 and check["max_abs_z"] < check["critical_z"]
    off = [noisy[2].copy(), noisy[3].copy()]
    for img in off:
        img[2] += 0.02  # one view biased
    check = view_agreement(noisy[0], noisy[1], *off)
    assert not check["passed"] and [v["passed"] for v in check["views"]] == [True, True, False, True]


# --------------------------------------------------------------------------- scores less a render's own variance

def _noisy_views(seed: int = 0, sigma_ref: float = 0.02):
    """Truth ``(4, 32, 32, 3)`` in [0.2, 0.8] and references around it with noise ``sigma_ref``."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0.2, 0.8, size=(4, 32, 32, 3))
    return rng, truth, truth + rng.normal(0.0, sigma_ref, truth.shape)


def test_two_independent_renders_give_the_variance_and_the_score_without_it():
    """A render with noise 0.03 against references with noise 0.02: less the variance two renders measure, it scores
    what the noise-free image scores (within 0.2 dB: the variance of 3072 values a view is known to 2.6%, and it is
    2.25 times what is left)."""
    from mitsnerf.scoring.variance import pair_variance, without_variance

    rng, truth, refs = _noisy_views()
    a, b = (truth + rng.normal(0.0, 0.03, truth.shape) for _ in range(2))
    var = pair_variance(a, b)
    assert var.mean() == pytest.approx(0.03**2, rel=0.03)
    masks = np.ones(truth.shape[:3], bool)
    found = without_variance(a, refs, masks, var)
    exact = image_scores(truth, refs, masks)["psnr_test_medium"]
    raw = image_scores(a, refs, masks)["psnr_test_medium"]
    assert raw < exact - 5 and found["psnr_test_medium_without_mc"] == pytest.approx(exact, abs=0.2)
    assert found["mc_var_test_medium"] == pytest.approx(var.mean()) and found["mc_note"] is None


def test_a_variance_that_explains_all_the_error_is_unbounded_and_says_so():
    from mitsnerf.scoring.variance import without_variance

    refs = np.full((2, 4, 4, 3), 0.5)
    found = without_variance(refs + 0.01, refs, np.ones((2, 4, 4), bool), np.full(refs.shape, 2e-4))
    assert found["psnr_test_medium_without_mc"] is None and found["psnr_test_medium_without_mc_per_view"] == [None] * 2
    assert found["mc_note"].startswith("unbounded without its Monte Carlo variance") and "view 1" in found["mc_note"]


class _MonteCarloModel:
    """A path tracer's stand-in: the truth plus seeded noise per render (a second, independent render on request)."""

    rung, monte_carlo_renders, knows = "full transport", True, ()

    def __init__(self, truth, sigma: float, independent: bool = True):
        self.truth, self.sigma, self.independent, self.renders = truth, sigma, independent, 0

    def render_view(self, camera, *, pixel_center: float = 0.5, footprint: int = 1, seed: int = 0):
        from mitsnerf.render.camera import Rendered

        self.renders += 1
        noise = np.random.default_rng([camera, seed]).normal(0.0, self.sigma, self.truth[camera].shape)
        return Rendered((self.truth[camera] + noise).astype(np.float32), np.ones(self.truth.shape[1:3]), None)

    def render_view_independent(self, camera, *, pixel_center: float = 0.5, footprint: int = 1):
        return self.render_view(camera, seed=1) if self.independent else None


def test_a_monte_carlo_row_is_scored_without_its_own_variance_from_a_second_render():
    """score_model renders a Monte Carlo model's views twice, independently: the row's medium PSNR less its own
    variance is the noise-free image's; a model without a second render is scored raw and says so."""
    from mitsnerf.runs.fit import score_model
    from mitsnerf.scoring.reference import Reference
    from mitsnerf.train.evaluate import EvalConfig

    _, truth, refs = _noisy_views(1)
    ref = Reference(refs, tuple(range(len(refs))), 0.5, UNIT_BOX, None, np.ones(truth.shape[:3], bool), None)
    model = _MonteCarloModel(truth, 0.03)
    scores = score_model(model, ref, EvalConfig(footprint=1))[0]
    exact = image_scores(truth, refs, ref.masks)["psnr_test_medium"]
    assert model.renders == 2 * len(refs)
    assert scores["psnr_test_medium"] < exact - 5
    assert scores["psnr_test_medium_without_mc"] == pytest.approx(exact, abs=0.2) and scores["mc_note"] is None
    raw = score_model(_MonteCarloModel(truth, 0.03, independent=False), ref, EvalConfig(footprint=1))[0]
    assert raw.get("psnr_test_medium_without_mc") is None and raw["mc_note"].startswith("raw: its renders are Monte")
