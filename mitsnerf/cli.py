"""``mitsnerf``: the command line. Argument parsing only; each command calls into the package.

Errors the user can act on (bad spec, missing or corrupt data, an unusable output location, no LLVM,
NaN loss) print one line ``mitsnerf: error: FILE: FIELD: what`` and exit with status 2 (``--debug``
shows their traceback); anything else is a bug and keeps its traceback. SIGINT, SIGTERM and SIGHUP
stop a command: training saves a checkpoint and says how to continue; the exit status is 128 + the
signal's number (130, 143, 129).
"""

from __future__ import annotations

import argparse
import errno
import functools
import json
import os
import sys
from pathlib import Path


def _overrides(pairs: list[str] | None) -> dict:
    """``--set KEY=VALUE`` pairs as ``{dotted key: value}`` (values read by :func:`mitsnerf.config.parse_value`)."""
    from mitsnerf.config import parse_value
    from mitsnerf.errors import UsageError

    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise UsageError("--set", f"expected KEY=VALUE, got {pair!r}")
        out[key.strip()] = parse_value(value)
    return out


def _with_user_dirs(command):
    """``command`` with the ``--scenes DIR`` and ``--config DIR`` directories put before those of
    ``$MITSNERF_SCENES`` and ``$MITSNERF_BENCHMARKS`` while it runs (the package, and any worker
    process it starts, look names up there); the environment is restored afterwards."""

    @functools.wraps(command)
    def run(args) -> int:
        from mitsnerf.bench.config import BENCHMARKS_ENV
        from mitsnerf.errors import SpecError
        from mitsnerf.scene.spec import SCENES_ENV

        added = {SCENES_ENV: (getattr(args, "scenes", None), "--scenes"),
                 BENCHMARKS_ENV: (getattr(args, "config_dirs", None), "--config")}
        saved = {env_var: os.environ.get(env_var) for env_var in added}
        for env_var, (dirs, flag) in added.items():
            for d in dirs or ():
                if not Path(d).is_dir():
                    raise SpecError(d, None, f"no such directory (given to {flag})")
            if dirs:
                os.environ[env_var] = os.pathsep.join([*dirs, *filter(None, [saved[env_var]])])
        try:
            return command(args)
        finally:
            for env_var, value in saved.items():
                if value is None:
                    os.environ.pop(env_var, None)
                else:
                    os.environ[env_var] = value

    return run


def cmd_env(args) -> int:
    from mitsnerf import env

    print(json.dumps(env.provenance(), indent=2))
    return 0


@_with_user_dirs
def cmd_scenes(args) -> int:
    from mitsnerf.errors import SpecError
    from mitsnerf.scene.spec import list_scenes, load_scene

    status = 0
    for name in list_scenes():
        try:
            print(f"{name:16s} {load_scene(name).description}")
        except SpecError as exc:  # the others are still listed
            print(f"mitsnerf: error: {exc}", file=sys.stderr)
            status = 2
    return status


def _scene_overrides(args) -> dict:
    """``--nerf-synthetic`` (the box at [-1.5, 1.5]^3, cameras at radius 4), then the ``--set`` pairs over it."""
    from mitsnerf.scene.spec import nerf_synthetic_overrides

    return {**(nerf_synthetic_overrides() if args.nerf_synthetic else {}), **_overrides(args.set)}


def cmd_methods(args) -> int:
    from mitsnerf.config import doc_table
    from mitsnerf.errors import SpecError
    from mitsnerf.methods import METHODS

    if not args.name:
        for name, entry in METHODS.items():
            print(f"{name:16s} {entry.description}")
        return 0
    if args.name not in METHODS:
        raise SpecError(None, "NAME", f"unknown method {args.name!r} (known: {', '.join(METHODS)})")
    entry = METHODS[args.name]
    print(f"{entry.name}: {entry.description}\n\n{doc_table(entry.config_type, nested=True)}\n\n"
          f"Set with: mitsnerf train DATASET --method {entry.name} --set KEY=VALUE "
          "(or in a bench file's [[methods]] config table).")
    return 0


@_with_user_dirs
def cmd_generate(args) -> int:
    from mitsnerf.errors import UsageError
    from mitsnerf.generate import generate_all, generate_dataset
    from mitsnerf.outputs import check_output_dir
    from mitsnerf.scene.spec import load_scene

    if not args.all and not args.scene:
        raise UsageError("generate", "name a SCENE or pass --all")
    check_output_dir(Path(args.out), "--out")
    overrides = _scene_overrides(args)
    if args.all:
        for path in generate_all(Path(args.out), overrides=overrides, force=args.force,
                                 verify_hashes=not args.no_verify, progress=not args.no_progress):
            print(path)
        return 0
    spec = load_scene(args.scene)
    if overrides:
        spec = spec.with_overrides(overrides)
    print(generate_dataset(spec, Path(args.out), force=args.force, verify_hashes=not args.no_verify,
                           progress=not args.no_progress))
    return 0


DEFAULT_METHOD = "ngp"
"""What ``mitsnerf train DIR`` fits with no ``--method``: a few minutes on a 2-core CPU."""


def _train_values(args) -> dict:
    values = {"steps": args.steps, "seconds": args.seconds, "batch_rays": args.batch_rays, "seed": args.seed,
              "checkpoint_every": args.checkpoint_every}
    if args.no_pixel_jitter:
        values["pixel_jitter"] = False
    return {k: v for k, v in values.items() if v is not None}


def _options_config(cls, values: dict, command: str = "train"):
    """Config ``cls`` of the command-line values (``{field: value}``); a bad one is blamed on its flag
    (``--batch-rays``, ``--lr``, ``--footprint``), not on the config."""
    from mitsnerf.config import from_dict
    from mitsnerf.errors import SpecError, UsageError

    try:
        return from_dict(cls, values)
    except SpecError as exc:
        raise UsageError(f"--{exc.field.replace('_', '-')}" if exc.field else command, exc.message) from None


def _load(args, path):
    """The dataset at ``path`` with the command's load options, verified (``--no-verify``: no hashes);
    says which box it has and what the verification read."""
    import time

    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.data.verify import verify_dataset
    from mitsnerf.errors import UsageError
    from mitsnerf.math.box import Box

    _check_numbers([("--pixel-center", args.pixel_center, lambda v: 0 <= v < 1, "in [0, 1)"),
                    ("--background", args.background, lambda v: v >= 0, "finite and >= 0")])
    box = None
    if args.box:
        try:
            box = Box(tuple(args.box[:3]), tuple(args.box[3:]))
        except ValueError as exc:  # the box's own check, of the user's numbers
            raise UsageError("--box", str(exc).removeprefix("box: ")) from None
    dataset = load_dataset(Path(path), box=box, pixel_center=args.pixel_center, background=args.background)
    print(f"mitsnerf: scene box {dataset.box.to_list()} ({dataset.box_source})", flush=True)
    if not dataset.manifest:  # foreign data, whose own readers may use a fixed near/far
        print(f"mitsnerf: near/far: {_near_far(dataset)}", flush=True)
    v = verify_dataset(dataset, hashes=not args.no_verify)
    hashed = f"{v.hashed_files} files hashed ({v.hashed_bytes / 1e6:.1f} MB), " if v.hashed_files else ""
    print(f"mitsnerf: dataset verified: {hashed}{v.views} views checked in {v.seconds:.2f} s", flush=True)
    return dataset


def _near_far(dataset) -> str:
    """The near/far rule and the range it gives over the training views, in words."""
    from mitsnerf.data.box import NEAR_FAR_RULE, near_far_range

    views = dataset.views("train")
    n_lo, n_hi, f_lo, f_hi, misses, rays = near_far_range(dataset.box, views.cameras, views.pixel_center)
    missed = f"; {misses} of {rays} sampled rays miss the box" if misses else ""
    return (f"{NEAR_FAR_RULE}, no fixed near/far; over the train views t_n {n_lo:.3g}..{n_hi:.3g}, "
            f"t_f {f_lo:.3g}..{f_hi:.3g}{missed}")


def _fresh_settings(args) -> tuple[str, dict, object]:
    """``(method, method overrides, EvalConfig)`` of a new run, checked before anything runs."""
    from mitsnerf.config import apply_overrides, from_dict
    from mitsnerf.errors import UsageError
    from mitsnerf.evaluate import EvalConfig
    from mitsnerf.methods import METHODS

    if not args.dataset:
        raise UsageError("train", "name a DATASET directory (or pass --resume to continue the run in --out)")
    method = DEFAULT_METHOD if args.method is None else args.method
    if method not in METHODS:
        raise UsageError("--method", f"unknown method {method!r} (known: {', '.join(sorted(METHODS))})")
    overrides = apply_overrides({}, _overrides(args.set), "--set")
    if args.lr is not None:
        _options_config(METHODS[method].config_type, {"lr": args.lr})
        overrides["lr"] = args.lr
    from_dict(METHODS[method].config_type, overrides, source="--set")
    eval_config = _options_config(EvalConfig, {} if args.footprint is None else {"footprint": args.footprint})
    return method, overrides, eval_config


def _check_resume_flags(args) -> None:
    from mitsnerf.errors import UsageError

    fixed = [flag for flag, value in (("--method", args.method), ("--set", args.set), ("--batch-rays", args.batch_rays),
                                       ("--lr", args.lr), ("--seed", args.seed), ("--box", args.box),
                                       ("--footprint", args.footprint), ("--no-pixel-jitter", args.no_pixel_jitter),
                                       ("--deterministic", args.deterministic)) if value not in (None, False)]
    if args.force:
        raise UsageError("--force", "starts the run over; --resume continues it: pass one of them")
    if fixed:
        raise UsageError("train --resume", f"{', '.join(fixed)} come from the checkpoint; "
                                           "only --steps, --seconds and --checkpoint-every may change")


def _check_outside_dataset(out: Path, dataset: Path) -> None:
    """Refuse a run directory inside (or at) the dataset directory: its files would change a hashed dataset."""
    from mitsnerf.errors import UsageError

    ds = dataset.resolve()
    if out.resolve().is_relative_to(ds):
        raise UsageError("--out", f"{out} is inside the dataset {dataset}: a run there would change the dataset's "
                                  "files; put the run outside it, e.g. --out runs/NAME")


def cmd_train(args) -> int:
    from mitsnerf.run import fit, resume_run
    from mitsnerf.run_dir import claim_run_dir
    from mitsnerf.train import TrainConfig

    train_values = _train_values(args)
    train_config = _options_config(TrainConfig, train_values)  # every setting checked before anything runs
    if args.resume:
        _check_resume_flags(args)
    else:
        method, overrides, eval_config = _fresh_settings(args)
    out = Path(args.out)
    if args.dataset:
        _check_outside_dataset(out, Path(args.dataset))
    with claim_run_dir(out, resume=args.resume, force=args.force):
        if args.resume:
            run = resume_run(out, train_values, dataset=_load(args, args.dataset) if args.dataset else None,
                             verify_hashes=not args.no_verify, progress=not args.no_progress)
        else:
            dataset = _load(args, args.dataset)
            run = fit(dataset, method, overrides, train_config, out, eval_config=eval_config,
                      deterministic=args.deterministic, progress=not args.no_progress)
    m = run.metrics()
    medium = "" if m.get("psnr_test_medium") is None else f" ({m['psnr_test_medium']:.2f} dB on medium pixels)"
    rate = "no steps run" if m["rays_per_s"] is None else f"{m['rays_per_s']:.0f} rays/s"
    print(f"{run.method}: test PSNR {m['psnr_test']:.2f} dB{medium}, footprint {m['footprint']}x{m['footprint']}, "
          f"train PSNR {m['psnr_train']:.2f} dB, {m['steps']} steps in {m['train_seconds']:.1f} s, "
          f"{rate} -> {args.out}")
    return 0


def cmd_score(args) -> int:
    from mitsnerf.bench.tables import QUALITY, markdown_table, scene_rows
    from mitsnerf.data.atomic import atomic_write_json
    from mitsnerf.evaluate import EvalConfig
    from mitsnerf.external import renders_folder, score_renders
    from mitsnerf.outputs import check_output_file

    renders = renders_folder(Path(args.renders))
    out = Path(args.out) if args.out else renders / "scores.json"
    check_output_file(out, "--out")
    _options_config(EvalConfig, {"footprint": args.footprint}, "score")
    dataset = _load(args, args.dataset)
    result = score_renders(dataset, renders, density=Path(args.density) if args.density else None, name=args.name,
                           fmt=args.format, footprint=args.footprint, exr_alpha=args.exr_alpha)
    record = result.record(dataset, renders)
    scene = (dataset.manifest or {}).get("name") or Path(dataset.root).resolve().name
    row = scene_rows([{"scene": scene, "method": f"{result.name} (external)", "seed": 0, "metrics": result.metrics}])
    atomic_write_json(out, record)
    print(markdown_table(row, QUALITY))
    print(f"\n{len(result.files)} renders matched by {result.matched_by}; {result.oracle}; "
          f"density: {result.density or 'none given'} -> {out}")
    if result.metrics.get("noise_floor_of"):
        print(f"ref agreement: {result.metrics['noise_floor_of']}")
    return 0


def _check_numbers(checks) -> None:
    """A :class:`~mitsnerf.errors.UsageError` for the first ``(flag, values, ok, what)`` whose values
    (None: not given) are not all finite and ``ok``."""
    import math

    from mitsnerf.errors import UsageError

    for flag, values, ok, what in checks:
        if values is None:
            continue
        values = values if isinstance(values, (list, tuple)) else [values]
        if not all(math.isfinite(v) and ok(v) for v in values):
            shown = " ".join(f"{v:g}" for v in values)
            raise UsageError(flag, f"must be {what}, got {shown}")


def cmd_render(args) -> int:
    from mitsnerf.errors import UsageError
    from mitsnerf.novel import ViewRequest, render_run
    from mitsnerf.outputs import check_output_dir

    if args.size and len(args.size) > 2:
        raise UsageError("--size", f"give W or W H, got {len(args.size)} numbers")
    _check_numbers([("--size", args.size, lambda v: v >= 1, "whole numbers >= 1"),
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


def cmd_export(args) -> int:
    from mitsnerf.export import MAX_RESOLUTION, export_run
    from mitsnerf.outputs import check_output_dir

    _check_numbers([("--resolution", args.resolution, lambda v: 1 <= v <= MAX_RESOLUTION,
                     f"in [1, {MAX_RESOLUTION}] (an R^3 grid: R = {MAX_RESOLUTION} already writes 32 GiB)"),
                    ("--directions", args.directions, lambda v: v >= 1, ">= 1"),
                    ("--direction", args.direction, lambda v: True, "finite")])
    if args.direction is not None and not any(args.direction):
        from mitsnerf.errors import UsageError

        raise UsageError("--direction", "must not be 0 0 0")
    out = Path(args.out) if args.out else Path(args.run) / "export"
    check_output_dir(out, "--out")
    paths = export_run(Path(args.run), out, args.resolution, args.direction, args.directions)
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


@_with_user_dirs
def cmd_bench(args) -> int:
    from mitsnerf.bench.config import load_bench_config
    from mitsnerf.bench.runner import BenchOptions, default_data_root, run_benchmark
    from mitsnerf.errors import UsageError
    from mitsnerf.outputs import check_output_dir

    if args.deterministic and args.cpus_per_cell not in (0, 1):
        raise UsageError("--deterministic", f"runs each cell on one thread; --cpus-per-cell {args.cpus_per_cell} contradicts it")
    options = BenchOptions(
        quick=args.quick,
        data_root=Path(args.data) if args.data else default_data_root(),
        results_root=Path(args.results),
        progress=not args.no_progress,
        executor=args.executor,
        workers=args.workers,
        address=args.address,
        cpus_per_cell=1 if args.deterministic else args.cpus_per_cell,
        force=args.force,
        verify_hashes=not args.no_verify,
    )
    check_output_dir(options.results_root, "--results")
    check_output_dir(options.data_root, "--data" if args.data else "dataset cache ($MITSNERF_DATA or ./data)")
    config = load_bench_config(args.config)
    result = run_benchmark(config, options)
    print(result.markdown)
    print(f"\n{len(result.computed)} cells run, {len(result.skipped)} already done -> {result.out_root} "
          f"({', '.join(sorted(p for p in result.files if '/' not in p))})")
    if result.failed:
        print(f"mitsnerf: {len(result.failed)} cells failed: " + "; ".join(f"{f['key']}: {f['error']}" for f in result.failed),
              file=sys.stderr)
        return 1
    return 0


def cmd_check(args) -> int:
    from mitsnerf.outputs import check_output_dir
    from mitsnerf.verify.cases import QUALITIES
    from mitsnerf.verify.runner import count_line, format_mutations, format_table, run_checks, run_mutations

    if args.out:
        check_output_dir(Path(args.out), "--out")
    alpha = QUALITIES[args.quality].alpha
    if args.mutations:
        progress = None if args.no_progress else (
            lambda label, r: print(f"  {label}: {r.name}: {r.status} ({r.seconds:.1f} s)", file=sys.stderr, flush=True))
        report = run_mutations(args.quality, only=args.case, progress=progress)
        print(format_table(report.clean, alpha))
        print()
        print(format_mutations(report), flush=True)
        failed = [r.name for r in report.clean if r.passed is False]
        if failed:
            print(f"mitsnerf check: {len(failed)} case(s) failed without a mutation: {', '.join(failed)}", file=sys.stderr)
        if report.escaped:
            print(f"mitsnerf check: {len(report.escaped)} mutation(s) caught by no case: {', '.join(report.escaped)}",
                  file=sys.stderr)
        sys.stderr.flush()
        print(count_line(report.clean))  # last, alone on its line
        return 0 if report.passed else 1
    progress = None if args.no_progress else (
        lambda r: print(f"  {r.name}: {r.status} ({r.seconds:.1f} s)", file=sys.stderr, flush=True))
    results = run_checks(args.quality, out=args.out, only=args.case, progress=progress)
    print(format_table(results, alpha), flush=True)
    failed = [r.name for r in results if r.passed is False]
    if failed:
        print(f"mitsnerf check: {len(failed)} case(s) failed: {', '.join(failed)}", file=sys.stderr, flush=True)
    print(count_line(results))  # last, alone on its line
    return 1 if failed else 0


NO_PROGRESS_HELP = "no progress bars (they are off anyway when stderr is not a terminal)"

SCENES_HELP = ("a directory of your own scene specs (NAME.toml), searched before the library "
               "(repeatable; also $MITSNERF_SCENES)")


class _Parser(argparse.ArgumentParser):
    """argparse, with a mistake on the command line reported as every user error is: one line
    ``mitsnerf: error: ...`` (and where to find the usage), exit status 2."""

    def error(self, message: str):
        self.exit(2, f"mitsnerf: error: {self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="mitsnerf",
        description="Mitsuba 3 ground truth for participating media, Dr.Jit NeRFs fitted to it, and the benchmarks between them.",
    )
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of a user error too (bad input, data, output location)")
    parser.add_argument("--variant", help="Mitsuba variant (default: $MITSNERF_VARIANT, else cuda_ad_rgb if a GPU is usable, else llvm_ad_rgb)")
    sub = parser.add_subparsers(dest="command", required=True)
    for add_command in COMMANDS:
        add_command(sub)
    return parser


def _env_parser(sub) -> None:
    p = sub.add_parser("env", help="print the environment: variant, versions, LLVM, commit")
    p.set_defaults(func=cmd_env)


def _scenes_parser(sub) -> None:
    p = sub.add_parser("scenes", help="list the scene library (and your own scene directories)")
    p.add_argument("--scenes", action="append", metavar="DIR", help=SCENES_HELP)
    p.set_defaults(func=cmd_scenes)


def _methods_parser(sub) -> None:
    p = sub.add_parser("methods", help="list the methods, or one method's settings (what --set takes)")
    p.add_argument("name", nargs="?", metavar="NAME", help="a method: print its settings, ranges and defaults")
    p.set_defaults(func=cmd_methods)


def _generate_parser(sub) -> None:
    p = sub.add_parser("generate", help="render a scene's ground-truth dataset with Mitsuba's volpath")
    p.add_argument("scene", nargs="?", help="a scene name (mitsnerf scenes lists them) or the path of a spec")
    p.add_argument("--scenes", action="append", metavar="DIR", help=SCENES_HELP)
    p.add_argument("--out", default="data", help="dataset root; the dataset goes to OUT/NAME-HASH (default: data)")
    p.add_argument("--all", action="store_true", help="render every scene of the library and of --scenes")
    p.add_argument("--force", action="store_true", help="render again even if cached")
    p.add_argument("--no-verify", action="store_true",
                   help="on a cache hit, skip checking the files against the manifest's sha256 hashes")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a spec field, e.g. cameras.width=32")
    p.add_argument("--nerf-synthetic", action="store_true",
                   help="write the scene at the NeRF-synthetic scale: box [-1.5, 1.5]^3 (world.scale=3, sigma_t / 3), "
                        "cameras at radius 4, where those readers' near/far 2..6 work; --set wins over it")
    p.add_argument("--no-progress", action="store_true", help=NO_PROGRESS_HELP)
    p.set_defaults(func=cmd_generate)


def _train_parser(sub) -> None:
    p = sub.add_parser("train", help="fit a method to a dataset and evaluate it on the test views")
    p.add_argument("dataset", nargs="?", help="dataset directory (mitsnerf generate output or NeRF-synthetic); "
                                              "with --resume, default: the one the checkpoint names")
    p.add_argument("--out", required=True, help="run directory to write (checkpoints go there while training)")
    p.add_argument("--method", help=f"default: {DEFAULT_METHOD}")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its checkpoint.npz, bit-for-bit (settings come from it)")
    p.add_argument("--force", action="store_true",
                   help="replace the run already in --out (finished or interrupted); without it such a run is refused")
    p.add_argument("--no-verify", action="store_true",
                   help="skip checking the dataset's files against the sha256 hashes in its manifest "
                        "(grids and images are still checked)")
    p.add_argument("--deterministic", action="store_true",
                   help="train on one thread: every method bit-identical run to run (multi-threaded, the grid "
                        "methods' scatter-add gradients round in thread order; slower)")
    p.add_argument("--checkpoint-every", type=int, metavar="N",
                   help="write a checkpoint every N steps (default 0: only at the end and on Ctrl-C)")
    p.add_argument("--steps", type=int, help="the budget: optimiser steps (default 3000); schedules follow the step")
    p.add_argument("--seconds", type=float, help="also stop after this many seconds of training (not reproducible)")
    p.add_argument("--batch-rays", type=int)
    p.add_argument("--lr", type=float, help="the method's learning rate (its config's lr)")
    p.add_argument("--box", type=float, nargs=6, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                   help="the scene box (default: from the data: an aabb key, mitsnerf's manifest, instant-ngp's "
                        "aabb_scale, else [-1.5, 1.5]^3)")
    p.add_argument("--footprint", type=int, metavar="K",
                   help="evaluate each test pixel as the mean of K x K rays over its area (default 3; 1: the centre)")
    p.add_argument("--no-pixel-jitter", action="store_true",
                   help="train on rays through pixel centres instead of random points of each pixel")
    p.add_argument("--seed", type=int)
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="method config override, e.g. network.width=128")
    p.add_argument("--pixel-center", type=float, help="0.5 (Mitsuba, mitsnerf) or 0 (original NeRF loader); default from the data")
    p.add_argument("--background", type=float, nargs=3, metavar=("R", "G", "B"), help="background for foreign PNG data (default white)")
    p.add_argument("--no-progress", action="store_true", help=NO_PROGRESS_HELP)
    p.set_defaults(func=cmd_train)


def _score_parser(sub) -> None:
    p = sub.add_parser("score", help="score any tool's renders of a dataset's test views, as a benchmark cell",
                       description="Score RENDERS (a folder of PNG or EXR images) against DATASET's test views: "
                                   "PSNR/SSIM linear and sRGB, medium PSNR, the noise floor, the oracle (when the "
                                   "dataset has one cached, DATASET/oracle/), and with --density the density errors. "
                                   "Images are matched to the test frames by file name (r_000.png ...) or, when no "
                                   "name is a frame's, by the frame number in each name; PNG alpha is composited "
                                   "over the dataset's background as straight alpha, EXR alpha as its header's "
                                   "mitsnerf:alpha says (--exr-alpha to say otherwise). A run directory stands for "
                                   "its test/ renders.")
    p.add_argument("dataset", help="dataset directory (mitsnerf generate output, NeRF-synthetic or instant-ngp)")
    p.add_argument("renders", help="folder of the renders of the test views, or a run directory (its test/)")
    p.add_argument("--density", metavar="GRID", help="sigma_t on a grid over the dataset's box: .npy [z, y, x] or Mitsuba .vol")
    p.add_argument("--name", help="the row's name (default: the renders folder's name)")
    p.add_argument("--format", choices=("png", "exr"), help="read only these images (needed when both are there)")
    p.add_argument("--exr-alpha", choices=("premultiplied", "straight", "ignore"),
                   help="how an RGBA EXR's alpha composites over the dataset's background (default: as the file's "
                        "mitsnerf:alpha header says; premultiplied, OpenEXR's rule; ignore: the RGB as it is)")
    p.add_argument("--out", help="JSON record to write (default: RENDERS/scores.json)")
    p.add_argument("--footprint", type=int, default=1, metavar="K",
                   help="the tool's rays per pixel side (default 1: one through each pixel centre): which of the "
                        "cached oracle's renders the renders are held against")
    p.add_argument("--box", type=float, nargs=6, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                   help="the scene box (default: from the data, as mitsnerf train)")
    p.add_argument("--pixel-center", type=float, help="0.5 (Mitsuba, mitsnerf) or 0 (original NeRF loader); default from the data")
    p.add_argument("--background", type=float, nargs=3, metavar=("R", "G", "B"), help="background for foreign PNG data (default white)")
    p.add_argument("--no-verify", action="store_true",
                   help="skip checking the dataset's files against the sha256 hashes in its manifest")
    p.set_defaults(func=cmd_score)


def _render_parser(sub) -> None:
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
    p.set_defaults(func=cmd_render)


def _export_parser(sub) -> None:
    p = sub.add_parser("export", help="sample a run's learned field on a grid: Mitsuba .vol files + numpy arrays",
                       epilog=EXPORT_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="run directory (mitsnerf train --out)")
    p.add_argument("--out", help="output directory (default: RUN/export)")
    p.add_argument("--resolution", type=int, default=64, metavar="R", help="grid resolution R, 1..1024 (default 64)")
    p.add_argument("--direction", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="colour seen looking along this direction (default: averaged over directions)")
    p.add_argument("--directions", type=int, default=16, metavar="M",
                   help="number of view directions the colour is averaged over (default 16)")
    p.set_defaults(func=cmd_export)


def _bench_parser(sub) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print its table")
    p.add_argument("config", nargs="?", default="default",
                   help="a benchmark name (one shipped with mitsnerf, or NAME.toml in a --config directory) or the "
                        "path of a config (default: default)")
    p.add_argument("--config", dest="config_dirs", action="append", metavar="DIR",
                   help="a directory of your own benchmark configs, searched before the shipped ones (repeatable; "
                        "also $MITSNERF_BENCHMARKS)")
    p.add_argument("--scenes", action="append", metavar="DIR", help=SCENES_HELP)
    p.add_argument("--quick", action="store_true", help="the config's quick profile (tiny scenes, few steps)")
    p.add_argument("--data", help="dataset cache root (default: $MITSNERF_DATA or ./data)")
    p.add_argument("--results", default="results", help="results root (default: results)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress lines or bars on stderr (bars are off anyway when stderr is not a terminal)")
    p.add_argument("--executor", choices=("sequential", "pool", "ray"), default="sequential",
                   help="where cells run: this process one after another (default; the only one whose timings "
                        "are comparable), a local process pool, or Ray (pip install 'mitsnerf[ray]')")
    p.add_argument("--address", help="Ray cluster address (--executor ray; default: start a local instance)")
    p.add_argument("--workers", type=int, default=0, metavar="N", help="cells at once (pool, ray)")
    p.add_argument("--cpus-per-cell", type=int, default=0, metavar="N",
                   help="Dr.Jit threads (Ray: CPUs) per cell (default: all cores; cores/workers in a pool; 1 on Ray)")
    p.add_argument("--force", action="store_true",
                   help="recompute every cell (default: skip cells with a result for the same config and code)")
    p.add_argument("--no-verify", action="store_true",
                   help="skip checking cached datasets against their manifests' sha256 hashes")
    p.add_argument("--deterministic", action="store_true",
                   help="one Dr.Jit thread per cell (--cpus-per-cell 1): every method bit-identical run to run")
    p.set_defaults(func=cmd_bench)


def _check_parser(sub) -> None:
    p = sub.add_parser("check", help="verify the integrator against Mitsuba's volpath, closed forms and finite differences",
                       description="Run the verification cases (mitsnerf.verify) and print a table; "
                                   "exit status 1 if any case fails.")
    p.add_argument("--quality", choices=("quick", "thorough"), default="quick",
                   help="quick: 12x12 images, 256-16384 spp (about a minute); thorough: 24x24, 1024-65536 spp (minutes)")
    p.add_argument("--out", help="directory for the images of failing cases (default: a new temporary directory)")
    p.add_argument("--case", action="append", metavar="NAME", help="run only this case (repeatable)")
    p.add_argument("--mutations", action="store_true",
                   help="also run every case under each built-in mutation (bugs planted in the package's functions) "
                        "and print which cases catch each; exit status 1 if one is caught by none")
    p.add_argument("--no-progress", action="store_true", help="no per-case progress lines on stderr")
    p.set_defaults(func=cmd_check)


COMMANDS = (_env_parser, _scenes_parser, _methods_parser, _generate_parser, _train_parser, _render_parser, _export_parser,
            _score_parser, _bench_parser, _check_parser)
"""Each adds its command's parser to the subparsers; in the order ``mitsnerf --help`` lists them."""


#: OSErrors of the machine rather than of the code (full disk, read-only or forbidden place), reported in
#: one line naming the file; every other exception that is not a MitsnerfError is a bug and keeps its traceback.
ENVIRONMENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM})


def user_error_line(exc: BaseException) -> str | None:
    """The one line a user error prints (``FILE: FIELD: problem``), None for a bug.

    User errors are matched by class: :class:`mitsnerf.errors.MitsnerfError` (bad input, data, output
    location; command-line options as :class:`~mitsnerf.errors.UsageError`), the environment's
    :class:`~mitsnerf._llvm.LLVMError` and :class:`~mitsnerf.env.EnvironmentError_`, and an OSError of
    :data:`ENVIRONMENT_ERRNOS` with its file. A plain ValueError from the package's own code is a bug.
    """
    from mitsnerf._llvm import LLVMError
    from mitsnerf.env import EnvironmentError_
    from mitsnerf.errors import DiskFullError, MitsnerfError

    if isinstance(exc, (MitsnerfError, LLVMError, EnvironmentError_)):
        return str(exc)
    if DiskFullError.of(exc) is not None:  # a full disk the atomic writers did not see (a lock file, a cache)
        return str(DiskFullError.of(exc))
    if isinstance(exc, OSError) and exc.errno in ENVIRONMENT_ERRNOS and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    return None


def _interrupted(exc: KeyboardInterrupt) -> int:
    """Say what a signal stopped (and what it saved); the shell's exit status 128 + its number."""
    from mitsnerf.errors import Interrupted

    print("mitsnerf: interrupted" + (f"; {exc}" if str(exc) else ""), file=sys.stderr)
    return exc.exit_status if isinstance(exc, Interrupted) else 130


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        import mitsnerf  # noqa: F401  (finds libLLVM before drjit loads)
        from mitsnerf import env

        env.set_variant(args.variant, "--variant")
        from mitsnerf.train.checkpointing import stop_signals

        with stop_signals():  # SIGTERM and SIGHUP stop a command as Ctrl-C does
            return int(args.func(args) or 0)
    except KeyboardInterrupt as exc:
        return _interrupted(exc)
    except Exception as exc:  # one line for errors a user can act on; tracebacks for bugs
        from mitsnerf.errors import signal_cause

        stop = signal_cause(exc)
        if stop is not None:  # a signal inside code that re-raised it as another error (an import)
            return _interrupted(stop)
        line = user_error_line(exc)
        if line is None or args.debug:
            raise
        print(f"mitsnerf: error: {line}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
