"""Benchmark configs: the shipped ones load, the quick profile merges, mistakes name their field."""

from __future__ import annotations

import warnings

import pytest

from mitsnerf.bench.config import benchmarks_dir, load_bench_config, parse_bench_config
from mitsnerf.bench.runner import BenchOptions, plan_cells
from mitsnerf.errors import SpecError
from mitsnerf.methods import methods
from mitsnerf.scene.spec import list_scenes

from .conftest import write_scene


def test_the_shipped_configs_load_and_plan(tmp_path):
    names = sorted(p.stem for p in benchmarks_dir().glob("*.toml"))
    assert {"default", "full"} <= set(names)
    for name in names:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # full.toml may name methods that have not landed yet
            config = load_bench_config(name)
        for quick in (False, True):
            cells = plan_cells(config, BenchOptions(quick=quick, data_root=tmp_path, results_root=tmp_path, code_version="t"))
            assert len(cells) == len(config.scenes) * len(config.methods) * len(config.seeds)


@pytest.mark.parametrize("name", ["default", "full", "targets", "paper"])
def test_shipped_budgets_are_steps(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        config = load_bench_config(name)
    for quick in (False, True):
        for method in config.methods:
            _, train = config.method_settings(method, quick)
            assert "seconds" not in train and train.get("steps", 0) >= 1, (name, method.label, quick)


def test_full_runs_every_scene_and_method_with_three_seeds():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        config = load_bench_config("full")
    assert list(config.scenes) == list_scenes()
    assert sorted(m.name for m in config.methods) == sorted(methods())
    assert len(config.seeds) == 3


def test_default_quick_profile_merges_over_the_method_settings():
    config = load_bench_config("default")
    method = config.methods[0]
    _, train = config.method_settings(method, quick=False)
    mconfig, qtrain = config.method_settings(method, quick=True)
    assert "seconds" not in train and "seconds" not in qtrain and qtrain["steps"] < train["steps"]  # step budgets
    assert qtrain["batch_rays"] < train["batch_rays"] and mconfig["n_samples"] == 32
    assert config.eval_config(True).curve_points < config.eval_config(False).curve_points


def _config(**kw):
    raw = {"name": "t", "scenes": ["cloud"], "methods": [{"name": "nerf"}]}
    raw.update(kw)
    return parse_bench_config(raw, "t.toml")


@pytest.mark.parametrize("change, field", [
    ({"methods": [{"name": "nope"}]}, "methods.0.name"),  # list items by index, as in overrides
    ({"methods": [{"name": "nerf"}, {"name": "nerf"}]}, "methods"),
    ({"seeds": []}, "seeds"),
    ({"scenes": "some"}, "scenes"),
    ({"method_settings": {"nerf": {}}}, "method_settings"),
    ({"eval": {"curve_points": -1}}, "eval.curve_points"),
    ({"bogus": 1}, "bogus"),
])
def test_mistakes_name_their_field(change, field):
    with pytest.raises(SpecError) as info:
        _config(**change)
    assert info.value.field == field and str(info.value).startswith("t.toml: ")


def test_methods_all_with_settings_for_a_method_not_registered_yet_warns():
    with pytest.warns(UserWarning, match="method_settings.not-yet"):
        config = _config(methods="all", method_settings={"nerf": {"label": "N", "config": {"n_samples": 8}}, "not-yet": {}})
    labels = {m.name: m.label for m in config.methods}
    assert labels["nerf"] == "N" and set(labels) == set(methods())


def test_plan_validates_method_settings_before_running(tmp_path):
    options = BenchOptions(data_root=tmp_path, results_root=tmp_path, code_version="t")
    with pytest.raises(ValueError, match=r"^t\.toml: methods\.0\.config\.n_samples: .*\(method nerf\)"):
        plan_cells(_config(methods=[{"name": "nerf", "config": {"n_samples": 0}}]), options)
    with pytest.raises(ValueError, match="train.seed"):
        plan_cells(_config(methods=[{"name": "nerf", "train": {"seed": 3}}]), options)


def test_the_config_hash_changes_with_what_decides_the_result(tmp_path):
    options = BenchOptions(data_root=tmp_path, results_root=tmp_path, code_version="t")
    base = plan_cells(_config(), options)[0]
    assert plan_cells(_config(), options)[0].config_hash == base.config_hash
    assert plan_cells(_config(seeds=[1]), options)[0].config_hash != base.config_hash
    assert plan_cells(_config(train={"steps": 5}), options)[0].config_hash != base.config_hash
    assert plan_cells(_config(eval={"curve_points": 2}), options)[0].config_hash != base.config_hash
    other_root = BenchOptions(data_root=tmp_path / "x", results_root=tmp_path / "y", code_version="t")
    assert plan_cells(_config(), other_root)[0].config_hash == base.config_hash  # paths are not part of it


def test_cli_rejects_executor_options_that_do_not_fit(capsys):
    from mitsnerf.cli import main

    assert main(["bench", "default", "--quick", "--address", "ray://x:1"]) == 2
    assert "--address: only with --executor ray" in capsys.readouterr().err
    assert main(["bench", "default", "--quick", "--workers", "3"]) == 2
    assert "--workers" in capsys.readouterr().err


def _plan(raw: dict, source: str = "benchmarks/x.toml", quick: bool = False, tmp=None):
    options = BenchOptions(quick=quick, data_root=tmp, results_root=tmp, code_version="t")
    return plan_cells(parse_bench_config(raw, source), options)


NERF = [{"name": "nerf"}]
BAD_BENCH = [  # (raw config, quick, field, message); every error names benchmarks/x.toml
    ({}, False, "scenes", "missing field (a list)"),
    ({"scenes": ["cloud"]}, False, "methods", "at least one method (or an [[external]] entry) is needed"),
    ({"scenes": ["cloud"], "methods": NERF, "seeds": [0, -1]}, False, "seeds.1", "must be an integer >= 0, got -1"),
    ({"scenes": ["cloud"], "methods": NERF, "train": 3}, False, "train", "must be a table, got an integer"),
    ({"scenes": ["cloud"], "methods": [{"name": "nerf", "confg": {}}]}, False, "methods.0.confg",
     "unknown field (did you mean 'config'?)"),
    ({"scenes": ["cloud"], "methods": NERF, "train": {"steps": 0}}, False, "train.steps",
     "must be an integer in [1, 100000000], got 0 (method nerf)"),
    ({"scenes": ["cloud"], "methods": [{"name": "nerf", "train": {"stepz": 5}}]}, False, "methods.0.train.stepz",
     "unknown field (did you mean 'steps'?) (method nerf)"),
    ({"scenes": ["cloud"], "methods": NERF, "quick": {"train": {"steps": -3}}}, True, "quick.train.steps",
     "must be an integer in [1, 100000000], got -3 (method nerf)"),
    ({"scenes": ["cloud"], "methods": [{"name": "nerf", "quick": {"config": {"n_samples": 0}}}]}, True,
     "methods.0.quick.config.n_samples", "must be an integer in [1, 4096], got 0 (method nerf)"),
    ({"scenes": ["cloud"], "methods": NERF, "quick": {"scene": {"cameras.width": 0}}}, True,
     "quick.scene.cameras.width", "must be an integer in [1, 8192], got 0 (scene cloud)"),
    ({"scenes": ["cloud"], "methods": NERF, "quick": {"scene": {"lights.5.radiance": [1, 1, 1]}}}, True,
     "quick.scene.lights.5.radiance", "no item '5' (there are 2) (scene cloud)"),
    ({"scenes": ["cloud"], "methods": NERF, "scene": {"cameras.n_train": 0}}, False,
     "scene.cameras.n_train", "must be an integer in [1, 10000], got 0 (scene cloud)"),
    ({"scenes": ["cloud"], "methods": NERF, "quick": {"eval": {"curve_pionts": 1}}}, True, "quick.eval.curve_pionts",
     "unknown field (did you mean 'curve_points'?)"),
    ({"scenes": ["cloud"], "methods": "all", "method_settings": {"nerf": {"config": {"n_samples": 0}}}}, False,
     "method_settings.nerf.config.n_samples", "must be an integer in [1, 4096], got 0 (method nerf)"),
    ({"scenes": ["cloud"], "methods": "all", "method_settings": {"nerf": {"label": "a/b"}}}, False,
     "method_settings.nerf.label", "must not contain '/' or start with '.', got 'a/b'"),
]


@pytest.mark.parametrize("raw, quick, field, message", BAD_BENCH, ids=[b[2] for b in BAD_BENCH])
def test_bench_errors_name_the_bench_file_and_the_field(tmp_path, raw, quick, field, message):
    with pytest.raises(SpecError) as info:
        _plan(raw, quick=quick, tmp=tmp_path)
    assert (info.value.where, info.value.field, info.value.message) == ("benchmarks/x.toml", field, message)


def test_scene_overrides_apply_to_every_scene_and_quick_goes_over_them(tmp_path):
    raw = {"scenes": ["cloud", "plume"], "methods": NERF, "scene": {"cameras.width": 40, "cameras.height": 30},
           "quick": {"scene": {"cameras.width": 16}}}
    full = {c.scene: c.spec["cameras"] for c in _plan(raw, tmp=tmp_path)}
    quick = {c.scene: c.spec["cameras"] for c in _plan(raw, quick=True, tmp=tmp_path)}
    assert sorted(full) == ["cloud", "plume"]
    assert {(c["width"], c["height"]) for c in full.values()} == {(40, 30)}
    assert {(c["width"], c["height"]) for c in quick.values()} == {(16, 30)}


def test_paper_is_sized_like_the_fields_benchmarks(tmp_path):
    """At least 3 library scenes, 256x256 or more, 100 train views, every method, step budgets."""
    config = load_bench_config("paper")
    options = BenchOptions(data_root=tmp_path, results_root=tmp_path, code_version="t")
    specs = {c.scene: c.spec for c in plan_cells(config, options)}
    assert len(specs) >= 3 and set(specs) <= set(list_scenes())
    for spec in specs.values():
        assert min(spec["cameras"]["width"], spec["cameras"]["height"]) >= 256 and spec["cameras"]["n_train"] == 100
        assert spec["render"]["noise_floor"] and spec["render"]["spp_test"] >= 2048
    assert sorted(m.name for m in config.methods) == sorted(methods())


def test_an_undecodable_or_empty_bench_file_is_named(tmp_path, capsys):
    from mitsnerf.cli import main

    (tmp_path / "empty.toml").write_text("")
    assert main(["bench", str(tmp_path / "empty.toml")]) == 2
    assert capsys.readouterr().err == f"mitsnerf: error: {tmp_path / 'empty.toml'}: scenes: missing field (a list)\n"
    (tmp_path / "binary.toml").write_bytes(b"\xc3\x28")
    assert main(["bench", str(tmp_path / "binary.toml")]) == 2
    assert capsys.readouterr().err == f"mitsnerf: error: {tmp_path / 'binary.toml'}: not a text file (invalid UTF-8 at byte 0)\n"


def test_a_relative_spec_path_is_relative_to_the_config_file(tmp_path, monkeypatch):
    folder = tmp_path / "configs"
    (folder / "specs").mkdir(parents=True)
    write_scene(folder / "specs", "mine")
    (folder / "b.toml").write_text('scenes = ["specs/mine.toml"]\n[[methods]]\nname = "voxel"\n')
    monkeypatch.chdir(tmp_path)  # not the config's folder: the path must not be read from the working directory
    options = BenchOptions(data_root=tmp_path, results_root=tmp_path, code_version="t")
    cells = plan_cells(load_bench_config(folder / "b.toml"), options)
    assert [c.scene for c in cells] == ["mine"]
