"""A user's own grid file reaches a dataset by three routes: ``mitsnerf generate FILE``, a spec naming the file,
and ``mitsnerf.api.generate``. Each takes the same overrides, and each refuses the same bad file with the same
one line (exit 2 on the command line, a SpecError from the API) before anything is written: an ``.npz`` of
several arrays without ``volume.params.array``, a header declaring more values than a grid may hold or more
bytes than the file has, a 0-d array, a symlink loop, a directory, an albedo grid of another shape."""

from __future__ import annotations

import json
import os
import struct
import zipfile
from pathlib import Path

import numpy as np
import numpy.lib.format as npformat
import pytest

from mitsnerf import api
from mitsnerf.cli import main
from mitsnerf.errors import SpecError
from mitsnerf.scene.spec import load_scene
from mitsnerf.volumes import generate_volume
from mitsnerf.volumes.grid import MAX_VALUES

#: Views of 8 x 8 pixels at 2 spp: enough to render every split.
TINY = {"cameras.width": 8, "cameras.height": 8, "cameras.n_train": 1, "cameras.n_test": 1,
        "render.spp_train": 2, "render.spp_test": 2}


def _flags(overrides: dict) -> list[str]:
    return [arg for k, v in overrides.items() for arg in ("--set", f"{k}={v if isinstance(v, str) else json.dumps(v)}")]


def write_spec(path: Path, grid: str, **params) -> Path:
    """A whole spec (the cloud scene's lights, cameras and render settings) whose medium is the ``grid`` file."""
    data = load_scene("cloud").to_dict()
    inline = ", ".join(f"{k} = {json.dumps(v)}" for k, v in {"path": grid, **params}.items())
    lines = ['name = "mine"', "[volume]", 'family = "grid"', "resolution = 8", "sigma_t_scale = 10.0",
             f"params = {{ {inline} }}"]
    for light in data["lights"]:
        lines += ["[[lights]]"] + [f"{k} = {json.dumps(v)}" for k, v in light.items()]
    for table in ("cameras", "render"):
        lines += [f"[{table}]"] + [f"{k} = {json.dumps(v)}" for k, v in data[table].items()]
    path.write_text("\n".join(lines) + "\n")
    return path


class Routes:
    """The three routes from a grid file to a dataset, each into its own output root."""

    def __init__(self, tmp: Path, capsys) -> None:
        self.tmp, self.capsys = tmp, capsys

    def cli(self, scene: Path, overrides: dict, out: str = "cli") -> tuple[int, str, str]:
        self.capsys.readouterr()
        rc = main(["generate", str(scene), "--out", str(self.tmp / out), "--no-progress", *_flags(overrides)])
        captured = self.capsys.readouterr()
        return rc, captured.out.strip(), captured.err.strip()

    def api(self, scene: Path, overrides: dict, out: str = "api") -> Path:
        return api.generate(scene, self.tmp / out, overrides=overrides)

    def refused(self, scene: Path, overrides: dict, says: str) -> str:
        """Assert both the command and the API refuse ``scene`` with one line containing ``says``, writing
        nothing; return the line."""
        rc, out, err = self.cli(scene, overrides)
        assert rc == 2 and out == "", err
        assert err.startswith("mitsnerf: error: ") and "\n" not in err and says in err, err
        with pytest.raises(SpecError) as info:
            self.api(scene, overrides)
        assert says in str(info.value) and "\n" not in str(info.value)
        assert str(info.value) in err
        for out_dir in ("cli", "api"):
            assert not (self.tmp / out_dir).exists() or not any((self.tmp / out_dir).iterdir()), out_dir
        return err


@pytest.fixture
def routes(tmp_path, capsys) -> Routes:
    return Routes(tmp_path, capsys)


def test_an_npz_of_several_arrays_takes_the_array_the_error_advises(tmp_path, routes):
    a = np.zeros((8, 8, 8), np.float32)
    a[2:6, 2:6, 2:6] = 0.5
    b = np.full((8, 8, 8), 0.25, np.float32)
    b[:, :, :4] = 0.75
    np.savez(tmp_path / "g.npz", a=a, b=b)
    grid = tmp_path / "g.npz"
    line = routes.refused(grid, TINY, "holds 2 arrays (a, b)")
    assert "--set volume.params.array=NAME" in line and "albedo_array" not in line
    pick = {**TINY, "volume.params.array": "b"}
    rc, made, err = routes.cli(grid, pick)
    assert rc == 0, err
    np.testing.assert_array_equal(np.load(Path(made) / "volume" / "sigma_t.npy"), np.float32(30.0) * b)
    assert routes.api(grid, pick, out="cli") == Path(made)  # the same spec: the same dataset
    spec = write_spec(tmp_path / "mine.toml", "g.npz")
    rc, from_spec, err = routes.cli(spec, pick, out="spec")
    assert rc == 0, err
    np.testing.assert_array_equal(np.load(Path(from_spec) / "volume" / "sigma_t.npy"), np.float32(10.0) * b)
    assert routes.api(spec, pick, out="spec") == Path(from_spec)


def test_the_albedo_npz_names_its_own_field(tmp_path):
    np.save(tmp_path / "d.npy", np.ones((4, 4, 4), np.float32))
    np.savez(tmp_path / "alb.npz", r=np.ones((4, 4, 4)), g=np.ones((4, 4, 4)))
    with pytest.raises(SpecError, match=r"alb.npz: holds 2 arrays \(r, g\); name one: --set "
                                         r"volume.params.albedo_array=NAME"):
        generate_volume("grid", 8, 0, {"path": str(tmp_path / "d.npy"), "albedo_path": str(tmp_path / "alb.npz")})


def _header_only(path: Path, shape: tuple[int, ...], data: bytes = b"\0" * 64) -> None:
    with open(path, "wb") as f:
        npformat.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False, "shape": shape})
        f.write(data)


def test_a_header_declaring_a_huge_grid_is_refused_before_reading(tmp_path, routes):
    _header_only(tmp_path / "huge.npy", (2000, 2000, 2000))
    line = routes.refused(tmp_path / "huge.npy", TINY, "declares (2000, 2000, 2000) float32: 8,000,000,000 values")
    assert f"{tmp_path / 'huge.npy'}: " in line and f"{MAX_VALUES:,}" in line
    routes.refused(write_spec(tmp_path / "huge.toml", "huge.npy"), TINY, "8,000,000,000 values")
    with zipfile.ZipFile(tmp_path / "huge.npz", "w") as z:  # an archive member's header, read without its data
        with z.open("rho.npy", "w") as member:
            npformat.write_array_header_1_0(member, {"descr": "<f8", "fortran_order": False, "shape": (4096,) * 3})
    routes.refused(tmp_path / "huge.npz", TINY, "declares (4096, 4096, 4096) float64")
    header = struct.pack("<3sBiiiii6f", b"VOL", 3, 1, 3000, 3000, 3000, 1, -0.5, -0.5, -0.5, 0.5, 0.5, 0.5)
    (tmp_path / "huge.vol").write_bytes(header)
    routes.refused(tmp_path / "huge.vol", TINY, "declares (3000, 3000, 3000) float32")


def test_a_header_declaring_more_bytes_than_the_file_holds_is_truncated(tmp_path, routes):
    _header_only(tmp_path / "cut.npy", (16, 16, 16), b"\0" * 100)
    routes.refused(tmp_path / "cut.npy", TINY, "truncated: the header declares (16, 16, 16) float32, 16,384 bytes; "
                                               "the file holds 100")


def test_a_0d_array_is_refused_alike_on_every_route(tmp_path, routes):
    np.save(tmp_path / "scalar.npy", np.float32(3.0))
    says = "scalar.npy: has 0 axes (), a density grid needs 3 ([z, y, x])"
    routes.refused(tmp_path / "scalar.npy", TINY, says)
    routes.refused(write_spec(tmp_path / "scalar.toml", "scalar.npy"), TINY, says)


@pytest.mark.parametrize(("make", "says"), [
    (lambda p: (os.symlink(p.with_name("b.npy"), p), os.symlink(p, p.with_name("b.npy"))), "a symlink loop"),
    (lambda p: p.mkdir(), "is a directory, not a grid file"),
    (lambda p: os.symlink(p.with_name("gone.npy"), p), "a broken symlink (to "),
    (lambda p: None, "no such grid file"),
], ids=["loop", "directory", "broken-link", "missing"])
def test_a_path_that_is_no_file_is_one_line(tmp_path, routes, make, says):
    grid = tmp_path / "a.npy"
    make(grid)
    line = routes.refused(grid, TINY, says)
    assert f"{grid}: {says}" in line
    routes.refused(write_spec(tmp_path / "s.toml", "a.npy"), TINY, f"{grid}: {says}")


def test_an_albedo_grid_of_another_shape_is_refused_naming_both(tmp_path, routes):
    np.save(tmp_path / "d.npy", np.ones((8, 8, 8), np.float32))
    np.save(tmp_path / "alb.npy", np.full((4, 8, 8, 3), 0.5, np.float32))
    says = (f"{tmp_path / 'alb.npy'}: the albedo grid's shape (4, 8, 8) differs from the density grid "
            f"{tmp_path / 'd.npy'}'s (8, 8, 8)")
    with pytest.raises(SpecError) as info:
        generate_volume("grid", 8, 0, {"path": str(tmp_path / "d.npy"), "albedo_path": str(tmp_path / "alb.npy")})
    assert str(info.value).startswith(says)
    routes.refused(tmp_path / "d.npy", {**TINY, "volume.params.albedo_path": "alb.npy"}, says)
    routes.refused(write_spec(tmp_path / "s.toml", "d.npy", albedo_path="alb.npy"), TINY, says)
    for grey in ((8, 8, 8), (8, 8, 8, 1)):  # the same [z, y, x]: taken, grey with or without its channel axis
        np.save(tmp_path / "grey.npy", np.full(grey, 0.5, np.float32))
        g = generate_volume("grid", 8, 0, {"path": str(tmp_path / "d.npy"), "albedo_path": str(tmp_path / "grey.npy")})
        np.testing.assert_array_equal(g.albedo, np.float32(0.5))


def test_a_uniform_cube_of_one_voxel_renders(tmp_path, routes):
    """A 1x1x1 grid fills the box: camera rays that cross it have T down to 1e-14, and the composed image's
    round-off (about 1e-15 below 0) must not be taken for negative radiance."""
    np.save(tmp_path / "one.npy", np.ones((1, 1, 1), np.float32))
    rc, made, err = routes.cli(tmp_path / "one.npy", TINY)
    assert rc == 0, err
    assert np.load(Path(made) / "volume" / "sigma_t.npy").min() == np.float32(30.0)
    assert routes.api(tmp_path / "one.npy", TINY, out="cli") == Path(made)


README = Path(__file__).resolve().parents[2] / "README.md"


def readme_grid_spec() -> str:
    """The spec the README shows for a grid of one's own (the toml block of "Your own volume")."""
    import re

    section = README.read_text().split("**Your own volume.**", 1)[1].split("\n**", 1)[0]
    blocks = re.findall(r"```toml\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "README's 'Your own volume' has no toml block, or several"
    return blocks[0]


def test_the_readmes_grid_spec_works_as_written(tmp_path, routes):
    """The README's block, written beside a grid named as it names it, renders (at a tiny size) that grid."""
    import tomllib

    text = readme_grid_spec()
    data = tomllib.loads(text)
    grid = np.zeros((8, 8, 8), np.float32)
    grid[2:6, 1:7, 3:5] = 0.75
    np.save(tmp_path / data["volume"]["params"]["path"], grid)
    spec = tmp_path / "mine.toml"
    spec.write_text(text)
    rc, made, err = routes.cli(spec, {**TINY, "volume.resolution": 8})
    assert rc == 0, err
    scale = data["volume"]["sigma_t_scale"]
    np.testing.assert_array_equal(np.load(Path(made) / "volume" / "sigma_t.npy"), np.float32(scale) * grid)
    assert Path(made).name.startswith(data["name"] + "-")
