"""scripts/offline_wheels.py: a Mitsuba wheel trimmed to some variants still installs (RECORD true),
and a wheelhouse is written whole or not at all. A fabricated wheel stands in for the 60 MB one."""

from __future__ import annotations

import doctest
import importlib.util
import zipfile
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "offline_wheels.py"
TAG = "cpython-312-x86_64-linux-gnu.so"
MEMBERS = {
    "mitsuba/__init__.py": b"# init\n",
    f"mitsuba/scalar_rgb.{TAG}": b"scalar",
    f"mitsuba/llvm_ad_rgb.{TAG}": b"llvm rgb",
    f"mitsuba/llvm_ad_spectral.{TAG}": b"llvm spectral",
    f"mitsuba/cuda_ad_rgb.{TAG}": b"cuda rgb",
    f"mitsuba/mitsuba_ext.{TAG}": b"ext",
    "mitsuba/libmitsuba.so": b"lib",
    "mitsuba/plugins/volpath.so": b"volpath",
    "mitsuba/include/mitsuba/core/fwd.h": b"header",
    "mitsuba/cmake/mitsubaConfig.cmake": b"cmake",
    "mitsuba/data/srgb.coeff": b"table" * 100,
    "mitsuba/data/ior/gold.eta.spd": b"ior",
    "mitsuba-3.9.1.dist-info/METADATA": b"Name: mitsuba\n",
}


@pytest.fixture(scope="module")
def wheels():
    spec = importlib.util.spec_from_file_location("offline_wheels", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def fake_wheel(path: Path) -> Path:
    with zipfile.ZipFile(path, "w") as z:
        for name, data in MEMBERS.items():
            z.writestr(name, data)
        z.writestr("mitsuba-3.9.1.dist-info/RECORD", "stale\n")
    return path


def test_doctests(wheels):
    result = doctest.testmod(wheels)
    assert result.attempted >= 4 and result.failed == 0


def test_trim_keeps_the_variants_named_and_what_every_variant_needs(wheels, tmp_path):
    src = fake_wheel(tmp_path / "mitsuba-3.9.1-cp312-cp312-manylinux_2_28_x86_64.whl")
    dst = tmp_path / "out.whl"
    dropped = wheels.trim_mitsuba(src, dst, ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"))
    kept = set(zipfile.ZipFile(dst).namelist())
    assert set(dropped) == {f"mitsuba/llvm_ad_spectral.{TAG}", "mitsuba/include/mitsuba/core/fwd.h",
                            "mitsuba/cmake/mitsubaConfig.cmake", "mitsuba/data/srgb.coeff"}
    assert kept == (set(MEMBERS) - set(dropped)) | {"mitsuba-3.9.1.dist-info/RECORD"}


def test_trim_keeps_the_spectral_table_for_a_spectral_variant(wheels, tmp_path):
    src = fake_wheel(tmp_path / "in.whl")
    wheels.trim_mitsuba(src, tmp_path / "out.whl", ("llvm_ad_spectral",))
    assert "mitsuba/data/srgb.coeff" in zipfile.ZipFile(tmp_path / "out.whl").namelist()


def test_the_record_lists_every_file_with_its_true_hash(wheels, tmp_path):
    src = fake_wheel(tmp_path / "in.whl")
    wheels.trim_mitsuba(src, tmp_path / "out.whl", ("llvm_ad_rgb",))
    with zipfile.ZipFile(tmp_path / "out.whl") as z:
        rows = z.read("mitsuba-3.9.1.dist-info/RECORD").decode().splitlines()
        files = [n for n in z.namelist() if not n.endswith("RECORD")]
        expected = {wheels.record_line(n, z.read(n)) for n in files}
    assert set(rows) == expected | {"mitsuba-3.9.1.dist-info/RECORD,,"}


def test_a_variant_the_wheel_lacks_is_refused_by_name(wheels, tmp_path):
    src = fake_wheel(tmp_path / "in.whl")
    with pytest.raises(wheels.WheelhouseError, match="has no variant cuda_ad_mono"):
        wheels.trim_mitsuba(src, tmp_path / "out.whl", ("llvm_ad_rgb", "cuda_ad_mono"))


def test_over_budget_leaves_no_wheelhouse(wheels, tmp_path, monkeypatch, capsys):
    def download(pins, python_version, into):
        return {"mitsuba": fake_wheel(into / "mitsuba-3.9.1-cp312-cp312-manylinux_2_28_x86_64.whl")}

    monkeypatch.setattr(wheels, "download", download)
    out = tmp_path / "house"
    assert wheels.main([str(out), "--budget-mib", "0.000001"]) == 2
    assert not out.exists() and "over --budget-mib" in capsys.readouterr().err
    assert wheels.main([str(out), "--budget-mib", "0"]) == 0
    assert [p.name for p in out.iterdir()] == ["mitsuba-3.9.1-cp312-cp312-manylinux_2_28_x86_64.whl"]
    assert wheels.main([str(out)]) == 2 and "already exists" in capsys.readouterr().err
