"""What mitsuba-inverse can score at best: the true medium rendered by its own renderer, scored as a bench cell.

The method's renders are Monte Carlo too: a test view rendered at ``eval_spp`` samples per pixel carries noise
of its own, so even the true medium scores below the references' agreement unless ``eval_spp`` is well above the
references' 2048. This sets the method's ``sigma_t`` and albedo to the dataset's true grids (resampled to
``--resolution``) and scores its test renders at each ``--spp`` (medium PSNR, whole-image PSNR), beside the
dataset's noise floor.

    .venv/bin/python benchmarks/inverse_ceiling.py --data /work/data/lib --scene cloud --spp 128 2048 4096
    .venv/bin/python benchmarks/inverse_ceiling.py --dataset DATA/cloud_hg85-d1a39285f64f --spp 2048
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", help="the dataset cache: --scene is generated there unless it is cached")
    parser.add_argument("--scene", default="cloud")
    parser.add_argument("--dataset", help="an existing dataset directory (instead of --data and --scene)")
    parser.add_argument("--spp", nargs="+", type=int, default=[128, 2048, 4096])
    parser.add_argument("--estimator", default="drt")
    args = parser.parse_args()

    import mitsnerf  # noqa: F401  (libLLVM before drjit)
    from mitsnerf import env

    env.set_variant()
    import mitsuba as mi

    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.methods.mitsuba_inverse import MitsubaInverseConfig, MitsubaInverseModel
    from mitsnerf.runs.fit import scene_info
    from mitsnerf.scene.spec import load_scene
    from mitsnerf.scene.to_mitsuba import volume_grids
    from mitsnerf.scoring.reference import load_reference
    from mitsnerf.scoring.views import score_views
    from mitsnerf.train.evaluate import render_views, stack_rgb

    if args.dataset is None and args.data is None:
        parser.error("give --data (with --scene) or --dataset")
    dataset = load_dataset(args.dataset or generate_dataset(load_scene(args.scene), Path(args.data)))
    views = dataset.views("train")
    info = scene_info(dataset, views)
    ref = load_reference(dataset, "test")
    rows = []
    for spp in args.spp:
        model = MitsubaInverseModel(MitsubaInverseConfig(resolutions=(64,), upsample_at=(), eval_spp=spp,
                                                         estimator=args.estimator), info)
        sigma, albedo = volume_grids(model.spec)
        r = sigma.shape[0]
        tau = (sigma.reshape(r, r, r, -1)[..., : model.channels] * model.side).astype(np.float32)
        model.set_parameters({"sigma_t": mi.TensorXf(tau), "albedo": mi.TensorXf(np.asarray(albedo, np.float32))})
        start = time.perf_counter()
        preds = stack_rgb(render_views(model, ref.cameras)[0])
        seconds = time.perf_counter() - start
        metrics, _ = score_views(preds, ref)
        name = dataset.manifest.get("name", args.scene)
        rows.append({"scene": name, "eval_spp": spp, "psnr_test_medium": metrics["psnr_test_medium"],
                     "psnr_test": metrics["psnr_test"], "noise_floor_medium": metrics["noise_floor_psnr_medium"],
                     "render_seconds": seconds})
        print(json.dumps(rows[-1]), flush=True)


if __name__ == "__main__":
    main()
