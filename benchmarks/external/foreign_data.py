"""Foreign data: `mitsnerf train DIR` with its defaults against nerfstudio's tensorf and nerfacto at the same wall time.

For each library scene: the dataset at the NeRF-synthetic scale (``mitsnerf generate SCENE --nerf-synthetic``,
cached in ``--data``), copied into the layout of the NeRF-synthetic data mitsnerf did not write: RGBA PNGs
(8-bit sRGB, transparent background, so white where the tools composite them) and
``transforms_{train,val,test}.json`` holding only ``camera_angle_x`` and each frame's ``file_path`` and
``transform_matrix`` (no box, no pixel centre, no manifest). Then on that folder:

1. nerfstudio's ``tensorf`` and ``nerfacto`` (``run_nerfstudio.sh``: ``ns-train``, ``ns-render``), ``--steps``
   of ``--rays`` each; their ``ns-train`` wall time, start-up included, is measured;
2. ``mitsnerf train FOLDER`` with its defaults (method, steps, rays) and ``--seconds`` the shorter of the two
   tools' wall times: training stops at its own budget or at that time, whichever comes first;
3. every row scored by ``mitsnerf score FOLDER RENDERS``: the test PNGs over white, linear and sRGB.

Prints one markdown table and writes ``OUT/foreign.json``; a finished run in ``OUT`` is reused::

    NERFSTUDIO_VENV=... .venv/bin/python benchmarks/external/foreign_data.py --scenes cloud plume nebula
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
SPLITS = ("train", "val", "test")
TOOLS = ("tensorf", "nerfacto")


def foreign_copy(medium: Path, out: Path) -> Path:
    """``medium`` (a NeRF-synthetic folder mitsnerf wrote) as a plain NeRF-synthetic folder ``out``: the same
    PNGs; transforms with ``camera_angle_x`` and each frame's ``file_path`` and ``transform_matrix`` only."""
    if (out / "transforms_test.json").is_file():
        return out
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    for split in SPLITS:
        doc = json.loads((medium / f"transforms_{split}.json").read_text())
        frames = [{"file_path": f["file_path"], "transform_matrix": f["transform_matrix"]} for f in doc["frames"]]
        (tmp / split).mkdir(parents=True)
        for f in frames:
            name = Path(f["file_path"]).name + ".png"
            shutil.copy(medium / Path(f["file_path"]).parent / name, tmp / split / name)
        plain = {"camera_angle_x": doc["camera_angle_x"], "frames": frames}
        (tmp / f"transforms_{split}.json").write_text(json.dumps(plain, indent=1))
    tmp.rename(out)
    return out


def run(cmd: list[str], log: Path | None = None, **env: str) -> str:
    """Run ``cmd`` from the repository's root; its stdout (also into ``log``); a failure stops the script."""
    proc = subprocess.run(cmd, cwd=ROOT, env={**os.environ, **env}, stdout=subprocess.PIPE, text=True)
    if log is not None:
        log.write_text(proc.stdout)
    if proc.returncode:
        sys.exit(f"foreign_data.py: {' '.join(cmd)}: exit status {proc.returncode}")
    return proc.stdout


def score(python: str, folder: Path, renders: Path, out: Path) -> dict:
    """``mitsnerf score``'s metrics of the EXR renders in ``renders`` (a folder, or a run directory)."""
    if not out.is_file():
        run([python, "-m", "mitsnerf", "score", str(folder), str(renders), "--format", "exr", "--out", str(out)])
    return json.loads(out.read_text())["metrics"]


def scene_rows(scene: str, args: argparse.Namespace) -> list[dict]:
    py = args.python
    dataset = Path(run([py, "-m", "mitsnerf", "generate", scene, "--nerf-synthetic", "--out", str(args.data)])
                   .strip().splitlines()[-1])
    folder = foreign_copy(dataset / "medium", args.out / scene / "data")
    rows = []
    for tool in TOOLS:
        where = args.out / scene / tool
        if not (where / "timings.json").is_file():
            shutil.rmtree(where, ignore_errors=True)
            run([str(HERE / "run_nerfstudio.sh"), tool, str(folder), str(where), str(args.steps), str(args.rays)],
                MITSNERF_PYTHON=py)
        t = json.loads((where / "timings.json").read_text())
        m = score(py, folder, where / "renders" / "rgba", where / "scores.json")
        rows.append({"scene": scene, "method": f"{tool} (nerfstudio)", "budget": f"{t['steps']} x {t['rays_per_step']}",
                     "wall_s": t["train_wall_s"], **_metrics(m)})
    seconds = min(r["wall_s"] for r in rows)
    variants = [("defaults", [])] + [(label, extra.split()) for label, extra in args.extra]
    for i, (label, extra) in enumerate(variants):
        rows.insert(i, mitsnerf_row(scene, folder, label, extra, seconds, args))
    return rows


def mitsnerf_row(scene: str, folder: Path, label: str, extra: list[str], seconds: float,
                 args: argparse.Namespace) -> dict:
    """``mitsnerf train FOLDER --seconds SECONDS EXTRA...`` (a finished run is reused), scored."""
    py, name = args.python, "mitsnerf" + "".join(f"_{w}" for w in label.split() if label != "defaults")
    where = args.out / scene / name
    if not (where / "wall.json").is_file():
        shutil.rmtree(where, ignore_errors=True)
        t0 = time.perf_counter()
        run([py, "-m", "mitsnerf", "train", str(folder), "--out", str(where), "--seconds", f"{seconds:.1f}",
             "--no-progress", *extra], log=args.out / scene / f"{name}.log")
        (where / "wall.json").write_text(json.dumps({"wall_s": round(time.perf_counter() - t0, 1)}))
    summary = json.loads((where / "metrics.json").read_text())
    train = json.loads((where / "config.json").read_text())["train"]  # the cap it ran under (EXTRA may set it)
    m = score(py, folder, where, args.out / scene / f"{name}-scores.json")
    return {"scene": scene, "method": f"mitsnerf {summary['method']} ({label})",
            "budget": f"{summary['steps']} x {train['batch_rays']} (stopped by {summary['stopped_by']}, "
                      f"cap {train['seconds']:.0f} s)",
            "wall_s": json.loads((where / "wall.json").read_text())["wall_s"], **_metrics(m)}


def _metrics(m: dict) -> dict:
    return {k: m.get(k) for k in ("psnr_test", "psnr_test_srgb", "ssim_test", "ssim_test_srgb")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["cloud", "plume", "nebula"], help="library scene names")
    ap.add_argument("--steps", type=int, default=800, help="the nerfstudio methods' steps (default 800)")
    ap.add_argument("--rays", type=int, default=1024, help="... of this many rays (default 1024)")
    ap.add_argument("--data", type=Path, default=ROOT / "data", help="dataset cache (default data/)")
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "external" / "foreign", help="runs and results")
    ap.add_argument("--python", default=str(ROOT / ".venv" / "bin" / "python"), help="the interpreter with mitsnerf")
    ap.add_argument("--extra", nargs=2, action="append", default=[], metavar=("LABEL", "ARGS"),
                    help="one more mitsnerf row: LABEL, and arguments added to its train command (repeatable; a "
                         "--seconds there replaces the shorter tool's time)")
    args = ap.parse_args()
    rows = [row for scene in args.scenes for row in scene_rows(scene, args)]
    (args.out / "foreign.json").write_text(json.dumps(rows, indent=1))
    keys = ("scene", "method", "budget", "wall_s", "psnr_test", "psnr_test_srgb", "ssim_test_srgb")
    print("| scene | method | steps x rays | train wall s | PSNR lin | PSNR sRGB | SSIM sRGB |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        cells = [f"{r[k]:.4f}" if k.startswith("ssim") and r[k] is not None
                 else f"{r[k]:.2f}" if isinstance(r[k], float) else str(r[k]) for k in keys]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
