"""Lights for Mitsuba: emitter dictionaries, and the sky baked to a lat-long environment map.

Mitsuba's ``envmap`` is Y-up in its own frame. A world direction ``d`` (Z-up world) is looked up
as (``M = SKY_TO_WORLD``, the emitter's ``to_world``)::

    v     = M^T d                                        (local, Y-up)
    u     = atan2(v.x, -v.z) / (2 pi)   (mod 1)          column coordinate: u * W - 1/2
    t     = acos(v.y) / pi                               row coordinate:    t * (H - 1)

then bilinear between texels, wrapping in ``u``: column ``i`` sits at ``u = (i + 1/2) / W``, row ``j``
at polar angle ``pi j / (H - 1)`` (rows 0 and H-1 are the poles). :func:`bake_sky` fills texels at
exactly those directions and :func:`envmap_eval` reproduces the lookup in numpy (tested against
Mitsuba renders), so a NeRF can composite the same background Mitsuba saw.

    >>> from mitsnerf.scene.spec import SkyLight
    >>> sky = SkyLight(zenith=(0.2, 0.3, 0.8), horizon=(0.8, 0.8, 0.9), ground=(0.3, 0.25, 0.2))
    >>> sky_radiance(sky, np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])).round(3).tolist()
    [[0.2, 0.3, 0.8], [0.8, 0.8, 0.9]]
    >>> img = bake_sky(sky)
    >>> img.shape, img.dtype
    ((128, 256, 3), dtype('float32'))
    >>> bool(np.abs(envmap_eval(img, SKY_TO_WORLD, np.array([[0.0, 0.0, 1.0]])) - [0.2, 0.3, 0.8]).max() < 1e-6)
    True
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from mitsnerf.scene.spec import ConstantLight, DirectionalLight, LightSpec, PointLight, SkyLight

#: Mitsuba envmap frame (Y-up) to the Z-up world: local x -> x, local y -> z, local z -> -y.
SKY_TO_WORLD = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


def sky_radiance(sky: SkyLight, directions: np.ndarray) -> np.ndarray:
    """Radiance (float64, (N, 3)) of the analytic sky in unit world directions ``(N, 3)`` (times ``scale``)."""
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    h = d[:, 2:3]
    zenith, horizon, ground = (np.asarray(c, dtype=np.float64) for c in (sky.zenith, sky.horizon, sky.ground))
    up = horizon + (zenith - horizon) * (1.0 - np.square(1.0 - np.clip(h, 0.0, 1.0)))
    down = horizon + (ground - horizon) * (1.0 - np.square(1.0 - np.clip(-h, 0.0, 1.0)))
    rad = np.where(h >= 0.0, up, down)
    if sky.sun_direction is not None and any(sky.sun_glow):
        to_sun = -np.asarray(sky.sun_direction, dtype=np.float64)
        to_sun /= np.linalg.norm(to_sun)
        glow = np.exp(sky.sun_sharpness * (d @ to_sun - 1.0))[:, None]
        rad = rad + glow * np.asarray(sky.sun_glow, dtype=np.float64)
    return rad * sky.scale


def envmap_texel_directions(width: int, height: int, to_world: np.ndarray = SKY_TO_WORLD) -> np.ndarray:
    """World directions (H, W, 3) at which Mitsuba's envmap places the texels of a ``W x H`` bitmap."""
    theta = np.pi * np.arange(height) / (height - 1)
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    local = np.stack([np.sin(ph) * np.sin(th), np.cos(th), -np.cos(ph) * np.sin(th)], axis=-1)
    return local @ np.asarray(to_world)[:3, :3].T


def bake_sky(sky: SkyLight) -> np.ndarray:
    """The sky as a float32 lat-long bitmap ``(resolution // 2, resolution, 3)`` for ``envmap``.

    The bitmap holds the radiance *without* ``scale``; the emitter applies ``scale``.
    """
    width = sky.resolution
    height = max(3, width // 2)
    dirs = envmap_texel_directions(width, height).reshape(-1, 3)
    unscaled = sky_radiance(sky, dirs) / sky.scale
    return unscaled.reshape(height, width, 3).astype(np.float32)


def envmap_eval(bitmap: np.ndarray, to_world: np.ndarray, directions: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Mitsuba's ``envmap`` lookup in numpy: radiance (N, 3) seen in unit world directions (N, 3).

    ``bitmap`` is the (H, W, 3) image given to the emitter, ``to_world`` its 4x4 transform. Mitsuba
    also averages the first and last column for continuity: it pads a copy of column 0 after the
    last one, which is what the wrap below does.
    """
    img = np.asarray(bitmap, dtype=np.float64)
    h, w = img.shape[:2]
    v = np.asarray(directions, dtype=np.float64) @ np.asarray(to_world)[:3, :3]  # M^T d, row vectors
    u = np.arctan2(v[:, 0], -v[:, 2]) / (2.0 * np.pi)
    t = np.arccos(np.clip(v[:, 1], -1.0, 1.0)) / np.pi
    x = np.mod(u - 0.5 / w, 1.0) * w
    y = t * (h - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 1)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x1 = (x0 + 1) % w
    top = (1 - fx) * img[y0, x0] + fx * img[y0, x1]
    bottom = (1 - fx) * img[y0 + 1, x0] + fx * img[y0 + 1, x1]
    return ((1 - fy) * top + fy * bottom) * scale


def _rgb(value) -> dict[str, Any]:
    return {"type": "rgb", "value": [float(c) for c in value]}


def emitter_dict(light: LightSpec) -> dict[str, Any]:
    """The ``mi.load_dict`` entry of one light (the sky's bitmap is baked here)."""
    import mitsuba as mi

    if isinstance(light, ConstantLight):
        return {"type": "constant", "radiance": _rgb(light.radiance)}
    if isinstance(light, SkyLight):
        return {
            "type": "envmap",
            "bitmap": mi.Bitmap(bake_sky(light)),
            "to_world": mi.ScalarTransform4f(SKY_TO_WORLD),
            "scale": float(light.scale),
        }
    if isinstance(light, DirectionalLight):
        return {"type": "directional", "direction": list(light.direction), "irradiance": _rgb(light.irradiance)}
    if isinstance(light, PointLight):
        return {"type": "point", "position": list(light.position), "intensity": _rgb(light.intensity)}
    raise TypeError(f"no Mitsuba emitter for light {light!r}")


# --------------------------------------------------------------------------- delta lights


def delta_lights(lights: Sequence[LightSpec]) -> list[LightSpec]:
    """The spec's delta lights (directional and point), in order: the lights whose unscattered light reaches a
    point from one direction only, so that its single scattering can be computed exactly (a direction sampled
    by volpath never meets them). Environment lights (``constant``, ``sky``) are not among them."""
    return [light for light in lights if isinstance(light, (DirectionalLight, PointLight))]


def toward_light(light: LightSpec, x: np.ndarray) -> np.ndarray:
    """Unit direction from points ``x`` (M, 3) to a delta light (a directional light: ``-direction``;
    a point light: towards its position), float64 (M, 3): the ``w`` its light arrives from.

    >>> toward_light(DirectionalLight(direction=(0.0, 0.0, -2.0), irradiance=(1.0, 1.0, 1.0)), np.zeros((1, 3)))[0, 2]
    np.float64(1.0)
    """
    x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    if isinstance(light, DirectionalLight):
        w = -np.asarray(light.direction, np.float64) / np.linalg.norm(light.direction)
        return np.broadcast_to(w, x.shape)
    if not isinstance(light, PointLight):
        raise TypeError(f"toward_light: not a delta light: {light!r}")
    v = np.asarray(light.position, np.float64) - x
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def light_terms(lights: Sequence[LightSpec], x) -> list[tuple[Any, Any, Any]]:
    """Per delta light, at Dr.Jit points ``x`` (Array3f (M,)): ``(w, E, s_max)``: the unit direction the light
    arrives from (Array3f), its irradiance there before the medium attenuates it (Array3f: a directional
    light's ``irradiance``; a point light's ``intensity / r^2``), and the distance to it (Float; None for a
    directional light, which is met only where the ray leaves the box). Other lights are skipped.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> lamp = PointLight(position=(0.0, 0.0, 2.0), intensity=(4.0, 4.0, 4.0))
    >>> w, E, s_max = light_terms([lamp], mi.Array3f(0.0, 0.0, 0.0))[0]
    >>> w, E, s_max
    ([[0, 0, 1]], [[1, 1, 1]], [2])
    """
    import drjit as dr

    Array3f = type(x)
    out = []
    for light in lights:
        if isinstance(light, DirectionalLight):
            out.append((-dr.normalize(Array3f(*light.direction)), Array3f(*light.irradiance), None))
        elif isinstance(light, PointLight):
            to_light = Array3f(*light.position) - x
            r2 = dr.squared_norm(to_light)
            out.append((to_light * dr.rsqrt(r2), Array3f(*light.intensity) / r2, dr.sqrt(r2)))
    return out
