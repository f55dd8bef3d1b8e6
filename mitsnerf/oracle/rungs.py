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
    return f"single scattering, L_f {degree}, L_z {zonal}, footprint {footprint}"


def single_scattering_ceiling(oracle, dataset, degree: int, zonal: int, footprint: int, reference) -> float | None:
    """Medium PSNR of the single-scattering rung's ceiling (:func:`score_on_basis`); the oracle's own for an
    isotropic medium (only order 0 scatters). Computed once and kept in the oracle's directory (``rungs.json``)."""
    import json

    from mitsnerf.data.atomic import atomic_write_json
    from mitsnerf.data.cache import dataset_lock

    if "directional" not in oracle.info:
        return oracle.metrics(footprint).get("psnr_test_medium")
    path = Path(oracle.path) / "rungs.json"
    key = _key(degree, zonal, footprint)
    with dataset_lock(path, progress=False):  # one writer at a time (a pool's workers share the oracle)
        found = json.loads(path.read_text()) if path.is_file() else {}
        if key not in found:
            found[key] = score_on_basis(oracle.path, dataset, degree, zonal, footprint, reference)
            atomic_write_json(path, found)
    return found[key]


def score_on_basis(oracle_dir, dataset, degree: int, zonal: int, footprint: int, reference) -> float | None:
    """Medium PSNR of :func:`single_scattering_field` (the directional oracle in ``oracle_dir`` with its remainder
    on the basis ``degree``/``zonal``) rendered at ``footprint`` and scored against ``reference`` (the test
    views'); not cached."""
    from mitsnerf.oracle.field import render_field
    from mitsnerf.render.background import make_background
    from mitsnerf.scoring.views import score_views

    field, info = single_scattering_field(oracle_dir, dataset, degree, zonal)
    image = render_field(field, reference.cameras, dataset.box, int(info["config"]["n_samples"]),
                         background=make_background(dataset.background, dataset.root), footprint=footprint,
                         pixel_center=reference.pixel_center)
    return score_views(image, reference, None)[0].get("psnr_test_medium")


def ceiling_figures(rung: str | None, basis: tuple[int, int] | None, oracle, dataset, footprint: int, reference,
                    metrics: Mapping[str, Any]) -> dict[str, Any]:
    """The ceiling of a row's ``rung`` on medium pixels and the gap to it, ``{"ceiling_psnr_test_medium": C,
    "gap_to_ceiling": C - metrics["psnr_test_medium"]}`` (None where there is no ceiling): the oracle's medium PSNR
    in ``metrics`` (emission-absorption); the oracle with its remainder on the method's basis ``(L_f, L_z)``
    (single scattering, :func:`single_scattering_ceiling`); the references' agreement + :data:`PERFECT_DB`
    (full transport). ``metrics``: the row's scores (``psnr_test_medium``, ``oracle_psnr_test_medium``,
    ``noise_floor_psnr_medium``)."""
    ceiling = None
    if rung == "emission-absorption":
        ceiling = metrics.get("oracle_psnr_test_medium")
    elif rung == "single scattering" and oracle is not None and basis is not None:
        ceiling = single_scattering_ceiling(oracle, dataset, basis[0], basis[1], footprint, reference)
    elif rung == "full transport" and metrics.get("noise_floor_psnr_medium") is not None:
        ceiling = metrics["noise_floor_psnr_medium"] + PERFECT_DB
    medium = metrics.get("psnr_test_medium")
    gap = None if ceiling is None or medium is None else ceiling - medium
    return {"ceiling_psnr_test_medium": ceiling, "gap_to_ceiling": gap}
