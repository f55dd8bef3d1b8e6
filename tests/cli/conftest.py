"""The command line, driven as a user would: a tiny spec, its dataset and a finished nerf run, made
once and shared read-only (``world``); a case that changes something copies it first."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from mitsnerf.cli import main

SPEC = """\
name = "tiny"
[volume]
family = "cloud"
resolution = 16
seed = 1
sigma_t_scale = 30.0
params = { albedo = [0.8, 0.8, 0.8] }
[[lights]]
type = "constant"
radiance = [0.5, 0.55, 0.6]
[cameras]
rig = "sphere"
n_train = 3
n_test = 2
width = 8
height = 8
fov = 40.0
radius = 2.2
[render]
spp_train = 4
spp_test = 8
"""
#: A nerf small enough to train a few steps in well under a second.
NERF = ("--method", "nerf", "--set", "network.width=8", "--set", "network.depth=1", "--set", "network.head_width=8",
        "--set", "network.features=4", "--set", "n_samples=8", "--batch-rays", "32")


@pytest.fixture(scope="session")
def world(tmp_path_factory):
    """``spec`` (tiny.toml), ``dataset`` (generated from it), ``run`` (2 steps of the tiny nerf),
    ``nerf`` (its flags) and ``repo`` (this checkout, for child processes)."""
    root = tmp_path_factory.mktemp("world")
    spec = root / "tiny.toml"
    spec.write_text(SPEC)
    assert main(["generate", str(spec), "--out", str(root / "data")]) == 0
    (dataset,) = [p for p in (root / "data").iterdir() if p.name.startswith("tiny-")]
    run = root / "run"
    assert main(["train", str(dataset), "--out", str(run), "--steps", "2", *NERF]) == 0
    return SimpleNamespace(root=root, spec=spec, dataset=dataset, run=run, nerf=NERF,
                           repo=Path(__file__).resolve().parents[2])
