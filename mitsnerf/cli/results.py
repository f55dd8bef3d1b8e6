"""``mitsnerf results``: the results page of one or more sweeps, from their ``results.json``."""

from __future__ import annotations

import shlex
from pathlib import Path

DESCRIPTION = """\
Write one Markdown page (e.g. RESULTS.md) of the tables of one or more benchmark sweeps, each made from the
results.json that `mitsnerf bench` wrote: a section per sweep with the command that ran it, its commit, when its
cells ran, the machine and links to its files; its tables as `mitsnerf bench` printed them (quality and cost per
scene, each scene's oracle and reference agreement, what each row was given and the gap to its rung's ceiling);
every column folded beneath; the columns' legend at the end. Nothing on the page is typed by hand but a sweep's
reading: a few lines on what its tables show, with links to the longer notes, in reading.md beside its
results.json, headed by the lines '---', 'commit: <the commit of the results it reads>', '---' (the page says so
when the results it sits beside are of another commit). Run the same command again after a sweep and the page
follows."""

EPILOG = """\
examples:
  mitsnerf results results/default                         # print the default sweep's page
  mitsnerf results results/default results/physics --out RESULTS.md
  mitsnerf results benchmarks/results/*/ --out RESULTS.md  # every committed sweep, one page"""


def run(args) -> int:
    from mitsnerf.bench.page import check_distinct, read_sweep, results_page
    from mitsnerf.data.atomic import atomic_write_text
    from mitsnerf.outputs import check_output_file

    sweeps = [read_sweep(path) for path in args.sweeps]  # every one read and checked before anything is written
    check_distinct(sweeps)
    command = shlex.join(["mitsnerf", *args.argv]) if getattr(args, "argv", None) else None
    if args.out is None:
        print(results_page(sweeps, title=args.title, command=command), end="")
        return 0
    out = Path(args.out)
    check_output_file(out, "--out")
    page = results_page(sweeps, title=args.title, command=command, base=out.resolve().parent)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, page)
    print(f"{out}: {len(sweeps)} sweep{'' if len(sweeps) == 1 else 's'} "
          f"({', '.join(s.data['benchmark'] + ('-quick' if s.data['quick'] else '') for s in sweeps)})")
    return 0


def add_parser(sub) -> None:
    import argparse

    p = sub.add_parser("results", help="write the results page (Markdown) of sweeps from their results.json",
                       description=DESCRIPTION, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sweeps", nargs="+", metavar="SWEEP",
                   help="a sweep's results directory (where `mitsnerf bench NAME` wrote its tables: results/NAME, "
                        "results/NAME-quick with --quick, under --results ROOT if given) or its results.json; a "
                        "section each, in this order")
    p.add_argument("--out", metavar="FILE",
                   help="write the page to FILE (whole, or not at all), its links relative to FILE's directory "
                        "(default: print it)")
    p.add_argument("--title", default="mitsnerf results", help="the page's title (default: %(default)s)")
    p.set_defaults(func=run)
