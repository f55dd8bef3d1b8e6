#!/usr/bin/env bash
# nerfacto (nerfstudio, external) trained on a mitsnerf dataset and scored beside voxel, ngp and nerf:
# the "External tools" table of benchmarks/README.md. Runs from the repository's root wherever it is called.
#
#   export NERFSTUDIO_VENV=...                          # optional; default ~/.cache/mitsnerf/nerfstudio
#   benchmarks/external/setup_nerfstudio.sh            # once: the throw-away venv (several GB)
#   benchmarks/external/bench_nerfacto.sh [STEPS] [RAYS]
#
# 1. the default cloud at the NeRF-synthetic scale (`mitsnerf generate cloud --nerf-synthetic`, cached in data/);
# 2. nerfacto on its medium/ view, STEPS (default 800) of RAYS rays (default 1024), nerf's default budget
#    (run_nerfacto.sh, into runs/external/nerfacto-cloud). A finished run there is reused only if it was
#    made on the same dataset with the same STEPS and RAYS; anything else there is refused, never deleted;
# 3. `mitsnerf bench benchmarks/external/nerfacto.toml`: voxel, ngp and nerf at the default budgets on the
#    same dataset, nerfacto's renders scored as an external row, with the oracle and the noise floor.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
cd "$here/../.."
steps=${1:-800}
rays=${2:-1024}
mitsnerf=${MITSNERF:-.venv/bin/mitsnerf}
run=runs/external/nerfacto-cloud
python=$([ -x .venv/bin/python ] && echo .venv/bin/python || echo python3)

dataset=$($mitsnerf generate "$here/cloud_nerf_synthetic.toml" --out data | tail -n 1)
[ -d "$dataset/medium" ] || { echo "bench_nerfacto.sh: generate did not print a dataset folder: $dataset" >&2; exit 1; }
if [ -e "$run" ]; then
    "$python" - "$run" "$dataset" "$steps" "$rays" <<'PY' || exit 2
import json, os, sys
run, dataset, steps, rays = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
try:
    made = json.load(open(f"{run}/timings.json"))
    scored = json.load(open(f"{run}/scores.json"))["dataset"]
except (OSError, KeyError, ValueError) as exc:
    sys.exit(f"bench_nerfacto.sh: {run}: not a finished run ({exc}); move it away or remove it")
if (made["steps"], made["rays_per_step"]) != (steps, rays) or os.path.realpath(scored) != os.path.realpath(dataset):
    sys.exit(f"bench_nerfacto.sh: {run}: made with {made['steps']} x {made['rays_per_step']} on {scored}, "
             f"not {steps} x {rays} on {dataset}; move it away or remove it")
print(f"bench_nerfacto.sh: reusing {run} ({steps} x {rays})", file=sys.stderr)
PY
else
    MITSNERF="$mitsnerf" "$here/run_nerfacto.sh" "$dataset" "$run" "$steps" "$rays"
fi
$mitsnerf bench "$here/nerfacto.toml" --data data --results results
