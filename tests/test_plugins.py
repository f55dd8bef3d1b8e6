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
from mitsnerf.plugins import PluginError, parse_variable

PLUGINS = Path(__file__).resolve().parent / "plugins"
TINY = f"{PLUGINS / 'tiny_plugin.py'}"


def test_the_built_ins_register_themselves_in_their_own_modules():
    registry = methods()
    assert sorted(registry) == ["mitsuba-inverse", "nerf", "ngp", "voxel"]
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


def test_a_plugin_cannot_take_a_built_in_name(monkeypatch):
    monkeypatch.setenv("MITSNERF_METHODS", f"nerf={TINY}:TinyNGP")
    assert get_method("nerf").source.kind == "built-in"
    assert "the name 'nerf' is taken by the built-in method (mitsnerf.methods.nerf); rename it" in \
        methods().problems["nerf"]


def test_the_variable_takes_commas_or_colons_and_refuses_what_is_not_an_entry():
    assert parse_variable("V", "a=m:A:b=dir/f.py:B, c=x.y:C.D") == [("a", "m", "A"), ("b", "dir/f.py", "B"),
                                                                    ("c", "x.y", "C.D")]
    with pytest.raises(PluginError, match="V: 'b=m': not NAME=MODULE:ATTR"):
        parse_variable("V", "a=m:A,b=m")


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


def test_methods_check_exits_by_the_verdict(monkeypatch, capsys):
    monkeypatch.setenv("MITSNERF_METHODS", f"mine={TINY}:TinyNGP,frozen={TINY}:FrozenNGP")
    assert main(["methods", "--check", "mine"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "mine: conforms"
    assert main(["methods", "--check", "frozen"]) == 1
    assert capsys.readouterr().out.strip().splitlines()[-1] == "frozen: does not conform (2 broken)"


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
    monkeypatch.setenv("MITSNERF_METHODS", f"fog={tmp_path / 'fog_method.py'}:FogModel")
    mitsnerf.methods._methods.cache_clear()
    assert main(["methods", "--check", "fog", "--no-progress"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "fog: conforms"
