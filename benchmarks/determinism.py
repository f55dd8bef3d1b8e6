#!/usr/bin/env python3
"""How far two trainings of the same config differ: every method twice multi-threaded, twice on one thread.

The same dataset, config and seed, trained with :func:`mitsnerf.runs.fit.fit` (no run directory). For
each pair: the largest difference of any parameter value, and of the test PSNR (whole image and
medium pixels). Multi-threaded, the grid methods' scatter-add gradients are summed in the order
the threads run, so their runs drift apart; ``deterministic`` (one Dr.Jit thread, ``--deterministic``)
must give zero for every method. Not a timing: the machine's load changes nothing but the thread
interleaving it measures.

Run:
    .venv/bin/python benchmarks/determinism.py [--scene cloud] [--steps 200] [--methods voxel ngp nerf]
Prints one JSON line per (method, threads).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env

#: The quick profile's scene: 16x16 views, 8 training views, a 32^3 grid.
QUICK_SCENE = {"cameras.width": 16, "cameras.height": 16, "cameras.n_train": 8, "cameras.n_test": 2,
               "render.spp_train": 8, "render.spp_test": 16, "volume.resolution": 32}


def _params(run) -> dict[str, np.ndarray]:
    return {k: np.array(v.numpy() if hasattr(v, "numpy") else v) for k, v in run.model.parameters().items()}


def _pair(dataset, method: str, steps: int, batch: int, deterministic: bool) -> dict:
    from mitsnerf.runs.fit import fit
    from mitsnerf.train import TrainConfig

    runs = [fit(dataset, method, {}, TrainConfig(steps=steps, batch_rays=batch, log_every=steps), None,
                progress=False, deterministic=deterministic) for _ in range(2)]
    a, b = (_params(r) for r in runs)
    m = [r.metrics() for r in runs]
    return {
        "method": method, "steps": steps, "batch_rays": batch, "threads": 1 if deterministic else "all",
        "max_abs_param_diff": max(float(np.max(np.abs(a[k] - b[k]))) if a[k].size else 0.0 for k in a),
        "bit_identical": all(np.array_equal(a[k], b[k]) for k in a),
        "psnr_test": [x["psnr_test"] for x in m],
        "psnr_diff_db": abs(m[0]["psnr_test"] - m[1]["psnr_test"]),
        "psnr_medium_diff_db": abs((m[0]["psnr_test_medium"] or 0) - (m[1]["psnr_test_medium"] or 0)),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cloud")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--batch-rays", type=int, default=1024)
    ap.add_argument("--methods", nargs="+", default=["voxel", "ngp", "nerf", "mitsuba-inverse"])
    ap.add_argument("--data", default=None, help="dataset cache root (default: a temporary directory)")
    args = ap.parse_args()

    env.set_variant()
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import load_scene

    spec = load_scene(args.scene).with_overrides(QUICK_SCENE)
    dataset = load_dataset(generate_dataset(spec, Path(args.data or tempfile.mkdtemp()), progress=False))
    for method in args.methods:
        for deterministic in (False, True):
            print(json.dumps(_pair(dataset, method, args.steps, args.batch_rays, deterministic)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
