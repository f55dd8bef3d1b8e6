"""The dataset cache is one per user (``$MITSNERF_DATA``, else ``$XDG_CACHE_HOME/mitsnerf``, else
``~/.cache/mitsnerf``), found from any working directory; ``mitsnerf env`` says where and how big; the suite
itself never writes the user's."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import pytest

from mitsnerf.bench.config import parse_bench_config
from mitsnerf.bench.runner import BenchOptions, plan_scenes
from mitsnerf.cli import main
from mitsnerf.outputs import data_cache

from .conftest import TINY_SCENE, scene_toml


def test_the_suite_never_writes_the_users_cache():
    """conftest points XDG_CACHE_HOME at a temporary directory for the session, children included."""
    root, chosen_by = data_cache()
    assert chosen_by == "$XDG_CACHE_HOME" and "MITSNERF_DATA" not in os.environ
    assert root.is_relative_to(Path(tempfile.gettempdir())) and root != Path.home() / ".cache" / "mitsnerf"


@pytest.fixture
def own_cache(tmp_path, monkeypatch):
    """A cache of this test's own (XDG_CACHE_HOME), and two working directories."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
    return tmp_path / "xdg" / "mitsnerf"


def test_generate_and_bench_find_one_cache_from_any_working_directory(own_cache, tmp_path, monkeypatch, capsys):
    """Before, both defaulted to ./data: a bench run from another directory rendered the ground truth again."""
    monkeypatch.chdir(tmp_path / "a")
    spec = tmp_path / "a" / "tiny.toml"
    spec.write_text(scene_toml(TINY_SCENE))
    assert main(["generate", str(spec), "--no-progress"]) == 0
    made = Path(capsys.readouterr().out.strip().splitlines()[-1])
    assert made.parent == own_cache and (made / "manifest.json").is_file()
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["tiny.toml"]  # nothing in the working directory
    monkeypatch.chdir(tmp_path / "b")
    config = parse_bench_config({"name": "t", "scenes": [str(spec)], "methods": [{"name": "voxel"}]}, "t.toml")
    (site,) = plan_scenes(config, BenchOptions(progress=False))
    assert Path(site.dataset_dir) == made


def test_mitsnerf_data_wins_and_env_says_where_the_cache_is_and_how_big(own_cache, tmp_path, monkeypatch, capsys):
    assert main(["env"]) == 0
    shown = json.loads(capsys.readouterr().out)["data_cache"]
    assert shown["path"] == str(own_cache) and shown["chosen_by"] == "$XDG_CACHE_HOME" and shown["bytes"] == 0
    (tmp_path / "elsewhere" / "cloud-0123").mkdir(parents=True)
    (tmp_path / "elsewhere" / "cloud-0123" / "manifest.json").write_text("{}")
    monkeypatch.setenv("MITSNERF_DATA", str(tmp_path / "elsewhere"))
    assert main(["env"]) == 0
    shown = json.loads(capsys.readouterr().out)["data_cache"]
    assert shown["path"] == str(tmp_path / "elsewhere") and shown["chosen_by"] == "$MITSNERF_DATA"
    assert (shown["datasets"], shown["files"], shown["bytes"]) == (1, 1, 2)


@pytest.mark.parametrize("command", ["bench", "generate"])
def test_the_help_says_where_datasets_go_by_default(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "$XDG_CACHE_HOME/mitsnerf, else ~/.cache/mitsnerf" in text and "./data" not in text
    assert "default: data)" not in text

