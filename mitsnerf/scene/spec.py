"""Scene specifications: ``scenes/NAME.toml`` parsed into frozen, validated dataclasses.

A spec names a volume (a :mod:`mitsnerf.volumes` family, its grid and optical thickness), the
lights, a camera rig and the render settings; see ``docs/conventions.md`` ("Scene specs") for
the file format. Every problem with a spec raises :class:`mitsnerf.errors.SpecError` naming the
file and the dotted field::

    >>> parse_scene({"name": "x"}, "inline.toml")
    Traceback (most recent call last):
    ...
    mitsnerf.errors.SpecError: inline.toml: volume: missing field (a table)

The world is Z-up (``UP``): the hemisphere rig and the sky use it.

    >>> spec = load_scene("cloud")
    >>> small = spec.with_overrides({"cameras.width": 16, "cameras.height": 16})
    >>> small.cameras.width, spec.cameras.width
    (16, 64)
    >>> parse_scene(small.to_dict(), "copy") == small
    True
    >>> small.content_hash() != spec.content_hash()
    True
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import json
import math
import os
import re
import sys
from dataclasses import dataclass, field
from numbers import Integral, Real
from pathlib import Path
from types import MappingProxyType
from typing import Any, ClassVar, Mapping

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

from mitsnerf.errors import SpecError
from mitsnerf.config import range_text

#: The world's up axis (Z-up). Rigs' "upper half" and the sky's zenith are +Z.
UP = (0.0, 0.0, 1.0)
#: Environment variable naming the directory that holds the scene library.
SCENES_ENV = "MITSNERF_SCENES"
RIGS = ("sphere", "hemisphere", "ring")
#: Cameras must stay outside the scene box's bounding sphere (radius sqrt(3)/2).
MIN_CAMERA_RADIUS = math.sqrt(3.0) / 2.0
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_MISSING = object()


# --------------------------------------------------------------------------- field reader


def _is_int(v: Any) -> bool:
    return isinstance(v, Integral) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, Real) and not isinstance(v, bool)


def _type_name(v: Any) -> str:
    return {bool: "a boolean", str: "a string", list: "a list", dict: "a table", tuple: "a list"}.get(
        type(v), type(v).__name__
    )


class _Table:
    """Reads the fields of one TOML table, raising :class:`SpecError` with the dotted field name.

    Unknown keys are reported when the reader is made, before missing ones, so a typo gets
    "unknown field ... (did you mean ...)" rather than a confusing "missing field".
    """

    def __init__(self, data: Any, source: str, prefix: str, known: tuple[str, ...]) -> None:
        if not isinstance(data, Mapping):
            raise SpecError(source, prefix or None, f"must be a table, got {_type_name(data)}")
        self.data, self.source, self.prefix = data, source, prefix
        for key in data:
            if key not in known:
                close = difflib.get_close_matches(str(key), known, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(known)})"
                raise SpecError(source, self.name(key), f"unknown field{hint}")

    def name(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def error(self, key: str, message: str) -> SpecError:
        return SpecError(self.source, self.name(key), message)

    def get(self, key: str, default: Any, what: str) -> Any:
        if key in self.data:
            return self.data[key]
        if default is _MISSING:
            raise self.error(key, f"missing field ({what})")
        return default

    def int(self, key: str, default: Any = _MISSING, lo: int | None = None, hi: int | None = None) -> int:
        what = "an integer" + range_text(lo, hi)
        v = self.get(key, default, what)
        if not _is_int(v) or (lo is not None and v < lo) or (hi is not None and v > hi):
            raise self.error(key, f"must be {what}, got {v!r}")
        return int(v)

    def float(
        self, key: str, default: Any = _MISSING, lo: float | None = None, hi: float | None = None,
        lo_open: bool = False, hi_open: bool = False,
    ) -> float:
        what = "a number" + range_text(lo, hi, lo_open, hi_open)
        v = self.get(key, default, what)
        bad = not _is_number(v) or not math.isfinite(v)
        if not bad:
            bad = (lo is not None and (v <= lo if lo_open else v < lo)) or (
                hi is not None and (v >= hi if hi_open else v > hi)
            )
        if bad:
            raise self.error(key, f"must be {what}, got {v!r}")
        return float(v)

    def str(self, key: str, default: Any = _MISSING, choices: tuple[str, ...] | None = None) -> str:
        what = f"one of {', '.join(map(repr, choices))}" if choices else "a string"
        v = self.get(key, default, what)
        if not isinstance(v, str) or (choices is not None and v not in choices):
            raise self.error(key, f"must be {what}, got {v!r}")
        return v

    def bool(self, key: str, default: Any = _MISSING) -> bool:
        v = self.get(key, default, "true or false")
        if not isinstance(v, bool):
            raise self.error(key, f"must be true or false, got {v!r}")
        return v

    def vec3(self, key: str, default: Any = _MISSING, *, nonneg: bool = False, nonzero: bool = False):
        what = "3 numbers" + (" >= 0" if nonneg else "") + (", not all zero" if nonzero else "")
        v = self.get(key, default, what)
        if v is None:
            return None
        if not isinstance(v, (list, tuple)):
            raise self.error(key, f"must be {what}, got {_type_name(v)} {v!r}")
        if len(v) != 3:
            raise self.error(key, f"must be {what}, got {len(v)} values")
        if not all(_is_number(c) and math.isfinite(c) for c in v):
            raise self.error(key, f"must be {what}, got {v!r}")
        if nonneg and any(c < 0 for c in v):
            raise self.error(key, f"must be {what}, got {v!r}")
        if nonzero and not any(c != 0 for c in v):
            raise self.error(key, f"must be {what}, got {v!r}")
        return tuple(float(c) for c in v)

    def table(self, key: str, default: Any = _MISSING) -> Mapping:
        v = self.get(key, default, "a table")
        if not isinstance(v, Mapping):
            raise self.error(key, f"must be a table, got {_type_name(v)}")
        return v


def _freeze(obj: Any) -> Any:
    """Deep read-only copy: tables become mapping proxies, lists tuples."""
    if isinstance(obj, Mapping):
        return MappingProxyType({str(k): _freeze(v) for k, v in obj.items()})
    if isinstance(obj, (list, tuple)):
        return tuple(_freeze(v) for v in obj)
    return obj


def _thaw(obj: Any) -> Any:
    """Plain JSON/TOML data again: mappings become dicts, tuples lists."""
    if isinstance(obj, Mapping):
        return {k: _thaw(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_thaw(v) for v in obj]
    return obj


# --------------------------------------------------------------------------- volume


@dataclass(frozen=True)
class VolumeSpec:
    """The medium: a volume family evaluated on an ``R^3`` grid and its optical thickness.

    ``sigma_t = sigma_t_scale * density`` (world units; the box has side 1), density in [0, 1].
    ``params`` holds the family's parameters with every default filled in (as the family's
    params dataclass normalises them), read-only.
    """

    family: str
    resolution: int
    seed: int
    sigma_t_scale: float
    params: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    FIELDS: ClassVar[tuple[str, ...]] = ("family", "resolution", "seed", "sigma_t_scale", "params")

    @classmethod
    def parse(cls, data: Any, source: str) -> "VolumeSpec":
        t = _Table(data, source, "volume", cls.FIELDS)
        from mitsnerf import volumes

        names = tuple(sorted(volumes.FAMILIES))
        family = t.get("family", _MISSING, f"one of {', '.join(names)}")
        if not isinstance(family, str) or family not in volumes.FAMILIES:
            raise t.error("family", f"unknown volume family {family!r} (known: {', '.join(names)})")
        raw = dict(t.table("params", {}))
        try:
            params = volumes.make_params(family, raw)
        except ValueError as exc:
            sub, sep, message = str(exc).partition(": ")
            if sep and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.\[\]]*", sub):
                raise SpecError(source, f"volume.params.{sub}", message) from None
            raise SpecError(source, "volume.params", str(exc)) from None
        if dataclasses.is_dataclass(params):
            params = {f.name: getattr(params, f.name) for f in dataclasses.fields(params)}
        elif not isinstance(params, Mapping):
            params = raw
        return cls(
            family=family,
            resolution=t.int("resolution", lo=8, hi=512),
            seed=t.int("seed", 0, lo=0, hi=2**32 - 1),
            sigma_t_scale=t.float("sigma_t_scale", lo=0.0, lo_open=True),
            params=_freeze(params),
        )

    def __hash__(self) -> int:  # params is a read-only mapping, which Python does not hash
        return hash(json.dumps(self.to_dict(), sort_keys=True))

    def to_dict(self) -> dict[str, Any]:
        return {
            "family": self.family,
            "resolution": self.resolution,
            "seed": self.seed,
            "sigma_t_scale": self.sigma_t_scale,
            "params": _thaw(self.params),
        }


# --------------------------------------------------------------------------- lights


@dataclass(frozen=True)
class LightSpec:
    """Base of the light kinds; ``type`` is the TOML ``type`` key. See :data:`LIGHT_TYPES`."""

    type: ClassVar[str] = ""
    #: An environment light is seen by camera rays (at most one per scene, Mitsuba's rule).
    is_environment: ClassVar[bool] = False

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": self.type}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is not None:
                out[f.name] = list(value) if isinstance(value, tuple) else value
        return out


@dataclass(frozen=True)
class ConstantLight(LightSpec):
    """Uniform environment: the same ``radiance`` (RGB, linear) from every direction."""

    radiance: tuple[float, float, float]
    type: ClassVar[str] = "constant"
    is_environment: ClassVar[bool] = True

    @classmethod
    def parse(cls, t: _Table) -> "ConstantLight":
        return cls(radiance=t.vec3("radiance", nonneg=True))


@dataclass(frozen=True)
class SkyLight(LightSpec):
    """Procedural sky gradient (Z-up), baked to a lat-long bitmap for Mitsuba's ``envmap``.

    Radiance seen in world direction ``d`` (unit), ``h = d.z``::

        h >= 0:  horizon + (zenith - horizon) * (1 - (1 - h)^2)
        h <  0:  horizon + (ground - horizon) * (1 - (1 + h)^2)
        + sun_glow * exp(sun_sharpness * (dot(d, -sun_direction) - 1))   (when sun_direction is set)

    all times ``scale``. ``sun_direction`` is the direction sunlight *travels* (as a
    ``directional`` light's ``direction``), so a sky and a sun can share one vector.
    ``resolution`` is the bitmap width (height ``resolution // 2``).
    """

    zenith: tuple[float, float, float]
    horizon: tuple[float, float, float]
    ground: tuple[float, float, float]
    sun_direction: tuple[float, float, float] | None = None
    sun_glow: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sun_sharpness: float = 200.0
    scale: float = 1.0
    resolution: int = 256
    type: ClassVar[str] = "sky"
    is_environment: ClassVar[bool] = True

    @classmethod
    def parse(cls, t: _Table) -> "SkyLight":
        return cls(
            zenith=t.vec3("zenith", nonneg=True),
            horizon=t.vec3("horizon", nonneg=True),
            ground=t.vec3("ground", nonneg=True),
            sun_direction=t.vec3("sun_direction", None, nonzero=True),
            sun_glow=t.vec3("sun_glow", (0.0, 0.0, 0.0), nonneg=True),
            sun_sharpness=t.float("sun_sharpness", 200.0, lo=1.0, hi=1e5),
            scale=t.float("scale", 1.0, lo=0.0, lo_open=True),
            resolution=t.int("resolution", 256, lo=8, hi=4096),
        )


@dataclass(frozen=True)
class DirectionalLight(LightSpec):
    """A sun at infinity: ``direction`` is the way the light travels, ``irradiance`` RGB (W/m^2)."""

    direction: tuple[float, float, float]
    irradiance: tuple[float, float, float]
    type: ClassVar[str] = "directional"

    @classmethod
    def parse(cls, t: _Table) -> "DirectionalLight":
        return cls(direction=t.vec3("direction", nonzero=True), irradiance=t.vec3("irradiance", nonneg=True))


@dataclass(frozen=True)
class PointLight(LightSpec):
    """An isotropic point light at ``position`` with radiant ``intensity`` RGB (W/sr)."""

    position: tuple[float, float, float]
    intensity: tuple[float, float, float]
    type: ClassVar[str] = "point"

    @classmethod
    def parse(cls, t: _Table) -> "PointLight":
        return cls(position=t.vec3("position"), intensity=t.vec3("intensity", nonneg=True))


#: The light kinds by TOML ``type``.
LIGHT_TYPES: dict[str, type[LightSpec]] = {
    c.type: c for c in (ConstantLight, SkyLight, DirectionalLight, PointLight)
}


def _parse_light(data: Any, source: str, prefix: str) -> LightSpec:
    if not isinstance(data, Mapping):
        raise SpecError(source, prefix, f"must be a table, got {_type_name(data)}")
    kind = data.get("type", _MISSING)
    if kind is _MISSING:
        raise SpecError(source, f"{prefix}.type", f"missing field (one of {', '.join(LIGHT_TYPES)})")
    if kind not in LIGHT_TYPES:
        raise SpecError(source, f"{prefix}.type", f"unknown light type {kind!r} (known: {', '.join(LIGHT_TYPES)})")
    cls = LIGHT_TYPES[kind]
    known = ("type",) + tuple(f.name for f in dataclasses.fields(cls))
    return cls.parse(_Table(data, source, prefix, known))


# --------------------------------------------------------------------------- cameras, render


@dataclass(frozen=True)
class CameraRigSpec:
    """Where the cameras are (see :mod:`mitsnerf.scene.rigs`): all look at the origin from ``radius``.

    ``fov`` is the horizontal field of view in degrees; images are ``width x height``.
    """

    rig: str
    n_train: int
    n_test: int
    width: int
    height: int
    fov: float
    radius: float
    seed: int = 0

    FIELDS: ClassVar[tuple[str, ...]] = ("rig", "n_train", "n_test", "width", "height", "fov", "radius", "seed")

    @classmethod
    def parse(cls, data: Any, source: str) -> "CameraRigSpec":
        t = _Table(data, source, "cameras", cls.FIELDS)
        return cls(
            rig=t.str("rig", choices=RIGS),
            n_train=t.int("n_train", lo=1, hi=10000),
            n_test=t.int("n_test", lo=1, hi=10000),
            width=t.int("width", lo=1, hi=8192),
            height=t.int("height", lo=1, hi=8192),
            fov=t.float("fov", lo=0.0, hi=180.0, lo_open=True, hi_open=True),
            radius=cls._radius(t),
            seed=t.int("seed", 0, lo=0, hi=2**32 - 1),
        )

    @staticmethod
    def _radius(t: _Table) -> float:
        radius = t.float("radius", lo=0.0, hi=1e4, lo_open=True)
        if radius <= MIN_CAMERA_RADIUS:
            raise t.error(
                "radius",
                f"must be > {MIN_CAMERA_RADIUS:.4f} (outside the scene box's bounding sphere), got {radius:g}",
            )
        return radius

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class RenderSpec:
    """Mitsuba ``volpath`` settings. ``max_depth = -1`` is unlimited (a cap loses energy in thick
    media). ``noise_floor`` renders the test cameras a second time with another seed (``test_ref``).
    """

    spp_train: int
    spp_test: int
    max_depth: int = -1
    seed: int = 0
    noise_floor: bool = True

    FIELDS: ClassVar[tuple[str, ...]] = ("spp_train", "spp_test", "max_depth", "seed", "noise_floor")

    @classmethod
    def parse(cls, data: Any, source: str) -> "RenderSpec":
        t = _Table(data, source, "render", cls.FIELDS)
        max_depth = t.int("max_depth", -1, lo=-1, hi=100000)
        if max_depth == 0:
            raise t.error("max_depth", "must be -1 (unlimited) or >= 1, got 0")
        return cls(
            spp_train=t.int("spp_train", lo=1, hi=2**20),
            spp_test=t.int("spp_test", lo=1, hi=2**20),
            max_depth=max_depth,
            seed=t.int("seed", 0, lo=0, hi=2**32 - 1),
            noise_floor=t.bool("noise_floor", True),
        )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# --------------------------------------------------------------------------- scene


@dataclass(frozen=True)
class SceneSpec:
    """A whole scene. ``source`` (the file it came from) is not part of equality or the hash."""

    name: str
    description: str
    volume: VolumeSpec
    lights: tuple[LightSpec, ...]
    cameras: CameraRigSpec
    render: RenderSpec
    source: str | None = field(default=None, compare=False)

    FIELDS: ClassVar[tuple[str, ...]] = ("name", "description", "volume", "lights", "cameras", "render")

    @property
    def environment(self) -> LightSpec | None:
        """The environment light (constant or sky) that camera rays see, or None."""
        return next((l for l in self.lights if l.is_environment), None)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (TOML/JSON types) that :func:`parse_scene` turns back into an equal spec."""
        return {
            "name": self.name,
            "description": self.description,
            "volume": self.volume.to_dict(),
            "lights": [l.to_dict() for l in self.lights],
            "cameras": self.cameras.to_dict(),
            "render": self.render.to_dict(),
        }

    def with_overrides(self, overrides: Mapping[str, Any]) -> "SceneSpec":
        """A copy with dotted fields replaced (``{"cameras.width": 16, "lights.0.radiance": [1, 1, 1]}``),
        validated again. Integer path parts index the ``lights`` list."""
        data = self.to_dict()
        source = f"{self.source or '<spec>'} (with overrides)"
        for key, value in overrides.items():
            parts = str(key).split(".")
            node: Any = data
            for i, part in enumerate(parts):
                last = i == len(parts) - 1
                if isinstance(node, list):
                    if not part.isdigit() or int(part) >= len(node):
                        raise SpecError(source, key, f"no item {part!r} (there are {len(node)})")
                    part = int(part)
                elif not isinstance(node, dict):
                    raise SpecError(source, key, f"cannot override inside {'.'.join(parts[:i])!r}: not a table")
                if last:
                    node[part] = _thaw(value)
                else:
                    if isinstance(node, dict) and part not in node:
                        node[part] = {}
                    node = node[part]
        return parse_scene(data, source)

    def content_hash(self, extra: Mapping[str, Any] | None = None) -> str:
        """sha256 (hex) of the canonical JSON of :meth:`to_dict` and ``extra``.

        ``description`` is left out: rewording a scene must not invalidate its datasets.
        """
        spec = self.to_dict()
        del spec["description"]
        text = json.dumps(
            {"spec": spec, "extra": _thaw(dict(extra or {}))},
            sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False,
        )
        return hashlib.sha256(text.encode("utf-8")).hexdigest()


def parse_scene(data: Mapping[str, Any], source: str | os.PathLike | None = None) -> SceneSpec:
    """Validate plain data (a parsed TOML document) into a :class:`SceneSpec`."""
    source = str(source) if source is not None else "<spec>"
    t = _Table(data, source, "", SceneSpec.FIELDS)
    name = t.str("name")
    if not _NAME_RE.match(name):
        raise t.error("name", f"must be letters, digits, '_', '-' or '.', starting with a letter or digit; got {name!r}")
    description = t.str("description", "")
    volume = VolumeSpec.parse(t.table("volume"), source)
    raw_lights = t.get("lights", _MISSING, "one or more [[lights]] tables")
    if not isinstance(raw_lights, (list, tuple)) or not raw_lights:
        raise t.error("lights", f"must be one or more [[lights]] tables, got {raw_lights!r}")
    lights = tuple(_parse_light(l, source, f"lights.{i}") for i, l in enumerate(raw_lights))
    envs = [i for i, l in enumerate(lights) if l.is_environment]
    if len(envs) > 1:
        raise SpecError(
            source, f"lights.{envs[1]}.type",
            "at most one environment light (constant or sky) per scene; merge them into one",
        )
    return SceneSpec(
        name=name,
        description=description,
        volume=volume,
        lights=lights,
        cameras=CameraRigSpec.parse(t.table("cameras"), source),
        render=RenderSpec.parse(t.table("render"), source),
        source=source,
    )


# --------------------------------------------------------------------------- the library


def scenes_dir() -> Path:
    """The scene library: ``$MITSNERF_SCENES``, else ``scenes/`` at the repository root."""
    env = os.environ.get(SCENES_ENV)
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "scenes"


def list_scenes() -> list[str]:
    """Names of the specs in :func:`scenes_dir`, sorted."""
    d = scenes_dir()
    return sorted(p.stem for p in d.glob("*.toml")) if d.is_dir() else []


def load_scene(name_or_path: str | os.PathLike) -> SceneSpec:
    """Load a spec by library name (``"cloud"``) or by path (anything with a ``/`` or ending in ``.toml``)."""
    text = os.fspath(name_or_path)
    if isinstance(name_or_path, Path) or "/" in text or os.sep in text or text.endswith(".toml"):
        path = Path(text)
        if not path.is_file():
            raise SpecError(path, None, "no such spec file")
    else:
        path = scenes_dir() / f"{text}.toml"
        if not path.is_file():
            known = list_scenes()
            raise SpecError(
                path, None,
                f"unknown scene {text!r} (known: {', '.join(known) if known else f'none in {scenes_dir()}'})",
            )
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(path, None, f"TOML syntax error: {exc}") from None
    except OSError as exc:
        raise SpecError(path, None, f"cannot read: {exc.strerror or exc}") from None
    return parse_scene(data, path)
