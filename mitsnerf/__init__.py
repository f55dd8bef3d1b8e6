"""mitsnerf: Mitsuba 3 ground truth, Dr.Jit NeRFs, and the benchmarks between them.

Importing the package first makes drjit safe to load: it points
``DRJIT_LIBLLVM_PATH`` at a libLLVM >= 16, or raises
:class:`mitsnerf._llvm.LLVMError` with the fix, instead of letting drjit 1.5 abort
the process on LLVM 15. (Run from the ``mitsnerf`` command, the same problem is
one error line and exit status 2, as from ``python -m mitsnerf``.)
"""

import os as _os
import sys as _sys

from mitsnerf import _llvm
from mitsnerf import env as _env

__version__ = _env.package_version()

try:
    _env.prepare()
except _llvm.LLVMError as _exc:
    _argv0 = _sys.argv[0] if _sys.argv else ""
    if _os.path.basename(_argv0) == "mitsnerf" or _argv0 == "-m":  # the command, or python -m mitsnerf[.cli]
        print(f"mitsnerf: error: {_exc}", file=_sys.stderr)
        raise SystemExit(2) from None
    raise
