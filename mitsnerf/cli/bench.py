"""``mitsnerf bench``."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from mitsnerf.cli.common import SCENES_HELP, command_name, with_user_dirs
from mitsnerf.outputs import DATA_ENV


def next_steps(result, command: str) -> str:
    """Where the benchmark's datasets are, and the commands a newcomer would run next on them: train one of
    the benchmark's methods alone on its first dataset (at the cell's step budget), render that run, write the
    results page, open the report. ``command``: how to call mitsnerf (:func:`mitsnerf.cli.common.command_name`)."""
    datasets = dict.fromkeys((c.scene, c.dataset_dir) for c in result.cells)
    lines = ["datasets (ground truth and oracles, reused by every later run):"]
    lines += [f"  {scene}: {path}" for scene, path in datasets]
    if result.cells:
        cell = result.cells[0]
        run = f"runs/{cell.label}"
        lines += ["next:",
                  f"  {command} train {shlex.quote(cell.dataset_dir)} --method {cell.method} "
                  f"--steps {cell.train['steps']} --out {run}      # fit one method yourself",
                  f"  {command} render {run} --orbit 36 --out renders/{cell.label}      # novel views, orbit.gif",
                  f"  {command} results {shlex.quote(str(result.out_root))} --out RESULTS.md      # the results page",
                  f"  {command} --help      # every command; the report: {result.out_root / 'report.html'}"]
    return "\n".join(lines)


@with_user_dirs
def run(args) -> int:
    from mitsnerf.bench.config import load_bench_config
    from mitsnerf.bench.runner import BenchOptions, run_benchmark
    from mitsnerf.errors import UsageError
    from mitsnerf.outputs import check_output_dir, data_cache
    from mitsnerf.train.threads import refuse_nondeterministic

    refuse_nondeterministic(args.deterministic, "--deterministic")
    if args.deterministic and args.cpus_per_cell not in (0, 1):
        raise UsageError(
            "--deterministic", f"runs each cell on one thread; --cpus-per-cell {args.cpus_per_cell} contradicts it"
        )
    options = BenchOptions(
        quick=args.quick,
        data_root=Path(args.data) if args.data else data_cache()[0],
        results_root=Path(args.results),
        progress=not args.no_progress,
        executor=args.executor,
        workers=args.workers,
        address=args.address,
        cpus_per_cell=1 if args.deterministic else args.cpus_per_cell,
        force=args.force,
        verify_hashes=not args.no_verify,
        command=shlex.join(["mitsnerf", *args.argv]) if getattr(args, "argv", None) else None,
    )
    check_output_dir(options.results_root, "--results")
    check_output_dir(options.data_root, "--data" if args.data else
                     f"dataset cache (chosen by {data_cache()[1]}; --data or ${DATA_ENV} moves it)")
    config = load_bench_config(args.config)
    result = run_benchmark(config, options)
    print(result.markdown)
    print(f"\n{len(result.computed)} cells run, {len(result.skipped)} already done -> {result.out_root} "
          f"({', '.join(sorted(p for p in result.files if '/' not in p))})")
    print(next_steps(result, command_name()))
    if result.failed:
        print(
            f"mitsnerf: {len(result.failed)} cells failed: "
            + "; ".join(f"{f['key']}: {f['error']}" for f in result.failed),
            file=sys.stderr,
        )
        return 1
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print its table")
    p.add_argument("config", nargs="?", default="default",
                   help="a benchmark name (one shipped with mitsnerf, or NAME.toml in a --config directory) or the "
                        "path of a config (default: default)")
    p.add_argument("--config", dest="config_dirs", action="append", metavar="DIR",
                   help="a directory of your own benchmark configs, searched before the shipped ones (repeatable; "
                        "also $MITSNERF_BENCHMARKS)")
    p.add_argument("--scenes", action="append", metavar="DIR", help=SCENES_HELP)
    p.add_argument("--quick", action="store_true", help="the config's quick profile (tiny scenes, few steps)")
    p.add_argument("--data", metavar="DIR",
                   help="where datasets and their oracles are cached (default: $MITSNERF_DATA, else "
                        "$XDG_CACHE_HOME/mitsnerf, else ~/.cache/mitsnerf; `mitsnerf env` shows it)")
    p.add_argument("--results", default="results", help="results root (default: results)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress lines or bars on stderr (bars are off anyway when stderr is not a terminal)")
    from mitsnerf.bench.executors import EXECUTORS

    p.add_argument("--executor", choices=EXECUTORS, default="sequential",
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
                   help="one Dr.Jit thread per cell (--cpus-per-cell 1): every method bit-identical run to run "
                        "(LLVM only: refused on CUDA, whose float atomics no thread count orders)")
    p.set_defaults(func=run)
