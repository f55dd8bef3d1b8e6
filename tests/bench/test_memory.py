"""Each cell's own peak memory: the same whatever ran before it in the process; the saved model's size beside it."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import pytest

from mitsnerf.bench.config import parse_bench_config
from mitsnerf.bench.runner import run_benchmark
from mitsnerf.train import memory

NERF = {"network": {"width": 16, "depth": 1, "features": 4, "head_width": 8, "pos_octaves": 4, "dir_octaves": 2},
        "n_samples": 16, "n_importance": 0}
VOXEL = {"resolution": 16, "initial_resolution": 8, "upsample_steps": [4], "n_samples": 24}


def _config(scene, methods):
    return parse_bench_config({
        "name": "memory", "scenes": [str(scene)], "seeds": [0],
        "train": {"steps": 6, "batch_rays": 128, "log_every": 3},
        "eval": {"curve_points": 0, "od_samples": 16},
        "oracle": {"spp": 4, "resolution": 8, "n_samples": 16, "noise_replicas": 1},
        "methods": methods}, "memory.toml")


@pytest.fixture(scope="module")
def both_orders(tiny_bench):
    """``{label: (record, cell directory)}`` of a sweep of voxel then nerf, and of nerf then voxel, both sweeps in
    this one process."""
    config, options = tiny_bench
    scene = config.scenes[0]
    methods = [{"name": "voxel", "label": "v", "config": VOXEL}, {"name": "nerf", "label": "n", "config": NERF}]
    out = []
    for order, name in ((methods, "voxel-first"), (methods[::-1], "nerf-first")):
        result = run_benchmark(_config(scene, order), options(name, report=False))
        paths = {c.key: c.path for c in result.cells}
        out.append({r["method"]: (r, paths[r["key"]]) for r in result.records})
    return out


def test_a_cells_peak_memory_does_not_depend_on_the_cells_before_it(both_orders):
    first, second = both_orders
    for label in ("v", "n"):
        a, b = first[label][0]["metrics"], second[label][0]["metrics"]
        assert a["peak_memory_mb"] > 0
        assert a["peak_memory_mb"] == pytest.approx(b["peak_memory_mb"], rel=1e-3), label
    # each cell its own figure: voxel's grids and replayed march are not the small network's
    assert first["v"][0]["metrics"]["peak_memory_mb"] != pytest.approx(first["n"][0]["metrics"]["peak_memory_mb"],
                                                                        rel=0.05)


def test_the_saved_models_size_is_its_parameter_files(both_orders):
    for cells in both_orders:
        for record, path in cells.values():
            m = record["metrics"]
            assert m["model_bytes"] == (path / "run" / "params.npz").stat().st_size
            assert m["model_bytes"] > 4 * m["num_parameters"]


def test_start_forgets_what_was_freed_before():
    big = dr.arange(mi.Float, 1 << 22)  # 16 MiB
    dr.eval(big)
    del big
    memory.start()
    small = dr.arange(mi.Float, 1 << 16)
    dr.eval(small)
    assert memory.peak_memory_mb() < 1.0
