#!/usr/bin/env bash
# mitsnerf on a CUDA machine with no package index: install, test, measure, in steps that each fit a
# 10-minute command. Run from the checkout's root, with the wheelhouse of scripts/offline_wheels.py:
#
#   bash scripts/gpu_check.sh WHEELHOUSE OUTDIR STEP [STEP ...]
#
# Steps (each writes OUTDIR/STEP.log, and JSON lines where a benchmark prints them):
#   install     scripts/offline_install.sh into /tmp/mitsnerf-site, nvidia-smi, the versions
#   tests       the suite on cuda_ad_rgb (the variant-dependent tests also on llvm_ad_rgb where it runs), every
#               failure, error and skip listed with its reason
#   groundtruth volpath samples/s through mitsnerf generate against raw Mitsuba (256x256, 4 views, 256 spp)
#   integrator  the integrator's samples/s forward and backward (256x256 views, N = 64, 128, 256)
#   mlp         the NeRF MLP: tensor mode, cooperative vectors fp32/fp16, JAX and PyTorch (this Python)
#   paper       mitsnerf bench paper (ground truth cached in ./data between calls on a warm machine)
#   paper-cloud the cloud row of paper alone (benchmarks/paper_cloud.toml), ngp first, ngp and nerf also on
#               fp16 cooperative vectors (what decides network_path = auto on CUDA), for a short lease
#
# A bench step's results (its tables, records and plots; no EXR or arrays: the archive must stay under the
# 16 MiB a device call returns per file, which paper-cloud's passed) are packed into OUTDIR/STEP-results.tgz.
# Environment: LIMIT_<STEP> (LIMIT_tests=150, LIMIT_paper_cloud=300) stops a step after that many seconds
# (exit 124), so that one slow step leaves the later ones their time; TEST_WORKERS=N runs the suite in N
# processes (default: one per core where pytest-xdist is installed; on the H200's 16 cores the suite took 163 s).
#
# install must have run on this machine first (it is idempotent). Nothing here reaches a network.
set -uo pipefail
WHEELS=${1:?usage: gpu_check.sh WHEELHOUSE OUTDIR STEP [STEP ...]}
OUT=${2:?usage: gpu_check.sh WHEELHOUSE OUTDIR STEP [STEP ...]}
shift 2
SITE=/tmp/mitsnerf-site
PYTHON=${PYTHON:-python3}
mkdir -p "$OUT"
export PYTHONPATH="$PWD:$SITE" PYTHONUNBUFFERED=1 MITSNERF_VARIANT=${MITSNERF_VARIANT:-cuda_ad_rgb}

run() {  # run STEP COMMAND...: log to OUT/STEP.log (within LIMIT_STEP s), say how it ended and how long it took
    local step=$1; shift
    local t0=$SECONDS limit_var="LIMIT_${step//-/_}"
    timeout "${!limit_var:-0}" "$@" > "$OUT/$step.log" 2>&1
    local rc=$?
    echo "$step: exit $rc, $((SECONDS - t0)) s" | tee -a "$OUT/summary.txt"
    tail -n 5 "$OUT/$step.log"
    return $rc
}

status=0
for step in "$@"; do
    case $step in
        install)
            run install bash -c 'nvidia-smi; PYTHON="$1" bash scripts/offline_install.sh "$2" "$3"' _ "$PYTHON" "$WHEELS" "$SITE" ;;
        tests)
            workers=${TEST_WORKERS:-}
            if [ -z "$workers" ] && "$PYTHON" -c "import xdist" 2>/dev/null; then workers=auto; fi
            run tests "$PYTHON" -m pytest -q -m "not slow" -p no:cacheprovider -rfEs ${workers:+-n "$workers"} ;;
        groundtruth)
            run groundtruth "$PYTHON" benchmarks/throughput_groundtruth.py --scene cloud --train-views 8 --test-views 2 --size 256 ;;
        integrator)
            run integrator "$PYTHON" benchmarks/throughput_integrator.py --scene cloud --size 256 --views 8 --samples 64 128 256 ;;
        mlp)
            run mlp "$PYTHON" benchmarks/throughput_mlp.py --batch-log2 14 16 18 20 --no-peak \
                --jax-python "$(command -v "$PYTHON")" --torch-python "$(command -v "$PYTHON")" ;;
        paper|paper-cloud)
            config=paper; [ "$step" = paper-cloud ] && config=benchmarks/paper_cloud.toml
            run "$step" "$PYTHON" -m mitsnerf bench "$config" --no-progress --data data --results "runs/gpu/$step"
            rc=$?
            tar -czf "$OUT/$step-results.tgz" --exclude='*.exr' --exclude='*.npz' --exclude='*.npy' \
                -C runs/gpu "$step" 2>/dev/null
            [ $rc -eq 0 ] ;;
        *)
            echo "gpu_check: unknown step '$step' (install, tests, groundtruth, integrator, mlp, paper, paper-cloud)" >&2
            exit 2 ;;
    esac || status=1
done
exit $status
