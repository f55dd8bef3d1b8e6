"""The Python API: the commands' work from a notebook or a script, with the numbers the commands print.

Five functions, each the command of the same name without its printing (``import mitsnerf`` gives them):

==============  ======================================================  ==================================
function        does                                                    returns
==============  ======================================================  ==================================
``generate``    render a scene's ground-truth dataset (cached)          the dataset directory (``Path``)
``fit``         train a method on a dataset, then score its test views  :class:`Fit` (``metrics`` as
                                                                        ``metrics.json``)
``evaluate``    render a saved run's test views again and score them    the scores (``dict``)
``score``       score a folder of any tool's renders of the test views  the scores (``dict``)
``bench``       run a benchmark config (cells cached by config)         :class:`mitsnerf.bench.runner.
                                                                        BenchResult` (``markdown``: the
                                                                        tables ``mitsnerf bench`` prints)
==============  ======================================================  ==================================

Scores are the keys of a bench record's ``metrics``: ``psnr_test``, ``psnr_test_medium``, ``ssim_test``,
``noise_floor_psnr_medium``, the oracle's and the density errors where they apply. Nothing here prints
unless ``progress=True`` (progress bars). A problem with the input raises the package's typed exceptions,
subclasses of :class:`mitsnerf.errors.MitsnerfError` (``SpecError``, ``DatasetError``, ``UsageError``,
``OutputError``, ``TrainingError``), whose message names the file and field, and advises arguments in the
API's own words (``force=True``, not ``--force``: :data:`mitsnerf.errors.API`); never ``SystemExit``.

Any function may be the first call of a process: each selects the Mitsuba variant if none is set yet (the one
already set is kept; else ``$MITSNERF_VARIANT``, else ``cuda_ad_rgb`` where a GPU is usable, else
``llvm_ad_rgb``). Datasets go, unless told otherwise, to the cache the command line uses
(:func:`mitsnerf.outputs.data_cache`: ``$MITSNERF_DATA``, else ``$XDG_CACHE_HOME/mitsnerf``, else
``~/.cache/mitsnerf``).
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mitsnerf.errors import API, UsageError

if TYPE_CHECKING:
    from mitsnerf.bench.runner import BenchResult
    from mitsnerf.data.dataset import Dataset
    from mitsnerf.methods.base import Model
    from mitsnerf.scene.spec import SceneSpec

__all__ = ["Fit", "bench", "evaluate", "fit", "generate", "score"]

PathLike = str | os.PathLike


def _ready() -> str:
    """Select the Mitsuba variant unless one is set (each function may be the first call of a process)."""
    import mitsuba as mi

    from mitsnerf.env import set_variant

    current = mi.variant()
    return set_variant(current, "mitsuba.variant()") if current else set_variant()


def _mapping(value: Any, argument: str, example: str) -> dict:
    """``value`` (None: empty) as a dict; anything but a mapping is a UsageError naming ``argument``."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise UsageError(argument, f"must be a mapping of dotted field names to values ({example}), "
                                   f"got {type(value).__name__} {value!r:.60}")
    return dict(value)


def generate(scene: SceneSpec | PathLike, out: PathLike | None = None, *,
             overrides: Mapping[str, Any] | None = None, nerf_synthetic: bool = False, force: bool = False,
             progress: bool = False) -> Path:
    """Render ``scene`` (a library name such as ``"cloud"``, a spec file, a grid file ``.npy``/``.npz``/``.vol``,
    or a :class:`~mitsnerf.scene.spec.SceneSpec`) into ``out/NAME-HASH`` and return that directory; a cached
    dataset of the same spec and versions is returned at once (``force``: rendered again). ``out`` defaults to
    the dataset cache (:func:`mitsnerf.outputs.data_cache`), where ``bench`` finds it too.

    ``overrides``: dotted spec fields, as ``--set`` (``{"cameras.width": 32}``; for a grid file also the array of an
    ``.npz``, ``{"volume.params.array": "rho"}``); ``nerf_synthetic``: the box at [-1.5, 1.5]^3 and the cameras at
    radius 4, as ``generate --nerf-synthetic`` (``overrides`` win over it). A bad spec or grid file raises a
    :class:`~mitsnerf.errors.SpecError` naming the file before anything is written.
    """
    from mitsnerf.generate import generate_dataset
    from mitsnerf.outputs import check_output_dir, data_cache
    from mitsnerf.scene.spec import SceneSpec, nerf_synthetic_overrides, open_scene

    _ready()
    changes = {**(nerf_synthetic_overrides() if nerf_synthetic else {}),
               **_mapping(overrides, "overrides", '{"cameras.width": 32}')}
    if isinstance(scene, SceneSpec):
        spec = scene.with_overrides(changes) if changes else scene
    else:
        spec = open_scene(scene, changes)
    root = Path(out) if out is not None else data_cache()[0]
    check_output_dir(root, "out")
    return generate_dataset(spec, root, force=force, progress=progress)


@dataclass(frozen=True)
class Fit:
    """A trained and scored run (what :func:`fit` returns)."""

    method: str
    metrics: Mapping[str, Any]
    """What the run's ``metrics.json`` records: the test scores (``psnr_test``, ``psnr_test_medium``, ...), the
    step budget, ``steps``, ``train_seconds``, ``rays_per_s``, ``num_parameters``, ``model_bytes`` (the size of
    ``params.npz``)."""
    summary: str
    """The line ``mitsnerf train`` prints."""
    out: Path | None
    """The run directory (None: not written)."""
    model: Model
    """The trained model: ``model.render_view(camera)``, ``model.field()`` where it has one."""


def _open(dataset: Dataset | PathLike, verify: bool = True) -> Dataset:
    """The dataset (a directory, verified; or a loaded one), its messages in the API's words."""
    from dataclasses import replace

    from mitsnerf.data.dataset import Dataset, load_dataset
    from mitsnerf.data.verify import verify_dataset

    if isinstance(dataset, Dataset):
        return dataset if dataset.words is API else replace(dataset, words=API)
    opened = load_dataset(Path(dataset), words=API)
    verify_dataset(opened, hashes=verify, words=API)
    return opened


def _root(dataset: Dataset | PathLike) -> Path:
    """The directory of ``dataset`` (a path, or a loaded one)."""
    from mitsnerf.data.dataset import Dataset

    return Path(dataset.root) if isinstance(dataset, Dataset) else Path(dataset)


def _refuse_fixed_on_resume(given: Mapping[str, Any]) -> None:
    """``resume=True`` takes its settings from the checkpoint: any of ``given`` set (not None/False) is refused."""
    if given.get("force"):
        raise UsageError("force", f"starts the run over; {API(resume=True)} continues it: pass one of them")
    fixed = [name for name, value in given.items() if value not in (None, False)]
    if fixed:
        raise UsageError("resume", f"{', '.join(fixed)} come from the checkpoint; only steps and seconds may change")


def _resume(dataset: Dataset | PathLike | None, out: PathLike | None, steps: int | None, seconds: float | None,
            progress: bool):
    """Continue the run in ``out`` (``fit(..., resume=True)``): its RunResult."""
    from mitsnerf.runs.directory import check_outside_dataset, claim_run_dir
    from mitsnerf.runs.fit import resume_run

    if out is None:
        raise UsageError("out", f"{API(resume=True)} continues the run in out: name its directory")
    if dataset is not None:
        check_outside_dataset(Path(out), _root(dataset), API)
    changes = {k: v for k, v in (("steps", steps), ("seconds", seconds)) if v is not None}
    with claim_run_dir(Path(out), resume=True, words=API):
        data = _open(dataset) if dataset is not None else None
        return resume_run(Path(out), changes, dataset=data, progress=progress, words=API)


def fit(dataset: Dataset | PathLike | None = None, method: str | None = None, *,
        settings: Mapping[str, Any] | None = None, steps: int | None = None, seconds: float | None = None,
        seed: int | None = None, batch_rays: int | None = None, footprint: int | None = None,
        out: PathLike | None = None, force: bool = False, resume: bool = False, deterministic: bool = False,
        progress: bool = False) -> Fit:
    """Train ``method`` (a registered name: ``mitsnerf methods``; default ``ngp``) on ``dataset`` (a directory
    or a loaded :class:`~mitsnerf.data.dataset.Dataset`), then render and score its test views, as ``mitsnerf
    train``.

    ``settings``: the method's config fields, dotted (``{"network.width": 32}``, as ``--set``); ``steps`` /
    ``seconds``: the budget (default: the training config's); ``seed`` (default 0); ``footprint``: rays per
    pixel side when scoring (default 1); ``out``: write the run there (checkpoints, ``metrics.json``, test
    renders; not inside the dataset), refused if it holds another run unless ``force`` (start over) or
    ``resume`` (continue it from its checkpoint, on its own dataset unless ``dataset`` names it; only ``steps``
    and ``seconds`` may change: ``fit(resume=True, out="runs/ngp", steps=4000)``); ``deterministic``: one
    thread, bit-identical on a rerun (LLVM; refused on CUDA, whose float atomics no thread count orders).
    """
    if resume:
        _ready()
        _refuse_fixed_on_resume({"method": method, "settings": settings, "seed": seed, "batch_rays": batch_rays,
                                 "footprint": footprint, "deterministic": deterministic, "force": force})
        result = _resume(dataset, out, steps, seconds, progress)
        return Fit(result.method, result.metrics(), result.summary(out), Path(out), result.model)  # type: ignore[arg-type]
    return _fit_new(dataset, method or "ngp", _mapping(settings, "settings", '{"network.width": 32}'),
                    {"steps": steps, "seconds": seconds, "seed": seed, "batch_rays": batch_rays}, footprint, out,
                    force, deterministic, progress)


def _fit_new(dataset: Dataset | PathLike | None, method: str, settings: dict, budget: dict, footprint: int | None,
             out: PathLike | None, force: bool, deterministic: bool, progress: bool) -> Fit:
    """A new run (:func:`fit` without ``resume``), every argument checked before any work."""
    from mitsnerf.config import from_dict
    from mitsnerf.methods import methods
    from mitsnerf.runs.directory import check_outside_dataset, claim_run_dir
    from mitsnerf.runs.fit import fit as fit_run
    from mitsnerf.train import TrainConfig
    from mitsnerf.train.evaluate import EvalConfig
    from mitsnerf.train.threads import refuse_nondeterministic

    _ready()
    if dataset is None:
        raise UsageError("dataset", f"name a dataset directory (or pass {API(resume=True)} to continue the run "
                                    "in out)")
    refuse_nondeterministic(deterministic)
    problem = methods().why_not(method)
    if problem:
        raise UsageError("method", problem)
    from_dict(methods()[method].config_type, settings, source="settings")  # checked before any work
    train_config = from_dict(TrainConfig, {k: v for k, v in budget.items() if v is not None}, source="fit")
    eval_config = from_dict(EvalConfig, {} if footprint is None else {"footprint": footprint}, source="fit")
    if out is not None:
        check_outside_dataset(Path(out), _root(dataset), API)
    data = _open(dataset)

    def run(out_dir: Path | None):
        return fit_run(data, method, settings, train_config, out_dir, eval_config=eval_config,
                       deterministic=deterministic, progress=progress, words=API)

    if out is None:
        result = run(None)
    else:
        with claim_run_dir(Path(out), force=force, words=API):
            result = run(Path(out))
    return Fit(method, result.metrics(), result.summary(out), Path(out) if out is not None else None, result.model)


def evaluate(run: PathLike, *, footprint: int | None = None) -> dict[str, Any]:
    """Render the test views of the run saved in ``run`` again (with its own footprint, or ``footprint``)
    and score them: the scores ``metrics.json`` holds, recomputed from the saved parameters."""
    from dataclasses import replace

    from mitsnerf.config import from_dict, from_saved
    from mitsnerf.runs.fit import load_run, score_model
    from mitsnerf.scoring.reference import load_reference
    from mitsnerf.train.evaluate import EvalConfig

    _ready()
    model, dataset, config = load_run(Path(run))
    eval_config = from_saved(EvalConfig, dict(config.get("eval") or {}), source=Path(run) / "config.json",
                             prefix="eval.")
    if footprint is not None:
        eval_config = replace(eval_config, footprint=from_dict(EvalConfig, {"footprint": footprint}).footprint)
    scores, _, _, _ = score_model(model, load_reference(dataset, "test"), eval_config)
    return scores


def score(dataset: Dataset | PathLike, renders: PathLike, *, density: PathLike | None = None,
          name: str | None = None, footprint: int | None = None,
          format: str | None = None,  # noqa: A002 (the CLI's word)
          exr_alpha: str | None = None, compute_oracle: bool = False, progress: bool = False) -> dict[str, Any]:
    """Score a folder of renders of ``dataset``'s test views (or a run directory's ``test/``), as ``mitsnerf
    score``: the metrics of a bench cell, with the oracle where the dataset has one cached (``compute_oracle``:
    computed and cached first where it has none; ``progress``: its progress lines on stderr), and with
    ``density`` (a ``.npy``/``.vol`` grid of sigma_t over the dataset's box) the density errors. A run
    directory gives the run's own figures (its footprint, its density scores; ``footprint`` and ``density``
    override them); one trained on another dataset is a :class:`~mitsnerf.errors.UsageError`."""
    from mitsnerf.outputs import progress_log
    from mitsnerf.runs.external import score_renders

    _ready()
    result = score_renders(_open(dataset), Path(renders), density=Path(density) if density is not None else None,
                           name=name, fmt=format, footprint=footprint, exr_alpha=exr_alpha,
                           compute_oracle=compute_oracle, log=progress_log(progress))
    return dict(result.metrics)


def _call(function, *args: Any, **given: Any) -> str:
    """How a call of ``function`` of this module reads, the arguments left at their defaults left out (what a sweep
    records it was run by): ``api.bench('default', quick=True)``."""
    defaults = {k: p.default for k, p in inspect.signature(function).parameters.items()}
    return API.command(function.__name__, *args, **{k: v for k, v in given.items() if v != defaults.get(k)})


def bench(config: PathLike = "default", *, quick: bool = False, results: PathLike = "results",
          data: PathLike | None = None, executor: str = "sequential", workers: int = 0, force: bool = False,
          progress: bool = False) -> BenchResult:
    """Run a benchmark (a shipped config's name, or a config file's path), as ``mitsnerf bench``: cells already
    computed with the same config and code are read back, not rerun. ``data``: where datasets are cached
    (default :func:`mitsnerf.outputs.data_cache`). ``result.markdown`` is the tables the command prints,
    ``result.per_scene`` / ``result.average`` their rows, ``result.failed`` the cells that failed (with their
    error), ``result.out_root`` where everything was written. ``executor="pool"`` from a script needs the call
    under ``if __name__ == "__main__":`` (its workers import the script again), and says so if it is not."""
    from mitsnerf.bench.config import load_bench_config
    from mitsnerf.bench.runner import BenchOptions, run_benchmark
    from mitsnerf.outputs import check_output_dir, data_cache

    _ready()
    options = BenchOptions(quick=quick, data_root=Path(data) if data is not None else data_cache()[0],
                           results_root=Path(results), progress=progress, executor=executor, workers=workers,
                           force=force, words=API,
                           command=_call(bench, os.fspath(config), quick=quick, results=os.fspath(results),
                                         data=None if data is None else os.fspath(data), executor=executor,
                                         workers=workers, force=force))
    check_output_dir(options.results_root, "results")
    check_output_dir(options.data_root, "data")
    return run_benchmark(load_bench_config(os.fspath(config)), options)
