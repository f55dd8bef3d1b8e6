"""The verification scenarios: frozen configs (scene, sizes, tolerances) and their procedural inputs.

Every scenario names the mutations (deliberately broken compositing,
:mod:`mitsnerf.verify.mutations`) that it must detect; the tests run each such pair and
require a failure, so no tolerance can be wide enough to pass those bugs.

Why the media are "front-heavy". The quadrature (``stratified_t`` midpoints, then
``composite``) integrates optical depth as ``sum_{i<N-1} sigma_i h + sigma_{N-1} h/2`` with
``h = (t_f - t_n)/N``: the midpoint rule minus half of the last interval, so its error is::

    tau_hat - tau = -(h/2) sigma_t(t_f) + O(h^2)

(first order, set by the density at the *exit*). The mutation "delta from the wrong end"
(``delta_i = t_i - t_{i-1}``) errs by ``-(h/2) sigma_t(t_n)`` instead. Seen from the
verification camera (on the -y axis) the media are dense where rays enter (the y = -0.5
face) and vanish on every face rays leave by, so the correct quadrature is second order and
well inside the Monte Carlo noise while the mutated one is off by a first-order amount.
A medium dense at both ends could not tell the two apart: both converge at rate 1/N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

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
    """Family-wise error rate of each scenario's tests (Holm over pixels, and the image mean)."""
    seed: int = 0

    def __post_init__(self) -> None:
        if self.width < 2 or self.spp < 16 or self.n_samples < 2 or self.resolution < 4:
            raise ValueError(f"quality {self.name!r}: sizes too small ({self})")
        if not 0.0 < self.alpha < 0.5:
            raise ValueError(f"quality {self.name!r}: alpha must be in (0, 0.5), got {self.alpha}")

    def camera(self) -> Camera:
        return Camera.from_fov(look_at(CAMERA_ORIGIN, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
                               self.width, self.width, CAMERA_FOV_DEG)


QUALITIES = {
    "quick": Quality("quick", width=12, spp=1024, n_samples=64),
    "thorough": Quality("thorough", width=24, spp=4096, n_samples=128),
}


# --------------------------------------------------------------------------- scenarios


@dataclass(frozen=True)
class VolpathScenario:
    """Emission-absorption rendering against ``volpath`` on the same rays.

    ``source`` chooses the integrator's colour c(x, d): ``"zero"`` (absorption only),
    ``"one"`` (white furnace) or ``"single_scatter"`` (``albedo p E T_light``).
    """

    name: str
    title: str
    sigma_t_max: float
    albedo: str  # "zero" | "one" | "procedural"
    environment: str  # "constant" | "envmap" | "black"
    source: str  # "zero" | "one" | "single_scatter"
    env_radiance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    sun_direction: tuple[float, float, float] | None = None
    """Direction the directional light travels (towards the scene), or None."""
    sun_irradiance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_depth: int = -1
    homogeneous: bool = False
    """A homogeneous box of ``sigma_t_max`` instead of the front-heavy medium."""
    spp_factor: float = 1.0
    max_rel_error: float = 0.01
    """Bound on ``|sum ours - sum ref| / sum ref``, on top of the z-tests."""
    detects: tuple[str, ...] = ()
    """Mutations this scenario must fail on."""
    compare_to_one: bool = False
    """Also z-test the reference against the constant image 1 (furnace)."""

    def __post_init__(self) -> None:
        if self.albedo not in ("zero", "one", "procedural"):
            raise ValueError(f"{self.name}: albedo must be zero, one or procedural, got {self.albedo!r}")
        if self.environment not in ("constant", "envmap", "black"):
            raise ValueError(f"{self.name}: environment must be constant, envmap or black, got {self.environment!r}")
        if self.source not in ("zero", "one", "single_scatter"):
            raise ValueError(f"{self.name}: source must be zero, one or single_scatter, got {self.source!r}")
        if self.source == "single_scatter" and self.sun_direction is None:
            raise ValueError(f"{self.name}: single scattering needs a sun_direction")


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
    detects: tuple[str, ...] = ("off_by_one_T", "delta_wrong_end", "no_background")


@dataclass(frozen=True)
class GradientCase:
    """AD derivatives of a rendered image's loss against central finite differences."""

    name: str
    title: str
    parameter: str  # "sigma_t_grid" | "nerf_weights" | "color_grid"
    eps: float
    """Finite-difference step (absolute, in the parameter's units)."""
    rtol: float
    atol_frac: float
    """Absolute floor, as a fraction of the largest |derivative| checked (float32 round-off)."""
    n_checked: int = 6
    detects: tuple[str, ...] = ()


@dataclass(frozen=True)
class PluginCase:
    """The Mitsuba integrator plugin renders a field exactly as the package does."""

    name: str
    title: str
    field: str  # "grid" | "nerf"
    environment: str  # "constant" | "envmap"
    atol: float = 1e-5
    detects: tuple[str, ...] = ("no_background", "off_by_one_T")


SUN = tuple(float(v) for v in np.array([0.3, 0.5, -0.8]) / np.linalg.norm([0.3, 0.5, -0.8]))

SCENARIOS: tuple[VolpathScenario, ...] = (
    VolpathScenario("absorption_constant", "albedo 0, constant environment",
                    sigma_t_max=8.0, albedo="zero", environment="constant", source="zero",
                    env_radiance=(0.6, 0.8, 1.0), spp_factor=4.0, detects=("delta_wrong_end", "no_background")),
    VolpathScenario("absorption_envmap", "albedo 0, envmap environment",
                    sigma_t_max=8.0, albedo="zero", environment="envmap", source="zero", spp_factor=4.0,
                    detects=("delta_wrong_end", "no_background")),
    VolpathScenario("white_furnace", "albedo 1, environment 1, unlimited depth",
                    sigma_t_max=8.0, albedo="one", environment="constant", source="one",
                    spp_factor=0.25, compare_to_one=True, detects=("off_by_one_T", "no_background")),
    VolpathScenario("single_scatter", "directional light, black environment, volpath max_depth 2",
                    sigma_t_max=8.0, albedo="procedural", environment="black", source="single_scatter",
                    sun_direction=SUN, sun_irradiance=(3.0, 2.5, 2.0), max_depth=2, spp_factor=4.0,
                    max_rel_error=0.02,
                    detects=("off_by_one_T", "delta_wrong_end")),
)

FURNACE_DEPTHS = FurnaceDepthRecord("furnace_max_depth", sigma_t=10.0, max_depths=(2, 8, 32, 64, -1))

CLOSED_FORM = ClosedFormCase()

GRADIENT_CASES: tuple[GradientCase, ...] = (
    GradientCase("grad_sigma_t", "d loss / d sigma_t grid values", "sigma_t_grid",
                 eps=0.05, rtol=0.01, atol_frac=0.01, detects=("detach_T",)),
    GradientCase("grad_nerf", "d loss / d NeRF trunk weights", "nerf_weights",
                 eps=0.01, rtol=0.02, atol_frac=0.02, detects=("detach_T", "detach_rgb")),
    GradientCase("grad_color", "d loss / d colour grid values", "color_grid",
                 eps=0.05, rtol=0.005, atol_frac=0.01, detects=("detach_rgb",)),
)

PLUGIN_CASES: tuple[PluginCase, ...] = (
    PluginCase("plugin_grid", "mitsnerf_ea plugin vs package: grid field, envmap", "grid", "envmap"),
    PluginCase("plugin_nerf", "mitsnerf_ea plugin vs package: NeRF field, constant env", "nerf", "constant"),
)


# --------------------------------------------------------------------------- procedural inputs


def voxel_centres(resolution: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World coordinates ``(x, y, z)`` of the voxel centres, each ``(R, R, R)`` indexed ``[z, y, x]``."""
    c = (np.arange(resolution) + 0.5) / resolution - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
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


def scenario_grids(s: VolpathScenario, resolution: int) -> tuple[np.ndarray, np.ndarray | float]:
    """``(sigma_t (R, R, R), albedo (R, R, R, 3) or a float)`` of a scenario."""
    if s.homogeneous:
        sigma = np.full((resolution,) * 3, s.sigma_t_max, np.float32)
    else:
        sigma = front_heavy_sigma_t(resolution, s.sigma_t_max)
    albedo: np.ndarray | float = {"zero": 0.0, "one": 1.0}.get(s.albedo, None)  # type: ignore[assignment]
    if albedo is None:
        albedo = procedural_albedo(resolution)
    return sigma, albedo


def isotropic_phase() -> float:
    """The isotropic phase function's value ``p = 1 / (4 pi)``."""
    return 1.0 / (4.0 * math.pi)


ALL_CASE_NAMES = (
    [CLOSED_FORM.name] + [s.name for s in SCENARIOS] + [FURNACE_DEPTHS.name]
    + [g.name for g in GRADIENT_CASES] + [p.name for p in PLUGIN_CASES]
)
