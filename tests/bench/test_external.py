"""A benchmark's [[external]] entries: other tools' renders scored beside the cells, marked external."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import pytest

import mitsnerf.bench.runner as runner
import mitsnerf.bench.worker as worker
from mitsnerf.bench.config import parse_bench_config
from mitsnerf.bench.runner import plan_cells, run_benchmark
from mitsnerf.config import to_dict
from mitsnerf.errors import DatasetError, SpecError


def _with_external(config, external, tmp_path):
    """The tiny benchmark cut to one scene (tcloud) and one method, with ``external`` entries."""
    raw = {**{k: v for k, v in to_dict(config).items() if k != "methods"}, "scenes": list(config.scenes[:1]),
           "methods": [to_dict(config.methods[0])], "external": external}
    return parse_bench_config(raw, tmp_path / "ext.toml")


def _renders(cells, scene, tmp_path, opts, name="ref"):
    """The scene's test_ref EXRs as a renders folder (they score exactly the noise floor); the dataset is
    generated here if no earlier test made it (each test stands alone, in any order or process)."""
    first = next(c for c in cells if c.scene == scene)
    runner._generate([first], opts, lambda line: None)
    dataset = first.dataset_dir
    folder = tmp_path / name
    folder.mkdir()
    for f in sorted((Path(dataset) / "test_ref").glob("r_*.exr")):
        shutil.copy(f, folder / f.name)
    return folder, Path(dataset)


def test_external_rows_in_tables_plots_and_report(tiny_bench, tmp_path):
    config, options = tiny_bench
    opts = options("ext")  # not test_sweep's results: it counts the cells it runs
    plain = _with_external(config, [], tmp_path)
    cells = plan_cells(plain, opts)
    run_benchmark(plain, dataclasses.replace(opts, report=False))  # the cell first
    folder, dataset = _renders(cells, "tcloud", tmp_path, opts)
    ext = _with_external(config, [{"name": "ref", "renders": {"tcloud": "ref"},
                                   "density": {"tcloud": str(dataset / "volume" / "sigma_t.npy")}}], tmp_path)
    result = run_benchmark(ext, opts)
    assert not result.computed  # the externals did not change any cell
    row = next(r for r in result.per_scene if r["method"] == "ref (external)")
    floor = json.loads((dataset / "manifest.json").read_text())["noise_floor"]
    assert row["scene"] == "tcloud" and row["psnr_test"] == floor["psnr"] and row["density_rel_l1"] == 0.0
    assert row.get("train_seconds") is None  # no training: the cost columns stay empty
    record = next(r for r in result.records if r.get("external"))
    oracle = json.loads((Path(record["oracle"]["path"]) / "scores.json").read_text())["footprint_1"]
    assert row["oracle_psnr_test_medium"] == oracle["psnr_test_medium"]  # the cells' oracle, at footprint 1
    cell = next(r for r in result.per_scene if not r.get("external") and not r.get("ceiling")
                and r["method"] != "ref (external)")
    # one table, each row at its own footprint with its own oracle: the cells' K = 3, the renders' K = 1
    assert (cell["footprint"], row["footprint"]) == (3, 1)
    assert cell["oracle_psnr_test_medium"] == next(r for r in result.per_scene if r.get("ceiling"))["psnr_test_medium"]
    assert cell["oracle_psnr_test_medium"] != row["oracle_psnr_test_medium"]
    assert row["gap_to_oracle"] == pytest.approx(oracle["psnr_test_medium"] - row["psnr_test_medium"], abs=1e-5)
    root = result.out_root
    assert "| tcloud | ref (external) | 1 |" in (root / "table.md").read_text()
    assert "ref (external)" in (root / "table.csv").read_text() and "ref (external)" in (root / "report.html").read_text()
    data = json.loads((root / "results.json").read_text())
    assert [r["key"] for r in data["cells"] if r.get("external")] == ["tcloud/ref (external)"]
    assert (root / "plots" / "images_tcloud.png").is_file() and (root / "plots" / "density_tcloud.png").is_file()


def test_bad_external_stops_before_training(tiny_bench, tmp_path, monkeypatch):
    config, options = tiny_bench
    cells = plan_cells(config, options("fresh"))
    folder, _ = _renders(cells, "tcloud", tmp_path, options("fresh"))
    (folder / "r_001.exr").unlink()
    monkeypatch.setattr(worker, "run_cell", lambda *a, **k: pytest.fail("a cell ran"))
    ext = _with_external(config, [{"name": "ref", "renders": {"tcloud": "ref"}}], tmp_path)
    with pytest.raises(DatasetError, match="no render for test frame r_001"):
        run_benchmark(ext, options("fresh"))
    wrong = _with_external(config, [{"name": "ref", "renders": {"nosuch": "ref"}}], tmp_path)
    with pytest.raises(SpecError, match=r"ext.toml: external.0.renders.nosuch: not a scene of this benchmark"):
        run_benchmark(wrong, options("fresh"))


def test_a_missing_renders_folder_stops_before_any_dataset_or_oracle_is_made(tiny_bench, tmp_path, monkeypatch):
    config, options = tiny_bench
    monkeypatch.setattr(runner, "_generate", lambda *a, **k: pytest.fail("a dataset was generated"))
    ext = _with_external(config, [{"name": "ref", "renders": {"tcloud": "gone"}}], tmp_path)
    with pytest.raises(SpecError, match=r"ext.toml: external.0.renders.tcloud: .*gone: renders folder not found"):
        run_benchmark(ext, options("fresh"))


def test_external_entries_need_a_quick_table_for_quick(tiny_bench, tmp_path):
    from mitsnerf.bench.external import plan_externals

    config, options = tiny_bench
    (tmp_path / "ref").mkdir()
    for name in ("r_000.exr", "r_001.exr"):  # matched to the test frames before any dataset is made
        (tmp_path / "ref" / name).write_bytes(b"")
    ext = _with_external(config, [{"name": "ref", "renders": {"tcloud": "ref"}}], tmp_path)
    cells = plan_cells(ext, options("fresh"))
    assert [e.key for e in plan_externals(ext, False, cells)] == ["tcloud/ref (external)"]
    assert plan_externals(ext, True, cells) == []
    assert plan_externals(ext, False, cells)[0].renders == tmp_path / "ref"


def test_a_config_of_external_entries_only_is_scored(tiny_bench, tmp_path):
    """No [[methods]] at all: it used to be refused twice (methods: missing field, then at least one method)."""
    config, options = tiny_bench
    scenes = runner.plan_scenes(config, options("ext-only"))
    folder, dataset = _renders(scenes, "tcloud", tmp_path, options("ext-only"))
    raw = {**{k: v for k, v in to_dict(config).items() if k != "methods"}, "scenes": list(config.scenes[:1]),
           "external": [{"name": "ref", "renders": {"tcloud": "ref"}}]}
    ext = parse_bench_config(raw, tmp_path / "ext.toml")
    assert ext.methods == () and plan_cells(ext, options("ext-only")) == []
    result = run_benchmark(ext, dataclasses.replace(options("ext-only"), report=False))
    assert [(r["scene"], r["method"]) for r in result.per_scene if not r.get("ceiling")] == [("tcloud", "ref (external)")]
    assert "| tcloud | ref (external) |" in (result.out_root / "table.md").read_text()
    with pytest.raises(SpecError, match=r"ext.toml: external: nothing to run"):
        run_benchmark(ext, options("ext-only", quick=True))


def test_a_missing_density_file_or_render_stops_before_any_dataset_is_made(tiny_bench, tmp_path, monkeypatch):
    config, options = tiny_bench
    folder, _ = _renders(runner.plan_scenes(config, options("fresh")), "tcloud", tmp_path, options("fresh"))
    monkeypatch.setattr(runner, "_generate", lambda *a, **k: pytest.fail("a dataset was generated"))
    ext = _with_external(config, [{"name": "ref", "renders": {"tcloud": "ref"}, "density": {"tcloud": "no.npy"}}],
                         tmp_path)
    with pytest.raises(SpecError, match=r"ext.toml: external.0.density.tcloud: .*no.npy: density file not found"):
        run_benchmark(ext, options("fresh"))
    (folder / "r_001.exr").unlink()
    ext = _with_external(config, [{"name": "ref", "renders": {"tcloud": "ref"}}], tmp_path)
    with pytest.raises(DatasetError, match="no render for test frame r_001"):
        run_benchmark(ext, options("fresh"))


def test_a_timings_file_fills_the_budget_and_cost_columns(tiny_bench, tmp_path):
    """The launcher's timings.json gives the external row its budget, train seconds and rays/s; a malformed
    one stops the run before anything is made, naming the file and the field."""
    config, options = tiny_bench
    folder, _ = _renders(runner.plan_scenes(config, options("ext-cost")), "tcloud", tmp_path, options("ext-cost"))
    timings = tmp_path / "timings.json"
    timings.write_text(json.dumps({"steps": 300, "rays_per_step": 512, "train_wall_s": 12.5, "matched": "seconds"}))
    raw = {**{k: v for k, v in to_dict(config).items() if k != "methods"}, "scenes": list(config.scenes[:1]),
           "external": [{"name": "ref", "renders": {"tcloud": "ref"}, "timings": {"tcloud": "timings.json"}}]}
    result = run_benchmark(parse_bench_config(raw, tmp_path / "ext.toml"),
                           dataclasses.replace(options("ext-cost"), report=False))
    row = next(r for r in result.per_scene if r["method"] == "ref (external)")
    assert (row["steps"], row["train_seconds"], row["rays_per_s"]) == (300, 12.5, 300 * 512 / 12.5)
    assert "| 300 steps x 512 rays (seconds matched) |" in (result.out_root / "table.md").read_text()
    timings.write_text(json.dumps({"steps": 300, "rays_per_step": 512}))
    with pytest.raises(SpecError, match=r"timings.json: train_wall_s: missing"):
        run_benchmark(parse_bench_config(raw, tmp_path / "ext.toml"), options("ext-cost"))
    timings.unlink()
    with pytest.raises(SpecError, match=r"ext.toml: external.0.timings.tcloud: .*timings.json: timings file not found"):
        run_benchmark(parse_bench_config(raw, tmp_path / "ext.toml"), options("ext-cost"))


def test_score_of_a_cells_run_gives_the_cells_own_figures(tiny_bench, tmp_path, capsys):
    """``mitsnerf score DATASET CELL/run`` prints and writes what the benchmark does for that cell: the same
    renders held against the same oracle at the run's footprint (3, not the folder default 1), the row named
    after the run's method, and the density scores of its model (which the renders alone cannot give)."""
    from mitsnerf.cli import main

    config, options = tiny_bench
    opts = options("ext")
    plain = _with_external(config, [], tmp_path)
    result = run_benchmark(plain, dataclasses.replace(opts, report=False))
    (cell,) = plan_cells(plain, opts)
    record = next(r for r in result.records if r["key"] == cell.key)
    assert main(["score", record["dataset"], str(cell.path / "run"), "--out", str(tmp_path / "s.json")]) == 0
    out = capsys.readouterr().out
    scored, bench = json.loads((tmp_path / "s.json").read_text())["metrics"], record["metrics"]
    assert bench["footprint"] == 3 and bench["density_rel_l1"] is not None and bench["oracle_psnr_test_medium"]
    for key in ("footprint", "psnr_test", "psnr_test_medium", "oracle_psnr_test_medium", "gap_to_oracle",
                "noise_floor_psnr_medium", "density_rel_l1", "density_rel_mass", "tau_rel_l1", "transmittance_mae",
                "psnr_train"):
        assert scored[key] == bench[key], key
    assert f"| tcloud | {cell.method} | 1 |" in out and "(external)" not in out


def test_a_scene_loads_its_reference_once_and_its_oracle_is_scored_against_it(tiny_bench, tmp_path, monkeypatch):
    """A cell whose dataset has no oracle cached yet computes it against the reference the cell is scored
    against: the scene's test views are loaded as a reference once, not once more inside the oracle."""
    import mitsnerf.scoring.reference as reference
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import parse_scene

    config, options = tiny_bench
    (cell,) = plan_cells(_with_external(config, [], tmp_path),
                         dataclasses.replace(options("once"), data_root=tmp_path / "data"))
    generate_dataset(parse_scene(dict(cell.spec), "tcloud"), Path(cell.data_root), progress=False)
    loads = []
    real = reference.load_reference
    monkeypatch.setattr(reference, "load_reference", lambda *a, **k: loads.append(a) or real(*a, **k))
    _, oracle, ref = worker.SceneLoads().scene(cell, progress=False)
    assert oracle is not None and len(loads) == 1
    assert oracle.metrics(3)["noise_floor_psnr_medium"] == ref.noise_floor["psnr_medium"]
