"""Tiny scene specs for the scene tests (8x8..24x24 images, a few spp, 16^3 grids)."""

from __future__ import annotations

import copy

import pytest

from mitsnerf.scene.spec import parse_scene

TINY = {
    "name": "tiny",
    "description": "a 16^3 cloud, 8x8 views",
    "volume": {"family": "cloud", "resolution": 16, "seed": 1, "sigma_t_scale": 30.0, "params": {"albedo": [0.8, 0.8, 0.8]}},
    "lights": [
        {"type": "constant", "radiance": [0.5, 0.55, 0.6]},
        {"type": "directional", "direction": [-0.4, -0.8, -0.45], "irradiance": [4.0, 3.8, 3.5]},
    ],
    "cameras": {"rig": "sphere", "n_train": 3, "n_test": 2, "width": 8, "height": 8, "fov": 40.0, "radius": 2.2, "seed": 0},
    "render": {"spp_train": 4, "spp_test": 8, "max_depth": -1, "seed": 0, "noise_floor": True},
}


@pytest.fixture
def tiny_dict() -> dict:
    """A fresh, mutable copy of the tiny spec's plain data."""
    return copy.deepcopy(TINY)


@pytest.fixture
def tiny_spec():
    return parse_scene(copy.deepcopy(TINY), "tiny.toml")
