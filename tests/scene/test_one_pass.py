"""One volpath pass per split: the images composed from the medium alone and the exact transmittance.

What is checked, with the statistics the harness uses everywhere (two independent pairs of renders, a
z-test and a dispersion ratio per view, the family held at 1e-3):

- the medium-alone render is the full render without the environment seen straight through the medium,
  and nothing else (the same paths with the same seed; in-scattered environment light stays);
- the composed images agree with volpath renders of the full scene, view by view (constant environment,
  sky, no environment), and are as noisy as those (``M`` plus the exact background alone would be noisier);
- ``medium/``'s alpha agrees with the exact ``1 - T`` (the manifest's ``transmittance_check``);
- a planted bug in the transmittance (pixel centre at the corner, the footprint ignored, the grid looked
  up half a voxel off) fails the transmittance check;
- lights that do not allow one pass get two, and the manifest says so.
"""

from __future__ import annotations

import copy
import functools
import json

import numpy as np
import pytest

from mitsnerf import generate as gen
from mitsnerf.data.images import read_exr
from mitsnerf.errors import SpecError
from mitsnerf.scene import render as scene_render
from mitsnerf.scene import transmittance as tr
from mitsnerf.scene.render import medium_alone_integrator, render_split
from mitsnerf.scene.rigs import camera_rig
from mitsnerf.scene.spec import parse_scene
from mitsnerf.scene.to_mitsuba import load_sensor, scene_box, scene_dict, volume_grids
from mitsnerf.scoring.agreement import transmittance_agreement, view_agreement
from mitsnerf.scoring.density import true_density

from .conftest import TINY

SKY = {"type": "sky", "zenith": [0.2, 0.3, 0.8], "horizon": [0.8, 0.8, 0.9], "ground": [0.3, 0.25, 0.2],
       "sun_direction": [0.3, 0.2, -1.0], "sun_glow": [2.0, 1.8, 1.5], "resolution": 32}
LIGHTS = {"constant": TINY["lights"], "sky": [SKY, TINY["lights"][1]], "none": [TINY["lights"][1]]}


def small(kind: str = "constant", **render) -> dict:
    """The tiny spec at 16x16, two test views at 256 spp: power enough for the per-view tests."""
    d = copy.deepcopy(TINY)
    d["name"] = f"one_{kind}"
    d["lights"] = copy.deepcopy(LIGHTS[kind])
    d["cameras"].update(width=16, height=16, n_train=2, n_test=2)
    d["render"].update({"spp_train": 16, "spp_test": 256, **render})
    return d


def _stack(root, split):
    return np.stack([read_exr(p) for p in sorted((root / split).glob("r_*.exr"))])


def _manifest(path):
    return json.loads((path / "manifest.json").read_text())


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("one_pass")
    return {kind: gen.generate_dataset(parse_scene(small(kind), f"{kind}.toml"), root, progress=False)
            for kind in LIGHTS}


@functools.cache
def direct(kind: str, seeds: tuple[str, str] = ("test_medium", "test_ref_medium")) -> tuple[np.ndarray, np.ndarray]:
    """Two renders of the test views by volpath with the environment visible (the full scene, directly), by
    default with seeds of their own (those of ``test_medium``, ``test_ref_medium``: independent of the dataset's)."""
    import mitsuba as mi

    spec = parse_scene(small(kind), "x.toml")
    scene = mi.load_dict(scene_dict(spec, *volume_grids(spec)))
    cams = camera_rig(spec.cameras, "test")
    return tuple(np.stack(render_split(scene, spec, "test", cams, False, seed_split=s)[0]) for s in seeds)


def test_one_pass_is_the_default_and_the_manifest_says_how(datasets):
    for kind, path in datasets.items():
        m = _manifest(path)
        assert m["format_version"] == gen.FORMAT_VERSION == 6
        assert m["render"]["passes"] == 1 and m["render"]["two_passes_because"] is None
        assert m["render"]["footprint"] == {"train": 8, "test": 8, "test_ref": 8}
        assert set(m["timings"]) == {"train", "test", "test_ref", "total_seconds"}  # no medium/ pass
        assert m["timings"]["test"]["transmittance_seconds"] > 0
        assert m["medium"]["composite_check"] is None
        assert m["medium"]["transmittance_check"]["passed"], (kind, m["medium"]["transmittance_check"])


def test_the_medium_alone_is_the_full_render_less_the_environment_seen_through_it(tiny_dict):
    """With one seed, volpath with and without hide_emitters traces the same paths: the full render minus the
    medium alone is exactly the escaped camera samples' environment, (1 - alpha) B for a constant B (to float
    rounding); the in-scattered environment light is in both. Without an environment they are one image."""
    import mitsuba as mi

    for kind in ("constant", "none"):
        spec = parse_scene(small(kind), "x.toml")
        scene = mi.load_dict(scene_dict(spec, *volume_grids(spec)))
        sensor = load_sensor(camera_rig(spec.cameras, "test")[0], 64)
        full = np.array(mi.render(scene, sensor=sensor, spp=64, seed=3))
        med = np.array(mi.render(scene, sensor=sensor, integrator=medium_alone_integrator(spec), spp=64, seed=3))
        if kind == "none":
            if mi.variant().startswith("cuda"):  # the film adds a pixel's samples by float atomics, in no fixed
                np.testing.assert_allclose(full, med, rtol=1e-5, atol=1e-6)  # order: 64 of them, ~4e-6 relative
            else:
                assert np.array_equal(full, med)
            continue
        background = np.asarray(LIGHTS["constant"][0]["radiance"])
        assert np.abs(full[..., :3] - (med[..., :3] + (1 - med[..., 3:]) * background)).max() < 1e-5
        inside = med[..., 3] > 0.5
        assert (med[..., :3][inside] > 0.05).all()  # lit by scattered light (the sun and the environment)


def _seen(path, split="test"):
    """What the pixels of ``split`` see through the medium, as generate computed it."""
    from mitsnerf.render.background import make_background

    m = _manifest(path)
    spec = parse_scene(m["spec"], "m")
    sigma_t, box = np.load(path / "volume" / "sigma_t.npy"), scene_box(spec)
    background = make_background(m["background"], path) if spec.environment is not None else None
    return tr.pixel_transmittance(true_density(sigma_t, box), sigma_t.shape[0], box,
                                  camera_rig(spec.cameras, "test" if split != "train" else "train"),
                                  footprint=m["render"]["footprint"][split], background=background)


@pytest.mark.parametrize("kind", list(LIGHTS))
def test_composed_images_agree_with_direct_renders(datasets, kind):
    path = datasets[kind]
    composed = _stack(path, "test"), _stack(path, "test_ref")
    check = view_agreement(*composed, *direct(kind))
    assert check["passed"] and len(check["views"]) == 2, check
    # as noisy as a direct render; M plus the exact background term alone would be noisier (the medium is
    # brighter than half the background: Var(direct) - Var(M + T B) = p (1 - p) B (B - 2 mu) < 0)
    noise = [float(np.mean((a[..., :3] - b[..., :3]) ** 2)) for a, b in (composed, direct(kind))]
    if kind == "constant":  # the direct render with the dataset's own seeds, sample for sample
        same_seeds = direct(kind, ("test", "test_ref"))
        assert all(np.abs(c - d).max() < 1e-5 for c, d in zip(composed, same_seeds))
    else:
        assert 0.5 < noise[0] / noise[1] < 2, noise
    if kind != "none":
        seen = _seen(path), _seen(path, "test_ref")
        exact_only = [_stack(path / gen.MEDIUM_DIR, s)[..., :3] + v.through for s, v in zip(("test", "test_ref"), seen)]
        assert float(np.mean((exact_only[0] - exact_only[1]) ** 2)) > 1.2 * noise[0]
        # the check has power: the environment seen through the medium 3% too bright is rejected
        bright = [np.concatenate([c[..., :3] + 0.03 * v.through, c[..., 3:]], axis=-1) for c, v in zip(composed, seen)]
        assert not view_agreement(*bright, *direct(kind))["passed"]


def test_full_alpha_is_one_under_an_environment_else_the_medium_alpha(datasets):
    for kind, path in datasets.items():
        full, med = _stack(path, "train"), _stack(path / gen.MEDIUM_DIR, "train")
        assert np.array_equal(full[..., 3], np.ones_like(full[..., 3]) if kind != "none" else med[..., 3])
        if kind == "none":
            assert np.array_equal(full, med)


def test_medium_alpha_agrees_with_the_exact_transmittance(datasets):
    path = datasets["constant"]
    spec = parse_scene(_manifest(path)["spec"], "m")
    sigma_t = np.load(path / "volume" / "sigma_t.npy")
    cams = camera_rig(spec.cameras, "test")
    box = scene_box(spec)
    t_mean = tr.pixel_transmittance(true_density(sigma_t, box), sigma_t.shape[0], box, cams).t
    alpha = _stack(path / gen.MEDIUM_DIR, "test")[..., 3]
    check = transmittance_agreement(alpha, t_mean, 256)
    recorded = _manifest(path)["medium"]["transmittance_check"]["splits"]["test"]
    assert check["passed"] and check["views"][0]["z"] == pytest.approx(recorded["views"][0]["z"])
    assert not transmittance_agreement(alpha * 0.97, t_mean, 256)["passed"]  # it has power


def _half_voxel_off(real, density, resolution, box, o, d, **kwargs):
    """optical_depths of the grid looked up half a voxel off (voxel corners taken for centres)."""
    import mitsuba as mi

    shift = mi.ScalarArray3f(*(s / (2 * resolution) for s in box.size))
    return real(lambda x: density(x + shift), resolution, box, o, d, **kwargs)


def _forcing(real, **forced):
    """``real`` with keyword arguments forced (over those its caller passes)."""
    return lambda *args, **kwargs: real(*args, **{**kwargs, **forced})


BUGS = {
    "pixel centre at the corner": ("pixel_transmittance", lambda real: _forcing(real, pixel_center=0.0)),
    "footprint ignored": ("pixel_transmittance", lambda real: _forcing(real, footprint=1)),
    "grid half a voxel off": ("optical_depths", lambda real: functools.partial(_half_voxel_off, real)),
}


@pytest.mark.parametrize("bug", list(BUGS))
def test_a_planted_bug_in_the_transmittance_fails_the_check(datasets, tmp_path, monkeypatch, bug):
    """medium/'s alpha against the exact 1 - T rejects each bug; the images do not depend on T under a constant
    environment (the exact term and the zero-mean term cancel there: M + (1 - alpha) B), so they stay right."""
    name, plant = BUGS[bug]
    monkeypatch.setattr(tr, name, plant(getattr(tr, name)))
    path = gen.generate_dataset(parse_scene(small("constant"), "bug.toml"), tmp_path, progress=False)
    assert path.name == datasets["constant"].name
    check = _manifest(path)["medium"]["transmittance_check"]
    assert not check["passed"] and not check["splits"]["test"]["passed"], bug
    assert np.allclose(_stack(path, "test"), _stack(datasets["constant"], "test"), atol=1e-5)


def test_lights_that_do_not_allow_one_pass_get_two(tmp_path, monkeypatch):
    monkeypatch.setattr(scene_render, "SEPARABLE_LIGHTS",
                        {k: v for k, v in scene_render.SEPARABLE_LIGHTS.items() if k != "sky"})
    spec = parse_scene(small("sky"), "sky.toml")
    assert "lights.0 ('sky')" in scene_render.one_pass_reason(spec)
    path = gen.generate_dataset(spec, tmp_path, progress=False)
    m = _manifest(path)
    assert m["render"]["passes"] == 2 and "lights.0" in m["render"]["two_passes_because"]
    assert {"medium/train", "medium/test", "medium/test_ref"} <= set(m["timings"])
    assert m["medium"]["composite_check"]["passed"] and m["medium"]["transmittance_check"]["passed"]
    seeds = [json.loads((root / "transforms_test.json").read_text())["render_seeds"]
             for root in (path, path / gen.MEDIUM_DIR)]
    assert not set(seeds[0]) & set(seeds[1])  # two independent passes
    check = view_agreement(_stack(path, "test"), _stack(path, "test_ref"), *direct("sky"))
    assert check["passed"], check


def test_max_depth_one_gets_two_passes(tmp_path):
    """With max_depth 1 volpath marks no camera sample as collided: the medium alone has alpha 0, which does not
    estimate 1 - T, so the image is rendered directly and the transmittance check says why it does not apply."""
    spec = parse_scene(small("constant", max_depth=1, spp_test=16), "depth1.toml")
    assert "max_depth = 1" in scene_render.one_pass_reason(spec)
    m = _manifest(gen.generate_dataset(spec, tmp_path, progress=False))
    assert m["render"]["passes"] == 2 and m["medium"]["transmittance_check"]["passed"] is None


def test_an_older_format_in_the_cache_is_rendered_again(datasets, monkeypatch):
    """A complete dataset of another format is not a cache hit: its manifest's format_version decides."""
    path = datasets["none"]
    spec = parse_scene(_manifest(path)["spec"], "m")
    assert gen._cache_state(path, _manifest(path)["hash"], False) == "ok"
    monkeypatch.setattr(gen, "FORMAT_VERSION", 5)
    assert gen._cache_state(path, _manifest(path)["hash"], False) == "missing"
    assert gen.dataset_dir(spec, path.parent) != path  # and the hash, hence the directory, differs


def chromatic_spec() -> dict:
    """:func:`small` with a chromatic extinction (blue stopped four times as often as red)."""
    d = small("constant")
    d["name"] = "one_chromatic"
    d["volume"]["sigma_t_scale"] = [10.0, 20.0, 40.0]
    return d


def _channel(images: np.ndarray, k: int) -> np.ndarray:
    """Channel ``k`` of RGBA images, as a grey RGB image (so a test over the channels sees it alone)."""
    return np.repeat(images[..., k:k + 1], 3, axis=-1)


def _agree_per_channel(x, x_ref, y, y_ref) -> list[dict]:
    return [view_agreement(*(_channel(v, k) for v in (x, x_ref, y, y_ref))) for k in range(3)]


def test_a_chromatic_medium_is_composed_per_channel_and_agrees_with_direct_renders(tmp_path):
    """Channel k of the image is M + T_k B_k, T_k through sigma_t[..., k]: each channel agrees with volpath's
    direct renders (independent seeds) view by view, and composing with the channels' mean T (a grey medium's
    rule) is rejected."""
    import mitsuba as mi

    spec = parse_scene(chromatic_spec(), "c.toml")
    path = gen.generate_dataset(spec, tmp_path, progress=False)
    m = _manifest(path)
    assert m["volume"]["chromatic"] and np.load(path / "volume" / "sigma_t.npy").shape == (16, 16, 16, 3)
    assert m["render"]["passes"] == 1 and m["medium"]["transmittance_check"]["passed"] is None
    assert m["render"]["composition"] == gen.COMPOSITION_CHROMATIC and "alpha term" in m["render"]["composition"]
    scene = mi.load_dict(scene_dict(spec, *volume_grids(spec)))
    cams = camera_rig(spec.cameras, "test")
    direct_renders = [np.stack(render_split(scene, spec, "test", cams, False, seed_split=s)[0])
                      for s in ("test_medium", "test_ref_medium")]
    composed = _stack(path, "test"), _stack(path, "test_ref")
    checks = _agree_per_channel(*composed, *direct_renders)
    assert all(c["passed"] and len(c["views"]) == 2 for c in checks), checks
    # the check has power: the grey rule (every channel through the channels' mean extinction) is rejected
    sigma_t = np.load(path / "volume" / "sigma_t.npy")
    box, bg = scene_box(spec), np.asarray(spec.lights[0].radiance)
    t_grey = tr.pixel_transmittance(true_density(sigma_t.mean(-1), box), 16, box, cams, footprint=8).t
    t_k = np.stack([tr.pixel_transmittance(true_density(sigma_t[..., k], box), 16, box, cams, footprint=8).t
                    for k in range(3)], axis=-1)
    grey = [np.concatenate([c[..., :3] + (t_grey[..., None] - t_k) * bg, c[..., 3:]], axis=-1) for c in composed]
    assert not all(c["passed"] for c in _agree_per_channel(*grey, *direct_renders))


def test_round_off_below_zero_is_no_negative_radiance_but_a_real_negative_is():
    """A 1x1x1 grid fills the box: a pixel whose every sample collided (alpha 1, M 0) sees the constant sky of
    0.6 through T = 3.3e-7, and is 0 exactly; float32 pixel means leave it 8e-15 below. That is float32
    rounding at the view's scale (its peak 0.6): passed and written as 0. A value below 0 by more stays refused."""
    from mitsnerf.data import verify
    from mitsnerf.scene.ground_truth import check_views

    sky = float(np.float32(0.6))
    medium = [np.array([[[5.7263066e-23] * 3 + [1.0], [0.0, 0.0, 0.0, 0.0]]], np.float32)]
    seen = tr.PixelTransmittance(np.array([[[3.306799101210345e-07, 1.0]]]),
                                 np.array([[[[1.984079460726207e-07] * 3, [sky] * 3]]]), np.full((1, 1, 2, 3), sky))
    image = scene_render.compose(medium, seen, has_environment=True)[0]
    assert -1e-14 < image[0, 0, :3].min() < 0 and image[0, 1, :3].min() == np.float32(sky)  # the case itself
    spec = parse_scene(TINY, "t.toml")
    check_views(spec, "test", [image])
    assert verify.without_roundoff(image)[0, 0, :3].tolist() == [0.0, 0.0, 0.0]
    for wrong in (-1e-5, -1e-3):  # a negative medium radiance, not rounding at a peak of 0.6
        bad = scene_render.compose([np.array([[[wrong, 0, 0, 1.0], [0, 0, 0, 0]]], np.float32)], seen, True)[0]
        assert verify.without_roundoff(bad)[0, 0, 0] < 0
        with pytest.raises(SpecError, match="1 negative radiance value"):
            check_views(spec, "test", [bad])
