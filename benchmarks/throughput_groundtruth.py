#!/usr/bin/env python3
"""Ground-truth throughput: mitsnerf's dataset generator against one raw Mitsuba pass of the same images.

The harness path is ``mitsnerf.generate.generate_dataset`` end to end (volume synthesis, scene load, one
volpath pass per view as the medium alone, the exact transmittance and the composition, EXR + PNG writing
of the images and of ``medium/``, the checks, hashing, manifest). The raw path is what a Mitsuba user
writes by hand for the same images: a ``mi.load_dict`` of a cube with a heterogeneous medium whose grids
are the dataset's own ``volume/*.vol`` files, the same emitters, and one ``mi.render`` of the full scene per
view of every split, with the sensors and sampler seeds of the ``transforms_*.json`` files. Under a
constant environment (or none) the two must give the same images (the composition is the direct render
sample for sample, up to the order of the float32 sums over a pixel's samples: ``max_rel_diff``, relative
to the pixel, grows with spp, 6.5e-7 at 64 spp and 4.9e-4 at 2048 on the cloud (2.9e-4
absolute, over ten times below a 2048-spp pixel's noise)); under a sky they differ by noise only.

Both paths run in this one process, twice each, as harness, raw, raw, harness (with ``--two-passes`` the
harness forced into two passes per split, the image and the medium alone rendered separately, format 5's
cost, runs in the middle), so that a load drifting during the run weighs on both alike; the figure is the
ratio of their summed wall times (``harness_over_raw``). (A bug planted in the transmittance against the
dataset's check: benchmarks/onepass_noise.py --plant.)

Run (measure only on an otherwise idle machine; compare figures of one run only):
    .venv/bin/python benchmarks/throughput_groundtruth.py [--scene cloud] [--train-views 8] [--test-views 2]
        [--size 64] [--spp-train 64] [--spp-test 2048] [--two-passes]
Prints one JSON line per path and a summary line.
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

SPLITS = ("train", "test", "test_ref")


def raw_scene_dict(spec_data: dict, dataset: Path) -> dict:
    """The scene as a Mitsuba user writes it, from plain spec data and the dataset's files."""
    import mitsuba as mi

    # The grids' to_world in the form of the export's documentation, translate(lo).scale(hi - lo): the
    # shorter translate(-0.5) is the same matrix but evaluates sigma_t differently in the last bits
    # (4e-5 of 30 measured), enough for delta tracking to take other decisions and the images to differ
    # in their noise. accel=False as the harness's grids: on CUDA the default interpolates in reduced
    # precision in hardware (on the CPU it changes nothing).
    grid = lambda name: {"type": "gridvolume", "filename": str(dataset / "volume" / name),  # noqa: E731
                         "to_world": mi.ScalarTransform4f().translate([-0.5] * 3).scale([1.0] * 3), "accel": False}
    phase = spec_data["volume"].get("phase", {"type": "isotropic"})
    scene = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": int(spec_data["render"].get("max_depth", -1))},
        "box": {"type": "cube", "to_world": mi.ScalarTransform4f().scale(0.5), "bsdf": {"type": "null"},
                "interior": {"type": "heterogeneous", "scale": 1.0, "phase": dict(phase),
                             "sigma_t": grid("sigma_t.vol"), "albedo": grid("albedo.vol")}},
    }
    rgb = lambda v: {"type": "rgb", "value": [float(c) for c in v]}  # noqa: E731
    manifest = json.loads((dataset / "manifest.json").read_text())
    for i, light in enumerate(spec_data["lights"]):
        kind = light["type"]
        if kind == "constant":
            scene[f"light{i}"] = {"type": "constant", "radiance": rgb(light["radiance"])}
        elif kind == "sky":
            bg = manifest["background"]
            scene[f"light{i}"] = {"type": "envmap", "filename": str(dataset / bg["file"]), "scale": bg["scale"],
                                  "to_world": mi.ScalarTransform4f(bg["to_world"])}
        elif kind == "directional":
            scene[f"light{i}"] = {"type": "directional", "direction": list(light["direction"]),
                                  "irradiance": rgb(light["irradiance"])}
        elif kind == "point":
            scene[f"light{i}"] = {"type": "point", "position": list(light["position"]),
                                  "intensity": rgb(light["intensity"])}
        else:
            raise SystemExit(f"the raw path supports constant, sky, directional and point lights, not {kind!r}")
    return scene


def raw_sensor(frame: dict, fov_x: float, width: int, height: int, spp: int) -> dict:
    import mitsuba as mi

    to_world = np.asarray(frame["transform_matrix"], dtype=np.float64) @ np.diag([-1.0, 1.0, -1.0, 1.0])
    return {"type": "perspective", "fov_axis": "x", "fov": fov_x, "to_world": mi.ScalarTransform4f(to_world),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                     "pixel_format": "rgba"}}


def harness(spec, out: Path, two_passes: bool = False) -> tuple[Path, dict]:
    """``generate_dataset`` end to end (two passes per split when asked, as the fallback renders them)."""
    from mitsnerf import generate
    from mitsnerf.scene import render

    real = render.one_pass_reason
    if two_passes:
        generate.one_pass_reason = lambda spec: "timed in two passes (throughput_groundtruth.py --two-passes)"
    try:
        start = time.perf_counter()
        path = generate.generate_dataset(spec, out, force=True, progress=False)
        wall = time.perf_counter() - start
    finally:
        generate.one_pass_reason = real
    m = json.loads((path / "manifest.json").read_text())
    t = m["timings"]
    render_s = sum(v["seconds"] for k, v in t.items() if isinstance(v, dict))
    return path, {"path": "mitsnerf" + (" (two passes)" if two_passes else ""), "wall_s": wall,
                  "render_s": render_s, "transmittance_s": sum(t[s].get("transmittance_seconds", 0) for s in SPLITS),
                  "other_s": wall - render_s - sum(t[s].get("transmittance_seconds", 0) for s in SPLITS),
                  "passes": m["render"]["passes"], "transmittance_check": m["medium"]["transmittance_check"]["passed"],
                  "noise_floor_psnr_medium": (m["noise_floor"] or {}).get("psnr_medium")}


def raw(spec, path: Path, size: int) -> dict:
    """One ``mi.render`` of the full scene per view of every split, the dataset's sensors and seeds."""
    import mitsuba as mi

    from mitsnerf.data.images import read_image

    start = time.perf_counter()
    scene = mi.load_dict(raw_scene_dict(spec.to_dict(), path))
    load_s = time.perf_counter() - start
    times, max_diff, max_rel = [], 0.0, 0.0
    for split in SPLITS:
        transforms = json.loads((path / f"transforms_{split}.json").read_text())
        spp = int(transforms["spp"])
        for i, frame in enumerate(transforms["frames"]):
            sensor = mi.load_dict(raw_sensor(frame, float(np.degrees(transforms["camera_angle_x"])), size, size, spp))
            t0 = time.perf_counter()
            img = np.array(mi.render(scene, sensor=sensor, spp=spp, seed=transforms["render_seeds"][i]),
                           dtype=np.float32)
            times.append(time.perf_counter() - t0)
            ref = read_image(path / split / f"r_{i:03d}.exr")[..., :3]
            diff = np.abs(img[..., :3] - ref)
            max_diff = max(max_diff, float(diff.max()))
            max_rel = max(max_rel, float((diff / np.maximum(np.abs(ref), 1e-2)).max()))
    return {"path": "raw-mitsuba", "wall_s": load_s + sum(times), "scene_load_s": load_s, "render_s": sum(times),
            "first_view_s": times[0], "max_abs_diff_vs_harness": max_diff, "max_rel_diff_vs_harness": max_rel}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cloud", help="a scene name (mitsnerf scenes lists them)")
    ap.add_argument("--train-views", type=int, default=8)
    ap.add_argument("--test-views", type=int, default=2, help="views of test and of test_ref each")
    ap.add_argument("--size", type=int, default=64, help="image width and height")
    ap.add_argument("--spp-train", type=int, default=None, help="default: the scene's")
    ap.add_argument("--spp-test", type=int, default=None, help="default: the scene's")
    ap.add_argument("--two-passes", action="store_true", help="also time the harness in two passes per split")
    args = ap.parse_args()

    from mitsnerf.scene.spec import load_scene

    variant = env.set_variant()
    base = load_scene(args.scene)
    spec = base.with_overrides({
        "cameras.n_train": args.train_views, "cameras.n_test": args.test_views, "cameras.width": args.size,
        "cameras.height": args.size, "render.spp_train": args.spp_train or base.render.spp_train,
        "render.spp_test": args.spp_test or base.render.spp_test, "render.noise_floor": True})
    shape = {"scene": args.scene, "train_views": args.train_views, "test_views": args.test_views, "size": args.size,
             "spp_train": spec.render.spp_train, "spp_test": spec.render.spp_test, "variant": variant}
    print(json.dumps(shape), flush=True)
    with tempfile.TemporaryDirectory(prefix="mitsnerf-gt-") as tmp:
        # harness, raw, [two passes,] raw, harness: a load that drifts during the run weighs on both paths alike
        path, first = harness(spec, Path(tmp) / "one")
        print(json.dumps(first), flush=True)
        raws = [raw(spec, path, args.size)]
        print(json.dumps(raws[0]), flush=True)
        two = harness(spec, Path(tmp) / "two", two_passes=True)[1] if args.two_passes else None
        if two is not None:
            print(json.dumps(two), flush=True)
        raws.append(raw(spec, path, args.size))
        print(json.dumps(raws[1]), flush=True)
        last = harness(spec, Path(tmp) / "again")[1]
        print(json.dumps(last), flush=True)
        raw_s = sum(r["wall_s"] for r in raws)
        raw_render_s = sum(r["render_s"] for r in raws)
        summary = {"harness_over_raw": (first["wall_s"] + last["wall_s"]) / raw_s,
                   "harness_over_raw_renders_only": (first["render_s"] + last["render_s"]) / raw_render_s,
                   "max_abs_diff_vs_harness": max(r["max_abs_diff_vs_harness"] for r in raws),
                   "max_rel_diff_vs_harness": max(r["max_rel_diff_vs_harness"] for r in raws)}
        if two is not None:
            summary["two_passes_over_raw"] = two["wall_s"] / (raw_s / 2)
            summary["one_pass_over_two_passes"] = (first["wall_s"] + last["wall_s"]) / 2 / two["wall_s"]
    print(json.dumps(summary), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
