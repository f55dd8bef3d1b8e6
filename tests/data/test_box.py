"""Where a dataset's box comes from, and the box errors a user can make (one line, exit 2, nothing written)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mitsnerf.cli import main
from mitsnerf.data.box import NERF_SYNTHETIC_BOX, ngp_box, resolve_box
from mitsnerf.data.dataset import load_dataset
from mitsnerf.data.images import write_png
from mitsnerf.data.transforms import write_transforms
from mitsnerf.errors import DatasetError
from mitsnerf.math.box import UNIT_BOX, Box
from mitsnerf.math.camera import Camera, look_at

T, M = "transforms_train.json", "manifest.json"


@pytest.mark.parametrize("explicit, transforms, manifest, box, source", [
    (Box.cube(2.0), {"aabb": [[-1] * 3, [1] * 3]}, {"box": [[0] * 3, [1] * 3]}, Box.cube(2.0), "given explicitly"),
    (None, {"aabb": [[-1] * 3, [1] * 3], "aabb_scale": 4}, {"box": [[0] * 3, [1] * 3]}, Box.cube(1.0), f"{T}: aabb"),
    (None, {"aabb_scale": 4}, {"box": [[0] * 3, [1] * 3]}, Box((0, 0, 0), (1, 1, 1)), "manifest.json: box"),
    (None, {"aabb_scale": 4}, {"spec": {}}, UNIT_BOX, "manifest.json: spec"),
    (None, {"aabb_scale": 1, "scale": 0.5, "offset": [0.5, 0.5, 0.5]}, None, Box.cube(1.0), f"{T}: instant-ngp"),
    (None, {}, None, NERF_SYNTHETIC_BOX, "default for NeRF-synthetic data"),
])
def test_box_precedence(tmp_path, explicit, transforms, manifest, box, source):
    resolved = resolve_box(explicit, transforms, tmp_path / T, manifest, tmp_path / M)
    assert np.allclose(resolved.box.to_list(), box.to_list()) and resolved.source.startswith(source)


def test_ngp_box_follows_scale_and_offset():
    """instant-ngp renders q = p * scale + offset in [0.5 - a/2, 0.5 + a/2]^3."""
    box = ngp_box({"aabb_scale": 2, "scale": 0.25, "offset": [0.5, 0.25, 0.75]})
    assert np.allclose(np.asarray(box.lo) * 0.25 + [0.5, 0.25, 0.75], -0.5)
    assert np.allclose(np.asarray(box.hi) * 0.25 + [0.5, 0.25, 0.75], 1.5)


def _foreign(root, aabb=None, radius=4.0):
    """Two 4x4 views from ``radius``, RGBA PNGs, an optional aabb key."""
    cams = [Camera.from_fov(look_at((radius * math.cos(k), radius * math.sin(k), 0.5)), 4, 4, 40.0) for k in range(2)]
    for split in ("train", "test"):
        (root / split).mkdir(parents=True)
        for k in range(2):
            write_png(root / split / f"r_{k}.png", np.full((4, 4, 4), 0.5))
        write_transforms(root / f"transforms_{split}.json", cams, [f"./{split}/r_{k}" for k in range(2)],
                         extra={} if aabb is None else {"aabb": aabb})
    return root


def _train(capsys, root, out, *extra):
    status = main(["train", str(root), "--out", str(out), "--steps", "2", *extra])
    captured = capsys.readouterr()
    return status, captured.err


@pytest.mark.parametrize("aabb, extra, message", [
    ([[-5, -5, -5], [5, 5, 5]], [], "transforms_train.json: frames[*].transform_matrix: every camera lies inside the "
                                    "scene box"),
    ([[1, -1, -1], [-1, 1, 1]], [], "transforms_train.json: aabb: min must be < max on every axis"),
    (None, ["--box", "-1", "-1", "-1", "-1", "1", "1"], "--box: min must be < max on every axis"),
    (None, ["--box", "-9", "-9", "-9", "9", "9", "9"], "every camera lies inside the scene box [[-9.0"),
])
def test_bad_box_one_line_exit_2_nothing_written(tmp_path, capsys, aabb, extra, message):
    root = _foreign(tmp_path / "data", aabb)
    status, err = _train(capsys, root, tmp_path / "run", *extra)
    assert status == 2 and err.count("\n") == 1 and err.startswith("mitsnerf: error: ") and message in err, err
    assert not (tmp_path / "run").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]


def test_cameras_inside_the_box_fail_when_the_split_loads(tmp_path):
    ds = load_dataset(_foreign(tmp_path / "d", [[-5, -5, -5], [5, 5, 5]]))
    with pytest.raises(DatasetError) as e:
        ds.views("train")
    assert e.value.field == "frames[*].transform_matrix" and e.value.where.endswith(T)
    assert json.loads((tmp_path / "d" / T).read_text())["aabb"] == [[-5] * 3, [5] * 3]


def test_train_defaults_to_ngp_with_a_bar_that_shows_the_remaining_time(tmp_path, capsys):
    """``mitsnerf train DIR`` without --method: ngp, its budget in steps, a tqdm bar with elapsed<remaining."""
    import re

    from mitsnerf.train import TrainConfig

    root = _foreign(tmp_path / "data")
    assert main(["train", str(root), "--out", str(tmp_path / "run"), "--steps", "3", "--batch-rays", "16"]) == 0
    err = capsys.readouterr().err
    assert re.search(r"train ngp: .*\b3/3 \[\d\d:\d\d<\d\d:\d\d", err), err[-300:]
    assert json.loads((tmp_path / "run" / "config.json").read_text())["method"] == "ngp"
    assert TrainConfig().steps == 3000  # the default budget: a few minutes of ngp on a 2-core CPU
