"""``mitsnerf score``."""

from __future__ import annotations

from pathlib import Path

from mitsnerf.cli.common import add_dataset_options, open_dataset, options_config


def run(args) -> int:
    from mitsnerf.bench.tables import QUALITY, ceiling_reason, markdown_table, scene_rows
    from mitsnerf.data.atomic import atomic_write_json
    from mitsnerf.outputs import check_output_dir, check_output_file, progress_log
    from mitsnerf.runs.directory import check_outside_dataset
    from mitsnerf.runs.external import renders_folder, score_renders
    from mitsnerf.train.evaluate import EvalConfig

    renders = renders_folder(Path(args.renders))  # a run's test/
    out = Path(args.out) if args.out else renders / "scores.json"
    check_output_file(out, "--out")
    check_outside_dataset(out, Path(args.dataset), what="a scores file", example="scores.json")
    if args.compute_oracle:  # the oracle is cached with the dataset
        check_output_dir(Path(args.dataset) / "oracle", "--compute-oracle")
    if args.footprint is not None:
        options_config(EvalConfig, {"footprint": args.footprint}, "score")
    dataset = open_dataset(args, args.dataset)
    result = score_renders(dataset, Path(args.renders), density=Path(args.density) if args.density else None,
                           name=args.name, fmt=args.format, footprint=args.footprint, exr_alpha=args.exr_alpha,
                           compute_oracle=args.compute_oracle, log=progress_log(not args.no_progress))
    record = result.record(dataset, renders)
    scene = (dataset.manifest or {}).get("name") or Path(dataset.root).resolve().name
    seed = result.run.seed if result.run is not None else 0
    row = scene_rows([{"scene": scene, "method": result.label, "seed": seed, "metrics": result.metrics}])
    atomic_write_json(out, record)
    print(markdown_table(row, QUALITY))
    reason = ceiling_reason(row[0])  # a run's row above its own ceiling says why, as the bench's tables do
    if reason is not None:
        print(reason)
    print(f"\n{len(result.files)} renders matched by {result.matched_by}; {result.oracle}; "
          f"density: {result.density or 'none given'} -> {out}")
    if result.metrics.get("noise_floor_of"):
        print(f"ref agreement: {result.metrics['noise_floor_of']}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("score", help="score any tool's renders of a dataset's test views, as a benchmark cell",
                       description="Score RENDERS (a folder of PNG or EXR images) against DATASET's test views: "
                                   "PSNR/SSIM linear and sRGB, medium PSNR, the noise floor, the oracle (when the "
                                   "dataset has one cached, DATASET/oracle/, or with --compute-oracle), and with "
                                   "--density the density errors. "
                                   "Images are matched to the test frames by file name (r_000.png ...) or, when no "
                                   "name is a frame's, by the frame number in each name; PNG alpha is composited "
                                   "over the dataset's background as straight alpha, EXR alpha as its header's "
                                   "mitsnerf:alpha says (--exr-alpha to say otherwise). A run directory (mitsnerf "
                                   "train --out, a benchmark cell's run) stands for its test/ renders and gives the "
                                   "run's own figures: its footprint, its method's name, what it was given, its rung "
                                   "and that rung's ceiling, and the density scores of its metrics.json (--footprint, "
                                   "--name, --density override them); a run trained on another dataset is refused. "
                                   "A folder mitsnerf render wrote is held at the footprint its render.json records.")
    p.add_argument("dataset", help="dataset directory (mitsnerf generate output, NeRF-synthetic or instant-ngp)")
    p.add_argument("renders", help="folder of the renders of the test views, or a run directory (its test/)")
    p.add_argument(
        "--density", metavar="GRID", help="sigma_t on a grid over the dataset's box: .npy [z, y, x] or Mitsuba .vol "
                                          "(default for a run: its own density scores)"
    )
    p.add_argument("--name", help="the row's name (default: the renders folder's name; a run's method)")
    p.add_argument("--format", choices=("png", "exr"), help="read only these images (needed when both are there)")
    p.add_argument("--exr-alpha", choices=("premultiplied", "straight", "ignore"),
                   help="how an RGBA EXR's alpha composites over the dataset's background (default: as the file's "
                        "mitsnerf:alpha header says; premultiplied, OpenEXR's rule; ignore: the RGB as it is)")
    p.add_argument("--out", help="JSON record to write (default: RENDERS/scores.json)")
    p.add_argument("--footprint", type=int, metavar="K",
                   help="the tool's rays per pixel side (default 1: one through each pixel centre; a run: the "
                        "footprint it rendered with; a folder mitsnerf render wrote: the one its render.json "
                        "records): which of the cached oracle's renders the renders are held "
                        "against")
    p.add_argument("--compute-oracle", action="store_true",
                   help="a dataset mitsnerf generated without an oracle at the renders' footprint (your own "
                        "volume's, say): compute it first, with the default settings, and cache it in DATASET/oracle/ "
                        "(what mitsnerf bench does for its scenes)")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr (--compute-oracle's)")
    add_dataset_options(p)
    p.set_defaults(func=run)
