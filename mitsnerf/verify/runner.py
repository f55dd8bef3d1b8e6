"""Run the verification cases and print their table (``mitsnerf check``).

Each case gives one :class:`CaseResult`: what it was compared with, the measured error, the
z-statistics where the reference is Monte Carlo (largest per-pixel ``|z|``, pixel tests rejected
after Holm's correction, the image-mean z), pass/fail and the time. A failing comparison with
an image writes ``ours.exr``, ``reference.exr``, ``error.exr`` (ours - reference) and ``z.exr``
(|z|) to ``OUT/CASE/`` and names that directory in its detail line.

Every run takes an optional ``composite_fn``: the tests pass the broken variants of
:mod:`mitsnerf.verify.mutations` and require the cases that name them to fail.
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from mitsnerf.math.composite import composite
from mitsnerf.verify import cases as C
from mitsnerf.verify.stats import compare
from mitsnerf.math.box import UNIT_BOX


@dataclass(frozen=True)
class CaseResult:
    """One row of the table."""

    name: str
    reference: str
    error: str
    max_abs_z: float | None
    rejected: str
    passed: bool | None  # None: a record, not a check
    seconds: float
    detail: str = ""

    @property
    def status(self) -> str:
        return "info" if self.passed is None else ("pass" if self.passed else "FAIL")


class Artifacts:
    """Where failing cases write their images (a temporary directory made on first use if none given)."""

    def __init__(self, root: str | Path | None) -> None:
        self._root = Path(root) if root is not None else None

    def case_dir(self, name: str) -> Path:
        if self._root is None:
            self._root = Path(tempfile.mkdtemp(prefix="mitsnerf-check-"))
        path = self._root / name
        path.mkdir(parents=True, exist_ok=True)
        return path

    def write(self, name: str, images: dict[str, np.ndarray]) -> Path:
        from mitsnerf.data.images import write_exr

        path = self.case_dir(name)
        for key, image in images.items():
            write_exr(path / f"{key}.exr", np.asarray(image, dtype=np.float32))
        return path


# --------------------------------------------------------------------------- volpath scenarios


@dataclass(frozen=True)
class PreparedScenario:
    """A scenario's Mitsuba reference and the field/background the integrator renders (reusable)."""

    scenario: C.VolpathScenario
    quality: C.Quality
    reference: Any  # mitsuba_refs.Reference, (H, W, 3)
    field: Any
    background: Any


def _emitters(s: C.VolpathScenario) -> dict[str, dict]:
    from mitsnerf.verify import mitsuba_refs as M

    emitters: dict[str, dict] = {}
    if s.environment == "constant":
        emitters["environment"] = M.constant_environment(s.env_radiance)
    elif s.environment == "envmap":
        emitters["environment"] = M.envmap_environment(C.environment_bitmap())
    if s.sun_direction is not None:
        emitters["sun"] = M.directional_light(s.sun_direction, s.sun_irradiance)
    return emitters


def prepare_scenario(s: C.VolpathScenario, quality: C.Quality) -> PreparedScenario:
    """Render the volpath reference of ``s`` (the slow part) and build the matching field."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField
    from mitsnerf.render.background import EnvmapBackground
    from mitsnerf.verify import mitsuba_refs as M
    from mitsnerf.verify.sources import SingleScatterSource

    sigma_t, albedo = C.scenario_grids(s, quality.resolution)
    scene = mi.load_dict(M.scene_dict(sigma_t, albedo, _emitters(s), s.max_depth))
    camera = quality.camera()
    o, d = camera.pixel_rays()
    spp = max(16, int(round(quality.spp * s.spp_factor)))
    names = [x.name for x in C.SCENARIOS]  # a seed of its own per scenario: independent references
    seed = quality.seed * 1000 + (names.index(s.name) if s.name in names else len(names))
    ref = M.sample_rays(scene, o, d, spp, seed).reshaped(camera.height, camera.width)
    # The emitter object volpath saw, evaluated the same way (None: black).
    env = scene.environment()
    background = EnvmapBackground(env) if env is not None else None
    if s.source == "zero":
        field = GridField.from_arrays(sigma_t, UNIT_BOX, color=(0.0, 0.0, 0.0))
    elif s.source == "one":
        field = GridField.from_arrays(sigma_t, UNIT_BOX, color=(1.0, 1.0, 1.0))
    else:
        albedo_grid = albedo if np.ndim(albedo) else np.full(sigma_t.shape + (3,), float(albedo), np.float32)
        field = SingleScatterSource(GridField.from_arrays(sigma_t, UNIT_BOX), GridField.from_arrays(sigma_t, UNIT_BOX, color=albedo_grid),
                                    s.sun_direction, s.sun_irradiance, C.isotropic_phase())
    return PreparedScenario(s, quality, ref, field, background)


def evaluate_scenario(p: PreparedScenario, composite_fn=composite, artifacts: Artifacts | None = None) -> CaseResult:
    """Render the integrator's image and test it against the prepared reference."""
    from mitsnerf.verify.sources import render_image

    s, q, ref = p.scenario, p.quality, p.reference
    start = time.perf_counter()
    ours = render_image(p.field, q.camera(), q.n_samples, p.background, composite_fn)
    cmp = compare(ours, ref.mean, ref.var, ref.n, q.alpha, s.max_rel_error)
    checks = [cmp]
    reference = f"volpath {ref.n} spp" + (f", max_depth {s.max_depth}" if s.max_depth >= 0 else "")
    if s.compare_to_one:
        to_one = compare(np.ones_like(ref.mean), ref.mean, ref.var, ref.n, q.alpha, s.max_rel_error)
        checks.append(to_one)
        reference += "; volpath vs 1"
    passed = all(c.passed for c in checks)
    detail = "; ".join(c.summary() for c in checks)
    if not passed and artifacts is not None:
        path = artifacts.write(s.name, {"ours": ours, "reference": ref.mean, "error": ours - ref.mean,
                                        "z": np.abs(cmp.z)})
        detail += f"; images in {path}"
    worst = max(checks, key=lambda c: c.max_abs_z)
    return CaseResult(
        s.name, reference,
        f"rel. mean {max(c.rel_mean_error for c in checks):.1e} (<= {s.max_rel_error:g}), "
        f"mean z {max((c.z_mean for c in checks), key=abs):+.2f}",
        worst.max_abs_z,
        f"{sum(c.n_rejected for c in checks)}/{sum(c.z.size for c in checks)}",
        passed, ref.seconds + time.perf_counter() - start, detail,
    )


def run_scenario(s: C.VolpathScenario, quality: C.Quality, composite_fn=composite,
                 artifacts: Artifacts | None = None) -> CaseResult:
    return evaluate_scenario(prepare_scenario(s, quality), composite_fn, artifacts)


def furnace_depths(rec: C.FurnaceDepthRecord, quality: C.Quality) -> CaseResult:
    """Record volpath's white-furnace mean (pixels that see the medium) at each ``max_depth`` (-1: unlimited).

    A homogeneous box of ``rec.sigma_t``, albedo 1, environment 1. Every depth uses the same
    seed, so the depths share their first bounces: their differences are better resolved than
    each mean's ``+/-`` (one standard error) says.
    """
    import mitsuba as mi

    from mitsnerf.math.rays import to_array3f
    from mitsnerf.verify import mitsuba_refs as M

    start = time.perf_counter()
    r = quality.resolution
    camera = quality.camera()
    o, d = camera.pixel_rays()
    _, _, hit = intersect_box(to_array3f(mi.Array3f, o), to_array3f(mi.Array3f, d))
    hit = np.asarray(hit, dtype=bool)
    sigma = np.full((r, r, r), rec.sigma_t, np.float32)
    spp = max(16, int(round(quality.spp * rec.spp_factor)))
    parts, zs = [], []
    for depth in rec.max_depths:
        desc = M.scene_dict(sigma, 1.0, {"environment": M.constant_environment((1.0, 1.0, 1.0))}, depth)
        ref = M.sample_rays(mi.load_dict(desc), o[hit], d[hit], spp, quality.seed)
        mean = float(ref.mean.mean())
        se = math.sqrt(float(ref.var.sum()) / ref.n) / ref.mean.size
        zs.append((mean - 1.0) / se if se > 0 else 0.0)
        parts.append(f"{'inf' if depth < 0 else depth}: {mean:.4f}+/-{se:.4f}")
    return CaseResult(
        rec.name, f"volpath sigma_t {rec.sigma_t:g} furnace, {spp} spp, by max_depth",
        "mean " + ", ".join(parts), None, "-", None, time.perf_counter() - start,
        "z of (mean - 1) per depth: " + ", ".join(f"{z:+.1f}" for z in zs),
    )


# --------------------------------------------------------------------------- deterministic cases


def closed_form_case(case: C.ClosedFormCase, composite_fn=composite) -> CaseResult:
    from mitsnerf.verify.closed_form import run_closed_form

    r = run_closed_form(case, composite_fn)
    orders = r.orders
    return CaseResult(
        case.name, "closed forms; orders over N = 8..64",
        f"max rel {r.max_rel_error:.1e} (<= {case.rtol:g}); orders {orders['order_exit0']:.2f} (2), "
        f"{orders['order_linear']:.2f} (1)",
        None, "-", r.passed, r.seconds, "; ".join(r.failures),
    )


def gradient_case(case: C.GradientCase, quality: C.Quality, composite_fn=composite) -> CaseResult:
    from mitsnerf.verify.gradients import check_gradients

    r = check_gradients(case, quality, composite_fn)
    return CaseResult(
        case.name, f"central FD, eps {case.eps:g}",
        f"max rel {r.max_rel_error:.1e} (<= {case.rtol:g}); fwd {r.forward_ad:.4e} vs {r.forward_fd:.4e}",
        None, "-", r.passed, r.seconds, "; ".join(r.failures),
    )


def plugin_case(case: C.PluginCase, quality: C.Quality, composite_fn=composite,
                artifacts: Artifacts | None = None) -> CaseResult:
    """Render a field through ``mi.render`` with the ``mitsnerf_ea`` plugin and through the package."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField
    from mitsnerf.fields.nerf import NeRFConfig, NeRFField
    from mitsnerf.render.background import EnvmapBackground
    from mitsnerf.render.mitsuba_plugin import NAME, register
    from mitsnerf.verify import mitsuba_refs as M
    from mitsnerf.verify.sources import render_image

    start = time.perf_counter()
    register()
    camera = quality.camera()
    if case.field == "grid":
        r = quality.resolution
        field = GridField.from_arrays(C.front_heavy_sigma_t(r, 8.0), UNIT_BOX, color=C.procedural_albedo(r))
    else:
        field = NeRFField.create(NeRFConfig(width=32, depth=2, skip=None), mi.TensorXf, UNIT_BOX, seed=quality.seed + 1)
    env = (M.envmap_environment(C.environment_bitmap()) if case.environment == "envmap"
           else M.constant_environment((0.6, 0.8, 1.0)))
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": NAME, "n_samples": quality.n_samples},
        "sensor": M.sensor_dict(camera, 1, pixel_centres=True),
        "environment": env,
    })
    integrator = scene.integrator()
    integrator.field = field
    integrator.box = UNIT_BOX
    integrator.composite_fn = composite_fn
    theirs = np.asarray(mi.render(scene), dtype=np.float64)
    ours = render_image(field, camera, quality.n_samples, EnvmapBackground(scene.environment()))
    err = float(np.abs(theirs - ours).max())
    passed = err <= case.atol
    detail = ""
    if not passed and artifacts is not None:
        path = artifacts.write(case.name, {"ours": ours, "reference": theirs, "error": ours - theirs})
        detail = f"images in {path}"
    return CaseResult(case.name, "package render_rays, same pixels", f"max abs {err:.1e} (<= {case.atol:g})",
                      None, "-", passed, time.perf_counter() - start, detail)


# --------------------------------------------------------------------------- all of them


def run_checks(quality: C.Quality | str = "quick", out: str | Path | None = None,
               only: Iterable[str] | None = None, composite_fn=composite,
               progress: Callable[[CaseResult], None] | None = None) -> list[CaseResult]:
    """Run every case (or those named in ``only``); failing cases write images under ``out``."""
    from mitsnerf.errors import UsageError  # a ValueError naming the command-line option

    if isinstance(quality, str):
        if quality not in C.QUALITIES:
            raise UsageError("--quality", f"unknown quality {quality!r}; choose one of {', '.join(C.QUALITIES)}")
        quality = C.QUALITIES[quality]
    wanted = set(only) if only else None
    if wanted:
        unknown = wanted - set(C.ALL_CASE_NAMES)
        if unknown:
            raise UsageError("--case", f"unknown case(s) {', '.join(sorted(unknown))}; known: {', '.join(C.ALL_CASE_NAMES)}")
    artifacts = Artifacts(out)
    jobs: list[tuple[str, Callable[[], CaseResult]]] = [
        (C.CLOSED_FORM.name, lambda: closed_form_case(C.CLOSED_FORM, composite_fn))]
    jobs += [(s.name, lambda s=s: run_scenario(s, quality, composite_fn, artifacts)) for s in C.SCENARIOS]
    jobs += [(C.FURNACE_DEPTHS.name, lambda: furnace_depths(C.FURNACE_DEPTHS, quality))]
    jobs += [(g.name, lambda g=g: gradient_case(g, quality, composite_fn)) for g in C.GRADIENT_CASES]
    jobs += [(p.name, lambda p=p: plugin_case(p, quality, composite_fn, artifacts)) for p in C.PLUGIN_CASES]
    results = []
    for name, job in jobs:
        if wanted is None or name in wanted:
            results.append(job())
            if progress is not None:
                progress(results[-1])
    return results


def format_table(results: list[CaseResult]) -> str:
    """A fixed-width ASCII table: case, reference, measured error, max |z|, rejections, result, time."""
    header = ("case", "reference", "measured error", "max|z|", "rejected", "result", "time")
    rows = [header] + [
        (r.name, r.reference, r.error, "-" if r.max_abs_z is None else f"{r.max_abs_z:.2f}", r.rejected,
         r.status, f"{r.seconds:.1f} s")
        for r in results
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    notes = [f"{r.name}: {r.detail}" for r in results if r.detail and r.passed is not True]
    return "\n".join(lines + ([""] + notes if notes else []))
