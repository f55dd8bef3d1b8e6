"""``mitsnerf_ea``: a Mitsuba integrator that renders a field with mitsnerf's own quadrature.

For each camera ray it does exactly what :func:`mitsnerf.render.volume.render_rays` does
(the same function is called): clip to the scene box ``integrator.box``, ``N`` samples at the
stratum midpoints, and::

    C = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i + T_N * bg(d),   T_i = exp(-sum_{j<i} sigma_j delta_j)

where ``bg(d)`` is the scene's environment emitter seen in direction ``d`` (black without one),
or whatever ``integrator.background`` is set to. So a trained model rendered through Mitsuba
(any sensor, film, reconstruction filter and sample count) matches the package's own renderer.

.. list-table:: Parameters
   :header-rows: 1

   * - name
     - type
     - default
     - meaning
   * - ``n_samples``
     - int
     - 128
     - samples per ray N (>= 1)

Usage::

    from mitsnerf.render.mitsuba_plugin import register
    register()                                     # after choosing the variant
    scene = mi.load_dict({..., "integrator": {"type": "mitsnerf_ea", "n_samples": 64}})
    scene.integrator().field = field               # any callable (x, d) -> (rgb, sigma)
    scene.integrator().box = dataset.box           # the scene box the field lives in
    image = mi.render(scene)

Limitations (by design, not yet needed):

- The field cannot go through ``mi.load_dict``: Mitsuba's ``Properties`` only carry types
  exposed through nanobind, not Python callables. Set ``integrator.field`` (and the
  :class:`mitsnerf.math.box.Box` it lives in, ``integrator.box``) after loading; rendering
  before that raises an error that says so. The field is then part of the
  integrator object, not of the scene: ``mi.traverse`` does not see the field's parameters.
- Primal rendering only: this is a plain ``SamplingIntegrator``, without ``render_forward`` /
  ``render_backward``. Differentiate :func:`~mitsnerf.render.volume.render_rays` instead.
- Deterministic stratum midpoints (the evaluation setting): no per-sample jitter. Extra samples
  per pixel only average over the pixel area (with a box filter) and reduce nothing else.
- Scene geometry and media are ignored: the field is the whole content of ``integrator.box``;
  only the environment emitter is used (as the background).
"""

from __future__ import annotations

from typing import Any

import drjit as dr

NAME = "mitsnerf_ea"

#: Plugin classes already registered, by Mitsuba variant (the class derives from the variant's
#: ``mi.SamplingIntegrator``, so it is made per variant).
_CLASSES: dict[str, type] = {}


def _make_class():
    import mitsuba as mi

    from mitsnerf.render.background import EnvmapBackground
    from mitsnerf.render.volume import render_rays

    class EmissionAbsorptionIntegrator(mi.SamplingIntegrator):
        """The ``mitsnerf_ea`` integrator; see :mod:`mitsnerf.render.mitsuba_plugin`."""

        def __init__(self, props):
            super().__init__(props)
            n = props.get("n_samples", 128)
            if not isinstance(n, int) or n < 1:
                raise ValueError(f"{NAME}: n_samples must be an integer >= 1, got {n!r}")
            self.n_samples = n
            self.field: Any = None
            """``(x, d) -> (rgb, sigma)``; set after ``mi.load_dict``."""
            self.box: Any = None
            """The :class:`mitsnerf.math.box.Box` the field lives in; set after ``mi.load_dict``."""
            self.background: Any = None
            """``d -> Array3f``, a constant, or None: the scene's environment emitter."""

        def sample(self, scene, sampler, ray, medium=None, active=True):
            if self.field is None or self.box is None:
                raise RuntimeError(
                    f"{NAME}: no field to render; set scene.integrator().field = your field callable and "
                    "scene.integrator().box = its scene box after mi.load_dict (Mitsuba properties cannot "
                    "carry Python objects)"
                )
            background = self.background
            if background is None and scene.environment() is not None:
                background = EnvmapBackground(scene.environment())
            o = mi.Array3f(ray.o)
            d = mi.Array3f(ray.d)
            out = render_rays(self.field, o, d, self.n_samples, box=self.box, background=background)
            valid = dr.full(mi.Bool, True, dr.width(out.T_final))
            return mi.Spectrum(out.rgb), valid, []

        def aov_names(self):
            return []

        def to_string(self):
            return f"EmissionAbsorptionIntegrator[n_samples={self.n_samples}, field={self.field!r}]"

    return EmissionAbsorptionIntegrator


def register() -> type:
    """Register ``mitsnerf_ea`` for the current Mitsuba variant (idempotent); returns the class."""
    return register_once(NAME, _make_class, _CLASSES)


def register_once(name: str, make_class, classes: dict[str, type]) -> type:
    """Register the integrator ``make_class()`` builds under ``name`` for the current Mitsuba variant, once per
    variant (``classes``: the module's own cache, variant -> class, since a class binds one variant's types);
    returns the class."""
    import mitsuba as mi

    variant = mi.variant()
    if variant is None:
        raise RuntimeError(f"{name}: choose a Mitsuba variant first (mitsnerf.env.set_variant())")
    if variant not in classes:
        cls = make_class()
        mi.register_integrator(name, lambda props: cls(props))
        classes[variant] = cls
    return classes[variant]
