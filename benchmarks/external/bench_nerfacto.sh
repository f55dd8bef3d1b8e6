#!/usr/bin/env bash
# nerfacto (nerfstudio, external) trained on a mitsnerf dataset and scored beside voxel, ngp and nerf:
# the "External tools" table of benchmarks/README.md, from the repository's root.
#
#   benchmarks/external/setup_nerfstudio.sh            # once: the throw-away venv (several GB)
#   benchmarks/external/bench_nerfacto.sh [STEPS] [RAYS]
#
# 1. the default cloud at the NeRF-synthetic scale (`mitsnerf generate cloud --nerf-synthetic`, cached in data/);
# 2. nerfacto on its medium/ view, STEPS (default 800) of RAYS rays (default 1024), nerf's default budget
#    (run_nerfacto.sh, into runs/external/nerfacto-cloud; an existing run there is kept);
# 3. `mitsnerf bench benchmarks/external/nerfacto.toml`: voxel, ngp and nerf at the default budgets on the
#    same dataset, nerfacto's renders scored as an external row, with the oracle and the noise floor.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
steps=${1:-800}
rays=${2:-1024}
mitsnerf=${MITSNERF:-.venv/bin/mitsnerf}
run=runs/external/nerfacto-cloud

dataset=$($mitsnerf generate "$here/cloud_nerf_synthetic.toml" --out data | tail -n 1)
[ -d "$dataset/medium" ] || { echo "bench_nerfacto.sh: generate did not print a dataset folder: $dataset" >&2; exit 1; }
if [ ! -e "$run/renders/test/rgba" ]; then
    rm -rf "$run"
    MITSNERF="$mitsnerf" "$here/run_nerfacto.sh" "$dataset" "$run" "$steps" "$rays"
fi
$mitsnerf bench "$here/nerfacto.toml" --data data --results results
