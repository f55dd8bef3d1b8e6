"""A self-contained HTML report: the tables, the figures embedded as base64 PNGs, provenance."""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mitsnerf.bench.tables import (
    BEST,
    QUALITY,
    Column,
    _cell_text,
    best_values,
    cost_columns,
    is_best,
    legend,
    reference_lines,
)

STYLE = """
body { font-family: sans-serif; margin: 2em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 3px 7px; text-align: right; }
th { background: #eee; } td:nth-child(-n+2) { text-align: left; }
td.best { font-weight: bold; background: #e6f4e6; }
img { max-width: 100%; border: 1px solid #ddd; margin: 0.3em 0; }
pre { background: #f6f6f6; padding: 0.6em; font-size: 12px; overflow-x: auto; }
.legend { font-size: 12px; color: #555; max-width: 70em; }
tr.ceiling td { font-style: italic; background: #fbeaea; }
"""


def html_table(rows: Sequence[dict], columns: Sequence[Column], group: str | None = None,
               best: dict[str, str] | None = None) -> str:
    marks = best_values(rows, BEST if best is None else best, group)
    out = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for _, h, _ in columns) + "</tr>"]
    for row in rows:
        cells = []
        for key, _, digits in columns:
            attr = ' class="best"' if is_best(row, key, digits, marks, group) else ""
            cells.append(f"<td{attr}>{html.escape(_cell_text(row, key, digits))}</td>")
        out.append(("<tr class='ceiling'>" if row.get("ceiling") else "<tr>") + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _lines(lines: Sequence[str], tag: str = "div") -> str:
    """``lines`` as one paragraph each (``tag="div"``) or as a list (``"ul"``), escaped."""
    if tag == "ul":
        return "<ul class='legend'>" + "".join(f"<li>{html.escape(line)}</li>" for line in lines) + "</ul>"
    return "".join(f"<p class='legend'>{html.escape(line)}</p>" for line in lines)


def _img(path: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{html.escape(Path(path).name)}">'


def write_report(path: Path, *, title: str, per_scene: Sequence[dict], average: Sequence[dict],
                 figures: dict[str, list[tuple[str, Path]]], provenance: dict[str, Any], config: dict[str, Any],
                 failed: Sequence[dict] = (), notes: Sequence[str] = (), best: dict[str, str] | None = None) -> Path:
    """Write the report to ``path`` (atomically) and return it."""
    from mitsnerf.data.atomic import atomic_write_text

    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
             f"<style>{STYLE}</style></head><body>", f"<h1>{html.escape(title)}</h1>"]
    for note in notes:
        parts.append(f"<p class='legend'>{html.escape(note)}</p>")
    if failed:
        parts.append("<h2>Failed cells</h2><ul>" + "".join(
            f"<li>{html.escape(f['key'])}: {html.escape(f.get('error', ''))}</li>" for f in failed) + "</ul>")
    cost = cost_columns(per_scene)
    parts += [
        "<h2>Quality per scene</h2>",
        html_table(per_scene, QUALITY, "scene", best),
        _lines(reference_lines(per_scene)),
        "<h2>Cost per scene</h2>",
        html_table(per_scene, cost, "scene", best),
    ]
    if len({r["scene"] for r in per_scene}) > 1:
        parts += [
            "<h2>Quality averaged over scenes</h2>",
            html_table(average, QUALITY, None, best),
            _lines(reference_lines(average)),
            "<h2>Cost averaged over scenes</h2>",
            html_table(average, cost, None, best),
        ]
    parts += ["<h2>Columns</h2>", _lines([line[2:] for line in legend(QUALITY + cost).splitlines()], "ul")]
    for scene, figs in figures.items():
        parts.append(f"<h2>Scene {html.escape(scene)}</h2>")
        for caption, fig_path in figs:
            parts.append(f"<h3>{html.escape(caption)}</h3>{_img(fig_path)}")
    parts += ["<h2>Provenance</h2>", f"<pre>{html.escape(json.dumps(provenance, indent=2))}</pre>",
              "<h2>Configuration</h2>", f"<pre>{html.escape(json.dumps(config, indent=2))}</pre>",
              "</body></html>"]
    atomic_write_text(path, "\n".join(parts) + "\n")
    return Path(path)
