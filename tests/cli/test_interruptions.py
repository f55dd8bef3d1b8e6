"""Interruptions of the real command in a child process: SIGTERM and SIGHUP while training, two
trainings into one run directory, SIGTERM in a benchmark sweep and while generating.

What ``timeout``, systemd, Slurm and Ray send must leave what Ctrl-C leaves: a checkpoint of the
last completed step, the line that says how to continue, exit status 128 + the signal's number,
and a run that ``--resume`` finishes exactly as an uninterrupted one.
"""

from __future__ import annotations

import gc
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mitsnerf.cli import main
from ..conftest import child_pythonpath

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def fast(world) -> list[str]:
    """The tiny nerf at 512 rays a step, a checkpoint after every step."""
    return [*world.nerf[:-2], "--batch-rays", "512", "--checkpoint-every", "1"]


def spawn(argv: list[str]) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": child_pythonpath(REPO)}
    return subprocess.Popen([sys.executable, "-m", "mitsnerf.cli", *argv], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def wait_for(path: Path, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    """Until ``path`` exists (the child still running), polling."""
    end = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, f"the child ended first: {proc.communicate()}"
        assert time.monotonic() < end, f"{path} did not appear"
        time.sleep(0.02)


def wait_for_step(checkpoint: Path, proc: subprocess.Popen, step: int, timeout: float = 120.0) -> None:
    """Until the checkpoint (replaced atomically each step) holds ``step`` or a later one; a signal sent
    then lands in training however slowly the child or this process are scheduled."""
    from mitsnerf.train.checkpoint import load_checkpoint

    wait_for(checkpoint, proc, timeout)
    end = time.monotonic() + timeout
    while load_checkpoint(checkpoint).step < step:
        assert proc.poll() is None, f"the child ended first: {proc.communicate()}"
        assert time.monotonic() < end, f"{checkpoint} did not reach step {step}"
        time.sleep(0.02)


def stop(proc: subprocess.Popen, signum: int) -> tuple[int, str]:
    """Send ``signum``; the exit status and stderr (a child still running a minute later is killed)."""
    proc.send_signal(signum)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise
    return proc.returncode, err


def _params(run: Path) -> dict:
    with np.load(run / "params.npz") as z:
        return {k: z[k] for k in z.files}


def _interrupt(world, fast, run: Path, signum: int) -> int:
    """Train into ``run``, send ``signum`` after the first checkpoint, check what the signal leaves;
    returns the checkpoint's step."""
    from mitsnerf.train.checkpoint import load_checkpoint

    proc = spawn(["train", str(world.dataset), "--out", str(run), "--steps", "30", *fast])
    wait_for(run / "checkpoint.npz", proc)
    code, err = stop(proc, signum)
    assert code == 128 + signum, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    step = load_checkpoint(run / "checkpoint.npz").step
    assert 1 <= step < 30
    assert last == (f"mitsnerf: interrupted; stopped by {signal.Signals(signum).name}; checkpoint of step {step} saved "
                    f"to {run / 'checkpoint.npz'}; continue with mitsnerf train --resume --out {run}")
    assert sorted(p.name for p in run.parent.iterdir()) == [run.name], "no lock file or temporary left"
    return step


def test_sighup_saves_a_checkpoint_and_says_how_to_continue(world, fast, tmp_path):
    _interrupt(world, fast, tmp_path / "run", signal.SIGHUP)


def test_sigterm_saves_a_checkpoint_and_the_resume_equals_a_straight_run(world, fast, tmp_path):
    run = tmp_path / "interrupted" / "run"
    run.parent.mkdir()
    _interrupt(world, fast, run, signal.SIGTERM)

    assert main(["train", "--resume", "--out", str(run)]) == 0
    straight = tmp_path / "straight"
    assert main(["train", str(world.dataset), "--out", str(straight), "--steps", "30", *fast]) == 0
    resumed, reference = _params(run), _params(straight)
    assert resumed.keys() == reference.keys()
    for key in reference:
        np.testing.assert_array_equal(resumed[key], reference[key], err_msg=key)  # nerf resumes bit for bit
    history = [json.loads((r / "history.json").read_text()) for r in (run, straight)]
    assert [(h["step"], h["loss"], h["loss_mean"]) for h in history[0]] == \
        [(h["step"], h["loss"], h["loss_mean"]) for h in history[1]]


def test_a_second_training_into_a_run_being_written_is_refused_at_once(world, fast, tmp_path):
    run = tmp_path / "run"
    first = spawn(["train", str(world.dataset), "--out", str(run), "--steps", "30", *fast])
    wait_for(run / "checkpoint.npz", first)
    second = spawn(["train", str(world.dataset), "--out", str(run), "--steps", "3", *fast, "--force"])
    _, err = second.communicate(timeout=60)
    assert second.returncode == 2, err
    assert err.strip().splitlines()[-1] == (f"mitsnerf: error: {run}: pid {first.pid} is writing it now (lock .run.lock); "
                                            "wait for it to finish or pick another output")
    assert first.wait(timeout=120) == 0, first.communicate()
    assert json.loads((run / "metrics.json").read_text())["steps"] == 30


BENCH = """\
name = "b"
scenes = ["SPEC"]
seeds = [0]
train = { steps = 80, batch_rays = 512, log_every = 5, checkpoint_every = 1 }
eval = { curve_points = 4, od_samples = 16 }
oracle = { enabled = false }  # not what this test is about: it would cost a minute before the first cell
[[methods]]
name = "nerf"
config = { network = { width = 8, depth = 1, head_width = 8, features = 4 }, n_samples = 8, n_importance = 0 }
"""


def test_a_stopped_sweep_continues_the_cell_in_flight_from_its_checkpoint(world, tmp_path):
    config = tmp_path / "b.toml"
    config.write_text(BENCH.replace("SPEC", str(world.spec)))
    data = tmp_path / "data"
    shutil.copytree(world.dataset.parent, data)
    argv = ["bench", str(config), "--results", str(tmp_path / "res"), "--data", str(data), "--no-progress"]
    cell = tmp_path / "res" / "b" / "cells" / "tiny" / "nerf-seed0"
    proc = spawn(argv)
    # past the first held-out evaluation (step 20), so the curve resumes too; 59 steps to spare
    wait_for_step(cell / "run" / "checkpoint.npz", proc, 21)
    code, err = stop(proc, signal.SIGTERM)
    assert code == 143, err
    assert "Traceback" not in err and "run the same command again to resume" in err.strip().splitlines()[-1]
    assert not (cell / "result.json").exists() and (cell / "in_flight.json").is_file()
    from mitsnerf.train.checkpoint import load_checkpoint

    step = load_checkpoint(cell / "run" / "checkpoint.npz").step

    assert main(argv) == 0
    record = json.loads((cell / "result.json").read_text())
    assert record["worker"]["resumed_from_step"] == step and record["metrics"]["steps"] == 80
    assert [p["step"] for p in record["curve"]["points"]] == [20, 40, 60, 80]


def test_a_stopped_generate_leaves_nothing_that_looks_complete(world, tmp_path):
    spec = tmp_path / "slow.toml"
    spec.write_text(world.spec.read_text().replace('"tiny"', '"slow"').replace("spp_test = 8", "spp_test = 2048"))
    proc = spawn(["generate", str(spec), "--out", str(tmp_path / "data")])
    end = time.monotonic() + 60
    while not list((tmp_path / "data").glob(".slow-*.tmp-*")):  # the dataset is being built
        assert proc.poll() is None and time.monotonic() < end, proc.communicate()
        time.sleep(0.02)
    time.sleep(0.5)  # into the rendering (the test views take seconds)
    assert proc.poll() is None, "generate finished before the signal: make the spec slower"
    code, err = stop(proc, signal.SIGTERM)
    assert code == 143, err
    assert "Traceback" not in err and "mitsnerf: interrupted; stopped by SIGTERM" in err
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == [], "no dataset, temporary or lock left"


def test_a_resume_runs_the_log_hook_again_on_the_entry_a_signal_stopped_it_on(world, tmp_path):
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.errors import Interrupted
    from mitsnerf.runs.fit import fit
    from mitsnerf.train import TrainConfig

    overrides = {"network": {"width": 8, "depth": 1, "head_width": 8, "features": 4}, "n_samples": 8}
    config = TrainConfig(steps=8, batch_rays=64, log_every=2, checkpoint_every=1)
    seen: list[int] = []

    def stopped_inside_at_4(entry, model):
        if entry["step"] == 4:
            raise KeyboardInterrupt  # as a signal arriving while the hook evaluates
        seen.append(entry["step"])

    dataset = load_dataset(world.dataset)
    with pytest.raises(Interrupted, match="checkpoint of step 4"):
        fit(dataset, "nerf", overrides, config, tmp_path / "run", progress=False, on_log=stopped_inside_at_4)
    fit(dataset, "nerf", overrides, config, tmp_path / "run", progress=False, resume=True,
        on_log=lambda entry, model: seen.append(entry["step"]))
    assert seen == [2, 4, 6, 8]


def test_a_signal_while_evaluating_keeps_the_trained_checkpoint_and_the_resume_only_evaluates(world, tmp_path,
                                                                                              monkeypatch, capsys):
    import mitsnerf.runs.fit

    run = tmp_path / "run"
    evaluate = mitsnerf.runs.fit.evaluate_run

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(mitsnerf.runs.fit, "evaluate_run", stopped)
    assert main(["train", str(world.dataset), "--out", str(run), "--steps", "3", *world.nerf]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"mitsnerf: interrupted; stopped by SIGINT while evaluating; checkpoint of step 3 saved to "
        f"{run / 'checkpoint.npz'}; continue with mitsnerf train --resume --out {run}")
    monkeypatch.setattr(mitsnerf.runs.fit, "evaluate_run", evaluate)
    assert main(["train", "--resume", "--out", str(run)]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["steps"] == 3 and metrics["rays_per_s"] is None  # no step ran in the session that evaluated
    assert "3 steps in" in capsys.readouterr().out


def test_a_signal_that_an_import_turned_into_another_error_still_exits_as_the_signal(world, tmp_path, monkeypatch,
                                                                                    capsys):
    import mitsnerf.runs.fit
    from mitsnerf.errors import Interrupted

    def import_stopped(*args, **kwargs):
        try:
            raise Interrupted(15, "stopped by SIGTERM")
        except Interrupted as exc:
            raise ImportError("initialization failed") from exc  # what a C extension's import makes of it

    monkeypatch.setattr(mitsnerf.runs.fit, "fit", import_stopped)
    assert main(["train", str(world.dataset), "--out", str(tmp_path / "r"), *world.nerf]) == 143
    assert capsys.readouterr().err.strip().splitlines()[-1] == "mitsnerf: interrupted; stopped by SIGTERM"


def test_training_saves_its_checkpoint_when_a_library_wraps_the_signal_in_another_error(world, tmp_path):
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.errors import Interrupted
    from mitsnerf.runs.fit import fit
    from mitsnerf.train import TrainConfig

    def wrapped_at_4(entry, model):
        if entry["step"] == 4:
            try:
                raise Interrupted(1, "stopped by SIGHUP")
            except Interrupted as exc:
                raise RuntimeError("a callback failed") from exc  # as a C++ library may report it

    overrides = {"network": {"width": 8, "depth": 1, "head_width": 8, "features": 4}, "n_samples": 8}
    with pytest.raises(Interrupted, match=r"stopped by SIGHUP; checkpoint of step 4 saved") as info:
        fit(load_dataset(world.dataset), "nerf", overrides, TrainConfig(steps=8, batch_rays=64, log_every=2),
            tmp_path / "run", progress=False, on_log=wrapped_at_4)
    assert info.value.exit_status == 129


class _SignalsInItsFinalizer:
    """An object whose finalizer is where the signal is handled: Python runs the handler at the next
    instruction, inside ``__del__``, which cannot propagate what the handler raises (nor can a weakref
    callback, or a generator the garbage collector closes); only the object's own code is ours."""

    def __init__(self, signum: int) -> None:
        self.signum = signum

    def __del__(self) -> None:
        signal.raise_signal(self.signum)
        self.signum = 0  # an instruction after the signal: its handler runs here, inside the finalizer


def _a_weakref_callback_signals(signum: int) -> None:
    """As the sweep that printed ``Exception ignored in: <function WeakKeyDictionary.__init__.<locals>.remove>``:
    a weakref's callback, run when its referent goes, is where the signal is handled."""
    import weakref

    class Referent:
        pass

    def callback(ref) -> None:
        signal.raise_signal(signum)
        ref.signum = signum  # its handler runs here, inside the callback

    referent = Referent()
    ref = weakref.ref(referent, callback)
    del referent  # the callback runs now
    assert ref() is None


FINALIZERS = {"__del__": _SignalsInItsFinalizer, "weakref callback": _a_weakref_callback_signals}


@pytest.mark.parametrize("finalizer", FINALIZERS)
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_handled_inside_a_finalizer_still_stops_the_training(world, tmp_path, monkeypatch, capsys, signum,
                                                                      finalizer):
    """The window of a sweep that printed ``Exception ignored in: ... WeakKeyDictionary ... remove``
    and ran on: a stop signal landing in a finalizer was printed and lost. It must stop the command
    as anywhere else: the checkpoint of the step, the line that says how to continue, 128 + signum."""
    import mitsnerf.train.loop

    run = tmp_path / "run"
    step = mitsnerf.train.loop._Loop.one_step

    def one_step_then_a_finalizer_at_3(loop):
        step(loop)
        if loop.step == 3:
            FINALIZERS[finalizer](signum)  # its finalizer runs at once
            end = time.monotonic() + 10
            while time.monotonic() < end:  # the stop comes back from the finalizer at an instruction here
                time.sleep(0.01)

    monkeypatch.setattr(mitsnerf.train.loop._Loop, "one_step", one_step_then_a_finalizer_at_3)
    assert main(["train", str(world.dataset), "--out", str(run), "--steps", "8", *world.nerf]) == 128 + signum
    err = capsys.readouterr().err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert err.strip().splitlines()[-1] == (
        f"mitsnerf: interrupted; stopped by {signal.Signals(signum).name}; checkpoint of step 3 saved to "
        f"{run / 'checkpoint.npz'}; continue with mitsnerf train --resume --out {run}")


class _SignalsAtItsWrite(io.BytesIO):
    """The file an archive is written to, where the stop signal is handled at its ``nth`` write: inside
    ``np.savez``'s zip code, as a SIGTERM that a sweep got while a checkpoint was written (CI printed the
    zip's finalizer's "Can't close the ZIP file while there is an open writing handle" traceback)."""

    def __init__(self, signum: int, nth: int) -> None:
        super().__init__()
        self.signum, self.nth, self.writes = signum, nth, 0

    def write(self, data) -> int:
        self.writes += 1
        if self.writes == self.nth:
            signal.raise_signal(self.signum)
        return super().write(data)  # its handler runs at this instruction, zipfile's frames under it


SMALL_NPZ = {"param/sigma_t": np.arange(100.0), "adam/sigma_t/m": np.ones(7)}


def _writes_of_a_small_npz() -> int:
    """How many writes ``np.savez`` of :data:`SMALL_NPZ` makes when nothing stops it (18 with numpy 2.4: the
    headers, the data, the directory)."""
    archive = _SignalsAtItsWrite(signal.SIGTERM, 0)
    np.savez(archive, **SMALL_NPZ)
    return archive.writes


WRITES_OF_A_SMALL_NPZ = _writes_of_a_small_npz()


@pytest.mark.parametrize("nth", range(1, WRITES_OF_A_SMALL_NPZ + 1))
def test_a_signal_while_an_archive_is_written_stops_once_it_is_complete(capsys, nth):
    from mitsnerf.errors import Interrupted
    from mitsnerf.train.checkpointing import stop_signals

    archive = _SignalsAtItsWrite(signal.SIGTERM, nth)
    with pytest.raises(Interrupted, match="stopped by SIGTERM"):
        with stop_signals():
            np.savez(archive, **SMALL_NPZ)
    assert archive.writes == WRITES_OF_A_SMALL_NPZ, "the write was cut short"
    with np.load(io.BytesIO(archive.getvalue())) as back:
        assert sorted(back.files) == sorted(SMALL_NPZ) and np.array_equal(back["param/sigma_t"], np.arange(100.0))
    gc.collect()  # the finalizer of a zip left open would print its traceback here
    err = capsys.readouterr().err
    assert "Traceback" not in err and "Exception ignored" not in err, err


@pytest.mark.parametrize("wrapped", [False, True], ids=["signal", "signal-inside-an-import"])
def test_a_sweep_stopped_after_its_last_cell_says_how_to_write_the_tables(world, tmp_path, monkeypatch, capsys,
                                                                          wrapped):
    """The signal may land after the last cell, while the tables are written (a sweep whose signal came
    late): the line still says what is saved and what to run, and the next run only writes the tables."""
    import mitsnerf.bench.runner
    from mitsnerf.errors import Interrupted

    config = tmp_path / "b.toml"
    config.write_text(BENCH.replace("SPEC", str(world.spec)).replace("steps = 80", "steps = 8"))
    data = tmp_path / "data"
    shutil.copytree(world.dataset.parent, data)
    argv = ["bench", str(config), "--results", str(tmp_path / "res"), "--data", str(data), "--no-progress"]
    write_outputs = mitsnerf.bench.runner.write_outputs

    def stopped(*args, **kwargs):
        if wrapped:
            try:
                raise Interrupted(15, "stopped by SIGTERM")
            except Interrupted as exc:  # in the import of a C extension (matplotlib's, for the plots)
                raise ImportError("initialization failed") from exc
        raise Interrupted(15, "stopped by SIGTERM")  # as the handler raises it there

    monkeypatch.setattr(mitsnerf.bench.runner, "write_outputs", stopped)
    assert main(argv) == 143
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"mitsnerf: interrupted; stopped by SIGTERM; every cell is saved under {tmp_path / 'res' / 'b'}; run the "
        "same command again to write the tables and the report")
    monkeypatch.setattr(mitsnerf.bench.runner, "write_outputs", write_outputs)
    assert main(argv) == 0
    assert "0 cells run, 1 already done" in capsys.readouterr().out


def test_a_signal_while_the_last_checkpoint_is_written_writes_it_again_and_says_so(world, tmp_path, monkeypatch):
    """Without --checkpoint-every the checkpoint at the end is the only one: a signal while it is written
    (or while the bar closes) is inside the trainer's watch, so the step is saved and the line says so."""
    from mitsnerf.train.checkpoint import Checkpointer, load_checkpoint
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.errors import Interrupted
    from mitsnerf.runs.fit import fit
    from mitsnerf.train import TrainConfig

    save, calls = Checkpointer.save, []

    def stopped_while_writing_the_first(self, state):
        calls.append(state.step)
        if len(calls) == 1:
            raise Interrupted(15, "stopped by SIGTERM")  # as the handler raises it inside the write
        save(self, state)

    monkeypatch.setattr(Checkpointer, "save", stopped_while_writing_the_first)
    overrides = {"network": {"width": 8, "depth": 1, "head_width": 8, "features": 4}, "n_samples": 8}
    run = tmp_path / "run"
    with pytest.raises(Interrupted, match=r"stopped by SIGTERM; checkpoint of step 4 saved"):
        fit(load_dataset(world.dataset), "nerf", overrides, TrainConfig(steps=4, batch_rays=64), run, progress=False)
    assert calls == [4, 4] and load_checkpoint(run / "checkpoint.npz").step == 4


def test_a_pool_sweep_stopped_by_sigterm_stops_its_cells_in_flight_at_their_checkpoint(world, tmp_path):
    """SIGTERM reaches the driver alone (``timeout``, ``kill``): the cells training in pool workers get it
    too, save their checkpoint and stop; before, the stopped driver waited for each to train to its end."""
    from mitsnerf.train.checkpoint import load_checkpoint

    config = tmp_path / "b.toml"
    config.write_text(BENCH.replace("SPEC", str(world.spec)).replace("steps = 80", "steps = 4000"))
    data = tmp_path / "data"
    shutil.copytree(world.dataset.parent, data)
    cell = tmp_path / "res" / "b" / "cells" / "tiny" / "nerf-seed0"
    proc = spawn(["bench", str(config), "--results", str(tmp_path / "res"), "--data", str(data), "--no-progress",
                  "--executor", "pool", "--workers", "1"])
    wait_for_step(cell / "run" / "checkpoint.npz", proc, 2)
    code, err = stop(proc, signal.SIGTERM)
    assert code == 143 and "Traceback" not in err, err
    assert "run the same command again to resume" in err.strip().splitlines()[-1]
    assert load_checkpoint(cell / "run" / "checkpoint.npz").step < 4000
    assert not (cell / "run" / "metrics.json").exists() and (cell / "in_flight.json").is_file()


#: Run in a child before ``python -m mitsnerf``: SIGTERM at the first Python code that matplotlib's ft2font (a
#: pybind11 extension) runs while it initialises (its enums), the moment a fuzzed sweep hit. Raised there, the
#: import failed and the interpreter's teardown then aborted (exit status 134, "Fatal Python error"); the stop
#: must wait for the import to end.
SIGNAL_IN_FT2FONT = """
import runpy, signal, sys

def profile(frame, event, arg):
    if event == "call" and frame.f_code.co_filename.endswith("enum.py") and "_bootstrap" in frame.f_back.f_code.co_filename:
        names, f = [], frame
        while f is not None:
            names.append(f.f_code.co_filename)
            f = f.f_back
        if any("matplotlib" in name for name in names):
            sys.setprofile(None)
            signal.raise_signal(signal.SIGTERM)

sys.setprofile(profile)
sys.argv = ["mitsnerf", *sys.argv[1:]]
runpy.run_module("mitsnerf", run_name="__main__")
"""


def test_a_signal_during_an_extensions_import_waits_for_it_and_exits_with_its_status(world, tmp_path):
    config = tmp_path / "b.toml"
    config.write_text(BENCH.replace("SPEC", str(world.spec)).replace("steps = 80", "steps = 4"))
    data = tmp_path / "data"
    shutil.copytree(world.dataset.parent, data)
    env = {**os.environ, "PYTHONPATH": child_pythonpath(REPO)}
    proc = subprocess.run([sys.executable, "-c", SIGNAL_IN_FT2FONT, "bench", str(config), "--results",
                           str(tmp_path / "res"), "--data", str(data), "--no-progress"], env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 143, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        f"mitsnerf: interrupted; stopped by SIGTERM; every cell is saved under {tmp_path / 'res' / 'b'}; run the "
        "same command again to write the tables and the report")
