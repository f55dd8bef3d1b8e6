"""``mitsnerf scenes``."""

from __future__ import annotations

import sys

from mitsnerf.cli.common import SCENES_HELP, with_user_dirs


@with_user_dirs
def run(args) -> int:
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


def add_parser(sub) -> None:
    p = sub.add_parser("scenes", help="list the scene library (and your own scene directories)")
    p.add_argument("--scenes", action="append", metavar="DIR", help=SCENES_HELP)
    p.set_defaults(func=run)
