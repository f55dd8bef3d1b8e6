"""What a ray sees behind the medium: the radiance composited with ``T_N``.

Built from a dataset manifest's ``background`` description (see docs/conventions.md):
``{"type": "constant", "radiance": [r, g, b]}`` or
``{"type": "envmap", "file": ..., "to_world": 4x4, "scale": s}``, evaluated through
Mitsuba's own ``envmap`` emitter so the lookup is exactly what ``volpath`` saw.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import drjit as dr

from mitsnerf.errors import DatasetError


@dataclass(frozen=True)
class ConstantBackground:
    """The same radiance in every direction."""

    radiance: tuple[float, float, float]

    def __call__(self, d):
        return type(d)(*self.radiance)


@dataclass(frozen=True)
class EnvmapBackground:
    """Radiance of a Mitsuba ``envmap`` emitter in direction ``d`` (world space)."""

    emitter: Any

    def __call__(self, d):
        import mitsuba as mi

        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(d))
        si.wi = -mi.Vector3f(d)
        return type(d)(self.emitter.eval(si))


def make_background(desc: Mapping[str, Any] | None, root: Path | None = None):
    """A callable ``d -> Array3f`` from a background description (None: black)."""
    if not desc:
        return ConstantBackground((0.0, 0.0, 0.0))
    kind = desc.get("type")
    if kind == "constant":
        rgb = desc.get("radiance", [0.0, 0.0, 0.0])
        if isinstance(rgb, (int, float)):
            rgb = [rgb] * 3
        if len(rgb) != 3:
            raise DatasetError(root, "background.radiance", f"needs 3 values, got {rgb!r}")
        return ConstantBackground(tuple(float(v) for v in rgb))
    if kind == "envmap":
        import mitsuba as mi

        path = Path(desc["file"])
        if root is not None and not path.is_absolute():
            path = Path(root) / path
        if not path.exists():
            raise DatasetError(path, "background.file", "environment map not found")
        emitter = mi.load_dict(
            {
                "type": "envmap",
                "filename": str(path),
                "scale": float(desc.get("scale", 1.0)),
                "to_world": mi.ScalarTransform4f(desc.get("to_world", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])),
            }
        )
        return EnvmapBackground(emitter)
    raise DatasetError(root, "background.type", f"unknown background type {kind!r} (constant, envmap)")
