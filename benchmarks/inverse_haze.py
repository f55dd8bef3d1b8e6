"""mitsuba-inverse's haze: each remedy of the inverse-rendering literature on its own, then together.

Every run starts from ``mitsuba-inverse``'s settings in the ``targets`` benchmark, changes one thing and
trains for the same number of steps on the default cloud; it is scored like a bench cell: medium and
whole-image PSNR of the test views, the density's relative L1 error (epsilon) and relative mass error
(delta, > 0 when the learned medium holds more), and the transmittance MAE along the test rays.

- ``baseline``: the settings as they are;
- ``init 0.1`` / ``init 0``: a low or zero initial extinction (``init_depth``);
- ``l1 X``: the sparsity prior ``X * mean(sigma_t)`` added to the loss;
- ``4 views``: four whole training views per step instead of a batch of pixels over every view;
- ``primal x16``: the image the loss compares at 16 instead of 4 times the gradient's paths;
- ``no carve``: without the emptiness mask from training pixels that show the environment unattenuated;
- ``majorant 40``: prbvolpath's delta-tracking majorant fixed at 40 (the true maximum is 30) instead of the grid's
  maximum, and ``init 0, majorant 40``: the zero start it makes possible (both with ``estimator = prbvolpath``);
- combinations: ``--combo '{"NAME": {FIELD: VALUE, ...}}'`` adds variants (MitsubaInverseConfig fields).

Budgets are steps, so the figures do not depend on the machine's load (the train seconds do). The figures of
docs/notes/mitsuba-inverse.md, "mitsuba-inverse: removing the haze", were measured before the method had its
``estimator`` setting and its ray batches (one whole view per step, the emptiness mask off by default then), with
Mitsuba's ``prbvolpath`` (today ``--combo '{"NAME": {"estimator": "prbvolpath",
...}}'`` repeats them); the variants now run with the method's default estimator unless they name one.

    .venv/bin/python benchmarks/inverse_haze.py [--steps 400] [--variants baseline "no carve" ...] [--data DIR]
        [--jsonl FILE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

#: One change each from the targets config (``config`` overrides of MitsubaInverseConfig).
VARIANTS: dict[str, dict] = {
    "baseline": {},
    "init 0.1": {"init_depth": 0.1},
    "init 0": {"init_depth": 0.0},
    "l1 1e-3": {"l1": 1e-3},
    "l1 1e-2": {"l1": 1e-2},
    "4 views": {"batch": "views", "views_per_step": 4},
    "primal x16": {"spp_primal_factor": 16},
    "no carve": {"carve": False},
    "majorant 40": {"estimator": "prbvolpath", "majorant_depth": 40.0},
    "init 0, majorant 40": {"estimator": "prbvolpath", "init_depth": 0.0, "majorant_depth": 40.0},
}


def settings(name: str, steps: int, combos: dict) -> dict:
    """The config overrides of variant ``name`` (one of VARIANTS or of ``combos``) at ``steps`` steps."""
    return dict(combos[name]) if name in combos else dict(VARIANTS[name])


def run_one(name: str, config: dict, steps: int, data_root: Path, scene: str) -> dict:
    from mitsnerf.bench.config import load_bench_config
    from mitsnerf.config import from_dict, to_dict
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.runs.fit import fit
    from mitsnerf.scene.spec import load_scene
    from mitsnerf.scoring.reference import load_reference
    from mitsnerf.train import TrainConfig
    from mitsnerf.train.evaluate import EvalConfig

    bench = load_bench_config("targets")
    method = next(m for m in bench.methods if m.name == "mitsuba-inverse")
    base, train = bench.method_settings(method, quick=False)
    dataset = load_dataset(generate_dataset(load_scene(scene), data_root))
    run = fit(dataset, "mitsuba-inverse", {**base, **config}, from_dict(TrainConfig, {**train, "steps": steps}),
              None, eval_config=from_dict(EvalConfig, to_dict(bench.eval)), progress=False,
              reference=load_reference(dataset, "test"))
    m = run.metrics()
    keys = ("psnr_test_medium", "psnr_test", "density_rel_l1", "density_rel_mass", "transmittance_mae",
            "train_seconds", "psnr_train")
    return {"variant": name, "config": config, "steps": m["steps"], **{k: m.get(k) for k in keys}}


def table(rows: list[dict]) -> str:
    lines = ["| choice | steps | medium PSNR | whole PSNR | density rel L1 (epsilon) | delta | T MAE | train s |",
             "|---|---|---|---|---|---|---|---|"]

    def f(v, fmt="{:.2f}"):
        return "-" if v is None else fmt.format(v)
    for r in rows:
        lines.append(f"| {r['variant']} | {r['steps']} | {f(r['psnr_test_medium'])} | {f(r['psnr_test'])} | "
                     f"{f(r['density_rel_l1'], '{:.3f}')} | {f(r['density_rel_mass'], '{:+.3f}')} | "
                     f"{f(r['transmittance_mae'], '{:.4f}')} | {f(r['train_seconds'], '{:.0f}')} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="cloud")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--variants", nargs="+", default=None,
                        help="names of VARIANTS or of --combo (default: the combos if any, else VARIANTS)")
    parser.add_argument("--combo", default="{}", help='JSON {"NAME": {overrides}}: more variants')
    parser.add_argument("--data", help="dataset cache root (default: mitsnerf's, `mitsnerf env` shows it)")
    parser.add_argument("--jsonl", default=None, help="append each row to this file as it finishes")
    args = parser.parse_args()
    from mitsnerf.outputs import data_cache

    data_root = Path(args.data) if args.data else data_cache()[0]

    import mitsnerf  # noqa: F401  (libLLVM before drjit)
    from mitsnerf import env

    env.set_variant()
    combos = json.loads(args.combo)
    names = args.variants or ([*combos] if combos else [*VARIANTS])
    unknown = [n for n in names if n not in VARIANTS and n not in combos]
    if unknown:
        parser.error(f"unknown variants {unknown}: choose from {[*VARIANTS, *combos]}")
    rows = []
    for name in names:
        rows.append(run_one(name, settings(name, args.steps, combos), args.steps,
                            data_root, args.scene))
        print(json.dumps(rows[-1]), flush=True)
        if args.jsonl:
            with open(args.jsonl, "a") as fh:
                fh.write(json.dumps(rows[-1]) + "\n")
    print()
    print(table(rows))


if __name__ == "__main__":
    main()
