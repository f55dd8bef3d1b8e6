"""The medium alone: every split rendered again without the environment seen through the medium,
as a NeRF-synthetic dataset of its own (``DIR/medium``), and the world scale that puts a dataset
at NeRF-synthetic's box ``[-1.5, 1.5]^3``."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from mitsnerf import generate as gen
from mitsnerf.data.dataset import load_dataset
from mitsnerf.data.images import over, read_exr, read_png
from mitsnerf.math.color import srgb_to_linear
from mitsnerf.math.rays import camera_rays_numpy
from mitsnerf.render.background import ConstantBackground, make_background, pixel_background
from mitsnerf.runs.external import score_renders
from mitsnerf.scene.spec import nerf_synthetic_overrides, parse_scene
from mitsnerf.scene.to_mitsuba import background_description, scene_box, volume_grids
from mitsnerf.scoring.images import image_scores
from mitsnerf.scoring.medium import near_far_coverage

from .conftest import TINY

SKY = {"type": "sky", "zenith": [0.2, 0.3, 0.8], "horizon": [0.8, 0.8, 0.9], "ground": [0.3, 0.25, 0.2],
       "resolution": 32}


def small(**changes) -> dict:
    """The tiny spec at 16x16 with 256-spp test views: enough samples for the composite test to have power."""
    d = copy.deepcopy(TINY)
    d["cameras"].update(width=16, height=16, n_train=2, n_test=2)
    d["render"].update(spp_train=16, spp_test=256)
    for key, value in changes.items():
        d[key] = value
    return d


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    """A constant-environment and a sky dataset, generated once."""
    root = tmp_path_factory.mktemp("data")
    sky = small(lights=[SKY, TINY["lights"][1]], name="sky")
    return {name: gen.generate_dataset(parse_scene(d, f"{name}.toml"), root, progress=False)
            for name, d in (("constant", small()), ("sky", sky))}


def _stack(root, split):
    return np.stack([read_exr(p) for p in sorted((root / split).glob("r_*.exr"))])


def _environment(path):
    manifest = json.loads((path / "manifest.json").read_text())
    test = load_dataset(path).views("test")
    return pixel_background(make_background(manifest["background"], path), test.cameras)


@pytest.mark.parametrize("kind", ["constant", "sky"])
def test_composite_over_the_environment_reproduces_the_images(datasets, kind):
    """medium + (1 - alpha) environment is the full image (one pass: the image is composed from medium/):
    to float rounding under a constant environment; under a sky up to the exact term the composition adds,
    each pixel's covariance of T and L_env over its square, which is small. The statistical checks (the
    images against direct renders, medium/'s alpha against the exact 1 - T) are in test_one_pass.py."""
    path = datasets[kind]
    full, med = _stack(path, "test"), _stack(path / "medium", "test")
    env = _environment(path)
    diff = np.abs(full[..., :3] - over(med[..., :3], med[..., 3:4], env))
    if kind == "constant":
        assert diff.max() < 1e-5
    else:
        assert 0 < diff.max() < 0.02 * env.max() and diff.mean() < 1e-3 * env.mean()
    medium = json.loads((path / "manifest.json").read_text())["medium"]
    assert medium["composite_check"] is None and medium["transmittance_check"]["passed"]


def test_alpha_is_zero_where_rays_miss_the_box_and_full_images_keep_alpha_one(datasets):
    path = datasets["constant"]
    ds = load_dataset(path)
    med = _stack(path / "medium", "test")
    o, d = camera_rays_numpy(ds.views("test").cameras)
    _, _, hit = ds.box.intersect_numpy(o, d)
    alpha = med[..., 3].reshape(-1)
    assert (~hit).any() and np.all(alpha[~hit] == 0) and np.all(med[..., :3].reshape(-1, 3)[~hit] == 0)
    assert alpha.max() > 0.5
    assert np.all(_stack(path, "test")[..., 3] == 1)  # the full images: alpha 1 under an environment


def test_medium_view_is_a_nerf_synthetic_dataset(datasets):
    """What a NeRF-synthetic reader (nerfstudio's blender parser, TensoRF) does: transforms_{train,val,test}.json,
    camera_angle_x, file_path + ".png", RGBA composited on white; mitsnerf reads the same data alike."""
    root = datasets["constant"] / gen.MEDIUM_DIR
    for split in ("train", "val", "test", "test_ref"):
        doc = json.loads((root / f"transforms_{split}.json").read_text())
        assert 0 < doc["camera_angle_x"] < np.pi and doc["frames"]
        for frame in doc["frames"]:
            assert "." not in frame["file_path"].removeprefix("./")  # no extension, as NeRF-synthetic
            png = read_png(root / (frame["file_path"] + ".png"))
            assert png.shape == (16, 16, 4) and np.asarray(frame["transform_matrix"]).shape == (4, 4)
    val, test = (json.loads((root / f"transforms_{s}.json").read_text()) for s in ("val", "test"))
    assert val["frames"] == test["frames"]
    # straight alpha in the PNG, premultiplied in the EXR: both composite to the same image over white
    exr = read_exr(root / "test" / "r_000.exr")
    png = read_png(root / "test" / "r_000.png")
    from_png = srgb_to_linear(png[..., :3]) * png[..., 3:] + (1 - png[..., 3:])
    from_exr = exr[..., :3] + (1 - exr[..., 3:])
    unclipped = (exr[..., :3] <= exr[..., 3:]).all(axis=-1)  # the PNG clips straight colour to [0, 1]
    assert np.allclose(from_png[unclipped], np.clip(from_exr, 0, 1)[unclipped], atol=0.02)
    ds = load_dataset(root)
    assert ds.box_source == "transforms_train.json: aabb" and ds.box == scene_box(parse_scene(small(), "x"))
    assert np.allclose(ds.views("test").images[0], from_exr, atol=1e-6)  # EXR first, composited on white
    black = load_dataset(root, background=0.0).views("test").images[0]
    assert np.allclose(black, exr[..., :3], atol=1e-6)


def test_world_scale_scales_box_and_divides_sigma_t(tiny_dict):
    spec = parse_scene(tiny_dict, "t")
    scaled = spec.with_overrides({"world.scale": 3.0, "cameras.radius": 6.6})
    assert scene_box(scaled).to_list() == [[-1.5] * 3, [1.5] * 3]
    assert np.allclose(volume_grids(scaled)[0] * 3.0, volume_grids(spec)[0], rtol=1e-6)
    assert spec.to_dict() == parse_scene(spec.to_dict(), "copy").to_dict() and "world" not in spec.to_dict()
    assert scaled.to_dict()["world"] == {"scale": 3.0} and parse_scene(scaled.to_dict(), "copy") == scaled
    with pytest.raises(ValueError, match=r"cameras.radius: must be > 2.5981"):
        spec.with_overrides({"world.scale": 3.0})  # radius 2.2 lies inside the scaled box's bounding sphere


def test_world_scale_keeps_the_images(tmp_path):
    """A box 3 times larger with sigma_t / 3, seen from 3 times farther: the same images (same seeds)."""
    cams = {**TINY["cameras"], "n_train": 1, "n_test": 1}
    one = gen.generate_dataset(parse_scene(small(cameras=cams), "one"), tmp_path, progress=False)
    three = gen.generate_dataset(parse_scene(small(world={"scale": 3.0}, cameras={**cams, "radius": 6.6}), "three"),
                                 tmp_path, progress=False)
    a, b = _stack(one, "test"), _stack(three, "test")
    floor = json.loads((one / "manifest.json").read_text())["noise_floor"]["psnr"]
    assert image_scores(b[..., :3], a[..., :3], with_ssim=False)["psnr_test"] > floor + 3
    m3 = json.loads((three / "manifest.json").read_text())
    assert m3["box"] == [[-1.5] * 3, [1.5] * 3]
    assert load_dataset(three).box.to_list() == m3["box"]
    # the true grids and the scores follow the scale: the .vol's box is the scaled one, its own grid scores 0 error
    s = score_renders(load_dataset(three), three / "test_ref", density=three / "volume" / "sigma_t.vol", fmt="exr")
    assert s.metrics["psnr_test"] == m3["noise_floor"]["psnr"] and s.metrics["density_rel_l1"] == pytest.approx(0, abs=1e-6)
    assert s.metrics["tau_rel_l1"] < 1e-5 and s.reference.masks.any()


def test_nerf_synthetic_scale_fits_fixed_near_far(tiny_dict):
    """At the NeRF-synthetic scale every bit of the medium lies within near 2 .. far 6 of every test camera."""
    from mitsnerf.scene.rigs import camera_rig

    spec = parse_scene(tiny_dict, "t")
    for s, least, most in ((spec.with_overrides(nerf_synthetic_overrides()), 1.0, 1.0), (spec, 0.0, 0.99)):
        coverage = near_far_coverage(volume_grids(s)[0], scene_box(s), camera_rig(s.cameras, "test"),
                                     *gen.NERF_SYNTHETIC_NEAR_FAR)
        assert least - 1e-12 <= coverage <= most


def test_pixel_background_of_a_sky_is_the_mean_over_the_pixel(datasets):
    """Constant: exact; sky: between the values at the pixel's corners' directions (a box filter)."""
    path = datasets["sky"]
    cams = load_dataset(path).views("test").cameras
    env = pixel_background(make_background(background_description(parse_scene(small(lights=[SKY]), "s")), path), cams)
    assert env.shape == (2, 16, 16, 3) and np.all(env > 0)
    fine = pixel_background(make_background(json.loads((path / "manifest.json").read_text())["background"], path), cams,
                            footprint=8)
    assert np.allclose(env, fine, rtol=0.02)
    assert np.array_equal(pixel_background(ConstantBackground((1.0, 2.0, 3.0)), cams)[1, 5, 7], [1.0, 2.0, 3.0])
