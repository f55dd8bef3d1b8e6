"""``mitsnerf env``."""

from __future__ import annotations

import json


def run(args) -> int:
    from mitsnerf import env

    print(json.dumps(env.provenance(), indent=2))
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("env", help="print the environment: variant, versions, LLVM, commit")
    p.set_defaults(func=run)
