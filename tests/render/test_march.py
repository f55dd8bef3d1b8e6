"""The one-loop march computes what render_rays computes at the stratum midpoints."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsnerf.fields.grid import GridField
from mitsnerf.math.box import UNIT_BOX, Box
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.math.rays import camera_rays
from mitsnerf.render.background import ConstantBackground
from mitsnerf.render.march import march_rays
from mitsnerf.render.volume import render_rays


def test_march_equals_render_rays_on_a_grid_field(blob_grid, each_variant):
    rng = np.random.default_rng(1)
    colour = rng.uniform(0.1, 1.0, (*blob_grid.shape, 3)).astype(np.float32)
    box = Box((-0.7, -0.5, -0.4), (0.6, 0.5, 0.6))  # not the unit box: the march maps the box it is given
    field = GridField.from_arrays(blob_grid, box, color=colour)
    cams = [Camera.from_fov(look_at(p), 10, 8, 50.0) for p in ((0.0, -2.0, 0.3), (1.5, 1.2, -0.4))]
    rays = camera_rays(mi.Array3f, cams)
    bg = ConstantBackground((0.2, 0.3, 0.4))
    for n in (1, 7, 64):
        ref = render_rays(field, rays.o, rays.d, n, box=box, background=bg)
        out = march_rays(field, rays.o, rays.d, n, box=box, background=bg)
        for a, b in ((ref.rgb, out.rgb), (ref.opacity, out.opacity), (ref.depth, out.depth), (ref.T_final, out.T_final)):
            np.testing.assert_allclose(np.array(b), np.array(a), rtol=2e-5, atol=2e-6)
