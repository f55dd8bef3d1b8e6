"""``--deterministic``: one Dr.Jit thread while training makes every method bit-identical run to run on LLVM;
on CUDA, whose float atomics no thread count orders, it is refused rather than promised."""

from __future__ import annotations

import numpy as np
import pytest

import mitsnerf.train.threads
from mitsnerf.cli import main
from mitsnerf.errors import UsageError
from mitsnerf.methods import methods
from mitsnerf.train.threads import nondeterminism


def _fit_twice(method, dataset, threads):
    from mitsnerf.runs.fit import fit
    from mitsnerf.train import TrainConfig

    runs = []
    for _ in range(2):
        run = fit(dataset, method, methods()[method].tiny, TrainConfig(steps=6, batch_rays=128, log_every=2), None,
                  progress=False, deterministic=True, on_log=lambda entry, model: threads.append(_thread_count()))
        runs.append({k: np.array(v.numpy() if hasattr(v, "numpy") else v) for k, v in run.model.parameters().items()})
    return runs


def _thread_count() -> int:
    import drjit as dr

    return dr.thread_count()


@pytest.mark.parametrize("method", sorted(methods()))
def test_deterministic_training_is_bit_identical_and_runs_on_one_thread(method, world):
    from mitsnerf.data.dataset import load_dataset

    dataset = load_dataset(world.dataset)
    if nondeterminism() is not None:  # CUDA: refused, whatever the method
        with pytest.raises(UsageError, match="deterministic: .* float atomics"):
            _fit_twice(method, dataset, [])
        return
    threads_before, threads = _thread_count(), []
    runs = _fit_twice(method, dataset, threads)
    assert set(threads) == {1} and _thread_count() == threads_before
    assert runs[0].keys() == runs[1].keys()
    for key in runs[0]:
        np.testing.assert_array_equal(runs[0][key], runs[1][key], err_msg=f"{method}: {key}")


def test_deterministic_is_refused_in_one_line_where_the_backend_cannot_keep_it(world, tmp_path, monkeypatch, capsys):
    """Where :func:`nondeterminism` gives a reason (CUDA), train and bench refuse --deterministic before
    anything is made, and the library refuses ``deterministic=True``."""
    reason = "cuda_ad_rgb adds gradients with float atomics in an order the GPU decides"
    monkeypatch.setattr(mitsnerf.train.threads, "nondeterminism", lambda variant=None: reason)
    run = tmp_path / "run"
    assert main(["train", str(world.dataset), "--out", str(run), "--steps", "2", "--deterministic", *world.nerf]) == 2
    assert main(["bench", "--quick", "--deterministic", "--results", str(tmp_path / "results")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"mitsnerf: error: --deterministic: {reason}"] * 2
    assert not run.exists() and not (tmp_path / "results").exists()
    with pytest.raises(UsageError, match=f"^deterministic: {reason}$"):
        with mitsnerf.train.threads.one_thread():
            pass


def test_a_refused_deterministic_run_leaves_the_run_directory_as_it_was(world, tmp_path, monkeypatch):
    """The refusal comes before anything is written: ``api.fit(out=RUN, force=True, deterministic=True)`` on
    such a backend keeps the run in RUN, and resuming a run trained with --deterministic names its checkpoint."""
    from mitsnerf import api
    from mitsnerf.runs.fit import resume_run

    run = tmp_path / "run"
    # the run to protect is trained with --deterministic whatever the backend (CUDA itself refuses it)
    monkeypatch.setattr(mitsnerf.train.threads, "nondeterminism", lambda variant=None: None)
    assert main(["train", str(world.dataset), "--out", str(run), "--steps", "2", "--deterministic", *world.nerf]) == 0
    before = sorted(p.name for p in run.iterdir())
    monkeypatch.setattr(mitsnerf.train.threads, "nondeterminism", lambda variant=None: "no fixed order here")
    with pytest.raises(UsageError, match="^deterministic: no fixed order here$"):
        api.fit(world.dataset, "nerf", steps=2, out=run, force=True, deterministic=True)
    assert sorted(p.name for p in run.iterdir()) == before
    with pytest.raises(UsageError, match=r"checkpoint.npz: the run was trained with --deterministic, .* "
                                         r"MITSNERF_VARIANT=llvm_ad_rgb\): no fixed order here$"):
        resume_run(run, {"steps": 4}, progress=False)
    assert sorted(p.name for p in run.iterdir()) == before


def test_a_run_records_the_commit_it_started_with_not_the_one_at_its_end(world, tmp_path, monkeypatch):
    # The checkout may move while a run trains (a long run beside development): its files name the code it ran.
    import json

    from mitsnerf import env
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.runs.fit import fit
    from mitsnerf.train import TrainConfig

    commits = iter(["started-here"] + ["moved-on"] * 10)
    monkeypatch.setattr(env, "git_commit", lambda: next(commits))
    fit(load_dataset(world.dataset), "voxel", methods()["voxel"].tiny, TrainConfig(steps=2, batch_rays=64),
        tmp_path / "run", progress=False)
    for name in ("config.json", "metrics.json"):
        assert json.loads((tmp_path / "run" / name).read_text())["provenance"]["commit"] == "started-here"
