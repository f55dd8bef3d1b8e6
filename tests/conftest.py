"""Shared fixtures: the Mitsuba variant, and tiny synthetic scenes that need no Mitsuba render."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

import mitsnerf  # (configures libLLVM before drjit loads)
from mitsnerf import env


@pytest.fixture(scope="session", autouse=True)
def variant() -> str:
    """Every test runs on the variant the package would choose here (override: MITSNERF_VARIANT)."""
    return env.set_variant()


@pytest.fixture(scope="session")
def checkout_files() -> tuple[Path, list[str]]:
    """The checkout's root and the files git would commit (tracked, and untracked ones it does not ignore)."""
    root = Path(mitsnerf.__file__).resolve().parents[1]
    try:
        out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=root,
                             capture_output=True, check=True).stdout.decode()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return root, [name for name in out.split("\0") if name and (root / name).exists()]


@pytest.fixture
def blob_grid() -> np.ndarray:
    """A 24^3 gaussian blob of peak sigma_t 20, off-centre in the scene box, indexed [z, y, x]."""
    r = 24
    c = (np.arange(r) + 0.5) / r - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    return (20.0 * np.exp(-((x - 0.1) ** 2 + y**2 + z**2) / 0.02)).astype(np.float32)
