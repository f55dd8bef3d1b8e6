"""The battery: bad inputs and misuse a hostile but fair user tries, run through the CLI.

One table, one row per case: the command, the exit status, what the error line must name (the file
and the field where there is one) and what must be left on disk. A user error is exactly one line
``mitsnerf: error: ...``, no traceback. Cases that need a place root cannot write run in a child
process without ``CAP_DAC_OVERRIDE`` (``chmod 555`` does not stop root). The interruptions
(SIGTERM, SIGHUP, a run directory being written, a stopped sweep) are in ``test_interruptions.py``; the
tiny dataset and run they share are ``conftest.py``'s ``world``.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Callable

import numpy as np
import pytest

from mitsnerf.cli import main
from ..conftest import child_pythonpath


def cli_args(argv: list[str], ctx) -> list[str]:
    """``argv`` with ``{placeholders}`` filled from ``ctx`` and ``NERF`` expanded to the tiny nerf's flags."""
    out = []
    for a in argv:
        out += list(ctx.world.nerf) if a == "NERF" else [_fill(a, ctx)]
    return out


# --------------------------------------------------------------------------- setups (each in the case's tmp)


def copy_dataset(ctx) -> Path:
    ctx.ds = ctx.tmp / "ds"
    shutil.copytree(ctx.world.dataset, ctx.ds)
    return ctx.ds


def copy_run(ctx) -> Path:
    ctx.rn = ctx.tmp / "rn"
    shutil.copytree(ctx.world.run, ctx.rn)
    return ctx.rn


def a_file(ctx) -> None:
    ctx.file = ctx.tmp / "afile"
    ctx.file.write_text("keep me")


def interrupted_run(ctx) -> None:
    copy_run(ctx)
    for name in ("metrics.json", "params.npz", "history.json", "config.json"):
        (ctx.rn / name).unlink()
    shutil.rmtree(ctx.rn / "test")


def foreign_dir(ctx) -> None:
    ctx.foreign = ctx.tmp / "home"
    ctx.foreign.mkdir()
    (ctx.foreign / "thesis.tex").write_text("years of work")


def _rewrite_exr(path: Path, change: Callable[[np.ndarray], None]) -> None:
    from mitsnerf.data.images import read_exr, write_exr

    img = read_exr(path)
    change(img)
    write_exr(path, img)


def swapped_image(ctx) -> None:
    ds = copy_dataset(ctx)
    a, b = ds / "train" / "r_000.exr", ds / "train" / "r_001.exr"
    tmp = ds / "swap"
    a.rename(tmp), b.rename(a), tmp.rename(b)


def negative_radiance(ctx) -> None:
    _rewrite_exr(copy_dataset(ctx) / "train" / "r_000.exr", lambda img: img.__setitem__((2, 3, 1), -50.0))


def nan_radiance(ctx) -> None:
    _rewrite_exr(copy_dataset(ctx) / "train" / "r_001.exr", lambda img: img.__setitem__((0, 0, 0), np.nan))


def nan_grid(ctx) -> None:
    path = copy_dataset(ctx) / "volume" / "sigma_t.npy"
    grid = np.load(path)
    grid[1, 2, 3] = np.nan
    np.save(path, grid)


def garbage_grid(ctx) -> None:
    (copy_dataset(ctx) / "volume" / "sigma_t.npy").write_bytes(os.urandom(256))


def nan_transforms(ctx) -> None:
    path = copy_dataset(ctx) / "transforms_train.json"
    doc = json.loads(path.read_text())
    doc["frames"][1]["transform_matrix"][0][3] = float("nan")
    path.write_text(json.dumps(doc))  # json writes NaN, as a careless tool would


def deleted_image(ctx) -> None:
    (copy_dataset(ctx) / "train" / "r_002.exr").unlink()


def garbage_manifest(ctx) -> None:
    (copy_dataset(ctx) / "manifest.json").write_text("{not json")


def truncated_checkpoint(ctx) -> None:
    path = copy_run(ctx) / "checkpoint.npz"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def garbage_checkpoint(ctx) -> None:
    (copy_run(ctx) / "checkpoint.npz").write_bytes(os.urandom(512))


def binary_spec(ctx) -> None:
    ctx.scenes = ctx.tmp / "scenes"
    ctx.scenes.mkdir()
    (ctx.scenes / "good.toml").write_text(ctx.world.spec.read_text().replace('"tiny"', '"good"'))
    (ctx.scenes / "binary.toml").write_bytes(bytes(range(256)))


def bad_grid(name: str, value) -> Callable:
    """A grid file ``ctx.grid`` (``name`` in the case's tmp; bytes are written as they are) and a spec
    ``ctx.grid_spec``: the tiny scene with that grid as its medium."""
    def setup(ctx) -> None:
        from mitsnerf.data.vol import write_vol

        ctx.grid = ctx.tmp / name
        if isinstance(value, bytes):
            ctx.grid.write_bytes(value)
        elif name.endswith(".vol"):
            write_vol(ctx.grid, value)
        else:
            np.save(ctx.grid, value)
        ctx.grid_spec = ctx.tmp / "mine.toml"
        text = ctx.world.spec.read_text().replace('family = "cloud"', 'family = "grid"')
        ctx.grid_spec.write_text(text.replace("params = { albedo = [0.8, 0.8, 0.8] }", f'params = {{ path = "{name}" }}'))
    return setup


def finished_run_and_swapped_image(ctx) -> None:
    copy_run(ctx)
    swapped_image(ctx)


def bench_file(text: str) -> Callable:
    def setup(ctx) -> None:
        ctx.bench = ctx.tmp / "b.toml"
        ctx.bench.write_text(text.replace("SPEC", str(ctx.world.spec)))
    return setup


def bench_external(entry: str, keep_renders: int = 2) -> Callable:
    """A bench file with one method and the ``[[external]]`` table ``entry`` (``SPEC``: the tiny spec), and a
    renders folder ``ren`` holding the first ``keep_renders`` of the tiny dataset's test views."""
    def setup(ctx) -> None:
        bench_file(f'scenes = ["SPEC"]\n[[methods]]\nname = "nerf"\n[[external]]\n{entry}\n')(ctx)
        (ctx.tmp / "ren").mkdir()
        for path in sorted((ctx.world.dataset / "test").glob("r_*.exr"))[:keep_renders]:
            shutil.copy(path, ctx.tmp / "ren" / path.name)
    return setup


def deleted_cached_image(ctx) -> None:
    """A cache hit whose training image was deleted: generate must notice and render it again."""
    shutil.copytree(ctx.world.dataset.parent, ctx.tmp / "data")
    ctx.ds = ctx.tmp / "data" / ctx.world.dataset.name
    (ctx.ds / "train" / "r_001.exr").unlink()


def edited_checkpoint(change: Callable) -> Callable:
    """A copy of the run whose checkpoint ``change(ckpt, ctx)`` edited (as another version or a hand would)."""
    def setup(ctx) -> None:
        from mitsnerf.train.checkpoint import load_checkpoint, save_checkpoint

        path = copy_run(ctx) / "checkpoint.npz"
        ckpt = load_checkpoint(path)
        ctx.key = sorted(ckpt.params)[0]
        change(ckpt, ctx)
        save_checkpoint(path, ckpt)
    return setup


def edited_config(change: Callable) -> Callable:
    """A copy of the run without its checkpoint (render and export read config.json + params.npz), whose
    ``config.json`` ``change(config)`` edited."""
    def setup(ctx) -> None:
        (copy_run(ctx) / "checkpoint.npz").unlink()
        config = json.loads((ctx.rn / "config.json").read_text())
        change(config)
        (ctx.rn / "config.json").write_text(json.dumps(config))
    return setup


def misshaped_params(ctx) -> None:
    (copy_run(ctx) / "checkpoint.npz").unlink()
    params = dict(np.load(ctx.rn / "params.npz"))
    ctx.key = sorted(params)[0]
    params[ctx.key] = np.zeros((3, 5), np.float32)
    np.savez(ctx.rn / "params.npz", **params)


def run_and_another_dataset(ctx) -> None:
    """The finished run, and a second tiny dataset (another volume seed: another manifest hash)."""
    copy_run(ctx)
    assert main(["generate", str(ctx.world.spec), "--set", "volume.seed=2", "--out", str(ctx.tmp / "d2")]) == 0
    (ctx.ds2,) = (ctx.tmp / "d2").iterdir()


def disk_full(name: str, nth: int = 1) -> Callable:
    """A full disk reported when the ``nth`` file called ``name`` is synced (its temporary, by the atomic
    writers): ``fsync`` is where a filesystem with delayed allocation (ext4, XFS, NFS) reports ENOSPC, the
    bytes written before never reaching the disk. Other files are written as usual."""
    def fault(ctx, monkeypatch) -> None:
        real, seen = os.fsync, []

        def fsync(fd) -> None:
            if f"{name}.tmp-" in Path(os.readlink(f"/proc/self/fd/{fd}")).name:
                seen.append(fd)
                if len(seen) == nth:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            real(fd)

        monkeypatch.setattr(os, "fsync", fsync)
    return fault


def in_tmp(ctx, monkeypatch) -> None:
    monkeypatch.chdir(ctx.tmp)


# --------------------------------------------------------------------------- what must be left


def unchanged(name: str) -> Callable:
    """The case left ``ctx.<name>``'s bytes (a file) or its files (a directory) as they were."""
    def check(ctx, before) -> None:
        assert before[name] == _snapshot(getattr(ctx, name))
    check.snapshots = (name,)
    return check


def absent(pattern: str) -> Callable:
    def check(ctx, before) -> None:
        assert not list(ctx.tmp.glob(pattern)), sorted(p.name for p in ctx.tmp.glob(pattern))
    return check


def only_checkpoint(name: str, step: int) -> Callable:
    """``ctx.tmp / name`` holds the checkpoint of ``step`` and nothing else (no temporary, no half a run)."""
    def check(ctx, before) -> None:
        from mitsnerf.train.checkpoint import load_checkpoint

        assert sorted(p.name for p in (ctx.tmp / name).iterdir()) == ["checkpoint.npz"]
        assert load_checkpoint(ctx.tmp / name / "checkpoint.npz").step == step
    return check


def _snapshot(path: Path) -> dict:
    if path.is_file():
        return {"": path.read_bytes()}
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


@dataclass
class Case:
    id: str
    item: int
    """The issue's item: 1 outputs, 3 corrupt data, 4 overwrites, 5 tracebacks, 6 messages, 7 small things."""
    argv: list[str]
    code: int
    names: tuple[str, ...] = ()
    """What the error line must contain (``{placeholders}`` of the context)."""
    setup: Callable | None = None
    left: tuple[Callable, ...] = ()
    env: dict = field(default_factory=dict)
    fault: Callable | None = None
    """``fault(ctx, monkeypatch)`` before the command: a fault to inject, or a directory to run in."""


def train_on(dataset: str) -> list[str]:
    return ["train", dataset, "--steps", "2", "NERF"]


TRAIN = train_on("{world.dataset}")
CASES = [
    # 1. outputs checked before any work
    Case("train --out is a file", 1, [*TRAIN, "--out", "{file}"], 2, ("{file}", "--out", "not a directory"),
         a_file, (unchanged("file"),)),
    Case("train --out under a file", 1, [*TRAIN, "--out", "{file}/run"], 2, ("{file}", "is a file"), a_file,
         (unchanged("file"),)),
    Case("train --out a finished run", 4, [*TRAIN, "--out", "{rn}"], 2, ("{rn}", "--out", "finished run (nerf, 2 steps)",
                                                                            "--force"), copy_run, (unchanged("rn"),)),
    Case("train --out an interrupted run", 4, [*TRAIN, "--out", "{rn}"], 2, ("{rn}", "interrupted run", "--resume"),
         interrupted_run, (unchanged("rn"),)),
    Case("train --out a non-run directory", 4, [*TRAIN, "--out", "{foreign}"], 2,
         ("{foreign}", "not a mitsnerf run", "thesis.tex"), foreign_dir, (unchanged("foreign"),)),
    Case("train --force a non-run directory", 4, [*TRAIN, "--out", "{foreign}", "--force"], 2,
         ("{foreign}", "not a mitsnerf run"), foreign_dir, (unchanged("foreign"),)),
    Case("train --force with a bad dataset", 4, [*train_on("{ds}"), "--out", "{rn}", "--force"], 2,
         ("train/r_000.exr", "sha256"), finished_run_and_swapped_image, (unchanged("rn"),)),
    Case("train --resume a missing run", 1, ["train", "--resume", "--out", "{tmp}/none"], 2,
         ("{tmp}/none", "no checkpoint.npz to resume"), None, (absent("none"),)),
    Case("render --out is a file", 1, ["render", "{world.run}", "--out", "{file}"], 2, ("{file}", "--out"), a_file,
         (unchanged("file"),)),
    Case("export --out is a file", 1, ["export", "{world.run}", "--out", "{file}"], 2, ("{file}", "--out"), a_file,
         (unchanged("file"),)),
    Case("generate --out is a file", 1, ["generate", "{world.spec}", "--out", "{file}"], 2, ("{file}", "--out"), a_file,
         (unchanged("file"),)),
    Case("check --out is a file", 1, ["check", "--out", "{file}", "--case", "closed_form"], 2, ("{file}", "--out"),
         a_file, (unchanged("file"),)),
    Case("score --out is a directory", 1, ["score", "{world.dataset}", "{tmp}", "--out", "{tmp}"], 2,
         ("{tmp}", "--out", "is a directory"), None, (absent("*.json"),)),
    Case("bench --results is a file", 1, ["bench", "default", "--results", "{file}", "--data", "{tmp}/d"], 2,
         ("{file}", "--results"), a_file, (unchanged("file"), absent("d"))),
    # 3. corrupt data refused, naming the file and field
    Case("sigma_t_scale 1e300", 3, ["generate", "{world.spec}", "--set", "volume.sigma_t_scale=1e300", "--out", "{tmp}/d"],
         2, ("tiny.toml", "volume.sigma_t_scale", "opaque surface"), None, (absent("d/tiny-*"),)),
    Case("light radiance past float32", 3, ["generate", "{world.spec}", "--set", "lights.0.radiance=[1e39, 1, 1]",
                                            "--out", "{tmp}/d"], 2, ("tiny.toml", "lights.0", "non-finite"), None,
         (absent("d/tiny-*"), absent("d/.tiny-*"))),
    Case("grid with NaN", 3, ["generate", "{grid_spec}", "--out", "{tmp}/d"], 2, ("{grid}", "non-finite"),
         bad_grid("nan.npy", np.full((8, 8, 8), np.nan, np.float32)), (absent("d/tiny-*"), absent("d/.tiny-*"))),
    Case("grid with negative density", 3, ["generate", "{grid}", "--out", "{tmp}/d"], 2, ("{grid}", "outside >= 0"),
         bad_grid("neg.npy", -np.ones((8, 8, 8), np.float32)), (absent("d/neg-*"), absent("d/.neg-*"))),
    Case("grid of rank 2", 3, ["generate", "{grid_spec}", "--out", "{tmp}/d"], 2, ("{grid}", "has 2 axes"),
         bad_grid("flat.npy", np.ones((8, 8), np.float32)), (absent("d/tiny-*"),)),
    Case("grid all zero", 3, ["generate", "{grid}", "--out", "{tmp}/d"], 2, ("{grid}", "holds no medium"),
         bad_grid("empty.npy", np.zeros((8, 8, 8), np.float32)), (absent("d/empty-*"), absent("d/.empty-*"))),
    Case("grid unreadable", 3, ["generate", "{grid_spec}", "--out", "{tmp}/d"], 2, ("{grid}", "cannot be read"),
         bad_grid("junk.npy", b"\x93NUMPY garbage"), (absent("d/tiny-*"),)),
    Case("grid .vol of 3 channels", 3, ["generate", "{grid}", "--out", "{tmp}/d"], 2, ("{grid}", "3 channels"),
         bad_grid("rgb.vol", np.ones((8, 8, 8, 3), np.float32)), (absent("d/rgb-*"),)),
    Case("grid file missing", 3, ["generate", "{grid_spec}", "--out", "{tmp}/d"], 2,
         ("gone.npy", "no such grid file", "volume.params.path"), bad_grid("gone.npy", b""), (absent("d/tiny-*"),),
         fault=lambda ctx, mp: ctx.grid.unlink()),
    Case("swapped training image", 3, [*train_on("{ds}"), "--out", "{tmp}/r"], 2, ("train/r_000.exr", "sha256"),
         swapped_image, (absent("r"),)),
    Case("radiance -50", 3, [*train_on("{ds}"), "--out", "{tmp}/r"], 2, ("train/r_000.exr", "sha256"),
         negative_radiance, (absent("r"),)),
    Case("radiance -50 --no-verify", 3, [*train_on("{ds}"), "--out", "{tmp}/r", "--no-verify"], 2,
         ("transforms_train.json", "frames[0]", "negative radiance", "-50"), negative_radiance, (absent("r"),)),
    Case("NaN radiance --no-verify", 3, [*train_on("{ds}"), "--out", "{tmp}/r", "--no-verify"], 2,
         ("train/r_001.exr", "non-finite"), nan_radiance, (absent("r"),)),
    Case("NaN in sigma_t.npy", 3, [*train_on("{ds}"), "--out", "{tmp}/r"], 2, ("volume/sigma_t.npy", "sha256"),
         nan_grid, (absent("r"),)),
    Case("NaN in sigma_t.npy --no-verify", 3, [*train_on("{ds}"), "--out", "{tmp}/r", "--no-verify"], 2,
         ("volume/sigma_t.npy", "non-finite"), nan_grid, (absent("r"),)),
    Case("garbage sigma_t.npy --no-verify", 6, [*train_on("{ds}"), "--out", "{tmp}/r", "--no-verify"], 2,
         ("volume/sigma_t.npy", "not a numpy .npy file"), garbage_grid, (absent("r"),)),
    Case("deleted training image", 3, [*train_on("{ds}"), "--out", "{tmp}/r"], 2, ("train/r_002.exr", "missing"),
         deleted_image, (absent("r"),)),
    Case("garbage manifest", 3, [*train_on("{ds}"), "--out", "{tmp}/r"], 2, ("manifest.json", "invalid JSON"),
         garbage_manifest, (absent("r"),)),
    Case("cache hit with a deleted image", 3, ["generate", "{world.spec}", "--out", "{tmp}/data"], 0,
         ("train/r_001.exr", "rendering it again"), deleted_cached_image, ()),
    # 5. tracebacks that must be one line
    Case("unknown --method", 5, ["train", "{world.dataset}", "--out", "{tmp}/r", "--method", "nope"], 2,
         ("--method", "nope", "known: "), None, (absent("r"), absent(".r.lock"))),
    Case("--batch-rays 1e9", 5, [*TRAIN, "--out", "{tmp}/r", "--batch-rays", "1000000000"], 2,
         ("--batch-rays", "[1, 4194304]"), None, (absent("r"),)),
    Case("--batch-rays 1e9 as typed", 5, [*TRAIN, "--out", "{tmp}/r", "--batch-rays", "1e9"], 2,
         ("--batch-rays", "invalid int value: '1e9'", "--help"), None, (absent("r"),)),
    Case("unknown command", 5, ["trian", "{world.dataset}"], 2, ("invalid choice: 'trian'",), None, ()),
    Case("--steps 0", 5, [*TRAIN, "--out", "{tmp}/r", "--steps", "0"], 2, ("--steps", "[1, 100000000]"), None, (absent("r"),)),
    Case("truncated checkpoint --resume", 5, ["train", "--resume", "--out", "{rn}", "--steps", "4"], 2,
         ("{rn}/checkpoint.npz", "truncated"), truncated_checkpoint, (unchanged("rn"),)),
    Case("truncated checkpoint render", 5, ["render", "{rn}", "--out", "{tmp}/img"], 2,
         ("{rn}/checkpoint.npz", "truncated"), truncated_checkpoint, (absent("img/*.exr"),)),
    Case("garbage checkpoint --resume", 6, ["train", "--resume", "--out", "{rn}", "--steps", "4"], 2,
         ("{rn}/checkpoint.npz", "not a numpy .npz archive"), garbage_checkpoint, (unchanged("rn"),)),
    Case("--set without =", 5, [*TRAIN, "--out", "{tmp}/r", "--set", "lr"], 2, ("--set", "KEY=VALUE"), None,
         (absent("r"),)),
    Case("--set unknown key", 5, [*TRAIN, "--out", "{tmp}/r", "--set", "bogus=1"], 2, ("--set", "bogus", "unknown"),
         None, (absent("r"),)),
    Case("--resume with --lr", 5, ["train", "--resume", "--out", "{world.run}", "--lr", "0.5"], 2,
         ("train --resume", "--lr"), None, ()),
    Case("--box inverted", 5, [*TRAIN, "--out", "{tmp}/r", "--box", "1", "1", "1", "0", "0", "0"], 2, ("--box",),
         None, (absent("r"),)),
    Case("--pixel-center nan", 5, [*TRAIN, "--out", "{tmp}/r", "--pixel-center", "nan"], 2, ("--pixel-center",),
         None, (absent("r"),)),
    Case("render --index past the split", 5, ["render", "{world.run}", "--out", "{tmp}/img", "--index", "9"], 2,
         ("--index", "0..1"), None, (absent("img/*.exr"),)),
    Case("render --fov 200", 5, ["render", "{world.run}", "--out", "{tmp}/img", "--fov", "200"], 2, ("--fov",),
         None, (absent("img"),)),
    Case("render --look-from the look-at point", 5, ["render", "{world.run}", "--out", "{tmp}/img", "--look-from",
                                                    "0", "0", "0"], 2, ("--look-from", "--look-at"), None,
         (absent("img"),)),
    Case("render --size 1000000 1000000", 5, ["render", "{world.run}", "--out", "{tmp}/img", "--size", "1000000",
                                              "1000000"], 2, ("--size", "1000000 x 1000000"), None, (absent("img"),)),
    Case("render --split nope", 5, ["render", "{world.run}", "--out", "{tmp}/img", "--split", "nope"], 2,
         ("--split", "'nope'", "test"), None, (absent("img"),)),
    Case("render into a folder whose render.json is not a record", 1, ["render", "{world.run}", "--out", "{tmp}"], 2,
         ("{tmp}/render.json", "not a render record"), lambda ctx: (ctx.tmp / "render.json").write_text("{oops"),
         (absent("*.exr"),)),
    Case("export --resolution 0", 5, ["export", "{world.run}", "--out", "{tmp}/x", "--resolution", "0"], 2,
         ("--resolution",), None, (absent("x"),)),
    Case("export --direction 0 0 0", 5, ["export", "{world.run}", "--out", "{tmp}/x", "--direction", "0", "0", "0"],
         2, ("--direction",), None, (absent("x"),)),
    Case("render a missing run", 5, ["render", "{tmp}/nothing"], 2, ("{tmp}/nothing", "not found"), None, ()),
    Case("train on a missing dataset", 5, ["train", "{tmp}/nothing", "--out", "{tmp}/r"], 2,
         ("{tmp}/nothing", "not found"), None, (absent("r"),)),
    Case("train on a file", 5, ["train", "{file}", "--out", "{tmp}/r"], 2, ("{file}", "not a directory"), a_file,
         (absent("r"),)),
    Case("bench --workers with sequential", 5, ["bench", "default", "--workers", "2", "--results", "{tmp}/res",
                                                "--data", "{tmp}/d"], 2, ("--workers",), None, (absent("res"),)),
    # 6. messages that name the culprit
    Case("binary spec file", 6, ["generate", "{scenes}/binary.toml", "--out", "{tmp}/d"], 2,
         ("binary.toml", "not a text file"), binary_spec, (absent("d"),)),
    Case("binary spec in scenes", 6, ["scenes"], 2, ("binary.toml",), binary_spec, (),
         {"MITSNERF_SCENES": "{scenes}"}),
    Case("binary spec in generate --all", 6, ["generate", "--all", "--out", "{tmp}/d"], 2, ("binary.toml",),
         binary_spec, (absent("d/*"),), {"MITSNERF_SCENES": "{scenes}"}),
    Case("directory as spec path", 6, ["generate", "{tmp}", "--out", "{tmp}/d"], 2, ("{tmp}", "directory"), None,
         (absent("d"),)),
    Case("unknown scene", 6, ["generate", "no_such_scene", "--out", "{tmp}/d"], 2, ("no_such_scene",), None,
         (absent("d"),)),
    Case("empty bench config", 6, ["bench", "{bench}", "--results", "{tmp}/res", "--data", "{tmp}/d"], 2,
         ("b.toml",), bench_file(""), (absent("res"),)),
    Case("bench quick scene override", 6, ["bench", "{bench}", "--quick", "--results", "{tmp}/res", "--data",
                                           "{tmp}/d"], 2, ("b.toml", "quick.scene.cameras.width"),
         bench_file('scenes = ["SPEC"]\n[[methods]]\nname = "nerf"\n[quick]\nscene = { "cameras.width" = 0 }\n'),
         (absent("d/*"),)),
    Case("bench train.steps 0", 6, ["bench", "{bench}", "--results", "{tmp}/res", "--data", "{tmp}/d"], 2,
         ("b.toml", "methods.0.train.steps"),
         bench_file('scenes = ["SPEC"]\n[[methods]]\nname = "nerf"\ntrain = { steps = 0 }\n'), (absent("d/*"),)),
    Case("bench unknown scene", 6, ["bench", "{bench}", "--results", "{tmp}/res", "--data", "{tmp}/d"], 2,
         ("b.toml", "scenes.0", "unknown scene 'no_such_scene'"),
         bench_file('scenes = ["no_such_scene"]\n[[methods]]\nname = "nerf"\n'), (absent("res"), absent("d"))),
    Case("bench external missing density", 6, ["bench", "{bench}", "--results", "{tmp}/res", "--data", "{tmp}/d"], 2,
         ("b.toml", "external.0.density.tiny", "{tmp}/no.npy", "density file not found"),
         bench_external('name = "x"\nrenders = { tiny = "ren" }\ndensity = { tiny = "no.npy" }'),
         (absent("res"), absent("d"))),
    Case("bench external missing render", 6, ["bench", "{bench}", "--results", "{tmp}/res", "--data", "{tmp}/d"], 2,
         ("{tmp}/ren", "no render for test frame r_001"),
         bench_external('name = "x"\nrenders = { tiny = "ren" }', keep_renders=1), (absent("res"), absent("d"))),
    # 7. small things
    Case("range printed whole", 7, ["generate", "{world.spec}", "--set", "render.spp_test=0", "--out", "{tmp}/d"], 2,
         ("render.spp_test", "[1, 1048576]"), None, (absent("d"),)),
    Case("--resume of a finished run", 7, ["train", "--resume", "--out", "{rn}"], 2,
         ("{rn}", "finished at step 2", "--steps"), copy_run, (unchanged("rn"),)),
    # runs, checkpoints, outputs and full disks: tracebacks that must be one line
    *[Case(f"checkpoint of an unknown method {cmd[0]}", 5, cmd, 2,
           ("{rn}/checkpoint.npz", "method", "'bogus'", "known: "),
           edited_checkpoint(lambda c, ctx: c.config.update(method="bogus")), (unchanged("rn"), absent("img"), absent("x")))
      for cmd in (["train", "--resume", "--out", "{rn}", "--steps", "4"], ["render", "{rn}", "--out", "{tmp}/img"],
                  ["export", "{rn}", "--out", "{tmp}/x"])],
    Case("checkpoint without method --resume", 5, ["train", "--resume", "--out", "{rn}", "--steps", "4"], 2,
         ("{rn}/checkpoint.npz", "method", "missing"), edited_checkpoint(lambda c, ctx: c.config.pop("method")),
         (unchanged("rn"),)),
    Case("config.json of an unknown method render", 5, ["render", "{rn}", "--out", "{tmp}/img"], 2,
         ("{rn}/config.json", "method", "'bogus'", "known: "), edited_config(lambda c: c.update(method="bogus")),
         (unchanged("rn"), absent("img"))),
    Case("config.json without method export", 5, ["export", "{rn}", "--out", "{tmp}/x"], 2,
         ("{rn}/config.json", "method", "missing"), edited_config(lambda c: c.pop("method")),
         (unchanged("rn"), absent("x"))),
    Case("config.json bad method_config export", 5, ["export", "{rn}", "--out", "{tmp}/x"], 2,
         ("{rn}/config.json", "method_config.bogus", "unknown"),
         edited_config(lambda c: c["method_config"].update(bogus=1)), (unchanged("rn"), absent("x"))),
    Case("checkpoint lacking a parameter --resume", 5, ["train", "--resume", "--out", "{rn}", "--steps", "4"], 2,
         ("{rn}/checkpoint.npz", "param/{key}", "missing"), edited_checkpoint(lambda c, ctx: c.params.pop(ctx.key)),
         (unchanged("rn"),)),
    Case("checkpoint misshaped parameter --resume", 5, ["train", "--resume", "--out", "{rn}", "--steps", "4"], 2,
         ("{rn}/checkpoint.npz", "{key}", "(3, 5)"),
         edited_checkpoint(lambda c, ctx: c.params.update({ctx.key: np.zeros((3, 5), np.float32)})), (unchanged("rn"),)),
    Case("params.npz misshaped parameter export", 5, ["export", "{rn}", "--out", "{tmp}/x"], 2,
         ("{rn}/params.npz", "{key}", "(3, 5)"), misshaped_params, (unchanged("rn"), absent("x"))),
    Case("export --resolution 100000", 5, ["export", "{world.run}", "--out", "{tmp}/x", "--resolution", "100000"], 2,
         ("--resolution", "[1, 1024]", "100000"), None, (absent("x"),)),
    Case("train --out ''", 5, [*TRAIN, "--out", ""], 2, ("--out", "current directory"), None, (absent("*"), absent(".*")),
         fault=in_tmp),
    Case("train --out .", 5, [*TRAIN, "--out", "."], 2, ("--out", "'.'", "current directory"), None,
         (absent("*"), absent(".*")), fault=in_tmp),
    Case("disk full during generate", 5, ["generate", "{world.spec}", "--out", "{tmp}/d"], 2,
         ("{tmp}/d/tiny-", "disk full", "writing train/r_001.png", "was not created"), None,
         (absent("d/*"), absent("d/.*")), fault=disk_full("r_001.png")),
    Case("disk full at the second checkpoint", 5, ["train", "{world.dataset}", "--steps", "12", "--checkpoint-every", "5",
                                                   "NERF", "--out", "{tmp}/r"], 2,
         ("{tmp}/r/checkpoint.npz", "disk full", "step 10 was not saved", "step 5, is kept", "train --resume --out"),
         None, (only_checkpoint("r", 5), absent(".r*")), fault=disk_full("checkpoint.npz", 2)),
    Case("disk full writing the finished run", 5, [*TRAIN, "--out", "{tmp}/r"], 2,
         ("{tmp}/r", "disk full", "writing params.npz", "step 2, is kept", "train --resume --out"), None,
         (only_checkpoint("r", 2), absent(".r*")), fault=disk_full("params.npz")),
    Case("disk full during export", 5, ["export", "{world.run}", "--out", "{tmp}/x"], 2,
         ("{tmp}/x", "disk full", "writing sigma_t.npy", "none of sigma_t.vol"), None, (absent("x"), absent(".x*")),
         fault=disk_full("sigma_t.npy")),
    # runs, checkpoints and outputs: silently accepted, now refused
    Case("--resume on another dataset", 4, ["train", "{ds2}", "--resume", "--out", "{rn}", "--steps", "4"], 2,
         ("--resume", "{world.dataset}", "{ds2}"), run_and_another_dataset, (unchanged("rn"),)),
    Case("--method ''", 6, ["train", "{world.dataset}", "--out", "{tmp}/r", "--method", ""], 2,
         ("--method", "''", "known: ", "ngp"), None, (absent("r"),)),
    Case("checkpoint step -5", 3, ["train", "--resume", "--out", "{rn}", "--steps", "4"], 2,
         ("{rn}/checkpoint.npz", "step", "-5"), edited_checkpoint(lambda c, ctx: setattr(c, "step", -5)),
         (unchanged("rn"),)),
    Case("--out inside the dataset", 1, [*train_on("{ds}"), "--out", "{ds}/run"], 2, ("--out", "{ds}/run", "inside the dataset"),
         copy_dataset, (unchanged("ds"),)),
    # the environment, the data and the options' names
    Case("deleted EXR --no-verify", 3, [*train_on("{ds}"), "--out", "{tmp}/r", "--no-verify"], 2,
         ("train/r_002.exr", "missing", "frames[2].file_path", "preview"), deleted_image, (absent("r"),)),
    Case("NaN in a transforms JSON --no-verify", 6, [*train_on("{ds}"), "--out", "{tmp}/r", "--no-verify"], 2,
         ("transforms_train.json", "frames[1].transform_matrix[0][3]", "NaN"), nan_transforms, (absent("r"),)),
    Case("MITSNERF_SCENES a missing directory", 7, ["scenes"], 2, ("$MITSNERF_SCENES", "{tmp}/nodir", "no such directory"),
         None, (), {"MITSNERF_SCENES": "{tmp}/nodir"}),
    Case("MITSNERF_BENCHMARKS a missing directory", 7, ["bench", "default", "--results", "{tmp}/res", "--data", "{tmp}/d"],
         2, ("$MITSNERF_BENCHMARKS", "{tmp}/nodir"), None, (absent("res"), absent("d")),
         {"MITSNERF_BENCHMARKS": "{tmp}/nodir"}),
    Case("--pixel-center 2", 7, [*TRAIN, "--out", "{tmp}/r", "--pixel-center", "2"], 2, ("--pixel-center", "[0, 1)"),
         None, (absent("r"),)),
    Case("--lr 0 names --lr", 6, [*TRAIN, "--out", "{tmp}/r", "--lr", "0"], 2, ("error: --lr: ", "got 0"), None,
         (absent("r"),)),
    Case("--footprint 0 names --footprint", 6, [*TRAIN, "--out", "{tmp}/r", "--footprint", "0"], 2,
         ("error: --footprint: ", "[1, 16]"), None, (absent("r"),)),
    Case("score --footprint 0 names --footprint", 6, ["score", "{world.dataset}", "{world.run}", "--footprint", "0",
                                                      "--out", "{tmp}/s.json"], 2, ("error: --footprint: ",), None,
         (absent("s.json"),)),
    Case("--variant unsupported", 6, ["--variant", "scalar_spectral", "env"], 2,
         ("--variant", "scalar_spectral", "llvm_ad_rgb, cuda_ad_rgb"), None, ()),
    Case("MITSNERF_VARIANT unsupported", 6, ["env"], 2, ("MITSNERF_VARIANT", "scalar_rgb", "not supported"), None, (),
         {"MITSNERF_VARIANT": "scalar_rgb"}),
]


def _fill(text: str, ctx) -> str:
    return text.format(**vars(ctx)) if "{" in text else text


def _error_lines(err: str) -> list[str]:
    return [line[line.index("mitsnerf: error:"):] for line in err.splitlines() if "mitsnerf: error:" in line]


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_battery(case: Case, world, tmp_path, capsys, monkeypatch):
    ctx = SimpleNamespace(world=world, tmp=tmp_path)
    if case.setup is not None:
        case.setup(ctx)
    for key, value in case.env.items():
        monkeypatch.setenv(key, _fill(value, ctx))
    before = {name: _snapshot(getattr(ctx, name)) for check in case.left for name in getattr(check, "snapshots", ())}
    if case.fault is not None:
        case.fault(ctx, monkeypatch)
    capsys.readouterr()
    try:
        code = main(cli_args(case.argv, ctx))
    except SystemExit as exc:  # argparse's own checks
        code = exc.code
    err = capsys.readouterr().err
    assert code == case.code, err
    assert "Traceback" not in err
    if case.code == 2:
        lines = _error_lines(err)
        assert len(lines) == 1, err
        for name in case.names:
            assert _fill(name, ctx) in lines[0], lines[0]
    else:
        for name in case.names:
            assert _fill(name, ctx) in err, err
    for check in case.left:
        check(ctx, before)


def test_a_cache_hit_that_fails_verification_is_rendered_again(world, tmp_path, capsys):
    ctx = SimpleNamespace(world=world, tmp=tmp_path)
    deleted_cached_image(ctx)
    assert main(["generate", str(world.spec), "--out", str(tmp_path / "data")]) == 0
    assert (ctx.ds / "train" / "r_001.exr").read_bytes() == (world.dataset / "train" / "r_001.exr").read_bytes()


def test_force_replaces_a_finished_run_and_keeps_what_it_did_not_write(world, tmp_path):
    ctx = SimpleNamespace(world=world, tmp=tmp_path)
    run = copy_run(ctx)
    (run / "notes.txt").write_text("mine")
    (run / "renders").mkdir()
    (run / "renders" / "a.png").write_bytes(b"png")
    assert main(["train", str(world.dataset), "--out", str(run), "--force", "--steps", "3", *world.nerf]) == 0
    assert json.loads((run / "metrics.json").read_text())["steps"] == 3
    assert (run / "notes.txt").read_text() == "mine" and (run / "renders" / "a.png").read_bytes() == b"png"
    assert not list(tmp_path.glob(".rn*")), "no lock file or temporary left beside the run"


def test_resume_on_a_moved_copy_of_its_dataset_continues(world, tmp_path):
    """The run records its dataset's manifest hash: the same data elsewhere is the same dataset."""
    ctx = SimpleNamespace(world=world, tmp=tmp_path)
    run, moved = copy_run(ctx), tmp_path / "moved"
    shutil.copytree(world.dataset, moved)
    assert main(["train", str(moved), "--resume", "--out", str(run), "--steps", "3"]) == 0
    assert json.loads((run / "metrics.json").read_text())["steps"] == 3


def test_a_full_disk_is_one_line_and_other_os_errors_are_bugs():
    from mitsnerf.cli import user_error_line

    line = user_error_line(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)))  # a write that names no file
    assert line is not None and "disk full" in line
    assert user_error_line(OSError(errno.EDQUOT, os.strerror(errno.EDQUOT))) is not None
    assert user_error_line(OSError(errno.EBADF, os.strerror(errno.EBADF))) is None


def test_a_locked_run_directory_is_refused_naming_the_holder(world, tmp_path, capsys):
    from mitsnerf.outputs import exclusive_lock
    from mitsnerf.runs.directory import lock_path

    run = tmp_path / "r"
    with exclusive_lock(lock_path(run), wait=False, what=run):
        assert main([*cli_args(TRAIN, SimpleNamespace(world=world)), "--out", str(run)]) == 2
    (line,) = _error_lines(capsys.readouterr().err)
    assert str(run) in line and f"pid {os.getpid()} is writing it" in line
    assert not run.exists()


def test_a_generate_waiting_for_another_says_for_whom(world, tmp_path, capsys):
    from mitsnerf.generate import dataset_dir
    from mitsnerf.outputs import exclusive_lock
    from mitsnerf.scene.spec import load_scene

    final = dataset_dir(load_scene(str(world.spec)), tmp_path)
    held, release = threading.Event(), threading.Event()

    def hold() -> None:
        with exclusive_lock(final.parent / f".{final.name}.lock", wait=False, what=final):
            held.set()
            release.wait(30)

    holder = threading.Thread(target=hold)
    holder.start()
    held.wait(30)
    threading.Timer(1.0, release.set).start()
    assert main(["generate", str(world.spec), "--out", str(tmp_path)]) == 0
    holder.join()
    assert f"waiting for pid {os.getpid()}, which is writing {final}" in capsys.readouterr().err


def test_a_value_error_from_the_package_is_a_bug_and_keeps_its_traceback(world, tmp_path, monkeypatch):
    import mitsnerf.runs.fit

    def broken(*args, **kwargs):
        raise ValueError("an internal invariant failed")

    monkeypatch.setattr(mitsnerf.runs.fit, "fit", broken)
    with pytest.raises(ValueError, match="internal invariant"):
        main([*cli_args(TRAIN, SimpleNamespace(world=world)), "--out", str(tmp_path / "r")])


def test_debug_shows_the_traceback_of_a_user_error(world, tmp_path):
    from mitsnerf.errors import UsageError

    with pytest.raises(UsageError, match="--method"):
        main(["--debug", "train", str(world.dataset), "--out", str(tmp_path / "r"), "--method", "nope"])


# --------------------------------------------------------------------------- places root cannot write

#: Run in one child process without CAP_DAC_OVERRIDE: each argv through main(), the exit status and
#: the error lines back as JSON.
_CHILD = """
import contextlib, io, json, sys
from mitsnerf.cli import main
out = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(argv)
    out.append([code, err.getvalue()])
print(json.dumps(out))
"""


def test_unwritable_outputs_are_refused_before_any_work(world, tmp_path):
    if os.geteuid() == 0 and not shutil.which("setpriv"):
        pytest.skip("as root, testing an unwritable directory needs setpriv to drop CAP_DAC_OVERRIDE")
    locked = tmp_path / "ro"
    locked.mkdir()
    run = locked / "run"
    shutil.copytree(world.run, run)
    train = cli_args(TRAIN, SimpleNamespace(world=world))
    argvs = [[*train, "--out", str(locked / "new")],                    # a new run in a read-only directory
             ["train", "--resume", "--out", str(run), "--steps", "4"],  # resuming a read-only run
             ["render", str(run)],                                      # the default RUN/renders
             ["generate", str(world.spec), "--out", str(locked / "data")]]
    for p in (run, locked):
        p.chmod(0o555)
    try:
        prefix = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search"] if os.geteuid() == 0 else []
        env = {**os.environ, "PYTHONPATH": child_pythonpath(world.repo)}
        done = subprocess.run([*prefix, sys.executable, "-c", _CHILD, json.dumps(argvs)], env=env, capture_output=True,
                              text=True, timeout=120)
    finally:
        for p in (locked, run):
            p.chmod(0o755)
    assert done.returncode == 0, done.stderr
    results = json.loads(done.stdout.strip().splitlines()[-1])
    for argv, (code, err) in zip(argvs, results):
        assert code == 2 and "Traceback" not in err, (argv, err)
        (line,) = _error_lines(err)
        assert str(locked) in line and ("cannot" in line), line
    assert sorted(p.name for p in locked.iterdir()) == ["run"]
    assert json.loads((run / "metrics.json").read_text())["steps"] == 2
