"""Where the best methods' missing dB go on a scene: one change at a time against the default run.

Each method starts from its configuration and step budget in the default benchmark (``make bench``)
and one factor is changed at a time; every run is scored on the medium pixels of the test views with
the default footprint, next to the dataset's noise floor and the emission-absorption oracle (the best
any emission-absorption model can do on the dataset):

- ``baseline``: the default run;
- ``clean views``: the same scene with nearly noise-free training views (``render.spp_train = S_clean``,
  ``--clean-spp``, 2048 unless told, instead of the scene's): what the training views' Monte Carlo noise
  costs, the clean-views row minus the baseline;
- ``finer``: a representation with twice the resolution (voxel grid 128^3; ngp's finest level 48;
  nerf one more position octave, twice its finest frequency):
  what the representation's resolution costs;
- ``less prior`` / ``more prior``: the regulariser 10x weaker / stronger (voxel's TV weights);
- ``4x steps``: the optimisation budget;
- ``K = 1`` / ``centre rays``: the pixel footprint in evaluation / in training.

``--spp-train S`` renders every variant's training views at ``S`` spp instead of the scene's (a candidate
default: the baseline row is then that candidate's). Budgets are steps, so the figures do not depend on the
machine's load.

    .venv/bin/python benchmarks/error_budget.py [--scene cloud] [--methods voxel ngp] [--data DIR]
        [--spp-train S] [--clean-spp S_clean]
"""

from __future__ import annotations

import argparse
import copy
import json
from pathlib import Path

VARIANTS = ("baseline", "clean views", "finer", "less prior", "more prior", "4x steps", "K = 1", "centre rays")


CLEAN_SPP = 2048


def variant(method: str, name: str, settings: dict, clean_spp: int = CLEAN_SPP) -> dict | None:
    """``settings`` (``config``, ``train``, ``eval``, ``spec``) changed for one variant, or None if it does not apply;
    ``clean_spp``: the training views' spp of ``clean views``."""
    s = copy.deepcopy(settings)
    config, train, evalc = s["config"], s["train"], s["eval"]
    if name == "clean views":
        s["spec"] = {**(s["spec"] or {}), "render.spp_train": clean_spp}
    elif name == "finer" and method == "voxel":
        config.update(resolution=128, initial_resolution=32, upsample_steps=[150, 400])
    elif name == "finer" and method == "ngp":
        config["network"] = {**config.get("network", {}), "n_levels": 4, "max_resolution": 48}
    elif name == "finer" and method == "nerf":
        config["network"] = {**config.get("network", {}), "pos_octaves": 5}
        config["coarse_network"] = {"width": 32, "depth": 2, **config.get("coarse_network", {}), "pos_octaves": 5}
    elif name in ("less prior", "more prior") and method == "voxel":
        f = 0.1 if name == "less prior" else 10.0
        config.update(tv_sigma=1e-3 * f, tv_sh=1e-3 * f)
    elif name == "4x steps":
        train["steps"] = 4 * train["steps"]
    elif name == "K = 1":
        evalc["footprint"] = 1
    elif name == "centre rays":
        train["pixel_jitter"] = False
    elif name != "baseline":
        return None
    return s


def run_one(method: str, name: str, s: dict, data_root: Path, scene: str) -> dict:
    from mitsnerf.config import from_dict
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.oracle.cache import OracleConfig, ensure_oracle
    from mitsnerf.runs.fit import fit
    from mitsnerf.scene.spec import load_scene
    from mitsnerf.scoring.reference import load_reference
    from mitsnerf.train import TrainConfig
    from mitsnerf.train.evaluate import EvalConfig

    spec = load_scene(scene)
    if s.get("spec"):
        spec = spec.with_overrides(s["spec"])
    dataset = load_dataset(generate_dataset(spec, data_root))
    evalc = from_dict(EvalConfig, s["eval"])
    found = ensure_oracle(dataset, OracleConfig(), evalc.footprint)
    oracle = found.metrics(evalc.footprint) if found is not None else None
    run = fit(dataset, method, s["config"], from_dict(TrainConfig, s["train"]), None, eval_config=evalc,
              progress=False, reference=load_reference(dataset, "test"), oracle=oracle)
    m = run.metrics()
    return {"method": method, "variant": name, "spp_train": spec.render.spp_train, "steps": m["steps"],
            "footprint": m["footprint"],
            "psnr_medium": m["psnr_test_medium"], "psnr": m["psnr_test"], "psnr_train": m["psnr_train"],
            "oracle_medium": m.get("oracle_psnr_test_medium"), "floor_medium": m.get("noise_floor_psnr_medium"),
            "gap_to_oracle": m.get("gap_to_oracle"), "train_seconds": m["train_seconds"]}


def table(rows: list[dict]) -> str:
    lines = ["| method | variant | train spp | steps | K | medium PSNR | change | gap to oracle | oracle | floor "
             "| train PSNR |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    base = {r["method"]: r["psnr_medium"] for r in rows if r["variant"] == "baseline"}

    def f(v, fmt="{:.2f}"):
        return "-" if v is None else fmt.format(v)
    for r in rows:
        change = None if base.get(r["method"]) is None else r["psnr_medium"] - base[r["method"]]
        lines.append(f"| {r['method']} | {r['variant']} | {r['spp_train']} | {r['steps']} | {r['footprint']} | "
                     f"{f(r['psnr_medium'])} | "
                     f"{f(change, '{:+.2f}')} | {f(r['gap_to_oracle'])} | {f(r['oracle_medium'])} | "
                     f"{f(r['floor_medium'])} | {f(r['psnr_train'])} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="cloud")
    parser.add_argument("--methods", nargs="+", default=["voxel", "ngp"])
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    parser.add_argument("--data", help="dataset cache root (default: mitsnerf's, `mitsnerf env` shows it)")
    parser.add_argument("--spp-train", type=int, help="training views' spp of every variant (default: the scene's)")
    parser.add_argument("--clean-spp", type=int, default=CLEAN_SPP, help="training views' spp of 'clean views'")
    args = parser.parse_args()
    from mitsnerf.outputs import data_cache

    data_root = Path(args.data) if args.data else data_cache()[0]

    import mitsnerf  # noqa: F401  (libLLVM before drjit)
    from mitsnerf import env
    from mitsnerf.bench.config import load_bench_config
    from mitsnerf.config import to_dict

    env.set_variant()
    bench = load_bench_config("default")
    rows = []
    for method in bench.methods:
        if method.name not in args.methods:
            continue
        config, train = bench.method_settings(method, quick=False)
        spec = None if args.spp_train is None else {"render.spp_train": args.spp_train}
        settings = {"config": config, "train": train, "eval": to_dict(bench.eval), "spec": spec}
        for name in args.variants:
            s = variant(method.name, name, settings, args.clean_spp)
            if s is not None:
                rows.append(run_one(method.name, name, s, data_root, args.scene))
                print(json.dumps(rows[-1]), flush=True)
    print()
    print(table(rows))


if __name__ == "__main__":
    main()
