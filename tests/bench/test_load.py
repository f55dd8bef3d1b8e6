"""Step budgets make a table evidence: the same config and seed give the same quality columns with and
without a CPU-burning process beside the sweep.

Bit-for-bit: ``nerf`` with any thread count (its gradients are summed in a fixed order); the grid
methods (``voxel``, ``ngp``) single-threaded (``--cpus-per-cell 1``), since multi-threaded
scatter-adds round in the order the threads run. On CUDA the grid methods' scatter-adds are float atomics
that no thread count orders: there their columns agree to a relative 1e-6 (measured on an H200: 3e-12), far
below what a budget that followed the load would change.
"""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from mitsnerf.bench.config import parse_bench_config
from mitsnerf.bench.runner import BenchOptions, run_benchmark
from mitsnerf.train.threads import nondeterminism

from .conftest import CODE_VERSION, write_scene

QUALITY_KEYS = ("psnr_test", "psnr_test_medium", "psnr_test_srgb", "ssim_test", "psnr_train", "density_rel_l1",
                "tau_rel_l1", "steps")


def _config(scene, method: dict):
    return parse_bench_config({
        "name": "load", "scenes": [str(scene)], "seeds": [0],
        "train": {"steps": 10, "batch_rays": 128, "log_every": 5},
        "eval": {"curve_points": 2, "od_samples": 16, "footprint": 2},
        "methods": [method],
    }, "load.toml")


def _quality(result) -> list:
    out = []
    for record in result.records:
        m = record["metrics"]
        out.append([m.get(k) for k in QUALITY_KEYS] + [(p["step"], p["psnr"]) for p in record["curve"]["points"]])
    return out


def _flat(rows: list) -> list:
    return [x for row in rows for v in row for x in (v if isinstance(v, tuple) else (v,))]


def _far_apart(a: list, b: list, rel: float) -> list:
    """The pairs of ``a`` and ``b`` (None only with None) further apart than ``rel`` of the larger."""
    assert len(a) == len(b)
    return [(x, y) for x, y in zip(a, b)
            if (x is None) != (y is None) or (x is not None and abs(x - y) > rel * max(abs(x), abs(y)))]


@pytest.fixture
def burners():
    """Two processes that burn a CPU core each while the test runs."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    yield procs
    for p in procs:
        p.kill()
        p.wait()


@pytest.mark.parametrize("method, threads", [
    ({"name": "nerf", "config": {"network": {"width": 16, "depth": 1, "features": 4, "head_width": 8, "pos_octaves": 4},
                                 "n_samples": 12, "n_importance": 8}}, 0),
    ({"name": "voxel", "config": {"resolution": 16, "initial_resolution": 8, "upsample_steps": [4], "n_samples": 16}}, 1),
])
def test_the_same_config_gives_the_same_table_under_load(tmp_path, method, threads, burners):
    scene = write_scene(tmp_path, "tload")
    config = _config(scene, method)

    def run(results: str):
        options = BenchOptions(data_root=tmp_path / "data", results_root=tmp_path / results, progress=False,
                               code_version=CODE_VERSION, cpus_per_cell=threads)
        return run_benchmark(config, options)

    for p in burners:  # quiet first
        p.send_signal(signal.SIGSTOP)
    quiet = run("quiet")
    for p in burners:
        p.send_signal(signal.SIGCONT)
    loaded = run("loaded")
    assert quiet.records
    if threads == 1 and nondeterminism() is not None:
        assert _far_apart(_flat(_quality(quiet)), _flat(_quality(loaded)), rel=1e-6) == []
    else:
        assert _quality(quiet) == _quality(loaded)
    assert quiet.records[0]["metrics"]["budget"] == "steps"
