"""What ``mitsuba-inverse`` starts from and the priors it adds: another run's exported density, the emissive phase's
loss, the total variation inside the emptiness mask.

``init_from``: a directory that ``mitsnerf export RUN`` wrote (``sigma_t.npy`` and ``export.json``, or a run
directory holding it as ``export/``), or a mitsnerf dataset (its true grids ``volume/sigma_t.npy`` and
``volume/albedo.npy`` over the box its manifest gives: the "truth start"). Its extinction (world units, over its
box) is looked up trilinearly at the voxel centres of the method's grid; points outside that box get 0::

    tau[k, j, i] = side * sigma_export(x_kji)          (optical depth per box side)

The emissive phase (the first ``emissive_steps`` steps, after Nimier-David et al. 2022's emissive start): the same
extinction grid and an RGB emission grid rendered by emission-absorption quadrature, fitted to random training
pixels; a scattering start falls into local minima that this one avoids, and its extinction carries over.
"""

from __future__ import annotations

import json
from pathlib import Path

import drjit as dr
import numpy as np

from mitsnerf.errors import DatasetError
from mitsnerf.math.box import Box

EXPORT_FILES = ("sigma_t.npy", "export.json")


def export_dir(path: str | Path) -> Path:
    """The export directory ``path`` names: itself, or its ``export/`` (a run directory); a
    :class:`~mitsnerf.errors.DatasetError` naming ``init_from`` when neither holds an export (nor is ``path`` a
    dataset with its true grids)."""
    p = Path(path)
    for candidate in (p, p / "export"):
        if all((candidate / name).is_file() for name in EXPORT_FILES):
            return candidate
    hint = (f"it is a run: run 'mitsnerf export {p}' first" if (p / "config.json").is_file()
            else "expected a directory written by 'mitsnerf export' (sigma_t.npy, export.json), a run holding one, "
                 "or a dataset (volume/sigma_t.npy)")
    raise DatasetError(p, "init_from", f"no exported density ({', '.join(EXPORT_FILES)}) here or in export/; {hint}")


def _grid(path: Path, channels: tuple[int, ...]) -> np.ndarray:
    """A finite (R, R, R) or (R, R, R, C) grid from ``path`` as (R, R, R, C) float32, C in ``channels``."""
    try:
        grid = np.load(path)
    except (OSError, ValueError) as e:
        raise DatasetError(path, None, f"not a numpy array ({e})") from None
    grid = grid[..., None] if grid.ndim == 3 else grid
    r = grid.shape[0]
    if grid.shape[:3] != (r, r, r) or grid.shape[3] not in channels or not np.all(np.isfinite(grid)):
        raise DatasetError(path, None, f"expected a finite (R, R, R) or (R, R, R, {' or '.join(map(str, channels))}) "
                                       f"grid, got shape {grid.shape}")
    return np.maximum(grid, 0.0).astype(np.float32)


def read_dataset_truth(path: str | Path) -> tuple[np.ndarray, np.ndarray | None, Box] | None:
    """``(sigma_t (R, R, R, C), albedo (R, R, R, 3) or None, box)`` of a dataset's true grids, or None when
    ``path`` is not a dataset holding them."""
    from mitsnerf.data.dataset import load_dataset, true_grid_path

    if not true_grid_path(path).is_file():
        return None
    box = load_dataset(path).box
    albedo_path = true_grid_path(path, "albedo")
    albedo = _grid(albedo_path, (1, 3)) if albedo_path.is_file() else None
    return _grid(true_grid_path(path), (1, 3)), albedo, box


def read_export(path: str | Path) -> tuple[np.ndarray, Box]:
    """``(sigma_t (R, R, R, C), box)`` of an export directory (or a run's ``export/``), checked."""
    d = export_dir(path)
    try:
        info = json.loads((d / "export.json").read_text())
        lo, hi = [float(v) for v in info["box_min"]], [float(v) for v in info["box_max"]]
        box = Box((lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]))
    except (KeyError, TypeError, ValueError) as e:
        raise DatasetError(d / "export.json", "box_min/box_max", f"unreadable ({e})") from None
    return _grid(d / "sigma_t.npy", (1, 3)), box


def resampled(grid: np.ndarray, source: Box, box: Box, resolution: int) -> np.ndarray:
    """``grid`` (R', R', R', C) over ``source`` looked up trilinearly at the voxel centres of ``box`` at
    ``resolution``: (R, R, R, C) float32, 0 outside ``source``."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField

    c = grid.shape[-1]
    field = GridField.from_arrays(grid, source)
    x = box.voxel_centres(resolution).reshape(-1, 3)
    with dr.suspend_grad():
        values = field.density(mi.Array3f(*(np.ascontiguousarray(x[:, k], dtype=np.float32) for k in range(3))))
    v = np.stack([np.asarray(values[k]) for k in range(3)], axis=-1) if c == 3 else np.asarray(values)[:, None]
    inside = np.all((x >= np.asarray(source.lo)) & (x <= np.asarray(source.hi)), axis=1)
    v = np.where(inside[:, None], v, 0.0)
    return np.ascontiguousarray(v.reshape(resolution, resolution, resolution, c), dtype=np.float32)


def resampled_start(start: str | Path | tuple, box: Box, resolution: int,
                    channels: int) -> tuple[np.ndarray, np.ndarray | None]:
    """``init_from``'s start on the method's grid: the extinction as optical depth per box side (``(R, R, R,
    channels)`` float32: a chromatic source averaged to one channel, a grey one repeated to three), and a
    dataset's true albedo (R, R, R, 3) (None from an export: its colour is not an albedo). ``start``: a path, or
    the grids themselves ``(sigma_t (R, R, R[, C]) world units, albedo, their box)``."""
    truth = start if isinstance(start, tuple) else read_dataset_truth(start)
    if truth is not None:
        sigma, albedo, source = truth
    elif isinstance(start, (str, Path)):
        (sigma, source), albedo = read_export(start), None
    sigma = sigma[..., None] if sigma.ndim == 3 else sigma
    if channels == 1 and sigma.shape[-1] == 3:
        sigma = sigma.mean(axis=-1, keepdims=True)
    tau = resampled(sigma, source, box, resolution) * np.float32(box.size[0])
    tau = np.repeat(tau, channels, axis=-1) if tau.shape[-1] == 1 and channels == 3 else tau
    if albedo is not None:
        albedo = np.clip(resampled(np.repeat(albedo, 3, axis=-1) if albedo.shape[-1] == 1 else albedo,
                                   source, box, resolution), 0.0, 1.0)
    return np.ascontiguousarray(tau, dtype=np.float32), albedo


def tv_pairs(keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The neighbouring voxel pairs ``(a, b)`` (flat ``[z, y, x]`` indices) along the three axes whose voxels are
    both kept (``keep`` (R, R, R) bool).

    >>> a, b = tv_pairs(np.ones((2, 2, 2), bool))
    >>> len(a), sorted(set((b - a).tolist()))          # 4 pairs per axis; steps of 1 (x), 2 (y), 4 (z)
    (12, [1, 2, 4])
    >>> keep = np.ones((2, 2, 2), bool); keep[0, 0, 0] = False
    >>> len(tv_pairs(keep)[0])                        # the 3 pairs at the carved voxel are gone
    9
    """
    r = keep.shape
    index = np.arange(keep.size).reshape(r)
    a_all, b_all = [], []
    for axis in range(3):
        lo = tuple(slice(0, -1) if k == axis else slice(None) for k in range(3))
        hi = tuple(slice(1, None) if k == axis else slice(None) for k in range(3))
        both = keep[lo] & keep[hi]
        a_all.append(index[lo][both])
        b_all.append(index[hi][both])
    return np.concatenate(a_all).astype(np.uint32), np.concatenate(b_all).astype(np.uint32)


def masked_tv(grid, pairs: tuple, channels: int):
    """``mean over kept pairs and channels of (g_a - g_b)^2`` of a (R, R, R, C) tensor (Float of width 1,
    differentiable); 0 without pairs.

    >>> import mitsuba as mi
    >>> g = mi.TensorXf(np.arange(8, dtype=np.float32).reshape(2, 2, 2, 1))   # +1 in x, +2 in y, +4 in z
    >>> masked_tv(g, tv_pairs(np.ones((2, 2, 2), bool)), 1)                   # (4 + 16 + 64) / 3
    [7]
    """
    import mitsuba as mi

    a, b = pairs
    if len(a) == 0:
        return mi.Float(0.0)
    total = mi.Float(0.0)
    for c in range(channels):
        ga = dr.gather(mi.Float, grid.array, mi.UInt32(a) * channels + c)
        gb = dr.gather(mi.Float, grid.array, mi.UInt32(b) * channels + c)
        total += dr.sum(dr.square(ga - gb))
    return total / (len(a) * channels)
