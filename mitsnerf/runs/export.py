"""Export a learned field as a Mitsuba heterogeneous medium (``mitsnerf export RUN``).

The run's field ``(x, d) -> (c, sigma)`` is sampled at the voxel centres of an ``R^3`` grid
over the dataset's scene box ``[lo, hi]`` (:meth:`mitsnerf.math.box.Box.voxel_centres`: voxel
``[k, j, i]`` is centred at ``x = lo + ((i, j, k) + 0.5) / R * (hi - lo)``)::

    sigma_t[k, j, i] = (1/M) sum_m sigma(x, d_m)
    color[k, j, i]   = (1/M) sum_m c(x, d_m)

over ``M`` ray directions ``d_m``. By default these are ``M = 16`` directions spread evenly
over the sphere (a Fibonacci lattice), i.e. the **view-averaged** colour; with
``direction=(x, y, z)`` it is the colour a camera looking along that one direction sees.
(A density that depends only on position, as every mitsnerf field's does, is unchanged by
the averaging.) Sampling at voxel centres makes Mitsuba's trilinear ``gridvolume`` lookup
return exactly the sampled values there.

Files written to ``OUT`` (atomically, all or none: :func:`mitsnerf.data.atomic.atomic_files`)::

    sigma_t.vol   (R, R, R, 1) float32 extinction per unit length, Mitsuba's .vol format (3 channels for a
                  field with one density per colour: Mitsuba's rgb variants render it as a chromatic medium)
    albedo.vol    (R, R, R, 3) the colour clipped to [0, 1]
    sigma_t.npy   (R, R, R) float32, indexed [z, y, x] ((R, R, R, 3): one density per colour)
    color.npy     (R, R, R, 3) float32, unclipped
    export.json   resolution, directions, box, source run and method, variant/versions/commit

The density carries over exactly: ``sigma_t`` means extinction per unit length in both
worlds. The colour does not in general: a NeRF's colour is radiance leaving the medium
toward the camera, not a single-scattering albedo, so a medium built from it has the right
shape but only roughly the right shading. For ``mitsuba-inverse`` the field's colour *is*
the medium's albedo and the export is that medium (resampled to ``R``).

Putting it into a Mitsuba scene (``gridvolume`` maps ``[0, 1]^3``, so its ``to_world`` is
``translate(lo) scale(hi - lo)``; the ``cube`` is ``[-1, 1]^3``; ``export.json`` has ``lo``
and ``hi``; below the unit box ``[-0.5, 0.5]^3`` of mitsnerf's own scenes)::

    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    lo, hi = [-0.5] * 3, [0.5] * 3
    # accel False: no reduced-precision interpolation on CUDA
    grid = lambda name: {"type": "gridvolume", "filename": f"OUT/{name}", "accel": False,
                         "to_world": mi.ScalarTransform4f().translate(lo).scale([b - a for a, b in zip(lo, hi)])}
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": -1},
        "medium_box": {
            "type": "cube", "bsdf": {"type": "null"},
            "to_world": mi.ScalarTransform4f().translate([(a + b) / 2 for a, b in zip(lo, hi)])
                                              .scale([(b - a) / 2 for a, b in zip(lo, hi)]),
            "interior": {"type": "heterogeneous", "scale": 1.0,
                         "sigma_t": grid("sigma_t.vol"), "albedo": grid("albedo.vol")},
        },
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.5, 0.55, 0.6]}},
    })
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf import env
from mitsnerf.data.atomic import atomic_files, atomic_write_bytes, atomic_write_json
from mitsnerf.data.vol import write_vol
from mitsnerf.errors import DatasetError
from mitsnerf.math.box import Box
from mitsnerf.math.rays import fibonacci_directions
from mitsnerf.methods.base import HasField

DEFAULT_DIRECTIONS = 16
#: The largest grid resolution ``R`` exported: ``R^3`` voxels, each 8 float32 values in the files and
#: about 60 bytes of memory while sampling (1024: 32 GiB of files, 64 GiB of memory).
MAX_RESOLUTION = 1024


def sample_field(
    field,
    resolution: int,
    directions: np.ndarray | Sequence[float] | None,
    box: Box,
    chunk_points: int = 1 << 17,
) -> tuple[np.ndarray, np.ndarray]:
    """``(sigma_t (R, R, R), color (R, R, R, 3))`` float32: the field averaged over ``directions`` (``sigma_t``
    (R, R, R, 3) for a field with one density per colour channel).

    ``directions``: (M, 3) or one (3,) direction (normalised here); None: the
    :data:`DEFAULT_DIRECTIONS` Fibonacci directions.
    """
    import drjit as dr
    import mitsuba as mi

    if not 1 <= resolution <= MAX_RESOLUTION:
        raise ValueError(f"resolution: must be in [1, {MAX_RESOLUTION}], got {resolution}")
    dirs = fibonacci_directions(DEFAULT_DIRECTIONS) if directions is None else np.asarray(directions, dtype=np.float64)
    dirs = dirs.reshape(-1, 3)
    norms = np.linalg.norm(dirs, axis=1, keepdims=True)
    if not np.all(norms > 0) or not np.all(np.isfinite(dirs)):
        raise ValueError(f"direction: must be finite and non-zero, got {dirs.tolist()}")
    dirs = dirs / norms
    from mitsnerf.math.rays import host

    points = box.voxel_centres(resolution).reshape(-1, 3).astype(np.float32)
    sigma = np.zeros(0)
    color = np.zeros((len(points), 3), dtype=np.float64)
    with dr.suspend_grad():
        for start in range(0, len(points), chunk_points):
            p = points[start:start + chunk_points]
            n = len(p)
            x = mi.Array3f(p[:, 0], p[:, 1], p[:, 2])
            for d in dirs:
                rgb, s = field(x, mi.Array3f(*(float(c) for c in d)) + dr.zeros(mi.Array3f, n))
                s = host(s + dr.zeros(type(x.x), n))  # (n,), or (n, 3) for one density per colour
                if sigma.shape[:1] != (len(points),):
                    sigma = np.zeros((len(points),) + s.shape[1:])
                sigma[start:start + n] += s
                color[start:start + n] += np.stack([np.asarray(c, dtype=np.float64) for c in rgb], axis=-1)
    r = resolution
    return ((sigma / len(dirs)).astype(np.float32).reshape((r, r, r) + sigma.shape[1:]),
            (color / len(dirs)).astype(np.float32).reshape(r, r, r, 3))


def _save_npy(path: Path, array: np.ndarray) -> None:
    import io

    buf = io.BytesIO()
    np.save(buf, array)
    atomic_write_bytes(path, buf.getvalue())


def export_field(
    field,
    out_dir: Path,
    resolution: int = 64,
    direction: Sequence[float] | None = None,
    n_directions: int = DEFAULT_DIRECTIONS,
    box: Box | None = None,
    info: dict[str, Any] | None = None,
) -> dict[str, Path]:
    """Sample ``field`` over ``box`` and write the files of the module docstring to ``out_dir``; returns them by
    name."""
    if box is None:
        raise ValueError("export_field: the scene box the field lives in is needed")
    dirs = np.asarray(direction, dtype=np.float64) if direction is not None else fibonacci_directions(n_directions)
    sigma, color = sample_field(field, resolution, dirs, box)
    if not (np.isfinite(sigma).all() and np.isfinite(color).all()):
        raise DatasetError((info or {}).get("run"), None, "the learned field returned non-finite values "
                                                          "(a diverged run?); nothing exported")
    out_dir = Path(out_dir)
    names = ("sigma_t.vol", "albedo.vol", "sigma_t.npy", "color.npy", "export.json")
    with atomic_files(out_dir, names) as tmp:
        _write_export(tmp, sigma, color, box, {**(info or {}), "resolution": resolution}, direction, n_directions)
    return {name: out_dir / name for name in names}


def _write_export(paths: dict[str, Path], sigma: np.ndarray, color: np.ndarray, box: Box, info: dict[str, Any],
                  direction: Sequence[float] | None, n_directions: int) -> None:
    """The files of the module docstring, each to its path in ``paths``."""
    write_vol(paths["sigma_t.vol"], np.maximum(sigma, 0.0), box.lo, box.hi)
    write_vol(paths["albedo.vol"], np.clip(color, 0.0, 1.0), box.lo, box.hi)
    _save_npy(paths["sigma_t.npy"], sigma)
    _save_npy(paths["color.npy"], color)
    atomic_write_json(paths["export.json"], {
        **info,
        "box_min": list(box.lo),
        "box_max": list(box.hi),
        "colour": (f"seen looking along {np.asarray(direction, dtype=float).tolist()}" if direction is not None
                   else f"averaged over {n_directions} Fibonacci directions"),
        "sigma_t_max": float(sigma.max()),
        "sampled_at": "voxel centres ((i + 0.5) / R) of the box, [z, y, x]",
    })


def export_run(run_dir: Path, out_dir: Path | None = None, resolution: int = 64,
               direction: Sequence[float] | None = None, n_directions: int = DEFAULT_DIRECTIONS,
               progress: bool = False) -> dict[str, Path]:
    """Export the field of the run in ``run_dir`` (default ``OUT = RUN/export``; not inside the run's dataset, which
    its files would change). ``progress``: a line on stderr before and after (:func:`mitsnerf.outputs.progress_log`)."""
    import time

    from mitsnerf.outputs import progress_log
    from mitsnerf.runs.directory import check_outside_dataset
    from mitsnerf.runs.fit import load_run

    model, dataset, config = load_run(Path(run_dir))
    out_dir = Path(out_dir) if out_dir is not None else Path(run_dir) / "export"
    check_outside_dataset(out_dir, Path(dataset.root), what="an export", example="export/NAME")
    if not isinstance(model, HasField):
        raise DatasetError(run_dir, None, f"method {config.get('method')!r} has no queryable field to export")
    log, start = progress_log(progress), time.perf_counter()
    colour = "along one direction" if direction is not None else f"averaged over {n_directions} directions"
    log(f"[export] {config.get('method')}'s density and colour ({colour}) at the {resolution ** 3} voxel centres of "
        f"a {resolution}^3 grid -> {out_dir} ...")
    paths = export_field(model.field(), out_dir, resolution, direction, n_directions, box=dataset.box,
                         info={"run": str(run_dir), "method": config.get("method"), "provenance": env.provenance()})
    log(f"[export] written in {time.perf_counter() - start:.1f} s")
    return paths
