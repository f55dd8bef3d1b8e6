"""Mitsuba's binary grid volume format (``.vol``), as read by its ``gridvolume`` plugin.

Layout (little-endian)::

    bytes 0-2    'V', 'O', 'L'
    byte  3      version, 3
    int32        encoding, 1 = float32 (the only one written or read here)
    int32 x3     xres, yres, zres
    int32        channels (1 for density, 3 for RGB albedo)
    float32 x6   bounding box: xmin, ymin, zmin, xmax, ymax, zmax
    float32 ...  data[((z * yres + y) * xres + x) * channels + c]: x fastest, then y, then z,
                 channels interleaved; i.e. a C-order (z, y, x, channels) array

Mitsuba 3 places the grid with the plugin's ``to_world`` (``[0, 1]^3`` by default) rather than the
stored box; mitsnerf records the scene box there for other readers.

>>> import tempfile, os
>>> path = os.path.join(tempfile.mkdtemp(), "density.vol")
>>> write_vol(path, np.arange(24, dtype=np.float32).reshape(2, 3, 4))
>>> os.path.getsize(path)  # 48-byte header + 24 values
144
>>> data, lo, hi = read_vol(path)
>>> data.shape, float(data[1, 2, 3, 0]), lo, hi
((2, 3, 4, 1), 23.0, (-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
"""

from __future__ import annotations

import os
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mitsnerf.data.atomic import atomic_path
from mitsnerf.errors import DatasetError

MAGIC = b"VOL"
VERSION = 3
ENCODING_FLOAT32 = 1
_HEADER = struct.Struct("<3sBiiiii6f")  # 48 bytes
HEADER_SIZE = _HEADER.size


def _box(name: str, value: Sequence[float]) -> tuple[float, float, float]:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise ValueError(f"{name}: must be 3 finite numbers, got {value!r}")
    return float(v[0]), float(v[1]), float(v[2])


def write_vol(
    path: str | os.PathLike,
    data: np.ndarray,
    bbox_min: Sequence[float] = (-0.5, -0.5, -0.5),
    bbox_max: Sequence[float] = (0.5, 0.5, 0.5),
) -> None:
    """Write a (z, y, x) or (z, y, x, C) float grid to ``path`` as a float32 ``.vol`` file, atomically.

    The bytes go to a temporary sibling ``.<name>.tmp-<random>`` that is renamed onto ``path``
    with ``os.replace`` once complete and removed on failure (:func:`mitsnerf.data.atomic.atomic_path`),
    so readers never see half a file.

    Raises:
        ValueError: ``data`` is not 3-D or 4-D, has an empty axis, or the box is not
            ``bbox_min < bbox_max`` componentwise.
    """
    arr = np.asarray(data)
    if arr.ndim == 3:
        arr = arr[..., None]
    if arr.ndim != 4 or 0 in arr.shape:
        raise ValueError(
            f"data: must have shape (z, y, x) or (z, y, x, C) with no empty axis, got {np.shape(data)}"
        )
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"data: must be a real numeric array, got dtype {arr.dtype}")
    lo, hi = _box("bbox_min", bbox_min), _box("bbox_max", bbox_max)
    if not all(a < b for a, b in zip(lo, hi)):
        raise ValueError(f"bbox_max: must exceed bbox_min componentwise, got {lo} and {hi}")
    zres, yres, xres, channels = arr.shape
    header = _HEADER.pack(MAGIC, VERSION, ENCODING_FLOAT32, xres, yres, zres, channels, *lo, *hi)
    body = np.ascontiguousarray(arr, dtype="<f4")

    with atomic_path(path) as tmp:
        with open(tmp, "xb") as f:
            f.write(header)
            f.write(body.data.cast("B"))
            f.flush()
            os.fsync(f.fileno())


@dataclass(frozen=True)
class VolHeader:
    """What a ``.vol`` file's header declares (module docstring): the grid's shape and box."""

    zres: int
    yres: int
    xres: int
    channels: int
    bbox_min: tuple[float, float, float]
    bbox_max: tuple[float, float, float]

    @property
    def nbytes(self) -> int:
        """The bytes of data the header declares (float32 values)."""
        return 4 * self.zres * self.yres * self.xres * self.channels


def _parse_header(path: str | os.PathLike, raw: bytes) -> VolHeader:
    """The header at the start of ``raw`` (a DatasetError naming the field that is wrong)."""
    if len(raw) < HEADER_SIZE:
        raise DatasetError(path, "header", f"truncated: {len(raw)} bytes, a .vol header has {HEADER_SIZE}")
    magic, version, encoding, xres, yres, zres, channels, *box = _HEADER.unpack_from(raw)
    if magic != MAGIC:
        raise DatasetError(path, "magic", f"expected b'VOL', got {magic!r}: not a Mitsuba .vol file")
    if version != VERSION:
        raise DatasetError(path, "version", f"expected {VERSION}, got {version}")
    if encoding != ENCODING_FLOAT32:
        raise DatasetError(
            path, "encoding", f"only {ENCODING_FLOAT32} (float32) is supported, got {encoding}"
        )
    if min(xres, yres, zres) < 1:
        raise DatasetError(path, "resolution", f"must be positive, got {xres} x {yres} x {zres}")
    if channels < 1:
        raise DatasetError(path, "channels", f"must be positive, got {channels}")
    lo, hi = tuple(float(c) for c in box[:3]), tuple(float(c) for c in box[3:])
    if not all(np.isfinite(box)):
        raise DatasetError(path, "bbox", f"must be finite, got {lo} to {hi}")
    return VolHeader(zres, yres, xres, channels, lo, hi)  # type: ignore[arg-type]


def read_vol_header(path: str | os.PathLike) -> VolHeader:
    """The header of the ``.vol`` file at ``path``, read without its data (the checks of :func:`read_vol`
    that need no data).

    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "g.vol")
    >>> write_vol(path, np.zeros((2, 3, 4, 3), np.float32))
    >>> h = read_vol_header(path); (h.zres, h.yres, h.xres, h.channels, h.nbytes)
    (2, 3, 4, 3, 288)
    """
    with open(path, "rb") as f:
        return _parse_header(path, f.read(HEADER_SIZE))


def read_vol(path: str | os.PathLike) -> tuple[np.ndarray, tuple[float, ...], tuple[float, ...]]:
    """Read a float32 ``.vol`` file.

    Returns:
        ``(data, bbox_min, bbox_max)``: data float32 of shape (zres, yres, xres, channels), the box
        corners as tuples of 3 floats.

    Raises:
        DatasetError(path, field, message): the file is missing, truncated, too long, or its
            header is wrong (field ``magic``, ``version``, ``encoding``, ``resolution``,
            ``channels``, ``bbox`` or ``data``).
    """
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise DatasetError(path, None, "no such file") from None
    except IsADirectoryError:
        raise DatasetError(path, None, "is a directory, expected a .vol file") from None
    h = _parse_header(path, raw)
    xres, yres, zres, channels = h.xres, h.yres, h.zres, h.channels
    count = xres * yres * zres * channels
    expected = HEADER_SIZE + 4 * count
    if len(raw) != expected:
        what = "truncated" if len(raw) < expected else "too long"
        raise DatasetError(
            path, "data",
            f"{what}: {len(raw)} bytes, {xres} x {yres} x {zres} x {channels} float32 values need {expected}",
        )
    data = np.frombuffer(raw, dtype="<f4", count=count, offset=HEADER_SIZE)
    return data.reshape(zres, yres, xres, channels).astype(np.float32), h.bbox_min, h.bbox_max
