"""How much of an external tool's error is opacity in empty space: its RGBA renders against the dataset.

"Empty" pixels are those where the true medium's alpha (the dataset's ``medium/test`` EXRs, ``1 - T``
through the true ``sigma_t``) is below ``--empty``. Prints, as one JSON line: the fraction of the image
they are, the tool's alpha there (mean, 99th percentile, fraction above ``--visible``), and the share
of the tool's squared error (linear RGB clipped to [0, 1], composited as ``mitsnerf score`` does) that
falls on them::

    .venv/bin/python benchmarks/external/empty_space.py DATASET RENDERS
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("renders", help="the tool's RGBA renders of the test views (PNG or EXR, named as the frames)")
    ap.add_argument("--empty", type=float, default=1e-3, help="true alpha below this: an empty pixel")
    ap.add_argument("--visible", type=float, default=0.01, help="the tool's alpha above this: visible opacity")
    args = ap.parse_args()
    env.set_variant()
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.data.images import read_image
    from mitsnerf.runs.external import read_renders

    dataset = load_dataset(args.dataset)
    views = dataset.views("test")
    images, paths, _ = read_renders(dataset, Path(args.renders))
    alpha = np.stack([read_image(p)[..., 3] for p in paths])  # read_renders returns colour only
    true_alpha = load_dataset(Path(args.dataset) / "medium").views("test").alpha  # the medium alone: 1 - T
    empty = true_alpha < args.empty
    se = np.sum((np.clip(images, 0, 1) - np.clip(views.images[..., :3], 0, 1)) ** 2, axis=-1)
    print(json.dumps({"renders": str(args.renders), "empty_fraction": float(empty.mean()),
                      "alpha_mean_empty": float(alpha[empty].mean()),
                      "alpha_p99_empty": float(np.percentile(alpha[empty], 99)),
                      "visible_fraction_of_empty": float((alpha[empty] > args.visible).mean()),
                      "error_share_empty": float(se[empty].sum() / se.sum())}))


if __name__ == "__main__":
    main()
