"""A tiny benchmark: two 16x16 scenes, two NeRF variants, one seed, a dozen steps each."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

from mitsnerf.bench.config import parse_bench_config
from mitsnerf.bench.runner import BenchOptions

#: A fixed code version: other developers may commit while the tests run.
CODE_VERSION = "test"

SCENE = {
    "volume": {"family": "cloud", "resolution": 16, "seed": 1, "sigma_t_scale": 30.0, "params": {"albedo": [0.8, 0.8, 0.8]}},
    "lights": [{"type": "constant", "radiance": [0.5, 0.55, 0.6]},
               {"type": "directional", "direction": [-0.4, -0.8, -0.45], "irradiance": [4.0, 3.8, 3.5]}],
    "cameras": {"rig": "sphere", "n_train": 4, "n_test": 2, "width": 16, "height": 16, "fov": 40.0, "radius": 2.2, "seed": 0},
    "render": {"spp_train": 4, "spp_test": 16, "max_depth": -1, "seed": 0, "noise_floor": True},
}


def _toml(value) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f'"{k}" = {_toml(v)}' for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def write_scene(directory: Path, name: str, family: str = "cloud", seed: int = 1) -> Path:
    spec = copy.deepcopy(SCENE)
    spec["volume"]["family"], spec["volume"]["seed"] = family, seed
    if family != "cloud":
        spec["volume"]["params"] = {}
    lines = [f'name = "{name}"']
    for table, values in spec.items():
        if table == "lights":
            for light in values:
                lines.append("[[lights]]")
                lines += [f"{k} = {_toml(v)}" for k, v in light.items()]
        else:
            lines.append(f"[{table}]")
            lines += [f"{k} = {_toml(v)}" for k, v in values.items()]
    path = directory / f"{name}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def tiny_config(scene_paths, name: str = "tiny"):
    net = {"network": {"width": 16, "depth": 1, "features": 4, "head_width": 8, "pos_octaves": 4, "dir_octaves": 2},
           "n_samples": 16, "n_importance": 0}
    wide = copy.deepcopy(net)
    wide["network"]["width"], wide["n_importance"] = 24, 8  # hierarchical: 16 + 16 + 8 samples per ray
    return parse_bench_config({
        "name": name,
        "scenes": [str(p) for p in scene_paths],
        "seeds": [0],
        "train": {"steps": 12, "batch_rays": 128, "log_every": 4},
        "eval": {"curve_points": 2, "od_samples": 16},
        "oracle": {"spp": 4, "resolution": 8, "n_samples": 16, "noise_replicas": 1},
        "methods": [{"name": "nerf", "label": "nerf-a", "config": net},
                    {"name": "nerf", "label": "nerf-b", "config": {**wide, "lr": 0.01}}],
    }, "tiny.toml")


@pytest.fixture(scope="session")
def tiny_bench(tmp_path_factory):
    """(config, options maker, data root): scenes and datasets shared by the bench tests."""
    root = tmp_path_factory.mktemp("bench")
    scenes = [write_scene(root, "tcloud", "cloud", 1), write_scene(root, "tblobs", "blobs", 3)]
    config = tiny_config(scenes)
    data = root / "data"

    def options(results: str, **kw) -> BenchOptions:
        return BenchOptions(data_root=data, results_root=root / results, progress=False, code_version=CODE_VERSION, **kw)

    return config, options
