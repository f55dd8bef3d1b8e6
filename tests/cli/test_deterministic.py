"""``--deterministic``: one Dr.Jit thread while training makes every method bit-identical run to run."""

from __future__ import annotations

import numpy as np
import pytest

from mitsnerf.methods import METHODS

TINY = {
    "nerf": {"network": {"width": 8, "depth": 1, "head_width": 8, "features": 4}, "n_samples": 8, "n_importance": 4},
    "ngp": {"network": {"n_levels": 2, "log2_hashmap_size": 10, "base_resolution": 8, "max_resolution": 16,
                        "hidden": 8, "color_hidden": 8}, "occupancy": {"resolution": 8, "update_every": 2},
            "n_samples": 16},
    "voxel": {"resolution": 8, "initial_resolution": 4, "upsample_steps": [3], "n_samples": 16},
    "mitsuba-inverse": {"resolutions": [4, 8], "upsample_at": [3], "spp": 2, "eval_spp": 4},
}


def test_every_method_has_a_tiny_config_here():
    assert sorted(TINY) == sorted(METHODS)


@pytest.mark.parametrize("method", sorted(TINY))
def test_deterministic_training_is_bit_identical_and_runs_on_one_thread(method, world):
    import drjit as dr

    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.runs.fit import fit
    from mitsnerf.train import TrainConfig

    dataset = load_dataset(world.dataset)
    threads_before = dr.thread_count()
    runs, threads = [], []
    for _ in range(2):
        run = fit(dataset, method, TINY[method], TrainConfig(steps=6, batch_rays=128, log_every=2), None,
                  progress=False, deterministic=True, on_log=lambda entry, model: threads.append(dr.thread_count()))
        runs.append({k: np.array(v.numpy() if hasattr(v, "numpy") else v) for k, v in run.model.parameters().items()})
    assert set(threads) == {1} and dr.thread_count() == threads_before
    assert runs[0].keys() == runs[1].keys()
    for key in runs[0]:
        np.testing.assert_array_equal(runs[0][key], runs[1][key], err_msg=f"{method}: {key}")
