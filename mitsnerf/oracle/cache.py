"""A dataset's oracle, computed once and cached with the dataset: ``DATASET/oracle/<key[:12]>/``.

The key is the sha256 of the oracle's settings (:class:`OracleConfig`), the footprint it is
scored at, the dataset's own hash (which covers the spec, the Mitsuba/Dr.Jit versions and the
variant) and :data:`ORACLE_FORMAT`. The directory is built in a temporary sibling and renamed
into place (:func:`mitsnerf.data.atomic.atomic_dir`) under a lock (one writer at a time), with
``oracle.json`` as its index::

    oracle.json        settings, key, timings, Monte Carlo error, scores summary, provenance
    scores.json        {"footprint_1": metrics, "footprint_K": metrics}  (mitsnerf.scoring.views.score_views; at K
                       also the medium PSNR less its own Monte Carlo variance, psnr_test_medium_without_mc)
    lbar_mc.npy        Lbar_mc (R, R, R, 3) and its standard error lbar_mc_se.npy
    lbar_delta.npy     the delta lights' term (R_d, R_d, R_d, 3)
    test_k1.npy        the oracle's test views (V, H, W, 3) at footprint 1, test_kK.npy at K
    var_kK.npy         their Monte Carlo variance at K (:func:`mitsnerf.oracle.field.image_variance`)

An anisotropic medium's oracle (:mod:`mitsnerf.oracle.directional`) keeps ``lbar_sh.npy`` (R, R, R, (L+1)^2, 3),
its standard error ``lbar_sh_se.npy``, its error patterns ``lbar_sh_errors.npy`` (replicas, R, R, R, (L+1)^2, 3:
what a projection of the coefficients, a rung's ceiling, takes its own variance from) and ``delta_irradiance.npy``
(R_d, R_d, R_d, lights, 3) instead of the ``lbar_*`` grids, and ``oracle.json``'s ``directional`` holds the medium
PSNR at each order scored.

The error of the oracle against ``test`` splits into what it cannot help and what it adds::

    MSE(oracle, test) = s_ref^2 + Var_mc + bias^2,   s_ref^2 = MSE(test, test_ref) / 2

(``s_ref^2``: the test views' own noise; ``Var_mc``: the oracle's from ``Lbar_mc``; ``bias^2``:
grid interpolation, quadrature and footprint), each a mean over medium pixels in ``oracle.json``. The oracle's
ceiling is its medium PSNR without ``Var_mc`` (:mod:`mitsnerf.scoring.variance`, per view from ``var_kK.npy``),
the raw figure beside it; an oracle cached before that figure was kept gets it once, from its cached renders
(:func:`variance_free`).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mitsnerf.config import check_fields, param, to_dict
from mitsnerf.oracle.directional import DirectionalConfig

if TYPE_CHECKING:
    from mitsnerf.scoring.reference import Reference

ORACLE_FORMAT = 1
ORACLE_DIR = "oracle"


@dataclass(frozen=True)
class OracleConfig:
    """How a dataset's oracle is computed (every field is part of its cache key).

    The defaults, measured on the default cloud (64^3 sigma_t, docs/notes/oracle.md): on a 32^3
    grid the interpolation bias of ``Lbar_mc`` is ~15x below the test views' own noise (16^3: 2x
    above it), and per volpath sample a 32^3 grid with more directions beats a 64^3 one; 128
    directions put the oracle's Monte Carlo variance at about half the test views' noise.
    """

    spp: int = param(128, lo=2, doc="volpath directions per grid point for Lbar_mc")
    resolution: int = param(32, lo=0, doc="Lbar_mc grid R (0: the true sigma_t grid's)")
    delta_resolution: int = param(0, lo=0, doc="grid of the delta lights' term (0: the true sigma_t grid's)")
    n_samples: int = param(128, lo=1, doc="the integrator's samples per ray N")
    noise_replicas: int = param(1, lo=1, doc="sign patterns for the image's Monte Carlo variance")
    seed: int = param(0, lo=0, doc="seed of the volpath samples")
    enabled: bool = param(True, doc="compute the oracle (false: no ceiling row, no error budget)")
    directional: DirectionalConfig | None = param(None, doc="anisotropic media: the directional oracle's settings "
                                                            "(order, window; None: the defaults)")

    def __post_init__(self) -> None:
        check_fields(self)
        for name in ("resolution", "delta_resolution"):
            if getattr(self, name) == 1:
                raise ValueError(f"{name}: must be 0 (the true grid's) or >= 2, got 1")


def oracle_key(dataset_hash: str, config: OracleConfig, footprint: int) -> str:
    """sha256 of what decides the oracle (module docstring).

    >>> oracle_key("abc", OracleConfig(), 3) == oracle_key("abc", OracleConfig(spp=128), 3)
    True
    >>> oracle_key("abc", OracleConfig(), 3) == oracle_key("abc", OracleConfig(), 1)
    False
    """
    import hashlib

    text = json.dumps({"dataset": dataset_hash, "config": to_dict(config), "footprint": int(footprint),
                       "format": ORACLE_FORMAT}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class Oracle:
    """A computed (or cached) oracle: ``info`` (``oracle.json``) and ``scores`` per footprint."""

    path: Path | None
    info: dict
    scores: dict

    def metrics(self, footprint: int) -> dict:
        """``score_views`` metrics of the oracle's test views rendered at ``footprint`` (1 or the scored K)."""
        return self.scores[f"footprint_{int(footprint)}"]


def _grids(dataset) -> tuple[Any, np.ndarray, np.ndarray] | None:
    """``(spec, sigma_t, albedo)`` of a generated dataset; None for foreign data (no spec or grids)."""
    from mitsnerf.data.dataset import true_grid_path
    from mitsnerf.scene.spec import parse_scene

    spec_data = (dataset.manifest or {}).get("spec")
    sigma_t, albedo = (true_grid_path(dataset.root, name) for name in ("sigma_t", "albedo"))
    if not spec_data or not sigma_t.is_file() or not albedo.is_file():
        return None
    spec = parse_scene(spec_data, Path(dataset.root) / "manifest.json")
    return spec, np.load(sigma_t), np.load(albedo)


def _inner_scene(spec, sigma_t: np.ndarray, albedo: np.ndarray):
    """The Mitsuba scene volpath estimates the in-scattered light in (None: nothing in-scatters)."""
    import mitsuba as mi

    from mitsnerf.oracle.source import inner_max_depth
    from mitsnerf.scene.to_mitsuba import scene_dict

    depth = inner_max_depth(spec.render.max_depth)
    if depth is None:
        return None
    description = scene_dict(spec, sigma_t, albedo)
    description["integrator"] = {"type": "volpath", "max_depth": depth}
    return mi.load_dict(description)


def estimate_source(spec, sigma_t: np.ndarray, albedo: np.ndarray, box, config: OracleConfig):
    """``(SourceGrids, OracleField)`` of an isotropic scene: ``Lbar`` estimated by volpath from inside the medium."""
    from mitsnerf.oracle.field import OracleField
    from mitsnerf.oracle.source import estimate_grids

    r = config.resolution or sigma_t.shape[0]
    r_delta = config.delta_resolution or sigma_t.shape[0]
    grids = estimate_grids(_inner_scene(spec, sigma_t, albedo), spec.lights, sigma_t, box, r, r_delta, config.spp,
                           config.seed)
    return grids, OracleField.from_grids(sigma_t, albedo, grids.mc, grids.delta, box)


@dataclass(frozen=True)
class _Estimate:
    """What an oracle's estimate gives the renders: the field, the fields at lower orders (directional),
    the image variance at a footprint, the arrays to cache and what ``oracle.json`` says of it."""

    field: Any
    by_order: dict[int, Any]
    variance: Callable[[Any, int, float], np.ndarray]
    arrays: dict[str, np.ndarray]
    info: dict[str, Any]


def _rel_se(mean: np.ndarray, se: np.ndarray) -> dict[str, float | None]:
    needed = se.any(axis=-1) | (mean != 0).any(axis=-1)
    rel = se[needed] / np.maximum(np.abs(mean[needed]), 1e-12)
    return {"lbar_rel_se_median": float(np.median(rel)) if rel.size else None,
            "lbar_rel_se_p90": float(np.quantile(rel, 0.9)) if rel.size else None}


def _isotropic(spec, sigma_t: np.ndarray, albedo: np.ndarray, box, config: OracleConfig) -> _Estimate:
    from mitsnerf.oracle.field import image_variance

    grids, field = estimate_source(spec, sigma_t, albedo, box, config)

    def variance(cameras, footprint: int, pixel_center: float) -> np.ndarray:
        return image_variance(sigma_t, albedo, grids.mc_se, cameras, box, config.n_samples, pixel_center=pixel_center,
                              footprint=footprint, replicas=config.noise_replicas, seed=config.seed)

    info = {"grid_points": grids.points, "volpath_samples": grids.points * grids.spp, "seconds": dict(grids.seconds),
            "mc_error": _rel_se(grids.mc, grids.mc_se)}
    return _Estimate(field, {}, variance, {"lbar_mc": grids.mc, "lbar_mc_se": grids.mc_se, "lbar_delta": grids.delta},
                     info)


def _directional(spec, sigma_t: np.ndarray, albedo: np.ndarray, box, config: OracleConfig) -> _Estimate:
    from mitsnerf.oracle import directional as D

    dc = config.directional or D.DirectionalConfig()
    r = config.resolution or sigma_t.shape[0]
    r_delta = config.delta_resolution or sigma_t.shape[0]
    grids = D.estimate(_inner_scene(spec, sigma_t, albedo), spec.lights, spec.volume.phase.g, sigma_t, box, r,
                       r_delta, dc.spp or config.spp, dc.order, config.seed, config.noise_replicas)
    by_order = {o: D.oracle_field(grids, sigma_t, albedo, box, o, dc.window) for o in dc.orders()}

    def variance(cameras, footprint: int, pixel_center: float) -> np.ndarray:
        return D.image_variance(grids, sigma_t, albedo, cameras, box, config.n_samples, dc, pixel_center=pixel_center,
                                footprint=footprint)

    info = {"grid_points": grids.points, "volpath_samples": grids.points * grids.spp, "seconds": dict(grids.seconds),
            "mc_error": _rel_se(grids.sh[..., 0, :], grids.sh_se[..., 0, :]),
            "directional": {"g": grids.g, "order": dc.order, "window": dc.window,
                            "rule": "mitsnerf.oracle.directional: L(x, w) in real spherical harmonics up to order, "
                                    "times g^l and the window per band, clamped at 0; the delta lights exact"}}
    arrays = {"lbar_sh": grids.sh, "lbar_sh_se": grids.sh_se, "lbar_sh_errors": grids.sh_errors,
              "delta_irradiance": grids.irradiance}
    return _Estimate(by_order[dc.order], by_order, variance, arrays, info)


def _medium_mean(values: np.ndarray, masks: np.ndarray) -> float:
    return float(np.mean(values[masks])) if masks.any() else float("nan")


def error_split(oracle: np.ndarray, var: np.ndarray, ref, test_ref: np.ndarray | None) -> dict[str, Any]:
    """``MSE(oracle, test) = s_ref^2 + Var_mc + bias^2`` over medium pixels (module docstring), with PSNRs."""
    if ref.masks is None:
        return {}
    masks = ref.masks
    total = _medium_mean(np.square(oracle - ref.images).mean(-1), masks)
    out: dict[str, Any] = {"mse_medium": total, "mc_var_medium": _medium_mean(var.mean(-1), masks)}
    # the pooled medium PSNR the oracle would score without its own Monte Carlo noise
    out["psnr_medium_without_mc"] = float(-10.0 * np.log10(max(total - out["mc_var_medium"], 1e-30)))
    if test_ref is not None:
        out["ref_var_medium"] = 0.5 * _medium_mean(np.square(test_ref - ref.images).mean(-1), masks)
        out["bias2_medium"] = total - out["ref_var_medium"] - out["mc_var_medium"]
    out["note"] = ("mean over medium pixels and channels; MSE = ref_var + mc_var + bias2 (bias2 by difference: "
                   "grid interpolation, quadrature, footprint); PSNR of a term x alone: -10 log10(x)")
    return out


def compute_oracle(dataset, config: OracleConfig, footprint: int, log: Callable[[str], None] = lambda line: None,
                   reference: Reference | None = None) -> tuple[dict, dict, dict[str, np.ndarray]] | None:
    """``(info, scores, arrays)`` of the oracle of ``dataset``'s test views (None for foreign data); ``reference``:
    the test views' :class:`~mitsnerf.scoring.reference.Reference` if the caller has it (else loaded here).

    An isotropic medium's colour is ``J(x)`` (:mod:`mitsnerf.oracle.source`); an anisotropic one's depends on the
    view direction (:mod:`mitsnerf.oracle.directional`), and its ceiling is also scored at the lower orders."""
    from mitsnerf import env
    from mitsnerf.oracle.field import render_field
    from mitsnerf.render.background import make_background
    from mitsnerf.scene.spec import is_isotropic
    from mitsnerf.scoring.density import true_density
    from mitsnerf.scoring.reference import load_reference
    from mitsnerf.scoring.views import score_views

    inputs = _grids(dataset)
    if inputs is None:
        return None
    spec, sigma_t, albedo = inputs
    config = resolved(config, spec)
    ref = reference or load_reference(dataset, "test")
    spp = config.directional.spp or config.spp if config.directional is not None else config.spp
    log(f"oracle: the in-scattered light by volpath from inside the medium ({spp} directions per point) ...")
    est = (_isotropic if is_isotropic(spec.volume.phase) else _directional)(spec, sigma_t, albedo, dataset.box, config)
    seconds = est.info.pop("seconds")
    start = time.perf_counter()
    background = make_background(dataset.background, dataset.root)

    def render(field, k: int) -> np.ndarray:
        return render_field(field, ref.cameras, dataset.box, config.n_samples, background=background, footprint=k,
                            pixel_center=ref.pixel_center)

    renders = {k: render(est.field, k) for k in sorted({1, int(footprint)})}
    seconds["render"] = time.perf_counter() - start
    var = est.variance(ref.cameras, int(footprint), ref.pixel_center)
    seconds["variance"] = time.perf_counter() - start - seconds["render"]
    density = true_density(sigma_t, dataset.box)
    scores = {f"footprint_{k}": score_views(img, ref, density, variance=var if k == int(footprint) else None)[0]
              for k, img in renders.items()}
    if est.by_order:
        est.info["directional"]["psnr_test_medium_by_order"] = {
            str(o): score_views(render(f, int(footprint)), ref, None)[0].get("psnr_test_medium")
            for o, f in est.by_order.items()}
    test_ref = dataset.views("test_ref").images if "test_ref" in dataset.splits else None
    info = {
        "format": ORACLE_FORMAT, "config": to_dict(config), "footprint": int(footprint),
        "dataset_hash": dataset.manifest.get("hash"), "max_depth": spec.render.max_depth, **est.info,
        "seconds": seconds, "error_split": error_split(renders[int(footprint)], var, ref, test_ref),
        "psnr_test_medium": {k: s.get("psnr_test_medium") for k, s in scores.items()},
        "noise_floor_psnr_medium": (ref.noise_floor or {}).get("psnr_medium"), "provenance": env.provenance(),
    }
    arrays = {**est.arrays, f"var_k{footprint}": var.astype(np.float32)}
    arrays.update({f"test_k{k}": img for k, img in renders.items()})
    return info, scores, arrays


def resolved(config: OracleConfig, spec) -> OracleConfig:
    """``config`` as it applies to the medium of ``spec``: an anisotropic one's with its directional settings
    spelt out (None: :class:`DirectionalConfig`'s defaults), so that they are part of its key."""
    from mitsnerf.scene.spec import is_isotropic

    if spec is None or config.directional is not None or is_isotropic(spec.volume.phase):
        return config
    return replace(config, directional=DirectionalConfig())


def oracle_path(dataset, config: OracleConfig, footprint: int) -> Path:
    """Where ``dataset``'s oracle for these settings is cached (:func:`resolved` settings)."""
    config = resolved(config, (_grids(dataset) or (None,))[0])
    return Path(dataset.root) / ORACLE_DIR / oracle_key(str(dataset.manifest.get("hash")), config, footprint)[:12]


def load_oracle(path: Path) -> Oracle | None:
    """The oracle cached at ``path`` (None when it is not there or not complete)."""
    try:
        info = json.loads((path / "oracle.json").read_text(encoding="utf-8"))
        scores = json.loads((path / "scores.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return Oracle(path, info, scores) if info.get("format") == ORACLE_FORMAT else None


def ensure_oracle(dataset, config: OracleConfig, footprint: int, log: Callable[[str], None] = lambda line: None,
                  reference: Reference | None = None) -> Oracle | None:
    """The cached oracle of ``dataset``, computed and written first if missing (None for foreign data);
    ``reference``: its test views' :class:`~mitsnerf.scoring.reference.Reference`, if the caller has it.

    One writer at a time (a lock next to the directory); ``oracle.json`` is written last inside
    a temporary directory renamed into place, so an interrupted run leaves no complete-looking oracle. Returned
    with its medium PSNR less its own Monte Carlo variance (:func:`variance_free`).
    """
    from mitsnerf.data.cache import dataset_lock

    inputs = _grids(dataset)
    if inputs is None:
        return None
    config = resolved(config, inputs[0])
    path = oracle_path(dataset, config, footprint)
    found = load_oracle(path)
    if found is None:
        with dataset_lock(path, progress=False):
            found = load_oracle(path) or _computed(dataset, config, footprint, log, reference, path)
    return variance_free(found, dataset, footprint, reference)


def _computed(dataset, config: OracleConfig, footprint: int, log: Callable[[str], None], reference,
              path: Path) -> Oracle:
    """The oracle computed and written at ``path`` (under the caller's lock): ``oracle.json`` last."""
    from mitsnerf.data.atomic import atomic_dir, atomic_write_json, clean_stale_temps

    clean_stale_temps(path.parent, min_age_s=0.0)
    computed = compute_oracle(dataset, config, footprint, log, reference)
    if computed is None:  # checked by the caller: the dataset has its grids
        raise AssertionError(f"{dataset.root}: grids found, yet no oracle computed")
    info, scores, arrays = computed
    info["key"] = oracle_key(str(dataset.manifest.get("hash")), config, footprint)
    with atomic_dir(path, overwrite=True) as tmp:
        for name, array in arrays.items():
            np.save(tmp / f"{name}.npy", np.ascontiguousarray(array))
        atomic_write_json(tmp / "scores.json", scores)
        atomic_write_json(tmp / "oracle.json", info)
    found = load_oracle(path)
    if found is None:
        raise AssertionError(f"{path}: written, yet not read back")
    return found


def variance_free(oracle: Oracle, dataset, footprint: int, reference: Reference | None = None) -> Oracle:
    """``oracle`` with its medium PSNR at ``footprint`` less its own Monte Carlo variance
    (:func:`mitsnerf.scoring.variance.without_variance` of its cached ``test_kK.npy`` and ``var_kK.npy`` against
    ``reference``, the test views', loaded if None): an oracle cached before that figure was kept gets it once,
    written into its ``scores.json`` (under its lock); as it was where it has it or no variance was cached."""
    import json

    from mitsnerf.data.atomic import atomic_write_json
    from mitsnerf.data.cache import dataset_lock
    from mitsnerf.scoring.reference import load_reference
    from mitsnerf.scoring.variance import WITHOUT_MC, without_variance

    key, path = f"footprint_{int(footprint)}", oracle.path
    if path is None or "psnr_test_medium" + WITHOUT_MC in oracle.scores.get(key, {}) \
            or not (path / f"var_k{footprint}.npy").is_file() or not (path / f"test_k{footprint}.npy").is_file():
        return oracle
    ref = reference or load_reference(dataset, "test")
    found = without_variance(np.load(path / f"test_k{footprint}.npy"), ref.images, ref.masks,
                             np.load(path / f"var_k{footprint}.npy"))
    with dataset_lock(path, progress=False):
        scores = json.loads((path / "scores.json").read_text(encoding="utf-8"))
        scores[key] = {**scores.get(key, {}), **found}
        atomic_write_json(path / "scores.json", scores)
    return load_oracle(path) or oracle
