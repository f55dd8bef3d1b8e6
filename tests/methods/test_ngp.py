import numpy as np
import pytest

from mitsnerf.fields.ngp import NGPConfig
from mitsnerf.fields.occupancy import OccupancyConfig
from mitsnerf.methods import get_method
from mitsnerf.methods.ngp import NGPMethodConfig, NGPModel
from mitsnerf.train import TrainConfig, train

TINY = NGPConfig(n_levels=4, log2_hashmap_size=12, base_resolution=8, max_resolution=32, hidden=16,
                 geo_features=7, color_hidden=16, sh_degree=1)


def test_training_lowers_the_loss_and_the_occupancy_grid_skips_empty_space(tiny_views):
    data, info = tiny_views()
    config = NGPMethodConfig(network=TINY, occupancy=OccupancyConfig(resolution=16, update_every=10), n_samples=32)
    model = NGPModel(config, info)
    result, _ = train(model, data, TrainConfig(steps=80, batch_rays=256, log_every=10), 2e-2, progress=False)
    losses = [h["loss"] for h in result.history]
    assert np.mean(losses[-2:]) < 0.5 * losses[0]
    assert model.grid.updates == 8
    assert model.active_fraction < 0.8
    assert 0.0 < model.grid.occupied_fraction() < 0.9
    state = model.extra_state()
    assert state["occupancy.rho"].shape == (16**3,)


def test_training_on_cooperative_vectors_follows_the_tensor_path(tiny_views, require_network_path):
    """The same seed and batches through the occupancy grid's updates: fp32 losses agree to round-off."""
    require_network_path("coopvec-fp32")
    import dataclasses

    data, info = tiny_views()
    losses = {}
    for path in ("tensor", "coopvec-fp32"):
        config = NGPMethodConfig(network=dataclasses.replace(TINY, network_path=path),
                                 occupancy=OccupancyConfig(resolution=16, update_every=10), n_samples=16)
        result, _ = train(NGPModel(config, info), data, TrainConfig(steps=30, batch_rays=128, log_every=10), 2e-2,
                          progress=False)
        losses[path] = [h["loss"] for h in result.history]
    np.testing.assert_allclose(losses["coopvec-fp32"], losses["tensor"], rtol=1e-3)
    assert losses["tensor"][-1] < 0.7 * losses["tensor"][0]


def test_without_occupancy_every_sample_is_evaluated(tiny_views):
    data, info = tiny_views(n_views=2, size=6)
    model = NGPModel(NGPMethodConfig(network=TINY, use_occupancy=False, n_samples=8), info)
    train(model, data, TrainConfig(steps=3, batch_rays=32), 1e-2, progress=False)
    assert model.grid is None and model.active_fraction == 1.0


def test_registered_with_its_config():
    entry = get_method("ngp")
    assert entry.config_type is NGPMethodConfig and entry.model_type is NGPModel
    with pytest.raises(ValueError, match="max_resolution"):
        NGPConfig(base_resolution=64, max_resolution=32)


def test_parameters_of_another_shape_are_refused_by_name(tiny_views):
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.methods.base import ParameterShapeError

    _, info = tiny_views()
    model = NGPModel(NGPMethodConfig(), info)
    key = next(k for k, v in model.parameters().items() if len(v.shape) == 2)
    wrong = dr.zeros(mi.TensorXf, (model.parameters()[key].shape[0] + 1, model.parameters()[key].shape[1]))
    with pytest.raises(ParameterShapeError, match="the method's config builds") as e:
        model.set_parameters({key: wrong})
    assert e.value.key == key


def test_one_density_per_colour_on_both_network_paths(require_network_path):
    """``network.density_channels = 3`` (chromatic media): the density MLP's first three outputs are the three
    extinctions (an Array3f sigma), the colour MLP takes the features after them; both paths agree."""
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.fields.ngp import NGPConfig, NGPField
    from mitsnerf.math.box import UNIT_BOX
    from mitsnerf.math.rays import host
    from mitsnerf.methods.ngp import NGPMethodConfig

    with pytest.raises(ValueError, match="replay: .* set replay = false"):
        NGPMethodConfig(network=NGPConfig(density_channels=3), replay=True)
    small = dict(n_levels=2, max_resolution=16, hidden=8, color_hidden=8, density_channels=3)
    f = NGPField(NGPConfig(**small), mi.TensorXf, UNIT_BOX, seed=3)
    assert f.sigma_channels == 3 and f.params["density.1.bias"].shape[-1] == 3 + f.config.geo_features
    # away from the near-zero start, so that a permuted channel or a wrong feature offset would show
    rng = np.random.default_rng(0)
    bias = f.params["density.1.bias"]
    shifts = np.zeros(bias.shape[-1], np.float32)
    shifts[:3] = (-4.0, 0.0, 4.0)  # red, green, blue extinctions e^4 apart
    f.set_parameters({"encoding.data": mi.Float(rng.uniform(-1, 1, dr.width(f.params["encoding.data"]))),
                      "density.1.bias": type(bias)(shifts.reshape(bias.shape))})
    x, d = mi.Array3f([0.1, -0.2, 0.3], [0.0, 0.2, -0.1], 0.05), mi.Array3f(0, 0, 1)
    rgb, sigma = f(x, d)
    s = host(sigma)
    assert s.shape == (3, 3) and np.allclose(host(f.density(x)), s)
    assert np.all(s[:, 0] < s[:, 1]) and np.all(s[:, 1] < s[:, 2])  # the extinctions are the first three outputs
    require_network_path("coopvec-fp32")
    coop = NGPField(NGPConfig(**small, network_path="coopvec-fp32"), mi.TensorXf, UNIT_BOX, seed=3)
    coop.set_parameters(f.params)
    rgb_c, sigma_c = coop(x, d)
    np.testing.assert_allclose(host(sigma_c), s, rtol=1e-4)
    np.testing.assert_allclose(host(rgb_c), host(rgb), rtol=1e-4)


def test_the_replayed_march_is_refused_where_fp32_cooperative_vectors_are_missing(tiny_views, monkeypatch):
    """On CUDA (no coopvec-fp32) the replayed march needs the fp16 path: any other network_path with replay = true
    is refused when the model is built, naming replay and both ways out; fp16 is built."""
    import dataclasses

    import mitsnerf.fields.ngp as ngp_field
    from mitsnerf.errors import SpecError

    _, info = tiny_views(n_views=2, size=6)
    monkeypatch.setattr(ngp_field, "usable_network_paths", lambda TensorXf: ("auto", "tensor", "coopvec-fp16"))
    for path in ("auto", "tensor"):
        config = NGPMethodConfig(network=dataclasses.replace(TINY, network_path=path), replay=True)
        with pytest.raises(SpecError, match=r"^replay: the replayed march cannot run here: .* fp32 cooperative "
                                            r"vectors .*set network.network_path = coopvec-fp16, or replay = false$"):
            NGPModel(config, info)
    NGPModel(NGPMethodConfig(network=dataclasses.replace(TINY, network_path="auto")), info)  # no replay: fine
    model = NGPModel(NGPMethodConfig(network=dataclasses.replace(TINY, network_path="coopvec-fp16"), replay=True), info)
    assert model.loop_field().half
