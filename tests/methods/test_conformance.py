"""The conformance suite (``mitsnerf methods --check NAME``): every registered method keeps every promise, and
each promise's check fails on a planted bug where a real one would sit (the shared trainer, checkpoint and run
code, or a plugin's own model)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from mitsnerf.methods import methods
from mitsnerf.runs.conformance import PROMISES, RESUME_ATOL, check_method

PLUGIN = Path(__file__).resolve().parents[1] / "plugins" / "tiny_plugin.py"


@pytest.mark.parametrize("name", sorted(methods()))
def test_every_registered_method_conforms(name):
    report = check_method(name)
    assert report.passed, report.summary()
    assert [o.promise for o in report.outcomes] == [p[0] for p in PROMISES]
    assert all(o.passed for o in report.outcomes if o.promise != "exports its density, which is scored"), \
        report.summary()


def _broken(report) -> list[str]:
    return [o.promise for o in report.failures()]


def test_a_plugin_whose_set_parameters_drops_the_values_fails_to_train(monkeypatch):
    monkeypatch.setenv("MITSNERF_METHODS", f"frozen={PLUGIN}:FrozenNGP")
    report = check_method("frozen")
    assert not report.passed and _broken(report)[0] == "trains and evaluates", report.summary()
    assert "FAILED   trains and evaluates" in report.summary() and "frozen: does not conform" in report.summary()


def test_a_learning_rate_of_zero_is_seen_as_not_learning(monkeypatch):
    import mitsnerf.train.step

    monkeypatch.setattr(mitsnerf.train.step, "learning_rate", lambda *args, **kwargs: 0.0)
    report = check_method("ngp")
    assert _broken(report)[:1] == ["trains and evaluates"], report.summary()
    assert "every parameter is as initialised" in report.failures()[0].detail


def test_an_interrupt_that_saves_nothing_breaks_the_sigterm_promise(monkeypatch):
    from mitsnerf.train.checkpointing import CheckpointPolicy, interrupted_message

    monkeypatch.setattr(CheckpointPolicy, "interrupted",
                        lambda self, exc, save: interrupted_message(exc, self.checkpointer.path, 0))
    report = check_method("voxel")
    assert _broken(report) == ["SIGTERM checkpoints the last completed step"], report.summary()


def test_a_resume_without_the_optimiser_moments_does_not_equal_the_run(monkeypatch):
    """Broken on either backend: the parameters move far more than CUDA's tolerance (RESUME_ATOL)."""
    import mitsnerf.runs.fit

    restore = mitsnerf.runs.fit.restore_optimizer

    def forget_moments(opt, ckpt, path):
        restore(opt, ckpt, path)
        for key in list(opt.keys()):
            opt.reset(key)

    monkeypatch.setattr(mitsnerf.runs.fit, "restore_optimizer", forget_moments)
    report = check_method("nerf")
    assert _broken(report) == ["resume equals the run never stopped"], report.summary()
    detail = report.failures()[0].detail
    assert "differ from the run never stopped" in detail
    assert float(re.search(r"largest difference ([-+.e0-9]+)", detail).group(1)) > 100 * RESUME_ATOL, detail


def test_a_run_read_back_without_its_parameters_renders_differently(monkeypatch):
    import mitsnerf.runs.fit

    monkeypatch.setattr(mitsnerf.runs.fit, "set_checked", lambda model, values, where, method, run_dir: None)
    report = check_method("voxel")
    assert "renders a saved run" in _broken(report), report.summary()


def test_a_resume_that_ignores_the_settings_breaks_the_refusal_promise(monkeypatch):
    import mitsnerf.runs.fit

    monkeypatch.setattr(mitsnerf.runs.fit, "_check_resumable", lambda saved, current, where: None)
    report = check_method("ngp")
    assert _broken(report) == ["a run of other settings is refused on resume"], report.summary()


def test_a_nan_parameter_differs_from_any_value_even_another_nan():
    from mitsnerf.runs.conformance import parameter_gaps

    nan = np.array([np.nan, 1.0])
    gaps = parameter_gaps({"w": nan, "b": np.zeros(2), "s": np.zeros(3)},
                          {"w": nan, "b": np.zeros(2), "s": np.zeros(2)})
    assert np.isnan(gaps["w"]) and not gaps["w"] <= RESUME_ATOL
    assert gaps["b"] == 0.0 and gaps["s"] == np.inf


def test_where_no_thread_count_orders_the_sums_a_resume_is_held_to_the_tolerance(monkeypatch):
    """The CUDA branch on this machine: conformance trains multi-threaded and the resumed grid method, within
    RESUME_ATOL of the run never stopped, keeps the promise, saying it is not bit for bit and why."""
    import mitsnerf.runs.conformance as conformance

    monkeypatch.setattr(conformance, "nondeterminism", lambda variant=None: "sums in no fixed order")
    report = check_method("voxel")
    assert report.passed, report.summary()
    outcome = next(o for o in report.outcomes if o.promise == "resume equals the run never stopped")
    assert f"within {RESUME_ATOL:g}" in outcome.detail
    assert outcome.detail.endswith("not bit for bit: sums in no fixed order")
