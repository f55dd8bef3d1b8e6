import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.math.box import UNIT_BOX
from mitsnerf.fields.voxel import VoxelField, VoxelFieldConfig, total_variation, upsample
from mitsnerf.methods import get_method
from mitsnerf.methods.base import ParameterShapeError
from mitsnerf.methods.voxel import SH_KEY, SIGMA_KEY, VoxelMethodConfig, VoxelModel
from mitsnerf.train import TrainConfig, make_optimizer, train


def test_training_lowers_the_loss_and_upsamples_on_schedule(tiny_views):
    data, info = tiny_views()
    config = VoxelMethodConfig(resolution=16, initial_resolution=8, upsample_steps=(40,), n_samples=32)
    model = VoxelModel(config, info)
    result, opt = train(model, data, TrainConfig(steps=80, batch_rays=256, log_every=10), 0.3, progress=False)
    losses = [h["loss"] for h in result.history]
    assert np.mean(losses[-2:]) < 0.5 * losses[0]
    assert model.resolution == 16
    assert opt[SIGMA_KEY].shape == (16, 16, 16, 1) and opt[SH_KEY].shape == (16, 16, 16, 12)
    # the model renders the optimiser's (upsampled) grids
    assert model.parameters()[SIGMA_KEY].shape == (16, 16, 16, 1)


def test_upsampling_keeps_the_rendered_field():
    rng = np.random.default_rng(0)
    r = 8
    c = (np.arange(r) + 0.5) / r
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    smooth = np.sin(2 * x + y) + z**2
    sigma_raw = mi.TensorXf(smooth[..., None].astype(np.float32))
    sh = mi.TensorXf(np.repeat(smooth[..., None], 12, -1).astype(np.float32))
    f = VoxelField(VoxelFieldConfig(), sigma_raw, sh, UNIT_BOX)
    g = f.with_grids(upsample(sigma_raw, 2 * r), upsample(sh, 2 * r))
    assert g.resolution == 2 * r
    p = rng.uniform(-0.4, 0.4, (2000, 3)).astype(np.float32)
    x3 = mi.Array3f(*p.T)
    np.testing.assert_allclose(np.asarray(g.density(x3)), np.asarray(f.density(x3)), rtol=0.02)


def test_upsample_is_exact_on_linear_grids():
    # Trilinear interpolation reproduces a linear function away from the clamped border.
    r = 4
    c = (np.arange(r) + 0.5) / r
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    lin = (x + 2 * y - z).astype(np.float32)[..., None]
    up = upsample(mi.TensorXf(lin), 8).numpy()[..., 0]
    c8 = (np.arange(8) + 0.5) / 8
    z8, y8, x8 = np.meshgrid(c8, c8, c8, indexing="ij")
    inner = (slice(1, 7),) * 3
    np.testing.assert_allclose(up[inner], (x8 + 2 * y8 - z8)[inner], atol=1e-5)


def test_total_variation_is_zero_on_constants_and_pulls_neighbours_together():
    g = dr.full(mi.TensorXf, 3.0, (4, 4, 4, 2))
    assert total_variation(g)[0] == 0.0
    a = np.zeros((4, 4, 4, 1), np.float32)
    a[1, 2, 3] = 1.0
    t = mi.TensorXf(a)
    dr.enable_grad(t)
    dr.backward(total_variation(t))
    grad = dr.grad(t).numpy()
    assert grad[1, 2, 3, 0] > 0 and grad[1, 2, 2, 0] < 0


def test_a_resumed_model_takes_upsampled_grids():
    from mitsnerf.methods.base import SceneInfo
    from mitsnerf.render.background import ConstantBackground

    info = SceneInfo(UNIT_BOX, ConstantBackground((0, 0, 0)), 1.0)
    config = VoxelMethodConfig(resolution=8, initial_resolution=4, upsample_steps=(3,), n_samples=8)
    model = VoxelModel(config, info)
    opt = make_optimizer(model, 0.1)
    assert model.after_step(2, opt) == {}
    assert model.resolution == 4
    opt.update(model.after_step(3, opt))  # the trainer writes the upsampled grids into the optimiser
    assert model.resolution == 8 and opt[SH_KEY].shape == (8, 8, 8, 12)
    fresh = VoxelModel(config, info)
    fresh.set_parameters({k: opt[k] for k in opt.keys()})
    assert fresh.resolution == 8
    assert config.resolution_at(3) == 4 and config.resolution_at(4) == 8


def test_grids_of_another_shape_are_refused_naming_the_parameter():
    from mitsnerf.methods.base import ParameterShapeError, SceneInfo
    from mitsnerf.render.background import ConstantBackground

    config = VoxelMethodConfig(resolution=8, initial_resolution=4, upsample_steps=(3,), n_samples=8)
    model = VoxelModel(config, SceneInfo(UNIT_BOX, ConstantBackground((0, 0, 0)), 1.0))
    with pytest.raises(ParameterShapeError, match=r"\(3, 5\)") as bad_sh:
        model.set_parameters({SH_KEY: mi.TensorXf(np.zeros((3, 5), np.float32))})
    with pytest.raises(ParameterShapeError) as mixed:  # an 8^3 density with the current 4^3 colours
        model.set_parameters({SIGMA_KEY: mi.TensorXf(np.zeros((8, 8, 8, 1), np.float32))})
    assert (bad_sh.value.key, mixed.value.key) == (SH_KEY, SH_KEY) and mixed.value.want == (8, 8, 8, 12)
    assert model.resolution == 4


def test_config_is_validated():
    assert get_method("voxel").config_type is VoxelMethodConfig
    with pytest.raises(ValueError, match="upsample_steps"):
        VoxelMethodConfig(resolution=64, initial_resolution=16, upsample_steps=(10,))
    with pytest.raises(ValueError, match="power of 2"):
        VoxelMethodConfig(resolution=48, initial_resolution=32, upsample_steps=(10,))
    with pytest.raises(ValueError, match="sh_degree"):
        VoxelFieldConfig(sh_degree=4)


def _tv_numpy(g):
    return sum(np.mean(np.diff(g, axis=a) ** 2) for a in range(3))


def test_total_variation_value_and_gradient_match_numpy():
    rng = np.random.default_rng(1)
    g = rng.normal(size=(5, 4, 3, 2)).astype(np.float32)
    t = mi.TensorXf(g)
    dr.enable_grad(t)
    tv = total_variation(t)
    np.testing.assert_allclose(tv[0], _tv_numpy(g.astype(np.float64)), rtol=1e-5)
    dr.backward(2.0 * tv)
    grad = dr.grad(t).numpy()
    eps = 1e-3
    for index in [(0, 0, 0, 0), (2, 1, 1, 1), (4, 3, 2, 0), (1, 3, 0, 1)]:
        gp, gm = g.astype(np.float64).copy(), g.astype(np.float64).copy()
        gp[index] += eps
        gm[index] -= eps
        fd = 2.0 * (_tv_numpy(gp) - _tv_numpy(gm)) / (2 * eps)
        assert grad[index] == pytest.approx(fd, rel=1e-3, abs=1e-5)


def test_one_density_per_colour_trains_and_renders_each_channel_with_its_own():
    """``grid.density_channels = 3`` (chromatic media): a (R, R, R, 3) density grid, an Array3f sigma, each colour
    composited with its own extinction; the replayed march, which carries one extinction per ray, is refused."""
    from mitsnerf.render.volume import render_rays

    with pytest.raises(ValueError, match="replay: .* set replay = false"):
        VoxelMethodConfig(grid=VoxelFieldConfig(density_channels=3))
    config = VoxelFieldConfig(density_channels=3, sh_degree=0)
    raw = np.stack([np.full((4, 4, 4), v, np.float32) for v in (-3.0, 0.0, 2.0)], axis=-1)
    field = VoxelField(config, mi.TensorXf(raw), dr.zeros(mi.TensorXf, (4, 4, 4, 3)), UNIT_BOX)
    assert field.sigma_channels == 3
    o, d = mi.Array3f(0, 0, -2), mi.Array3f(0, 0, 1)
    out = render_rays(field, o, d, 32, box=UNIT_BOX, background=1.0)
    tau = config.sigma_scale * np.log1p(np.exp([-3.0, 0.0, 2.0])) * (1.0 - 1.0 / 64)  # seed's rule: L - h/2
    np.testing.assert_allclose(np.asarray(out.T_final).ravel(), np.exp(-tau), rtol=1e-4)
    assert float(out.rgb.x[0]) > float(out.rgb.y[0]) > float(out.rgb.z[0])  # red sees most of the white background
    model = VoxelModel(VoxelMethodConfig(grid=config, replay=False, resolution=8, initial_resolution=8,
                                         upsample_steps=(), use_occupancy=False), _info())
    with pytest.raises(ParameterShapeError) as err:  # a grey grid (a run of the default config) is refused
        model.set_parameters({SIGMA_KEY: dr.zeros(mi.TensorXf, (8, 8, 8, 1))})
    assert err.value.key == SIGMA_KEY and err.value.want == (8, 8, 8, 3)


def _info():
    from mitsnerf.methods.base import SceneInfo

    return SceneInfo(box=UNIT_BOX, background=lambda d: mi.Array3f(0.0), radiance_max=1.0)


def test_a_per_colour_model_trains(tiny_views):
    data, info = tiny_views()
    config = VoxelMethodConfig(grid=VoxelFieldConfig(density_channels=3), replay=False, resolution=8,
                               initial_resolution=8, upsample_steps=(), n_samples=16)
    model = VoxelModel(config, info)
    result, opt = train(model, data, TrainConfig(steps=30, batch_rays=128, log_every=10), 0.3, progress=False)
    assert opt[SIGMA_KEY].shape == (8, 8, 8, 3)
    assert result.history[-1]["loss"] < result.history[0]["loss"]


@pytest.mark.parametrize("sh_degree", [0, 2])
def test_a_bright_colour_range_starts_the_colour_grey(tiny_views, sh_degree):
    """Bright training views (cloud_hg85's sun seen through the cloud) raise ``c_max`` (``cover_radiance``); the SH
    colour starts at 0.5 in every direction whatever ``c_max`` is, not at ``c_max / 2``, a start brighter than the
    medium that the fit answered by clearing the density (docs/notes/physics-table.md, "The table at 88c2ab4")."""
    from dataclasses import replace

    _, info = tiny_views()
    config = VoxelMethodConfig(resolution=8, initial_resolution=8, upsample_steps=(),
                               grid=VoxelFieldConfig(sh_degree=sh_degree))
    model = VoxelModel(config, replace(info, radiance_max=10.0))
    assert model.base_field.config.c_max == pytest.approx(12.5)
    rng = np.random.default_rng(2)
    x = mi.Array3f(*rng.uniform(-0.5, 0.5, (3, 256)).astype(np.float32))
    d = dr.normalize(mi.Array3f(*rng.normal(size=(3, 256)).astype(np.float32)))
    rgb, _ = model.base_field(x, d)
    assert np.allclose(np.asarray(rgb), 0.5, atol=1e-5)
