#!/usr/bin/env python3
"""The directional oracle's ceiling per spherical-harmonic order: where it converges, and what it costs.

Generates a library scene with an anisotropic medium (default ``cloud_hg85``) at a reduced size, or takes a
generated dataset (``--dataset``, e.g. the library-size one the ``physics`` benchmark uses), then computes its
oracle (``mitsnerf.oracle.directional``) at each setting given and prints, per setting, the medium PSNR of the
oracle's test views at every order scored up to ``--order``, beside the views' own agreement (the noise floor),
the oracle's error split (its Monte Carlo variance ``mc_var`` against its MSE) and the seconds it took. The orders
above the converged one stop gaining, or lose to the Monte Carlo noise of their coefficients: the samples per
point (``--spp``) decide how high an order pays. Each oracle is cached in its dataset (a second run reads it).

Run:
    .venv/bin/python benchmarks/oracle_orders.py [--scene cloud_hg85] [--size 16] [--spp 64 256] \\
        [--resolution 16] [--order 8] [--window lanczos none] [--data /tmp/oracle-orders]
    .venv/bin/python benchmarks/oracle_orders.py --dataset DATA/cloud_hg85-HASH --footprint 3 \\
        --resolution 32 --spp 256 512 --order 9 --report-orders 0 1 2 4 6 8 --rescore-windows none
Prints one JSON line per (spp, window), and per window rescored its medium PSNR by order (clamped at 0, and
unclamped: what the clamp does).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import mitsnerf  # noqa: F401  (libLLVM before drjit)


def _args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cloud_hg85")
    ap.add_argument("--dataset", default=None, help="a generated dataset to use as it is (no reduced scene)")
    ap.add_argument("--size", type=int, default=16, help="test image width and height")
    ap.add_argument("--test-views", type=int, default=3)
    ap.add_argument("--spp-test", type=int, default=256, help="samples per pixel of test and test_ref")
    ap.add_argument("--volume-resolution", type=int, default=32)
    ap.add_argument("--spp", type=int, nargs="+", default=[64, 256], help="volpath directions per grid point")
    ap.add_argument("--resolution", type=int, default=16, help="the oracle's grid R")
    ap.add_argument("--order", type=int, default=8)
    ap.add_argument("--report-orders", type=int, nargs="*", default=None,
                    help="lower orders also scored (default: every order below --order)")
    ap.add_argument("--window", nargs="+", default=["lanczos"], choices=["lanczos", "none"])
    ap.add_argument("--rescore-windows", nargs="*", default=[], choices=["lanczos", "none"],
                    help="also score these windows from each oracle's cached coefficients (no second volpath)")
    ap.add_argument("--rescore-orders", type=int, nargs="*", default=None,
                    help="the orders --rescore-windows renders (default: --order alone)")
    ap.add_argument("--footprint", type=int, default=1, help="the scored footprint K (the benchmarks': 3)")
    ap.add_argument("--data", default="/tmp/oracle-orders")
    return ap.parse_args()


def _dataset(args: argparse.Namespace):
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import load_scene

    if args.dataset:
        return load_dataset(args.dataset)
    small = {"cameras.width": args.size, "cameras.height": args.size, "cameras.n_train": 2,
             "cameras.n_test": args.test_views, "render.spp_train": 4, "render.spp_test": args.spp_test,
             "volume.resolution": args.volume_resolution}
    return load_dataset(generate_dataset(load_scene(args.scene).with_overrides(small), args.data, progress=False))


def rescore(dataset, oracle, window: str, orders, footprint: int) -> dict:
    """Medium PSNR by order of an oracle's cached coefficients with another window, clamped and unclamped."""
    import numpy as np

    from mitsnerf.oracle.cache import _grids
    from mitsnerf.oracle.field import DirectionalOracleField, render_field
    from mitsnerf.render.background import make_background
    from mitsnerf.scene.lights import delta_lights
    from mitsnerf.scoring.reference import load_reference
    from mitsnerf.scoring.views import score_views

    spec, sigma_t, albedo = _grids(dataset)
    sh, irradiance = (np.load(oracle.path / f"{name}.npy") for name in ("lbar_sh", "delta_irradiance"))
    ref, background = load_reference(dataset, "test"), make_background(dataset.background, dataset.root)
    out: dict = {}
    for clamp in (True, False):
        for o in orders:
            f = DirectionalOracleField.from_grids(sigma_t, albedo, sh, spec.volume.phase.g, delta_lights(spec.lights),
                                                  irradiance, dataset.box, order=o, window=window, clamp=clamp)
            image = render_field(f, ref.cameras, dataset.box, oracle.info["config"]["n_samples"],
                                 background=background, footprint=footprint, pixel_center=ref.pixel_center)
            psnr = score_views(image, ref, None)[0]["psnr_test_medium"]
            out.setdefault("clamped" if clamp else "unclamped", {})[str(o)] = round(psnr, 2)
    return out


def main() -> int:
    args = _args()
    from mitsnerf import env
    from mitsnerf.oracle.cache import OracleConfig, ensure_oracle
    from mitsnerf.oracle.directional import DirectionalConfig

    variant = env.set_variant()
    dataset = _dataset(args)
    orders = tuple(range(args.order)) if args.report_orders is None else tuple(args.report_orders)
    for spp in args.spp:
        for window in args.window:
            config = OracleConfig(spp=spp, resolution=args.resolution,
                                  directional=DirectionalConfig(spp=spp, order=args.order, window=window,
                                                                report_orders=orders))
            start, load = time.perf_counter(), os.getloadavg()[0]
            oracle = ensure_oracle(dataset, config, args.footprint)
            info = oracle.info
            split = {k: v for k, v in info["error_split"].items() if k != "note"}
            print(json.dumps({"dataset": os.path.basename(str(dataset.root)), "variant": variant, "spp": spp,
                              "window": window, "resolution": args.resolution, "footprint": args.footprint,
                              "seconds": round(time.perf_counter() - start, 1),
                              "oracle_seconds": {k: round(v, 1) for k, v in info["seconds"].items()},
                              "load_start_end": [round(load, 2), round(os.getloadavg()[0], 2)],
                              "noise_floor_psnr_medium": round(info["noise_floor_psnr_medium"], 2),
                              "psnr_medium_by_order": {k: round(v, 2) for k, v in
                                                       info["directional"]["psnr_test_medium_by_order"].items()},
                              "mc_fraction": round(split["mc_var_medium"] / split["mse_medium"], 3),
                              "error_split": split, "path": str(oracle.path)}), flush=True)
            for other in args.rescore_windows:
                start = time.perf_counter()
                scored = rescore(dataset, oracle, other, tuple(args.rescore_orders or [args.order]), args.footprint)
                print(json.dumps({"spp": spp, "coefficients_of_window": window, "window": other, **scored,
                                  "seconds": round(time.perf_counter() - start, 1)}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
