"""The Mitsuba side: camera convention, sky envmap mapping, determinism, grids."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mitsnerf.math.camera import Camera, look_at
from mitsnerf.scene.lights import SKY_TO_WORLD, bake_sky, emitter_dict, envmap_eval, sky_radiance
from mitsnerf.scene.rigs import camera_rig
from mitsnerf.scene.spec import UP, SkyLight
from mitsnerf.scene.to_mitsuba import (
    background_description,
    load_sensor,
    scene_dict,
    sensor_dict,
    volume_grids,
)


def _render(scene, camera: Camera, spp: int, seed: int = 0) -> np.ndarray:
    import mitsuba as mi

    return np.array(mi.render(scene, sensor=load_sensor(camera, spp), spp=spp, seed=seed))


def _hot_blob(p: np.ndarray, r: int = 32, sigma: float = 0.03, peak: float = 40.0) -> np.ndarray:
    c = (np.arange(r) + 0.5) / r - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    d2 = (x - p[0]) ** 2 + (y - p[1]) ** 2 + (z - p[2]) ** 2
    return (peak * np.exp(-d2 / (2 * sigma**2))).astype(np.float32)


def test_camera_convention_hot_blob(tiny_spec):
    """An absorbing blob at a known world point is darkest where camera.project puts it."""
    import mitsuba as mi

    p = np.array([0.22, -0.13, 0.17])
    sigma_t = _hot_blob(p)
    albedo = np.zeros(sigma_t.shape + (3,), np.float32)
    spec = tiny_spec.with_overrides({"lights": [{"type": "constant", "radiance": [1.0, 1.0, 1.0]}]})
    scene = mi.load_dict(scene_dict(spec, sigma_t, albedo))
    # non-square images (transposition errors show), varied orientations incl. near the poles
    origins = [(2.0, 0.3, 0.4), (-0.5, -2.1, 0.9), (0.2, 0.4, 2.3), (0.3, -0.2, -2.2), (-1.6, 1.4, -0.5)]
    for o in origins:
        cam = Camera.from_fov(look_at(o, (0.0, 0.0, 0.0), UP), 24, 16, 30.0)
        img = _render(scene, cam, spp=64)
        dark = 1.0 - img[..., 0]
        row, col = np.unravel_index(np.argmax(dark), dark.shape)
        u, v = cam.project(p[None])[0]
        assert abs(u - (col + 0.5)) <= 1.0 and abs(v - (row + 0.5)) <= 1.0, (o, (u, v), (col, row))
        # darkness-weighted centroid: sub-pixel agreement
        w = np.where(dark > 0.3 * dark.max(), dark, 0.0)
        rows, cols = np.indices(dark.shape)
        cu, cv = (w * (cols + 0.5)).sum() / w.sum(), (w * (rows + 0.5)).sum() / w.sum()
        assert abs(cu - u) < 0.35 and abs(cv - v) < 0.35, (o, (u, v), (cu, cv))


def test_sensor_matches_camera():
    cam = Camera.from_fov(look_at((1.0, -2.0, 0.5)), 20, 10, 35.0)
    sensor = load_sensor(cam, 4)
    m = np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
    assert np.allclose(m, cam.mitsuba_to_world(), atol=1e-6)
    assert np.allclose(m @ np.diag([-1.0, 1.0, -1.0, 1.0]), cam.c2w, atol=1e-6)
    film = sensor.film()
    assert tuple(film.size()) == (20, 10)
    off = Camera(cam.c2w, 20, 10, cam.fl_x, cam.fl_y, 9.0, 5.0)
    with pytest.raises(ValueError, match="centred"):
        sensor_dict(off, 4)


SKY = SkyLight(zenith=(0.1, 0.25, 0.9), horizon=(0.9, 0.8, 0.7), ground=(0.3, 0.2, 0.1),
               sun_direction=(0.3, -0.4, -0.6), sun_glow=(2.0, 1.5, 1.0), sun_sharpness=20.0, scale=1.5,
               resolution=128)


def test_sky_envmap_matches_mitsuba():
    """Mitsuba's envmap lookup of the baked sky equals envmap_eval and, up to interpolation, the formula."""
    import mitsuba as mi

    scene = mi.load_dict({"type": "scene", "integrator": {"type": "volpath"}, "sky": emitter_dict(SKY)})
    # up, down, horizon and towards the sun's glow; narrow fov so a pixel's footprint is small
    for target in [(0, 0, 1), (0, 0, -1), (1, 0, 0.05), (-0.3, 0.4, 0.6), (0.2, 1, -0.3)]:
        cam = Camera.from_fov(look_at((0, 0, 0), target, UP), 12, 8, 12.0)
        img = _render(scene, cam, spp=16)[..., :3]
        _, d = cam.pixel_rays()
        ours = envmap_eval(bake_sky(SKY), SKY_TO_WORLD, d, SKY.scale).reshape(img.shape)
        assert np.allclose(img, ours, rtol=0.01, atol=2e-3), target
        exact = sky_radiance(SKY, d).reshape(img.shape)
        assert np.allclose(img, exact, rtol=0.03, atol=0.02), target
    plain = dataclasses.replace(SKY, sun_glow=(0.0, 0.0, 0.0))
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.6, 0.8, 0.0]])
    expected = np.array([SKY.zenith, SKY.ground, SKY.horizon]) * SKY.scale
    assert np.allclose(sky_radiance(plain, d), expected, atol=1e-12)


def test_background_description(tiny_spec):
    assert background_description(tiny_spec) == {"type": "constant", "radiance": [0.5, 0.55, 0.6]}
    sky = tiny_spec.with_overrides({"lights.0": SKY.to_dict()})
    bg = background_description(sky)
    assert bg["type"] == "envmap" and bg["file"] == "volume/envmap.exr" and bg["scale"] == 1.5
    assert np.allclose(bg["to_world"], SKY_TO_WORLD)
    dark = tiny_spec.with_overrides({"lights": [{"type": "point", "position": [1, 1, 1], "intensity": [1, 1, 1]}]})
    assert background_description(dark) == {"type": "constant", "radiance": [0.0, 0.0, 0.0]}


def test_grids_and_render_deterministic(tiny_spec):
    import mitsuba as mi

    s1, a1 = volume_grids(tiny_spec)
    s2, a2 = volume_grids(tiny_spec)
    assert s1.dtype == np.float32 and s1.shape == (16, 16, 16) and a1.shape == (16, 16, 16, 3)
    assert np.array_equal(s1, s2) and np.array_equal(a1, a2)
    assert s1.max() <= 30.0 + 1e-4 and s1.max() > 10.0  # sigma_t = 30 * density, density in [0, 1]
    cam = camera_rig(tiny_spec.cameras, "test")[0]
    r1 = _render(mi.load_dict(scene_dict(tiny_spec, s1, a1)), cam, 8, seed=5)
    r2 = _render(mi.load_dict(scene_dict(tiny_spec, s2, a2)), cam, 8, seed=5)
    r3 = _render(mi.load_dict(scene_dict(tiny_spec, s2, a2)), cam, 8, seed=6)
    assert np.array_equal(r1, r2)
    assert not np.array_equal(r1, r3)
    assert r1.shape == (8, 8, 4) and np.all(r1[..., 3] == 1.0)  # alpha is 1 with an environment
