"""nerfstudio's raw renders of a method trained with a random background, as RGBA EXRs ``mitsnerf score`` reads.

``ns-render dataset --rendered-output-names raw-RGB raw-ACC`` writes each test view's float outputs, unquantised,
as ``RENDERS/test/raw-RGB/r_NNN.npy.gz``: ``RGB`` (``rgb`` for nerfacto and tensorf, ``rgb_fine`` for vanilla-nerf
and mipnerf, which have no ``rgba`` output) is the colour composited over black (nerfstudio's rule at evaluation
for a model trained with ``background-color random``), ``ACC`` the accumulated opacity. Since the model fits the
training PNGs' values, that colour is sRGB-encoded. Each view becomes ``OUT/r_NNN.exr``: straight linear colour
``srgb_to_linear(RGB / ACC)`` (clipped to [0, 1], nerfstudio's own clamp) and alpha ``ACC``, its header saying
``straight``, so that ``mitsnerf score`` composites it over the dataset's background as it does a PNG, without
the 8-bit rounding of ``ns-render``'s PNGs::

    .venv/bin/python benchmarks/external/ns_rgba.py RENDERS/test OUT --rgb rgb_fine --acc accumulation_fine
"""

from __future__ import annotations

import argparse
import gzip
import sys
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf.data.images import write_exr
from mitsnerf.math.color import srgb_to_linear


def straight_rgba(rgb: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """``(H, W, 4)`` linear straight RGBA from sRGB colour over black ``(H, W, 3)`` and opacity ``(H, W[, 1])``.

    >>> straight_rgba(np.full((1, 1, 3), 0.25), np.full((1, 1, 1), 0.5))[0, 0].astype(float).round(4).tolist()
    [0.214, 0.214, 0.214, 0.5]
    """
    acc = np.clip(acc.reshape(rgb.shape[:2] + (1,)), 0.0, 1.0)
    colour = np.clip(rgb / np.maximum(acc, 1e-10), 0.0, 1.0)
    return np.concatenate([srgb_to_linear(colour), acc], axis=-1).astype(np.float32)


def _load(path: Path) -> np.ndarray:
    with gzip.open(path, "rb") as f:
        return np.load(f)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("split", type=Path, help="ns-render's output folder of one split (RENDERS/test)")
    ap.add_argument("out", type=Path, help="a new folder for the EXRs")
    ap.add_argument("--rgb", default="rgb", help="the colour output's name (default rgb)")
    ap.add_argument("--acc", default="accumulation", help="the opacity output's name (default accumulation)")
    args = ap.parse_args()
    rgb_dir, acc_dir = args.split / f"raw-{args.rgb}", args.split / f"raw-{args.acc}"
    frames = sorted(rgb_dir.glob("*.npy.gz"))
    if not frames:
        sys.exit(f"ns_rgba.py: {rgb_dir}: no raw renders (*.npy.gz)")
    missing = [f.name for f in frames if not (acc_dir / f.name).is_file()]
    if missing:
        sys.exit(f"ns_rgba.py: {acc_dir}: no {missing[0]}")
    if args.out.exists():
        sys.exit(f"ns_rgba.py: {args.out}: exists already")
    args.out.mkdir(parents=True)
    for f in frames:
        write_exr(args.out / f.name.replace(".npy.gz", ".exr"), straight_rgba(_load(f), _load(acc_dir / f.name)),
                  alpha="straight")
    print(f"{len(frames)} RGBA EXRs in {args.out}")


if __name__ == "__main__":
    main()
