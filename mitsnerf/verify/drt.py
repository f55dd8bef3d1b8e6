"""The gradient of ``mitsnerf_drt`` (:mod:`mitsnerf.render.drt`) against finite differences of Mitsuba's ``volpath``.

A small medium (the ``front_heavy`` grid at ``R = 8``: dense where the camera's rays enter, exactly zero on the
other five faces; a procedural albedo; optionally a chromatic extinction or a Henyey-Greenstein phase), a
constant sky and a sun, the verification camera's pixel-centre rays. The loss is linear in the image,

    f(theta) = sum_p,c W_pc L_pc(theta)        (W fixed, random in [0, 1])

so that the expectation of an unbiased gradient estimate is exactly ``grad E[f]``. Along directions ``v`` of the
parameters the test compares the estimator's ``g . v`` (the mean of ``K`` independent renders of ``spp`` samples
per ray, with its standard error) with a difference quotient of ``E[f]`` rendered by volpath (``J`` seeds, each
pair of renders with common random numbers and a fixed majorant, so that they differ little; the quotients'
mean and standard error):

- ``sigma_t``: random signs on the voxels above 1/4 of the maximum (central differences, step ``eps``);
- ``sigma_t`` at zero: +1 on every voxel that is 0 (one-sided, second order:
  ``(-3 f(0) + 4 f(h) - f(2h)) / 2h``): the density growing where there is none, where free-flight
  gradients are biased (they never collide there);
- ``albedo``: random signs on every voxel and channel (central).

With the primal image against volpath on the same rays (per pixel and per channel mean,
:func:`mitsnerf.verify.stats.z_test`), these are one family decided by weighted Holm at the quality's ``alpha``
(:func:`mitsnerf.verify.stats.decide`: the pixel tests share half the weight, the channel means and the
directions the other half).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from mitsnerf.verify import mitsuba_refs as M
from mitsnerf.verify.cases import DrtCase, Quality, front_heavy_sigma_t, procedural_albedo
from mitsnerf.verify.stats import Family, ZTest, decide, z_test

SIGMA_KEY = "medium_box.interior_medium.sigma_t.data"
ALBEDO_KEY = "medium_box.interior_medium.albedo.data"
SUN = ((-0.3, 0.8, -0.5), (3.0, 2.8, 2.6))
SKY = (0.5, 0.55, 0.6)


@dataclass(frozen=True)
class Problem:
    """The grids, the rays and the loss's weights of a case."""

    sigma_t: np.ndarray  # (R, R, R) or (R, R, R, 3)
    albedo: np.ndarray  # (R, R, R, 3)
    o: np.ndarray  # (P, 3) pixel-centre rays
    d: np.ndarray
    weights: np.ndarray  # (P, 3)
    shape: tuple[int, int]


def make_problem(case: DrtCase, quality: Quality) -> Problem:
    """The case's medium (``case.resolution``), the quality's camera and the loss's weights."""
    sigma = front_heavy_sigma_t(case.resolution, case.sigma_t_max)
    if case.chromatic:
        sigma = (sigma[..., None] * np.asarray((0.7, 1.0, 1.4), np.float32)).astype(np.float32)
    camera = quality.camera()
    o, d = camera.pixel_rays()
    weights = np.random.default_rng(quality.seed + 5).random((len(o), 3))
    return Problem(sigma, procedural_albedo(case.resolution), o, d, weights, (camera.height, camera.width))


def scene_of(case: DrtCase, sigma_t: np.ndarray, albedo: np.ndarray, integrator: dict[str, Any],
             max_value: float | None = None):
    """The Mitsuba scene: the medium box, the sky, the sun, ``integrator``; ``max_value``: volpath's fixed
    majorant (None: the grid's maximum)."""
    import mitsuba as mi

    phase = {"type": "isotropic"} if case.phase_g == 0.0 else {"type": "hg", "g": float(case.phase_g)}
    desc = M.scene_dict(sigma_t, albedo, {"sky": M.constant_environment(SKY), "sun": M.directional_light(*SUN)},
                        case.max_depth, phase)
    desc["integrator"] = integrator
    if max_value is not None:
        desc["medium_box"]["interior"]["sigma_t"]["max_value"] = float(max_value)
    return mi.load_dict(desc)


def drt_integrator(case: DrtCase) -> dict[str, Any]:
    from mitsnerf.render.drt import NAME, register

    register()
    return {"type": NAME, "max_depth": case.max_depth, "majorant_cell": case.majorant_cell,
            "majorant_floor": case.majorant_floor, "drt": case.estimator == "drt"}


def estimate(scene, problem: Problem, spp: int, seed: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One render of the scene's (``mitsnerf_drt``) integrator on the problem's rays: the per-ray mean (P, 3) and
    the gradient of ``f`` with respect to the sigma_t and albedo grids (their shapes)."""
    import drjit as dr
    import mitsuba as mi

    params = mi.traverse(scene)
    for key in (SIGMA_KEY, ALBEDO_KEY):
        dr.enable_grad(params[key])
    params.update()
    n = len(problem.o)
    idx = np.repeat(np.arange(n), spp)
    ray = mi.Ray3f(mi.Point3f(*problem.o[idx].astype(np.float32).T), mi.Vector3f(*problem.d[idx].astype(np.float32).T))
    sampler = mi.load_dict({"type": "independent", "sample_count": 1})
    sampler.seed(seed, n * spp)
    integrator = scene.integrator()
    with dr.suspend_grad():
        L, _, _, state = integrator.sample(mode=dr.ADMode.Primal, scene=scene, sampler=sampler.clone(), ray=ray,
                                           δL=None, state_in=None, active=mi.Bool(True))
        grad_L = mi.Spectrum(*(problem.weights[idx] / spp).astype(np.float32).T)
        integrator.sample(mode=dr.ADMode.Backward, scene=scene, sampler=sampler, ray=ray, δL=grad_L,
                          state_in=state, active=mi.Bool(True))
    grads = {key: np.asarray(dr.grad(params[key]), dtype=np.float64).reshape(params[key].shape)
             for key in (SIGMA_KEY, ALBEDO_KEY)}
    for key in (SIGMA_KEY, ALBEDO_KEY):
        dr.disable_grad(params[key])
    mean = np.stack([np.asarray(c, dtype=np.float64) for c in L], axis=-1).reshape(n, spp, 3).mean(axis=1)
    return mean, grads


@dataclass(frozen=True)
class Direction:
    """A direction ``v`` of one grid and how its difference quotient is taken."""

    label: str
    key: str  # SIGMA_KEY or ALBEDO_KEY
    v: np.ndarray  # the grid's shape
    one_sided: bool
    eps: float


def directions(case: DrtCase, problem: Problem, seed: int) -> list[Direction]:
    """The tested directions (module docstring)."""
    rng = np.random.default_rng(seed + 11)
    s = problem.sigma_t
    dense = s >= 0.25 * s.max()
    signs = np.where(rng.random(s.shape) < 0.5, -1.0, 1.0)
    out = [Direction("sigma_t", SIGMA_KEY, signs * dense, False, case.eps * case.sigma_t_max),
           Direction("sigma_t at 0", SIGMA_KEY, (s == 0).astype(np.float64), True, case.eps * case.sigma_t_max)]
    a_signs = np.where(rng.random(problem.albedo.shape) < 0.5, -1.0, 1.0)
    out.append(Direction("albedo", ALBEDO_KEY, a_signs, False, case.eps))
    return out


def _loss(reference: M.Reference, weights: np.ndarray) -> float:
    return float(np.sum(reference.mean * weights))


def difference_quotient(case: DrtCase, problem: Problem, direction: Direction, quality: Quality) -> np.ndarray:
    """Volpath's difference quotients of ``E[f]`` along ``direction``, one per seed (J,)."""
    spp = quality.reference_spp(case.fd_spp_factor)
    majorant = 1.5 * float(np.max(problem.sigma_t)) + 2.0 * case.eps * case.sigma_t_max
    steps = (0.0, 1.0, 2.0) if direction.one_sided else (1.0, -1.0)
    out = []
    for j in range(case.fd_seeds):
        values = []
        for k in steps:
            grids = {"sigma_t": problem.sigma_t, "albedo": problem.albedo}
            name = "sigma_t" if direction.key == SIGMA_KEY else "albedo"
            grids[name] = (grids[name] + k * direction.eps * direction.v.reshape(grids[name].shape)).astype(np.float32)
            scene = scene_of(case, grids["sigma_t"], grids["albedo"], {"type": "volpath", "max_depth": case.max_depth},
                             max_value=majorant)
            ref = M.sample_rays(scene, problem.o, problem.d, spp, quality.seed + 101 * j)
            values.append(_loss(ref, problem.weights))
        if direction.one_sided:
            out.append((-3.0 * values[0] + 4.0 * values[1] - values[2]) / (2.0 * direction.eps))
        else:
            out.append((values[0] - values[1]) / (2.0 * direction.eps))
    return np.asarray(out)


@dataclass(frozen=True)
class DrtResult:
    """The family (primal pixels and channel means, one test per direction) and the numbers behind it."""

    family: Family
    gradient: dict[str, tuple[float, float]]  # direction -> (mean g . v, standard error)
    finite_difference: dict[str, tuple[float, float]]
    seconds: float

    @property
    def passed(self) -> bool:
        return self.family.passed


def _mean_se(x) -> tuple[float, float]:
    x = np.asarray(x, dtype=np.float64)
    return float(x.mean()), float(x.std(ddof=1) / math.sqrt(len(x)))


@dataclass(frozen=True)
class PreparedDrt:
    """What volpath says of a case, rendered once: the primal reference and each direction's quotients."""

    case: DrtCase
    quality: Quality
    problem: Problem
    directions: tuple[Direction, ...]
    reference: M.Reference
    finite_difference: dict[str, tuple[float, float]]
    seconds: float


def prepare_drt(case: DrtCase, quality: Quality) -> PreparedDrt:
    """Render the case's references (volpath only: no code under test runs here)."""
    start = time.perf_counter()
    problem = make_problem(case, quality)
    dirs = tuple(directions(case, problem, quality.seed))
    scene = scene_of(case, problem.sigma_t, problem.albedo, {"type": "volpath", "max_depth": case.max_depth})
    ref = M.sample_rays(scene, problem.o, problem.d, quality.reference_spp(case.ref_spp_factor), quality.seed + 7)
    fd = {d.label: _mean_se(difference_quotient(case, problem, d, quality)) for d in dirs}
    return PreparedDrt(case, quality, problem, dirs, ref, fd, time.perf_counter() - start)


def evaluate_drt(prepared: PreparedDrt) -> DrtResult:
    """The estimator's renders against the prepared references (module docstring)."""
    start = time.perf_counter()
    case, quality, problem = prepared.case, prepared.quality, prepared.problem
    scene = scene_of(case, problem.sigma_t, problem.albedo, drt_integrator(case))
    images: list[np.ndarray] = []
    dots: dict[str, list[float]] = {d.label: [] for d in prepared.directions}
    for k in range(case.renders):
        mean, grads = estimate(scene, problem, case.spp, quality.seed * 1000 + k)
        images.append(mean)
        for d in prepared.directions:
            dots[d.label].append(float(np.sum(grads[d.key] * d.v.reshape(grads[d.key].shape))))
    stack, ref, (h, w) = np.stack(images), prepared.reference, problem.shape
    primal = z_test(stack.mean(axis=0).reshape(h, w, 3), ref.mean.reshape(h, w, 3), ref.var.reshape(h, w, 3), ref.n,
                    measured_var=stack.var(axis=0, ddof=1).reshape(h, w, 3), measured_n=len(images),
                    label="image")
    gradient = {label: _mean_se(v) for label, v in dots.items()}
    fd = prepared.finite_difference
    z = np.array([(gradient[k][0] - fd[k][0]) / math.hypot(gradient[k][1], fd[k][1]) for k in gradient])
    family = decide([primal, ZTest("gradient . v", np.zeros((0, 1)), z, 0.0, math.inf)], quality.alpha)
    return DrtResult(family, gradient, fd, time.perf_counter() - start)


def check_drt(case: DrtCase, quality: Quality) -> DrtResult:
    """Prepare and evaluate the case (module docstring)."""
    return evaluate_drt(prepare_drt(case, quality))
