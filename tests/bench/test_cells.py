"""A cell's files on disk: what a finished cell keeps and what it drops."""

from __future__ import annotations

import json

from mitsnerf.bench.cells import ERROR_FILE, IN_FLIGHT_FILE, RESULT_FILE, Cell, write_result


def _cell(tmp_path) -> Cell:
    return Cell(bench="b", scene="s", label="nerf", method="nerf", seed=0, spec={}, method_config={}, train={},
                eval={}, variant="llvm_ad_rgb", code_version="t", dataset_dir=str(tmp_path / "d"),
                data_root=str(tmp_path), out_dir=str(tmp_path / "cell"))


def test_a_finished_cell_is_no_longer_marked_in_flight(tmp_path):
    """A sweep stopped after a cell finished used to leave that cell's in_flight.json behind."""
    cell = _cell(tmp_path)
    cell.path.mkdir()
    (cell.path / IN_FLIGHT_FILE).write_text(json.dumps({"key": cell.key}))
    (cell.path / ERROR_FILE).write_text("{}")
    write_result(cell, {"key": cell.key}, None)
    assert sorted(p.name for p in cell.path.iterdir()) == [RESULT_FILE]
