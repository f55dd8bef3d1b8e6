"""Benchmark configurations (``benchmarks/*.toml``) as frozen, validated dataclasses.

```toml
name = "default"                 # default: the file's stem
description = "..."
scenes = ["cloud"]               # scene names or spec paths, or "all" (every scene of scenes/)
seeds = [0]
train = { seconds = 240 }        # training settings shared by every method (TrainConfig keys)
[eval]                           # EvalConfig: what is measured besides the final test PSNR
curve_points = 8
[[methods]]                      # or: methods = "all" (every registered method, see below)
name = "nerf"                    # a registered method
label = "nerf"                   # column label (default: name); unique
config = { n_samples = 64 }      # the method's config (nested tables for nested configs)
train = { batch_rays = 2048 }    # this method's training settings (over the shared ones)
quick = { config = { n_samples = 32 } }   # this method's part of the --quick profile
[quick]                          # the --quick profile: tiny scenes, few steps
scene = { "cameras.width" = 16 } # SceneSpec.with_overrides keys
train = { steps = 40, seconds = 0 }
eval = { curve_points = 3 }
```

With ``methods = "all"``, every method in :data:`mitsnerf.methods.METHODS` runs with its
default settings, and ``[method_settings.NAME]`` tables (``config``, ``train``, ``quick``)
adjust the ones that need it; a table naming a method that is not registered is ignored
with a warning (configs may name methods before they land).
"""

from __future__ import annotations

import os
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from mitsnerf.config import deep_merge, from_dict
from mitsnerf.errors import SpecError
from mitsnerf.evaluate import EvalConfig
from mitsnerf.methods import METHODS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

BENCHMARKS_ENV = "MITSNERF_BENCHMARKS"


@dataclass(frozen=True)
class MethodQuick:
    """A method's own part of the ``--quick`` profile (over the profile's shared settings)."""

    config: Mapping[str, Any] = field(default_factory=dict)
    train: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class MethodRun:
    """One method column of a benchmark: the method, its config, its training budget."""

    name: str
    label: str = ""
    config: Mapping[str, Any] = field(default_factory=dict)
    """The method's config (``mitsnerf.methods.METHODS[name].config_type`` keys)."""
    train: Mapping[str, Any] = field(default_factory=dict)
    """Training settings over the benchmark's shared ``train`` (``mitsnerf.train.TrainConfig`` keys)."""
    quick: MethodQuick = field(default_factory=MethodQuick)

    def __post_init__(self) -> None:
        if self.name not in METHODS:
            raise ValueError(f"name: unknown method {self.name!r} (known: {', '.join(sorted(METHODS))})")
        if not self.label:
            object.__setattr__(self, "label", self.name)
        if "/" in self.label or self.label.startswith("."):
            raise ValueError(f"label: must not contain '/' or start with '.', got {self.label!r}")


@dataclass(frozen=True)
class QuickProfile:
    """Overrides applied by ``--quick``: to every scene spec, every method config, budget and eval."""

    scene: Mapping[str, Any] = field(default_factory=dict)
    config: Mapping[str, Any] = field(default_factory=dict)
    train: Mapping[str, Any] = field(default_factory=dict)
    eval: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class BenchConfig:
    name: str
    scenes: tuple[str, ...]
    methods: tuple[MethodRun, ...]
    seeds: tuple[int, ...] = (0,)
    train: Mapping[str, Any] = field(default_factory=dict)
    """Training settings shared by every method (a method's own ``train`` wins)."""
    eval: EvalConfig = field(default_factory=EvalConfig)
    quick: QuickProfile = field(default_factory=QuickProfile)
    description: str = ""

    def __post_init__(self) -> None:
        if not self.name or "/" in self.name or self.name.startswith("."):
            raise ValueError(f"name: must be a non-empty name without '/', got {self.name!r}")
        if not self.scenes:
            raise ValueError("scenes: at least one scene is needed")
        if len(set(self.scenes)) != len(self.scenes):
            raise ValueError(f"scenes: listed twice: {sorted({s for s in self.scenes if self.scenes.count(s) > 1})}")
        if not self.methods:
            raise ValueError("methods: at least one method is needed")
        if not self.seeds:
            raise ValueError("seeds: at least one seed is needed")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds: listed twice in {list(self.seeds)}")
        if any(s < 0 for s in self.seeds):
            raise ValueError(f"seeds: must be >= 0, got {list(self.seeds)}")
        labels = [m.label for m in self.methods]
        if len(set(labels)) != len(labels):
            raise ValueError(f"methods: labels must be unique, got {labels}")

    def method_settings(self, method: MethodRun, quick: bool) -> tuple[dict, dict]:
        """``(method config, train settings)`` of ``method``, merged in order: shared, the
        method's own, then (``quick``) the profile's shared and the method's quick settings."""
        config = deep_merge({}, method.config)
        train = deep_merge(self.train, method.train)
        if quick:
            config = deep_merge(deep_merge(config, self.quick.config), method.quick.config)
            train = deep_merge(deep_merge(train, self.quick.train), method.quick.train)
        return config, train

    def eval_config(self, quick: bool) -> EvalConfig:
        if not quick or not self.quick.eval:
            return self.eval
        from mitsnerf.config import to_dict

        return from_dict(EvalConfig, deep_merge(to_dict(self.eval), self.quick.eval), prefix="quick.eval.")


def benchmarks_dir() -> Path:
    """Where named benchmark configs live: ``$MITSNERF_BENCHMARKS`` or the repo's ``benchmarks/``."""
    return Path(os.environ.get(BENCHMARKS_ENV) or Path(__file__).resolve().parents[2] / "benchmarks")


def _expand(raw: dict) -> dict:
    """``scenes = "all"`` and ``methods = "all"`` (with ``[method_settings.NAME]``) as explicit lists."""
    raw = dict(raw)
    if raw.get("scenes") == "all":
        from mitsnerf.scene.spec import list_scenes

        raw["scenes"] = list_scenes()
    settings = raw.pop("method_settings", None)
    if raw.get("methods") == "all":
        settings = dict(settings or {})
        if not isinstance(settings, Mapping):
            raise ValueError("method_settings: expected a table of method names")
        for name in sorted(set(settings) - set(METHODS)):
            warnings.warn(f"method_settings.{name}: no method {name!r} is registered (yet); ignored", stacklevel=3)
        methods = []
        for name in sorted(METHODS):
            entry = dict(settings.get(name) or {})
            if "name" in entry and entry["name"] != name:
                raise ValueError(f"method_settings.{name}.name: must be {name!r} or left out")
            methods.append({**entry, "name": name})
        raw["methods"] = methods
    elif settings is not None:
        raise ValueError('method_settings: only with methods = "all" (give settings in each [[methods]] table)')
    elif isinstance(raw.get("methods"), str):
        raise ValueError(f'methods: a list of [[methods]] tables or "all", got {raw["methods"]!r}')
    if isinstance(raw.get("scenes"), str):
        raise ValueError(f'scenes: a list of scene names or "all", got {raw["scenes"]!r}')
    return raw


def parse_bench_config(raw: Mapping[str, Any], source: str | os.PathLike = "<config>") -> BenchConfig:
    """A :class:`BenchConfig` from plain data (a parsed TOML file); SpecError naming the field."""
    raw = dict(raw)
    raw.setdefault("name", Path(str(source)).stem)
    try:
        return from_dict(BenchConfig, _expand(raw))
    except ValueError as exc:
        field_name, _, message = str(exc).partition(": ")
        raise SpecError(source, field_name, message or str(exc)) from None


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
    return parse_bench_config(raw, path)
