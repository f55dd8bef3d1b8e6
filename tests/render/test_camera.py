"""Whole views: the pixel footprint integrates a pixel's area as a box-filtered film does."""

from __future__ import annotations

import mitsuba as mi
import drjit as dr
import numpy as np
import pytest

from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.render.camera import render_view
from mitsnerf.render.volume import render_rays

EDGE_COL = 3.3
"""The image column the sheet's edge projects to: pixel 3 is 70% covered."""


def _sheet_camera():
    """A camera on the +z axis looking down at the sheet z = 0: x_world = (col - cx) / fl * 2.5 at the sheet."""
    return Camera.from_fov(look_at((0.0, 0.0, 2.5), up=(0.0, 1.0, 0.0)), 8, 6, 20.0)  # all inside the box


def _sheet(cam):
    """A thin opaque sheet (|z| < 0.002) covering x > x0, emitting 1: the edge x = x0 projects to EDGE_COL."""
    x0 = (EDGE_COL - cam.cx) / cam.fl_x * 2.5

    def field(x, d):
        inside = (x.x > x0) & (dr.abs(x.z) < 0.002)
        return mi.Array3f(1.0) + 0.0 * x.x, dr.select(inside, 2e4, 0.0)
    return field


def test_a_footprint_reproduces_the_box_filtered_pixel_of_a_sharp_edge():
    cam = _sheet_camera()
    field = _sheet(cam)
    renderer = lambda o, d: render_rays(field, o, d, 2048, box=UNIT_BOX, background=0.0)  # noqa: E731
    covered = np.clip(np.arange(cam.width) + 1.0 - EDGE_COL, 0.0, 1.0)  # area of [col, col+1) right of the edge
    k = 20
    box = render_view(renderer, cam, footprint=k).rgb[..., 0]
    # stratified K x K: the edge cuts one column of strata, so a pixel's area is resolved to 1/K
    np.testing.assert_allclose(box, np.broadcast_to(covered, box.shape), atol=1.0 / k)
    assert box[2, 3] == pytest.approx(0.7, abs=1.0 / k)
    point = render_view(renderer, cam, footprint=1).rgb[..., 0]
    assert point[2, 3] == pytest.approx(1.0, abs=1e-3)  # the centre ray alone sees all or nothing
    assert abs(point[2, 3] - 0.7) > 0.25
