"""Shared fixtures: the Mitsuba variant, the tiny scene spec, the checkout's files, and tiny synthetic grids; the
dataset cache moved to a temporary directory for the whole session."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

import mitsnerf  # (configures libLLVM before drjit loads)
from mitsnerf import env

CACHE_KEY = pytest.StashKey[str]()
"""Where this session's ``XDG_CACHE_HOME`` points (:func:`pytest_configure`)."""


def pytest_configure(config) -> None:
    """The suite never writes the user's dataset cache (``~/.cache/mitsnerf``, or ``$MITSNERF_DATA``): before any
    test is collected, ``XDG_CACHE_HOME`` points at a temporary directory (removed at the end) and
    ``MITSNERF_DATA`` is unset, for this process and every child it starts."""
    os.environ.pop("MITSNERF_DATA", None)
    os.environ["XDG_CACHE_HOME"] = tempfile.mkdtemp(prefix="mitsnerf-test-cache-")
    config.stash[CACHE_KEY] = os.environ["XDG_CACHE_HOME"]


def pytest_unconfigure(config) -> None:
    cache = config.stash.get(CACHE_KEY, None)
    if cache is not None:
        shutil.rmtree(cache, ignore_errors=True)


@pytest.fixture(scope="session", autouse=True)
def variant() -> str:
    """Every test runs on the variant the package would choose here (override: MITSNERF_VARIANT)."""
    return env.set_variant()


USABLE_VARIANTS = env.usable_variants()
if not USABLE_VARIANTS:  # every variant-dependent test would be skipped in silence
    raise RuntimeError(f"no Mitsuba variant of {env.SUPPORTED_VARIANTS} can run here (see mitsnerf env)")


@pytest.fixture(params=USABLE_VARIANTS)
def each_variant(request, variant) -> str:
    """A variant-dependent test runs once on each variant this machine can run (both on a machine
    with a GPU, ``llvm_ad_rgb`` alone on a CPU); the session's variant is restored after it."""
    try:
        yield env.set_variant(request.param)
    finally:
        env.set_variant(variant)


@pytest.fixture
def require_network_path(variant):
    """``require_network_path(PATH)`` skips the test where the session's backend lacks network path PATH
    (:func:`mitsnerf.fields.mlp.usable_network_paths`: CUDA has no ``coopvec-fp32``)."""
    def require(path: str) -> None:
        import mitsuba as mi

        from mitsnerf.fields.mlp import usable_network_paths

        if path not in usable_network_paths(mi.TensorXf):
            pytest.skip(f"{path} does not run on {variant}")

    return require


TINY_SCENE = {
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
"""The tiny scene of the tests that render (plain spec data): a 16^3 cloud, 8x8 views, a few spp."""


def tiny_scene(overrides: dict | None = None) -> dict:
    """A fresh copy of :data:`TINY_SCENE` with dotted overrides (``{"cameras.width": 12}``)."""
    from mitsnerf.config import apply_overrides

    return apply_overrides(TINY_SCENE, overrides or {})


#: A bench config of one tiny cell (voxel on the default cloud), for the tests that run `mitsnerf bench CONFIG --quick`
#: (the README's CONFIG, the results page).
TINY_BENCH = """name = "first"
description = "the default cloud, voxel, seconds"
scenes = ["cloud"]
seeds = [0]
[[methods]]
name = "voxel"
config = { resolution = 8, initial_resolution = 8, upsample_steps = [], n_samples = 8 }
train = { steps = 4, batch_rays = 64 }
[quick]
scene = { "cameras.width" = 8, "cameras.height" = 8, "cameras.n_train" = 3, "cameras.n_test" = 2, \
"render.spp_train" = 4, "render.spp_test" = 8, "volume.resolution" = 16 }
train = { steps = 2, batch_rays = 64, log_every = 1 }
eval = { curve_points = 1, footprint = 1 }
oracle = { spp = 4, resolution = 8, n_samples = 16 }
"""


def scene_toml(spec: dict) -> str:
    """A scene spec (plain data, as :data:`TINY_SCENE`) written as TOML: its tables and lists of tables.

    >>> print(scene_toml({"name": "t", "cameras": {"width": 8}, "lights": [{"type": "constant"}]}))
    name = "t"
    [cameras]
    width = 8
    [[lights]]
    type = "constant"
    <BLANKLINE>
    """
    import json

    def value(v) -> str:
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return ("true" if v else "false") if isinstance(v, bool) else json.dumps(v)

    lines = [f"{k} = {value(v)}" for k, v in spec.items() if not isinstance(v, (dict, list))]
    for table, body in spec.items():
        for entry in (body if isinstance(body, list) else [body] if isinstance(body, dict) else []):
            lines.append(f"[[{table}]]" if isinstance(body, list) else f"[{table}]")
            lines += [f"{k} = {value(v)}" for k, v in entry.items()]
    return "\n".join(lines) + "\n"


def child_pythonpath(repo: Path) -> str:
    """PYTHONPATH for a child Python that must import ``repo``'s mitsnerf: ``repo`` first, then the
    entries already set (an install by ``--target``, as scripts/offline_install.sh makes, stays reachable).

    >>> child_pythonpath(Path("/r")).split(os.pathsep)[0]
    '/r'
    """
    rest = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    return os.pathsep.join([str(repo), *rest])


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
