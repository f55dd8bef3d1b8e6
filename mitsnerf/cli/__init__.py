"""``mitsnerf``: the command line. Argument parsing only; each command calls into the package.

Errors the user can act on (bad spec, missing or corrupt data, an unusable output location, no LLVM,
NaN loss) print one line ``mitsnerf: error: FILE: FIELD: what`` and exit with status 2 (``--debug``
shows their traceback); anything else is a bug and keeps its traceback. SIGINT, SIGTERM and SIGHUP
stop a command: training saves a checkpoint and says how to continue; the exit status is 128 + the
signal's number (130, 143, 129).
"""

from __future__ import annotations

import argparse
import errno
import sys

from mitsnerf.cli import bench, check, env, export, generate, methods, render, results, scenes, score, train, volumes


class _Parser(argparse.ArgumentParser):
    """argparse, with a mistake on the command line reported as every user error is: one line
    ``mitsnerf: error: ...`` (and where to find the usage), exit status 2; an option or a command that is not
    one is reported by the command it was given to, with the closest names (``--stpes``: ``--steps``)."""

    def error(self, message: str):
        where = f"{self.prog}: " if " " in self.prog else ""  # a command's parser names it; the top one is said
        self.exit(2, f"mitsnerf: error: {where}{message}{_closest(self, message)} (see {self.prog} --help)\n")

    def parse_args(self, args=None, namespace=None):
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            sub = _command_parser(self, getattr(parsed, "command", None))
            sub.error(f"unrecognized arguments: {' '.join(extras)}")
        return parsed


def _command_parser(parser: argparse.ArgumentParser, command: str | None) -> argparse.ArgumentParser:
    """The parser of ``command`` (a subcommand of ``parser``), else ``parser`` itself."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return action.choices[command]
    return parser


def _closest(parser: argparse.ArgumentParser, message: str) -> str:
    """`` (did you mean --steps?)`` for an unrecognised option or an invalid command in argparse's ``message``,
    from ``parser``'s own options and commands; "" when none is close.

    >>> p = _Parser(prog="mitsnerf train"); _ = p.add_argument("--steps")
    >>> _closest(p, "unrecognized arguments: --stpes 10")
    ' (did you mean --steps?)'
    """
    import difflib
    import re

    options = [o for a in parser._actions for o in a.option_strings]
    commands = [c for a in parser._actions if isinstance(a, argparse._SubParsersAction) for c in a.choices]
    if message.startswith("unrecognized arguments: "):
        wrong, known = [w.split("=")[0] for w in message.split()[2:] if w.startswith("-")], options
    else:
        wrong, known = re.findall(r"invalid choice: '([^']*)'", message), commands
    bare = {k.lstrip("-"): k for k in known}  # the dashes every option shares say nothing of closeness
    close = [bare[m] for w in wrong for m in difflib.get_close_matches(w.lstrip("-"), list(bare), n=1)]
    return f" (did you mean {', '.join(dict.fromkeys(close))}?)" if close else ""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="mitsnerf",
        description="Mitsuba 3 ground truth for participating media, Dr.Jit NeRFs fitted to it, and the benchmarks "
        "between them.",
    )
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of a user error too (bad input, data, output location)")
    parser.add_argument(
        "--variant",
        help="Mitsuba variant (default: $MITSNERF_VARIANT, else cuda_ad_rgb if a GPU is usable, else llvm_ad_rgb)",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


COMMANDS = (env, scenes, volumes, methods, generate, train, score, render, export, bench, results, check)
"""The command modules, each with ``add_parser(subparsers)`` and ``run(args)``; in the order ``mitsnerf --help``
lists them."""


#: OSErrors of the machine rather than of the code (full disk, read-only or forbidden place), reported in
#: one line naming the file; every other exception that is not a MitsnerfError is a bug and keeps its traceback.
ENVIRONMENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM})


def user_error_line(exc: BaseException) -> str | None:
    """The one line a user error prints (``FILE: FIELD: problem``), None for a bug.

    User errors are matched by class: :class:`mitsnerf.errors.MitsnerfError` (bad input, data, output
    location; command-line options as :class:`~mitsnerf.errors.UsageError`), the environment's
    :class:`~mitsnerf._llvm.LLVMError` and :class:`~mitsnerf.env.EnvironmentError_`, and an OSError of
    :data:`ENVIRONMENT_ERRNOS` with its file. A plain ValueError from the package's own code is a bug.
    """
    from mitsnerf._llvm import LLVMError
    from mitsnerf.env import EnvironmentError_
    from mitsnerf.errors import DiskFullError, MitsnerfError

    if isinstance(exc, (MitsnerfError, LLVMError, EnvironmentError_)):
        return str(exc)
    if DiskFullError.of(exc) is not None:  # a full disk the atomic writers did not see (a lock file, a cache)
        return str(DiskFullError.of(exc))
    if isinstance(exc, OSError) and exc.errno in ENVIRONMENT_ERRNOS and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    return None


def _interrupted(exc: KeyboardInterrupt) -> int:
    """Say what a signal stopped (and what it saved); the shell's exit status 128 + its number."""
    from mitsnerf.errors import Interrupted

    print("mitsnerf: interrupted" + (f"; {exc}" if str(exc) else ""), file=sys.stderr)
    return exc.exit_status if isinstance(exc, Interrupted) else 130


def _drop_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's final flush of a closed pipe raises nothing."""
    import os

    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout is not a real file (a test's capture): nothing to redirect
        pass
    finally:
        os.close(devnull)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # as typed: what a sweep records it was run by
    try:
        import mitsnerf  # noqa: F401  (finds libLLVM before drjit loads)
        from mitsnerf import env

        env.set_variant(args.variant, "--variant")
        from mitsnerf.train.checkpointing import stop_signals

        with stop_signals():  # SIGTERM and SIGHUP stop a command as Ctrl-C does
            status = int(args.func(args) or 0)
        sys.stdout.flush()  # a pipe closed before the output was flushed shows here, not at the interpreter's exit
        return status
    except KeyboardInterrupt as exc:
        return _interrupted(exc)
    except BrokenPipeError:  # the reader went away (`mitsnerf methods | head`): stop quietly, as Unix tools do
        _drop_stdout()
        return 128 + 13  # SIGPIPE's status, what a shell reports for a writer whose pipe closed
    except Exception as exc:  # one line for errors a user can act on; tracebacks for bugs
        from mitsnerf.errors import signal_cause

        stop = signal_cause(exc)
        if stop is not None:  # a signal inside code that re-raised it as another error (an import)
            return _interrupted(stop)
        line = user_error_line(exc)
        if line is None or args.debug:
            raise
        print(f"mitsnerf: error: {line}", file=sys.stderr)
        return 2
