"""Result tables as Markdown (terminal and file) and CSV."""

from __future__ import annotations

import csv
import io
import math
from typing import Any, Sequence


def _fmt(value: Any, digits: int) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if math.isnan(value):
            return "-"
        if math.isinf(value):
            return "inf"
        if abs(value) >= 1e5:
            return f"{value:.3g}"
        return f"{value:.{digits}f}"
    return str(value)


def markdown_table(rows: Sequence[dict], columns: Sequence[tuple[str, str, int]], best: dict[str, str] | None = None) -> str:
    """A Markdown table of ``rows``; ``columns`` are (key, header, decimals).

    ``best`` maps a key to ``"max"`` or ``"min"``: the best value in that column is bold.

    >>> print(markdown_table([{"m": "a", "p": 30.0}, {"m": "b", "p": 31.5}], [("m", "method", 0), ("p", "PSNR", 2)], {"p": "max"}))
    | method | PSNR |
    |---|---|
    | a | 30.00 |
    | b | **31.50** |
    """
    best = best or {}
    marks: dict[str, Any] = {}
    for key, how in best.items():
        values = [r.get(key) for r in rows if isinstance(r.get(key), (int, float)) and not math.isnan(r.get(key))]
        if len(values) > 1:
            marks[key] = max(values) if how == "max" else min(values)
    lines = ["| " + " | ".join(h for _, h, _ in columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        cells = []
        for key, _, digits in columns:
            text = _fmt(row.get(key), digits)
            if key in marks and row.get(key) == marks[key]:
                text = f"**{text}**"
            cells.append(text)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def csv_table(rows: Sequence[dict], keys: Sequence[str]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(keys), extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: row.get(k) for k in keys})
    return buf.getvalue()
