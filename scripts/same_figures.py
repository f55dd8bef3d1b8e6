"""Do two versions of mitsnerf report the same figures? Every score a tiny workload produces, compared bit for bit.

    python scripts/same_figures.py --base REV [--keep DIR]

``REV`` (a commit, branch or tag of this repository) is extracted with ``git archive`` into a temporary
directory; the working tree is the other version. Each version runs the same workload through the command
line (``python -m mitsnerf`` in a child process whose PYTHONPATH is that version), on one Dr.Jit thread
(``--deterministic``), in its own directory:

- ``generate`` two tiny scenes (an isotropic cloud and a Henyey-Greenstein ``g = 0.5`` one: the reduced
  extinction's density scores): the manifests (noise floor, the medium-alone agreement tests, near/far
  coverage, the verification records);
- ``bench`` a tiny config over both scenes (a nerf, footprint 2, a tiny oracle, a held-out curve): every
  cell's record and its run's ``metrics.json``, the oracle's ``scores.json``;
- ``train`` a tiny nerf (footprint 2) and ``score`` its ``test/`` folder as a plain folder of renders, with
  and without ``--density`` (the true grid).

Every JSON value is compared with ``==`` after JSON's exact round trip of floats, except what differs from
run to run by nature (wall times, rates, memory, the worker process, provenance: :data:`VOLATILE`); the
versions' directories are written ``WORK`` in every path.
Exit 0 when every figure matches; else each difference on a line and exit 1. Minutes on two cores.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: Keys whose values differ between two runs of the same code: wall times and rates (any key holding one of
#: :data:`TIMED`), and these (memory, the worker process, provenance, the code's version).
VOLATILE = ("peak_rss_mb", "peak_rss_mb_at_start", "worker", "provenance", "started", "finished", "code_version")
TIMED = ("seconds", "rays_per_s", "samples_per_s")

SCENE = """\
name = "{name}"
[volume]
family = "cloud"
resolution = 16
seed = 1
sigma_t_scale = 30.0
params = {{ albedo = [0.8, 0.8, 0.8] }}
{phase}
[[lights]]
type = "constant"
radiance = [0.5, 0.55, 0.6]
[[lights]]
type = "directional"
direction = [-0.4, -0.8, -0.45]
irradiance = [4.0, 3.8, 3.5]
[cameras]
rig = "sphere"
n_train = 3
n_test = 2
width = 12
height = 12
fov = 40.0
radius = 2.2
seed = 0
[render]
spp_train = 4
spp_test = 8
seed = 0
noise_floor = true
"""

BENCH = """\
name = "figures"
scenes = ["{iso}", "{hg}"]
seeds = [0]
train = {{ steps = 6, batch_rays = 64, log_every = 2 }}
eval = {{ curve_points = 2, od_samples = 8, footprint = 2 }}
oracle = {{ spp = 2, resolution = 8, n_samples = 8, noise_replicas = 1 }}

[[methods]]
name = "nerf"
config = {{ network = {{ width = 8, depth = 1, features = 4, head_width = 8 }}, n_samples = 8 }}
"""

NERF = ("--method", "nerf", "--set", "network.width=8", "--set", "network.depth=1", "--set", "network.head_width=8",
        "--set", "network.features=4", "--set", "n_samples=8", "--batch-rays", "32", "--steps", "4",
        "--footprint", "2", "--deterministic")


def workload(tree: Path, work: Path) -> dict:
    """Run the workload with the mitsnerf of ``tree`` in ``work``; every figure it wrote, by file."""
    env = {**os.environ, "PYTHONPATH": str(tree), "MITSNERF_VARIANT": "llvm_ad_rgb"}

    def cli(*argv) -> None:
        subprocess.run([sys.executable, "-m", "mitsnerf", *map(str, argv)], cwd=work, env=env, check=True,
                       stdout=subprocess.DEVNULL)

    (work / "iso.toml").write_text(SCENE.format(name="iso", phase=""))
    (work / "hg.toml").write_text(SCENE.format(name="hg", phase='phase = { type = "hg", g = 0.5 }'))
    (work / "figures.toml").write_text(BENCH.format(iso=work / "iso.toml", hg=work / "hg.toml"))
    cli("bench", work / "figures.toml", "--data", work / "data", "--results", work / "results", "--deterministic",
        "--no-progress")
    (iso,) = (work / "data").glob("iso-*")
    cli("train", iso, "--out", work / "run", "--no-progress", *NERF)
    cli("score", iso, work / "run" / "test", "--out", work / "score.json")
    cli("score", iso, work / "run" / "test", "--density", iso / "volume" / "sigma_t.npy", "--out",
        work / "score_density.json")
    files = sorted(p for p in work.rglob("*.json") if not p.name.startswith("."))
    return {str(p.relative_to(work)): json.loads(p.read_text().replace(str(work), "WORK")) for p in files}


def differences(a, b, where: str = "") -> list[str]:
    """Every place where ``a`` and ``b`` differ, leaving out :data:`VOLATILE` keys."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k in VOLATILE or any(t in k for t in TIMED):
                continue
            at = f"{where}.{k}" if where else str(k)
            if k not in a or k not in b:
                out.append(f"{at}: only in {'the base' if k in a else 'the working tree'}")
            else:
                out += differences(a[k], b[k], at)
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: {len(a)} items, {len(b)} in the working tree"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{where}[{i}]")]
    return [] if a == b or (a != a and b != b) else [f"{where}: {a!r} (base) != {b!r} (working tree)"]


def count(value) -> int:
    """How many numbers ``value`` holds (what the comparison covered)."""
    if isinstance(value, dict):
        return sum(count(v) for v in value.values())
    if isinstance(value, list):
        return sum(count(v) for v in value)
    return int(isinstance(value, (int, float)) and not isinstance(value, bool))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", required=True, help="the other version: a commit, branch or tag")
    parser.add_argument("--keep", type=Path, help="do the work here and keep it (default: a temporary directory)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        base = root / "base-tree"
        base.mkdir(parents=True)
        archive = subprocess.run(["git", "-C", str(REPO), "archive", args.base], check=True, capture_output=True)
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive.stdout, check=True)
        figures = []
        for name, tree in (("base", base), ("working tree", REPO)):
            (root / name.replace(" ", "-")).mkdir()
            print(f"{name}: {tree}", file=sys.stderr)
            figures.append(workload(tree, root / name.replace(" ", "-")))
    found = differences(*figures)
    for line in found:
        print(line)
    print(f"{len(figures[0])} files, {count(figures[0])} numbers compared: "
          + ("the same" if not found else f"{len(found)} differences"))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
