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

from collections.abc import Mapping
from typing import Any

from mitsnerf.bench.cells import Cell

PREFIX = "@"
#: The export resolution of a referred run (``mitsnerf export RUN``'s default): ``R^3`` voxels.
EXPORT_RESOLUTION = 64

Keys = tuple[str, ...]


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


def cell_references(method_config: Mapping[str, Any], referred: Mapping[str, Cell]) -> dict[str, dict[str, str]]:
    """What a cell keeps of the cells its resolved ``method_config`` refers to: ``LABEL -> {key, out_dir,
    config_hash}``; ``referred``: the cells of the same scene and seed planned so far, by label."""
    labels = dict.fromkeys(references_in(method_config).values())
    return {label: {"key": referred[label].key, "out_dir": referred[label].out_dir,
                    "config_hash": referred[label].config_hash} for label in labels}
