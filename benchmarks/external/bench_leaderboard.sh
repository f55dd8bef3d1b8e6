#!/usr/bin/env bash
# The leaderboard (docs/notes/leaderboard.md, "The leaderboard"): every built-in method, the TensoRF-VM plugin and
# nerfstudio's CPU-capable methods on the default cloud at the NeRF-synthetic scale, one table.
# Runs from the repository's root wherever it is called.
#
#   export NERFSTUDIO_VENV=...                          # optional; default ~/.cache/mitsnerf/nerfstudio
#   benchmarks/external/setup_nerfstudio.sh            # once: the throw-away venv (several GB)
#   benchmarks/external/bench_leaderboard.sh
#
# 1. the dataset: `mitsnerf generate benchmarks/external/cloud_nerf_synthetic.toml` (cached in data/);
# 2. the plugin examples/mitsnerf-tensorf, installed into runs/external/leaderboard/plugin (not into .venv);
# 3. nerfstudio's nerfacto, tensorf, vanilla-nerf and mipnerf, each by run_nerfstudio.sh into
#    runs/external/leaderboard/METHOD, STEPS_<METHOD> steps of 1024 rays. A finished run there is reused only
#    if it was made on the same dataset with the same steps and rays; anything else there is refused, never
#    deleted;
# 4. `mitsnerf bench benchmarks/external/leaderboard.toml`: the built-in methods and the plugin trained, the
#    external renders scored, with the oracle and the noise floor.
#
# vanilla-nerf's and mipnerf's steps were chosen so that their training takes about nerfacto's wall time on the
# 2-core CPU that made the table (their 800 steps would take hours); the table's budget column says so.
# Not run here, for a CUDA machine (nerfacc's occupancy grid and gsplat's rasteriser have no CPU path):
#   run_nerfstudio.sh cannot run them; with nerfstudio on a GPU, the same flags with
#   `ns-train instant-ngp-bounded` and `ns-train splatfacto` (which takes a random-background model too).
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
cd "$here/../.."
rays=1024
declare -A steps=([nerfacto]=${STEPS_NERFACTO:-800} [tensorf]=${STEPS_TENSORF:-800}
                  [vanilla-nerf]=${STEPS_VANILLA_NERF:-24} [mipnerf]=${STEPS_MIPNERF:-24})
declare -A matched=([nerfacto]=steps [tensorf]=steps [vanilla-nerf]=seconds [mipnerf]=seconds)
python=$([ -x .venv/bin/python ] && echo .venv/bin/python || echo python3)
mitsnerf=("$python" -m mitsnerf)
root=runs/external/leaderboard

dataset=$("${mitsnerf[@]}" generate "$here/cloud_nerf_synthetic.toml" --out data | tail -n 1)
[ -d "$dataset/medium" ] || { echo "bench_leaderboard.sh: generate did not print a dataset folder: $dataset" >&2; exit 1; }
mkdir -p "$root"
if [ ! -d "$root/plugin/mitsnerf_tensorf" ]; then
    "$python" -m pip install -q --no-deps --no-build-isolation --target "$root/plugin" examples/mitsnerf-tensorf
fi

for method in nerfacto tensorf vanilla-nerf mipnerf; do
    run=$root/$method
    if [ -e "$run" ]; then
        "$python" - "$run" "$dataset" "${steps[$method]}" "$rays" <<'PY' || exit 2
import json, os, sys
run, dataset, steps, rays = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
try:
    made = json.load(open(f"{run}/timings.json"))
except (OSError, ValueError) as exc:
    sys.exit(f"bench_leaderboard.sh: {run}: not a finished run ({exc}); move it away or remove it")
if (made.get("steps"), made.get("rays_per_step")) != (steps, rays) \
        or os.path.realpath(made.get("dataset", "")) != os.path.realpath(dataset):
    sys.exit(f"bench_leaderboard.sh: {run}: made with {made.get('steps')} x {made.get('rays_per_step')} on "
             f"{made.get('dataset')}, not {steps} x {rays} on {dataset}; move it away or remove it")
print(f"bench_leaderboard.sh: reusing {run} ({steps} x {rays})", file=sys.stderr)
PY
    else
        MATCHED=${matched[$method]} MITSNERF_PYTHON="$python" \
            "$here/run_nerfstudio.sh" "$method" "$dataset" "$run" "${steps[$method]}" "$rays"
    fi
done
PYTHONPATH="$root/plugin${PYTHONPATH:+:$PYTHONPATH}" "${mitsnerf[@]}" bench "$here/leaderboard.toml" \
    --data data --results results "$@"
