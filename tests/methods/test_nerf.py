import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.grid import GridField
from mitsnerf.fields.nerf import NeRFConfig
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.methods.base import SceneInfo
from mitsnerf.methods.nerf import NeRFMethodConfig, NeRFModel
from mitsnerf.render.background import ConstantBackground
from mitsnerf.render.rays import camera_rays
from mitsnerf.render.volume import render_rays
from mitsnerf.train import PixelData, TrainConfig, train


def _synthetic_views(blob_grid, n_views=6, size=12):
    rng = np.random.default_rng(0)
    cams = []
    for _ in range(n_views):
        v = rng.normal(size=3)
        cams.append(Camera.from_fov(look_at(2.0 * v / np.linalg.norm(v)), size, size, 40.0))
    bg = ConstantBackground((0.05, 0.1, 0.3))
    gt = GridField.from_arrays(blob_grid, color=(1.0, 0.9, 0.1))
    rays = camera_rays(mi.Array3f, cams)
    with dr.suspend_grad():
        comp = render_rays(gt, rays.o, rays.d, 64, background=bg)
    images = np.stack([np.asarray(c) for c in comp.rgb], -1).reshape(n_views, size, size, 3)
    return images, cams, bg


def test_nerf_density_depends_on_position_only():
    info = SceneInfo((-0.5,) * 3, (0.5,) * 3, ConstantBackground((0, 0, 0)), 1.0)
    model = NeRFModel(NeRFMethodConfig(network=NeRFConfig(width=16, depth=2)), info)
    x = mi.Array3f([0.1, 0.1], [0.2, 0.2], [-0.3, -0.3])
    d = mi.Array3f([1.0, 0.0], [0.0, 0.0], [0.0, 1.0])
    rgb, sigma = model.field()(x, d)
    s = np.asarray(sigma)
    assert s[0] == s[1]
    assert not np.allclose(np.asarray(rgb.x)[0], np.asarray(rgb.x)[1])


def test_a_few_training_steps_lower_the_loss(blob_grid):
    images, cams, bg = _synthetic_views(blob_grid)
    data = PixelData.from_views(images, cams)
    info = SceneInfo((-0.5,) * 3, (0.5,) * 3, bg, float(images.max()))
    model = NeRFModel(NeRFMethodConfig(network=NeRFConfig(width=32, depth=2), n_samples=24), info)
    result, _ = train(model, data, TrainConfig(steps=80, batch_rays=256, log_every=10), 2e-2, progress=False)
    losses = [h["loss"] for h in result.history]
    assert result.steps == 80
    print(losses); assert np.mean(losses[-2:]) < 0.5 * losses[0]
    assert result.rays_per_s > 0
    assert result.samples_per_s == pytest.approx(result.rays_per_s * 24)


def test_training_is_deterministic_for_a_seed(blob_grid):
    images, cams, bg = _synthetic_views(blob_grid, n_views=3, size=8)
    data = PixelData.from_views(images, cams)
    info = SceneInfo((-0.5,) * 3, (0.5,) * 3, bg, float(images.max()))
    params = []
    for _ in range(2):
        model = NeRFModel(NeRFMethodConfig(network=NeRFConfig(width=8, depth=1), n_samples=8), info, seed=3)
        train(model, data, TrainConfig(steps=5, batch_rays=64, seed=7), 1e-2, progress=False)
        params.append({k: np.asarray(v) for k, v in model.parameters().items()})
    for key in params[0]:
        np.testing.assert_array_equal(params[0][key], params[1][key])
