"""The reverse direction: mitsnerf trains on datasets in the field's own layouts.

From one tiny dataset generated at the NeRF-synthetic scale (box ``[-1.5, 1.5]^3``, cameras at
radius 4), its medium-alone view is rewritten (a) in the original NeRF-synthetic layout
(``transforms_{train,val,test}.json`` with ``camera_angle_x`` only, extensionless ``file_path``,
RGBA PNGs) and (b) in instant-ngp's single-file layout (one ``transforms.json`` with
``aabb_scale``/``scale``/``offset`` and file paths with extensions). ``mitsnerf train`` must find
the right box in each without being told, and fit the data far better than its background alone.
"""

from __future__ import annotations

import copy
import json
import shutil

import numpy as np
import pytest

from mitsnerf import generate as gen
from mitsnerf.cli import main
from mitsnerf.data.dataset import holdout_frames, load_dataset
from mitsnerf.data.images import read_png
from mitsnerf.math.box import Box
from mitsnerf.math.color import srgb_to_linear
from mitsnerf.scene.spec import nerf_synthetic_overrides, parse_scene

TINY_NS = {
    "name": "tinyns",
    "volume": {"family": "cloud", "resolution": 16, "seed": 1, "sigma_t_scale": 30.0, "params": {"albedo": [0.8, 0.8, 0.8]}},
    "lights": [{"type": "constant", "radiance": [0.5, 0.55, 0.6]},
               {"type": "directional", "direction": [-0.4, -0.8, -0.45], "irradiance": [4.0, 3.8, 3.5]}],
    "cameras": {"rig": "sphere", "n_train": 14, "n_test": 2, "width": 16, "height": 16, "fov": 40.0, "radius": 2.2},
    "render": {"spp_train": 32, "spp_test": 64, "noise_floor": False},
}
TRAIN = ["--method", "voxel", "--steps", "150", "--batch-rays", "512", "--footprint", "1",
         "--set", "n_samples=32"]


@pytest.fixture(scope="module")
def medium_view(tmp_path_factory):
    spec = parse_scene(copy.deepcopy(TINY_NS), "tinyns.toml").with_overrides(nerf_synthetic_overrides())
    path = gen.generate_dataset(spec, tmp_path_factory.mktemp("data"), progress=False)
    return path / gen.MEDIUM_DIR


def _frames(view, split):
    return json.loads((view / f"transforms_{split}.json").read_text())


def nerf_synthetic_layout(view, out):
    """The original layout: only camera_angle_x and frames (file_path, rotation, transform_matrix); PNGs only."""
    for split in ("train", "val", "test"):
        doc = _frames(view, split)
        source = "test" if split == "val" else split
        (out / source).mkdir(parents=True, exist_ok=True)
        frames = []
        for frame in doc["frames"]:
            shutil.copy(view / (frame["file_path"] + ".png"), out / (frame["file_path"] + ".png"))
            frames.append({"file_path": frame["file_path"], "rotation": 0.012566370614359171,
                           "transform_matrix": frame["transform_matrix"]})
        (out / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": doc["camera_angle_x"],
                                                                  "frames": frames}))
    return out


def ngp_layout(view, out):
    """instant-ngp's one transforms.json: test frames where the hold-out rule puts them, paths with
    extensions, intrinsics at the top, and aabb_scale 1 with scale 1/3, offset 0.5 (the box [-1.5, 1.5]^3)."""
    train, test = _frames(view, "train"), _frames(view, "test")
    n = len(train["frames"]) + len(test["frames"])
    slots = iter(test["frames"]), iter(train["frames"])
    (out / "images").mkdir(parents=True)
    frames = []
    for i in range(n):
        frame = next(slots[0] if i in holdout_frames("test", n) else slots[1])
        name = f"images/{len(frames):04d}.png"
        shutil.copy(view / (frame["file_path"] + ".png"), out / name)
        frames.append({"file_path": name, "transform_matrix": frame["transform_matrix"]})
    top = {k: train[k] for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")}
    (out / "transforms.json").write_text(json.dumps({**top, "aabb_scale": 1, "scale": 1 / 3,
                                                     "offset": [0.5, 0.5, 0.5], "frames": frames}))
    return out


def _white_psnr(root):
    """PSNR of a plain white image (the background alone) against the test views composited on white."""
    imgs = load_dataset(root).views("test").images
    return float(np.mean([10 * np.log10(1 / np.mean((1 - np.clip(v, 0, 1)) ** 2)) for v in imgs]))


@pytest.mark.parametrize("layout, source, extra", [
    (nerf_synthetic_layout, "default for NeRF-synthetic data", []),  # pixel centres by default, as rendered
    (ngp_layout, "transforms.json: instant-ngp aabb_scale/scale/offset", []),
])
def test_train_on_foreign_layout(medium_view, tmp_path, capsys, layout, source, extra):
    root = layout(medium_view, tmp_path / "data")
    ds = load_dataset(root)
    assert ds.views("train").pixel_center == 0.5
    assert ds.box_source.startswith(source)
    assert np.allclose(ds.box.to_list(), Box.cube(1.5).to_list(), atol=1e-6)
    assert len(ds.views("test")) == 2 and len(ds.views("train")) == 14
    assert main(["train", str(root), "--out", str(tmp_path / "run"), *TRAIN, *extra]) == 0
    line = next(l for l in capsys.readouterr().out.splitlines() if l.startswith("mitsnerf: scene box"))
    assert line.startswith("mitsnerf: scene box [[-1.5") and f"]] ({source}" in line  # said, and right
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    # measured: 28.4 dB against 10.3 dB for the white background alone
    assert metrics["psnr_test"] > _white_psnr(root) + 10, (metrics["psnr_test"], _white_psnr(root))


def test_ngp_layout_uses_pixel_centres_and_the_holdout_rule(medium_view, tmp_path):
    root = ngp_layout(medium_view, tmp_path / "ngp")
    ds = load_dataset(root)
    assert ds.splits == ("test", "train") and ds.single_file
    test = ds.views("test")
    assert test.pixel_center == 0.5 and test.names == ("0000", "0008")
    first = read_png(root / "images" / "0000.png")
    expected = srgb_to_linear(first[..., :3]) * first[..., 3:] + (1 - first[..., 3:])
    assert np.allclose(test.images[0], expected, atol=1e-6)
    assert np.allclose(test.cameras[1].c2w, _frames(medium_view, "test")["frames"][1]["transform_matrix"])
