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
