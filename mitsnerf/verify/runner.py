"""Run the verification cases and print their table (``mitsnerf check``), or the mutation matrix (``--mutations``).

Each case gives one :class:`CaseResult`: what it checks (the integrator, the sampler, the
plugin, gradients, or Mitsuba itself), what it was compared with, the measured error, the
z-statistics where the reference is Monte Carlo (largest per-pixel ``|z|``, tests rejected out
of the scenario's one family), pass/fail and the time. A failing comparison with an image
writes its images (``ours_*.exr``, ``reference.exr``, ``error_*.exr``, ``z_*.exr``) to
``OUT/CASE/`` and names that directory in its detail line.

:func:`run_mutations` renders the Mitsuba references once, runs every case clean, then every
case under every mutation of :mod:`mitsnerf.verify.mutations` (planted in the package's own
functions) and reports which cases catch each.
"""

from __future__ import annotations

import functools
import math
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.errors import UsageError  # a ValueError naming the command-line option
from mitsnerf.math.box import UNIT_BOX
from mitsnerf.verify import cases as C
from mitsnerf.verify import scenarios as S
from mitsnerf.verify.mutations import MUTATION_LIST, MUTATIONS, Mutation, planted


@dataclass(frozen=True)
class CaseResult:
    """One row of the table."""

    name: str
    checks: str  # what is under test: integrator, training path, sampler, plugin, gradients, Mitsuba
    reference: str
    error: str
    max_abs_z: float | None
    rejected: str
    passed: bool | None  # None: a record, not a check
    seconds: float
    detail: str = ""
    """Why it failed (printed under the table for failures)."""
    note: str = ""
    """Printed under the table whatever the result (measured biases and the like)."""
    evidence: str = ""
    """The statistic that decides a failure, short (the mutation matrix prints it)."""

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
            image = np.asarray(image, dtype=np.float32)  # RGBA: Mitsuba's film, premultiplied
            write_exr(path / f"{key}.exr", image, alpha="premultiplied" if image.shape[-1] == 4 else None)
        return path


def _family_result(name: str, checks: str, o: S.Outcome, artifacts: Artifacts | None) -> CaseResult:
    f = o.family
    detail = "" if f.passed else f.summary()
    if not f.passed and artifacts is not None:
        detail += f"; images in {artifacts.write(name, o.images)}"
    bound = min(t.max_rel_error for t in f.tests)
    worst = max(f.tests, key=lambda t: t.rel_mean_error / t.max_rel_error)
    evidence = (f"mean z {f.z_mean:+.1f}" if f.mean_rejected_any else
                f"{f.n_rejected} px" if f.n_rejected else f"rel. mean {worst.rel_mean_error:.1e}")
    return CaseResult(
        name,
        checks,
        o.reference,
        f"rel. mean {f.rel_mean_error:.1e} (<= {bound:g}), mean z {f.z_mean:+.2f}",
        f.max_abs_z,
        f"{f.n_rejected_all}/{f.n_tests}",
        f.passed,
        o.seconds,
        detail,
        o.note,
        evidence,
    )


# --------------------------------------------------------------------------- deterministic cases


def closed_form_case(case: C.ClosedFormCase) -> CaseResult:
    from mitsnerf.verify.closed_form import run_closed_form

    r = run_closed_form(case)
    o = r.orders
    return CaseResult(
        case.name, "integrator", "closed forms; orders over N = 8..64",
        f"max rel {r.max_rel_error:.1e} (<= {case.rtol:g}); orders {o['order_exit0']:.2f} (2), "
        f"{o['order_linear']:.2f} (1), midpoint {o['order_midpoint']:.2f} (2)",
        None, "-", r.passed, r.seconds, "; ".join(r.failures),
        evidence=r.failures[0].split(":")[0] if r.failures else "")


def gradient_case(case: C.GradientCase, quality: C.Quality) -> CaseResult:
    from mitsnerf.verify.gradients import check_gradients

    r = check_gradients(case, quality)
    return CaseResult(
        case.name, "gradients", f"central FD, eps {case.eps:g} (entries), {case.eps_direction:g} (along v)",
        f"entries max rel {r.max_rel_error:.1e} (<= {case.rtol:g}); along v {r.direction_rel_error:.1e} "
        f"(<= {case.rtol_direction:g})",
        None, "-", r.passed, r.seconds, "; ".join(r.failures),
        evidence=f"along v {r.direction_rel_error:.1e}" if r.direction_rel_error > case.rtol_direction
        else f"entries {r.max_rel_error:.1e}")


def drt_case(prepared, artifacts: Artifacts | None = None) -> CaseResult:
    """``mitsnerf_drt``'s primal and gradient expectation against volpath (:mod:`mitsnerf.verify.drt`)."""
    from mitsnerf.verify.drt import evaluate_drt

    r = evaluate_drt(prepared)
    f = r.family
    worst = max(r.gradient, key=lambda k: abs(r.gradient[k][0] - r.finite_difference[k][0])
                / math.hypot(r.gradient[k][1], r.finite_difference[k][1]))
    g, d = r.gradient[worst], r.finite_difference[worst]
    detail = "" if f.passed else f.summary()
    case = prepared.case
    return CaseResult(
        case.name, "gradients", f"volpath image and FD along {len(r.gradient)} directions ({case.renders} renders "
        f"x {case.spp} spp)", f"{worst}: {g[0]:.3g}+/-{g[1]:.2g} vs FD {d[0]:.3g}+/-{d[1]:.2g}",
        f.max_abs_z, f"{f.n_rejected_all}/{f.n_tests}", f.passed, r.seconds + prepared.seconds, detail,
        evidence=f"mean z {f.z_mean:+.1f}" if f.mean_rejected_any else f"{f.n_rejected} px")


def jitter_case(case: C.JitterCase, quality: C.Quality) -> CaseResult:
    from mitsnerf.verify.jitter import check_jitter

    r = check_jitter(case, quality)
    detail = "; ".join(list(r.failures) + ([f"rejected: {', '.join(r.rejected)}"] if r.rejected else []))
    return CaseResult(
        case.name, "sampler", f"U[0,1) in each stratum, independent; exact intervals ({r.n_rays} rays x {r.n_samples})",
        f"KS D {r.ks_d:.3f} (p {r.ks_p:.2f}), stratum z {r.worst_stratum_z:+.2f}, neighbours z {r.neighbour_z:+.2f}, "
        f"steps z {r.steps_z:+.2f}; intervals {r.max_interval_error:.0e}",
        None, f"{len(r.rejected)}/{r.n_tests}", r.passed, r.seconds, detail,
        evidence=(r.failures[0].split(":")[0] if r.failures else ", ".join(r.rejected[:2])))


def plugin_case(case: C.PluginCase, quality: C.Quality, artifacts: Artifacts | None = None) -> CaseResult:
    """Render a field through ``mi.render`` with the ``mitsnerf_ea`` plugin; compare with the float64 quadrature."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField
    from mitsnerf.fields.nerf import NeRFConfig, NeRFField
    from mitsnerf.render.mitsuba_plugin import NAME, register
    from mitsnerf.verify import mitsuba_refs as M
    from mitsnerf.verify import quadrature64 as Q

    start = time.perf_counter()
    register()
    camera = quality.camera()
    field: GridField | NeRFField
    if case.field == "grid":
        r = quality.resolution
        field = GridField.from_arrays(C.exit_heavy_sigma_t(r, 8.0), UNIT_BOX, color=C.procedural_albedo(r))
    else:
        field = NeRFField.create(NeRFConfig(width=32, depth=2, skip=None), mi.TensorXf, UNIT_BOX,
                                 seed=quality.seed + 1)
    env = (M.envmap_environment(C.environment_bitmap()) if case.environment == "envmap"
           else M.constant_environment((0.6, 0.8, 1.0)))
    scene = mi.load_dict({"type": "scene", "integrator": {"type": NAME, "n_samples": quality.n_samples},
                          "sensor": M.sensor_dict(camera, 1, pixel_centres=True), "environment": env})
    scene.integrator().field = field
    scene.integrator().box = UNIT_BOX
    theirs = np.asarray(mi.render(scene), dtype=np.float64)
    o, d = camera.pixel_rays()
    reference = Q.render(field, o, d, quality.n_samples, Q.environment_radiance(scene.environment(), d))
    reference = reference.reshape(theirs.shape)
    err = float(np.abs(theirs - reference).max())
    passed = err <= case.atol
    detail = ""
    if not passed and artifacts is not None:
        path = artifacts.write(case.name, {"ours": theirs, "reference": reference, "error": theirs - reference})
        detail = f"images in {path}"
    return CaseResult(case.name, "plugin", "float64 quadrature of the same samples (numpy)",
                      f"max abs {err:.1e} (<= {case.atol:g})", None, "-", passed, time.perf_counter() - start,
                      detail, evidence=f"max abs {err:.1e}")


# --------------------------------------------------------------------------- records and Mitsuba


def furnace_depths(rec: C.FurnaceDepthRecord, quality: C.Quality) -> CaseResult:
    """Record volpath's white-furnace mean (pixels that see the medium) at each ``max_depth`` (-1: unlimited).

    A homogeneous box of ``rec.sigma_t``, albedo 1, environment 1. Every depth uses the same
    seed, so the depths share their first bounces: their differences are better resolved than
    each mean's ``+/-`` (one standard error) says.
    """
    import math

    import mitsuba as mi

    from mitsnerf.verify import mitsuba_refs as M

    start = time.perf_counter()
    r = quality.resolution
    o, d = quality.camera().pixel_rays()
    t_n, t_f, _ = UNIT_BOX.intersect_numpy(o, d)
    hit = t_f > t_n
    sigma = np.full((r, r, r), rec.sigma_t, np.float32)
    spp = quality.reference_spp(rec.spp_factor)
    parts, zs = [], []
    for depth in rec.max_depths:
        desc = M.scene_dict(sigma, 1.0, {"environment": M.constant_environment((1.0, 1.0, 1.0))}, depth)
        ref = M.sample_rays(mi.load_dict(desc), o[hit], d[hit], spp, quality.seed)
        mean = float(ref.mean.mean())
        se = math.sqrt(float(ref.var.sum()) / ref.n) / ref.mean.size
        zs.append((mean - 1.0) / se if se > 0 else 0.0)
        parts.append(f"{'inf' if depth < 0 else depth}: {mean:.4f}+/-{se:.4f}")
    return CaseResult(
        rec.name, "record", f"volpath sigma_t {rec.sigma_t:g} furnace, {spp} spp, by max_depth",
        "mean " + ", ".join(parts), None, "-", None, time.perf_counter() - start,
        note="z of (mean - 1) per depth: " + ", ".join(f"{z:+.1f}" for z in zs),
    )


# --------------------------------------------------------------------------- all of them


@dataclass
class Suite:
    """The cases of one quality; Mitsuba references are rendered on first use and kept."""

    quality: C.Quality
    artifacts: Artifacts | None = None
    prepared: dict[str, S.PreparedScenario] = field(default_factory=dict)
    drt_prepared: dict[str, Any] = field(default_factory=dict)

    def _scenario_result(self, name: str) -> CaseResult:
        return _family_result(name, "integrator", S.evaluate_scenario(self.scenario(name)), self.artifacts)

    def scenario(self, name: str) -> S.PreparedScenario:
        if name not in self.prepared:
            self.prepared[name] = S.prepare_scenario(next(s for s in C.SCENARIOS if s.name == name), self.quality)
        return self.prepared[name]

    def drt(self, case: C.DrtCase) -> CaseResult:
        from mitsnerf.verify.drt import prepare_drt

        if case.name not in self.drt_prepared:
            self.drt_prepared[case.name] = prepare_drt(case, self.quality)
        return drt_case(self.drt_prepared[case.name], self.artifacts)

    def jobs(self) -> list[tuple[str, Callable[[], CaseResult]]]:
        """``(name, run)`` of every case, in table order."""
        q, a = self.quality, self.artifacts
        jobs: list[tuple[str, Callable[[], CaseResult]]] = [
            (C.CLOSED_FORM.name, lambda: closed_form_case(C.CLOSED_FORM))
        ]
        jobs += [(s.name, functools.partial(self._scenario_result, s.name)) for s in C.SCENARIOS]
        t = C.TRAINING_PATH
        jobs += [(t.name, lambda: _family_result(t.name, "training path",
                                                 S.evaluate_training_path(t, self.scenario(t.scenario)), a))]
        jobs += [(C.JITTER.name, lambda: jitter_case(C.JITTER, q))]
        jobs += [(g.name, functools.partial(gradient_case, g, q)) for g in C.GRADIENT_CASES]
        jobs += [(d.name, functools.partial(self.drt, d)) for d in C.DRT_CASES]
        jobs += [(p.name, functools.partial(plugin_case, p, q, a)) for p in C.PLUGIN_CASES]
        f = C.MITSUBA_FURNACE
        jobs += [(f.name, lambda: _family_result(f.name, "Mitsuba", S.mitsuba_furnace(f, q), a))]
        jobs += [(C.FURNACE_DEPTHS.name, lambda: furnace_depths(C.FURNACE_DEPTHS, q))]
        return jobs


MITSUBA_ONLY = (C.MITSUBA_FURNACE.name, C.FURNACE_DEPTHS.name)
"""Cases that run no package code under test (mutations cannot reach them; ``--mutations`` skips them)."""


def _quality(quality: C.Quality | str) -> C.Quality:
    if isinstance(quality, C.Quality):
        return quality
    if quality not in C.QUALITIES:
        raise UsageError("--quality", f"unknown quality {quality!r}; choose one of {', '.join(C.QUALITIES)}")
    return C.QUALITIES[quality]


def _wanted(only: Iterable[str] | None) -> set[str] | None:
    wanted = set(only) if only else None
    if wanted:
        unknown = wanted - set(C.ALL_CASE_NAMES)
        if unknown:
            raise UsageError(
                "--case", f"unknown case(s) {', '.join(sorted(unknown))}; known: {', '.join(C.ALL_CASE_NAMES)}"
            )
    return wanted


def run_checks(quality: C.Quality | str = "quick", out: str | Path | None = None,
               only: Iterable[str] | None = None,
               progress: Callable[[CaseResult], None] | None = None) -> list[CaseResult]:
    """Run every case (or those named in ``only``); failing cases write images under ``out``."""
    suite = Suite(_quality(quality), Artifacts(out))
    wanted = _wanted(only)
    results = []
    for name, job in suite.jobs():
        if wanted is None or name in wanted:
            results.append(job())
            if progress is not None:
                progress(results[-1])
    return results


@dataclass(frozen=True)
class MutationReport:
    """The clean run and, per mutation, every case's result under it."""

    clean: list[CaseResult]
    matrix: dict[str, list[CaseResult]]  # mutation name -> results in case order

    def caught_by(self, mutation: str) -> list[CaseResult]:
        return [r for r in self.matrix[mutation] if r.passed is False]

    @property
    def escaped(self) -> list[str]:
        return [m for m in self.matrix if not self.caught_by(m)]

    @property
    def passed(self) -> bool:
        return all(r.passed is not False for r in self.clean) and not self.escaped


def run_mutations(quality: C.Quality | str = "quick", mutations: Iterable[Mutation] = MUTATION_LIST,
                  only: Iterable[str] | None = None,
                  progress: Callable[[str, CaseResult], None] | None = None) -> MutationReport:
    """Every case clean, then under each mutation (references rendered once; Mitsuba-only cases skipped)."""
    suite = Suite(_quality(quality))
    wanted = _wanted(only)
    jobs = [(n, j) for n, j in suite.jobs() if n not in MITSUBA_ONLY and (wanted is None or n in wanted)]
    report = MutationReport([], {})
    for label, mutation in [("clean", None)] + [(m.name, m) for m in mutations]:
        results = []
        with planted(mutation):  # every case of the pass under the one mutation
            for _, job in jobs:
                results.append(job())
                if progress is not None:
                    progress(label, results[-1])
        if mutation is None:
            report.clean.extend(results)
        else:
            report.matrix[label] = results
    return report


#: ``(pattern, one line)``: the words of the notes under the table that a user may not know, each explained once
#: when a note uses it (:func:`terms`).
TERMS: tuple[tuple[str, str], ...] = (
    (r"seed's rule", "seed's rule: the default quadrature, delta_i = t_{i+1} - t_i with the last to t_f; in a medium "
                     "dense where rays leave it, it is biased by about -(h/2) sigma_t(t_f) in optical depth (h: the "
                     "sample spacing; its 'exit bias'), measured and printed, not tested"),
    (r"midpoint", "midpoint rule: the quadrature option without that bias (each sample stands for its whole stratum)"),
    (r"\bz\b", "z: a difference divided by its Monte Carlo standard error (|z| below about 4 is noise); "
               "channel-mean z: that of the image's mean, per colour channel"),
    (r"\bN = ", "N: samples per ray"),
    (r"jitter", "jitter: training's random placement of each sample within its stratum of the ray"),
    (r"furnace", "furnace: a medium in a uniform environment of radiance 1; with albedo 1 and unlimited depth the "
                 "exact image is 1"),
)


def terms(notes: Iterable[str]) -> list[str]:
    """One line per term of :data:`TERMS` that ``notes`` use, in that order.

    >>> [line.split(":")[0] for line in terms(["box: seed's rule against volpath, channel-mean z +6.3"])]
    ["seed's rule", 'z']
    """
    import re

    text = "\n".join(notes)
    return [line for pattern, line in TERMS if re.search(pattern, text)]


COMPACT_WIDTH = 100
"""Columns of the table ``mitsnerf check`` prints by default (``--wide``: every column, each row on one line)."""


def _wide_rows(results: list[CaseResult]) -> list[tuple[str, ...]]:
    """The header and one row per case, every column (the ``--wide`` table and the ``--out`` file)."""
    header: tuple[str, ...] = ("case", "checks", "reference", "measured error", "max|z|", "rejected", "result", "time")
    rows: list[tuple[str, ...]] = [header]
    return rows + [
        (r.name, r.checks, r.reference, r.error, "-" if r.max_abs_z is None else f"{r.max_abs_z:.2f}", r.rejected,
         r.status, f"{r.seconds:.1f} s")
        for r in results
    ]


def _aligned(rows: list[tuple[str, ...]]) -> list[str]:
    """Rows as fixed-width lines, a rule of dashes under the header."""
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return lines


def _compact_lines(results: list[CaseResult], width: int) -> list[str]:
    """The table in about ``width`` columns: no reference column, the measured error last and wrapped under
    itself (its continuation lines indented to that column).

    >>> r = CaseResult("box", "integrator", "volpath", "rel. mean 9.1e-05 (<= 0.01), mean z -1.17", 3.02, "0/3462",
    ...                True, 67.6)
    >>> print("\\n".join(_compact_lines([r], 60)))
    case  checks      result  max|z|  rejected  time    measured error
    ----  ----------  ------  ------  --------  ------  ------------------------
    box   integrator  pass    3.02    0/3462    67.6 s  rel. mean 9.1e-05 (<=
                                                        0.01), mean z -1.17
    """
    import textwrap

    wide = _wide_rows(results)
    order = (0, 1, 6, 4, 5, 7)  # case, checks, result, max|z|, rejected, time; then the measured error
    rows = [tuple(row[i] for i in order) for row in wide]
    widths = [max(len(row[i]) for row in rows) for i in range(len(order))]
    indent = sum(widths) + 2 * len(widths)
    room = max(width - indent, 24)
    lines = ["  ".join(h.ljust(w) for h, w in zip(rows[0], widths)) + "  measured error",
             "  ".join("-" * w for w in widths) + "  " + "-" * min(room, max(len(r[3]) for r in wide))]
    for row, full in zip(rows[1:], wide[1:]):
        error = textwrap.wrap(full[3], room) or [""]
        lines.append("  ".join(c.ljust(w) for c, w in zip(row, widths)) + "  " + error[0])
        lines += [" " * indent + part for part in error[1:]]
    return lines


def format_table(results: list[CaseResult], alpha: float | None = None, *, wide: bool = False,
                 width: int = COMPACT_WIDTH) -> str:
    """The table, then the notes, the alpha line and the words of the notes, one line each. The table is compact
    by default (about ``width`` columns: case, checks, result, max |z|, rejections, time, the measured error
    wrapped under itself); ``wide``: every column (the reference too), each row on one line."""
    lines = _aligned(_wide_rows(results)) if wide else _compact_lines(results, width)
    notes = [f"{r.name}: {r.note}" for r in results if r.note]
    notes += [f"{r.name}: {r.detail}" for r in results if r.detail and r.passed is not True]
    if alpha is not None and any(r.rejected != "-" for r in results):
        notes.append(f"rejected: the case's statistical tests (pixels and channel means) that found a difference; "
                     f"a correct integrator gets one with probability at most {alpha:g} per case (columns: README.md, "
                     f"'Reading mitsnerf check'{'' if wide else '; the reference column: --wide'})")
    words = terms(notes)
    return "\n".join(lines + ([""] + notes if notes else []) + (["", "Words in the notes:"] + words if words else []))


def count_line(results: list[CaseResult]) -> str:
    """The summary a check run ends with: ``N passed, M failed`` (records, neither passed nor failed, are not counted).

    >>> passed, recorded = (CaseResult(n, "c", "r", "e", None, "-", ok, 0.1) for n, ok in (("a", True), ("b", None)))
    >>> count_line([passed, recorded])
    '1 passed, 0 failed'
    """
    passed = sum(r.passed is True for r in results)
    return f"{passed} passed, {sum(r.passed is False for r in results)} failed"


def format_mutations(report: MutationReport) -> str:
    """Per mutation: where it is planted, which cases catch it (with the deciding statistic), and the 0/1 matrix."""
    header = ("mutation", "planted in", "kind", "caught by")
    rows = [header]
    for name, results in report.matrix.items():
        m = MUTATIONS.get(name)
        caught = ", ".join(f"{r.name} ({r.evidence})" for r in results if r.passed is False) or "NOT CAUGHT"
        rows.append((name, m.where if m else "?", m.kind if m else "?", caught))
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row[:3], widths)) + "  " + row[3] for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths) + "  " + "-" * 9)
    cases = [r.name for r in report.clean]
    lines += ["", "matrix (x: the case fails under the mutation; columns in case order):"]
    lines += [f"  {i + 1:2d} {name}" for i, name in enumerate(cases)]
    width = max(len(n) for n in report.matrix) if report.matrix else 8
    lines.append(" " * (width + 2) + " ".join(f"{i + 1:2d}" for i in range(len(cases))))
    lines.append("clean".ljust(width + 2) + " ".join(" ." if r.passed is not False else " X" for r in report.clean))
    for name, results in report.matrix.items():
        lines.append(name.ljust(width + 2) + " ".join(" x" if r.passed is False else " ." for r in results))
    return "\n".join(lines)
