"""mitsuba-inverse's gradient estimators side by side: the variance of the extinction's gradient and the time per step.

One process, one dataset (the default cloud), the method's own training step (one training view rendered at
``spp`` samples per pixel, its mean squared error against the view, back-propagated) with each estimator of
``mitsuba-inverse``'s ``estimator`` setting at each ``spp``, ``--repeats`` times with independent seeds, the
estimators taking turns so that the machine's load falls on all of them alike. The extinction is held at a
state (``--states``):

- ``start``: the method's start inside the emptiness mask (``carve``), ``init_depth = 10`` at 64^3, albedo 0.6;
- ``truth``: the true extinction and albedo resampled to 64^3 (the loss's gradient is then pure noise plus
  the images' own noise).

Reported per state, estimator and spp: the time per step (median over the repeats, seconds), the variance of the
gradient of the extinction grid (``sum over the voxels inside the mask of the variance over the repeats``, mean
over ``--views`` views), their product (the variance a second of compute leaves; lower is better) and that
product over prbvolpath's at 8 spp (today's step): at equal variance, the time per step relative to today's;
and the tail: the largest share one repeat holds of the summed squared deviations (the worst view), and the
variance without that repeat (a heavy-tailed gradient's sample variance is dominated by its rare large samples).

    .venv/bin/python benchmarks/inverse_variance.py --data /work/data/lib [--repeats 12] [--spp 4 8 16]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ESTIMATORS = ("prbvolpath", "drt", "free_flight")


def state_grids(dataset, model, state: str) -> tuple[np.ndarray, np.ndarray]:
    """``(tau (R, R, R, C), albedo (R, R, R, 3))`` of a state at the model's resolution, inside its mask."""
    from mitsnerf.scene.to_mitsuba import volume_grids

    r = model.resolution
    keep = model._keep_mask(r)
    if state == "start":
        tau = np.full((r, r, r, model.channels), 10.0, np.float32)
        albedo = np.full((r, r, r, 3), 0.6, np.float32)
    else:
        sigma, albedo = volume_grids(model.spec)
        if sigma.shape[0] != r:
            raise SystemExit(f"the dataset's grid is {sigma.shape[0]}^3, the state needs {r}^3")
        tau = (sigma.reshape(r, r, r, -1) * model.side).astype(np.float32)
    return tau * keep[..., None], np.asarray(albedo, np.float32)


def gradient(model, data, view: int, spp: int, seed: int) -> tuple[np.ndarray, float]:
    """One training step's gradient of the extinction grid (numpy) and its seconds (render + backward)."""
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.methods.mitsuba_inverse import _rgb_sensor

    sigma = mi.TensorXf(model.sigma_t)
    dr.enable_grad(sigma)
    model.params[model._key_sigma] = sigma
    model.params.update()
    sensor = _rgb_sensor(data.cameras[view], spp)
    target = mi.TensorXf(np.ascontiguousarray(data.images[view], dtype=np.float32))
    start = time.perf_counter()
    img = mi.render(model.scene, model.params, sensor=sensor, spp=spp, seed=seed)
    dr.backward(dr.mean(dr.square(img - target), axis=None))
    g = np.asarray(dr.grad(sigma))
    seconds = time.perf_counter() - start
    model.params[model._key_sigma] = mi.TensorXf(dr.detach(sigma))
    model.params.update()
    return g.reshape(np.asarray(sigma).shape), seconds


def build(dataset, info, data, estimator: str, state: str):
    import mitsuba as mi

    from mitsnerf.methods.mitsuba_inverse import MitsubaInverseConfig, MitsubaInverseModel

    config = MitsubaInverseConfig(resolutions=(64,), upsample_at=(), carve=True, init_depth=10.0, estimator=estimator)
    model = MitsubaInverseModel(config, info)
    model.carve(data)
    tau, albedo = state_grids(dataset, model, state)
    model.set_parameters({"sigma_t": model._carved(mi.TensorXf(tau)), "albedo": mi.TensorXf(albedo)})
    return model


def measure(args) -> list[dict]:
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.runs.fit import scene_info
    from mitsnerf.scene.spec import load_scene
    from mitsnerf.train import PixelData

    dataset = load_dataset(args.dataset or generate_dataset(load_scene(args.scene), Path(args.data)))
    views = dataset.views("train")
    info, data = scene_info(dataset, views), PixelData.from_views(views.images, views.cameras)
    rows = []
    for state in args.states:
        models = {e: build(dataset, info, data, e, state) for e in args.estimators}
        keep = models[args.estimators[0]]._keep_mask(64)[..., None]
        acc = {(e, s, v): [] for e in args.estimators for s in args.spp for v in range(args.views)}
        for e in args.estimators:  # compile every kernel before the clock starts
            for s in args.spp:
                gradient(models[e], data, 0, s, 1)
        for k in range(args.repeats):
            for v in range(args.views):
                for s in args.spp:
                    for e in args.estimators:
                        acc[e, s, v].append(gradient(models[e], data, args.view0 + 7 * v, s, 1000 * k + 17 * v + s))
        rows += [summary(state, e, s, [acc[e, s, v] for v in range(args.views)], keep)
                 for e in args.estimators for s in args.spp]
    return rows


def tail(g: np.ndarray) -> tuple[float, float]:
    """Of repeats ``g`` (K, ...): the largest share one repeat has of the summed squared deviations
    ``d_k = |g_k - mean g|^2``, and the variance (summed over voxels) without that repeat.

    A gradient whose variance is finite spreads ``sum d_k`` over the repeats (each near ``1 / K``); one
    repeat holding most of it is a heavy tail, where the sample variance says little.

    >>> g = np.array([[0.0], [0.0], [0.0], [4.0]])  # d = 1, 1, 1, 9
    >>> tail(g)
    (0.75, 0.0)
    """
    d = np.square(g - g.mean(axis=0)).reshape(len(g), -1).sum(axis=1)
    worst = int(np.argmax(d))
    rest = np.delete(g, worst, axis=0)
    return float(d[worst] / d.sum()), float(rest.var(axis=0, ddof=1).sum())


def summary(state: str, estimator: str, spp: int, runs: list[list[tuple]], keep: np.ndarray) -> dict:
    variances, means, seconds, shares, trimmed = [], [], [], [], []
    for run in runs:
        g = np.stack([x[0] for x in run]) * keep
        variances.append(float(g.var(axis=0, ddof=1).sum()))
        means.append(float(np.sqrt(np.square(g.mean(axis=0)).sum())))
        seconds += [x[1] for x in run]
        share, rest = tail(g)
        shares.append(share)
        trimmed.append(rest)
    return {"state": state, "estimator": estimator, "spp": spp, "seconds": float(np.median(seconds)),
            "variance": float(np.mean(variances)), "mean_norm": float(np.mean(means)), "repeats": len(runs[0]),
            "largest_share": float(np.max(shares)), "variance_without_largest": float(np.mean(trimmed))}


def table(rows: list[dict]) -> str:
    lines = ["| state | estimator | spp | time per step (s) | variance of the sigma_t gradient | variance x time | "
             "vs prbvolpath at 8 spp | largest repeat's share | variance without it | norm of the mean gradient |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        base = next((b for b in rows if b["state"] == r["state"] and b["estimator"] == "prbvolpath"
                     and b["spp"] == 8), None)
        ratio = "-" if base is None else f"{r['variance'] * r['seconds'] / (base['variance'] * base['seconds']):.3f}"
        lines.append(f"| {r['state']} | {r['estimator']} | {r['spp']} | {r['seconds']:.3f} | {r['variance']:.3e} | "
                     f"{r['variance'] * r['seconds']:.3e} | {ratio} | {r['largest_share']:.2f} | "
                     f"{r['variance_without_largest']:.3e} | {r['mean_norm']:.3e} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", help="dataset cache root: --scene is generated there unless it is cached")
    parser.add_argument("--dataset", help="an existing dataset directory (instead of --data and --scene)")
    parser.add_argument("--scene", default="cloud")
    parser.add_argument("--states", nargs="+", default=["start", "truth"], choices=["start", "truth"])
    parser.add_argument("--estimators", nargs="+", default=list(ESTIMATORS), choices=ESTIMATORS)
    parser.add_argument("--spp", nargs="+", type=int, default=[4, 8, 16])
    parser.add_argument("--repeats", type=int, default=12)
    parser.add_argument("--views", type=int, default=2, help="training views (0, 7, 14, ...), each its own variance")
    parser.add_argument("--view0", type=int, default=3)
    parser.add_argument("--json", default=None, help="write the rows here too")
    args = parser.parse_args()
    if args.dataset is None and args.data is None:
        parser.error("give --data (with --scene) or --dataset")

    import mitsnerf  # noqa: F401  (libLLVM before drjit)
    from mitsnerf import env

    env.set_variant()
    rows = measure(args)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    print(table(rows))


if __name__ == "__main__":
    main()
