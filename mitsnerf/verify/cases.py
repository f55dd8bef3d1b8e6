"""The verification cases: frozen configs (scene, sizes, tolerances) and their procedural inputs.

Every case names the mutations (bugs planted in the package's functions,
:mod:`mitsnerf.verify.mutations`) that it must detect; the tests run each such pair and
require a failure, and ``mitsnerf check --mutations`` prints the full matrix.

Media and quadratures. The seed's quadrature (``stratified_t`` midpoints, then ``composite``)
integrates optical depth as ``sum_{i<N-1} sigma_i h + sigma_{N-1} h/2`` with
``h = (t_f - t_n)/N``: the midpoint rule minus half of the last interval, so its error is::

    tau_hat - tau = -(h/2) sigma_t(t_f) + O(h^2)

(first order, set by the density at the *exit*). Each scenario says which rules it renders
and what each is compared with:

- ``front_heavy`` media (dense where the camera's rays enter, zero on every face they
  leave by): the seed's rule is second order there and is compared with volpath directly;
  a delta taken from the wrong end (error ``-(h/2) sigma_t(t_n)``) is first order.
- ``homogeneous`` boxes (dense at the exit): with ``c = 0`` the seed's rule renders exactly
  ``exp(-sigma_t (L - h/2)) bg`` per ray (``L = t_f - t_n``), so volpath's mean times
  ``exp(sigma_t L / 2N)`` is its reference (the closed form of the biased quadrature);
  the midpoint rule (``quadrature="midpoint"``) is compared with volpath as it is.
- ``exit_heavy`` media (zero at the entry face, dense at the far faces): the midpoint rule
  against volpath; the seed's bias there is measured and printed, not tested.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.camera import Camera, look_at

#: Where the verification camera sits (it looks at the origin along +y, z up).
CAMERA_ORIGIN = (0.0, -2.6, 0.0)
CAMERA_FOV_DEG = 36.0


@dataclass(frozen=True)
class Quality:
    """Sizes of one run of the checks."""

    name: str
    width: int
    """Image width and height in pixels (square images)."""
    spp: int
    """Mitsuba samples per pixel of the reference (scenarios scale it by ``spp_factor``)."""
    n_samples: int
    """Samples per ray N of the integrator under test."""
    resolution: int = 16
    """Grid resolution R of the procedural media (R^3 voxels)."""
    alpha: float = 0.001
    """Family-wise error rate of each scenario: all its pixel and channel-mean tests are one
    weighted-Holm family (:func:`mitsnerf.verify.stats.decide`)."""
    seed: int = 0
    j_spp: int = 32
    """Volpath directions per sample point of the in-scattered (multiple-scattering) source."""

    def __post_init__(self) -> None:
        if self.width < 2 or self.spp < 16 or self.n_samples < 2 or self.resolution < 4:
            raise ValueError(f"quality {self.name!r}: sizes too small ({self})")
        if not 0.0 < self.alpha < 0.5:
            raise ValueError(f"quality {self.name!r}: alpha must be in (0, 0.5), got {self.alpha}")

    def reference_spp(self, spp_factor: float) -> int:
        """Samples per pixel of a case's Mitsuba reference: this quality's ``spp`` times the case's factor,
        at least 16.

        >>> QUALITIES["quick"].reference_spp(4.0), QUALITIES["quick"].reference_spp(0.001)
        (4096, 16)
        """
        return max(16, int(round(self.spp * spp_factor)))

    def camera(self) -> Camera:
        return Camera.from_fov(look_at(CAMERA_ORIGIN, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
                               self.width, self.width, CAMERA_FOV_DEG)


QUALITIES = {
    "quick": Quality("quick", width=12, spp=1024, n_samples=64),
    "thorough": Quality("thorough", width=24, spp=4096, n_samples=128, j_spp=64),
}


# --------------------------------------------------------------------------- scenarios

MEDIA = ("front_heavy", "exit_heavy", "homogeneous")

SOURCES = ("zero", "single_scatter", "in_scattered", "scatter_field")
"""The integrator's colour ``c(x, d)`` of a volpath scenario: ``"zero"`` (absorption only),
``"single_scatter"`` (``albedo p E T_light`` of a directional light), ``"in_scattered"`` (the
multiple-scattering source ``J = albedo (1/4pi) int L dw`` estimated by volpath at the integrator's
own samples: the emission-absorption oracle, :class:`mitsnerf.oracle.compare.PointSource`) or
``"scatter_field"`` (the ``scatter`` method's field holding the true medium: single scattering through its
own shadow cache and phase function). Each has a builder in :data:`mitsnerf.verify.sources.SOURCE_BUILDERS`."""


@dataclass(frozen=True)
class VolpathScenario:
    """Emission-absorption rendering against ``volpath`` on the same rays (one test family).

    ``quadratures``: the rules rendered (``"seed"``, ``"midpoint"``); each is one comparison
    of the family (see the module docstring for each medium's reference).
    """

    name: str
    title: str
    medium: str  # one of MEDIA
    sigma_t_max: float
    albedo: str  # "zero" | "one" | "procedural"
    environment: str  # "constant" | "envmap" | "black"
    source: str  # one of SOURCES
    quadratures: tuple[str, ...] = ("seed",)
    env_radiance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    sun_direction: tuple[float, float, float] | None = None
    """Direction the directional light travels (towards the scene), or None."""
    sun_irradiance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_depth: int = -1
    spp_factor: float = 1.0
    max_rel_error: float = 0.01
    """Bound on ``|sum ours - sum ref| / sum ref``, on top of the z-tests."""
    detects: tuple[str, ...] = ()
    """Mutations this scenario must fail on."""
    phase_g: float = 0.0
    """The medium's phase function: 0 isotropic, else Henyey-Greenstein with this ``g`` (the in-scattered
    source then depends on the view direction)."""
    sigma_t_rgb: tuple[float, float, float] | None = None
    """Chromatic extinction: channel ``k`` of ``sigma_t`` is the medium's grid times ``sigma_t_rgb[k]`` (None: grey)."""

    def phase(self) -> dict[str, Any]:
        """The Mitsuba phase plugin's entry."""
        return {"type": "isotropic"} if self.phase_g == 0.0 else {"type": "hg", "g": float(self.phase_g)}

    def __post_init__(self) -> None:
        if self.medium not in MEDIA:
            raise ValueError(f"{self.name}: medium must be one of {', '.join(MEDIA)}, got {self.medium!r}")
        if self.albedo not in ("zero", "one", "procedural"):
            raise ValueError(f"{self.name}: albedo must be zero, one or procedural, got {self.albedo!r}")
        if self.environment not in ("constant", "envmap", "black"):
            raise ValueError(f"{self.name}: environment must be constant, envmap or black, got {self.environment!r}")
        if self.source not in SOURCES:
            raise ValueError(f"{self.name}: source must be one of {', '.join(SOURCES)}, got {self.source!r}")
        if self.source in ("single_scatter", "in_scattered", "scatter_field") and self.sun_direction is None:
            raise ValueError(f"{self.name}: single scattering needs a sun_direction")
        if self.phase_g != 0.0 and self.source not in ("zero", "in_scattered", "scatter_field"):
            raise ValueError(f"{self.name}: an anisotropic medium needs the in_scattered source (or none)")
        if not self.quadratures or set(self.quadratures) - {"seed", "midpoint"}:
            raise ValueError(f"{self.name}: quadratures must be a non-empty subset of seed, midpoint")
        if "seed" in self.quadratures and self.seed_reference() is None:
            raise ValueError(f"{self.name}: the seed's rule is first-order biased in a {self.medium} medium and "
                             "has no closed form with this source; render it with quadrature midpoint")

    def seed_reference(self) -> str | None:
        """How the seed's rule is compared: ``"volpath"``, ``"closed_form_bias"`` or None (not possible)."""
        if self.medium == "front_heavy":
            return "volpath"
        if self.medium == "homogeneous" and self.source == "zero":
            return "closed_form_bias"
        return None


@dataclass(frozen=True)
class MitsubaFurnace:
    """A check of Mitsuba itself, not of the integrator: volpath in a white furnace renders 1."""

    name: str = "mitsuba_furnace"
    title: str = "volpath, albedo 1, environment 1, unlimited depth, against 1"
    sigma_t_max: float = 8.0
    spp_factor: float = 0.25
    max_rel_error: float = 0.01
    max_depth: int = -1


@dataclass(frozen=True)
class FurnaceDepthRecord:
    """Not a pass/fail check: how far volpath with a finite ``max_depth`` falls below 1 in a white furnace."""

    name: str
    sigma_t: float
    max_depths: tuple[int, ...]
    spp_factor: float = 0.25


@dataclass(frozen=True)
class ClosedFormCase:
    """Deterministic checks of the quadrature against formulas (no Monte Carlo)."""

    name: str = "closed_form"
    title: str = "homogeneous box, piecewise-constant density, convergence order"
    optical_depths: tuple[float, ...] = (0.1, 1.0, 4.0, 10.0)
    rtol: float = 2e-5
    """Float32 compositing of up to a few hundred terms."""
    order_tol: float = 0.15
    detects: tuple[str, ...] = ("T_off_by_one", "wrong_interval", "background_T_before_last", "no_background",
                                "delta_x1.01", "delta_wrong_end")


@dataclass(frozen=True)
class GradientCase:
    """AD derivatives of a rendered image's loss against central finite differences."""

    name: str
    title: str
    parameter: str  # "sigma_t_grid" | "nerf_weights" | "color_grid"
    eps: float
    """Finite-difference step of single entries (absolute, in the parameter's units)."""
    rtol: float
    atol_frac: float
    """Absolute floor of single entries, as a fraction of the largest |derivative| checked (float32 round-off)."""
    eps_direction: float
    """Finite-difference step along the unit direction v."""
    rtol_direction: float = 1e-3
    """Along v: a 0.3% error of the gradient must fail (measured FD error: see gradients.py)."""
    n_checked: int = 6
    float64: bool = False
    """Render in float64 (rays, field, compositing): for a field that is not smooth enough for float32 FD."""
    detects: tuple[str, ...] = ()


@dataclass(frozen=True)
class DrtCase:
    """``mitsnerf_drt``'s gradient expectation against volpath's finite differences (:mod:`mitsnerf.verify.drt`)."""

    name: str
    title: str
    chromatic: bool = False
    """A three-channel extinction (the grid times 0.7, 1, 1.4 per channel)."""
    phase_g: float = 0.0
    estimator: str = "drt"
    """``"drt"`` (differential ratio tracking) or ``"free_flight"`` (the in-scattering gradient at the path's own
    collisions)."""
    resolution: int = 8
    sigma_t_max: float = 6.0
    max_depth: int = -1
    majorant_cell: int = 2
    majorant_floor: float = 1.0
    renders: int = 16
    """Independent gradient renders (each ``spp`` samples per pixel-centre ray)."""
    spp: int = 64
    eps: float = 0.02
    """Difference step: ``eps sigma_t_max`` for the extinction, ``eps`` for the albedo."""
    fd_seeds: int = 6
    """Seeds of volpath's difference quotients (each a pair or triple of renders with common random numbers)."""
    fd_spp_factor: float = 1.0
    """Samples per ray of each of those renders, times the quality's ``spp``."""
    ref_spp_factor: float = 4.0
    """Samples per ray of the primal's volpath reference, times the quality's ``spp``."""
    detects: tuple[str, ...] = ()


@dataclass(frozen=True)
class PluginCase:
    """The Mitsuba integrator plugin renders a field as an independent float64 quadrature of the same samples does."""

    name: str
    title: str
    field: str  # "grid" | "nerf"
    environment: str  # "constant" | "envmap"
    atol: float = 1e-5
    """Float32 against float64 compositing of N = 64-128 samples (measured within 4e-6)."""
    detects: tuple[str, ...] = ("T_off_by_one", "wrong_interval", "background_T_before_last", "no_background",
                                "delta_x1.01", "delta_wrong_end")


@dataclass(frozen=True)
class JitterCase:
    """The training sampler's jitter, tested statistically: positions uniform in their strata, independent."""

    name: str = "sampler_jitter"
    title: str = "training jitter through stratified_t: uniform, independent across samples and steps"
    steps: tuple[int, int] = (0, 1)
    """Two training steps whose generators must give independent jitter."""
    rtol: float = 1e-5
    """Float32 tolerance of the deterministic interval checks (relative to the ray's span)."""
    detects: tuple[str, ...] = ("jitter_ignored", "jitter_frozen", "delta_x1.01", "delta_wrong_end")


@dataclass(frozen=True)
class TrainingPathCase:
    """The average of jittered (training-mode) renders against volpath (a scenario's reference reused).

    The seed's rule with jitter has a first-order bias in expectation,
    ``E[tau_hat] - tau = (h/12) sigma_t(t_n) - (7h/12) sigma_t(t_f) + O(h^2)`` (a missing
    ``[t_n, t_0]`` of mean length ``h/2`` and left-point intervals of mean square length
    ``7h^2/6``); in the front-heavy scenario ``sigma_t(t_f) = 0`` and ``n_factor`` x N samples
    put ``(h/12) sigma_t(t_n)`` below the noise. The measured difference is printed.
    """

    name: str = "train_average"
    scenario: str = "single_scatter"
    n_factor: int = 8
    renders: int = 16
    detects: tuple[str, ...] = ()


_sun = np.array([0.3, 0.5, -0.8]) / np.linalg.norm([0.3, 0.5, -0.8])
SUN = (float(_sun[0]), float(_sun[1]), float(_sun[2]))

SINGLE_SCATTER = VolpathScenario(
    "single_scatter",
    "front-heavy, directional light, black environment, volpath max_depth 2",
    "front_heavy",
    sigma_t_max=8.0,
    albedo="procedural",
    environment="black",
    source="single_scatter",
    sun_direction=SUN,
    sun_irradiance=(3.0, 2.5, 2.0),
    max_depth=2,
    spp_factor=4.0,
    max_rel_error=0.02,
    detects=("T_off_by_one", "delta_wrong_end"),
)

SCATTER_SINGLE = replace(
    SINGLE_SCATTER,
    name="scatter_single",
    title="the scatter method's field on the true medium: front-heavy, directional light, volpath max_depth 2",
    source="scatter_field",
    detects=("phase_factor_missing",),  # the sun's reversal: symmetric here for an isotropic medium, see below
)
"""The ``scatter`` method's field holding the true medium, against volpath's single scattering."""

MULTIPLE_SCATTER = VolpathScenario(
    "multiple_scatter",
    "front-heavy, albedo < 1, sky + sun, unlimited depth: the oracle's J by volpath",
    "front_heavy",
    sigma_t_max=8.0,
    albedo="procedural",
    environment="constant",
    source="in_scattered",
    env_radiance=(0.5, 0.55, 0.6),
    sun_direction=SUN,
    sun_irradiance=(3.0, 2.5, 2.0),
    max_depth=-1,
    spp_factor=4.0,
    max_rel_error=0.02,
    detects=("T_off_by_one", "delta_wrong_end", "no_background"),
)

SCENARIOS: tuple[VolpathScenario, ...] = (
    VolpathScenario(
        "absorption_constant",
        "front-heavy, albedo 0, constant environment",
        "front_heavy",
        sigma_t_max=8.0,
        albedo="zero",
        environment="constant",
        source="zero",
        env_radiance=(0.6, 0.8, 1.0),
        spp_factor=4.0,
        detects=("delta_wrong_end", "no_background"),
    ),
    VolpathScenario(
        "absorption_envmap",
        "front-heavy, albedo 0, envmap environment",
        "front_heavy",
        sigma_t_max=8.0,
        albedo="zero",
        environment="envmap",
        source="zero",
        spp_factor=4.0,
        detects=("delta_wrong_end", "no_background"),
    ),
    SINGLE_SCATTER,
    VolpathScenario(
        "box_absorption",
        "homogeneous box, albedo 0, envmap; seed rule (closed-form bias) and midpoint",
        "homogeneous",
        sigma_t_max=2.0,
        albedo="zero",
        environment="envmap",
        source="zero",
        quadratures=("seed", "midpoint"),
        spp_factor=16.0,
        detects=("wrong_interval", "background_T_before_last", "no_background", "delta_x1.01"),
    ),
    VolpathScenario(
        "exit_absorption",
        "exit-heavy, albedo 0, envmap; midpoint rule",
        "exit_heavy",
        sigma_t_max=8.0,
        albedo="zero",
        environment="envmap",
        source="zero",
        quadratures=("midpoint",),
        spp_factor=4.0,
        detects=("background_T_before_last", "no_background", "delta_x1.01"),
    ),
    VolpathScenario(
        "exit_single_scatter",
        "exit-heavy, directional light, volpath max_depth 2; midpoint rule",
        "exit_heavy",
        sigma_t_max=8.0,
        albedo="procedural",
        environment="black",
        source="single_scatter",
        quadratures=("midpoint",),
        sun_direction=SUN,
        sun_irradiance=(3.0, 2.5, 2.0),
        max_depth=2,
        spp_factor=4.0,
        max_rel_error=0.02,
        detects=("T_off_by_one",),
    ),
    SCATTER_SINGLE,
    replace(SCATTER_SINGLE, name="scatter_single_g85", phase_g=0.85,
            title="the same with Henyey-Greenstein g = 0.85: the phase function of the sun's light",
            detects=("light_direction_flipped", "phase_factor_missing", "hg_sign", "cosine_reversed")),
    MULTIPLE_SCATTER,
    replace(MULTIPLE_SCATTER, name="forward_scatter_g50", phase_g=0.5, detects=("hg_sign", "cosine_reversed"),
            title="front-heavy, albedo < 1, sky + sun, unlimited depth, Henyey-Greenstein g = 0.5: the directional "
                  "oracle"),
    replace(MULTIPLE_SCATTER, name="forward_scatter_g85", phase_g=0.85, detects=("hg_sign", "cosine_reversed"),
            title="the same with g = 0.85 (water clouds): the sun's forward lobe"),
    replace(MULTIPLE_SCATTER, name="chromatic", sigma_t_rgb=(0.5, 1.0, 2.0), detects=("extinction_first_channel",),
            title="the multiple-scattering scene with chromatic extinction (sigma_t x 0.5, 1, 2 in R, G, B): the "
                  "oracle per channel"),
)

MITSUBA_FURNACE = MitsubaFurnace()

FURNACE_DEPTHS = FurnaceDepthRecord("furnace_max_depth", sigma_t=10.0, max_depths=(2, 8, 32, 64, -1))

CLOSED_FORM = ClosedFormCase()

JITTER = JitterCase()

TRAINING_PATH = TrainingPathCase()

GRADIENT_CASES: tuple[GradientCase, ...] = (
    GradientCase("grad_sigma_t", "d loss / d sigma_t grid values", "sigma_t_grid",
                 eps=0.05, rtol=0.01, atol_frac=0.01, eps_direction=0.2,
                 detects=("T_detached", "tau_grad_x1.003", "C_grad_x1.003")),
    GradientCase("grad_nerf", "d loss / d NeRF trunk weights (float64)", "nerf_weights",
                 eps=1e-6, rtol=1e-4, atol_frac=1e-4, eps_direction=1e-6, float64=True,
                 detects=("T_detached", "rgb_detached", "C_grad_x1.003")),
    GradientCase("grad_color", "d loss / d colour grid values", "color_grid",
                 eps=0.05, rtol=0.005, atol_frac=0.01, eps_direction=0.2,
                 detects=("rgb_detached", "rgb_grad_x1.003", "C_grad_x1.003")),
)

DRT_CASES: tuple[DrtCase, ...] = (
    DrtCase("drt_gradient", "mitsnerf_drt: E[gradient] vs volpath FD (grey, isotropic)",
            detects=("drt_no_ratio_weight", "majorant_below_density")),
    DrtCase("drt_gradient_rgb", "mitsnerf_drt: E[gradient] vs volpath FD (chromatic sigma_t, HG g = 0.5)",
            chromatic=True, phase_g=0.5, detects=("drt_no_ratio_weight", "majorant_below_density")),
)

PLUGIN_CASES: tuple[PluginCase, ...] = (
    PluginCase("plugin_grid", "mitsnerf_ea plugin: exit-heavy grid field, envmap", "grid", "envmap"),
    PluginCase("plugin_nerf", "mitsnerf_ea plugin: NeRF field, constant env", "nerf", "constant"),
)


# --------------------------------------------------------------------------- procedural inputs


def voxel_centres(resolution: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World coordinates ``(x, y, z)`` of the voxel centres of the unit box (:meth:`Box.voxel_axes`), each
    ``(R, R, R)`` indexed ``[z, y, x]``."""
    cx, cy, cz = UNIT_BOX.voxel_axes(resolution)
    z, y, x = np.meshgrid(cz, cy, cx, indexing="ij")
    return x, y, z


def front_heavy_sigma_t(resolution: int, sigma_t_max: float) -> np.ndarray:
    """A heterogeneous ``sigma_t`` grid (R, R, R), dense at y = -0.5, zero on the other five faces.

    With ``s = (i + 1/2)/R`` the voxel-centre coordinate in [0, 1] along each axis and
    ``e(s) = (s - s_0)/(s_1 - s_0)`` mapping the outer voxel centres to 0 and 1::

        sigma_t = sigma_t_max * (1 - e(s_y))^2 * sin(pi e(s_x)) sin(pi e(s_z)) * h / max(...)
        h       = 1 + 0.6 sin(2 pi (1.3 x + 0.7 z) + 1) cos(2 pi 1.1 y) + 0.8 exp(-|x - x_b|^2 / 0.02)

    (``x_b = (0.15, -0.05, 0.1)``: a blob). Outer voxel layers other than y = -0.5 are 0, so
    trilinear lookups vanish on those faces.
    """
    x, y, z = voxel_centres(resolution)
    s0 = 0.5 / resolution - 0.5
    e = lambda v: (v - s0) / (-2.0 * s0)  # noqa: E731  (outer centres -> 0, 1)
    ramp = (1.0 - e(y)) ** 2
    bump = np.sin(np.pi * e(x)) * np.sin(np.pi * e(z))
    blob = np.exp(-((x - 0.15) ** 2 + (y + 0.05) ** 2 + (z - 0.1) ** 2) / 0.02)
    h = 1.0 + 0.6 * np.sin(2 * np.pi * (1.3 * x + 0.7 * z) + 1.0) * np.cos(2 * np.pi * 1.1 * y) + 0.8 * blob
    sigma = np.clip(ramp * bump * h, 0.0, None)
    sigma[:, -1, :] = 0.0
    sigma[0], sigma[-1], sigma[..., 0], sigma[..., -1] = 0.0, 0.0, 0.0, 0.0
    return (sigma_t_max * sigma / sigma.max()).astype(np.float32)


def procedural_albedo(resolution: int) -> np.ndarray:
    """An RGB albedo grid (R, R, R, 3) in [0.15, 0.95], varying differently per channel."""
    x, y, z = voxel_centres(resolution)
    r = 0.55 + 0.4 * np.sin(2 * np.pi * (x + 0.3 * y))
    g = 0.55 + 0.4 * np.cos(2 * np.pi * (0.8 * z - 0.5 * x))
    b = 0.55 + 0.35 * np.sin(2 * np.pi * (0.6 * y + z) + 0.5)
    return np.clip(np.stack([r, g, b], axis=-1), 0.15, 0.95).astype(np.float32)


def environment_bitmap(height: int = 8, width: int = 16) -> np.ndarray:
    """A small non-constant lat-long bitmap (H, W, 3): a vertical gradient times a horizontal wave."""
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    vv, uu = np.meshgrid(v, u, indexing="ij")
    r = 0.3 + 0.9 * (1 - vv) * (1 + 0.5 * np.sin(2 * np.pi * uu))
    g = 0.4 + 0.5 * vv + 0.3 * np.cos(4 * np.pi * uu)
    b = 0.8 + 0.4 * np.sin(2 * np.pi * (uu + vv))
    return np.stack([r, g, b], axis=-1).astype(np.float32)


def exit_heavy_sigma_t(resolution: int, sigma_t_max: float) -> np.ndarray:
    """A heterogeneous ``sigma_t`` grid (R, R, R), zero at y = -0.5 (where the camera's rays enter), dense beyond.

    With ``e(s)`` as in :func:`front_heavy_sigma_t`::

        sigma_t = sigma_t_max * e(s_y)^2 * h / max(...),   h as there

    The side faces are not zeroed: rays leave through dense medium on every face.
    """
    x, y, z = voxel_centres(resolution)
    s0 = 0.5 / resolution - 0.5
    e = (y - s0) / (-2.0 * s0)
    blob = np.exp(-((x - 0.15) ** 2 + (y + 0.05) ** 2 + (z - 0.1) ** 2) / 0.02)
    h = 1.0 + 0.6 * np.sin(2 * np.pi * (1.3 * x + 0.7 * z) + 1.0) * np.cos(2 * np.pi * 1.1 * y) + 0.8 * blob
    sigma = np.clip(e**2 * h, 0.0, None)
    sigma[:, 0, :] = 0.0
    return (sigma_t_max * sigma / sigma.max()).astype(np.float32)


def medium_sigma_t(medium: str, resolution: int, sigma_t_max: float) -> np.ndarray:
    """The ``sigma_t`` grid (R, R, R) of a medium kind (:data:`MEDIA`)."""
    if medium == "homogeneous":
        return np.full((resolution,) * 3, sigma_t_max, np.float32)
    if medium == "exit_heavy":
        return exit_heavy_sigma_t(resolution, sigma_t_max)
    if medium == "front_heavy":
        return front_heavy_sigma_t(resolution, sigma_t_max)
    raise ValueError(f"unknown medium {medium!r}; choose one of {', '.join(MEDIA)}")


def scenario_grids(s: VolpathScenario, resolution: int) -> tuple[np.ndarray, np.ndarray | float]:
    """``(sigma_t (R, R, R), or (R, R, R, 3) chromatic, albedo (R, R, R, 3) or a float)`` of a scenario."""
    sigma = medium_sigma_t(s.medium, resolution, s.sigma_t_max)
    if s.sigma_t_rgb is not None:
        sigma = (sigma[..., None] * np.asarray(s.sigma_t_rgb, np.float32)).astype(np.float32)
    albedo: np.ndarray | float = {"zero": 0.0, "one": 1.0}.get(s.albedo, None)  # type: ignore[assignment]
    if albedo is None:
        albedo = procedural_albedo(resolution)
    return sigma, albedo


def isotropic_phase() -> float:
    """The isotropic phase function's value ``p = 1 / (4 pi)``."""
    return 1.0 / (4.0 * math.pi)


ALL_CASE_NAMES = (
    [CLOSED_FORM.name] + [s.name for s in SCENARIOS] + [TRAINING_PATH.name, JITTER.name]
    + [g.name for g in GRADIENT_CASES] + [d.name for d in DRT_CASES] + [p.name for p in PLUGIN_CASES]
    + [MITSUBA_FURNACE.name, FURNACE_DEPTHS.name]
)
