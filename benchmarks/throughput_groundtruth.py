#!/usr/bin/env python3
"""Ground-truth rendering throughput: mitsnerf's dataset generator against raw Mitsuba, same scene.

The harness path is ``mitsnerf.generate.generate_dataset`` (volume synthesis, scene
load, one ``mi.render`` per view, EXR + PNG writing, hashing, manifest). The raw path is what a
Mitsuba user would write by hand for the same scene: a ``mi.load_dict`` of a cube with a
heterogeneous medium whose grids are the dataset's own ``volume/*.vol`` files, the same emitters,
one ``perspective`` sensor per view from ``transforms_train.json`` and the same sampler seeds, so
both paths must render identical images (checked). Samples are camera samples: W * H * spp per view;
the harness renders each view twice (the image, and the medium alone for ``medium/``), and its
end-to-end rate counts both.

Run (measure only on an otherwise idle machine):
    .venv/bin/python benchmarks/throughput_groundtruth.py [--scene cloud] [--views 4] [--size 64] [--spp 64]
Prints one JSON line per path and one with the harness's overhead.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env


def raw_scene_dict(spec_data: dict, dataset: Path) -> dict:
    """The scene as a Mitsuba user writes it, from plain spec data and the dataset's .vol files."""
    import mitsuba as mi

    # The grids' to_world in the form of the export's documentation, translate(lo).scale(hi - lo): the
    # shorter translate(-0.5) is the same matrix but evaluates sigma_t differently in the last bits
    # (4e-5 of 30 measured), enough for delta tracking to take other decisions and the images to differ
    # in their noise. accel=False as the harness's grids: on CUDA the default interpolates in reduced
    # precision in hardware (on the CPU it changes nothing).
    grid = lambda name: {"type": "gridvolume", "filename": str(dataset / "volume" / name),  # noqa: E731
                         "to_world": mi.ScalarTransform4f().translate([-0.5] * 3).scale([1.0] * 3), "accel": False}
    scene = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": int(spec_data["render"].get("max_depth", -1))},
        "box": {"type": "cube", "to_world": mi.ScalarTransform4f().scale(0.5), "bsdf": {"type": "null"},
                "interior": {"type": "heterogeneous", "scale": 1.0, "phase": {"type": "isotropic"},
                             "sigma_t": grid("sigma_t.vol"), "albedo": grid("albedo.vol")}},
    }
    rgb = lambda v: {"type": "rgb", "value": [float(c) for c in v]}  # noqa: E731
    for i, light in enumerate(spec_data["lights"]):
        kind = light["type"]
        if kind == "constant":
            scene[f"light{i}"] = {"type": "constant", "radiance": rgb(light["radiance"])}
        elif kind == "directional":
            scene[f"light{i}"] = {"type": "directional", "direction": list(light["direction"]),
                                  "irradiance": rgb(light["irradiance"])}
        elif kind == "point":
            scene[f"light{i}"] = {"type": "point", "position": list(light["position"]),
                                  "intensity": rgb(light["intensity"])}
        else:
            raise SystemExit(f"the raw path supports constant, directional and point lights, not {kind!r}")
    return scene


def raw_sensor(frame: dict, fov_x: float, width: int, height: int, spp: int) -> dict:
    import mitsuba as mi

    to_world = np.asarray(frame["transform_matrix"], dtype=np.float64) @ np.diag([-1.0, 1.0, -1.0, 1.0])
    return {"type": "perspective", "fov_axis": "x", "fov": fov_x, "to_world": mi.ScalarTransform4f(to_world),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                     "pixel_format": "rgba"}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cloud", help="a scene name (mitsnerf scenes lists them; constant, directional, point lights)")
    ap.add_argument("--views", type=int, default=4, help="views rendered by each path (the first one includes compilation)")
    ap.add_argument("--size", type=int, default=64, help="image width and height")
    ap.add_argument("--spp", type=int, default=64)
    args = ap.parse_args()

    import mitsuba as mi

    from mitsnerf.data.images import read_image
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import load_scene

    variant = env.set_variant()
    spec = load_scene(args.scene).with_overrides({
        "cameras.n_train": args.views, "cameras.n_test": 1, "cameras.width": args.size, "cameras.height": args.size,
        "render.spp_train": args.spp, "render.spp_test": 1, "render.noise_floor": False})
    samples_per_view = args.size * args.size * args.spp
    out = {"scene": args.scene, "views": args.views, "size": args.size, "spp": args.spp, "variant": variant}

    with tempfile.TemporaryDirectory(prefix="mitsnerf-gt-") as tmp:
        start = time.perf_counter()
        path = generate_dataset(spec, tmp, force=True, splits=("train",), progress=False)
        wall = time.perf_counter() - start
        timing = json.loads((path / "manifest.json").read_text())["timings"]["train"]
        steady = timing["seconds"] - timing["first_view_seconds"]
        # generate renders every split twice (the images, and the medium alone under medium/): end to end
        # counts both renders' samples; steady state is the image renders alone, as the raw path's
        harness = {"path": "mitsnerf", **out, "end_to_end_s": wall, "render_s": timing["seconds"],
                   "first_view_s": timing["first_view_seconds"],
                   "samples_per_s_end_to_end": 2 * samples_per_view * args.views / wall,
                   "samples_per_s_steady": samples_per_view * (args.views - 1) / steady if args.views > 1 else None}
        print(json.dumps(harness), flush=True)

        transforms = json.loads((path / "transforms_train.json").read_text())
        start = time.perf_counter()
        scene = mi.load_dict(raw_scene_dict(spec.to_dict(), path))
        load_s = time.perf_counter() - start
        times, max_diff = [], 0.0
        for i, frame in enumerate(transforms["frames"]):
            sensor = mi.load_dict(raw_sensor(frame, float(np.degrees(transforms["camera_angle_x"])), args.size, args.size, args.spp))
            t0 = time.perf_counter()
            img = np.array(mi.render(scene, sensor=sensor, spp=args.spp, seed=transforms["render_seeds"][i]), dtype=np.float32)
            times.append(time.perf_counter() - t0)
            ref = read_image(path / "train" / f"r_{i:03d}.exr")
            max_diff = max(max_diff, float(np.max(np.abs(img - ref))))
        wall_raw = load_s + sum(times)
        raw = {"path": "raw-mitsuba", **out, "scene_load_s": load_s, "render_s": sum(times), "first_view_s": times[0],
               "samples_per_s_end_to_end": samples_per_view * args.views / wall_raw,
               "samples_per_s_steady": samples_per_view * (args.views - 1) / sum(times[1:]) if args.views > 1 else None,
               "max_abs_diff_vs_harness": max_diff}
        print(json.dumps(raw), flush=True)
    summary = {"overhead_end_to_end": raw["samples_per_s_end_to_end"] / harness["samples_per_s_end_to_end"] - 1.0,
               "overhead_steady": (raw["samples_per_s_steady"] / harness["samples_per_s_steady"] - 1.0)
               if args.views > 1 else None,
               "identical_images": max_diff == 0.0,
               "note": "end to end counts the harness's two renders per view (image, medium alone) at one "
                       "rate; the raw path renders the image only"}
    print(json.dumps(summary), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
