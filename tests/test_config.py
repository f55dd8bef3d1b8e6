"""Typed configs from plain tables: nested tables override the field's own default."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, Mapping

import pytest

from mitsnerf.config import (apply_overrides, doc_table, field_docs, from_dict, param, parse_value, read_toml, to_dict,
                             with_overrides)
from mitsnerf.errors import SpecError
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


# ---------------------------------------------------------------- the one mechanism: param(), from_dict


@dataclass(frozen=True)
class Leaf:
    n: int = param(1, lo=1, hi=2**20)
    x: float = param(0.5, lo=0.0, hi=1.0, hi_open=True)
    rgb: tuple[float, float, float] = param((0.0, 0.0, 0.0), lo=0.0)
    mode: str = param("a", choices=("a", "b"))
    flag: bool = param(True)
    kind: Literal["p", "q"] = param("p")
    pair: tuple[int, int] | None = param(None)


@dataclass(frozen=True)
class Circle:
    config_kind: ClassVar[str] = "shape"
    type: ClassVar[str] = "circle"
    r: float = param(lo=0.0, lo_open=True)


@dataclass(frozen=True)
class Square:
    config_kind: ClassVar[str] = "shape"
    type: ClassVar[str] = "square"
    side: float = param(1.0, lo=0.0, lo_open=True)


@dataclass(frozen=True)
class Root:
    name: str = param()
    leaf: Leaf = param(default_factory=Leaf)
    shapes: tuple[Circle | Square, ...] = param(())
    seeds: tuple[int, ...] = param((0,), lo=0)
    extra: Mapping[str, Any] = param(default_factory=dict)
    """Free-form settings."""

    def __post_init__(self) -> None:
        if self.name == "bad":
            raise ValueError("name: must not be 'bad'")
        if len(self.shapes) > 2:
            raise ValueError("shapes.2: at most two shapes")


CIRCLE = {"type": "circle", "r": 1}
BAD_ROOTS = [
    ({"leaf": {"n": 0}}, "leaf.n", "must be an integer in [1, 1048576], got 0"),
    ({"leaf": {"n": True}}, "leaf.n", "must be an integer in [1, 1048576], got True"),
    ({"leaf": {"n": 2.0}}, "leaf.n", "must be an integer in [1, 1048576], got 2.0"),
    ({"leaf": {"x": 1.0}}, "leaf.x", "must be a number in [0, 1), got 1.0"),
    ({"leaf": {"x": float("nan")}}, "leaf.x", "must be a number in [0, 1), got nan"),
    ({"leaf": {"x": "0.5"}}, "leaf.x", "must be a number in [0, 1), got '0.5'"),
    ({"leaf": {"rgb": [1, -1, 0]}}, "leaf.rgb", "must be 3 numbers >= 0, got [1, -1, 0]"),
    ({"leaf": {"rgb": [1, float("inf"), 0]}}, "leaf.rgb", "must be 3 numbers >= 0, got [1, inf, 0]"),
    ({"leaf": {"rgb": [1, 1]}}, "leaf.rgb", "must be 3 numbers >= 0, got 2 values"),
    ({"leaf": {"rgb": "red"}}, "leaf.rgb", "must be 3 numbers >= 0, got a string 'red'"),
    ({"leaf": {"mode": "c"}}, "leaf.mode", "must be one of 'a', 'b', got 'c'"),
    ({"leaf": {"flag": 1}}, "leaf.flag", "must be true or false, got 1"),
    ({"leaf": {"kind": "r"}}, "leaf.kind", "must be one of 'p', 'q', got 'r'"),
    ({"leaf": {"pair": [1, "x"]}}, "leaf.pair", "must be 2 numbers, got [1, 'x']"),
    ({"leaf": 3}, "leaf", "must be a table, got an integer"),
    ({"leaf": {"mdoe": "a"}}, "leaf.mdoe", "unknown field (did you mean 'mode'?)"),
    ({"lef": {}}, "lef", "unknown field (did you mean 'leaf'?)"),
    ({"zzz": 1}, "zzz", "unknown field (known: name, leaf, shapes, seeds, extra)"),
    ({"name": None}, "name", "missing field (a string)"),
    ({"name": "bad"}, "name", "must not be 'bad'"),
    ({"shapes": [CIRCLE, {"type": "square", "side": -1}]}, "shapes.1.side", "must be a number > 0, got -1"),
    ({"shapes": [{"r": 1}]}, "shapes.0.type", "missing field (one of circle, square)"),
    ({"shapes": [{"type": "hexagon"}]}, "shapes.0.type", "unknown shape type 'hexagon' (known: circle, square)"),
    ({"shapes": [{"type": "circle"}]}, "shapes.0.r", "missing field (a number > 0)"),
    ({"shapes": [{"type": "circle", "r": 1, "d": 2}]}, "shapes.0.d", "unknown field (known: r)"),
    ({"shapes": [CIRCLE, [1]]}, "shapes.1", "must be a table, got a list"),
    ({"shapes": [CIRCLE, CIRCLE, CIRCLE]}, "shapes.2", "at most two shapes"),
    ({"shapes": "circle"}, "shapes", "must be a list, got a string 'circle'"),
    ({"seeds": [0, -1]}, "seeds.1", "must be an integer >= 0, got -1"),
    ({"extra": [1]}, "extra", "must be a table, got a list"),
]


@pytest.mark.parametrize("change, field_name, message", BAD_ROOTS, ids=[c[1] + ":" + c[2][:20] for c in BAD_ROOTS])
def test_every_problem_names_the_file_and_the_field(change, field_name, message):
    data = {k: v for k, v in {"name": "r", **change}.items() if v is not None}
    with pytest.raises(SpecError) as info:
        from_dict(Root, data, source="dir/f.toml")
    assert (info.value.where, info.value.field, info.value.message) == ("dir/f.toml", field_name, message)
    assert str(info.value) == f"dir/f.toml: {field_name}: {message}"
    assert isinstance(info.value, ValueError)  # callers that catch ValueError keep working


def test_prefix_and_no_source():
    with pytest.raises(SpecError) as info:
        from_dict(Leaf, {"n": 0}, prefix="quick.leaf")
    assert info.value.where is None and str(info.value) == "quick.leaf.n: must be an integer in [1, 1048576], got 0"


def test_values_are_converted_and_round_trip():
    root = from_dict(Root, {"name": "r", "leaf": {"x": 0, "rgb": [1, 2, 3], "pair": [1, 2]}, "seeds": [3, 4],
                            "shapes": [CIRCLE, {"type": "square"}]})
    assert root.leaf.x == 0.0 and isinstance(root.leaf.x, float) and root.leaf.rgb == (1.0, 2.0, 3.0)
    assert root.leaf.pair == (1, 2) and root.seeds == (3, 4)
    assert root.shapes == (Circle(r=1.0), Square(side=1.0))
    data = to_dict(root)
    assert data["shapes"] == [{"type": "circle", "r": 1.0}, {"type": "square", "side": 1.0}]
    assert data["leaf"]["rgb"] == [1.0, 2.0, 3.0]
    assert "pair" not in to_dict(Leaf())  # None with a None default is left out (TOML has no null)
    assert from_dict(Root, data) == root


def test_method_config_errors_still_read_field_problem():
    from mitsnerf.methods.voxel import VoxelMethodConfig

    with pytest.raises(ValueError) as info:
        from_dict(NeRFMethodConfig, {"n_samples": 0})
    assert str(info.value) == "n_samples: must be an integer in [1, 4096], got 0"
    with pytest.raises(ValueError, match=r"^network\.depth: "):
        from_dict(NeRFMethodConfig, {"network": {"depth": 0}})
    with pytest.raises(ValueError) as info:  # a message that does not start with one field stays whole
        from_dict(VoxelMethodConfig, {"resolution": 4, "initial_resolution": 8})
    assert info.value.field is None and str(info.value).startswith("initial_resolution, resolution: ")
    with pytest.raises(ValueError, match=r"^coarse_network\.width: must be an integer in \[1, 4096\], got 'w'$"):
        from_dict(NeRFMethodConfig, {"coarse_network": {"width": "w"}})


def test_docs_come_from_one_place_per_field():
    from mitsnerf.volumes.cloud import Params

    assert field_docs(Root)["extra"] == "Free-form settings."  # an attribute docstring
    assert field_docs(Params)["radius"] == "envelope radius (density 0 beyond it)"  # param(doc=...)
    table = doc_table(Params)
    assert "| radius | a number in [0.05, 0.45] | 0.32 | envelope radius (density 0 beyond it) |" in table
    assert "| albedo | 3 numbers in [0, 1] | [0.8, 0.8, 0.8] |" in table
    assert "| seeds | a list | [0] |" in doc_table(Root) and "| name | a string | required |" in doc_table(Root)


# ---------------------------------------------------------------- dotted overrides, CLI values, files


GOOD_OVERRIDES = [
    ({}, {"a.b": 1}, {"a": {"b": 1}}),
    ({"l": [{"x": 0}, {"x": 1}]}, {"l.1.x": 2}, {"l": [{"x": 0}, {"x": 2}]}),
    ({"l": [{"x": 0}]}, {"l.0": {"y": (1, 2)}}, {"l": [{"y": [1, 2]}]}),
    ({"m": [{"c": {"n": 1}}, {"c": {}}]}, {"m.1.c.n": 3}, {"m": [{"c": {"n": 1}}, {"c": {"n": 3}}]}),
]


@pytest.mark.parametrize("data, overrides, expected", GOOD_OVERRIDES)
def test_apply_overrides(data, overrides, expected):
    before = copy.deepcopy(data)
    assert apply_overrides(data, overrides, "x.toml") == expected
    assert data == before  # a copy


BAD_OVERRIDES = [
    ({"l": [{"x": 0}, {"x": 1}]}, "l.2.x", "no item '2' (there are 2)"),
    ({"l": [{"x": 0}]}, "l.x", "no item 'x' (there are 1)"),
    ({"n": 1}, "n.x", "cannot override inside 'n': not a table"),
    ({"n": {"m": "s"}}, "n.m.k", "cannot override inside 'n.m': not a table"),
]


@pytest.mark.parametrize("data, key, message", BAD_OVERRIDES)
def test_apply_overrides_errors_name_the_source_and_the_key(data, key, message):
    with pytest.raises(SpecError) as info:
        apply_overrides(data, {key: 1}, "--set")
    assert (info.value.where, info.value.field, info.value.message) == ("--set", key, message)


@pytest.mark.parametrize("text, value", [("16", 16), ("0.5", 0.5), ("[1, 1, 1]", [1, 1, 1]), ("true", True),
                                         ('"7"', "7"), ("sphere", "sphere"), ("", "")])
def test_parse_value(text, value):
    assert parse_value(text) == value and type(parse_value(text)) is type(value)


def test_read_toml_names_the_file(tmp_path):
    good = tmp_path / "good.toml"
    good.write_text('a = 1\n[b]\nc = "x"\n')
    assert read_toml(good) == {"a": 1, "b": {"c": "x"}}
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"a = 1\n\xff\xfe\x00\x80")
    bad = tmp_path / "bad.toml"
    bad.write_text("a = \n")
    for path, message in [(binary, "not a text file (invalid UTF-8 at byte 6)"), (tmp_path, "is a directory, not a spec"),
                          (tmp_path / "absent.toml", "cannot read: No such file or directory")]:
        with pytest.raises(SpecError) as info:
            read_toml(path, "a spec")
        assert (info.value.where, info.value.field, info.value.message) == (str(path), None, message)
    with pytest.raises(SpecError, match=r"bad\.toml: TOML syntax error: .*line 1"):
        read_toml(bad)


# ---------------------------------------------------------------- the method and field configs


def _param_configs():
    from mitsnerf.fields.ngp import NGPConfig
    from mitsnerf.fields.occupancy import OccupancyConfig
    from mitsnerf.fields.voxel import VoxelFieldConfig
    from mitsnerf.methods.mitsuba_inverse import MitsubaInverseConfig
    from mitsnerf.methods.ngp import NGPMethodConfig
    from mitsnerf.methods.voxel import VoxelMethodConfig

    return [NGPMethodConfig, NGPConfig, OccupancyConfig, VoxelMethodConfig, VoxelFieldConfig, MitsubaInverseConfig]


@pytest.mark.parametrize("cls", _param_configs(), ids=lambda c: c.__name__)
def test_method_and_field_configs_declare_every_field_once(cls):
    import dataclasses

    from mitsnerf.config import _BOUNDS

    undeclared = [f.name for f in dataclasses.fields(cls) if _BOUNDS not in f.metadata]
    undocumented = [name for name, doc in field_docs(cls).items() if not doc]
    assert not undeclared and not undocumented, (undeclared, undocumented)
    assert "| name " not in (cls.__doc__ or "") and "| field " not in (cls.__doc__ or "")  # no second table
    assert from_dict(cls, to_dict(cls())) == cls()


CODE_BUILT = [  # (config, kwargs, message): built in code, checked as from_dict checks a file
    ("OccupancyConfig", {"decay": 2.0}, "decay: must be a number in [0, 1], got 2.0"),
    ("OccupancyConfig", {"resolution": 1}, "resolution: must be an integer in [2, 512], got 1"),
    ("NGPConfig", {"features_per_level": 3}, "features_per_level: must be one of 2, 4, 8, got 3"),
    ("NGPMethodConfig", {"lr": 0.0}, "lr: must be a number > 0, got 0.0"),
    ("VoxelFieldConfig", {"sh_degree": 4}, "sh_degree: must be an integer in [0, 3], got 4"),
    ("VoxelMethodConfig", {"upsample_steps": (-1,)}, "upsample_steps.0: must be an integer >= 0, got -1"),
    ("MitsubaInverseConfig", {"max_depth": -2}, "max_depth: must be an integer >= -1, got -2"),
    ("MitsubaInverseConfig", {"init_depth": 300.0}, "init_depth: must be <= depth_max (200), got 300"),
    ("MitsubaInverseConfig", {"majorant_depth": 40.0}, "majorant_depth: fixes prbvolpath's one majorant; estimator "
                                                      "'drt' uses a majorant grid (majorant_cell, majorant_floor)"),
    ("MitsubaInverseConfig", {"estimator": "delta"},
     "estimator: must be one of 'drt', 'free_flight', 'prbvolpath', got 'delta'"),
]


@pytest.mark.parametrize("name, kwargs, message", CODE_BUILT, ids=[c[2][:24] for c in CODE_BUILT])
def test_configs_built_in_code_are_checked(name, kwargs, message):
    cls = {c.__name__: c for c in _param_configs()}[name]
    with pytest.raises(ValueError) as info:
        cls(**kwargs)
    assert str(info.value) == message
    with pytest.raises(SpecError) as info:  # and from a file: the same words, the file and the field
        from_dict(cls, kwargs, source="m.toml")
    assert str(info.value) == f"m.toml: {message}"


def test_a_nested_table_lists_the_dotted_keys_with_the_fields_own_defaults():
    from mitsnerf.methods.voxel import VoxelMethodConfig

    table = doc_table(VoxelMethodConfig, nested=True)
    assert "| grid.sh_degree | an integer in [0, 3] | 1 | Highest SH band L" in table
    assert "| occupancy.early_stop_T | a number in [0, 1) | 0.0001 |" in table
    assert "| grid |" not in table and "| grid | a table |" in doc_table(VoxelMethodConfig)
    small = doc_table(Outer, nested=True)  # Outer.small's default is Inner(width=32, depth=2), not Inner()
    assert "| small.width | an integer | 32 |" in small and "| main.width | an integer | 64 |" in small


def test_the_methods_command_prints_a_methods_settings(capsys):
    from mitsnerf.cli import main
    from mitsnerf.methods import methods

    assert main(["methods"]) == 0
    assert [line.split()[0] for line in capsys.readouterr().out.splitlines()] == list(methods())
    assert main(["methods", "mitsuba-inverse"]) == 0
    out = capsys.readouterr().out
    assert "| max_depth | an integer >= -1 | 0 | Path length" in out and "--method mitsuba-inverse" in out
    assert main(["methods", "nope"]) == 2
    assert capsys.readouterr().err.startswith("mitsnerf: error: NAME: unknown method 'nope' (known: ")


def test_a_nested_method_config_error_names_the_dotted_field():
    from mitsnerf.methods.ngp import NGPMethodConfig

    with pytest.raises(SpecError) as info:
        from_dict(NGPMethodConfig, {"network": {"log2_hashmap_size": 30}}, source="--set")
    assert str(info.value) == "--set: network.log2_hashmap_size: must be an integer in [8, 24], got 30"
    with pytest.raises(SpecError, match=r"^--set: occupancy\.decy: unknown field \(did you mean 'decay'\?\)$"):
        from_dict(NGPMethodConfig, {"occupancy": {"decy": 0.5}}, source="--set")


@pytest.mark.parametrize(("data", "hint"), [
    ({"shadow_samples": 8}, "(did you mean 'field.shadow_samples'?)"),  # a nested field's name: its dotted name
    ({"depth": 8}, "(did you mean 'main.depth' or 'small.depth'?)"),
    ({"widht": 8}, "(did you mean 'main.width'?)"),  # nothing close at the top: the closest nested field
])
def test_an_unknown_field_that_a_nested_config_has_is_pointed_at_by_its_dotted_name(data, hint):
    """``--set shadow_samples=8`` on scatter suggested ``n_samples``, a field of another meaning, rather than the
    ``field.shadow_samples`` it names."""
    from mitsnerf.methods.scatter import ScatterMethodConfig

    cls = ScatterMethodConfig if "shadow_samples" in data else Outer
    with pytest.raises(SpecError) as exc:
        from_dict(cls, data, source="--set")
    assert str(exc.value).endswith(hint), str(exc.value)


def test_a_nested_field_is_set_by_its_dotted_name_as_by_its_table():
    assert from_dict(Outer, {"main.width": 8, "small": {"depth": 1}, "small.width": 2}) == \
        Outer(main=Inner(width=8), small=Inner(width=2, depth=1))


# ---------------------------------------------------------------- configs read back as saved


@dataclass(frozen=True)
class _SavedGrid:
    resolution: int = param(64, lo=1)
    skip: bool = param(True, since=("0.1.0+abc1234", False))


@dataclass(frozen=True)
class _SavedMethod:
    grid: _SavedGrid = param(default_factory=lambda: _SavedGrid(resolution=32))
    lr: float = param(0.1)


def test_a_saved_config_reads_a_missing_nested_setting_as_declared_over_the_fields_own_default():
    from mitsnerf.config import from_saved, saved_readings

    assert from_saved(_SavedMethod, {"lr": 0.2}) == _SavedMethod(grid=_SavedGrid(resolution=32, skip=False), lr=0.2)
    assert from_saved(_SavedMethod, {"grid": {"resolution": 8, "skip": True}}).grid == _SavedGrid(8, True)  # as is
    assert from_dict(_SavedMethod, {"lr": 0.2}).grid.skip  # a new config: today's default
    assert saved_readings(_SavedMethod) == {"grid.resolution": 32, "grid.skip": False, "lr": 0.1}
    assert "(added in 0.1.0+abc1234: a run saved before reads false) |" in doc_table(_SavedMethod, nested=True)
