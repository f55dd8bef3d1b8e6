"""The exact transmittance of a trilinear grid along rays, and its mean over each pixel."""

from __future__ import annotations

import numpy as np
import pytest

from mitsnerf.math.box import UNIT_BOX, Box
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.math.rays import camera_rays_numpy, footprint_offsets, to_array3f
from mitsnerf.render.background import ConstantBackground
from mitsnerf.scene.transmittance import TAU_STOP, empty_distances, optical_depths, pixel_transmittance
from mitsnerf.scoring.density import ray_optical_depths, true_density


def _rays(n: int, seed: int = 0, box: Box = UNIT_BOX) -> tuple[np.ndarray, np.ndarray]:
    """Rays from a sphere around ``box`` towards random points near it (some miss it)."""
    rng = np.random.default_rng(seed)
    centre, size = np.asarray(box.centre), np.asarray(box.size)
    o = rng.normal(size=(n, 3))
    o = centre + 2.0 * max(size) * o / np.linalg.norm(o, axis=1, keepdims=True)
    target = centre + size * rng.uniform(-0.7, 0.7, size=(n, 3))
    d = target - o
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def _tau(grid: np.ndarray, box: Box, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    import mitsuba as mi

    fn = true_density(grid, box)
    return np.asarray(optical_depths(fn, grid.shape[0], box, to_array3f(mi.Array3f, o), to_array3f(mi.Array3f, d)),
                      np.float64)


def test_a_homogeneous_grid_gives_sigma_times_the_chord():
    box = Box((-0.3, -0.5, 0.0), (0.7, 0.5, 2.0))
    o, d = _rays(2000, box=box)
    t_n, t_f, hit = box.intersect_numpy(o, d)
    tau = _tau(np.full((8, 8, 8), 2.5, np.float32), box, o, d)
    assert (~hit).any() and np.all(tau[~hit] == 0)
    assert np.allclose(tau, 2.5 * (t_f - t_n), rtol=1e-5, atol=1e-5)  # float32 distances of ~4


def test_axis_aligned_rays_and_rays_through_voxel_centres():
    """Direction components of 0 (no plane crossed on that axis) and rays lying in the planes the walk steps on."""
    grid = np.random.default_rng(1).uniform(0, 4, size=(8, 8, 8)).astype(np.float32)
    fn_ref = true_density(grid, UNIT_BOX)
    o = np.array([[-1.0, 0.0625, 0.3], [0.2, -1.0, -0.1875], [0.0625, 0.0625, 2.0], [-1.0, -1.0, -1.0]])
    d = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 1.0, 1.0]]) / np.array([[1], [1], [1], [3**0.5]])
    ref = ray_optical_depths(fn_ref, o, d, UNIT_BOX, 20000)
    assert np.allclose(_tau(grid, UNIT_BOX, o, d), ref, rtol=2e-5)


def test_a_random_grid_matches_a_fine_midpoint_rule_and_the_rule_converges_to_it():
    """The midpoint rule's error falls as h^2 towards the exact value (cell by cell Gauss-Legendre is exact for
    the cubic a trilinear lookup is along a line), including the clamped half voxel at the borders."""
    grid = np.random.default_rng(2).uniform(0, 30, size=(12, 12, 12)).astype(np.float32)
    o, d = _rays(500, seed=3)
    exact = _tau(grid, UNIT_BOX, o, d)
    fn = true_density(grid, UNIT_BOX)
    errors = [np.abs(ray_optical_depths(fn, o, d, UNIT_BOX, n) - exact).max() for n in (250, 1000)]
    assert errors[1] < errors[0] / 8 and errors[1] < 2e-3 * exact.max()


def test_a_ray_stops_once_it_is_opaque():
    grid = np.full((4, 4, 4), 1000.0, np.float32)
    o, d = np.array([[0.0, 0.0, -2.0]]), np.array([[0.0, 0.0, 1.0]])
    tau = _tau(grid, UNIT_BOX, o, d)
    assert TAU_STOP <= tau[0] < 1000.0 and np.exp(-tau[0]) < 1e-13


def _sparse(r: int, seed: int) -> np.ndarray:
    """A grid mostly 0: isolated voxels up to 30 in empty space (some at the borders)."""
    rng = np.random.default_rng(seed)
    return np.where(rng.uniform(size=(r, r, r)) < 0.02, rng.uniform(1, 30, size=(r, r, r)), 0).astype(np.float32)


@pytest.mark.parametrize("channels", [1, 3])
def test_empty_space_is_crossed_without_changing_tau(channels):
    """A sparse grid: the walk that crosses empty cubes without lookups (empty_cells) gives the tau of the walk
    that looks every cell up (distances all 0), to float32 rounding, on random rays and on rays in the planes the
    walk steps on; a chromatic grid's cell is empty where every channel is 0 (its channels empty apart)."""
    import mitsuba as mi

    grid = _sparse(16, 7) if channels == 1 else np.stack([_sparse(16, 7), 0 * _sparse(16, 7), _sparse(16, 8)], -1)
    o, d = _rays(3000, seed=8)
    o = np.concatenate([o, [[-1.0, 0.03125, 0.3], [0.0625, 0.0625, 2.0], [-1.0, -1.0, -1.0]]])
    d = np.concatenate([d, np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [1.0, 1.0, 1.0]]) / [[1], [1], [3**0.5]]])
    fn, rays = true_density(grid, UNIT_BOX), (to_array3f(mi.Array3f, o), to_array3f(mi.Array3f, d))
    skipped = np.asarray(optical_depths(fn, 16, UNIT_BOX, *rays, channels=channels), np.float64)
    looked_up = np.asarray(optical_depths(fn, 16, UNIT_BOX, *rays, channels=channels,
                                          distances=mi.Int32(np.zeros(17**3, np.int32))), np.float64)
    assert 0.3 < (skipped > 0).mean() < 0.95
    assert np.allclose(skipped, looked_up, rtol=2e-6, atol=0)


def test_empty_distances_are_the_chebyshev_distances_to_the_medium():
    """Each cell's entry against every occupied cell's Chebyshev distance, by brute force (capped)."""
    grid = _sparse(6, 9)
    got = empty_distances(grid, cap=3)
    padded = np.pad(grid != 0, 1, mode="edge")
    cells = np.stack(np.meshgrid(*[np.arange(7)] * 3, indexing="ij"), -1).reshape(-1, 3)
    full = np.array([padded[x:x + 2, y:y + 2, z:z + 2].any() for x, y, z in cells])
    far = np.abs(cells[:, None, :] - cells[None, full, :]).max(-1).min(1)
    assert full.any() and (far >= 3).any() and np.array_equal(got.ravel(), np.minimum(far, 3))


def test_pixel_means_with_one_ray_are_the_centre_rays_and_a_constant_background_factors_out():
    grid = np.random.default_rng(4).uniform(0, 20, size=(8, 8, 8)).astype(np.float32)
    cams = [Camera.from_fov(look_at(p, (0, 0, 0), (0, 0, 1)), 6, 5, 40.0) for p in ((2.0, 0.5, 0.3), (-0.4, 1.9, 0.8))]
    fn = true_density(grid, UNIT_BOX)
    one = pixel_transmittance(fn, 8, UNIT_BOX, cams, footprint=1)
    o, d = camera_rays_numpy(cams)
    assert one.through is None and np.allclose(one.t.ravel(), np.exp(-_tau(grid, UNIT_BOX, o, d)), rtol=1e-4)
    seen = pixel_transmittance(fn, 8, UNIT_BOX, cams, footprint=3, background=ConstantBackground((0.5, 1.0, 2.0)))
    assert np.allclose(seen.env, [0.5, 1.0, 2.0]) and np.allclose(seen.through, seen.t[..., None] * [0.5, 1.0, 2.0])
    sub = [np.exp(-_tau(grid, UNIT_BOX, *camera_rays_numpy(cams, offset=tuple(f)))) for f in footprint_offsets(3)]
    assert np.allclose(seen.t.ravel(), np.mean(sub, axis=0), rtol=1e-4)
    shifted = pixel_transmittance(fn, 8, UNIT_BOX, cams, footprint=1, pixel_center=0.0)
    o0, d0 = camera_rays_numpy(cams, 0.0)
    assert np.allclose(shifted.t.ravel(), np.exp(-_tau(grid, UNIT_BOX, o0, d0)), rtol=1e-4)
    assert not np.allclose(shifted.t, one.t, rtol=1e-2)


@pytest.mark.parametrize("sigma", [1e-9, 1e-6, 1e-4])
def test_a_faint_medium_keeps_its_small_collision_probability(sigma):
    """A pixel's 1 - mean T where the medium is faint (its edge): the mean over the pixel's rays of tau to
    float32's relative precision, not 0 (1 - exp(-tau) in float32 rounds to 0 below tau ~ 6e-8) nor rounded away
    in a float32 sum of K x K values near 1; a chromatic grid's per-channel T_k alike."""
    grid = np.full((8, 8, 8), sigma, np.float32)
    cams = [Camera.from_fov(look_at((2.0, 0.5, 0.3), (0, 0, 0), (0, 0, 1)), 6, 5, 40.0)]
    seen = pixel_transmittance(true_density(grid, UNIT_BOX), 8, UNIT_BOX, cams, footprint=16)
    sub = [_tau(grid, UNIT_BOX, *camera_rays_numpy(cams, offset=tuple(f))) for f in footprint_offsets(16)]
    expected = np.mean(sub, axis=0).reshape(seen.t.shape)  # 1 - exp(-tau) = tau to 1e-4 relative here
    assert (expected > 0).mean() > 0.8 and np.allclose(1.0 - seen.t, expected, rtol=2e-4, atol=0)
    rgb = np.stack([grid, 2 * grid, 4 * grid], axis=-1)
    chromatic = pixel_transmittance(true_density(rgb, UNIT_BOX), 8, UNIT_BOX, cams, footprint=16, channels=3)
    assert np.allclose(1.0 - chromatic.t_rgb, expected[..., None] * [1, 2, 4], rtol=4e-4, atol=0)
    assert np.allclose(1.0 - chromatic.t, expected * 7 / 3, rtol=4e-4, atol=0)


@pytest.mark.parametrize("chunk", [64, 1 << 21])
def test_chunks_do_not_change_the_result(chunk):
    grid = np.random.default_rng(5).uniform(0, 10, size=(8, 8, 8)).astype(np.float32)
    cams = [Camera.from_fov(look_at((0.3, -2.0, 0.4), (0, 0, 0), (0, 0, 1)), 7, 7, 50.0)]
    fn = true_density(grid, UNIT_BOX)
    ref = pixel_transmittance(fn, 8, UNIT_BOX, cams, footprint=2)
    assert np.array_equal(pixel_transmittance(fn, 8, UNIT_BOX, cams, footprint=2, chunk=chunk).t, ref.t)


@pytest.mark.parametrize("chunk", [4 * 20, 1 << 21])
def test_each_chunk_walks_its_rays_once(chunk):
    """T, 1 - T and T L per channel read one evaluated walk (at 07aa360 each traced the loop into its own kernel:
    5 walks a chunk with a background, 5x the time): the kernels that contain the walk's loop (its label in their
    code) are one a chunk."""
    import drjit as dr

    grid = np.random.default_rng(6).uniform(0, 10, size=(8, 8, 8)).astype(np.float32)
    cams = [Camera.from_fov(look_at((0.3, -2.0, 0.4), (0, 0, 0), (0, 0, 1)), 7, 5, 50.0)] * 2
    fn, background = true_density(grid, UNIT_BOX), ConstantBackground((0.5, 1.0, 2.0))
    dr.kernel_history()  # (empties it)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        pixel_transmittance(fn, 8, UNIT_BOX, cams, footprint=2, background=background, chunk=chunk)
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    walks = [k for k in dr.kernel_history() if "ir" in k and "optical_depths" in k["ir"].getvalue()]
    assert len(walks) == -(-2 * 35 // (chunk // 4))
