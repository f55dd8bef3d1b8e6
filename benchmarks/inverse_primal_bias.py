"""The bias of a gradient whose loss compares the image of its own paths: mitsuba-inverse's L2 step, correlated
against independent, measured.

For ``Loss = mean_p (I_p - I*_p)^2`` the gradient ``2 (I_p - I*_p) dI_p`` has the expectation
``2 (E[I_p] - I*_p) E[dI_p]`` only when ``I_p`` and ``dI_p`` come from independent paths; from the same paths it
adds ``2 Cov(I_p, dI_p)``, which does not shrink with more steps. On a fixed batch of training pixels and a fixed
medium (the true one scaled by ``--scale``: a fit half way), this averages the extinction's gradient over
``--seeds`` seeds for each setting:

- ``correlated``: the primal is the gradient's own paths (``seed_grad = seed``, ``spp_grad = spp``);
- ``independent xK``: the primal from ``K x spp`` other paths (mitsuba-inverse's ``spp_primal_factor = K``);

against a reference: independent, at ``--reference-factor`` times the primal's paths. It prints each setting's
relative bias ``|mean g - g_ref| / |g_ref|`` with its standard error (from the seeds' spread), and the cosine
of its mean with the reference.

    .venv/bin/python benchmarks/inverse_primal_bias.py --dataset DATA/cloud-32eb7c2db154 --spp 1 4
"""

from __future__ import annotations

import argparse

import numpy as np


def gradient(model, batch, target, spp: int, factor: int, seed: int, correlated: bool) -> np.ndarray:
    """The extinction's gradient of the L2 loss over ``batch`` (one seed)."""
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.render.path_batch import render_pixels

    sigma = mi.TensorXf(model.sigma_t)
    dr.enable_grad(sigma)
    model.params[model._key_sigma] = sigma
    model.params.update()
    spp_primal, seed_grad = (spp, seed) if correlated else (spp * factor, seed + 1)
    image = render_pixels(batch, {"sigma_t": sigma}, spp=spp_primal, spp_grad=spp, seed=seed, seed_grad=seed_grad)
    dr.backward(dr.mean(dr.square(image - target), axis=None))
    return np.asarray(dr.grad(sigma), np.float64).ravel()


def summary(name: str, grads: np.ndarray, ref: np.ndarray) -> str:
    mean = grads.mean(axis=0)
    norm = np.linalg.norm(ref)
    bias = np.linalg.norm(mean - ref) / norm
    # standard error of the bias' norm: the seeds' spread of the mean, projected on its own direction
    se = np.sqrt(np.sum(grads.var(axis=0, ddof=1)) / len(grads)) / norm
    cos = float(mean @ ref / (np.linalg.norm(mean) * norm))
    return f"{name:<24} {bias:8.3f} +- {se:6.3f}   {cos:7.4f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True, help="a mitsnerf dataset (its spec gives the scene)")
    parser.add_argument("--spp", nargs="+", type=int, default=[1, 4], help="the gradient's paths per pixel")
    parser.add_argument("--factor", nargs="+", type=int, default=[1, 4], help="independent primals' multiples")
    parser.add_argument("--reference-factor", type=int, default=64)
    parser.add_argument("--pixels", type=int, default=2048)
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--scale", type=float, default=0.5, help="the medium: the truth times this")
    parser.add_argument("--resolution", type=int, default=32)
    args = parser.parse_args()

    import mitsnerf  # noqa: F401  (libLLVM before drjit)
    from mitsnerf import env

    env.set_variant()
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.methods.mitsuba_inverse import MitsubaInverseConfig, MitsubaInverseModel
    from mitsnerf.render.path_batch import PathBatch
    from mitsnerf.runs.fit import scene_info
    from mitsnerf.train.data import PixelData

    dataset = load_dataset(args.dataset)
    views = dataset.views("train")
    info = scene_info(dataset, views)
    config = MitsubaInverseConfig(resolutions=(args.resolution,), upsample_at=(), init_from=str(dataset.root))
    model = MitsubaInverseModel(config, info)
    model.set_parameters({"sigma_t": model.sigma_t * args.scale})
    data = PixelData.from_views(views.images, views.cameras)
    index = dr.minimum(mi.UInt32(dr.rng(seed=1).random(mi.Float, args.pixels) * data.size), data.size - 1)
    batch = PathBatch(model.scene, model.scene.integrator(), index, data.pixels.rays)
    target = dr.gather(mi.Array3f, data.rgb, index)
    print(f"{dataset.root.name}: {args.pixels} pixels, the truth x {args.scale} at {args.resolution}^3, "
          f"{args.seeds} seeds per setting")
    print(f"{'setting':<24} {'rel. bias':>8} {'+- se':>9}   {'cos':>7}")
    for spp in args.spp:
        ref = np.mean([gradient(model, batch, target, spp, args.reference_factor, 10_000 + 2 * s, False)
                       for s in range(args.seeds)], axis=0)
        print(f"spp {spp}, reference: independent x{args.reference_factor}")
        settings = [("correlated", 1, True)] + [(f"independent x{k}", k, False) for k in args.factor]
        for name, k, corr in settings:
            grads = np.array([gradient(model, batch, target, spp, k, 2 * s, corr) for s in range(args.seeds)])
            print(summary(f"  {name}", grads, ref))


if __name__ == "__main__":
    main()
