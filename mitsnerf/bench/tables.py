"""Result tables: cells aggregated per (scene, method) over seeds and averaged over scenes, as
Markdown (terminal and file), CSV and JSON-ready rows; the best value per column marked.

Two tables each: *quality* (image scores in both encodings, whole image and medium pixels,
the ground truth's noise floor and the oracle next to them, density-field errors) and *cost*
(training time, throughput, peak memory, parameters). Each scene with an oracle
(:mod:`mitsnerf.oracle`) gets an ``oracle`` row first (:func:`oracle_row`): the ceiling any
emission-absorption method can reach on that dataset, never marked best.
"""

from __future__ import annotations

import csv
import io
import math
import re
from typing import Any, Iterable, Sequence

Column = tuple[str, str, int]
"""(key, header, decimals)."""

KEYS: tuple[Column, ...] = (("scene", "scene", 0), ("method", "method", 0), ("seeds", "seeds", 0))
QUALITY: tuple[Column, ...] = KEYS + (
    ("psnr_test", "PSNR lin", 2),
    ("psnr_test_medium", "PSNR lin medium", 2),
    ("noise_floor_psnr", "GT floor", 2),
    ("noise_floor_psnr_medium", "GT floor medium", 2),
    ("oracle_psnr_test_medium", "oracle medium", 2),
    ("gap_to_oracle", "gap to oracle", 2),
    ("psnr_test_srgb", "PSNR sRGB", 2),
    ("psnr_test_medium_srgb", "PSNR sRGB medium", 2),
    ("ssim_test", "SSIM lin", 4),
    ("ssim_test_srgb", "SSIM sRGB", 4),
    ("psnr_train", "PSNR train", 2),
    ("density_rel_l1", "sigma rel L1", 3),
    ("density_rel_l2", "sigma rel L2", 3),
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
    ("peak_rss_mb", "peak RSS MiB", 0),
    ("num_parameters", "params", 0),
    ("curve_eval_seconds", "curve eval s", 1),
    ("note", "note", 0),
)
_TO_TARGET = re.compile(r"seconds_to_(.+)db")
BEST: dict[str, str] = {
    "psnr_test": "max", "psnr_test_medium": "max", "psnr_test_srgb": "max", "psnr_test_medium_srgb": "max",
    "ssim_test": "max", "ssim_test_srgb": "max", "psnr_train": "max",
    "density_rel_l1": "min", "density_rel_l2": "min", "density_psnr": "max", "tau_rel_l1": "min",
    "transmittance_mae": "min", "rays_per_s": "max", "samples_per_s": "max", "peak_rss_mb": "min",
}  # and "min" for every "seconds to X dB" column, whatever the config's targets (:func:`best_values`)
LEGEND = (
    "PSNR/SSIM of the test views; lin: linear radiance clipped to [0, 1]; sRGB: the clipped values "
    "sRGB-encoded; medium: only pixels whose ray crosses the true medium. GT floor: PSNR between two "
    "independent ground-truth renders of the test views (manifest noise_floor; a noise-free model scores "
    "about 3 dB above it). oracle (the ceiling row): the true sigma_t with the in-scattered radiance J "
    "estimated by volpath, rendered by the package's integrator at the same footprint: the best an "
    "emission-absorption model can do on the dataset at the oracle's grid resolution; gap to oracle: "
    "oracle medium PSNR minus the method's. sigma: learned against true density on the voxel centres; tau: optical depth "
    "along every test ray; T MAE: mean abs error of the transmittance exp(-tau). budget: what set the run's "
    "length (steps: the table is the same on any machine and load; a seconds cap makes it machine-dependent). "
    "footprint K: each test pixel is the mean of K x K rays over its area (1: its centre ray). "
    "train s excludes held-out evaluation; s to X dB medium: training seconds at the first held-out "
    "evaluation (steps k/N of the budget) reaching X dB on medium pixels (measured, not decisive). "
    "peak RSS: the high-water mark of the process that ran the cell (cumulative over "
    "the cells of a sequential run, so not marked best there). "
    "NAME (external): renders made by another tool, scored as mitsnerf score does (no training or cost figures). "
    "Bold: best in the column (per scene). Means over seeds."
)


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


def _cell_text(row: dict, key: str, digits: int) -> str:
    """A table cell: the formatted value; a ceiling row's method reads ``oracle (ceiling)``."""
    text = _fmt(row.get(key), digits)
    return f"{text} (ceiling)" if key == "method" and row.get("ceiling") else text


def best_values(rows: Sequence[dict], best: dict[str, str], group: str | None = None) -> dict[tuple[Any, str], Any]:
    """``{(group value, key): best value}`` over rows with at least two numbers in the column; the
    "seconds to X dB" columns found in ``rows`` are best at their minimum."""
    marks: dict[tuple[Any, str], Any] = {}
    groups: dict[Any, list[dict]] = {}
    for row in rows:
        groups.setdefault(row.get(group) if group else None, []).append(row)
    to_target = {k: "min" for r in rows for k in r if _TO_TARGET.fullmatch(k)}
    for g, members in groups.items():
        members = [r for r in members if not r.get("ceiling")]
        for key, how in {**to_target, **best}.items():
            values = [r[key] for r in members if _is_number(r.get(key))]
            if len(values) > 1:
                marks[(g, key)] = max(values) if how == "max" else min(values)
    return marks


def markdown_table(rows: Sequence[dict], columns: Sequence[Column], best: dict[str, str] | None = None,
                   group: str | None = None) -> str:
    """A Markdown table of ``rows``; ``columns`` are (key, header, decimals).

    ``best`` maps a key to ``"max"`` or ``"min"``: the best value in that column is bold
    (within each group of rows sharing ``row[group]`` when ``group`` is given).

    >>> print(markdown_table([{"m": "a", "p": 30.0}, {"m": "b", "p": 31.5}], [("m", "method", 0), ("p", "PSNR", 2)], {"p": "max"}))
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
            mark = marks.get((row.get(group) if group else None, key))
            if mark is not None and row.get(key) == mark:
                text = f"**{text}**"
            cells.append(text)
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
    return row


def _aggregate(rows: Sequence[dict], base: dict) -> dict:
    """Means (and ``_std``) of the numeric columns of ``rows``; a text column kept where every row agrees."""
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
        if not values:
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
            notes = sorted({c["density_note"] for c in members if c.get("density_note")})
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


def markdown_report(per_scene: Sequence[dict], average: Sequence[dict], best: dict[str, str] | None = None) -> str:
    """The Markdown printed and written as ``table.md``: quality and cost, per scene and averaged."""
    best = BEST if best is None else best
    cost = cost_columns(per_scene)
    parts = ["## Quality per scene", "", markdown_table(per_scene, QUALITY, best, group="scene"), "",
             "## Cost per scene", "", markdown_table(per_scene, cost, best, group="scene")]
    if len({r["scene"] for r in per_scene}) > 1:
        parts += ["", "## Quality averaged over scenes", "", markdown_table(average, QUALITY, best), "",
                  "## Cost averaged over scenes", "", markdown_table(average, cost, best)]
    parts += ["", LEGEND]
    return "\n".join(parts)


def csv_keys(rows: Sequence[dict]) -> list[str]:
    """Every column of ``rows``: the table columns first, then the rest in first-seen order."""
    keys = [k for k, _, _ in QUALITY + COST]
    keys = list(dict.fromkeys(keys))
    for row in rows:
        keys.extend(k for k in row if k not in keys)
    return keys


ORACLE = "oracle"
"""The method label of the ceiling rows."""


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
    row["note"] = (f"ceiling: J by volpath ({cfg.get('spp')} directions, {res}^3 grid), N = {cfg.get('n_samples')}, "
                   f"footprint {info.get('footprint')}; medium at footprint 1: {_fmt(k1, 2)}")
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
