#!/usr/bin/env bash
# A throw-away venv with nerfstudio, outside the project, for the external benchmarks
# (docs/notes/nerfstudio.md, "External tools"). Nothing of nerfstudio enters the repository.
#
#   benchmarks/external/setup_nerfstudio.sh [VENV]
#
# VENV defaults to $NERFSTUDIO_VENV, else ~/.cache/mitsnerf/nerfstudio. Versions: every package
# pinned by nerfstudio-constraints.txt (the pip freeze of the venv that produced the figures).
#
# torch is PyPI's build (its CUDA libraries come along, about 3 GB; it runs on the CPU). A CPU-only
# torch (2.13.0+cpu) does not work: PyPI's torchvision wheels link libtorch_cuda, so with a CPU
# torch `import torchvision` fails ("operator torchvision::nms does not exist") and so does every
# nerfstudio command. `torch===2.13.0` (exact string) keeps pip from taking a local +cpu wheel.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
venv=${1:-${NERFSTUDIO_VENV:-$HOME/.cache/mitsnerf/nerfstudio}}
python=${PYTHON:-python3}

"$python" -m venv "$venv"
"$venv/bin/pip" install --quiet --upgrade pip
"$venv/bin/pip" install -c "$here/nerfstudio-constraints.txt" \
    "torch===2.13.0" "torchvision===0.28.0" "nerfstudio==1.1.5"
"$venv/bin/python" - <<'PY'
import importlib.metadata as md
import torch, torchvision.ops  # torchvision's compiled ops must load against this torch
import nerfstudio.scripts.train  # noqa: F401  (what ns-train imports)
print("nerfstudio", md.version("nerfstudio"), "torch", torch.__version__, "torchvision", md.version("torchvision"),
      "CUDA available:", torch.cuda.is_available())
PY
echo "venv ready: $venv (ns-train, ns-render in $venv/bin)"
