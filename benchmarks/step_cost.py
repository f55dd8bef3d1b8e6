#!/usr/bin/env python3
"""Training seconds per step of several methods or settings side by side, their steps interleaved in one process.

Each ``--model LABEL=METHOD [KEY=VALUE ...]`` (settings as ``--set`` takes them, JSON values) is built on the same
dataset with the same seed and the same ray batches; their steps alternate (A, B, C, A, B, C, ...) so that every
one sees the same machine load. A step is the trainer's (mitsnerf.train.loop: learning rate, the batch's loss,
backward, Adam, the new values back into the model, its after-step work). The first ``--warmup`` steps
(compilation) are not timed. Printed: per model the median seconds per step and, against the first model, the
median of the per-round ratios (each round runs every model once, back to back): the figure to quote on a shared
machine. Also the final loss of each (they train on the same batches).

Run:
    .venv/bin/python benchmarks/step_cost.py DATA/cloud-HASH --steps 60 --batch-rays 2048 \\
        --model ngp=ngp --model scatter=scatter --model "no-shadow-grad=scatter field.shadow_gradient=false"
Prints one JSON line per model.
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


def parse_model(text: str) -> tuple[str, str, dict]:
    """``"LABEL=METHOD KEY=VALUE ..."`` -> (label, method, settings); a VALUE is JSON where it parses, else text.

    >>> parse_model("fast=scatter field.shadow_samples=16 medium=grid")
    ('fast', 'scatter', {'field.shadow_samples': 16, 'medium': 'grid'})
    """
    head, *pairs = text.split()
    label, _, method = head.partition("=")
    settings = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        try:
            settings[key] = json.loads(value)
        except json.JSONDecodeError:
            settings[key] = value
    return label, method or label, settings


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--model", action="append", required=True, metavar="LABEL=METHOD [KEY=VALUE ...]")
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--batch-rays", type=int, default=None, help="the training config's default if not given")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    variant = env.set_variant()
    import drjit as dr
    import drjit.opt  # noqa: F401

    from mitsnerf.config import apply_overrides
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

    runs = []
    for text in args.model:
        label, method, settings = parse_model(text)
        model, config = build_model(method, apply_overrides({}, settings), info, args.seed)
        opt = make_optimizer(model, config.lr)
        model.set_parameters(opt)
        runs.append({"label": label, "method": method, "settings": settings, "model": model, "opt": opt,
                     "lr": config.lr, "times": [], "loss": None})
    for step in range(args.steps):
        for run in runs:
            t0 = time.perf_counter()
            run["loss"] = bare_step(run["model"], run["opt"], data, train_config, run["lr"], step)
            if step >= args.warmup:
                run["times"].append(time.perf_counter() - t0)
    first = np.asarray(runs[0]["times"])
    for run in runs:
        times = np.asarray(run["times"])
        print(json.dumps({"bench": "step_cost", "label": run["label"], "method": run["method"],
                          "settings": run["settings"], "steps": args.steps, "timed_steps": len(times),
                          "median_step_s": float(np.median(times)), "steps_per_s": float(1.0 / np.median(times)),
                          "ratio_to_first_paired_median": float(np.median(times / first)),
                          "rays_per_step": train_config.batch_rays, "final_loss": run["loss"],
                          "active_fraction": getattr(run["model"], "active_fraction", None),
                          "threads": dr.thread_count(), "variant": variant}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
