"""Ground-truth datasets: a scene spec rendered by Mitsuba's ``volpath`` into the dataset layout.

``generate_dataset(spec, out_root)`` writes ``out_root / f"{spec.name}-{hash[:12]}"`` (layout in
``docs/conventions.md``, "Dataset directory"). The hash covers the spec, the splits, the Mitsuba
and Dr.Jit versions, the variant and :data:`FORMAT_VERSION`: a changed spec gets a new directory,
an unchanged one is a cache hit (:mod:`mitsnerf.data.cache`). The directory is built in a
temporary sibling and renamed into place with ``manifest.json`` written last, so an interrupted
run (Ctrl-C, SIGKILL) never leaves a directory that looks complete. Views are rendered by
:mod:`mitsnerf.scene.render`; the noise floor is scored by :mod:`mitsnerf.scoring` on the same
medium pixels as every method.

Every split is rendered once by ``volpath``, as **the medium alone** (:mod:`mitsnerf.scene.render`: the
environment seen straight through the medium hidden, alpha ``~ 1 - T``), and the full image is composed
from it (:func:`mitsnerf.scene.render.compose`): ``M`` plus each pixel's mean of ``T(d) L_env(d)``, with
``T`` the exact transmittance of the true grid (:mod:`mitsnerf.scene.transmittance`), minus a zero-mean
term that keeps the image as little noisy as a direct render, so the image costs no second pass. The
medium-alone renders are ``medium/``, a NeRF-synthetic dataset of its own
(``transforms_{train,val,test,test_ref}.json``, ``val`` being the test views; RGBA PNGs with straight alpha
over a transparent background, and premultiplied linear EXRs), which NeRF-synthetic readers load unchanged.
The manifest records the statistical check that their alpha agrees with the exact ``1 - T``
(:func:`mitsnerf.scoring.agreement.transmittance_agreement`, per view), and how much of the medium a reader with
NeRF-synthetic's fixed near/far sees (:func:`mitsnerf.scoring.medium.near_far_coverage`). Where the lights do not
allow one pass (:func:`mitsnerf.scene.render.one_pass_reason`) every split is rendered twice, as before
format 6, and the manifest says so (``render.passes``) and records the composite check
(:func:`mitsnerf.scoring.agreement.composite_agreement`) instead.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.config import to_dict
from mitsnerf.data.cache import clean_temps, dataset_lock, is_complete, sha256_file
from mitsnerf.data.verify import without_roundoff
from mitsnerf.math.box import Box
from mitsnerf.math.camera import Camera
from mitsnerf.scene import ground_truth
from mitsnerf.scene.render import compose, footprint_for, one_pass_reason, render_split, split_spp, write_volume
from mitsnerf.scene.rigs import camera_rig
from mitsnerf.scene.spec import SceneSpec, list_scenes, load_scene
from mitsnerf.scene.to_mitsuba import background_description, scene_box, scene_dict, volume_grids

#: Version of the dataset layout and generation rules; part of the dataset hash.
#: 2: the noise floor's medium mask is the centre-ray opacity > 1e-3 rule of ``mitsnerf.runs.fit``.
#: 3: the plume family rises along the world's up axis z (it lay along y); families are part of the data.
#: 4: the scene box is recorded (manifest ``box``, transforms ``aabb``); medium masks by ``mitsnerf.scoring``.
#: 5: the medium alone (``medium/``, a NeRF-synthetic view); the spec's ``world.scale``.
#: 6: one volpath pass per split: the images composed from ``medium/`` and the exact transmittance, ``medium/``
#:    rendered with its split's seeds (two passes, as in 5, only where the lights need them: ``render.passes``).
FORMAT_VERSION = 6
SPLITS = ("train", "test", "test_ref")
#: The medium-alone NeRF-synthetic view, relative to the dataset directory.
MEDIUM_DIR = "medium"
#: The near and far planes NeRF-synthetic readers hard-code.
NERF_SYNTHETIC_NEAR_FAR = (2.0, 6.0)


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


def hash_extra(splits: Sequence[str], spec: SceneSpec | None = None) -> dict[str, Any]:
    """What besides the spec decides a dataset's content (needs the Mitsuba variant set): the versions,
    the splits, and a plugin volume family's version (its distribution and source hash)."""
    import drjit as dr
    import mitsuba as mi

    extra = {"format_version": FORMAT_VERSION, "variant": mi.variant(), "mitsuba": mi.__version__,
             "drjit": dr.__version__, "splits": list(splits)}
    version = _family_version(spec) if spec is not None else None
    return {**extra, "volume_family": version} if version is not None else extra


def _family_version(spec: SceneSpec) -> str | None:
    """A plugin volume family's version (:attr:`mitsnerf.plugins.Source.version`); None for a built-in."""
    from mitsnerf import volumes

    return volumes.families().entry(spec.volume.family).source.version


def data_inputs(spec: SceneSpec) -> dict[str, Any] | None:
    """What decides ``spec``'s dataset beyond its text and mitsnerf's version, for a bench cell's key: the
    input files' sha256 (``inputs``) and a plugin family's version (``volume_family``); None when neither."""
    found = {"inputs": spec.volume.input_digests(), "volume_family": _family_version(spec)}
    found = {k: v for k, v in found.items() if v}
    return found or None


def _ensure_variant() -> str:
    import mitsuba as mi

    from mitsnerf.env import set_variant

    return set_variant(mi.variant())


def dataset_dir(spec: SceneSpec, out_root: str | os.PathLike, splits: Sequence[str] | None = None) -> Path:
    """Where :func:`generate_dataset` puts ``spec`` (sets the default variant if none is set)."""
    _ensure_variant()
    digest = spec.content_hash(hash_extra(_resolve_splits(spec, splits), spec))
    return Path(out_root) / f"{spec.name}-{digest[:12]}"


def _write_split(root: Path, spec: SceneSpec, split: str, images: list[np.ndarray], cameras: list[Camera],
                 box: Box, medium: bool = False, seed_split: str | None = None) -> None:
    """The split's EXR and PNG images and its ``transforms_<split>.json`` (with the box as ``aabb``) under ``root``.

    ``medium``: the medium-alone view: the EXRs premultiplied RGBA (``"exr_alpha": "premultiplied"``),
    the PNGs straight RGBA as NeRF-synthetic readers expect, and the test split written also as
    ``transforms_val.json``. ``seed_split``: whose render seeds the views had (default ``split``).
    """
    from mitsnerf.data.images import unpremultiply, write_exr, write_png
    from mitsnerf.data.transforms import write_transforms
    from mitsnerf.scene.render import render_seed

    (root / split).mkdir(parents=True)
    for i, img in enumerate(images):
        write_exr(root / split / f"r_{i:03d}.exr", img, alpha=("premultiplied" if medium else "opacity")
                  if img.shape[2] == 4 else None)
        write_png(root / split / f"r_{i:03d}.png", unpremultiply(img) if medium else img[..., :3])
    seeds = [render_seed(spec.render.seed, seed_split or split, i) for i in range(len(cameras))]
    extra = {"aabb": box.to_list(), "split": split, "spp": split_spp(spec, split), "render_seeds": seeds,
             **({"exr_alpha": "premultiplied"} if medium else {})}
    for name in (split, "val") if medium and split == "test" else (split,):
        write_transforms(root / f"transforms_{name}.json", cameras,
                         [f"./{split}/r_{i:03d}" for i in range(len(cameras))], aabb_scale=1, extra=extra)


COMPOSITION = ("RGB = M + mean(T L_env) - mean(L_env) (alpha - (1 - mean T)), (M, alpha) medium/'s render of the "
               "pixel, means over K x K stratified points of the pixel (render.footprint), T the exact transmittance "
               "of the true sigma_t along each ray (mitsnerf.scene.transmittance: trilinear, two-point "
               "Gauss-Legendre per cell), L_env the background; the last term has mean zero and keeps the noise "
               "of a direct render (mitsnerf.scene.render.compose); alpha as render.alpha says")
COMPOSITION_CHROMATIC = ("RGB_k = M_k + mean(T_k L_env,k) per colour channel k, (M, alpha) medium/'s render of "
                         "the pixel, T_k the exact transmittance of sigma_t's channel k "
                         "(mitsnerf.scene.transmittance), means over K x K stratified points of the pixel "
                         "(render.footprint); no alpha term: in a "
                         "chromatic medium volpath's alpha is not a channel's 1 - T (mitsnerf.scene.render)")


def volume_description(spec: SceneSpec) -> dict[str, Any]:
    """What the manifest says of the medium's grids and phase function (docs/conventions.md)."""
    v = spec.volume
    shape = "(R, R, R, 3) [z, y, x, rgb]: one extinction per colour channel" if v.chromatic else "(R, R, R) [z, y, x]"
    return {
        "sigma_t": f"volume/sigma_t.npy float32 {shape}, per unit of world length",
        "chromatic": v.chromatic, "sigma_t_scale": list(v.sigma_t_rgb) if v.chromatic else v.sigma_t_scale,
        "albedo": "volume/albedo.npy float32 (R, R, R, 3) [z, y, x, rgb], sigma_s / sigma_t per channel",
        "phase": to_dict(v.phase),
    }


def _manifest(spec: SceneSpec, digest: str, splits, box: Box, timings: dict, checks: dict, tmp: Path,
              fallback: str | None) -> dict:
    from mitsnerf.env import provenance

    files = {p.relative_to(tmp).as_posix(): sha256_file(p) for p in sorted(tmp.rglob("*")) if p.is_file()}
    one_pass = fallback is None
    return {
        "format_version": FORMAT_VERSION, "name": spec.name, "hash": digest, "spec": spec.to_dict(),
        "source": spec.source, "provenance": provenance(), "box": box.to_list(),
        "inputs": {str(path): {"field": f"volume.{field}", "sha256": sha256_file(path)}
                   for field, path in spec.volume.input_files().items()},
        "background": background_description(spec), "volume": volume_description(spec),
        "render": {
            "integrator": "volpath", "max_depth": spec.render.max_depth, "film": "hdrfilm, rgba, box filter",
            "pixel_center": 0.5, "spp": {s: split_spp(spec, s) for s in splits}, "seed": spec.render.seed,
            "seed_rule": "mitsnerf.scene.render.render_seed(render.seed, split, view index)",
            "passes": 1 if one_pass else 2,
            "two_passes_because": fallback,
            "composition": ((COMPOSITION_CHROMATIC if spec.volume.chromatic else COMPOSITION) if one_pass
                            else "the image rendered directly by volpath"),
            "footprint": {s: footprint_for(split_spp(spec, s)) for s in splits},
            "alpha": "1 everywhere with an environment light; else the fraction of samples "
                     "that scattered or were absorbed in the medium (an estimate of 1 - transmittance" + (
                         "; not of a channel's in this chromatic medium)" if spec.volume.chromatic else ")"),
        },
        "splits": list(splits), "timings": timings, "noise_floor": checks["noise_floor"],
        "medium": {
            "dir": MEDIUM_DIR,
            "layout": "NeRF-synthetic: transforms_{train,val,test,test_ref}.json (val: the test views), "
                      "r_NNN.png RGBA with straight alpha (sRGB, colour clipped to [0, 1]), r_NNN.exr "
                      "premultiplied linear RGBA",
            "render": "volpath with hide_emitters: the medium's own radiance; alpha is the fraction of a pixel's "
                      "samples whose camera ray collided in the medium, an estimate of 1 - T" + (
                          " in a grey medium (this chromatic one's estimates no single 1 - T: see transmittance_check)"
                          if spec.volume.chromatic else ""),
            "seeds": "its split's: the renders the images are composed from" if one_pass
                     else "those of the splits <split>_medium, independent of the images'",
            "transmittance_check": checks["transmittance_check"],
            "composite_check": checks["composite_check"],
        },
        "nerf_synthetic": checks["nerf_synthetic"], "files": files,
    }


def _checks(tmp: Path, spec: SceneSpec, box: Box, sigma_t: np.ndarray, cams: dict, images: dict,
            medium: dict, transmittance: dict, one_pass: bool) -> dict:
    """The noise floor, the transmittance check of ``medium/``'s alpha, the composite check (two passes only)
    and the near/far coverage of the test views."""
    from mitsnerf.render.background import make_background, pixel_background
    from mitsnerf.scoring.agreement import composite_agreement
    from mitsnerf.scoring.images import noise_floor
    from mitsnerf.scoring.medium import medium_masks, near_far_coverage

    out: dict[str, Any] = {"noise_floor": None, "composite_check": None, "nerf_synthetic": None,
                           "transmittance_check": _transmittance_check(spec, medium, transmittance)}
    if "test" not in images:
        return out
    near, far = NERF_SYNTHETIC_NEAR_FAR
    out["nerf_synthetic"] = {"near": near, "far": far, "test_optical_depth_within": near_far_coverage(
        sigma_t, box, cams["test"], near, far)}
    if "test_ref" in images:
        full, full_ref = np.stack(images["test"]), np.stack(images["test_ref"])
        masks = medium_masks(sigma_t, box, cams["test"])
        out["noise_floor"] = noise_floor(full, full_ref, masks)
        if not one_pass and spec.volume.chromatic:
            out["composite_check"] = {"passed": None, "note": "chromatic extinction: medium/'s alpha is not a "
                                                              "channel's 1 - T, so M + (1 - alpha) B is not the image"}
        elif not one_pass:
            env = pixel_background(make_background(background_description(spec), tmp), cams["test"])
            out["composite_check"] = {
                **composite_agreement(full, full_ref, np.stack(medium["test"]), np.stack(medium["test_ref"]), env),
                "rule": "mitsnerf.scoring.agreement.composite_agreement: test and test_ref against medium/test and "
                        "medium/test_ref composited over the environment (mean over 4 x 4 points of each pixel)"}
    return out


def _transmittance_check(spec: SceneSpec, medium: dict, transmittance: dict) -> dict[str, Any]:
    """Per split, :func:`mitsnerf.scoring.agreement.transmittance_agreement` of ``medium/``'s alpha against
    ``1 - T``."""
    from mitsnerf.scoring.agreement import transmittance_agreement

    if spec.render.max_depth == 1:
        return {"passed": None, "note": "render.max_depth = 1: volpath counts no camera sample as collided, so "
                                        "medium/'s alpha is 0, not an estimate of 1 - T"}
    if spec.volume.chromatic:
        return {"passed": None, "note": "chromatic extinction: volpath draws a camera path's real collisions with "
                                        "probabilities that mix the colour channels by the path's throughput, so "
                                        "medium/'s alpha is not a channel's 1 - T (mitsnerf.scene.render)"}
    per = {s: transmittance_agreement(np.stack(medium[s])[..., 3], transmittance[s], split_spp(spec, s))
           for s in medium}
    return {"passed": all(c["passed"] for c in per.values()), "splits": per,
            "rule": "mitsnerf.scoring.agreement.transmittance_agreement: per view, medium/'s alpha against 1 - T, "
                    "T the exact transmittance averaged over the pixel (render.footprint), variance p (1 - p) / spp"}


class _Truth:
    """What the background term needs: the true density, its grid resolution, the box and the environment."""

    def __init__(self, tmp: Path, spec: SceneSpec, sigma_t: np.ndarray, box: Box) -> None:
        from mitsnerf.render.background import make_background
        from mitsnerf.scoring.density import true_density

        self.density = true_density(sigma_t, box)
        self.resolution = int(sigma_t.shape[0])
        self.channels = int(sigma_t.shape[3]) if sigma_t.ndim == 4 else 1
        self.box = box
        self.background = (make_background(background_description(spec), tmp)
                           if spec.environment is not None else None)

    def transmittance(self, cameras: list[Camera], footprint: int, with_background: bool):
        from mitsnerf.scene.transmittance import pixel_transmittance

        return pixel_transmittance(self.density, self.resolution, self.box, cameras, footprint=footprint,
                                   channels=self.channels,
                                   background=self.background if with_background else None)


def _render(scene, spec: SceneSpec, split: str, cameras: list[Camera], truth: _Truth, one_pass: bool,
            timings: dict, progress: bool) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """One split: ``(images, medium-alone images, each pixel's mean T)``, its timings into ``timings``."""
    k = footprint_for(split_spp(spec, split))
    if one_pass:
        medium, timings[split] = render_split(scene, spec, split, cameras, progress, medium_alone=True)
    else:
        images, timings[split] = render_split(scene, spec, split, cameras, progress)
        medium, timings[f"{MEDIUM_DIR}/{split}"] = render_split(scene, spec, split, cameras, progress,
                                                                medium_alone=True, seed_split=f"{split}_medium")
    start = time.perf_counter()
    seen = truth.transmittance(cameras, k, with_background=one_pass)
    timings[split]["transmittance_seconds"] = time.perf_counter() - start
    if one_pass:
        images = compose(medium, seen, spec.environment is not None, spec.volume.chromatic)
    return images, medium, seen.t


def _build(tmp: Path, spec: SceneSpec, splits: tuple[str, ...], digest: str, progress: bool) -> dict:
    """Render everything into ``tmp``; returns the manifest (not yet written)."""
    import mitsuba as mi

    started = time.perf_counter()
    box = scene_box(spec)
    sigma_t, albedo = volume_grids(spec)
    ground_truth.check_grids(spec, sigma_t, albedo)
    write_volume(tmp, spec, sigma_t, albedo, box)
    scene = mi.load_dict(scene_dict(spec, sigma_t, albedo))
    truth = _Truth(tmp, spec, sigma_t, box)
    fallback = one_pass_reason(spec)
    cams = {s: camera_rig(spec.cameras, "train" if s == "train" else "test") for s in splits}
    images: dict[str, Any] = {}
    medium: dict[str, Any] = {}
    transmittance: dict[str, Any] = {}
    timings: dict[str, Any] = {}
    for split in splits:
        images[split], medium[split], transmittance[split] = _render(scene, spec, split, cams[split], truth,
                                                                     fallback is None, timings, progress)
        ground_truth.check_views(spec, split, images[split])
        images[split] = [without_roundoff(view) for view in images[split]]  # what the check let pass as rounding is 0
        _write_split(tmp, spec, split, images[split], cams[split], box)
        _write_split(tmp / MEDIUM_DIR, spec, split, medium[split], cams[split], box, medium=True,
                     seed_split=split if fallback is None else f"{split}_medium")
    checks = _checks(tmp, spec, box, sigma_t, cams, images, medium, transmittance, fallback is None)
    timings["total_seconds"] = time.perf_counter() - started
    return _manifest(spec, digest, splits, box, timings, checks, tmp, fallback)


def _cache_state(final: Path, digest: str, hashes: bool) -> str:
    """``"ok"`` (a complete dataset of ``digest`` that passes :func:`mitsnerf.data.verify.verify_dataset`),
    ``"missing"``, or ``"broken"`` (complete-looking but failing; said on stderr)."""
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.data.verify import verify_dataset
    from mitsnerf.errors import DatasetError

    if not is_complete(final, digest, FORMAT_VERSION):
        return "missing"
    try:
        verify_dataset(load_dataset(final), hashes=hashes)
    except DatasetError as exc:
        print(
            f"mitsnerf: the cached dataset fails verification: {exc}; rendering it again", file=sys.stderr, flush=True
        )
        return "broken"
    return "ok"


def generate_dataset(spec: SceneSpec, out_root: str | os.PathLike, *, force: bool = False, progress: bool = True,
                     splits: Sequence[str] | None = None, verify_hashes: bool = True) -> Path:
    """Render ``spec`` into ``out_root / f"{spec.name}-{hash[:12]}"`` and return that directory.

    A complete dataset with the same hash is returned at once (``force=True`` regenerates it) if it
    passes :func:`mitsnerf.data.verify.verify_dataset` (``verify_hashes=False`` skips the file
    hashes); one that fails is said so and rendered again.
    ``splits``: a subset of ``("train", "test", "test_ref")`` (default: all, ``test_ref`` only with
    ``render.noise_floor``); the noise floor is measured when both ``test`` and ``test_ref`` are made.
    Uses the current Mitsuba variant, else :func:`mitsnerf.env.set_variant`'s default. The volume's input
    files are checked first (:meth:`~mitsnerf.scene.spec.VolumeSpec.check_inputs`): a bad one is refused
    before anything is written.
    """
    from mitsnerf.data.atomic import atomic_dir, atomic_write_json

    spec.volume.check_inputs()
    _ensure_variant()
    splits = _resolve_splits(spec, splits)
    digest = spec.content_hash(hash_extra(splits, spec))
    final = Path(out_root) / f"{spec.name}-{digest[:12]}"
    state = "missing" if force else _cache_state(final, digest, verify_hashes)
    if state == "ok":
        return final
    with dataset_lock(final, progress):
        if state == "missing" and not force and _cache_state(final, digest, verify_hashes) == "ok":
            return final  # another process finished it meanwhile
        clean_temps(final)
        with atomic_dir(final, overwrite=True) as tmp:
            atomic_write_json(tmp / "manifest.json", _build(tmp, spec, splits, digest, progress))
    return final


def generate_all(out_root: str | os.PathLike, *, names: Sequence[str] | None = None,
                 overrides: Mapping[str, Any] | None = None, force: bool = False, progress: bool = True,
                 verify_hashes: bool = True) -> list[Path]:
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
    with tqdm(specs, desc="scenes", unit="scene", disable=None if progress else True) as bar:
        for spec in bar:
            bar.set_postfix_str(spec.name)
            out.append(generate_dataset(spec, out_root, force=force, progress=progress, verify_hashes=verify_hashes))
    return out
