#!/usr/bin/env bash
# nerfstudio's nerfacto trained on a mitsnerf dataset's medium/ view (its NeRF-synthetic folder, read
# unchanged by nerfstudio's blender dataparser) on the CPU, its test views rendered by ns-render and
# scored by `mitsnerf score` as a benchmark cell (benchmarks/README.md, "External tools").
#
#   benchmarks/external/run_nerfacto.sh DATASET OUT [STEPS] [RAYS]
#
# DATASET: a `mitsnerf generate ... --nerf-synthetic` dataset. OUT: a new folder for the run.
# STEPS (default 1000) of RAYS rays each (default 4096, nerfacto's own batch).
# Environment: NERFSTUDIO_VENV (setup_nerfstudio.sh's venv; default ~/.cache/mitsnerf/nerfstudio),
# MITSNERF (the command that runs mitsnerf; default .venv/bin/mitsnerf, else mitsnerf on PATH).
#
# What is changed from nerfacto's defaults, and why:
# - `blender-data --alpha-color None` and `--pipeline.model.background-color random`: nerfstudio keeps
#   the RGBA images and composites both the image and its render over a random colour each step, so
#   the model learns the medium alone with its opacity (the parser's default composites on white, and
#   nerfacto's default background, last_sample, would learn that white as part of the scene). Only
#   with a random background does `ns-render --rendered-output-names rgba` write the opacity
#   (accumulation) as alpha; otherwise alpha is 1 everywhere.
# - `--pipeline.model.camera-optimizer.mode off`: the poses are exact (mitsnerf renders them); pose
#   refinement (nerfacto's SO3xR3 default) could only move the training cameras away from the test ones.
# - `--machine.device-type cpu` (mixed precision is then off by nerfstudio's own rule), `--vis tensorboard`
#   (no viewer server), and the step budget.
#
# The renders: test/rgba/r_NNN.png, straight colour (rgb / accumulation) and alpha = accumulation, 8-bit
# sRGB as the training PNGs; `mitsnerf score` composites them over the dataset's background (its sky),
# matched to the test frames by file name.
set -euo pipefail

if [ $# -lt 2 ]; then
    sed -n '2,12p' "$0" >&2
    exit 2
fi
dataset=$(cd "$1" && pwd)
out=$2
steps=${3:-1000}
rays=${4:-4096}
save_every=${SAVE_EVERY:-$steps}
venv=${NERFSTUDIO_VENV:-$HOME/.cache/mitsnerf/nerfstudio}
if [ -n "${MITSNERF:-}" ]; then
    read -r -a mitsnerf <<< "$MITSNERF"
elif [ -x .venv/bin/mitsnerf ]; then
    mitsnerf=(.venv/bin/mitsnerf)
else
    mitsnerf=(mitsnerf)
fi
[ -d "$dataset/medium" ] || { echo "run_nerfacto.sh: $dataset/medium: not found (a mitsnerf dataset?)" >&2; exit 2; }
[ -x "$venv/bin/ns-train" ] || { echo "run_nerfacto.sh: $venv/bin/ns-train: not found (run setup_nerfstudio.sh)" >&2; exit 2; }
[ ! -e "$out" ] || { echo "run_nerfacto.sh: $out: exists already" >&2; exit 2; }
mkdir -p "$out"
now() { date +%s.%N; }

launch=("$venv/bin/python" "$(dirname "$0")/ns_launch.py")

t0=$(now)
"${launch[@]}" train nerfacto \
    --machine.device-type cpu --vis tensorboard \
    --max-num-iterations "$steps" --steps-per-save "$save_every" --save-only-latest-checkpoint False \
    --pipeline.datamanager.train-num-rays-per-batch "$rays" \
    --pipeline.model.background-color random \
    --pipeline.model.camera-optimizer.mode off \
    --pipeline.model.num-levels 8 --pipeline.model.max-res 256 \
    --pipeline.model.num-proposal-samples-per-ray 64 32 --pipeline.model.num-nerf-samples-per-ray 32 \
    --output-dir "$out/ns" --experiment-name nerfacto --timestamp run \
    blender-data --data "$dataset/medium" --alpha-color None 2>&1 | tee "$out/train.log"
t1=$(now)
"${launch[@]}" render dataset --load-config "$out/ns/nerfacto/nerfacto/run/config.yml" \
    --split test --rendered-output-names rgba --image-format png --output-path "$out/renders" 2>&1 | tee "$out/render.log"
t2=$(now)
"${mitsnerf[@]}" score "$dataset" "$out/renders/test/rgba" --name nerfacto --out "$out/scores.json"
"$venv/bin/python" - "$out" "$steps" "$rays" "$t0" "$t1" "$t2" <<'PY'
import json, sys
out, steps, rays, t0, t1, t2 = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), *map(float, sys.argv[4:])
info = {"steps": steps, "rays_per_step": rays, "train_wall_s": round(t1 - t0, 1), "render_wall_s": round(t2 - t1, 1)}
json.dump(info, open(f"{out}/timings.json", "w"), indent=1)
print(json.dumps(info))
PY
