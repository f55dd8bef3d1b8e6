"""A field backed by voxel grids, looked up trilinearly exactly as Mitsuba's ``gridvolume``.

Grids are indexed ``[z, y, x]`` and cover the scene box (docs/conventions.md); the
lookup position of a world point ``x`` is ``box.to_unit(x)`` in ``[0, 1]^3`` with voxel
centres at ``(i + 0.5) / R`` (:mod:`mitsnerf.math.box`), clamped at the borders. The
textures are built with ``use_accel=False`` so the lookups are full precision and
differentiable with respect to the grid values on every backend.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.math.box import Box


def _texture(Texture3f, TensorXf, data, channels: int | tuple[int, ...]):
    if isinstance(data, np.ndarray):
        data = np.ascontiguousarray(data, dtype=np.float32)
        if data.ndim == 3:
            data = data[..., None]
        data = TensorXf(data)
    if data.ndim == 3:
        data = dr.reshape(TensorXf, data, (*data.shape, 1))
    if data.shape[-1] not in ((channels,) if isinstance(channels, int) else channels):
        raise ValueError(f"grid has {data.shape[-1]} channels, expected {channels}")
    return Texture3f(
        data,
        use_accel=False,
        filter_mode=dr.FilterMode.Linear,
        wrap_mode=dr.WrapMode.Clamp,
    )


def extinction(channels, Array3f):
    """A lookup's channels as the extinction: the Float of one channel, an ``Array3f`` of three (chromatic)."""
    return channels[0] if len(channels) == 1 else Array3f(channels[0], channels[1], channels[2])


@dataclass(frozen=True)
class GridField:
    """``sigma(x)`` and ``c(x)`` from voxel grids; colour may instead be a constant RGB.

    Build with :meth:`from_arrays`. ``sigma_t`` (z, y, x[, 1]), or (z, y, x, 3) for a chromatic
    medium (then ``sigma`` is an Array3f, one extinction per colour channel: see
    :func:`mitsnerf.math.composite.composite`), ``color`` (z, y, x, 3) numpy arrays or Dr.Jit
    tensors (tensors keep their AD graph, so gradients reach the grid values).

    >>> import numpy as np, mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> f = GridField.from_arrays(np.full((2, 2, 2), 3.0), UNIT_BOX, color=(0.5, 0.5, 0.5))
    >>> rgb, sigma = f(mi.Array3f(0.1, 0.2, 0.3), mi.Array3f(0, 0, 1))
    >>> sigma, rgb
    ([3], [[0.5, 0.5, 0.5]])
    """

    sigma_t: Any  # Texture3f, 1 channel (3: chromatic)
    color: Any  # Texture3f, 3 channels, or an RGB tuple
    box: Box

    @classmethod
    def from_arrays(cls, sigma_t, box: Box, color=(0.0, 0.0, 0.0)) -> GridField:
        import mitsuba as mi

        sigma_tex = _texture(mi.Texture3f, mi.TensorXf, sigma_t, (1, 3))
        if isinstance(color, (tuple, list)):
            color_tex = tuple(float(c) for c in color)
        else:
            color_tex = _texture(mi.Texture3f, mi.TensorXf, color, 3)
        return cls(sigma_tex, color_tex, box)

    @property
    def sigma_channels(self) -> int:
        """1, or 3 for a chromatic extinction (``sigma`` an Array3f)."""
        return int(self.sigma_t.tensor().shape[-1])

    def density(self, x):
        """``sigma(x)``, Float (M,) (Array3f for a chromatic grid)."""
        return extinction(self.sigma_t.eval(self.box.to_unit(x)), type(x))

    def textures(self) -> tuple:
        """The textures looked up (a :class:`~mitsnerf.fields.protocols.TextureField`): sigma_t, and the
        colour unless it is a constant."""
        return (self.sigma_t,) if isinstance(self.color, tuple) else (self.sigma_t, self.color)

    def head(self, values, x, d):
        """``(rgb, sigma)`` from the lookups of :meth:`textures` (the values themselves: no activation)."""
        Array3f = type(x)
        sigma = extinction(values[0], Array3f)
        if isinstance(self.color, tuple):
            return Array3f(*self.color) + 0.0 * sigma, sigma
        c = values[1]
        return Array3f(c[0], c[1], c[2]), sigma

    def __call__(self, x, d):
        p = self.box.to_unit(x)
        return self.head([tex.eval(p) for tex in self.textures()], x, d)
