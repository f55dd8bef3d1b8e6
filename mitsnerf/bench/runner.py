"""Run a benchmark: plan every (scene, method, seed) cell, run the missing ones, write the outputs.

1. **Plan** (:func:`plan_cells`): every cell resolved and validated before anything runs
   (scene spec with the ``--quick`` overrides, method config, training budget, evaluation).
2. **Skip** cells whose ``result.json`` has the same config hash and code version
   (:func:`mitsnerf.bench.cells.is_done`) unless ``force``; an interrupted sweep resumes.
3. **Ground truth**: the datasets of scenes with pending cells are generated once, here
   (cached by :func:`mitsnerf.generate.generate_dataset`), and so is each dataset's
   emission-absorption oracle (:func:`mitsnerf.oracle.cache.ensure_oracle`, cached in the
   dataset directory: the ceiling row of the tables, and every cell's error budget).
4. **Run** the pending cells on an executor (:mod:`mitsnerf.bench.executors`); each finished
   cell is written at once, atomically (a failed one as ``error.json``, retried next time).
5. **Outputs** from every cell on disk (:func:`write_outputs`), under ``results/<bench>[-quick]/``:
   ``table.md`` (every column; a compact table is printed), ``table.csv`` (per scene and method), ``average.csv``,
   ``cells.csv`` (one row per cell), ``results.json`` (everything, with provenance: the commit, the machine, when
   the tables were written and the command that ran the sweep; ``mitsnerf results`` makes a page of it),
   ``plots/*.png`` and ``report.html`` (self-contained).

The config's ``[[external]]`` entries (other tools' renders) are scored after step 3, before any
cell trains (:mod:`mitsnerf.bench.external`), and appear in every output as ``NAME (external)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf import env
from mitsnerf.bench.cells import (
    ARTEFACTS_FILE,
    ERROR_FILE,
    Cell,
    SceneData,
    cell_dir,
    code_version,
    is_done,
    read_record,
    write_error,
    write_result,
)
from mitsnerf.bench.config import BenchConfig, method_order
from mitsnerf.bench.tables import (
    ORACLE,
    average_rows,
    best_rules,
    cell_row,
    compact_report,
    csv_keys,
    csv_table,
    markdown_report,
    oracle_row,
    quick_banner,
    scene_rows,
    with_ceiling_reasons,
    with_oracle_rows,
)
from mitsnerf.config import from_dict, to_dict
from mitsnerf.data.atomic import atomic_write_json, atomic_write_text
from mitsnerf.errors import CLI, SpecError, Words, signal_cause
from mitsnerf.outputs import data_cache, progress_log


def _cache_dir() -> Path:
    return data_cache()[0]


@dataclass(frozen=True)
class BenchOptions:
    quick: bool = False
    data_root: Path = field(default_factory=_cache_dir)
    """Where the datasets and their oracles are cached (default :func:`mitsnerf.outputs.data_cache`: the user's
    cache directory, shared by every working directory)."""
    results_root: Path = Path("results")
    progress: bool = True
    executor: str = "sequential"
    """``sequential`` (in this process), ``pool`` (local processes) or ``ray``."""
    workers: int = 0
    """Cells at once for ``pool`` and ``ray`` (0: the executor's default)."""
    address: str | None = None
    """Ray cluster address (``ray`` only; None: start a local instance)."""
    cpus_per_cell: int = 0
    """Dr.Jit threads (Ray: CPUs) per cell (0: all cores sequentially; cores / workers in a pool; 1 on Ray)."""
    force: bool = False
    """Recompute every cell, even those with a result for the same config and code."""
    code_version: str | None = None
    """The code version results are keyed by (None: :func:`mitsnerf.bench.cells.code_version`)."""
    report: bool = True
    """Write the plots and the HTML report (tables are always written)."""
    verify_hashes: bool = True
    """Check a cached dataset's files against its manifest's sha256 hashes (``--no-verify``: not)."""
    words: Words = CLI
    """How messages name the options: the command line's (``--force``) or the Python API's (``force=True``)."""
    command: str | None = None
    """The command that ran the sweep, as typed (``mitsnerf bench physics --quick``), recorded in ``results.json``
    for the results page (:mod:`mitsnerf.bench.page`); None: not known (a caller that is not the command line)."""


@dataclass
class BenchResult:
    out_root: Path
    cells: list[Cell]
    records: list[dict]
    failed: list[dict]
    computed: list[str] = field(default_factory=list)
    """Keys of the cells run this time (finished)."""
    skipped: list[str] = field(default_factory=list)
    """Keys of the cells whose results were already there."""
    per_scene: list[dict] = field(default_factory=list)
    average: list[dict] = field(default_factory=list)
    markdown: str = ""
    """The compact tables printed by ``mitsnerf bench`` (:func:`mitsnerf.bench.tables.compact_report`)."""
    files: dict[str, Path] = field(default_factory=dict)
    external: list[tuple[dict, dict]] = field(default_factory=list)
    """``(record, artefacts)`` of every external entry, scored this run."""


def out_root_of(config: BenchConfig, options: BenchOptions) -> Path:
    return Path(options.results_root) / (config.name + ("-quick" if options.quick else ""))


def plan_scenes(config: BenchConfig, options: BenchOptions) -> list[SceneData]:
    """Every scene of ``config``, resolved and validated (a SpecError naming the bench file and field)."""
    from mitsnerf.generate import data_inputs, dataset_dir

    data_root = Path(options.data_root).resolve()
    evalc = to_dict(config.eval_config(options.quick))
    oracle = config.oracle_config(options.quick)
    oracle_data = to_dict(oracle) if oracle.enabled else None
    return [SceneData(scene=spec.name, spec=spec.to_dict(), eval=evalc, dataset_dir=str(dataset_dir(spec, data_root)),
                      data_root=str(data_root), oracle=oracle_data, data_inputs=data_inputs(spec))
            for spec in _scene_specs(config, options.quick)]


def plan_cells(config: BenchConfig, options: BenchOptions, scenes: list[SceneData] | None = None) -> list[Cell]:
    """Every cell of ``config`` (on ``scenes``, default :func:`plan_scenes`), resolved and validated (a
    SpecError naming the bench file and field). Per scene, the rows go in
    :func:`~mitsnerf.bench.config.method_order` (a row after the rows its ``"@LABEL"`` settings name), each with
    its seeds."""
    import mitsuba as mi

    from mitsnerf.bench.references import cell_references
    from mitsnerf.methods import get_method

    variant = mi.variant() or env.set_variant()
    version = options.code_version or code_version()
    out_root = out_root_of(config, options).resolve()
    cells: list[Cell] = []
    for site in plan_scenes(config, options) if scenes is None else scenes:
        planned: dict[int, dict[str, Cell]] = {seed: {} for seed in config.seeds}  # this scene's, by seed and label
        for method, resolved, train in _method_settings(config, options.quick):
            for seed in config.seeds:
                cell = Cell(
                    bench=config.name, scene=site.scene, label=method.label, method=method.name, seed=seed,
                    spec=site.spec, method_config=resolved, train=train[seed], eval=site.eval,
                    variant=variant, code_version=version, dataset_dir=site.dataset_dir, data_root=site.data_root,
                    out_dir=str(cell_dir(out_root, site.scene, method.label, seed)), quick=options.quick,
                    oracle=site.oracle, method_version=get_method(method.name).source.version,
                    data_inputs=site.data_inputs, references=cell_references(resolved, planned[seed]) or None,
                )
                planned[seed][method.label] = cell
                cells.append(cell)
    return cells


def _scene_specs(config: BenchConfig, quick: bool) -> list:
    """The benchmark's scene specs, with the config's ``scene`` overrides, then (``quick``) the quick
    profile's (each problem blamed on ``scene.KEY`` or ``quick.scene.KEY``).

    A spec given by a relative path is relative to the config file's folder, as external renders are.
    """
    layers = [("scene", config.scene)] + ([("quick.scene", config.quick.scene)] if quick else [])
    specs = []
    for i, name in enumerate(config.scenes):
        spec = _listed_scene(config, i, name)
        for where, overrides in layers:
            if not overrides:
                continue
            try:
                spec = spec.with_overrides(overrides)
            except SpecError as exc:
                raise SpecError(config.source, f"{where}.{exc.field}" if exc.field else where,
                                f"{exc.message} (scene {name})") from None
        specs.append(spec)
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise SpecError(
            config.source, "scenes", f"two specs share a name ({', '.join(names)}); results are keyed by name"
        )
    return specs


def _listed_scene(config: BenchConfig, i: int, name: str):
    """``scenes[i]`` of ``config`` loaded; an unknown scene name or a missing spec file is a SpecError at
    ``scenes.I`` of the bench file (a problem inside a spec file names that file)."""
    from mitsnerf.scene.spec import is_spec_path, load_scene

    path = config.base_dir / name if is_spec_path(name) else None
    if path is not None and not path.exists():
        raise SpecError(config.source, f"scenes.{i}", f"{path}: no such spec file")
    try:
        return load_scene(path or name)
    except SpecError as exc:
        if path is None and exc.where == name:  # not a library scene: the bench file named it
            raise SpecError(config.source, f"scenes.{i}", exc.message) from None
        raise


def _method_settings(config: BenchConfig, quick: bool) -> list[tuple[Any, dict, dict[int, dict]]]:
    """``(method, resolved method config, {seed: resolved train settings})`` per method, validated, in
    :func:`~mitsnerf.bench.config.method_order`; a problem is blamed on the field of the bench file that set
    it."""
    from mitsnerf.methods import get_method
    from mitsnerf.train import TrainConfig

    out = []
    for method in method_order(config, quick):
        mconfig, train = config.method_settings(method, quick)
        if "seed" in train:
            raise config.blame(method, quick, "train", ValueError("seed: set by the benchmark's seeds, not per method"))
        try:
            resolved = to_dict(from_dict(get_method(method.name).config_type, mconfig))
        except ValueError as exc:
            raise config.blame(method, quick, "config", exc) from None
        try:
            trains = {seed: to_dict(from_dict(TrainConfig, {**train, "seed": seed})) for seed in config.seeds}
        except ValueError as exc:
            raise config.blame(method, quick, "train", exc) from None
        out.append((method, resolved, trains))
    return out


def _generate(cells: list, options: BenchOptions, log: Callable[[str], None]) -> None:
    """Generate (or find cached) the dataset of every scene among ``cells`` (cells or :class:`SceneData`), here,
    once."""
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import parse_scene

    seen: set[str] = set()
    for cell in cells:
        if cell.dataset_dir in seen:
            continue
        seen.add(cell.dataset_dir)
        if not (Path(cell.dataset_dir) / "manifest.json").is_file():
            log(f"[{cell.scene}] rendering the ground truth (cached for later runs) ...")
        path = generate_dataset(parse_scene(dict(cell.spec), f"<scene {cell.scene}>"), Path(cell.data_root),
                                progress=options.progress, verify_hashes=options.verify_hashes)
        if str(path.resolve()) != str(Path(cell.dataset_dir).resolve()):  # pragma: no cover (hash drift)
            raise RuntimeError(f"dataset of {cell.scene} went to {path}, planned {cell.dataset_dir}")
        if cell.oracle is not None:
            from mitsnerf.bench.worker import cell_oracle

            cell_oracle(cell, log=lambda line, scene=cell.scene: log(f"[{scene}] {line}"))



def _load_artefacts(cell: Cell) -> dict[str, np.ndarray]:
    path = cell.path / ARTEFACTS_FILE
    if not path.is_file():
        return {}
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError):
        return {}


def oracle_rows(records: list[dict], scenes: list[str]) -> list[dict]:
    """The ceiling row of every scene whose cells name a cached oracle (:func:`mitsnerf.bench.tables.oracle_row`)."""
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.oracle.cache import load_oracle, variance_free

    rows = []
    for scene in scenes:
        record = next((r for r in records if r["scene"] == scene and r.get("oracle")), None)
        summary = record["oracle"] if record is not None else None
        oracle = load_oracle(Path(summary["path"])) if summary is not None else None
        if record is not None and summary is not None and oracle is not None:
            if "psnr_test_medium_without_mc" not in oracle.metrics(summary["footprint"]):  # cached before it was kept
                oracle = variance_free(oracle, load_dataset(Path(record["dataset"])), summary["footprint"])
            rows.append(oracle_row(scene, oracle.metrics(summary["footprint"]), oracle.info))
    return rows


def collect(cells: list[Cell]) -> tuple[list[dict], list[dict]]:
    """``(records, failures)`` on disk for ``cells`` (matching config hash and code version)."""
    records, failed = [], []
    for cell in cells:
        record = read_record(cell.path) if is_done(cell) else None
        if record is not None:
            records.append(record)
            continue
        err = read_record(cell.path, ERROR_FILE)
        if err and err.get("config_hash") == cell.config_hash and err.get("code_version") == cell.code_version:
            failed.append({**err, "scene": cell.scene, "method": cell.label, "seed": cell.seed})
    return records, failed


def quick_sizes(cells: Sequence[Any]) -> str:
    """The sizes a quick run has, in words (for :func:`mitsnerf.bench.tables.quick_banner`): each distinct value
    across ``cells`` (:class:`Cell`, or anything with its ``spec`` and ``train``), ``16x16 views, 2 test views at
    16 spp, 30 steps``."""
    def values(get) -> str:
        return "/".join(dict.fromkeys(str(get(c)) for c in cells))

    def size(cell: Cell) -> str:
        return f"{cell.spec['cameras']['width']}x{cell.spec['cameras']['height']}"

    if not cells:
        return ""
    return (f"{values(size)} views, {values(lambda c: c.spec['cameras']['n_test'])} test views at "
            f"{values(lambda c: c.spec['render']['spp_test'])} spp, {values(lambda c: c.train['steps'])} steps")


def write_outputs(config: BenchConfig, options: BenchOptions, cells: list[Cell], result: BenchResult) -> BenchResult:
    """Tables, CSV, JSON, plots and the HTML report from the cells' results on disk and the external entries."""
    out_root = out_root_of(config, options)
    out_root.mkdir(parents=True, exist_ok=True)
    records, failed = collect(cells)
    records += [record for record, _ in result.external]
    scenes = list(dict.fromkeys([c.scene for c in cells] + [r["scene"] for r, _ in result.external]))
    methods = [m.label for m in config.methods] + list(dict.fromkeys(r["method"] for r, _ in result.external))
    ceilings = oracle_rows(records, scenes)
    per_scene = with_oracle_rows(scene_rows(records, failed, scenes, methods), ceilings)
    average = average_rows(per_scene, methods)
    if len(ceilings) > 1:
        average = [{**r, "ceiling": True} for r in average_rows(ceilings, [ORACLE])] + average
    per_scene, average = with_ceiling_reasons(per_scene), with_ceiling_reasons(average)  # every output says why
    best = best_rules(records)
    quick = quick_banner(quick_sizes(cells)) if options.quick else None
    markdown = compact_report(per_scene, average, best, quick)
    files = {"table.md": out_root / "table.md", "table.csv": out_root / "table.csv",
             "average.csv": out_root / "average.csv", "cells.csv": out_root / "cells.csv",
             "results.json": out_root / "results.json"}
    title = f"mitsnerf benchmark {config.name}" + (" (quick)" if options.quick else "")
    atomic_write_text(files["table.md"], f"# {title}\n\n{markdown_report(per_scene, average, best, quick)}\n")
    atomic_write_text(files["table.csv"], csv_table(per_scene, csv_keys(per_scene)))
    atomic_write_text(files["average.csv"], csv_table(average, csv_keys(average)))
    cell_rows = [cell_row(r) for r in records]
    atomic_write_text(
        files["cells.csv"],
        csv_table(
            cell_rows,
            ["scene", "method", "seed"]
            + [k for k in csv_keys(cell_rows) if k not in ("scene", "method", "seed", "seeds", "note")],
        ),
    )
    provenance = env.provenance()
    config_data = {"name": config.name, "description": config.description, "quick": options.quick,
                   "cells": [c.identity() for c in cells]}
    notes = [f"code version {cells[0].code_version if cells else '?'}; executor {options.executor}; "
             f"{len(records)} of {len(cells)} cells have results"]
    atomic_write_json(files["results.json"], {
        "benchmark": config.name, "description": config.description, "quick": options.quick,
        "code_version": cells[0].code_version if cells else None, "provenance": provenance,
        "command": options.command, "written": _now(),
        "executor": options.executor, "tables": {"per_scene": per_scene, "average": average},
        "failed": failed, "cells": records, "config": config_data,
    })
    if options.report:
        files.update(_write_report(out_root, cells, result, records, scenes, methods, title=title, per_scene=per_scene,
                                   average=average, provenance=provenance, config=config_data, failed=failed,
                                   notes=[quick, *notes] if quick else notes, best=best))
    result.records, result.failed = records, failed
    result.per_scene, result.average, result.markdown, result.files = per_scene, average, markdown, files
    return result


def _now() -> str:
    """The time now, UTC, to the second (ISO 8601): when a sweep's tables were written."""
    from datetime import datetime, timezone

    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _write_report(out_root: Path, cells: list[Cell], result: BenchResult, records: list[dict], scenes: list[str],
                  methods: list[str], **report: Any) -> dict[str, Path]:
    """The plots per scene (cells' artefacts from disk, the external entries' from memory) and the HTML report."""
    from mitsnerf.bench.plots import scene_figures
    from mitsnerf.bench.report import write_report

    files, figures = {}, {}
    for scene in scenes:
        mine = [r for r in records if r["scene"] == scene]
        if not mine:
            continue
        arts = {c.key: _load_artefacts(c) for c in cells if c.scene == scene and is_done(c)}
        arts.update({r["key"]: a for r, a in result.external if r["scene"] == scene})
        figures[scene] = scene_figures(scene, mine, methods, arts, out_root / "plots")
        for _, path in figures[scene]:
            files[f"plots/{path.name}"] = path
    files["report.html"] = write_report(out_root / "report.html", figures=figures, **report)
    return files


def _score_externals(config: BenchConfig, options: BenchOptions, cells: list[SceneData],
                     log: Callable[[str], None]) -> list:
    """Score the config's external entries on the benchmark's datasets (``cells``: one per scene; generated here
    if needed)."""
    from mitsnerf.bench.external import plan_externals, score_external

    entries = plan_externals(config, options.quick, cells)
    if not entries and not config.methods:
        raise SpecError(config.source, "external", "nothing to run: no method, and no entry has renders for "
                                                   f"the datasets of {options.words(quick=True)} (its quick = "
                                                   "{ renders = ... } table)")
    if not entries:
        return []
    _generate([c for c in cells if c.scene in {e.scene for e in entries}], options, log)
    from mitsnerf.bench.worker import cell_oracle

    view = config.eval_config(options.quick).report_view
    first = {c.scene: c for c in reversed(cells)}
    oracles = {scene: cell_oracle(first[scene], log=log) for scene in dict.fromkeys(e.scene for e in entries)}
    scored = []
    for entry in entries:
        record, artefacts = score_external(entry, view, oracles[entry.scene])
        scored.append((record, artefacts))
        log(f"[external] {entry.key}: PSNR {record['metrics']['psnr_test']:.2f} dB (renders matched by "
            f"{record['matched_by']}, {entry.renders})")
    return scored


def run_benchmark(config: BenchConfig, options: BenchOptions, log: Callable[[str], None] | None = None) -> BenchResult:
    """Run every missing cell of ``config``, then write the outputs; see the module docstring.

    ``log`` receives one line per event (default: print to stderr when ``options.progress``).
    An interrupt (Ctrl-C) keeps every finished cell on disk and re-raises.
    """
    from mitsnerf.bench.executors import check_options, run_cells

    check_options(options.executor, options.workers, options.cpus_per_cell, options.address, options.words)
    if log is None:
        log = progress_log(options.progress)
    scenes = plan_scenes(config, options)
    cells = plan_cells(config, options, scenes)
    out_root = out_root_of(config, options)
    result = BenchResult(out_root=out_root, cells=cells, records=[], failed=[])
    result.external = _score_externals(config, options, scenes, log)
    pending = [c for c in cells if options.force or not is_done(c)]
    result.skipped = [c.key for c in cells if c not in pending]
    if result.skipped:
        log(f"{len(result.skipped)} of {len(cells)} cells already done (same config and code); "
            f"{len(pending)} to run" + (f" ({options.words(force=True)} recomputes them)" if pending else ""))
    if pending:
        _generate(pending, options, log)
        total = len(pending)

        def on_done(cell: Cell, record: dict, artefacts: bytes) -> None:
            write_result(cell, record, artefacts)
            result.computed.append(cell.key)
            m = record["metrics"]
            med = m.get("psnr_test_medium")
            log(f"[{len(result.computed)}/{total}] {cell.key}: PSNR {m['psnr_test']:.2f} dB"
                + (f" (medium {med:.2f})" if med is not None else "")
                + f", {m['train_seconds']:.1f} s, {m['steps']} steps")

        def on_error(cell: Cell, message: str, details: str) -> None:
            write_error(cell, message, details)
            log(f"[failed] {cell.key}: {message}")

        def on_start(cell: Cell) -> None:
            log(f"[{len(result.computed) + 1}/{total}] {cell.key}: training {cell.method} ...")

        try:
            run_cells(options.executor, pending, on_done, on_error, progress=options.progress,
                      workers=options.workers, threads=options.cpus_per_cell, address=options.address,
                      on_start=on_start, words=options.words)
        except BaseException as exc:  # Ctrl-C, SIGTERM, SIGHUP: the same exit status, the cells kept
            if signal_cause(exc) is None:
                raise
            raise _stopped(exc, f"{len(result.computed)} cells finished in this run are saved under {out_root}; "
                                f"{options.words.again('bench')} to resume (the cell in flight continues from its "
                                "checkpoint, if it reached one)") from None
    try:
        return write_outputs(config, options, cells, result)
    except BaseException as exc:  # after the last cell: only the tables and the report are missing
        if signal_cause(exc) is None:
            raise
        raise _stopped(exc, f"every cell is saved under {out_root}; {options.words.again('bench')} to write the "
                            "tables and the report") from None


def _stopped(exc: BaseException, saved: str):
    """The :class:`~mitsnerf.errors.Interrupted` of a sweep stopped by the signal in ``exc`` (also one that an
    import or a library turned into another error, :func:`mitsnerf.errors.signal_cause`): what is saved, what to do."""
    from mitsnerf.errors import Interrupted
    from mitsnerf.train.checkpointing import signal_number

    stop = signal_cause(exc)
    if stop is None:
        raise AssertionError("_stopped is only called for a signal") from exc
    return Interrupted(signal_number(stop), (f"{stop}; " if str(stop) else "") + saved)
