"""Tiny scene specs for the scene tests (8x8..24x24 images, a few spp, 16^3 grids)."""

from __future__ import annotations

import pytest

from mitsnerf.scene.spec import parse_scene

from ..conftest import TINY_SCENE, tiny_scene

TINY = TINY_SCENE  # the scene tests' name for it


@pytest.fixture
def tiny_dict() -> dict:
    """A fresh, mutable copy of the tiny spec's plain data."""
    return tiny_scene()


@pytest.fixture
def tiny_spec():
    return parse_scene(tiny_scene(), "tiny.toml")
