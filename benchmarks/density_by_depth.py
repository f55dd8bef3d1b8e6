#!/usr/bin/env python3
"""Where a learned density's mass is, against the truth's, by how deep each voxel sits in the true medium.

Every voxel the true ``sigma_t`` fills is binned twice: by its optical depth (through the TRUE medium, its channels'
mean) to the nearest training camera, and to the scene's first delta light (the sun). Per bin: the true mass's
fraction and, for each exported density (``mitsnerf export RUN --resolution R``: its ``sigma_t.npy`` on the
dataset's grid), the learned mass in those voxels as a fraction of the whole true mass and as a multiple of the
bin's. An excess in the bins deep in the sun's shadow that the camera bins do not show is density that only the
shadow rays put there. Optical depths are the scatter field's shadow march (``mitsnerf.math.box.
march_optical_depth``, ``--samples`` midpoints from the voxel's centre to where the ray leaves the box, the
cameras being outside it) through the true grid's trilinear lookup.

Run:
    .venv/bin/python benchmarks/density_by_depth.py DATA/cloud-HASH EXPORT [EXPORT ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env

EDGES = (0.0, 1.0, 3.0, 6.0, 10.0, np.inf)


def depths(dataset, truth: np.ndarray, samples: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The filled voxels of the grey ``truth`` [z, y, x] (a mask) and their optical depths to the nearest training
    camera and to the first delta light."""
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.math.box import march_optical_depth
    from mitsnerf.math.rays import host, to_array3f
    from mitsnerf.scene.lights import light_terms
    from mitsnerf.scene.spec import parse_scene
    from mitsnerf.scoring.density import true_density

    box = dataset.box
    filled = truth > 0
    x = to_array3f(mi.Array3f, box.voxel_centres(truth.shape[0])[filled])
    density = true_density(truth, box)
    with dr.suspend_grad():
        def tau(w, s_max=None) -> np.ndarray:
            return host(march_optical_depth(density, x, w, samples, box, s_max))

        out = {"to the nearest camera": np.min([tau(dr.normalize(mi.Array3f(*map(float, cam.origin)) - x))
                                                for cam in dataset.views("train").cameras], axis=0)}
        lights = light_terms(parse_scene(dataset.manifest["spec"], "manifest.json: spec").lights, x)
        if lights:
            w, _, s_max = lights[0]
            out["to the sun"] = tau(w, s_max)
    return filled, out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, help="a dataset mitsnerf generated (its volume/sigma_t.npy is the truth)")
    ap.add_argument("exports", type=Path, nargs="+", help="folders of mitsnerf export at the truth's resolution")
    ap.add_argument("--samples", type=int, default=96, help="midpoints per ray (default 96)")
    args = ap.parse_args()
    env.set_variant()

    from mitsnerf.data.dataset import load_dataset, true_grid_path
    from mitsnerf.scoring.density import grey

    dataset = load_dataset(args.dataset)
    sigma_t = np.load(true_grid_path(dataset.root))
    truth = grey(sigma_t, sigma_t.ndim == 4).astype(np.float64)
    learned = {}
    for e in args.exports:
        path = e / "sigma_t.npy"
        grid = np.load(path) if path.is_file() else None
        if grid is None or grid.shape[:3] != truth.shape:
            found = "missing (not a mitsnerf export folder)" if grid is None else f"{grid.shape}"
            print(f"{path}: {found}; the truth is {truth.shape}: mitsnerf export RUN --resolution {truth.shape[0]}",
                  file=sys.stderr)
            return 2
        learned[e.name if e.name != "export" else e.parent.name] = grey(grid, grid.ndim == 4)
    filled, binned = depths(dataset, truth, args.samples)
    true_values, total = truth[filled], truth.sum()
    learned_values = {n: g[filled] for n, g in learned.items()}
    print(f"{args.dataset.name}: true mass {total:.1f}; in voxels the truth leaves empty: "
          + ", ".join(f"{n} {g[~filled].sum() / total:.3f}" for n, g in learned.items()))
    for label, tau in binned.items():
        print(f"optical depth {label} | voxels | true | " + " | ".join(learned))
        for lo, hi in zip(EDGES, EDGES[1:]):
            m = (tau >= lo) & (tau < hi)
            if not m.any():
                continue
            cells = [f"[{lo:g}, {hi:g})", str(int(m.sum())), f"{true_values[m].sum() / total:.3f}"]
            for values in learned_values.values():
                mass = values[m].sum()
                cells.append(f"{mass / total:.3f} (x{mass / true_values[m].sum():.2f})")
            print(" | ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
