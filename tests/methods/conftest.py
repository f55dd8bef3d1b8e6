"""Tiny training sets for the method tests: a ground-truth GridField rendered by our own renderer."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.grid import GridField
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.methods.base import SceneInfo
from mitsnerf.render.background import ConstantBackground
from mitsnerf.math.rays import camera_rays
from mitsnerf.render.volume import render_rays
from mitsnerf.train import PixelData
from mitsnerf.math.box import UNIT_BOX


@pytest.fixture
def tiny_views(blob_grid):
    """``make(n_views, size) -> (PixelData, SceneInfo)``: views of the blob from random directions."""

    def make(n_views: int = 6, size: int = 12):
        rng = np.random.default_rng(0)
        cams = []
        for _ in range(n_views):
            v = rng.normal(size=3)
            cams.append(Camera.from_fov(look_at(2.0 * v / np.linalg.norm(v)), size, size, 40.0))
        bg = ConstantBackground((0.05, 0.1, 0.3))
        gt = GridField.from_arrays(blob_grid, UNIT_BOX, color=(1.0, 0.9, 0.1))
        rays = camera_rays(mi.Array3f, cams)
        with dr.suspend_grad():
            comp = render_rays(gt, rays.o, rays.d, 64, background=bg, box=UNIT_BOX)
        images = np.stack([np.asarray(c) for c in comp.rgb], -1).reshape(n_views, size, size, 3)
        data = PixelData.from_views(images, cams)
        return data, SceneInfo(UNIT_BOX, bg, float(images.max()), train_views=data)

    return make
