"""Export: a field sampled at voxel centres, written as .vol, read back by Mitsuba's gridvolume."""

from __future__ import annotations

import json

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.runs.export import export_field, sample_field
from mitsnerf.fields.grid import GridField
from mitsnerf.fields.nerf import NeRFConfig, NeRFField
from mitsnerf.math.box import UNIT_BOX


def _mitsuba_grid(path):
    return mi.load_dict({"type": "gridvolume", "filename": str(path),
                         "to_world": mi.ScalarTransform4f().translate(-0.5), "accel": False})


def _eval_at(volume, points: np.ndarray, channels: int) -> np.ndarray:
    it = dr.zeros(mi.Interaction3f, len(points))
    it.p = mi.Point3f(points[:, 0], points[:, 1], points[:, 2])
    if channels == 1:
        return np.asarray(volume.eval_1(it))
    return np.stack([np.asarray(c) for c in volume.eval(it)], axis=-1)


def _field_at(field, points: np.ndarray, d) -> tuple[np.ndarray, np.ndarray]:
    x = mi.Array3f(points[:, 0], points[:, 1], points[:, 2])
    rgb, sigma = field(x, mi.Array3f(*d) + dr.zeros(mi.Array3f, len(points)))
    return np.asarray(sigma), np.stack([np.asarray(c) for c in rgb], axis=-1)


def test_exported_nerf_medium_matches_the_field_at_voxel_centres_in_mitsuba(tmp_path):
    field = NeRFField.create(NeRFConfig(width=16, depth=2, dir_octaves=0, sigma_bias=1.0), mi.TensorXf, UNIT_BOX, seed=1)
    d = (0.0, 0.6, 0.8)
    paths = export_field(field, tmp_path, resolution=6, direction=d, box=UNIT_BOX)
    points = UNIT_BOX.voxel_centres(6).reshape(-1, 3).astype(np.float32)
    sigma, color = _field_at(field, points, d)
    assert sigma.max() > 0.1  # a non-trivial density

    np.testing.assert_allclose(_eval_at(_mitsuba_grid(paths["sigma_t.vol"]), points, 1), sigma, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(_eval_at(_mitsuba_grid(paths["albedo.vol"]), points, 3), np.clip(color, 0, 1), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.load(paths["sigma_t.npy"]).reshape(-1), sigma, rtol=1e-6)
    assert np.load(paths["color.npy"]).shape == (6, 6, 6, 3)
    assert "seen looking along" in json.loads(paths["export.json"].read_text())["colour"]


def test_a_grid_field_exported_at_its_own_resolution_is_its_grid(tmp_path, blob_grid):
    albedo = np.random.default_rng(0).uniform(0.2, 0.9, size=(*blob_grid.shape, 3)).astype(np.float32)
    paths = export_field(GridField.from_arrays(blob_grid, UNIT_BOX, albedo), tmp_path, resolution=blob_grid.shape[0],
                         box=UNIT_BOX)
    np.testing.assert_allclose(np.load(paths["sigma_t.npy"]), blob_grid, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.load(paths["color.npy"]), albedo, rtol=1e-5, atol=1e-6)


def test_colour_is_averaged_over_directions_by_default():
    def field(x, d):  # colour = d, so the average over a symmetric set is ~0
        return mi.Array3f(d), x.x * 0.0 + 1.0

    sigma, color = sample_field(field, 2, None, UNIT_BOX)
    assert np.all(sigma == 1.0) and np.abs(color).max() < 0.05
    _, along = sample_field(field, 2, (0.0, 0.0, 2.0), UNIT_BOX)
    np.testing.assert_allclose(along[..., 2], 1.0)
    with pytest.raises(ValueError, match="direction"):
        sample_field(field, 2, (0.0, 0.0, 0.0), UNIT_BOX)
