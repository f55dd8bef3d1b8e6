"""``mitsnerf methods``."""

from __future__ import annotations

from mitsnerf.errors import unknown


def run(args) -> int:
    from mitsnerf.config import doc_table
    from mitsnerf.errors import SpecError
    from mitsnerf.methods import METHODS

    if not args.name:
        for name, entry in METHODS.items():
            print(f"{name:16s} {entry.description}")
        return 0
    if args.name not in METHODS:
        raise SpecError(None, "NAME", unknown("method", args.name, sorted(METHODS)))
    entry = METHODS[args.name]
    print(f"{entry.name}: {entry.description}\n\n{doc_table(entry.config_type, nested=True)}\n\n"
          f"Set with: mitsnerf train DATASET --method {entry.name} --set KEY=VALUE "
          "(or in a bench file's [[methods]] config table).")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("methods", help="list the methods, or one method's settings (what --set takes)")
    p.add_argument("name", nargs="?", metavar="NAME", help="a method: print its settings, ranges and defaults")
    p.set_defaults(func=run)
