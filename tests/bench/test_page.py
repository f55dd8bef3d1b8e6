"""The results page (``mitsnerf results``): written from a sweep's ``results.json`` alone, the same page from the same
file (a stored sweep and its stored page), its tables the sweep's own, stamped with the command, commit, dates and
machine the sweep recorded; bad input is one line naming the file and the field, and nothing is written."""

from __future__ import annotations

import csv
import json
import shutil
from datetime import datetime, timezone
from pathlib import Path

import pytest

from mitsnerf.bench.page import read_sweep, results_page
from mitsnerf.cli import main

from ..conftest import TINY_BENCH

STORED = Path(__file__).with_name("stored")
"""``default-quick/``: the ``results.json`` and ``table.csv`` of ``mitsnerf bench default --quick``; ``RESULTS.md``:
the page ``mitsnerf results`` wrote of them (:data:`WRITE_AGAIN`)."""
WRITE_AGAIN = "mitsnerf results tests/bench/stored/default-quick --out tests/bench/stored/RESULTS.md"



def test_the_page_of_a_stored_sweep_is_the_stored_page():
    page = results_page([read_sweep(STORED / "default-quick")], command=WRITE_AGAIN, base=STORED)
    assert page == (STORED / "RESULTS.md").read_text(), f"the page's writer changed; if on purpose: {WRITE_AGAIN}"


def test_the_pages_tables_are_the_sweeps_own():
    """Each method's row on the page shows the figures of the sweep's own table.csv, beside the scene's oracle row
    and its reference agreement, and says what the method was given."""
    page = (STORED / "RESULTS.md").read_text()
    compact = page.split("### Per scene", 1)[1].split("<details>", 1)[0]
    with open(STORED / "default-quick" / "table.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {r["method"] for r in rows} == {"oracle", "voxel", "ngp", "nerf", "primitives", "scatter"}
    for row in rows:
        if row["method"] == "oracle":
            assert f"| cloud | oracle (ceiling) | - | - | - | {float(row['psnr_test_medium']):.2f} |" in compact
            continue
        line = next(line for line in compact.splitlines() if line.startswith(f"| cloud | {row['method']} |"))
        for key, digits in (("psnr_test_medium", 2), ("train_seconds", 1), ("peak_memory_mb", 0)):
            assert f"{float(row[key]):.{digits}f}" in line, (row["method"], key, line)
        assert f"| {row['given']} |" in line
    assert "cloud: two reference renders agree to " in compact and "the oracle scores " in compact


def test_the_page_is_stamped_with_what_the_sweep_recorded():
    sweep = read_sweep(STORED / "default-quick")
    page = results_page([sweep], base=STORED)
    data = sweep.data
    assert data["command"].startswith("mitsnerf bench default --quick")
    assert f"- **Command:** `{data['command']}`; 5 of 5 cells have results (executor sequential)" in page
    assert f"commit `{data['provenance']['commit']}`" in page and "+dirty" not in data["provenance"]["commit"]
    written = datetime.fromisoformat(data["written"]).astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    assert f"tables written {written}" in page and f"- **Machine:** {data['provenance']['machine']}" in page
    assert "[results.json](default-quick/results.json), [table.csv](default-quick/table.csv)" in page


def test_results_writes_the_page_whole_with_its_links_beside_it(tmp_path, capsys):
    out = tmp_path / "site" / "RESULTS.md"
    assert main(["results", str(STORED / "default-quick"), "--out", str(out)]) == 0
    assert capsys.readouterr().out == f"{out}: 1 sweep (default-quick)\n"
    command = f"mitsnerf results {STORED / 'default-quick'} --out {out}"
    assert out.read_text() == results_page([read_sweep(STORED / "default-quick" / "results.json")],
                                           command=command, base=out.parent)
    assert main(["results", str(STORED / "default-quick" / "results.json")]) == 0  # no --out: printed
    assert capsys.readouterr().out.startswith("# mitsnerf results\n")


def _broken(tmp_path: Path, change) -> Path:
    sweep = tmp_path / "sweep"
    shutil.copytree(STORED / "default-quick", sweep)
    data = json.loads((sweep / "results.json").read_text())
    change(data)
    (sweep / "results.json").write_text(json.dumps(data))
    return sweep


BAD = [  # (what is wrong, how to make it, what the line says after "mitsnerf: error: ")
    ("not a sweep", lambda t: t, "{path}: no results.json: not a sweep's results directory"),
    ("no tables", lambda t: _broken(t, lambda d: d.pop("tables")), "{path}/results.json: tables: missing: not a "
                                                                   "sweep's results.json"),
    ("rows", lambda t: _broken(t, lambda d: d["tables"]["per_scene"][0].pop("method")),
     "{path}/results.json: tables.per_scene: must be a list of rows, each with its scene and method"),
    ("not json", lambda t: (t / "results.json").write_text("{") and t, "{path}/results.json: invalid JSON"),
]


@pytest.mark.parametrize("what, make, message", BAD, ids=[b[0] for b in BAD])
def test_a_bad_sweep_is_one_line_naming_the_file_and_field_and_nothing_is_written(what, make, message, tmp_path,
                                                                                  capsys):
    path = make(tmp_path)
    out = tmp_path / "RESULTS.md"
    assert main(["results", str(STORED / "default-quick"), str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mitsnerf: error: " + message.format(path=path)), err
    assert not out.exists()


def test_the_same_sweep_twice_is_refused(tmp_path, capsys):
    sweep = STORED / "default-quick"
    assert main(["results", str(sweep), str(sweep / "results.json"), "--out", str(tmp_path / "R.md")]) == 2
    assert capsys.readouterr().err == f"mitsnerf: error: SWEEP: {sweep / 'results.json'} is given twice\n"
    assert not (tmp_path / "R.md").exists()


def test_a_sweep_records_the_command_and_when_and_its_page_says_so(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "first.toml").write_text(TINY_BENCH)
    argv = ["bench", "first.toml", "--quick", "--results", "sweeps", "--no-progress"]
    assert main(argv) == 0
    data = json.loads((tmp_path / "sweeps" / "first-quick" / "results.json").read_text())
    assert data["command"] == "mitsnerf bench first.toml --quick --results sweeps --no-progress"
    age = datetime.now(timezone.utc) - datetime.fromisoformat(data["written"])
    assert 0 <= age.total_seconds() < 600
    capsys.readouterr()
    assert main(["results", "sweeps/first-quick"]) == 0
    page = capsys.readouterr().out
    assert f"- **Command:** `{data['command']}`; 1 of 1 cells have results" in page
    assert "| cloud | voxel | images | 2 steps |" in page and "Quick profile (8x8 views, 2 test views" in page


def _with_reading(tmp_path: Path, text: str) -> Path:
    """The stored sweep copied to ``tmp_path/sweeps/default-quick`` with ``text`` as its reading.md."""
    sweep = tmp_path / "sweeps" / "default-quick"
    shutil.copytree(STORED / "default-quick", sweep)
    (sweep / "reading.md").write_text(text)
    return sweep


def test_a_reading_sits_under_its_sweeps_tables_with_its_links_rebased(tmp_path):
    commit = read_sweep(STORED / "default-quick").data["provenance"]["commit"]
    sweep = _with_reading(tmp_path, f"---\ncommit: {commit[:12]}\n---\nscatter leads; why: "
                                    "[the note](../../docs/notes/scatter.md#the-rows), [elsewhere](https://x.org).\n")
    page = results_page([read_sweep(sweep)], base=tmp_path)
    tables, rest = page.split("### Per scene", 1)[1].split("<details>", 1)
    assert "**What it shows** ([reading.md](sweeps/default-quick/reading.md)):\n\nscatter leads; why: [the note]" \
           "(docs/notes/scatter.md#the-rows), [elsewhere](https://x.org)." in tables
    assert "scatter leads" not in rest


def test_a_reading_written_for_other_results_says_so(tmp_path):
    sweep = _with_reading(tmp_path, "---\ncommit: 0123456\n---\nscatter leads.\n")
    page = results_page([read_sweep(sweep)], base=tmp_path)
    ran = read_sweep(sweep).data["provenance"]["commit"][:12]
    assert (f"**What it showed** ([reading.md](sweeps/default-quick/reading.md), written for the results of commit "
            f"`0123456`; these are of {ran}, so its figures may not be these):\n\nscatter leads.") in page
    assert "**What it shows**" not in page


BAD_READINGS = [  # (what is wrong, reading.md, the field and message after the file)
    ("no header", "scatter leads.\n", "commit: missing: a reading starts with the lines '---', 'commit: "),
    ("no commit", "---\nwhen: today\n---\nscatter leads.\n", "commit: missing: a reading starts with"),
    ("bad commit", "---\ncommit: latest\n---\nscatter leads.\n", "commit: must be a commit's hash (7 to 40 hex "
                                                                  "digits), got 'latest'"),
    ("too long", "---\ncommit: 0123456\n---\n" + "a line.\n" * 9, "9 lines of text: a reading has 1 to 8; put a "
                                                                   "longer one in a note and link it"),
    ("empty", "---\ncommit: 0123456\n---\n\n", "0 lines of text"),
]


@pytest.mark.parametrize("what, text, message", BAD_READINGS, ids=[b[0] for b in BAD_READINGS])
def test_a_bad_reading_is_one_line_naming_the_file_and_field_and_nothing_is_written(what, text, message, tmp_path,
                                                                                    capsys):
    sweep = _with_reading(tmp_path, text)
    out = tmp_path / "RESULTS.md"
    assert main(["results", str(sweep), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"mitsnerf: error: {sweep / 'reading.md'}: {message}"), err
    assert not out.exists()
