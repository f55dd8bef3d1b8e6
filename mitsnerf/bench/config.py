"""Benchmark configurations (TOML; the shipped ones: ``mitsnerf/bench/configs/*.toml``) as frozen, validated
dataclasses.

```toml
name = "default"                 # default: the file's stem
description = "..."
scenes = ["cloud"]               # scene names or spec paths (relative to this file's folder), or "all"
seeds = [0]
scene = { "cameras.width" = 256 }  # dotted SceneSpec.with_overrides keys, for every scene (e.g. a paper-size version)
train = { seconds = 240 }        # training settings shared by every method (TrainConfig keys)
[eval]                           # EvalConfig: what is measured besides the final test PSNR
curve_points = 8
[oracle]                         # OracleConfig: the dataset's emission-absorption ceiling (cached with it)
spp = 64
[[methods]]                      # or: methods = "all" (every registered method, see below)
name = "nerf"                    # a registered method
label = "nerf"                   # column label (default: name); unique
config = { n_samples = 64 }      # the method's config (nested tables for nested configs)
train = { batch_rays = 2048 }    # this method's training settings (over the shared ones)
quick = { config = { n_samples = 32 } }   # this method's part of the --quick profile
[[methods]]
name = "mitsuba-inverse"
label = "mitsuba-inverse (nerf start)"
config = { init_from = "@nerf" }  # "@LABEL": the run of row LABEL on the same scene and seed (below)
[[external]]                     # renders made by another tool, scored beside the methods (optional)
name = "nerfacto"                # the row reads "nerfacto (external)"
renders = { cloud = "renders/nerfacto/cloud" }    # per scene name: a folder of its test views' renders
density = { cloud = "renders/nerfacto/cloud.npy" }  # optional, per scene: sigma_t (.npy or .vol) in its box
timings = { cloud = "runs/nerfacto/timings.json" }  # optional, per scene: {"steps": 800, "rays_per_step": 1024,
                                 #   "train_wall_s": 412.0, "matched": "steps"} -> budget, train s, rays/s
quick = { renders = { cloud = "..." } }          # renders of the --quick datasets (else not in --quick)
[quick]                          # the --quick profile: tiny scenes, few steps
scene = { "cameras.width" = 16 } # SceneSpec.with_overrides keys
train = { steps = 40, seconds = 0 }
eval = { curve_points = 3 }
oracle = { spp = 8 }
```

External renders are matched and scored as ``mitsnerf score`` does (:mod:`mitsnerf.runs.external`);
relative paths are relative to the config file's folder. A config of ``[[external]]`` entries alone
(no ``[[methods]]``) scores them against the datasets and their oracles, training nothing.

A string setting of a method's ``config`` (any method's, any string setting; in ``config``, ``quick.config`` or
``[method_settings.NAME]``) whose value is ``"@LABEL"`` names another row's result: it becomes the run directory
of the cell of row ``LABEL`` on the same scene and seed, with that run's medium exported in its ``export/`` as
``mitsnerf export RUN`` writes it (64^3), which ``mitsuba-inverse``'s ``init_from`` starts from. That row's cells
run first; the row's cell fails (``error.json``) when the cell it names failed; the tables show the row by its
label, and its recorded config keeps ``"@LABEL"``. An unknown label, a row naming itself or a cycle of rows is
refused at load, naming the field. :mod:`mitsnerf.bench.references` has the details.

With ``methods = "all"``, every registered method (:func:`mitsnerf.methods.methods`) runs with its
default settings, and ``[method_settings.NAME]`` tables (``config``, ``train``, ``quick``)
adjust the ones that need it; a table naming a method that is not registered is ignored
with a warning (configs may name methods before they land).
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mitsnerf.bench.references import PREFIX, references_in
from mitsnerf.config import (
    INTERNAL,
    as_spec_error,
    deep_merge,
    from_dict,
    named_files,
    param,
    read_toml,
    search_dirs,
    source_field,
    to_dict,
)
from mitsnerf.errors import SpecError
from mitsnerf.methods import methods as registered_methods
from mitsnerf.oracle.cache import OracleConfig
from mitsnerf.train.evaluate import EvalConfig

#: Environment variable listing a user's benchmark config directories (``os.pathsep``-separated),
#: searched before the shipped configs (``mitsnerf bench --config DIR`` adds to it).
BENCHMARKS_ENV = "MITSNERF_BENCHMARKS"
#: The shipped benchmark configs, package data.
SHIPPED = Path(__file__).resolve().parent / "configs"


@dataclass(frozen=True)
class MethodQuick:
    """A method's own part of the ``--quick`` profile (over the profile's shared settings)."""

    config: Mapping[str, Any] = param(default_factory=dict, doc="method config keys")
    train: Mapping[str, Any] = param(default_factory=dict, doc="training settings")


@dataclass(frozen=True)
class MethodRun:
    """One method column of a benchmark: the method, its config, its training budget."""

    name: str = param(doc="a registered method (`mitsnerf methods` lists them)")
    label: str = param("", doc="column label (default: name); unique")
    config: Mapping[str, Any] = param(
        default_factory=dict, doc="the method's config (the keys `mitsnerf methods NAME` lists)")
    train: Mapping[str, Any] = param(
        default_factory=dict,
        doc="training settings over the benchmark's shared train (mitsnerf.train.TrainConfig keys)")
    quick: MethodQuick = param(default_factory=MethodQuick, doc="this method's part of the --quick profile")

    def __post_init__(self) -> None:
        problem = registered_methods().why_not(self.name)
        if problem:
            raise ValueError(f"name: {problem}")
        if not self.label:
            object.__setattr__(self, "label", self.name)
        if "/" in self.label or self.label.startswith("."):
            raise ValueError(f"label: must not contain '/' or start with '.', got {self.label!r}")


@dataclass(frozen=True, kw_only=True)
class ExternalFiles:
    """Per scene name: a folder of renders of its test views, and optionally a density grid over its box."""

    renders: Mapping[str, str] = param(default_factory=dict, doc="scene name -> folder of renders of its test views")
    density: Mapping[str, str] = param(default_factory=dict, doc="scene name -> sigma_t grid (.npy or .vol) in its box")
    timings: Mapping[str, str] = param(
        default_factory=dict,
        doc="scene name -> JSON of the tool's training run: steps, rays_per_step, train_wall_s and optionally "
            'matched ("steps" or "seconds": what the budget was set to equal); fills the budget and cost columns')


@dataclass(frozen=True, kw_only=True)
class ExternalRun(ExternalFiles):
    """Renders made by another tool, scored like a cell (``mitsnerf score``) and shown marked external."""

    name: str = param(doc='the row reads "NAME (external)"; unique')
    format: str = param("", choices=("", "png", "exr"), doc="read only these images (empty: both)")
    exr_alpha: str = param("", choices=("", "premultiplied", "straight", "ignore"),
                           doc="how an RGBA EXR's alpha composites over the background (mitsnerf score --exr-alpha; "
                               "empty: as each file's header says)")
    footprint: int = param(1, lo=1, hi=64, doc="the tool's rays per pixel side (1: one through each pixel centre): "
                                               "the oracle's renders it is held against")
    quick: ExternalFiles = param(default_factory=ExternalFiles,
                                 doc="the same for the --quick profile's datasets (none: left out of --quick)")

    def __post_init__(self) -> None:
        if not self.name or "/" in self.name or self.name.startswith("."):
            raise ValueError(f"name: must be a non-empty name without '/', got {self.name!r}")
        if not self.renders:
            raise ValueError("renders: at least one scene's renders are needed")

    @property
    def label(self) -> str:
        return f"{self.name} (external)"

    def files(self, quick: bool) -> ExternalFiles:
        """The renders and densities of the profile (``quick``) being run."""
        return self.quick if quick else ExternalFiles(renders=self.renders, density=self.density, timings=self.timings)


@dataclass(frozen=True)
class QuickProfile:
    """Overrides applied by ``--quick``: to every scene spec, every method config, budget and eval."""

    scene: Mapping[str, Any] = param(default_factory=dict, doc="dotted SceneSpec.with_overrides keys")
    config: Mapping[str, Any] = param(default_factory=dict, doc="method config keys, for every method")
    train: Mapping[str, Any] = param(default_factory=dict, doc="training settings, for every method")
    eval: Mapping[str, Any] = param(default_factory=dict, doc="EvalConfig keys")
    oracle: Mapping[str, Any] = param(default_factory=dict, doc="OracleConfig keys")


@dataclass(frozen=True)
class BenchConfig:
    name: str = param(doc="results go to results/<name>[-quick]/; default: the file's stem")
    scenes: tuple[str, ...] = param(doc='scene names or spec paths, or "all"')
    methods: tuple[MethodRun, ...] = param((), doc='[[methods]] tables, or "all" (with [method_settings.NAME]); '
                                                    'may be left out when [[external]] entries are given')
    seeds: tuple[int, ...] = param((0,), lo=0, doc="training seeds; every cell runs once per seed")
    scene: Mapping[str, Any] = param(
        default_factory=dict, doc="dotted SceneSpec.with_overrides keys applied to every scene (before --quick's)"
    )
    train: Mapping[str, Any] = param(default_factory=dict)
    """Training settings shared by every method (a method's own ``train`` wins)."""
    eval: EvalConfig = param(default_factory=EvalConfig, doc="what is measured besides the test PSNR")
    quick: QuickProfile = param(default_factory=QuickProfile, doc="the --quick profile")
    oracle: OracleConfig = param(default_factory=OracleConfig,
                                 doc="the emission-absorption oracle of each dataset (the ceiling row)")
    external: tuple[ExternalRun, ...] = param(
        (), doc="[[external]] tables: other tools' renders, scored beside the methods"
    )
    description: str = param("", doc="one line")
    source: str | None = source_field()
    methods_all: bool = field(default=False, compare=False, metadata={INTERNAL: True})
    """``methods = "all"``: the methods' settings are ``[method_settings.NAME]`` tables."""

    def __post_init__(self) -> None:
        if not self.name or "/" in self.name or self.name.startswith("."):
            raise ValueError(f"name: must be a non-empty name without '/', got {self.name!r}")
        if not self.scenes:
            raise ValueError("scenes: at least one scene is needed")
        if len(set(self.scenes)) != len(self.scenes):
            raise ValueError(f"scenes: listed twice: {sorted({s for s in self.scenes if self.scenes.count(s) > 1})}")
        if not self.methods and not self.external:
            raise ValueError("methods: at least one method (or an [[external]] entry) is needed")
        if not self.seeds:
            raise ValueError("seeds: at least one seed is needed")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds: listed twice in {list(self.seeds)}")
        labels = [m.label for m in self.methods]
        if len(set(labels)) != len(labels):
            raise ValueError(f"methods: labels must be unique, got {labels}")
        names = [e.name for e in self.external]
        if len(set(names)) != len(names):
            raise ValueError(f"external: names must be unique, got {names}")

    def method_path(self, method: MethodRun) -> str:
        """Where ``method``'s settings are in the file: ``methods.I`` or ``method_settings.NAME``."""
        if self.methods_all:
            return f"method_settings.{method.name}"
        return f"methods.{[m.label for m in self.methods].index(method.label)}"

    def setting_layers(self, method: MethodRun, quick: bool, part: str) -> list[tuple[str, Mapping[str, Any]]]:
        """``(where in the file, table)`` of ``method``'s ``part`` ("config" or "train"), in merge order:
        shared (``train`` only), the method's own, then (``quick``) the profile's and the method's quick."""
        own = self.method_path(method)
        layers = [(part, self.train)] if part == "train" else []
        layers.append((f"{own}.{part}", getattr(method, part)))
        if quick:
            layers += [
                (f"quick.{part}", getattr(self.quick, part)),
                (f"{own}.quick.{part}", getattr(method.quick, part)),
            ]
        return layers

    def method_settings(self, method: MethodRun, quick: bool) -> tuple[dict, dict]:
        """``(method config, train settings)`` of ``method``: its :meth:`setting_layers` merged."""
        config: dict = {}
        train: dict = {}
        for _, table in self.setting_layers(method, quick, "config"):
            config = deep_merge(config, table)
        for _, table in self.setting_layers(method, quick, "train"):
            train = deep_merge(train, table)
        return config, train

    def blame(self, method: MethodRun, quick: bool, part: str, exc: ValueError) -> SpecError:
        """``exc`` (about ``method``'s merged ``part`` settings) as a SpecError at the field of the
        file that set the key: the last layer holding it, else the method's own table."""
        error = as_spec_error(exc, self.source)
        head = (error.field or "").split(".")[0]
        layers = self.setting_layers(method, quick, part)
        path = next((where for where, table in reversed(layers) if head in table), f"{self.method_path(method)}.{part}")
        field_name = f"{path}.{error.field}" if error.field else path
        return SpecError(self.source, field_name, f"{error.message} (method {method.label})")

    @property
    def base_dir(self) -> Path:
        """The folder relative paths in the config (spec files, external renders) are relative to: the
        config file's (the working directory for a config made in code)."""
        return Path(self.source).parent if self.source else Path(".")

    def oracle_config(self, quick: bool) -> OracleConfig:
        """The oracle's settings, with the quick profile's ``oracle`` keys over them."""
        if not quick or not self.quick.oracle:
            return self.oracle
        return from_dict(OracleConfig, deep_merge(to_dict(self.oracle), self.quick.oracle), source=self.source,
                         prefix="quick.oracle")

    def eval_config(self, quick: bool) -> EvalConfig:
        if not quick or not self.quick.eval:
            return self.eval
        return from_dict(EvalConfig, deep_merge(to_dict(self.eval), self.quick.eval), source=self.source,
                         prefix="quick.eval")


def _lookup(table: Mapping[str, Any], keys: tuple[str, ...]) -> Any:
    """``table[k0][k1]...`` (None where a key is missing)."""
    value: Any = table
    for key in keys:
        value = value.get(key) if isinstance(value, Mapping) else None
    return value


def row_references(config: BenchConfig, method: MethodRun, quick: bool) -> list[tuple[str, str]]:
    """``(field in the file, LABEL)`` of each reference in ``method``'s merged config in the profile (``quick``);
    the field is where the last layer that sets it wrote it (``methods.1.config.init_from``)."""
    merged, _ = config.method_settings(method, quick)
    layers = config.setting_layers(method, quick, "config")
    out = []
    for keys, label in references_in(merged).items():
        where = next(w for w, table in reversed(layers) if _lookup(table, keys) == PREFIX + label)
        out.append((".".join((where, *keys)), label))
    return out


def _check_label(config: BenchConfig, method: MethodRun, field: str, label: str) -> None:
    """A SpecError at ``field`` when ``label`` names no other ``[[methods]]`` row."""
    labels = [m.label for m in config.methods]
    if label == method.label:
        raise SpecError(config.source, field, f"{PREFIX}{label} is this row's own label: a row cannot start "
                                              "from its own result")
    if label in labels:
        return
    external = [e.label for e in config.external if label in (e.name, e.label)]
    why = (f"{external[0]!r} is an [[external]] entry: renders only, no run to start from" if external
           else f"no [[methods]] row is labelled {label!r}")
    raise SpecError(config.source, field, f"{PREFIX}{label}: {why} (labels: {', '.join(labels)})")


def _edges(config: BenchConfig, quick: bool) -> dict[str, list[tuple[str, str]]]:
    """Row label -> ``(field, referred label)`` of its references in the profile, each label checked."""
    edges = {}
    for method in config.methods:
        refs = row_references(config, method, quick)
        for where, label in refs:
            _check_label(config, method, where, label)
        edges[method.label] = refs
    return edges


def _visit(label: str, edges: Mapping[str, list[tuple[str, str]]], path: list[str], done: list[str],
           source: str | None) -> None:
    """Depth-first: append ``label`` to ``done`` after every row it refers to; a SpecError on a cycle, at the
    field of the first reference around it."""
    if label in done:
        return
    for _, referred in edges[label]:
        if referred in path:
            cycle = path[path.index(referred):] + [label, referred]
            first = next(f for f, r in edges[cycle[0]] if r == cycle[1])
            raise SpecError(source, first, f"{PREFIX}{cycle[1]}: the rows refer to each other in a cycle "
                                           f"({' -> '.join(cycle)}): none of them can run first")
        _visit(referred, edges, [*path, label], done, source)
    done.append(label)


def method_order(config: BenchConfig, quick: bool) -> list[MethodRun]:
    """The config's method rows, each after the rows it refers to, otherwise in the file's order (a stable
    topological order); a SpecError for an unknown label, a row naming itself or a cycle."""
    edges = _edges(config, quick)
    done: list[str] = []
    for method in config.methods:
        _visit(method.label, edges, [], done, config.source)
    by_label = {m.label: m for m in config.methods}
    return [by_label[label] for label in done]


def check_references(config: BenchConfig) -> None:
    """Every ``"@LABEL"`` of ``config`` valid in both profiles (the SpecErrors of :func:`method_order`)."""
    for quick in (False, True):
        method_order(config, quick)


def benchmarks_dir() -> Path:
    """The benchmark configs shipped with the package (``mitsnerf/bench/configs``)."""
    return SHIPPED


def benchmark_dirs() -> list[Path]:
    """Where benchmark names are looked up, first match first: ``$MITSNERF_BENCHMARKS``'s directories, then the
    shipped ones."""
    return search_dirs(BENCHMARKS_ENV, SHIPPED)


def _expand(raw: dict, source: str) -> dict:
    """``scenes = "all"`` and ``methods = "all"`` (with ``[method_settings.NAME]``) as explicit lists."""
    raw = dict(raw)
    if raw.get("scenes") == "all":
        from mitsnerf.scene.spec import list_scenes

        raw["scenes"] = list_scenes()
    settings = raw.pop("method_settings", None)
    if raw.get("methods") == "all":
        if not isinstance(settings or {}, Mapping):
            raise SpecError(source, "method_settings", "must be a table of method names")
        settings = dict(settings or {})
        registered = registered_methods()
        for name in sorted(set(settings) - set(registered)):
            warnings.warn(f"method_settings.{name}: no method {name!r} is registered (yet); ignored", stacklevel=3)
        listed = []
        for name in sorted(registered):
            entry = dict(settings.get(name) or {})
            if "name" in entry and entry["name"] != name:
                raise SpecError(source, f"method_settings.{name}.name", f"must be {name!r} or left out")
            listed.append({**entry, "name": name})
        raw["methods"] = listed
    elif settings is not None:
        raise SpecError(
            source, "method_settings", 'only with methods = "all" (give settings in each [[methods]] table)'
        )
    elif isinstance(raw.get("methods"), str):
        raise SpecError(source, "methods", f'a list of [[methods]] tables or "all", got {raw["methods"]!r}')
    if isinstance(raw.get("scenes"), str):
        raise SpecError(source, "scenes", f'a list of scene names or "all", got {raw["scenes"]!r}')
    return raw


def parse_bench_config(raw: Mapping[str, Any], source: str | os.PathLike = "<config>") -> BenchConfig:
    """A :class:`BenchConfig` from plain data (a parsed TOML file); SpecError naming the file and field (its
    ``"@LABEL"`` settings checked too: :func:`check_references`)."""
    config = _parse(raw, str(source))
    check_references(config)
    return config


def _parse(raw: Mapping[str, Any], source: str) -> BenchConfig:
    """:func:`parse_bench_config`'s dataclass, before the references are checked."""
    raw = dict(raw)
    raw.setdefault("name", Path(source).stem)
    expanded = _expand(raw, source)
    if raw.get("methods") != "all":
        return from_dict(BenchConfig, expanded, source=source)
    names = [m["name"] for m in expanded["methods"]]
    try:
        config = from_dict(BenchConfig, expanded, source=source)
    except SpecError as exc:  # methods.I.x of the expanded list is method_settings.NAME.x in the file
        head, _, rest = (exc.field or "").partition(".")
        index, _, tail = rest.partition(".")
        if head == "methods" and index.isdigit():
            raise SpecError(exc.where, ".".join(filter(None, ("method_settings", names[int(index)], tail))),
                            exc.message) from None
        raise
    return dataclasses.replace(config, methods_all=True)


def load_bench_config(name_or_path: str | os.PathLike) -> BenchConfig:
    """A benchmark config by name (``NAME.toml`` in :func:`benchmark_dirs`) or path; SpecError on any problem."""
    path = Path(name_or_path)
    known = named_files(benchmark_dirs())
    if path.suffix != ".toml" and not path.exists():
        path = known.get(str(name_or_path), path)
    if not path.exists():
        raise SpecError(path, None, f"no such benchmark config (known: {', '.join(known) or 'none'})")
    return parse_bench_config(read_toml(path, "a benchmark config"), path)
