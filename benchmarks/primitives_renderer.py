"""Which renderer for the primitives method: Mitsuba's ``ellipsoids`` + ``volprim_rf_basic``, or the harness's walk
with each kernel's closed-form optical depth (:mod:`mitsnerf.render.primitives`)?

One set of kernels, two questions:

1. *Fidelity.* Does the renderer show the medium whose density the method reports (the kernels' sum, what the
   density scores and ``mitsnerf export`` read)? Both render the same kernels (each with one colour, its SH
   band 0, and the density of the trained run), black background, against the emission-absorption integral of
   that medium by the shared quadrature (:func:`mitsnerf.render.volume.render_rays`, ``--reference-samples``
   midpoints per ray). Mitsuba's integrator blends each kernel once, at the ellipsoid's entry point in the
   order the rays meet the shells, with the alpha ``min(opacity exp(-m*^2 / 2), 0.9999)`` of 3D Gaussian ray
   tracing; the opacity given to kernel k is the alpha of its chord through the centre along its mean scale,
   ``1 - exp(-sigma_k sqrt(2 pi) s_mean)``, the closest a per-kernel number comes to a density.
2. *Cost.* Seconds of one training step (primal and backward passes of a batch of rays, gradients to every
   kernel parameter), side by side in one process.

    PYTHONPATH=. python benchmarks/primitives_renderer.py RUN [--rays 4096] [--views 2]

``RUN``: a trained ``primitives`` run directory (``mitsnerf train DATA --method primitives --out RUN``).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np


def _kernels_grey(model):
    """The run's kernels with their colour's SH band 0 only (a constant colour per kernel), as numpy arrays."""
    params = {k: np.asarray(v.numpy(), np.float64) for k, v in model.parameters().items()}
    params["sh"][:, 3:] = 0.0
    return params


def _walk(model, params, cells: int, grad: bool = False):
    """The run's kernels (``params``) as tensors (gradients on with ``grad``), their field config at ``cells`` cells per
    axis, and their cell lists."""
    import dataclasses

    import drjit as dr
    import mitsuba as mi

    from mitsnerf.fields.primitives import CellLists, Kernels

    config = dataclasses.replace(model.field_config, cells=cells)
    tensors = {k: mi.TensorXf(v.astype(np.float32)) for k, v in params.items()}
    if grad:
        dr.enable_grad(*tensors.values())
    with dr.suspend_grad():
        lists = CellLists.build(Kernels(config, tensors), model.scene.box, mi.UInt32)
    return tensors, config, lists


def _mitsuba_scene(model, params):
    """Mitsuba's ellipsoids (extent: the kernels' cutoff) with the opacities and band-0 colours of the kernels."""
    import mitsuba as mi

    from mitsnerf.fields.sh import sh_basis

    scale = np.exp(params["log_scale"])
    q = params["rotation"] / np.linalg.norm(params["rotation"], axis=1, keepdims=True)
    data = np.concatenate([params["mean"], scale, q], axis=1).astype(np.float32)
    sigma = np.exp(params["density"]).max(axis=1)
    opacity = 1.0 - np.exp(-sigma * math.sqrt(2.0 * math.pi) * np.exp(np.log(scale).mean(axis=1)))
    y0 = float(np.asarray(sh_basis(mi.Array3f(0, 0, 1), 0)[0])[0])
    colour = model.field_config.c_max / (1.0 + np.exp(-params["sh"][:, :3] * y0))
    sh = (colour - 0.5) / y0  # volprim_rf_basic emits max(sum_j sh_j Y_j + 0.5, 0)
    return mi.load_dict({"type": "scene",
                         "prims": {"type": "ellipsoids", "data": mi.TensorXf(data), "extent": model.field_config.cutoff,
                                   "opacities": mi.TensorXf(opacity.astype(np.float32)[:, None]),
                                   "sh_coeffs": mi.TensorXf(sh.astype(np.float32))}})


def _volprim(scene, o, d, max_depth: int):
    import drjit as dr
    import mitsuba as mi

    integrator = mi.load_dict({"type": "volprim_rf_basic", "max_depth": max_depth, "srgb_primitives": False})
    ray = mi.Ray3f(o, d)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, dr.width(o))

    def primal():
        with dr.suspend_grad():  # as Mitsuba's own render_backward calls it: the integrator resumes what it needs
            L, _, _, _ = integrator.sample(dr.ADMode.Primal, scene, sampler, ray, None, None, mi.Bool(True))
        return L

    def backward(L, grad):
        with dr.suspend_grad():
            integrator.sample(dr.ADMode.Backward, scene, sampler, ray, grad, L, mi.Bool(True))
        dr.eval()

    return primal, backward


def _rays(dataset, views: int):
    """Every pixel ray of the first ``views`` test views that crosses the box (Array3f, numpy mask of pixels)."""
    import mitsuba as mi

    from mitsnerf.math.rays import camera_rays_numpy, to_array3f

    cams = dataset.views("test").cameras[:views]
    o, d = camera_rays_numpy(cams, dataset.views("test").pixel_center)
    _, _, hit = dataset.box.intersect_numpy(o, d)
    return to_array3f(mi.Array3f, o[hit]), to_array3f(mi.Array3f, d[hit]), int(hit.sum())


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.clip(a, 0, 1) - np.clip(b, 0, 1)) ** 2))
    return 10.0 * math.log10(1.0 / max(mse, 1e-20))


def _np(v) -> np.ndarray:
    return np.stack([np.asarray(c, np.float64) for c in v], -1)


def fidelity(model, dataset, params, views: int, reference_samples: int, cells: int, max_depth: int) -> dict:
    """PSNR of each renderer against the emission-absorption integral of the kernels' medium, on every ray of the
    first ``views`` test views that crosses the box, and on those of opacity > 0.5 (the dense part)."""
    import drjit as dr

    from mitsnerf.fields.primitives import Kernels, PrimitiveField
    from mitsnerf.render.primitives import render_primitives
    from mitsnerf.render.volume import render_rays

    o, d, n = _rays(dataset, views)
    tensors, config, lists = _walk(model, params, cells)
    box = model.scene.box
    with dr.suspend_grad():
        kernels = Kernels(config, tensors)
        ref = render_rays(PrimitiveField(kernels, box, lists), o, d, reference_samples, box=box, quadrature="midpoint")
        ref_rgb, dense = _np(ref.rgb), np.asarray(ref.opacity) > 0.5
        ours = render_primitives(kernels, lists, o, d, box=box, min_transmittance=0.0)
        primal, _ = _volprim(_mitsuba_scene(model, params), o, d, max_depth)
        got = {"harness walk": _np(ours.rgb), "volprim_rf_basic": _np(primal())}
    out: dict = {"rays": n, "dense_rays": int(dense.sum())}
    for name, rgb in got.items():
        out[name] = {"psnr": _psnr(rgb, ref_rgb), "psnr_dense": _psnr(rgb[dense], ref_rgb[dense]),
                     "max_abs": float(np.abs(rgb - ref_rgb).max())}
    return out


def _timed(work, *args) -> float:
    import drjit as dr

    start = time.perf_counter()
    work(*args)
    dr.sync_thread()
    return time.perf_counter() - start


def cost(model, dataset, params, rays: int, cells: int, max_depth: int, repeats: int) -> dict:
    """Seconds of a training step's rendering (primal and backward, gradients to every kernel parameter) of
    ``rays`` random training rays, for each renderer the median of ``repeats`` steps alternating between the two
    (after one untimed warm-up each)."""
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.fields.primitives import Kernels
    from mitsnerf.render.primitives import render_primitives
    from mitsnerf.train import PixelData

    views = dataset.views("train")
    data = PixelData.from_views(views.images, views.cameras, views.pixel_center)
    tensors, config, lists = _walk(model, params, cells, grad=True)
    scene = _mitsuba_scene(model, params)
    scene_params = mi.traverse(scene)
    keys = ["prims.data", "prims.opacities", "prims.sh_coeffs"]
    dr.enable_grad(*(scene_params[key] for key in keys))
    scene_params.update()
    def walk_step(o, d, target):
        out = render_primitives(Kernels(config, tensors), lists, o, d, box=model.scene.box, min_transmittance=1e-4)
        dr.backward(dr.mean(dr.square(out.rgb - target), axis=None))
        dr.eval([dr.grad(t) for t in tensors.values()])

    def volprim_step(o, d, target):
        primal, backward = _volprim(scene, o, d, max_depth)
        L = primal()
        backward(L, dr.detach(2.0 * (L - target) / (3.0 * rays)))
        dr.eval([dr.grad(scene_params[key]) for key in keys])

    times: dict[str, list[float]] = {"harness walk": [], "volprim_rf_basic": []}
    for k in range(repeats + 1):
        batch = data.batch(dr.rng(seed=k), rays, True)
        for name, work in (("harness walk", walk_step), ("volprim_rf_basic", volprim_step)):
            seconds = _timed(work, *batch)
            if k:
                times[name].append(seconds)
        for t in (*tensors.values(), *(scene_params[key] for key in keys)):
            dr.clear_grad(t)
    return {name: float(np.median(t)) for name, t in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a trained primitives run directory")
    parser.add_argument("--views", type=int, default=2, help="test views whose rays the fidelity is measured on")
    parser.add_argument("--reference-samples", type=int, default=2048, help="midpoints per ray of the reference")
    parser.add_argument("--rays", type=int, default=4096, help="rays of the timed training batch")
    parser.add_argument("--repeats", type=int, default=3, help="timed steps per renderer (the median is given)")
    parser.add_argument("--cells", type=int, default=0, help="cells per axis of the walk (0: the run's)")
    parser.add_argument("--max-depth", type=int, default=100000, help="volprim_rf_basic's largest number of hits")
    args = parser.parse_args()
    from mitsnerf.env import set_variant

    set_variant("llvm_ad_rgb")
    from mitsnerf.runs.fit import load_run

    model, dataset, _ = load_run(args.run)
    params = _kernels_grey(model)
    cells = args.cells or model.field_config.cells
    print(f"{len(params['mean'])} kernels, walk of {cells}^3 cells, volprim_rf_basic max_depth {args.max_depth}")
    print("fidelity:", fidelity(model, dataset, params, args.views, args.reference_samples, cells, args.max_depth))
    print("seconds per step:", cost(model, dataset, params, args.rays, cells, args.max_depth, args.repeats))


if __name__ == "__main__":
    main()
