"""Benchmark configurations (``benchmarks/*.toml``) as frozen, validated dataclasses.

```toml
name = "default"
scenes = ["cloud"]
seeds = [0]
[[methods]]
name = "nerf"                  # a registered method
label = "nerf"                 # column label (default: name)
config = { n_samples = 64 }    # the method's config (dotted tables allowed)
train = { seconds = 240, batch_rays = 2048 }   # mitsnerf.train.TrainConfig
[quick]                        # the --quick profile: smaller scenes, fewer steps
scene = { "cameras.width" = 16, "cameras.height" = 16 }
train = { steps = 40, seconds = 0 }
```
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from mitsnerf.config import from_dict
from mitsnerf.errors import SpecError
from mitsnerf.methods import METHODS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

BENCHMARKS_ENV = "MITSNERF_BENCHMARKS"


@dataclass(frozen=True)
class MethodRun:
    """One method column of a benchmark: the method, its config, its training budget."""

    name: str
    label: str = ""
    config: Mapping[str, Any] = field(default_factory=dict)
    train: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.name not in METHODS:
            raise ValueError(f"name: unknown method {self.name!r} (known: {', '.join(sorted(METHODS))})")
        if not self.label:
            object.__setattr__(self, "label", self.name)


@dataclass(frozen=True)
class QuickProfile:
    """Overrides applied by ``--quick``: to every scene spec, every method config, every budget."""

    scene: Mapping[str, Any] = field(default_factory=dict)
    config: Mapping[str, Any] = field(default_factory=dict)
    train: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class BenchConfig:
    name: str
    scenes: tuple[str, ...]
    methods: tuple[MethodRun, ...]
    seeds: tuple[int, ...] = (0,)
    quick: QuickProfile = field(default_factory=QuickProfile)
    description: str = ""

    def __post_init__(self) -> None:
        if not self.scenes:
            raise ValueError("scenes: at least one scene is needed")
        if not self.methods:
            raise ValueError("methods: at least one method is needed")
        if not self.seeds:
            raise ValueError("seeds: at least one seed is needed")
        labels = [m.label for m in self.methods]
        if len(set(labels)) != len(labels):
            raise ValueError(f"methods: labels must be unique, got {labels}")


def benchmarks_dir() -> Path:
    """Where named benchmark configs live: ``$MITSNERF_BENCHMARKS`` or the repo's ``benchmarks/``."""
    return Path(os.environ.get(BENCHMARKS_ENV) or Path(__file__).resolve().parents[2] / "benchmarks")


def load_bench_config(name_or_path: str | os.PathLike) -> BenchConfig:
    """A benchmark config by name (``benchmarks/<name>.toml``) or path; SpecError on any problem."""
    path = Path(name_or_path)
    if path.suffix != ".toml" and not path.exists():
        path = benchmarks_dir() / f"{name_or_path}.toml"
    if not path.is_file():
        known = sorted(p.stem for p in benchmarks_dir().glob("*.toml"))
        raise SpecError(path, None, f"no such benchmark config (known: {', '.join(known) or 'none'})")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(path, None, f"TOML syntax error: {exc}") from None
    raw.setdefault("name", path.stem)
    try:
        return from_dict(BenchConfig, raw)
    except ValueError as exc:
        field_name, _, message = str(exc).partition(": ")
        raise SpecError(path, field_name, message or str(exc)) from None
