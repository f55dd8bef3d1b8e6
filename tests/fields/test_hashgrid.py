"""The hash grid's settings are declared once (:class:`mitsnerf.fields.hashgrid.HashGridConfig`) and used by both the
ngp field and scatter's hash medium, with the keys (``--set`` and saved configs) they had before."""

from __future__ import annotations

import dataclasses

import pytest

from mitsnerf.config import from_dict, to_dict
from mitsnerf.fields.media import HashMediumConfig
from mitsnerf.fields.ngp import NGPConfig

GRID_KEYS = ("n_levels", "features_per_level", "log2_hashmap_size", "base_resolution", "max_resolution", "init_scale")

#: The configs as saved before the hash grid's declaration was shared (to_dict of the defaults, then).
SAVED = {
    NGPConfig: {"n_levels": 3, "features_per_level": 2, "log2_hashmap_size": 15, "base_resolution": 16,
                "max_resolution": 24, "hidden": 64, "geo_features": 15, "color_hidden": 64, "color_layers": 1,
                "sh_degree": 0, "sigma_bias": 0.0, "density_channels": 1, "c_max": 1.0, "init_scale": 1e-4,
                "network_path": "auto", "split_k": -1},
    HashMediumConfig: {"n_levels": 3, "features_per_level": 2, "log2_hashmap_size": 15, "base_resolution": 16,
                       "max_resolution": 24, "hidden": 64, "features": 15, "color_hidden": 64, "init_scale": 1e-4},
}


def _declared_by(cls, name: str) -> type:
    """The class of ``cls``'s MRO whose own body declares field ``name``."""
    return next(k for k in cls.__mro__ if name in k.__dict__.get("__annotations__", {}))


def test_the_hash_grid_settings_have_one_declaration_for_ngp_and_scatter():
    for name in GRID_KEYS:
        owners = {_declared_by(cls, name) for cls in (NGPConfig, HashMediumConfig)}
        assert len(owners) == 1, f"{name} is declared by {sorted(o.__name__ for o in owners)}"
        fields = [{f.name: f for f in dataclasses.fields(cls)}[name] for cls in (NGPConfig, HashMediumConfig)]
        assert fields[0] is fields[1]  # one range, one default, one meaning


@pytest.mark.parametrize("cls", list(SAVED), ids=lambda c: c.__name__)
def test_saved_configs_and_set_keys_read_as_before(cls):
    assert to_dict(cls()) == SAVED[cls]
    assert from_dict(cls, SAVED[cls]) == cls()
    assert from_dict(cls, {**SAVED[cls], "n_levels": 4, "max_resolution": 64}).per_level_scale == pytest.approx(
        (64 / 16) ** (1 / 3))


def test_both_refuse_a_finest_level_below_the_coarsest():
    for cls in (NGPConfig, HashMediumConfig):
        with pytest.raises(ValueError, match=r"^max_resolution: must be >= base_resolution \(32\), got 16$"):
            cls(base_resolution=32, max_resolution=16)
