"""``mitsnerf check``."""

from __future__ import annotations

import sys
from pathlib import Path


def _case_line(r) -> None:
    print(f"  {r.name}: {r.status} ({r.seconds:.1f} s)", file=sys.stderr, flush=True)


def _mutation_line(label: str, r) -> None:
    print(f"  {label}: {r.name}: {r.status} ({r.seconds:.1f} s)", file=sys.stderr, flush=True)


TABLE_FILE = "check.txt"
"""The file ``--out DIR`` holds: the wide table, its notes and the count line."""


def _show(args, text: str, wide_text: str) -> None:
    """Print the table (``--wide``: the wide one) and write the wide one to ``--out``'s :data:`TABLE_FILE`."""
    print(wide_text if args.wide else text, flush=True)
    if args.out:
        from mitsnerf.data.atomic import atomic_write_text

        Path(args.out).mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(args.out) / TABLE_FILE, wide_text + "\n")


def run(args) -> int:
    from mitsnerf.outputs import check_output_dir
    from mitsnerf.verify.cases import QUALITIES
    from mitsnerf.verify.runner import count_line, format_mutations, format_table, run_checks, run_mutations

    if args.out:
        check_output_dir(Path(args.out), "--out")
    alpha = QUALITIES[args.quality].alpha
    if args.mutations:
        report = run_mutations(args.quality, only=args.case, progress=None if args.no_progress else _mutation_line)
        matrix = format_mutations(report)
        _show(args, f"{format_table(report.clean, alpha)}\n\n{matrix}",
              f"{format_table(report.clean, alpha, wide=True)}\n\n{matrix}\n{count_line(report.clean)}")
        failed = [r.name for r in report.clean if r.passed is False]
        if failed:
            print(
                f"mitsnerf check: {len(failed)} case(s) failed without a mutation: {', '.join(failed)}", file=sys.stderr
            )
        if report.escaped:
            print(f"mitsnerf check: {len(report.escaped)} mutation(s) caught by no case: {', '.join(report.escaped)}",
                  file=sys.stderr)
        sys.stderr.flush()
        print(count_line(report.clean))  # last, alone on its line
        return 0 if report.passed else 1
    results = run_checks(args.quality, out=args.out, only=args.case, progress=None if args.no_progress else _case_line)
    _show(args, format_table(results, alpha), f"{format_table(results, alpha, wide=True)}\n{count_line(results)}")
    failed = [r.name for r in results if r.passed is False]
    if failed:
        print(f"mitsnerf check: {len(failed)} case(s) failed: {', '.join(failed)}", file=sys.stderr, flush=True)
    print(count_line(results))  # last, alone on its line
    return 1 if failed else 0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "check",
        help="verify the integrator against Mitsuba's volpath, closed forms and finite differences",
        description="Run the verification cases (mitsnerf.verify) and print a table; exit status 1 if any case fails.",
    )
    from mitsnerf.verify.cases import QUALITIES
    from mitsnerf.verify.runner import COMPACT_WIDTH

    sizes = "; ".join(f"{q.name}: {q.width}x{q.width} images, Mitsuba references at {q.spp} spp times each case's "
                      f"factor, N = {q.n_samples} samples per ray" for q in QUALITIES.values())
    p.add_argument("--quality", choices=tuple(QUALITIES), default="quick",
                   help=f"{sizes} (default quick: a few minutes on 2 cores)")
    p.add_argument("--out", metavar="DIR",
                   help=f"write the wide table to DIR/{TABLE_FILE}, and the images of failing cases under DIR "
                        "(default: no table file; failing cases' images in a new temporary directory)")
    p.add_argument("--wide", action="store_true",
                   help=f"print every column (the reference each case is compared with), each row on one line "
                        f"(default: a compact table of about {COMPACT_WIDTH} columns)")
    p.add_argument("--case", action="append", metavar="NAME", help="run only this case (repeatable)")
    p.add_argument("--mutations", action="store_true",
                   help="also run every case under each built-in mutation (bugs planted in the package's functions) "
                        "and print which cases catch each; exit status 1 if one is caught by none")
    p.add_argument("--no-progress", action="store_true", help="no per-case progress lines on stderr")
    p.set_defaults(func=run)
