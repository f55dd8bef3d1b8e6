"""mitsnerf: Mitsuba 3 ground truth, Dr.Jit NeRFs, and the benchmarks between them.

Importing the package first makes drjit safe to load: it points
``DRJIT_LIBLLVM_PATH`` at a libLLVM >= 16, or raises
:class:`mitsnerf._llvm.LLVMError` with the fix, instead of letting drjit 1.5 abort
the process on LLVM 15.
"""

from mitsnerf import env as _env

__version__ = "0.1.0"

_env.prepare()
