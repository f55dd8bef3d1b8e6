"""Scene specifications: TOML files (the library: ``mitsnerf/scene/library/NAME.toml``) parsed into frozen,
validated dataclasses.

A spec names a volume (a :mod:`mitsnerf.volumes` family, its grid and optical thickness), the
lights, a camera rig and the render settings; see ``docs/conventions.md`` ("Scene specs") for
the file format. Every problem with a spec raises :class:`mitsnerf.errors.SpecError` naming the
file and the dotted field::

    >>> parse_scene({"name": "x", "volume": {"family": "cloud"}}, "inline.toml")
    Traceback (most recent call last):
    ...
    mitsnerf.errors.SpecError: inline.toml: volume.resolution: missing field (an integer in [8, 512])

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
import hashlib
import json
import math
import os
import re
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, ClassVar

from mitsnerf.config import (
    apply_overrides,
    from_dict,
    named_files,
    param,
    plain,
    read_toml,
    search_dirs,
    source_field,
    to_dict,
    with_overrides,
)
from mitsnerf.errors import SpecError

#: The world's up axis (Z-up). Rigs' "upper half" and the sky's zenith are +Z.
UP = (0.0, 0.0, 1.0)
#: Environment variable listing a user's scene directories (``os.pathsep``-separated), searched
#: before the library shipped with the package (``mitsnerf --scenes DIR`` adds to it).
SCENES_ENV = "MITSNERF_SCENES"
#: The scene library, package data.
LIBRARY = Path(__file__).resolve().parent / "library"
RIGS = ("sphere", "hemisphere", "ring")
#: Cameras must stay outside the scene box's bounding sphere (radius sqrt(3)/2 times ``world.scale``).
MIN_CAMERA_RADIUS = math.sqrt(3.0) / 2.0
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


def _freeze(obj: Any) -> Any:
    """Deep read-only copy: tables become mapping proxies, lists tuples."""
    if isinstance(obj, Mapping):
        return MappingProxyType({str(k): _freeze(v) for k, v in obj.items()})
    if isinstance(obj, (list, tuple)):
        return tuple(_freeze(v) for v in obj)
    return obj


def absolute_path(path: Path) -> Path:
    """``path`` absolute, its directory's symlinks and ``..`` resolved and its own name kept: a link to a grid
    stays the link, so a broken link or a symlink loop is reported as itself when the file is opened.

    >>> absolute_path(Path("/a/../b.npy"))
    PosixPath('/b.npy')
    """
    full = Path(os.path.abspath(path))
    try:
        return full.parent.resolve() / full.name
    except (OSError, RuntimeError):  # a loop among the directories: opening the file names it
        return full


def _not_all_zero(name: str, v: tuple[float, float, float] | None) -> None:
    if v is not None and not any(v):
        raise ValueError(f"{name}: must be 3 numbers, not all zero, got {list(v)}")


# --------------------------------------------------------------------------- volume

#: The largest ``volume.sigma_t_scale`` (extinction per box side: ``sigma_t`` is it divided by ``world.scale``).
SIGMA_T_SCALE_MAX = 1e4


@dataclass(frozen=True)
class IsotropicPhase:
    """Isotropic scattering, ``p(d, w) = 1 / (4 pi)`` (Mitsuba's ``isotropic``): the default. For it volpath's
    image is exactly the emission-absorption integral with a direction-free colour (the oracle's premise)."""

    config_kind: ClassVar[str] = "phase function"
    type: ClassVar[str] = "isotropic"

    def mitsuba(self) -> dict[str, Any]:
        """The phase plugin's ``mi.load_dict`` entry."""
        return {"type": "isotropic"}


@dataclass(frozen=True)
class HGPhase:
    """Henyey-Greenstein scattering (Mitsuba's ``hg``), ``p(cos theta) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos
    theta)^(3/2))`` with ``theta`` the angle between the incident light's travel and the scattered direction:
    ``g > 0`` scatters forward (water clouds about 0.85), ``g < 0`` backward, ``g = 0`` is isotropic. ``g`` is
    always written: Mitsuba's own default (0.8) is never taken silently."""

    config_kind: ClassVar[str] = "phase function"
    type: ClassVar[str] = "hg"
    g: float = param(lo=-1.0, hi=1.0, lo_open=True, hi_open=True, doc="the mean cosine of the scattering angle")

    def mitsuba(self) -> dict[str, Any]:
        return {"type": "hg", "g": float(self.g)}


Phase = IsotropicPhase | HGPhase
#: The phase functions by TOML ``type``.
PHASE_TYPES: dict[str, type] = {c.type: c for c in typing.get_args(Phase)}


def is_isotropic(phase: Phase) -> bool:
    """Whether ``phase`` scatters uniformly (``isotropic``, or ``hg`` with ``g = 0``).

    >>> is_isotropic(IsotropicPhase()), is_isotropic(HGPhase(g=0.0)), is_isotropic(HGPhase(g=0.85))
    (True, True, False)
    """
    return isinstance(phase, IsotropicPhase) or (isinstance(phase, HGPhase) and phase.g == 0.0)


@dataclass(frozen=True, kw_only=True)
class VolumeSpec:
    """The medium: a volume family evaluated on an ``R^3`` grid and its optical thickness.

    ``sigma_t = sigma_t_scale * density / world.scale`` in world units, density in [0, 1]: the
    optical depth across the box is ``sigma_t_scale`` times the mean density whatever the scale.
    ``sigma_t_scale`` may be an RGB triple: chromatic extinction, ``sigma_t`` a 3-channel grid
    (channel ``k`` is ``sigma_t_scale[k] * density / world.scale``), as Mitsuba's ``*_rgb`` variants
    take it (each path follows one colour channel).
    ``params`` holds the family's parameters with every default filled in (converted by
    :func:`mitsnerf.config.from_dict` against the family's params dataclass), read-only.
    """

    family: str = param(doc="a mitsnerf.volumes family: cloud, plume, blobs, shell, lattice, nebula; grid (a file)")
    resolution: int = param(lo=8, hi=512, doc="grid R (R^3 voxels)")
    seed: int = param(0, lo=0, hi=2**32 - 1, doc="the family's seed")
    sigma_t_scale: float | tuple[float, float, float] = param(
        lo=0.0, hi=SIGMA_T_SCALE_MAX, lo_open=True,
        doc="sigma_t = sigma_t_scale * density / world.scale (density in [0, 1]); an RGB triple [r, g, b]: "
            "chromatic extinction, a 3-channel sigma_t",
                                 hi_why=f"a mean free path below {1 / SIGMA_T_SCALE_MAX:g} of the box side is under "
                                        "1/19 of the finest grid's voxel (1/512 of it): the medium would render as an "
                                        "opaque surface")
    params: Mapping[str, Any] = param(default_factory=lambda: MappingProxyType({}),
                                      doc="the family's parameters; defaults are filled in (and hashed)")
    phase: Phase = param(default_factory=IsotropicPhase,
                         doc='the phase function: { type = "isotropic" } (the default) or { type = "hg", g = G }')

    def __post_init__(self) -> None:
        from mitsnerf import volumes

        registry = volumes.families()
        problem = registry.why_not(self.family)
        if problem:
            raise ValueError(f"family: {problem}")
        params = from_dict(registry[self.family].params_type, self.params, prefix="params")
        object.__setattr__(self, "params", _freeze(to_dict(params)))  # the filled-in, read-only table
        if getattr(params, "values", "density") == "sigma_t" and self.sigma_t_scale != 1.0:
            raise ValueError(f"sigma_t_scale: must be 1 when params.values is 'sigma_t' (the grid is the "
                             f"extinction itself, not scaled), got {self.sigma_t_scale}")

    @property
    def chromatic(self) -> bool:
        """Whether the extinction depends on the colour channel (``sigma_t_scale`` an RGB triple).

        >>> VolumeSpec(family="cloud", resolution=8, sigma_t_scale=(4.0, 6.0, 9.0)).chromatic
        True
        """
        return isinstance(self.sigma_t_scale, tuple)

    @property
    def sigma_t_rgb(self) -> tuple[float, float, float]:
        """``sigma_t_scale`` per colour channel (a scalar repeated three times)."""
        s = self.sigma_t_scale
        return s if isinstance(s, tuple) else (s, s, s)

    @property
    def file_fields(self) -> tuple[str, ...]:
        """The family's parameters that name input files (:attr:`mitsnerf.volumes.base.Family.files`)."""
        from mitsnerf import volumes

        return tuple(volumes.families()[self.family].files)

    def input_files(self) -> dict[str, Path]:
        """``params.FIELD -> path`` of every input file the family reads (the fields that are set)."""
        return {f"params.{f}": Path(self.params[f]) for f in self.file_fields if self.params.get(f)}

    def with_files_under(self, base: Path) -> VolumeSpec:
        """A copy whose relative input-file paths are resolved against ``base`` (absolute, normalised:
        :func:`absolute_path`)."""
        moved = {f: str(absolute_path(base / self.params[f])) for f in self.file_fields
                 if self.params.get(f) and not Path(self.params[f]).is_absolute()}
        return dataclasses.replace(self, params={**self.params, **moved}) if moved else self

    def check_inputs(self) -> None:
        """Every input file is a file, then the family's checks of them that need not read them whole (a
        header's shape: :attr:`mitsnerf.volumes.base.Family.check`); a SpecError naming the file."""
        from mitsnerf import volumes

        self._check_files()
        family = volumes.families()[self.family]
        if family.check is not None:
            family.check(volumes.make_params(self.family, self.params))

    def _check_files(self) -> None:
        """A SpecError naming the first input file that is no file (missing, a directory, a loop) and its field."""
        from mitsnerf.data.arrays import file_problem

        for field, path in self.input_files().items():
            problem = file_problem(path, "grid file")
            if problem is not None:
                raise SpecError(path, None, f"{problem} (volume.{field})")

    def input_digests(self) -> dict[str, str]:
        """``params.FIELD -> sha256`` of every input file's content (what a dataset's key covers
        instead of the path); a SpecError naming a file that cannot be read."""
        from mitsnerf.data.cache import sha256_file

        self._check_files()
        return {field: sha256_file(path) for field, path in self.input_files().items()}

    def __hash__(self) -> int:  # params is a read-only mapping, which Python does not hash
        return hash(json.dumps(to_dict(self), sort_keys=True))


# --------------------------------------------------------------------------- lights


@dataclass(frozen=True)
class LightSpec:
    """Base of the light kinds; ``type`` is the TOML ``type`` key. See :data:`LIGHT_TYPES`."""

    config_kind: ClassVar[str] = "light"
    type: ClassVar[str] = ""
    #: An environment light is seen by camera rays (at most one per scene, Mitsuba's rule).
    is_environment: ClassVar[bool] = False

    def to_dict(self) -> dict[str, Any]:
        return to_dict(self)


def _rgb(doc: str, default: Any = dataclasses.MISSING) -> Any:
    """A linear RGB colour field: 3 numbers >= 0."""
    return param(default, lo=0.0, doc=doc)


@dataclass(frozen=True)
class ConstantLight(LightSpec):
    """Uniform environment: the same ``radiance`` (RGB, linear) from every direction."""

    radiance: tuple[float, float, float] = _rgb("radiance from every direction")
    type: ClassVar[str] = "constant"
    is_environment: ClassVar[bool] = True


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

    zenith: tuple[float, float, float] = _rgb("radiance straight up (+z)")
    horizon: tuple[float, float, float] = _rgb("radiance at the horizon")
    ground: tuple[float, float, float] = _rgb("radiance straight down")
    sun_direction: tuple[float, float, float] | None = param(None, doc="the way sunlight travels (no glow if unset)")
    sun_glow: tuple[float, float, float] = _rgb("radiance of the glow around the sun", (0.0, 0.0, 0.0))
    sun_sharpness: float = param(200.0, lo=1.0, hi=1e5, doc="how tight the glow is")
    scale: float = param(1.0, lo=0.0, lo_open=True, doc="multiplies the whole sky")
    resolution: int = param(256, lo=8, hi=4096, doc="bitmap width (height width / 2)")
    type: ClassVar[str] = "sky"
    is_environment: ClassVar[bool] = True

    def __post_init__(self) -> None:
        _not_all_zero("sun_direction", self.sun_direction)


@dataclass(frozen=True)
class DirectionalLight(LightSpec):
    """A sun at infinity: ``direction`` is the way the light travels, ``irradiance`` RGB (W/m^2)."""

    direction: tuple[float, float, float] = param(doc="the way the light travels (need not be normalised)")
    irradiance: tuple[float, float, float] = _rgb("irradiance, W/m^2")
    type: ClassVar[str] = "directional"

    def __post_init__(self) -> None:
        _not_all_zero("direction", self.direction)


@dataclass(frozen=True)
class PointLight(LightSpec):
    """An isotropic point light at ``position`` with radiant ``intensity`` RGB (W/sr)."""

    position: tuple[float, float, float] = param(doc="world position")
    intensity: tuple[float, float, float] = _rgb("radiant intensity, W/sr")
    type: ClassVar[str] = "point"


#: A light of any kind: a table picks its kind by its ``type`` key.
Light = ConstantLight | SkyLight | DirectionalLight | PointLight
#: The light kinds by TOML ``type``.
LIGHT_TYPES: dict[str, type[LightSpec]] = {c.type: c for c in typing.get_args(Light)}


# --------------------------------------------------------------------------- cameras, render


@dataclass(frozen=True)
class CameraRigSpec:
    """Where the cameras are (see :mod:`mitsnerf.scene.rigs`): all look at the origin from ``radius``.

    ``fov`` is the horizontal field of view in degrees; images are ``width x height``.
    """

    rig: str = param(choices=RIGS, doc="see mitsnerf/scene/rigs.py")
    n_train: int = param(lo=1, hi=10000, doc="training views")
    n_test: int = param(lo=1, hi=10000, doc="test views")
    width: int = param(lo=1, hi=8192, doc="image width, pixels")
    height: int = param(lo=1, hi=8192, doc="image height, pixels")
    fov: float = param(lo=0.0, hi=180.0, lo_open=True, hi_open=True, doc="horizontal field of view, degrees")
    radius: float = param(lo=0.0, hi=1e4, lo_open=True,
                          doc="camera distance from the origin in world units, outside the box's bounding "
                              "sphere (> world.scale * sqrt(3)/2)")
    seed: int = param(0, lo=0, hi=2**32 - 1, doc="rig randomisation (rotation of the sphere, azimuths)")


@dataclass(frozen=True)
class RenderSpec:
    """Mitsuba ``volpath`` settings. ``max_depth = -1`` is unlimited (a cap loses energy in thick
    media). ``noise_floor`` renders the test cameras a second time with another seed (``test_ref``).
    """

    spp_train: int = param(lo=1, hi=2**20, doc="samples per pixel of the training views")
    spp_test: int = param(lo=1, hi=2**20, doc="samples per pixel of the test views (and test_ref)")
    max_depth: int = param(-1, lo=-1, hi=100000, doc="volpath depth; -1 or >= 1; -1 unlimited")
    seed: int = param(0, lo=0, hi=2**32 - 1, doc="base of the per-view render seeds")
    noise_floor: bool = param(True, doc="also render test_ref and measure the noise floor")

    def __post_init__(self) -> None:
        if self.max_depth == 0:
            raise ValueError("max_depth: must be -1 (unlimited) or >= 1, got 0")


# --------------------------------------------------------------------------- world


#: ``world.scale`` that puts the box at NeRF-synthetic's ``[-1.5, 1.5]^3``.
NERF_SYNTHETIC_SCALE = 3.0
#: Camera distance of the NeRF-synthetic scenes (about 4.03): with their fixed ``near = 2``,
#: ``far = 6`` a camera there sees everything within 2 of the origin, the box's inscribed ball.
NERF_SYNTHETIC_RADIUS = 4.0


@dataclass(frozen=True)
class WorldSpec:
    """Where the medium sits in world units.

    The volume families are authored in the box ``[-0.5, 0.5]^3``; the scene box is
    ``scale * [-0.5, 0.5]^3`` and ``sigma_t = volume.sigma_t_scale * density / scale``, so the
    optical depth along any chord of the box, and the images from cameras ``scale`` times
    farther away, do not change. Cameras (``cameras.radius``) and point lights are in world
    units. ``scale = 3`` (:data:`NERF_SYNTHETIC_SCALE`) is NeRF-synthetic's box ``[-1.5, 1.5]^3``.
    """

    scale: float = param(1.0, lo=0.0, hi=1e4, lo_open=True,
                         doc="the box is scale * [-0.5, 0.5]^3 and sigma_t is divided by scale "
                             "(3: NeRF-synthetic's [-1.5, 1.5]^3)")


def nerf_synthetic_overrides() -> dict[str, Any]:
    """``SceneSpec.with_overrides`` keys that write a scene at the NeRF-synthetic scale: the box at
    ``[-1.5, 1.5]^3`` and the cameras at radius 4, where those readers' fixed near/far (2, 6) see
    the whole inscribed ball of the box (``mitsnerf generate --nerf-synthetic``).

    >>> nerf_synthetic_overrides()
    {'world.scale': 3.0, 'cameras.radius': 4.0}
    """
    return {"world.scale": NERF_SYNTHETIC_SCALE, "cameras.radius": NERF_SYNTHETIC_RADIUS}


# --------------------------------------------------------------------------- scene


@dataclass(frozen=True, kw_only=True)
class SceneSpec:
    """A whole scene. ``source`` (the file it came from) is not part of equality or the hash."""

    name: str = param(doc="dataset directory prefix: letters, digits, '_', '-', '.'")
    description: str = param("", doc="one line; not part of the hash")
    volume: VolumeSpec = param(doc="the medium")
    lights: tuple[Light, ...] = param(doc="one or more [[lights]] tables; at most one environment (constant or sky)")
    cameras: CameraRigSpec = param(doc="the camera rig")
    render: RenderSpec = param(doc="volpath settings")
    world: WorldSpec = param(default_factory=WorldSpec, doc="the box in world units (a scale)")
    source: str | None = source_field()

    def __post_init__(self) -> None:
        # input files are relative to the spec file's directory (a spec without a file: the working directory)
        object.__setattr__(self, "volume", self.volume.with_files_under(_directory_of(self.source)))
        if not _NAME_RE.match(self.name):
            raise ValueError(
                f"name: must be letters, digits, '_', '-' or '.', starting with a letter or digit; got {self.name!r}")
        if not self.lights:
            raise ValueError("lights: must be one or more [[lights]] tables, got []")
        least = self.world.scale * MIN_CAMERA_RADIUS
        if self.cameras.radius <= least:
            raise ValueError(f"cameras.radius: must be > {least:.4f} (outside the scene box's bounding sphere, "
                             f"sqrt(3)/2 times world.scale {self.world.scale:g}), got {self.cameras.radius:g}")
        envs = [i for i, light in enumerate(self.lights) if light.is_environment]
        if len(envs) > 1:
            raise ValueError(f"lights.{envs[1]}.type: at most one environment light (constant or sky) per scene; "
                             "merge them into one")

    @property
    def environment(self) -> LightSpec | None:
        """The environment light (constant or sky) that camera rays see, or None."""
        return next((light for light in self.lights if light.is_environment), None)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (TOML/JSON types) that :func:`parse_scene` turns back into an equal spec.

        The default ``world`` and the default (isotropic) ``volume.phase`` are left out, so specs written before
        they existed keep their hashes.
        """
        data = to_dict(self)
        if self.world == WorldSpec():
            del data["world"]
        if self.volume.phase == IsotropicPhase():  # as the default world: older specs keep their hashes
            del data["volume"]["phase"]
        return data

    def with_overrides(self, overrides: Mapping[str, Any]) -> SceneSpec:
        """A copy with dotted fields replaced (``{"cameras.width": 16, "lights.0.radiance": [1, 1, 1]}``),
        validated again. Integer path parts index the ``lights`` list."""
        return with_overrides(self, overrides, f"{self.source or '<spec>'} (with overrides)")

    def content_hash(self, extra: Mapping[str, Any] | None = None) -> str:
        """sha256 (hex) of the canonical JSON of :meth:`to_dict` and ``extra``.

        ``description`` is left out: rewording a scene must not invalidate its datasets. An input
        file (a ``grid`` volume's) counts by its content's sha256, not its path: editing the file
        changes the hash, moving it does not.
        """
        spec = self.to_dict()
        del spec["description"]
        for field, digest in self.volume.input_digests().items():  # a file's content, not where it lies
            spec["volume"]["params"][field.split(".", 1)[1]] = {"sha256": digest}
        text = json.dumps(
            {"spec": spec, "extra": plain(dict(extra or {}))},
            sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False,
        )
        return hashlib.sha256(text.encode("utf-8")).hexdigest()


#: The key of a spec that starts from another: a library scene's name or a spec file's path.
EXTENDS = "extends"
#: How a spec that extends another is merged into it (the README and the errors of such a spec say it).
MERGE_RULE = ("a table merges into the base's key by key, a list or a value replaces the base's whole; a table whose "
              "type changes (volume.phase) is replaced whole, and so is volume.params when volume.family changes")
#: The tables every spec needs, which ``extends`` can supply.
_REQUIRED = ("name", "volume", "lights", "cameras", "render")


def parse_scene(data: Mapping[str, Any], source: str | os.PathLike | None = None) -> SceneSpec:
    """Validate plain data (a parsed TOML document) into a :class:`SceneSpec`; with ``extends``, over the spec it
    names (:func:`merge_specs`; a path relative to ``source``'s directory, else the working directory)."""
    where = source if source is not None else "<spec>"
    return _parse(data, where, _chain_start(where))


def merge_specs(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``over`` (what a spec says) merged into ``base`` (the spec it extends), as :data:`MERGE_RULE` says.

    >>> merge_specs({"cameras": {"width": 64, "fov": 40}, "lights": [1, 2]}, {"cameras": {"width": 16}, "lights": [3]})
    {'cameras': {'width': 16, 'fov': 40}, 'lights': [3]}
    >>> merge_specs({"volume": {"family": "cloud", "resolution": 64, "params": {"octaves": 4}}},
    ...             {"volume": {"family": "grid", "params": {"path": "g.npy"}}})
    {'volume': {'family': 'grid', 'resolution': 64, 'params': {'path': 'g.npy'}}}
    >>> merge_specs({"phase": {"type": "hg", "g": 0.85}}, {"phase": {"type": "isotropic"}})
    {'phase': {'type': 'isotropic'}}
    """
    out = dict(base)
    for key, value in over.items():
        old = out.get(key)
        if (isinstance(value, Mapping) and isinstance(old, Mapping)
                and value.get("type", old.get("type")) == old.get("type")):
            if value.get("family", old.get("family")) != old.get("family"):
                old = {k: v for k, v in old.items() if k != "params"}
            out[key] = merge_specs(old, value)
        else:
            out[key] = value
    return out


def _directory_of(source: Any) -> Path:
    """Where the paths a spec names are relative to: its file's directory, else (no file) the working directory."""
    path = Path(os.fspath(source)) if isinstance(source, (str, os.PathLike)) else None
    return path.parent if path is not None and path.is_file() else Path.cwd()


def _chain_start(source: Any) -> tuple[str, ...]:
    """The specs being read when ``source`` is: itself, if it is a file."""
    path = Path(os.fspath(source)) if isinstance(source, (str, os.PathLike)) else None
    return (str(absolute_path(path)),) if path is not None and path.is_file() else ()


def _parse(data: Mapping[str, Any], source: Any, chain: tuple[str, ...]) -> SceneSpec:
    """:func:`parse_scene`, ``chain`` the spec files being read (each extending the next): a cycle is refused."""
    if EXTENDS not in data:
        try:
            return from_dict(SceneSpec, data, source=source)
        except SpecError as exc:
            if exc.field in _REQUIRED and exc.message.startswith("missing field"):
                raise SpecError(exc.where, exc.field, f"{exc.message}; or start from a library scene "
                                                      f'(extends = "cloud") and give only what differs') from None
            raise
    ref = data[EXTENDS]
    base_path = _base_path(ref, source)
    key = str(absolute_path(base_path))
    if key in chain:
        raise SpecError(source, EXTENDS, f"a cycle: {' -> '.join((*chain, key))}")
    base = _parse(read_toml(base_path, "a spec file"), base_path, (*chain, key))
    merged = merge_specs(base.to_dict(), {k: v for k, v in data.items() if k != EXTENDS})
    try:
        return from_dict(SceneSpec, merged, source=source)
    except SpecError as exc:
        raise SpecError(exc.where, exc.field, f"{exc.message}; this spec extends {ref!r}: {MERGE_RULE}") from None


def _base_path(ref: Any, source: Any) -> Path:
    """The spec file ``extends = ref`` names: a library scene's (or ``--scenes`` DIR's), or a path relative to the
    extending spec's directory."""
    if not isinstance(ref, str) or not ref:
        raise SpecError(source, EXTENDS, f"must be a library scene's name or a spec file's path, got {ref!r}")
    if is_spec_path(ref):
        path = Path(ref) if Path(ref).is_absolute() else _directory_of(source) / ref
        if not path.exists():
            raise SpecError(source, EXTENDS, f"no such spec file {str(path)!r}")
        return path
    found = named_files(scene_dirs())
    if ref not in found:
        raise SpecError(source, EXTENDS, f"unknown scene {ref!r} (known: {', '.join(found)})")
    return found[ref]


# --------------------------------------------------------------------------- the library


def scenes_dir() -> Path:
    """The scene library shipped with the package (``mitsnerf/scene/library``)."""
    return LIBRARY


def scene_dirs() -> list[Path]:
    """Where scene names are looked up, first match first: ``$MITSNERF_SCENES``'s directories, then the library."""
    return search_dirs(SCENES_ENV, LIBRARY)


def list_scenes() -> list[str]:
    """Names of the specs in :func:`scene_dirs`, sorted."""
    return list(named_files(scene_dirs()))


def load_scene(name_or_path: str | os.PathLike) -> SceneSpec:
    """Load a spec by library name (``"cloud"``) or by path (anything with a ``/`` or ending in ``.toml``)."""
    path = _spec_path(name_or_path)
    return parse_scene(read_toml(path, "a spec file"), path)


def open_scene(name_or_path: str | os.PathLike, overrides: Mapping[str, Any] | None = None) -> SceneSpec:
    """What ``mitsnerf generate SCENE --set KEY=VALUE`` renders: a library scene or a spec file
    (:func:`load_scene`) with ``overrides`` applied, or a grid file's scene (:func:`grid_scene`) built with them."""
    if is_grid_path(name_or_path):
        return grid_scene(name_or_path, overrides=overrides)
    spec = load_scene(name_or_path)
    return spec.with_overrides(overrides) if overrides else spec


def is_grid_path(name_or_path: str | os.PathLike) -> bool:
    """Whether ``name_or_path`` names a grid file (``.npy``, ``.npz``, ``.vol``) rather than a spec.

    >>> is_grid_path("smoke.npy"), is_grid_path("data/smoke.VOL"), is_grid_path("cloud")
    (True, True, False)
    """
    from mitsnerf.volumes.grid import SUFFIXES

    return Path(os.fspath(name_or_path)).suffix.lower() in SUFFIXES


def grid_scene(path: str | os.PathLike, template: str = "cloud",
               overrides: Mapping[str, Any] | None = None) -> SceneSpec:
    """The library's ``template`` scene with its medium replaced by the grid in ``path``: family ``grid``
    (values a density, the template's ``sigma_t_scale``), named after the file, with ``overrides`` (dotted
    fields, as ``--set``) applied, and, unless they set ``volume.resolution``, at the grid's own resolution (its
    longest axis, kept in [8, 512], of the array ``volume.params.array`` names). What ``mitsnerf generate
    FILE.npy`` renders. The file's header is checked here (:func:`mitsnerf.volumes.grid.grid_header`)."""
    from mitsnerf.volumes import MAX_RESOLUTION, MIN_RESOLUTION
    from mitsnerf.volumes.grid import check_shape, grid_header

    path = absolute_path(Path(path))
    data = load_scene(template).to_dict()
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", path.stem).lstrip("_.-") or "grid"
    data.update(name=name, description=f"the grid in {path.name}")
    data["volume"] = {"family": "grid", "sigma_t_scale": data["volume"]["sigma_t_scale"],
                      "params": {"path": str(path)}}
    where = f"{path} (with overrides)" if overrides else str(path)
    data = apply_overrides(data, overrides or {}, where)
    volume = data.get("volume")
    own = not isinstance(volume, dict) or "resolution" in volume or volume.get("family") != "grid"
    if isinstance(volume, dict) and not own:
        volume["resolution"] = MIN_RESOLUTION  # for now: the grid's own once its path and array are known
    try:
        spec = parse_scene(data, path)
    except SpecError as exc:  # an override's problem: said as with_overrides says it
        raise SpecError(where if exc.where == str(path) else exc.where, exc.field, exc.message) from None
    if own:
        return spec
    params = spec.volume.params
    shape, _ = grid_header(params["path"], params["array"])
    check_shape(shape, params["path"], 1, "density")
    resolution = min(max(max(shape[:3]), MIN_RESOLUTION), MAX_RESOLUTION)
    return dataclasses.replace(spec, volume=dataclasses.replace(spec.volume, resolution=resolution))


def is_spec_path(name_or_path: str | os.PathLike) -> bool:
    """Whether ``name_or_path`` is a spec file's path rather than a library name.

    >>> is_spec_path("cloud"), is_spec_path("my_cloud.toml"), is_spec_path("specs/cloud")
    (False, True, True)
    """
    text = os.fspath(name_or_path)
    return isinstance(name_or_path, Path) or "/" in text or os.sep in text or text.endswith(".toml")


def _spec_path(name_or_path: str | os.PathLike) -> Path:
    """The file a scene name or spec path means; a SpecError if there is none."""
    text = os.fspath(name_or_path)
    if is_spec_path(name_or_path):
        path = Path(text)
        if not path.exists():
            raise SpecError(path, None, "no such spec file")
        return path  # a directory is reported by read_toml
    found = named_files(scene_dirs())
    if text in found:
        return found[text]
    if Path(text).is_dir():
        raise SpecError(text, None, "is a directory, not a scene name or spec file")
    where = ", ".join(map(str, scene_dirs()))
    raise SpecError(text, None, f"unknown scene {text!r} (known: {', '.join(found) if found else f'none in {where}'})")
