"""The example plugin examples/mitsnerf-tensorf (TensoRF-VM) as a user installs it: pip builds it into a folder of
its own, outside the package, and mitsnerf finds its ``mitsnerf.methods`` entry point on ``PYTHONPATH``; then its
VM density against numpy, and its tiny configuration learning."""

from __future__ import annotations

import doctest
import json
import importlib
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "mitsnerf-tensorf"


def _env(site: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("MITSNERF_METHODS", "MITSNERF_VOLUMES")}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))
    return env


def _mitsnerf(site: Path, *args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mitsnerf", *args], cwd=cwd, env=_env(site), capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The plugin installed as README.md says, ``pip install --no-deps --no-build-isolation --target DIR``, from a
    copy of its source (a build writes egg-info and build/ next to the source)."""
    try:
        import pip  # noqa: F401
    except ImportError:
        pytest.skip("pip is not installed in this environment: the plugin cannot be installed the way users do")
    root = tmp_path_factory.mktemp("tensorf")
    source = root / "src"
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    target = root / "site"
    done = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index",
                           "--disable-pip-version-check", "--quiet", "--target", str(target), str(source)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, (
        "pip could not build the plugin without build isolation; the test extra's setuptools >= 70.1 "
        f"(make setup) builds wheels by itself:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    assert list(target.glob("mitsnerf_tensorf-*.dist-info/entry_points.txt")), sorted(p.name for p in target.iterdir())
    return target


def test_methods_lists_tensorf_from_its_entry_point_with_its_version(site, tmp_path):
    done = _mitsnerf(site, "methods", cwd=tmp_path)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    line = next(line for line in done.stdout.splitlines() if line.startswith("tensorf "))
    assert line.split()[1:3] == ["entry", "point"] and "TensoRF" in line
    assert ("from entry point mitsnerf.methods: tensorf = mitsnerf_tensorf:TensoRFModel (mitsnerf-tensorf==0.1.0)"
            in done.stdout)
    shown = _mitsnerf(site, "methods", "tensorf", cwd=tmp_path)
    assert shown.returncode == 0 and "| field.density_components |" in shown.stdout and "| upsample_steps |" in \
        shown.stdout


def test_methods_check_tensorf_conforms(site, tmp_path):
    done = _mitsnerf(site, "methods", "--check", "tensorf", "--no-progress", cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.strip().splitlines()
    assert lines[-1] == "tensorf: conforms" and sum(line.startswith("ok ") for line in lines) == 7, done.stdout


SCENE = """name = "tcloud"
[volume]
family = "cloud"
resolution = 16
seed = 1
sigma_t_scale = 30.0
params = { albedo = [0.8, 0.8, 0.8] }
[[lights]]
type = "constant"
radiance = [0.5, 0.55, 0.6]
[[lights]]
type = "directional"
direction = [-0.4, -0.8, -0.45]
irradiance = [4.0, 3.8, 3.5]
[cameras]
rig = "sphere"
n_train = 4
n_test = 2
width = 16
height = 16
fov = 40.0
radius = 2.2
seed = 0
[render]
spp_train = 4
spp_test = 16
max_depth = -1
seed = 0
noise_floor = true
"""

BENCH = """name = "plugin"
scenes = ["tcloud.toml"]
seeds = [0]
train = { steps = 12, batch_rays = 128, log_every = 4 }
eval = { curve_points = 2, od_samples = 16 }
oracle = { spp = 4, resolution = 8, n_samples = 16, noise_replicas = 1 }

[[methods]]
name = "ngp"
config.n_samples = 16
config.network = { n_levels = 2, base_resolution = 8, max_resolution = 16, hidden = 8, color_hidden = 8 }

[[methods]]
name = "tensorf"
config.n_samples = 16
config.resolution = 16
config.initial_resolution = 8
config.upsample_steps = [5]
config.field = { density_components = 4, app_components = 4 }
"""


def test_a_tiny_sweep_puts_tensorf_beside_ngp(site, tmp_path):
    (tmp_path / "tcloud.toml").write_text(SCENE)
    (tmp_path / "plugin.toml").write_text(BENCH)
    done = _mitsnerf(site, "bench", str(tmp_path / "plugin.toml"), "--data", str(tmp_path / "data"), "--results",
                     str(tmp_path / "results"), "--no-progress", cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    table = (tmp_path / "results" / "plugin" / "table.md").read_text()
    rows = [[c.strip() for c in line.split("|")[1:-1]] for line in table.splitlines() if line.startswith("| tcloud |")]
    methods = [r[1] for r in rows]
    assert {"ngp", "tensorf", "oracle (ceiling)"} <= set(methods), table
    tensorf = [r for r in rows if r[1] == "tensorf"]
    assert any("12 steps" in r for r in tensorf), table  # the cost table's budget column
    psnr = float(tensorf[0][3])  # the quality table's linear PSNR
    assert math.isfinite(psnr) and psnr > 10.0, table


# -- in-process: the plugin's module from its source folder --------------------------------------------------------


@pytest.fixture
def tensorf(monkeypatch):
    from mitsnerf.env import set_variant

    set_variant("llvm_ad_rgb")
    monkeypatch.syspath_prepend(str(EXAMPLE))
    return importlib.import_module("mitsnerf_tensorf")


def _linear(line: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(M, C): a line (R, C) at unit coordinates ``u``, texel centres at (i + 1/2) / R, clamped."""
    r = line.shape[0]
    t = np.clip(u * r - 0.5, 0.0, r - 1.0)
    i0 = np.floor(t).astype(int)
    i1 = np.minimum(i0 + 1, r - 1)
    f = (t - i0)[:, None]
    return (1 - f) * line[i0] + f * line[i1]


def _bilinear(plane: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(M, C): a plane (R_v, R_u, C) indexed [v, u] at unit coordinates (u, v), the same rule along each axis."""
    def corners(w, r):
        t = np.clip(w * r - 0.5, 0.0, r - 1.0)
        i0 = np.floor(t).astype(int)
        return i0, np.minimum(i0 + 1, r - 1), (t - i0)[:, None]

    iu0, iu1, fu = corners(u, plane.shape[1])
    iv0, iv1, fv = corners(v, plane.shape[0])
    return ((1 - fv) * ((1 - fu) * plane[iv0, iu0] + fu * plane[iv0, iu1])
            + fv * ((1 - fu) * plane[iv1, iu0] + fu * plane[iv1, iu1]))


def test_the_density_is_what_its_vectors_and_planes_say(tensorf):
    """A 5-texel VM of 3 components with known values: ``sigma = s * softplus(sum_m sum_r M_r^m v_r^m + shift)``
    against numpy's bilinear and linear lookups of the same texel-centre convention."""
    import mitsuba as mi
    from mitsnerf_tensorf.field import PAIRS, VMField, VMFieldConfig, init_params

    from mitsnerf.math.box import Box

    rng = np.random.default_rng(7)
    config = VMFieldConfig(density_components=3, app_components=2, density_shift=-1.5, distance_scale=3.0)
    params = init_params(config, 5, mi.TensorXf, seed=0)
    known = {}
    for key in params:
        if key.startswith("density."):
            known[key] = rng.uniform(-1.0, 1.0, params[key].shape).astype(np.float32)
            params[key] = mi.TensorXf(known[key])
    box = Box((-1.0, 0.0, 2.0), (1.0, 4.0, 3.0))
    field = VMField(config, params, box)
    x = np.stack([rng.uniform(-1.2, 1.2, 64), rng.uniform(-0.2, 4.2, 64), rng.uniform(1.9, 3.1, 64)], axis=1)
    p = (x - np.array(box.lo)) / (np.array(box.hi) - np.array(box.lo))
    feature = np.zeros(len(x))
    for plane, (a, b), axis, c in PAIRS:
        m = _bilinear(known[f"density.plane.{plane}"].astype(np.float64), p[:, a], p[:, b])
        v = _linear(known[f"density.line.{axis}"].astype(np.float64), p[:, c])
        feature += np.sum(m * v, axis=1)
    want = 3.0 * np.logaddexp(0.0, feature - 1.5)
    got = np.array(field.density(mi.Array3f(*(mi.Float(x[:, k].astype(np.float32)) for k in range(3)))))
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=1e-6)
    assert np.ptp(feature) > 1.0  # the points see different texels, not one constant


@pytest.mark.parametrize("decode, sh_degree", [("sh", 0), ("sh", 2), ("mlp", 0), ("mlp", 1)])
def test_both_colour_decodes_give_colours_in_range_with_gradients(tensorf, decode, sh_degree):
    import drjit as dr
    import mitsuba as mi
    from mitsnerf_tensorf.field import VMField, VMFieldConfig, init_params

    from mitsnerf.math.box import UNIT_BOX

    config = VMFieldConfig(decode=decode, sh_degree=sh_degree, app_components=3, c_max=2.0)
    params = init_params(config, 6, mi.TensorXf, seed=3)
    assert params["basis"].shape == (9, config.basis_width)
    for value in params.values():
        dr.enable_grad(value)
    field = VMField(config, params, UNIT_BOX)
    rng = dr.rng(seed=0)
    x = mi.Array3f(*(rng.random(mi.Float, 50) - 0.5 for _ in range(3)))
    rgb, sigma = field(x, dr.normalize(mi.Array3f(1.0, 2.0, 3.0)))
    values = np.array(rgb)
    assert values.shape == (3, 50) and np.all((values > 0.0) & (values < 2.0)) and np.ptp(values) > 0
    dr.backward(dr.sum(rgb.x + rgb.y + rgb.z + sigma))
    assert all(np.any(np.array(dr.grad(v)) != 0) for v in params.values())


def test_resampling_keeps_a_linear_ramp(tensorf):
    import mitsuba as mi
    from mitsnerf_tensorf.field import resample

    ramp = mi.TensorXf(((np.arange(8) + 0.5) / 8).astype(np.float32).reshape(8, 1))
    up = np.array(resample(ramp, 16)).ravel()
    inner = (np.arange(16) + 0.5) / 16
    np.testing.assert_allclose(up[1:-1], inner[1:-1], atol=1e-6)  # the ends clamp to the outer texels
    plane = mi.TensorXf(np.ones((4, 4, 3), np.float32))
    assert resample(plane, 7).shape == (7, 7, 3)


def test_the_tiny_config_is_valid_and_learns(tensorf):
    """The conformance suite's tiny settings parse, build a model, and fit rays rendered through a known medium."""
    import drjit as dr
    import drjit.opt  # noqa: F401
    import mitsuba as mi

    from mitsnerf.config import from_dict
    from mitsnerf.fields.grid import GridField
    from mitsnerf.math.box import UNIT_BOX
    from mitsnerf.methods.base import SceneInfo
    from mitsnerf.render.volume import render_rays
    from mitsnerf.train import make_optimizer
    from mitsnerf.train.step import apply_step

    model_type = tensorf.TensoRFModel
    config = from_dict(model_type.config_type, dict(model_type.tiny))
    assert config.resolution == 8 and config.resolutions() == (8,)
    scene = SceneInfo(box=UNIT_BOX, background=lambda d: mi.Array3f(0.2, 0.3, 0.4), radiance_max=1.0)
    model = model_type(config, scene, seed=0)
    n = 256
    rng = dr.rng(seed=1)
    o = mi.Array3f(rng.random(mi.Float, n) - 0.5, rng.random(mi.Float, n) - 0.5, mi.Float(-2.0) + 0.0 * rng.random(
        mi.Float, n))
    d = mi.Array3f(0.0, 0.0, 1.0) + 0.0 * o
    blob = np.exp(-np.sum(np.square(np.stack(np.meshgrid(*[np.linspace(-1, 1, 8)] * 3, indexing="ij"))), 0) * 2.0)
    truth = GridField.from_arrays((8.0 * blob).astype(np.float32), UNIT_BOX, color=(0.9, 0.6, 0.3))
    target = render_rays(truth, o, d, 32, box=UNIT_BOX, background=scene.background).rgb
    dr.eval(target)

    def mse() -> float:
        with dr.suspend_grad():
            return float(dr.mean(dr.square(model.render_rays(o, d).rgb - target), axis=None)[0])

    before = mse()
    opt = make_optimizer(model, config.lr)
    model.set_parameters(opt)  # the optimiser's differentiable copies, as the trainer hands them over
    for step in range(40):
        out = model.render_rays(o, d, u=rng.random(mi.Float, n * model.jitter_size()), training=True)
        loss = dr.mean(dr.square(out.rgb - target), axis=None)
        for extra in out.extra_losses.values():
            loss = loss + extra
        dr.backward(loss)
        apply_step(model, opt, step)  # as the trainer does
    assert model.resolution == 8 and math.isfinite(mse())
    assert mse() < 0.25 * before, (before, mse())


def test_the_plugins_doctests_pass(tensorf):
    from mitsnerf_tensorf import field, model

    for module in (field, model):
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
        assert result.failed == 0 and result.attempted > 0, module.__name__


def test_the_leaderboard_config_names_the_plugin_and_the_external_rows(site, tmp_path):
    """benchmarks/external/leaderboard.toml loads where the plugin is installed (its tensorf row needs it), and
    its [[external]] entries read the renders and timings run_nerfstudio.sh writes."""
    config = Path(__file__).resolve().parents[1] / "benchmarks" / "external" / "leaderboard.toml"
    code = ("import json, sys; from mitsnerf.bench.config import load_bench_config as load; c = load(sys.argv[1]); "
            "print(json.dumps([[m.name for m in c.methods], [(e.name, e.format, dict(e.renders), dict(e.timings)) "
            "for e in c.external]]))")
    done = subprocess.run([sys.executable, "-c", code, str(config)], cwd=tmp_path, env=_env(site),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    methods, external = json.loads(done.stdout)
    assert methods == ["voxel", "ngp", "nerf", "primitives", "tensorf", "scatter", "mitsuba-inverse"]
    assert [e[0] for e in external] == ["nerfacto", "tensorf", "vanilla-nerf", "mipnerf"]
    for name, fmt, renders, timings in external:
        run = f"../../runs/external/leaderboard/{name}"
        assert (fmt, renders, timings) == ("exr", {"cloud": f"{run}/renders/rgba"}, {"cloud": f"{run}/timings.json"})
