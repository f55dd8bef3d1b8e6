"""Camera rigs: counts, distances, orientation, determinism, train/test separation."""

from __future__ import annotations

import numpy as np
import pytest

from mitsnerf.scene.rigs import camera_positions, camera_rig
from mitsnerf.scene.spec import CameraRigSpec


def _rig(kind: str, n_train: int = 12, n_test: int = 5, seed: int = 0) -> CameraRigSpec:
    return CameraRigSpec(kind, n_train=n_train, n_test=n_test, width=10, height=6, fov=40.0, radius=2.5, seed=seed)


@pytest.mark.parametrize("kind", ["sphere", "hemisphere", "ring"])
def test_rig_geometry(kind):
    spec = _rig(kind)
    for split, n in (("train", 12), ("test", 5)):
        cams = camera_rig(spec, split)
        assert len(cams) == n
        for cam in cams:
            assert np.linalg.norm(cam.origin) == pytest.approx(2.5, abs=1e-9)
            # the optical axis (-z of the OpenGL c2w) points at the origin
            forward = -cam.c2w[:3, 2]
            assert np.allclose(forward, -cam.origin / 2.5, atol=1e-9)
            # the origin projects onto the image centre
            assert np.allclose(cam.project(np.zeros((1, 3)))[0], [5.0, 3.0], atol=1e-9)
            assert (cam.width, cam.height) == (10, 6) and cam.fov_x_deg == pytest.approx(40.0)
            # Z-up: the image's up vector has no downward world component unless looking straight down
            assert cam.c2w[2, 1] >= -1e-9
        z = np.array([c.origin[2] for c in cams])
        if kind == "hemisphere":
            assert np.all(z > 0)
        if kind == "ring":
            assert np.allclose(z, 0.0, atol=1e-12)


@pytest.mark.parametrize("kind", ["sphere", "hemisphere", "ring"])
def test_rig_deterministic_and_splits_differ(kind):
    spec = _rig(kind)
    for split in ("train", "test"):
        assert np.array_equal(camera_positions(spec, split), camera_positions(spec, split))
    train, test = camera_positions(spec, "train"), camera_positions(spec, "test")
    dist = np.linalg.norm(train[:, None, :] - test[None, :, :], axis=-1)
    assert dist.min() > 1e-3, "a test camera repeats a train camera"
    # another seed moves the cameras
    assert not np.allclose(camera_positions(_rig(kind, seed=1), "train"), train)


def test_sphere_covers_the_sphere():
    pos = camera_positions(_rig("sphere", n_train=200), "train") / 2.5
    assert abs(pos.mean(axis=0)).max() < 0.05  # balanced
    assert (pos[:, 2] > 0).mean() == pytest.approx(0.5, abs=0.1)


def test_ring_evenly_spaced():
    pos = camera_positions(_rig("ring", n_train=8), "train")
    phi = np.sort(np.arctan2(pos[:, 1], pos[:, 0]))
    steps = np.diff(np.concatenate([phi, phi[:1] + 2 * np.pi]))
    assert np.allclose(steps, 2 * np.pi / 8)


def test_equal_counts_still_differ():
    spec = _rig("ring", n_train=10, n_test=10)
    train, test = camera_positions(spec, "train"), camera_positions(spec, "test")
    assert np.linalg.norm(train[:, None] - test[None], axis=-1).min() > 0.1


def test_bad_split():
    with pytest.raises(ValueError, match="split"):
        camera_rig(_rig("ring"), "val")
