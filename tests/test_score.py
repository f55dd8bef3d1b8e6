"""``mitsnerf score``: any tool's renders against a dataset's test views, matched by name or by order."""

from __future__ import annotations

import copy
import json
import shutil

import numpy as np
import pytest

from mitsnerf import generate as gen
from mitsnerf.cli import main
from mitsnerf.data.dataset import load_dataset
from mitsnerf.data.images import read_exr, write_exr, write_png
from mitsnerf.data.vol import write_vol
from mitsnerf.errors import DatasetError
from mitsnerf.runs.external import match_renders, score_renders
from mitsnerf.scene.spec import parse_scene

SPEC = {
    "name": "scored",
    "volume": {"family": "cloud", "resolution": 16, "seed": 1, "sigma_t_scale": 30.0},
    "lights": [{"type": "constant", "radiance": [0.5, 0.55, 0.6]},
               {"type": "directional", "direction": [-0.4, -0.8, -0.45], "irradiance": [4.0, 3.8, 3.5]}],
    "cameras": {"rig": "sphere", "n_train": 2, "n_test": 3, "width": 12, "height": 12, "fov": 40.0, "radius": 2.2},
    "render": {"spp_train": 4, "spp_test": 64},
}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return gen.generate_dataset(parse_scene(copy.deepcopy(SPEC), "scored.toml"), tmp_path_factory.mktemp("d"),
                                progress=False)


def _copy(src, dst, names=None, suffix=".exr"):
    dst.mkdir(parents=True, exist_ok=True)
    files = sorted(src.glob(f"r_*{suffix}"))
    for i, f in enumerate(files):
        shutil.copy(f, dst / ((names[i] if names else f.stem) + suffix))
    return dst


def _score(capsys, *argv):
    status = main(["score", *map(str, argv)])
    out, err = capsys.readouterr()
    return status, out, err


def test_test_ref_scores_exactly_the_noise_floor(dataset, capsys, tmp_path):
    status, out, err = _score(capsys, dataset, dataset / "test_ref", "--format", "exr", "--out", tmp_path / "s.json")
    assert status == 0, err
    floor = json.loads((dataset / "manifest.json").read_text())["noise_floor"]
    m = json.loads((tmp_path / "s.json").read_text())["metrics"]
    assert m["psnr_test"] == floor["psnr"] and m["psnr_test_medium"] == floor["psnr_medium"]
    assert m["psnr_test_srgb"] == floor["psnr_srgb"] and m["noise_floor_psnr"] == floor["psnr"]
    assert "| scored | test_ref (external) | 1 |" in out and "matched by name; no oracle" in out
    assert out.startswith("mitsnerf: scene box [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]] (transforms_train.json: aabb)")


def test_png_renders_are_held_against_the_floor_of_8_bit_png(dataset, capsys, tmp_path):
    """test_ref's PNG previews score exactly the PNG floor, which lies below the manifest's (EXR) floor;
    the row shows it as its ref agreement and says which floor it is."""
    status, out, err = _score(capsys, dataset, dataset / "test_ref", "--format", "png", "--out", tmp_path / "s.json")
    assert status == 0, err
    floor = json.loads((dataset / "manifest.json").read_text())["noise_floor"]
    m = json.loads((tmp_path / "s.json").read_text())["metrics"]
    assert m["psnr_test"] == m["noise_floor_psnr"] and m["psnr_test_medium"] == m["noise_floor_psnr_medium"]
    assert m["noise_floor_psnr"] < floor["psnr"] and "8-bit sRGB PNG" in m["noise_floor_of"]
    assert "ref agreement: 8-bit sRGB PNG" in out


def test_matched_by_order_equals_matched_by_name(dataset, tmp_path):
    by_name = _copy(dataset / "test_ref", tmp_path / "a")
    by_order = _copy(dataset / "test_ref", tmp_path / "b", ["frame_9", "frame_10", "frame_11"])  # 9 < 10 < 11
    ds = load_dataset(dataset)
    a, b = score_renders(ds, by_name), score_renders(ds, by_order)
    assert (a.matched_by, b.matched_by) == ("name", "order")
    assert a.metrics["psnr_test_per_view"] == b.metrics["psnr_test_per_view"]
    assert list(b.files.values())[0].endswith("frame_9.exr")


def test_png_with_alpha_is_composited_over_the_background(dataset, tmp_path):
    """The medium-alone PNGs (straight alpha) over the dataset's environment are the test images again."""
    renders = _copy(dataset / "medium" / "test_ref", tmp_path / "png", suffix=".png")
    s = score_renders(load_dataset(dataset), renders)
    floor = json.loads((dataset / "manifest.json").read_text())["noise_floor"]
    assert s.metrics["psnr_test"] > 30 and s.metrics["psnr_test"] > floor["psnr"] - 8  # 8-bit PNG and clipped colour
    exr = score_renders(load_dataset(dataset), _copy(dataset / "medium" / "test_ref", tmp_path / "exr"))
    # the same renders in linear premultiplied EXR: the same score up to 8-bit rounding (not composited, > 10 dB less)
    assert exr.metrics["psnr_test"] == pytest.approx(s.metrics["psnr_test"], abs=0.5)


def test_exr_alpha_is_premultiplied(dataset, tmp_path):
    """An RGBA EXR composites as ``rgb + B (1 - a)`` (OpenEXR's premultiplied alpha): the test images written
    as half opacity over the dataset's own background score exactly; read as straight alpha they would not."""
    from mitsnerf.runs.external import read_renders
    from mitsnerf.render.background import make_background, pixel_background

    ds = load_dataset(dataset)
    views = ds.views("test")
    background = pixel_background(make_background(ds.background, ds.root), views.cameras, views.pixel_center)
    folder = tmp_path / "half"
    folder.mkdir()
    for i, name in enumerate(views.names):
        rgb = views.images[i][..., :3] - 0.5 * background[i]
        write_exr(folder / f"{name}.exr", np.concatenate([rgb, np.full_like(rgb[..., :1], 0.5)], axis=-1),
                  alpha="premultiplied")
    images, _, _ = read_renders(ds, folder)
    np.testing.assert_allclose(images, views.images[..., :3], atol=1e-6)
    straight, _, _ = read_renders(ds, folder, exr_alpha="straight")  # rgb a + B (1 - a): not the test images
    assert np.abs(straight - views.images[..., :3]).max() > 0.05
    ignored, _, _ = read_renders(ds, folder, exr_alpha="ignore")
    np.testing.assert_array_equal(ignored, views.images[..., :3] - 0.5 * background.astype(np.float32))


def test_an_exr_with_alpha_one_is_used_as_it_is_and_a_later_one_is_composited(dataset, tmp_path):
    """mitsnerf's own EXRs (alpha 1) are read unchanged; the background is computed when a later file needs it."""
    from mitsnerf.data.images import read_image
    from mitsnerf.runs.external import read_renders

    ds = load_dataset(dataset)
    views = ds.views("test")
    folder = _copy(dataset / "test", tmp_path / "mixed")
    last = views.names[-1]
    medium = read_image(dataset / "medium" / "test" / f"{last}.exr")
    write_exr(folder / f"{last}.exr", medium)  # the medium alone, premultiplied
    images, _, _ = read_renders(ds, folder)
    np.testing.assert_array_equal(images[:-1], views.images[:-1, ..., :3])
    assert np.abs(images[-1] - views.images[-1, ..., :3]).mean() < 0.02  # the composite is the view again (MC noise)
    assert np.abs(medium[..., :3] - views.images[-1, ..., :3]).mean() > 0.05  # and the bare medium is not



def test_density_grid_and_oracle(dataset, tmp_path):
    from mitsnerf.oracle.cache import ORACLE_DIR, ORACLE_FORMAT

    renders = _copy(dataset / "test_ref", tmp_path / "r")
    ds = load_dataset(dataset)
    s = score_renders(ds, renders, density=dataset / "volume" / "sigma_t.vol")
    assert s.metrics["density_rel_l1"] == pytest.approx(0.0, abs=1e-6) and s.metrics["tau_rel_l1"] < 1e-5
    half = tmp_path / "half.npy"
    np.save(half, 0.5 * np.load(dataset / "volume" / "sigma_t.npy"))
    assert score_renders(ds, renders, density=half).metrics["density_rel_l1"] == pytest.approx(0.5, abs=1e-4)
    elsewhere = tmp_path / "elsewhere.vol"
    write_vol(elsewhere, np.load(dataset / "volume" / "sigma_t.npy"), (-1, -1, -1), (1, 1, 1))
    with pytest.raises(DatasetError, match=r"elsewhere.vol: bbox: \[\[-1.0, -1.0, -1.0\], \[1.0, 1.0, 1.0\]\] is not the dataset's box"):
        score_renders(ds, renders, density=elsewhere)
    assert s.oracle.startswith("no oracle") and s.metrics["oracle_psnr_test_medium"] is None
    copy_root = tmp_path / "with_oracle"
    shutil.copytree(dataset, copy_root)
    cached = copy_root / ORACLE_DIR / "0123456789ab"  # a cached oracle's index and scores (mitsnerf.oracle.cache)
    cached.mkdir(parents=True)
    (cached / "oracle.json").write_text(json.dumps({"format": ORACLE_FORMAT, "config": {}, "footprint": 3}))
    (cached / "scores.json").write_text(json.dumps({"footprint_1": {"psnr_test": 50.0, "psnr_test_medium": 40.0},
                                                    "footprint_3": {"psnr_test": 51.0, "psnr_test_medium": 41.0}}))
    for k, medium in ((1, 40.0), (3, 41.0)):
        o = score_renders(load_dataset(copy_root), renders, footprint=k)
        assert str(cached) in o.oracle and o.metrics["oracle_psnr_test_medium"] == medium
        assert o.metrics["gap_to_oracle"] == pytest.approx(medium - o.metrics["psnr_test_medium"], abs=1e-5)
    assert score_renders(load_dataset(copy_root), renders, footprint=2).oracle.startswith("no oracle")


def _bad_count(d, r):
    (r / "r_002.exr").rename(r / "x.exr")
    for f in r.glob("r_*.exr"):
        f.rename(r / f"frame{f.stem[-1]}.exr")
    (r / "x.exr").unlink()


def _bad_size(d, r):
    write_exr(r / "r_001.exr", np.zeros((8, 12, 4), np.float32))


def _nan(d, r):
    img = read_exr(r / "r_002.exr")
    img[3, 4, 1] = np.nan
    write_exr(r / "r_002.exr", img)


BAD = [
    ("wrong count", _bad_count, "renders: 2 images for 3 test frames (matched by order"),
    ("missing frame", lambda d, r: (r / "r_001.exr").unlink(), "renders: no render for test frame r_001 (2 of 3"),
    ("stray file", lambda d, r: shutil.copy(r / "r_000.exr", r / "extra.exr"), "extra.exr: named after no test frame"),
    ("wrong size", _bad_size, "r_001.exr: image is 12x8, test frame r_001 is 12x12"),
    ("NaN pixel", _nan, "r_002.exr: 1 non-finite pixel values (NaN/inf), first at row 3, column 4"),
    ("two kinds", lambda d, r: (write_exr(r / "r_000.exr", read_exr(r / "r_000.exr")[..., :3]),  # says no alpha
                                write_png(r / "r_000.png", np.zeros((12, 12, 3)))), "both r_000.exr and r_000.png"),
    ("no number", lambda d, r: [f.rename(r / f"view{'abc'[int(f.stem[-1])]}.exr") for f in r.glob("r_*.exr")],
     "no frame number in the name"),
    ("box min >= max", lambda d, r: None, "--box: min must be < max"),
]


@pytest.mark.parametrize("what, spoil, message", BAD, ids=[b[0] for b in BAD])
def test_bad_renders_one_line_exit_2_nothing_written(dataset, tmp_path, capsys, what, spoil, message):
    renders = _copy(dataset / "test_ref", tmp_path / "renders")
    spoil(dataset, renders)
    extra = ["--box", "0", "0", "0", "0", "1", "1"] if what.startswith("box") else []
    status, out, err = _score(capsys, dataset, renders, *extra)
    assert status == 2 and err.count("\n") == 1 and err.startswith("mitsnerf: error: "), err
    assert message in err, err
    assert not (renders / "scores.json").exists() and "|" not in out  # at most the box line, no table


def test_match_needs_a_folder(tmp_path):
    with pytest.raises(Exception, match="renders folder not found"):
        match_renders(tmp_path / "nope", ["r_000"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(Exception, match="no .png or .exr images"):
        match_renders(tmp_path / "empty", ["r_000"])


def test_a_bad_footprint_is_one_line_and_exit_2(dataset, tmp_path, capsys):
    renders = _copy(dataset / "test_ref", tmp_path / "renders")
    status, out, err = _score(capsys, dataset, renders, "--footprint", "0")
    assert status == 2 and err == "mitsnerf: error: --footprint: must be an integer in [1, 16], got 0\n", err
    assert not (renders / "scores.json").exists()


def test_a_single_scattering_runs_basis_is_the_one_it_recorded_else_its_models(dataset, tmp_path):
    """The ceiling of a scatter run's row needs its remainder basis (L_f, L_z): metrics.json's rung_basis, else
    (a run from before it was recorded) the basis its model, built from the run's settings, has."""
    from mitsnerf.methods import methods
    from mitsnerf.runs.external import RunRenders, run_basis

    ds = load_dataset(dataset)
    assert run_basis(RunRenders(tmp_path, {"method": "scatter"}, {"rung_basis": [2, 5]}, 1), ds) == (2, 5)
    settings = copy.deepcopy(dict(methods()["scatter"].model_type.tiny))
    settings["field"].update({"remainder_degree": 1, "zonal_degree": 3})  # the model's: none in an isotropic medium
    assert run_basis(RunRenders(tmp_path, {"method": "scatter", "method_config": settings}, {}, 1), ds) == (0, 0)
    with pytest.raises(DatasetError, match="metrics.json: rung_basis: must be two whole numbers"):
        run_basis(RunRenders(tmp_path, {"method": "scatter"}, {"rung_basis": [1.5, 2]}, 1), ds)
