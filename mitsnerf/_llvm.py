"""Find a libLLVM that drjit 1.5 can use (version >= 16), without importing drjit.

drjit 1.5 aborts the whole process (``LLVM ERROR: Cannot select: ... fminimum``) at
its first kernel compile when it loads LLVM 15 or older. This module finds the
newest libLLVM on the machine, refuses an old one with a clear message, and is
standard-library only so that the set-up script can run it before anything is
installed (``python3 mitsnerf/_llvm.py --require``).

>>> llvm_version_from_name('/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1')
19
>>> llvm_version_from_name('libLLVM-15.so.1')
15
>>> llvm_version_from_name('/usr/lib/llvm-17/lib/libLLVM.so') is None
False
>>> llvm_version_from_name('libfoo.so') is None
True
"""

from __future__ import annotations

import glob
import os
import re
import subprocess
import sys
from collections.abc import Mapping, MutableMapping

MIN_LLVM_VERSION = 16
INSTALL_HINT = "apt-get install -y libllvm19"

# The places drjit itself searches, plus the versioned LLVM trees Debian/Ubuntu use.
_SEARCH_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM.dylib",
    "/usr/local/opt/llvm/lib/libLLVM.dylib",
)

_NAME_PATTERNS = (
    re.compile(r"libLLVM-(\d+)(?:[.\d]*)?\.so"),  # libLLVM-15.so.1, libLLVM-14.0.6.so.1
    re.compile(r"libLLVM\.so\.(\d+)"),  # libLLVM.so.19.1
    re.compile(r"/llvm-(\d+)/"),  # /usr/lib/llvm-17/lib/libLLVM.so
)


class LLVMError(RuntimeError):
    """No usable libLLVM (>= 16) for drjit's LLVM backend."""


def llvm_version_from_name(path: str) -> int | None:
    """Major LLVM version encoded in a library path, or None if the name does not say."""
    for pattern in _NAME_PATTERNS:
        m = pattern.search(path)
        if m:
            return int(m.group(1))
    return None


def probe_llvm_version(path: str) -> int | None:
    """Major version of the library at ``path``.

    From its (resolved) file name where that says; otherwise by calling
    ``LLVMGetVersion`` (LLVM >= 16 exports it) in a child process, so that an old
    library is never loaded into this one.
    """
    for candidate in (path, os.path.realpath(path)):
        version = llvm_version_from_name(candidate)
        if version is not None:
            return version
    code = (
        "import ctypes,sys\n"
        "lib=ctypes.CDLL(sys.argv[1])\n"
        "f=getattr(lib,'LLVMGetVersion',None)\n"
        "if f is None: print(0)\n"
        "else:\n"
        "  a,b,c=ctypes.c_uint(),ctypes.c_uint(),ctypes.c_uint()\n"
        "  f(ctypes.byref(a),ctypes.byref(b),ctypes.byref(c)); print(a.value)\n"
    )
    try:
        out = subprocess.run(
            [sys.executable, "-c", code, path], capture_output=True, text=True, timeout=30
        )
        version = int(out.stdout.strip() or "-1")
    except (OSError, ValueError, subprocess.TimeoutExpired):
        return None
    if version < 0:
        return None
    # No LLVMGetVersion symbol: the library predates LLVM 16.
    return version if version > 0 else MIN_LLVM_VERSION - 1


def candidates(search_globs: tuple[str, ...] = _SEARCH_GLOBS) -> list[tuple[int, str]]:
    """Every libLLVM found on the machine as (major version, path), newest first."""
    found: dict[str, int] = {}
    for pattern in search_globs:
        for path in glob.glob(pattern):
            if not os.path.isfile(os.path.realpath(path)):
                continue
            version = probe_llvm_version(path)
            if version is not None:
                found[path] = version
    # One entry per real file, preferring the most specific name.
    by_real: dict[str, tuple[int, str]] = {}
    for path, version in found.items():
        real = os.path.realpath(path)
        if real not in by_real or len(path) > len(by_real[real][1]):
            by_real[real] = (version, path)
    return sorted(by_real.values(), key=lambda vp: (-vp[0], vp[1]))


def find_libllvm(
    environ: Mapping[str, str] | None = None, search_globs: tuple[str, ...] = _SEARCH_GLOBS
) -> tuple[str, int]:
    """The libLLVM drjit should load: ``(path, major version)``.

    ``DRJIT_LIBLLVM_PATH``, if set, is honoured but checked. Otherwise the newest
    library found is chosen. Raises :class:`LLVMError` (with the fix) when none is
    at least version 16.
    """
    env: Mapping[str, str] = os.environ if environ is None else environ
    user_path = env.get("DRJIT_LIBLLVM_PATH")
    if user_path:
        if not os.path.exists(user_path):
            raise LLVMError(
                f"DRJIT_LIBLLVM_PATH={user_path}: no such file; unset it or point it at "
                f"libLLVM >= {MIN_LLVM_VERSION} (install one with: {INSTALL_HINT})"
            )
        version = probe_llvm_version(user_path)
        if version is None or version < MIN_LLVM_VERSION:
            raise LLVMError(
                f"DRJIT_LIBLLVM_PATH={user_path}: LLVM {version if version else '?'} is too old; "
                f"drjit 1.5 aborts with LLVM < {MIN_LLVM_VERSION}. Install a newer one "
                f"({INSTALL_HINT}) and point DRJIT_LIBLLVM_PATH at it, or unset it"
            )
        return user_path, version
    found = candidates(search_globs)
    if not found or found[0][0] < MIN_LLVM_VERSION:
        have = ", ".join(f"LLVM {v} ({p})" for v, p in found) or "no libLLVM at all"
        raise LLVMError(
            f"no libLLVM >= {MIN_LLVM_VERSION} found (have: {have}); drjit 1.5 aborts with "
            f"older ones. Fix: {INSTALL_HINT} (or set DRJIT_LIBLLVM_PATH to a libLLVM >= "
            f"{MIN_LLVM_VERSION})"
        )
    version, path = found[0]
    return path, version


def configure(environ: MutableMapping[str, str] | None = None) -> tuple[str, int]:
    """Find libLLVM and set ``DRJIT_LIBLLVM_PATH`` if the user has not; returns ``(path, version)``."""
    env: MutableMapping[str, str] = os.environ if environ is None else environ
    path, version = find_libllvm(env)
    env.setdefault("DRJIT_LIBLLVM_PATH", path)
    return path, version


def _main(argv: list[str]) -> int:
    try:
        path, version = find_libllvm()
    except LLVMError as exc:
        print(f"mitsnerf: {exc}", file=sys.stderr)
        return 1
    if "--quiet" not in argv:
        print(f"LLVM {version}: {path}")
    return 0


if __name__ == "__main__":  # pragma: no cover - used by scripts/ensure_llvm.sh
    sys.exit(_main(sys.argv[1:]))
