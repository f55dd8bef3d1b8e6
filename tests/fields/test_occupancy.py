"""The occupancy grid on ground-truth fields: conservative (never empties occupied space), and
skipping with it leaves a render unchanged."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.grid import GridField
from mitsnerf.fields.occupancy import OccupancyConfig, OccupancyGrid, eval_masked
from mitsnerf.render.skipping import render_rays_skipping
from mitsnerf.render.volume import render_rays, sample_rays
from mitsnerf.math.box import UNIT_BOX


def _smooth_noise_grid(r=32, seed=0, peak=30.0):
    """A cloud-like field: low-pass filtered noise, clipped, so with holes, clumps and zero regions."""
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=(r, r, r))
    k = np.fft.fftfreq(r)
    kz, ky, kx = np.meshgrid(k, k, k, indexing="ij")
    smooth = np.real(np.fft.ifftn(np.fft.fftn(noise) * np.exp(-(kx**2 + ky**2 + kz**2) / (2 * 0.06**2))))
    smooth /= smooth.std()
    c = (np.arange(r) + 0.5) / r - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    envelope = np.clip(1.0 - np.sqrt(x**2 + y**2 + z**2) / 0.45, 0.0, 1.0)
    return (peak * envelope * np.clip(smooth - 0.3, 0.0, 1.0)).astype(np.float32)


def _misses(field, grid, threshold, n=200_000, seed=1):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.5, 0.5, (n, 3)).astype(np.float32)
    x = mi.Array3f(p[:, 0], p[:, 1], p[:, 2])
    sigma = np.asarray(field.density(x))
    occupied = np.asarray(grid.is_occupied(x))
    dense = sigma > threshold
    return int(np.sum(dense & ~occupied)), int(np.sum(dense)), float(np.mean(occupied))


@pytest.mark.parametrize("resolution", [32, 64])
@pytest.mark.parametrize("threshold", [0.01, 1.0])
def test_occupied_space_is_never_marked_empty(blob_grid, resolution, threshold):
    for sigma_t in (blob_grid, _smooth_noise_grid()):
        field = GridField.from_arrays(sigma_t, UNIT_BOX)
        grid = OccupancyGrid(OccupancyConfig(resolution=resolution, threshold=threshold), mi.Float, UNIT_BOX)
        for step in range(3):  # a few updates, as during training
            grid.update(field.density, seed=0, step=step)
        misses, dense, occupied = _misses(field, grid, threshold)
        assert dense > 1000
        assert misses == 0
        assert occupied < 0.9  # and it does skip something


def test_a_single_update_is_conservative_with_dilation_only(blob_grid):
    field = GridField.from_arrays(_smooth_noise_grid(seed=3), UNIT_BOX)
    loose = OccupancyGrid(OccupancyConfig(resolution=32, threshold=0.5, dilate=0), mi.Float, UNIT_BOX)
    tight = OccupancyGrid(OccupancyConfig(resolution=32, threshold=0.5, dilate=1), mi.Float, UNIT_BOX)
    loose.update(field.density, seed=0, step=0)
    tight.update(field.density, seed=0, step=0)
    assert _misses(field, tight, 0.5)[0] == 0
    # without dilation, a single jittered sample per cell does miss some dense points
    assert _misses(field, loose, 0.5)[0] > 0


def test_skipping_and_early_stopping_leave_a_ground_truth_render_unchanged():
    sigma_t = _smooth_noise_grid(seed=2, peak=150.0)  # thick enough for rays to become opaque
    r = sigma_t.shape[0]
    color = np.stack([np.linspace(0.2, 1.0, r)[None, None, :].repeat(r, 0).repeat(r, 1)] * 3, -1).astype(np.float32)
    field = GridField.from_arrays(sigma_t, UNIT_BOX, color=color)
    grid = OccupancyGrid(OccupancyConfig(resolution=32), mi.Float, UNIT_BOX)
    for step in range(2):
        grid.update(field.density, seed=0, step=step)
    rng = np.random.default_rng(4)
    o = rng.normal(size=(4096, 3))
    o = 2.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    target = rng.uniform(-0.3, 0.3, (4096, 3))
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o, d = mi.Array3f(*o.T.astype(np.float32)), mi.Array3f(*d.T.astype(np.float32))
    full = render_rays(field, o, d, 128, background=0.5, box=UNIT_BOX)
    fast, mask = render_rays_skipping(field, grid, o, d, 128, background=0.5, box=UNIT_BOX)
    kept = dr.count(mask)[0] / dr.width(mask)
    assert kept < 0.75
    diff = np.abs(np.stack([np.asarray(a) for a in fast.rgb]) - np.stack([np.asarray(a) for a in full.rgb]))
    assert diff.max() < 2e-3


def test_skipping_changes_a_ray_by_at_most_the_skipped_optical_depth(blob_grid):
    """Zeroing sigma on a set S of a ray's samples moves its colour by at most (1 - exp(-tau_S)) times the
    range of the colours and background (a coupling argument: the two renders differ only when a sample
    of S would have absorbed). The blob's gaussian tails lie below the grid's threshold over long
    stretches, so tau_S is not negligible here, and the bound is what holds."""
    field = GridField.from_arrays(blob_grid, UNIT_BOX, color=(1.0, 0.9, 0.1))
    grid = OccupancyGrid(OccupancyConfig(resolution=24), mi.Float, UNIT_BOX)
    grid.update(field.density, seed=0, step=0)
    rng = np.random.default_rng(7)
    o = rng.normal(size=(2048, 3))
    o = 2.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-0.3, 0.3, (2048, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o, d = mi.Array3f(*o.T.astype(np.float32)), mi.Array3f(*d.T.astype(np.float32))
    n, bg = 96, 0.3
    full = render_rays(field, o, d, n, background=bg, box=UNIT_BOX)
    fast, mask = render_rays_skipping(field, grid, o, d, n, background=bg, box=UNIT_BOX)
    s, _ = sample_rays(o, d, n, UNIT_BOX)
    tau_s = np.asarray(dr.block_sum(dr.select(mask, 0.0, field.density(s.x) * s.delta), n))
    bound = -np.expm1(-tau_s) * (1.0 - 0.1)  # colours and background lie in [0.1, 1]
    diff = np.abs(np.stack([np.asarray(a) for a in fast.rgb]) - np.stack([np.asarray(a) for a in full.rgb])).max(0)
    assert np.all(diff <= bound + 1e-5)
    assert diff.max() > 1e-3  # the tails are skipped: the bound is exercised, not vacuous


def test_eval_masked_gradients_reach_active_samples_only():
    x = mi.Float([1.0, 2.0, 3.0])
    dr.enable_grad(x)
    f = lambda p, d: (mi.Array3f(p.x), 2.0 * p.x)  # noqa: E731
    rgb, sigma = eval_masked(f, mi.Array3f(x, 0, 0), mi.Array3f(0, 0, 1), mi.Bool([True, False, True]))
    dr.backward(dr.sum(sigma))
    np.testing.assert_array_equal(np.asarray(dr.grad(x)), [2.0, 0.0, 2.0])


def test_config_is_validated():
    with pytest.raises(ValueError, match="resolution"):
        OccupancyConfig(resolution=1)
    with pytest.raises(ValueError, match="early_stop_T"):
        OccupancyConfig(early_stop_T=1.0)


def test_eval_masked_with_nothing_active_keeps_a_gradient_path():
    w = mi.Float(2.0)
    dr.enable_grad(w)
    f = lambda p, d: (mi.Array3f(w * p.x), w * p.x)  # noqa: E731
    rgb, sigma = eval_masked(f, mi.Array3f([1.0, 2.0], 0, 0), mi.Array3f(0, 0, 1), mi.Bool([False, False]))
    assert np.all(np.asarray(sigma) == 0.0)
    dr.backward(dr.sum(sigma) + dr.sum(rgb.x))  # must not raise "does not depend on the input"
    assert dr.grad(w)[0] == 0.0
