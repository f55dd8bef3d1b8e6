"""The emission-absorption oracle of a dataset at several settings: medium PSNR at footprint 1 and K,
the noise floor, the split of its error (reference noise, its own Monte Carlo noise, bias), the MSE
between its footprint-1 and footprint-K renders on medium pixels (the footprint's own share) and timings.

Prints one JSON line per setting; nothing is cached (``compute_oracle`` runs every time).

    .venv/bin/python benchmarks/oracle_settings.py data/cloud-<hash> --spp 64 256 --resolution 32 64 --n-samples 128
"""

from __future__ import annotations

import argparse
import itertools
import json
import time

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("--spp", type=int, nargs="+", default=[64])
    parser.add_argument("--resolution", type=int, nargs="+", default=[32])
    parser.add_argument("--delta-resolution", type=int, nargs="+", default=[0])
    parser.add_argument("--n-samples", type=int, nargs="+", default=[128])
    parser.add_argument("--footprint", type=int, default=3)
    parser.add_argument("--replicas", type=int, default=2)
    args = parser.parse_args()

    from mitsnerf import env

    env.set_variant()
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.oracle.cache import OracleConfig, compute_oracle
    from mitsnerf.scoring.reference import load_reference

    dataset = load_dataset(args.dataset)
    masks = load_reference(dataset, "test").masks
    for spp, res, dres, n in itertools.product(args.spp, args.resolution, args.delta_resolution, args.n_samples):
        config = OracleConfig(spp=spp, resolution=res, delta_resolution=dres, n_samples=n,
                              noise_replicas=args.replicas)
        start = time.perf_counter()
        info, scores, arrays = compute_oracle(dataset, config, args.footprint)
        k1, kk = arrays["test_k1"], arrays[f"test_k{args.footprint}"]
        print(json.dumps({"config": info["config"], "footprint": args.footprint,
                          "psnr_medium": info["psnr_test_medium"],
                          "psnr": {k: s["psnr_test"] for k, s in scores.items()},
                          "floor_medium": info["noise_floor_psnr_medium"], "error_split": info["error_split"],
                          "footprint_mse_medium": float(np.square(k1 - kk).mean(-1)[masks].mean()),
                          "grid_points": info["grid_points"], "seconds": info["seconds"],
                          "wall_s": time.perf_counter() - start, "commit": env.provenance().get("commit")}),
              flush=True)


if __name__ == "__main__":
    main()
