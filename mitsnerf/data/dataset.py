"""A dataset directory: ``transforms_<split>.json`` files, their images, and mitsnerf's ``manifest.json``.

Everything handed out is linear RGB float32, whichever form the files take:

- **EXR** images are linear radiance, used as rendered: mitsnerf's EXRs already
  contain the background radiance, so they are not re-composited. An alpha
  channel is returned separately as ``Views.alpha``.
- **PNG** images (foreign NeRF-synthetic data: 8-bit sRGB RGBA) are decoded to
  linear (``color_space="srgb"``, the default; ``"linear"`` keeps the values),
  then an alpha channel is composited over the background colour ``b`` (linear,
  default white as in NeRF-synthetic), in linear space::

      rgb = srgb_to_linear(png_rgb) * a + b * (1 - a)

  (The NeRF code composites the sRGB values instead; the two agree where
  ``a`` is 0 or 1 and differ only on partly covered pixels.)

- **Premultiplied EXR** (a transforms file with ``"exr_alpha": "premultiplied"``: the
  medium-alone view of a mitsnerf dataset): RGB is radiance over a transparent background,
  composited over the same background colour ``b`` as PNG alpha: ``rgb + b * (1 - a)``.

**instant-ngp's single file**: a directory with one ``transforms.json`` (all frames, file paths
with their extension) and no ``transforms_<split>.json`` has two splits drawn from it by the
LLFF hold-out rule: frames ``0, 8, 16, ...`` (every :data:`HOLDOUT`-th, from the first) are
``test``, the others ``train``; rays pass through pixel centres (``0.5``, instant-ngp's rule)
unless the file says otherwise.

Frame ``file_path`` entries are resolved against the transforms file's
directory: ``file_path + ".exr"`` if that exists, else ``file_path + ".png"``,
else the path as given.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from mitsnerf.data.box import check_cameras_outside, resolve_box
from mitsnerf.data.images import over, read_image
from mitsnerf.data.transforms import read_json, read_transforms
from mitsnerf.errors import CLI, DatasetError, Words
from mitsnerf.math.box import Box
from mitsnerf.math.camera import Camera
from mitsnerf.math.color import srgb_to_linear

COLOR_SPACES = ("srgb", "linear")
_IMAGE_SUFFIXES = (".exr", ".png")


def true_grid_path(root: str | Path, name: str = "sigma_t") -> Path:
    """Where a mitsnerf dataset keeps its true grid ``name`` (``sigma_t``, ``albedo``): ``ROOT/volume/NAME.npy``,
    indexed ``[z, y, x]`` (docs/conventions.md).

    >>> true_grid_path("data/cloud-0123").as_posix()
    'data/cloud-0123/volume/sigma_t.npy'
    """
    return Path(root) / "volume" / f"{name}.npy"
#: instant-ngp's one transforms file, and the hold-out rule its splits are drawn by.
SINGLE_FILE = "transforms.json"
HOLDOUT = 8


def holdout_frames(split: str, n: int) -> list[int]:
    """Frame indices of ``split`` among the ``n`` frames of a single ``transforms.json``: every
    :data:`HOLDOUT`-th frame from the first is ``test``, the rest ``train``.

    >>> holdout_frames("test", 17), holdout_frames("train", 10)
    ([0, 8, 16], [1, 2, 3, 4, 5, 6, 7, 9])
    """
    return [i for i in range(n) if (i % HOLDOUT == 0) == (split == "test")]


@dataclass(frozen=True)
class Views:
    """The images of one split and their cameras.

    ``images``: ``(V, H, W, 3)`` float32 linear RGB. ``alpha``: ``(V, H, W)`` float32
    coverage, or ``None`` when not every image has an alpha channel. ``cameras``
    and ``names`` have one entry per view; a name is the image's file name without
    extension (``"r_000"``), or its relative path without extension
    (``"train/r_000"``) where file names alone would collide. ``pixel_center``:
    where rays pass through a pixel (see :func:`mitsnerf.data.transforms.read_transforms`).
    Arrays loaded by :class:`Dataset` are read-only (they are cached and shared).
    """

    images: np.ndarray
    alpha: np.ndarray | None
    cameras: tuple[Camera, ...]
    names: tuple[str, ...]
    pixel_center: float = 0.5

    def __post_init__(self) -> None:
        v = len(self.cameras)
        if self.images.ndim != 4 or self.images.shape[0] != v or self.images.shape[3] != 3:
            raise ValueError(f"images must have shape (V={v}, H, W, 3), got {self.images.shape}")
        if self.alpha is not None and self.alpha.shape != self.images.shape[:3]:
            raise ValueError(f"alpha must have shape {self.images.shape[:3]}, got {self.alpha.shape}")
        if len(self.names) != v:
            raise ValueError(f"{len(self.names)} names for {v} views")

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def height(self) -> int:
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        return int(self.images.shape[2])


def _resolve_image(base: Path, file_path: str) -> Path | None:
    given = base / file_path
    for candidate in (given.with_name(given.name + s) for s in _IMAGE_SUFFIXES):
        if candidate.is_file():
            return candidate
    return given if given.is_file() else None


def _view_names(file_paths: Sequence[str]) -> tuple[str, ...]:
    def strip(p: PurePosixPath) -> PurePosixPath:
        return p.with_suffix("") if p.suffix.lower() in _IMAGE_SUFFIXES else p

    rel = [strip(PurePosixPath(fp.replace("\\", "/"))) for fp in file_paths]
    short = [p.name for p in rel]
    if len(set(short)) == len(short):
        return tuple(short)
    return tuple(str(p) for p in rel)  # PurePosixPath drops a leading "./"


@dataclass(frozen=True)
class Dataset:
    """A dataset directory opened by :func:`load_dataset`; splits load lazily with :meth:`views`.

    ``manifest``: ``manifest.json`` (``{}`` for foreign data). ``background``: the
    manifest's ``"background"`` description, else ``{"type": "constant",
    "radiance": [r, g, b]}`` with the colour PNG alpha is composited over.
    ``pixel_center``: overrides the transforms files' (``None``: their rule).
    ``color_space``: how PNG values are read, ``"srgb"`` or ``"linear"``.
    ``png_background``: linear RGB that PNG alpha is composited over.
    ``box``: the scene box every field and score maps, and ``box_source`` where it came from
    (:mod:`mitsnerf.data.box`). ``words``: how its messages advise a setting (:class:`mitsnerf.errors.Words`:
    the command line's ``--box``, or the Python API's words when the API opened it).
    """

    root: Path
    manifest: dict
    background: dict
    box: Box
    box_source: str
    pixel_center: float | None = None
    color_space: str = "srgb"
    png_background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    words: Words = field(default=CLI, compare=False, repr=False)
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def splits(self) -> tuple[str, ...]:
        """Names of the available splits (``transforms_<split>.json`` files), sorted."""
        return _split_names(self.root)

    @property
    def single_file(self) -> bool:
        """instant-ngp's layout: one ``transforms.json``, split by :func:`holdout_frames`."""
        return _single_file(self.root)

    def transforms_path(self, split: str) -> Path:
        return self.root / (SINGLE_FILE if self.single_file else f"transforms_{split}.json")

    def views(self, split: str) -> Views:
        """Load (once; later calls return the cached result) the images and cameras of ``split``."""
        if split not in self._cache:
            self._cache[split] = self._load(split)
        return self._cache[split]

    def _load(self, split: str) -> Views:
        tpath = self.transforms_path(split)
        if not tpath.is_file() or split not in self.splits:
            raise DatasetError(tpath, None, f"no split {split!r} here; available: {', '.join(self.splits) or 'none'}")
        base = tpath.parent
        loaded: dict[str, tuple[Path, np.ndarray]] = {}

        def load(fp: str) -> tuple[Path, np.ndarray]:
            if fp not in loaded:
                path = _resolve_image(base, fp)
                if path is None:
                    raise FileNotFoundError(f"image not found: {base / fp} (tried .exr, .png and the path as given)")
                if self.manifest.get("format_version") is not None and path.suffix.lower() != ".exr":
                    raise FileNotFoundError(f"{base / fp}.exr: missing (a mitsnerf dataset's images are its linear "
                                            f"EXRs; {path.name} beside it is an 8-bit sRGB preview)")
                loaded[fp] = (path, read_image(path))
            return loaded[fp]

        def size_of(fp: str) -> tuple[int, int]:
            img = load(fp)[1]
            return int(img.shape[1]), int(img.shape[0])

        file_paths, cameras, meta = read_transforms(tpath, self.pixel_center, image_size_of=size_of)
        if self.single_file:
            file_paths, cameras = _held_out(tpath, split, file_paths, cameras)
        images: Any = None  # (V, H, W, 3) and (V, H, W), allocated at the first view's size
        alpha: Any = None
        all_alpha = True
        first: tuple[Path, int, int] | None = None
        for i, (fp, cam) in enumerate(zip(file_paths, cameras)):
            try:
                path, img = load(fp)
            except FileNotFoundError as exc:
                raise DatasetError(tpath, f"frames[{i}].file_path", str(exc)) from None
            loaded.pop(fp)  # the copy below is all we keep
            h, w = img.shape[:2]
            if first is None:
                first = (path, w, h)
                images = np.empty((len(cameras), h, w, 3), dtype=np.float32)
                alpha = np.empty((len(cameras), h, w), dtype=np.float32)
            elif (w, h) != first[1:]:
                raise DatasetError(path, None, f"image is {w}x{h} but {first[0].relative_to(base)} "
                                               f"in the same split is {first[1]}x{first[2]}")
            if (w, h) != (cam.width, cam.height):
                raise DatasetError(tpath, f"frames[{i}]", f"camera is {cam.width}x{cam.height} "
                                                          f"but image {path.relative_to(base)} is {w}x{h}")
            bad = ~np.isfinite(img)
            if bad.any():
                r, c, _ = np.argwhere(bad)[0]
                raise DatasetError(path, None, f"{int(bad.sum())} non-finite pixel values (NaN/inf), "
                                               f"first at row {r}, column {c}")
            images[i], a = self._to_linear(path, img, meta.get("exr_alpha") == "premultiplied")
            if a is None:
                all_alpha = False
            else:
                alpha[i] = a
        images.setflags(write=False)
        alpha.setflags(write=False)
        check_cameras_outside(self.box, [c.origin for c in cameras], tpath, self.box_source, self.words)
        return Views(images, alpha if all_alpha else None, tuple(cameras), _view_names(file_paths),
                     float(meta["pixel_center"]))

    def _to_linear(
        self, path: Path, img: np.ndarray, premultiplied: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Linear RGB ``(H, W, 3)`` and alpha ``(H, W)`` or None, per the module's rules."""
        rgb = img[..., :3]
        a = img[..., 3] if img.shape[2] == 4 else None
        if path.suffix.lower() == ".exr":
            if premultiplied and a is not None:
                rgb = over(rgb, a[..., None], np.asarray(self.png_background, dtype=np.float32))
            return rgb, a
        if self.color_space == "srgb":
            rgb = srgb_to_linear(rgb)
        if a is not None:
            rgb = over(rgb, a[..., None], np.asarray(self.png_background, dtype=np.float32), premultiplied=False)
        return rgb, a


def _held_out(tpath: Path, split: str, file_paths: list[str], cameras: list) -> tuple[list[str], list]:
    """The frames of ``split`` in a single ``transforms.json`` (:func:`holdout_frames`)."""
    keep = holdout_frames(split, len(cameras))
    if not keep:
        raise DatasetError(tpath, "frames", f"{len(cameras)} frame(s): too few to hold out a {split} split "
                                            f"(every {HOLDOUT}th frame is a test frame, the rest train)")
    return [file_paths[i] for i in keep], [cameras[i] for i in keep]


def _split_names(root: Path) -> tuple[str, ...]:
    prefix, suffix = "transforms_", ".json"
    names = tuple(sorted(p.name[len(prefix):-len(suffix)] for p in root.glob(f"{prefix}*{suffix}")
                         if p.is_file() and len(p.name) > len(prefix) + len(suffix)))
    return ("test", "train") if not names and (root / SINGLE_FILE).is_file() else names


def _single_file(root: Path) -> bool:
    return (root / SINGLE_FILE).is_file() and _split_names(root) == ("test", "train") and not (
        root / "transforms_train.json").is_file()


def _background_rgb(background: Any) -> tuple[float, float, float]:
    if background is None:
        return (1.0, 1.0, 1.0)
    try:
        arr = np.asarray(background, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.full(1, np.nan)
    rgb = np.full(3, arr) if arr.ndim == 0 else arr
    if rgb.shape != (3,) or not np.all(np.isfinite(rgb)) or np.any(rgb < 0):
        raise ValueError(f"background must be a finite non-negative number or RGB triple, got {background!r}")
    return (float(rgb[0]), float(rgb[1]), float(rgb[2]))


def load_dataset(
    root: str | os.PathLike,
    *,
    box: Box | None = None,
    background: float | Sequence[float] | None = None,
    pixel_center: float | None = None,
    color_space: str | None = None,
    words: Words = CLI,
) -> Dataset:
    """Open a dataset directory; images load lazily, per split, with :meth:`Dataset.views`.

    ``box``: the scene box, overriding what the data says (:mod:`mitsnerf.data.box`).
    ``background``: linear colour (a number or RGB) that PNG alpha is composited
    over; default white. It does not change EXR images, which are used as
    rendered. ``pixel_center``: overrides the transforms files (``None``: the rule
    of :func:`~mitsnerf.data.transforms.read_transforms`). ``color_space``: how PNG
    values are read: ``"srgb"`` (default, decoded to linear) or ``"linear"``.
    ``words``: how its messages advise a setting (:class:`mitsnerf.errors.Words`).
    Raises :class:`DatasetError` if ``root`` is not a directory with at least one
    ``transforms_*.json`` or has a malformed ``manifest.json``.
    """
    root = Path(root)
    if not root.exists():
        raise DatasetError(root, None, "dataset directory not found")
    if not root.is_dir():
        raise DatasetError(root, None, "not a directory")
    space = "srgb" if color_space is None else color_space
    if space not in COLOR_SPACES:
        raise ValueError(f"color_space must be one of {COLOR_SPACES}, got {color_space!r}")
    if pixel_center is not None and not math.isfinite(pixel_center):
        raise ValueError(f"pixel_center must be finite, got {pixel_center!r}")
    png_bg = _background_rgb(background)

    manifest: dict = {}
    manifest_path = root / "manifest.json"
    if manifest_path.exists():
        manifest = read_json(manifest_path)
        if not isinstance(manifest, dict):
            raise DatasetError(manifest_path, None, f"must hold a JSON object, got {type(manifest).__name__}")
    bg_desc = manifest.get("background")
    if bg_desc is None:
        bg_desc = {"type": "constant", "radiance": list(png_bg)}
    elif not isinstance(bg_desc, dict):
        raise DatasetError(manifest_path, "background", f"must be an object, got {type(bg_desc).__name__}")

    splits = _split_names(root)
    if not splits:
        raise DatasetError(root, None, "no transforms_*.json or transforms.json: not a NeRF-synthetic or "
                                       "instant-ngp style dataset")
    tpath = root / (
        SINGLE_FILE if _single_file(root) else f"transforms_{'train' if 'train' in splits else splits[0]}.json"
    )
    top = read_json(tpath)
    if not isinstance(top, dict):
        raise DatasetError(tpath, None, f"must hold a JSON object, got {type(top).__name__}")
    resolved = resolve_box(box, top, tpath, manifest, manifest_path, words)
    return Dataset(root, manifest, bg_desc, resolved.box, resolved.source, pixel_center, space, png_bg, words)
