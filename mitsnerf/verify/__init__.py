"""Verification of the emission-absorption integrator against Mitsuba's ``volpath`` and finite differences.

``mitsnerf check`` (:func:`mitsnerf.verify.runner.run_checks`) runs the cases of
:mod:`mitsnerf.verify.cases`:

1. ``closed_form``: the quadrature against formulas (homogeneous box, piecewise-constant
   density, order of convergence) -- :mod:`mitsnerf.verify.closed_form`;
2. ``absorption_*``: albedo 0 before a constant or an envmap environment, ``c = 0``;
3. ``white_furnace``: albedo 1, environment 1, unlimited depth, ``c = 1`` (and a record of how
   far volpath with a finite ``max_depth`` falls below 1);
4. ``single_scatter``: a directional light, ``c = albedo p E T_light``, volpath ``max_depth = 2``;
5. ``grad_*``: reverse- and forward-mode derivatives against central differences
   -- :mod:`mitsnerf.verify.gradients`;
6. ``plugin_*``: the ``mitsnerf_ea`` Mitsuba integrator plugin against the package's renderer.

Cases 2-4 compare with volpath on the same pixel-centre rays by z-tests
(:mod:`mitsnerf.verify.stats`, :mod:`mitsnerf.verify.mitsuba_refs`). Each case names the
deliberately broken compositing steps (:mod:`mitsnerf.verify.mutations`) it must detect.
"""
