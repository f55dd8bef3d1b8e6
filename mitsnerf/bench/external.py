"""A benchmark's ``[[external]]`` entries: other tools' renders, scored as ``mitsnerf score`` does
(:func:`mitsnerf.runs.external.score_renders`) against the benchmark's own datasets, and shown in the
tables, plots and report beside the cells as ``NAME (external)``.

They are scored on every run (it takes seconds), after the datasets exist and before any cell
trains, so a bad renders folder stops the run at once with one error line.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.bench.config import BenchConfig, ExternalRun
from mitsnerf.errors import SpecError
from mitsnerf.runs.external import match_renders


@dataclass(frozen=True)
class ExternalEntry:
    """One external entry on one scene, its paths resolved."""

    run: ExternalRun
    scene: str
    dataset_dir: Path
    renders: Path
    density: Path | None
    timings: dict[str, Any] | None = None

    @property
    def key(self) -> str:
        return f"{self.scene}/{self.run.label}"


def plan_externals(config: BenchConfig, quick: bool, cells: Sequence) -> list[ExternalEntry]:
    """Every (external, scene) of the profile being run; paths relative to the config file's folder.

    A scene name that is not one of the benchmark's, a renders folder or density file that does not
    exist, is a SpecError at ``external.I.renders.NAME`` (``density.NAME``, ``timings.NAME``; a malformed
    timings file: :func:`read_timings`); a folder lacking a test frame's render is a DatasetError naming it.
    All before any dataset is generated.
    """
    datasets = {c.scene: Path(c.dataset_dir) for c in cells}
    n_test = {c.scene: int(c.spec["cameras"]["n_test"]) for c in cells}
    base = config.base_dir
    entries = []
    for i, run in enumerate(config.external):
        files, where = run.files(quick), f"external.{i}" + (".quick" if quick else "")
        for part, table in (("renders", files.renders), ("density", files.density), ("timings", files.timings)):
            for scene in table:
                if scene not in datasets:
                    raise SpecError(config.source, f"{where}.{part}.{scene}",
                                    f"not a scene of this benchmark (scenes: {', '.join(datasets)})")
        for scene, folder in files.renders.items():
            if not (base / folder).is_dir():  # before the datasets and oracles are made, not after
                raise SpecError(config.source, f"{where}.renders.{scene}", f"{base / folder}: renders folder not found")
            density = files.density.get(scene)
            if density is not None and not (base / density).is_file():
                raise SpecError(config.source, f"{where}.density.{scene}", f"{base / density}: density file not found")
            timings = files.timings.get(scene)
            cost = None if timings is None else read_timings(base / timings, config.source, f"{where}.timings.{scene}")
            match_renders(base / folder, [f"r_{k:03d}" for k in range(n_test[scene])], run.format or None)
            entries.append(ExternalEntry(run, scene, datasets[scene], base / folder,
                                         None if density is None else base / density, cost))
    return entries


def read_timings(path: Path, source: str | None = None, where: str = "timings") -> dict[str, Any]:
    """The cost columns of an external row from the JSON its launcher wrote: ``steps`` (int >= 0),
    ``rays_per_step`` (int >= 1), ``train_wall_s`` (seconds > 0) and optionally ``matched``, what the
    budget was set to equal across the table's rows (``"steps"``, the default, or ``"seconds"``).

    A missing file is a SpecError at ``where`` in the config ``source``; a malformed one names the file
    and the field.

    >>> import json, tempfile
    >>> f = Path(tempfile.mkdtemp()) / "timings.json"
    >>> _ = f.write_text(json.dumps({"steps": 800, "rays_per_step": 1024, "train_wall_s": 409.6}))
    >>> read_timings(f)
    {'steps': 800, 'budget': 'steps x 1024 rays', 'train_seconds': 409.6, 'rays_per_s': 2000.0}
    >>> _ = f.write_text(json.dumps({"steps": 800, "rays_per_step": 0, "train_wall_s": 409.6}))
    >>> read_timings(f)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    mitsnerf.errors.SpecError: ...timings.json: rays_per_step: must be an integer >= 1, got 0
    """
    import json
    import math

    if not path.is_file():
        raise SpecError(source, where, f"{path}: timings file not found")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise SpecError(str(path), None, f"not a JSON file ({exc})") from None
    if not isinstance(data, dict):
        raise SpecError(str(path), None, "must be a JSON object")

    def number(key: str, lo: float, integer: bool) -> Any:
        v = data.get(key)
        if integer:
            ok, kind = isinstance(v, int) and not isinstance(v, bool) and v >= lo, f"an integer >= {lo:g}"
        else:
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > lo
            kind = f"a number > {lo:g}"
        if not ok:
            raise SpecError(str(path), key, f"must be {kind}, got {v!r}" if key in data else "missing")
        return v

    steps, rays, seconds = number("steps", 0, True), number("rays_per_step", 1, True), number("train_wall_s", 0, False)
    matched = data.get("matched", "steps")
    if matched not in ("steps", "seconds"):
        raise SpecError(str(path), "matched", f'must be "steps" or "seconds", got {matched!r}')
    budget = f"steps x {rays} rays" + (" (seconds matched)" if matched == "seconds" else "")
    return {"steps": steps, "budget": budget, "train_seconds": float(seconds),
            "rays_per_s": round(steps * rays / seconds, 1)}


def score_external(
    entry: ExternalEntry, report_view: int = 0, oracle=None
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """``(record, artefacts)`` of one entry, shaped as a cell's (:mod:`mitsnerf.bench.cells`); ``oracle``:
    the dataset's (:class:`mitsnerf.oracle.cache.Oracle`, the cells'), else whatever is cached."""
    from mitsnerf import env
    from mitsnerf.bench.worker import oracle_summary
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.runs.external import score_renders

    dataset = load_dataset(entry.dataset_dir)
    k = entry.run.footprint
    s = score_renders(dataset, entry.renders, density=entry.density, name=entry.run.name, fmt=entry.run.format or None,
                      footprint=k, oracle=oracle, exr_alpha=entry.run.exr_alpha or None)
    record = {"key": entry.key, "scene": entry.scene, "method": entry.run.label, "method_name": "external",
              "seed": 0, "external": True, "renders": str(entry.renders), "matched_by": s.matched_by,
              "density": s.density, "oracle_source": s.oracle, "oracle": oracle_summary(s.oracle_used, k),
              "dataset": str(dataset.root), "metrics": {**s.metrics, **(entry.timings or {}), "footprint": k},
              "provenance": env.provenance()}
    ref = s.reference
    v = min(report_view, len(ref.cameras) - 1)
    artefacts = {"ref": np.asarray(ref.images[v], np.float32), "render": s.renders[v], "view": np.int32(v), **s.slices}
    if ref.masks is not None:
        artefacts["mask"] = ref.masks[v]
    return record, artefacts
