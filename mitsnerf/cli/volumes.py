"""``mitsnerf volumes``: the volume families (built-in and plugins) and where each came from, or one family's
parameters (what a spec's ``[volume.params]`` takes)."""

from __future__ import annotations

from mitsnerf.cli.common import print_registry


def run(args) -> int:
    from mitsnerf.config import doc_table
    from mitsnerf.errors import SpecError
    from mitsnerf.volumes import families

    registry = families()
    if not args.name:
        return print_registry(registry, lambda family: family.description)
    problem = registry.why_not(args.name)
    if problem:
        raise SpecError(None, "NAME", problem)
    family, source = registry[args.name], registry.entry(args.name).source
    print(f"{family.name}: {family.description}\n({source.kind}: {source.where})\n\n"
          f"{doc_table(family.params_type, nested=True)}\n\n"
          f'Set in a spec: [volume] family = "{family.name}", and the keys above in [volume.params].')
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "volumes", help="list the volume families (built-in and plugins), or one family's parameters",
        description="Without NAME: every registered volume family and where it came from (built-in, a "
                    "'mitsnerf.volumes' entry point, or the MITSNERF_VOLUMES variable: NAME=MODULE:ATTR, separated "
                    "by ',' or ':'), and the plugins that failed to load. With NAME: its parameters.")
    p.add_argument("name", nargs="?", metavar="NAME", help="a family: print its parameters, ranges and defaults")
    p.set_defaults(func=run)
