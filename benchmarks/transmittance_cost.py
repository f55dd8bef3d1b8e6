#!/usr/bin/env python3
"""The exact transmittance's cost, commit against commit: ``pixel_transmittance`` on the same rays.

Each commit's ``mitsnerf/scene/transmittance.py`` (``git show REV:...``) is imported beside the working tree's
package (the rest of the package is the current one) and called as the harness calls it for a scene's splits
(``mitsnerf.generate``): its train views at K = 8 and its test views at K = 16 (``footprint_for`` at 64 and 512
spp), with the scene's environment as the background. The versions alternate in one process, ``--repeats``
times, so that a load drifting during the run weighs on each alike. One JSON line per case and version: the
seconds of each repeat, how many kernels ran the optical-depth loop in one call (its label in their code), and the
largest difference of its mean ``T`` and ``T L`` from the first version's.

Run (benchmarks/README.md, "Ground truth's exact transmittance (issue 50)"):
    .venv/bin/python benchmarks/transmittance_cost.py 1826733^ 07aa360 HEAD [--scene cloud] [--train-views 8]
        [--test-views 2] [--size 64] [--repeats 3]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env

ROOT = Path(__file__).resolve().parent.parent
FILE = "mitsnerf/scene/transmittance.py"


def load_version(rev: str, into: Path):
    """The module ``FILE`` as it was at ``rev``, imported under a name of its own."""
    source = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{FILE}"], check=True, capture_output=True,
                            text=True).stdout
    name = "transmittance_" + "".join(c if c.isalnum() else "_" for c in rev)
    path = into / f"{name}.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # (dataclasses look their module up)
    spec.loader.exec_module(module)
    return module


def timed_call(module, truth: dict, cameras: list, k: int):
    """``(seconds, walks, result)`` of one call, walks counted in Dr.Jit's kernel history."""
    import drjit as dr

    dr.kernel_history()  # (empties it)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        start = time.perf_counter()
        seen = module.pixel_transmittance(truth["density"], truth["resolution"], truth["box"], cameras, footprint=k,
                                          channels=truth["channels"], background=truth["background"])
        seconds = time.perf_counter() - start
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    walks = sum("ir" in kernel and "optical_depths" in kernel["ir"].getvalue() for kernel in dr.kernel_history())
    return seconds, walks, seen


def setup(args, tmp: Path) -> tuple[dict, dict]:
    """The scene's true grid and background (as the harness builds them) and its cases ``name -> (cameras, K)``."""
    from mitsnerf.render.background import make_background
    from mitsnerf.scene.rigs import camera_rig
    from mitsnerf.scene.spec import load_scene
    from mitsnerf.scene.to_mitsuba import background_description, scene_box, volume_grids
    from mitsnerf.scoring.density import true_density

    spec = load_scene(args.scene).with_overrides({
        "cameras.n_train": args.train_views, "cameras.n_test": args.test_views, "cameras.width": args.size,
        "cameras.height": args.size})
    box, (sigma_t, _) = scene_box(spec), volume_grids(spec)
    truth = {"density": true_density(sigma_t, box), "resolution": int(sigma_t.shape[0]), "box": box,
             "channels": 3 if sigma_t.ndim == 4 else 1,
             "background": make_background(background_description(spec), tmp) if spec.environment else None}
    cases = {f"{args.train_views} train views, K 8": (camera_rig(spec.cameras, "train"), 8),
             f"{args.test_views} test views, K 16": (camera_rig(spec.cameras, "test"), 16)}
    return truth, cases


def report(case: str, runs: dict, first: str) -> list[dict]:
    """Per version: the seconds of its calls, its walks per call, its largest differences from ``first``'s result."""
    ref = runs[first][-1][2]
    out = []
    for rev, calls in runs.items():
        seen = calls[-1][2]
        through = 0.0 if seen.through is None else float(np.abs(seen.through - ref.through).max())
        out.append({"case": case, "rev": rev, "seconds": [round(c[0], 3) for c in calls],
                    "walks_per_call": calls[-1][1], "max_abs_diff_t": float(np.abs(seen.t - ref.t).max()),
                    "max_abs_diff_through": through})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("revs", nargs="+", help="commits (git revisions) whose transmittance.py to time")
    ap.add_argument("--scene", default="cloud")
    ap.add_argument("--train-views", type=int, default=8)
    ap.add_argument("--test-views", type=int, default=2)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    env.set_variant()
    with tempfile.TemporaryDirectory(prefix="mitsnerf-tcost-") as tmp:
        versions = {rev: load_version(rev, Path(tmp)) for rev in args.revs}
        truth, cases = setup(args, Path(tmp))
        for case, (cameras, k) in cases.items():
            runs: dict[str, list] = {rev: [] for rev in versions}
            for _ in range(args.repeats):
                for rev, module in versions.items():
                    runs[rev].append(timed_call(module, truth, cameras, k))
            for line in report(case, runs, args.revs[0]):
                print(json.dumps(line), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
