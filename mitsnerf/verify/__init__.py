"""Verification of the emission-absorption integrator against Mitsuba's ``volpath``, formulas and finite differences.

``mitsnerf check`` (:func:`mitsnerf.verify.runner.run_checks`) runs the cases of
:mod:`mitsnerf.verify.cases`. Every case compares with a reference that a bug in the
package's sampling or compositing cannot reach:

1. ``closed_form``: both quadrature rules against formulas (homogeneous box, piecewise-constant
   density, orders of convergence) -- :mod:`mitsnerf.verify.closed_form`;
2. volpath scenarios (:mod:`mitsnerf.verify.scenarios`): albedo 0 (``c = 0``) and single
   scattering of a directional light (``c = albedo p E T_light``), in media dense at the entry
   (seed's rule), homogeneous boxes (seed's rule against the closed form of its bias, and the
   midpoint rule) and media dense at the exit (midpoint rule; the seed's bias printed);
3. ``train_average``: the mean of jittered, training-mode renders against volpath, and
   ``sampler_jitter``: the training jitter's distribution -- :mod:`mitsnerf.verify.jitter`;
4. ``grad_*``: reverse- and forward-mode derivatives against central differences
   -- :mod:`mitsnerf.verify.gradients`;
5. ``plugin_*``: the ``mitsnerf_ea`` Mitsuba integrator plugin against an independent float64
   quadrature of the same samples -- :mod:`mitsnerf.verify.quadrature64`;
6. checks of Mitsuba itself, not of the integrator: ``mitsuba_furnace`` (volpath renders 1 in a
   white furnace) and the ``furnace_max_depth`` record.

The volpath comparisons are z-tests on the same rays, all tests of a scenario one family at a
family-wise alpha (:mod:`mitsnerf.verify.stats`, :mod:`mitsnerf.verify.mitsuba_refs`). Each
case names the planted bugs (:mod:`mitsnerf.verify.mutations`) it must detect;
``mitsnerf check --mutations`` prints which cases catch each.
"""
