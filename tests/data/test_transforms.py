"""transforms_*.json: round trips, original NeRF-synthetic files, precedence rules, errors naming fields."""

import mitsnerf  # noqa: F401

import json
import math

import numpy as np
import pytest

from mitsnerf.data.transforms import read_transforms, write_transforms
from mitsnerf.errors import DatasetError
from mitsnerf.math.camera import Camera, look_at


def _cameras(n=3, w=8, h=6):
    cams = []
    for k in range(n):
        phi = 2 * math.pi * k / n
        c2w = look_at((2 * math.cos(phi), 2 * math.sin(phi), 0.5))
        cams.append(Camera(c2w, w, h, 7.0 + k, 7.5 + k, 4.25, 2.75))
    return cams


def _write_raw(path, doc):
    path.write_text(json.dumps(doc))
    return path


def _foreign_doc(n=2):
    """Original NeRF-synthetic layout: camera_angle_x and frames only."""
    frames = [{"file_path": f"./train/r_{k:03d}", "rotation": 0.0, "transform_matrix": look_at((0, -3, k)).tolist()}
              for k in range(n)]
    return {"camera_angle_x": 0.6911112070083618, "frames": frames}


def test_round_trip(tmp_path):
    cams = _cameras()
    names = [f"./train/r_{k:03d}" for k in range(3)]
    path = tmp_path / "transforms_train.json"
    write_transforms(path, cams, names, aabb_scale=2, extra={"scene": "cloud"})
    doc = json.loads(path.read_text())
    assert list(doc)[:10] == ["camera_angle_x", "fl_x", "fl_y", "cx", "cy", "w", "h", "aabb_scale",
                              "pixel_center", "camera_convention"]
    assert doc["camera_convention"] == "opengl" and doc["pixel_center"] == 0.5 and doc["scene"] == "cloud"
    assert list(doc)[-1] == "frames"
    assert set(doc["frames"][1]) == {"file_path", "transform_matrix", "camera_angle_x", "w", "h",
                                     "fl_x", "fl_y", "cx", "cy"}
    paths, back, meta = read_transforms(path)
    assert paths == names
    assert meta["pixel_center"] == 0.5 and meta["aabb_scale"] == 2 and "frames" not in meta
    for a, b in zip(cams, back):
        assert np.array_equal(a.c2w, b.c2w)
        assert (a.width, a.height, a.fl_x, a.fl_y, a.cx, a.cy) == (b.width, b.height, b.fl_x, b.fl_y, b.cx, b.cy)


def test_write_rejects_mismatched_inputs_and_reserved_extra(tmp_path):
    with pytest.raises(ValueError, match="2 file paths"):
        write_transforms(tmp_path / "t.json", _cameras(3), ["a", "b"])
    with pytest.raises(ValueError, match="frames"):
        write_transforms(tmp_path / "t.json", _cameras(1), ["a"], extra={"frames": []})
    assert list(tmp_path.iterdir()) == []


def test_original_nerf_synthetic_uses_image_size_and_no_pixel_offset(tmp_path):
    path = _write_raw(tmp_path / "transforms_train.json", _foreign_doc())
    asked = []

    def size_of(fp):
        asked.append(fp)
        return 800, 600

    paths, cams, meta = read_transforms(path, image_size_of=size_of)
    assert asked == paths == ["./train/r_000", "./train/r_001"]
    assert meta["pixel_center"] == 0.5  # pixel centres, where Blender sampled them
    fl = 0.5 * 800 / math.tan(0.5 * 0.6911112070083618)
    for cam in cams:
        assert (cam.width, cam.height) == (800, 600)
        assert cam.fl_x == pytest.approx(fl) and cam.fl_y == pytest.approx(fl)  # square pixels
        assert (cam.cx, cam.cy) == (400.0, 300.0)
    assert read_transforms(path, 0.5, image_size_of=size_of)[2]["pixel_center"] == 0.5


def test_original_without_size_resolver_names_the_field(tmp_path):
    path = _write_raw(tmp_path / "t.json", _foreign_doc())
    with pytest.raises(DatasetError) as info:
        read_transforms(path)
    assert info.value.field == "frames[0].w"


def test_missing_image_from_the_size_resolver_names_file_path(tmp_path):
    path = _write_raw(tmp_path / "t.json", _foreign_doc())

    def size_of(fp):
        raise FileNotFoundError(f"image not found: {fp}.png")

    with pytest.raises(DatasetError) as info:
        read_transforms(path, image_size_of=size_of)
    assert info.value.field == "frames[0].file_path" and "r_000.png" in info.value.message


def test_pixel_center_rules(tmp_path):
    doc = _foreign_doc()
    doc.update(w=4, h=4)
    assert read_transforms(_write_raw(tmp_path / "a.json", doc))[2]["pixel_center"] == 0.5
    assert read_transforms(tmp_path / "a.json", pixel_center=0.0)[2]["pixel_center"] == 0.0  # the original loader
    doc["pixel_center"] = 0.25
    assert read_transforms(_write_raw(tmp_path / "c.json", doc))[2]["pixel_center"] == 0.25
    assert read_transforms(tmp_path / "c.json", pixel_center=0.0)[2]["pixel_center"] == 0.0


def test_frame_intrinsics_override_top_level(tmp_path):
    doc = _foreign_doc(2)
    doc.update(w=10, h=8, fl_x=12.0, cx=5.0)
    doc["frames"][1].update(w=20, h=16, camera_angle_x=math.pi / 2, fl_y=3.0, cy=7.0)
    _, (c0, c1), _ = read_transforms(_write_raw(tmp_path / "t.json", doc))
    assert (c0.width, c0.height, c0.fl_x, c0.fl_y, c0.cx, c0.cy) == (10, 8, 12.0, 12.0, 5.0, 4.0)
    # the frame's camera_angle_x wins over the top-level fl_x
    assert (c1.width, c1.height, c1.fl_y, c1.cx, c1.cy) == (20, 16, 3.0, 5.0, 7.0)
    assert c1.fl_x == pytest.approx(10.0)


def _error(tmp_path, doc_or_text, **kw):
    path = tmp_path / "transforms_train.json"
    path.write_text(doc_or_text if isinstance(doc_or_text, str) else json.dumps(doc_or_text))
    with pytest.raises(DatasetError) as info:
        read_transforms(path, **kw)
    assert info.value.where == str(path)
    assert "\n" not in str(info.value)
    return info.value


def _sized_doc(n=4):
    doc = _foreign_doc(n)
    doc.update(w=8, h=8)
    return doc


def test_malformed_json(tmp_path):
    err = _error(tmp_path, '{"frames": [')
    assert err.field is None and "invalid JSON" in err.message and "line 1" in err.message
    err = _error(tmp_path, '{"camera_angle_x": NaN, "frames": []}')
    assert err.field == "camera_angle_x" and "NaN" in err.message
    err = _error(tmp_path, '{"frames": [{"file_path": "a", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, -Infinity]]}]}')
    assert err.field == "frames[0].transform_matrix[1][3]" and "-Infinity" in err.message
    err = _error(tmp_path, "[1, 2]")
    assert "JSON object" in err.message


def test_missing_file(tmp_path):
    with pytest.raises(DatasetError, match="file not found"):
        read_transforms(tmp_path / "nope.json")


def test_missing_or_empty_frames(tmp_path):
    assert _error(tmp_path, {"camera_angle_x": 0.5}).field == "frames"
    assert _error(tmp_path, {"camera_angle_x": 0.5, "frames": []}).field == "frames"


@pytest.mark.parametrize(
    "bad, message",
    [
        (None, "missing"),
        ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "4x4"),
        ([[1, 0, 0, 0]] * 4, "last row"),
        ("identity", "4x4"),
        ((2 * np.eye(4) + np.diag([0, 0, 0, -1])).tolist(), "orthonormal"),
    ],
)
def test_bad_transform_matrix_names_the_frame(tmp_path, bad, message):
    doc = _sized_doc()
    if bad is None:
        del doc["frames"][3]["transform_matrix"]
    else:
        doc["frames"][3]["transform_matrix"] = bad
    err = _error(tmp_path, doc)
    assert err.field == "frames[3].transform_matrix"
    assert message in err.message


def test_missing_file_path(tmp_path):
    doc = _sized_doc()
    del doc["frames"][2]["file_path"]
    assert _error(tmp_path, doc).field == "frames[2].file_path"


@pytest.mark.parametrize(
    "where, key, value, field",
    [
        ("frame", "fl_x", 0.0, "frames[1].fl_x"),
        ("frame", "fl_y", -2.0, "frames[1].fl_y"),
        ("top", "fl_x", -1.0, "fl_x"),
        ("top", "camera_angle_x", 4.0, "camera_angle_x"),
        ("frame", "w", 0, "frames[1].w"),
        ("frame", "h", 7.5, "frames[1].h"),
        ("frame", "cx", "centre", "frames[1].cx"),
        ("top", "k1", 0.01, "k1"),
    ],
)
def test_bad_intrinsics_name_the_field(tmp_path, where, key, value, field):
    doc = _sized_doc()
    (doc["frames"][1] if where == "frame" else doc)[key] = value
    err = _error(tmp_path, doc)
    assert err.field == field


def test_no_focal_length(tmp_path):
    doc = _sized_doc()
    del doc["camera_angle_x"]
    assert _error(tmp_path, doc).field == "frames[0].fl_x"
