"""The ``scatter`` method: it reads the lights and the phase function from the dataset's spec (and refuses data
without one), sizes its medium from them, and trains."""

from __future__ import annotations

from dataclasses import replace

import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.errors import DatasetError
from mitsnerf.fields.media import cell_centres
from mitsnerf.math.carve import carve
from mitsnerf.methods.base import SceneInfo
from mitsnerf.methods.scatter import ScatterMethodConfig, ScatterModel
from mitsnerf.train import TrainConfig, train

from ..conftest import tiny_scene

SMALL = {"hash": {"n_levels": 2, "log2_hashmap_size": 10, "base_resolution": 8, "max_resolution": 16, "hidden": 16,
                  "color_hidden": 16},
         "field": {"shadow_resolution": 8, "shadow_samples": 8, "shadow_density_resolution": 8}, "n_samples": 32}


def _config(**changes) -> ScatterMethodConfig:
    from mitsnerf.config import from_dict

    return from_dict(ScatterMethodConfig, {**SMALL, **changes})


def _with_spec(info: SceneInfo, overrides: dict | None = None) -> SceneInfo:
    return replace(info, manifest={"spec": tiny_scene(overrides)})


def test_data_without_a_spec_is_refused_in_one_line(tiny_views):
    """Foreign data (no manifest, as a NeRF-synthetic folder): the line says so and names no manifest.json, which
    such a folder does not have (it used to); a manifest without its spec is named."""
    _, info = tiny_views(n_views=2, size=4)
    with pytest.raises(DatasetError, match=r"^scatter needs a dataset made by 'mitsnerf generate' \(its spec gives "
                                           r"the lights and the phase function\); this one is foreign data "
                                           r"\(NeRF-synthetic or instant-ngp\), which holds no scene spec$"):
        ScatterModel(_config(), info)
    with pytest.raises(DatasetError, match=r"^manifest.json: spec: scatter needs a dataset made by 'mitsnerf "):
        ScatterModel(_config(), replace(info, manifest={"name": "old"}))


@pytest.mark.parametrize(("overrides", "channels", "basis", "k"), [
    ({}, 1, (0, 0), 1),                                                     # isotropic, grey
    ({"volume.sigma_t_scale": [20.0, 30.0, 45.0]}, 3, (0, 0), 1),          # chromatic: a density per colour
    ({"volume.phase": {"type": "hg", "g": 0.85}}, 1, (3, 8), 16 + 5),      # anisotropic: SH 3 + zonal 4..8
])
def test_the_medium_is_sized_from_the_spec(tiny_views, overrides, channels, basis, k):
    _, info = tiny_views(n_views=2, size=4)
    model = ScatterModel(_config(), _with_spec(info, overrides))
    assert model.base_field.medium.density_channels == channels
    assert model.rung_basis() == basis and model.base_field.medium.n_rest == 3 * k
    assert model.knows == ("lights", "phase function") and model.rung == "single scattering"


@pytest.mark.parametrize("medium", ["hash", "grid"])
def test_training_lowers_the_loss(tiny_views, medium):
    data, info = tiny_views(n_views=4, size=10)
    extra = {"resolution": 8, "initial_resolution": 8, "upsample_steps": [], "rest_resolution": 4} if medium == "grid" \
        else {}
    model = ScatterModel(_config(medium=medium, **extra), _with_spec(info))
    lr = 2e-2 if medium == "hash" else 0.3
    result, _ = train(model, data, TrainConfig(steps=40, batch_rays=256, log_every=10), lr, progress=False)
    losses = [h["loss"] for h in result.history]
    assert np.mean(losses[-2:]) < 0.6 * losses[0], losses


def test_carve_zeroes_the_density_where_the_views_show_the_background(tiny_views):
    """``carve = true``: the mask is built from the training views at construction; the field's density is 0 in
    every carved voxel (the blob's, off-centre at x = 0.1, kept), and the shadows too march through it."""
    data, info = tiny_views(n_views=6, size=12)
    info = _with_spec(info)
    config = _config(carve_resolution=8, carve_tol=1e-3)
    model = ScatterModel(config, info)
    keep = carve(data.images, data.cameras, info.background, info.box, 8, 1e-3)
    assert 0.05 < keep.mean() < 0.95 and keep[4, 4, 4]
    sigma = np.asarray(model.field().density(cell_centres(info.box, 8, mi.Array3f))).reshape(8, 8, 8)
    assert np.all(sigma[~keep] == 0.0) and np.all(sigma[keep] > 0.0)
    assert model.base_field.keep is not None and model.base_field.with_shadows().shadows is not None


def test_carve_without_the_training_views_is_refused(tiny_views):
    _, info = tiny_views(n_views=2, size=4)
    info = replace(_with_spec(info), train_views=None)
    with pytest.raises(ValueError, match=r"^carve: needs the training views .*or set carve = false$"):
        ScatterModel(_config(), info)
    assert ScatterModel(_config(carve=False), info).base_field.keep is None


@pytest.mark.parametrize("medium", ["hash", "grid"])
def test_init_depth_starts_the_density_at_an_optical_depth_per_box_side(tiny_views, medium):
    """``init_depth = 5`` in a box of side 2: sigma = 2.5 everywhere at the start, whatever the medium."""
    from mitsnerf.math.box import Box

    _, info = tiny_views(n_views=2, size=4)
    box = Box((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
    model = ScatterModel(_config(medium=medium, init_depth=5.0), replace(_with_spec(info), box=box))
    sigma = np.asarray(model.base_field.density(cell_centres(box, 4, mi.Array3f)))
    np.testing.assert_allclose(sigma, 2.5, rtol=1e-2)
