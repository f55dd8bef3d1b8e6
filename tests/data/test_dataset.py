"""Dataset directories: mitsnerf's own (EXR + manifest) and foreign NeRF-synthetic (sRGB PNG RGBA)."""

import mitsnerf  # noqa: F401

import json
import math

import numpy as np
import pytest
from PIL import Image

from mitsnerf.data.atomic import atomic_write_json
from mitsnerf.data.dataset import Dataset, Views, load_dataset
from mitsnerf.data.images import write_exr, write_png
from mitsnerf.data.transforms import write_transforms
from mitsnerf.errors import DatasetError
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.math.color import srgb_to_linear

W, H = 6, 4


def _cams(n, w=W, h=H):
    return [Camera.from_fov(look_at((2 * math.cos(k), 2 * math.sin(k), 0.3)), w, h, 40.0) for k in range(n)]


def _images(n, c, seed=0, w=W, h=H):
    return np.random.default_rng(seed).uniform(0.0, 1.0, size=(n, h, w, c)).astype(np.float32)


def _own_dataset(root, c=4, fmt="exr", splits=("train", "test"), n=2):
    """A dataset laid out as `mitsnerf generate` writes it; returns the images written per split."""
    root.mkdir()
    written = {}
    for s_i, split in enumerate(splits):
        (root / split).mkdir()
        imgs = _images(n, c, seed=s_i)
        names = [f"./{split}/r_{k:03d}" for k in range(n)]
        for name, img in zip(names, imgs):
            (write_exr if fmt == "exr" else write_png)(root / f"{name}.{fmt}", img)
        write_transforms(root / f"transforms_{split}.json", _cams(n), names)
        written[split] = imgs
    atomic_write_json(root / "manifest.json", {"background": {"type": "envmap", "file": "sky.exr"}})
    return written


def _foreign_dataset(root, rgba):
    """Original NeRF-synthetic layout: 8-bit sRGB RGBA PNGs, transforms with camera_angle_x only."""
    (root / "train").mkdir(parents=True)
    frames = []
    for k, img in enumerate(rgba):
        Image.fromarray(img, "RGBA").save(root / "train" / f"r_{k}.png")
        c2w = look_at((0, -4, k)).tolist()
        frames.append({"file_path": f"./train/r_{k}", "rotation": 0.012, "transform_matrix": c2w})
    (root / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.6911112070083618, "frames": frames}))


def _foreign_pixels():
    rgba = np.zeros((2, H, W, 4), dtype=np.uint8)
    rgba[..., :3] = np.arange(H * W * 3).reshape(H, W, 3) * 3 % 256
    rgba[:, 0, :, 3] = 0      # row 0 empty
    rgba[:, 1, :, 3] = 255    # row 1 opaque
    rgba[:, 2:, :, 3] = 128   # rows 2.. half covered
    return rgba


# --- loading ------------------------------------------------------------------------------------

def test_own_exr_dataset_rgba(tmp_path):
    written = _own_dataset(tmp_path / "ds")
    ds = load_dataset(tmp_path / "ds")
    assert ds.splits == ("test", "train")
    assert ds.background == {"type": "envmap", "file": "sky.exr"}
    v = ds.views("train")
    assert isinstance(v, Views) and len(v) == 2 and (v.height, v.width) == (H, W)
    assert v.images.dtype == np.float32 and v.images.shape == (2, H, W, 3)
    assert np.array_equal(v.images, written["train"][..., :3])  # used as rendered, not composited
    assert np.array_equal(v.alpha, written["train"][..., 3])
    assert v.names == ("r_000", "r_001") and v.pixel_center == 0.5
    assert np.allclose(v.cameras[1].c2w, _cams(2)[1].c2w)
    assert ds.views("train") is v  # cached
    assert not v.images.flags.writeable
    assert np.array_equal(ds.views("test").images, written["test"][..., :3])


def test_own_exr_dataset_rgb_has_no_alpha(tmp_path):
    written = _own_dataset(tmp_path / "ds", c=3, splits=("train",))
    v = load_dataset(tmp_path / "ds").views("train")
    assert v.alpha is None
    assert np.array_equal(v.images, written["train"])


def test_pixel_center_override(tmp_path):
    _own_dataset(tmp_path / "ds", splits=("train",))
    assert load_dataset(tmp_path / "ds", pixel_center=0.0).views("train").pixel_center == 0.0


@pytest.mark.parametrize("c", [3, 4])
def test_png_dataset_is_linearised_and_composited(tmp_path, c):
    _own_dataset(tmp_path / "ds", c=c, fmt="png", splits=("train",))
    stored = np.stack([np.asarray(Image.open(tmp_path / "ds" / "train" / f"r_{k:03d}.png")) for k in range(2)])
    stored = stored.astype(np.float64) / 255.0
    v = load_dataset(tmp_path / "ds", background=(0.0, 0.5, 2.0)).views("train")
    lin = srgb_to_linear(stored[..., :3])
    if c == 4:
        a = stored[..., 3:]
        expected = lin * a + np.array([0.0, 0.5, 2.0]) * (1 - a)
        assert np.allclose(v.alpha, stored[..., 3], atol=1e-7)
    else:
        expected = lin
        assert v.alpha is None
    assert np.allclose(v.images, expected, atol=1e-6)


def test_foreign_nerf_synthetic(tmp_path):
    rgba = _foreign_pixels()
    _foreign_dataset(tmp_path / "lego", rgba)
    ds = load_dataset(tmp_path / "lego")
    assert ds.manifest == {}
    assert ds.background == {"type": "constant", "radiance": [1.0, 1.0, 1.0]}
    v = ds.views("train")
    assert v.names == ("r_0", "r_1") and v.pixel_center == 0.5  # pixel centres, as Blender renders them
    img = v.images[0]
    srgb = rgba[0, ..., :3] / 255.0
    assert np.allclose(img[0], 1.0)                                 # transparent: white background
    assert np.allclose(img[1], srgb_to_linear(srgb[1]), atol=1e-6)  # opaque: sRGB decoded
    a = 128 / 255
    assert np.allclose(img[2:], srgb_to_linear(srgb[2:]) * a + (1 - a), atol=1e-6)
    assert np.allclose(v.alpha[:, 0], 0.0) and np.allclose(v.alpha[:, 1], 1.0)
    cam = v.cameras[0]
    fl = 0.5 * W / math.tan(0.5 * 0.6911112070083618)
    assert (cam.width, cam.height) == (W, H)
    assert cam.fl_x == pytest.approx(fl) and cam.fl_y == pytest.approx(fl)
    assert (cam.cx, cam.cy) == (W / 2, H / 2)


def test_foreign_options_linear_and_black_background(tmp_path):
    rgba = _foreign_pixels()
    _foreign_dataset(tmp_path / "lego", rgba)
    ds = load_dataset(tmp_path / "lego", background=0.0, color_space="linear", pixel_center=0.5)
    assert ds.background == {"type": "constant", "radiance": [0.0, 0.0, 0.0]}
    v = ds.views("train")
    stored = rgba[0] / 255.0
    assert np.allclose(v.images[0], stored[..., :3] * stored[..., 3:], atol=1e-6)
    assert v.pixel_center == 0.5


def test_name_collisions_fall_back_to_relative_paths(tmp_path):
    root = tmp_path / "ds"
    (root / "a").mkdir(parents=True)
    (root / "b").mkdir()
    imgs = _images(2, 3)
    write_exr(root / "a" / "r_0.exr", imgs[0])
    write_exr(root / "b" / "r_0.exr", imgs[1])
    write_transforms(root / "transforms_train.json", _cams(2), ["./a/r_0", "b/r_0.exr"])
    v = load_dataset(root).views("train")
    assert v.names == ("a/r_0", "b/r_0")
    assert np.array_equal(v.images, imgs)


def test_arguments_are_validated(tmp_path):
    _own_dataset(tmp_path / "ds", splits=("train",))
    with pytest.raises(ValueError, match="color_space"):
        load_dataset(tmp_path / "ds", color_space="rec709")
    with pytest.raises(ValueError, match="background"):
        load_dataset(tmp_path / "ds", background=(1.0, 1.0))


# --- errors -------------------------------------------------------------------------------------

def _views_error(root, split="train", **kw):
    with pytest.raises(DatasetError) as info:
        load_dataset(root, **kw).views(split)
    assert "\n" not in str(info.value)
    return info.value


def test_root_missing_or_not_a_directory(tmp_path):
    with pytest.raises(DatasetError, match="not found") as info:
        load_dataset(tmp_path / "nope")
    assert info.value.where == str(tmp_path / "nope")
    (tmp_path / "file").write_text("x")
    with pytest.raises(DatasetError, match="not a directory"):
        load_dataset(tmp_path / "file")


def test_no_transforms_files(tmp_path):
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "train").mkdir()
    with pytest.raises(DatasetError, match="no transforms_"):
        load_dataset(tmp_path / "ds")


def test_unknown_split(tmp_path):
    _own_dataset(tmp_path / "ds", splits=("train",))
    err = _views_error(tmp_path / "ds", "val")
    assert err.where == str(tmp_path / "ds" / "transforms_val.json") and "available: train" in err.message


def test_malformed_manifest(tmp_path):
    _own_dataset(tmp_path / "ds", splits=("train",))
    (tmp_path / "ds" / "manifest.json").write_text("{oops")
    with pytest.raises(DatasetError, match="invalid JSON") as info:
        load_dataset(tmp_path / "ds")
    assert info.value.where == str(tmp_path / "ds" / "manifest.json")
    (tmp_path / "ds" / "manifest.json").write_text('{"background": 3}')
    with pytest.raises(DatasetError) as info:
        load_dataset(tmp_path / "ds")
    assert info.value.field == "background"


@pytest.mark.parametrize("foreign", [False, True])
def test_image_missing_names_the_frame(tmp_path, foreign):
    root = tmp_path / "ds"
    if foreign:  # w/h come from the image itself, so the lookup fails while reading the cameras
        _foreign_dataset(root, _foreign_pixels())
        (root / "train" / "r_1.png").unlink()
    else:
        _own_dataset(root, splits=("train",))
        (root / "train" / "r_001.exr").unlink()
    err = _views_error(root)
    assert err.where == str(root / "transforms_train.json")
    assert err.field == "frames[1].file_path"
    assert "image not found" in err.message


def test_image_unreadable_names_the_image(tmp_path):
    root = tmp_path / "ds"
    _own_dataset(root, splits=("train",))
    (root / "train" / "r_001.exr").write_bytes(b"garbage")
    err = _views_error(root)
    assert err.where == str(root / "train" / "r_001.exr") and "not a readable" in err.message


def test_images_of_different_sizes(tmp_path):
    root = tmp_path / "ds"
    _foreign_dataset(root, _foreign_pixels())
    Image.fromarray(np.zeros((H + 1, W, 4), np.uint8), "RGBA").save(root / "train" / "r_1.png")
    err = _views_error(root)
    assert err.where == str(root / "train" / "r_1.png")
    assert f"{W}x{H + 1}" in err.message and "r_0.png" in err.message


def test_image_size_disagrees_with_camera(tmp_path):
    root = tmp_path / "ds"
    _own_dataset(root, splits=("train",))
    write_transforms(root / "transforms_train.json", _cams(2, w=W, h=H + 2), ["./train/r_000", "./train/r_001"])
    err = _views_error(root)
    assert err.where == str(root / "transforms_train.json") and err.field == "frames[0]"
    assert f"{W}x{H + 2}" in err.message and f"{W}x{H}" in err.message


def test_non_finite_pixels(tmp_path):
    root = tmp_path / "ds"
    _own_dataset(root, splits=("train",))
    img = _images(1, 4)[0]
    img[2, 3, 1] = np.nan
    img[3, 0, 0] = np.inf
    write_exr(root / "train" / "r_001.exr", img)
    err = _views_error(root)
    assert err.where == str(root / "train" / "r_001.exr")
    assert "2 non-finite" in err.message and "row 2, column 3" in err.message


def test_bad_camera_in_transforms_is_reported_with_its_field(tmp_path):
    root = tmp_path / "ds"
    _own_dataset(root, splits=("train",))
    doc = json.loads((root / "transforms_train.json").read_text())
    doc["frames"][1]["transform_matrix"][0][0] = 3.0
    (root / "transforms_train.json").write_text(json.dumps(doc))
    err = _views_error(root)
    assert err.field == "frames[1].transform_matrix"


def test_dataset_is_frozen(tmp_path):
    _own_dataset(tmp_path / "ds", splits=("train",))
    ds = load_dataset(tmp_path / "ds")
    assert isinstance(ds, Dataset)
    with pytest.raises(AttributeError):
        ds.root = tmp_path
