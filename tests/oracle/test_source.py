"""The estimator of J: volpath from inside the medium, uniform directions, 1/4pi; the delta lights' term."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mitsnerf.math.box import UNIT_BOX, march_transmittance
from mitsnerf.oracle.source import delta_radiance, mean_radiance, needed_voxels
from mitsnerf.scene.spec import DirectionalLight, PointLight
from mitsnerf.scoring.density import true_density
from mitsnerf.verify import mitsuba_refs as M


def _grid(r: int = 8, peak: float = 6.0) -> np.ndarray:
    c = (np.arange(r) + 0.5) / r - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    return (peak * np.exp(-((x - 0.1) ** 2 + y**2 + z**2) / 0.05)).astype(np.float32)


def _scene(sigma_t, albedo, max_depth=-1, env=(1.0, 1.0, 1.0)):
    import mitsuba as mi

    return mi.load_dict(M.scene_dict(sigma_t, albedo, {"env": M.constant_environment(env)}, max_depth))


POINTS = np.array([[0.1, 0.0, 0.0], [-0.3, 0.2, 0.1], [0.4, -0.4, 0.45]])


def test_white_furnace_gives_one_in_a_heterogeneous_medium():
    """Albedo 1 inside radiance 1: L = 1 in every direction, so the mean radiance is exactly 1."""
    mean, se = mean_radiance(_scene(_grid(), 1.0), POINTS, 2048, seed=3)
    assert np.all(se < 0.02)
    assert np.all(np.abs(mean - 1.0) < 5 * se + 1e-6), (mean, se)


def _sphere_directions(n: int) -> np.ndarray:
    """A Fibonacci lattice: n nearly uniform unit vectors (a deterministic quadrature over the sphere)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def test_first_segment_is_attenuated_from_inside_the_medium():
    """max_depth 1 (no scattering): ``Lbar = Le (1 / 4 pi) int T(x, w) dw``, T through the heterogeneous
    medium from x to the box; a ray started without its medium would see Le unattenuated, and a
    wrong direction pdf would scale the mean."""
    import mitsuba as mi

    sigma_t, le = _grid(peak=20.0), np.array([0.3, 0.6, 0.9])
    mean, se = mean_radiance(_scene(sigma_t, 0.5, max_depth=1, env=le), POINTS, 4096, seed=5)
    w = _sphere_directions(20000)
    density = true_density(sigma_t, UNIT_BOX)
    means = []
    for p, m, s in zip(POINTS, mean, se):
        x = mi.Array3f(*(np.repeat(p[None], len(w), 0).T.astype(np.float32)))
        T = np.asarray(march_transmittance(density, x, mi.Array3f(*w.T.astype(np.float32)), 256, UNIT_BOX))
        expected = le * T.mean()
        assert np.all(np.abs(m - expected) < 5 * s + 1e-3 * expected), (m, expected, s)
        means.append(T.mean())
    assert min(means) < 0.6  # the medium is thick enough that attenuation matters


def test_delta_radiance_of_directional_and_point_lights():
    """``(1 / 4 pi) sum E T``: a sun in vacuum gives E / 4pi; a point light I / (4 pi r^2) times T."""
    sun = DirectionalLight(direction=(0.0, 0.0, -2.0), irradiance=(1.0, 2.0, 3.0))
    lamp = PointLight(position=(0.0, 0.0, 1.5), intensity=(4.0, 4.0, 4.0))
    vacuum = delta_radiance([sun, lamp], lambda x: 0.0 * x.x, np.zeros((1, 3)), UNIT_BOX, 16)
    expected = (np.array([1.0, 2.0, 3.0]) + 4.0 / 1.5**2) / (4 * math.pi)
    np.testing.assert_allclose(vacuum[0], expected, rtol=1e-5)
    inside = PointLight(position=(0.0, 0.0, 0.25), intensity=(1.0, 1.0, 1.0))  # in the box: march only to it
    slab = delta_radiance([inside], lambda x: 2.0 + 0.0 * x.x, np.zeros((1, 3)), UNIT_BOX, 16)
    np.testing.assert_allclose(slab[0], np.exp(-0.5) / 0.25**2 / (4 * math.pi), rtol=1e-5)


@pytest.mark.parametrize("resolution", [4, 8, 13])
def test_needed_voxels_cover_every_lookup_where_sigma_t_is_not_zero(resolution):
    """A grid that is 0 on the needed voxels and 1 elsewhere reads 0 wherever sigma_t(x) > 0."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField

    sigma_t = np.zeros((8, 8, 8), np.float32)
    sigma_t[2:4, 3, 5] = 1.0
    sigma_t[7, 0, 0] = 1.0  # a corner: the clamped border
    marker = (~needed_voxels(sigma_t, resolution)).astype(np.float32)[..., None].repeat(3, -1)
    field = GridField.from_arrays(sigma_t, UNIT_BOX, color=marker)
    p = np.random.default_rng(0).uniform(-0.5, 0.5, (200000, 3))
    rgb, sigma = field(mi.Array3f(*p.T.astype(np.float32)), mi.Array3f(0, 0, 1))
    hit = np.asarray(sigma) > 0
    assert hit.sum() > 100
    assert np.abs(np.asarray(rgb[0])[hit]).max() == 0.0
    assert needed_voxels(sigma_t, resolution).mean() < 0.7  # and it does leave voxels out
