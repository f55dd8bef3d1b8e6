"""A row started from another row's result (``init_from = "@ngp"``): checked at load, ordered, hashed with the
row it names, resolved in the worker, and a tiny sweep end to end."""

from __future__ import annotations

import pytest

from mitsnerf.bench.config import parse_bench_config
from mitsnerf.bench.runner import BenchOptions, plan_cells
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


def test_a_row_runs_after_the_row_it_names(tmp_path):
    config = _config([INVERSE, {"name": "ngp"}, {"name": "nerf"}], scenes=["cloud", "plume"], seeds=[0, 1])
    cells = _plan(config, tmp_path)
    assert [c.key for c in cells[:6]] == ["cloud/ngp-seed0", "cloud/ngp-seed1", "cloud/inverse-seed0",
                                         "cloud/inverse-seed1", "cloud/nerf-seed0", "cloud/nerf-seed1"]
    inverse = cells[2]
    assert inverse.references == {"ngp": {"key": "cloud/ngp-seed0", "out_dir": cells[0].out_dir,
                                          "config_hash": cells[0].config_hash}}
    assert [c.references for c in cells if c.label != "inverse"] == [None] * 8


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
