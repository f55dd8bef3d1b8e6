"""``mitsuba-inverse``: optimise a heterogeneous medium through Mitsuba's differentiable volumetric path tracer.

The physically based route, after Mitsuba's volume optimisation tutorial: the scene is the
dataset's own (its manifest's spec through :func:`mitsnerf.scene.to_mitsuba.scene_dict`:
the same lights, the medium box, phase function) with the medium's grids replaced by the
unknowns, and each step renders training views with ``prbvolpath`` at low spp and
minimises

    L = mean over pixels and channels of (render(sigma_t, albedo; camera_i) - image_i)^2

with Adam on ``sigma_t`` (TensorXf (R, R, R, 1), extinction per unit length) and, unless
``optimize_albedo = false``, ``albedo`` (TensorXf (R, R, R, 3)). Gradients come from
``mi.render(scene, params, ...)``; the views and render seeds are drawn from the step's
generator, so a resumed run renders the same views with the same seeds.

Coarse to fine: the grids start at ``resolutions[0]`` and are resampled (trilinear,
``dr.resample``) to ``resolutions[l + 1]`` after step ``upsample_at[l]``; the optimiser's
state for them restarts then (their shape changed) and the learning rate is multiplied by
``upsample_lr_factor`` for every upsampling so far (a fixed rate diverged after upsampling
here). After every step ``sigma_t`` is clamped to ``[0, sigma_t_max]`` -- Mitsuba 3.9's
heterogeneous medium uses one global majorant, so a single spiking voxel would slow every
step -- and ``albedo`` to ``[0, 1]``.

What it knows that the emission-absorption methods do not: the dataset's spec gives it the lights
(the constant sky and the sun, with their radiance), the phase function, the medium's box and the path
length, so it fits only ``sigma_t`` and the albedo, and its ``sigma_t`` is an extinction in the same
units as the truth's; the other methods learn a radiance field that must also absorb the lighting.

The haze. Under a nearly uniform environment a scattering haze of the right albedo is almost invisible
(the white-furnace ambiguity), so from ``init_sigma_t = 1`` the images leave a haze of sigma_t ~ 5 in the
empty part of the box. The remedies, each a setting (benchmarks/README.md, "mitsuba-inverse: removing the
haze", measures each):

- ``carve``: an emptiness mask. A training pixel whose value is the environment seen straight through
  (``max over channels |image - background(d)| <= carve_tol``; in the generated datasets exactly the
  pixels whose samples all missed the medium) says the medium is empty along its ray, so every voxel that
  its centre ray crosses is held at 0 (space carving, at each resolution);
- ``l1``: a sparsity prior ``l1 * mean(sigma_t)`` in the loss;
- ``init_sigma_t``: a low start; a zero start needs ``majorant``, a fixed delta-tracking majorant
  (the grid's ``max_value``), since under the grid's own maximum a zero grid gets no collisions and so
  no gradient;
- ``views_per_step`` and ``spp_late`` / ``spp_late_at``: less noise in each step's gradient.

Mitsuba 3.9's ``prbvolpath`` has no other estimator to choose: its gradients of a heterogeneous medium
come from differentiable delta tracking (unbiased, one global majorant); the majorant is its one knob.

The settings (a bench file's ``[[methods]] config`` table, ``--set`` on the command line) are
:class:`MitsubaInverseConfig`'s fields.

Not supported: foreign datasets (no manifest spec: the lights are unknown), pixel centres
other than Mitsuba's ``+0.5``, per-ray rendering: it is a whole-view model
(:class:`mitsnerf.methods.base.ViewModel`). Evaluation renders whole cameras through Mitsuba's
film, which box-filters each pixel whatever footprint is asked for; the opacity and depth maps
come from emission-absorption quadrature of the current ``sigma_t`` grid over the same footprint.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.fields.grid import GridField
from mitsnerf.methods.base import MethodConfig, SceneInfo, StepLoss, ViewModel, scene_spec
from mitsnerf.render.camera import Rendered, render_view
from mitsnerf.render.volume import render_rays

SIGMA_T_SUFFIX = "interior_medium.sigma_t.data"
ALBEDO_SUFFIX = "interior_medium.albedo.data"
EVAL_SEED = 0x5EED


@dataclass(frozen=True)
class MitsubaInverseConfig(MethodConfig):
    """Configuration of the ``mitsuba-inverse`` method."""

    resolutions: tuple[int, ...] = param((16, 32, 64), lo=2, hi=512)
    """Grid resolution of each coarse-to-fine stage (one or more)."""
    upsample_at: tuple[int, ...] = param((100, 250), lo=1)
    """Step counts (increasing) after which the grids are resampled to the next resolution."""
    init_sigma_t: float = param(1.0, lo=0.0)
    """Initial constant extinction (world units^-1, at most ``sigma_t_max``)."""
    init_albedo: float = param(0.6, lo=0.0, hi=1.0)
    """Initial constant albedo."""
    optimize_albedo: bool = param(True)
    """Optimise the albedo grid too (else it stays ``init_albedo``)."""
    lr: float = param(0.5, lo=0.0, lo_open=True)
    """Adam learning rate of sigma_t (world units^-1 per step)."""
    albedo_lr_factor: float = param(0.04, lo=0.0, lo_open=True)
    """The albedo's learning rate relative to sigma_t's (albedo lives in [0, 1])."""
    upsample_lr_factor: float = param(0.5, lo=0.0, lo_open=True)
    """Learning-rate factor applied once per upsampling."""
    sigma_t_max: float = param(200.0, lo=0.0, lo_open=True)
    """Clamp of sigma_t after each step (one spiking voxel raises the global majorant)."""
    majorant: float = param(0.0, lo=0.0)
    """Fixed majorant of delta tracking (world units^-1; the sigma_t ``gridvolume``'s ``max_value``), and
    then the clamp of sigma_t too when below ``sigma_t_max``; 0: Mitsuba's default, the grid's maximum
    after each update. Differentiable delta tracking gets sigma_t's gradient only at the collisions,
    real and null, that it samples at this rate: a zero grid under the default majorant has none."""
    spp: int = param(8, lo=1)
    """Samples per pixel of each training render."""
    spp_late: int = param(0, lo=0)
    """Samples per pixel of the training renders from step ``spp_late_at`` on (0: ``spp`` throughout)."""
    spp_late_at: int = param(0, lo=0)
    """The step (0-based) from which training renders use ``spp_late`` samples per pixel."""
    views_per_step: int = param(1, lo=1)
    """Training views rendered per step; the image term is their mean squared error."""
    l1: float = param(0.0, lo=0.0)
    """Weight of the sparsity prior: ``l1 * mean over voxels of sigma_t`` (world units^-1) is added to
    the loss, so its gradient is ``l1 / R^3`` per voxel (0: no prior)."""
    carve: bool = param(False)
    """Emptiness mask: sigma_t is held at 0 in every voxel that a training pixel's centre ray crosses
    when that pixel shows the environment unattenuated (``max over channels |image - background(d)|
    <= carve_tol``: no sample of the pixel met the medium), at every resolution."""
    carve_tol: float = param(1e-4, lo=0.0)
    """Largest ``|image - background|`` (linear radiance) of a pixel that counts as unattenuated."""
    max_depth: int = param(0, lo=-1)
    """prbvolpath path length: 0 takes the dataset's ``render.max_depth`` (-1: unlimited)."""
    eval_spp: int = param(128, lo=1)
    """Samples per pixel of evaluation renders."""

    def __post_init__(self) -> None:
        check_fields(self)
        if not self.resolutions:
            raise ValueError("resolutions: must be one or more sizes, got []")
        if len(self.upsample_at) != len(self.resolutions) - 1:
            raise ValueError(f"upsample_at: needs {len(self.resolutions) - 1} steps (one per later resolution), "
                             f"got {list(self.upsample_at)}")
        if any(b <= a for a, b in zip(self.upsample_at, self.upsample_at[1:])):
            raise ValueError(f"upsample_at: must be increasing, got {list(self.upsample_at)}")
        if self.spp_late and not self.spp_late_at:
            raise ValueError("spp_late_at: needs the step from which spp_late applies (> 0), got 0")
        if self.init_sigma_t > self.sigma_t_max:
            raise ValueError(f"init_sigma_t: must be <= sigma_t_max ({self.sigma_t_max:g}), got {self.init_sigma_t:g}")
        if self.majorant and self.init_sigma_t > self.majorant:
            raise ValueError(f"init_sigma_t: must be <= majorant ({self.majorant:g}), got {self.init_sigma_t:g}")

    @property
    def sigma_t_clamp(self) -> float:
        """The largest sigma_t kept after a step: ``sigma_t_max``, or the fixed ``majorant`` if lower."""
        return min(self.sigma_t_max, self.majorant) if self.majorant else self.sigma_t_max


def unattenuated_pixels(images: np.ndarray, cameras, background, tol: float) -> list[np.ndarray]:
    """Per view, the pixels (H W,) bool whose value is the environment seen straight through:
    ``max over channels |image - background(d)| <= tol``, ``d`` the pixel centre ray's direction."""
    from mitsnerf.math.rays import camera_rays_numpy

    out = []
    for img, cam in zip(images, cameras):
        _, d = camera_rays_numpy([cam])
        bg = np.asarray(background(mi.Vector3f(*(np.ascontiguousarray(d[:, k]) for k in range(3)))))
        bg = bg.reshape(3, -1).T  # (H W, 3), or (1, 3) for a constant background
        out.append(np.abs(np.asarray(img, np.float64).reshape(-1, 3) - bg).max(axis=1) <= tol)
    return out


def carve_mask(cameras, empty: list[np.ndarray], box, resolution: int) -> np.ndarray:
    """Voxels (R, R, R) ``[z, y, x]`` to keep: False where the centre ray of an ``empty`` pixel passes
    (its points every half voxel along the chord ``[t_n, t_f]``, each in the voxel that holds it)."""
    from mitsnerf.math.rays import camera_rays_numpy

    r = int(resolution)
    keep = np.ones((r, r, r), dtype=bool)
    lo, size = np.asarray(box.lo, np.float64), np.asarray(box.size, np.float64)
    n = int(np.ceil(2 * np.sqrt(3.0) * r)) + 1
    u = (np.arange(n) + 0.5) / n
    for cam, e in zip(cameras, empty):
        o, d = camera_rays_numpy([cam])
        t_n, t_f, hit = box.intersect_numpy(o, d)
        sel = hit & e
        t = t_n[sel, None] + u[None] * (t_f - t_n)[sel, None]
        p = o[sel, None].astype(np.float64) + t[..., None] * d[sel, None].astype(np.float64)
        idx = np.clip(((p - lo) / size * r).astype(np.int64), 0, r - 1).reshape(-1, 3)
        keep[idx[:, 2], idx[:, 1], idx[:, 0]] = False
    return keep


def _rgb_sensor(camera, spp: int):
    from mitsnerf.scene.to_mitsuba import sensor_dict

    d = sensor_dict(camera, spp)
    d["film"]["pixel_format"] = "rgb"
    return mi.load_dict(d)


class MitsubaInverseModel(ViewModel):
    name = "mitsuba-inverse"
    config_type = MitsubaInverseConfig
    description = "sigma_t/albedo grids through Mitsuba's prbvolpath, coarse to fine"
    knows = ("lights", "phase function")
    rung = "full transport"
    tiny = MappingProxyType({"resolutions": [4, 8], "upsample_at": [3], "spp": 2, "eval_spp": 4})

    def __init__(self, config: MitsubaInverseConfig, scene: SceneInfo, seed: int = 0) -> None:
        from mitsnerf.scene.to_mitsuba import scene_dict

        self.spec = scene_spec(scene, self.name, "its spec gives the lights and the medium's placement")
        self.config = config
        self.box = scene.box
        self.max_depth = config.max_depth or self.spec.render.max_depth
        r = config.resolutions[0]
        sigma_t = np.full((r, r, r), config.init_sigma_t, dtype=np.float32)
        albedo = np.full((r, r, r, 3), config.init_albedo, dtype=np.float32)
        desc = scene_dict(self.spec, sigma_t, albedo)
        desc["integrator"] = {"type": "prbvolpath", "max_depth": int(self.max_depth)}
        if config.majorant:
            desc["medium_box"]["interior"]["sigma_t"]["max_value"] = float(config.majorant)
        self.scene = mi.load_dict(desc)
        self.params = mi.traverse(self.scene)
        self._key_sigma = self._find_key(SIGMA_T_SUFFIX)
        self._key_albedo = self._find_key(ALBEDO_SUFFIX)
        self.sigma_t = mi.TensorXf(self.params[self._key_sigma])
        self.albedo = mi.TensorXf(self.params[self._key_albedo])
        self._sensors: dict[int, Any] = {}
        self._targets: dict[int, Any] = {}
        self._background = scene.background
        self._keep: dict[int, Any] | None = None  # resolution -> TensorXf (R, R, R, 1) of 0/1 (carve)

    def _find_key(self, suffix: str) -> str:
        keys = [k for k in self.params.keys() if k.endswith(suffix)]
        if len(keys) != 1:
            raise RuntimeError(f"expected one scene parameter ending in {suffix!r}, found {keys}")
        return keys[0]

    # ------------------------------------------------------------------ parameters

    def parameters(self) -> Mapping[str, Any]:
        params = {"sigma_t": self.sigma_t}
        if self.config.optimize_albedo:
            params["albedo"] = self.albedo
        return params

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        if "sigma_t" in values:
            self.sigma_t = values["sigma_t"]
            self.params[self._key_sigma] = self.sigma_t
        if "albedo" in values:
            self.albedo = values["albedo"]
            self.params[self._key_albedo] = self.albedo
        self.params.update()

    @property
    def resolution(self) -> int:
        return int(self.sigma_t.shape[0])

    def level(self, step: int) -> int:
        """Upsamplings done before step ``step`` (0-based) starts."""
        return sum(1 for s in self.config.upsample_at if s <= step)

    def lr_scales(self, step: int) -> Mapping[str, float]:
        factor = self.config.upsample_lr_factor ** self.level(step)
        scales = {"sigma_t": factor}
        if self.config.optimize_albedo:
            scales["albedo"] = factor * self.config.albedo_lr_factor
        return scales

    def after_step(self, step: int, params: Mapping[str, Any]) -> Mapping[str, Any]:
        """The grids resampled after ``upsample_at`` steps; sigma_t clamped to [0, sigma_t_clamp] and carved,
        albedo clamped to [0, 1]."""
        done = step + 1
        new = {key: params[key] for key in ("sigma_t", "albedo") if key in params}
        if done in self.config.upsample_at:
            r = self.config.resolutions[self.config.upsample_at.index(done) + 1]
            new = {key: dr.resample(v, (r, r, r, v.shape[-1]), filter="linear", boundary="nearest")
                   for key, v in new.items()}
        new["sigma_t"] = self._carved(dr.clip(new["sigma_t"], 0.0, self.config.sigma_t_clamp))
        if "albedo" in new:
            new["albedo"] = dr.clip(new["albedo"], 0.0, 1.0)
        self.set_parameters(new)
        return new

    # ------------------------------------------------------------------ training

    def samples_per_ray(self) -> int:
        return self.config.spp

    def spp_at(self, step: int) -> int:
        """Samples per pixel of the training renders at step ``step`` (0-based)."""
        c = self.config
        return c.spp_late if c.spp_late and step >= c.spp_late_at else c.spp

    def carve(self, data) -> None:
        """Build the emptiness masks of every resolution from the training views (``carve = true``)."""
        empty = unattenuated_pixels(data.images, data.cameras, self._background, self.config.carve_tol)
        self._keep = {r: mi.TensorXf(carve_mask(data.cameras, empty, self.box, r).astype(np.float32)[..., None])
                      for r in self.config.resolutions}

    def _carved(self, sigma_t):
        """``sigma_t`` times the emptiness mask of its resolution (itself without one)."""
        if self._keep is None:
            return sigma_t
        return sigma_t * self._keep[int(sigma_t.shape[0])]

    def _sparsity(self, sigma_t):
        """The prior's term ``l1 * mean(sigma_t)`` (Float of width 1)."""
        return self.config.l1 * mi.Float(dr.mean(sigma_t.array))

    def training_loss(self, data, step: int, rng) -> StepLoss:
        """Render ``views_per_step`` random training views at :meth:`spp_at` samples per pixel; the loss is
        the mean squared error against their images plus the sparsity prior (``l1``), of ``sigma_t`` times
        the emptiness mask (``carve``, built from the training views on the first call)."""
        if data is None or data.images is None or not data.cameras:
            raise ValueError("mitsuba-inverse trains on whole views: PixelData.from_views gives them")
        if abs(data.pixel_center - 0.5) > 1e-9:
            raise ValueError(
                f"mitsuba-inverse renders with Mitsuba's pixel centres (+0.5), the data has {data.pixel_center}"
            )
        if self.config.carve and self._keep is None:
            self.carve(data)
        sigma_t = self._carved(self.sigma_t)
        if self._keep is not None or self.config.l1:
            self.params[self._key_sigma] = sigma_t
            self.params.update()
        spp = self.spp_at(step)
        n_views = len(data.cameras)
        v = self.config.views_per_step
        u = np.asarray(rng.random(mi.Float, 2 * v), dtype=np.float64)
        loss: Any = None
        rays = 0
        for k in range(v):
            i = min(int(u[k] * n_views), n_views - 1)
            seed = int(u[v + k] * 2**31)
            if i not in self._sensors:
                self._sensors[i] = _rgb_sensor(data.cameras[i], self.config.spp)
                self._targets[i] = mi.TensorXf(np.ascontiguousarray(data.images[i], dtype=np.float32))
            img = mi.render(self.scene, self.params, sensor=self._sensors[i], spp=spp, seed=seed)
            err = mi.Float(dr.mean(dr.square(img - self._targets[i]), axis=None).array)
            loss = err if loss is None else loss + err
            rays += data.cameras[i].width * data.cameras[i].height
        mse = loss / v
        loss = mse + self._sparsity(sigma_t) if self.config.l1 else mse
        return StepLoss(loss, dr.detach(mse), rays)

    # ------------------------------------------------------------------ rendering

    def field(self) -> GridField:
        """The medium as a field: ``sigma_t`` and, as its colour, the albedo."""
        return GridField.from_arrays(dr.detach(self.sigma_t), self.box, dr.detach(self.albedo))

    def render_view(self, camera, *, pixel_center: float = 0.5, footprint: int = 1) -> Rendered:
        """``prbvolpath`` at ``eval_spp`` through Mitsuba's box-filtered film for the colour; opacity
        and depth by quadrature of ``sigma_t`` with ``max(footprint, 2)`` rays per pixel side."""
        if abs(pixel_center - 0.5) > 1e-9:
            raise ValueError(f"mitsuba-inverse renders with Mitsuba's pixel centres (+0.5), asked for {pixel_center}")
        with dr.suspend_grad():
            img = mi.render(self.scene, sensor=_rgb_sensor(camera, self.config.eval_spp),
                            spp=self.config.eval_spp, seed=EVAL_SEED)
            rgb = np.array(img, dtype=np.float32)
            density = GridField.from_arrays(dr.detach(self.sigma_t), self.box)
            n = 2 * self.resolution
            quad = render_view(lambda o, d: render_rays(density, o, d, n, box=self.box), camera,
                               pixel_center=pixel_center, footprint=max(footprint, 2))
        return Rendered(rgb, quad.opacity, quad.depth)


#: The method this module declares (:mod:`mitsnerf.methods` registers it as ``mitsuba-inverse``).
METHOD = MitsubaInverseModel
