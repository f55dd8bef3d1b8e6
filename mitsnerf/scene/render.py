"""Rendering the ground truth: one ``volpath`` pass per view of a split, the image composed from it, and
the true grids on disk.

Each view is rendered with ``mi.render(scene, sensor=..., spp=..., seed=...)`` on one loaded scene,
with a seed of its own (:func:`render_seed`), so noise is independent across views and between
``test`` and ``test_ref``.

**The medium alone** (``medium_alone=True``, :func:`medium_alone_integrator`): ``volpath`` with
``hide_emitters``, which hides an emitter only where a path meets it at depth 0, that is, the
environment a camera ray sees straight through the medium without a real collision (null collisions
and the box's ``null`` surfaces do not count as depth). Everything else is kept: light from the
environment and the other lights scattered in the medium (sampled towards the emitters, and met by
scattered rays, at depth >= 1). Volpath draws the same random numbers with and without
``hide_emitters`` (it only masks that one contribution), so with one seed the two renders trace the
same paths and differ by exactly the escaped camera samples' environment radiance, which
``tests/scene/test_one_pass.py`` checks to float rounding. The film's alpha is the fraction of a pixel's
samples whose camera ray had a real collision (volpath's ``valid_ray``): with delta tracking that
happens with probability ``1 - T``, so alpha is an unbiased, box-filtered estimate of ``1 - T``.

**One pass per split** (:func:`compose`): per camera sample, a direct render's estimate is ``m`` if the
camera ray collided (probability ``p = 1 - T``) and ``L_env(d)`` if it escaped; the medium alone's is ``m``
or 0. With ``T`` along a ray through the known grid deterministic
(:func:`mitsnerf.scene.transmittance.pixel_transmittance`: exact along the ray, a ``K x K`` average over the
pixel, :func:`footprint_for`), a pixel of the image is composed from the medium render ``(M, alpha)`` alone::

    image = M + mean(T L_env) - B (alpha - (1 - mean T))        B = mean(L_env) over the pixel

``mean(T L_env)`` is the environment seen through the medium, exactly; ``alpha - (1 - mean T)`` has mean
zero (alpha estimates ``1 - mean T`` without bias), so any coefficient keeps the image unbiased and ``B``
is the one that keeps its noise down. Without that term (coefficient 0: ``M`` plus the exact background
alone) the image is *noisier* than a direct render wherever the medium is brighter than half the
background: per sample ``Var(direct) - Var(M + T B) = p (1 - p) B (B - 2 mu)``, ``mu`` the mean radiance
of a collided sample. Coefficient ``mu`` is the optimum; ``B`` beats 0 on every library scene with an
environment, by 0.17-4.41 dB of medium noise floor, and is within 0.1 dB of the optimum on four of the
seven, 0.84 dB on lattice (benchmarks/README.md, "One volpath pass per split"). Under a constant
environment the image is then ``M + (1 - alpha) B``, which is the direct render with the same seed,
sample for sample (the paths are the same); under a sky the escaped samples' ``L_env(d_k)`` is replaced
by the pixel's mean and the exact covariance term ``mean(T L) - mean(T) B`` restores the expectation.
Without an environment the image is ``M``. Where the lights do not allow it (:func:`one_pass_reason`)
each split is rendered twice, the image directly and the medium alone with the seeds of
``<split>_medium``.

**A chromatic medium** (3-channel ``sigma_t``): volpath follows one colour channel per path and
weights the others by ratios of transmittances, and Mitsuba 3.9 draws a real collision with a probability
that mixes the channels by the path's throughput (``Medium::get_interaction_probabilities``), so alpha is
not the collision probability of any channel, nor their mean (``benchmarks/chromatic_alpha.py`` on the
library's ``smoke``, 8 views at 2048 spp: z from 61 to 668 against each channel's ``1 - T`` and the
channels' mean; it agrees with ``1 - T`` of the channels' mean extinction, z -1.2 and +0.4, an observation
rather than a derived identity, since the mixing weights change along the path). The image is then
``M + mean(T L_env)`` per channel, without the alpha term: unbiased whatever alpha estimates (a camera path
escapes with weighted throughput ``T_k`` in channel ``k`` on average), and alpha is recorded, not checked.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.math.box import Box
from mitsnerf.math.camera import Camera
from mitsnerf.scene.lights import bake_sky
from mitsnerf.scene.spec import SceneSpec, SkyLight
from mitsnerf.scene.to_mitsuba import ENVMAP_FILE, load_sensor
from mitsnerf.scene.transmittance import PixelTransmittance

SPLIT_IDS = {"train": 0, "test": 1, "test_ref": 2, "train_medium": 3, "test_medium": 4, "test_ref_medium": 5}


def render_seed(seed: int, split: str, index: int) -> int:
    """The Mitsuba sampler seed (uint32) of view ``index`` of ``split``: distinct per view and split.

    >>> render_seed(0, "test", 0) != render_seed(0, "test_ref", 0)
    True
    """
    ss = np.random.SeedSequence([seed, SPLIT_IDS[split], index])
    return int(ss.generate_state(1, dtype=np.uint32)[0])


def split_spp(spec: SceneSpec, split: str) -> int:
    return spec.render.spp_train if split == "train" else spec.render.spp_test


def write_volume(directory: Path, spec: SceneSpec, sigma_t: np.ndarray, albedo: np.ndarray, box: Box) -> None:
    """The true grids under ``directory/volume/`` (``.npy`` and Mitsuba ``.vol``), and the sky's bitmap."""
    from mitsnerf.data.dataset import true_grid_path
    from mitsnerf.data.images import write_exr
    from mitsnerf.data.vol import write_vol

    vol = true_grid_path(directory).parent
    vol.mkdir()
    np.save(true_grid_path(directory, "sigma_t"), sigma_t)
    np.save(true_grid_path(directory, "albedo"), albedo)
    write_vol(vol / "sigma_t.vol", sigma_t, box.lo, box.hi)
    write_vol(vol / "albedo.vol", albedo, box.lo, box.hi)
    if isinstance(spec.environment, SkyLight):
        write_exr(directory / ENVMAP_FILE, bake_sky(spec.environment))


#: Light types whose part of a camera pixel is ``M + mean T L_env`` with ``L_env`` the manifest's
#: ``background`` (why, per type). A light of another type is rendered in two passes (:func:`one_pass_reason`).
SEPARABLE_LIGHTS = {
    "constant": "an environment: hidden at depth 0 by hide_emitters, its radiance behind the medium is the "
                "background's constant",
    "sky": "an environment (envmap): hidden at depth 0 by hide_emitters, looked up as the background's envmap",
    "directional": "a delta light: never met by a camera ray, only sampled from scattering points",
    "point": "a delta light: never met by a camera ray, only sampled from scattering points",
}
#: Sub-pixel rays per side for the background term: K = 16 where a split's spp is at least this, else 8.
FINE_FOOTPRINT_SPP = 512


def one_pass_reason(spec: SceneSpec) -> str | None:
    """None when one volpath pass per split gives both the image and the medium alone; else why not (the
    split is then rendered twice). One pass needs every light in :data:`SEPARABLE_LIGHTS`, and a
    ``render.max_depth`` other than 1: with 1, volpath stops a camera path at its first real collision
    before it counts it (``valid_ray``), so the medium alone's alpha is 0, not an estimate of ``1 - T``."""
    for i, light in enumerate(spec.lights):
        if light.type not in SEPARABLE_LIGHTS:
            return (f"lights.{i} ({light.type!r}) is not an environment the background describes nor a delta "
                    "light: what a camera ray sees of it through the medium is not T times the background")
    if spec.render.max_depth == 1:
        return ("render.max_depth = 1: volpath counts no camera sample as collided, so the medium alone's alpha is 0, "
                "not an estimate of 1 - T")
    return None


def footprint_for(spp: int) -> int:
    """K, the K x K sub-pixel rays per pixel of a split's background term: 16 at :data:`FINE_FOOTPRINT_SPP`
    spp or more, else 8. Against K = 32 (3 test views each of cloud, cloud_thick, lattice, nebula, plume,
    shell; ``benchmarks/onepass_noise.py --footprint``), in standard deviations of a pixel's alpha
    (``sqrt(p (1 - p) / spp)``) at the scene's test spp: K = 16 leaves at most 0.24 (lattice's sharp edges;
    0.48 at 2048 spp), 0.015 rms; K = 8 up to 1.9 on lattice at 512 spp, 0.67 at the 64 spp of the train
    views, the only ones it is used for there."""
    return 16 if spp >= FINE_FOOTPRINT_SPP else 8


def compose(medium: list[np.ndarray], seen: PixelTransmittance, has_environment: bool,
            chromatic: bool = False) -> list[np.ndarray]:
    """The full images from the medium-alone renders (RGBA ``(H, W, 4)`` each) and what each pixel sees
    through the medium (``seen``: its mean ``T``, ``T L_env`` and ``L_env``; no environment: ``through`` None):
    ``RGB = M + mean(T L) - mean(L) (alpha - (1 - mean T))`` (module docstring; ``chromatic``: without the
    alpha term), and alpha 1 under an environment light (Mitsuba's full render), else the medium's alpha (the
    full render is then the medium render itself)."""
    out = []
    for i, img in enumerate(medium):
        full = np.array(img, dtype=np.float32, copy=True)
        if seen.through is not None and seen.env is not None:
            zero_mean = (0.0 if chromatic else
                         img[..., 3:4].astype(np.float64) - (1.0 - seen.t[i][..., None]))
            full[..., :3] = (img[..., :3] + seen.through[i] - seen.env[i] * zero_mean).astype(np.float32)
        if has_environment:
            full[..., 3] = 1.0
        out.append(full)
    return out


def medium_alone_integrator(spec: SceneSpec):
    """``volpath`` with ``hide_emitters``: the medium's own radiance, alpha ``~ 1 - T`` (module docstring)."""
    import mitsuba as mi

    return mi.load_dict({"type": "volpath", "max_depth": int(spec.render.max_depth), "hide_emitters": True})


def render_split(scene, spec: SceneSpec, split: str, cameras: list[Camera], progress: bool, *,
                 medium_alone: bool = False, seed_split: str | None = None) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Every view of ``split`` (RGBA float32 (H, W, 4)) and the timings of the rendering.

    ``medium_alone``: the medium without the environment seen through it (module docstring).
    ``seed_split``: whose seeds (:func:`render_seed`) the views take, default ``split``.
    """
    import mitsuba as mi
    from tqdm.auto import tqdm

    spp = split_spp(spec, split)
    integrator = medium_alone_integrator(spec) if medium_alone else None
    seed_split = seed_split or split
    images, seconds = [], []
    with tqdm(total=len(cameras), desc=f"{spec.name} {seed_split}", unit="view", disable=None if progress else True,
              leave=False) as bar:
        for i, cam in enumerate(cameras):
            bar.set_postfix_str(f"r_{i:03d} ({spp} spp)")
            sensor = load_sensor(cam, spp)
            start = time.perf_counter()
            images.append(np.array(mi.render(scene, sensor=sensor, integrator=integrator, spp=spp,
                                             seed=render_seed(spec.render.seed, seed_split, i)), dtype=np.float32))
            seconds.append(time.perf_counter() - start)
            bar.update()
    total = float(sum(seconds))
    w, h = cameras[0].width, cameras[0].height
    timing = {"views": len(cameras), "spp": spp, "seconds": total, "seconds_per_view": total / len(cameras),
              "first_view_seconds": seconds[0],
              "samples_per_second": w * h * spp * len(cameras) / total if total > 0 else None}
    return images, timing
