"""Ground-truth datasets: render a scene spec with Mitsuba into the dataset directory layout.

``generate_dataset(spec, out_root)`` writes ``out_root / f"{spec.name}-{hash[:12]}"`` (layout in
``docs/conventions.md``, "Dataset directory"). The hash covers the spec, the splits, the Mitsuba
and Dr.Jit versions, the variant and :data:`FORMAT_VERSION`: a changed spec gets a new directory,
an unchanged one is a cache hit that returns at once. The directory is built in a temporary
sibling and renamed into place with ``manifest.json`` written last, so an interrupted run
(Ctrl-C, SIGKILL) never leaves a directory that looks complete; the next run removes the
leftovers. Concurrent runs for the same dataset are serialised by a lock file next to it.

Each view is rendered once, ``mi.render(scene, sensor=..., spp=..., seed=...)`` on one loaded
scene, with a seed of its own (:func:`render_seed`), so noise is independent across views and
between ``test`` and ``test_ref``.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import time
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from mitsnerf.math.camera import Camera
from mitsnerf.scene.lights import bake_sky
from mitsnerf.scene.rigs import camera_rig
from mitsnerf.scene.spec import SceneSpec, SkyLight, list_scenes, load_scene
from mitsnerf.scene.to_mitsuba import ENVMAP_FILE, background_description, load_sensor, scene_dict, volume_grids

#: Version of the dataset layout and generation rules; part of the dataset hash.
#: 2: the noise floor's medium mask is the centre-ray opacity > 1e-3 rule of ``mitsnerf.run``.
#: 3: the plume family rises along the world's up axis z (it lay along y); families are part of the data.
FORMAT_VERSION = 3
SPLITS = ("train", "test", "test_ref")
#: Opacity along a pixel's centre ray above which it "sees the medium" (``noise_floor.psnr_medium``).
MEDIUM_OPACITY = 1e-3
#: Temporaries of *other* datasets are removed once this old (seconds); a dataset's own at once.
STALE_TEMP_AGE_S = 24 * 3600.0
_SPLIT_IDS = {"train": 0, "test": 1, "test_ref": 2}
_BOX_MIN, _BOX_MAX = (-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)


# --------------------------------------------------------------------------- naming


def default_splits(spec: SceneSpec) -> tuple[str, ...]:
    """``train``, ``test``, and ``test_ref`` when ``render.noise_floor`` is on."""
    return SPLITS if spec.render.noise_floor else SPLITS[:2]


def _resolve_splits(spec: SceneSpec, splits: Sequence[str] | None) -> tuple[str, ...]:
    if splits is None:
        return default_splits(spec)
    unknown = [s for s in splits if s not in SPLITS]
    if unknown or not splits:
        raise ValueError(f"splits must be a non-empty subset of {SPLITS}, got {list(splits)}")
    return tuple(s for s in SPLITS if s in splits)


def hash_extra(splits: Sequence[str]) -> dict[str, Any]:
    """What besides the spec decides a dataset's content (needs the Mitsuba variant set)."""
    import drjit as dr
    import mitsuba as mi

    return {
        "format_version": FORMAT_VERSION,
        "variant": mi.variant(),
        "mitsuba": mi.__version__,
        "drjit": dr.__version__,
        "splits": list(splits),
    }


def dataset_dir(spec: SceneSpec, out_root: str | os.PathLike, splits: Sequence[str] | None = None) -> Path:
    """Where :func:`generate_dataset` puts ``spec`` (sets the default variant if none is set)."""
    _ensure_variant()
    digest = spec.content_hash(hash_extra(_resolve_splits(spec, splits)))
    return Path(out_root) / f"{spec.name}-{digest[:12]}"


def render_seed(seed: int, split: str, index: int) -> int:
    """The Mitsuba sampler seed (uint32) of view ``index`` of ``split``: distinct per view and split."""
    ss = np.random.SeedSequence([seed, _SPLIT_IDS[split], index])
    return int(ss.generate_state(1, dtype=np.uint32)[0])


def _ensure_variant() -> str:
    import mitsuba as mi

    from mitsnerf.env import set_variant

    return set_variant(mi.variant())


# --------------------------------------------------------------------------- medium mask


def optical_depth(origins: np.ndarray, directions: np.ndarray, sigma_t: np.ndarray, steps_per_voxel: int = 2) -> np.ndarray:
    """Optical depth ``int sigma_t dt`` (N,) along rays (N, 3) through the scene box.

    Midpoint rule, ``steps_per_voxel`` samples per voxel length along the longest chord,
    trilinear lookups with clamped borders (as Mitsuba's ``gridvolume``). Rays that miss the box get 0.
    """
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    r = sigma_t.shape[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t_a = (np.asarray(_BOX_MIN) - o) * inv
        t_b = (np.asarray(_BOX_MAX) - o) * inv
    t0 = np.nanmax(np.minimum(t_a, t_b), axis=1).clip(min=0.0)
    t1 = np.nanmin(np.maximum(t_a, t_b), axis=1)
    hit = t1 > t0
    tau = np.zeros(len(o))
    k = int(np.ceil(np.sqrt(3.0) * r * steps_per_voxel))
    grid = np.asarray(sigma_t, dtype=np.float64)
    idx = np.nonzero(hit)[0]
    for chunk in np.array_split(idx, max(1, len(idx) * k // 2_000_000 + 1)):
        if len(chunk) == 0:
            continue
        dt = (t1[chunk] - t0[chunk]) / k
        ts = t0[chunk, None] + (np.arange(k) + 0.5)[None, :] * dt[:, None]
        p = o[chunk, None, :] + ts[..., None] * d[chunk, None, :]
        # voxel-index coordinates: centre of voxel i at (i + 0.5) / R - 0.5
        c = np.clip((p + 0.5) * r - 0.5, 0.0, r - 1.0)
        c0 = np.minimum(np.floor(c).astype(np.int64), r - 2) if r > 1 else np.zeros(c.shape, np.int64)
        f = c - c0
        x0, y0, z0 = c0[..., 0], c0[..., 1], c0[..., 2]
        fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
        val = 0.0
        for dz, wz in ((0, 1 - fz), (1, fz)):
            for dy, wy in ((0, 1 - fy), (1, fy)):
                for dx, wx in ((0, 1 - fx), (1, fx)):
                    val = val + wz * wy * wx * grid[z0 + dz, y0 + dy, x0 + dx]
        tau[chunk] = val.sum(axis=1) * dt
    return tau


def medium_mask(
    camera: Camera, sigma_t: np.ndarray, opacity: float = MEDIUM_OPACITY, pixel_center: float = 0.5
) -> np.ndarray:
    """Boolean (H, W): pixels that see the medium.

    A pixel counts when the true medium's opacity ``1 - exp(-tau)`` along the ray through its
    centre exceeds ``opacity`` (the definition ``mitsnerf.run.medium_masks`` uses to score methods,
    so the noise floor and the methods' medium PSNR are measured on the same pixels).
    """
    _, d = camera.pixel_rays(pixel_center)
    o = np.broadcast_to(camera.origin, d.shape)
    tau = optical_depth(o, d, sigma_t)
    return (-np.expm1(-tau) > opacity).reshape(camera.height, camera.width)


# --------------------------------------------------------------------------- manifest, cache


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_manifest(directory: str | os.PathLike) -> dict[str, Any] | None:
    """The dataset's manifest, or None when it is missing or unreadable."""
    import json

    try:
        return json.loads((Path(directory) / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _is_complete(directory: Path, digest: str) -> bool:
    m = read_manifest(directory)
    return bool(m) and m.get("format_version") == FORMAT_VERSION and m.get("hash") == digest


@contextlib.contextmanager
def _dataset_lock(final: Path) -> Iterator[None]:
    """Exclusive lock on ``.<name>.lock`` next to ``final`` while one process generates it."""
    final.parent.mkdir(parents=True, exist_ok=True)
    with open(final.parent / f".{final.name}.lock", "a+b") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def _clean_temps(final: Path) -> None:
    """Remove leftovers of interrupted runs: this dataset's at once (we hold its lock), others when old."""
    import shutil

    from mitsnerf.data.atomic import clean_stale_temps

    for p in final.parent.glob(f".{final.name}.tmp-*"):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    clean_stale_temps(final.parent, min_age_s=STALE_TEMP_AGE_S)


# --------------------------------------------------------------------------- generation


def _finite_or_none(x: float) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def _write_volume(tmp: Path, spec: SceneSpec, sigma_t: np.ndarray, albedo: np.ndarray) -> None:
    from mitsnerf.data.images import write_exr
    from mitsnerf.data.vol import write_vol

    vol = tmp / "volume"
    vol.mkdir()
    np.save(vol / "sigma_t.npy", sigma_t)
    np.save(vol / "albedo.npy", albedo)
    write_vol(vol / "sigma_t.vol", sigma_t, _BOX_MIN, _BOX_MAX)
    write_vol(vol / "albedo.vol", albedo, _BOX_MIN, _BOX_MAX)
    env = spec.environment
    if isinstance(env, SkyLight):
        write_exr(tmp / ENVMAP_FILE, bake_sky(env))


def _render_split(
    scene, spec: SceneSpec, split: str, cameras: list[Camera], tmp: Path, progress: bool
) -> tuple[np.ndarray, dict[str, Any]]:
    """Render, write images and transforms of one split; return the images and the timings."""
    import mitsuba as mi
    from tqdm.auto import tqdm

    from mitsnerf.data.images import write_exr, write_png
    from mitsnerf.data.transforms import write_transforms

    spp = spec.render.spp_train if split == "train" else spec.render.spp_test
    (tmp / split).mkdir()
    seeds = [render_seed(spec.render.seed, split, i) for i in range(len(cameras))]
    images, seconds = [], []
    bar = tqdm(total=len(cameras), desc=f"{spec.name} {split}", unit="view", disable=not progress, leave=False)
    try:
        for i, (cam, seed) in enumerate(zip(cameras, seeds)):
            bar.set_postfix_str(f"r_{i:03d} ({spp} spp)")
            sensor = load_sensor(cam, spp)
            start = time.perf_counter()
            img = np.array(mi.render(scene, sensor=sensor, spp=spp, seed=seed), dtype=np.float32)
            seconds.append(time.perf_counter() - start)
            write_exr(tmp / split / f"r_{i:03d}.exr", img)
            write_png(tmp / split / f"r_{i:03d}.png", img[..., :3])
            images.append(img)
            bar.update()
    finally:
        bar.close()
    write_transforms(
        tmp / f"transforms_{split}.json",
        cameras,
        [f"./{split}/r_{i:03d}" for i in range(len(cameras))],
        aabb_scale=1,
        extra={"split": split, "spp": spp, "render_seeds": seeds},
    )
    total = float(sum(seconds))
    w, h = cameras[0].width, cameras[0].height
    timing = {
        "views": len(cameras),
        "spp": spp,
        "seconds": total,
        "seconds_per_view": total / len(cameras),
        "first_view_seconds": seconds[0],
        "samples_per_second": w * h * spp * len(cameras) / total if total > 0 else None,
    }
    return np.stack(images), timing


def _noise_floor(test: np.ndarray, ref: np.ndarray, cameras: list[Camera], sigma_t: np.ndarray) -> dict[str, Any]:
    from mitsnerf.math.metrics import psnr

    a, b = test[..., :3], ref[..., :3]
    whole = psnr(a, b)
    masks = np.stack([medium_mask(c, sigma_t) for c in cameras])
    seen = masks.reshape(len(cameras), -1).any(axis=1)
    medium = psnr(a[seen], b[seen], mask=masks[seen]) if seen.any() else np.array([])
    return {
        "psnr": _finite_or_none(np.mean(whole)),
        "psnr_medium": _finite_or_none(np.mean(medium)) if len(medium) else None,
        "psnr_per_view": [_finite_or_none(x) for x in whole],
        "psnr_medium_per_view": [_finite_or_none(x) for x in medium],
        "medium_pixel_fraction": float(masks.mean()),
        "medium_mask": (
            f"pixels whose centre ray has opacity 1 - exp(-tau) > {MEDIUM_OPACITY:g} through the true "
            "sigma_t (trilinear); views without such pixels are skipped"
        ),
        "method": "mean over test views of PSNR(test, test_ref), RGB, max_val 1",
    }


def generate_dataset(
    spec: SceneSpec,
    out_root: str | os.PathLike,
    *,
    force: bool = False,
    progress: bool = True,
    splits: Sequence[str] | None = None,
) -> Path:
    """Render ``spec`` into ``out_root / f"{spec.name}-{hash[:12]}"`` and return that directory.

    A complete dataset with the same hash is returned at once (``force=True`` regenerates it).
    ``splits``: a subset of ``("train", "test", "test_ref")`` (default: all, ``test_ref`` only with
    ``render.noise_floor``); the noise floor is measured when both ``test`` and ``test_ref`` are made.
    Uses the current Mitsuba variant, else :func:`mitsnerf.env.set_variant`'s default.
    """
    import mitsuba as mi

    from mitsnerf.data.atomic import atomic_dir, atomic_write_json
    from mitsnerf.env import provenance

    _ensure_variant()
    splits = _resolve_splits(spec, splits)
    digest = spec.content_hash(hash_extra(splits))
    final = Path(out_root) / f"{spec.name}-{digest[:12]}"
    if not force and _is_complete(final, digest):
        return final
    with _dataset_lock(final):
        if not force and _is_complete(final, digest):  # another process finished it meanwhile
            return final
        _clean_temps(final)
        started = time.perf_counter()
        with atomic_dir(final, overwrite=True) as tmp:
            sigma_t, albedo = volume_grids(spec)
            _write_volume(tmp, spec, sigma_t, albedo)
            scene = mi.load_dict(scene_dict(spec, sigma_t, albedo))
            timings: dict[str, Any] = {}
            images: dict[str, np.ndarray] = {}
            cams = {s: camera_rig(spec.cameras, "train" if s == "train" else "test") for s in splits}
            for split in splits:
                images[split], timings[split] = _render_split(scene, spec, split, cams[split], tmp, progress)
            noise = None
            if "test" in images and "test_ref" in images:
                noise = _noise_floor(images["test"], images["test_ref"], cams["test"], sigma_t)
            files = {
                p.relative_to(tmp).as_posix(): _sha256(p) for p in sorted(tmp.rglob("*")) if p.is_file()
            }
            manifest = {
                "format_version": FORMAT_VERSION,
                "name": spec.name,
                "hash": digest,
                "spec": spec.to_dict(),
                "source": spec.source,
                "provenance": provenance(),
                "background": background_description(spec),
                "render": {
                    "integrator": "volpath",
                    "max_depth": spec.render.max_depth,
                    "film": "hdrfilm, rgba, box filter",
                    "pixel_center": 0.5,
                    "spp": {s: (spec.render.spp_train if s == "train" else spec.render.spp_test) for s in splits},
                    "seed": spec.render.seed,
                    "seed_rule": "mitsnerf.scene.generate.render_seed(render.seed, split, view index)",
                    "alpha": "1 everywhere with an environment light; else the fraction of samples "
                    "that scattered or were absorbed in the medium (an estimate of 1 - transmittance)",
                },
                "splits": list(splits),
                "timings": {**timings, "total_seconds": time.perf_counter() - started},
                "noise_floor": noise,
                "files": files,
            }
            atomic_write_json(tmp / "manifest.json", manifest)
    return final


def generate_all(
    out_root: str | os.PathLike,
    *,
    names: Sequence[str] | None = None,
    overrides: Mapping[str, Any] | None = None,
    force: bool = False,
    progress: bool = True,
) -> list[Path]:
    """Generate every scene of the library (or ``names``), each with ``overrides`` applied.

    Returns the dataset directories in the order of ``names`` (default: :func:`list_scenes`).
    Every spec is loaded first: a broken one is reported (a SpecError naming its file) before
    anything renders.
    """
    from tqdm.auto import tqdm

    names = list(names) if names is not None else list_scenes()
    specs = [load_scene(name) for name in names]  # every spec checked before anything renders
    if overrides:
        specs = [spec.with_overrides(overrides) for spec in specs]
    out: list[Path] = []
    with tqdm(specs, desc="scenes", unit="scene", disable=not progress) as bar:
        for spec in bar:
            bar.set_postfix_str(spec.name)
            out.append(generate_dataset(spec, out_root, force=force, progress=progress))
    return out
