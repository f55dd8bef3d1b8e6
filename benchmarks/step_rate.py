#!/usr/bin/env python3
"""Training steps per second of the grid methods with and without the replayed renderer, in one run.

For each method (``voxel``, ``ngp``) two models of the same seed train side by side on the same dataset and
batches: one with ``replay = false`` (the shared renderer's R x N arrays: render_rays_skipping) and one with
``replay = true`` (mitsnerf.render.replay); their steps alternate (A, B, A, B, ...) so that both see the same
machine load. A step is the trainer's (mitsnerf.train.loop): the step's learning rate, the ray batch's loss,
backward, Adam, the new values back into the model, its after-step work (occupancy updates, upsampling). The
first ``--warmup`` steps (compilation) are not timed; the speedup is the median of the per-step ratios (each
pair of steps run back to back), and ``--split`` gives it before and after a step (voxel's upsampling).
Also printed: the losses of the two models, whose largest relative difference says whether they train alike
(float noise, which Adam's steps amplify over time).

Run (an otherwise idle machine gives absolute figures; on a shared one, only the ratio in the same run holds):
    .venv/bin/mitsnerf generate cloud --out data
    .venv/bin/python benchmarks/step_rate.py data/cloud-* [--methods voxel ngp] [--steps 60] [--batch-rays 2048]
Prints one JSON line per (method, replay) and one per method with the ratio.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--methods", nargs="+", default=["voxel", "ngp"])
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--batch-rays", type=int, default=None, help="the training config's default if not given")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--split", type=int, default=None, metavar="STEP",
                    help="also the medians of the timed steps before STEP and from STEP on (voxel: its upsampling)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a method setting for both models (JSON value), e.g. n_samples=64")
    args = ap.parse_args()

    variant = env.set_variant()
    import drjit as dr
    import drjit.opt  # noqa: F401

    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.runs.fit import build_model, scene_info
    from mitsnerf.train import PixelData, TrainConfig, make_optimizer
    from mitsnerf.train.step import bare_step

    dataset = load_dataset(args.dataset)
    views = dataset.views("train")
    info = scene_info(dataset, views)
    data = PixelData.from_views(views.images, views.cameras, views.pixel_center)
    train_config = TrainConfig(steps=args.steps, seed=args.seed,
                               **({"batch_rays": args.batch_rays} if args.batch_rays else {}))
    extra = {k: json.loads(v) for k, v in (s.split("=", 1) for s in args.set)}

    for method in args.methods:
        runs = {}
        for replay in (False, True):
            model, config = build_model(method, {**extra, "replay": replay}, info, args.seed)
            opt = make_optimizer(model, config.lr)
            model.set_parameters(opt)
            runs[replay] = {"model": model, "opt": opt, "lr": config.lr, "times": [], "losses": []}
        for step in range(args.steps):
            for run in runs.values():
                t0 = time.perf_counter()
                run["losses"].append(bare_step(run["model"], run["opt"], data, train_config, run["lr"], step))
                if step >= args.warmup:
                    run["times"].append(time.perf_counter() - t0)
        base = np.asarray(runs[False]["losses"])
        for replay, run in runs.items():
            med = float(np.median(run["times"]))
            rel = np.abs(np.asarray(run["losses"]) - base) / np.abs(base)
            phases = {}
            if args.split is not None:
                cut = max(args.split - args.warmup, 0)
                phases = {"median_step_s_before_split": float(np.median(run["times"][:cut] or [np.nan])),
                          "median_step_s_from_split": float(np.median(run["times"][cut:] or [np.nan]))}
            print(json.dumps({"bench": "step_rate", "method": method, "replay": replay, "steps": args.steps, **phases,
                              "timed_steps": len(run["times"]), "median_step_s": med, "steps_per_s": 1.0 / med,
                              "rays_per_step": train_config.batch_rays,
                              "samples_per_ray": run["model"].samples_per_ray(),
                              "active_fraction": run["model"].active_fraction, "final_loss": run["losses"][-1],
                              "loss_rel_diff_first10": float(rel[:10].max()), "loss_rel_diff_all": float(rel.max()),
                              "threads": dr.thread_count(), "variant": variant}), flush=True)
        ratio = np.asarray(runs[False]["times"]) / np.asarray(runs[True]["times"])
        speedup = {"speedup_median": float(np.median(runs[False]["times"]) / np.median(runs[True]["times"])),
                   "speedup_paired_median": float(np.median(ratio))}
        if args.split is not None:
            cut = max(args.split - args.warmup, 0)
            speedup.update({"speedup_paired_before_split": float(np.median(ratio[:cut])) if cut else None,
                            "speedup_paired_from_split": float(np.median(ratio[cut:])) if cut < len(ratio) else None})
        print(json.dumps({"bench": "step_rate", "method": method, **speedup}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
