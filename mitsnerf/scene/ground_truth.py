"""The ground truth checked before it is written: a bad grid or image is refused, naming the spec
field that caused it, and nothing of the dataset is left on disk.

- The grids (:func:`check_grids`): ``sigma_t`` finite and ``>= 0``, ``albedo`` finite in ``[0, 1]``.
  ``volume.sigma_t_scale`` is bounded (:data:`mitsnerf.scene.spec.SIGMA_T_SCALE_MAX`), so its product
  with a density in ``[0, 1]`` cannot overflow: what is wrong in a grid comes from the family,
  ``volume.params``.
- The rendered views (:func:`check_views`): finite and non-negative radiance, up to float32 rounding at
  the view's scale (:func:`mitsnerf.data.verify.roundoff_tolerance`: a pixel that is 0 exactly, such as the
  background through a medium of transmittance 1e-14, may come out 1e-15 below; generation writes it as 0).
  With the grids checked, what is left to overflow in volpath is the light: the brightest light's table is named.

The problems are found by :func:`mitsnerf.data.verify.grid_problem` and
:func:`~mitsnerf.data.verify.image_problem`, the checks a dataset gets again when it is opened.
"""

from __future__ import annotations

import numpy as np

from mitsnerf.data.verify import grid_problem, image_problem
from mitsnerf.errors import SpecError
from mitsnerf.scene.spec import SceneSpec


def _source(spec: SceneSpec) -> str:
    return spec.source or "<spec>"


def check_grids(spec: SceneSpec, sigma_t: np.ndarray, albedo: np.ndarray) -> None:
    """Refuse grids with non-finite or out-of-range values (a :class:`~mitsnerf.errors.SpecError`)."""
    for name, grid, hi in (("sigma_t", sigma_t, None), ("albedo", albedo, 1.0)):
        problem = grid_problem(grid, lo=0.0, hi=hi)
        if problem is not None:
            raise SpecError(_source(spec), "volume.params", f"the {spec.volume.family} family's {name} grid has "
                                                            f"{problem}; nothing written")


def _brightest_light(spec: SceneSpec) -> int:
    """Index of the light with the largest radiance, irradiance or intensity value."""
    def peak(light) -> float:
        values = [v for f in ("radiance", "irradiance", "intensity", "zenith", "horizon", "ground", "sun_glow")
                  for v in (getattr(light, f, None) or ())]
        return max(values, default=0.0) * float(getattr(light, "scale", 1.0))
    return int(np.argmax([peak(light) for light in spec.lights]))


def check_views(spec: SceneSpec, split: str, images: list[np.ndarray]) -> None:
    """Refuse rendered views with non-finite or negative radiance, before any is written."""
    for i, image in enumerate(images):
        problem = image_problem(image)
        if problem is not None:
            raise SpecError(_source(spec), f"lights.{_brightest_light(spec)}",
                            f"the rendered view {split}/r_{i:03d} has {problem} (radiance overflowing float32 "
                            "in volpath); nothing written")
