"""Derivatives of a rendered image's loss: Dr.Jit reverse and forward mode against central differences.

The loss of an image ``C(theta)`` (pixel-centre rays of a small camera, midpoint samples,
constant background ``bg``) against a constant target::

    loss(theta) = mean_p,ch (C_p(theta) - target)^2

Checked, for ``theta`` each of a sigma_t grid, the first trunk layer's weights of a
:class:`~mitsnerf.fields.nerf.NeRFField`, and a colour grid:

- reverse mode ``g = d loss / d theta`` (``dr.backward``) at ``n_checked`` entries ``k``
  (the largest ``|g_k|`` and random others) against
  ``fd_k = (loss(theta + eps e_k) - loss(theta - eps e_k)) / (2 eps)``, to ``rtol`` with an
  absolute floor ``atol_frac max_k |fd_k|`` (single entries: small derivatives, float32 noise);
- along a direction ``v = r sign(g)`` (``r`` random in [0.5, 1.5], normalised), the
  derivative ``d loss / d s`` of ``loss(theta_0 + s v)`` three ways: forward mode
  (``dr.forward(s)``), ``g . v`` (reverse mode), and central differences with step
  ``eps_direction``. Forward and reverse must agree to ``1e-5`` (one derivative, two AD modes);
  each against the difference quotient to ``rtol_direction = 1e-3``. Along ``v`` the
  derivative sums every entry coherently, so it is large and well resolved: a gradient off by
  0.3% (a scaled or partly detached term) fails there although single entries cannot show it.

Central differences err by ``O(eps^2)`` (truncation) plus the round-off of the rendered
pixels divided by ``eps``; the loss is summed in float64 (:func:`loss64`) so that its own
rounding does not add to it. The grid cases render in float32 (as training does); measured
along ``v`` (quick camera, two direction seeds) the difference quotient is within 1.3e-4 of
AD for the sigma_t grid and 3e-5 for the colour grid at eps 0.2. The NeRF's ReLUs make its
loss piecewise smooth: difference quotients over steps of 0.01-0.2 straddle kinks and err
by up to 1e-2, growing with ``eps`` (first order, not ``eps^2``). So the NeRF case renders
the whole pipeline in float64 (every function is type-generic) with ``eps = 1e-6``: there
the difference quotient matches AD to 1e-8.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.math.box import UNIT_BOX
from mitsnerf.verify.cases import GradientCase, Quality, front_heavy_sigma_t, procedural_albedo

TARGET = 0.3
BACKGROUND = (0.8, 0.7, 0.6)
IMAGE_WIDTH = 8
N_SAMPLES = 32
GRID_RESOLUTION = 16
SIGMA_T_MAX = 6.0


@dataclass(frozen=True)
class GradientResult:
    """AD and FD derivatives of one case, and the comparisons that failed."""

    reverse_ad: np.ndarray  # at the checked entries
    reverse_fd: np.ndarray
    forward_ad: float  # along v
    forward_fd: float
    forward_from_reverse: float  # g . v
    max_rel_error: float  # max |ad - fd| / max(|fd|, floor) over the single entries
    direction_rel_error: float  # max |ad - fd| / |fd| along v (forward mode and g . v)
    failures: tuple[str, ...]
    seconds: float

    @property
    def passed(self) -> bool:
        return not self.failures


def _rays(quality: Quality, Array3f):
    """Pixel-centre rays of an ``IMAGE_WIDTH``-square version of the verification camera, as ``Array3f``."""

    from mitsnerf.math.camera import Camera
    from mitsnerf.math.rays import camera_rays

    cam = quality.camera()
    small = Camera.from_fov(cam.c2w, IMAGE_WIDTH, IMAGE_WIDTH, cam.fov_x_deg)
    rays = camera_rays(Array3f, [small])
    return rays.o, rays.d


def make_problem(case: GradientCase, quality: Quality) -> tuple[Any, Callable[[Any], Any]]:
    """``(theta_0, image_fn)``: the parameter tensor and ``theta -> C`` (Array3f, one entry per pixel)."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField
    from mitsnerf.fields.nerf import NeRFConfig, NeRFField
    from mitsnerf.render.volume import render_rays

    Array3f, TensorXf = mi.Array3f, mi.TensorXf
    if case.float64:
        Array3f, TensorXf = dr.float64_array_t(Array3f), dr.float64_array_t(TensorXf)
    o, d = _rays(quality, Array3f)
    bg = Array3f(*BACKGROUND)

    def image_of(field):
        return render_rays(field, o, d, N_SAMPLES, box=UNIT_BOX, background=bg).rgb

    sigma_np = front_heavy_sigma_t(GRID_RESOLUTION, SIGMA_T_MAX)
    albedo_np = procedural_albedo(GRID_RESOLUTION)
    if case.parameter == "sigma_t_grid":
        color = mi.TensorXf(albedo_np)
        return mi.TensorXf(sigma_np[..., None]), lambda theta: image_of(
            GridField.from_arrays(theta, UNIT_BOX, color=color)
        )
    if case.parameter == "color_grid":
        return mi.TensorXf(albedo_np), lambda theta: image_of(GridField.from_arrays(sigma_np, UNIT_BOX, color=theta))
    if case.parameter == "nerf_weights":
        config = NeRFConfig(width=16, depth=3, skip=2, pos_octaves=3, use_direction=True, dir_octaves=1, features=4,
                            head_width=8)
        field = NeRFField.create(config, TensorXf, UNIT_BOX, seed=3)
        layer = field.net.trunk[0]

        def image_nerf(theta):
            layer.weights = theta
            return image_of(field)

        return TensorXf(layer.weights), image_nerf
    raise ValueError(f"{case.name}: unknown parameter {case.parameter!r} (sigma_t_grid, color_grid, nerf_weights)")


def loss(image):
    """``mean_p,ch (C_p - target)^2`` of a Dr.Jit image (Float of width 1, differentiable)."""
    diff = image - TARGET
    return dr.mean(dr.square(diff.x) + dr.square(diff.y) + dr.square(diff.z)) / 3.0


def loss64(image) -> float:
    """The same loss summed in float64 (finite differences: no float32 rounding of the sum)."""
    c = np.stack([np.asarray(ch, dtype=np.float64) for ch in image], axis=-1)
    return float(np.mean(np.square(c - TARGET)))


def _scalar(x) -> float:
    return float(np.asarray(dr.detach(x)).ravel()[0])


def _unit_direction(g: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``v = r sign(g)``, ``r ~ U(0.5, 1.5)``, normalised: a direction of large derivative.

    A random ``v`` would mostly cancel (thousands of entries of both signs); if ``g``'s signs
    were wrong, the difference quotient along this ``v`` would disagree.
    """
    v = rng.uniform(0.5, 1.5, g.size) * np.where(g >= 0, 1.0, -1.0)
    return v / np.linalg.norm(v)


def _pick_entries(g: np.ndarray, n_checked: int, rng: np.random.Generator) -> np.ndarray:
    """The largest ``|g|`` and random others among the entries that matter (FD of the rest is ~0)."""
    g_abs = np.abs(g)
    top = [int(k) for k in np.argsort(-g_abs)[: n_checked // 2]]
    pool = np.flatnonzero(g_abs > 1e-3 * g_abs.max()) if g_abs.max() > 0 else np.arange(g.size)
    rest = [int(k) for k in rng.permutation(pool) if int(k) not in top][: n_checked - len(top)]
    return np.array(top + rest, dtype=np.int64)


def check_gradients(case: GradientCase, quality: Quality) -> GradientResult:
    """Run the reverse- and forward-mode comparisons of ``case`` (see the module docstring)."""
    start = time.perf_counter()
    theta0, image_fn = make_problem(case, quality)
    shape = tuple(theta0.shape)
    base = np.asarray(theta0, dtype=np.float64).ravel()
    rng = np.random.default_rng(quality.seed + 17)

    TensorXf = type(theta0)
    dtype = np.float64 if case.float64 else np.float32

    def tensor(values: np.ndarray):
        return TensorXf(np.asarray(values, dtype=dtype).reshape(shape))

    def central(direction: np.ndarray, eps: float) -> float:
        with dr.suspend_grad():
            plus, minus = (
                loss64(image_fn(tensor(base + eps * direction))),
                loss64(image_fn(tensor(base - eps * direction))),
            )
        return (plus - minus) / (2 * eps)

    theta = tensor(base)
    dr.enable_grad(theta)
    dr.backward(loss(image_fn(theta)), flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    g = np.asarray(dr.grad(theta), dtype=np.float64).ravel()
    entries = _pick_entries(g, case.n_checked, rng)
    fd = np.array([central(np.eye(1, base.size, k).ravel(), case.eps) for k in entries])
    ad = g[entries]

    v = _unit_direction(g, rng)
    s = dr.leaf_t(TensorXf)(0.0)
    dr.enable_grad(s)
    loss_s = loss(image_fn(tensor(base) + s * tensor(v)))
    dr.forward(s, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    fwd_ad = _scalar(dr.grad(loss_s))
    fwd_fd = central(v, case.eps_direction)
    from_reverse = float(g @ v)

    floor = case.atol_frac / case.rtol * float(np.max(np.abs(fd)))
    comparisons = [(f"reverse d/dtheta[{k}]", a, f, floor, case.rtol) for k, a, f in zip(entries.tolist(), ad, fd)]
    comparisons += [("forward along v vs FD", fwd_ad, fwd_fd, 0.0, case.rtol_direction),
                    ("reverse . v vs FD", from_reverse, fwd_fd, 0.0, case.rtol_direction),
                    ("forward vs reverse . v", fwd_ad, from_reverse, 0.0, 1e-5)]
    failures, rel = [], []
    for label, a, f, fl, tol in comparisons:
        r = abs(a - f) / max(abs(f), fl, 1e-30)
        rel.append(r)
        if not r <= tol:
            failures.append(f"{label}: {a:.6e} vs {f:.6e} (relative {r:.2e} > {tol:g})")
    n_entries = len(entries)
    return GradientResult(ad, fd, fwd_ad, fwd_fd, from_reverse, float(max(rel[:n_entries])),
                          float(max(rel[n_entries:n_entries + 2])), tuple(failures), time.perf_counter() - start)
