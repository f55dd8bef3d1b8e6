"""A tiny sweep end to end: every output, resume after an interrupt, and the Ray executor."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

import mitsnerf.bench.worker as worker
from mitsnerf.bench.cells import ARTEFACTS_FILE, RESULT_FILE
from mitsnerf.bench.runner import plan_cells, run_benchmark

QUALITY_KEYS = ("psnr_test", "psnr_test_srgb", "psnr_test_medium", "psnr_test_medium_srgb", "ssim_test",
                "ssim_test_srgb", "density_rel_l1", "density_rel_l2", "density_rel_mass", "density_psnr", "tau_rel_l1", "tau_rmse",
                "transmittance_mae")


@pytest.fixture(scope="module")
def interrupted_then_resumed(tiny_bench, monkeypatch_module):
    """The sweep interrupted (Ctrl-C) during its third cell, then run again."""
    config, options = tiny_bench
    opts = options("seq")
    calls = []
    real = worker.run_cell

    def run_cell(cell, **kw):
        calls.append(cell.key)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(cell, **kw)

    monkeypatch_module.setattr(worker, "run_cell", run_cell)
    with pytest.raises(KeyboardInterrupt):
        run_benchmark(config, opts)
    first = list(calls)
    cells = plan_cells(config, opts)
    saved = {c.key: (c.path / RESULT_FILE).read_bytes() for c in cells if (c.path / RESULT_FILE).exists()}
    calls.clear()
    opened = []
    real_open = worker._open_dataset

    def open_dataset(cell, progress):
        opened.append(cell.scene)
        return real_open(cell, progress)

    monkeypatch_module.setattr(worker, "_open_dataset", open_dataset)
    result = run_benchmark(config, opts)
    return cells, first, saved, list(calls), result, opened


@pytest.fixture(scope="module")
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


def test_resume_computes_only_the_missing_cells(interrupted_then_resumed):
    cells, first, saved, second, result, _ = interrupted_then_resumed
    keys = [c.key for c in cells]
    assert len(keys) == 4 and first == keys[:3]
    assert sorted(saved) == keys[:2]
    assert second == keys[2:] == result.computed
    assert result.skipped == keys[:2]
    for cell in cells[:2]:
        assert (cell.path / RESULT_FILE).read_bytes() == saved[cell.key]


def test_sweep_writes_every_output(interrupted_then_resumed):
    cells, _, _, _, result, _ = interrupted_then_resumed
    root = result.out_root
    for name in ("table.md", "table.csv", "average.csv", "cells.csv", "results.json", "report.html"):
        assert (root / name).is_file(), name
    for scene in ("tcloud", "tblobs"):
        for kind in ("psnr_time", "per_view", "error_budget", "images", "density"):
            png = root / "plots" / f"{kind}_{scene}.png"
            assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", png
    for cell in cells:
        assert (cell.path / ARTEFACTS_FILE).is_file() and (cell.path / "run" / "params.npz").is_file()

    md = (root / "table.md").read_text()
    assert "Quality per scene" in md and "Cost averaged over scenes" in md and "**" in md
    assert md.isascii()
    assert len(result.per_scene) == 6 and len(result.average) == 3  # and an oracle row per scene, averaged
    ceilings = [r for r in result.per_scene if r["method"] == "oracle"]
    assert [r["scene"] for r in ceilings] == ["tcloud", "tblobs"] and all(r["ceiling"] for r in ceilings)
    assert [result.per_scene.index(r) for r in ceilings] == [0, 3]  # first in each scene's group
    lines = md.split("\n")
    assert md.count("| oracle (ceiling) |") == 6  # quality and cost, per scene and averaged
    assert "oracle (ceiling)" in lines[6] and "**" not in lines[6]  # never marked best
    assert "class='ceiling'" in (root / "report.html").read_text()
    assert (root / "cells.csv").read_text().count("\n") == 5
    html = (root / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 10 and "<table>" in html

    data = json.loads((root / "results.json").read_text())
    assert data["provenance"]["variant"] and len(data["cells"]) == 4
    for record in data["cells"]:
        m = record["metrics"]
        for key in QUALITY_KEYS:
            assert isinstance(m[key], float) and math.isfinite(m[key]), key
        assert len(m["psnr_test_per_view"]) == len(m["ssim_test_srgb_per_view"]) == 2
        assert m["noise_floor_psnr"] > 0 and m["noise_floor_psnr_medium"] > 0
        ceiling = next(r for r in ceilings if r["scene"] == record["scene"])
        assert m["oracle_psnr_test_medium"] == ceiling["psnr_test_medium"] and math.isfinite(m["gap_to_oracle"])
        without = m["oracle_psnr_test_medium_without_mc"]  # the ceiling less its own Monte Carlo variance
        assert without == ceiling["psnr_test_medium_without_mc"] and without > ceiling["psnr_test_medium"]
        assert m["gap_to_oracle"] == pytest.approx(without - m["psnr_test_medium"])
        assert (Path(record["oracle"]["path"]) / "oracle.json").is_file()
        assert m["steps"] == 12 and m["num_parameters"] > 0 and m["peak_rss_mb"] > 0
        per_ray = 16 if record["method"] == "nerf-a" else 40
        assert m["rays_per_s"] > 0 and m["samples_per_s"] == pytest.approx(per_ray * m["rays_per_s"])
        points = record["curve"]["points"]
        assert [p["step"] for p in points] == [8, 12]  # the log entries at 1/2 and 2/2 of the budget
        assert points[-1]["seconds"] == pytest.approx(m["train_seconds"], abs=0.05)
        assert points[-1]["psnr"] == pytest.approx(m["psnr_test"])
        assert any("psnr_heldout" in h for h in record["history"])
        for key in ("commit", "variant", "mitsuba", "drjit", "machine"):
            assert record["provenance"][key]
        assert record["code_version"] == "test" and len(record["config_hash"]) == 64


def _quality(result):
    return {(r["scene"], r["method"], k): r[k] for r in result.per_scene if not r.get("ceiling") for k in QUALITY_KEYS}


def _ceilings(result):
    return [r for r in result.per_scene if r.get("ceiling")]


def test_pool_executor_gives_the_same_table(tiny_bench, interrupted_then_resumed):
    config, options = tiny_bench
    sequential = interrupted_then_resumed[4]
    pooled = run_benchmark(config, options("pool", executor="pool", workers=2, report=False))
    assert len(pooled.computed) == 4
    assert _quality(pooled) == pytest.approx(_quality(sequential), rel=1e-6)  # threads: 1 per cell, not 2
    assert _ceilings(pooled) == _ceilings(sequential) and len(_ceilings(pooled)) == 2  # the cached oracle
    assert all(r["worker"]["executor"] == "pool" for r in pooled.records)


def test_ray_executor_on_a_local_instance_gives_the_same_table(tiny_bench, interrupted_then_resumed):
    pytest.importorskip("ray")
    config, options = tiny_bench
    sequential = interrupted_then_resumed[4]
    on_ray = run_benchmark(config, options("ray", executor="ray", workers=2, report=False))
    assert len(on_ray.computed) == 4
    assert _quality(on_ray) == pytest.approx(_quality(sequential), rel=1e-6)
    assert _ceilings(on_ray) == _ceilings(sequential)
    assert all(r["worker"]["executor"] == "ray" and r["worker"]["fresh_process"] for r in on_ray.records)


def test_the_sequential_sweep_loads_each_scene_once(interrupted_then_resumed):
    """The resumed run computes both cells of the second scene: its dataset, oracle and reference are loaded
    once for the two (worker.SceneLoads), not once per cell."""
    cells, _, _, second, _, opened = interrupted_then_resumed
    assert [c.scene for c in cells if c.key in second] == ["tblobs", "tblobs"] and opened == ["tblobs"]


def test_a_quick_run_says_on_every_table_that_it_is_a_smoke_test(tiny_bench, interrupted_then_resumed):
    """The printed tables, table.md and report.html of a quick run start with what it is (and the tiny config's
    sizes); a full run's do not."""
    from dataclasses import replace

    from mitsnerf.bench.runner import BenchResult, write_outputs

    config, options = tiny_bench
    cells, result = interrupted_then_resumed[0], interrupted_then_resumed[4]
    assert not result.markdown.startswith("Quick profile")
    quick = write_outputs(config, replace(options("seq"), quick=True), cells, BenchResult(result.out_root, cells, [], []))
    banner = "Quick profile (16x16 views, 2 test views at 16 spp, 12 steps): a smoke test"
    assert quick.markdown.startswith(banner)
    assert banner in quick.files["table.md"].read_text() and banner in quick.files["report.html"].read_text()
