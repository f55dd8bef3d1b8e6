"""What several commands share: --set pairs, the dataset options, number checks, the user's directories."""

from __future__ import annotations

import functools
import os
from pathlib import Path


def parse_overrides(pairs: list[str] | None) -> dict:
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


def with_user_dirs(command):
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


def options_config(cls, values: dict, command: str = "train"):
    """Config ``cls`` of the command-line values (``{field: value}``); a bad one is blamed on its flag
    (``--batch-rays``, ``--lr``, ``--footprint``), not on the config."""
    from mitsnerf.config import from_dict
    from mitsnerf.errors import SpecError, UsageError

    try:
        return from_dict(cls, values)
    except SpecError as exc:
        raise UsageError(f"--{exc.field.replace('_', '-')}" if exc.field else command, exc.message) from None


def open_dataset(args, path):
    """The dataset at ``path`` with the command's load options, verified (``--no-verify``: no hashes);
    says which box it has and what the verification read."""

    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.data.verify import verify_dataset
    from mitsnerf.errors import UsageError
    from mitsnerf.math.box import Box

    check_numbers([("--pixel-center", args.pixel_center, lambda v: 0 <= v < 1, "in [0, 1)"),
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


def check_numbers(checks) -> None:
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


NO_PROGRESS_HELP = "no progress bars (they are off anyway when stderr is not a terminal)"


SCENES_HELP = ("a directory of your own scene specs (NAME.toml), searched before the library "
               "(repeatable; also $MITSNERF_SCENES)")
