#!/usr/bin/env python3
"""The directional oracle's ceiling per spherical-harmonic order: where it converges, and what it costs.

Generates a library scene with an anisotropic medium (default ``cloud_hg85``) at a reduced size, then computes
its oracle (``mitsnerf.oracle.directional``) at each setting given and prints, per setting, the medium PSNR of
the oracle's test views at every order up to ``--order``, beside the views' own agreement (the noise floor)
and the seconds it took. The orders above the converged one stop gaining, or lose to the Monte Carlo noise of
their coefficients: the samples per point (``--spp``) decide how high an order pays.

Run:
    .venv/bin/python benchmarks/oracle_orders.py [--scene cloud_hg85] [--size 16] [--spp 64 256] \\
        [--resolution 16] [--order 8] [--window lanczos none] [--data /tmp/oracle-orders]
Prints one JSON line per (spp, window).
"""

from __future__ import annotations

import argparse
import json
import time

import mitsnerf  # noqa: F401  (libLLVM before drjit)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cloud_hg85")
    ap.add_argument("--size", type=int, default=16, help="test image width and height")
    ap.add_argument("--test-views", type=int, default=3)
    ap.add_argument("--spp-test", type=int, default=256, help="samples per pixel of test and test_ref")
    ap.add_argument("--volume-resolution", type=int, default=32)
    ap.add_argument("--spp", type=int, nargs="+", default=[64, 256], help="volpath directions per grid point")
    ap.add_argument("--resolution", type=int, default=16, help="the oracle's grid R")
    ap.add_argument("--order", type=int, default=8)
    ap.add_argument("--window", nargs="+", default=["lanczos"], choices=["lanczos", "none"])
    ap.add_argument("--data", default="/tmp/oracle-orders")
    args = ap.parse_args()

    from mitsnerf import env
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.oracle.cache import OracleConfig, ensure_oracle
    from mitsnerf.oracle.directional import DirectionalConfig
    from mitsnerf.scene.spec import load_scene

    variant = env.set_variant()
    small = {"cameras.width": args.size, "cameras.height": args.size, "cameras.n_train": 2,
             "cameras.n_test": args.test_views, "render.spp_train": 4, "render.spp_test": args.spp_test,
             "volume.resolution": args.volume_resolution}
    dataset = load_dataset(generate_dataset(load_scene(args.scene).with_overrides(small), args.data, progress=False))
    orders = tuple(range(args.order))
    for spp in args.spp:
        for window in args.window:
            config = OracleConfig(spp=spp, resolution=args.resolution,
                                  directional=DirectionalConfig(order=args.order, window=window, report_orders=orders))
            start = time.perf_counter()
            oracle = ensure_oracle(dataset, config, 1)
            by_order = oracle.info["directional"]["psnr_test_medium_by_order"]
            print(json.dumps({"scene": args.scene, "variant": variant, "spp": spp, "window": window,
                              "resolution": args.resolution, "seconds": round(time.perf_counter() - start, 1),
                              "noise_floor_psnr_medium": round(oracle.info["noise_floor_psnr_medium"], 2),
                              "psnr_medium_by_order": {k: round(v, 2) for k, v in by_order.items()},
                              "error_split": {k: v for k, v in oracle.info["error_split"].items() if k != "note"}}),
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
