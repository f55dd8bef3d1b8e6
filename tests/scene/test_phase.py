"""A medium's phase function: the spec's ``volume.phase`` (isotropic by default, ``hg`` with ``g`` always
written), carried to volpath, out of the hash of older specs, and the directional oracle for an anisotropic medium."""

from __future__ import annotations

import numpy as np
import pytest

import mitsnerf  # noqa: F401  (sets up LLVM before drjit loads anywhere)
from mitsnerf.errors import SpecError
from mitsnerf.scene.spec import HGPhase, IsotropicPhase, is_isotropic, list_scenes, load_scene, parse_scene


def with_phase(phase, name: str = "cloud"):
    data = load_scene(name).to_dict()
    data["volume"]["phase"] = phase
    return parse_scene(data, "s.toml")


def test_the_default_is_isotropic_and_left_out_of_the_hash():
    cloud = load_scene("cloud")
    assert cloud.volume.phase == IsotropicPhase() and "phase" not in cloud.to_dict()["volume"]
    assert with_phase({"type": "isotropic"}).content_hash() == cloud.content_hash()
    hg = with_phase({"type": "hg", "g": 0.85})
    assert hg.volume.phase == HGPhase(g=0.85) and hg.content_hash() != cloud.content_hash()
    assert parse_scene(hg.to_dict(), "again") == hg


@pytest.mark.parametrize(("phase", "message"), [
    ({"type": "hg"}, "s.toml: volume.phase.g: missing field (a number in (-1, 1))"),
    ({"type": "hg", "g": 1.0}, "s.toml: volume.phase.g: must be a number in (-1, 1), got 1.0"),
    ({"type": "isotropic", "g": 0.5}, "s.toml: volume.phase.g: unknown key (it takes none)"),
    ({"type": "rayleigh"}, "s.toml: volume.phase.type: unknown phase function type 'rayleigh' (known: isotropic, hg)"),
])
def test_a_bad_phase_names_its_field(phase, message):
    with pytest.raises(SpecError) as err:
        with_phase(phase)
    assert str(err.value) == message


def test_the_library_has_forward_scattering_clouds():
    assert {"cloud_hg85", "cloud_hg50"} <= set(list_scenes())
    assert load_scene("cloud_hg85").volume.phase == HGPhase(g=0.85)
    assert load_scene("cloud_hg50").volume.phase == HGPhase(g=0.5)
    assert not is_isotropic(load_scene("cloud_hg85").volume.phase) and is_isotropic(HGPhase(g=0.0))


def _backlit_radiance(phase) -> float:
    """Mean radiance of a 16^3 cloud seen by a camera looking towards the sun (sun only, no sky)."""
    import mitsuba as mi

    from mitsnerf.math.camera import Camera, look_at
    from mitsnerf.scene.to_mitsuba import load_sensor, scene_dict, volume_grids

    spec = with_phase(phase).with_overrides({"volume.resolution": 16, "lights": [
        {"type": "directional", "direction": [0.0, 0.0, -1.0], "irradiance": [4.0, 4.0, 4.0]}]})
    sigma_t, albedo = volume_grids(spec)
    scene = mi.load_dict(scene_dict(spec, sigma_t, albedo))
    camera = Camera.from_fov(look_at((0.0, 0.0, -2.2)), 16, 16, 40.0)  # below the cloud, the sun above it
    image = mi.render(scene, sensor=load_sensor(camera, 64), seed=0)
    return float(np.asarray(image)[..., :3].mean())


def test_volpath_scatters_with_the_specs_phase_function():
    """Forward scattering sends the sun's light on through the cloud: seen against the sun it is brighter."""
    import mitsuba as mi

    from mitsnerf.env import set_variant

    set_variant(mi.variant())
    iso, forward = _backlit_radiance({"type": "isotropic"}), _backlit_radiance({"type": "hg", "g": 0.85})
    assert forward > 2.0 * iso


def test_an_anisotropic_medium_gets_the_directional_oracle(tmp_path):
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.oracle.cache import OracleConfig, ensure_oracle
    from mitsnerf.oracle.directional import DirectionalConfig

    small = {"cameras.width": 8, "cameras.height": 8, "cameras.n_train": 2, "cameras.n_test": 1,
             "render.spp_train": 4, "render.spp_test": 4, "volume.resolution": 16}
    spec = with_phase({"type": "hg", "g": 0.5}).with_overrides(small)
    dataset = load_dataset(generate_dataset(spec, tmp_path, progress=False))
    assert dataset.manifest["spec"]["volume"]["phase"] == {"type": "hg", "g": 0.5}
    config = OracleConfig(spp=4, resolution=8, directional=DirectionalConfig(spp=4, order=2,
                                                                            report_orders=(0,)))
    oracle = ensure_oracle(dataset, config, 1)
    assert oracle is not None and set(oracle.info["directional"]["psnr_test_medium_by_order"]) == {"0", "2"}
    assert (oracle.path / "lbar_sh.npy").is_file() and not (oracle.path / "lbar_mc.npy").exists()


def test_mitsuba_inverse_optimises_a_medium_with_the_datasets_phase_function():
    import mitsuba as mi

    from mitsnerf.env import set_variant
    from mitsnerf.methods import get_method
    from mitsnerf.methods.base import SceneInfo
    from mitsnerf.oracle.source import box_medium
    from mitsnerf.scene.to_mitsuba import scene_box

    set_variant(mi.variant())
    spec = with_phase({"type": "hg", "g": 0.85})
    method = get_method("mitsuba-inverse")
    config = method.config_type(**{**method.tiny, "carve": False})  # no training views: no emptiness mask
    model = method.model_type(config, SceneInfo(scene_box(spec), lambda d: 0.0, 1.0, {"spec": spec.to_dict()}), 0)
    assert str(box_medium(model.scene).phase_function()).replace("\n", "").replace(" ", "") == "HGPhaseFunction[g=[0.85]]"

