"""mitsnerf.api: the README's example runs as written, the functions return the numbers the commands print
and write, and bad input raises the package's typed errors, never SystemExit."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from mitsnerf import api
from mitsnerf.cli import main
from mitsnerf.errors import DatasetError, MitsnerfError, SpecError, UsageError
from mitsnerf.train.threads import nondeterminism

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
