"""Dataset integrity, checked when a dataset is opened for training or found in the cache.

:func:`verify_dataset` checks, in this order, and raises one :class:`~mitsnerf.errors.DatasetError`
naming the file (and the field) of the first problem:

1. **Hashes** (skipped with ``hashes=False``, ``--no-verify``): every file ``manifest.json``
   lists exists and has the sha256 recorded there (a swapped, edited, truncated or deleted
   image, grid or camera file).
2. **Grids** (mitsnerf datasets): ``volume/sigma_t.npy`` and ``volume/albedo.npy`` are plain
   numpy arrays of the manifest's resolution (``sigma_t`` (R, R, R), or (R, R, R, 3) for a chromatic
   extinction), finite, ``sigma_t >= 0``, albedo in ``[0, 1]``.
3. **Views**: every split loads (:meth:`mitsnerf.data.dataset.Dataset.views`: image sizes
   match their cameras and each other, no NaN or inf), as many views as the spec asks for, and
   in a mitsnerf dataset no negative radiance (a box-filtered pixel is a mean of radiance >= 0) beyond
   float32 rounding at the view's scale (:func:`roundoff_tolerance`).

The views stay loaded in the dataset (training reads them anyway); the hashes cost one more read
of every file. :func:`grid_problem` and :func:`image_problem` are also the checks generation runs
on the ground truth before writing it (:mod:`mitsnerf.scene.ground_truth`).

>>> image_problem(np.array([[[0.5, -50.0, 0.2]]], np.float32))
'1 negative radiance value (min -50), first at row 0, column 0'
>>> grid_problem(np.array([[[1.0, np.inf]]], np.float32), lo=0.0)
'1 non-finite value (NaN/inf), first at [0, 0, 1]'
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mitsnerf.data.arrays import read_npy
from mitsnerf.data.cache import sha256_file
from mitsnerf.data.dataset import Dataset, true_grid_path
from mitsnerf.errors import CLI, DatasetError, Placeholder, Words


def regenerate(words: Words = CLI) -> str:
    """How a damaged dataset is made again, in ``words``: ``regenerate it (mitsnerf generate SCENE --force)``."""
    return f"regenerate it ({words.command('generate', Placeholder('SCENE'), force=True)})"


@dataclass(frozen=True)
class Verified:
    """What :func:`verify_dataset` read."""

    hashed_files: int
    hashed_bytes: int
    views: int
    seconds: float


def _first(mask: np.ndarray) -> str:
    return ", ".join(str(int(i)) for i in np.argwhere(mask)[0])


def _plural(n: int, what: str) -> str:
    return f"{n} {what}{'' if n == 1 else 's'}"


#: How far below 0, in units of float32 rounding (2^-24) of a view's brightest value, a radiance value may lie
#: and still be 0 rounded: a value whose exact result is 0 (a pixel that sees nothing, or the background through
#: a medium of transmittance 1e-14) keeps the rounding of the float32 terms it was computed from (volpath's path
#: weights, the composition's pixel means), each a few units of its own size, and no term of a pixel of the view
#: is taken to be much larger than the view's brightest pixel. 16 units (1e-6 of the peak) admit that and nothing
#: an image shows: a 16-bit PNG's step is 1.5e-5 of white.
ROUNDOFF_UNITS = 16


def roundoff_tolerance(image: np.ndarray) -> float:
    """How far below 0 a value of the radiance image ``image`` ``(H, W, C)`` may lie by float32 rounding alone:
    ``ROUNDOFF_UNITS * 2^-24 * max |RGB|`` (:data:`ROUNDOFF_UNITS`), 0 for an image without a finite value.

    >>> f"{roundoff_tolerance(np.array([[[0.6, 0.0, -1e-15, 1.0]]], np.float32)):.2e}"
    '5.72e-07'
    """
    rgb = np.abs(np.asarray(image[..., :3], np.float64))
    peak = float(rgb[np.isfinite(rgb)].max(initial=0.0))
    return ROUNDOFF_UNITS * 2.0**-24 * peak


def without_roundoff(image: np.ndarray) -> np.ndarray:
    """``image`` with the values below 0 by no more than :func:`roundoff_tolerance` set to 0 (what they are,
    rounded); a value further below stays, for :func:`image_problem` to refuse.

    >>> without_roundoff(np.array([[[0.6, -1e-15, -0.1, 1.0]]], np.float32)).tolist()
    [[[0.6000000238418579, 0.0, -0.10000000149011612, 1.0]]]
    """
    tolerance = roundoff_tolerance(image)
    rgb = image[..., :3]
    out = np.array(image, copy=True)
    out[..., :3] = np.where((rgb < 0) & (rgb >= -tolerance), 0, rgb)
    return out


def image_problem(image: np.ndarray, *, negative: bool = True) -> str | None:
    """What is wrong with a radiance image ``(H, W, C)``: non-finite values, or (``negative``)
    values below 0 by more than float32 rounding (:func:`roundoff_tolerance`); None when nothing is."""
    bad = ~np.isfinite(image)
    if bad.any():
        r, c = np.argwhere(bad)[0][:2]
        return f"{_plural(int(bad.sum()), 'non-finite value')} (NaN/inf), first at row {r}, column {c}"
    low = image[..., :3] < -roundoff_tolerance(image) if negative else np.zeros(1, bool)
    if low.any():
        r, c = np.argwhere(low)[0][:2]
        return (f"{_plural(int(low.sum()), 'negative radiance value')} (min {float(image[..., :3].min()):g}), "
                f"first at row {r}, column {c}")
    return None


def grid_problem(grid: np.ndarray, *, lo: float = 0.0, hi: float | None = None,
                 shape: tuple[int, ...] | None = None) -> str | None:
    """What is wrong with a grid: shape (when given), dtype, non-finite values, values outside
    ``[lo, hi]``; None when nothing is."""
    if shape is not None and grid.shape != shape:
        return f"shape {grid.shape}, expected {shape}"
    if grid.dtype.kind != "f":
        return f"dtype {grid.dtype}, expected floating point"
    bad = ~np.isfinite(grid)
    if bad.any():
        return f"{_plural(int(bad.sum()), 'non-finite value')} (NaN/inf), first at [{_first(bad)}]"
    out = (grid < lo) | (grid > hi) if hi is not None else grid < lo
    if out.any():
        span = f"[{lo:g}, {hi:g}]" if hi is not None else f">= {lo:g}"
        return (f"{_plural(int(out.sum()), 'value')} outside {span} (min {float(grid.min()):g}, "
                f"max {float(grid.max()):g}), first at [{_first(out)}]")
    return None


def check_hashes(root: Path, manifest: dict, words: Words = CLI) -> tuple[int, int]:
    """Every file of ``manifest["files"]`` against its sha256; returns (files, bytes) read."""
    again = regenerate(words)
    files = manifest.get("files")
    if not isinstance(files, dict) or not files:
        raise DatasetError(root / "manifest.json", "files", "missing: the dataset cannot be verified; " + again)
    size = 0
    for rel, digest in files.items():
        path = root / rel
        if not path.is_file():
            raise DatasetError(path, None, f"missing (manifest.json lists it): the dataset is incomplete; {again}")
        if sha256_file(path) != digest:
            raise DatasetError(path, None, "differs from the sha256 in manifest.json (modified, swapped or damaged "
                                           f"since generation); {again}")
        size += path.stat().st_size
    return len(files), size


def _resolution(root: Path, manifest: dict) -> int:
    try:
        return int(manifest["spec"]["volume"]["resolution"])
    except (KeyError, TypeError, ValueError):
        raise DatasetError(root / "manifest.json", "spec.volume.resolution", "missing or not an integer") from None


def _chromatic(manifest: dict) -> bool:
    """Whether the manifest's spec has a chromatic extinction (``volume.sigma_t_scale`` an RGB triple)."""
    volume = (manifest.get("spec") or {}).get("volume") or {}
    return isinstance(volume.get("sigma_t_scale"), (list, tuple))


def check_grids(root: Path, manifest: dict) -> None:
    """The true grids of a mitsnerf dataset: readable, the manifest's resolution (``sigma_t`` with a trailing
    RGB axis when the extinction is chromatic), in range."""
    r = _resolution(root, manifest)
    sigma_shape = (r, r, r, 3) if _chromatic(manifest) else (r, r, r)
    for name, hi, shape in (("sigma_t", None, sigma_shape), ("albedo", 1.0, (r, r, r, 3))):
        path = true_grid_path(root, name)
        problem = grid_problem(read_npy(path, f"{name} grid"), lo=0.0, hi=hi, shape=shape)
        if problem is not None:
            raise DatasetError(path, None, problem)


def _expected_views(manifest: dict, split: str) -> int | None:
    cameras = (manifest.get("spec") or {}).get("cameras") or {}
    n = cameras.get("n_train" if split == "train" else "n_test")
    return n if isinstance(n, int) else None


def check_views(dataset: Dataset) -> int:
    """Load every split (the loader's checks), count its views, and in a mitsnerf dataset refuse
    negative radiance; returns the number of views."""
    manifest, total = dataset.manifest, 0
    for split in sorted(dataset.splits, key=lambda name: name != "train"):  # the training views first
        views = dataset.views(split)
        tpath = dataset.transforms_path(split)
        expected = _expected_views(manifest, split) if manifest else None
        if expected is not None and len(views) != expected:
            raise DatasetError(tpath, "frames", f"{len(views)} views, the manifest's spec has {expected}")
        for i, image in enumerate(views.images if manifest else ()):
            problem = image_problem(image)
            if problem is not None:
                raise DatasetError(tpath, f"frames[{i}]", f"image {views.names[i]}: {problem}")
        total += len(views)
    return total


def verify_dataset(dataset: Dataset, *, hashes: bool = True, words: Words = CLI) -> Verified:
    """Check ``dataset`` as the module says; returns what was read and how long it took. ``words``: how the
    advice to regenerate it is written (:class:`mitsnerf.errors.Words`)."""
    start = time.perf_counter()
    root, manifest = Path(dataset.root), dataset.manifest
    files = size = 0
    if manifest:
        if hashes:
            files, size = check_hashes(root, manifest, words)
        check_grids(root, manifest)
    views = check_views(dataset)
    return Verified(files, size, views, time.perf_counter() - start)
