"""Renders from any tool, scored against a dataset's test views as a benchmark cell is (``mitsnerf score``).

**Images.** ``RENDERS`` is a folder of ``.png`` and ``.exr`` files (other files are ignored; with
``fmt`` only that kind is read). Both are composited over what each pixel of the dataset sees
behind the medium (its ``background``: a constant, or the environment map averaged over the pixel)
where they have an alpha channel below 1. PNG is sRGB with straight alpha, decoded to linear,
``rgb * a + B * (1 - a)``. An EXR's alpha means what its header's ``mitsnerf:alpha`` says
(:data:`mitsnerf.data.images.ALPHA_ATTRIBUTE`, written into every RGBA EXR mitsnerf writes):
``premultiplied`` ``rgb + B * (1 - a)``, ``straight`` ``rgb * a + B * (1 - a)``, or ``opacity``
(mitsnerf's renders: the RGB is the full image already, used as it is). ``exr_alpha`` overrides
the file: ``"premultiplied"``, ``"straight"`` or ``"ignore"`` (the RGB as it is). An EXR that
does not say, with alpha below 1, is taken as premultiplied (OpenEXR's rule) only when the data
agree, every pixel of alpha 0 black; else (its RGB holds a background already, or no pixel is
transparent) it is refused with a line naming ``--exr-alpha`` rather than guessed. Every image
must have the test frame's size and finite values.

**A run** (a folder with ``config.json`` and ``test/``, :func:`read_run`) stands for its ``test/`` renders and
is scored as its own evaluation scored them: at its footprint (``config.json``'s ``eval.footprint``), named
after its method, with the density figures of its ``metrics.json`` (what its model's density scored, the
figures the benchmark shows), unless ``footprint``, ``name`` or ``density`` say otherwise; its oracle is the
cached one whose medium PSNR the run recorded, where there is one. A run trained on another dataset is
refused (:func:`mitsnerf.runs.fit.check_same_dataset`: the same manifest hash, else the same path), before
anything is read. Where one stem has both an ``.exr`` that says its alpha (mitsnerf's) and a ``.png`` (its sRGB
preview), the EXR is scored.

**Matching** (:func:`match_renders`), against the test frames' names (``r_000``, ...):

1. *by file name*: when any file's stem is a test frame's name, every test frame must have
   exactly one such file and no other image may be there;
2. *by order*: when no stem is a frame's name, there must be as many images as test frames;
   each stem must hold a frame number (its last run of digits, e.g. ``00007`` in
   ``frame_00007``), all different, and the images in increasing number are the test frames in
   the order of ``transforms_test.json``.

Anything else is refused: two files with one stem (``r_000.png`` and ``r_000.exr``: choose with
``fmt``), a frame without its render, an image named after no frame, a wrong count, a name
without a number or two with the same number.

**Density** (:func:`read_density`): ``sigma_t`` on a grid over the dataset's box, indexed
``[z, y, x]``, as ``.npy`` (``(R, R, R)``, or ``(R, R, R, 3)`` for one density per colour channel) or
Mitsuba ``.vol`` (one channel or three; its bounding box must be the dataset's), looked up trilinearly as
Mitsuba's ``gridvolume``.

**Oracle** (:func:`read_oracle`): the dataset's cached emission-absorption oracle
(``DATASET/oracle/<key>/``, :mod:`mitsnerf.oracle.cache`, computed by ``mitsnerf bench``), its
scores at the renders' footprint (1: one ray through each pixel centre, what most tools render;
``K``: the mean of ``K x K`` rays over the pixel; a folder ``mitsnerf render`` wrote: the footprint its
``render.json`` records, :func:`rendered_footprint`). Of several cached oracles, the one whose medium PSNR a
run recorded, else the one with the default settings is taken. None cached: "no oracle", naming what computes
one (:func:`no_oracle`); ``compute_oracle`` computes it then and there (:func:`find_oracle`).

**Noise floor** (``noise_floor_*`` of the metrics, ``noise_floor_of`` says which): renders that are
all PNG are held against the floor of their format, :func:`mitsnerf.scoring.images.png_noise_floor` (the
second ground-truth render quantised to 8-bit sRGB: the dataset's own ``test_ref`` scores exactly
it as PNG), others against the manifest's.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.data.dataset import Dataset
from mitsnerf.data.images import ALPHA_ATTRIBUTE, over, read_exr_alpha, read_image
from mitsnerf.errors import CLI, DatasetError, UsageError, Words
from mitsnerf.math.box import Box
from mitsnerf.math.color import srgb_to_linear
from mitsnerf.scoring.density import true_density
from mitsnerf.scoring.images import png_noise_floor
from mitsnerf.scoring.reference import Reference, load_reference
from mitsnerf.scoring.views import density_figures, score_views

FORMATS = ("png", "exr")
#: How an EXR render's alpha is applied (module docstring).
EXR_ALPHA = ("premultiplied", "straight", "ignore")
_NUMBER = re.compile(r"(\d+)(?!.*\d)")


def is_run(folder: Path) -> bool:
    """Whether ``folder`` is a run directory: it has ``config.json`` and ``test/``."""
    return (Path(folder) / "config.json").is_file() and (Path(folder) / "test").is_dir()


def renders_folder(folder: Path) -> Path:
    """``folder``, or its ``test/`` when it is a run (:func:`is_run`)."""
    folder = Path(folder)
    return folder / "test" if is_run(folder) else folder


@dataclass(frozen=True)
class RunRenders:
    """A run directory's test renders and what the run says of them (:func:`read_run`)."""

    path: Path
    config: dict
    """``config.json``: method, settings, the dataset it trained on."""
    metrics: dict
    """``metrics.json`` (empty when missing)."""
    footprint: int
    """The rays per pixel side it rendered its test views with (``eval.footprint``)."""

    @property
    def method(self) -> str:
        return str(self.config.get("method"))

    @property
    def seed(self) -> int:
        return int((self.config.get("train") or {}).get("seed", 0))


def read_run(folder: Path) -> RunRenders | None:
    """The run in ``folder`` (None when it is not one, :func:`is_run`); a malformed ``config.json`` or
    ``metrics.json`` is a DatasetError (a SpecError for a bad ``eval`` field) naming the file."""
    from mitsnerf.config import from_saved
    from mitsnerf.data.transforms import read_json
    from mitsnerf.train.evaluate import EvalConfig

    def json_object(path: Path) -> dict:
        data = read_json(path) if path.is_file() else {}
        if not isinstance(data, dict):
            raise DatasetError(path, None, f"must be a JSON object, got {type(data).__name__}")
        return data

    folder = Path(folder)
    if not is_run(folder):
        return None
    config = json_object(folder / "config.json")
    eval_config = from_saved(EvalConfig, dict(config.get("eval") or {}), source=folder / "config.json", prefix="eval.")
    return RunRenders(folder, config, json_object(folder / "metrics.json"), eval_config.footprint)


def _preview_pair(a: Path, b: Path) -> Path | None:
    """The EXR of a stem's ``.exr`` and ``.png`` when the EXR says its alpha (mitsnerf's; the PNG its preview)."""
    exr, png = sorted((a, b), key=lambda p: p.suffix.lower() != ".exr")
    if exr.suffix.lower() == ".exr" and png.suffix.lower() == ".png" and read_exr_alpha(exr) is not None:
        return exr
    return None


def image_files(folder: Path, fmt: str | None = None, words: Words = CLI) -> dict[str, Path]:
    """``{stem: path}`` of the ``.png``/``.exr`` files directly in ``folder`` (only ``fmt`` if given).

    Two files with the same stem are refused: which one is meant is not for mitsnerf to guess,
    unless they are mitsnerf's EXR and its PNG preview (:func:`_preview_pair`).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(folder, None, "renders folder not found" if not folder.exists() else "not a folder")
    kinds = (fmt,) if fmt else FORMATS
    found: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if not path.is_file() or path.suffix.lower().lstrip(".") not in kinds:
            continue
        if path.stem in found and (exr := _preview_pair(found[path.stem], path)) is not None:
            found[path.stem] = exr
            continue
        if path.stem in found:
            raise DatasetError(folder, None, f"both {found[path.stem].name} and {path.name}: "
                                             f"say which to score ({words(format='png')} or "
                                             f"{words(format='exr')})")
        found[path.stem] = path
    if not found:
        raise DatasetError(folder, None, f"no {' or '.join('.' + k for k in kinds)} images")
    return found


def match_renders(folder: Path, names: Sequence[str], fmt: str | None = None,
                  words: Words = CLI) -> tuple[list[Path], str]:
    """The render of each test frame ``names[i]`` and the rule that matched them, ``"name"`` or ``"order"``.

    >>> import tempfile; d = Path(tempfile.mkdtemp())
    >>> for n in ("frame_10.png", "frame_9.png"): _ = (d / n).write_bytes(b"")
    >>> [p.name for p in match_renders(d, ["r_000", "r_001"])[0]]
    ['frame_9.png', 'frame_10.png']
    """
    folder = Path(folder)
    files = image_files(folder, fmt, words)
    if set(files) & set(names):
        missing = [n for n in names if n not in files]
        if missing:
            raise DatasetError(folder, None, f"no render for test frame {missing[0]} ({len(names) - len(missing)} of "
                                             f"{len(names)} frames have one; renders are matched by file name)")
        extra = sorted(set(files) - set(names))
        if extra:
            raise DatasetError(files[extra[0]], None, "named after no test frame (renders are matched by file name; "
                                                      f"the test frames are {names[0]} .. {names[-1]})")
        return [files[n] for n in names], "name"
    if len(files) != len(names):
        raise DatasetError(folder, None, f"{len(files)} images for {len(names)} test frames (matched by order: "
                                         f"no file is named after a test frame such as {names[0]})")
    numbered: dict = {}
    for stem, path in files.items():
        found = _NUMBER.search(stem)
        if found is None:
            raise DatasetError(path, None, "no frame number in the name, so the images cannot be put in order "
                                           f"(or name them after the test frames, {names[0]} ..)")
        number = int(found.group(1))
        if number in numbered:
            raise DatasetError(path, None, f"frame number {number} again ({numbered[number].name})")
        numbered[number] = path
    return [numbered[k] for k in sorted(numbered)], "order"


def exr_alpha_of(path: Path, img: np.ndarray, override: str | None = None, words: Words = CLI) -> str:
    """How the alpha of the RGBA EXR ``img`` (read from ``path``) applies: ``override`` if given, else what
    the file says (``opacity`` is ``"ignore"``), else ``"premultiplied"`` where every pixel of alpha 0 is
    black; a :class:`~mitsnerf.errors.DatasetError` naming ``--exr-alpha`` otherwise (module docstring).

    >>> exr_alpha_of(Path("x.exr"), np.array([[[0.0, 0.0, 0.0, 0.0], [0.3, 0.3, 0.3, 0.5]]]))
    'premultiplied'
    """
    if override is not None:
        return override
    said = read_exr_alpha(path) if path.exists() else None
    if said is not None:
        return "ignore" if said == "opacity" else said
    clear = img[..., 3] <= 0
    if clear.any() and not np.any(img[..., :3][clear]):
        return "premultiplied"
    why = "its RGB is not black where alpha is 0 (a background already?)" if clear.any() else "no pixel has alpha 0"
    raise DatasetError(path, "alpha", f"below 1, the file does not say what it means (no {ALPHA_ATTRIBUTE} in its "
                                      f"header) and {why}: say it with {words.name('exr_alpha')} premultiplied, "
                                      "straight or ignore")


def _to_linear(path: Path, img: np.ndarray, background: np.ndarray | None, exr_alpha: str | None = None,
               words: Words = CLI) -> np.ndarray:
    """Linear RGB of one render (module docstring): EXR by :func:`exr_alpha_of`, PNG sRGB with straight
    alpha, each composited over ``background`` by its alpha when it has one."""
    exr = path.suffix.lower() == ".exr"
    rgb = img[..., :3] if exr else srgb_to_linear(img[..., :3])
    if img.shape[2] != 4 or background is None:  # no alpha, or alpha 1 everywhere
        return rgb
    mode = exr_alpha_of(path, img, exr_alpha, words) if exr else "straight"
    if mode == "ignore":
        return rgb
    return over(rgb, img[..., 3:4], background, premultiplied=mode == "premultiplied")


def read_renders(dataset: Dataset, folder: Path, fmt: str | None = None, split: str = "test",
                 exr_alpha: str | None = None) -> tuple[np.ndarray, list[Path], str]:
    """The renders of ``split``'s views as linear RGB ``(V, H, W, 3)``, their files and the matching rule
    (``exr_alpha``: None, each EXR as its file says). Messages advise settings in the dataset's words
    (:attr:`mitsnerf.data.dataset.Dataset.words`)."""
    words = dataset.words
    if exr_alpha is not None and exr_alpha not in EXR_ALPHA:
        raise UsageError(words.name("exr_alpha"), f"must be one of {', '.join(EXR_ALPHA)}, got {exr_alpha!r}")
    from mitsnerf.render.background import make_background, pixel_background

    views = dataset.views(split)
    paths, rule = match_renders(Path(folder), views.names, fmt, words)
    images = np.empty(views.images.shape, dtype=np.float32)
    background = None
    for i, (path, name) in enumerate(zip(paths, views.names)):
        img = read_image(path)
        h, w = img.shape[:2]
        if (w, h) != (views.width, views.height):
            raise DatasetError(path, None, f"image is {w}x{h}, test frame {name} is {views.width}x{views.height}")
        bad = ~np.isfinite(img)
        if bad.any():
            r, c, _ = np.argwhere(bad)[0]
            raise DatasetError(
                path, None, f"{int(bad.sum())} non-finite pixel values (NaN/inf), first at row {r}, column {c}"
            )
        if background is None and img.shape[2] == 4 and (img[..., 3] < 1).any():
            bg = make_background(dataset.background, dataset.root)
            background = pixel_background(bg, views.cameras, views.pixel_center).astype(np.float32)
        images[i] = _to_linear(path, img, None if background is None else background[i], exr_alpha, words)
    return images, paths, rule


def read_density(path: Path, box: Box) -> np.ndarray:
    """A density grid ``(Z, Y, X)`` (or ``(Z, Y, X, 3)``, per colour) float32 over ``box`` from ``.npy`` or ``.vol``
    (module docstring)."""
    from mitsnerf.data.arrays import read_npy
    from mitsnerf.data.vol import read_vol

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".vol":
        data, lo, hi = read_vol(path)
        if data.shape[3] not in (1, 3):
            raise DatasetError(path, "channels", f"a density has 1 channel (3: one per colour), got {data.shape[3]}")
        if not np.allclose([lo, hi], box.to_list(), rtol=1e-5, atol=1e-5):
            raise DatasetError(path, "bbox", f"{[list(lo), list(hi)]} is not the dataset's box {box.to_list()}")
        grid = data[..., 0] if data.shape[3] == 1 else data
    elif suffix == ".npy":
        grid = read_npy(path, "density grid")
        grid = grid[..., 0] if grid.ndim == 4 and grid.shape[3] == 1 else grid
    else:
        raise DatasetError(path, None, f"unsupported density format {suffix or '(no suffix)'!r}: .npy or .vol")
    if not (grid.ndim == 3 or (grid.ndim == 4 and grid.shape[3] == 3)) or min(grid.shape) < 1:
        raise DatasetError(path, None, f"a density grid is (Z, Y, X) or (Z, Y, X, 3), got shape {grid.shape}")
    if not np.all(np.isfinite(grid)) or grid.min() < 0:
        raise DatasetError(path, None, "density values must be finite and >= 0")
    return np.ascontiguousarray(grid, dtype=np.float32)


def read_oracle(dataset: Dataset, footprint: int = 1, recorded: float | None = None):
    """``(oracle, source)``: the cached :class:`mitsnerf.oracle.cache.Oracle` of ``dataset`` with scores at
    ``footprint`` (the one whose medium PSNR there is ``recorded``, what a run scored against, first; then the
    default settings'), and where it is; ``(None, "no oracle ...")`` without one."""
    from mitsnerf.config import to_dict
    from mitsnerf.oracle.cache import ORACLE_DIR, OracleConfig, load_oracle

    found = [o for o in (load_oracle(p.parent) for p in sorted((Path(dataset.root) / ORACLE_DIR).glob("*/oracle.json")))
             if o is not None and f"footprint_{int(footprint)}" in o.scores]
    if not found:
        return None, no_oracle(dataset, footprint)
    default = to_dict(OracleConfig())
    same = [o for o in found if recorded is not None and o.metrics(footprint).get("psnr_test_medium") == recorded]
    oracle = next(iter(same), next((o for o in found if o.info.get("config") == default), found[0]))
    return oracle, f"oracle {oracle.path} at footprint {footprint}"


def no_oracle(dataset: Dataset, footprint: int) -> str:
    """Why ``dataset`` has no oracle at ``footprint``, and how to get one (in the dataset's words): foreign data
    has no true medium to compute it from; a generated dataset's is computed by ``compute_oracle``
    (``--compute-oracle``)."""
    from mitsnerf.oracle.cache import ORACLE_DIR

    if not (dataset.manifest or {}).get("spec"):
        return "no oracle (foreign data: no true medium to compute one from)"
    return (f"no oracle (none cached in {Path(dataset.root) / ORACLE_DIR} at footprint {footprint}; "
            f"{dataset.words(compute_oracle=True)} computes it and caches it with the dataset)")


def find_oracle(dataset: Dataset, footprint: int, recorded: float | None, compute: bool, reference: Reference,
                log: Callable[[str], None] = lambda line: None):
    """``(oracle, source)`` as :func:`read_oracle`; with ``compute``, a generated dataset without one at
    ``footprint`` gets the default settings' computed and cached first (:func:`mitsnerf.oracle.cache.ensure_oracle`,
    its progress lines to ``log``)."""
    from mitsnerf.oracle.cache import OracleConfig, ensure_oracle

    oracle, source = read_oracle(dataset, footprint, recorded)
    if oracle is not None or not compute or not (dataset.manifest or {}).get("spec"):
        return oracle, source
    oracle = ensure_oracle(dataset, OracleConfig(), footprint, log, reference)
    return oracle, source if oracle is None else f"oracle {oracle.path} at footprint {footprint} (computed now)"


RENDER_RECORD = "render.json"
"""What ``mitsnerf render`` writes beside its renders: each call's views and the footprint it rendered them at."""


def rendered_footprint(folder: Path, paths: Sequence[Path], words: Words = CLI) -> int | None:
    """The footprint ``mitsnerf render`` recorded for the renders ``paths`` in ``folder`` (its
    :data:`RENDER_RECORD`: of each file, the last call that wrote a view of its name), None where the folder has
    no such record or it records the footprint of none of them; renders made at several footprints are a
    DatasetError naming ``footprint`` (which oracle they are held against is then the user's to say)."""
    from mitsnerf.runs.novel import read_calls

    record = Path(folder) / RENDER_RECORD
    if not record.is_file():
        return None
    try:
        calls = read_calls(record)
    except ValueError as exc:
        raise DatasetError(record, None, f"{exc}: move it away, or say the footprint with "
                                         f"{words.name('footprint')}") from None
    made = {view.get("name"): call.get("footprint") for call in calls for view in call.get("views") or ()
            if isinstance(view, dict)}
    found = {made[p.stem] for p in paths if made.get(p.stem) is not None}  # None: a record from before footprints
    if any(not isinstance(k, int) or isinstance(k, bool) or k < 1 for k in found):
        raise DatasetError(record, "footprint", f"must be whole numbers >= 1, got {sorted(map(str, found))}")
    if len(found) > 1:
        raise DatasetError(record, "footprint", f"the renders were made at footprints {sorted(found)}: score "
                                                f"each footprint's apart, or say which with {words.name('footprint')}")
    return found.pop() if found else None


PNG_FLOOR = "8-bit sRGB PNG: test_ref quantised as a PNG against test"
EXR_FLOOR = "linear float: test_ref against test (the manifest's)"


def _floor_of_format(
    dataset: Dataset, ref: Reference, paths: Sequence[Path]
) -> tuple[Reference, str | None]:
    """``ref`` with the noise floor of the renders' format, and what that floor is: renders that are all PNG
    are held against :func:`mitsnerf.scoring.images.png_noise_floor` (8-bit quantisation costs dB no tool can win
    back), others against the manifest's floor; ``(ref, None)`` without a floor."""
    import dataclasses

    if ref.noise_floor is None:
        return ref, None
    if ref.masks is None or "test_ref" not in dataset.splits or any(p.suffix.lower() != ".png" for p in paths):
        return ref, EXR_FLOOR
    floor = png_noise_floor(ref.images, dataset.views("test_ref").images, ref.masks)
    return dataclasses.replace(ref, noise_floor=floor), PNG_FLOOR


@dataclass(frozen=True)
class ExternalScore:
    """The scores of one folder of renders, and what they were matched and scored with."""

    name: str
    metrics: dict
    files: dict[str, str]
    """Test frame name -> render file."""
    matched_by: str
    density: str | None
    oracle: str
    renders: np.ndarray
    """(V, H, W, 3) linear, as scored."""
    slices: dict
    reference: Reference
    """What they were scored against (the test views, their medium masks)."""
    oracle_used: Any = None
    """The :class:`mitsnerf.oracle.cache.Oracle` whose scores are in ``metrics`` (None: no oracle)."""
    footprint: int = 1
    """The footprint they were held against the oracle at."""
    run: RunRenders | None = None
    """The run whose ``test/`` they are (None: a folder of renders)."""

    def record(self, dataset: Dataset, folder: Path) -> dict[str, Any]:
        """The JSON record ``mitsnerf score`` writes."""
        from mitsnerf import env

        run = None if self.run is None else str(self.run.path)
        return {"name": self.name, "external": run is None, "run": run, "dataset": str(dataset.root),
                "renders": str(folder), "matched_by": self.matched_by, "files": self.files,
                "density": self.density, "oracle": self.oracle, "metrics": self.metrics, "provenance": env.provenance()}

    @property
    def label(self) -> str:
        """The row's method: a run's name as it is, other renders' marked ``NAME (external)``."""
        return self.name if self.run is not None else f"{self.name} (external)"


#: What a run scored against another dataset than it trained on is told to do instead.
SCORE_ELSEWHERE = "score it against the dataset it trained on"


def score_renders(dataset: Dataset, folder: Path, *, density: Path | None = None, name: str | None = None,
                  fmt: str | None = None, footprint: int | None = None, oracle=None, exr_alpha: str | None = None,
                  reference: Reference | None = None, compute_oracle: bool = False,
                  log: Callable[[str], None] = lambda line: None) -> ExternalScore:
    """Score the renders in ``folder`` against ``dataset``'s test views: the metrics of a benchmark
    cell (:func:`mitsnerf.scoring.views.score_views`), with the oracle's at ``footprint`` (``oracle``, else
    :func:`find_oracle`'s: ``compute_oracle`` computes a missing one, its progress lines to ``log``) where there is
    one; ``reference``: the test views' :class:`~mitsnerf.scoring.reference.Reference` if the caller has it. A
    run directory is scored as the run (module docstring): ``footprint`` (None: the run's, else 1), ``name`` and
    ``density`` override it. Messages name settings in the dataset's words
    (:attr:`mitsnerf.data.dataset.Dataset.words`: ``--format``, or ``format`` from the Python API)."""
    words = dataset.words
    if fmt is not None and fmt not in FORMATS:
        raise UsageError(words.name("format"), f"must be one of {', '.join(FORMATS)}, got {fmt!r}")
    if footprint is not None and footprint < 1:
        raise UsageError(words.name("footprint"), f"must be >= 1, got {footprint}")
    run = read_run(Path(folder))
    if run is not None:
        from mitsnerf.runs.fit import check_same_dataset

        check_same_dataset(run.config, dataset, run.path, "renders", SCORE_ELSEWHERE, words)
    folder = renders_folder(Path(folder))
    grid = read_density(density, dataset.box) if density is not None else None  # bad input before the work
    images, paths, rule = read_renders(dataset, folder, fmt, exr_alpha=exr_alpha)
    k = footprint if footprint is not None else run.footprint if run is not None else \
        rendered_footprint(folder, paths, words) or 1
    reference = reference or load_reference(dataset, "test")
    if oracle is None or f"footprint_{k}" not in oracle.scores:
        own = run.metrics.get("oracle_psnr_test_medium") if run is not None and k == run.footprint else None
        oracle, oracle_source = find_oracle(dataset, k, own, compute_oracle, reference, log)
    else:
        oracle_source = f"oracle {oracle.path} at footprint {k}"
    ref, floor_of = _floor_of_format(dataset, reference, paths)
    if oracle is not None:  # its medium PSNR less its own Monte Carlo variance, once, if cached before it was kept
        from mitsnerf.oracle.cache import variance_free

        oracle = variance_free(oracle, dataset, k, ref)
    fn = None if grid is None else true_density(grid, dataset.box)
    metrics, slices = score_views(images, ref, fn, oracle=None if oracle is None else oracle.metrics(k))
    metrics["noise_floor_of"], metrics["footprint"] = floor_of, k
    density_source = None if density is None else str(density)
    if fn is None and ref.sigma_t is not None:
        density_source = _density_of_run(metrics, ref, run)
    if run is not None and run.metrics:
        metrics["psnr_train"] = run.metrics.get("psnr_train")  # of training views: only the run has it
        metrics.update(_rung_figures(run, oracle, dataset, k, ref, metrics))
    views = dataset.views("test")
    return ExternalScore(name or (run.method if run is not None else folder.resolve().name), metrics,
                         {n: str(p) for n, p in zip(views.names, paths)}, rule, density_source, oracle_source, images,
                         slices, ref, oracle, k, run)


def _density_of_run(metrics: dict, ref: Reference, run: RunRenders | None) -> str | None:
    """Renders scored without a density grid: a run's own density figures (its ``metrics.json``, what its model's
    density scored) go into ``metrics`` and it says where they come from; else a note that none was given."""
    if run is None or not run.metrics:
        metrics["density_note"] = "no density grid given"  # data: the same whichever surface scored it
        return None
    metrics.update({key: run.metrics.get(key) for key in density_figures(None, ref)[0]})
    return f"the run's own ({run.path / 'metrics.json'})"


def _rung_figures(run: RunRenders, oracle, dataset: Dataset, footprint: int, ref: Reference,
                  metrics: dict) -> dict[str, Any]:
    """What a run's row says of its rung: ``given`` and ``rung`` as its ``metrics.json`` records them, the ceiling
    of that rung and the gap to it (:func:`mitsnerf.oracle.rungs.ceiling_figures`), as a bench cell has them."""
    from mitsnerf.oracle.rungs import ceiling_figures

    rung = run.metrics.get("rung")
    basis = run_basis(run, dataset) if rung == "single scattering" and oracle is not None else None
    return {"given": run.metrics.get("given"), "rung": rung,
            **ceiling_figures(rung, basis, oracle, dataset, footprint, ref, metrics)}


def run_basis(run: RunRenders, dataset: Dataset) -> tuple[int, int]:
    """A single-scattering run's remainder basis ``(L_f, L_z)`` (:mod:`mitsnerf.oracle.rungs`): its ``metrics.json``'s
    ``rung_basis``, else (a run from before it was recorded) what its method's model built from the run's settings
    says; a malformed one is a DatasetError naming the file."""
    recorded = run.metrics.get("rung_basis")
    if recorded is not None:
        if not (isinstance(recorded, list) and len(recorded) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in recorded)):
            raise DatasetError(run.path / "metrics.json", "rung_basis", f"must be two whole numbers >= 0 (L_f, L_z), "
                                                                       f"got {recorded!r:.60}")
        return recorded[0], recorded[1]
    from mitsnerf.runs.fit import build_model, scene_info

    model, _ = build_model(run.method, run.config.get("method_config"), scene_info(dataset, dataset.views("train")),
                           run.seed, run.path / "config.json")
    return model.rung_basis()
