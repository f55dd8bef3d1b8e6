"""A method row that starts from another row's result: a string setting ``"@LABEL"``.

In a benchmark config, a string in a method's ``config`` (any method, any string setting, nested tables too)
whose value is ``"@LABEL"`` stands for the run directory of the row labelled ``LABEL`` on the same scene and
seed, with that run's learned medium exported in its ``export/`` (as ``mitsnerf export RUN`` writes it, at
:data:`EXPORT_RESOLUTION`)::

    [[methods]]
    name = "ngp"
    [[methods]]
    name = "mitsuba-inverse"
    label = "mitsuba-inverse (ngp start)"
    config = { init_from = "@ngp" }     # -> cells/<scene>/ngp-seed<k>/run, holding export/

- **At load** (:func:`mitsnerf.bench.config.check_references`, both profiles): an unknown label, a row naming
  itself and a cycle are a :class:`~mitsnerf.errors.SpecError` naming the file and the field that set the
  reference (``methods.1.config.init_from``). Every ``[[methods]]`` row runs on every scene and seed of the
  config, so the cell referred to always exists; an ``[[external]]`` entry has no run, and is no row to refer to.
- **Order** (:func:`mitsnerf.bench.config.method_order`): the rows are planned referred-to first (otherwise in
  the file's order), so the sequential executor runs a cell after the cells it refers to; the pool and Ray run
  the pending cells in dependency waves (:func:`dependency_waves`).
- **Hash**: a referring cell's identity holds the config hash of every cell it refers to
  (:meth:`mitsnerf.bench.cells.Cell.identity`), so changing the referred row recomputes the referring one; the
  recorded config keeps ``"@LABEL"``.
- **In the worker** (:func:`resolved_config`): before fitting, each ``"@LABEL"`` becomes the referred cell's
  ``run/`` path, after checking that cell has a result for its config and code and exporting its medium to
  ``run/export/`` if that is missing; else the referring cell fails with an error that says why.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mitsnerf.bench.cells import ERROR_FILE, Cell, matching_record, read_record
from mitsnerf.errors import MitsnerfError

PREFIX = "@"
#: The export resolution of a referred run (``mitsnerf export RUN``'s default): ``R^3`` voxels.
EXPORT_RESOLUTION = 64

Keys = tuple[str, ...]


class UnresolvedReference(MitsnerfError):
    """A ``"@LABEL"`` setting whose cell has no usable result (failed, not run, or its run missing)."""


def referred_label(value: Any) -> str | None:
    """``LABEL`` of a setting ``"@LABEL"``; None for any other value.

    >>> referred_label("@ngp"), referred_label("truth"), referred_label(3)
    ('ngp', None, None)
    """
    return value[len(PREFIX):] if isinstance(value, str) and value.startswith(PREFIX) else None


def references_in(settings: Mapping[str, Any], keys: Keys = ()) -> dict[Keys, str]:
    """Every ``"@LABEL"`` string of ``settings`` (nested tables walked): key path -> ``LABEL``.

    >>> references_in({"init_from": "@ngp", "grid": {"path": "@a", "n": 3}, "loss": "l2"})
    {('init_from',): 'ngp', ('grid', 'path'): 'a'}
    """
    out: dict[Keys, str] = {}
    for key, value in settings.items():
        if isinstance(value, Mapping):
            out.update(references_in(value, keys + (str(key),)))
        elif (label := referred_label(value)) is not None:
            out[keys + (str(key),)] = label
    return out


def substitute(settings: Mapping[str, Any], paths: Mapping[str, str]) -> dict[str, Any]:
    """A copy of ``settings`` with every ``"@LABEL"`` string replaced by ``paths[LABEL]``.

    >>> substitute({"init_from": "@ngp", "grid": {"p": "@ngp"}, "n": 1}, {"ngp": "/r/ngp-seed0/run"})
    {'init_from': '/r/ngp-seed0/run', 'grid': {'p': '/r/ngp-seed0/run'}, 'n': 1}
    """
    out: dict[str, Any] = {}
    for key, value in settings.items():
        label = referred_label(value)
        out[key] = (substitute(value, paths) if isinstance(value, Mapping)
                    else paths[label] if label is not None else value)
    return out


def cell_references(method_config: Mapping[str, Any], referred: Mapping[str, Cell]) -> dict[str, dict[str, str]]:
    """What a cell keeps of the cells its resolved ``method_config`` refers to: ``LABEL -> {key, out_dir,
    config_hash}``; ``referred``: the cells of the same scene and seed planned so far, by label."""
    labels = dict.fromkeys(references_in(method_config).values())
    return {label: {"key": referred[label].key, "out_dir": referred[label].out_dir,
                    "config_hash": referred[label].config_hash} for label in labels}


def referred_keys(cell: Cell) -> list[str]:
    """Keys of the cells ``cell`` refers to."""
    return [ref["key"] for ref in (cell.references or {}).values()]


def dependency_waves(cells: Sequence[Cell]) -> list[list[Cell]]:
    """``cells`` in waves, each to run after the ones before: wave ``w(c) = 0`` when ``c`` refers to none of
    ``cells``, else ``1 + max w(r)`` over the cells ``r`` among them it refers to (cells keep their order)."""
    by_key = {c.key: c for c in cells}
    depth: dict[str, int] = {}

    def wave(cell: Cell) -> int:
        if cell.key not in depth:
            depth[cell.key] = 1 + max((wave(by_key[k]) for k in referred_keys(cell) if k in by_key), default=-1)
        return depth[cell.key]

    waves: list[list[Cell]] = [[] for _ in range(1 + max(map(wave, cells), default=-1))]
    for cell in cells:
        waves[wave(cell)].append(cell)
    return waves


def _check_result(cell: Cell, setting: str, label: str, ref: Mapping[str, str]) -> Path:
    """The run directory of the cell ``ref`` names (``cell``'s ``setting = "@label"``), which must have a result
    for its config hash and ``cell``'s code version; else an :class:`UnresolvedReference` saying why."""
    directory, same = Path(ref["out_dir"]), (ref["config_hash"], cell.code_version)
    named = f"{PREFIX + label!r} is cell {ref['key']}"
    error = matching_record(directory, *same, name=ERROR_FILE)
    if error is not None:
        raise UnresolvedReference(None, setting, f"{named}, which failed ({error.get('error')}), so this cell has "
                                                 "nothing to start from")
    if matching_record(directory, *same) is None:
        raise UnresolvedReference(None, setting, f"{named}, which has no result for its config and code (not run "
                                                 "yet, interrupted, or stale)")
    run = directory / "run"
    if not (run / "config.json").is_file():
        raise UnresolvedReference(None, setting, f"{named}, whose run directory {run} is not on this machine (on a "
                                                 "Ray cluster, --results must be a folder every node shares)")
    return run


def _has_export(run: Path) -> bool:
    """Whether ``run/export`` holds an export at :data:`EXPORT_RESOLUTION`."""
    info = read_record(run / "export", "export.json") or {}
    return (run / "export" / "sigma_t.npy").is_file() and info.get("resolution") == EXPORT_RESOLUTION


def ensure_export(run: Path, progress: bool = False) -> Path:
    """``run/export``, exported first (:func:`mitsnerf.runs.export.export_run`) unless it holds an export at
    :data:`EXPORT_RESOLUTION`; under a lock, so cells in parallel that start from the same run export it once."""
    from mitsnerf.outputs import exclusive_lock
    from mitsnerf.runs.directory import lock_path
    from mitsnerf.runs.export import export_run

    with exclusive_lock(lock_path(run / "export"), wait=True, what=run / "export"):
        if not _has_export(run):
            export_run(run, run / "export", EXPORT_RESOLUTION, progress=progress)
    return run / "export"


def resolved_config(cell: Cell, progress: bool = False) -> dict[str, Any]:
    """``cell``'s method config with each ``"@LABEL"`` replaced by the referred cell's ``run/`` path (its
    medium exported in ``run/export/``, :func:`ensure_export`); an :class:`UnresolvedReference` naming the setting
    when a referred cell has no result."""
    settings = {label: ".".join(keys) for keys, label in references_in(cell.method_config).items()}
    paths = {}
    for label, ref in (cell.references or {}).items():
        run = _check_result(cell, settings.get(label, PREFIX + label), label, ref)
        ensure_export(run, progress)
        paths[label] = str(run)
    return substitute(cell.method_config, paths)
