"""The runtime environment: libLLVM for drjit, the Mitsuba variant, provenance.

Import order matters: :func:`mitsnerf._llvm.configure` must run before drjit is
imported, so ``mitsnerf/__init__.py`` calls :func:`prepare` first thing. Nothing
here keeps mutable module state: Mitsuba's variant is process-wide by Mitsuba's
design, and :func:`set_variant` is the one place that sets it.

Variant choice: ``--variant`` on the CLI, else ``$MITSNERF_VARIANT``, else
``cuda_ad_rgb`` when a CUDA device is usable, else ``llvm_ad_rgb``.
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
import platform
import subprocess
import warnings
from collections.abc import Mapping, MutableMapping
from functools import lru_cache
from pathlib import Path

from mitsnerf import _llvm

VARIANT_ENV = "MITSNERF_VARIANT"
SUPPORTED_VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")


class EnvironmentError_(RuntimeError):
    """The machine cannot run mitsnerf as configured (no LLVM, bad variant)."""


def cuda_device_count() -> int:
    """Number of CUDA devices the driver reports (0 without a driver), without drjit."""
    for name in ("libcuda.so.1", "libcuda.so", "nvcuda.dll"):
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        try:
            if lib.cuInit(0) != 0:
                return 0
            count = ctypes.c_int(0)
            if lib.cuDeviceGetCount(ctypes.byref(count)) != 0:
                return 0
            return int(count.value)
        except AttributeError:
            return 0
    return 0


def prepare(environ: MutableMapping[str, str] | None = None) -> tuple[str, int] | None:
    """Make drjit safe to import: point it at a libLLVM >= 16.

    Returns ``(path, version)`` of the library chosen, or None when none is usable
    but a CUDA device is (then drjit is kept from loading an old LLVM at all).
    Raises :class:`mitsnerf._llvm.LLVMError` when neither is available.
    """
    env: MutableMapping[str, str] = os.environ if environ is None else environ
    try:
        return _llvm.configure(env)
    except _llvm.LLVMError:
        wants_llvm = env.get(VARIANT_ENV, "").startswith("llvm")
        if wants_llvm or cuda_device_count() == 0:
            raise
        warnings.warn(
            "no libLLVM >= 16: the LLVM backend is disabled, CUDA only "
            f"({_llvm.INSTALL_HINT} enables it)",
            stacklevel=2,
        )
        # A path that does not exist keeps drjit from loading an LLVM that would abort it.
        env["DRJIT_LIBLLVM_PATH"] = "/nonexistent/libLLVM-disabled.so"
        return None


def default_variant(environ: Mapping[str, str] | None = None) -> str:
    """The variant to use when the caller names none (see module docstring)."""
    requested = (os.environ if environ is None else environ).get(VARIANT_ENV)
    if requested:
        return requested
    return "cuda_ad_rgb" if cuda_device_count() > 0 else "llvm_ad_rgb"


def _installed(variant: str) -> bool:
    """Whether Mitsuba's module of ``variant`` is installed (a wheel trimmed to some variants lacks the
    others, yet ``mitsuba.variants()``, compiled in, still lists them all)."""
    return importlib.util.find_spec(f"mitsuba.{variant}") is not None


def usable_variants() -> tuple[str, ...]:
    """The supported variants this machine can run, in :data:`SUPPORTED_VARIANTS` order: each one's
    Mitsuba module is installed (a wheel trimmed to some variants lacks the others) and its Dr.Jit
    backend is available (a libLLVM >= 16 for ``llvm_ad_rgb``, a CUDA device for ``cuda_ad_rgb``).

    >>> "llvm_ad_rgb" in usable_variants() or "cuda_ad_rgb" in usable_variants()
    True
    """
    import drjit as dr

    backend = {"llvm_ad_rgb": dr.JitBackend.LLVM, "cuda_ad_rgb": dr.JitBackend.CUDA}
    return tuple(v for v in SUPPORTED_VARIANTS if _installed(v) and dr.has_backend(backend[v]))


def set_variant(variant: str | None = None, source: str = "variant") -> str:
    """Select the Mitsuba variant (``None``: :func:`default_variant`) and return its name. A variant this
    machine cannot run is refused naming where it came from (``source``, e.g. ``--variant``; one from
    ``$MITSNERF_VARIANT`` names that), why, and the usable ones:

    >>> set_variant("llvm_ad_rgb")
    'llvm_ad_rgb'
    >>> set_variant("scalar_rgb", "--variant")
    Traceback (most recent call last):
    ...
    mitsnerf.env.EnvironmentError_: --variant: 'scalar_rgb' is not supported; choose one of llvm_ad_rgb, cuda_ad_rgb
    """
    import mitsuba as mi

    if not variant:
        variant, source = default_variant(), VARIANT_ENV if os.environ.get(VARIANT_ENV) else source
    if variant not in SUPPORTED_VARIANTS:
        raise EnvironmentError_(
            f"{source}: {variant!r} is not supported; choose one of {', '.join(SUPPORTED_VARIANTS)}"
        )
    why = _why_unusable(variant)
    if why:
        usable = ", ".join(usable_variants()) or "none"
        raise EnvironmentError_(f"{source}: {variant!r} cannot run here: {why} (usable here: {usable})")
    if mi.variant() != variant:
        try:
            mi.set_variant(variant)
        except Exception as exc:  # Mitsuba raises ImportError/RuntimeError by backend
            raise EnvironmentError_(f"{source}: cannot use {variant!r}: {exc}") from exc
    return variant


def _why_unusable(variant: str) -> str:
    """Why this machine cannot run supported ``variant`` ("" when it can)."""
    import drjit as dr

    if not _installed(variant):
        return "this Mitsuba has no module for it (a wheel trimmed to other variants)"
    if variant.startswith("cuda") and not dr.has_backend(dr.JitBackend.CUDA):
        return "no CUDA device or driver"
    if variant.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
        return f"no usable libLLVM >= 16 ({_llvm.INSTALL_HINT})"
    return ""


def package_version() -> str:
    """mitsnerf's version, from the installed package's metadata (pyproject.toml is its one source);
    ``"0+unknown"`` for a checkout imported from PYTHONPATH without being installed (the provenance's
    ``commit`` says which code it is then).

    >>> package_version() != ""
    True
    """
    from importlib import metadata

    try:
        return metadata.version("mitsnerf")
    except metadata.PackageNotFoundError:
        return "0+unknown"


@lru_cache(maxsize=1)
def git_commit() -> str:
    """The commit of the checkout mitsnerf runs from ('+dirty' if modified), or 'unknown'."""
    root = Path(__file__).resolve().parent.parent
    try:
        sha = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return sha + ("+dirty" if dirty else "")


def provenance() -> dict[str, object]:
    """What every output records: variant, library versions, LLVM, commit, machine."""
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    try:
        llvm = ".".join(str(v) for v in dr.detail.llvm_version())
    except Exception:  # no LLVM backend (CUDA-only machine)
        llvm = None
    return {
        "mitsnerf": package_version(),
        "commit": git_commit(),
        "variant": mi.variant(),
        "mitsuba": mi.__version__,
        "drjit": dr.__version__,
        "llvm": llvm,
        "libllvm_path": os.environ.get("DRJIT_LIBLLVM_PATH"),
        "numpy": np.__version__,
        "python": platform.python_version(),
        "machine": f"{platform.system()} {platform.machine()}, {os.cpu_count()} cores, {cpu_name()}"
        + (f", {gpu}" if (gpu := gpu_name()) else ""),
    }


def cpu_name(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The processor's model name (``/proc/cpuinfo``'s, else the platform's), ``cpu`` where neither says.

    >>> import tempfile
    >>> f = Path(tempfile.mkdtemp()) / "cpuinfo"
    >>> _ = f.write_text("processor\\t: 0\\nmodel name\\t: Intel(R) Xeon(R) Gold 6338 CPU @ 2.00GHz\\n")
    >>> cpu_name(f)
    'Intel(R) Xeon(R) Gold 6338 CPU @ 2.00GHz'
    """
    try:
        for line in cpuinfo.read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                return value.strip()
    except OSError:
        pass
    return platform.processor() or "cpu"


def gpu_name() -> str | None:
    """The first CUDA device's name when Mitsuba runs a CUDA variant (what a run on it measured), else None."""
    import mitsuba as mi

    if not (mi.variant() or "").startswith("cuda"):
        return None
    try:
        lib = ctypes.CDLL("libcuda.so.1")
        name = ctypes.create_string_buffer(256)
        if lib.cuInit(0) != 0 or lib.cuDeviceGetName(name, 256, 0) != 0:
            return None
    except (OSError, AttributeError):
        return None
    return name.value.decode(errors="replace") or None
