"""Dataset generation: layout, manifest, cameras as rendered, cache, invalidation, atomicity, determinism."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mitsnerf.data.images import read_exr
from mitsnerf.data.transforms import read_transforms
from mitsnerf import generate as gen
from mitsnerf.scene import render as scene_render
from mitsnerf.scene.lights import bake_sky
from mitsnerf.scene.rigs import camera_rig
from mitsnerf.scene.spec import parse_scene
from mitsnerf.scene.to_mitsuba import volume_grids

from .conftest import TINY

GL_TO_MITSUBA = np.diag([-1.0, 1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """The tiny dataset, generated once, with the sensors Mitsuba rendered with recorded."""
    spec = parse_scene(json.loads(json.dumps(TINY)), "tiny.toml")
    root = tmp_path_factory.mktemp("data")
    used: list[np.ndarray] = []
    real = scene_render.load_sensor

    def recording(camera, spp):
        sensor = real(camera, spp)
        used.append(np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4))
        return sensor

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(scene_render, "load_sensor", recording)
        path = gen.generate_dataset(spec, root, progress=False)
    return spec, root, path, used


def test_layout_and_manifest(generated):
    spec, root, path, _ = generated
    assert path.parent == root and path.name.startswith("tiny-") and len(path.name) == len("tiny-") + 12
    m = json.loads((path / "manifest.json").read_text())
    assert m["format_version"] == gen.FORMAT_VERSION and path.name.endswith(m["hash"][:12])
    assert parse_scene(m["spec"], "manifest") == spec
    assert m["background"] == {"type": "constant", "radiance": [0.5, 0.55, 0.6]}
    assert m["provenance"]["mitsuba"] and m["provenance"]["variant"]
    assert m["splits"] == ["train", "test", "test_ref"]
    for split, n, spp in (("train", 3, 4), ("test", 2, 8), ("test_ref", 2, 8)):
        t = m["timings"][split]
        assert t["views"] == n and t["spp"] == spp and t["seconds_per_view"] > 0 and t["samples_per_second"] > 0
        for i in range(n):
            img = read_exr(path / split / f"r_{i:03d}.exr")
            assert img.shape == (8, 8, 4) and img.dtype == np.float32 and np.all(np.isfinite(img))
            assert (path / split / f"r_{i:03d}.png").is_file()
    nf = m["noise_floor"]
    assert 10 < nf["psnr"] < 80 and 5 < nf["psnr_medium"] < nf["psnr"]
    assert 0 < nf["medium_pixel_fraction"] < 1
    # every file is listed with its sha256, the manifest itself excepted
    on_disk = sorted(p.relative_to(path).as_posix() for p in path.rglob("*") if p.is_file())
    assert sorted(m["files"]) == [f for f in on_disk if f != "manifest.json"]
    for rel, digest in m["files"].items():
        assert hashlib.sha256((path / rel).read_bytes()).hexdigest() == digest
    assert not [p for p in root.iterdir() if ".tmp-" in p.name]


def test_transforms_equal_rendered_cameras(generated):
    spec, _, path, used = generated
    rendered = iter(used)
    for split, rig_split in (("train", "train"), ("test", "test"), ("test_ref", "test")):
        expected = camera_rig(spec.cameras, rig_split)
        views = [read_transforms(root / f"transforms_{split}.json") for root in (path, path / gen.MEDIUM_DIR)]
        for files, cams, meta in views:
            assert files == [f"./{split}/r_{i:03d}" for i in range(len(expected))]
            assert meta["pixel_center"] == 0.5 and meta["spp"] in (4, 8)
            for cam, exp in zip(cams, expected, strict=True):
                assert np.allclose(cam.c2w, exp.c2w, atol=1e-12)
                assert (cam.width, cam.height, cam.cx, cam.cy) == (exp.width, exp.height, exp.cx, exp.cy)
                assert cam.fl_x == pytest.approx(exp.fl_x) and cam.fl_y == pytest.approx(exp.fl_y)
        for cam in views[0][1]:  # one volpath pass per view: what Mitsuba rendered with is what the files say
            assert np.allclose(next(rendered), cam.c2w @ GL_TO_MITSUBA, atol=1e-5)
    assert next(rendered, None) is None
    seeds = {root: [json.loads((root / f"transforms_{s}.json").read_text())["render_seeds"]
                    for s in ("train", "test", "test_ref")] for root in (path, path / gen.MEDIUM_DIR)}
    assert seeds[path] == seeds[path / gen.MEDIUM_DIR]  # the images are composed from the medium's renders
    assert len({seed for split in seeds[path] for seed in split}) == sum(len(split) for split in seeds[path])


def test_volume_files(generated):
    import mitsuba as mi

    spec, _, path, _ = generated
    sigma_t, albedo = volume_grids(spec)
    assert np.array_equal(np.load(path / "volume" / "sigma_t.npy"), sigma_t)
    assert np.array_equal(np.load(path / "volume" / "albedo.npy"), albedo)
    for name, grid in (("sigma_t", sigma_t), ("albedo", albedo)):
        vol = mi.load_dict({"type": "gridvolume", "filename": str(path / "volume" / f"{name}.vol")})
        data = np.array(mi.traverse(vol)["data"]).reshape(grid.shape)
        assert np.array_equal(data, grid), name


def test_cache_hit_does_not_render(generated, monkeypatch):
    import mitsuba as mi

    spec, root, path, _ = generated
    stamp = (path / "manifest.json").stat().st_mtime_ns

    def boom(*args, **kwargs):
        raise AssertionError("rendered on a cache hit")

    monkeypatch.setattr(mi, "render", boom)
    start = time.perf_counter()
    assert gen.generate_dataset(spec, root, progress=False) == path
    assert time.perf_counter() - start < 1.0
    assert (path / "manifest.json").stat().st_mtime_ns == stamp
    assert gen.dataset_dir(spec, root) == path


def test_changed_spec_new_dir_and_determinism(generated, tmp_path):
    spec, root, path, _ = generated
    reseeded = spec.with_overrides({"render.seed": 1})
    assert gen.dataset_dir(reseeded, root) != path
    assert gen.dataset_dir(spec.with_overrides({"description": "reworded"}), root) == path
    assert gen.dataset_dir(spec, root, splits=["train"]) != path
    # the same spec regenerated elsewhere: identical grids and images
    again = gen.generate_dataset(spec, tmp_path, progress=False)
    assert again.name == path.name
    m1 = json.loads((path / "manifest.json").read_text())["files"]
    m2 = json.loads((again / "manifest.json").read_text())["files"]
    assert m1 == m2


def test_sky_scene_writes_envmap_and_partial_splits(tiny_spec, tmp_path):
    sky = {"type": "sky", "zenith": [0.1, 0.2, 0.8], "horizon": [0.8, 0.8, 0.8], "ground": [0.2, 0.2, 0.2],
           "resolution": 32}
    spec = tiny_spec.with_overrides({"lights.0": sky})
    path = gen.generate_dataset(spec, tmp_path, progress=False, splits=["train"])
    m = json.loads((path / "manifest.json").read_text())
    assert m["background"]["type"] == "envmap" and m["splits"] == ["train"] and m["noise_floor"] is None
    assert np.array_equal(read_exr(path / m["background"]["file"]), bake_sky(spec.lights[0]))
    assert not (path / "test").exists()


def test_interrupt_leaves_nothing(tiny_spec, tmp_path, monkeypatch):
    import mitsuba as mi

    real, calls = mi.render, []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(mi, "render", interrupted)
    spec = tiny_spec.with_overrides({"render.seed": 7})
    with pytest.raises(KeyboardInterrupt):
        gen.generate_dataset(spec, tmp_path, progress=False)
    assert [p.name for p in tmp_path.iterdir() if not p.name.endswith(".lock")] == []


_CHILD = """
import json, sys, time
import mitsnerf
from mitsnerf.env import set_variant
set_variant()
import mitsuba as mi
from mitsnerf.generate import generate_dataset
from mitsnerf.scene.spec import parse_scene
real = mi.render
def slow(*args, **kwargs):
    time.sleep(0.3)
    return real(*args, **kwargs)
mi.render = slow
generate_dataset(parse_scene(json.loads(sys.argv[1]), "tiny.toml"), sys.argv[2], progress=False)
"""


def test_sigkill_mid_render_then_recover(tiny_spec, tmp_path):
    spec = tiny_spec.with_overrides({"cameras.n_train": 20, "render.seed": 11})
    child = subprocess.Popen([sys.executable, "-c", _CHILD, json.dumps(spec.to_dict()), str(tmp_path)],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob(".tiny-*.tmp-*/train/r_001.exr")):
            assert child.poll() is None, child.stdout.read().decode()
            assert time.monotonic() < deadline, "the child never started rendering"
            time.sleep(0.05)
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.kill()
        child.wait()
        child.stdout.close()
    visible = [p for p in tmp_path.iterdir() if not p.name.startswith(".")]
    assert visible == [], "a killed run left a dataset-looking directory"
    assert list(tmp_path.glob(".tiny-*.tmp-*")), "expected the killed run's temporary"
    path = gen.generate_dataset(spec, tmp_path, progress=False)
    assert (path / "manifest.json").is_file()
    assert not list(tmp_path.glob(".*.tmp-*")), "stale temporaries were not cleaned"
    assert [p for p in tmp_path.iterdir() if not p.name.startswith(".")] == [path]
