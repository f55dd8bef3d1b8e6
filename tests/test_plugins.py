"""Methods from outside the package: the registry's three sources (built-in, entry point, variable), where each
came from, broken plugins refused in one line while the rest keep working, and a plugin's version in a bench
cell's key."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import mitsnerf.methods
from mitsnerf.cli import main
from mitsnerf.methods import get_method, methods
from mitsnerf.plugins import parse_variable

from .conftest import tiny_scene

PLUGINS = Path(__file__).resolve().parent / "plugins"
TINY = f"{PLUGINS / 'tiny_plugin.py'}"
MLP = f"{Path(__file__).resolve().parents[1] / 'examples' / 'mlp_method.py'}"


def test_the_built_ins_register_themselves_in_their_own_modules():
    registry = methods()
    assert sorted(registry) == ["mitsuba-inverse", "nerf", "ngp", "primitives", "scatter", "voxel"]
    assert {m.source.kind for m in registry.values()} == {"built-in"}
    assert get_method("nerf").source.where == "mitsnerf.methods.nerf" and get_method("nerf").source.version is None
    assert registry.problems == {}


def test_a_variable_registers_code_that_is_not_installed(monkeypatch):
    monkeypatch.setenv("MITSNERF_METHODS", f"mine={TINY}:TinyNGP")
    method = get_method("mine")
    assert method.model_type.__name__ == "TinyNGP" and method.source.kind == "variable"
    assert method.source.version.startswith("sha256:") and method.description.startswith("ngp, registered")
    assert list(methods())[-1] == "mine"  # after the built-ins


@pytest.mark.parametrize("text, problem", [
    (f"imp={PLUGINS / 'broken_import.py'}:X", "ModuleNotFoundError: No module named 'mitsnerf_missing_dependency'"),
    (f"fn={TINY}:not_a_class", "tiny_plugin.not_a_class is not a mitsnerf.methods.base.Model subclass"),
    (f"cfg={TINY}:NoConfig", "config_type must be a dataclass subclassing mitsnerf.methods.base.MethodConfig"),
    (f"gone={TINY}:Missing", "module 'tiny_plugin' has no attribute 'Missing'"),
    (f"nofile={PLUGINS / 'nothing.py'}:X", "no such file"),
    ("mod=mitsnerf_no_such_module:X", "ModuleNotFoundError"),
])
def test_a_broken_plugin_is_one_line_and_the_others_keep_working(monkeypatch, text, problem):
    name = text.split("=")[0]
    monkeypatch.setenv("MITSNERF_METHODS", f"{text},mine={TINY}:TinyNGP")
    registry = methods()
    assert name not in registry and "mine" in registry and "nerf" in registry
    line = registry.problems[name]
    assert line.startswith(f"MITSNERF_METHODS: {text}: ") and problem in line and "\n" not in line
    with pytest.raises(KeyError, match=f"method '{name}' is broken: MITSNERF_METHODS"):
        get_method(name)


def test_a_plugin_cannot_take_a_built_in_name_and_the_name_is_refused_until_renamed(monkeypatch, capsys, tmp_path):
    from mitsnerf.bench.config import parse_bench_config
    from mitsnerf.errors import SpecError

    monkeypatch.setenv("MITSNERF_METHODS", f"voxel={TINY}:TinyNGP")
    registry = methods()
    assert registry.entry("voxel").source.kind == "built-in" and registry.why_not("nerf") is None
    line = (f"MITSNERF_METHODS: voxel={TINY}:TinyNGP: the name 'voxel' is taken by the built-in method "
            "(mitsnerf.methods.voxel), which a plugin cannot replace: rename the plugin "
            "(until then 'voxel' is refused)")
    assert registry.problems["voxel"] == line
    assert main(["train", str(tmp_path), "--method", "voxel", "--out", str(tmp_path / "r")]) == 2
    assert capsys.readouterr().err == f"mitsnerf: error: --method: method 'voxel' is claimed twice: {line}\n"
    assert not (tmp_path / "r").exists()
    with pytest.raises(SpecError, match="method 'voxel' is claimed twice"):
        parse_bench_config({"name": "b", "scenes": ["cloud"], "methods": "all"})
    parse_bench_config({"name": "b", "scenes": ["cloud"], "methods": [{"name": "nerf"}]})  # the others work


def test_two_plugins_of_one_name_are_both_named_and_neither_is_used(monkeypatch):
    monkeypatch.setenv("MITSNERF_METHODS", f"mine={TINY}:TinyNGP,mine={TINY}:FrozenNGP")
    registry = methods()
    assert registry.entry("mine").value.model_type.__name__ == "TinyNGP"  # listed as first claimed
    assert registry.why_not("mine") == (f"method 'mine' is claimed twice: MITSNERF_METHODS: mine={TINY}:FrozenNGP: "
                                        f"the name 'mine' is taken by MITSNERF_METHODS: mine={TINY}:TinyNGP: rename "
                                        "one of them (until then 'mine' is refused)")


def test_the_variable_takes_commas_or_colons_and_names_each_item_that_is_not_an_entry():
    assert parse_variable("V", "a=m:A:b=dir/f.py:B, c=x.y:C.D") == ([("a", "m", "A"), ("b", "dir/f.py", "B"),
                                                                     ("c", "x.y", "C.D")], {})
    entries, problems = parse_variable("V", "a=m:A,b=m,junk,-x=m:A,d=m:1bad,e=m:E")
    assert entries == [("a", "m", "A"), ("e", "m", "E")]
    assert problems == {
        "b": "V: 'b=m': not NAME=MODULE:ATTR (no ':ATTR' after the module: which object to register?)",
        "junk": "V: 'junk': not NAME=MODULE:ATTR (no '=': which name to register it under?)",
        "-x=m:A": "V: '-x=m:A': not NAME=MODULE:ATTR ('-x' is not a NAME: letters, digits, '_', '.', '-', not "
                  "starting with one of the last three)",
        "d": "V: 'd=m:1bad': not NAME=MODULE:ATTR ('1bad' is not an attribute path (Python names separated by '.'))",
    }


def test_a_malformed_entry_hides_none_beside_it_and_asking_for_it_names_it(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("MITSNERF_METHODS", f"first={TINY}:TinyNGP,bad,nocls={TINY}:second={TINY}:TinyNGP")
    registry = methods()
    assert {"first", "second", "nerf"} <= set(registry) and "nocls" not in registry
    assert registry.why_not("nocls") == (f"method 'nocls' is broken: MITSNERF_METHODS: 'nocls={TINY}': not "
                                         "NAME=MODULE:ATTR (no ':ATTR' after the module: which object to register?)")
    assert main(["train", str(tmp_path), "--method", "nocls", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mitsnerf: error: --method: method 'nocls' is broken: MITSNERF_METHODS: 'nocls=")
    assert len(err.splitlines()) == 1 and not (tmp_path / "r").exists()
    assert main(["methods"]) == 0
    assert "mitsnerf: warning: not loaded: MITSNERF_METHODS: 'bad': not NAME=MODULE:ATTR" in capsys.readouterr().err


def test_a_plugin_that_calls_sys_exit_is_one_line_and_every_command_runs(monkeypatch, capsys, tmp_path):
    (tmp_path / "quits.py").write_text("import sys\n\nsys.exit(3)\n")
    monkeypatch.setenv("MITSNERF_METHODS", f"quits={tmp_path / 'quits.py'}:X,mine={TINY}:TinyNGP")
    assert main(["methods"]) == 0  # the registry loads as the parser is built: every command met the exit here
    out, err = capsys.readouterr()
    assert "mine" in out and "voxel" in out
    assert err.splitlines() == [f"mitsnerf: warning: not loaded: MITSNERF_METHODS: quits={tmp_path / 'quits.py'}:X: "
                                "the module called sys.exit(3) while it was imported; a plugin module may only "
                                "define things"]
    assert main(["methods", "nerf"]) == 0


def test_a_plugin_file_named_after_another_module_is_refused_and_replaces_nothing(monkeypatch, tmp_path):
    import json

    monkeypatch.setitem(sys.modules, "json", json)  # put back even if the refusal breaks
    (tmp_path / "std").mkdir()
    (tmp_path / "std" / "json.py").write_text(Path(TINY).read_text())
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    for d in ("a", "b"):
        (tmp_path / d / "my_fog_method.py").write_text(Path(TINY).read_text())
    monkeypatch.setenv("MITSNERF_METHODS", f"js={tmp_path / 'std' / 'json.py'}:TinyNGP,"
                                           f"a={tmp_path / 'a' / 'my_fog_method.py'}:TinyNGP,"
                                           f"b={tmp_path / 'b' / 'my_fog_method.py'}:TinyNGP")
    registry = methods()
    assert sys.modules["json"] is json and json.dumps([1]) == "[1]"
    assert "js" not in registry and registry.problems["js"] == (
        f"MITSNERF_METHODS: js={tmp_path / 'std' / 'json.py'}:TinyNGP: '{tmp_path / 'std' / 'json.py'}' would be "
        "imported as module 'json', which would replace Python's standard-library module json; rename the file")
    assert "a" in registry and "b" not in registry
    assert (f"which would replace the module my_fog_method already imported ({tmp_path / 'a' / 'my_fog_method.py'})"
            in registry.problems["b"])
    assert sys.modules["my_fog_method"].__file__ == str(tmp_path / "a" / "my_fog_method.py")
    sys.modules.pop("my_fog_method")


def _fake_distribution(root: Path, version: str) -> None:
    """An installed distribution on ``root``: its module and its dist-info declaring a mitsnerf.methods entry point."""
    (root / "fakeplugin.py").write_text((PLUGINS / "tiny_plugin.py").read_text())
    info = root / f"fakeplugin-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: fakeplugin\nVersion: {version}\n")
    (info / "entry_points.txt").write_text("[mitsnerf.methods]\nfake = fakeplugin:TinyNGP\n"
                                           "clash = fakeplugin:not_a_class\n")


def test_an_entry_point_registers_an_installed_method_under_its_name(tmp_path, monkeypatch):
    _fake_distribution(tmp_path, "1.2.3")
    monkeypatch.syspath_prepend(str(tmp_path))
    registry = methods()
    source = registry.entry("fake").source
    assert source.kind == "entry point" and "fakeplugin==1.2.3" in source.where
    assert source.version.startswith("fakeplugin==1.2.3 sha256:")
    assert registry.problems["clash"].startswith("entry point mitsnerf.methods: clash = fakeplugin:not_a_class: ")
    sys.modules.pop("fakeplugin", None)


def test_methods_lists_where_each_came_from_and_warns_of_broken_plugins(monkeypatch, capsys):
    monkeypatch.setenv("MITSNERF_METHODS", f"mine={TINY}:TinyNGP,fn={TINY}:not_a_class")
    assert main(["methods"]) == 0
    out, err = capsys.readouterr()
    assert "nerf" in out and "built-in" in out and f"from MITSNERF_METHODS: mine={TINY}:TinyNGP" in out
    assert err.splitlines() == [f"mitsnerf: warning: not loaded: MITSNERF_METHODS: fn={TINY}:not_a_class: "
                                "tiny_plugin.not_a_class is not a mitsnerf.methods.base.Model subclass"]


def test_train_names_a_broken_method_and_why(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("MITSNERF_METHODS", f"fn={TINY}:not_a_class")
    assert main(["train", str(tmp_path), "--method", "fn", "--out", str(tmp_path / "r")]) == 2
    assert capsys.readouterr().err.strip() == (f"mitsnerf: error: --method: method 'fn' is broken: MITSNERF_METHODS: "
                                               f"fn={TINY}:not_a_class: tiny_plugin.not_a_class is not a "
                                               "mitsnerf.methods.base.Model subclass")


def test_methods_check_exits_by_the_verdict_and_says_it_trained_the_tiny_settings(monkeypatch, capsys):
    monkeypatch.setenv("MITSNERF_METHODS", f"mine={TINY}:TinyNGP,frozen={TINY}:FrozenNGP")
    assert main(["methods", "--check", "mine"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == ("conformance of 'mine', trained only at its tiny settings, not its defaults (a check of "
                        "promises, not of quality):")
    assert lines[1].startswith("  tiny settings network.n_levels=2, ")
    assert "n_samples=16; 6 steps of 64 rays" in lines[1]
    assert lines[-1] == "mine: conforms"
    assert main(["methods", "--check", "frozen"]) == 1
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1] == "frozen: does not conform (2 broken)"
    assert lines[3] == ("FAILED   trains and evaluates: MethodError: tiny_plugin.FrozenNGP: step 0: the loss depends "
                        "on none of parameters(), so there is nothing to step: render from the values that "
                        "set_parameters() receives (the optimiser's), not from copies of them")


def test_a_method_with_nothing_to_train_is_refused_in_a_sentence(monkeypatch, capsys):
    from mitsnerf.runs.conformance import check_method

    monkeypatch.setenv("MITSNERF_METHODS", f"empty={TINY}:EmptyNGP")
    report = check_method("empty")
    line = (f"method 'empty' (MITSNERF_METHODS: empty={TINY}:EmptyNGP): parameters(): returned nothing to train: a "
            "method optimises at least one Dr.Jit array (return a drjit.nn module or a dict of name -> array, and "
            "render from those values)")
    assert [(o.promise, o.passed, o.detail) for o in report.failures()] == \
        [("builds, with parameters to train", False, line)]
    assert all(o.passed is None for o in report.outcomes[1:]), report.summary()


def test_train_refuses_a_method_with_nothing_to_train_before_writing(monkeypatch, capsys, tmp_path):
    from mitsnerf.errors import MethodError
    from mitsnerf.generate import generate_dataset
    from mitsnerf.runs.conformance import TINY_SCENE
    from mitsnerf.scene.spec import parse_scene

    data = generate_dataset(parse_scene(TINY_SCENE, "tiny"), tmp_path / "data", progress=False)
    monkeypatch.setenv("MITSNERF_METHODS", f"empty={TINY}:EmptyNGP,frozen={TINY}:FrozenNGP")
    assert main(["train", str(data), "--method", "empty", "--out", str(tmp_path / "r"), "--no-progress"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith(f"mitsnerf: error: method 'empty' (MITSNERF_METHODS: empty={TINY}:EmptyNGP): "
                              "parameters(): returned nothing to train")
    assert main(["train", str(data), "--method", "frozen", "--out", str(tmp_path / "r"), "--no-progress"]) == 2
    assert "tiny_plugin.FrozenNGP: step 0: the loss depends on none of parameters()" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    from mitsnerf import api

    with pytest.raises(MethodError, match="parameters\\(\\): returned nothing to train"):
        api.fit(data, "empty", steps=2)


def test_a_plugins_version_is_in_its_cells_key_and_a_built_ins_is_not(tmp_path, monkeypatch):
    from mitsnerf.bench.config import parse_bench_config
    from mitsnerf.bench.runner import BenchOptions, plan_cells

    plugin = tmp_path / "my_method.py"
    plugin.write_text((PLUGINS / "tiny_plugin.py").read_text())
    monkeypatch.setenv("MITSNERF_METHODS", f"mine={plugin}:TinyNGP")
    config = parse_bench_config({"name": "b", "scenes": ["cloud"], "methods": [{"name": "mine"}, {"name": "ngp"}]})
    options = BenchOptions(data_root=tmp_path, results_root=tmp_path, code_version="v")
    before = {c.method: c.config_hash for c in plan_cells(config, options)}
    plugin.write_text(plugin.read_text() + "\n# edited\n")
    sys.modules.pop("my_method", None)  # as a new process would import it
    mitsnerf.methods._methods.cache_clear()
    after = {c.method: c.config_hash for c in plan_cells(config, options)}
    assert before["ngp"] == after["ngp"] and before["mine"] != after["mine"]


def test_a_volume_family_joins_through_the_variable_and_a_broken_one_is_named(tmp_path, monkeypatch):
    from mitsnerf.scene.spec import load_scene
    from mitsnerf.volumes import families, generate_volume

    (tmp_path / "fog.py").write_text(
        "import numpy as np\n"
        "from dataclasses import dataclass\n"
        "from mitsnerf.config import param\n"
        "from mitsnerf.volumes.base import Family, VolumeGrids\n\n"
        "@dataclass(frozen=True)\nclass FogParams:\n    level: float = param(0.5, lo=0.0, hi=1.0)\n\n"
        "def generate(params, resolution, seed):\n"
        "    d = np.full((resolution,) * 3, params.level, np.float32)\n"
        "    return VolumeGrids(d, np.full(d.shape + (3,), 0.9, np.float32))\n\n"
        "FAMILY = Family('whatever', FogParams, generate, 'uniform fog')\n")
    monkeypatch.setenv("MITSNERF_VOLUMES", f"fog={tmp_path / 'fog.py'}:FAMILY,bad={tmp_path / 'fog.py'}:FogParams")
    registry = families()
    assert registry["fog"].name == "fog" and registry.entry("fog").source.kind == "variable"
    assert "is not a mitsnerf.volumes.base.Family" in registry.problems["bad"]
    assert float(generate_volume("fog", 8, 0, {"level": 0.25}).density.max()) == 0.25
    spec = load_scene("cloud").with_overrides({"volume.family": "fog", "volume.params": {"level": 0.3}})
    assert spec.volume.family == "fog" and spec.volume.params["level"] == 0.3


def test_volumes_lists_the_families_with_their_sources_and_a_familys_parameters(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MITSNERF_VOLUMES", f"bad={TINY}:TinyNGP")
    assert main(["volumes"]) == 0
    out, err = capsys.readouterr()
    assert [line.split()[:2] for line in out.splitlines()][:2] == [["blobs", "built-in"], ["cloud", "built-in"]]
    assert err.startswith(f"mitsnerf: warning: not loaded: MITSNERF_VOLUMES: bad={TINY}:TinyNGP: ")
    assert main(["volumes", "shell"]) == 0
    assert "| shape | one of 'sphere', 'torus' |" in capsys.readouterr().out
    assert main(["volumes", "bad"]) == 2
    assert "NAME: volume family 'bad' is broken" in capsys.readouterr().err


def test_the_readmes_method_skeleton_conforms(tmp_path, monkeypatch, capsys):
    """README.md's "Write your own method" block, saved as the README says and registered by the variable."""
    import re

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = readme.split("**Write your own method.**", 1)[1]
    code = re.findall(r"```python\n(.*?)```", section, flags=re.S)[0]
    (tmp_path / "fog_method.py").write_text(code)
    monkeypatch.delitem(sys.modules, "fog_method", raising=False)  # this folder's, not another test's
    monkeypatch.setenv("MITSNERF_METHODS", f"fog={tmp_path / 'fog_method.py'}:FogModel")
    mitsnerf.methods._methods.cache_clear()
    assert main(["methods", "--check", "fog", "--no-progress"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "fog: conforms"


def test_the_network_example_conforms_and_trains_to_the_noise_floor(tmp_path, monkeypatch, capsys):
    """examples/mlp_method.py (README.md, "A network method"), registered as the README says: it passes the
    conformance suite, and its tiny settings trained 300 steps reach the test views' noise floor (28.9 dB where the
    floor is 28.2; 24.4 after one step), its medium pixels gaining over 3 dB."""
    from mitsnerf import api
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import parse_scene

    monkeypatch.setenv("MITSNERF_METHODS", f"mlp={MLP}:MLPModel")
    assert main(["methods", "--check", "mlp", "--no-progress"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "mlp: conforms"
    spec = tiny_scene({"cameras.width": 16, "cameras.height": 16, "cameras.n_train": 8})
    data = generate_dataset(parse_scene(spec, "tiny"), tmp_path / "data", progress=False)
    settings = {**get_method("mlp").tiny, "n_samples": 16}
    start = api.fit(data, "mlp", settings=settings, steps=1, batch_rays=256).metrics
    end = api.fit(data, "mlp", settings=settings, steps=300, batch_rays=256).metrics
    assert end["psnr_test"] > end["noise_floor_psnr"] - 1.0, end
    assert end["psnr_test_medium"] > start["psnr_test_medium"] + 3.0, (start, end)
