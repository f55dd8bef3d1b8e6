"""Novel views of a trained run: any camera or an orbit, with depth and opacity maps (``mitsnerf render``).

Cameras (world is Z-up, cameras look at ``look_at``, default the box centre):

- a dataset view: ``split`` and ``index`` (default: the first test view);
- every view of a split: ``split`` without ``index``, each named as the dataset's frame (``r_000``),
  so that the folder scores as it is (``mitsnerf score DATASET OUT``);
- a point: ``look_from = (x, y, z)``;
- an orbit of ``N`` cameras around the vertical axis through ``look_at``, at the reference
  view's distance and elevation unless given: camera ``k`` sits at azimuth
  ``phi_k = phi_0 + 360 k / N`` degrees, position
  ``look_at + r (cos e cos phi_k, cos e sin phi_k, sin e)``.

Field of view and image size default to the reference view's (the dataset view above).

Files written for a view named ``STEM`` (orbit frames are ``orbit/frame_000`` ...; depth and
opacity go apart from the images, so that a folder of renders scores as it is)::

    STEM.exr            linear RGB, the full image over the background; alpha = opacity 1 - T_N,
                        its header saying so (mitsnerf:alpha = opacity)
    STEM.png            sRGB preview
    depth/STEM.exr      D = sum_i w_i t_i / (1 - T_N): expected distance from the camera at which
                        light is absorbed or scattered, given it is (0 where 1 - T_N < 1e-4);
                        the same value in R, G, B
    depth/STEM.png      D mapped through matplotlib's 'viridis' from the nearest to the farthest
                        pixel with opacity > 0.01 (others black)
    opacity/STEM.exr    1 - T_N in R, G, B
    opacity/STEM.png    the same, grey, linear (not sRGB-encoded)

(for ``orbit/frame_000``: ``orbit/depth/frame_000.exr`` ...), plus ``render.json``, a list with one
entry per call that rendered into the folder (every view's camera, the run, the variant, versions
and commit), and for an
orbit also ``orbit.gif`` (pillow) and, only if ``imageio-ffmpeg`` is installed, ``orbit.mp4``.
All files are written atomically.
"""

from __future__ import annotations

import importlib.util
import io
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mitsnerf import env
from mitsnerf.data.atomic import atomic_path, atomic_write_bytes, atomic_write_json
from mitsnerf.data.images import write_exr, write_png
from mitsnerf.math.camera import Camera
from mitsnerf.math.camera import look_at as look_at_matrix

MIN_OPACITY = 1e-4
"""Depth is reported only where the opacity exceeds this."""
MAX_PIXELS = 4096 * 4096
"""The most pixels one rendered view may have (``--size``)."""


def orbit_cameras(
    n: int,
    radius: float,
    elevation_deg: float,
    width: int,
    height: int,
    fov_x_deg: float,
    target: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
    start_azimuth_deg: float = 0.0,
) -> list[Camera]:
    """``n`` cameras evenly spaced in azimuth around the vertical axis through ``target``.

    >>> cams = orbit_cameras(4, 2.0, 0.0, 8, 8, 40.0)
    >>> [c.origin.round(6).tolist() for c in cams[:2]]
    [[2.0, 0.0, 0.0], [0.0, 2.0, 0.0]]
    """
    if n < 1:
        raise ValueError(f"orbit: needs at least 1 camera, got {n}")
    if not radius > 0:
        raise ValueError(f"radius: must be > 0, got {radius}")
    e = math.radians(elevation_deg)
    centre = np.asarray(target, dtype=np.float64)
    cams = []
    for k in range(n):
        phi = math.radians(start_azimuth_deg + 360.0 * k / n)
        pos = centre + radius * np.array([math.cos(e) * math.cos(phi), math.cos(e) * math.sin(phi), math.sin(e)])
        cams.append(Camera.from_fov(look_at_matrix(pos, centre), width, height, fov_x_deg))
    return cams


def normalised_depth(depth: np.ndarray, opacity: np.ndarray) -> np.ndarray:
    """``sum_i w_i t_i / (1 - T_N)`` where the opacity exceeds :data:`MIN_OPACITY`, else 0.

    >>> normalised_depth(np.array([0.5, 1e-6]), np.array([0.25, 1e-6])).tolist()
    [2.0, 0.0]
    """
    seen = opacity > MIN_OPACITY
    return np.where(seen, depth / np.where(seen, opacity, 1.0), 0.0).astype(np.float32)


def depth_colours(depth: np.ndarray, opacity: np.ndarray, threshold: float = 0.01) -> np.ndarray:
    """(H, W, 3) display colours in [0, 1]: viridis from near to far where opacity > threshold, else black."""
    from matplotlib import colormaps

    seen = opacity > threshold
    out = np.zeros((*depth.shape, 3), dtype=np.float32)
    if seen.any():
        near, far = float(depth[seen].min()), float(depth[seen].max())
        x = (depth - near) / max(far - near, 1e-9)
        out[seen] = colormaps["viridis"](np.clip(x[seen], 0.0, 1.0))[:, :3]
    return out


def _grey3(a: np.ndarray) -> np.ndarray:
    return np.repeat(np.asarray(a, dtype=np.float32)[..., None], 3, axis=-1)


def _to_uint8(display: np.ndarray) -> np.ndarray:
    return (np.clip(display, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_display_png(path: Path, display: np.ndarray) -> None:
    """Write already display-encoded values in [0, 1] (H, W, 3) as an 8-bit PNG, atomically."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(_to_uint8(display)).save(buf, format="PNG")
    atomic_write_bytes(path, buf.getvalue())


def write_views(out_dir: Path, stem: str, rendered) -> list[Path]:
    """The six files of one rendered view (see the module docstring); returns their paths."""
    image = Path(out_dir) / stem
    folder, name = image.parent, image.name
    for sub in (folder / "depth", folder / "opacity"):
        sub.mkdir(parents=True, exist_ok=True)
    depth = normalised_depth(rendered.depth, rendered.opacity)
    files = {
        folder / f"{name}.exr": lambda p: write_exr(p, np.concatenate([rendered.rgb, rendered.opacity[..., None]],
                                                                      axis=-1), alpha="opacity"),
        folder / f"{name}.png": lambda p: write_png(p, rendered.rgb),
        folder / "depth" / f"{name}.exr": lambda p: write_exr(p, _grey3(depth)),
        folder / "depth" / f"{name}.png": lambda p: write_display_png(p, depth_colours(depth, rendered.opacity)),
        folder / "opacity" / f"{name}.exr": lambda p: write_exr(p, _grey3(rendered.opacity)),
        folder / "opacity" / f"{name}.png": lambda p: write_display_png(p, _grey3(rendered.opacity)),
    }
    for path, write in files.items():
        write(path)
    return list(files)


def write_gif(path: Path, frames: Sequence[np.ndarray], fps: float = 12.0) -> None:
    """An animated, looping GIF of display frames (H, W, 3) in [0, 1], atomically."""
    from PIL import Image

    images = [Image.fromarray(_to_uint8(f)) for f in frames]
    buf = io.BytesIO()
    images[0].save(buf, format="GIF", save_all=True, append_images=images[1:],
                   duration=max(int(round(1000.0 / fps)), 10), loop=0)
    atomic_write_bytes(path, buf.getvalue())


def mp4_available() -> bool:
    """Whether ``imageio-ffmpeg`` (optional) is installed."""
    return importlib.util.find_spec("imageio_ffmpeg") is not None


def write_mp4(path: Path, frames: Sequence[np.ndarray], fps: float = 12.0) -> None:
    """An H.264 MP4 of display frames through ``imageio-ffmpeg`` (padded to even sizes), atomically."""
    import imageio_ffmpeg

    first = _to_uint8(frames[0])
    h, w = first.shape[:2]
    H, W = h + h % 2, w + w % 2
    with atomic_path(path) as tmp:
        writer = imageio_ffmpeg.write_frames(str(tmp), (W, H), fps=fps, macro_block_size=1, output_params=["-f", "mp4"])
        writer.send(None)
        for f in frames:
            img = np.zeros((H, W, 3), dtype=np.uint8)
            img[:h, :w] = _to_uint8(f)
            writer.send(np.ascontiguousarray(img))
        writer.close()


@dataclass(frozen=True)
class ViewRequest:
    """Which cameras ``render_run`` renders; unset values come from the reference view."""

    split: str | None = None
    index: int | None = None
    """None: the first view, or with ``split`` given, every view of it."""
    look_from: tuple[float, float, float] | None = None
    look_at: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fov: float | None = None
    size: tuple[int, int] | None = None
    orbit: int = 0
    elevation: float | None = None
    radius: float | None = None
    fps: float = 12.0
    footprint: int | None = None
    """Rays per pixel side (None: the run's evaluation footprint)."""


def _reference(dataset, split: str | None, index: int):
    from mitsnerf.errors import UsageError

    splits = dataset.splits
    if split is not None and split not in splits:
        raise UsageError("--split", f"the dataset has no split {split!r}; its splits: {', '.join(splits)}")
    split = split or ("test" if "test" in splits else splits[0])
    views = dataset.views(split)
    if not 0 <= index < len(views):
        raise UsageError("--index", f"split {split!r} has views 0..{len(views) - 1}, got {index}")
    return views.cameras[index], views.pixel_center, f"{split}_{index:03d}"


def check_request(request: ViewRequest) -> None:
    """A :class:`~mitsnerf.errors.UsageError` naming the option for a request no camera can honour:
    ``look_from`` at ``look_at`` (no direction to look in), or a ``size`` over :data:`MAX_PIXELS`."""
    from mitsnerf.errors import UsageError

    if request.look_from is not None and np.allclose(request.look_from, request.look_at, rtol=0.0, atol=1e-9):
        shown = " ".join(f"{v:g}" for v in request.look_from)
        raise UsageError("--look-from", f"must differ from --look-at, the point looked at; both are {shown}")
    if request.size is not None and request.size[0] * request.size[1] > MAX_PIXELS:
        raise UsageError("--size", f"at most {MAX_PIXELS} pixels a view (4096 x 4096), got "
                                   f"{request.size[0]} x {request.size[1]}")


def cameras_for(request: ViewRequest, dataset) -> tuple[list[Camera], list[str], float]:
    """The cameras of ``request`` with their file stems, and the pixel-centre convention."""
    check_request(request)
    ref, pixel_center, ref_name = _reference(dataset, request.split, request.index or 0)
    width, height = request.size or (ref.width, ref.height)
    fov = request.fov or ref.fov_x_deg
    if request.split is not None and request.index is None and not request.orbit and request.look_from is None:
        views = dataset.views(request.split)
        cams = [c if request.size is None and request.fov is None else Camera.from_fov(c.c2w, width, height, fov)
                for c in views.cameras]
        return cams, list(views.names), pixel_center
    target = np.asarray(request.look_at, dtype=np.float64)
    if request.orbit:
        offset = ref.origin - target
        radius = request.radius or float(np.linalg.norm(offset))
        elevation = request.elevation
        if elevation is None:
            elevation = math.degrees(math.asin(np.clip(offset[2] / np.linalg.norm(offset), -1.0, 1.0)))
        start = math.degrees(math.atan2(offset[1], offset[0]))
        cams = orbit_cameras(request.orbit, radius, elevation, width, height, fov, target, start)
        return cams, [f"orbit/frame_{k:03d}" for k in range(len(cams))], pixel_center
    if request.look_from is not None:
        cam = Camera.from_fov(look_at_matrix(request.look_from, target), width, height, fov)
        return [cam], ["view"], pixel_center
    if request.size is None and request.fov is None:
        return [ref], [ref_name], pixel_center
    return [Camera.from_fov(ref.c2w, width, height, fov)], [ref_name], pixel_center


def read_calls(path: Path) -> list:
    """The entries of the ``render.json`` at ``path`` (one per call that rendered into its folder; an older file's
    one record is one entry); a ``ValueError`` saying why when it is not such a record."""
    import json

    try:
        calls = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"not a render record ({exc})") from None
    calls = [calls] if isinstance(calls, dict) else calls
    if not isinstance(calls, list) or not all(isinstance(c, dict) for c in calls):
        raise ValueError("not a render record (a JSON list of objects)")
    return calls


def previous_calls(path: Path) -> list:
    """The entries of an existing ``render.json`` (:func:`read_calls`), ``[]`` without one; an
    :class:`~mitsnerf.errors.OutputError` when it is not such a record."""
    from mitsnerf.errors import OutputError

    if not path.exists():
        return []
    try:
        return read_calls(path)
    except ValueError as exc:
        raise OutputError(path, None, f"{exc}; move it away to render here") from None


def render_run(run_dir: Path, out_dir: Path, request: ViewRequest = ViewRequest(), progress: bool = True) -> list[Path]:
    """Render the views of ``request`` from the run in ``run_dir`` into ``out_dir`` (not inside the run's dataset,
    which its files would change); returns the files. ``progress``: a bar on a terminal, and a line on stderr
    before and after (:func:`mitsnerf.outputs.progress_log`)."""
    from tqdm.auto import tqdm

    from mitsnerf.math.color import linear_to_srgb
    from mitsnerf.outputs import progress_log
    from mitsnerf.runs.directory import check_outside_dataset
    from mitsnerf.runs.fit import load_run

    model, dataset, config = load_run(Path(run_dir))
    check_outside_dataset(Path(out_dir), Path(dataset.root), what="renders", example="renders/NAME")
    cams, stems, pixel_center = cameras_for(request, dataset)
    footprint = request.footprint or int((config.get("eval") or {}).get("footprint", 1))
    out_dir = Path(out_dir)
    calls = previous_calls(out_dir / "render.json")
    out_dir.mkdir(parents=True, exist_ok=True)
    written, frames = [], []
    log, start = progress_log(progress), time.perf_counter()
    log(f"[render] {len(cams)} views of {cams[0].width}x{cams[0].height} at footprint {footprint} from {run_dir} "
        f"-> {out_dir} ...")
    for cam, stem in tqdm(
        list(zip(cams, stems)),
        desc="render",
        unit="view",
        disable=True if not progress or len(cams) < 2 else None,
        leave=False,
    ):
        rendered = model.render_view(cam, pixel_center=pixel_center, footprint=footprint)
        written += write_views(out_dir, stem, rendered)
        frames.append(linear_to_srgb(np.clip(rendered.rgb, 0.0, 1.0)))
    atomic_write_json(out_dir / "render.json", [*calls, {
        "run": str(run_dir),
        "views": [{"name": stem, "transform_matrix": cam.c2w.tolist(), "w": cam.width, "h": cam.height,
                   "fl_x": cam.fl_x, "fl_y": cam.fl_y, "cx": cam.cx, "cy": cam.cy} for cam, stem in zip(cams, stems)],
        "pixel_center": pixel_center,
        "footprint": footprint,
        "provenance": env.provenance(),
    }])
    written.append(out_dir / "render.json")
    log(f"[render] {len(cams)} views in {time.perf_counter() - start:.1f} s")
    if request.orbit:
        write_gif(out_dir / "orbit.gif", frames, request.fps)
        written.append(out_dir / "orbit.gif")
        if mp4_available():
            write_mp4(out_dir / "orbit.mp4", frames, request.fps)
            written.append(out_dir / "orbit.mp4")
    return written
