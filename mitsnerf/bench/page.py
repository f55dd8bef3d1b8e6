"""The results page (``mitsnerf results``): one Markdown page of the tables of one or more sweeps, each section
written from a sweep's ``results.json`` by the functions that print and write its tables
(:mod:`mitsnerf.bench.tables`), so nothing on it is typed by hand and the same file always gives the same page.

A section per sweep, in the order given: its config's description; where it came from (the command that ran it,
its commit, when its cells ran and its tables were written, the machine, the files); the tables ``mitsnerf bench``
prints (per scene, with each scene's oracle and reference-agreement lines, and averaged over scenes); under them
the sweep's reading, if its results directory holds one (:data:`READING_FILE`); then every column (``table.md``'s
tables) folded away. The legend of every column ends the page.

A reading is the only prose on the page a person writes: a few lines (at most :data:`READING_LINES`) on what the
tables show, with links to the notes that hold the longer readings, committed beside the ``results.json`` it reads
and headed by the commit of those results::

    ---
    commit: cb16d0947d84
    ---
    scatter leads every scene; the measurements behind it: [physics-table.md](../../../docs/notes/physics-table.md).

Its links are relative to its own directory (the page rebases them). When the sweep is run again at another commit
and its results replace the old ones, the page says that the reading was written for other results, so that a
reading's figures are never shown as the table's without the reader being told.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from mitsnerf.bench.tables import COMPACT, QUALITY, best_rules, compact_tables, cost_columns, full_tables, legend
from mitsnerf.errors import DatasetError, UsageError

RESULTS_FILE = "results.json"
"""What a sweep's results directory holds the page is made from (:func:`mitsnerf.bench.runner.write_outputs`)."""
READING_FILE = "reading.md"
"""Beside ``results.json``: what its tables show, in a few lines a person wrote (see the module docstring)."""
READING_LINES = 8
"""The most lines of text a reading may have; a longer one belongs in a note it links to."""
SIDE_FILES = ("table.md", "table.csv")
"""Written beside ``results.json`` by the same sweep; linked from its section where they are there."""


@dataclass(frozen=True)
class Sweep:
    """One sweep's ``results.json``, read and checked (:func:`read_sweep`)."""

    path: Path
    """The ``results.json``."""
    data: dict


def read_sweep(path: str | os.PathLike) -> Sweep:
    """The sweep whose results directory (or ``results.json``) is ``path``; a DatasetError naming the file and the
    field when it is not one that ``mitsnerf bench`` wrote."""
    from mitsnerf.data.transforms import read_json

    path = Path(path)
    file = path / RESULTS_FILE if path.is_dir() else path
    if path.is_dir() and not file.is_file():
        raise DatasetError(path, None, f"no {RESULTS_FILE}: not a sweep's results directory (mitsnerf bench writes "
                                       f"RESULTS/NAME/{RESULTS_FILE})")
    data = read_json(file)
    if not isinstance(data, dict):
        raise DatasetError(file, None, f"must be a JSON object (a sweep's {RESULTS_FILE}), got {type(data).__name__}")
    for field, kind in (("benchmark", str), ("quick", bool), ("provenance", dict), ("tables", dict), ("cells", list),
                        ("failed", list)):
        if not isinstance(data.get(field), kind):
            raise DatasetError(file, field, _not_a(kind, data.get(field)))
    for field in ("per_scene", "average"):
        rows = data["tables"].get(field)
        if not isinstance(rows, list) or not all(isinstance(r, dict) and "scene" in r and "method" in r for r in rows):
            raise DatasetError(file, f"tables.{field}", "must be a list of rows, each with its scene and method")
    return Sweep(file, data)


def _not_a(kind: type, value: Any) -> str:
    what = {str: "a string", bool: "true or false", dict: "an object", list: "a list"}[kind]
    return "missing: not a sweep's results.json" if value is None else f"must be {what}, got {type(value).__name__}"


def check_distinct(sweeps: Sequence[Sweep], option: str = "SWEEP") -> None:
    """Refuse the same ``results.json`` given twice (a UsageError of ``option``)."""
    seen: set[Path] = set()
    for sweep in sweeps:
        if sweep.path.resolve() in seen:
            raise UsageError(option, f"{sweep.path} is given twice")
        seen.add(sweep.path.resolve())


def results_page(sweeps: Sequence[Sweep], *, title: str = "mitsnerf results", command: str | None = None,
                 base: Path = Path(".")) -> str:
    """The page (Markdown) of ``sweeps``, a section each in their order; ``command``: the one that wrote the page
    (said under the title); ``base``: the page's directory, which its links to the sweeps' files are relative to."""
    heads = _anchors([_heading(s) for s in sweeps])
    parts = [f"# {title}", "", _intro(command), ""]
    parts += [f"- [{_heading(s)}](#{anchor}): {_summary(s)}" for s, anchor in zip(sweeps, heads)]
    for sweep in sweeps:
        parts += ["", section(sweep, base)]
    columns = COMPACT + QUALITY + tuple(c for s in sweeps for c in cost_columns(s.data["tables"]["per_scene"]))
    parts += ["", "## Columns", "", legend(columns), ""]
    return "\n".join(parts)


def _intro(command: str | None) -> str:
    made = f"this page by `{command}`, which writes it again" if command else "this page by `mitsnerf results`"
    return (f"Every table below is written by mitsnerf from the `{RESULTS_FILE}` of a sweep (`mitsnerf bench`), as "
            f"that sweep printed it, with the command, commit, dates and machine it recorded; {made}.")


def _heading(sweep: Sweep) -> str:
    return sweep.data["benchmark"] + (" (quick)" if sweep.data["quick"] else "")


def _anchors(headings: Sequence[str]) -> list[str]:
    """The link targets GitHub gives ``headings`` (``## default (quick)`` -> ``default-quick``), repeats numbered.

    >>> _anchors(["default (quick)", "physics", "physics"])
    ['default-quick', 'physics', 'physics-1']
    """
    out: list[str] = []
    for text in headings:
        anchor = re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")
        n = sum(1 for a in out if a == anchor or re.fullmatch(re.escape(anchor) + r"-\d+", a))
        out.append(anchor if n == 0 else f"{anchor}-{n}")
    return out


def _summary(sweep: Sweep) -> str:
    """The contents line of a sweep: its scenes and methods, its commit and when its tables were written."""
    rows = [r for r in sweep.data["tables"]["per_scene"] if not r.get("ceiling")]
    scenes, methods = (list(dict.fromkeys(r[k] for r in rows)) for k in ("scene", "method"))
    when = _date(sweep.data.get("written")) or "date not recorded"
    return (f"{_count(scenes, 'scene')} ({', '.join(scenes)}), {_count(methods, 'method')}; commit "
            f"{_short(_commit(sweep))}, {when}")


def _count(items: Sequence[str], noun: str) -> str:
    return f"{len(items)} {noun}{'' if len(items) == 1 else 's'}"


def section(sweep: Sweep, base: Path = Path(".")) -> str:
    """One sweep's section of the page (see the module docstring)."""
    d = sweep.data
    per_scene, average = d["tables"]["per_scene"], d["tables"]["average"]
    best = best_rules(d["cells"])
    quick = _quick_banner(d) if d["quick"] else None
    parts = [f"## {_heading(sweep)}", ""]
    if d.get("description"):
        parts += [str(d["description"]), ""]
    parts += [*_provenance(sweep, base), ""]
    parts += [compact_tables(per_scene, average, best, quick, heading="###"), ""]
    reading = read_reading(sweep)
    if reading is not None:
        parts += [_reading_section(sweep, reading, base), ""]
    parts += ["<details><summary>Every column: quality and cost (table.md)</summary>", "",
              full_tables(per_scene, average, best, None, heading="####"), "", "</details>"]
    return "\n".join(parts)


@dataclass(frozen=True)
class Reading:
    """A sweep's :data:`READING_FILE`: the commit of the results it was written for, and its text."""

    path: Path
    commit: str
    text: str


def read_reading(sweep: Sweep) -> Reading | None:
    """The reading beside ``sweep``'s ``results.json`` (None where there is none); a DatasetError naming the file and
    the field when it lacks its ``commit`` header or is longer than :data:`READING_LINES` lines of text.

    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> _ = (d / READING_FILE).write_text("---\\ncommit: cb16d09\\n---\\nscatter leads.\\n")
    >>> r = read_reading(Sweep(d / RESULTS_FILE, {}))
    >>> r.commit, r.text
    ('cb16d09', 'scatter leads.')
    """
    path = sweep.path.parent / READING_FILE
    if not path.is_file():
        return None
    head, sep, body = path.read_text().partition("\n---\n")
    fields = dict(line.split(":", 1) for line in head.splitlines()[1:] if ":" in line)
    commit = fields.get("commit", "").strip()
    if not head.startswith("---\n") or not sep or "commit" not in fields:
        raise DatasetError(path, "commit", "missing: a reading starts with the lines '---', 'commit: <the commit of "
                                           "the results it reads>', '---'")
    if not re.fullmatch(r"[0-9a-f]{7,40}", commit):
        raise DatasetError(path, "commit", f"must be a commit's hash (7 to 40 hex digits), got {commit!r}")
    text = body.strip()
    lines = [line for line in text.splitlines() if line.strip()]
    if not lines or len(lines) > READING_LINES:
        raise DatasetError(path, None, f"{len(lines)} lines of text: a reading has 1 to {READING_LINES}; put a "
                                       "longer one in a note and link it")
    return Reading(path, commit, text)


def _reading_section(sweep: Sweep, reading: Reading, base: Path) -> str:
    """The reading under a sweep's tables, its links rebased to the page, and whether it reads these results."""
    link = _link(reading.path, base)
    ran = _commit(sweep)
    if ran.startswith(reading.commit):
        head = f"**What it shows** ([{READING_FILE}]({link})):"
    else:
        head = (f"**What it showed** ([{READING_FILE}]({link}), written for the results of commit "
                f"`{reading.commit}`; these are of {_short(ran)}, so its figures may not be these):")
    return head + "\n\n" + _rebase_links(reading.text, reading.path.parent, base)


def _link(path: Path, base: Path) -> str:
    """``path`` as a Markdown link target from the page's directory ``base`` (relative, with forward slashes)."""
    return Path(os.path.relpath(path, base)).as_posix()


def _rebase_links(text: str, source: Path, base: Path) -> str:
    """``text``'s relative Markdown links, written from ``source``, made relative to ``base``.

    >>> _rebase_links("[n](../../docs/n.md), [w](https://x.org), [a](#physics)", Path("/r/b/results/p"), Path("/r"))
    '[n](b/docs/n.md), [w](https://x.org), [a](#physics)'
    """
    def rebase(match: re.Match) -> str:
        target = match.group(1)
        if re.match(r"[a-z][a-z0-9+.-]*:|#|/", target):
            return match.group(0)
        path, hash_, fragment = target.partition("#")
        return f"]({_link(Path(os.path.normpath(source / path)), base)}{hash_}{fragment})"

    return re.sub(r"\]\(([^)\s]+)\)", rebase, text)


def _quick_banner(data: dict) -> str:
    """The banner a quick sweep's tables start with, from the cells its ``results.json`` lists."""
    from mitsnerf.bench.runner import quick_sizes
    from mitsnerf.bench.tables import quick_banner

    cells = (data.get("config") or {}).get("cells") or []
    try:
        sizes = quick_sizes([SimpleNamespace(spec=c["spec"], train=c["train"]) for c in cells])
    except (KeyError, TypeError):
        sizes = ""
    return quick_banner(sizes)


def _provenance(sweep: Sweep, base: Path) -> list[str]:
    """Where the sweep's tables came from, a line each: command, commit, dates, machine, files."""
    d, p = sweep.data, sweep.data["provenance"]
    cells, planned = len(d["cells"]), len((d.get("config") or {}).get("cells") or d["cells"])
    failed = f", {len(d['failed'])} failed" if d["failed"] else ""
    command = f"`{d['command']}`" if d.get("command") else "not recorded (written before mitsnerf recorded it)"
    lines = [f"- **Command:** {command}; {cells} of {planned} cells have results{failed} (executor "
             f"{d.get('executor', '?')})",
             f"- **Code:** mitsnerf {p.get('mitsnerf', '?')} at {_commit_words(_commit(sweep))}",
             f"- **When:** {_when(d)}",
             f"- **Machine:** {p.get('machine', 'not recorded')}; {_software(p)}",
             f"- **Files:** {_files(sweep, base)}"]
    lines += [f"- **Failed:** {f.get('key', '?')}: {f.get('error', '')}" for f in d["failed"]]
    return lines


def _commit(sweep: Sweep) -> str:
    return str(sweep.data["provenance"].get("commit") or "unknown")


def _short(commit: str) -> str:
    return commit if commit == "unknown" else commit[:12] + ("+dirty" if commit.endswith("+dirty") else "")


def _commit_words(commit: str) -> str:
    """The commit a sweep ran at, and what it means for repeating it."""
    if commit == "unknown":
        return "an unknown commit (not run from a git checkout)"
    if commit.endswith("+dirty"):
        return f"commit `{commit[:-6]}` with uncommitted changes (the commit alone does not repeat it)"
    return f"commit `{commit}`"


def _date(iso: Any) -> str | None:
    """``2026-11-28 22:10 UTC`` of an ISO time, None where there is none."""
    try:
        return datetime.fromisoformat(str(iso)).astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    except ValueError:
        return None


def _when(data: dict) -> str:
    """When the cells ran (their first start and last finish) and when the tables were written."""
    starts = [c["started"] for c in data["cells"] if isinstance(c.get("started"), (int, float))]
    ends = [c["finished"] for c in data["cells"] if isinstance(c.get("finished"), (int, float))]
    parts = []
    if starts and ends:
        first, last = (datetime.fromtimestamp(t, timezone.utc).isoformat() for t in (min(starts), max(ends)))
        parts.append(f"cells ran {_date(first)} to {_date(last)}")
    parts.append(f"tables written {_date(data.get('written')) or 'at a date not recorded'}")
    return "; ".join(parts)


def _software(p: dict) -> str:
    llvm = f", LLVM {p['llvm']}" if p.get("llvm") else ""
    return (f"variant {p.get('variant', '?')} (Mitsuba {p.get('mitsuba', '?')}, Dr.Jit {p.get('drjit', '?')}{llvm}), "
            f"Python {p.get('python', '?')}, numpy {p.get('numpy', '?')}")


def _files(sweep: Sweep, base: Path) -> str:
    """Links to the sweep's results.json and the tables beside it, relative to the page's directory."""
    names = [RESULTS_FILE] + [n for n in SIDE_FILES if (sweep.path.parent / n).is_file()]
    links = [f"[{n}]({_link(sweep.path.parent / n, base)})" for n in names]
    return ", ".join(links)
