"""Camera rigs: deterministic camera placements around the scene box, all looking at the origin.

The world is Z-up (:data:`mitsnerf.scene.spec.UP`). For ``n`` cameras at distance ``radius``:

- ``sphere``: a Fibonacci sphere (``z_i = 1 - 2 (i + 1/2) / n``, azimuth ``i`` times the golden
  angle), turned by a random rotation drawn from ``(seed, split)``, so test views are not train views.
- ``hemisphere``: the same on the upper half (``z_i = (i + 1/2) / n``), turned by a random
  azimuth drawn from ``(seed, split)``.
- ``ring``: the equator, evenly spaced, starting at an azimuth drawn from ``seed``; the test
  split is offset by the golden-ratio fraction of a step, so it never repeats a train azimuth.

Cameras are pinhole, centred, with the spec's horizontal ``fov`` and image size, and ``up = +Z``.

    >>> from mitsnerf.scene.spec import CameraRigSpec
    >>> spec = CameraRigSpec("ring", n_train=4, n_test=2, width=8, height=8, fov=40.0, radius=2.0)
    >>> cams = camera_rig(spec, "train")
    >>> len(cams), [round(float(np.linalg.norm(c.origin)), 6) for c in cams]
    (4, [2.0, 2.0, 2.0, 2.0])
"""

from __future__ import annotations

import math

import numpy as np

from mitsnerf.math.camera import Camera, look_at
from mitsnerf.scene.spec import UP, CameraRigSpec

SPLITS = ("train", "test")
_GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
_GOLDEN_FRACTION = (math.sqrt(5.0) - 1.0) / 2.0


def _rng(seed: int, split: str) -> np.random.Generator:
    return np.random.default_rng([seed, SPLITS.index(split), 0x5CE7E])


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random 3x3 rotation (from a random unit quaternion)."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _fibonacci(z: np.ndarray, phase: float = 0.0) -> np.ndarray:
    phi = _GOLDEN_ANGLE * np.arange(len(z)) + phase
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def camera_positions(spec: CameraRigSpec, split: str) -> np.ndarray:
    """World positions (N, 3) of the cameras of ``split`` (``"train"`` or ``"test"``)."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    n = spec.n_train if split == "train" else spec.n_test
    i = np.arange(n, dtype=np.float64)
    rng = _rng(spec.seed, split)
    if spec.rig == "sphere":
        unit = _fibonacci(1.0 - 2.0 * (i + 0.5) / n) @ _random_rotation(rng).T
    elif spec.rig == "hemisphere":
        unit = _fibonacci((i + 0.5) / n, phase=rng.uniform(0.0, 2.0 * math.pi))
    elif spec.rig == "ring":
        start = np.random.default_rng([spec.seed, 0x5CE7E]).uniform(0.0, 1.0)
        offset = 0.0 if split == "train" else _GOLDEN_FRACTION
        phi = 2.0 * math.pi * ((i + offset) / n + start)
        unit = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=-1)
    else:  # CameraRigSpec validates the rig; this is a programming error
        raise ValueError(f"unknown rig {spec.rig!r}")
    return unit * spec.radius


def camera_rig(spec: CameraRigSpec, split: str) -> list[Camera]:
    """The cameras of ``split``, deterministic in ``spec`` (see the module docstring)."""
    return [
        Camera.from_fov(look_at(p, (0.0, 0.0, 0.0), UP), spec.width, spec.height, spec.fov)
        for p in camera_positions(spec, split)
    ]
