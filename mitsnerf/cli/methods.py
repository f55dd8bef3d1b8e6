"""``mitsnerf methods``: the registered methods and where each came from, one method's settings, or
``--check NAME``: the conformance suite (:mod:`mitsnerf.runs.conformance`) on it."""

from __future__ import annotations

from mitsnerf.cli.common import print_registry


def _show(method) -> int:
    from mitsnerf.config import doc_table

    print(f"{method.name}: {method.description}\n({method.source.kind}: {method.source.where})\n\n"
          f"{doc_table(method.config_type, nested=True)}\n\n"
          f"Set with: mitsnerf train DATASET --method {method.name} --set KEY=VALUE "
          "(or in a bench file's [[methods]] config table).")
    return 0


def run(args) -> int:
    from mitsnerf.errors import SpecError
    from mitsnerf.methods import methods

    registry = methods()
    name = args.check or args.name
    if not name:
        return print_registry(registry, lambda method: method.description)
    problem = registry.why_not(name)
    if problem:
        raise SpecError(None, "--check" if args.check else "NAME", problem)
    if args.check:
        from mitsnerf.runs.conformance import check_method

        report = check_method(name, progress=not args.no_progress)
        print(report.summary())
        return 0 if report.passed else 1
    return _show(registry[name])


def add_parser(sub) -> None:
    from mitsnerf.cli.common import NO_PROGRESS_HELP

    p = sub.add_parser(
        "methods",
        help="list the methods (built-in and plugins), one method's settings, or check a method's conformance",
        description="Without NAME: every registered method, where it came from (built-in, a 'mitsnerf.methods' "
                    "entry point, or the MITSNERF_METHODS variable: NAME=MODULE:CLASS, separated by ',' or ':') and "
                    "the plugins that failed to load; a plugin cannot take a built-in's name, and a name claimed "
                    "twice is refused until one is renamed. With NAME: its settings (what --set takes). With --check "
                    "NAME: train its tiny configuration (the method's `tiny` settings, not its defaults: a check of "
                    "promises, not of quality) through every promise the harness makes for a method.")
    p.add_argument("name", nargs="?", metavar="NAME", help="a method: print its settings, ranges and defaults")
    p.add_argument("--check", metavar="NAME",
                   help="run the conformance suite on method NAME at its tiny settings (exit 1 if it fails)")
    p.add_argument("--no-progress", action="store_true", help=NO_PROGRESS_HELP)
    p.set_defaults(func=run)
