"""Rendering the ground truth: each view of a split through Mitsuba's ``volpath``, and the true grids on disk.

Each view is rendered once, ``mi.render(scene, sensor=..., spp=..., seed=...)`` on one loaded
scene, with a seed of its own (:func:`render_seed`), so noise is independent across views and
between ``test`` and ``test_ref``.

**The medium alone** (``medium_alone=True``): the same view through ``volpath`` with
``hide_emitters``, which drops what a camera ray sees of the environment straight through the
medium. What remains is the medium's own radiance ``M = sum_i w_i c_i`` (the emission-absorption
split of the pixel), and the film's alpha becomes the fraction of the pixel's samples whose
camera ray had a real collision in the medium: with delta tracking a ray collides with
probability ``1 - T``, so alpha is an unbiased, box-filtered estimate of ``1 - T`` from the same
samples as ``M``. Composited over the environment ``B``, ``M + (1 - alpha) B`` estimates the
full image (exactly in expectation for a constant environment). Its seeds are those of the
splits ``<split>_medium``, independent of the full images'.
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


def medium_alone_integrator(spec: SceneSpec):
    """``volpath`` with ``hide_emitters``: the medium's own radiance, alpha ``~ 1 - T`` (module docstring)."""
    import mitsuba as mi

    return mi.load_dict({"type": "volpath", "max_depth": int(spec.render.max_depth), "hide_emitters": True})


def render_split(scene, spec: SceneSpec, split: str, cameras: list[Camera], progress: bool, *,
                 medium_alone: bool = False) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Every view of ``split`` (RGBA float32 (H, W, 4)) and the timings of the rendering.

    ``medium_alone``: the medium without the environment seen through it (module docstring),
    with the seeds of split ``<split>_medium``.
    """
    import mitsuba as mi
    from tqdm.auto import tqdm

    spp = split_spp(spec, split)
    integrator = medium_alone_integrator(spec) if medium_alone else None
    seed_split = f"{split}_medium" if medium_alone else split
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
