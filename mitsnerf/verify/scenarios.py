"""The volpath cases: render the Mitsuba references once, then test the integrator against them.

A :class:`PreparedScenario` holds a scenario's volpath reference (the slow part) and the
field and background the integrator renders; :func:`evaluate_scenario` renders the
integrator's images (one per quadrature rule) and decides all their tests as one family
(:func:`mitsnerf.verify.stats.decide`). The training-path case reuses a scenario's reference;
the Mitsuba furnace tests volpath alone.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from mitsnerf.verify import cases as C
from mitsnerf.verify.stats import Family, decide, z_test


@dataclass(frozen=True)
class Outcome:
    """What a volpath case measured: its test family, the images for artifacts, a note to print."""

    family: Family
    reference: str
    images: dict[str, np.ndarray]
    note: str
    seconds: float


@dataclass(frozen=True)
class PreparedScenario:
    """A scenario's Mitsuba reference and the field/background the integrator renders (reusable)."""

    scenario: C.VolpathScenario
    quality: C.Quality
    reference: Any  # mitsuba_refs.Reference, (H, W, 3)
    field: Any
    background: Any
    ray_length: np.ndarray  # (H, W): L = t_f - t_n of each pixel's ray (independent float64 slab test)


def prepare_scenario(s: C.VolpathScenario, quality: C.Quality) -> PreparedScenario:
    """Render the volpath reference of ``s`` (the slow part) and build the matching field."""
    import mitsuba as mi

    from mitsnerf.math.box import UNIT_BOX
    from mitsnerf.render.background import EnvmapBackground
    from mitsnerf.verify import mitsuba_refs as M
    from mitsnerf.verify.sources import SOURCE_BUILDERS

    sigma_t, albedo = C.scenario_grids(s, quality.resolution)
    scene = mi.load_dict(M.scene_dict(sigma_t, albedo, M.emitters_of(s), s.max_depth, s.phase()))
    camera = quality.camera()
    o, d = camera.pixel_rays()
    spp = quality.reference_spp(s.spp_factor)
    names = [x.name for x in C.SCENARIOS]  # a seed of its own per scenario: independent references
    seed = quality.seed * 1000 + (names.index(s.name) if s.name in names else len(names))
    ref = M.sample_rays(scene, o, d, spp, seed).reshaped(camera.height, camera.width)
    # The emitter object volpath saw, evaluated the same way (None: black).
    env = scene.environment()
    background = EnvmapBackground(env) if env is not None else None
    field = SOURCE_BUILDERS[s.source](s, sigma_t, albedo, scene, quality)
    t_n, t_f, _ = UNIT_BOX.intersect_numpy(o, d)
    return PreparedScenario(s, quality, ref, field, background, (t_f - t_n).reshape(camera.height, camera.width))


def seed_bias_factor(p: PreparedScenario) -> np.ndarray:
    """``exp(sigma_t L / 2N)`` (H, W, 1): the seed's rule over volpath in a homogeneous box with ``c = 0``.

    With midpoints the seed's deltas sum to ``L - h/2``, so it renders exactly
    ``exp(-sigma_t (L - h/2)) bg = exp(sigma_t L / 2N) exp(-sigma_t L) bg``.
    """
    return np.exp(p.scenario.sigma_t_max * p.ray_length / (2 * p.quality.n_samples))[..., None]


def _render(p: PreparedScenario, quadrature: str, n_samples: int | None = None, jitter=None) -> np.ndarray:
    from mitsnerf.verify.sources import render_image

    q = p.quality
    return render_image(p.field, q.camera(), n_samples or q.n_samples, p.background, quadrature, jitter)


def _render_with_variance(p: PreparedScenario, quadrature: str) -> tuple[np.ndarray, np.ndarray | None]:
    """The integrator's image and, for a Monte Carlo source (the oracle's J), its own variance per pixel."""
    import mitsuba as mi

    from mitsnerf.math.box import UNIT_BOX
    from mitsnerf.math.rays import camera_rays
    from mitsnerf.oracle.compare import PointSource, render_with_variance

    if not isinstance(p.field, PointSource):
        return _render(p, quadrature), None
    if quadrature != "seed":
        raise ValueError(f"{p.scenario.name}: the in-scattered source renders with the seed's rule only")
    cam = p.quality.camera()
    rays = camera_rays(mi.Array3f, [cam])
    mean, var = render_with_variance(p.field, rays.o, rays.d, p.quality.n_samples, UNIT_BOX, p.background)
    return mean.reshape(cam.height, cam.width, 3), var.reshape(cam.height, cam.width, 3)


def _seed_bias_note(p: PreparedScenario, ours_seed: np.ndarray | None) -> str:
    """The seed's rule against raw volpath: measured (and, in a homogeneous box, predicted) relative bias."""
    ref = p.reference
    if ours_seed is None:
        ours_seed = _render(p, "seed")
    t = z_test(ours_seed, ref.mean, ref.var, ref.n)
    signed = float(np.sum(ours_seed - ref.mean) / np.sum(np.abs(ref.mean)))
    note = (f"seed's rule against volpath as it is (its first-order exit bias, not a test): relative "
            f"{signed:+.2e}, channel-mean z {t.z_mean:+.1f}")
    if p.scenario.seed_reference() == "closed_form_bias":
        predicted = float(np.sum((seed_bias_factor(p) - 1.0) * ref.mean) / np.sum(np.abs(ref.mean)))
        note += f" (closed form {predicted:+.2e})"
    return note


def evaluate_scenario(p: PreparedScenario) -> Outcome:
    """Render the integrator's image for each rule of the scenario and test them as one family."""
    s, q, ref = p.scenario, p.quality, p.reference
    start = time.perf_counter()
    tests, images, ours_seed = [], {"reference": ref.mean}, None
    for quadrature in s.quadratures:
        ours, ours_var = _render_with_variance(p, quadrature)
        mean, var, label = ref.mean, ref.var, f"{quadrature} vs volpath"
        if quadrature == "seed":
            ours_seed = ours
            if s.seed_reference() == "closed_form_bias":
                k = seed_bias_factor(p)
                mean, var, label = ref.mean * k, ref.var * k**2, "seed vs volpath x exp(sigma_t L / 2N)"
        # a Monte Carlo source's image variance V enters as measured_var = 2 V over measured_n = 2
        tests.append(z_test(ours, mean, var, ref.n, max_rel_error=s.max_rel_error, label=label,
                            measured_var=None if ours_var is None else 2.0 * ours_var,
                            measured_n=None if ours_var is None else 2))
        images[f"ours_{quadrature}"] = ours
        images[f"error_{quadrature}"] = ours - mean
        images[f"z_{quadrature}"] = np.abs(tests[-1].z)
    family = decide(tests, q.alpha)
    reference = f"volpath {ref.n} spp" + (f", max_depth {s.max_depth}" if s.max_depth >= 0 else "")
    note = "" if s.medium == "front_heavy" else _seed_bias_note(p, ours_seed)
    return Outcome(family, reference, images, note, ref.seconds + time.perf_counter() - start)


def evaluate_training_path(case: C.TrainingPathCase, p: PreparedScenario) -> Outcome:
    """The mean of ``case.renders`` jittered renders (training's generator, steps 0, 1, ...) against volpath."""
    import mitsuba as mi

    from mitsnerf.train.schedule import step_rng

    q, ref = p.quality, p.reference
    start = time.perf_counter()
    n = case.n_factor * q.n_samples
    renders = []
    for step in range(case.renders):
        generator = step_rng(q.seed, step)  # as the training loop draws u at this step
        renders.append(_render(p, "seed", n, lambda size, g=generator: g.random(mi.Float, size)))
    stack = np.stack(renders)
    mean, var = stack.mean(axis=0), stack.var(axis=0, ddof=1)
    test = z_test(mean, ref.mean, ref.var, ref.n, measured_var=var, measured_n=case.renders,
                  max_rel_error=p.scenario.max_rel_error, label=f"mean of {case.renders} jittered renders vs volpath")
    family = decide([test], q.alpha)
    signed = float(np.sum(mean - ref.mean) / np.sum(np.abs(ref.mean)))
    note = (f"N = {n} (seed's rule, training jitter); measured relative difference {signed:+.2e}; jitter's own "
            f"noise {math.sqrt(float(var.mean()) / case.renders):.1e} per pixel against the reference's "
            f"{math.sqrt(float(ref.var.mean()) / ref.n):.1e}")
    return Outcome(family, f"volpath of {p.scenario.name}, {ref.n} spp", {"ours": mean, "reference": ref.mean},
                   note, time.perf_counter() - start)


def mitsuba_furnace(case: C.MitsubaFurnace, quality: C.Quality) -> Outcome:
    """volpath in a white furnace (albedo 1, environment 1, unlimited depth) against the constant 1."""
    import mitsuba as mi

    from mitsnerf.verify import mitsuba_refs as M

    start = time.perf_counter()
    sigma = C.front_heavy_sigma_t(quality.resolution, case.sigma_t_max)
    scene = mi.load_dict(M.scene_dict(sigma, 1.0, {"environment": M.constant_environment((1.0, 1.0, 1.0))},
                                      case.max_depth))
    camera = quality.camera()
    o, d = camera.pixel_rays()
    spp = quality.reference_spp(case.spp_factor)
    ref = M.sample_rays(scene, o, d, spp, quality.seed * 1000 + 100).reshaped(camera.height, camera.width)
    test = z_test(np.ones_like(ref.mean), ref.mean, ref.var, ref.n, max_rel_error=case.max_rel_error,
                  label="1 vs volpath")
    return Outcome(decide([test], quality.alpha), f"the constant 1; volpath {ref.n} spp", {"reference": ref.mean},
                   "", time.perf_counter() - start)
