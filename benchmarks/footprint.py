"""The pixel footprint, per method: training rays jittered over the pixel or through its centre, and
test pixels evaluated as the mean of K x K rays (K = 1: the centre ray).

Mitsuba's film box-filters each pixel of the ground truth. Each method is trained at the default
benchmark's step budget and batch size twice (``pixel_jitter`` on and off, same seed), and each
trained model is scored at every K, on the medium pixels and the whole image. Step budgets: the
figures do not depend on the machine's load. Prints one JSON line per (method, jitter, K) and a
Markdown table.

    .venv/bin/python benchmarks/footprint.py DATASET [--methods voxel ngp nerf] [--k 1 3 5]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def default_budgets() -> dict[str, dict]:
    """Each method's config and train settings in the default benchmark (``make bench``)."""
    from mitsnerf.bench.config import load_bench_config

    config = load_bench_config("default")
    out = {}
    for method in config.methods:
        mconfig, train = config.method_settings(method, quick=False)
        out[method.name] = {"config": mconfig, "train": train}
    return out


def measure(dataset, method: str, settings: dict, jitter: bool, ks, ref) -> list[dict]:
    from mitsnerf.config import from_dict
    from mitsnerf.runs.fit import fit
    from mitsnerf.scoring.images import image_scores
    from mitsnerf.train import TrainConfig
    from mitsnerf.train.evaluate import render_views, stack_rgb

    train = from_dict(TrainConfig, {**settings["train"], "pixel_jitter": jitter})
    start = time.perf_counter()
    run = fit(dataset, method, settings["config"], train, None, progress=False, reference=ref)
    seconds = time.perf_counter() - start
    rows = []
    for k in ks:
        renders, _ = render_views(run.model, ref.cameras, pixel_center=ref.pixel_center, footprint=k)
        s = image_scores(stack_rgb(renders), ref.images, ref.masks, with_ssim=False)
        rows.append({"method": method, "pixel_jitter": jitter, "footprint": k, "steps": train.steps,
                     "psnr": s["psnr_test"], "psnr_medium": s["psnr_test_medium"], "fit_seconds": seconds})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def table(rows: list[dict], ks) -> str:
    head = "| method | training rays | steps | " + " | ".join(f"K={k} medium (whole)" for k in ks) + " |"
    lines = [head, "|" + "---|" * (3 + len(ks))]
    keys = list(dict.fromkeys((r["method"], r["pixel_jitter"]) for r in rows))
    for method, jitter in keys:
        mine = {r["footprint"]: r for r in rows if r["method"] == method and r["pixel_jitter"] == jitter}
        cells = [f"{mine[k]['psnr_medium']:.2f} ({mine[k]['psnr']:.2f})" for k in ks]
        steps = next(iter(mine.values()))["steps"]
        lines.append(f"| {method} | {'jittered' if jitter else 'centre'} | {steps} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("--methods", nargs="+", default=["voxel", "ngp", "nerf"])
    parser.add_argument("--k", nargs="+", type=int, default=[1, 3, 5])
    args = parser.parse_args()

    import mitsnerf  # noqa: F401  (libLLVM before drjit)
    from mitsnerf import env
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.scoring.reference import load_reference

    env.set_variant()
    dataset = load_dataset(Path(args.dataset))
    ref = load_reference(dataset, "test")
    budgets = default_budgets()
    rows = []
    for method in args.methods:
        for jitter in (False, True):
            rows += measure(dataset, method, budgets[method], jitter, args.k, ref)
    floor = (dataset.manifest.get("noise_floor") or {})
    print(f"\nnoise floor: {floor.get('psnr_medium')} medium ({floor.get('psnr')} whole)\n")
    print(table(rows, args.k))


if __name__ == "__main__":
    main()
