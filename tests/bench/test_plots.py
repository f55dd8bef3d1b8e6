"""The report's figures: nothing cut off, no writing across the lines they draw."""

from __future__ import annotations

import mitsnerf.bench.plots as plots


def _record(method: str, psnr: float) -> dict:
    return {"method": method, "metrics": {"psnr_test_medium": psnr, "oracle_psnr_test_medium": 44.82,
                                          "noise_floor_psnr_medium": 43.97}}


def test_the_error_budget_shows_its_axis_label_and_writes_clear_of_the_lines(tmp_path, monkeypatch):
    """Its x-axis label was cut off, and each bar's note ran across the floor and oracle lines."""
    drawn = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or path)
    records = [_record("voxel", 28.1), _record("ngp", 44.1), _record("nerf", 35.0)]
    assert plots.error_budget("cloud", records, ["voxel", "ngp", "nerf"], tmp_path / "e.png") is not None
    (fig,) = drawn
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    (ax,) = fig.axes
    page = fig.bbox
    label = ax.xaxis.label.get_window_extent(renderer)
    assert label.y0 >= page.y0 and label.x1 <= page.x1 and ax.xaxis.label.get_text()
    line_x = [ax.transData.transform((x, 0))[0] for x in (43.97, 44.82)]
    notes = [t for t in ax.texts if "below the oracle" in t.get_text()]
    assert len(notes) == 3
    for note in notes:
        box = note.get_window_extent(renderer)
        assert all(not box.x0 <= x <= box.x1 for x in line_x), note.get_text()
        assert box.x1 <= page.x1 and box.x0 >= ax.bbox.x1
