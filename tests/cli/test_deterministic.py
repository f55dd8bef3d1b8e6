"""``--deterministic``: one Dr.Jit thread while training makes every method bit-identical run to run."""

from __future__ import annotations

import numpy as np
import pytest

from mitsnerf.methods import methods


@pytest.mark.parametrize("method", sorted(methods()))
def test_deterministic_training_is_bit_identical_and_runs_on_one_thread(method, world):
    import drjit as dr

    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.runs.fit import fit
    from mitsnerf.train import TrainConfig

    dataset = load_dataset(world.dataset)
    threads_before = dr.thread_count()
    runs, threads = [], []
    for _ in range(2):
        run = fit(dataset, method, methods()[method].tiny, TrainConfig(steps=6, batch_rays=128, log_every=2), None,
                  progress=False, deterministic=True, on_log=lambda entry, model: threads.append(dr.thread_count()))
        runs.append({k: np.array(v.numpy() if hasattr(v, "numpy") else v) for k, v in run.model.parameters().items()})
    assert set(threads) == {1} and dr.thread_count() == threads_before
    assert runs[0].keys() == runs[1].keys()
    for key in runs[0]:
        np.testing.assert_array_equal(runs[0][key], runs[1][key], err_msg=f"{method}: {key}")
