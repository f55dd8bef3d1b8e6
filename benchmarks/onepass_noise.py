#!/usr/bin/env python3
"""The one-pass ground truth's two choices, measured: the composition's zero-mean term, and the footprint K.

1. **Noise** (``--noise``): the test views of each scene rendered twice as the medium alone (seeds of
   ``test`` and ``test_ref``), composed three ways, ``M + mean(T L) - beta (alpha - (1 - mean T))`` with
   ``beta`` = 0 (the exact background alone), the pixel's mean background ``B`` (what
   ``mitsnerf.scene.render.compose`` does; a direct render's noise), and ``mu``, the mean radiance of a
   collided sample estimated from both renders (the per-pixel optimum; biased as estimated here, shown
   only as the bound). Prints the medium noise floor (PSNR of test against test_ref on medium pixels) of
   each: the higher, the less noisy.
2. **Footprint** (``--footprint``): each pixel's mean transmittance at K x K = 8 x 8 and 16 x 16 against
   32 x 32, in units of the standard deviation of a pixel's alpha at the scene's test spp and at 2048 spp
   (``sqrt(p (1 - p) / spp)``, over pixels with ``p = 1 - mean T > 1e-6``): the largest and the rms.

3. **A planted bug** (``--plant BUG``): the scene generated at reduced views (``--train-views``, ``--views``
   test views) with ``BUG`` planted in :mod:`mitsnerf.scene.transmittance` (``footprint``: one ray through
   the pixel centre instead of K x K; ``pixel_centre``: the centre at the pixel's corner), and the dataset's
   ``medium.transmittance_check`` printed: it must fail.

Run (figures in docs/notes/ground-truth.md, "One volpath pass per split"):
    .venv/bin/python benchmarks/onepass_noise.py --noise --spp 128 --views 2 cloud shell nebula lattice plume
    .venv/bin/python benchmarks/onepass_noise.py --footprint --views 3 cloud shell lattice plume nebula
    .venv/bin/python benchmarks/onepass_noise.py --plant footprint --views 2 --train-views 4 lattice cloud
One JSON line per scene.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env
from mitsnerf.scoring.density import true_density
from mitsnerf.scoring.images import noise_floor
from mitsnerf.scoring.medium import medium_masks


def _setup(name: str, views: int, spp: int | None):
    import mitsuba as mi

    from mitsnerf.render.background import make_background
    from mitsnerf.scene.render import write_volume
    from mitsnerf.scene.rigs import camera_rig
    from mitsnerf.scene.spec import load_scene
    from mitsnerf.scene.to_mitsuba import background_description, scene_box, scene_dict, volume_grids

    spec = load_scene(name)
    if spp:
        spec = spec.with_overrides({"render.spp_test": spp})
    sigma_t, albedo = volume_grids(spec)
    box = scene_box(spec)
    tmp = Path(tempfile.mkdtemp(prefix="onepass-"))
    write_volume(tmp, spec, sigma_t, albedo, box)
    background = make_background(background_description(spec), tmp) if spec.environment is not None else None
    cams = camera_rig(spec.cameras, "test")[:views]
    return spec, sigma_t, box, background, cams, lambda: mi.load_dict(scene_dict(spec, sigma_t, albedo))


def noise(name: str, views: int, spp: int, k: int) -> dict:
    from mitsnerf.scene.render import render_split
    from mitsnerf.scene.transmittance import pixel_transmittance

    spec, sigma_t, box, background, cams, load = _setup(name, views, spp)
    if background is None:
        return {"scene": name, "note": "no environment: the image is the medium render, nothing to choose"}
    seen = pixel_transmittance(true_density(sigma_t, box), sigma_t.shape[0], box, cams, footprint=k,
                               background=background)
    scene = load()
    med = [np.stack(render_split(scene, spec, s, cams, False, medium_alone=True)[0]) for s in ("test", "test_ref")]
    masks = medium_masks(sigma_t, box, cams)
    p = (1.0 - seen.t)[..., None]

    def floor(beta):
        a, b = (m[..., :3] + seen.through - beta * (m[..., 3:4] - p) for m in med)
        return round(noise_floor(a, b, masks)["psnr_medium"], 2)

    alpha_sum = med[0][..., 3:4] + med[1][..., 3:4]
    mu = np.where(alpha_sum > 0, (med[0][..., :3] + med[1][..., :3]) / np.maximum(alpha_sum, 1e-9), 0.0)
    sel = masks & (med[0][..., 3] > 0.05)
    ratio = float(np.mean(mu[sel].sum(-1) / np.maximum(seen.env[sel].sum(-1), 1e-9)))
    return {"scene": name, "spp": spp, "views": views, "floor_beta_0": floor(0.0), "floor_beta_B": floor(seen.env),
            "floor_beta_mu_bound": floor(mu), "mean_mu_over_B": round(ratio, 2)}


def footprint(name: str, views: int) -> dict:
    from mitsnerf.scene.transmittance import pixel_transmittance

    spec, sigma_t, box, _, cams, _ = _setup(name, views, None)
    fn = true_density(sigma_t, box)
    t = {k: pixel_transmittance(fn, sigma_t.shape[0], box, cams, footprint=k).t for k in (8, 16, 32)}
    p = 1.0 - t[32]
    hit = p > 1e-6
    out = {"scene": name, "views": views, "spp_test": spec.render.spp_test}
    for spp in sorted({spec.render.spp_test, 2048}):
        sd = np.sqrt(p * (1.0 - p) / spp)
        for k in (8, 16):
            e = np.abs(t[k] - t[32])[hit] / np.maximum(sd[hit], 1e-12)
            out[f"K{k}_at_{spp}spp_max_sd"] = round(float(e.max()), 3)
            out[f"K{k}_at_{spp}spp_rms_sd"] = round(float(np.sqrt(np.mean(e**2))), 4)
    return out


def plant(name: str, bug: str, train_views: int, views: int) -> dict:
    """Generate ``name`` (reduced views) with ``bug`` planted in mitsnerf.scene.transmittance; its check must fail."""
    from mitsnerf import generate
    from mitsnerf.scene import transmittance as tr
    from mitsnerf.scene.spec import load_scene

    spec = load_scene(name).with_overrides({"cameras.n_train": train_views, "cameras.n_test": views})
    forced = {"footprint": {"footprint": 1}, "pixel_centre": {"pixel_center": 0.0}}[bug]
    attr, wrap = "pixel_transmittance", lambda f: lambda *a, **k: f(*a, **{**k, **forced})
    real = getattr(tr, attr)
    setattr(tr, attr, wrap(real))
    try:
        with tempfile.TemporaryDirectory(prefix="onepass-bug-") as tmp:
            path = generate.generate_dataset(spec, tmp, force=True, progress=False)
            check = json.loads((path / "manifest.json").read_text())["medium"]["transmittance_check"]
    finally:
        setattr(tr, attr, real)
    return {"scene": name, "planted": bug, "transmittance_check": check["passed"],
            **{f"{s}_max_abs_z": round(v["max_abs_z"], 2) for s, v in check["splits"].items()},
            **{f"{s}_max_ratio_z": round(v["max_ratio_z"], 2) for s, v in check["splits"].items()},
            "critical_z": {s: round(v["critical_z"], 2) for s, v in check["splits"].items()}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--noise", action="store_true")
    ap.add_argument("--footprint", action="store_true")
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--spp", type=int, default=128, help="--noise: test spp")
    ap.add_argument("--k", type=int, default=8, help="--noise: footprint K")
    ap.add_argument("--plant", choices=("footprint", "pixel_centre"))
    ap.add_argument("--train-views", type=int, default=4, help="--plant: train views")
    args = ap.parse_args()
    env.set_variant()
    for name in args.scenes:
        if args.noise:
            print(json.dumps(noise(name, args.views, args.spp, args.k)), flush=True)
        if args.footprint:
            print(json.dumps(footprint(name, args.views)), flush=True)
        if args.plant:
            print(json.dumps(plant(name, args.plant, args.train_views, args.views)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
