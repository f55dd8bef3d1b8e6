#!/usr/bin/env python3
"""What verifying a dataset costs when it is opened (:func:`mitsnerf.data.verify.verify_dataset`), by part.

- ``hashes``: sha256 of every file the manifest lists (skipped by ``--no-verify``);
- ``grids``: reading and range-checking ``volume/sigma_t.npy`` and ``albedo.npy``;
- ``views``: loading every split's images with the loader's checks plus the negative-radiance
  check; training loads ``train`` and ``test`` anyway (and keeps them), so only ``test_ref`` and
  the checks are extra.

Each part is timed on a freshly opened dataset (files in the page cache after the first repeat),
wall and process CPU seconds, the median over the repeats.

Run:
    .venv/bin/python benchmarks/verify_cost.py DATASET_DIR [--repeats 5]
Prints one JSON line per part and one for the whole.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env


def _timed(fn, repeats: int) -> dict:
    wall, cpu, out = [], [], None
    for _ in range(repeats + 1):  # the first reads the files into the page cache
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - w)
        cpu.append(time.process_time() - c)
    return {"wall_s": statistics.median(wall[1:]), "cpu_s": statistics.median(cpu[1:]), "result": out}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    env.set_variant()
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.data.verify import check_grids, check_hashes, check_views, verify_dataset

    root = Path(args.dataset)
    manifest = load_dataset(root).manifest
    parts = {
        "hashes": lambda: check_hashes(root, manifest),
        "grids": lambda: check_grids(root, manifest),
        "views": lambda: check_views(load_dataset(root)),
        "all": lambda: verify_dataset(load_dataset(root)).views,
        "all --no-verify": lambda: verify_dataset(load_dataset(root), hashes=False).views,
    }
    for name, fn in parts.items():
        t = _timed(fn, args.repeats)
        print(json.dumps({"part": name, "wall_s": round(t["wall_s"], 4), "cpu_s": round(t["cpu_s"], 4),
                          "result": t["result"] if not isinstance(t["result"], tuple) else list(t["result"])}),
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
