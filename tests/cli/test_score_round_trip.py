"""``mitsnerf score`` of mitsnerf's own renders reproduces the run's own figures, with no flags: the EXRs say
in their header that alpha is only opacity (``mitsnerf:alpha = opacity``), so the background is not
composited a second time."""

from __future__ import annotations

import json
import shutil

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


def test_renders_of_render_split_test_are_held_at_the_footprint_render_json_records(world, tmp_path, capsys):
    """``render RUN --split test`` renders at the run's footprint (3) and records it in render.json; ``score`` of
    that folder reads it (it used to take 1, and so the footprint-1 oracle); --footprint still overrides it."""
    out = tmp_path / "renders"
    assert main(["render", str(world.run), "--split", "test", "--out", str(out), "--no-progress"]) == 0
    assert json.loads((out / "render.json").read_text())[-1]["footprint"] == 3
    assert _scores(capsys, world.dataset, out, "--out", tmp_path / "s.json")["footprint"] == 3
    assert _scores(capsys, world.dataset, out, "--footprint", "1", "--out", tmp_path / "t.json")["footprint"] == 1


def test_renders_made_at_two_footprints_are_refused_not_guessed(world, tmp_path, capsys):
    """Views rendered into one folder at footprints 3 and 1: one line naming render.json and --footprint."""
    out = tmp_path / "renders"
    assert main(["render", str(world.run), "--split", "test", "--out", str(out), "--no-progress"]) == 0
    calls = json.loads((out / "render.json").read_text())
    calls.append({**calls[-1], "views": calls[-1]["views"][:1], "footprint": 1})
    (out / "render.json").write_text(json.dumps(calls))
    capsys.readouterr()
    assert main(["score", str(world.dataset), str(out), "--out", str(tmp_path / "s.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "render.json: footprint:" in err and "--footprint" in err, err
    assert not (tmp_path / "s.json").exists()


def test_a_run_gives_its_own_figures_unless_told_otherwise(world, tmp_path, capsys):
    """A run directory is scored as the run scored itself: at its footprint (3), in a row named after its
    method, with its model's density scores and train PSNR from metrics.json; --footprint, --density and
    --name override them."""
    own = json.loads((world.run / "metrics.json").read_text())
    assert main(["score", str(world.dataset), str(world.run), "--out", str(tmp_path / "s.json")]) == 0
    out = capsys.readouterr().out
    scored = json.loads((tmp_path / "s.json").read_text())
    assert own["footprint"] == 3 and own["density_rel_l1"] is not None
    assert scored["run"] == str(world.run) and scored["external"] is False
    assert "| tiny | nerf | 1 |" in out and "(external)" not in out and "density: the run's own" in out
    same = [k for k in own if k in scored["metrics"]]
    assert {"footprint", "psnr_test_medium", "density_rel_l1", "tau_rel_l1", "psnr_train"} <= set(same)
    for key in same:
        assert scored["metrics"][key] == own[key], key
    grid = world.dataset / "volume" / "sigma_t.npy"
    assert main(["score", str(world.dataset), str(world.run), "--footprint", "1", "--density", str(grid),
                 "--name", "mine", "--out", str(tmp_path / "t.json")]) == 0
    out = capsys.readouterr().out
    told = json.loads((tmp_path / "t.json").read_text())["metrics"]
    assert told["footprint"] == 1 and told["density_rel_l1"] == pytest.approx(0.0, abs=1e-6)
    assert "| tiny | mine | 1 |" in out


@pytest.fixture(scope="module")
def other(world, tmp_path_factory):
    """Another tiny dataset with the same cameras: the world's spec with another cloud (volume seed 2)."""
    root = tmp_path_factory.mktemp("other")
    spec = root / "tiny.toml"
    spec.write_text(world.spec.read_text().replace("seed = 1", "seed = 2", 1))
    assert main(["generate", str(spec), "--out", str(root / "data")]) == 0
    (dataset,) = [p for p in (root / "data").iterdir() if p.name.startswith("tiny-")]
    return dataset


def test_a_run_of_another_dataset_is_refused(world, other, tmp_path, capsys):
    """Same cameras, another medium: one line naming the run and both datasets, exit 2, nothing written (the
    API: a UsageError); the run's own dataset moved elsewhere (the same manifest hash) is still its own."""
    from mitsnerf import api
    from mitsnerf.errors import UsageError

    capsys.readouterr()
    for out in ([], ["--out", str(tmp_path / "s.json")]):
        status = main(["score", str(other), str(world.run), *out])
        err = capsys.readouterr().err
        assert status == 2 and err.count("\n") == 1, err
        assert f"the run in {world.run} trained on {world.dataset.resolve()}" in err and str(other.resolve()) in err
    assert not (tmp_path / "s.json").exists() and not (world.run / "test" / "scores.json").exists()
    with pytest.raises(UsageError, match=f"^renders: the run in {world.run} trained on"):
        api.score(other, world.run)
    moved = tmp_path / "moved"
    shutil.copytree(world.dataset, moved)
    assert main(["score", str(moved), str(world.run), "--out", str(tmp_path / "m.json")]) == 0


@pytest.fixture(scope="module")
def oracled(world, tmp_path_factory):
    """A copy of the world's dataset whose oracle ``score RUN --compute-oracle`` computed, and what the command
    printed (stdout, stderr, its scores.json). The oracle's volpath estimate takes a few directions per point of an
    8^3 grid, for time; the command itself takes the default settings."""
    import contextlib
    import io

    from mitsnerf.oracle import cache

    root = tmp_path_factory.mktemp("oracled")
    dataset = root / "data"
    shutil.copytree(world.dataset, dataset)  # the oracle is written into it
    cheap = cache.OracleConfig(spp=8, resolution=8)
    out, err = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as patch, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        patch.setattr(cache, "OracleConfig", lambda: cheap)
        status = main(["score", str(dataset), str(world.run), "--compute-oracle", "--out", str(root / "s.json")])
    assert status == 0, err.getvalue()
    return dataset, out.getvalue(), err.getvalue(), json.loads((root / "s.json").read_text())["metrics"]


def test_without_an_oracle_score_names_what_computes_it_and_compute_oracle_does(world, oracled, tmp_path, capsys):
    """A dataset with no oracle cached (a user's own volume's): the line says which option computes one; with it,
    the oracle is computed (saying so on stderr) and cached in the dataset, and the renders are held against it."""
    assert main(["score", str(world.dataset), str(world.run), "--out", str(tmp_path / "s.json")]) == 0
    out = capsys.readouterr().out
    assert "no oracle (none cached in" in out and "--compute-oracle computes it" in out, out
    dataset, out, err, scores = oracled
    assert "(computed now)" in out and "oracle: the in-scattered light by volpath" in err, (out, err)
    assert scores["oracle_psnr_test_medium"] is not None and list((dataset / "oracle").glob("*/oracle.json"))


def test_a_run_scores_with_what_it_was_given_and_its_rung(world, tmp_path, capsys):
    """score RUN fills the table's given and rung from the run's metrics.json, as the bench does."""
    scores = _scores(capsys, world.dataset, world.run, "--out", tmp_path / "s.json")
    assert (scores["given"], scores["rung"]) == ("images", "emission-absorption")
    assert scores["ceiling_psnr_test_medium"] is None  # no oracle cached: no ceiling for emission-absorption


def test_a_run_scores_with_its_rungs_ceiling(oracled):
    """With an oracle, score RUN fills its ceiling and the gap to it too (nerf: held to the oracle), as the bench
    does: the ceiling raw and less its own Monte Carlo variance, the gap between the variance-free figures."""
    _, out, _, scores = oracled
    assert (scores["given"], scores["rung"]) == ("images", "emission-absorption")
    assert scores["ceiling_psnr_test_medium"] == scores["oracle_psnr_test_medium"] is not None
    ceiling = scores["ceiling_psnr_test_medium_without_mc"]
    assert ceiling == scores["oracle_psnr_test_medium_without_mc"] is not None
    assert ceiling > scores["ceiling_psnr_test_medium"] and scores["ceiling_note"].startswith("the oracle, less its")
    assert scores["gap_to_ceiling"] == pytest.approx(ceiling - scores["psnr_test_medium"])
    assert "| images | emission-absorption |" in out
