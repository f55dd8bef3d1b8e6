"""``grid``: your own medium, read from a file: a numpy ``.npy``/``.npz`` array or a Mitsuba ``.vol``.

The file's grid is indexed ``[z, y, x]`` like the package's own (a ``.vol`` stores its values x
fastest, which is the same C-order array; Mitsuba's reader, ``mitsuba.VolumeGrid``, reads it).
Its bounds map into the scene box with their aspect ratio kept: the longest axis spans the box
less ``margin`` at each face, the others are centred. The grid is then resampled to the spec's
``resolution``: each target voxel takes the mean, over ``m^3`` points spread evenly in it, of the
grid's trilinear interpolation (clamped to the edge voxels inside the grid's bounds, 0 outside
them), ``m`` the ceiling of the source voxels per target voxel: a box prefilter when shrinking, plain
trilinear when growing, and the array itself, bit for bit, when the grid is already ``R^3`` and
``margin`` is 0.

``values`` says what the numbers are:

- ``"density"`` (the default): a shape, scaled like every family's (``sigma_t = sigma_t_scale *
  value / world.scale``). Values may exceed 1; they must be finite and >= 0.
- ``"sigma_t"``: the extinction itself, per unit of world length; the spec's ``sigma_t_scale`` must
  then be 1 (it is not applied).

The albedo is one RGB colour (``albedo``), or a grid (``albedo_path``, ``[z, y, x, 3]`` RGB or
``[z, y, x]`` grey, values in [0, 1]) of the density grid's own ``[z, y, x]`` shape, placed and resampled
like it: voxel for voxel the albedo of the density's voxel. Another shape is refused rather than resampled:
one of another aspect would cover other bounds and leave part of the medium with albedo 0, and one rule, the
same shape, leaves nothing to guess. Paths are relative to the spec file's directory. A file is hashed by its
content into the dataset's key: editing it makes a new dataset, moving it does not.

Bad grids are one line naming the file and the problem (:class:`~mitsnerf.errors.SpecError`):
no file (missing, a directory, a broken link, a symlink loop), unreadable, an ``.npz`` of several arrays
none named, not a number array, wrong rank or channel count, NaN or inf, negative, all zero. What the
header declares is checked before the data is read (:func:`grid_header`): at most :data:`MAX_VALUES`
values, all present in the file. :func:`check` runs every check that needs no data (``mitsnerf generate``
runs it before writing anything).
OpenVDB and NanoVDB files are not read: no reader installable from PyPI has been shown to reproduce a
sparse, compressed fog volume's own active-voxel count and sum (README, "Your own volume"); convert one
to ``.npy`` in the program that wrote it.

>>> import tempfile, os
>>> torus = np.zeros((8, 8, 8), np.float32); torus[2:6, 2:6, 2:6] = 0.5
>>> path = os.path.join(tempfile.mkdtemp(), "box.npy"); np.save(path, torus)
>>> g = generate(Params(path=path), 8, seed=0)
>>> bool(np.array_equal(g.density, torus)), g.values
(True, 'density')
>>> float(generate(Params(path=path), 4, seed=0).density.max())  # each 2^3 block averaged
0.5
"""

from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from mitsnerf.config import param
from mitsnerf.data.arrays import file_problem, read_npy_header
from mitsnerf.data.verify import grid_problem
from mitsnerf.data.vol import HEADER_SIZE as VOL_HEADER_SIZE
from mitsnerf.data.vol import read_vol_header
from mitsnerf.errors import DatasetError, SpecError
from mitsnerf.volumes import params as common
from mitsnerf.volumes.base import Family, VolumeGrids, constant_albedo

#: The file types the family reads, by suffix.
SUFFIXES = (".npy", ".npz", ".vol")
#: The names of the parameters that are files: resolved against the spec's directory, hashed by content.
FILES = ("path", "albedo_path")
_MAX_SUPERSAMPLES = 4  # per axis: a 4x larger source is box-filtered exactly, a larger one approximately


def _check_suffix(field: str, value: str, required: bool) -> None:
    if not value:
        if required:
            raise ValueError(f"{field}: required: the grid file ({', '.join(SUFFIXES)})")
        return
    if Path(value).suffix.lower() not in SUFFIXES:
        raise ValueError(f"{field}: must name a {', '.join(SUFFIXES)} file, got {value!r} "
                         "(OpenVDB/NanoVDB: convert the grid to .npy first)")


@dataclass(frozen=True)
class Params:
    """Parameters of ``grid``; ``mitsnerf volumes grid`` lists them."""

    config_noun: ClassVar[str] = "parameter of volume family 'grid'"

    path: str = param(doc="the medium's grid: .npy or .npz ([z, y, x]) or Mitsuba .vol, relative to the spec file")
    array: str = param("", doc=".npz only: the array to read (may be left empty when the file holds one)")
    values: str = param("density", choices=("density", "sigma_t"),
                        doc="density: scaled by volume.sigma_t_scale; sigma_t: the extinction itself (scale 1)")
    albedo: tuple[float, float, float] = common.albedo((0.8, 0.8, 0.8))
    albedo_path: str = param("", doc="an albedo grid ([z, y, x, 3] RGB or [z, y, x] grey, in [0, 1]) "
                                     "instead of albedo, of path's [z, y, x] shape")
    albedo_array: str = param("", doc=".npz only: the albedo array to read")
    margin: float = param(0.0, lo=0.0, hi=0.45, doc="empty border at each box face, a fraction of the box "
                                                     "side; the grid's longest axis spans the rest")

    def __post_init__(self) -> None:
        _check_suffix("path", self.path, required=True)
        _check_suffix("albedo_path", self.albedo_path, required=False)


#: The most values (voxels times channels) a grid file may declare: an 812^3 density, a 563^3 RGB albedo. Reading
#: and resampling takes about 8 bytes per value (float64) twice over, 8 GiB at the limit; the box holds at most
#: 512^3 voxels, which a larger file only reaches by being averaged down. A header declaring more is refused
#: before anything is read (a damaged or foreign header can declare billions).
MAX_VALUES = 2**29
#: The parameter naming an ``.npz``'s array, by what the grid is.
_ARRAY_FIELD = {"density": "array", "albedo": "albedo_array"}
_READ_ERRORS = (OSError, ValueError, EOFError, RuntimeError, zipfile.BadZipFile)


def grid_header(path: str | Path, array: str = "", what: str = "density") -> tuple[tuple[int, ...], np.dtype]:
    """The shape and dtype of the grid in ``path`` (as :func:`read_array` will read it: a ``.vol`` of one channel
    is ``(z, y, x)``), from the file's header alone, with every check that needs no data: the path is a regular
    file, an ``.npz``'s array is named (or the only one), the values are numbers, at most :data:`MAX_VALUES` of
    them, all present in the file. A SpecError naming the file otherwise; ``what`` (density, albedo) names the
    grid and its ``.npz`` parameter in the messages.

    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "g.npy"); np.save(path, np.zeros((2, 3, 4), np.float32))
    >>> grid_header(path)
    ((2, 3, 4), dtype('float32'))
    """
    path = Path(path)
    problem = file_problem(path, "grid file")
    if problem is not None:
        raise SpecError(path, None, problem)
    suffix = path.suffix.lower()
    try:
        shape, dtype, stored = _read_header(path, suffix, array, what)
    except SpecError:
        raise
    except _READ_ERRORS as exc:
        raise SpecError(path, None, f"cannot be read as a {suffix} grid ({exc})") from None
    _check_declared(path, shape, dtype, stored, what)
    return shape, dtype


def _read_header(path: Path, suffix: str, array: str, what: str) -> tuple[tuple[int, ...], np.dtype, int]:
    """``(shape, dtype, bytes of data the file holds)`` from the header of ``path``."""
    if suffix == ".vol":
        try:
            h = read_vol_header(path)
        except DatasetError as exc:
            raise ValueError(f"{exc.field}: {exc.message}" if exc.field else exc.message) from None
        shape = (h.zres, h.yres, h.xres) + ((h.channels,) if h.channels > 1 else ())
        return shape, np.dtype(np.float32), path.stat().st_size - VOL_HEADER_SIZE
    if suffix == ".npz":
        with zipfile.ZipFile(path) as archive:
            member = _npz_member(path, archive, array, what) + ".npy"
            with archive.open(member) as f:
                shape, dtype = read_npy_header(f)
                return shape, dtype, archive.getinfo(member).file_size - f.tell()
    with open(path, "rb") as f:
        shape, dtype = read_npy_header(f)
        return shape, dtype, path.stat().st_size - f.tell()


def _npz_member(path: Path, archive: zipfile.ZipFile, array: str, what: str) -> str:
    """The name of the ``.npz`` array to read: ``array``, or the archive's only one."""
    names = [n[:-4] for n in archive.namelist() if n.endswith(".npy")]
    if not array and len(names) == 1:
        return names[0]
    if array in names:
        return array
    field = _ARRAY_FIELD[what]
    held = (f"no array {array!r} ({', '.join(names)})" if array and names else
            f"{len(names)} arrays ({', '.join(names)})" if names else "no arrays")
    raise SpecError(path, None, f"holds {held}; name one: --set volume.params.{field}=NAME, or {field} = \"NAME\" "
                                "in the spec's [volume.params]")


def _check_declared(path: Path, shape: tuple[int, ...], dtype: np.dtype, stored: int, what: str) -> None:
    """Refuse a header declaring non-numbers, more than :data:`MAX_VALUES` values, or more bytes than stored."""
    if dtype.kind not in "biuf":
        raise SpecError(path, None, f"holds {dtype} values, a {what} grid needs numbers")
    values = math.prod(shape)
    if values > MAX_VALUES:
        raise SpecError(path, None, f"declares {shape} {dtype}: {values:,} values, more than the {MAX_VALUES:,} a "
                                    "grid file may hold (nothing was read); resample it to at most 512 a side first")
    if values * dtype.itemsize > stored:
        raise SpecError(path, None, f"truncated: the header declares {shape} {dtype}, {values * dtype.itemsize:,} "
                                    f"bytes; the file holds {max(stored, 0):,}")


def check_shape(shape: tuple[int, ...], path: str | Path, channels: int, what: str) -> None:
    """Refuse a grid of ``shape`` that is not ``[z, y, x]`` (or ``[z, y, x, channels]``; an albedo may be grey:
    one channel) or is empty, in a SpecError naming ``path``.

    >>> check_shape((), "s.npy", 1, "density")
    Traceback (most recent call last):
    ...
    mitsnerf.errors.SpecError: s.npy: has 0 axes (), a density grid needs 3 ([z, y, x])
    """
    if len(shape) not in (3, 4):
        raise SpecError(path, None, f"has {len(shape)} axes {tuple(shape)}, a {what} grid needs 3 ([z, y, x])"
                                    + (" or 4 ([z, y, x, 3])" if channels == 3 else ""))
    if len(shape) == 4 and shape[3] != channels and not (channels == 3 and shape[3] == 1):
        raise SpecError(path, None, f"has {shape[3]} channels {tuple(shape)}, a {what} grid needs "
                                    f"{channels}" + (" (or 1, grey)" if channels == 3 else ""))
    if 0 in shape:
        raise SpecError(path, None, f"is empty: shape {tuple(shape)}")


def read_array(path: str | Path, array: str = "", what: str = "density") -> np.ndarray:
    """The number array in ``path`` (.npy, .npz's ``array`` or Mitsuba .vol, whose channels are the
    last axis only when there are several), as read, once :func:`grid_header` has checked the header;
    a SpecError naming the file if it cannot be read."""
    path = Path(path)
    grid_header(path, array, what)
    suffix = path.suffix.lower()
    try:
        if suffix == ".vol":
            return _read_vol(path)
        if suffix == ".npz":
            with zipfile.ZipFile(path) as members:
                name = _npz_member(path, members, array, what)
            with np.load(path, allow_pickle=False) as archive:
                return archive[name]
        return np.load(path, allow_pickle=False)
    except _READ_ERRORS as exc:
        raise SpecError(path, None, f"cannot be read as a {suffix} grid ({exc})") from None


def _read_vol(path: Path) -> np.ndarray:
    import mitsuba as mi

    if mi.variant() is None:
        from mitsnerf.env import set_variant

        set_variant()
    return np.array(mi.VolumeGrid(str(path)))


def _as_grid(data: np.ndarray, path: Path, channels: int, what: str) -> np.ndarray:
    """``data`` as float64 ``(Z, Y, X, channels)``, refusing wrong ranks and channel counts and non-numbers."""
    if data.dtype.kind not in "biuf":
        raise SpecError(path, None, f"holds {data.dtype} values, a {what} grid needs numbers")
    check_shape(data.shape, path, channels, what)
    if data.ndim == 3:
        data = data[..., None]
    data = np.asarray(data, dtype=np.float64)
    problem = grid_problem(data, lo=0.0, hi=1.0 if channels == 3 else None)
    if problem is not None:
        raise SpecError(path, None, f"the {what} grid has {problem}")
    return np.repeat(data, 3, axis=3) if data.shape[3] != channels else data


def axis_weights(n: int, resolution: int, extent: float) -> np.ndarray:
    """``(resolution, n)`` weights resampling one axis of ``n`` voxels spanning ``extent`` (a fraction of
    the box side, centred) onto the box's ``resolution`` voxels (module docstring: the mean of ``m``
    linear interpolations per target voxel; 0 beyond the grid's bounds).

    >>> axis_weights(2, 2, 1.0).tolist()  # the same voxels: the identity
    [[1.0, 0.0], [0.0, 1.0]]
    >>> axis_weights(4, 2, 1.0).tolist()  # two source voxels per target voxel: their mean
    [[0.5, 0.5, 0.0, 0.0], [0.0, 0.0, 0.5, 0.5]]
    >>> axis_weights(1, 4, 0.5).tolist()  # one voxel in the middle half of the box
    [[0.0], [1.0], [1.0], [0.0]]
    """
    per_target = n / (resolution * extent)  # source voxels per target voxel
    m = min(max(1, math.ceil(per_target - 1e-9)), _MAX_SUPERSAMPLES)
    a = np.arange(resolution, dtype=np.float64)[:, None]
    k = (np.arange(m, dtype=np.float64)[None, :] + 0.5) / m
    # a point at (a + k) / R of the box sits at u source voxels from the grid's start
    u = ((a + k) - resolution * (1.0 - extent) / 2.0) * per_target
    inside = (u >= 0.0) & (u <= n)
    s = np.clip(u - 0.5, 0.0, n - 1.0)
    i0 = np.floor(s).astype(np.int64)
    f = s - i0
    i1 = np.minimum(i0 + 1, n - 1)
    w = np.zeros((resolution, n), np.float64)
    rows = np.broadcast_to(np.arange(resolution)[:, None], u.shape)
    np.add.at(w, (rows, i0), np.where(inside, (1.0 - f) / m, 0.0))
    np.add.at(w, (rows, i1), np.where(inside, f / m, 0.0))
    return w


def place(data: np.ndarray, resolution: int, margin: float) -> np.ndarray:
    """``data`` (Z, Y, X, C) placed in the box (aspect kept, ``margin`` at the faces) and resampled to
    ``(R, R, R, C)`` float32 (module docstring)."""
    span = 1.0 - 2.0 * margin
    longest = max(data.shape[:3])
    out = data
    for axis in range(3):  # separable: one axis at a time
        n = data.shape[axis]
        w = axis_weights(n, resolution, span * n / longest)
        out = np.moveaxis(np.tensordot(w, np.moveaxis(out, axis, 0), axes=(1, 0)), 0, axis)
    return np.ascontiguousarray(out, dtype=np.float32)


def check(params: Params) -> None:
    """Every check of the files that needs no data (:func:`grid_header`, :func:`check_shape`), and the albedo
    grid's ``[z, y, x]`` shape against the density's: what ``mitsnerf generate`` refuses before writing."""
    dshape, _ = grid_header(params.path, params.array, "density")
    check_shape(dshape, params.path, 1, "density")
    if params.albedo_path:
        ashape, _ = grid_header(params.albedo_path, params.albedo_array, "albedo")
        check_shape(ashape, params.albedo_path, 3, "albedo")
        if ashape[:3] != dshape[:3]:
            raise SpecError(params.albedo_path, None, f"the albedo grid's shape {ashape[:3]} differs from the density "
                                                      f"grid {params.path}'s {dshape[:3]}: an albedo grid must have "
                                                      "the density's [z, y, x] shape")


def generate(params: Params, resolution: int, seed: int) -> VolumeGrids:
    """Read, check, place and resample the grid (module docstring); the seed is unused."""
    check(params)
    path = Path(params.path)
    density = place(_as_grid(read_array(path, params.array), path, 1, "density"), resolution, params.margin)[..., 0]
    if not density.any():
        raise SpecError(path, None, "holds no medium: every value is 0")
    if params.albedo_path:
        apath = Path(params.albedo_path)
        albedo = place(_as_grid(read_array(apath, params.albedo_array, "albedo"), apath, 3, "albedo"), resolution,
                       params.margin)
        albedo = np.clip(albedo, 0.0, 1.0)  # interpolation keeps [0, 1] up to rounding
    else:
        albedo = constant_albedo(resolution, params.albedo)
    return VolumeGrids(density, albedo, values=params.values)


FAMILY = Family(
    name="grid",
    params_type=Params,
    generate=generate,
    description="your own medium from a .npy, .npz or Mitsuba .vol file, placed in the box and resampled",
    files=FILES,
    check=check,
)
