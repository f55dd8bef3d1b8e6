"""The dataset cache: content-hashed directory names, completeness, one writer at a time, leftovers.

A dataset lives at ``ROOT/<name>-<hash[:12]>``; it is complete when its ``manifest.json``
(written last, atomically) carries the full hash and the current format version. Concurrent
writers of the same dataset are serialised by an exclusive lock on ``ROOT/.<dir>.lock``; a
writer waiting on it says so. Temporaries of interrupted writers (``.<dir>.tmp-*``) are removed
by the next writer of that dataset at once, and those of other datasets once they are old.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mitsnerf.data.atomic import clean_stale_temps
from mitsnerf.outputs import exclusive_lock

#: Temporaries of *other* datasets are removed once this old (seconds); a dataset's own at once.
STALE_TEMP_AGE_S = 24 * 3600.0


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_manifest(directory: str | os.PathLike) -> dict[str, Any] | None:
    """The dataset's manifest, or None when it is missing or unreadable."""
    try:
        data = json.loads((Path(directory) / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def is_complete(directory: Path, digest: str, format_version: int) -> bool:
    """Whether ``directory`` holds the finished dataset of hash ``digest`` and this format."""
    m = read_manifest(directory)
    return m is not None and bool(m) and m.get("format_version") == format_version and m.get("hash") == digest


@contextlib.contextmanager
def dataset_lock(final: Path, progress: bool = True) -> Iterator[None]:
    """Exclusive lock on ``.<name>.lock`` next to ``final`` while one process writes it; a writer
    that has to wait says for whom (with ``progress``: a silent wait looks like a hang)."""
    def waiting(holder: str) -> None:
        print(f"mitsnerf: waiting for {holder}, which is writing {final} ...", file=sys.stderr, flush=True)

    with exclusive_lock(final.parent / f".{final.name}.lock", wait=True, what=final,
                        on_wait=waiting if progress else None):
        yield


def clean_temps(final: Path) -> None:
    """Remove leftovers of interrupted writers: this dataset's at once (we hold its lock), others when old."""
    for p in final.parent.glob(f".{final.name}.tmp-*"):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    clean_stale_temps(final.parent, min_age_s=STALE_TEMP_AGE_S)
