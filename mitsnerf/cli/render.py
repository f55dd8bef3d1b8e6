"""``mitsnerf render``."""

from __future__ import annotations

from pathlib import Path

from mitsnerf.cli.common import NO_PROGRESS_HELP, check_numbers


def run(args) -> int:
    from mitsnerf.errors import UsageError
    from mitsnerf.outputs import check_output_dir
    from mitsnerf.runs.novel import ViewRequest, render_run

    if args.size and len(args.size) > 2:
        raise UsageError("--size", f"give W or W H, got {len(args.size)} numbers")
    check_numbers([("--size", args.size, lambda v: v >= 1, "whole numbers >= 1"),
                    ("--fov", args.fov, lambda v: 0 < v < 180, "in (0, 180) degrees"),
                    ("--orbit", args.orbit, lambda v: v >= 0, ">= 0"),
                    ("--index", args.index, lambda v: v >= 0, ">= 0"),
                    ("--radius", args.radius, lambda v: v > 0, "> 0"),
                    ("--elevation", args.elevation, lambda v: -90 <= v <= 90, "in [-90, 90] degrees"),
                    ("--fps", args.fps, lambda v: v > 0, "> 0"),
                    ("--look-from", args.look_from, lambda v: True, "finite"),
                    ("--look-at", list(args.look_at), lambda v: True, "finite")])
    size = (args.size[0], args.size[-1]) if args.size else None
    request = ViewRequest(split=args.split, index=args.index,
                          look_from=tuple(args.look_from) if args.look_from else None,
                          look_at=tuple(args.look_at), fov=args.fov, size=size, orbit=args.orbit,
                          elevation=args.elevation, radius=args.radius, fps=args.fps)
    out = Path(args.out) if args.out else Path(args.run) / "renders"
    check_output_dir(out, "--out")
    files = render_run(Path(args.run), out, request, progress=not args.no_progress)
    print(f"{len(files)} files -> {out}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("render", help="render a trained run from any camera or an orbit, with depth and opacity maps",
                       description="Render RUN: a dataset view (--split/--index, default the first test view), "
                                   "every view of a split (--split without --index, named as its frames, r_000 ...: "
                                   "the folder scores as it is with mitsnerf score), a point (--look-from), or an "
                                   "orbit (--orbit N: frames, orbit.gif, and orbit.mp4 if imageio-ffmpeg is "
                                   "installed). Each view: STEM.exr/.png, depth/STEM.exr/.png, opacity/STEM.exr/.png; "
                                   "render.json lists every call into the folder.")
    p.add_argument("run", help="run directory (mitsnerf train --out)")
    p.add_argument("--out", help="output directory (default: RUN/renders)")
    p.add_argument("--split", help="dataset split to render, every view of it unless --index (default: the first "
                                   "test view); with --look-from or --orbit, the reference view's")
    p.add_argument("--index", type=int, help="view index in --split (default 0)")
    p.add_argument("--look-from", type=float, nargs=3, metavar=("X", "Y", "Z"), help="camera position, world units")
    p.add_argument("--look-at", type=float, nargs=3, metavar=("X", "Y", "Z"), default=(0.0, 0.0, 0.0),
                   help="point the camera looks at (default: the box centre)")
    p.add_argument("--fov", type=float, help="horizontal field of view, degrees (default: the reference view's)")
    p.add_argument("--size", type=int, nargs="+", metavar="N", help="image size W [H] (default: the reference view's)")
    p.add_argument("--orbit", type=int, default=0, metavar="N", help="render N cameras around the vertical axis")
    p.add_argument("--elevation", type=float, help="orbit elevation, degrees (default: the reference view's)")
    p.add_argument("--radius", type=float, help="orbit radius (default: the reference view's distance)")
    p.add_argument("--fps", type=float, default=12.0, help="orbit animation frame rate (default 12)")
    p.add_argument("--no-progress", action="store_true", help=NO_PROGRESS_HELP)
    p.set_defaults(func=run)
