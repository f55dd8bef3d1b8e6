"""``mitsnerf score`` of mitsnerf's own renders reproduces the run's own figures, with no flags: the EXRs say
in their header that alpha is only opacity (``mitsnerf:alpha = opacity``), so the background is not
composited a second time."""

from __future__ import annotations

import json

import pytest

from mitsnerf.cli import main
from mitsnerf.data.images import read_exr, read_exr_alpha, write_exr


def _scores(capsys, *argv) -> dict:
    status = main(["score", *map(str, argv)])
    err = capsys.readouterr().err
    assert status == 0, err
    return json.loads((argv[-1]).read_text())["metrics"]


def _same_as_run(scores: dict, run) -> None:
    own = json.loads((run / "metrics.json").read_text())
    for key in ("psnr_test", "psnr_test_medium"):
        assert scores[key] == pytest.approx(own[key], abs=0.01), key


def test_a_run_directory_scores_as_its_metrics(world, tmp_path, capsys):
    assert read_exr_alpha(world.run / "test" / "r_000.exr") == "opacity"
    _same_as_run(_scores(capsys, world.dataset, world.run, "--out", tmp_path / "s.json"), world.run)
    _same_as_run(_scores(capsys, world.dataset, world.run / "test", "--out", tmp_path / "t.json"), world.run)


def test_an_exr_that_does_not_say_its_alpha_is_refused_not_guessed(world, tmp_path, capsys):
    """A run's EXR without the header (as written before it existed): alpha below 1 over RGB that holds the
    background already; one line naming --exr-alpha, nothing written; with --exr-alpha ignore it scores."""
    renders = tmp_path / "old"
    renders.mkdir()
    for f in sorted((world.run / "test").glob("*.exr")):
        write_exr(renders / f.name, read_exr(f))
    assert read_exr_alpha(renders / "r_000.exr") is None
    status = main(["score", str(world.dataset), str(renders)])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "--exr-alpha" in err and "r_000.exr: alpha:" in err, err
    assert not (renders / "scores.json").exists()
    _same_as_run(_scores(capsys, world.dataset, renders, "--exr-alpha", "ignore", "--out", tmp_path / "s.json"),
                 world.run)


def test_render_split_test_scores_as_the_run(world, tmp_path, capsys):
    """``render RUN --split test`` renders every test view, named as the frames, depth and opacity apart:
    the folder scores as it is and gives the run's figures."""
    out = tmp_path / "renders"
    assert main(["render", str(world.run), "--split", "test", "--out", str(out), "--no-progress"]) == 0
    assert sorted(p.name for p in out.glob("*.exr")) == ["r_000.exr", "r_001.exr"]
    assert (out / "depth" / "r_001.exr").is_file() and (out / "opacity" / "r_001.png").is_file()
    _same_as_run(_scores(capsys, world.dataset, out, "--out", tmp_path / "s.json"), world.run)
