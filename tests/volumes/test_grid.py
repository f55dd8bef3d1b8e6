"""The ``grid`` family: the user's own medium from a file, exactly (identity at the same resolution, the
same array from .npy, .npz and .vol), placed with its aspect kept, box-filtered when shrunk; bad grids
refused in one line naming the file; the dataset's key follows the file's content, not its path."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

import mitsnerf  # noqa: F401  (sets up LLVM before drjit loads anywhere)
from mitsnerf.data.vol import write_vol
from mitsnerf.errors import SpecError
from mitsnerf.scene.spec import grid_scene, load_scene, parse_scene
from mitsnerf.scene.to_mitsuba import volume_grids
from mitsnerf.volumes import generate_volume, make_params
from mitsnerf.volumes.grid import Params, generate

R = 16


def torus(r: int = R) -> np.ndarray:
    """A torus of varying density, [z, y, x], float32."""
    c = (np.arange(r) + 0.5) / r - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    ring = (np.hypot(x, y) - 0.25) ** 2 + z**2
    return (np.exp(-ring / 0.006) * (1.0 + 0.5 * x)).astype(np.float32)


@pytest.fixture
def files(tmp_path):
    """The same torus as .npy, .npz (named ``rho`` beside another array) and .vol."""
    a = torus()
    np.save(tmp_path / "t.npy", a)
    np.savez(tmp_path / "t.npz", rho=a, other=np.zeros(3))
    write_vol(tmp_path / "t.vol", a)
    return a, tmp_path


def test_every_format_gives_the_array_itself_at_its_resolution(files):
    a, d = files
    for name, array in (("t.npy", ""), ("t.npz", "rho"), ("t.vol", "")):
        g = generate_volume("grid", R, 0, {"path": str(d / name), "array": array})
        assert g.density.dtype == np.float32
        np.testing.assert_array_equal(g.density, a)  # bit for bit
        np.testing.assert_array_equal(g.albedo, np.float32(0.8))


def test_shrinking_box_filters_and_growing_keeps_the_mass(files):
    a, d = files
    half = generate(Params(path=str(d / "t.npy")), R // 2, 0).density
    np.testing.assert_allclose(half, a.reshape(8, 2, 8, 2, 8, 2).mean(axis=(1, 3, 5)), rtol=1e-6, atol=1e-7)
    double = generate(Params(path=str(d / "t.npy")), 2 * R, 0).density
    assert double.mean() == pytest.approx(a.mean(), rel=1e-3)


def test_the_grid_keeps_its_aspect_and_the_margin(tmp_path):
    flat = np.ones((4, 8, 16), np.float32)  # z, y, x: a slab 16 wide, 4 high
    np.save(tmp_path / "slab.npy", flat)
    d = generate(Params(path=str(tmp_path / "slab.npy")), 16, 0).density
    filled = [np.nonzero(d.any(axis=tuple(i for i in range(3) if i != axis)))[0] for axis in range(3)]
    assert [list(f) for f in filled] == [list(range(6, 10)), list(range(4, 12)), list(range(16))]
    assert d.sum() == pytest.approx(flat.size)  # at the same voxel size every value lands once
    inset = generate(Params(path=str(tmp_path / "slab.npy"), margin=0.25), 16, 0).density
    assert np.nonzero(inset.any(axis=(0, 1)))[0].tolist() == list(range(4, 12))


def test_an_albedo_grid_grey_or_rgb(files):
    a, d = files
    rgb = np.stack([a / a.max(), np.full_like(a, 0.5), np.zeros_like(a)], axis=-1)
    np.save(d / "rgb.npy", rgb)
    np.save(d / "grey.npy", rgb[..., 0])
    g = generate(Params(path=str(d / "t.npy"), albedo_path=str(d / "rgb.npy")), R, 0)
    np.testing.assert_array_equal(g.albedo, rgb.astype(np.float32))
    grey = generate(Params(path=str(d / "t.npy"), albedo_path=str(d / "grey.npy")), R, 0).albedo
    np.testing.assert_array_equal(grey, np.repeat(rgb[..., :1], 3, axis=-1).astype(np.float32))


def spec_on(path, **volume):
    data = load_scene("cloud").to_dict()
    data["volume"] = {"family": "grid", "resolution": R, "sigma_t_scale": 30.0, "params": {"path": str(path)},
                      **volume}
    return data


def test_values_are_a_density_to_scale_or_sigma_t_itself(files):
    a, d = files
    sigma_t, _ = volume_grids(parse_scene(spec_on(d / "t.npy")))
    np.testing.assert_array_equal(sigma_t, np.float32(30.0) * a)
    data = spec_on(d / "t.npy", sigma_t_scale=1.0)
    data["volume"]["params"]["values"] = "sigma_t"
    sigma_t, _ = volume_grids(parse_scene(data))
    np.testing.assert_array_equal(sigma_t, a)
    data["volume"]["sigma_t_scale"] = 30.0
    with pytest.raises(SpecError, match=r"s.toml: volume.sigma_t_scale: must be 1 when params.values is 'sigma_t'"):
        parse_scene(data, "s.toml")


def test_paths_are_relative_to_the_spec_file(files, tmp_path):
    _, d = files
    spec_dir = d / "specs"
    spec_dir.mkdir()
    data = spec_on("../t.npy")
    (spec_dir / "mine.toml").write_text("\n".join(_toml(data)))
    spec = load_scene(spec_dir / "mine.toml")
    assert spec.volume.params["path"] == str((d / "t.npy").resolve())


def _toml(data) -> list[str]:
    import json

    v = data["volume"]
    lines = [f'name = "{data["name"]}"', "[volume]", f'family = "{v["family"]}"', f'resolution = {v["resolution"]}',
             f'sigma_t_scale = {v["sigma_t_scale"]}', f'params = {{ path = "{v["params"]["path"]}" }}']
    for light in data["lights"]:
        lines += ["[[lights]]"] + [f"{k} = {json.dumps(val)}" for k, val in light.items()]
    for table in ("cameras", "render"):
        lines += [f"[{table}]"] + [f"{k} = {json.dumps(val)}" for k, val in data[table].items()]
    return lines


def test_the_key_follows_the_content_not_the_path(files, tmp_path):
    a, d = files
    key = parse_scene(spec_on(d / "t.npy")).content_hash()
    moved = tmp_path / "elsewhere"
    moved.mkdir()
    shutil.copy(d / "t.npy", moved / "t.npy")
    assert parse_scene(spec_on(moved / "t.npy")).content_hash() == key
    np.save(moved / "t.npy", 0.5 * a)  # the case: half the density must be a new dataset
    assert parse_scene(spec_on(moved / "t.npy")).content_hash() != key


def test_generate_a_grid_file_names_the_scene_after_it(files):
    _, d = files
    spec = grid_scene(d / "t.vol")
    assert (spec.name, spec.volume.family, spec.volume.resolution) == ("t", "grid", R)
    assert spec.lights == load_scene("cloud").lights


def _bad(d, name: str, value) -> str:
    path = d / name
    if isinstance(value, bytes):
        path.write_bytes(value)
    elif name.endswith(".vol"):
        write_vol(path, value)
    else:
        np.save(path, value)
    return str(path)


BAD = [
    ("rank2.npy", np.ones((4, 4), np.float32), "has 2 axes (4, 4), a density grid needs 3"),
    ("nan.npy", np.where(torus() > 0.5, np.nan, torus()), "non-finite value"),
    ("neg.npy", torus() - 0.5, "outside >= 0"),
    ("size0.npy", np.ones((0, 4, 4), np.float32), "is empty"),
    ("zeros.npy", np.zeros((8, 8, 8), np.float32), "holds no medium: every value is 0"),
    ("strings.npy", np.array([["a"]]), "holds <U1 values, a density grid needs numbers"),
    ("rgb.vol", np.ones((4, 4, 4, 3), np.float32), "has 3 channels (4, 4, 4, 3), a density grid needs 1"),
    ("junk.npy", b"not a numpy file", "cannot be read as a .npy grid"),
    ("junk.vol", b"VOL garbage", "cannot be read as a .vol grid"),
]


@pytest.mark.parametrize(("name", "value", "problem"), BAD, ids=[b[0] for b in BAD])
def test_a_bad_grid_is_one_line_naming_the_file(tmp_path, name, value, problem):
    path = _bad(tmp_path, name, value)
    with pytest.raises(SpecError) as err:
        generate_volume("grid", 8, 0, {"path": path})
    assert str(err.value).startswith(f"{path}: ") and problem in str(err.value)
    assert "\n" not in str(err.value)


def test_npz_and_albedo_problems_name_the_file(files, tmp_path):
    a, d = files
    with pytest.raises(SpecError, match=r"t.npz: holds 2 arrays \(rho, other\); name one: --set volume.params.array=NAME"):
        generate_volume("grid", 8, 0, {"path": str(d / "t.npz")})
    np.save(tmp_path / "bright.npy", np.full(a.shape + (3,), 1.5, np.float32))
    with pytest.raises(SpecError, match=r"bright.npy: the albedo grid has .* outside \[0, 1\]"):
        generate_volume("grid", 8, 0, {"path": str(d / "t.npy"), "albedo_path": str(tmp_path / "bright.npy")})
    with pytest.raises(SpecError, match=r"nowhere.npy: no such grid file"):
        generate_volume("grid", 8, 0, {"path": str(tmp_path / "nowhere.npy")})


def test_params_name_what_is_wrong():
    with pytest.raises(SpecError, match="path: missing"):
        make_params("grid", {})
    with pytest.raises(SpecError, match=r"path: must name a .npy, .npz, .vol file, got 'smoke.vdb' \(OpenVDB"):
        make_params("grid", {"path": "smoke.vdb"})
    with pytest.raises(SpecError, match="values: must be one of"):
        make_params("grid", {"path": "a.npy", "values": "optical_depth"})


def test_a_spec_without_a_file_resolves_against_the_working_directory(files, monkeypatch):
    """A relative path in a spec without a file is relative to the working directory."""
    a, d = files
    monkeypatch.chdir(d)
    spec = parse_scene(spec_on("t.npy"))
    assert spec.volume.params["path"] == str((d / "t.npy").resolve())
    assert os.path.isabs(spec.volume.params["path"])


SMALL = ["--set", "cameras.width=8", "--set", "cameras.height=8", "--set", "cameras.n_train=2", "--set",
         "cameras.n_test=1", "--set", "render.spp_train=4", "--set", "render.spp_test=4", "--no-progress"]


def test_npy_and_vol_of_one_array_make_datasets_of_that_medium(files, tmp_path, capsys):
    """The issue's test: ``mitsnerf generate t.npy`` and ``t.vol``: the true sigma_t is the array times the scale."""
    from mitsnerf.cli import main

    a, d = files
    made = []
    for name in ("t.npy", "t.vol"):
        assert main(["generate", str(d / name), "--out", str(tmp_path / "data"), "--set",
                     "volume.sigma_t_scale=25", *SMALL]) == 0
        made.append(capsys.readouterr().out.strip())
    assert made[0] != made[1]  # two files, two datasets (their bytes differ)
    for root in made:
        sigma_t = np.load(os.path.join(root, "volume", "sigma_t.npy"))
        np.testing.assert_array_equal(sigma_t, np.float32(25.0) * a)
    import json

    manifest = json.load(open(os.path.join(made[1], "manifest.json")))
    assert manifest["inputs"][str((d / "t.vol").resolve())]["field"] == "volume.params.path"


def test_editing_a_grid_reruns_its_scenes_bench_cells_alone(files, tmp_path):
    from mitsnerf.bench.config import parse_bench_config
    from mitsnerf.bench.runner import BenchOptions, plan_cells

    a, d = files
    spec = d / "mine.toml"
    spec.write_text("\n".join(_toml(spec_on("t.npy"))).replace('name = "cloud"', 'name = "mine"'))
    config = parse_bench_config({"name": "b", "scenes": [str(spec), "cloud"], "methods": [{"name": "ngp"}]})
    options = BenchOptions(data_root=tmp_path, results_root=tmp_path, code_version="v")
    before = {c.scene: c.config_hash for c in plan_cells(config, options)}
    np.save(d / "t.npy", 0.5 * a)
    after = {c.scene: c.config_hash for c in plan_cells(config, options)}
    assert before["cloud"] == after["cloud"] and before["mine"] != after["mine"]
