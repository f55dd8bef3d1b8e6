"""``executor="pool"`` from a script without ``if __name__ == "__main__":``: spawn would run the script again in
each worker. Before, the sweep went on, every worker died while it started, and the table came back all ``-``,
"1 failed", its reference line blaming ``render.noise_floor``; now the call is refused at once, in one line that
names the script's line and the guard, and nothing is written."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import mitsnerf

from ..conftest import child_pythonpath

REPO = Path(mitsnerf.__file__).resolve().parents[1]


def _script(tmp_path: Path, body: str) -> subprocess.CompletedProcess:
    path = tmp_path / "sweep.py"
    path.write_text(textwrap.dedent(body))
    return subprocess.run([sys.executable, str(path)], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": child_pythonpath(REPO)})


def test_a_pool_started_from_unguarded_script_code_is_refused_naming_the_guard(tmp_path):
    proc = _script(tmp_path, """\
        from mitsnerf import api

        result = api.bench("default", quick=True, executor="pool", results="r", data="d")
        print(result.markdown)
        """)
    assert proc.returncode == 1 and proc.stdout == ""
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("mitsnerf.errors.UsageError: executor='pool': its workers start by spawn")
    assert f"{tmp_path / 'sweep.py'}:3 (this call)" in last and "'if __name__ == \"__main__\":'" in last
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sweep.py"]  # no dataset rendered, no results


def test_code_under_the_guard_or_in_a_function_it_calls_is_not_refused(tmp_path):
    proc = _script(tmp_path, """\
        from mitsnerf.bench.executors import unguarded_main_line

        def sweep():
            return unguarded_main_line()

        if __name__ == "__main__":
            print("guarded", sweep())
        print("top level", sweep())
        """)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == ["guarded None", f"top level {tmp_path / 'sweep.py'}:8"]


def test_a_scene_whose_cells_all_failed_says_so_not_that_no_floor_was_measured():
    from mitsnerf.bench.tables import reference_lines, scene_rows

    rows = scene_rows([], [{"scene": "cloud", "method": "nerf", "key": "cloud/nerf-seed0"}], ["cloud"], ["nerf"])
    (line,) = reference_lines(rows)
    assert line == "cloud: no cell finished, so nothing was scored." and rows[0]["note"] == "1 failed"
