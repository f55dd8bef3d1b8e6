"""mitsnerf.data.vol: round trips, agreement with Mitsuba's own gridvolume reader, malformed files."""

from __future__ import annotations

import struct

import numpy as np
import pytest

import mitsnerf  # noqa: F401  (sets up LLVM before drjit/mitsuba load)
from mitsnerf.data.vol import HEADER_SIZE, read_vol, write_vol
from mitsnerf.errors import DatasetError, DiskFullError


@pytest.fixture
def grid() -> np.ndarray:
    """A random (z, y, x, 3) grid with distinct extents per axis, so axis mix-ups show."""
    return np.random.default_rng(7).random((5, 6, 7, 3)).astype(np.float32)


def test_round_trip_keeps_values_shape_and_box(tmp_path, grid):
    path = tmp_path / "albedo.vol"
    write_vol(path, grid, bbox_min=(-1, -2, -3), bbox_max=(1, 2, 3.5))
    data, lo, hi = read_vol(path)
    assert data.dtype == np.float32 and data.shape == grid.shape
    np.testing.assert_array_equal(data, grid)
    assert lo == (-1.0, -2.0, -3.0) and hi == (1.0, 2.0, 3.5)
    assert path.stat().st_size == HEADER_SIZE + 4 * grid.size


def test_three_dimensional_input_gets_one_channel(tmp_path, grid):
    path = tmp_path / "density.vol"
    write_vol(path, grid[..., 0].astype(np.float64))
    data, lo, hi = read_vol(path)
    assert data.shape == grid.shape[:3] + (1,)
    np.testing.assert_array_equal(data[..., 0], grid[..., 0])
    assert (lo, hi) == ((-0.5,) * 3, (0.5,) * 3)


def test_header_layout_is_mitsubas(tmp_path, grid):
    path = tmp_path / "g.vol"
    write_vol(path, grid)
    raw = path.read_bytes()
    assert raw[:4] == b"VOL\x03"
    assert struct.unpack_from("<5i", raw, 4) == (1, 7, 6, 5, 3)  # encoding, xres, yres, zres, channels
    # x fastest, channels interleaved: the second value is channel 1 of voxel (0, 0, 0), the
    # fourth is channel 0 of voxel x = 1
    values = np.frombuffer(raw, "<f4", offset=HEADER_SIZE)
    assert values[1] == grid[0, 0, 0, 1] and values[3] == grid[0, 0, 1, 0]


@pytest.mark.parametrize("channels", [1, 3])
def test_mitsuba_gridvolume_reads_the_same_values(tmp_path, grid, channels):
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    values = grid[..., :channels]
    path = tmp_path / "g.vol"
    write_vol(path, values)
    vol = mi.load_dict({"type": "gridvolume", "filename": str(path), "filter_type": "nearest"})

    np.testing.assert_array_equal(np.array(mi.traverse(vol)["data"]), values)

    # evaluate at every voxel centre (gridvolume maps the grid onto [0, 1]^3)
    zres, yres, xres = values.shape[:3]
    k, j, i = (a.ravel() for a in np.meshgrid(*(np.arange(n) for n in (zres, yres, xres)), indexing="ij"))
    it = dr.zeros(mi.Interaction3f, len(i))
    it.p = mi.Point3f((i + 0.5) / xres, (j + 0.5) / yres, (k + 0.5) / zres)
    if channels == 1:
        got = np.array(vol.eval_1(it))[:, None]
    else:
        got = np.array(vol.eval(it)).T
    np.testing.assert_allclose(got, values.reshape(-1, channels), rtol=0, atol=1e-6)


def test_truncated_file_raises_dataset_error(tmp_path, grid):
    path = tmp_path / "g.vol"
    write_vol(path, grid)
    raw = path.read_bytes()
    path.write_bytes(raw[:-4])
    with pytest.raises(DatasetError) as e:
        read_vol(path)
    assert e.value.field == "data" and "truncated" in e.value.message and e.value.where == str(path)

    path.write_bytes(raw[:20])
    with pytest.raises(DatasetError, match="header: truncated"):
        read_vol(path)


@pytest.mark.parametrize(
    "offset, patch, field",
    [
        (0, b"VOX", "magic"),
        (3, bytes([2]), "version"),
        (4, struct.pack("<i", 3), "encoding"),
        (8, struct.pack("<i", 0), "resolution"),
        (20, struct.pack("<i", -1), "channels"),
        (24, struct.pack("<f", float("nan")), "bbox"),
    ],
)
def test_malformed_header_names_the_field(tmp_path, grid, offset, patch, field):
    path = tmp_path / "g.vol"
    write_vol(path, grid)
    raw = bytearray(path.read_bytes())
    raw[offset : offset + len(patch)] = patch
    path.write_bytes(bytes(raw))
    with pytest.raises(DatasetError) as e:
        read_vol(path)
    assert e.value.field == field


def test_trailing_bytes_and_missing_file_raise_dataset_error(tmp_path, grid):
    path = tmp_path / "g.vol"
    write_vol(path, grid)
    path.write_bytes(path.read_bytes() + b"\0\0\0\0")
    with pytest.raises(DatasetError, match="data: too long"):
        read_vol(path)
    with pytest.raises(DatasetError, match="no such file"):
        read_vol(tmp_path / "missing.vol")


def test_write_is_atomic_and_leaves_no_temporaries(tmp_path, grid, monkeypatch):
    path = tmp_path / "g.vol"
    write_vol(path, grid)
    write_vol(path, grid[:2])  # replaces the old file
    assert read_vol(path)[0].shape == (2, 6, 7, 3)
    with pytest.raises(ValueError, match="bbox_max"):
        write_vol(path, grid, bbox_min=(0, 0, 0), bbox_max=(1, 0, 1))
    with pytest.raises(ValueError, match="data"):
        write_vol(path, grid[0, 0])

    def disk_full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("mitsnerf.data.vol.os.fsync", disk_full)
    with pytest.raises(DiskFullError, match="g.vol: disk full .No space left on device.; the previous file is kept"):
        write_vol(path, grid)  # fails after the temporary was written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.vol"]
    assert read_vol(path)[0].shape == (2, 6, 7, 3)  # failed writes kept the old file
