#!/usr/bin/env python3
"""Where a learned density's mass is, against the truth's, by how deep each voxel sits in the true medium.

Every voxel the true ``sigma_t`` fills is binned twice: by its optical depth (through the TRUE medium) to the
nearest training camera, and to the scene's sun (its first directional light). Per bin: the true mass's fraction
and, for each exported density (``mitsnerf export RUN --resolution R``: its ``sigma_t.npy`` on the dataset's
grid), the learned mass in those voxels as a fraction of the whole true mass and as a multiple of the bin's. An
excess in the bins deep in the sun's shadow that the camera bins do not show is density that only the shadow rays
put there. Optical depths are midpoint sums of nearest-voxel lookups (``--samples`` per ray): a binning, not a
reference.

Run:
    .venv/bin/python benchmarks/density_by_depth.py DATA/cloud-HASH EXPORT [EXPORT ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

EDGES = (0.0, 1.0, 3.0, 6.0, 10.0, np.inf)


def mean_channels(grid: np.ndarray) -> np.ndarray:
    """A [z, y, x] grid, the channels of a [z, y, x, c] one averaged."""
    return grid.mean(-1) if grid.ndim == 4 else grid


def optical_depth(sigma: np.ndarray, origins: np.ndarray, directions: np.ndarray, lengths: np.ndarray,
                  samples: int) -> np.ndarray:
    """``tau = sum_k sigma(o + t_k w) dt`` along each ray (P,) in the unit box [-0.5, 0.5]^3, ``sigma`` [z, y, x],
    midpoints ``t_k`` over ``[0, length]``, nearest-voxel lookups (0 outside the box)."""
    n = sigma.shape[0]
    t = (np.arange(samples) + 0.5)[None, :] / samples * lengths[:, None]
    points = origins[:, None, :] + t[..., None] * directions[:, None, :]
    voxel = np.floor((points + 0.5) * n).astype(np.int64)                   # x, y, z voxel indices
    inside = np.all((voxel >= 0) & (voxel < n), axis=-1)
    voxel = np.clip(voxel, 0, n - 1)
    values = np.where(inside, sigma[voxel[..., 2], voxel[..., 1], voxel[..., 0]], 0.0)
    return values.sum(1) * lengths / samples


def depths(dataset: Path, truth: np.ndarray, samples: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The filled voxels' indices (V, 3) [z, y, x] and their optical depths to the nearest camera and to the sun."""
    spec = json.loads((dataset / "manifest.json").read_text())["spec"]
    suns = [light for light in spec["lights"] if light["type"] == "directional"]
    frames = json.loads((dataset / "transforms_train.json").read_text())["frames"]
    cameras = np.array([np.asarray(f["transform_matrix"])[:3, 3] for f in frames])
    index = np.argwhere(truth > 0)
    centres = (index[:, ::-1] + 0.5) / truth.shape[0] - 0.5                  # x, y, z in the unit box
    to_camera = np.full(len(centres), np.inf)
    for camera in cameras:
        offset = camera[None, :] - centres
        length = np.linalg.norm(offset, axis=1)
        to_camera = np.minimum(to_camera, optical_depth(truth, centres, offset / length[:, None],
                                                        np.minimum(length, 1.8), samples))
    out = {"to the nearest camera": to_camera}
    if suns:
        w = -np.asarray(suns[0]["direction"], float)
        w = np.broadcast_to(w / np.linalg.norm(w), centres.shape)
        out["to the sun"] = optical_depth(truth, centres, w, np.full(len(centres), 1.8), samples)
    return index, out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, help="a dataset mitsnerf generated (its volume/sigma_t.npy is the truth)")
    ap.add_argument("exports", type=Path, nargs="+", help="folders of mitsnerf export at the truth's resolution")
    ap.add_argument("--samples", type=int, default=96, help="midpoints per ray (default 96)")
    args = ap.parse_args()
    truth = mean_channels(np.load(args.dataset / "volume" / "sigma_t.npy").astype(np.float64))
    learned = {e.name if e.name != "export" else e.parent.name: mean_channels(np.load(e / "sigma_t.npy"))
               for e in args.exports}
    for name, grid in learned.items():
        if grid.shape != truth.shape:
            print(f"{name}: sigma_t.npy is {grid.shape}, the truth {truth.shape}: export at its resolution",
                  file=sys.stderr)
            return 2
    index, binned = depths(args.dataset, truth, args.samples)
    true_values, total = truth[tuple(index.T)], truth.sum()
    print(f"{args.dataset.name}: true mass {total:.1f}; in voxels the truth leaves empty: "
          + ", ".join(f"{n} {g[truth == 0].sum() / total:.3f}" for n, g in learned.items()))
    for label, tau in binned.items():
        print(f"optical depth {label} | voxels | true | " + " | ".join(learned))
        for lo, hi in zip(EDGES, EDGES[1:]):
            m = (tau >= lo) & (tau < hi)
            if not m.any():
                continue
            cells = [f"[{lo:g}, {hi:g})", str(int(m.sum())), f"{true_values[m].sum() / total:.3f}"]
            for grid in learned.values():
                mass = grid[tuple(index[m].T)].sum()
                cells.append(f"{mass / total:.3f} (x{mass / true_values[m].sum():.2f})")
            print(" | ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
