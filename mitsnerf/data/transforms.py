"""NeRF-synthetic (Blender) ``transforms_*.json`` camera files, with the instant-ngp intrinsics keys.

A file holds top-level intrinsics and a list of ``frames``, each with an image
``file_path`` (relative to the file's directory, without extension in
NeRF-synthetic) and an OpenGL camera-to-world ``transform_matrix`` (4x4).
Intrinsics may be given per frame, overriding the top-level ones::

    {"camera_angle_x": 0.69, "fl_x": 1111.1, "fl_y": 1111.1, "cx": 400.0, "cy": 400.0,
     "w": 800, "h": 800, "aabb_scale": 1, "pixel_center": 0.5, "camera_convention": "opengl",
     "frames": [{"file_path": "./train/r_000", "transform_matrix": [[...], ...], ...}]}

Focal lengths come from ``fl_x`` (else ``fl = 0.5 w / tan(0.5 camera_angle_x)``) and
``fl_y`` (else from ``camera_angle_y``, else ``fl_x``: square pixels); the principal
point from ``cx``/``cy``, else the image centre. The original NeRF-synthetic files
only have ``camera_angle_x``; their image size is then read from the images
through ``image_size_of``. Lens distortion (``k1``, ``k2``, ``p1``, ``p2``, ...) is
not supported and must be absent or zero.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.data.atomic import atomic_write_json
from mitsnerf.errors import DatasetError
from mitsnerf.math.camera import Camera

_INTRINSIC_KEYS = ("camera_angle_x", "camera_angle_y", "fl_x", "fl_y", "cx", "cy", "w", "h")
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
_RESERVED_KEYS = (*_INTRINSIC_KEYS, "aabb_scale", "pixel_center", "camera_convention", "frames")


def _intrinsics(cam: Camera) -> dict[str, Any]:
    return {
        "camera_angle_x": cam.camera_angle_x,
        "fl_x": float(cam.fl_x),
        "fl_y": float(cam.fl_y),
        "cx": float(cam.cx),
        "cy": float(cam.cy),
        "w": int(cam.width),
        "h": int(cam.height),
    }


def write_transforms(
    path: str | os.PathLike,
    cameras: Sequence[Camera],
    file_paths: Sequence[str],
    *,
    aabb_scale: int = 1,
    extra: Mapping[str, Any] | None = None,
) -> None:
    """Write ``cameras`` and their image paths as a ``transforms_*.json`` file, atomically.

    Top level: the first camera's intrinsics (``camera_angle_x``, ``fl_x``, ``fl_y``,
    ``cx``, ``cy``, ``w``, ``h``), ``aabb_scale``, ``pixel_center: 0.5``,
    ``camera_convention: "opengl"``, then the ``extra`` entries, then ``frames``.
    Each frame repeats its own camera's intrinsics. ``file_paths`` are written as
    given: relative to the file's directory, without extension, e.g. ``"./train/r_000"``.
    """
    if len(cameras) != len(file_paths):
        raise ValueError(f"{len(cameras)} cameras but {len(file_paths)} file paths")
    if not cameras:
        raise ValueError("no cameras to write")
    extra = dict(extra or {})
    clash = sorted(set(extra) & set(_RESERVED_KEYS))
    if clash:
        raise ValueError(f"extra keys {clash} would overwrite the file's own entries")
    doc: dict[str, Any] = _intrinsics(cameras[0])
    doc.update(aabb_scale=int(aabb_scale), pixel_center=0.5, camera_convention="opengl")
    doc.update(extra)
    doc["frames"] = [
        {"file_path": str(fp), "transform_matrix": np.asarray(cam.c2w, dtype=float).tolist(), **_intrinsics(cam)}
        for cam, fp in zip(cameras, file_paths)
    ]
    atomic_write_json(path, doc)


def read_json(path: str | os.PathLike) -> Any:
    """Parse a JSON file; a missing, unreadable or malformed file (NaN included) raises DatasetError."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DatasetError(path, None, "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(path, None, f"cannot read ({exc.__class__.__name__}: {exc})") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DatasetError(path, None, f"invalid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    bad = non_finite_field(doc)
    if bad is not None:
        raise DatasetError(path, bad[0], f"non-finite number {json.dumps(bad[1])} is not allowed")
    return doc


def non_finite_field(doc: Any, where: str = "") -> tuple[str, float] | None:
    """The dotted field (list items by index) of the first NaN or infinity in parsed JSON ``doc``, with it.

    >>> non_finite_field({"frames": [{"m": [[1, 2]]}, {"m": [[0, float("nan")]]}]})
    ('frames[1].m[0][1]', nan)
    >>> non_finite_field({"camera_angle_x": 0.7}) is None
    True
    """
    if isinstance(doc, float) and not math.isfinite(doc):
        return where, doc
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        found = non_finite_field(value, f"{where}[{key}]" if isinstance(key, int) else f"{where}.{key}".lstrip("."))
        if found is not None:
            return found
    return None


class _Frame:
    """Looks a key up in a frame, then at the top level, remembering which field it came from."""

    def __init__(self, path: Path, top: Mapping[str, Any], frame: Mapping[str, Any], index: int) -> None:
        self.path, self.top, self.frame, self.prefix = path, top, frame, f"frames[{index}]"

    def field(self, key: str, where: str) -> str:
        return f"{self.prefix}.{key}" if where == "frame" else key

    def error(self, key: str, where: str, message: str) -> DatasetError:
        return DatasetError(self.path, self.field(key, where), message)

    def get(self, key: str, levels=("frame", "top")) -> tuple[Any, str] | None:
        for where in levels:
            source = self.frame if where == "frame" else self.top
            if key in source and source[key] is not None:
                return source[key], where
        return None

    def number(self, key: str, where: str, value: Any, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(key, where, f"must be a finite number, got {value!r}")
        if positive and not value > 0:
            raise self.error(key, where, f"must be positive, got {value!r}")
        return float(value)

    def size(self, key: str) -> int | None:
        found = self.get(key)
        if found is None:
            return None
        value = self.number(key, found[1], found[0], positive=True)
        if value != int(value):
            raise self.error(key, found[1], f"must be a whole number of pixels, got {found[0]!r}")
        return int(value)

    def focal(self, fl_key: str, angle_key: str, extent: int) -> float | None:
        """``fl_key``, else ``0.5 extent / tan(0.5 angle)``; frame level before top level."""
        for level in ("frame", "top"):
            found = self.get(fl_key, (level,))
            if found is not None:
                return self.number(fl_key, level, found[0], positive=True)
            found = self.get(angle_key, (level,))
            if found is not None:
                angle = self.number(angle_key, level, found[0], positive=True)
                if not angle < math.pi:
                    raise self.error(angle_key, level, f"must be in (0, pi) radians, got {found[0]!r}")
                return 0.5 * extent / math.tan(0.5 * angle)
        return None


def _matrix(fr: _Frame) -> np.ndarray:
    found = fr.get("transform_matrix", ("frame",))
    if found is None:
        raise fr.error("transform_matrix", "frame", "missing")
    try:
        m = np.array(found[0], dtype=np.float64)
    except (TypeError, ValueError):
        raise fr.error("transform_matrix", "frame", "must be a 4x4 array of numbers") from None
    if m.shape != (4, 4):
        raise fr.error("transform_matrix", "frame", f"must be 4x4, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise fr.error("transform_matrix", "frame", "has non-finite entries")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise fr.error("transform_matrix", "frame", f"last row must be [0, 0, 0, 1], got {m[3].tolist()}")
    return m


def _pixel_center(path: Path, top: Mapping[str, Any], pixel_center: float | None) -> float:
    if pixel_center is not None:
        return float(pixel_center)
    if "pixel_center" in top:
        value = top["pixel_center"]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise DatasetError(path, "pixel_center", f"must be a finite number, got {value!r}")
        return float(value)
    return 0.5


def read_transforms(
    path: str | os.PathLike,
    pixel_center: float | None = None,
    *,
    image_size_of: Callable[[str], tuple[int, int]] | None = None,
) -> tuple[list[str], list[Camera], dict[str, Any]]:
    """Read a ``transforms_*.json`` file: ``(file_paths, cameras, meta)``.

    ``file_paths`` are the frames' ``file_path`` strings as written (relative to
    the file's directory). ``meta`` is the file's top-level entries except
    ``frames``, with ``meta["pixel_center"]`` set to the pixel centre that applies:

    1. the ``pixel_center`` argument, if given;
    2. else the file's ``pixel_center`` entry (every file mitsnerf writes has ``0.5``);
    3. else ``0.5``: rays through pixel centres, where Blender (which rendered NeRF-synthetic), Mitsuba
       and every other renderer put a pixel's sample, and where nerfstudio and instant-ngp cast their
       rays. The original NeRF loader cast them through integer pixel corners, half a pixel off its own
       data; pass ``0.0`` to reproduce it.

    ``image_size_of(file_path) -> (width, height)`` is called for frames whose
    ``w``/``h`` appear neither in the frame nor at the top level (original
    NeRF-synthetic files); it may raise ``FileNotFoundError``, reported against the
    frame's ``file_path``. Every problem raises :class:`DatasetError` naming the
    file and the field, e.g. ``frames[3].transform_matrix``.
    """
    path = Path(path)
    top = read_json(path)
    if not isinstance(top, dict):
        raise DatasetError(path, None, f"must hold a JSON object, got {type(top).__name__}")
    frames = top.get("frames")
    if frames is None:
        raise DatasetError(path, "frames", "missing")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(path, "frames", "must be a non-empty list")
    meta = {k: v for k, v in top.items() if k != "frames"}
    meta["pixel_center"] = _pixel_center(path, top, pixel_center)

    file_paths: list[str] = []
    cameras: list[Camera] = []
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise DatasetError(path, f"frames[{i}]", f"must be an object, got {type(frame).__name__}")
        fr = _Frame(path, top, frame, i)
        fp = frame.get("file_path")
        if not isinstance(fp, str) or not fp:
            raise fr.error("file_path", "frame", "missing" if fp is None else f"must be a non-empty string, got {fp!r}")
        c2w = _matrix(fr)
        for key in _DISTORTION_KEYS:
            found = fr.get(key)
            if found is not None and fr.number(key, found[1], found[0]) != 0.0:
                raise fr.error(key, found[1], "lens distortion is not supported (pinhole cameras only)")

        w, h = fr.size("w"), fr.size("h")
        if w is None or h is None:
            if image_size_of is None:
                raise fr.error("w", "frame", "no image size (w, h) in the frame or at the top level")
            try:
                w_img, h_img = image_size_of(fp)
            except FileNotFoundError as exc:
                raise fr.error("file_path", "frame", str(exc)) from None
            w = w_img if w is None else w
            h = h_img if h is None else h
        fl_x = fr.focal("fl_x", "camera_angle_x", w)
        if fl_x is None:
            raise fr.error("fl_x", "frame", "no focal length: fl_x or camera_angle_x is needed")
        fl_y = fr.focal("fl_y", "camera_angle_y", h)
        cx, cy = fr.get("cx"), fr.get("cy")
        try:
            cam = Camera(
                c2w,
                w,
                h,
                fl_x,
                fl_x if fl_y is None else fl_y,
                0.5 * w if cx is None else fr.number("cx", cx[1], cx[0]),
                0.5 * h if cy is None else fr.number("cy", cy[1], cy[0]),
            )
        except ValueError as exc:
            raise fr.error("transform_matrix", "frame", str(exc)) from None
        file_paths.append(fp)
        cameras.append(cam)
    return file_paths, cameras, meta
