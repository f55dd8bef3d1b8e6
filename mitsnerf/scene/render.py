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
seven, 0.84 dB on lattice (docs/notes/ground-truth.md, "One volpath pass per split"). Under a constant
environment the image is then ``M + (1 - alpha) B``, which is the direct render with the same seed,
sample for sample (the paths are the same); under a sky the escaped samples' ``L_env(d_k)`` is replaced
by the pixel's mean and the exact covariance term ``mean(T L) - mean(T) B`` restores the expectation.
Without an environment the image is ``M``. Where the lights do not allow it (:func:`one_pass_reason`)
each split is rendered twice, the image directly and the medium alone with the seeds of
``<split>_medium`` (a chromatic medium then as one chromatic scene).

**A chromatic medium** (3-channel ``sigma_t``, :func:`render_channels`): each colour channel is rendered on
its own, as a grey medium of extinction ``sigma_t[..., k]`` (the same albedo and lights; radiative transfer in
RGB does not couple the channels, so channel ``k`` of that render is channel ``k`` of the chromatic medium's),
with seeds of its own (:func:`render_seed`'s ``channel``), and composed by the grey rule with that channel's
exact ``T_k`` (:func:`compose`'s ``channel_alpha``)::

    image_k = M_k + mean(T_k L_env,k) - mean(L_env,k) (alpha_k - (1 - mean T_k))

``medium/`` holds ``M_k`` in channel ``k`` and alpha ``mean_k alpha_k``, an unbiased estimate of ``1 - mean_k T_k``
(:func:`merge_channels`). A chromatic render by volpath itself follows one channel per path and weights the
others by ratios of extinctions; its alpha agrees with no channel's ``1 - T`` nor their mean
(``benchmarks/chromatic_alpha.py``), so a composition from it cannot take the zero-mean term and is
``M + mean(T_k L_env,k)`` alone (dataset format 6): on the library's ``smoke`` at 512 spp 2.4, 4.9 and 1.8
times a direct render's variance in R, G and B, against 1.0, 1.3 and 0.21 for the per-channel renders, at 1.5
and 2.7 times the direct render's seconds (variance x seconds: 3.6 / 7.6 / 2.7 against 2.7 / 3.6 / 0.57; a
direct render, 1, would need a second pass for ``medium/``: 2.5; ``benchmarks/chromatic_noise.py``,
docs/notes/chromatic.md, "The smoke's noise: one grey render per channel").
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.math.box import Box
from mitsnerf.math.camera import Camera
from mitsnerf.outputs import progress_log
from mitsnerf.scene.lights import bake_sky
from mitsnerf.scene.spec import SceneSpec, SkyLight
from mitsnerf.scene.to_mitsuba import ENVMAP_FILE, load_sensor
from mitsnerf.scene.transmittance import PixelTransmittance

SPLIT_IDS = {"train": 0, "test": 1, "test_ref": 2, "train_medium": 3, "test_medium": 4, "test_ref_medium": 5,
             "test_direct": 6, "test_ref_direct": 7}


def render_seed(seed: int, split: str, index: int, channel: int | None = None) -> int:
    """The Mitsuba sampler seed (uint32) of view ``index`` of ``split``: distinct per view and split, and per
    colour ``channel`` when a chromatic medium's channels are rendered one by one (:func:`render_channels`).

    >>> render_seed(0, "test", 0) != render_seed(0, "test_ref", 0) != render_seed(0, "test_ref", 0, channel=0)
    True
    >>> len({render_seed(0, "test", 0, channel) for channel in (None, 0, 1, 2)})
    4
    """
    # channel + 1: SeedSequence ignores trailing zero words, so channel 0 would take the grey seed
    entropy = [seed, SPLIT_IDS[split], index] + ([] if channel is None else [channel + 1])
    return int(np.random.SeedSequence(entropy).generate_state(1, dtype=np.uint32)[0])


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
            channel_alpha: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """The full images from the medium-alone renders (RGBA ``(H, W, 4)`` each) and what each pixel sees
    through the medium (``seen``: its mean ``T``, ``T L_env`` and ``L_env``; no environment: ``through`` None):
    ``RGB = M + mean(T L) - mean(L) (alpha - (1 - mean T))`` (module docstring), and alpha 1 under an
    environment light (Mitsuba's full render), else the medium's alpha (the full render is then the medium
    render itself). ``channel_alpha``: a chromatic medium rendered per channel (:func:`render_channels`), each
    view's ``(H, W, 3)`` alphas, one per colour channel, with ``seen.t_rgb`` the channels' ``mean T_k``.

    >>> seen = PixelTransmittance(np.full((1, 1, 1), 0.5), np.full((1, 1, 1, 3), 0.25), np.full((1, 1, 1, 3), 0.5))
    >>> compose([np.array([[[0.25, 0.25, 0.25, 1.0]]])], seen, True)[0].tolist()  # a collided sample: M
    [[[0.25, 0.25, 0.25, 1.0]]]
    >>> compose([np.array([[[0.0, 0.0, 0.0, 0.0]]])], seen, True)[0].tolist()  # an escaped one: the background
    [[[0.5, 0.5, 0.5, 1.0]]]
    """
    out = []
    for i, img in enumerate(medium):
        full = np.array(img, dtype=np.float32, copy=True)
        if seen.through is not None and seen.env is not None:
            if channel_alpha is None:
                zero_mean = img[..., 3:4].astype(np.float64) - (1.0 - seen.t[i][..., None])
            else:
                assert seen.t_rgb is not None, "a per-channel composition needs each channel's T"
                zero_mean = channel_alpha[i].astype(np.float64) - (1.0 - seen.t_rgb[i])
            with np.errstate(over="ignore", invalid="ignore"):  # radiance past float32 (inf, NaN) is refused
                rgb = img[..., :3] + seen.through[i] - seen.env[i] * zero_mean  # after, in one line, by check_views
                full[..., :3] = rgb.astype(np.float32)
        if has_environment:
            full[..., 3] = 1.0
        out.append(full)
    return out


def merge_channels(renders: list[list[np.ndarray]]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """A chromatic medium's ``medium/`` views from its three grey renders (``renders[k]``: the RGBA views of
    channel ``k``'s medium alone): RGB channel ``k`` from render ``k``, alpha the mean of the three alphas
    (an estimate of ``1 - mean_k T_k``); and each view's ``(H, W, 3)`` per-channel alphas (:func:`compose`).

    >>> views, alphas = merge_channels([[np.full((1, 1, 4), k + 1.0)] for k in range(3)])
    >>> views[0].tolist(), alphas[0].tolist()
    ([[[1.0, 2.0, 3.0, 2.0]]], [[[1.0, 2.0, 3.0]]])
    """
    merged, alphas = [], []
    for views in zip(*renders):
        alpha = np.stack([v[..., 3] for v in views], axis=-1).astype(np.float32)
        rgb = np.stack([v[..., k] for k, v in enumerate(views)], axis=-1)
        merged.append(np.concatenate([rgb, alpha.mean(-1, keepdims=True)], axis=-1).astype(np.float32))
        alphas.append(alpha)
    return merged, alphas


def channel_scenes(spec: SceneSpec, sigma_t: np.ndarray, albedo: np.ndarray) -> list:
    """A chromatic medium's three grey Mitsuba scenes: channel ``k``'s with the extinction ``sigma_t[..., k]``."""
    import mitsuba as mi

    from mitsnerf.scene.to_mitsuba import scene_dict

    return [mi.load_dict(scene_dict(spec, np.ascontiguousarray(sigma_t[..., k]), albedo)) for k in range(3)]


def medium_alone_integrator(spec: SceneSpec):
    """``volpath`` with ``hide_emitters``: the medium's own radiance, alpha ``~ 1 - T`` (module docstring)."""
    import mitsuba as mi

    return mi.load_dict({"type": "volpath", "max_depth": int(spec.render.max_depth), "hide_emitters": True})


def render_split(scene, spec: SceneSpec, split: str, cameras: list[Camera], progress: bool, *,
                 medium_alone: bool = False, seed_split: str | None = None, channel: int | None = None,
                 spp: int | None = None) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Every view of ``split`` (RGBA float32 (H, W, 4)) and the timings of the rendering.

    ``medium_alone``: the medium without the environment seen through it (module docstring).
    ``seed_split``: whose seeds (:func:`render_seed`) the views take, default ``split``; ``channel``: the colour
    channel a chromatic medium's grey ``scene`` renders (its own seeds). ``spp``: default the split's.
    ``progress``: a bar on a terminal, and a line on stderr before and after (:func:`mitsnerf.outputs.progress_log`).
    """
    import mitsuba as mi
    from tqdm.auto import tqdm

    spp = spp or split_spp(spec, split)
    integrator = medium_alone_integrator(spec) if medium_alone else None
    seed_split = seed_split or split
    images, seconds = [], []
    what = seed_split if channel is None else f"{seed_split} {'RGB'[channel]}"
    log = progress_log(progress)
    log(f"[{spec.name}] {what}: rendering {len(cameras)} views of {cameras[0].width}x{cameras[0].height} at {spp} "
        "spp ...")
    with tqdm(total=len(cameras), desc=f"{spec.name} {what}", unit="view", disable=None if progress else True,
              leave=False) as bar:
        for i, cam in enumerate(cameras):
            bar.set_postfix_str(f"r_{i:03d} ({spp} spp)")
            sensor = load_sensor(cam, spp)
            start = time.perf_counter()
            images.append(np.array(mi.render(scene, sensor=sensor, integrator=integrator, spp=spp,
                                             seed=render_seed(spec.render.seed, seed_split, i, channel)),
                                   dtype=np.float32))
            seconds.append(time.perf_counter() - start)
            bar.update()
    log(f"[{spec.name}] {what}: {len(cameras)} views in {sum(seconds):.1f} s")
    return images, _timing(cameras, spp, float(sum(seconds)), seconds[0])


def _timing(cameras: list[Camera], spp: int, total: float, first: float, renders: int = 1) -> dict[str, Any]:
    """A split's render timings: ``total`` seconds, ``first`` those of its first view (kernel compilation
    included), ``renders`` renders of each view at ``spp``."""
    samples = cameras[0].width * cameras[0].height * spp * len(cameras) * renders
    return {"views": len(cameras), "spp": spp, "seconds": total, "seconds_per_view": total / len(cameras),
            "first_view_seconds": first, "samples_per_second": samples / total if total > 0 else None}


def render_channels(scenes: list, spec: SceneSpec, split: str, cameras: list[Camera],
                    progress: bool) -> tuple[list[np.ndarray], list[np.ndarray], dict[str, Any]]:
    """A chromatic medium's split, each colour channel rendered alone as the medium alone of its grey scene
    (:func:`channel_scenes`, module docstring): ``(medium/'s views, per-channel alphas, timings)``
    (:func:`merge_channels`); the timings add up the three renders (``renders_per_view``: 3)."""
    renders, timings = [], []
    for k, scene in enumerate(scenes):
        views, timing = render_split(scene, spec, split, cameras, progress, medium_alone=True, channel=k)
        renders.append(views)
        timings.append(timing)
    medium, alphas = merge_channels(renders)
    timing = _timing(cameras, split_spp(spec, split), sum(t["seconds"] for t in timings),
                     sum(t["first_view_seconds"] for t in timings), renders=len(scenes))
    return medium, alphas, {**timing, "renders_per_view": len(scenes)}
