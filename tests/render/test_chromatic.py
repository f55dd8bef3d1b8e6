"""A chromatic extinction (an Array3f ``sigma``, one per colour channel) through the shared renderers: channel
``k`` of every output is what a grey medium of ``sigma[k]`` gives channel ``k``; opacity and depth are the
channels' means."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.grid import GridField
from mitsnerf.math.box import UNIT_BOX, Box
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.math.rays import camera_rays, host
from mitsnerf.render.background import ConstantBackground
from mitsnerf.render.march import march_rays
from mitsnerf.render.volume import render_rays
from mitsnerf.scene.transmittance import pixel_transmittance
from mitsnerf.scoring.density import density_scores, optical_depth_scores, true_density
from mitsnerf.scoring.medium import medium_masks

BOX = Box((-0.7, -0.5, -0.4), (0.6, 0.5, 0.6))
BG = ConstantBackground((0.2, 0.3, 0.4))


def _setup(blob_grid):
    rng = np.random.default_rng(2)
    sigma = (blob_grid[..., None] * np.array([0.5, 1.0, 3.0], np.float32)).astype(np.float32)
    colour = rng.uniform(0.1, 1.0, (*blob_grid.shape, 3)).astype(np.float32)
    cams = [Camera.from_fov(look_at(p), 10, 8, 50.0) for p in ((0.0, -2.0, 0.3), (1.5, 1.2, -0.4))]
    return sigma, colour, cams, camera_rays(mi.Array3f, cams)


def _rows(v) -> np.ndarray:
    return host(v).reshape(len(host(v)), -1)


def test_every_renderer_composites_each_channel_with_its_own_extinction(blob_grid):
    sigma, colour, _, rays = _setup(blob_grid)
    chromatic = GridField.from_arrays(sigma, BOX, color=colour)
    assert chromatic.sigma_channels == 3
    grey = [GridField.from_arrays(np.ascontiguousarray(sigma[..., k]), BOX, color=colour) for k in range(3)]
    for render in (render_rays, march_rays):
        out = render(chromatic, rays.o, rays.d, 16, box=BOX, background=BG)
        singles = [render(g, rays.o, rays.d, 16, box=BOX, background=BG) for g in grey]
        for k in range(3):
            np.testing.assert_allclose(_rows(out.rgb)[:, k], _rows(singles[k].rgb)[:, k], rtol=2e-5, atol=2e-6)
            np.testing.assert_allclose(_rows(out.T_final)[:, k], _rows(singles[k].T_final)[:, 0], rtol=2e-5, atol=2e-6)
        for name in ("opacity", "depth"):
            mean = np.mean([host(getattr(s, name)) for s in singles], axis=0)
            np.testing.assert_allclose(host(getattr(out, name)), mean, rtol=2e-5, atol=2e-6)


def test_the_exact_transmittance_is_per_channel_and_t_is_their_mean(blob_grid):
    sigma, _, cams, _ = _setup(blob_grid)
    r = sigma.shape[0]
    out = pixel_transmittance(true_density(sigma, BOX), r, BOX, cams, footprint=2, background=BG, channels=3)
    singles = [pixel_transmittance(true_density(np.ascontiguousarray(sigma[..., k]), BOX), r, BOX, cams,
                                   footprint=2, background=BG) for k in range(3)]
    np.testing.assert_allclose(out.t, np.mean([s.t for s in singles], axis=0), rtol=1e-5, atol=1e-7)
    for k in range(3):
        np.testing.assert_allclose(out.through[..., k], singles[k].through[..., k], rtol=1e-5, atol=1e-7)
    assert out.t.min() < 0.9  # the rays do cross the medium


def test_a_grey_density_is_scored_against_every_channel(blob_grid):
    sigma, _, cams, _ = _setup(blob_grid)
    exact, slices = density_scores(true_density(sigma, UNIT_BOX), sigma, UNIT_BOX)
    assert slices["true_z"].ndim == 2 and slices["learned_z"].ndim == 2  # one image per slice: the channels' mean
    assert exact["density_rel_l1"] < 1e-7 and abs(exact["density_rel_mass"]) < 1e-7  # float32 lookups
    green = np.ascontiguousarray(sigma[..., 1])
    grey = density_scores(true_density(green, UNIT_BOX), sigma, UNIT_BOX)[0]
    # |1 - 0.5| + |1 - 1| + |1 - 3| over 0.5 + 1 + 3, and the mass 3 over 4.5
    assert abs(grey["density_rel_l1"] - 2.5 / 4.5) < 1e-6
    assert abs(grey["density_rel_mass"] - (3.0 / 4.5 - 1.0)) < 1e-6
    tau = optical_depth_scores(true_density(green, UNIT_BOX), sigma, UNIT_BOX, cams)
    assert abs(tau["tau_rel_l1"] - 2.5 / 4.5) < 1e-5
    masks = medium_masks(sigma, UNIT_BOX, cams)
    assert masks.shape == (2, 8, 10) and masks.any()


def test_a_per_colour_density_file_is_read_for_scoring(blob_grid, tmp_path):
    from mitsnerf.data.vol import write_vol
    from mitsnerf.errors import DatasetError
    from mitsnerf.runs.external import read_density

    sigma, _, _, _ = _setup(blob_grid)
    np.save(tmp_path / "s.npy", sigma)
    write_vol(tmp_path / "s.vol", sigma, UNIT_BOX.lo, UNIT_BOX.hi)
    for name in ("s.npy", "s.vol"):
        np.testing.assert_array_equal(read_density(tmp_path / name, UNIT_BOX), sigma)
    np.save(tmp_path / "two.npy", sigma[..., :2])
    with pytest.raises(DatasetError, match=r"\(Z, Y, X\) or \(Z, Y, X, 3\)"):
        read_density(tmp_path / "two.npy", UNIT_BOX)
