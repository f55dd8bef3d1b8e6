"""Chromatic extinction: ``volume.sigma_t_scale`` as an RGB triple makes a 3-channel ``sigma_t`` (channel k is
the family's density times ``sigma_t_scale[k]``), carried to Mitsuba, the dataset and its verification."""

from __future__ import annotations

import numpy as np
import pytest

import mitsnerf  # noqa: F401  (sets up LLVM before drjit loads anywhere)
from mitsnerf.data.verify import check_grids
from mitsnerf.errors import DatasetError, SpecError
from mitsnerf.scene.spec import list_scenes, load_scene, parse_scene
from mitsnerf.scene.to_mitsuba import scene_dict, volume_grids


def with_scale(scale, name: str = "cloud"):
    data = load_scene(name).to_dict()
    data["volume"]["sigma_t_scale"] = scale
    data["volume"]["resolution"] = 16
    return parse_scene(data, "s.toml")


def test_an_rgb_scale_is_chromatic_and_a_grey_triple_is_not_the_scalar():
    spec = with_scale([10, 20, 40])
    assert spec.volume.chromatic and spec.volume.sigma_t_scale == (10.0, 20.0, 40.0)
    assert spec.volume.sigma_t_rgb == (10.0, 20.0, 40.0)
    grey = with_scale(30.0)
    assert not grey.volume.chromatic and grey.volume.sigma_t_rgb == (30.0, 30.0, 30.0)
    assert parse_scene(spec.to_dict(), "again") == spec
    assert spec.content_hash() != grey.content_hash() != with_scale([30, 30, 30]).content_hash()


@pytest.mark.parametrize(("scale", "message"), [
    ([1, 2], "s.toml: volume.sigma_t_scale: must be 3 numbers in (0, 10000], got 2 values"),
    ([1, -2, 3], "s.toml: volume.sigma_t_scale: must be 3 numbers in (0, 10000], got [1, -2, 3]"),
    ("thick", "s.toml: volume.sigma_t_scale: must be a number in (0, 10000], got 'thick'"),
])
def test_a_bad_scale_names_its_field(scale, message):
    with pytest.raises(SpecError) as err:
        with_scale(scale)
    assert str(err.value) == message


def test_the_grid_has_one_channel_per_colour_each_the_grey_grid_scaled():
    sigma, albedo = volume_grids(with_scale([10, 20, 40]))
    grey, _ = volume_grids(with_scale(10.0))
    assert sigma.shape == (16, 16, 16, 3) and sigma.dtype == np.float32 and albedo.shape == (16, 16, 16, 3)
    for k, factor in enumerate((1, 2, 4)):
        np.testing.assert_allclose(sigma[..., k], factor * grey, rtol=1e-6)


def test_mitsuba_renders_it_and_blue_is_stopped_more_than_red():
    import mitsuba as mi

    from mitsnerf.scene.to_mitsuba import load_sensor
    from mitsnerf.scene.rigs import camera_rig

    spec = with_scale([5, 20, 80])
    data = scene_dict(spec, *volume_grids(spec))
    data["lights"] = {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
    for key in [k for k in data if k.startswith("light_")]:
        del data[key]
    data["medium_box"]["interior"]["albedo"] = 0.0  # absorption only: the image is T_k per channel
    scene = mi.load_dict(data)
    image = np.array(mi.render(scene, sensor=load_sensor(camera_rig(spec.cameras, "test")[0], 32), spp=32))
    centre = image[24:40, 24:40, :3].mean(axis=(0, 1))
    assert centre[0] > centre[1] > centre[2]


def test_a_dataset_checks_its_sigma_t_against_the_spec(tmp_path):
    from mitsnerf.data.dataset import true_grid_path

    manifest = {"spec": {"volume": {"resolution": 4, "sigma_t_scale": [1.0, 2.0, 3.0]}}}
    true_grid_path(tmp_path).parent.mkdir()
    np.save(true_grid_path(tmp_path, "albedo"), np.zeros((4, 4, 4, 3), np.float32))
    np.save(true_grid_path(tmp_path, "sigma_t"), np.zeros((4, 4, 4, 3), np.float32))
    check_grids(tmp_path, manifest)
    np.save(true_grid_path(tmp_path, "sigma_t"), np.zeros((4, 4, 4), np.float32))  # a grey grid for a chromatic spec
    with pytest.raises(DatasetError, match=r"sigma_t.npy: shape \(4, 4, 4\), expected \(4, 4, 4, 3\)"):
        check_grids(tmp_path, manifest)


def test_the_library_has_a_chromatic_smoke():
    assert "smoke" in list_scenes()
    smoke = load_scene("smoke").volume
    assert smoke.chromatic and smoke.sigma_t_rgb[0] < smoke.sigma_t_rgb[1] < smoke.sigma_t_rgb[2]
