"""EXR and PNG files: exact float round trips, sRGB previews, and one-line errors for bad files."""

import mitsnerf  # noqa: F401

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from mitsnerf.data.images import read_exr, read_image, read_png, write_exr, write_png
from mitsnerf.errors import DatasetError
from mitsnerf.math.color import linear_to_srgb, srgb_to_linear


def _random_image(c, h=5, w=7, seed=0, scale=3.0):
    return (np.random.default_rng(seed).random((h, w, c)) * scale).astype(np.float32)


def _raw_exr(path, channels):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


@pytest.mark.parametrize("c", [3, 4])
def test_exr_round_trip_is_exact(tmp_path, c):
    img = _random_image(c)
    img[0, 0, 0] = 1e-30  # denormal-ish and large values survive
    img[1, 1, 1] = 6.5e4
    write_exr(tmp_path / "a.exr", img)
    back = read_exr(tmp_path / "a.exr")
    assert back.dtype == np.float32 and back.shape == img.shape
    assert np.array_equal(back, img)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr"]


def test_exr_header_float_zip_rgba(tmp_path):
    write_exr(tmp_path / "a.exr", _random_image(4))
    with OpenEXR.File(str(tmp_path / "a.exr"), separate_channels=True) as f:
        assert f.header()["compression"] == OpenEXR.ZIP_COMPRESSION
        assert sorted(f.channels()) == ["A", "B", "G", "R"]
        assert all(ch.type() == OpenEXR.FLOAT for ch in f.channels().values())


def test_exr_channels_come_back_in_rgba_order_and_half_is_accepted(tmp_path):
    img = _random_image(4, scale=1.0)
    _raw_exr(tmp_path / "h.exr", {
        "A": img[..., 3].copy(),
        "Z": np.zeros(img.shape[:2], np.float32),
        "B": img[..., 2].astype(np.float16),
        "R": img[..., 0].astype(np.float16),
        "G": img[..., 1].astype(np.float16),
    })
    back = read_exr(tmp_path / "h.exr")
    assert back.shape == img.shape and back.dtype == np.float32
    assert np.allclose(back, img, atol=1e-3)
    assert np.array_equal(back[..., 3], img[..., 3])


def test_png_preview_round_trip_within_one_level(tmp_path):
    img = _random_image(4, h=16, w=16, scale=1.0)
    write_png(tmp_path / "a.png", img)
    back = read_png(tmp_path / "a.png")
    assert back.shape == img.shape and back.dtype == np.float32
    assert back.min() >= 0.0 and back.max() <= 1.0
    # 8-bit sRGB rounds to the nearest level: within half a level of the exact encoding, ...
    assert np.max(np.abs(back[..., :3] - linear_to_srgb(img[..., :3]))) <= 0.5 / 255.0 + 1e-6
    # ... so after decoding within 1/255 of linear except near white, where srgb_to_linear's
    # slope reaches 2.4 / 1.055 = 2.27 (half a level -> 1.14 / 255)
    err = np.abs(srgb_to_linear(back[..., :3]) - img[..., :3])
    assert np.max(err[img[..., :3] < 0.75]) <= 1.0 / 255.0
    assert np.max(err) <= 1.14 / 255.0
    assert np.max(np.abs(back[..., 3] - img[..., 3])) <= 0.5 / 255.0  # alpha stays linear


def test_png_clips_and_handles_nan(tmp_path):
    img = np.array([[[-1.0, 2.0, np.nan]]], dtype=np.float32)
    write_png(tmp_path / "a.png", img)
    assert read_png(tmp_path / "a.png").tolist() == [[[0.0, 1.0, 0.0]]]


def test_png_grey_and_grey_alpha_expand_to_rgb(tmp_path):
    Image.fromarray(np.full((2, 3), 51, np.uint8), "L").save(tmp_path / "l.png")
    Image.fromarray(np.full((2, 3, 2), 102, np.uint8), "LA").save(tmp_path / "la.png")
    assert np.allclose(read_png(tmp_path / "l.png"), 0.2)
    la = read_png(tmp_path / "la.png")
    assert la.shape == (2, 3, 4) and np.allclose(la, 0.4)


def test_read_image_dispatches_on_suffix(tmp_path):
    img = _random_image(3, scale=1.0)
    write_exr(tmp_path / "a.EXR", img)
    write_png(tmp_path / "a.png", img)
    assert np.array_equal(read_image(tmp_path / "a.EXR"), img)
    assert read_image(tmp_path / "a.png").shape == img.shape
    with pytest.raises(DatasetError, match="unsupported image format '.jpg'"):
        read_image(tmp_path / "a.jpg")


@pytest.mark.parametrize("name", ["a.exr", "a.png"])
def test_missing_file(tmp_path, name):
    with pytest.raises(DatasetError) as info:
        read_image(tmp_path / name)
    assert info.value.where == str(tmp_path / name)
    assert str(info.value).endswith("file not found")


@pytest.mark.parametrize("name", ["a.exr", "a.png"])
@pytest.mark.parametrize("how", ["garbage", "truncated"])
def test_corrupt_file_gives_one_line(tmp_path, capfd, name, how):
    path = tmp_path / name
    (write_exr if name.endswith(".exr") else write_png)(path, _random_image(4, h=32, w=32, scale=1.0))
    data = path.read_bytes()
    path.write_bytes(b"not an image at all" if how == "garbage" else data[: len(data) - 40])
    with pytest.raises(DatasetError) as info:
        read_image(path)
    err = info.value
    assert err.where == str(path) and "\n" not in str(err)
    assert "not a readable" in err.message
    out, errtext = capfd.readouterr()
    assert out == "" and errtext == ""  # the library's own diagnostics are not printed


def test_exr_without_rgb_names_the_channel(tmp_path):
    _raw_exr(tmp_path / "z.exr", {"Z": np.zeros((2, 2), np.float32)})
    with pytest.raises(DatasetError) as info:
        read_exr(tmp_path / "z.exr")
    assert info.value.field == "channel R"
    assert "has: Z" in info.value.message


def test_exr_with_integer_channel_names_it(tmp_path):
    z = np.zeros((2, 2), np.float32)
    _raw_exr(tmp_path / "u.exr", {"R": z, "G": np.zeros((2, 2), np.uint32), "B": z})
    with pytest.raises(DatasetError) as info:
        read_exr(tmp_path / "u.exr")
    assert info.value.field == "channel G" and "UINT" in info.value.message


def test_writers_reject_wrong_shapes(tmp_path):
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        write_exr(tmp_path / "a.exr", np.zeros((4, 4, 2), np.float32))
    with pytest.raises(ValueError):
        write_png(tmp_path / "a.png", np.zeros((4, 4), np.float32))
    assert list(tmp_path.iterdir()) == []
