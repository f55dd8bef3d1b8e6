"""The cells of a sweep: one (scene, method, seed) each, fully resolved, hashed, and their results on disk.

A :class:`Cell` carries everything a worker needs (the scene spec as data, the resolved
method and training configs, the evaluation settings, the variant, where to write), so it
can run in another process or on another machine. Its ``config_hash`` covers all of that
except the paths; a result on disk counts as done when its ``config_hash`` and
``code_version`` both match (see :func:`is_done`), so a sweep run again computes only what
is missing or stale.

Layout under ``results/<bench>[-quick]/``::

    cells/<scene>/<label>-seed<k>/result.json     the record (metrics, curve, provenance), written last
                                 /artefacts.npz   images and density slices for the plots
                                 /error.json      instead of result.json when the cell failed
                                 /run/            mitsnerf.runs.fit.fit's run directory (params, checkpoint, renders)
                                 /run/export/     its medium exported, when a row starts from it ("@LABEL",
                                                  mitsnerf.bench.references); removed when the cell runs again
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

RESULT_FILE = "result.json"
ARTEFACTS_FILE = "artefacts.npz"
ERROR_FILE = "error.json"
#: Which cell the checkpoint in ``CELL/run`` belongs to (config hash and code version), written before
#: training: a sweep stopped by a signal continues the cell in flight from its checkpoint only if they match.
#: Removed when the cell's result is written (a finished cell is not in flight).
IN_FLIGHT_FILE = "in_flight.json"
RECORD_FORMAT = 1
"""Version of the result record layout; part of every cell's hash."""


def code_version() -> str:
    """The code a result was computed with: ``<mitsnerf version>+<commit>`` (``+dirty`` if modified).

    A dirty checkout cannot be told apart from another dirty checkout of the same commit:
    pass ``--force`` after changing code without committing.
    """
    from mitsnerf import __version__
    from mitsnerf.env import git_commit

    return f"{__version__}+{git_commit()}"


def canonical_hash(obj: Any) -> str:
    """sha256 of the canonical JSON (sorted keys, no spaces) of ``obj``."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class Cell:
    """One (scene, method, seed) run of a benchmark, resolved and self-contained."""

    bench: str
    scene: str
    """The scene spec's name (unique within a benchmark)."""
    label: str
    """The method's column label."""
    method: str
    """The registered method name."""
    seed: int
    spec: Mapping[str, Any]
    """``SceneSpec.to_dict()`` after the benchmark's overrides: a worker can regenerate the dataset."""
    method_config: Mapping[str, Any]
    """The method's config, every field resolved (``to_dict`` of the dataclass)."""
    train: Mapping[str, Any]
    """``TrainConfig`` resolved, seed included."""
    eval: Mapping[str, Any]
    """``EvalConfig`` resolved."""
    variant: str
    code_version: str
    dataset_dir: str
    """Where the driver generated the dataset (absolute)."""
    data_root: str
    """Dataset cache root a worker regenerates into when ``dataset_dir`` is missing there."""
    out_dir: str
    """The cell's directory (absolute)."""
    quick: bool = False
    oracle: Mapping[str, Any] | None = None
    """``OracleConfig`` resolved (the dataset's oracle, scored at the eval footprint); None: no oracle."""
    method_version: str | None = None
    """A plugin method's version (:attr:`mitsnerf.plugins.Source.version`: its distribution's name and version,
    and a sha256 of its source), part of the hash: editing a plugin reruns its cells alone. None: a built-in,
    which ``code_version`` covers."""
    data_inputs: Mapping[str, Any] | None = None
    """What decides the dataset beyond the spec's text (:func:`mitsnerf.generate.data_inputs`: a grid file's
    sha256, a plugin volume family's version), part of the hash: editing a grid reruns its scene's cells."""
    references: Mapping[str, Mapping[str, str]] | None = None
    """The cells of the same scene and seed whose runs this cell's ``"@LABEL"`` settings name
    (:mod:`mitsnerf.bench.references`): ``LABEL -> {key, out_dir, config_hash}``; their config hashes are part
    of this cell's, so changing a referred row reruns this one. None: it refers to none."""

    @property
    def key(self) -> str:
        """``scene/label-seedK``, unique within a benchmark."""
        return f"{self.scene}/{self.label}-seed{self.seed}"

    def identity(self) -> dict[str, Any]:
        """Everything that decides the cell's result, except mitsnerf's code version (a plugin method's is in)."""
        plugin = {} if self.method_version is None else {"method_version": self.method_version}
        inputs = {} if self.data_inputs is None else {"data_inputs": self.data_inputs}
        refs = {} if not self.references else {"references": {k: r["config_hash"] for k, r in self.references.items()}}
        return {
            **plugin,
            **inputs,
            **refs,
            "record_format": RECORD_FORMAT,
            "scene": self.scene,
            "spec": self.spec,
            "method": self.method,
            "label": self.label,
            "seed": self.seed,
            "method_config": self.method_config,
            "train": self.train,
            "eval": self.eval,
            "variant": self.variant,
            "oracle": self.oracle,
        }

    @property
    def config_hash(self) -> str:
        return canonical_hash(self.identity())

    @property
    def path(self) -> Path:
        return Path(self.out_dir)


@dataclass(frozen=True)
class SceneData:
    """One scene's dataset as the benchmark makes it: what generating it, its oracle and the external
    entries on it need (the same fields as a :class:`Cell`'s)."""

    scene: str
    spec: dict
    eval: dict
    dataset_dir: str
    data_root: str
    oracle: dict | None
    data_inputs: dict | None = None


def cell_dir(out_root: Path, scene: str, label: str, seed: int) -> Path:
    return Path(out_root) / "cells" / scene / f"{label}-seed{seed}"


def read_record(directory: Path, name: str = RESULT_FILE) -> dict | None:
    """The JSON record in ``directory`` (None if missing or unreadable)."""
    path = Path(directory) / name
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def matching_record(directory: Path, config_hash: str, code_version: str, name: str = RESULT_FILE) -> dict | None:
    """The non-empty JSON record ``name`` in ``directory`` if it was written for ``config_hash`` and
    ``code_version`` (None otherwise: missing, unreadable, or stale)."""
    record = read_record(directory, name)
    if record and (record.get("config_hash"), record.get("code_version")) == (config_hash, code_version):
        return record
    return None


def is_done(cell: Cell) -> bool:
    """True when the cell's ``result.json`` exists for the same config hash and code version."""
    return matching_record(cell.path, cell.config_hash, cell.code_version) is not None


def write_result(cell: Cell, record: Mapping[str, Any], artefacts: bytes | None) -> Path:
    """Write the artefacts, then the record (each atomically; the record last, so a
    ``result.json`` is only ever seen with its artefacts). Removes a stale ``error.json`` and the
    cell's ``in_flight.json`` mark (:data:`IN_FLIGHT_FILE`)."""
    from mitsnerf.data.atomic import atomic_write_bytes, atomic_write_json

    directory = cell.path
    directory.mkdir(parents=True, exist_ok=True)
    if artefacts is not None:
        atomic_write_bytes(directory / ARTEFACTS_FILE, artefacts)
    atomic_write_json(directory / RESULT_FILE, dict(record))
    (directory / ERROR_FILE).unlink(missing_ok=True)
    (directory / IN_FLIGHT_FILE).unlink(missing_ok=True)
    return directory / RESULT_FILE


def write_error(cell: Cell, message: str, details: str = "") -> Path:
    """Record a failed cell (``error.json``); a stale ``result.json`` of it is removed, so a
    resumed sweep tries the cell again."""
    from mitsnerf.data.atomic import atomic_write_json

    directory = cell.path
    directory.mkdir(parents=True, exist_ok=True)
    (directory / RESULT_FILE).unlink(missing_ok=True)
    atomic_write_json(directory / ERROR_FILE, {"key": cell.key, "config_hash": cell.config_hash,
                                               "code_version": cell.code_version, "error": message, "details": details})
    return directory / ERROR_FILE
