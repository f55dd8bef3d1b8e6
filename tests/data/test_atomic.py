"""Atomic files and directories: complete under the final name, or absent; no temporaries left."""

import mitsnerf  # noqa: F401

import json
import math
import os

import pytest

from mitsnerf.data.atomic import (
    atomic_dir,
    atomic_path,
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    clean_stale_temps,
)


def _names(d):
    return sorted(p.name for p in d.iterdir())


def test_file_writes_replace_and_leave_no_temporaries(tmp_path):
    atomic_write_bytes(tmp_path / "a.bin", b"\x00\x01")
    atomic_write_text(tmp_path / "a.txt", "first")
    atomic_write_text(tmp_path / "a.txt", "second")
    atomic_write_json(tmp_path / "a.json", {"z": 1, "a": [0.5]})
    assert (tmp_path / "a.bin").read_bytes() == b"\x00\x01"
    assert (tmp_path / "a.txt").read_text() == "second"
    assert list(json.loads((tmp_path / "a.json").read_text())) == ["z", "a"]  # insertion order
    assert _names(tmp_path) == ["a.bin", "a.json", "a.txt"]
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o666 & ~umask


def test_json_with_nan_raises_and_writes_nothing(tmp_path):
    with pytest.raises(ValueError):
        atomic_write_json(tmp_path / "bad.json", {"x": math.nan})
    assert _names(tmp_path) == []


def test_atomic_path_removes_temporary_on_error(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "img.exr") as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("writer failed")
    assert _names(tmp_path) == []


def test_atomic_dir_success(tmp_path):
    final = tmp_path / "ds"
    with atomic_dir(final) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".ds.tmp-")
        (tmp / "x.txt").write_text("x")
        assert not final.exists()
    assert _names(tmp_path) == ["ds"]
    assert (final / "x.txt").read_text() == "x"


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_atomic_dir_failure_leaves_nothing(tmp_path, exc):
    final = tmp_path / "ds"
    with pytest.raises(type(exc)):
        with atomic_dir(final) as tmp:
            (tmp / "partial.txt").write_text("half")
            raise exc
    assert _names(tmp_path) == []


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_atomic_dir_failure_keeps_existing_final(tmp_path, exc):
    final = tmp_path / "ds"
    final.mkdir()
    (final / "old.txt").write_text("old")
    with pytest.raises(type(exc)):
        with atomic_dir(final, overwrite=True) as tmp:
            (tmp / "new.txt").write_text("new")
            raise exc
    assert _names(tmp_path) == ["ds"]
    assert _names(final) == ["old.txt"]


def test_atomic_dir_overwrite_semantics(tmp_path):
    final = tmp_path / "ds"
    final.mkdir()
    (final / "old.txt").write_text("old")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        with atomic_dir(final):
            pytest.fail("the body must not run when final exists and overwrite is False")
    assert _names(final) == ["old.txt"]
    with atomic_dir(final, overwrite=True) as tmp:
        (tmp / "new.txt").write_text("new")
    assert _names(final) == ["new.txt"]
    assert _names(tmp_path) == ["ds"]


def test_atomic_dir_refuses_final_that_appears_meanwhile(tmp_path):
    final = tmp_path / "ds"
    with pytest.raises(FileExistsError, match="appeared"):
        with atomic_dir(final) as tmp:
            (tmp / "new.txt").write_text("new")
            final.mkdir()
    assert _names(tmp_path) == ["ds"]
    assert _names(final) == []


def test_clean_stale_temps(tmp_path):
    (tmp_path / ".ds.tmp-abc123").mkdir()
    (tmp_path / ".ds.tmp-abc123" / "f").write_text("x")
    (tmp_path / ".a.json.tmp-ff").write_text("x")
    (tmp_path / "ds").mkdir()
    (tmp_path / ".hidden").write_text("keep")
    assert clean_stale_temps(tmp_path, min_age_s=3600) == []
    removed = clean_stale_temps(tmp_path)
    assert [p.name for p in removed] == [".a.json.tmp-ff", ".ds.tmp-abc123"]
    assert _names(tmp_path) == [".hidden", "ds"]
    assert clean_stale_temps(tmp_path / "missing") == []
