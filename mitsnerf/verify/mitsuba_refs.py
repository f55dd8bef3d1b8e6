"""Mitsuba's side of the verification: small medium scenes and volpath's per-pixel mean and variance.

The scenes follow docs/conventions.md exactly as the dataset generator does: a ``cube``
scaled to the box ``[-0.5, 0.5]^3`` with a ``null`` BSDF and a ``heterogeneous`` interior
medium whose ``sigma_t`` and ``albedo`` are ``gridvolume`` s indexed ``[z, y, x]``
(``to_world = translate(-0.5)``, ``accel = False``, medium ``scale = 1``), an isotropic phase
function. A convention mismatch between this and :class:`mitsnerf.fields.grid.GridField`
(axis order, voxel centres, box placement) is exactly what the comparison catches.

The reference is computed on the *same rays* as the integrator under test (pixel centres of a
:class:`~mitsnerf.math.camera.Camera`): ``n`` independent volpath samples per ray through
``SamplingIntegrator.sample``, accumulated in float64, give the per-pixel mean and the
per-sample variance::

    m_p = (1/n) sum_k L_pk,        s_p^2 = (1/(n-1)) sum_k (L_pk - m_p)^2

Rendering through a film instead (``mi.render``, or the ``moment`` integrator wrapping
volpath for the second moment) would average each pixel over its area while the integrator
under test shoots one ray through the pixel centre; at 16x16 pixels that difference is
larger than the noise. The film path is exercised by the plugin check
(:mod:`mitsnerf.render.mitsuba_plugin`), which renders through a real sensor.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.camera import Camera
from mitsnerf.scene.to_mitsuba import medium_box

if TYPE_CHECKING:
    from mitsnerf.verify.cases import VolpathScenario


def constant_environment(radiance) -> dict[str, Any]:
    return {"type": "constant", "radiance": {"type": "rgb", "value": [float(c) for c in radiance]}}


def envmap_environment(bitmap: np.ndarray, scale: float = 1.0) -> dict[str, Any]:
    """An ``envmap`` from a float ``(H, W, 3)`` numpy bitmap (identity ``to_world``: Mitsuba's Y-up frame)."""
    import mitsuba as mi

    return {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(bitmap, dtype=np.float32)),
            "scale": float(scale)}


def directional_light(direction, irradiance) -> dict[str, Any]:
    """A ``directional`` emitter; ``direction`` is the way the light *travels* (towards the scene)."""
    return {"type": "directional", "direction": [float(c) for c in direction],
            "irradiance": {"type": "rgb", "value": [float(c) for c in irradiance]}}


def scene_dict(sigma_t, albedo, emitters: dict[str, dict], max_depth: int = -1,
               phase: dict[str, Any] | None = None) -> dict[str, Any]:
    """``mi.load_dict`` input: the medium box (``phase``: its phase plugin, None isotropic), the ``emitters``
    (name -> dict), ``volpath(max_depth)``."""
    d: dict[str, Any] = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": int(max_depth)},
        "medium_box": medium_box(sigma_t, albedo, UNIT_BOX, phase),
    }
    d.update(emitters)
    return d


def sensor_dict(camera: Camera, spp: int, pixel_centres: bool = False) -> dict[str, Any]:
    """A ``perspective`` sensor for a centred, square-pixel ``camera`` (box filter, RGB film).

    ``pixel_centres=True`` uses a ``stratified`` sampler without jitter at 1 spp, so that every
    pixel is rendered with the one ray through its centre (as mitsnerf's cameras cast them).
    """
    import mitsuba as mi

    if not camera.is_centred() or abs(camera.fl_x - camera.fl_y) > 1e-9 * camera.fl_x:
        raise ValueError("only centred cameras with square pixels map onto a Mitsuba perspective sensor")
    sampler = ({"type": "stratified", "sample_count": 1, "jitter": False} if pixel_centres
               else {"type": "independent", "sample_count": int(spp)})
    return {
        "type": "perspective",
        "fov_axis": "x",
        "fov": float(camera.fov_x_deg),
        "to_world": mi.ScalarTransform4f(np.asarray(camera.mitsuba_to_world(), dtype=np.float64)),
        "sampler": sampler,
        "film": {"type": "hdrfilm", "width": int(camera.width), "height": int(camera.height),
                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
    }


@dataclass(frozen=True)
class Reference:
    """Per-ray statistics of ``n`` independent Mitsuba samples: mean and per-sample variance, (R, 3)."""

    mean: np.ndarray
    var: np.ndarray
    n: int
    seconds: float

    def reshaped(self, *shape: int) -> Reference:
        return Reference(self.mean.reshape(*shape, 3), self.var.reshape(*shape, 3), self.n, self.seconds)


def sample_rays(scene, o: np.ndarray, d: np.ndarray, spp: int, seed: int = 0, chunk_spp: int = 256) -> Reference:
    """Mean and variance of ``spp`` samples of ``scene.integrator()`` along rays ``o + t d`` ((R, 3) arrays).

    The rays start in vacuum (outside the medium box). Samples are drawn in passes of
    ``chunk_spp`` per ray, pass ``k`` seeded ``seed * 7919 + k`` (fixed seeds: reproducible).
    """
    import drjit as dr
    import mitsuba as mi

    if spp < 2:
        raise ValueError(f"sample_rays: need spp >= 2 for a variance, got {spp}")
    o = np.asarray(o, dtype=np.float32)
    d = np.asarray(d, dtype=np.float32)
    n_rays = len(o)
    integrator = scene.integrator()
    sampler = mi.load_dict({"type": "independent", "sample_count": 1})
    total = np.zeros((n_rays, 3))
    total_sq = np.zeros((n_rays, 3))
    done = 0
    start = time.perf_counter()
    pass_index = 0
    while done < spp:
        k = min(chunk_spp, spp - done)
        idx = np.repeat(np.arange(n_rays), k)
        ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(*o[idx].T), mi.Vector3f(*d[idx].T)))
        sampler.seed(seed * 7919 + pass_index, n_rays * k)
        with dr.suspend_grad():
            L, _, _ = integrator.sample(scene, sampler, ray, None, True)
        values = np.stack([np.asarray(c, dtype=np.float64) for c in L], axis=-1).reshape(n_rays, k, 3)
        total += values.sum(axis=1)
        total_sq += np.square(values).sum(axis=1)
        done += k
        pass_index += 1
    mean = total / spp
    var = np.maximum(total_sq - spp * np.square(mean), 0.0) / (spp - 1)
    return Reference(mean, var, spp, time.perf_counter() - start)


def render_reference(scene_description: dict[str, Any], camera: Camera, spp: int, seed: int = 0) -> Reference:
    """Load ``scene_description`` and sample every pixel-centre ray of ``camera``; (H, W, 3) statistics."""
    import mitsuba as mi

    scene = mi.load_dict(scene_description)
    o, d = camera.pixel_rays()
    return sample_rays(scene, o, d, spp, seed).reshaped(camera.height, camera.width)


def emitters_of(s: VolpathScenario) -> dict[str, dict]:
    """The Mitsuba emitters of a volpath scenario: its environment and its directional light."""
    from mitsnerf.verify.cases import environment_bitmap

    emitters: dict[str, dict] = {}
    if s.environment == "constant":
        emitters["environment"] = constant_environment(s.env_radiance)
    elif s.environment == "envmap":
        emitters["environment"] = envmap_environment(environment_bitmap())
    if s.sun_direction is not None:
        emitters["sun"] = directional_light(s.sun_direction, s.sun_irradiance)
    return emitters
