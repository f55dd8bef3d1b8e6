"""nerfstudio's camera rays for a mitsnerf dataset against mitsnerf's own, pixel by pixel.

nerfstudio (installed by ``setup_nerfstudio.sh`` in a venv outside the project) reads the
dataset's ``medium/`` folder unchanged through its blender (NeRF-synthetic) dataparser; this script
takes the rays it casts, both ways it casts them:

- *training*: ``RayGenerator`` (the data manager's path) for every ``(camera, row, col)``;
- *rendering*: ``Cameras.generate_rays(camera_indices=i, keep_shape=True)`` (``ns-render``'s path);

and compares their origins and directions with mitsnerf's for the same pixels
(``mitsnerf.math.rays.camera_rays_numpy`` and the Dr.Jit ``PixelRays`` at the pixel's sample point,
from ``mitsnerf.data.load_dataset`` of the same folder, whose transforms say ``pixel_center: 0.5``).
As a control, mitsnerf's rays through the integer pixel corners (``pixel_center`` 0, the original
NeRF loader's rule) are compared too: a reader with that rule would differ by about half a pixel.

The nerfstudio half runs in its own interpreter (``--python``; this file is run there with
``--dump``, importing only nerfstudio and numpy), the comparison in mitsnerf's::

    .venv/bin/python benchmarks/external/nerfstudio_rays.py DATASET --python VENV/bin/python

Prints one JSON line per (split, path) and a Markdown table. Every pixel of every view is compared.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

SPLITS = ("train", "test")


def dump_nerfstudio(medium: Path, out: Path) -> None:
    """(In nerfstudio's venv.) Every pixel's ray of each split, both of nerfstudio's paths, to ``out`` (npz)."""
    import importlib.metadata

    import torch
    from nerfstudio.data.dataparsers.blender_dataparser import BlenderDataParserConfig
    from nerfstudio.model_components.ray_generators import RayGenerator

    parser = BlenderDataParserConfig(data=medium).setup()
    arrays: dict[str, np.ndarray] = {}
    for split in SPLITS:
        cams = parser.get_dataparser_outputs(split=split).cameras
        n, h, w = cams.shape[0], int(cams.height[0]), int(cams.width[0])
        c, y, x = torch.meshgrid(torch.arange(n), torch.arange(h), torch.arange(w), indexing="ij")
        with torch.no_grad():
            gen = RayGenerator(cams)(torch.stack([c.ravel(), y.ravel(), x.ravel()], dim=-1))
            img = [cams.generate_rays(camera_indices=i, keep_shape=True) for i in range(n)]
        arrays[f"{split}_train_o"] = gen.origins.numpy()
        arrays[f"{split}_train_d"] = gen.directions.numpy()
        arrays[f"{split}_render_o"] = torch.stack([r.origins for r in img]).reshape(-1, 3).numpy()
        arrays[f"{split}_render_d"] = torch.stack([r.directions for r in img]).reshape(-1, 3).numpy()
        arrays[f"{split}_intrinsics"] = torch.stack([cams.fx[:, 0], cams.fy[:, 0], cams.cx[:, 0], cams.cy[:, 0]], -1).numpy()
    arrays["versions"] = np.array([importlib.metadata.version(p) for p in ("nerfstudio", "torch")])
    np.savez(out, **arrays)


def run_nerfstudio(python: str, medium: Path) -> dict[str, np.ndarray]:
    """Run :func:`dump_nerfstudio` under ``python`` and load what it wrote."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rays.npz"
        subprocess.run([python, __file__, str(medium), "--dump", str(out)], check=True,
                       stdout=subprocess.DEVNULL)
        with np.load(out) as data:
            return {k: data[k] for k in data.files}


def mitsnerf_rays(medium: Path, split: str, pixel_center: float | None = None) -> dict[str, np.ndarray]:
    """mitsnerf's rays of every pixel of ``split`` (numpy and Dr.Jit paths), flat view-major, float32."""
    import drjit as dr

    from mitsnerf import env
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.math.rays import PixelRays, camera_rays_numpy

    env.set_variant()
    views = load_dataset(medium, pixel_center=pixel_center).views(split)
    o, d = camera_rays_numpy(views.cameras, views.pixel_center)
    from drjit.llvm import Float, UInt32

    pix = PixelRays(Float, views.cameras, views.pixel_center)
    half = Float(np.full(pix.size, 0.5, np.float32))
    jo, jd = pix.rays(UInt32(np.arange(pix.size, dtype=np.uint32)), half, half)
    dr.eval(jo, jd)
    intr = np.array([[c.fl_x, c.fl_y, c.cx, c.cy] for c in views.cameras])
    return {"o": o, "d": d, "jit_o": np.array(jo).T, "jit_d": np.array(jd).T, "intrinsics": intr,
            "pixel_center": views.pixel_center}


def differences(o: np.ndarray, d: np.ndarray, ref_o: np.ndarray, ref_d: np.ndarray) -> dict[str, float]:
    """Largest origin and direction differences (absolute, and in float32 ulps of the value), and the
    largest angle between the directions (float64 ``atan2(|a x b|, a . b)``: exact for tiny angles)."""
    eps = float(np.finfo(np.float32).eps)
    do, dd = np.abs(o - ref_o), np.abs(d - ref_d)
    a, b = d.astype(np.float64), ref_d.astype(np.float64)
    angle = np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))
    return {"rays": int(len(o)), "max_abs_origin": float(do.max()), "max_abs_direction": float(dd.max()),
            "max_origin_ulps": float((do / (eps * np.maximum(np.abs(ref_o), 1e-30))).max()),
            "max_angle_rad": float(angle.max()),
            "direction_norm_error": float(np.abs(np.linalg.norm(d, axis=-1) - 1).max())}


def compare(dataset: Path, python: str) -> list[dict]:
    """Every comparison of the module docstring, as JSON-ready rows."""
    medium = dataset / "medium" if (dataset / "medium").is_dir() else dataset
    ns = run_nerfstudio(python, medium)
    rows = []
    for split in SPLITS:
        ours, corners = mitsnerf_rays(medium, split), mitsnerf_rays(medium, split, pixel_center=0.0)
        intr = float(np.abs(ns[f"{split}_intrinsics"] - ours["intrinsics"]).max())
        for path in ("train", "render"):
            o, d = ns[f"{split}_{path}_o"], ns[f"{split}_{path}_d"]
            for against, ref_o, ref_d in (("camera_rays_numpy", ours["o"], ours["d"]),
                                          ("PixelRays (Dr.Jit)", ours["jit_o"], ours["jit_d"]),
                                          ("camera_rays_numpy, pixel_center 0", corners["o"], corners["d"])):
                rows.append({"split": split, "nerfstudio": path, "mitsnerf": against,
                             "max_abs_intrinsics": intr, **differences(o, d, ref_o, ref_d)})
                print(json.dumps(rows[-1]), flush=True)
    rows[0]["versions"] = [str(v) for v in ns["versions"]]
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| split | nerfstudio path | mitsnerf | rays | max abs origin | max abs direction | max angle (rad) |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['split']} | {r['nerfstudio']} | {r['mitsnerf']} | {r['rays']} | {r['max_abs_origin']:.2e} | "
                     f"{r['max_abs_direction']:.2e} | {r['max_angle_rad']:.2e} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset", type=Path, help="a mitsnerf dataset (its medium/ is read) or a NeRF-synthetic folder")
    ap.add_argument("--python", help="nerfstudio's venv interpreter (VENV/bin/python)")
    ap.add_argument("--dump", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.dump is not None:
        dump_nerfstudio(args.dataset, args.dump)
        return 0
    if not args.python:
        ap.error("--python: nerfstudio's interpreter is needed (benchmarks/external/setup_nerfstudio.sh makes one)")
    rows = compare(args.dataset, args.python)
    print(f"\nnerfstudio {rows[0]['versions'][0]}, torch {rows[0]['versions'][1]}\n")
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
