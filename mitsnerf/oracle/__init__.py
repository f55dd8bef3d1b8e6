"""The emission-absorption oracle: the best image any emission-absorption model can make of a dataset.

For an isotropic phase function volpath's radiance is exactly the emission-absorption integral
with ``sigma = sigma_t`` and the source ``c = J = albedo (1 / 4 pi) int L(x, w) dw``, the
in-scattered radiance, multiple scattering and the sun's transmitted light included. The oracle
estimates ``J`` with Mitsuba itself and composites it with the true ``sigma_t`` through the
package's own integrator:

- :mod:`mitsnerf.oracle.source`: ``J`` by volpath from points inside the medium, plus the delta
  lights' direct term from shadow-ray transmittance, with its Monte Carlo standard error;
- :mod:`mitsnerf.oracle.field`: the oracle field ``(x, d) -> (J(x) trilinear, sigma_t(x))``, its
  renders and their Monte Carlo variance;
- :mod:`mitsnerf.oracle.compare`: ``J`` at the integrator's own sample points against volpath on
  the same rays, the statistical agreement that accounts for ``J``'s noise (the check's case);
- :mod:`mitsnerf.oracle.cache`: a dataset's oracle computed once, cached and scored
  (``DATASET/oracle/<key>/``), the ceiling row of every benchmark table.

A medium with an anisotropic phase function (``volume.phase`` ``hg`` with ``g != 0``) has a view-dependent
colour, ``albedo int p(w . d) L(x, w) dw``: :mod:`mitsnerf.oracle.directional` expands the in-scattered light in
spherical harmonics (the delta lights exact), and its ceiling is scored at several orders.
"""
