#!/usr/bin/env python3
"""What the alpha of a chromatic medium's ``medium/`` renders estimates: measured against the exact transmittances.

For a grey medium volpath's medium-alone alpha is an unbiased estimate of ``1 - mean T`` (the dataset's
``medium.transmittance_check``). In a chromatic one (a 3-channel ``sigma_t``) each path follows one colour
channel, but Mitsuba 3.9 draws a real collision with probabilities that mix the channels by the path's
throughput (``Medium::get_interaction_probabilities``), so alpha is not the collision probability of any
single channel. This script reads a generated dataset's ``medium/`` alphas and its true ``sigma_t`` and prints,
per split, the mean alpha against the mean ``1 - T`` of each channel, of the channels' mean ``T``, and of the
channels' mean extinction, each with the z of the difference (binomial standard error of the mean alpha,
``sqrt(sum p (1 - p) / spp) / pixels``). A grey rule the data agreed with would have |z| < 3.

Since dataset format 7 a chromatic medium's ``medium/`` alpha is the mean of three grey renders' alphas, one per
colour channel: ``check_mean_of_three`` is the manifest's ``transmittance_check`` of it with the package as it is
now (``mitsnerf.scoring.agreement.transmittance_agreement`` against each channel's ``1 - T_k``, the variance of a
mean of three binomials); a format-6 dataset's alpha fails it.

    .venv/bin/python -m mitsnerf generate smoke --out data        # or any spec with sigma_t_scale = [r, g, b]
    .venv/bin/python benchmarks/chromatic_alpha.py data/smoke-<hash> [--splits test test_ref]

One JSON line per split. Figures: docs/notes/chromatic.md, "Chromatic extinction: the smoke".
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np


def _alphas(root: Path, split: str) -> np.ndarray:
    from mitsnerf.data.images import read_exr

    return np.stack([read_exr(p)[..., 3] for p in sorted((root / "medium" / split).glob("r_*.exr"))])


def measure(root: Path, split: str) -> dict:
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.scene.render import footprint_for
    from mitsnerf.scene.transmittance import pixel_transmittance
    from mitsnerf.scoring.agreement import transmittance_agreement
    from mitsnerf.scoring.density import true_density

    dataset = load_dataset(root)
    spp = int(dataset.manifest["render"]["spp"][split])
    sigma_t = np.load(root / "volume" / "sigma_t.npy")
    if sigma_t.ndim != 4:
        raise SystemExit(f"{root}: sigma_t is grey (shape {sigma_t.shape}): nothing chromatic to measure")
    cams = dataset.views(split).cameras
    r, k = sigma_t.shape[0], footprint_for(spp)

    def one_minus_t(grid: np.ndarray, channels: int = 1) -> np.ndarray:
        density = true_density(np.ascontiguousarray(grid), dataset.box)
        return 1.0 - pixel_transmittance(density, r, dataset.box, cams, footprint=k, channels=channels).t

    alpha = _alphas(root, split)
    per_channel = pixel_transmittance(true_density(sigma_t, dataset.box), r, dataset.box, cams, footprint=k,
                                      channels=3).t_rgb
    check = transmittance_agreement(alpha, per_channel, spp)
    rules = {"red": one_minus_t(sigma_t[..., 0]), "green": one_minus_t(sigma_t[..., 1]),
             "blue": one_minus_t(sigma_t[..., 2]), "mean of the channels' T": one_minus_t(sigma_t, 3),
             "T of the mean extinction": one_minus_t(sigma_t.mean(-1))}
    out: dict = {"dataset": root.name, "format": dataset.manifest.get("format_version"), "split": split, "spp": spp,
                 "pixels": int(alpha.size), "mean_alpha": float(alpha.mean()),
                 "check_mean_of_three": {k: check[k] for k in ("passed", "max_abs_z", "max_ratio_z", "critical_z")}}
    for name, p in rules.items():
        se = math.sqrt(float(np.sum(p * (1.0 - p))) / spp) / alpha.size
        out[name] = {"mean_1_minus_T": float(p.mean()), "z": float((alpha.mean() - p.mean()) / se)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--splits", nargs="+", default=["test", "test_ref"])
    args = parser.parse_args()
    import mitsnerf  # noqa: F401  (LLVM set up before drjit loads)
    from mitsnerf.env import set_variant

    set_variant("llvm_ad_rgb")
    for split in args.splits:
        print(json.dumps(measure(args.dataset, split)), flush=True)


if __name__ == "__main__":
    main()
