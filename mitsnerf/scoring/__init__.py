"""Every score mitsnerf reports, each computed once, by one rule.

Dataset generation (the noise floor, the agreement tests), :func:`mitsnerf.runs.fit.fit`, the benchmark,
the oracle and ``mitsnerf score`` all score through this package; each module answers one question:

- :mod:`~mitsnerf.scoring.reference`: what are renders of a split scored against? Its
  :class:`~mitsnerf.scoring.reference.Reference` (images, cameras, true grid, medium pixels, noise floor),
  loaded once (:func:`~mitsnerf.scoring.reference.load_reference`) and passed along;
- :mod:`~mitsnerf.scoring.views`: every score of renders of a reference's views
  (:func:`~mitsnerf.scoring.views.score_views`), what a run and a benchmark cell record;
- :mod:`~mitsnerf.scoring.images`: how close are renders to their references? PSNR/SSIM linear and sRGB,
  on the medium pixels, the noise floor, the error budget against the oracle;
- :mod:`~mitsnerf.scoring.variance`: what would a Monte Carlo render score without its own variance? (the
  variance from two independent renders, or the estimate's own error patterns, taken off its MSE): every
  ceiling and every Monte Carlo row is compared on that figure, with the raw one beside it;
- :mod:`~mitsnerf.scoring.medium`: which pixels see the medium (the medium masks), and how much of its
  optical depth a fixed near/far keeps;
- :mod:`~mitsnerf.scoring.density`: how close is a learned density to the true one? On the voxel centres
  and as optical depth along the test rays, against ``sigma_t`` and an anisotropic medium's reduced
  extinction;
- :mod:`~mitsnerf.scoring.agreement`: do two estimators of the same images agree in expectation? The
  statistical tests of dataset verification (``critical_z``, ``ratio_z``, view, transmittance and
  composite agreement);
- :mod:`~mitsnerf.scoring.numbers`: scores as JSON numbers (None for NaN and infinities).
"""
