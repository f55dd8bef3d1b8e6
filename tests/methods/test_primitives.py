"""The primitives method: its start from the seed, its densification and pruning rule, and training."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.primitives import PrimitiveFieldConfig, kernel_volume
from mitsnerf.math.box import UNIT_BOX, Box
from mitsnerf.methods.base import ParameterShapeError, SceneInfo
from mitsnerf.methods.primitives import (
    KEYS,
    PrimitivesMethodConfig,
    PrimitivesModel,
    _rotation_matrices,
    densify,
    initial_kernels,
    largest_optical_depth,
    prune_mask,
)
from mitsnerf.render.background import ConstantBackground
from mitsnerf.train import TrainConfig, make_optimizer, train

BOX = Box((-1.0, -0.5, -0.5), (1.0, 0.5, 0.5))


def _info(box=UNIT_BOX):
    return SceneInfo(box, ConstantBackground((0.1, 0.1, 0.1)), 1.0)


def test_quaternions_turn_as_drjit_turns_them():
    q = np.random.default_rng(0).normal(size=(5, 4))
    ours = _rotation_matrices(q)
    theirs = dr.quat_to_matrix(mi.Matrix3f, dr.normalize(mi.Quaternion4f(*(mi.Float(q[:, i]) for i in range(4)))))
    np.testing.assert_allclose(ours, np.stack([[np.asarray(theirs[i][j]) for j in range(3)] for i in range(3)])
                               .transpose(2, 0, 1), atol=1e-6)


def test_the_start_is_the_seeds_and_holds_the_mean_density():
    config = PrimitivesMethodConfig(count=500, sigma_init=0.3)
    a, b, c = (initial_kernels(config, BOX, s) for s in (0, 0, 1))
    assert all(np.array_equal(a[k], b[k]) for k in KEYS) and not np.array_equal(a["mean"], c["mean"])
    assert np.all((a["mean"] >= BOX.lo) & (a["mean"] <= BOX.hi))
    mass = np.sum(np.exp(a["density"][:, 0]) * kernel_volume(a["log_scale"]))
    assert mass == pytest.approx(0.3 * 2.0, rel=1e-5)  # sigma_init times the box's volume


def _kernels(n, scale, density, rng):
    return {"mean": rng.uniform(-0.2, 0.2, (n, 3)), "log_scale": np.log(np.full((n, 3), scale)),
            "rotation": rng.normal(size=(n, 4)), "density": np.full((n, 1), np.log(density)),
            "sh": rng.normal(size=(n, 12))}


def test_thin_kernels_and_kernels_outside_the_box_are_pruned():
    rng = np.random.default_rng(1)
    k = _kernels(4, 0.02, 10.0, rng)
    k["density"][1] = np.log(1e-3)  # optical depth 5e-5 at most
    k["mean"][2] = (3.0, 0.0, 0.0)  # its shell far outside the box
    config = PrimitivesMethodConfig(prune_tau=1e-3)
    tau = largest_optical_depth(k["density"], k["log_scale"], PrimitiveFieldConfig())
    assert tau[0] == pytest.approx(0.02 * 10 * 2.49986, 1e-4)
    assert prune_mask(k, config, UNIT_BOX).tolist() == [True, False, False, True]


@pytest.mark.parametrize("scale, split", [(0.05, True), (0.005, False)])
def test_sampled_children_of_the_kernels_pulled_hardest_keep_their_mass(scale, split):
    rng = np.random.default_rng(2)
    k = _kernels(10, scale, 5.0, rng)
    score = np.arange(10.0)  # kernels 9 and 8 pulled hardest
    config = PrimitivesMethodConfig(densify_fraction=0.2, split_scale=0.01, densify_rule="sample")
    new, sources = densify(k, score, config, UNIT_BOX, np.random.default_rng(0))
    assert sources.tolist() == list(range(8)) + [-1] * 4
    assert len(new["mean"]) == 12
    np.testing.assert_array_equal(new["mean"][:8], k["mean"][:8].astype(np.float32))  # survivors first, in order
    children = slice(8, 12)
    parents = [9, 8, 9, 8]
    np.testing.assert_array_equal(new["sh"][children], k["sh"][parents].astype(np.float32))
    shrink = np.log(1.6) if split else 0.0
    np.testing.assert_allclose(new["log_scale"][children], k["log_scale"][parents] - shrink, atol=1e-6)
    mass = lambda p: np.exp(p["density"][:, 0]) * kernel_volume(p["log_scale"])  # noqa: E731
    assert mass(new).sum() == pytest.approx(mass(k).sum(), rel=1e-5)
    offsets = new["mean"][children] - k["mean"][parents]
    assert np.all(np.abs(offsets) < 5 * scale) and np.all(np.linalg.norm(offsets, axis=1) > 0)


def test_a_halved_kernel_keeps_its_mean_variance_mass_and_nearly_its_field():
    from mitsnerf.methods.primitives import _halves

    rng = np.random.default_rng(4)
    k = _kernels(3, 0.05, 5.0, rng)
    k["log_scale"] = np.log(rng.uniform(0.02, 0.08, (3, 3)))
    halves = _halves(k)
    R = _rotation_matrices(k["rotation"])
    x = k["mean"][:, None, :] + rng.normal(size=(3, 4000, 3)) * 0.1  # points around each kernel

    def field(p, i):
        local = np.einsum("ji,mj->mi", R[i], x[i] - p["mean"][i]) / np.exp(p["log_scale"][i])
        return np.exp(p["density"][i, 0]) * np.exp(-0.5 * np.sum(local**2, axis=1))

    for i in range(3):
        parent, pair = field(k, i), field(halves[0], i) + field(halves[1], i)
        assert np.abs(pair - parent).sum() < 0.05 * parent.sum()
        weights = [np.exp(h["density"][i, 0]) * kernel_volume(h["log_scale"][i:i + 1])[0] for h in halves]
        parent_mass = np.exp(k["density"][i, 0]) * kernel_volume(k["log_scale"][i:i + 1])[0]
        assert sum(weights) == pytest.approx(parent_mass, rel=1e-9)
        np.testing.assert_allclose((halves[0]["mean"][i] + halves[1]["mean"][i]) / 2, k["mean"][i])
        a = np.argmax(k["log_scale"][i])
        spread = 0.25 * np.exp(2 * k["log_scale"][i, a])  # (s/2)^2 from the two centres
        assert spread + np.exp(2 * halves[0]["log_scale"][i, a]) == pytest.approx(np.exp(2 * k["log_scale"][i, a]))


def test_densification_stops_at_max_count():
    rng = np.random.default_rng(3)
    k = _kernels(10, 0.05, 5.0, rng)
    config = PrimitivesMethodConfig(count=10, max_count=13, densify_fraction=0.5)
    assert len(densify(k, np.arange(10.0), config, UNIT_BOX, rng)[0]["mean"]) == 13


def test_parameters_of_another_count_are_taken_and_misshapen_ones_refused():
    model = PrimitivesModel(PrimitivesMethodConfig(count=20, field=PrimitiveFieldConfig(cells=4)), _info(), 0)
    other = initial_kernels(PrimitivesMethodConfig(count=7), UNIT_BOX, 3)
    model.set_parameters({k: mi.TensorXf(v) for k, v in other.items()})
    assert model.count == 7 and model.lists().pairs > 0
    with pytest.raises(ParameterShapeError) as wrong_columns:
        model.set_parameters({"sh": mi.TensorXf(np.zeros((7, 3), np.float32))})
    with pytest.raises(ParameterShapeError) as wrong_count:
        model.set_parameters({"mean": mi.TensorXf(np.zeros((8, 3), np.float32))})
    assert (wrong_columns.value.key, wrong_columns.value.want) == ("sh", (7, 12))
    assert (wrong_count.value.key, wrong_count.value.want) == ("log_scale", (8, 3))
    assert model.count == 7


def test_training_lowers_the_loss_and_densifies_on_schedule(tiny_views):
    data, info = tiny_views()
    config = PrimitivesMethodConfig(count=64, max_count=200, densify_every=20, densify_from=20, densify_until=60,
                                    densify_fraction=0.3, field=PrimitiveFieldConfig(cells=8), lr=0.2, lr_sh=0.1)
    model = PrimitivesModel(config, info, 0)
    result, opt = train(model, data, TrainConfig(steps=100, batch_rays=256, log_every=10), config.lr, progress=False)
    losses = [h["loss_mean"] for h in result.history]
    assert np.mean(losses[-2:]) < 0.5 * losses[0]
    assert 64 < model.count <= 200 and opt["mean"].shape == (model.count, 3)
    assert model.samples_per_ray() > 0


def test_the_positional_gradients_are_scored_per_kernel(tiny_views):
    data, info = tiny_views()
    model = PrimitivesModel(PrimitivesMethodConfig(count=32, field=PrimitiveFieldConfig(cells=4)), info, 0)
    opt = make_optimizer(model, 0.05)
    model.set_parameters(opt)
    o, d, target = data.batch(dr.rng(seed=0), 128, False)
    out = model.render_rays(o, d, training=True)
    dr.backward(dr.mean(dr.square(out.rgb - target), axis=None))
    opt.step()
    model.set_parameters(opt)
    assert model.after_step(0, opt) == {}
    hits, score = np.asarray(model.grad_hits), np.asarray(model.grad_sum)
    assert 0 < np.count_nonzero(hits) and np.all((score > 0) == (hits > 0))


def test_kernels_kept_by_a_densification_keep_their_adam_moments(tiny_views):
    from mitsnerf.train.step import apply_step

    data, info = tiny_views()
    config = PrimitivesMethodConfig(count=40, densify_every=3, densify_from=3, densify_until=3, densify_fraction=0.25,
                                    field=PrimitiveFieldConfig(cells=4))
    model = PrimitivesModel(config, info, 0)
    opt = make_optimizer(model, config.lr)
    model.set_parameters(opt)
    seen: dict = {}
    densify_now = model.after_step

    def after_step(step, params):  # the moments the optimiser's step left, then the densification's rows
        seen.update({k: np.asarray(opt.state[k][3][1].numpy()).reshape(model.count, -1) for k in KEYS})
        out = densify_now(step, params)
        seen["sources"] = getattr(out, "sources", {}).get("mean")
        return out

    model.after_step = after_step
    for step in range(3):
        o, d, target = data.batch(dr.rng(seed=step), 128, False)
        out = model.render_rays(o, d, training=True)
        dr.backward(dr.mean(dr.square(out.rgb - target), axis=None))
        apply_step(model, opt, step)
    sources = seen["sources"]
    assert model.count == 50 and list(sources[30:]) == [-1] * 20  # a quarter halved, none pruned
    for key in KEYS:
        m = np.asarray(opt.state[key][3][1].numpy()).reshape(model.count, -1)
        np.testing.assert_array_equal(m[:30], seen[key][sources[:30]], err_msg=key)  # the kept carry theirs
        assert np.count_nonzero(m[:30]) > 0 and np.all(m[30:] == 0), key  # the children start from zero
        assert opt.state[key][3][0][0] == 3  # Adam's step count continues


@pytest.mark.parametrize("sh_degree", [0, 2])
def test_a_bright_colour_range_starts_the_kernels_grey(sh_degree):
    """Bright training views raise ``c_max`` (``cover_radiance``: 12.5 here); every kernel's colour starts at 0.5 in
    every direction, not at ``c_max / 2``, a start brighter than the medium that the fit answered by clearing the
    density on cloud_hg85 (docs/notes/physics-table.md, "The table at 88c2ab4")."""
    from dataclasses import replace

    from mitsnerf.fields.primitives import kernel_colour
    from mitsnerf.fields.sh import sh_basis

    config = PrimitivesMethodConfig(count=16, field=PrimitiveFieldConfig(sh_degree=sh_degree))
    model = PrimitivesModel(config, replace(_info(), radiance_max=10.0))
    assert model.field_config.c_max == pytest.approx(12.5)
    sh = np.asarray(model.params["sh"])
    d = dr.normalize(mi.Array3f(*np.random.default_rng(3).normal(size=(3, 64)).astype(np.float32)))
    Y = sh_basis(d, sh_degree)
    for k in range(len(sh)):
        rgb = kernel_colour([mi.Float(float(v)) for v in sh[k]], Y, model.field_config.c_max)
        assert np.allclose(np.asarray(rgb), 0.5, atol=1e-5), k
