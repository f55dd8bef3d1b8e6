"""Typed configs from plain tables: nested tables override the field's own default."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from mitsnerf.config import from_dict, with_overrides
from mitsnerf.methods.nerf import NeRFMethodConfig


@dataclass(frozen=True)
class Inner:
    width: int = 64
    depth: int = 4


@dataclass(frozen=True)
class Outer:
    main: Inner = field(default_factory=Inner)
    small: Inner = field(default_factory=lambda: Inner(width=32, depth=2))
    lr: float = 0.1


def test_a_nested_table_overrides_the_fields_own_default_key_by_key():
    cfg = from_dict(Outer, {"small": {"depth": 3}, "lr": 1})
    assert cfg.small == Inner(width=32, depth=3)  # not Inner()'s width 64
    assert cfg.main == Inner() and cfg.lr == 1.0


def test_the_nerf_coarse_network_keeps_its_size_when_one_key_changes():
    default = NeRFMethodConfig()
    cfg = from_dict(NeRFMethodConfig, {"coarse_network": {"pos_octaves": 4}})
    assert cfg.coarse_network.pos_octaves == 4
    assert (cfg.coarse_network.width, cfg.coarse_network.depth) == (default.coarse_network.width, default.coarse_network.depth)


def test_errors_name_the_field():
    with pytest.raises(ValueError, match=r"^small\.width: expected an integer"):
        from_dict(Outer, {"small": {"width": "wide"}})
    with pytest.raises(ValueError, match=r"^bogus: unknown key"):
        from_dict(Outer, {"bogus": 1})
    assert with_overrides(Outer(), {"small.depth": 5}).small == Inner(width=32, depth=5)
