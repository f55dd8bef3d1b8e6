#!/usr/bin/env bash
# One of nerfstudio's methods trained on a mitsnerf dataset's medium/ view (its NeRF-synthetic folder, read
# unchanged by nerfstudio's blender dataparser) on the CPU, its test views rendered by ns-render into RGBA EXRs
# for `mitsnerf score` or a bench config's [[external]] entry (docs/notes/leaderboard.md, "The leaderboard").
#
#   benchmarks/external/run_nerfstudio.sh METHOD DATASET OUT [STEPS] [RAYS]
#
# METHOD: nerfacto, tensorf, vanilla-nerf, mipnerf, or on a GPU instant-ngp, splatfacto (nerfstudio's names). DATASET: a `mitsnerf generate
# ... --nerf-synthetic` dataset (its medium/ is trained on), or a NeRF-synthetic folder of RGBA PNGs
# (transforms_{train,val,test}.json). OUT: a new folder for the run. STEPS (default 800) of RAYS rays each
# (default 1024). Environment: NERFSTUDIO_VENV (setup_nerfstudio.sh's venv; default
# ~/.cache/mitsnerf/nerfstudio), MITSNERF_PYTHON (the interpreter with mitsnerf; default .venv/bin/python),
# MATCHED ("steps", the default, or "seconds": what STEPS was chosen to equal across the table's rows;
# written to timings.json for the table's budget column), NS_DEVICE (default cpu; cuda for instant-ngp and
# splatfacto, which have no CPU path, on a GPU machine with nerfstudio's CUDA extensions installed).
#
# What is changed from the methods' defaults, and why (the same for every method where it applies):
# - `blender-data --alpha-color None` and `--pipeline.model.background-color random`: nerfstudio keeps
#   the RGBA images and composites both the image and its render over a random colour each step, so
#   the model learns the medium alone with its opacity (the parser's default composites on white, and
#   a white or last-sample background would be learnt as part of the scene).
# - `--pipeline.model.camera-optimizer.mode off` (nerfacto, tensorf): the poses are exact (mitsnerf renders
#   them); pose refinement could only move the training cameras away from the test ones.
# - nerfacto: 8 hash levels to resolution 256 (the data's 64^3 grid at 64x64 pixels), proposal samples 64/32
#   and 32 NeRF samples. Without tiny-cuda-nn (CUDA only) nerfstudio's hash encoding is its PyTorch one.
# - `--machine.device-type cpu` (mixed precision is then off by nerfstudio's own rule), `--vis tensorboard`
#   (no viewer server), the step budget and the rays per step. Everything else is the method's default
#   (vanilla-nerf and mipnerf: near 2, far 6, NeRF-synthetic's; tensorf: the blender scene box).
#
# The renders: ns-render's unquantised float outputs (raw-rgb and raw-accumulation; raw-rgb_fine and
# raw-accumulation_fine for vanilla-nerf and mipnerf, which have no rgba output), turned by ns_rgba.py into
# renders/rgba/r_NNN.exr: straight linear colour and alpha = accumulation, which `mitsnerf score` composites
# over the dataset's background. timings.json: steps, rays_per_step, train_wall_s (ns-train's wall time,
# start-up included), render_wall_s, matched.
set -euo pipefail

if [ $# -lt 3 ]; then
    sed -n '2,16p' "$0" >&2
    exit 2
fi
method=$1
dataset=$(cd "$2" && pwd)
out=$3
steps=${4:-800}
rays=${5:-1024}
matched=${MATCHED:-steps}
here=$(cd "$(dirname "$0")" && pwd)
venv=${NERFSTUDIO_VENV:-$HOME/.cache/mitsnerf/nerfstudio}
python=${MITSNERF_PYTHON:-.venv/bin/python}
case "$method" in
    nerfacto)
        extra=(--pipeline.model.camera-optimizer.mode off
               --pipeline.model.num-levels 8 --pipeline.model.max-res 256
               --pipeline.model.num-proposal-samples-per-ray 64 32 --pipeline.model.num-nerf-samples-per-ray 32)
        outputs=(rgb accumulation) ;;
    tensorf)
        extra=(--pipeline.model.camera-optimizer.mode off)
        outputs=(rgb accumulation) ;;
    vanilla-nerf|mipnerf)
        extra=()
        outputs=(rgb_fine accumulation_fine) ;;
    instant-ngp|splatfacto)  # CUDA only (nerfacc's occupancy grid, gsplat's rasteriser): NS_DEVICE=cuda
        extra=()
        outputs=(rgb accumulation) ;;
    *) echo "run_nerfstudio.sh: $method: not one of nerfacto, tensorf, vanilla-nerf, mipnerf, instant-ngp, splatfacto" >&2
       exit 2 ;;
esac
case "$matched" in steps|seconds) ;; *) echo "run_nerfstudio.sh: MATCHED=$matched: not steps or seconds" >&2; exit 2 ;; esac
if [ -d "$dataset/medium" ]; then
    data=$dataset/medium
elif [ -f "$dataset/transforms_train.json" ]; then
    data=$dataset
else
    echo "run_nerfstudio.sh: $dataset: neither a mitsnerf dataset (medium/) nor NeRF-synthetic (transforms_train.json)" >&2
    exit 2
fi
[ -x "$venv/bin/ns-train" ] || { echo "run_nerfstudio.sh: $venv/bin/ns-train: not found (run setup_nerfstudio.sh)" >&2; exit 2; }
[ -x "$python" ] || { echo "run_nerfstudio.sh: $python: not found (set MITSNERF_PYTHON)" >&2; exit 2; }
[ ! -e "$out" ] || { echo "run_nerfstudio.sh: $out: exists already" >&2; exit 2; }
mkdir -p "$out"
now() { date +%s.%N; }
launch=("$venv/bin/python" "$here/ns_launch.py")

t0=$(now)
"${launch[@]}" train "$method" \
    --machine.device-type "${NS_DEVICE:-cpu}" --vis tensorboard \
    --max-num-iterations "$steps" --steps-per-save "$steps" --save-only-latest-checkpoint False \
    --pipeline.datamanager.train-num-rays-per-batch "$rays" \
    --pipeline.model.background-color random "${extra[@]}" \
    --output-dir "$out/ns" --experiment-name "$method" --timestamp run \
    blender-data --data "$data" --alpha-color None 2>&1 | tee "$out/train.log"
t1=$(now)
"${launch[@]}" render dataset --load-config "$out/ns/$method/$method/run/config.yml" \
    --split test --rendered-output-names "raw-${outputs[0]}" "raw-${outputs[1]}" --output-path "$out/raw" 2>&1 \
    | tee "$out/render.log"
t2=$(now)
"$python" "$here/ns_rgba.py" "$out/raw/test" "$out/renders/rgba" --rgb "${outputs[0]}" --acc "${outputs[1]}"
"$python" - "$out" "$method" "$steps" "$rays" "$matched" "$dataset" "$t0" "$t1" "$t2" <<'PY'
import json, sys
out, method, steps, rays, matched, dataset, t0, t1, t2 = sys.argv[1:]
info = {"method": method, "dataset": dataset, "steps": int(steps), "rays_per_step": int(rays), "matched": matched,
        "train_wall_s": round(float(t1) - float(t0), 1), "render_wall_s": round(float(t2) - float(t1), 1)}
json.dump(info, open(f"{out}/timings.json", "w"), indent=1)
print(json.dumps(info))
PY
