"""Image files: float EXR (linear radiance) and 8-bit sRGB PNG (previews, foreign datasets).

Arrays are float32 ``(H, W, C)`` with ``C = 3`` (RGB) or ``4`` (RGBA), row 0 at the
top. Every RGBA EXR mitsnerf writes says what its alpha means, in the string attribute
``mitsnerf:alpha`` of its header (:data:`ALPHA_ATTRIBUTE`, one of :data:`ALPHA_MEANINGS`):

- ``premultiplied``: RGB is the radiance of what is in front, alpha its coverage; over a
  background ``B`` the image is ``rgb + (1 - a) B`` (OpenEXR's rule);
- ``straight``: the same over ``B`` is ``rgb a + (1 - a) B``;
- ``opacity``: RGB is already the full image over the background; alpha is only the opacity
  ``1 - T`` (for depth-like use), never to be composited again.
 Writes are atomic (:mod:`mitsnerf.data.atomic`). A file that is missing,
unreadable, corrupt or lacks the R, G, B channels raises
:class:`~mitsnerf.errors.DatasetError` naming the file (and the channel), one line.

>>> import tempfile, shutil
>>> d = Path(tempfile.mkdtemp())
>>> img = np.array([[[0.0, 0.5, 2.0, 1.0]]], dtype=np.float32)   # (1, 1, 4), HDR value kept
>>> write_exr(d / "a.exr", img, alpha="opacity")
>>> read_exr(d / "a.exr").tolist(), read_exr_alpha(d / "a.exr")
([[[0.0, 0.5, 2.0, 1.0]]], 'opacity')
>>> write_png(d / "a.png", img)           # linear -> sRGB 8 bit, clipped to [0, 1]
>>> (read_png(d / "a.png") * 255).round().tolist()
[[[0.0, 188.0, 255.0, 255.0]]]
>>> shutil.rmtree(d)
"""

from __future__ import annotations

import io
import os
import sys
import tempfile
import typing
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np

from mitsnerf.data.atomic import atomic_path, atomic_write_bytes
from mitsnerf.errors import DatasetError
from mitsnerf.math.color import linear_to_srgb

_RGBA = ("R", "G", "B", "A")
ALPHA_ATTRIBUTE = "mitsnerf:alpha"
"""The EXR header attribute that says what an RGBA image's alpha means."""
ALPHA_MEANINGS = ("premultiplied", "straight", "opacity")


def _check_image(image) -> np.ndarray:
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4) or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"expected an image of shape (H, W, 3) or (H, W, 4), got {arr.shape}")
    return arr


def _check_exists(path: Path) -> None:
    if not path.exists():
        raise DatasetError(path, None, "file not found")
    if not path.is_file():
        raise DatasetError(path, None, "not a file")


@contextmanager
def _library_output_to_buffer() -> Iterator[dict[str, str]]:
    """Capture what is printed meanwhile, at the Python and file-descriptor level; fills the yielded dict.

    The OpenEXR bindings print warnings on ``sys.stdout`` and its C core prints
    errors on file descriptor 2, besides raising. When a read fails we report one
    DatasetError line instead and drop that noise. Keys: ``"stdout"``, ``"stderr"``.
    """
    captured: dict[str, str] = {}
    py_out, py_err = io.StringIO(), io.StringIO()
    saved: dict[int, int] = {}
    bufs: dict[int, typing.IO[bytes]] = {}
    try:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
        for fd in (1, 2):
            saved[fd] = os.dup(fd)
            bufs[fd] = tempfile.TemporaryFile()
            os.dup2(bufs[fd].fileno(), fd)
    except (OSError, ValueError):  # no usable descriptor: leave the rest alone
        pass
    try:
        with redirect_stdout(py_out), redirect_stderr(py_err):
            yield captured
    finally:
        for fd, buf in bufs.items():
            if fd in saved:
                os.dup2(saved[fd], fd)
                os.close(saved[fd])
            buf.seek(0)
            text = buf.read().decode("utf-8", errors="replace")
            buf.close()
            (py_out if fd == 1 else py_err).write(text)
        for fd in set(saved) - set(bufs):
            os.close(saved[fd])
        captured["stdout"], captured["stderr"] = py_out.getvalue(), py_err.getvalue()


def write_exr(path: str | os.PathLike, image, alpha: str | None = None) -> None:
    """Write a linear float image ``(H, W, 3|4)`` as a 32-bit float, ZIP-compressed RGB(A) EXR.

    ``alpha``: what an RGBA image's alpha means (one of :data:`ALPHA_MEANINGS`), written into the
    header as :data:`ALPHA_ATTRIBUTE`; every RGBA image mitsnerf writes says it (None: the file does
    not say, as another tool's). An RGB image has none.
    """
    import OpenEXR

    arr = _check_image(image).astype(np.float32, copy=False)
    if alpha is not None and (arr.shape[2] != 4 or alpha not in ALPHA_MEANINGS):
        raise ValueError(f"an RGBA image needs alpha in {ALPHA_MEANINGS} (an RGB image none), got {alpha!r} "
                         f"for {arr.shape[2]} channels")
    # The bindings read the raw buffer: each channel must be its own contiguous array.
    channels = {name: np.ascontiguousarray(arr[..., i]) for i, name in enumerate(_RGBA[: arr.shape[2]])}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if alpha is not None:
        header[ALPHA_ATTRIBUTE] = alpha
    with atomic_path(path) as tmp:
        with OpenEXR.File(header, channels) as f:
            try:
                f.write(str(tmp))
            except RuntimeError as exc:  # OpenEXR's own error, even for a full disk: that one as the OSError it is
                full = _disk_full(exc, tmp)
                if full is None:
                    raise
                raise full from exc


def _disk_full(exc: RuntimeError, path: Path) -> OSError | None:
    """The OSError (ENOSPC, EDQUOT) an OpenEXR write error reports in its text, else None."""
    import errno

    for code in (errno.ENOSPC, errno.EDQUOT):
        if os.strerror(code) in str(exc):
            return OSError(code, os.strerror(code), str(path))
    return None


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """Read an EXR's R, G, B (and A if present) channels as float32 ``(H, W, 3|4)``, in RGBA order.

    Half and float channels are accepted; other channels (depth, AOVs) are ignored.
    Only the first part of a multi-part file is read.
    """
    import OpenEXR

    path = Path(path)
    _check_exists(path)
    failed = False
    with _library_output_to_buffer() as noise:
        try:
            with OpenEXR.File(str(path), separate_channels=True) as f:
                channels = dict(f.channels())
                data = {}
                for name in _RGBA:
                    if name in channels:
                        data[name] = (channels[name].type(), np.array(channels[name].pixels))  # own copy
        except (RuntimeError, ValueError, OSError):
            failed = True
    if failed:
        raise DatasetError(path, None, "not a readable OpenEXR file (corrupt, truncated or another format)")
    for key, stream in (("stdout", sys.stdout), ("stderr", sys.stderr)):
        if noise.get(key) and stream is not None:
            stream.write(noise[key])  # a successful read keeps whatever the library had to say
    missing = [n for n in _RGBA[:3] if n not in data]
    if missing:
        have = ", ".join(sorted(channels)) or "none"
        raise DatasetError(path, f"channel {missing[0]}", f"missing (an RGB(A) image is needed; the file has: {have})")
    shape = data["R"][1].shape
    out = []
    for name in _RGBA[: 3 + ("A" in data)]:
        ptype, pixels = data[name]
        if ptype not in (OpenEXR.HALF, OpenEXR.FLOAT):
            raise DatasetError(path, f"channel {name}", f"pixel type {ptype.name}, expected HALF or FLOAT")
        if pixels.shape != shape:
            raise DatasetError(path, f"channel {name}",
                               f"size {pixels.shape} differs from channel R's {shape} (subsampled?)")
        out.append(pixels.astype(np.float32, copy=False))
    return np.stack(out, axis=-1)


def read_exr_alpha(path: str | os.PathLike) -> str | None:
    """What an EXR's alpha means, from its header's :data:`ALPHA_ATTRIBUTE` (None: the file does not say).

    A value that is not one of :data:`ALPHA_MEANINGS` raises :class:`~mitsnerf.errors.DatasetError`.
    """
    import OpenEXR

    path = Path(path)
    _check_exists(path)
    failed = False
    with _library_output_to_buffer():
        try:
            with OpenEXR.File(str(path), header_only=True) as f:
                value = f.header().get(ALPHA_ATTRIBUTE)
        except (RuntimeError, ValueError, OSError):
            failed = True
    if failed:
        raise DatasetError(path, None, "not a readable OpenEXR file (corrupt, truncated or another format)")
    if value is None:
        return None
    if value not in ALPHA_MEANINGS:
        raise DatasetError(path, ALPHA_ATTRIBUTE, f"{value!r} is none of {', '.join(ALPHA_MEANINGS)}")
    return str(value)


def png_levels(linear_image) -> np.ndarray:
    """The 8-bit levels :func:`write_png` stores for a linear image ``(..., 3|4)``: RGB clipped to
    ``[0, 1]`` and sRGB-encoded, alpha clipped, NaN as 0, each rounded to the nearest of 256 levels.

    >>> png_levels(np.array([[0.0, 0.5, 2.0]])).tolist()
    [[0, 188, 255]]
    """
    arr = np.asarray(linear_image, dtype=np.float64)
    arr = np.clip(np.nan_to_num(arr, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    arr[..., :3] = linear_to_srgb(arr[..., :3])
    return np.round(arr * 255.0).astype(np.uint8)


def png_quantised(linear_rgb) -> np.ndarray:
    """Linear RGB ``(..., 3)`` as it comes back from an 8-bit sRGB PNG (:func:`png_levels`, decoded):
    what a renderer that writes PNG can at best hand over.

    >>> [round(float(v), 4) for v in png_quantised(np.array([0.0, 0.5, 2.0]))]
    [0.0, 0.5029, 1.0]
    """
    from mitsnerf.math.color import srgb_to_linear

    return srgb_to_linear(png_levels(linear_rgb).astype(np.float32) / np.float32(255.0))


def write_png(path: str | os.PathLike, linear_image) -> None:
    """Write a linear image ``(H, W, 3|4)`` as an 8-bit sRGB PNG preview.

    RGB is clipped to ``[0, 1]`` and sRGB-encoded; alpha is clipped and stays linear.
    NaN becomes 0. Values are rounded to the nearest of the 256 levels.
    """
    from PIL import Image

    u8 = png_levels(_check_image(linear_image))
    buf = io.BytesIO()
    Image.fromarray(u8, mode="RGBA" if u8.shape[2] == 4 else "RGB").save(buf, format="PNG")
    atomic_write_bytes(path, buf.getvalue())


def over(rgb: np.ndarray, alpha: np.ndarray, background, premultiplied: bool = True) -> np.ndarray:
    """``rgb`` with ``alpha`` (..., 1) over the radiance ``background`` (broadcasting): premultiplied
    ``rgb + (1 - a) B`` (OpenEXR's rule, mitsnerf's ``medium/`` views), or straight ``rgb a + (1 - a) B`` (PNG).

    >>> over(np.array([0.2, 0.1, 0.0]), np.array([0.25]), np.array([1.0, 1.0, 1.0])).tolist()
    [0.95, 0.85, 0.75]
    >>> over(np.array([0.8, 0.4, 0.0]), np.array([0.25]), np.array([1.0, 1.0, 1.0]), premultiplied=False).tolist()
    [0.95, 0.85, 0.75]
    """
    return (rgb if premultiplied else rgb * alpha) + background * (1.0 - alpha)


def unpremultiply(rgba) -> np.ndarray:
    """Straight colour of a premultiplied RGBA image ``(..., 4)``: ``rgb / alpha`` where ``alpha > 0``, else 0.

    A PNG's alpha is straight: its readers composite ``rgb * a + b * (1 - a)``, which gives the
    premultiplied ``rgb + (1 - a) b`` back. Alpha is kept.

    >>> unpremultiply(np.array([[[0.2, 0.1, 0.0, 0.5], [0.3, 0.3, 0.3, 0.0]]])).tolist()
    [[[0.4, 0.2, 0.0, 0.5], [0.0, 0.0, 0.0, 0.0]]]
    """
    arr = np.asarray(rgba, dtype=np.float64)
    a = arr[..., 3:4]
    with np.errstate(divide="ignore", invalid="ignore"):
        rgb = np.where(a > 0, arr[..., :3] / np.where(a > 0, a, 1.0), 0.0)
    return np.concatenate([rgb, a], axis=-1)


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read a PNG (or another format pillow knows) as float32 ``(H, W, 3|4)`` in ``[0, 1]``, as stored.

    No colour conversion: sRGB values stay sRGB. Grey images are repeated to RGB,
    palette images expanded; 16-bit grey is scaled by 1/65535, 8-bit by 1/255.
    """
    from PIL import Image

    path = Path(path)
    _check_exists(path)
    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                grey = np.asarray(im, dtype=np.float64) / 65535.0
                return np.repeat(grey[..., None], 3, axis=-1).astype(np.float32)
            has_alpha = im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info)
            mode = "RGBA" if has_alpha else "RGB"
            arr = np.asarray(im if im.mode == mode else im.convert(mode))
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise DatasetError(path, None, f"not a readable image ({exc})") from None
    return arr.astype(np.float32) / np.float32(255.0)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read ``.exr`` with :func:`read_exr` and ``.png`` with :func:`read_png` (by suffix, any case)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".exr":
        return read_exr(path)
    if suffix == ".png":
        return read_png(path)
    raise DatasetError(path, None, f"unsupported image format {suffix or '(no suffix)'!r}: expected .exr or .png")
