"""``mitsnerf export``."""

from __future__ import annotations

import argparse
from pathlib import Path

from mitsnerf.cli.common import check_numbers


def run(args) -> int:
    from mitsnerf.outputs import check_output_dir
    from mitsnerf.runs.export import MAX_RESOLUTION, export_run

    check_numbers([("--resolution", args.resolution, lambda v: 1 <= v <= MAX_RESOLUTION,
                     f"in [1, {MAX_RESOLUTION}] (an R^3 grid: R = {MAX_RESOLUTION} already writes 32 GiB)"),
                    ("--directions", args.directions, lambda v: v >= 1, ">= 1"),
                    ("--direction", args.direction, lambda v: True, "finite")])
    if args.direction is not None and not any(args.direction):
        from mitsnerf.errors import UsageError

        raise UsageError("--direction", "must not be 0 0 0")
    out = Path(args.out) if args.out else Path(args.run) / "export"
    check_output_dir(out, "--out")
    paths = export_run(Path(args.run), out, args.resolution, args.direction, args.directions,
                       progress=not args.no_progress)
    print(f"{args.resolution}^3 medium -> {paths['sigma_t.vol'].parent} ({', '.join(paths)})")
    return 0


EXPORT_EPILOG = """\
Sampled at the voxel centres of an R^3 grid over the run's scene box (export.json: box_min,
box_max); colour averaged over --directions view directions spread over the sphere (default),
or seen along --direction. sigma_t transfers exactly; a NeRF's colour is radiance, not albedo,
so albedo.vol is only an approximation (for mitsuba-inverse it is the learned albedo itself).

Use it in Mitsuba (gridvolume maps [0, 1]^3 onto the box; here the unit box [-0.5, 0.5]^3 of a
default-scale dataset; for another box: translate(box_min).scale(box_max - box_min) for the grids,
translate(centre).scale(size / 2) for the cube):

  grid = lambda f: {"type": "gridvolume", "filename": "OUT/" + f, "accel": False,   # full precision on CUDA too
                    "to_world": mi.ScalarTransform4f().translate([-0.5] * 3).scale([1.0] * 3)}
  scene = mi.load_dict({"type": "scene", "integrator": {"type": "volpath"},
      "medium_box": {"type": "cube", "to_world": mi.ScalarTransform4f().scale(0.5),
          "bsdf": {"type": "null"},
          "interior": {"type": "heterogeneous", "scale": 1.0,
                       "sigma_t": grid("sigma_t.vol"), "albedo": grid("albedo.vol")}},
      "sky": {"type": "constant"}})
"""


def add_parser(sub) -> None:
    p = sub.add_parser("export", help="sample a run's learned field on a grid: Mitsuba .vol files + numpy arrays",
                       epilog=EXPORT_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="run directory (mitsnerf train --out)")
    p.add_argument("--out", help="output directory (default: RUN/export)")
    p.add_argument("--resolution", type=int, default=64, metavar="R", help="grid resolution R, 1..1024 (default 64)")
    p.add_argument("--direction", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="colour seen looking along this direction (default: averaged over directions)")
    p.add_argument("--directions", type=int, default=16, metavar="M",
                   help="number of view directions the colour is averaged over (default 16)")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=run)
