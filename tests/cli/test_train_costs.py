"""``mitsnerf train`` records what the run cost as a benchmark cell does: its own peak memory (the same whatever the
process did before it) and its saved model's size, in ``metrics.json`` and on the line it prints."""

from __future__ import annotations

import json

import drjit as dr
import mitsuba as mi
import pytest

from mitsnerf.cli import main


def _train(world, out, capsys) -> tuple[dict, str]:
    assert main(["train", str(world.dataset), "--out", str(out), "--steps", "2", "--no-progress", *world.nerf]) == 0
    return json.loads((out / "metrics.json").read_text()), capsys.readouterr().out


def test_a_run_records_its_own_peak_memory_and_model_size(world, tmp_path, capsys):
    first, line = _train(world, tmp_path / "a", capsys)
    assert first["peak_memory_mb"] > 0 and first["peak_rss_mb"] > 0 and isinstance(first["peak_rss_reset"], bool)
    assert first["model_bytes"] == (tmp_path / "a" / "params.npz").stat().st_size
    assert f"peak {first['peak_memory_mb']:.0f} MiB, model {first['model_bytes'] / 1e6:.3f} MB" in line, line
    big = dr.arange(mi.Float, 1 << 24)  # 64 MiB used and freed before the second run, in this process
    dr.eval(big)
    del big
    second, _ = _train(world, tmp_path / "b", capsys)
    assert second["peak_memory_mb"] == pytest.approx(first["peak_memory_mb"], rel=1e-3)
    assert second["peak_memory_mb"] < 64
