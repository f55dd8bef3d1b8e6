"""Derivatives of a rendered image's loss: Dr.Jit reverse and forward mode against central differences (case 5).

The loss of an image ``C(theta)`` (pixel-centre rays of a small camera, midpoint samples,
constant background ``bg``) against a constant target::

    loss(theta) = mean_p,ch (C_p(theta) - target)^2

Checked, for ``theta`` each of a sigma_t grid, the first trunk layer's weights of a
:class:`~mitsnerf.fields.nerf.NeRFField`, and a colour grid:

- reverse mode ``g = d loss / d theta`` (``dr.backward``) at ``n_checked`` entries ``k``
  (the largest ``|g_k|`` and random others) against
  ``fd_k = (loss(theta + eps e_k) - loss(theta - eps e_k)) / (2 eps)``;
- forward mode along a direction ``v = r sign(g)`` (``r`` random in [0.5, 1.5], normalised) (``theta = theta_0 + s v``, ``dr.forward(s)``)
  against ``(loss(theta + eps v) - loss(theta - eps v)) / (2 eps)``, and against ``g . v``.

Agreement: ``|ad - fd| <= rtol |fd| + atol_frac max_k |fd_k|``. Central differences err by
``O(eps^2)`` (truncation) plus ``O(u |loss| / eps)`` (float32 round-off, ``u = 6e-8``); each
case's ``eps`` and tolerances are set for its parameter's scale.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import drjit as dr
import numpy as np

from mitsnerf.math.composite import composite
from mitsnerf.verify.cases import GradientCase, Quality, front_heavy_sigma_t, procedural_albedo
from mitsnerf.math.box import UNIT_BOX

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
    max_rel_error: float  # max |ad - fd| / max(|fd|, floor) over every comparison
    failures: tuple[str, ...]
    seconds: float

    @property
    def passed(self) -> bool:
        return not self.failures


def _rays(quality: Quality):
    """Pixel-centre rays of an ``IMAGE_WIDTH``-square version of the verification camera."""
    import mitsuba as mi

    from mitsnerf.math.camera import Camera
    from mitsnerf.math.rays import camera_rays

    cam = quality.camera()
    small = Camera.from_fov(cam.c2w, IMAGE_WIDTH, IMAGE_WIDTH, cam.fov_x_deg)
    rays = camera_rays(mi.Array3f, [small])
    return rays.o, rays.d


def make_problem(case: GradientCase, quality: Quality, composite_fn=composite) -> tuple[object, Callable[[object], object]]:
    """``(theta_0, loss_fn)``: the parameter tensor and ``theta -> loss`` (a Float of width 1)."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField
    from mitsnerf.fields.nerf import NeRFConfig, NeRFField
    from mitsnerf.render.volume import render_rays

    o, d = _rays(quality)
    bg = mi.Array3f(*BACKGROUND)

    def loss_of(field):
        out = render_rays(field, o, d, N_SAMPLES, background=bg, composite_fn=composite_fn, box=UNIT_BOX)
        diff = out.rgb - TARGET
        return dr.mean(dr.square(diff.x) + dr.square(diff.y) + dr.square(diff.z)) / 3.0

    sigma_np = front_heavy_sigma_t(GRID_RESOLUTION, SIGMA_T_MAX)
    albedo_np = procedural_albedo(GRID_RESOLUTION)
    if case.parameter == "sigma_t_grid":
        color = mi.TensorXf(albedo_np)
        return mi.TensorXf(sigma_np[..., None]), lambda theta: loss_of(GridField.from_arrays(theta, UNIT_BOX, color=color))
    if case.parameter == "color_grid":
        return mi.TensorXf(albedo_np), lambda theta: loss_of(GridField.from_arrays(sigma_np, UNIT_BOX, color=theta))
    if case.parameter == "nerf_weights":
        config = NeRFConfig(width=16, depth=3, skip=2, pos_octaves=3, dir_octaves=1, features=4, head_width=8)
        field = NeRFField.create(config, mi.TensorXf, UNIT_BOX, seed=3)
        layer = field.net.trunk[0]

        def loss_nerf(theta):
            layer.weights = theta
            return loss_of(field)

        return mi.TensorXf(layer.weights), loss_nerf
    raise ValueError(f"{case.name}: unknown parameter {case.parameter!r} (sigma_t_grid, color_grid, nerf_weights)")


def _scalar(x) -> float:
    return float(np.asarray(dr.detach(x)).ravel()[0])


def check_gradients(case: GradientCase, quality: Quality, composite_fn=composite) -> GradientResult:
    """Run the reverse- and forward-mode comparisons of ``case`` (see the module docstring)."""
    import mitsuba as mi

    start = time.perf_counter()
    theta0, loss_fn = make_problem(case, quality, composite_fn)
    shape = tuple(theta0.shape)
    base = np.asarray(theta0, dtype=np.float64).ravel()
    rng = np.random.default_rng(quality.seed + 17)

    def tensor(values: np.ndarray):
        return mi.TensorXf(np.asarray(values, dtype=np.float32).reshape(shape))

    def loss_at(values: np.ndarray) -> float:
        with dr.suspend_grad():
            return _scalar(loss_fn(tensor(values)))

    def central(direction: np.ndarray) -> float:
        return (loss_at(base + case.eps * direction) - loss_at(base - case.eps * direction)) / (2 * case.eps)

    # Reverse mode.
    theta = tensor(base)
    dr.enable_grad(theta)
    dr.backward(loss_fn(theta), flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    g = np.asarray(dr.grad(theta), dtype=np.float64).ravel()

    # The largest |g| and random others among the entries that matter (FD of the rest is ~0).
    g_abs = np.abs(g)
    top = [int(k) for k in np.argsort(-g_abs)[: case.n_checked // 2]]
    pool = np.flatnonzero(g_abs > 1e-3 * g_abs.max()) if g_abs.max() > 0 else np.arange(g.size)
    rest = [int(k) for k in rng.permutation(pool) if int(k) not in top][: case.n_checked - len(top)]
    entries = np.array(top + rest, dtype=np.int64)
    unit = np.zeros_like(base)
    fd = []
    for k in entries:
        unit[k] = 1.0
        fd.append(central(unit))
        unit[k] = 0.0
    fd = np.array(fd)
    ad = g[entries]

    # Forward mode along a unit direction v: theta = theta_0 + s v, d loss / d s at s = 0. A random
    # v would mostly cancel (thousands of entries of both signs); v = r sign(g), r ~ U(0.5, 1.5),
    # has a large derivative, and if g's signs were wrong FD would disagree.
    v = rng.uniform(0.5, 1.5, base.size) * np.where(g >= 0, 1.0, -1.0)
    v /= np.linalg.norm(v)
    s = mi.Float(0.0)
    dr.enable_grad(s)
    loss_s = loss_fn(tensor(base) + s * tensor(v))
    dr.forward(s, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    fwd_ad = _scalar(dr.grad(loss_s))
    fwd_fd = central(v)
    from_reverse = float(g @ v)

    floor = case.atol_frac / case.rtol * float(np.max(np.abs(fd)))
    fwd_floor = case.atol_frac / case.rtol * float(np.linalg.norm(g))  # |d loss / dv| <= ||g||
    comparisons = [(f"reverse d/dtheta[{k}]", a, f, floor) for k, a, f in zip(entries.tolist(), ad, fd)]
    comparisons += [("forward along v", fwd_ad, fwd_fd, fwd_floor), ("reverse . v", from_reverse, fwd_fd, fwd_floor)]
    failures, rel = [], []
    for label, a, f, fl in comparisons:
        r = abs(a - f) / max(abs(f), fl, 1e-30)
        rel.append(r)
        if not r <= case.rtol:
            failures.append(f"{label}: AD {a:.5e} vs FD {f:.5e} (relative {r:.2e} > {case.rtol:g})")
    return GradientResult(ad, fd, fwd_ad, fwd_fd, from_reverse, float(max(rel)), tuple(failures),
                          time.perf_counter() - start)
