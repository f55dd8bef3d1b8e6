"""A row started from another row's result (``init_from = "@ngp"``): checked at load, ordered, hashed with the
row it names, resolved in the worker, and a tiny sweep end to end."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from mitsnerf.bench.cells import ERROR_FILE, RESULT_FILE, write_error, write_result
from mitsnerf.bench.config import parse_bench_config
from mitsnerf.bench.references import UnresolvedReference, dependency_waves, resolved_config
from mitsnerf.bench.runner import BenchOptions, plan_cells, run_benchmark
from mitsnerf.errors import SpecError

INVERSE = {"name": "mitsuba-inverse", "label": "inverse", "config": {"init_from": "@ngp"}}


def _config(methods, **kw):
    return parse_bench_config({"name": "r", "scenes": ["cloud"], "methods": methods, **kw}, "r.toml")


def _plan(config, tmp_path, quick: bool = False):
    options = BenchOptions(quick=quick, data_root=tmp_path, results_root=tmp_path, code_version="t")
    return plan_cells(config, options)


BAD = [  # (methods, other keys, field, message start)
    ([INVERSE], {}, "methods.0.config.init_from", "@ngp: no [[methods]] row is labelled 'ngp' (labels: inverse)"),
    ([{**INVERSE, "config": {"init_from": "@inverse"}}], {}, "methods.0.config.init_from",
     "@inverse is this row's own label"),
    ([{**INVERSE, "config": {"init_from": "@b"}}, {**INVERSE, "label": "b", "config": {}, "quick": {"config": {
        "init_from": "@inverse"}}}], {}, "methods.0.config.init_from",
     "@b: the rows refer to each other in a cycle (inverse -> b -> inverse)"),
    ([INVERSE], {"external": [{"name": "ngp", "renders": {"cloud": "x"}}]}, "methods.0.config.init_from",
     "@ngp: 'ngp (external)' is an [[external]] entry: renders only, no run to start from"),
    ("all", {"method_settings": {"mitsuba-inverse": {"quick": {"config": {"init_from": "@ngq"}}}}},
     "method_settings.mitsuba-inverse.quick.config.init_from", "@ngq: no [[methods]] row is labelled 'ngq'"),
]


@pytest.mark.parametrize("methods, more, field, message", BAD, ids=["unknown", "self", "cycle", "external", "all"])
def test_a_bad_reference_is_refused_at_load_naming_the_file_and_field(methods, more, field, message):
    with pytest.raises(SpecError) as info:
        _config(methods, **more)
    assert (info.value.where, info.value.field) == ("r.toml", field)
    assert info.value.message.startswith(message), info.value.message


def test_the_command_line_refuses_it_in_one_line_with_status_2(tmp_path, capsys):
    from mitsnerf.cli import main

    path = tmp_path / "b.toml"
    path.write_text('scenes = ["cloud"]\n[[methods]]\nname = "mitsuba-inverse"\nconfig = { init_from = "@ngp" }\n')
    assert main(["bench", str(path), "--quick"]) == 2
    assert capsys.readouterr().err == (f"mitsnerf: error: {path}: methods.0.config.init_from: @ngp: no [[methods]] "
                                       "row is labelled 'ngp' (labels: mitsuba-inverse)\n")


def test_a_row_runs_after_the_row_it_names_and_pools_run_in_waves(tmp_path):
    config = _config([INVERSE, {"name": "ngp"}, {"name": "nerf"}], scenes=["cloud", "plume"], seeds=[0, 1])
    cells = _plan(config, tmp_path)
    assert [c.key for c in cells[:6]] == ["cloud/ngp-seed0", "cloud/ngp-seed1", "cloud/inverse-seed0",
                                         "cloud/inverse-seed1", "cloud/nerf-seed0", "cloud/nerf-seed1"]
    inverse = cells[2]
    assert inverse.references == {"ngp": {"key": "cloud/ngp-seed0", "out_dir": cells[0].out_dir,
                                          "config_hash": cells[0].config_hash}}
    assert [c.references for c in cells if c.label != "inverse"] == [None] * 8
    waves = dependency_waves(cells)
    assert [sorted({c.label for c in w}) for w in waves] == [["nerf", "ngp"], ["inverse"]]
    assert [c.key for c in dependency_waves([c for c in cells if c.label != "ngp"])[0]] == [
        c.key for c in cells if c.label != "ngp"]  # the rows named already done: one wave


def test_the_pool_runs_each_wave_after_the_one_before(tmp_path, monkeypatch):
    import mitsnerf.bench.executors as executors

    cells = _plan(_config([INVERSE, {"name": "ngp"}], seeds=[0, 1]), tmp_path)
    waves = []
    monkeypatch.setattr(executors, "_pool_wave", lambda pool, wave, *rest: waves.append([c.key for c in wave]))
    executors.run_pool(cells, lambda *a: None, lambda *a: None, workers=1)
    assert waves == [["cloud/ngp-seed0", "cloud/ngp-seed1"], ["cloud/inverse-seed0", "cloud/inverse-seed1"]]


def test_the_hash_follows_the_row_named_and_the_record_keeps_the_label(tmp_path):
    base = {c.key: c for c in _plan(_config([INVERSE, {"name": "ngp"}]), tmp_path)}
    changed = {c.key: c for c in _plan(_config([INVERSE, {"name": "ngp", "config": {"n_samples": 64}}]), tmp_path)}
    assert changed["cloud/ngp-seed0"].config_hash != base["cloud/ngp-seed0"].config_hash
    assert changed["cloud/inverse-seed0"].config_hash != base["cloud/inverse-seed0"].config_hash  # rerun with it
    assert changed["cloud/inverse-seed0"].method_config == base["cloud/inverse-seed0"].method_config
    identity = base["cloud/inverse-seed0"].identity()
    assert identity["method_config"]["init_from"] == "@ngp"
    assert identity["references"] == {"ngp": base["cloud/ngp-seed0"].config_hash}
    assert "references" not in base["cloud/ngp-seed0"].identity()  # a row naming none hashes as before


def test_the_worker_refuses_a_row_whose_named_cell_failed_or_has_no_result(tmp_path):
    ngp, inverse = _plan(_config([INVERSE, {"name": "ngp"}]), tmp_path)
    with pytest.raises(UnresolvedReference, match=r"^init_from: '@ngp' is cell cloud/ngp-seed0, which has no result"):
        resolved_config(inverse)
    write_error(ngp, "TrainingError: loss became nan")
    with pytest.raises(UnresolvedReference, match=r"which failed \(TrainingError: loss became nan\), so this cell"):
        resolved_config(inverse)
    write_result(ngp, {"config_hash": ngp.config_hash, "code_version": ngp.code_version}, None)
    with pytest.raises(UnresolvedReference, match=r"whose run directory .*ngp-seed0/run is not on this machine"):
        resolved_config(inverse)


NGP = {"network": {"n_levels": 2, "log2_hashmap_size": 10, "base_resolution": 8, "max_resolution": 16, "hidden": 8,
                   "color_hidden": 8, "geo_features": 3}, "occupancy": {"resolution": 8}, "n_samples": 16}
INVERSE_TINY = {"resolutions": [8], "upsample_at": [], "spp": 1, "spp_primal_factor": 1, "albedo_resolution": 8,
                "init_from": "@ngp"}


@pytest.fixture(scope="module")
def started_from_ngp(tiny_bench):
    """A --quick sweep of the tiny scene: mitsuba-inverse started from ngp's fit (listed first), and ngp."""
    tiny, options = tiny_bench
    config = parse_bench_config({
        "name": "from-ngp", "scenes": [tiny.scenes[0]], "seeds": [0],
        "eval": {"curve_points": 1, "od_samples": 16},
        "oracle": {"spp": 4, "resolution": 8, "n_samples": 16, "noise_replicas": 1},  # tiny_bench's: its cached one
        "methods": [{"name": "mitsuba-inverse", "label": "inverse (ngp start)", "config": INVERSE_TINY,
                     "quick": {"config": {"eval_spp": 16}}},
                    {"name": "ngp", "config": NGP}],
        "quick": {"train": {"steps": 3, "batch_rays": 64, "log_every": 1}},
    }, "from-ngp.toml")
    opts = dataclasses.replace(options("refs"), quick=True, report=False)
    return run_benchmark(config, opts), plan_cells(config, opts), config, opts


def test_a_sweep_starts_the_row_from_the_named_rows_exported_fit(started_from_ngp):
    result, (ngp, inverse), _, _ = started_from_ngp
    assert result.computed == [ngp.key, inverse.key] and not result.failed  # ngp first, though listed second
    export = json.loads((ngp.path / "run" / "export" / "export.json").read_text())
    assert export["resolution"] == 64 and export["method"] == "ngp"
    run_config = json.loads((inverse.path / "run" / "config.json").read_text())
    assert run_config["method_config"]["init_from"] == str(ngp.path / "run")  # what the fit started from
    sigma = np.load(ngp.path / "run" / "export" / "sigma_t.npy")
    assert sigma.shape == (64, 64, 64) and np.all(np.isfinite(sigma))
    record = json.loads((inverse.path / RESULT_FILE).read_text())
    assert record["config"]["method_config"]["init_from"] == "@ngp"  # what the row says it started from
    assert record["config"]["references"] == {"ngp": ngp.config_hash}
    assert not (inverse.path / ERROR_FILE).exists()


def test_the_row_shows_in_the_tables_and_a_second_run_skips_both(started_from_ngp):
    result, cells, config, opts = started_from_ngp
    table = (result.out_root / "table.md").read_text()
    assert "| inverse (ngp start) |" in table and "| ngp |" in table
    data = json.loads((result.out_root / "results.json").read_text())
    assert [r["method"] for r in data["cells"]] == ["ngp", "inverse (ngp start)"] and not data["failed"]
    again = run_benchmark(config, opts)
    assert again.computed == [] and again.skipped == [c.key for c in cells]
    assert Path(cells[0].path / "run" / "export").is_dir()

