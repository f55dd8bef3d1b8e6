"""What several commands share: --set pairs, the dataset options, number checks, the user's directories."""

from __future__ import annotations

import functools
import os
import sys
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
        field = (exc.field or "").split(".")[0]
        raise UsageError(flag_of(cls, field) if field in values else command, exc.message) from None


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


def command_name(argv0: str | None = None, executable: str | None = None) -> str:
    """How to call mitsnerf again as this process was called, for the commands a command suggests: ``mitsnerf``
    where that name on ``PATH`` is this program, else the path it was run by (``.venv/bin/mitsnerf`` after
    ``make``, whose virtual environment is not activated), else ``PYTHON -m mitsnerf``.

    >>> command_name("/nowhere/bin/mitsnerf"), command_name("-m", "/opt/py/bin/python3")
    ('/nowhere/bin/mitsnerf', '/opt/py/bin/python3 -m mitsnerf')
    """
    import shlex
    import shutil

    argv0 = sys.argv[0] if argv0 is None else argv0
    if os.path.basename(argv0) == "mitsnerf":
        found = shutil.which("mitsnerf")
        if found and os.path.exists(argv0) and os.path.samefile(found, argv0):
            return "mitsnerf"
        return shlex.quote(argv0)
    return f"{shlex.quote(executable or sys.executable)} -m mitsnerf"


NO_PROGRESS_HELP = "no progress bars (they are off anyway when stderr is not a terminal)"


SCENES_HELP = ("a directory of your own scene specs (NAME.toml), searched before the library "
               "(repeatable; also $MITSNERF_SCENES)")


# --------------------------------------------------------------------------- options built from the configs


def flag_of(cls, field: str) -> str:
    """The option that sets field ``field`` of config ``cls``: ``--batch-rays``; a boolean whose default is
    true is turned off by ``--no-FIELD``.

    >>> from mitsnerf.train.config import TrainConfig
    >>> flag_of(TrainConfig, "batch_rays"), flag_of(TrainConfig, "pixel_jitter")
    ('--batch-rays', '--no-pixel-jitter')
    """
    from mitsnerf.config import option_spec

    dashed = field.replace("_", "-")
    return f"--no-{dashed}" if option_spec(cls, field).default is True else f"--{dashed}"


def add_config_options(parser, cls, names: tuple[str, ...], **defaults_shown) -> None:
    """One option per field of config ``cls`` in ``names``, its type, choices and help taken from the field's
    declaration (:func:`mitsnerf.config.option_spec`: doc, range, default), so that ``--help`` cannot drift
    from the code. An option not given is None: the config's default applies (``defaults_shown`` names
    another default for the help, where the command has its own).

    >>> import argparse
    >>> from mitsnerf.train.config import TrainConfig
    >>> p = argparse.ArgumentParser()
    >>> add_config_options(p, TrainConfig, ("steps", "pixel_jitter"))
    >>> vars(p.parse_args(["--steps", "5", "--no-pixel-jitter"]))
    {'steps': 5, 'pixel_jitter': False}
    >>> vars(p.parse_args([]))
    {'steps': None, 'pixel_jitter': None}
    """
    from mitsnerf.config import option_spec

    for name in names:
        o = option_spec(cls, name)
        doc = " ".join(o.doc.replace("``", "").split()).rstrip(".")
        if o.kind is bool:
            what = f"turn {'off' if o.default else 'on'} {name}"
            parser.add_argument(flag_of(cls, name), dest=name, action="store_const", const=not o.default,
                                default=None, help=f"{what}: {doc} (default: {'on' if o.default else 'off'})")
            continue
        default = defaults_shown.get(name, o.default)
        parser.add_argument(flag_of(cls, name), dest=name, type=o.kind, choices=o.choices, default=None,
                            metavar=None if o.choices else name.upper(),
                            help=f"{doc} ({o.what}; default {default:g})" if isinstance(default, float)
                            else f"{doc} ({o.what}; default {default})")


def given(args, names: tuple[str, ...]) -> dict:
    """The options of ``names`` the user gave (not None), as config data."""
    return {n: getattr(args, n) for n in names if getattr(args, n, None) is not None}


def add_dataset_options(parser) -> None:
    """The options of every command that reads a dataset (train, score): its box, pixel centre, the background
    of foreign PNGs, and ``--no-verify``; :func:`open_dataset` reads them."""
    parser.add_argument("--box", type=float, nargs=6, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                        help="the scene box (default: from the data: an aabb key, mitsnerf's manifest, instant-ngp's "
                             "aabb_scale, else [-1.5, 1.5]^3)")
    parser.add_argument("--pixel-center", type=float,
                        help="where a pixel's ray crosses it, in [0, 1): 0.5, its centre (the default unless the "
                             "data's transforms say pixel_center: Blender, Mitsuba, nerfstudio, instant-ngp), or 0, "
                             "its corner (the original NeRF loader)")
    parser.add_argument("--background", type=float, nargs=3, metavar=("R", "G", "B"),
                        help="background for foreign PNG data (default white)")
    parser.add_argument("--no-verify", action="store_true",
                        help="skip checking the dataset's files against the sha256 hashes in its manifest "
                             "(grids and images are still checked)")


def print_registry(registry, describe) -> int:
    """List a registry (:mod:`mitsnerf.plugins`): name, source kind and ``describe(value)`` per entry, where a
    plugin came from under it, and each plugin that failed to load as one warning line on stderr."""
    width = max(map(len, registry), default=4) + 2
    for name in registry:
        source = registry.entry(name).source
        print(f"{name:{width}s}{source.kind:13s}{describe(registry[name])}")
        if source.kind != "built-in":
            print(f"{'':{width}s}{'':13s}from {source.where}")
    for problem in registry.problems.values():
        print(f"mitsnerf: warning: not loaded: {problem}", file=sys.stderr)
    return 0
