"""mitsnerf.api: the README's example runs as written, the functions return the numbers the commands print
and write, and bad input raises the package's typed errors, never SystemExit."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from mitsnerf import api
from mitsnerf.cli import main
from mitsnerf.errors import DatasetError, MitsnerfError, SpecError, UsageError
from mitsnerf.train.threads import nondeterminism

from .conftest import child_pythonpath, scene_toml, tiny_scene

README = Path(__file__).resolve().parents[1] / "README.md"
SMALL = {"cameras.width": 8, "cameras.height": 8, "cameras.n_train": 3, "cameras.n_test": 2,
         "render.spp_train": 4, "render.spp_test": 8, "volume.resolution": 16}


def readme_example() -> str:
    section = README.read_text().split("## Python API", 1)[1]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert blocks, "README's Python API section has no python block"
    return blocks[0]


def test_the_readmes_example_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MITSNERF_DATA", raising=False)
    exec(compile(readme_example(), "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert re.search(r"^voxel: test PSNR [\d.]+ dB \([\d.]+ dB on medium pixels\)", out, flags=re.M)
    assert "| cloud | oracle (ceiling) |" in out and "| cloud | nerf |" in out
    assert (tmp_path / "runs" / "voxel" / "metrics.json").is_file()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return api.generate("cloud", tmp_path_factory.mktemp("data"), overrides=SMALL)


def test_fit_and_score_give_what_the_commands_write(dataset, tmp_path, capsys):
    run = api.fit(dataset, "voxel", steps=3, out=tmp_path / "run", deterministic=nondeterminism() is None,
                  settings={"resolution": 16, "initial_resolution": 16, "upsample_steps": [], "n_samples": 8})
    written = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert {k: written[k] for k in run.metrics} == json.loads(json.dumps(dict(run.metrics)))
    assert run.summary.startswith("voxel: test PSNR ") and run.summary.endswith(f"-> {tmp_path / 'run'}")
    scores = api.score(dataset, tmp_path / "run")
    assert main(["score", str(dataset), str(tmp_path / "run"), "--out", str(tmp_path / "s.json")]) == 0
    assert scores == json.loads((tmp_path / "s.json").read_text())["metrics"]
    assert api.evaluate(tmp_path / "run")["psnr_test_medium"] == run.metrics["psnr_test_medium"]


@pytest.mark.parametrize(("call", "error", "says"), [
    (lambda d, t: api.fit(d, "no_such_method"), UsageError, "method: unknown method 'no_such_method'"),
    (lambda d, t: api.fit(d, "voxel", steps=0), SpecError, "fit: steps"),
    (lambda d, t: api.fit(d, "voxel", settings={"resolutoin": 8}), SpecError, "settings: resolutoin"),
    (lambda d, t: api.fit(t / "nowhere", "voxel"), DatasetError, "nowhere"),
    (lambda d, t: api.generate("no_such_scene", t), SpecError, "no_such_scene"),
    (lambda d, t: api.generate("cloud", t, overrides={"volume.resolution": 2}), SpecError, "volume.resolution"),
    (lambda d, t: api.score(d, t), MitsnerfError, str(Path("{t}"))),
    (lambda d, t: api.bench("no_such_bench", results=t / "r", data=t / "d"), SpecError, "no_such_bench"),
])
def test_bad_input_raises_a_typed_error_never_system_exit(dataset, tmp_path, call, error, says):
    try:
        call(dataset, tmp_path)
    except SystemExit:  # pragma: no cover - the failure this test exists for
        pytest.fail("the API exited the process")
    except error as exc:
        assert says.format(t=tmp_path) in str(exc)
    else:
        pytest.fail(f"no {error.__name__}")


# --------------------------------------------------------------------------- every function as a process's first call

TINY_VOXEL = {"resolution": 8, "initial_resolution": 8, "upsample_steps": [], "n_samples": 8}


def _fresh_process(code: str, cwd: Path) -> subprocess.CompletedProcess:
    """``code`` run by a new Python: nothing imported before it, no Mitsuba variant set."""
    env = {**os.environ, "PYTHONPATH": child_pythonpath(Path(api.__file__).resolve().parents[1])}
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)


@pytest.fixture(scope="module")
def saved_run(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "voxel"
    api.fit(dataset, "voxel", steps=2, settings=TINY_VOXEL, out=out)
    return out


BENCH_TOML = """name = "first"
scenes = ["{spec}"]
seeds = [0]
train = {{ steps = 2, batch_rays = 64 }}
eval = {{ curve_points = 1, od_samples = 8 }}
oracle = {{ enabled = false }}
[[methods]]
name = "voxel"
config = {{ resolution = 8, initial_resolution = 8, upsample_steps = [], n_samples = 8 }}
"""


@pytest.mark.parametrize("call", ["generate", "fit", "evaluate", "score", "bench"])
def test_every_function_works_as_the_first_call_of_a_fresh_process(call, dataset, saved_run, tmp_path):
    """A notebook opening an existing dataset: before, fit and evaluate (and score) raised "Cannot access
    'Texture3f' before setting a variant" unless generate had run first."""
    spec = tmp_path / "tiny.toml"
    spec.write_text(scene_toml(tiny_scene({"name": "firsttiny"})))
    (tmp_path / "first.toml").write_text(BENCH_TOML.format(spec=spec))
    calls = {
        "generate": f"api.generate('cloud', {str(dataset.parent)!r}, overrides={SMALL!r})",
        "fit": f"api.fit({str(dataset)!r}, 'voxel', steps=2, settings={TINY_VOXEL!r})",
        "evaluate": f"api.evaluate({str(saved_run)!r})",
        "score": f"api.score({str(dataset)!r}, {str(saved_run / 'test')!r})",
        "bench": f"api.bench({str(tmp_path / 'first.toml')!r}, results='r', data='d').markdown",
    }
    proc = _fresh_process(f"from mitsnerf import api\nprint('OK', type({calls[call]}).__name__)", tmp_path)
    assert proc.returncode == 0 and "OK" in proc.stdout, proc.stderr[-2000:]



# --------------------------------------------------------------------------- the API's own words in its errors

def _raises(error, call):
    with pytest.raises(error) as info:
        call()
    text = str(info.value)
    assert "--" not in text, f"a command-line flag in an API message: {text}"
    return text


def test_a_run_already_there_is_refused_in_the_apis_words(dataset, tmp_path):
    from mitsnerf.errors import OutputError

    api.fit(dataset, "voxel", steps=2, settings=TINY_VOXEL, out=tmp_path / "run")
    text = _raises(OutputError, lambda: api.fit(dataset, "voxel", steps=2, settings=TINY_VOXEL, out=tmp_path / "run"))
    assert "pass force=True to replace it, or resume=True, steps=N to train it on" in text
    text = _raises(OutputError, lambda: api.fit(resume=True, out=tmp_path / "run"))
    assert "pass steps=N (N > 2) to train it on" in text
    resumed = api.fit(resume=True, out=tmp_path / "run", steps=3)
    assert resumed.metrics["steps"] == 3 and resumed.method == "voxel"
    assert "come from the checkpoint" in _raises(UsageError, lambda: api.fit(resume=True, out=tmp_path / "run",
                                                                           method="voxel", steps=4))
    assert "no checkpoint.npz to resume from" in _raises(OutputError, lambda: api.fit(resume=True, out=tmp_path / "x"))


def test_an_interrupted_fit_says_how_to_continue_in_the_apis_words(dataset, tmp_path, monkeypatch):
    import mitsnerf.train.loop
    from mitsnerf.errors import Interrupted

    real = mitsnerf.train.loop.apply_step

    def stop_at_2(model, opt, step):
        if step == 2:
            raise Interrupted(15, "")
        real(model, opt, step)

    monkeypatch.setattr(mitsnerf.train.loop, "apply_step", stop_at_2)
    text = _raises(Interrupted, lambda: api.fit(dataset, "voxel", steps=4, settings=TINY_VOXEL, out=tmp_path / "run"))
    assert f"continue with api.fit(resume=True, out={str(tmp_path / 'run')!r})" in text
    monkeypatch.setattr(mitsnerf.train.loop, "apply_step", real)
    assert api.fit(resume=True, out=tmp_path / "run").metrics["steps"] == 4


@pytest.mark.parametrize(("call", "error", "says"), [
    (lambda d, t: api.score(d, t / "renders", format="jpg"), UsageError, "format: must be one of"),
    (lambda d, t: api.score(d, t / "renders", exr_alpha="maybe"), UsageError, "exr_alpha: must be one of"),
    (lambda d, t: api.score(d, t / "renders", footprint=0), UsageError, "footprint: must be >= 1"),
    (lambda d, t: api.bench("default", workers=2, results=t / "r", data=t / "d"), UsageError,
     "workers: the sequential executor runs one cell at a time (use executor='pool' or executor='ray')"),
    (lambda d, t: api.bench("default", executor="serial", results=t / "r", data=t / "d"), UsageError,
     "executor: must be one of"),
    (lambda d, t: api.bench("default", workers=-1, executor="pool", results=t / "r", data=t / "d"), UsageError,
     "workers: must be >= 0"),
    (lambda d, t: api.fit(), UsageError, "dataset: name a dataset directory (or pass resume=True"),
    (lambda d, t: api.fit(d, resume=True, force=True, out=t / "run"), UsageError, "force: starts the run over"),
])
def test_the_apis_refusals_name_its_arguments_not_flags(dataset, tmp_path, call, error, says):
    assert says in _raises(error, lambda: call(dataset, tmp_path))


def test_a_damaged_dataset_says_to_regenerate_it_through_the_api(dataset, tmp_path):
    import shutil

    copy = tmp_path / dataset.name
    shutil.copytree(dataset, copy)
    next((copy / "train").glob("r_*.exr")).write_bytes(b"damaged")
    text = _raises(DatasetError, lambda: api.fit(copy, "voxel", steps=1, settings=TINY_VOXEL))
    assert "regenerate it (api.generate(SCENE, force=True))" in text


def test_a_scores_note_is_data_the_same_from_either_surface(dataset, saved_run, tmp_path):
    """The note named the command's --density in the scores the API returns; a record is the same whoever made it."""
    assert main(["score", str(dataset), str(saved_run / "test"), "--out", str(tmp_path / "s.json")]) == 0
    note = json.loads((tmp_path / "s.json").read_text())["metrics"]["density_note"]
    assert api.score(dataset, saved_run / "test")["density_note"] == note == "no density grid given"


# --------------------------------------------------------------------------- arguments checked as the commands check

@pytest.mark.parametrize("overrides", [[1], "cameras.width=8", 3])
def test_overrides_that_are_not_a_mapping_are_a_usage_error_naming_them(overrides, tmp_path):
    text = _raises(UsageError, lambda: api.generate("cloud", tmp_path, overrides=overrides))
    assert text.startswith("overrides: must be a mapping")
    assert not any(tmp_path.iterdir())


def test_settings_that_are_not_a_mapping_are_a_usage_error_naming_them(dataset):
    assert _raises(UsageError, lambda: api.fit(dataset, "voxel", settings=["x"])).startswith("settings: must be")


@pytest.mark.parametrize("inside", [".", "runs/voxel"])
def test_a_run_inside_the_dataset_is_refused_as_the_command_refuses_it(dataset, inside):
    before = sorted(p.relative_to(dataset) for p in dataset.rglob("*"))
    text = _raises(UsageError, lambda: api.fit(dataset, "voxel", steps=1, settings=TINY_VOXEL, out=dataset / inside))
    assert text.startswith("out: ") and "is inside the dataset" in text and "e.g. out='runs/NAME'" in text
    assert sorted(p.relative_to(dataset) for p in dataset.rglob("*")) == before


def test_a_stopped_bench_says_to_call_it_again_not_to_run_a_command(tmp_path, monkeypatch):
    import mitsnerf.bench.executors
    from mitsnerf.errors import Interrupted

    spec = tmp_path / "tiny.toml"
    spec.write_text(scene_toml(tiny_scene({"name": "stoptiny"})))
    (tmp_path / "first.toml").write_text(BENCH_TOML.format(spec=spec))

    def stopped(*args, **kwargs):
        raise Interrupted(15, "stopped by SIGTERM")

    monkeypatch.setattr(mitsnerf.bench.executors, "run_cells", stopped)  # the sweep stopped before its first cell
    text = _raises(Interrupted, lambda: api.bench(tmp_path / "first.toml", results=tmp_path / "r", data=tmp_path / "d"))
    assert "call api.bench again with the same arguments to resume" in text


def test_settings_take_the_dotted_keys_of_set_and_of_mitsnerf_methods(dataset):
    """``{"network.width": 8}`` as --set and ``mitsnerf methods NAME`` write them sets what ``{"network": {"width":
    8}}`` sets (it used to be refused: unknown field); a dotted key that names no field is refused at its full path."""
    dotted = {"network.width": 8, "network.depth": 1, "network.head_width": 8, "network.features": 4, "n_samples": 8}
    run = api.fit(dataset, "nerf", steps=1, batch_rays=32, settings=dotted)
    network = run.model.config.network
    assert (network.width, network.depth, network.head_width, network.features) == (8, 1, 8, 4)
    text = _raises(SpecError, lambda: api.fit(dataset, "nerf", steps=1, settings={"network.widht": 8}))
    assert text == "settings: network.widht: unknown field (did you mean 'width'?)", text
