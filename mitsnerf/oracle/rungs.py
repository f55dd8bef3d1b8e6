"""Ceilings per rung: the best a method can score on a dataset given the physics its colours can represent.

A method's rung (:attr:`mitsnerf.methods.base.Model.rung`) decides what its row is held against:

- ``emission-absorption``: the oracle (:mod:`mitsnerf.oracle`), the true ``sigma_t`` with the exact colour ``c =
  albedo [int p(w . d) L(x, w) dw + sum_l p(w_l . d) E_l T_l]`` (its view dependence in spherical harmonics up to
  the oracle's order): any colour field could hold it.
- ``single scattering``: the same oracle with the remainder of the in-scattered light (everything but the delta
  lights' unscattered light, which the rung computes exactly) projected on the method's own basis
  (:func:`project_remainder`): the orders ``l <= L_f`` whole, and for ``L_f < l <= L_z`` only the zonal harmonics
  around each delta light's direction (:mod:`mitsnerf.fields.scatter`). In an isotropic medium only order 0
  scatters (``g^l = 0`` above it), and the rung's ceiling is the oracle's.
- ``full transport``: a method whose renders are the physics itself (``mitsuba-inverse``) is held to the test
  views' own agreement: a perfect model scores 3.01 dB above two independent references' PSNR.

The projection, per band ``l`` of the coefficients ``a_lm`` (:func:`mitsnerf.oracle.source.radiance_sh`'s, at
each grid point): the zonal harmonic of order ``l`` around a unit ``s`` is ``sum_m z_m Y_lm`` with ``z_m =
sqrt(4 pi / (2 l + 1)) Y_lm(s)``, a unit vector (the addition theorem), so the band's part the basis keeps is
the least-squares projection of ``a_l`` on the span of the lights' ``z`` (one light: ``(a_l . z) z``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.math.box import Box

RUNGS = ("emission-absorption", "single scattering", "full transport")
"""The rungs of physics a method's colours can represent, lowest first."""
PERFECT_DB = 10 * math.log10(2)
"""How far above the reference agreement a perfect (noise-free) model scores: its error is one reference
render's noise, where two renders' difference holds two (half the MSE: +3.01 dB)."""


def project_remainder(sh: np.ndarray, axes: np.ndarray, degree: int, zonal: int) -> np.ndarray:
    """The coefficients ``sh`` (..., K, 3), ``K = (L + 1)^2`` (index ``l (l + 1) + m``), projected on the basis of
    orders ``l <= degree`` whole and the zonal harmonics around each of ``axes`` (..., n, 3) (unit directions,
    per point or shared) for ``degree < l <= zonal``; orders above ``max(degree, zonal)`` dropped. Returns
    (..., (max(degree, zonal, 0) + 1)^2 capped at K, 3).

    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> sh = np.zeros((4, 3)); sh[1:, 0] = [1.0, 2.0, 3.0]     # order 1 only, red
    >>> out = project_remainder(sh, np.array([[0.0, 0.0, 1.0]]), 0, 1)   # keep the part zonal around +z
    >>> out[:, 0].round(6).tolist()                                       # Y_10 is z's: 2 stays, 1 and 3 go
    [0.0, 0.0, 2.0, 0.0]
    """
    from mitsnerf.oracle.source import sh_basis

    full = math.isqrt(sh.shape[-2]) - 1
    top = min(full, max(degree, zonal))
    out = np.array(sh[..., : (top + 1) ** 2, :], dtype=np.float64, copy=True)
    axes = np.asarray(axes, np.float64)
    for order in range(degree + 1, top + 1):
        band = slice(order * order, (order + 1) ** 2)
        z = sh_basis(axes, order)[..., band] * math.sqrt(4.0 * math.pi / (2 * order + 1))  # (..., n, 2l + 1)
        z = np.broadcast_to(z, out.shape[:-2] + z.shape[-2:])
        gram = np.einsum("...im,...jm->...ij", z, z)
        coef = np.einsum("...im,...mc->...ic", z, out[..., band, :])                      # (..., n, 3)
        solved = np.linalg.solve(gram + 1e-9 * np.eye(gram.shape[-1]), coef)
        out[..., band, :] = np.einsum("...im,...ic->...mc", z, solved)
    return out


def light_axes(lights: Sequence[Any], box: Box, resolution: int) -> np.ndarray:
    """The directions the delta lights arrive from at the voxel centres of an ``R^3`` grid: (R, R, R, n, 3)."""
    from mitsnerf.scene.lights import toward_light

    points = box.voxel_centres(resolution).reshape(-1, 3)
    axes = np.stack([toward_light(light, points) for light in lights], axis=1) if lights else np.zeros((len(points),
                                                                                                          0, 3))
    return axes.reshape((resolution,) * 3 + (len(lights), 3))


def single_scattering_field(oracle_dir: Path, dataset, degree: int, zonal: int):
    """The directional oracle's field of ``dataset`` (its cached arrays in ``oracle_dir``) with the remainder projected
    on the single-scattering basis ``(degree, zonal)`` (:func:`project_remainder`), at the oracle's window."""
    import json

    from mitsnerf.oracle.cache import _grids
    from mitsnerf.oracle.directional import DirectionalConfig
    from mitsnerf.oracle.field import DirectionalOracleField
    from mitsnerf.scene.lights import delta_lights

    grids = _grids(dataset)
    if grids is None:
        raise ValueError(f"{dataset.root}: no spec or true grids, so no oracle")
    spec, sigma_t, albedo = grids
    info = json.loads((Path(oracle_dir) / "oracle.json").read_text())
    directional = DirectionalConfig(**{k: v for k, v in (info["config"].get("directional") or {}).items()})
    sh = np.load(Path(oracle_dir) / "lbar_sh.npy")
    lights = delta_lights(spec.lights)
    projected = project_remainder(sh, light_axes(lights, dataset.box, sh.shape[0]), degree, zonal)
    top = math.isqrt(projected.shape[-2]) - 1
    return DirectionalOracleField.from_grids(sigma_t, albedo, projected.astype(np.float32), spec.volume.phase.g,
                                             lights, np.load(Path(oracle_dir) / "delta_irradiance.npy"), dataset.box,
                                             order=top, window=directional.window), info


def _key(degree: int, zonal: int, footprint: int) -> str:
    return f"single scattering, L_f {degree}, L_z {zonal}, footprint {footprint}, with its Monte Carlo variance"


CEILING_KEYS = ("psnr_test_medium", "psnr_test_medium_without_mc", "mc_var_test_medium", "mc_note")
"""What a ceiling's figures hold (:func:`rung_ceiling`): its medium PSNR raw and less its own Monte Carlo variance
(:mod:`mitsnerf.scoring.variance`), that variance, and why the second is missing where it is."""


def rung_ceiling(rung: str | None, basis: tuple[int, int] | None, oracle, dataset, footprint: int, reference,
                 metrics: Mapping[str, Any]) -> dict[str, Any]:
    """The ceiling of a row on ``rung`` (module docstring): :data:`CEILING_KEYS` and ``note`` (what it is and what
    its variance-free figure rests on); ``metrics``: the row's own (its oracle's figures, the references'
    agreement). Empty where the rung has none here (no oracle; no references' agreement)."""
    if rung == "emission-absorption" and metrics.get("oracle_psnr_test_medium") is not None:
        found = {k: metrics.get(f"oracle_{k}") for k in CEILING_KEYS[:2]}
        found["mc_note"] = None if oracle is None else oracle.metrics(footprint).get("mc_note")
        return {**found, "note": "the oracle" + _variance_words(found, "its error patterns")}
    if rung == "single scattering" and oracle is not None and basis is not None:
        found = single_scattering_ceiling(oracle, dataset, *basis, footprint, reference)
        return {**found, "note": f"the oracle on the basis L_f {basis[0]}, L_z {basis[1]}"
                                 + _variance_words(found, found.get("variance_of") or "")}
    floor = metrics.get("noise_floor_psnr_medium")
    if rung == "full transport" and floor is not None:
        return {"psnr_test_medium": floor + PERFECT_DB, "psnr_test_medium_without_mc": floor + PERFECT_DB,
                "mc_var_test_medium": 0.0, "note": "a noise-free model's: the references' agreement + 3.01 dB, "
                                                   "no Monte Carlo of its own"}
    return {}


def ceiling_figures(rung: str | None, basis: tuple[int, int] | None, oracle, dataset, footprint: int, reference,
                    metrics: Mapping[str, Any]) -> dict[str, Any]:
    """What a row's table says of its ``rung``'s ceiling (:func:`rung_ceiling`; ``basis``: a single-scattering
    method's ``(L_f, L_z)``), as a bench cell and ``mitsnerf score RUN`` both record it: the ceiling's medium PSNR raw
    (``ceiling_psnr_test_medium``) and less its own Monte Carlo variance (``..._without_mc``), what it is
    (``ceiling_note``), and the gap between the two figures compared (``gap_to_ceiling``, each less its own Monte
    Carlo variance where that was measured: :func:`mitsnerf.scoring.variance.headline`); None where there is no
    ceiling. ``metrics``: the row's scores (``psnr_test_medium``, the oracle's, ``noise_floor_psnr_medium``)."""
    from mitsnerf.scoring.variance import headline

    ceiling = rung_ceiling(rung, basis, oracle, dataset, footprint, reference, metrics)
    top, medium = headline(ceiling), headline(dict(metrics))
    return {"ceiling_psnr_test_medium": ceiling.get("psnr_test_medium"),
            "ceiling_psnr_test_medium_without_mc": ceiling.get("psnr_test_medium_without_mc"),
            "ceiling_note": ceiling.get("note"),
            "gap_to_ceiling": None if top is None or medium is None else top - medium}


def _variance_words(found: dict, source: str) -> str:
    """How a ceiling's figure without its Monte Carlo variance was had, or why it is missing."""
    if found.get("psnr_test_medium_without_mc") is not None:
        return f", less its own Monte Carlo variance ({source})"
    return f", raw: {found.get('mc_note') or 'no estimate of its own Monte Carlo variance was kept'}"


def single_scattering_ceiling(oracle, dataset, degree: int, zonal: int, footprint: int, reference) -> dict[str, Any]:
    """The single-scattering rung's ceiling (:func:`score_on_basis`: :data:`CEILING_KEYS` and ``variance_of``); the
    oracle's own for an isotropic medium (only order 0 scatters). Computed once and kept in the oracle's directory
    (``rungs.json``)."""
    import json

    from mitsnerf.data.atomic import atomic_write_json
    from mitsnerf.data.cache import dataset_lock

    if "directional" not in oracle.info:
        return {**{k: oracle.metrics(footprint).get(k) for k in CEILING_KEYS},
                "variance_of": "the oracle's: isotropic, only order 0 scatters"}
    path = Path(oracle.path) / "rungs.json"
    key = _key(degree, zonal, footprint)
    with dataset_lock(path, progress=False):  # one writer at a time (a pool's workers share the oracle)
        found = json.loads(path.read_text()) if path.is_file() else {}
        if key not in found:
            found[key] = score_on_basis(oracle.path, dataset, degree, zonal, footprint, reference)
            atomic_write_json(path, found)
    return found[key]


def score_on_basis(oracle_dir, dataset, degree: int, zonal: int, footprint: int, reference) -> dict[str, Any]:
    """:data:`CEILING_KEYS` of :func:`single_scattering_field` (the directional oracle in ``oracle_dir`` with its
    remainder on the basis ``degree``/``zonal``) rendered at ``footprint`` and scored against ``reference`` (the test
    views'), its variance from :func:`basis_variance`, and ``variance_of`` (what that rests on); not cached."""
    from mitsnerf.oracle.field import render_field
    from mitsnerf.render.background import make_background
    from mitsnerf.scoring.views import score_views

    field, info = single_scattering_field(oracle_dir, dataset, degree, zonal)
    image = render_field(field, reference.cameras, dataset.box, int(info["config"]["n_samples"]),
                         background=make_background(dataset.background, dataset.root), footprint=footprint,
                         pixel_center=reference.pixel_center)
    variance, variance_of = basis_variance(oracle_dir, dataset, degree, zonal, footprint, reference)
    scores = score_views(image, reference, None, variance=variance)[0]
    return {**{k: scores.get(k) for k in CEILING_KEYS}, "variance_of": variance_of}


def basis_variance(oracle_dir, dataset, degree: int, zonal: int, footprint: int,
                   reference) -> tuple[np.ndarray | None, str]:
    """``(Var (V, H, W, 3) of the basis ceiling's render, what it rests on)``: the oracle's error patterns
    (``lbar_sh_errors.npy``) projected on the basis (:func:`project_remainder`, linear) and rendered
    (:func:`mitsnerf.oracle.directional.pattern_variance`); an oracle cached without them gives its own image's
    variance (``var_kK.npy``), which assumes the projection keeps all of it (and says so); None without either."""
    import json

    from mitsnerf.oracle.cache import _grids
    from mitsnerf.oracle.directional import pattern_variance
    from mitsnerf.scene.lights import delta_lights

    oracle_dir = Path(oracle_dir)
    if not (oracle_dir / "lbar_sh_errors.npy").is_file():
        full = oracle_dir / f"var_k{footprint}.npy"
        if not full.is_file():
            return None, "no variance of it kept"
        return np.load(full), "the full oracle's, assumed kept by the projection: its error patterns were not kept"
    grids = _grids(dataset)
    if grids is None:
        raise ValueError(f"{dataset.root}: no spec or true grids, so no oracle")
    spec, sigma_t, albedo = grids
    info = json.loads((oracle_dir / "oracle.json").read_text())
    patterns = np.load(oracle_dir / "lbar_sh_errors.npy")
    axes = light_axes(delta_lights(spec.lights), dataset.box, patterns.shape[1])
    projected = np.stack([project_remainder(p, axes, degree, zonal) for p in patterns]).astype(np.float32)
    window = (info["config"].get("directional") or {}).get("window", "lanczos")
    var = pattern_variance(projected, sigma_t, albedo, spec.volume.phase.g, reference.cameras, dataset.box,
                           int(info["config"]["n_samples"]), math.isqrt(projected.shape[-2]) - 1, window,
                           pixel_center=reference.pixel_center, footprint=footprint)
    return var, "the oracle's error patterns projected on the basis"
