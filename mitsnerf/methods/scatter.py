"""``scatter``: emission-absorption whose colour is the single scattering of the scene's known lights through the
learned medium, plus a learned remainder.

What it knows that the emission-absorption methods do not: the dataset's spec gives it the delta lights (suns,
point lights: their directions, positions and power) and the phase function, as it gives ``mitsuba-inverse``
everything. The colour of a sample is then ``albedo(x) [sum_l p(w_l . d) E_l T_l(x) + Rem(x, d)]``
(:mod:`mitsnerf.fields.scatter`): the transmittance ``T_l`` to each light is marched through the density being
learned, so the density answers for the shadows it casts as well as for what the view rays cross, and the
remainder (the environment and all light scattered more than once) is smooth and acts through the phase
function's bands. With the true medium and the remainder at its best this is the oracle's colour at the
remainder's orders: the ceiling of this rung (docs/notes/scatter.md, "Its ceiling by basis").

The medium (``medium``): a hash grid and two small MLPs (``hash``, the ngp field's encoding) or dense grids
(``grid``, as ``voxel``: the density and albedo coarse to fine, the remainder on its own coarser grid, total
variation priors; train it with ``lr = 0.3``). The shadow cache is recomputed from the density at every training
step, inside the step's AD graph, and once per parameter change for evaluation; samples are skipped in empty
cells by an occupancy grid as in ``voxel`` and ``ngp``. ``carve``: the density is multiplied by the training
views' emptiness mask (:mod:`mitsnerf.math.carve`), built when the model is (from ``SceneInfo.train_views``), so no
haze grows, nor casts a shadow, where a view shows the background unattenuated. Foreign datasets (no manifest
spec: the lights are unknown) are refused in one line.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.fields.media import Carved, GridMedium, GridMediumConfig, HashMedium, HashMediumConfig, rest_start
from mitsnerf.fields.occupancy import OccupancyConfig
from mitsnerf.fields.scatter import ScatterField, ScatterFieldConfig
from mitsnerf.fields.voxel import total_variation, upsample
from mitsnerf.math.carve import carve
from mitsnerf.math.rays import fibonacci_directions, to_array3f
from mitsnerf.methods.base import (
    MethodConfig,
    ParameterShapeError,
    RenderOutput,
    SceneInfo,
    check_shapes,
    scene_spec,
)
from mitsnerf.methods.occupancy import OccupancyModel

MEDIA = ("hash", "grid")


@dataclass(frozen=True)
class ScatterMethodConfig(MethodConfig):
    """Configuration of the ``scatter`` method."""

    medium: str = param("hash", choices=MEDIA)
    """What holds the medium: ``hash`` (a hash grid and two small MLPs) or ``grid`` (dense grids; lr 0.3)."""
    field: ScatterFieldConfig = param(default_factory=ScatterFieldConfig)
    """The remainder's orders, the albedo's start and the shadow cache."""
    hash: HashMediumConfig = param(default_factory=HashMediumConfig)
    """The hash medium's sizes."""
    grid: GridMediumConfig = param(default_factory=GridMediumConfig)
    """The grid medium's activations and starts."""
    density_channels: int = param(0, choices=(0, 1, 3))
    """0: one density per colour where the dataset's extinction is chromatic (its spec's ``sigma_t_scale`` an RGB
    triple), else one; 1 or 3: as given."""
    resolution: int = param(64, lo=2, hi=512)
    """Grid medium: final resolution of the density (and albedo) grid."""
    initial_resolution: int = param(32, lo=2, hi=512)
    """Grid medium: the density grid's resolution at the start; doubled after each of ``upsample_steps``."""
    upsample_steps: tuple[int, ...] = param((150,), lo=0)
    """Grid medium: steps (0-based, increasing) after which the density (and albedo) grid is doubled."""
    albedo_resolution: int = param(0, lo=0, hi=512)
    """Grid medium: the albedo grid's resolution, fixed (0: the density grid's, doubled with it)."""
    rest_resolution: int = param(16, lo=1, hi=256)
    """Grid medium: the remainder grid's resolution (fixed: the multiply scattered light is smooth)."""
    tv_sigma: float = param(1e-3, lo=0.0)
    """Grid medium: weight of the total-variation prior on the raw density grid."""
    tv_albedo: float = param(1e-3, lo=0.0)
    """Grid medium: weight of the total-variation prior on the raw albedo grid."""
    tv_rest: float = param(1e-3, lo=0.0)
    """Grid medium: weight of the total-variation prior on the remainder grid."""
    n_samples: int = param(128, lo=1)
    """Stratified samples per ray."""
    carve: bool = param(True, since=("0.1.0+7e1ef78", False))
    """An emptiness mask from the training views (:mod:`mitsnerf.math.carve`): the density is 0 in every voxel that
    the ray of a pixel showing the background unattenuated crosses (``max over channels |image - background| <=
    carve_tol``), in the view rays and the shadows alike, so no haze grows where the views show none (false: none;
    a model built without the training views, ``SceneInfo.train_views``, needs false)."""
    carve_tol: float = param(1e-4, lo=0.0)
    """Largest ``|image - background|`` (linear radiance) of a pixel that counts as unattenuated."""
    carve_resolution: int = param(64, lo=2, hi=512)
    """Voxels per axis of the emptiness mask."""
    init_depth: float = param(5.0, lo=0.0, since=("0.1.0+28686ef", 0.0))
    """The density's start as an optical depth per box side (scale-free: ``sigma = init_depth / side``): the hash
    medium's density head starts there (its output bias ``log(sigma)``), the grid medium's grid too (for its
    ``grid.sigma_init``); 0: the medium's own start (hash: ``exp(0)``, 1 per world unit; grid: ``grid.sigma_init``).
    Carved to the views' hull, a thin start stays thin (docs/notes/scatter.md, "The emptiness mask and a scale-free
    start")."""
    use_occupancy: bool = param(True)
    """Skip samples in empty cells of an occupancy grid refreshed from the density."""
    occupancy: OccupancyConfig = param(default_factory=OccupancyConfig)
    """The occupancy grid's settings."""
    lr: float = param(1e-2, lo=0.0, lo_open=True)
    """Adam learning rate (the hash medium's; the grid medium trains with 0.3, as ``voxel``)."""

    def __post_init__(self) -> None:
        if isinstance(self.upsample_steps, list):
            object.__setattr__(self, "upsample_steps", tuple(self.upsample_steps))
        check_fields(self)
        doublings = (self.resolution // self.initial_resolution).bit_length() - 1
        if self.initial_resolution > self.resolution or self.initial_resolution << doublings != self.resolution:
            raise ValueError(f"resolution: must be initial_resolution ({self.initial_resolution}) times a power "
                             f"of 2, got {self.resolution}")
        if len(self.upsample_steps) != doublings or any(b <= a for a, b in zip(self.upsample_steps,
                                                                                 self.upsample_steps[1:])):
            raise ValueError(f"upsample_steps: {self.initial_resolution} -> {self.resolution} takes {doublings} "
                             f"increasing step(s), got {list(self.upsample_steps)}")

    def resolution_at(self, step: int) -> int:
        """The grid medium's density resolution at (0-based) ``step``."""
        return self.initial_resolution * 2 ** sum(1 for s in self.upsample_steps if step > s)


def field_config(config: ScatterMethodConfig, spec) -> ScatterFieldConfig:
    """The field's settings for a scene: the remainder cut to order 0 where the phase function is isotropic
    (every higher band is multiplied by ``g^l = 0``: parameters nothing would reach)."""
    if asymmetry(spec) == 0.0:
        return replace(config.field, remainder_degree=0, zonal_degree=0)
    return config.field


def asymmetry(spec) -> float:
    """The phase function's ``g`` (0 for an isotropic one)."""
    return float(getattr(spec.volume.phase, "g", 0.0))


def environment_mean(scene: SceneInfo, n: int = 1024) -> tuple[float, float, float]:
    """The background's mean radiance over the sphere (RGB): where the remainder starts, so that the medium's
    colour starts near the light around it rather than darker (a start that made clearing the density the
    fastest way to the images)."""
    with dr.suspend_grad():
        bg = scene.background(to_array3f(mi.Array3f, fibonacci_directions(n)))
        return tuple(float(dr.mean(c)[0]) if dr.width(c) > 1 else float(c[0]) for c in bg)  # type: ignore[return-value]


def make_medium(config: ScatterMethodConfig, spec, scene: SceneInfo, n_rest: int, seed: int):
    """The starting medium of ``config.medium`` for a scene."""
    channels = config.density_channels or (3 if spec.volume.chromatic else 1)
    first = rest_start(environment_mean(scene), n_rest)
    sigma = config.init_depth / float(np.mean(scene.box.size))
    if config.medium == "hash":
        medium = HashMedium(config.hash, mi.TensorXf, scene.box, channels, first, config.field.albedo_init, seed)
        if not sigma:
            return medium
        bias = np.asarray(medium.params["density.1.bias"], np.float32).copy()
        bias[:channels] = np.log(sigma)
        return medium.with_params({"density.1.bias": mi.TensorXf(bias)})
    r = config.initial_resolution
    resolutions = (r, config.albedo_resolution or r, config.rest_resolution)
    grid = replace(config.grid, sigma_init=sigma) if sigma else config.grid
    return GridMedium.create(grid, resolutions, mi.TensorXf, scene.box, channels, first, config.field.albedo_init)


def emptiness_mask(config: ScatterMethodConfig, scene: SceneInfo) -> Carved:
    """The training views' emptiness mask at ``carve_resolution`` (``carve = true``), built from
    ``scene.train_views``."""
    views = scene.train_views
    if views is None:
        raise ValueError("carve: needs the training views (SceneInfo.train_views), and none were given: give them, "
                         "or set carve = false")
    keep = carve(views.images, views.cameras, scene.background, scene.box, config.carve_resolution,
                 config.carve_tol, views.pixel_center)
    return Carved(keep, scene.box)


class ScatterModel(OccupancyModel):
    name = "scatter"
    config_type = ScatterMethodConfig
    description = ("knows the lights and the phase function: single scattering through the learned medium, "
                   "a learned remainder")
    knows = ("lights", "phase function")
    rung = "single scattering"
    tiny = MappingProxyType({"resolution": 8, "initial_resolution": 4, "upsample_steps": [3], "rest_resolution": 2,
                             "n_samples": 16, "hash": {"n_levels": 2, "log2_hashmap_size": 10, "base_resolution": 8,
                                                       "max_resolution": 16, "hidden": 8, "color_hidden": 8},
                             "field": {"shadow_resolution": 4, "shadow_samples": 4, "shadow_density_resolution": 4,
                                       "zonal_degree": 2},
                             "occupancy": {"resolution": 8, "update_every": 2}})

    def __init__(self, config: ScatterMethodConfig, scene: SceneInfo, seed: int = 0) -> None:
        from mitsnerf.scene.lights import delta_lights

        spec = scene_spec(scene, self.name, "its spec gives the lights and the phase function")
        self.config = config
        lights = delta_lights(spec.lights)
        fc = field_config(config, spec)
        medium = make_medium(config, spec, scene, 3 * fc.n_remainder(len(lights)), seed)
        field = ScatterField(fc, medium, scene.box, lights, asymmetry(spec))
        if config.carve:
            field = field.with_keep(emptiness_mask(config, scene))
        super().__init__(field, config.occupancy if config.use_occupancy else None, scene, seed, config.n_samples)

    def parameters(self) -> Mapping[str, Any]:
        return self.base_field.medium.params

    def rung_basis(self) -> tuple[int, int]:
        c = self.base_field.config
        return c.remainder_degree, c.zonal_degree

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """New values of the medium's parameters (a grid medium's density and albedo grids may come at another
        resolution: a resumed run may hold upsampled ones); the shadows are recomputed before the next render."""
        medium = self.base_field.medium
        new = {k: values[k] for k in medium.params if k in values}
        if not new:
            return
        if isinstance(medium, GridMedium):
            self._check_grids({**medium.params, **new})
        else:
            check_shapes(medium.params, new)
        self.base_field = self.base_field.with_medium(medium.with_params(new))

    def _check_grids(self, grids: Mapping[str, Any]) -> None:
        sigma = grids["sigma_raw"]
        r = int(sigma.shape[0]) if sigma.ndim == 4 else 0
        current = self.base_field.medium.params
        expected = {"sigma_raw": (r, r, r, current["sigma_raw"].shape[-1]),
                    "albedo_raw": (self.config.albedo_resolution or r,) * 3 + (3,),
                    "rest": tuple(current["rest"].shape)}
        for key, shape in expected.items():
            if r < 1 or tuple(grids[key].shape) != shape:
                raise ParameterShapeError(key, tuple(grids[key].shape), shape)

    def _shadowed(self) -> None:
        """Compute the shadows of the current parameters once, outside any AD graph (evaluation, export)."""
        if self.base_field.shadows is None:
            with dr.suspend_grad():
                self.base_field = self.base_field.with_shadows()

    def field(self):
        self._shadowed()
        return super().field()

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        if training:  # inside this step's AD graph: the loss reaches the density along the shadow rays
            self.base_field = self.base_field.with_shadows()
        else:
            self._shadowed()
        return RenderOutput(self.composite(o, d, u, training), self._priors() if training else {})

    def _priors(self) -> dict:
        """The grid medium's total-variation priors (``extra_losses``); none for the hash medium."""
        medium, cfg = self.base_field.medium, self.config
        if not isinstance(medium, GridMedium):
            return {}
        out = {}
        for key, weight, name in (("tv_sigma", cfg.tv_sigma, "sigma_raw"), ("tv_albedo", cfg.tv_albedo, "albedo_raw"),
                                  ("tv_rest", cfg.tv_rest, "rest")):
            grid = medium.params[name]
            if weight > 0 and grid.shape[0] > 1:
                out[key] = weight * total_variation(grid)
        return out

    def after_step(self, step: int, params: Mapping[str, Any]) -> Mapping[str, Any]:
        """A grid medium's density (and albedo) grids doubled after a step listed in ``upsample_steps`` (their
        Adam state restarts); the occupancy grid refreshed every ``occupancy.update_every`` steps."""
        new = {}
        if isinstance(self.base_field.medium, GridMedium) and step in self.config.upsample_steps:
            r = self.config.resolution_at(step + 1)
            keys = ("sigma_raw",) if self.config.albedo_resolution else ("sigma_raw", "albedo_raw")
            new = {key: upsample(params[key], r) for key in keys}
            self.set_parameters(new)
        super().after_step(step, params)
        return new


#: The method this module declares (:mod:`mitsnerf.methods` registers it as ``scatter``).
METHOD = ScatterModel
