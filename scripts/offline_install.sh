#!/usr/bin/env bash
# Install mitsnerf's compiled dependencies from a wheelhouse on a machine with no package index.
#
# The wheelhouse is built where pip reaches the index by scripts/offline_wheels.py (Mitsuba trimmed
# to the rgb variants, Dr.Jit, OpenEXR). numpy, pillow, tqdm and matplotlib (and pytest, for the
# tests) must already be installed. mitsnerf itself runs from this checkout:
#
#   bash scripts/offline_install.sh WHEELHOUSE [TARGET]      # TARGET: /tmp/mitsnerf-site
#   export PYTHONPATH=$PWD:TARGET
#   python3 -m mitsnerf --help ; python3 -m pytest -q -m "not slow"
#
# Prints the versions and Mitsuba variants installed; exits non-zero, naming what is missing, otherwise.
set -euo pipefail
WHEELS=${1:?usage: offline_install.sh WHEELHOUSE [TARGET]}
TARGET=${2:-/tmp/mitsnerf-site}
PYTHON=${PYTHON:-python3}
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)

shopt -s nullglob
wheels=("$WHEELS"/*.whl)
if [ ${#wheels[@]} -eq 0 ]; then
    echo "offline_install: $WHEELS: no wheels (build them with scripts/offline_wheels.py)" >&2
    exit 2
fi
"$PYTHON" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --disable-pip-version-check --target "$TARGET" "${wheels[@]}"

PYTHONPATH="$ROOT:$TARGET" "$PYTHON" - <<'PY'
import importlib.util, sys
missing = [m for m in ("numpy", "PIL", "tqdm", "matplotlib") if importlib.util.find_spec(m) is None]
if missing:
    sys.exit(f"offline_install: not installed here and not in the wheelhouse: {', '.join(missing)}")
import mitsnerf  # configures libLLVM (or CUDA only) before drjit loads
import drjit, mitsuba, OpenEXR
kept = [v for v in mitsuba.variants() if importlib.util.find_spec(f"mitsuba.{v}")]
print(f"mitsuba {mitsuba.__version__} ({', '.join(kept)}), drjit {drjit.__version__}, "
      f"OpenEXR {OpenEXR.__version__}, variant chosen here: {mitsnerf.env.default_variant()}")
PY
echo "export PYTHONPATH=$ROOT:$TARGET"
