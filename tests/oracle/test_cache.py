"""A dataset's oracle: computed once, cached atomically in the dataset, keyed by its settings, scored both ways."""

from __future__ import annotations

import json

import numpy as np
import pytest

import mitsnerf.oracle.cache as cache
from mitsnerf.data.dataset import load_dataset
from mitsnerf.generate import generate_dataset
from mitsnerf.oracle.cache import OracleConfig, ensure_oracle, load_oracle, oracle_path
from mitsnerf.scene.spec import parse_scene

TINY = {
    "name": "tiny_oracle",
    "volume": {"family": "cloud", "resolution": 16, "seed": 1, "sigma_t_scale": 30.0,
               "params": {"albedo": [0.8, 0.8, 0.8]}},
    "lights": [{"type": "constant", "radiance": [0.5, 0.55, 0.6]},
               {"type": "directional", "direction": [-0.4, -0.8, -0.45], "irradiance": [4.0, 3.8, 3.5]}],
    "cameras": {"rig": "sphere", "n_train": 1, "n_test": 2, "width": 8, "height": 8, "fov": 40.0, "radius": 2.2},
    "render": {"spp_train": 4, "spp_test": 64, "max_depth": -1, "seed": 0, "noise_floor": True},
}
CONFIG = OracleConfig(spp=8, resolution=8, n_samples=32, noise_replicas=2)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = generate_dataset(parse_scene(json.loads(json.dumps(TINY)), "tiny.toml"), tmp_path_factory.mktemp("d"),
                            progress=False)
    return load_dataset(root)


def test_computed_once_then_read_from_the_cache(dataset, monkeypatch):
    oracle = ensure_oracle(dataset, CONFIG, 2)
    assert oracle.path == oracle_path(dataset, CONFIG, 2) and oracle.path.parent == dataset.root / "oracle"
    names = {p.name for p in oracle.path.iterdir()}
    assert names == {"oracle.json", "scores.json", "lbar_mc.npy", "lbar_mc_se.npy", "lbar_delta.npy",
                     "test_k1.npy", "test_k2.npy", "var_k2.npy"}
    assert not [p for p in oracle.path.parent.iterdir() if ".tmp-" in p.name]
    for k in (1, 2):
        m = oracle.metrics(k)
        assert 10 < m["psnr_test_medium"] < 80 and m["noise_floor_psnr_medium"] > 0
    info = oracle.info
    assert info["grid_points"] > 0 and info["volpath_samples"] == info["grid_points"] * 8
    assert set(info["error_split"]) >= {"mse_medium", "mc_var_medium", "ref_var_medium", "bias2_medium"}
    lbar, se = np.load(oracle.path / "lbar_mc.npy"), np.load(oracle.path / "lbar_mc_se.npy")
    assert lbar.shape == se.shape == (8, 8, 8, 3) and (se > 0).any() and (lbar >= 0).all()
    assert np.load(oracle.path / "lbar_delta.npy").shape == (16, 16, 16, 3)

    def boom(*args, **kwargs):
        raise AssertionError("the cached oracle was computed again")

    monkeypatch.setattr(cache, "compute_oracle", boom)
    again = ensure_oracle(dataset, CONFIG, 2)
    assert again.scores == oracle.scores
    with pytest.raises(AssertionError, match="computed again"):  # other settings: another oracle
        ensure_oracle(dataset, OracleConfig(spp=9, resolution=8, n_samples=32), 2)


def test_an_interrupted_computation_leaves_no_oracle(dataset, monkeypatch):
    config = OracleConfig(spp=4, resolution=4, n_samples=8, noise_replicas=1, seed=5)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "save", interrupted)
    with pytest.raises(KeyboardInterrupt):
        ensure_oracle(dataset, config, 1)
    path = oracle_path(dataset, config, 1)
    assert load_oracle(path) is None and not path.exists()
    assert not [p for p in path.parent.iterdir() if ".tmp-" in p.name]


def test_no_oracle_without_the_true_grids(dataset, tmp_path):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    for name in ("transforms_train.json", "transforms_test.json"):
        (foreign / name).write_text((dataset.root / name).read_text())
    for split in ("train", "test"):
        (foreign / split).symlink_to(dataset.root / split)
    assert ensure_oracle(load_dataset(foreign), CONFIG, 1) is None


def test_settings_are_validated():
    from mitsnerf.config import from_dict
    from mitsnerf.errors import SpecError

    with pytest.raises(SpecError, match="bench.toml: oracle.resolution: must be 0"):
        from_dict(OracleConfig, {"resolution": 1}, source="bench.toml", prefix="oracle")
    with pytest.raises(SpecError, match="spp"):
        from_dict(OracleConfig, {"spp": 1}, source="bench.toml", prefix="oracle")


def test_an_anisotropic_mediums_key_spells_out_the_directional_defaults():
    """With ``directional = None`` the defaults apply to an anisotropic medium, and are part of its key (a change
    of the defaults is another oracle); an isotropic medium's settings and key are left as they are."""
    from mitsnerf.oracle.cache import resolved
    from mitsnerf.oracle.directional import DirectionalConfig

    hg = parse_scene(json.loads(json.dumps({**TINY, "volume": {**TINY["volume"], "phase": {"type": "hg", "g": 0.85}}})),
                     "hg.toml")
    iso = parse_scene(json.loads(json.dumps(TINY)), "tiny.toml")
    assert resolved(CONFIG, iso) is CONFIG
    assert resolved(CONFIG, hg).directional == DirectionalConfig()
    custom = OracleConfig(directional=DirectionalConfig(spp=64, order=3))
    assert resolved(custom, hg) is custom


def test_the_oracle_is_scored_less_its_own_monte_carlo_variance_and_an_older_one_gets_it_once(dataset, monkeypatch):
    """At its footprint the oracle's medium PSNR less its own variance (its cached renders and their variance) is
    kept beside the raw one, above it; an oracle cached before that figure was kept gets it from its cached arrays
    (not computed again), written once into its scores.json."""
    from mitsnerf.scoring.reference import load_reference
    from mitsnerf.scoring.variance import without_variance

    oracle = ensure_oracle(dataset, CONFIG, 2)
    ref = load_reference(dataset)
    expected = without_variance(np.load(oracle.path / "test_k2.npy"), ref.images, ref.masks,
                                np.load(oracle.path / "var_k2.npy"))
    kept = oracle.metrics(2)
    assert kept["psnr_test_medium_without_mc"] == pytest.approx(expected["psnr_test_medium_without_mc"])
    assert kept["psnr_test_medium_without_mc"] > kept["psnr_test_medium"] and kept["mc_var_test_medium"] > 0
    assert "psnr_test_medium_without_mc" not in oracle.metrics(1)   # its variance is computed at its footprint
    scores = json.loads((oracle.path / "scores.json").read_text())
    scores["footprint_2"] = {k: v for k, v in scores["footprint_2"].items() if k not in expected}
    (oracle.path / "scores.json").write_text(json.dumps(scores))
    monkeypatch.setattr(cache, "compute_oracle", lambda *a, **k: pytest.fail("the cached oracle was computed again"))
    older = ensure_oracle(dataset, CONFIG, 2)
    assert older.metrics(2)["psnr_test_medium_without_mc"] == pytest.approx(kept["psnr_test_medium_without_mc"])
    assert json.loads((oracle.path / "scores.json").read_text())["footprint_2"]["psnr_test_medium_without_mc"] \
        == pytest.approx(kept["psnr_test_medium_without_mc"])
