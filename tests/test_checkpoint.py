"""Checkpoints: bit-for-bit resume, Ctrl-C, NaN and divergence leave the last good checkpoint."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.train.checkpoint import (
    CHECKPOINT_FILE,
    Checkpointer,
    capture,
    load_checkpoint,
    restore_optimizer,
    save_checkpoint,
)
from mitsnerf.errors import DatasetError, TrainingError
from mitsnerf.fields.grid import GridField
from mitsnerf.fields.nerf import NeRFConfig
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.methods.base import SceneInfo, StepLoss, ViewModel
from mitsnerf.methods.nerf import NeRFMethodConfig, NeRFModel
from mitsnerf.render.background import ConstantBackground
from mitsnerf.math.rays import camera_rays
from mitsnerf.render.volume import render_rays
from mitsnerf.train import PixelData, TrainConfig, TrainState, make_optimizer, train
from mitsnerf.math.box import UNIT_BOX

LR = 1e-2


@pytest.fixture
def nerf_setup(blob_grid):
    """Tiny views of the blob and a factory of identical fresh NeRF models."""
    rng = np.random.default_rng(0)
    cams = []
    for _ in range(3):
        v = rng.normal(size=3)
        cams.append(Camera.from_fov(look_at(2.0 * v / np.linalg.norm(v)), 8, 8, 40.0))
    bg = ConstantBackground((0.05, 0.1, 0.3))
    rays = camera_rays(mi.Array3f, cams)
    with dr.suspend_grad():
        comp = render_rays(GridField.from_arrays(blob_grid, UNIT_BOX, color=(1.0, 0.9, 0.1)), rays.o, rays.d, 32, background=bg, box=UNIT_BOX)
    images = np.stack([np.asarray(c) for c in comp.rgb], -1).reshape(3, 8, 8, 3)
    data = PixelData.from_views(images, cams)
    info = SceneInfo(UNIT_BOX, bg, float(images.max()))

    def make():
        return NeRFModel(NeRFMethodConfig(network=NeRFConfig(width=8, depth=1, head_width=8, features=4), n_samples=8), info, seed=3)

    return data, make


def _state(opt) -> dict:
    return {k: v for k, v in capture(0, opt).__dict__.items() if k in ("params", "moments", "optimizer")}


def _assert_same_state(a: dict, b: dict) -> None:
    assert a["optimizer"] == b["optimizer"]  # Adam t, per-parameter lr, hyperparameters
    for key in a["params"]:
        np.testing.assert_array_equal(a["params"][key], b["params"][key], err_msg=key)
        for moment in a["moments"][key]:
            np.testing.assert_array_equal(a["moments"][key][moment], b["moments"][key][moment], err_msg=f"{key} {moment}")


def _resume(make, data, config, path):
    model = make()
    opt = make_optimizer(model, LR)
    ckpt = load_checkpoint(path)
    restore_optimizer(opt, ckpt, path)
    model.load_extra_state(ckpt.extra_state)
    return train(model, data, config, LR, state=TrainState(opt, ckpt.step, ckpt.elapsed, ckpt.history, ckpt.monitor),
                 progress=False)


def _stop_at(step):
    """An on_log hook that interrupts training (as Ctrl-C would) once ``step`` is logged."""
    def hook(entry):
        if entry["step"] == step:
            raise KeyboardInterrupt
    return hook


def test_resume_is_bit_identical_to_an_uninterrupted_run(nerf_setup, tmp_path):
    data, make = nerf_setup
    config = TrainConfig(steps=8, batch_rays=64, seed=5, log_every=2)
    straight, opt_straight = train(make(), data, config, LR, progress=False)

    path = tmp_path / CHECKPOINT_FILE
    with pytest.raises(KeyboardInterrupt):
        train(make(), data, config, LR, progress=False, on_log=_stop_at(4),
              checkpointer=Checkpointer(path, config={"method": "nerf"}))
    assert load_checkpoint(path).step == 4
    resumed, opt_resumed = _resume(make, data, config, path)

    assert resumed.steps == 8 and resumed.steps_run == 4
    _assert_same_state(_state(opt_straight), _state(opt_resumed))
    assert [h["step"] for h in resumed.history] == [h["step"] for h in straight.history]
    assert resumed.history[-1]["loss"] == straight.history[-1]["loss"]
    # the loss monitor's interval sums travel with the checkpoint: the same interval means
    assert [h["loss_mean"] for h in resumed.history] == [h["loss_mean"] for h in straight.history]
    # the learning rate is a function of the step alone: the resumed run's schedule is the straight one's
    assert [h["lr"] for h in resumed.history] == [h["lr"] for h in straight.history]
    assert straight.history[0]["lr"] == LR * 0.1 ** (1 / 8) and straight.history[-1]["lr"] == LR * 0.1 ** (7 / 8)


def test_a_resume_in_the_middle_of_a_log_interval_keeps_the_interval_means(nerf_setup, tmp_path):
    data, make = nerf_setup
    config = TrainConfig(steps=8, batch_rays=64, seed=5, log_every=4, checkpoint_every=2)
    straight, _ = train(make(), data, config, LR, progress=False)
    path = tmp_path / CHECKPOINT_FILE
    with pytest.raises(KeyboardInterrupt):
        train(make(), data, config, LR, progress=False, on_log=_stop_at(4),
              checkpointer=Checkpointer(path, config={"method": "nerf"}))
    ckpt = load_checkpoint(path)
    assert ckpt.step == 4
    resumed, _ = _resume(make, data, TrainConfig(steps=8, batch_rays=64, seed=5, log_every=4, checkpoint_every=2), path)
    assert [h["loss_mean"] for h in resumed.history] == [h["loss_mean"] for h in straight.history]


def test_ctrl_c_leaves_a_loadable_checkpoint_of_the_last_completed_step(nerf_setup, tmp_path):
    data, make = nerf_setup
    config = TrainConfig(steps=6, batch_rays=64, seed=5, log_every=1)
    path = tmp_path / CHECKPOINT_FILE

    def interrupt(entry):
        if entry["step"] == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt, match="stopped by SIGINT; checkpoint of step 3 saved"):
        train(make(), data, config, LR, progress=False, on_log=interrupt,
              checkpointer=Checkpointer(path, config={"method": "nerf"}))
    ckpt = load_checkpoint(path)
    assert ckpt.step == 3 and [h["step"] for h in ckpt.history] == [1, 2, 3]
    assert all(entry["t"] == 3 for entry in ckpt.optimizer["params"].values())

    _, opt_straight = train(make(), data, config, LR, progress=False)
    _, opt_resumed = _resume(make, data, config, path)
    _assert_same_state(_state(opt_straight), _state(opt_resumed))


class _Quadratic(ViewModel):
    """One parameter vector ``x`` with loss ``scale(step) * mean((x - 1)^2)`` through the own-step hook."""

    name = "quadratic"

    def __init__(self, scale=lambda step: 1.0):
        self.x = dr.zeros(mi.Float, 4)
        self.scale = scale

    def parameters(self):
        return {"x": self.x}

    def set_parameters(self, values):
        self.x = values["x"]

    def render_view(self, camera, *, pixel_center=0.5, footprint=1):
        raise NotImplementedError

    def training_loss(self, data, step, rng):
        mse = dr.mean(dr.square(self.x - 1.0), axis=None)
        return StepLoss(mse * self.scale(step), mse, rays=1)


def test_nan_loss_names_the_step_and_keeps_the_previous_checkpoint(tmp_path):
    path = tmp_path / CHECKPOINT_FILE
    model = _Quadratic(scale=lambda step: float("nan") if step == 5 else 1.0)
    checkpointer = Checkpointer(path, config={"method": "quadratic"})
    params_after = {}

    def remember(entry):
        params_after[entry["step"]] = np.array(model.x)

    with pytest.raises(TrainingError, match=r"step 5: loss became nan.*last good checkpoint: .*checkpoint.npz \(step 4\)"):
        train(model, None, TrainConfig(steps=10, log_every=1, checkpoint_every=2), 0.1, progress=False,
              on_log=remember, checkpointer=checkpointer)
    ckpt = load_checkpoint(path)
    assert ckpt.step == 4
    np.testing.assert_array_equal(ckpt.params["x"], params_after[4])
    np.testing.assert_array_equal(np.array(model.x), params_after[5])  # step 5's update never happened


def test_a_nan_loss_at_the_first_step_says_so_and_names_no_step_before_it(tmp_path):
    model = _Quadratic(scale=lambda step: float("nan"))
    with pytest.raises(TrainingError) as caught:
        train(model, None, TrainConfig(steps=3, log_every=1), 0.1, progress=False)
    assert str(caught.value) == ("step 0: loss became nan; stopped, the initial parameters kept (before the first "
                                 "step); no checkpoint (no run directory)")


def test_a_diverging_loss_stops_training_and_keeps_the_last_healthy_checkpoint(tmp_path):
    path = tmp_path / CHECKPOINT_FILE
    model = _Quadratic(scale=lambda step: 1.0 if step < 10 else 1e4)
    config = TrainConfig(steps=40, log_every=2, checkpoint_every=1, divergence_factor=10.0, divergence_patience=2)
    with pytest.raises(TrainingError, match=r"step 14: loss diverging.*\(step 10\)"):
        train(model, None, config, 0.05, progress=False, checkpointer=Checkpointer(path, config={}))
    assert load_checkpoint(path).step == 10


def test_a_monte_carlo_losss_fireflies_are_not_taken_for_a_divergence():
    """One step in five from step 10 on meets a firefly (its loss x 1e4, as a path tracer's few-sample loss can):
    every later interval's mean is > 10 x the first's, which a mean-based check stops at; the median stays."""
    model = _Quadratic(scale=lambda step: 1e4 if step >= 10 and step % 5 == 3 else 1.0)
    config = TrainConfig(steps=40, log_every=5, divergence_factor=10.0, divergence_patience=2)
    result, _ = train(model, None, config, 0.01, progress=False)
    means = [h["loss_mean"] for h in result.history]
    assert result.steps == 40 and min(means[2:]) > 10 * means[0], means


def test_restore_refuses_a_mismatched_optimizer(tmp_path):
    path = tmp_path / CHECKPOINT_FILE
    opt = dr.opt.Adam(lr=0.1)
    opt["x"] = dr.zeros(mi.Float, 3)
    save_checkpoint(path, capture(1, opt))
    other = dr.opt.Adam(lr=0.1, beta_1=0.5)
    other["x"] = dr.zeros(mi.Float, 3)
    with pytest.raises(DatasetError, match="beta_1"):
        restore_optimizer(other, load_checkpoint(path), path)
    other = dr.opt.Adam(lr=0.1)
    other["y"] = dr.zeros(mi.Float, 3)
    with pytest.raises(DatasetError, match="params"):
        restore_optimizer(other, load_checkpoint(path), path)
    with pytest.raises(DatasetError, match="no checkpoint"):
        load_checkpoint(tmp_path / "nothing.npz")
