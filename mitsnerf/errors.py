"""Errors a user can act on. The CLI prints ``str(error)`` as one line and exits non-zero.

Each names where the problem is (a file and, where it applies, a field in it)::

    >>> str(SpecError("scenes/cloud.toml", "volume.resolution", "must be >= 1, got 0"))
    'scenes/cloud.toml: volume.resolution: must be >= 1, got 0'
"""

from __future__ import annotations

import errno
import os
import shlex
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType


def unknown(kind: str, name: object, known) -> str:
    """How every registry refuses a name it does not have: ``unknown KIND 'NAME' (known: A, B)``.

    >>> unknown("method", "nope", ["nerf", "ngp"])
    "unknown method 'nope' (known: nerf, ngp)"
    """
    return f"unknown {kind} {name!r} (known: {', '.join(known) or 'none'})"


class Placeholder(str):
    """A value a message leaves for the user to fill in (``N``, ``SCENE``): written bare by either :class:`Words`."""


@dataclass(frozen=True)
class Words:
    """How a message names what the user can set, in the language of the surface they called: the command
    line's options (``--force``, ``--resume --steps N``, ``mitsnerf train --resume --out RUN``) or the Python
    API's arguments (``force=True``, ``resume=True, steps=N``, ``api.fit(resume=True, out='RUN')``). A function
    whose refusal advises a setting takes ``words`` (default :data:`CLI`) and writes that advice through it;
    :mod:`mitsnerf.api` passes :data:`API`. Settings are named by their Python names (``exr_alpha``)::

        >>> N = Placeholder("N")
        >>> CLI(resume=True, steps=N), API(resume=True, steps=N)
        ('--resume --steps N', 'resume=True, steps=N')
        >>> CLI.name("exr_alpha"), API.name("exr_alpha"), CLI.name("dataset"), API(format="png")
        ('--exr-alpha', 'exr_alpha', 'DATASET', "format='png'")
        >>> CLI.command("train", resume=True, out="runs/a b"), API.command("train", resume=True, out="runs/a b")
        ("mitsnerf train --resume --out 'runs/a b'", "api.fit(resume=True, out='runs/a b')")
    """

    api: bool = False

    #: Command-line arguments that are positional (named by their metavar), not ``--options``.
    POSITIONAL = MappingProxyType({"dataset": "DATASET", "renders": "RENDERS", "run": "RUN", "scene": "SCENE",
                                   "config": "CONFIG"})
    #: The API function that does a command's work.
    FUNCTIONS = MappingProxyType({"train": "fit", "generate": "generate", "score": "score", "bench": "bench"})
    #: What the API says for a command-line option it has no argument for.
    API_ELSEWHERE = MappingProxyType({"box": "a Dataset loaded with mitsnerf.data.dataset.load_dataset(DIR, box=...)"})

    def name(self, option: str) -> str:
        """The setting itself (an error's ``where``): ``--exr-alpha`` or ``DATASET``; ``exr_alpha``."""
        if self.api:
            return self.API_ELSEWHERE.get(option, option)
        return self.POSITIONAL.get(option) or "--" + option.replace("_", "-")

    def _value(self, value: object) -> str:
        if isinstance(value, Placeholder) or (not self.api and not isinstance(value, (str, os.PathLike))):
            return str(value)
        text = os.fspath(value) if isinstance(value, os.PathLike) else value
        return repr(text) if self.api else shlex.quote(str(text))

    def __call__(self, **settings: object) -> str:
        """``settings`` as the user writes them: ``--resume --steps N`` (a flag for True); ``resume=True, steps=N``."""
        if self.api:
            return ", ".join(self.API_ELSEWHERE.get(k) or f"{k}={self._value(v)}" for k, v in settings.items())
        return " ".join(self.name(k) + ("" if v is True else f" {self._value(v)}") for k, v in settings.items())

    def again(self, command: str) -> str:
        """How to repeat a call: ``run the same command again``; ``call api.bench again with the same arguments``."""
        if self.api:
            return f"call api.{self.FUNCTIONS.get(command, command)} again with the same arguments"
        return "run the same command again"

    def command(self, command: str, *args: object, **settings: object) -> str:
        """A whole call of ``command`` (``train``, ``generate``, ...) with positional ``args`` and ``settings``."""
        if self.api:
            inner = ", ".join([self._value(a) for a in args] + ([self(**settings)] if settings else []))
            return f"api.{self.FUNCTIONS.get(command, command)}({inner})"
        words = ["mitsnerf", command, *(self._value(a) for a in args)]
        return " ".join(words + ([self(**settings)] if settings else []))


CLI = Words(api=False)
"""The command line's words (``--force``)."""
API = Words(api=True)
"""The Python API's words (``force=True``)."""


class MitsnerfError(Exception):
    """Base class: a problem with the user's input or environment, not a bug."""

    def __init__(self, where: str | os.PathLike | None, field: str | None, message: str) -> None:
        self.where = str(where) if where is not None else None
        self.field = field
        self.message = message
        parts = [p for p in (self.where, field, message) if p]
        super().__init__(": ".join(parts))


class SpecError(MitsnerfError, ValueError):
    """A configuration is malformed: a scene spec, a benchmark, a method or training config
    (file, dotted field, what is wrong). The one error of :func:`mitsnerf.config.from_dict`; a
    ``ValueError`` too, so a config built without a file reads ``field: problem``."""


#: The same class under the name the config layer uses.
ConfigError = SpecError


class DatasetError(MitsnerfError):
    """A dataset on disk is missing, incomplete or inconsistent (file, field, what is wrong)."""


class TrainingError(MitsnerfError):
    """Training cannot go on (NaN or diverging loss; the last good checkpoint is kept)."""


class MethodError(MitsnerfError):
    """A method's code breaks the contract of :mod:`mitsnerf.methods.base` where only running it shows
    (its model has no parameters, its loss depends on none of them): names the method and where it
    came from, the part of the contract, and what was seen. Raised before training changes anything.

    >>> str(MethodError("method 'fog' (MITSNERF_METHODS: fog=./fog.py:Fog)", "parameters()", "is empty"))
    "method 'fog' (MITSNERF_METHODS: fog=./fog.py:Fog): parameters(): is empty"
    """


class UsageError(MitsnerfError, ValueError):
    """A command-line option or argument is wrong: ``--box: X1 must exceed X0``.

    >>> str(UsageError("--method", "unknown method 'nope' (known: nerf, ngp)"))
    "--method: unknown method 'nope' (known: nerf, ngp)"
    """

    def __init__(self, option: str, message: str) -> None:
        super().__init__(option, None, message)


class OutputError(MitsnerfError):
    """An output location cannot be used: not writable, a file where a directory goes, a finished
    run that would be replaced, or a run directory another process is writing. Raised before any
    work starts."""


#: The errnos of a full disk or an exhausted quota.
DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


class DiskFullError(OutputError):
    """The disk (or the user's quota) filled while an output was written. Names the path, the file
    being written in it when that is another, and what was kept (the atomic writers of
    :mod:`mitsnerf.data.atomic` leave the previous version or nothing, never half a file)::

        >>> str(DiskFullError("data/tiny-0e80", "No space left on device", "data/tiny-0e80 was not created",
        ...                   writing="train/r_001.exr"))
        'data/tiny-0e80: disk full (No space left on device) writing train/r_001.exr; data/tiny-0e80 was not created'
    """

    def __init__(self, path: str | os.PathLike, reason: str, kept: str, writing: str | None = None) -> None:
        self.path, self.reason, self.kept, self.writing = Path(path), reason, kept, writing
        doing = f" writing {writing}" if writing else ""
        super().__init__(path, None, f"disk full ({reason}){doing}; {kept}")

    @classmethod
    def of(cls, exc: BaseException) -> DiskFullError | None:
        """``exc`` as a DiskFullError (an OSError of :data:`DISK_FULL_ERRNOS`: its file, else unnamed), or None."""
        if isinstance(exc, DiskFullError):
            return exc
        if isinstance(exc, OSError) and exc.errno in DISK_FULL_ERRNOS:
            return cls(exc.filename or "an output", exc.strerror or "no space left", "it was not written")
        return None


class Interrupted(KeyboardInterrupt):
    """Work stopped by a signal: SIGINT (Ctrl-C), or SIGTERM/SIGHUP (``timeout``, systemd, Slurm, Ray).

    A :class:`KeyboardInterrupt`, so code that cleans up after Ctrl-C does the same here;
    ``exit_status`` is the shell's ``128 + signal number`` (130, 143, 129). It survives pickling
    (a process pool hands it back to the sweep)::

        >>> import pickle
        >>> back = pickle.loads(pickle.dumps(Interrupted(15, "stopped by SIGTERM")))
        >>> back.exit_status, str(back)
        (143, 'stopped by SIGTERM')
    """

    def __init__(self, signum: int, message: str = "") -> None:
        super().__init__(message)
        self.signum = int(signum)

    def __reduce__(self):  # through a process pool: the signal travels with the message
        return (type(self), (self.signum, str(self)))

    @property
    def exit_status(self) -> int:
        return 128 + self.signum


def signal_cause(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (Ctrl-C, or a signal's :class:`Interrupted`) that is ``exc`` or in its chain
    of causes: a signal handled inside an import or a library callback can come back as another error."""
    seen = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None
