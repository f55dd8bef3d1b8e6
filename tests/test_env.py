import os
import subprocess
import sys
from pathlib import Path

import pytest

from mitsnerf import _llvm, env

from .conftest import child_pythonpath


def test_llvm_version_from_library_names():
    assert _llvm.llvm_version_from_name("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert _llvm.llvm_version_from_name("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert _llvm.llvm_version_from_name("/usr/lib/x86_64-linux-gnu/libLLVM-14.0.6.so.1") == 14
    assert _llvm.llvm_version_from_name("/usr/lib/llvm-17/lib/libLLVM.so") == 17


def test_old_llvm_named_by_the_user_is_refused_with_the_fix(tmp_path):
    fake = tmp_path / "libLLVM-15.so.1"
    fake.write_bytes(b"")
    with pytest.raises(_llvm.LLVMError, match="apt-get install -y libllvm19"):
        _llvm.find_libllvm({"DRJIT_LIBLLVM_PATH": str(fake)})


def test_only_old_llvm_on_the_machine_is_refused(tmp_path):
    (tmp_path / "libLLVM-15.so.1").write_bytes(b"")
    with pytest.raises(_llvm.LLVMError, match=r"no libLLVM >= 16 found .*LLVM 15"):
        _llvm.find_libllvm({}, search_globs=(str(tmp_path / "libLLVM*.so*"),))


def test_newest_llvm_is_chosen(tmp_path):
    for name in ("libLLVM-15.so.1", "libLLVM.so.19.1", "libLLVM-17.so.1"):
        (tmp_path / name).write_bytes(b"")
    environ: dict[str, str] = {}
    path, version = _llvm.find_libllvm(environ, search_globs=(str(tmp_path / "libLLVM*.so*"),))
    assert version == 19 and path.endswith("libLLVM.so.19.1")


def test_configure_respects_a_good_user_choice():
    path, version = _llvm.find_libllvm()
    environ = {"DRJIT_LIBLLVM_PATH": path}
    assert _llvm.configure(environ) == (path, version)
    assert environ["DRJIT_LIBLLVM_PATH"] == path


def test_cli_with_old_llvm_prints_one_line_instead_of_aborting(tmp_path):
    fake = tmp_path / "libLLVM-15.so.1"
    fake.write_bytes(b"")
    exe = Path(sys.executable).parent / "mitsnerf"
    if not exe.exists():
        pytest.skip("console script not installed")
    proc = subprocess.run([str(exe), "env"], capture_output=True, text=True,
                          env={**os.environ, "DRJIT_LIBLLVM_PATH": str(fake), env.VARIANT_ENV: "llvm_ad_rgb"},
                          timeout=120)  # asking for LLVM: on a GPU machine an old LLVM alone leaves CUDA (prepare)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "LLVM 15 is too old" in lines[0]


def test_python_m_mitsnerf_with_old_llvm_prints_one_line_too(tmp_path):
    fake = tmp_path / "libLLVM-15.so.1"
    fake.write_bytes(b"")
    pythonpath = child_pythonpath(Path(env.__file__).resolve().parents[1])
    proc = subprocess.run([sys.executable, "-m", "mitsnerf", "env"], capture_output=True, text=True, cwd=tmp_path,
                          env={**os.environ, "DRJIT_LIBLLVM_PATH": str(fake), "PYTHONPATH": pythonpath,
                               env.VARIANT_ENV: "llvm_ad_rgb"}, timeout=120)  # else a GPU machine goes CUDA-only
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mitsnerf: error: ") and "LLVM 15 is too old" in lines[0]


def test_import_with_old_llvm_raises_a_clear_error_not_an_abort(tmp_path):
    fake = tmp_path / "libLLVM-15.so.1"
    fake.write_bytes(b"")
    proc = subprocess.run([sys.executable, "-c", "import mitsnerf"], capture_output=True, text=True,
                          env={**os.environ, "DRJIT_LIBLLVM_PATH": str(fake), env.VARIANT_ENV: "llvm_ad_rgb"},
                          timeout=120)  # asking for LLVM: on a GPU machine an old LLVM alone leaves CUDA (prepare)
    assert proc.returncode == 1  # a Python exception, not SIGABRT (-6)
    assert "LLVMError" in proc.stderr and "libllvm19" in proc.stderr


def test_an_old_llvm_on_a_gpu_machine_leaves_cuda_unless_llvm_is_asked_for(monkeypatch):
    """What the GPU machine showed: with a CUDA device, no usable libLLVM disables the LLVM backend with a
    warning naming the fix (drjit kept from loading the old library); asking for LLVM still fails."""
    def no_llvm(environ=None):
        raise _llvm.LLVMError("LLVM 15 is too old")

    monkeypatch.setattr(_llvm, "configure", no_llvm)
    monkeypatch.setattr(env, "cuda_device_count", lambda: 1)
    environ: dict[str, str] = {}
    with pytest.warns(UserWarning, match=r"LLVM backend is disabled, CUDA only \(.*libllvm19"):
        assert env.prepare(environ) is None
    assert environ["DRJIT_LIBLLVM_PATH"] == "/nonexistent/libLLVM-disabled.so"
    with pytest.raises(_llvm.LLVMError, match="too old"):
        env.prepare({env.VARIANT_ENV: "llvm_ad_rgb"})
    monkeypatch.setattr(env, "cuda_device_count", lambda: 0)
    with pytest.raises(_llvm.LLVMError, match="too old"):
        env.prepare({})


def test_variant_override_and_validation(monkeypatch):
    monkeypatch.setenv(env.VARIANT_ENV, "llvm_ad_rgb")
    assert env.default_variant() == "llvm_ad_rgb"
    with pytest.raises(env.EnvironmentError_, match="not supported"):
        env.set_variant("scalar_spectral")


def test_provenance_records_versions_and_commit():
    info = env.provenance()
    for key in ("variant", "mitsuba", "drjit", "llvm", "commit"):
        assert info[key]
    assert info["mitsuba"].startswith("3.9") and info["drjit"].startswith("1.5")


@pytest.mark.skipif("cuda_ad_rgb" in env.usable_variants(), reason="a CUDA device is usable here")
@pytest.mark.parametrize("source", ["--variant", "MITSNERF_VARIANT"])
def test_cuda_without_a_cuda_device_is_one_line_naming_its_source(source, monkeypatch, capsys):
    from mitsnerf.cli import main

    argv = ["env"]
    if source == "--variant":
        argv = ["--variant", "cuda_ad_rgb", "env"]
    else:
        monkeypatch.setenv("MITSNERF_VARIANT", "cuda_ad_rgb")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("mitsnerf: error:") == 1 and "Traceback" not in err and "jit_init_thread_state" not in err
    assert f"error: {source}: 'cuda_ad_rgb' cannot run here: no CUDA device" in err and "llvm_ad_rgb" in err
