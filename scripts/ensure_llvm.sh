#!/usr/bin/env bash
# Make sure a libLLVM >= 16 exists for drjit 1.5 (it aborts on LLVM 15).
# Installs Debian's libllvm19 when running as root with apt; otherwise prints the command to run.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
PY=${PYTHON:-python3}
if "$PY" "$here/mitsnerf/_llvm.py" --quiet 2>/dev/null; then
    exit 0
fi
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "mitsnerf: no libLLVM >= 16 found; installing Debian's libllvm19" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y -q libllvm19 >/dev/null 2>&1 || {
        apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libllvm19 >/dev/null 2>&1;
    } || true
fi
if ! "$PY" "$here/mitsnerf/_llvm.py"; then
    echo "mitsnerf: set-up stopped: run 'sudo apt-get install -y libllvm19' (or set DRJIT_LIBLLVM_PATH to a libLLVM >= 16), then try again" >&2
    exit 1
fi
