"""The bias of a gradient whose loss compares the image of its own paths: mitsuba-inverse's L2 step, correlated
against independent, measured.

For ``Loss = mean_p (I_p - I*_p)^2`` the gradient ``2 (I_p - I*_p) dI_p`` has the expectation
``2 (E[I_p] - I*_p) E[dI_p]`` only when ``I_p`` and ``dI_p`` come from independent paths; from the same paths it
adds ``2 Cov(I_p, dI_p)``, which does not shrink with more steps. At the true medium (``--scale 1``) the exact
gradient is nearly 0 (the targets' own noise aside), so the bias is all that is left there: a fit started at the
truth is pushed away from it.

On a fixed batch of training pixels and the true medium scaled by each ``--scale``, it averages over ``--seeds``
seeds the derivative of the loss along the medium's own scale, ``dL/ds = sum_voxels g tau`` (``tau -> s tau`` at
``s = 1``: > 0 says "less medium"), for each setting:

- ``correlated``: the primal is the gradient's own paths (``seed_grad = seed``, ``spp_grad = spp``);
- ``independent xK``: the primal from ``K x spp`` other paths (mitsuba-inverse's ``spp_primal_factor = K``);

and prints its mean with the standard error of the mean (from the seeds' spread).

    .venv/bin/python benchmarks/inverse_primal_bias.py --dataset DATA/cloud-32eb7c2db154 --spp 1 4 --scale 1 0.8
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


def summary(name: str, values: np.ndarray) -> str:
    """``name``, the mean of ``values`` (one per seed) and its standard error."""
    se = values.std(ddof=1) / np.sqrt(len(values))
    return f"{name:<24} {values.mean():+11.4e} +- {se:9.2e}   ({values.mean() / se:+6.1f} se)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True, help="a mitsnerf dataset (its spec gives the scene)")
    parser.add_argument("--spp", nargs="+", type=int, default=[1, 4], help="the gradient's paths per pixel")
    parser.add_argument("--factor", nargs="+", type=int, default=[1, 4], help="independent primals' multiples")
    parser.add_argument("--pixels", type=int, default=2048)
    parser.add_argument("--seeds", type=int, default=48)
    parser.add_argument("--scale", nargs="+", type=float, default=[1.0, 0.8], help="the medium: the truth times this")
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
    truth = mi.TensorXf(model.sigma_t)
    data = PixelData.from_views(views.images, views.cameras)
    index = dr.minimum(mi.UInt32(dr.rng(seed=1).random(mi.Float, args.pixels) * data.size), data.size - 1)
    batch = PathBatch(model.scene, model.scene.integrator(), index, data.pixels.rays)
    target = dr.gather(mi.Array3f, data.rgb, index)
    print(f"{dataset.root.name}: {args.pixels} pixels at {args.resolution}^3, {args.seeds} seeds per setting; "
          "dL/ds: the loss's derivative along the medium's scale (> 0: less medium)")
    for scale in args.scale:
        model.set_parameters({"sigma_t": truth * scale})
        tau = np.asarray(model.sigma_t, np.float64).ravel()
        for spp in args.spp:
            print(f"the truth x {scale}, spp {spp}: {'setting':<13} {'dL/ds':>11}")
            settings = [("correlated", 1, True)] + [(f"independent x{k}", k, False) for k in args.factor]
            for name, k, corr in settings:
                values = np.array([gradient(model, batch, target, spp, k, 2 * s, corr) @ tau
                                   for s in range(args.seeds)])
                print(summary(f"  {name}", values))


if __name__ == "__main__":
    main()
