"""A :class:`~mitsnerf.scene.spec.SceneSpec` as a Mitsuba scene, its sensors, and its background.

The scene (``docs/conventions.md``, "World and volume"): a ``cube`` placed on the scene box
(:func:`scene_box`: ``world.scale * [-0.5, 0.5]^3``) with a ``null`` BSDF and a
``heterogeneous`` interior medium whose ``sigma_t`` and ``albedo`` are ``gridvolume`` s mapping
``[0, 1]^3`` onto the box (``accel = False``: no reduced precision hardware interpolation on
CUDA), medium ``scale = 1`` (the grid holds true sigma_t), the spec's phase function (``volume.phase``,
isotropic by default), a ``volpath`` integrator and the spec's emitters. Sensors are not part of the scene:
render each view with ``mi.render(scene, sensor=load_sensor(camera, spp), ...)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from mitsnerf.math.box import UNIT_BOX, Box
from mitsnerf.math.camera import Camera
from mitsnerf.scene.lights import SKY_TO_WORLD, emitter_dict
from mitsnerf.scene.spec import ConstantLight, SceneSpec, SkyLight

#: Where a dataset keeps the sky's bitmap (relative to the dataset directory).
ENVMAP_FILE = "volume/envmap.exr"


def scene_box(spec: SceneSpec) -> Box:
    """The box a spec's medium fills (world units): the volume families are authored in
    ``[-0.5, 0.5]^3``, placed in the world scaled by ``world.scale``.

    >>> from mitsnerf.scene.spec import load_scene, nerf_synthetic_overrides
    >>> scene_box(load_scene("cloud").with_overrides(nerf_synthetic_overrides())).to_list()
    [[-1.5, -1.5, -1.5], [1.5, 1.5, 1.5]]
    """
    return UNIT_BOX.scaled(spec.world.scale)


def _box_transform(box: Box):
    """The ``to_world`` taking ``[0, 1]^3`` onto ``box``."""
    import mitsuba as mi

    return mi.ScalarTransform4f().translate(list(box.lo)).scale(list(box.size))


def volume_grids(spec: SceneSpec) -> tuple[np.ndarray, np.ndarray]:
    """``(sigma_t float32 (R, R, R) or (R, R, R, 3), albedo float32 (R, R, R, 3))`` of the spec, ``[z, y, x]``.

    ``sigma_t = volume.sigma_t_scale * density / world.scale`` (world units: a box ``scale`` times
    larger with ``sigma_t`` divided by ``scale`` has the same optical depths), or the family's grid
    itself when it holds ``sigma_t`` (``VolumeGrids.values``); deterministic in the spec. A chromatic
    medium (``sigma_t_scale`` an RGB triple) gets one channel per colour, last.
    """
    from mitsnerf.volumes import generate_volume

    v = spec.volume
    grids = generate_volume(v.family, v.resolution, v.seed, dict(v.params))
    scale = np.asarray(v.sigma_t_scale, dtype=np.float64)
    per_unit = np.ones_like(scale) if grids.values == "sigma_t" else scale / spec.world.scale
    density = np.asarray(grids.density, dtype=np.float32)
    sigma_t = (per_unit.astype(np.float32) * density[..., None] if v.chromatic
               else np.float32(per_unit) * density).astype(np.float32)
    return np.ascontiguousarray(sigma_t), np.ascontiguousarray(grids.albedo, dtype=np.float32)


def grid_volume(data: np.ndarray, box: Box) -> dict[str, Any]:
    """A ``gridvolume`` over ``box`` for a ``[z, y, x]`` (1 channel) or ``[z, y, x, 3]`` array.

    ``to_world`` maps its [0, 1]^3 onto the box; ``accel=False`` keeps CUDA from using
    reduced-precision hardware interpolation.
    """
    import mitsuba as mi

    return {
        "type": "gridvolume",
        "grid": mi.VolumeGrid(np.ascontiguousarray(data, dtype=np.float32)),
        "to_world": _box_transform(box),
        "accel": False,
    }


def medium_box(sigma_t: np.ndarray, albedo, box: Box, phase: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The box: a ``cube`` with a ``null`` BSDF around a heterogeneous medium.

    ``sigma_t`` (R, R, R), or (R, R, R, 3) for a chromatic medium, holds the true extinction
    (``scale = 1``); ``albedo`` is an (R, R, R, 3)
    grid or one float; ``phase`` the phase plugin's entry (None: isotropic).
    """
    import mitsuba as mi

    albedo_entry: Any = (
        float(albedo) if np.ndim(albedo) == 0 else grid_volume(np.asarray(albedo, dtype=np.float32), box)
    )
    return {
        "type": "cube",
        "to_world": mi.ScalarTransform4f().translate(list(box.centre)).scale([0.5 * s for s in box.size]),
        "bsdf": {"type": "null"},
        "interior": {
            "type": "heterogeneous",
            "scale": 1.0,
            "phase": dict(phase) if phase is not None else {"type": "isotropic"},
            "sigma_t": grid_volume(sigma_t, box),
            "albedo": albedo_entry,
        },
    }


def scene_dict(spec: SceneSpec, sigma_t: np.ndarray, albedo: np.ndarray) -> dict[str, Any]:
    """The ``mi.load_dict`` dictionary of the scene (no sensor), for the current Mitsuba variant; the albedo grid
    may have a resolution of its own."""
    r, a = sigma_t.shape[0], albedo.shape[0]
    if sigma_t.shape not in ((r, r, r), (r, r, r, 3)) or albedo.shape != (a, a, a, 3):
        raise ValueError(f"grids must be (R, R, R) or (R, R, R, 3) and (A, A, A, 3), got {sigma_t.shape} and "
                         f"{albedo.shape}")
    d: dict[str, Any] = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": int(spec.render.max_depth)},
        "medium_box": medium_box(sigma_t, albedo, scene_box(spec), spec.volume.phase.mitsuba()),
    }
    for i, light in enumerate(spec.lights):
        d[f"light_{i}_{light.type}"] = emitter_dict(light)
    return d


def sensor_dict(camera: Camera, spp: int) -> dict[str, Any]:
    """A ``perspective`` sensor for ``camera``: horizontal fov, box filter, RGBA ``hdrfilm``."""
    import mitsuba as mi

    if not camera.is_centred():
        raise ValueError("only centred cameras (cx = W/2, cy = H/2) map onto a Mitsuba perspective sensor")
    if abs(camera.fl_x - camera.fl_y) > 1e-9 * camera.fl_x:
        raise ValueError("only square pixels (fl_x == fl_y) map onto a Mitsuba perspective sensor")
    return {
        "type": "perspective",
        "fov_axis": "x",
        "fov": float(camera.fov_x_deg),
        "to_world": mi.ScalarTransform4f(np.asarray(camera.mitsuba_to_world(), dtype=np.float64)),
        "sampler": {"type": "independent", "sample_count": int(spp)},
        "film": {
            "type": "hdrfilm",
            "width": int(camera.width),
            "height": int(camera.height),
            "rfilter": {"type": "box"},
            "pixel_format": "rgba",
        },
    }


def load_sensor(camera: Camera, spp: int):
    """``mi.load_dict(sensor_dict(camera, spp))``."""
    import mitsuba as mi

    return mi.load_dict(sensor_dict(camera, spp))


def background_description(spec: SceneSpec) -> dict[str, Any]:
    """What camera rays that miss the medium see (for a NeRF to composite ``T_N * background``).

    - constant environment: ``{"type": "constant", "radiance": [r, g, b]}``;
    - sky: ``{"type": "envmap", "file": "volume/envmap.exr", "to_world": 4x4, "scale": s}``, looked up
      as :func:`mitsnerf.scene.lights.envmap_eval` describes (the dataset holds the bitmap);
    - no environment (directional and point lights only; camera rays never see those):
      ``{"type": "constant", "radiance": [0, 0, 0]}``.
    """
    env = spec.environment
    if isinstance(env, ConstantLight):
        return {"type": "constant", "radiance": [float(c) for c in env.radiance]}
    if isinstance(env, SkyLight):
        return {
            "type": "envmap",
            "file": ENVMAP_FILE,
            "to_world": SKY_TO_WORLD.tolist(),
            "scale": float(env.scale),
        }
    return {"type": "constant", "radiance": [0.0, 0.0, 0.0]}
