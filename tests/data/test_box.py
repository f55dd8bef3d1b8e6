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


def test_train_defaults_to_ngp_with_a_bar_that_shows_the_remaining_time(tmp_path, monkeypatch):
    """``mitsnerf train DIR`` without --method: ngp, its budget in steps, a tqdm bar with elapsed<remaining
    (on a terminal: a log gets no bar, tests/cli/test_progress.py)."""
    import io
    import re
    import sys

    from mitsnerf.train import TrainConfig

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    root = _foreign(tmp_path / "data")
    monkeypatch.setattr(sys, "stderr", Terminal())
    assert main(["train", str(root), "--out", str(tmp_path / "run"), "--steps", "3", "--batch-rays", "16"]) == 0
    err = sys.stderr.getvalue()
    assert re.search(r"train ngp: .*\b3/3 \[\d\d:\d\d<\d\d:\d\d", err), err[-300:]
    assert json.loads((tmp_path / "run" / "config.json").read_text())["method"] == "ngp"
    assert TrainConfig().steps == 3000  # the default budget: a few minutes of ngp on a 2-core CPU


def test_train_on_foreign_data_says_its_near_far_rule_beside_the_box(tmp_path, capsys):
    """Foreign data's readers often fix near/far (2 and 6 for NeRF-synthetic); train says it has none:
    each ray's box entry and exit, and the range that gives over the train views."""
    from mitsnerf.data.box import NEAR_FAR_RULE

    root = _foreign(tmp_path / "data", aabb=[[-1, -1, -1], [1, 1, 1]], radius=4.0)
    assert main(["train", str(root), "--out", str(tmp_path / "run"), "--steps", "1", "--batch-rays", "16"]) == 0
    lines = capsys.readouterr().out.splitlines()
    box = lines.index("mitsnerf: scene box [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]] (transforms_train.json: aabb)")
    near_far = lines[box + 1]
    assert near_far.startswith(f"mitsnerf: near/far: {NEAR_FAR_RULE}, no fixed near/far; over the train views t_n "), \
        near_far
    ranges = near_far.split("over the train views ")[1]
    t_n = [float(v) for v in ranges.split("t_n ")[1].split(",")[0].split("..")]
    t_f = [float(v) for v in ranges.split("t_f ")[1].split(";")[0].split("..")]
    assert ranges.endswith(" of 162 sampled rays miss the box")  # 9 x 9 points of each view; the box fills no view
    # cameras at (4 cos k, 4 sin k, 0.5), 4.03 from the centre of the cube [-1, 1]^3: no ray enters it before
    # 4.03 - sqrt(3) or leaves after 4.03 + sqrt(3); view 0's centre ray (to the origin) enters at 3.02, leaves at 5.04
    r = math.hypot(4.0, 0.5)
    assert r - math.sqrt(3) <= t_n[0] <= 3.02 <= t_n[1] < t_f[1] and t_f[0] <= 5.04 <= t_f[1] <= r + math.sqrt(3), \
        near_far


def test_mitsnerf_data_prints_no_near_far_line(tmp_path, capsys):
    """mitsnerf's own datasets are not foreign: the box line alone (their readers follow the manifest)."""
    from tests.cli.conftest import SPEC

    spec = tmp_path / "tiny.toml"
    spec.write_text(SPEC)
    assert main(["generate", str(spec), "--out", str(tmp_path / "data"), "--no-progress"]) == 0
    (dataset,) = (tmp_path / "data").iterdir()
    capsys.readouterr()
    assert main(["train", str(dataset), "--out", str(tmp_path / "run"), "--steps", "1", "--method", "nerf",
                 "--batch-rays", "16", "--set", "network.width=8", "--set", "network.depth=1"]) == 0
    out = capsys.readouterr().out
    assert "mitsnerf: scene box" in out and "near/far" not in out
