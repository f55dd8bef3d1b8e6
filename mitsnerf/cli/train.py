"""``mitsnerf train``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from mitsnerf.cli.common import (
    NO_PROGRESS_HELP,
    add_config_options,
    add_dataset_options,
    given,
    open_dataset,
    options_config,
    parse_overrides,
)

if TYPE_CHECKING:
    from mitsnerf.train.evaluate import EvalConfig

DEFAULT_METHOD = "ngp"
"""What ``mitsnerf train DIR`` fits with no ``--method``: a few minutes on a 2-core CPU."""


TRAIN_OPTIONS = ("steps", "seconds", "batch_rays", "seed", "checkpoint_every", "pixel_jitter")
"""The TrainConfig fields ``train`` takes as options (``--batch-rays``, ``--no-pixel-jitter``), built from their
declarations."""


def _fresh_settings(args) -> tuple[str, dict, EvalConfig]:
    """``(method, method overrides, EvalConfig)`` of a new run, checked before anything runs."""
    from mitsnerf.config import apply_overrides, from_dict
    from mitsnerf.errors import UsageError
    from mitsnerf.methods import methods
    from mitsnerf.train.evaluate import EvalConfig

    if not args.dataset:
        raise UsageError("train", "name a DATASET directory (or pass --resume to continue the run in --out)")
    method = DEFAULT_METHOD if args.method is None else args.method
    registry = methods()
    problem = registry.why_not(method)
    if problem:
        raise UsageError("--method", problem)
    overrides = apply_overrides({}, parse_overrides(args.set), "--set")
    if args.lr is not None:
        options_config(registry[method].config_type, {"lr": args.lr})
        overrides["lr"] = args.lr
    from_dict(registry[method].config_type, overrides, source="--set")
    eval_config = options_config(EvalConfig, {} if args.footprint is None else {"footprint": args.footprint})
    return method, overrides, eval_config


def _check_resume_flags(args) -> None:
    from mitsnerf.errors import UsageError

    fixed = [
        flag
        for flag, value in (
            ("--method", args.method),
            ("--set", args.set),
            ("--batch-rays", args.batch_rays),
            ("--lr", args.lr),
            ("--seed", args.seed),
            ("--box", args.box),
            ("--footprint", args.footprint),
            ("--no-pixel-jitter", args.pixel_jitter is not None),
            ("--deterministic", args.deterministic),
        )
        if value not in (None, False)
    ]
    if args.force:
        raise UsageError("--force", "starts the run over; --resume continues it: pass one of them")
    if fixed:
        raise UsageError("train --resume", f"{', '.join(fixed)} come from the checkpoint; "
                                           "only --steps, --seconds and --checkpoint-every may change")


def run(args) -> int:
    from mitsnerf.runs.directory import check_outside_dataset, claim_run_dir
    from mitsnerf.runs.fit import fit, resume_run
    from mitsnerf.train import TrainConfig
    from mitsnerf.train.threads import refuse_nondeterministic

    train_values = given(args, TRAIN_OPTIONS)
    train_config = options_config(TrainConfig, train_values)  # every setting checked before anything runs
    refuse_nondeterministic(args.deterministic, "--deterministic")
    if args.resume:
        _check_resume_flags(args)
    else:
        method, overrides, eval_config = _fresh_settings(args)
    out = Path(args.out)
    if args.dataset:
        check_outside_dataset(out, Path(args.dataset))
    with claim_run_dir(out, resume=args.resume, force=args.force):
        if args.resume:
            run = resume_run(out, train_values, dataset=open_dataset(args, args.dataset) if args.dataset else None,
                             verify_hashes=not args.no_verify, progress=not args.no_progress)
        else:
            dataset = open_dataset(args, args.dataset)
            run = fit(dataset, method, overrides, train_config, out, eval_config=eval_config,
                      deterministic=args.deterministic, progress=not args.no_progress)
    print(run.summary(args.out))
    return 0


def _method_help() -> str:
    """What ``--method`` takes, from the method registry (so a method added there is listed)."""
    from mitsnerf.methods import methods

    listed = "; ".join(f"{name}: {entry.description}" for name, entry in methods().items())
    return f"the method to fit (default {DEFAULT_METHOD}): {listed}. `mitsnerf methods NAME` lists its --set keys"


def _lr_help() -> str:
    """``--lr``'s help: each registered method's own default learning rate, from its config."""
    from mitsnerf.config import option_spec
    from mitsnerf.methods import methods

    defaults = ", ".join(f"{n} {option_spec(e.config_type, 'lr').default:g}" for n, e in methods().items())
    return f"the method's learning rate, its config's lr (default: {defaults})"


def add_parser(sub) -> None:
    from mitsnerf.train import TrainConfig
    from mitsnerf.train.evaluate import EvalConfig

    p = sub.add_parser("train", help="fit a method to a dataset and evaluate it on the test views")
    p.add_argument("dataset", nargs="?", help="dataset directory (mitsnerf generate output or NeRF-synthetic); "
                                              "with --resume, default: the one the checkpoint names")
    p.add_argument("--out", required=True, help="run directory to write (checkpoints go there while training)")
    p.add_argument("--method", metavar="NAME", help=_method_help())
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its checkpoint.npz, bit-for-bit on LLVM (settings come "
                        "from it)")
    p.add_argument("--force", action="store_true",
                   help="replace the run already in --out (finished or interrupted); without it such a run is refused")
    p.add_argument("--deterministic", action="store_true",
                   help="train on one thread: every method bit-identical run to run (multi-threaded, the grid "
                        "methods' scatter-add gradients round in thread order; slower). LLVM only: refused "
                        "on CUDA, whose float atomics no thread count orders")
    training = p.add_argument_group("training (every method; the budget is steps, schedules follow the step)")
    add_config_options(training, TrainConfig, TRAIN_OPTIONS)
    training.add_argument("--lr", type=float, help=_lr_help())
    add_config_options(p.add_argument_group("evaluation"), EvalConfig, ("footprint",))
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="method config override, e.g. network.width=128")
    add_dataset_options(p)
    p.add_argument("--no-progress", action="store_true", help=NO_PROGRESS_HELP)
    p.set_defaults(func=run)
