"""Shared fixtures: the Mitsuba variant, and tiny synthetic scenes that need no Mitsuba render."""

from __future__ import annotations

import numpy as np
import pytest

import mitsnerf  # noqa: F401  (configures libLLVM before drjit loads)
from mitsnerf import env


@pytest.fixture(scope="session", autouse=True)
def variant() -> str:
    """Every test runs on the variant the package would choose here (override: MITSNERF_VARIANT)."""
    return env.set_variant()


@pytest.fixture
def blob_grid() -> np.ndarray:
    """A 24^3 gaussian blob of peak sigma_t 20, off-centre in the scene box, indexed [z, y, x]."""
    r = 24
    c = (np.arange(r) + 0.5) / r - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    return (20.0 * np.exp(-((x - 0.1) ** 2 + y**2 + z**2) / 0.02)).astype(np.float32)
