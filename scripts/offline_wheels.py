#!/usr/bin/env python3
"""Build a wheelhouse that installs mitsnerf's compiled dependencies on a machine with no registry.

A GPU machine that reaches no package index needs Mitsuba, Dr.Jit and OpenEXR carried to it as
wheels, often within a size limit (64 MiB for the whole upload, say). Mitsuba's wheel holds
thirteen variants' extension modules (about 1.3 MB each), headers, CMake files and the
spectral upsampling table ``data/srgb.coeff`` (9 MB, read only by spectral variants, lazily),
62.6 MB in all for 3.9.1 on CPython 3.12. This script downloads the three wheels for the target
Python and platform and rewrites Mitsuba's to keep only the variants named (by default the two
mitsnerf runs on and ``scalar_rgb``), dropping the headers, CMake files and, when no spectral
variant is kept, the spectral table. The wheel's ``RECORD`` is rewritten with the new hashes, so
pip installs it as usual. ``mitsuba.variants()`` is compiled in and still lists all thirteen;
mitsnerf checks that a variant's module is installed before it sets it.

Run where pip reaches the index (here), then carry the folder and install it there with
``scripts/offline_install.sh``::

    python3 scripts/offline_wheels.py wheelhouse                   # CPython 3.12, x86-64 Linux
    python3 scripts/offline_wheels.py wheelhouse --python-version 3.11 --budget-mib 0

It prints each wheel's size and the total, and exits non-zero when the total is over
``--budget-mib`` (0: no limit), leaving no partial wheelhouse behind.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

DEFAULT_VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
DEFAULT_PINS = {"mitsuba": "3.9.1", "drjit": "1.5.0", "OpenEXR": "3.5.3"}
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64")
DROPPED_DIRS = ("mitsuba/include/", "mitsuba/cmake/")
SPECTRAL_TABLE = "mitsuba/data/srgb.coeff"
_VARIANT_MODULE = re.compile(r"^mitsuba/((?:scalar|llvm_ad|cuda_ad)_[a-z_]+)\.cpython-[^/]+\.(?:so|pyd)$")


class WheelhouseError(RuntimeError):
    """The wheelhouse cannot be built as asked (one line, for the user)."""


def record_line(name: str, data: bytes) -> str:
    """A RECORD row: ``name,sha256=<urlsafe b64 without padding>,size`` (PEP 376/427).

    >>> record_line("a.txt", b"hi")
    'a.txt,sha256=j0NDRmSPa5bfid2pAcUXaxCm2Dlh3TwayItZstwyeqQ,2'
    """
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def keep_member(name: str, variants: tuple[str, ...]) -> bool:
    """Whether a trimmed Mitsuba wheel keeps the file ``name``.

    >>> keep_member("mitsuba/llvm_ad_rgb.cpython-312-x86_64-linux-gnu.so", ("llvm_ad_rgb",))
    True
    >>> keep_member("mitsuba/cuda_ad_spectral.cpython-312-x86_64-linux-gnu.so", ("llvm_ad_rgb",))
    False
    >>> keep_member("mitsuba/data/srgb.coeff", ("llvm_ad_rgb",)), keep_member("mitsuba/include/x.h", ())
    (False, False)
    """
    match = _VARIANT_MODULE.match(name)
    if match:
        return match.group(1) in variants
    if name.startswith(DROPPED_DIRS):
        return False
    if name == SPECTRAL_TABLE:
        return any("spectral" in v for v in variants)
    return True


def trim_mitsuba(src: Path, dst: Path, variants: tuple[str, ...]) -> list[str]:
    """Write ``dst``: the Mitsuba wheel ``src`` with only ``variants``; returns the names dropped."""
    dropped, rows = [], []
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        present = {m.group(1) for m in map(_VARIANT_MODULE.match, zin.namelist()) if m}
        missing = sorted(set(variants) - present)
        if missing:
            raise WheelhouseError(f"{src.name}: has no variant {', '.join(missing)} (it has {', '.join(sorted(present))})")
        record = next(n for n in zin.namelist() if n.endswith(".dist-info/RECORD"))
        for info in zin.infolist():
            name = info.filename
            if name == record:
                continue
            if not keep_member(name, variants):
                dropped.append(name)
                continue
            data = zin.read(info)
            info.compress_type = zipfile.ZIP_DEFLATED
            zout.writestr(info, data)
            if not name.endswith("/"):
                rows.append(record_line(name, data))
        zout.writestr(record, "\n".join(rows + [f"{record},,"]) + "\n")
    return dropped


def download(pins: dict[str, str], python_version: str, into: Path) -> dict[str, Path]:
    """``pip download`` each pinned wheel for the target Python and x86-64 Linux; name -> path."""
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--disable-pip-version-check",
           "--python-version", python_version, "--implementation", "cp", "-d", str(into)]
    for platform in PLATFORMS:
        cmd += ["--platform", platform]
    cmd += [f"{name}=={version}" for name, version in pins.items()]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise WheelhouseError(f"pip download failed: {tail}")
    wheels = {}
    for name in pins:
        found = sorted(into.glob(f"{name.lower()}-*.whl")) or sorted(into.glob(f"{name}-*.whl"))
        if not found:
            raise WheelhouseError(f"pip download wrote no wheel for {name}")
        wheels[name] = found[0]
    return wheels


def build(out: Path, pins: dict[str, str], python_version: str, variants: tuple[str, ...], budget_mib: float) -> int:
    """Download, trim and check the size; ``out`` is written whole or not at all. Returns total bytes."""
    if out.exists():
        raise WheelhouseError(f"{out}: already exists; remove it or name another folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:  # beside out: the final rename stays on one filesystem
        raw, stage = Path(tmp) / "raw", Path(tmp) / "stage"
        raw.mkdir()
        stage.mkdir()
        wheels = download(pins, python_version, raw)
        for name, path in wheels.items():
            if name == "mitsuba":
                dropped = trim_mitsuba(path, stage / path.name, variants)
                print(f"{path.name}: kept {', '.join(variants)}; dropped {len(dropped)} files "
                      f"({path.stat().st_size / 2**20:.1f} -> {(stage / path.name).stat().st_size / 2**20:.1f} MiB)")
            else:
                shutil.copy2(path, stage / path.name)
                print(f"{path.name}: {path.stat().st_size / 2**20:.1f} MiB")
        total = sum(p.stat().st_size for p in stage.iterdir())
        print(f"total: {total / 2**20:.1f} MiB" + (f" (budget {budget_mib:g} MiB)" if budget_mib else ""))
        if budget_mib and total > budget_mib * 2**20:
            raise WheelhouseError(f"the wheels take {total / 2**20:.1f} MiB, over --budget-mib {budget_mib:g}; keep fewer variants")
        stage.rename(out)
    return total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the wheelhouse folder to create (must not exist)")
    parser.add_argument("--python-version", default="3.12", help="the target machine's Python (default 3.12)")
    parser.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS), help="Mitsuba variants to keep")
    parser.add_argument("--budget-mib", type=float, default=56.0,
                        help="largest total size in MiB (default 56: leaves 8 of a 64 MiB upload to the checkout); 0: none")
    for name, version in DEFAULT_PINS.items():
        parser.add_argument(f"--{name.lower()}", default=version, help=f"{name} version (default {version})")
    args = parser.parse_args(argv)
    pins = {name: getattr(args, name.lower()) for name in DEFAULT_PINS}
    try:
        build(args.out.resolve(), pins, args.python_version, tuple(args.variants), args.budget_mib)
    except WheelhouseError as exc:
        print(f"offline_wheels: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
