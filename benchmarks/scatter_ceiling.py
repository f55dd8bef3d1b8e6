#!/usr/bin/env python3
"""The single-scattering rung's ceiling on an anisotropic dataset for several remainder bases, beside the oracle's.

For each basis ``L_f:L_z`` (spherical harmonics of every order up to ``L_f``, zonal harmonics around each delta
light from ``L_f + 1`` to ``L_z``; ``L:L`` is the full series to order ``L``) the dataset's cached directional
oracle is rendered with its remainder projected on that basis (:func:`mitsnerf.oracle.rungs.single_scattering_field`)
and scored on the test views' medium pixels: what the ``scatter`` method could reach with the true medium and the
best remainder its basis holds. The oracle itself (its full series) and the views' own agreement beside.

Run (the oracle must be cached: ``mitsnerf bench physics`` or ``ensure_oracle`` computes it):
    .venv/bin/python benchmarks/scatter_ceiling.py DATA/cloud_hg85-HASH --footprint 3 \\
        --bases 0:0 1:1 2:2 4:4 8:8 0:8 1:8 2:8
Prints one JSON line per basis.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--footprint", type=int, default=3)
    ap.add_argument("--bases", nargs="+", default=["0:0", "1:1", "2:2", "4:4", "8:8", "0:8", "1:8", "2:8"])
    args = ap.parse_args()
    env.set_variant()

    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.oracle.cache import OracleConfig, load_oracle, oracle_path
    from mitsnerf.oracle.rungs import score_on_basis
    from mitsnerf.scoring.reference import load_reference

    dataset = load_dataset(args.dataset)
    oracle = load_oracle(oracle_path(dataset, OracleConfig(), args.footprint))
    if oracle is None or "directional" not in oracle.info:
        sys.exit(f"{args.dataset}: no cached directional oracle at footprint {args.footprint}")
    ref = load_reference(dataset, "test")
    print(json.dumps({"oracle_medium": oracle.metrics(args.footprint).get("psnr_test_medium"),
                      "by_order": oracle.info["directional"].get("psnr_test_medium_by_order"),
                      "noise_floor_medium": (ref.noise_floor or {}).get("psnr_medium")}), flush=True)
    for basis in args.bases:
        degree, zonal = (int(v) for v in basis.split(":"))
        t0 = time.perf_counter()
        psnr = score_on_basis(oracle.path, dataset, degree, zonal, args.footprint, ref)
        print(json.dumps({"basis": basis, "degree": degree, "zonal": zonal, "psnr_test_medium": psnr,
                          "seconds": time.perf_counter() - t0}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
