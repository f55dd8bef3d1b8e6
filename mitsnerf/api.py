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
``OutputError``, ``TrainingError``), whose message names the file and field; never ``SystemExit``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mitsnerf.errors import UsageError

if TYPE_CHECKING:
    from mitsnerf.bench.runner import BenchResult
    from mitsnerf.data.dataset import Dataset
    from mitsnerf.methods.base import Model
    from mitsnerf.scene.spec import SceneSpec

__all__ = ["Fit", "bench", "evaluate", "fit", "generate", "score"]

PathLike = str | os.PathLike


def generate(scene: SceneSpec | PathLike, out: PathLike = "data", *, overrides: Mapping[str, Any] | None = None,
             nerf_synthetic: bool = False, force: bool = False, progress: bool = False) -> Path:
    """Render ``scene`` (a library name such as ``"cloud"``, a spec file, a grid file ``.npy``/``.npz``/``.vol``,
    or a :class:`~mitsnerf.scene.spec.SceneSpec`) into ``out/NAME-HASH`` and return that directory; a cached
    dataset of the same spec and versions is returned at once (``force``: rendered again).

    ``overrides``: dotted spec fields, as ``--set`` (``{"cameras.width": 32}``; for a grid file also the array of an
    ``.npz``, ``{"volume.params.array": "rho"}``); ``nerf_synthetic``: the box at [-1.5, 1.5]^3 and the cameras at
    radius 4, as ``generate --nerf-synthetic`` (``overrides`` win over it). A bad spec or grid file raises a
    :class:`~mitsnerf.errors.SpecError` naming the file before anything is written.
    """
    from mitsnerf.generate import generate_dataset
    from mitsnerf.outputs import check_output_dir
    from mitsnerf.scene.spec import SceneSpec, nerf_synthetic_overrides, open_scene

    changes = {**(nerf_synthetic_overrides() if nerf_synthetic else {}), **dict(overrides or {})}
    if isinstance(scene, SceneSpec):
        spec = scene.with_overrides(changes) if changes else scene
    else:
        spec = open_scene(scene, changes)
    check_output_dir(Path(out), "out")
    return generate_dataset(spec, Path(out), force=force, progress=progress)


@dataclass(frozen=True)
class Fit:
    """A trained and scored run (what :func:`fit` returns)."""

    method: str
    metrics: Mapping[str, Any]
    """What the run's ``metrics.json`` records: the test scores (``psnr_test``, ``psnr_test_medium``, ...), the
    step budget, ``steps``, ``train_seconds``, ``rays_per_s``, ``num_parameters``."""
    summary: str
    """The line ``mitsnerf train`` prints."""
    out: Path | None
    """The run directory (None: not written)."""
    model: Model
    """The trained model: ``model.render_view(camera)``, ``model.field()`` where it has one."""


def _open(dataset: Dataset | PathLike, verify: bool = True) -> Dataset:
    from mitsnerf.data.dataset import Dataset, load_dataset
    from mitsnerf.data.verify import verify_dataset

    if isinstance(dataset, Dataset):
        return dataset
    opened = load_dataset(Path(dataset))
    verify_dataset(opened, hashes=verify)
    return opened


def fit(dataset: Dataset | PathLike, method: str = "ngp", *, settings: Mapping[str, Any] | None = None,
        steps: int | None = None, seconds: float | None = None, seed: int = 0, batch_rays: int | None = None,
        footprint: int = 1, out: PathLike | None = None, force: bool = False, deterministic: bool = False,
        progress: bool = False) -> Fit:
    """Train ``method`` (a registered name: ``mitsnerf methods``) on ``dataset`` (a directory or a loaded
    :class:`~mitsnerf.data.dataset.Dataset`), then render and score its test views, as ``mitsnerf train``.

    ``settings``: the method's config fields, dotted (``{"network.width": 32}``, as ``--set``); ``steps`` /
    ``seconds``: the budget (default: the training config's); ``footprint``: rays per pixel side when
    scoring; ``out``: write the run there (checkpoints, ``metrics.json``, test renders), refused if it
    holds another run unless ``force``; ``deterministic``: one thread, bit-identical on a rerun (LLVM; refused
    on CUDA, whose float atomics no thread count orders).
    """
    from mitsnerf.config import from_dict
    from mitsnerf.methods import methods
    from mitsnerf.runs.directory import claim_run_dir
    from mitsnerf.runs.fit import fit as fit_run
    from mitsnerf.train import TrainConfig
    from mitsnerf.train.evaluate import EvalConfig
    from mitsnerf.train.threads import refuse_nondeterministic

    refuse_nondeterministic(deterministic)
    problem = methods().why_not(method)
    if problem:
        raise UsageError("method", problem)
    from_dict(methods()[method].config_type, dict(settings or {}), source="settings")  # checked before any work
    chosen = {"steps": steps, "seconds": seconds, "seed": seed, "batch_rays": batch_rays}
    train_config = from_dict(TrainConfig, {k: v for k, v in chosen.items() if v is not None}, source="fit")
    eval_config = from_dict(EvalConfig, {"footprint": footprint}, source="fit")
    data = _open(dataset)

    def run(out_dir: Path | None):
        return fit_run(data, method, dict(settings or {}), train_config, out_dir, eval_config=eval_config,
                       deterministic=deterministic, progress=progress)

    if out is None:
        result = run(None)
    else:
        with claim_run_dir(Path(out), force=force, option="out"):
            result = run(Path(out))
    return Fit(method, result.metrics(), result.summary(out), Path(out) if out is not None else None, result.model)


def evaluate(run: PathLike, *, footprint: int | None = None) -> dict[str, Any]:
    """Render the test views of the run saved in ``run`` again (with its own footprint, or ``footprint``)
    and score them: the scores ``metrics.json`` holds, recomputed from the saved parameters."""
    from dataclasses import replace

    from mitsnerf.config import from_dict
    from mitsnerf.runs.fit import load_run, score_model
    from mitsnerf.scoring.reference import load_reference
    from mitsnerf.train.evaluate import EvalConfig

    model, dataset, config = load_run(Path(run))
    eval_config = from_dict(EvalConfig, dict(config.get("eval") or {}), source=Path(run) / "config.json")
    if footprint is not None:
        eval_config = replace(eval_config, footprint=from_dict(EvalConfig, {"footprint": footprint}).footprint)
    scores, _, _, _ = score_model(model, load_reference(dataset, "test"), eval_config)
    return scores


def score(dataset: Dataset | PathLike, renders: PathLike, *, density: PathLike | None = None,
          name: str | None = None, footprint: int | None = None,
          format: str | None = None,  # noqa: A002 (the CLI's word)
          exr_alpha: str | None = None) -> dict[str, Any]:
    """Score a folder of renders of ``dataset``'s test views (or a run directory's ``test/``), as ``mitsnerf
    score``: the metrics of a bench cell, with the oracle where the dataset has one cached, and with
    ``density`` (a ``.npy``/``.vol`` grid of sigma_t over the dataset's box) the density errors. A run
    directory gives the run's own figures (its footprint, its density scores; ``footprint`` and ``density``
    override them); one trained on another dataset is a :class:`~mitsnerf.errors.UsageError`."""
    from mitsnerf.runs.external import score_renders

    result = score_renders(_open(dataset), Path(renders), density=Path(density) if density is not None else None,
                           name=name, fmt=format, footprint=footprint, exr_alpha=exr_alpha)
    return dict(result.metrics)


def bench(config: PathLike = "default", *, quick: bool = False, results: PathLike = "results",
          data: PathLike | None = None, executor: str = "sequential", workers: int = 0, force: bool = False,
          progress: bool = False) -> BenchResult:
    """Run a benchmark (a shipped config's name, or a config file's path), as ``mitsnerf bench``: cells already
    computed with the same config and code are read back, not rerun. ``result.markdown`` is the tables the
    command prints, ``result.per_scene`` / ``result.average`` their rows, ``result.failed`` the cells that
    failed (with their error), ``result.out_root`` where everything was written."""
    from mitsnerf.bench.config import load_bench_config
    from mitsnerf.bench.runner import BenchOptions, default_data_root, run_benchmark
    from mitsnerf.outputs import check_output_dir

    options = BenchOptions(quick=quick, data_root=Path(data) if data is not None else default_data_root(),
                           results_root=Path(results), progress=progress, executor=executor, workers=workers,
                           force=force)
    check_output_dir(options.results_root, "results")
    check_output_dir(options.data_root, "data")
    return run_benchmark(load_bench_config(os.fspath(config)), options)
