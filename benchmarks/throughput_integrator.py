#!/usr/bin/env python3
"""Integrator throughput on a ground-truth grid: mitsnerf's emission-absorption renderer, samples/s.

The field is the scene's true ``sigma_t`` and albedo grids (``GridField``: trilinear lookups as
Mitsuba's ``gridvolume``), rendered with ``mitsnerf.render.volume.render_rays`` along every pixel
ray of the scene's test cameras, N stratified samples per ray. Four passes: forward only
(evaluation) through ``render_rays`` (the sampler's, the field's and the compositing's arrays of
R * N entries) and through ``march_rays`` (the same quadrature as one loop per ray,
``mitsnerf.render.march``), and forward + backward with respect to the ``sigma_t`` grid (what fitting
a voxel grid costs; the texture is rebuilt from the grid tensor each time, as in training) through
``render_rays`` (AD through its R x N arrays) and through ``render_rays_replay`` (one loop per ray, its
gradient replayed per ray, ``mitsnerf.render.replay``). Samples =
rays * N; the median of the repeats after one warm-up (compilation), the passes taking turns repeat by
repeat (on a shared machine a change of load then hits every pass alike, and their ratios hold). Scenes
with a sky render with a black background here (the envmap lookup is not what is measured).

Run (measure only on an otherwise idle machine):
    .venv/bin/python benchmarks/throughput_integrator.py [--scene cloud] [--size 64] [--views 8] [--samples 64 128 256]
Prints one JSON line per (pass, N).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env
from mitsnerf.math.box import UNIT_BOX


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cloud")
    ap.add_argument("--size", type=int, default=64, help="image width and height")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--samples", type=int, nargs="+", default=[64, 128, 256], help="samples per ray N")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    variant = env.set_variant()
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField
    from mitsnerf.math.rays import camera_rays
    from mitsnerf.render.background import make_background
    from mitsnerf.render.march import march_rays
    from mitsnerf.render.replay import render_rays_replay
    from mitsnerf.render.volume import render_rays
    from mitsnerf.scene.rigs import camera_rig
    from mitsnerf.scene.spec import load_scene
    from mitsnerf.scene.to_mitsuba import background_description, volume_grids

    spec = load_scene(args.scene).with_overrides({"cameras.n_test": args.views, "cameras.width": args.size,
                                                  "cameras.height": args.size})
    sigma_np, albedo_np = volume_grids(spec)
    desc = background_description(spec)
    background = make_background(desc, None) if desc["type"] == "constant" else None
    rays = camera_rays(mi.Array3f, camera_rig(spec.cameras, "test"))
    n_rays = rays.size

    field_np = GridField.from_arrays(sigma_np, UNIT_BOX, albedo_np)

    def forward(n: int) -> None:
        field = field_np
        with dr.suspend_grad():
            comp = render_rays(field, rays.o, rays.d, n, background=background, box=UNIT_BOX)
            dr.eval(comp.rgb, comp.opacity)
        dr.sync_thread()

    def march(n: int) -> None:
        comp = march_rays(field_np, rays.o, rays.d, n, background=background, box=UNIT_BOX)
        dr.eval(comp.rgb, comp.opacity)
        dr.sync_thread()

    sigma = mi.TensorXf(np.ascontiguousarray(sigma_np[..., None]))
    dr.enable_grad(sigma)

    def backward_with(render):
        def backward(n: int) -> None:
            field = GridField.from_arrays(sigma, UNIT_BOX, albedo_np)
            comp = render(field, rays.o, rays.d, n, background=background, box=UNIT_BOX)
            loss = dr.mean(dr.square(comp.rgb), axis=None)
            dr.backward(loss)
            grad = dr.grad(sigma)
            dr.eval(grad)
            dr.sync_thread()
            dr.clear_grad(sigma)

        return backward

    passes = (("forward", forward), ("forward (march)", march), ("forward+backward", backward_with(render_rays)),
              ("forward+backward (replay)", backward_with(render_rays_replay)))
    for n in args.samples:
        for _, fn in passes:
            fn(n)  # warm-up: compilation
        times: dict[str, list[float]] = {name: [] for name, _ in passes}
        for _ in range(args.repeats):  # the passes take turns, so that a change of load hits them alike
            for name, fn in passes:
                t0 = time.perf_counter()
                fn(n)
                times[name].append(time.perf_counter() - t0)
        for name, _ in passes:
            med = float(np.median(times[name]))
            print(json.dumps({"bench": "integrator", "pass": name, "scene": args.scene, "grid": sigma_np.shape[0],
                              "rays": n_rays, "samples_per_ray": n, "median_s": med,
                              "samples_per_s": n_rays * n / med, "rays_per_s": n_rays / med,
                              "threads": dr.thread_count(), "variant": variant}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
