"""Result tables: cells aggregated per (scene, method) over seeds and averaged over scenes, as
Markdown (terminal and file), CSV and JSON-ready rows; the best value per column bold among the rows given
the same (every row equal to it at the displayed precision: ties are all bold).

Printed (:func:`compact_report`): :data:`COMPACT`, the headline medium-pixel PSNR beside the gap to
the oracle, with one line per scene giving the agreement of its two reference renders and what a
perfect model would score. Written (``table.md``, :func:`markdown_report`, and the report): two
tables each, *quality* (image scores in both encodings, whole image and medium pixels, the
reference agreement and the oracle next to them, density-field errors) and *cost* (training
time, throughput, peak memory, parameters). A legend gives one line per column (:func:`legend`).
Each scene with an oracle (:mod:`mitsnerf.oracle`) gets an ``oracle`` row first (:func:`oracle_row`): the ceiling any
emission-absorption method can reach on that dataset, never marked best.

Every ceiling (the oracle, each row's own rung's) and every Monte Carlo row is shown less its own Monte Carlo
variance, the raw figure beside it (``46.01 (raw 44.56)``, :data:`WITHOUT_MC_KEYS`,
:mod:`mitsnerf.scoring.variance`), and compared on that figure; a row still above its own ceiling says why in
its note (:func:`ceiling_reason`).
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Iterable, Sequence
from typing import Any

from mitsnerf.oracle.rungs import PERFECT_DB
from mitsnerf.scoring.variance import WITHOUT_MC, headline

Column = tuple[str, str, int]
"""(key, header, decimals)."""

KEYS: tuple[Column, ...] = (("scene", "scene", 0), ("method", "method", 0), ("seeds", "seeds", 0))
QUALITY: tuple[Column, ...] = KEYS + (
    ("psnr_test", "PSNR lin", 2),
    ("psnr_test_medium", "PSNR lin medium", 2),
    ("noise_floor_psnr", "ref agreement", 2),
    ("noise_floor_psnr_medium", "ref agreement medium", 2),
    ("oracle_psnr_test_medium", "oracle medium", 2),
    ("gap_to_oracle", "gap to oracle", 2),
    ("given", "given", 0),
    ("rung", "rung", 0),
    ("ceiling_psnr_test_medium", "its ceiling", 2),
    ("gap_to_ceiling", "gap to its ceiling", 2),
    ("psnr_test_srgb", "PSNR sRGB", 2),
    ("psnr_test_medium_srgb", "PSNR sRGB medium", 2),
    ("ssim_test", "SSIM lin", 4),
    ("ssim_test_srgb", "SSIM sRGB", 4),
    ("psnr_train", "PSNR train", 2),
    ("density_rel_l1", "sigma rel L1", 3),
    ("density_rel_l2", "sigma rel L2", 3),
    ("density_rel_mass", "sigma mass err", 3),
    ("density_rel_l1_reduced", "reduced sigma rel L1", 3),
    ("density_psnr", "sigma PSNR", 2),
    ("tau_rel_l1", "tau rel L1", 3),
    ("transmittance_mae", "T MAE", 4),
    ("footprint", "footprint K", 0),
    ("note", "note", 0),
)
COST: tuple[Column, ...] = KEYS + (
    ("budget", "budget", 0),
    ("steps", "steps", 0),
    ("train_seconds", "train s", 1),
    ("rays_per_s", "rays/s", 0),
    ("samples_per_s", "samples/s", 0),
    ("peak_memory_mb", "peak MiB", 0),
    ("peak_rss_mb", "peak RSS MiB", 0),
    ("num_parameters", "params", 0),
    ("model_mb", "model MB", 3),
    ("curve_eval_seconds", "curve eval s", 1),
    ("note", "note", 0),
)
COMPACT: tuple[Column, ...] = (
    ("scene", "scene", 0),
    ("method", "method", 0),
    ("given", "given", 0),
    ("budget", "budget", 0),
    ("train_seconds", "train s", 1),
    ("psnr_test_medium", "PSNR medium", 2),
    ("gap_to_oracle", "gap to oracle", 2),
    ("ceiling_psnr_test_medium", "its ceiling", 2),
    ("gap_to_ceiling", "gap to its ceiling", 2),
    ("ssim_test", "SSIM", 4),
    ("density_rel_l1", "sigma rel L1", 3),
    ("peak_memory_mb", "peak MiB", 0),
    ("model_mb", "model MB", 3),
)
"""The printed table: the headline (medium-pixel PSNR) and one figure of each kind; every column is in
``table.md``, the CSVs, ``results.json`` and ``report.html``."""
WITHOUT_MC_KEYS = ("psnr_test_medium", "oracle_psnr_test_medium", "ceiling_psnr_test_medium")
"""Figures shown less their own Monte Carlo variance where it was measured (``KEY_without_mc``), the raw one
beside it, and compared (bold, above a ceiling) on that figure."""
_TO_TARGET = re.compile(r"seconds_to_(.+)db")
BEST: dict[str, str] = {
    "psnr_test": "max", "psnr_test_medium": "max", "psnr_test_srgb": "max", "psnr_test_medium_srgb": "max",
    "ssim_test": "max", "ssim_test_srgb": "max", "psnr_train": "max",
    "density_rel_l1": "min", "density_rel_l2": "min", "density_rel_l1_reduced": "min", "density_psnr": "max",
    "tau_rel_l1": "min",
    "transmittance_mae": "min", "rays_per_s": "max", "samples_per_s": "max", "peak_rss_mb": "min",
    "peak_memory_mb": "min", "model_mb": "min",
}  # and "min" for every "seconds to X dB" column, whatever the config's targets (:func:`best_values`)

MEANINGS: dict[str, str] = {
    "scene": "the scene's name; mean of N: the mean over N scenes",
    "method": "oracle (ceiling): the true sigma_t, in-scattered radiance J by volpath (per direction if anisotropic), "
              "the best an emission-absorption model can do (never bold); NAME (external): another tool's renders, "
              "scored as mitsnerf score does",
    "seeds": "training seeds the row is the mean of",
    "PSNR lin": "PSNR of the test views, linear radiance clipped to [0, 1], whole image",
    "PSNR lin medium": "the same on the pixels whose ray crosses the true medium (the headline figure); a (raw b): a "
                       "Monte Carlo render's (the oracle's, a path tracer's) less its own Monte Carlo variance",
    "PSNR medium": "PSNR of the test views on the pixels whose ray crosses the true medium (linear, clipped); a (raw "
                   "b): a Monte Carlo render's (the oracle's, a path tracer's) less its own Monte Carlo variance",
    "ref agreement": "PSNR between two independent ground-truth renders of the test views (manifest noise_floor); "
                     f"a perfect model scores {PERFECT_DB:.2f} dB above it",
    "ref agreement medium": "the same on medium pixels",
    "oracle medium": "the oracle row's PSNR medium on this scene, less its own Monte Carlo variance (raw beside it)",
    "gap to oracle": "oracle medium PSNR minus the row's, each less its own Monte Carlo variance (dB; 0: as good as "
                     "the ceiling)",
    "given": "what the method was given: the images (and their cameras) alone, or also the lights and the phase "
             "function (read from the dataset's spec): compare rows that were given the same (bold does)",
    "rung": "the physics its renders can represent: emission-absorption, single scattering (the delta lights' "
            "single scattering through its own medium), full transport",
    "its ceiling": "its rung's ceiling, medium pixels, less its own Monte Carlo variance (raw beside): the oracle "
                   "(emission-absorption); the oracle on the method's basis (single scattering); the references' "
                   "agreement + 3.01 dB (full transport)",
    "gap to its ceiling": "its ceiling minus the row's medium PSNR, each less its own Monte Carlo variance (dB; < 0: "
                          "above it, the reason in the note)",
    "PSNR sRGB": "PSNR of the clipped values sRGB-encoded, whole image",
    "PSNR sRGB medium": "the same on medium pixels",
    "SSIM lin": "SSIM of the test views, linear radiance clipped to [0, 1]",
    "SSIM": "SSIM of the test views, linear radiance clipped to [0, 1]",
    "SSIM sRGB": "SSIM of the sRGB-encoded values",
    "PSNR train": "PSNR on the training views",
    "sigma rel L1": "relative L1 error of the learned density against the true sigma_t on the voxel centres",
    "sigma rel L2": "the same, relative L2",
    "reduced sigma rel L1": "anisotropic media: the same against sigma_t (1 - albedo g), which renders alike (- when "
                            "isotropic)",
    "sigma mass err": "relative mass error (sum learned - sum true) / sum true on the voxel centres, signed: > 0 the "
                      "learned medium holds more extinction (never bold: its sign is the information)",
    "sigma PSNR": "PSNR of the learned density against the true sigma_t",
    "tau rel L1": "relative L1 error of the optical depth along every test ray",
    "T MAE": "mean absolute error of the transmittance exp(-tau)",
    "footprint K": "each test pixel is the mean of K x K rays over its area (1: its centre ray)",
    "budget": "the training length: N steps (the table is the same on any machine), or steps with a seconds cap "
              "(machine-dependent)",
    "steps": "training steps run",
    "train s": "training seconds, held-out evaluation excluded",
    "rays/s": "training rays per second",
    "samples/s": "training samples (points along rays) per second",
    "peak MiB": "the cell's own peak memory: Dr.Jit's allocator high-water mark from its start (host memory on "
                "LLVM, device memory on CUDA), the same whatever ran before it",
    "peak RSS MiB": "resident high-water mark of the process during the cell (reset at its start on Linux), the "
                    "process's baseline included (so bold only when every cell had its own process)",
    "params": "trainable parameters",
    "model MB": "size of the saved model, the run's params.npz (10^6 bytes; model_bytes in the CSV and JSON)",
    "curve eval s": "seconds spent on the held-out evaluations of the PSNR curve",
    "s to X dB medium": "training seconds at the first held-out evaluation (steps k/N of the budget) reaching "
                        "X dB on medium pixels (measured, not decisive)",
    "note": "failed cells, the oracle's settings, why a density figure is missing, why a row is above its ceiling, "
            "a Monte Carlo row scored raw",
}
BOLD = ("bold: the column's best among the rows given the same, per scene (ties at the displayed precision all bold); "
        "figures are means over seeds")


def legend(columns: Sequence[Column]) -> str:
    """One line per column of ``columns`` (``- header: meaning``), then what bold means.

    >>> print(legend([("ssim_test", "SSIM", 4), ("train_seconds", "train s", 1)]))
    ... # doctest: +NORMALIZE_WHITESPACE
    - SSIM: SSIM of the test views, linear radiance clipped to [0, 1]
    - train s: training seconds, held-out evaluation excluded
    - bold: the column's best among the rows given the same, per scene (ties at the displayed precision all
      bold); figures are means over seeds
    """
    lines: list[str] = []
    for _, header, _ in columns:
        key = "s to X dB medium" if header.startswith("s to ") else header
        if key in MEANINGS and not any(line.startswith(f"- {key}:") for line in lines):
            lines.append(f"- {key}: {MEANINGS[key]}")
    return "\n".join(lines + [f"- {BOLD}"])


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _fmt(value: Any, digits: int) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if math.isnan(value):
            return "-"
        if math.isinf(value):
            return "inf"
        if abs(value) >= 1e5:
            return f"{value:.3g}"
        return f"{value:.{digits}f}"
    return str(value)


def _value(row: dict, key: str) -> Any:
    """The figure a row is compared on in column ``key``: less its own Monte Carlo variance for
    :data:`WITHOUT_MC_KEYS` where that was measured (:func:`mitsnerf.scoring.variance.headline`)."""
    return headline(row, key) if key in WITHOUT_MC_KEYS else row.get(key)


def _cell_text(row: dict, key: str, digits: int) -> str:
    """A table cell: the formatted value; a figure less its own Monte Carlo variance reads ``a (raw b)``; a ceiling
    row's method reads ``oracle (ceiling)``; a budget reads ``N steps`` (``N steps or seconds`` with a seconds cap).

    >>> oracle = {"method": "oracle", "ceiling": True, "psnr_test_medium": 44.56, "psnr_test_medium_without_mc": 46.01}
    >>> _cell_text({"budget": "steps", "steps": 800}, "budget", 0), _cell_text(oracle, "method", 0)
    ('800 steps', 'oracle (ceiling)')
    >>> _cell_text(oracle, "psnr_test_medium", 2)
    '46.01 (raw 44.56)'
    """
    text = _fmt(_value(row, key), digits)
    raw = _fmt(row.get(key), digits)
    if key in WITHOUT_MC_KEYS and text != raw:
        return f"{text} (raw {raw})"
    if key == "budget" and isinstance(row.get("budget"), str) and _is_number(row.get("steps")):
        return f"{row['steps']:.0f} {row['budget']}"
    if key == "method" and row.get("ceiling"):
        return f"{text} (ceiling, beaten: see below)" if row.get("beaten_by") else f"{text} (ceiling)"
    return text


def bold_group(row: dict, group: str | None) -> tuple[Any, str]:
    """The rows ``row``'s bold competes with: those of its ``group`` (a scene; None: the whole table) that were
    given the same (the ``given`` column's rule; a row that does not say, another tool's renders, was given the
    images).

    >>> bold_group({"scene": "cloud", "given": "images, lights, phase function"}, "scene")
    ('cloud', 'images, lights, phase function')
    >>> bold_group({"scene": "cloud"}, None)
    (None, 'images')
    """
    return row.get(group) if group else None, row.get("given") or "images"


def is_best(row: dict, key: str, digits: int, marks: dict[tuple[Any, str], Any], group: str | None) -> bool:
    """Whether ``row[key]`` is bold: equal to its group's best (:func:`best_values`, :func:`bold_group`) at the
    displayed precision, so every tied row is bold whatever the rows' order.

    >>> marks = {((None, "images"), "p"): 25.8712}
    >>> is_best({"p": 25.8712}, "p", 2, marks, None), is_best({"p": 25.8698}, "p", 2, marks, None)
    (True, True)
    >>> is_best({"p": 25.86}, "p", 2, marks, None), is_best({"p": 25.87, "ceiling": True}, "p", 2, marks, None)
    (False, False)
    """
    mark = marks.get((bold_group(row, group), key))
    return mark is not None and not row.get("ceiling") and _is_number(_value(row, key)) \
        and _fmt(_value(row, key), digits) == _fmt(mark, digits)


def best_values(rows: Sequence[dict], best: dict[str, str], group: str | None = None) -> dict[tuple[Any, str], Any]:
    """``{(bold group, key): best value}`` over the rows of each :func:`bold_group` with at least two numbers in the
    column; the "seconds to X dB" columns found in ``rows`` are best at their minimum."""
    marks: dict[tuple[Any, str], Any] = {}
    groups: dict[Any, list[dict]] = {}
    for row in rows:
        groups.setdefault(bold_group(row, group), []).append(row)
    to_target = {k: "min" for r in rows for k in r if _TO_TARGET.fullmatch(k)}
    for g, members in groups.items():
        members = [r for r in members if not r.get("ceiling")]
        for key, how in {**to_target, **best}.items():
            values = [_value(r, key) for r in members if _is_number(_value(r, key))]
            if len(values) > 1:
                marks[(g, key)] = max(values) if how == "max" else min(values)
    return marks


def markdown_table(rows: Sequence[dict], columns: Sequence[Column], best: dict[str, str] | None = None,
                   group: str | None = None) -> str:
    """A Markdown table of ``rows``; ``columns`` are (key, header, decimals).

    ``best`` maps a key to ``"max"`` or ``"min"``: the best value in that column is bold among the rows given the
    same (:func:`bold_group`; within each group of rows sharing ``row[group]`` when ``group`` is given).

    >>> rows, columns = [{"m": "a", "p": 30.0}, {"m": "b", "p": 31.5}], [("m", "method", 0), ("p", "PSNR", 2)]
    >>> print(markdown_table(rows, columns, {"p": "max"}))
    | method | PSNR |
    |---|---|
    | a | 30.00 |
    | b | **31.50** |
    """
    marks = best_values(rows, best or {}, group)
    lines = ["| " + " | ".join(h for _, h, _ in columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        cells = []
        for key, _, digits in columns:
            text = _cell_text(row, key, digits)
            cells.append(f"**{text}**" if is_best(row, key, digits, marks, group) else text)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def csv_table(rows: Sequence[dict], keys: Sequence[str]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(keys), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: row.get(k) for k in keys})
    return buf.getvalue()


def cell_row(record: dict) -> dict:
    """One cell's scalar metrics, flat, with scene/method/seed."""
    row = {"scene": record["scene"], "method": record["method"], "seed": record["seed"]}
    for key, value in (record.get("metrics") or {}).items():
        if value is None or _is_number(value) or isinstance(value, str):
            row[key] = value
    if _is_number(row.get("model_bytes")):
        row["model_mb"] = row["model_bytes"] / 1e6
    return row


def _aggregate(rows: Sequence[dict], base: dict) -> dict:
    """Means (and ``_std``) of the numeric columns of ``rows``; a text column kept where every row agrees; a figure
    less its own Monte Carlo variance only where every row has it (else a mean of some rows would read as all's)."""
    out = dict(base)
    keys: list[str] = []
    for row in rows:
        keys.extend(k for k in row if k not in keys and k not in ("scene", "method", "seed", "note", "density_note"))
    for key in keys:
        texts = {r[key] for r in rows if isinstance(r.get(key), str)}
        if texts:
            out[key] = texts.pop() if len(texts) == 1 else "mixed"
            continue
        values = [r[key] for r in rows if _is_number(r.get(key))]
        if not values or (key.endswith(WITHOUT_MC) and len(values) < len(rows)):
            out[key] = None
            continue
        mean = sum(values) / len(values)
        out[key] = mean
        if len(values) > 1:
            out[f"{key}_std"] = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))
    return out


def scene_rows(records: Sequence[dict], failed: Iterable[dict] = (), scenes: Sequence[str] = (),
               methods: Sequence[str] = ()) -> list[dict]:
    """One row per (scene, method): means (and ``_std`` over seeds), in config order."""
    cells = [cell_row(r) for r in records]
    failed = list(failed)
    scenes = list(scenes) or sorted({c["scene"] for c in cells} | {f["scene"] for f in failed})
    methods = list(methods) or sorted({c["method"] for c in cells} | {f["method"] for f in failed})
    rows = []
    for scene in scenes:
        for method in methods:
            members = [c for c in cells if c["scene"] == scene and c["method"] == method]
            n_failed = sum(1 for f in failed if f["scene"] == scene and f["method"] == method)
            if not members and not n_failed:
                continue
            row = _aggregate(members, {"scene": scene, "method": method, "seeds": len(members)})
            notes = sorted({c[k] for c in members for k in ("density_note", "mc_note") if c.get(k)})
            if n_failed:
                notes.insert(0, f"{n_failed} failed")
            row["note"] = "; ".join(notes) or None
            rows.append(row)
    return rows


def average_rows(rows: Sequence[dict], methods: Sequence[str] = ()) -> list[dict]:
    """One row per method: the mean over scenes of the per-scene means."""
    methods = list(methods) or list(dict.fromkeys(r["method"] for r in rows))
    out = []
    for method in methods:
        members = [{k: v for k, v in r.items() if not k.endswith("_std")} for r in rows if r["method"] == method]
        if not members:
            continue
        row = _aggregate(members, {"scene": f"mean of {len(members)}", "method": method,
                                   "seeds": sum(r["seeds"] or 0 for r in members)})
        row["note"] = "; ".join(sorted({r["note"] for r in members if r.get("note")})) or None
        out.append(row)
    return out


def best_rules(records: Sequence[dict]) -> dict[str, str]:
    """:data:`BEST`, less peak memory unless every cell ran in a fresh process (in a reused one the
    high-water mark carries the cells before it, so comparing them would mislead)."""
    fresh = all((r.get("worker") or {}).get("fresh_process") for r in records)
    return dict(BEST) if fresh else {k: v for k, v in BEST.items() if k != "peak_rss_mb"}


def cost_columns(rows: Sequence[dict]) -> tuple[Column, ...]:
    """:data:`COST` plus a "seconds to X dB" column per medium-PSNR target found in ``rows``.

    >>> [c[1] for c in cost_columns([{"seconds_to_35db": 1.0}])][-2]
    's to 35 dB medium'
    """
    targets = list(dict.fromkeys(m.group(1) for r in rows for k in r if (m := _TO_TARGET.fullmatch(k))))
    targets.sort(key=float)
    return COST[:-1] + tuple((f"seconds_to_{t}db", f"s to {t} dB medium", 1) for t in targets) + COST[-1:]


def _beats(row: dict, ceiling: float) -> bool:
    """Whether a method row's medium PSNR (less its own Monte Carlo variance where measured) is above ``ceiling`` as
    the table prints them (2 decimals)."""
    medium = headline(row)
    return not row.get("ceiling") and _is_number(medium) and round(float(medium), 2) > round(ceiling, 2)


def mark_beaten(rows: Sequence[dict], group: str = "scene") -> list[dict]:
    """``rows`` with ``beaten_by`` (the methods above it) on each ceiling row that a row of its group beats, so the
    table marks it and :func:`reference_lines` gives the reason.

    >>> rows = mark_beaten([{"scene": "a", "method": "oracle", "ceiling": True, "psnr_test_medium": 20.0},
    ...                     {"scene": "a", "method": "nerf", "psnr_test_medium": 21.3}])
    >>> rows[0]["beaten_by"], _cell_text(rows[0], "method", 0)
    (['nerf'], 'oracle (ceiling, beaten: see below)')
    """
    out = []
    for row in rows:
        if row.get("ceiling") and _is_number(headline(row)):
            above = [r["method"] for r in rows if r.get(group) == row.get(group) and _beats(r, headline(row))]
            row = {**row, "beaten_by": above} if above else row
        out.append(row)
    return out


def _oracle_words(members: Sequence[dict], oracle: float, perfect: float | None) -> str:
    """What the oracle scores (``oracle``: less its own Monte Carlo variance where measured, the raw figure beside it),
    and why, where it looks impossible: a method above it, or it above a perfect model."""
    ceiling = next(r for r in members if r.get("ceiling"))
    basis = ceiling.get("ceiling_basis")
    basis = basis if isinstance(basis, str) and basis != "mixed" else "see each scene's line"
    text = f"; the oracle scores {_fmt(oracle, 2)} dB"
    if _fmt(ceiling.get("psnr_test_medium"), 2) != _fmt(oracle, 2):
        text += f" less its own Monte Carlo variance (raw {_fmt(ceiling.get('psnr_test_medium'), 2)} dB)"
    if perfect is not None and round(oracle, 2) > round(perfect, 2):
        text += (", above that perfect-model figure: both are estimates (the oracle's in-scattered light: "
                 f"{basis}; the perfect model's: the two renders' own noise), close enough to cross")
    above = [r for r in members if _beats(r, oracle)]
    if above:
        names = ", ".join(f"{r['method']} {_fmt(headline(r), 2)}" for r in above)
        text += (f"; {names} above it: this ceiling is an estimate ({basis}), below the true one by its own error, "
                 "and a model that averages that error out can pass it")
    return text + "."


def reference_lines(rows: Sequence[dict], group: str = "scene") -> list[str]:
    """Per group of ``rows`` (a scene, or the mean over scenes): how well its two reference renders agree on
    medium pixels, what a perfect model would score, and the oracle (the ceiling), with the reason beside it
    where a method scores above it or it above the perfect model (:func:`_oracle_words`).

    >>> (line,) = reference_lines([{"scene": "cloud", "method": "oracle", "ceiling": True, "psnr_test_medium": 44.82,
    ...                             "noise_floor_psnr_medium": 43.97}])
    >>> for part in line.split("; "):
    ...     print(part)
    cloud: two reference renders agree to 43.97 dB (medium pixels): a perfect model would score about 46.98 dB
    the oracle scores 44.82 dB.
    """
    lines = []
    for name in dict.fromkeys(r.get(group) for r in rows):
        members = [r for r in rows if r.get(group) == name]
        floor = next((r["noise_floor_psnr_medium"] for r in members if _is_number(r.get("noise_floor_psnr_medium"))),
                     None)
        oracle = next((headline(r) for r in members if r.get("ceiling")), None)
        perfect = float(floor) + PERFECT_DB if floor is not None else None
        if perfect is not None:
            text = (f"two reference renders agree to {_fmt(floor, 2)} dB (medium pixels): a perfect model would "
                    f"score about {_fmt(perfect, 2)} dB")
        elif not any(_is_number(r.get("psnr_test_medium")) for r in members):
            text = "no cell finished, so nothing was scored"
        else:
            text = "no reference agreement measured (render.noise_floor = false)"
        lines.append(f"{name}: {text}" + (_oracle_words(members, oracle, perfect) if isinstance(oracle, float)
                                          and _is_number(oracle) else "."))
    return lines


def _notes(rows: Sequence[dict]) -> list[str]:
    """``scene method: note`` of every non-ceiling row with a note (failed cells, missing density, above its
    ceiling)."""
    return [f"{r['scene']} {r['method']}: {r['note']}" for r in rows if r.get("note") and not r.get("ceiling")]


def above_ceiling(row: dict) -> float | None:
    """By how much (dB, > 0) a method row's medium PSNR is above its own ceiling as the table prints them (2
    decimals), each less its own Monte Carlo variance where measured; None where it is not above it.

    >>> above_ceiling({"psnr_test_medium": 45.13, "ceiling_psnr_test_medium": 44.56})
    0.57
    >>> above_ceiling({"psnr_test_medium": 45.13, "ceiling_psnr_test_medium": 44.56,
    ...                "ceiling_psnr_test_medium_without_mc": 46.01}) is None
    True
    """
    medium, ceiling = headline(row), headline(row, "ceiling_psnr_test_medium")
    if row.get("ceiling") or not (_is_number(medium) and _is_number(ceiling)):
        return None
    gap = round(float(medium), 2) - round(float(ceiling), 2)
    return round(gap, 2) if gap > 0.005 else None


def ceiling_reason(row: dict) -> str | None:
    """Why a row is above its own ceiling (:func:`above_ceiling`), from what the ceiling is (``ceiling_note``) and
    what its figure rests on; None where it is not above it.

    >>> print(ceiling_reason({"psnr_test_medium": 45.13, "ceiling_psnr_test_medium": 44.56,
    ...                       "ceiling_note": "the oracle, raw: no estimate of its own Monte Carlo variance was kept"}))
    above its ceiling 44.56 by 0.57 dB: the ceiling is the oracle, raw: no estimate of its own Monte Carlo variance \
was kept; its own Monte Carlo variance, not removed, lowers it
    """
    by = above_ceiling(row)
    if by is None:
        return None
    text = (f"above its ceiling {_cell_text(row, 'ceiling_psnr_test_medium', 2)} by {by:.2f} dB: the ceiling is "
            f"{row.get('ceiling_note') or 'an estimate'}; ")
    if row.get("ceiling_psnr_test_medium" + WITHOUT_MC) is None:
        text += "its own Monte Carlo variance, not removed, lowers it"
    else:
        text += ("less its own Monte Carlo variance it is still an estimate, below the true ceiling by its other "
                 "error (its bias: a grid, a quadrature, a footprint; the variance estimate's own error), which a "
                 "model need not share")
    if row.get("psnr_test_medium" + WITHOUT_MC) is not None:
        text += "; the row's own Monte Carlo variance, taken off its figure, is itself an estimate from two renders"
    return text


def with_ceiling_reasons(rows: Sequence[dict]) -> list[dict]:
    """``rows`` with :func:`ceiling_reason` added to the note of every row above its own ceiling (once: a row that
    has it keeps its note): no table shows a row above its ceiling without the reason beside it."""
    out = []
    for row in rows:
        reason = ceiling_reason(row)
        new = reason is not None and reason not in (row.get("note") or "")
        out.append({**row, "note": "; ".join(n for n in (row.get("note"), reason) if n)} if new else row)
    return out


def quick_banner(sizes: str = "") -> str:
    """The line a quick table starts with: what it is for, and what it is not.

    >>> quick_banner("16x16 views, 30 steps").startswith("Quick profile (16x16 views, 30 steps): a smoke test")
    True
    """
    shown = f" ({sizes})" if sizes else ""
    return (f"Quick profile{shown}: a smoke test that every step runs, not a measurement. At this size the figures "
            "rank nothing and may leave their usual ranges (a method above the oracle, the oracle above the perfect-"
            "model figure, an SSIM below 0); the benchmark without its quick profile gives figures to read.")


def compact_tables(per_scene: Sequence[dict], average: Sequence[dict], best: dict[str, str] | None = None,
                   quick: str | None = None, heading: str = "##") -> str:
    """The tables ``mitsnerf bench`` prints, without their legend: :data:`COMPACT` per scene (and averaged over
    scenes when there are several) under ``heading``-level titles, each with its reference line(s) and notes;
    ``quick``: the :func:`quick_banner` first. The results page (:mod:`mitsnerf.bench.page`) shows the same."""
    best = BEST if best is None else best
    per_scene, average = (mark_beaten(with_ceiling_reasons(rows)) for rows in (per_scene, average))
    parts = ([quick, ""] if quick else []) + [
        f"{heading} Per scene", "", markdown_table(per_scene, COMPACT, best, group="scene"), "",
        *reference_lines(per_scene), *_notes(per_scene)]
    if len({r["scene"] for r in per_scene}) > 1:
        parts += ["", f"{heading} Averaged over scenes", "", markdown_table(average, COMPACT, best), "",
                  *reference_lines(average), *_notes(average)]
    return "\n".join(parts)


def compact_report(per_scene: Sequence[dict], average: Sequence[dict], best: dict[str, str] | None = None,
                   quick: str | None = None) -> str:
    """What ``mitsnerf bench`` prints: :func:`compact_tables` and the legend of their columns; ``quick``: the
    :func:`quick_banner` a quick table starts with."""
    return "\n".join([compact_tables(per_scene, average, best, quick), "", legend(COMPACT),
                      "Every column (whole-image and sRGB scores, density and cost figures): table.md, table.csv, "
                      "results.json, report.html."])


def full_tables(per_scene: Sequence[dict], average: Sequence[dict], best: dict[str, str] | None = None,
                quick: str | None = None, heading: str = "##") -> str:
    """Every column, quality and cost, per scene and averaged, under ``heading``-level titles, without the legend
    (``quick``: the :func:`quick_banner` first): ``table.md``'s tables, and the results page's."""
    best = BEST if best is None else best
    per_scene, average = (mark_beaten(with_ceiling_reasons(rows)) for rows in (per_scene, average))
    cost = cost_columns(per_scene)
    parts = ([quick, ""] if quick else []) + [
        f"{heading} Quality per scene",
        "",
        markdown_table(per_scene, QUALITY, best, group="scene"),
        "",
        *reference_lines(per_scene),
        "",
        f"{heading} Cost per scene",
        "",
        markdown_table(per_scene, cost, best, group="scene"),
    ]
    if len({r["scene"] for r in per_scene}) > 1:
        parts += [
            "",
            f"{heading} Quality averaged over scenes",
            "",
            markdown_table(average, QUALITY, best),
            "",
            *reference_lines(average),
            "",
            f"{heading} Cost averaged over scenes",
            "",
            markdown_table(average, cost, best),
        ]
    return "\n".join(parts)


def markdown_report(per_scene: Sequence[dict], average: Sequence[dict], best: dict[str, str] | None = None,
                    quick: str | None = None) -> str:
    """The Markdown written as ``table.md``: :func:`full_tables` and the legend of every column (``quick``: the
    :func:`quick_banner` first)."""
    return "\n".join([full_tables(per_scene, average, best, quick), "", legend(QUALITY + cost_columns(per_scene))])


def csv_keys(rows: Sequence[dict]) -> list[str]:
    """Every column of ``rows``: the table columns first, then the rest in first-seen order."""
    keys = [k for k, _, _ in QUALITY + COST]
    keys = list(dict.fromkeys(keys))
    for row in rows:
        keys.extend(k for k in row if k not in keys)
    return keys


ORACLE = "oracle"
"""The method label of the ceiling rows."""


def ceiling_basis(info: dict) -> str:
    """What an oracle's ceiling rests on (``info``: its ``oracle.json``), in words: the volpath directions per
    point behind its in-scattered light J, their error, its grid, and the spherical-harmonic order of an
    anisotropic medium's.

    >>> print(ceiling_basis({"config": {"spp": 8, "resolution": 16}, "mc_error": {"lbar_rel_se_median": 0.138},
    ...                      "directional": {"g": 0.85, "order": 2}}).replace(", ", ",\\n"))
    J from 8 volpath directions per point of a 16^3 grid,
    median relative error 14%,
    to spherical-harmonic order 2 for g = 0.85
    """
    cfg = info.get("config") or {}
    text = f"J from {cfg.get('spp')} volpath directions per point of a {cfg.get('resolution') or 'true'}^3 grid"
    err = (info.get("mc_error") or {}).get("lbar_rel_se_median")
    if isinstance(err, float) and _is_number(err):
        text += f", median relative error {100 * err:.0f}%"
    directional = info.get("directional")
    if isinstance(directional, dict) and directional.get("order") is not None:
        text += f", to spherical-harmonic order {directional['order']} for g = {directional.get('g')}"
    return text


def oracle_row(scene: str, metrics: dict, info: dict) -> dict:
    """The ceiling row of ``scene``: the oracle's scores at the evaluation footprint, its settings in the note.

    >>> row = oracle_row("cloud", {"psnr_test_medium": 43.0, "psnr_test_medium_per_view": [43.0]},
    ...                  {"config": {"spp": 64, "resolution": 32, "n_samples": 128}, "footprint": 3,
    ...                   "psnr_test_medium": {"footprint_1": 38.0}, "seconds": {"volpath": 60.0}})
    >>> row["method"], row["ceiling"], row["psnr_test_medium"], row["psnr_test_medium_k1"]
    ('oracle', True, 43.0, 38.0)
    >>> row["note"]
    'ceiling: J by volpath (64 directions, 32^3 grid), N = 128, footprint 3; medium at footprint 1: 38.00'
    """
    row: dict = {"scene": scene, "method": ORACLE, "seeds": None, "ceiling": True}
    row.update({k: v for k, v in metrics.items() if v is None or _is_number(v)})
    cfg = info.get("config") or {}
    k1 = (info.get("psnr_test_medium") or {}).get("footprint_1")
    row["psnr_test_medium_k1"] = k1
    row["oracle_seconds"] = sum((info.get("seconds") or {}).values()) or None
    res = cfg.get("resolution") or "true"
    row["ceiling_basis"] = ceiling_basis(info)
    row["note"] = (f"ceiling: J by volpath ({cfg.get('spp')} directions, {res}^3 grid), N = {cfg.get('n_samples')}, "
                   f"footprint {info.get('footprint')}; medium at footprint 1: {_fmt(k1, 2)}")
    if isinstance(metrics.get("mc_note"), str):
        row["note"] += f"; {metrics['mc_note']}"
    return row


def with_oracle_rows(rows: Sequence[dict], oracle_rows: Sequence[dict]) -> list[dict]:
    """``rows`` with each scene's oracle row put before that scene's methods."""
    by_scene = {r["scene"]: r for r in oracle_rows}
    out: list[dict] = []
    for row in rows:
        ceiling = by_scene.pop(row["scene"], None)
        if ceiling is not None:
            out.append(ceiling)
        out.append(row)
    return out + list(by_scene.values())
