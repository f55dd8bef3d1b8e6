"""``mitsnerf train`` (checkpoints, --resume, errors), ``render`` and ``export`` on a tiny run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mitsnerf.cli import main
from mitsnerf.data.images import read_exr, read_png
from mitsnerf.errors import TrainingError

from .conftest import tiny_scene

TINY = tiny_scene({"name": "tiny-cli", "description": "a 16^3 cloud, 12x12 views", "cameras.width": 12, "cameras.height": 12,
                   "render.spp_test": 4, "render.max_depth": 8, "render.noise_floor": False})

NERF = ["--method", "nerf", "--set", "network.width=8", "--set", "network.depth=1", "--set", "network.head_width=8",
        "--set", "network.features=4", "--set", "n_samples=8"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import parse_scene

    root = tmp_path_factory.mktemp("cli")
    dataset = generate_dataset(parse_scene(TINY, "tiny"), root / "data", progress=False)
    run = root / "run"
    assert main(["train", str(dataset), "--out", str(run), "--steps", "4", "--batch-rays", "64",
                 "--checkpoint-every", "2", *NERF]) == 0
    return run


def test_train_writes_a_run_with_its_final_checkpoint(run_dir):
    from mitsnerf.train.checkpoint import load_checkpoint

    names = {p.name for p in run_dir.iterdir()}
    assert {"config.json", "params.npz", "metrics.json", "checkpoint.npz", "test"} <= names
    ckpt = load_checkpoint(run_dir / "checkpoint.npz")
    assert ckpt.step == 4 and ckpt.config["method"] == "nerf" and ckpt.config["train"]["checkpoint_every"] == 2


def test_render_a_dataset_view_writes_rgb_depth_and_opacity(run_dir, tmp_path, capsys):
    assert main(["render", str(run_dir), "--out", str(tmp_path)]) == 0
    for sub in ("", "depth/", "opacity/"):
        assert read_exr(tmp_path / f"{sub}test_000.exr").shape == (12, 12, 4 if sub == "" else 3)
        assert read_png(tmp_path / f"{sub}test_000.png").shape[:2] == (12, 12)
    rgba = read_exr(tmp_path / "test_000.exr")
    opacity = read_exr(tmp_path / "opacity" / "test_000.exr")[..., 0]
    np.testing.assert_array_equal(rgba[..., 3], opacity)
    assert "7 files" in capsys.readouterr().out
    (info,) = json.loads((tmp_path / "render.json").read_text())
    assert info["views"][0]["name"] == "test_000" and info["provenance"]["variant"]


def test_render_look_from_with_size_and_an_orbit_gif(run_dir, tmp_path):
    from PIL import Image

    assert main(["render", str(run_dir), "--out", str(tmp_path), "--look-from", "2", "0", "0.5",
                 "--fov", "30", "--size", "10", "6"]) == 0
    assert read_exr(tmp_path / "view.exr").shape == (6, 10, 4)
    assert main(["render", str(run_dir), "--out", str(tmp_path), "--orbit", "3", "--size", "8"]) == 0
    assert sorted(p.name for p in (tmp_path / "orbit").glob("frame_*.png")) == \
        ["frame_000.png", "frame_001.png", "frame_002.png"]
    assert (tmp_path / "orbit" / "depth" / "frame_002.exr").is_file()
    calls = json.loads((tmp_path / "render.json").read_text())  # both calls, in order
    assert [c["views"][0]["name"] for c in calls] == ["view", "orbit/frame_000"]
    with Image.open(tmp_path / "orbit.gif") as gif:
        assert gif.n_frames == 3


def test_export_cli_writes_the_medium(run_dir, tmp_path):
    from mitsnerf.data.vol import read_vol

    assert main(["export", str(run_dir), "--out", str(tmp_path), "--resolution", "4", "--directions", "2"]) == 0
    sigma, lo, hi = read_vol(tmp_path / "sigma_t.vol")
    assert sigma.shape == (4, 4, 4, 1) and lo == (-0.5, -0.5, -0.5)
    assert read_vol(tmp_path / "albedo.vol")[0].shape == (4, 4, 4, 3)
    info = json.loads((tmp_path / "export.json").read_text())
    assert info["method"] == "nerf" and "averaged over 2" in info["colour"]


def test_resume_continues_the_run(run_dir, tmp_path):
    import shutil

    from mitsnerf.train.checkpoint import load_checkpoint

    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    assert main(["train", "--resume", "--out", str(run), "--steps", "6"]) == 0
    ckpt = load_checkpoint(run / "checkpoint.npz")
    assert ckpt.step == 6
    assert [h["step"] for h in json.loads((run / "history.json").read_text())] == [4, 6]
    assert main(["train", "--resume", "--out", str(run), "--lr", "0.5"]) == 2  # settings come from the checkpoint


def test_training_errors_are_one_line_and_exit_non_zero(run_dir, monkeypatch, capsys):
    import mitsnerf.runs.fit

    def nan(*args, **kwargs):
        raise TrainingError(None, "step 7", "loss became nan; stopped; last good checkpoint: RUN/checkpoint.npz (step 6)")

    monkeypatch.setattr(mitsnerf.runs.fit, "fit", nan)
    config = json.loads((run_dir / "config.json").read_text())
    assert main(["train", config["dataset"], "--out", str(run_dir.parent / "never")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["mitsnerf: error: step 7: loss became nan; stopped; last good checkpoint: RUN/checkpoint.npz (step 6)"]


def test_a_run_whose_parameters_its_config_does_not_build_is_refused_in_one_line(run_dir, tmp_path, capsys):
    """A run written by another version of the method (here: its config edited to take the view direction)."""
    import shutil

    old = tmp_path / "old-run"
    shutil.copytree(run_dir, old)
    (old / "checkpoint.npz").unlink()  # load from config.json + params.npz
    config = json.loads((old / "config.json").read_text())
    config["method_config"]["network"]["use_direction"] = True
    (old / "config.json").write_text(json.dumps(config))
    out = tmp_path / "renders"
    assert main(["render", str(old), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "params.npz: fine.head.0.weights: has shape" in err[0] and "retrain it" in err[0]
    assert not out.exists()


@pytest.mark.parametrize(("argv", "what"), [
    (["render", "{run}", "--split", "test", "--out", "{dataset}/renders"], "renders there"),
    (["export", "{run}", "--resolution", "4", "--out", "{dataset}/export"], "an export there"),
    (["score", "{dataset}", "{run}", "--out", "{dataset}/scores.json"], "a scores file there"),
    (["score", "{dataset}", "{dataset}/test"], "a scores file there"),  # its default, RENDERS/scores.json
])
def test_no_command_writes_inside_the_dataset(run_dir, capsys, argv, what):
    """render, export and score refuse an output inside the dataset, as train does: its files would change a
    hashed dataset (they used to write there). One line naming --out, exit 2, the dataset as it was."""
    (dataset,) = (run_dir.parent / "data").glob("tiny-cli-*")
    before = sorted(p.relative_to(dataset) for p in dataset.rglob("*"))
    capsys.readouterr()
    assert main([a.format(run=run_dir, dataset=dataset) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mitsnerf: error: --out: ") and what in err, err
    assert "is inside the dataset" in err and "put it outside, e.g. --out " in err, err
    assert sorted(p.relative_to(dataset) for p in dataset.rglob("*")) == before
