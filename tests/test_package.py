"""mitsnerf works when installed: the scene library and the shipped bench configs are package data,
and a user's own directories are searched before them (``--scenes``/``--config``, environment)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

import mitsnerf
from mitsnerf.bench.config import BENCHMARKS_ENV, benchmark_dirs, benchmarks_dir, load_bench_config
from mitsnerf.cli import main
from mitsnerf.errors import SpecError
from mitsnerf.scene.spec import SCENES_ENV, list_scenes, load_scene, scene_dirs, scenes_dir

ROOT = Path(mitsnerf.__file__).resolve().parents[1]
#: The environment of the subprocesses: none of this checkout on the path, none of the user's directories.
CLEAN_ENV = {k: v for k, v in os.environ.items() if k not in (SCENES_ENV, BENCHMARKS_ENV, "PYTHONPATH")}
PACKAGE_DATA = [(scenes_dir(), "mitsnerf/scene/library"), (benchmarks_dir(), "mitsnerf/bench/configs")]


def _checkout_copy(checkout_files, dest: Path) -> Path:
    """The files git would commit, as they are now, in ``dest``."""
    root, names = checkout_files
    for name in names:
        (dest / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / name, dest / name, follow_symlinks=False)
    return dest


@pytest.fixture(scope="module")
def wheel(tmp_path_factory, checkout_files) -> Path:
    """A wheel built from the working tree by pip, as a user's ``pip install .`` builds it."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = _checkout_copy(checkout_files, tmp / "src")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp / "dist"), str(src)],
                          capture_output=True, text=True, env=CLEAN_ENV)
    if proc.returncode and "No matching distribution found for setuptools" in proc.stderr:
        pytest.skip("pip cannot fetch the build backend (setuptools) here: offline")
    assert proc.returncode == 0, proc.stderr[-3000:]
    (path,) = (tmp / "dist").glob("mitsnerf-*.whl")
    return path


def test_the_wheel_holds_the_scene_library_and_the_bench_configs(wheel):
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        for folder, inside in PACKAGE_DATA:
            shipped = sorted(folder.glob("*.toml"))
            assert shipped, folder
            for path in shipped:
                assert zf.read(f"{inside}/{path.name}") == path.read_bytes(), path.name
    assert not [n for n in names if n.startswith(("scenes/", "benchmarks/"))]  # one copy: the package's
    assert {"default", "full", "targets"} <= {Path(n).stem for n in names if n.startswith("mitsnerf/bench/configs/")}


@pytest.mark.slow
def test_an_installed_wheel_lists_the_scenes_and_runs_the_quick_bench(wheel, tmp_path):
    """A fresh venv outside the checkout (its dependencies from pip's cache or index), run from elsewhere."""
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    py = env_dir / "bin" / "python"
    install = subprocess.run([str(py), "-m", "pip", "install", "-q", str(wheel)], capture_output=True, text=True,
                             env=CLEAN_ENV, cwd=tmp_path)
    assert install.returncode == 0, install.stderr[-3000:]
    work = tmp_path / "elsewhere"
    work.mkdir()
    run = lambda *args: subprocess.run([str(env_dir / "bin" / "mitsnerf"), *args], cwd=work, env=CLEAN_ENV,  # noqa: E731
                                       capture_output=True, text=True, timeout=900)
    scenes = run("scenes")
    assert scenes.returncode == 0, scenes.stderr
    assert [line.split()[0] for line in scenes.stdout.splitlines()] == list_scenes()
    bench = run("bench", "--quick", "--no-progress", "--data", str(work / "data"), "--results", str(work / "results"))
    assert bench.returncode == 0, bench.stderr[-3000:]
    assert "## Per scene" in bench.stdout and (work / "results" / "default-quick" / "table.md").is_file()


# ---------------------------------------------------------------- the user's own directories


def _my_scene(folder: Path, name: str, description: str) -> Path:
    """The library's cloud under another name and description, in ``folder``."""
    text = (scenes_dir() / "cloud.toml").read_text()
    text = re.sub(r"(?m)^name = .*$", f'name = "{name}"', text, count=1)
    text = re.sub(r"(?m)^description = .*$", f'description = "{description}"', text, count=1)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.toml").write_text(text)
    return folder / f"{name}.toml"


def test_the_environment_adds_scene_directories_before_the_library(tmp_path, monkeypatch):
    _my_scene(tmp_path / "a", "mine", "my own cloud")
    _my_scene(tmp_path / "b", "cloud", "a cloud that shadows the library's")
    monkeypatch.setenv(SCENES_ENV, os.pathsep.join([str(tmp_path / "a"), str(tmp_path / "b")]))
    assert scene_dirs() == [tmp_path / "a", tmp_path / "b", scenes_dir()]
    assert set(list_scenes()) == {p.stem for p in scenes_dir().glob("*.toml")} | {"mine"}
    assert load_scene("mine").description == "my own cloud"
    assert load_scene("cloud").description == "a cloud that shadows the library's"  # the first directory wins
    assert load_scene("plume").volume.family == "plume"  # the library still answers


def test_scenes_option_adds_a_directory_for_the_command_only(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(SCENES_ENV, raising=False)
    _my_scene(tmp_path / "mine", "mine", "my own cloud")
    assert main(["scenes", "--scenes", str(tmp_path / "mine")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == sorted({p.stem for p in scenes_dir().glob("*.toml")} | {"mine"})
    assert SCENES_ENV not in os.environ and "mine" not in list_scenes()  # restored after the command
    assert main(["scenes", "--scenes", str(tmp_path / "absent")]) == 2
    assert capsys.readouterr().err == f"mitsnerf: error: {tmp_path / 'absent'}: no such directory (given to --scenes)\n"


def test_bench_configs_by_name_from_the_package_and_from_a_users_directory(tmp_path, monkeypatch):
    monkeypatch.delenv(BENCHMARKS_ENV, raising=False)
    assert benchmark_dirs() == [benchmarks_dir()] and load_bench_config("default").name == "default"
    (tmp_path / "mybench.toml").write_text('scenes = ["cloud"]\n[[methods]]\nname = "ngp"\n')
    with pytest.raises(SpecError, match=r"no such benchmark config \(known: default, full, paper, physics, targets\)"):
        load_bench_config("mybench")
    monkeypatch.setenv(BENCHMARKS_ENV, str(tmp_path))
    config = load_bench_config("mybench")
    assert config.name == "mybench" and [m.name for m in config.methods] == ["ngp"]
    assert load_bench_config("full").name == "full"


def test_bench_config_option_is_a_directory(tmp_path, capsys):
    assert main(["bench", "--config", str(tmp_path / "nope"), "--quick"]) == 2
    assert capsys.readouterr().err == f"mitsnerf: error: {tmp_path / 'nope'}: no such directory (given to --config)\n"
    assert main(["bench", "--config", str(tmp_path), "mybench"]) == 2  # an empty directory adds no config
    assert "no such benchmark config (known: default, full, paper, physics, targets)" in capsys.readouterr().err


def test_the_top_level_scenes_path_is_the_package_library():
    """A developer's ``scenes/NAME.toml`` keeps working: it is a link to the package's one copy."""
    link = ROOT / "scenes"
    if not link.exists():
        pytest.skip("no checkout around the package")
    assert link.is_symlink() and link.resolve() == scenes_dir()
