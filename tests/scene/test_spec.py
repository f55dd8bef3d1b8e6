"""Scene specs: parsing, round trips, overrides, hashes, the library, and every malformed-spec path."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from mitsnerf.errors import SpecError
from mitsnerf.scene.spec import (
    ConstantLight,
    DirectionalLight,
    SkyLight,
    list_scenes,
    load_scene,
    parse_scene,
    scenes_dir,
)

from .conftest import TINY

DELETE = object()


def _set(d: dict, path: str, value) -> dict:
    node = d
    parts = path.split(".")
    for p in parts[:-1]:
        node = node[int(p)] if isinstance(node, list) else node[p]
    last = parts[-1]
    if isinstance(node, list):
        node[int(last)] = value
    elif value is DELETE:
        del node[last]
    else:
        node[last] = value
    return d


def test_parse_fields(tiny_spec):
    assert tiny_spec.name == "tiny"
    assert tiny_spec.volume.family == "cloud" and tiny_spec.volume.resolution == 16
    assert tiny_spec.volume.params["albedo"] == (0.8, 0.8, 0.8)
    assert "octaves" in tiny_spec.volume.params  # family defaults are filled in
    assert isinstance(tiny_spec.lights[0], ConstantLight) and isinstance(tiny_spec.lights[1], DirectionalLight)
    assert tiny_spec.environment == tiny_spec.lights[0]
    assert tiny_spec.cameras.width == 8 and tiny_spec.render.spp_test == 8
    with pytest.raises(AttributeError):
        tiny_spec.name = "x"  # frozen
    with pytest.raises(TypeError):
        tiny_spec.volume.params["albedo"] = (1, 1, 1)  # read-only mapping


def test_defaults_and_int_as_float(tiny_dict):
    del tiny_dict["description"], tiny_dict["volume"]["seed"], tiny_dict["render"]["max_depth"]
    del tiny_dict["render"]["noise_floor"], tiny_dict["cameras"]["seed"]
    tiny_dict["volume"]["sigma_t_scale"] = 30
    spec = parse_scene(tiny_dict, "t")
    assert spec.description == "" and spec.volume.seed == 0 and spec.render.max_depth == -1
    assert spec.render.noise_floor is True and spec.volume.sigma_t_scale == 30.0
    assert isinstance(spec.volume.sigma_t_scale, float)


def test_round_trip(tiny_spec):
    d = tiny_spec.to_dict()
    again = parse_scene(d, "copy")
    assert again == tiny_spec
    assert again.to_dict() == d
    sky = parse_scene(_set(copy.deepcopy(TINY), "lights.0", {"type": "sky", "zenith": [0.1, 0.2, 0.9],
                                                           "horizon": [1, 1, 1], "ground": [0.2, 0.2, 0.2]}), "s")
    assert isinstance(sky.lights[0], SkyLight) and sky.lights[0].sun_direction is None
    assert parse_scene(sky.to_dict(), "s2") == sky


def test_overrides(tiny_spec):
    small = tiny_spec.with_overrides({"cameras.width": 16, "render.spp_test": 2, "lights.0.radiance": [1, 1, 1],
                                      "volume.params.octaves": 2})
    assert small.cameras.width == 16 and small.render.spp_test == 2
    assert small.lights[0].radiance == (1.0, 1.0, 1.0) and small.volume.params["octaves"] == 2
    assert tiny_spec.cameras.width == 8  # the original is untouched
    with pytest.raises(SpecError) as e:
        tiny_spec.with_overrides({"cameras.width": 0})
    assert e.value.field == "cameras.width" and "with overrides" in e.value.where
    with pytest.raises(SpecError) as e:
        tiny_spec.with_overrides({"cameras.nope": 1})
    assert e.value.field == "cameras.nope"
    with pytest.raises(SpecError) as e:
        tiny_spec.with_overrides({"lights.7.radiance": [1, 1, 1]})
    assert e.value.field == "lights.7.radiance"


def test_hash_stable_and_sensitive(tiny_spec, tiny_dict):
    h = tiny_spec.content_hash()
    assert len(h) == 64 and h == tiny_spec.content_hash()
    assert parse_scene(tiny_spec.to_dict(), "other source").content_hash() == h
    reordered = {k: tiny_dict[k] for k in reversed(list(tiny_dict))}
    reordered["volume"]["sigma_t_scale"] = 30  # int for float: same spec
    assert parse_scene(reordered, "r").content_hash() == h
    assert tiny_spec.with_overrides({"description": "reworded"}).content_hash() == h
    for key, value in [("render.seed", 1), ("cameras.width", 9), ("volume.sigma_t_scale", 31.0),
                       ("volume.params.octaves", 2), ("lights.1.irradiance", [4, 3.8, 3.6]), ("name", "tiny2")]:
        assert tiny_spec.with_overrides({key: value}).content_hash() != h, key
    assert hash(parse_scene(tiny_spec.to_dict(), "x")) == hash(tiny_spec)  # usable as a dict key
    assert tiny_spec.content_hash({"mitsuba": "3.9.1"}) != h
    assert tiny_spec.content_hash({"mitsuba": "3.9.1"}) != tiny_spec.content_hash({"mitsuba": "3.9.2"})


def test_library_loads_and_names_resolve():
    names = list_scenes()
    assert {"cloud", "cloud_thick", "plume", "blobs", "shell", "lattice", "nebula"} <= set(names)
    families = set()
    for name in names:
        spec = load_scene(name)
        assert spec.name == name
        families.add(spec.volume.family)
        assert load_scene(scenes_dir() / f"{name}.toml") == spec
    assert families >= {"cloud", "plume", "blobs", "shell", "lattice", "nebula"}
    cloud = load_scene("cloud")
    assert (cloud.cameras.width, cloud.cameras.n_train, cloud.cameras.n_test) == (64, 40, 8)
    assert (cloud.render.spp_train, cloud.render.spp_test, cloud.volume.resolution) == (768, 2048, 64)


def test_unknown_name_lists_known():
    with pytest.raises(SpecError, match=r"unknown scene 'no_such_scene' \(known: .*cloud"):
        load_scene("no_such_scene")


def test_scenes_dir_env_override(tmp_path, monkeypatch):
    (tmp_path / "mine.toml").write_text((scenes_dir() / "cloud.toml").read_text().replace('"cloud"\ndesc', '"mine"\ndesc'))
    monkeypatch.setenv("MITSNERF_SCENES", str(tmp_path))
    assert list_scenes() == sorted({p.stem for p in scenes_dir().glob("*.toml")} | {"mine"})  # added to the library
    assert load_scene("mine").volume.family == "cloud"


def test_missing_file_and_toml_syntax(tmp_path):
    with pytest.raises(SpecError, match="no such spec file") as e:
        load_scene(tmp_path / "absent.toml")
    assert e.value.where == str(tmp_path / "absent.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[volume]\nfamily = \n')
    with pytest.raises(SpecError, match=r"TOML syntax error: .*line 3") as e:
        load_scene(bad)
    assert e.value.where == str(bad)


MALFORMED = [
    ("unknown family", "volume.family", "smoke", "volume.family", "unknown volume family"),
    ("unknown field", "volume.resolutoin", 64, "volume.resolutoin", "did you mean 'resolution'"),
    ("unknown top-level field", "colour", 1, "colour", "unknown field"),
    ("missing field", "cameras.fov", DELETE, "cameras.fov", "missing field"),
    ("missing table", "render", DELETE, "render", "missing field"),
    ("wrong type", "cameras.width", "64", "cameras.width", "must be an integer"),
    ("bool for int", "render.spp_test", True, "render.spp_test", "must be an integer"),
    ("table expected", "volume", 3, "volume", "must be a table"),
    ("negative sigma_t_scale", "volume.sigma_t_scale", -1.0, "volume.sigma_t_scale", "in (0, 10000]"),
    ("zero sigma_t_scale", "volume.sigma_t_scale", 0, "volume.sigma_t_scale", "in (0, 10000]"),
    ("huge sigma_t_scale", "volume.sigma_t_scale", 1e300, "volume.sigma_t_scale", "opaque surface"),
    ("resolution 0", "volume.resolution", 0, "volume.resolution", "in [8, 512]"),
    ("resolution too big", "volume.resolution", 1024, "volume.resolution", "in [8, 512]"),
    ("bad rig", "cameras.rig", "spiral", "cameras.rig", "one of 'sphere'"),
    ("n_train 0", "cameras.n_train", 0, "cameras.n_train", "in [1, 10000]"),
    ("n_test 0", "cameras.n_test", 0, "cameras.n_test", "in [1, 10000]"),
    ("fov 0", "cameras.fov", 0.0, "cameras.fov", "in (0, 180)"),
    ("fov 180", "cameras.fov", 180, "cameras.fov", "in (0, 180)"),
    ("camera inside the box", "cameras.radius", 0.5, "cameras.radius", "> 0.8660 (outside the scene box"),
    ("max_depth 0", "render.max_depth", 0, "render.max_depth", "-1 (unlimited) or >= 1"),
    ("noise_floor not bool", "render.noise_floor", "yes", "render.noise_floor", "true or false"),
    ("bad name", "name", "a/b", "name", "must be letters"),
    ("unknown light type", "lights.0.type", "spot", "lights.0.type", "unknown light type 'spot'"),
    ("light without type", "lights.0.type", DELETE, "lights.0.type", "missing field"),
    ("unknown light field", "lights.0.colour", [1, 1, 1], "lights.0.colour", "unknown field"),
    ("bad vector length", "lights.1.direction", [1.0, 2.0], "lights.1.direction", "got 2 values"),
    ("vector of strings", "lights.0.radiance", ["a", "b", "c"], "lights.0.radiance", "3 numbers"),
    ("negative radiance", "lights.0.radiance", [1, -1, 1], "lights.0.radiance", ">= 0"),
    ("zero direction", "lights.1.direction", [0, 0, 0], "lights.1.direction", "not all zero"),
    ("no lights", "lights", [], "lights", "one or more"),
    ("two environments", "lights.1", {"type": "constant", "radiance": [1, 1, 1]}, "lights.1.type", "at most one environment"),
    ("bad family parameter", "volume.params.octaves", 0, "volume.params.octaves", ">= 1"),
    ("unknown family parameter", "volume.params.fluffiness", 1.0, "volume.params.fluffiness", "unknown parameter"),
]


@pytest.mark.parametrize("case,path,value,field,message", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_spec_names_the_field(tiny_dict, case, path, value, field, message):
    _set(tiny_dict, path, value)
    with pytest.raises(SpecError) as e:
        parse_scene(tiny_dict, "scenes/bad.toml")
    assert e.value.where == "scenes/bad.toml"
    assert e.value.field == field
    assert message in e.value.message
    assert str(e.value).startswith(f"scenes/bad.toml: {field}: ")


def test_malformed_file_reports_the_file(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text((scenes_dir() / "cloud.toml").read_text().replace("resolution = 64", "resolution = 0"))
    with pytest.raises(SpecError) as e:
        load_scene(path)
    assert (e.value.where, e.value.field) == (str(path), "volume.resolution")


# Datasets on disk are keyed by these: a change to SceneSpec.to_dict() or to a default must not move them
# (computed with the spec reader before the config mechanism was unified, commit 04756f5).
SHIPPED_HASHES = {
    "blobs": "d8b5f2dce212d206da87a41984589eb668d90d714f5b7ba7e355253c41bf08c2",
    "cloud": "3414ceef2c609b037c853351b56eb9923ff9977c50ac98fcd9dbf195a3392320",  # spp_train 768 (was 64)
    "cloud_thick": "6604073a66e2b4cab6ffe2cd7717180767f69aa6aad0a68d1a7d402eacac5865",
    "lattice": "b48e19b0df38a335720c68d55ce691b03deeb7c560a6dabdddb303e29bcc21de",
    "nebula": "284852ca52707c7a2b65e0edb8f64ed4928a42febe68247b9648e7ee63bb77d1",
    "plume": "fe761b1d90d80230f45dfade73336fe351a07da7de551495248d0696a9331d80",
    "shell": "a165950a91f8eeae7c658274c1d2cf987230960e3e32143437b75626c09ecf76",
    "smoke": "739b6c2dc5453cf41adc53170ac0a4b388ceb01af2a7614ccb1305462b00bf51",  # spp_train 768 (was 64)
}


@pytest.mark.parametrize("name", sorted(SHIPPED_HASHES))
def test_shipped_scene_content_hashes_are_pinned(name):
    spec = load_scene(name)
    assert spec.content_hash() == SHIPPED_HASHES[name]
    assert parse_scene(spec.to_dict(), "again").content_hash() == SHIPPED_HASHES[name]


@pytest.mark.parametrize("name, old_hash", [
    ("cloud", "29f8e19170f27107730e1a8e70b4ecd95900857801130baa04f93f74c46249d4"),
    ("smoke", "b0acdeed298ed8d10e23a4a1449ab387fb89da36a34a9f31f035e09f87efa9e4"),
])
def test_a_scene_at_its_old_training_spp_keeps_its_old_hash(name, old_hash):
    """The cloud's and the smoke's hashes moved only because their specs did (render.spp_train 64 -> 768), not
    their serialisation: the datasets generated before keep their names."""
    old = load_scene(name).with_overrides({"render.spp_train": 64})
    assert old.content_hash() == old_hash


MORE_MALFORMED = [  # (path, value, field, exact message)
    ("render.spp_test", 2**21, "render.spp_test", "must be an integer in [1, 1048576], got 2097152"),
    ("render.seed", -1, "render.seed", "must be an integer in [0, 4294967295], got -1"),
    ("cameras.radius", float("inf"), "cameras.radius", "must be a number in (0, 10000], got inf"),
    ("volume.sigma_t_scale", float("nan"), "volume.sigma_t_scale", "must be a number in (0, 10000], got nan"),
    ("volume.params", [1], "volume.params", "must be a table, got a list"),
    ("volume.params.albedo", [1, 1], "volume.params.albedo", "must be 3 numbers in [0, 1], got 2 values"),
    ("volume.params.radius", 0.4, "volume.params.displacement",
     "radius + displacement * 0.866 must be <= 0.45, got 0.4 + 0.15 * 0.866"),
    ("volume.params.octavs", 2, "volume.params.octavs", "unknown parameter of volume family 'cloud' (did you mean 'octaves'?)"),
    ("lights.1", {"type": "point", "position": [1, 1, 1]}, "lights.1.intensity", "missing field (3 numbers >= 0)"),
    ("lights.0", {"type": "sky", "zenith": [1, 1, 1], "horizon": [1, 1, 1], "ground": [1, 1, 1], "resolution": 4},
     "lights.0.resolution", "must be an integer in [8, 4096], got 4"),
    ("lights.0", {"type": "sky", "zenith": [1, 1, 1], "horizon": [1, 1, 1], "ground": [1, 1, 1], "sun_direction": [0, 0, 0]},
     "lights.0.sun_direction", "must be 3 numbers, not all zero, got [0.0, 0.0, 0.0]"),
    ("cameras", {}, "cameras.rig", "missing field (one of 'sphere', 'hemisphere', 'ring')"),
    ("name", 3, "name", "must be a string, got 3"),
]


@pytest.mark.parametrize("path,value,field,message", MORE_MALFORMED, ids=[m[2] for m in MORE_MALFORMED])
def test_malformed_spec_exact_messages(tiny_dict, path, value, field, message):
    _set(tiny_dict, path, value)
    with pytest.raises(SpecError) as e:
        parse_scene(tiny_dict, "scenes/bad.toml")
    assert str(e.value) == f"scenes/bad.toml: {field}: {message}"


def test_override_errors_name_the_overridden_spec(tiny_spec):
    with pytest.raises(SpecError) as e:
        tiny_spec.with_overrides({"cameras.width.x": 1})
    assert (e.value.where, e.value.field) == ("tiny.toml (with overrides)", "cameras.width.x")
    assert e.value.message == "cannot override inside 'cameras.width': not a table"


def test_undecodable_spec_and_directory_are_one_line_naming_the_file(tmp_path, monkeypatch, capsys):
    from mitsnerf.cli import main

    binary = tmp_path / "binary.toml"
    binary.write_bytes(b'name = "x"\n\xff\xfe\x00')
    assert main(["generate", str(binary), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == f"mitsnerf: error: {binary}: not a text file (invalid UTF-8 at byte 11)\n"
    with pytest.raises(SpecError, match=r": is a directory, not a spec file$") as e:
        load_scene(tmp_path)
    assert e.value.where == str(tmp_path)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "somedir").mkdir()
    with pytest.raises(SpecError, match=r"^somedir: is a directory, not a scene name or spec file$"):
        load_scene("somedir")


def test_scenes_and_generate_all_name_a_broken_spec(tmp_path, monkeypatch, capsys):
    from mitsnerf.cli import main

    (tmp_path / "cloud.toml").write_text((scenes_dir() / "cloud.toml").read_text())
    (tmp_path / "broken.toml").write_bytes(b"\x80\x81")
    monkeypatch.setenv("MITSNERF_SCENES", str(tmp_path))
    assert main(["scenes"]) == 2
    out, err = capsys.readouterr()
    assert ("\n" + out).count("\ncloud ") == 1 and err == f"mitsnerf: error: {tmp_path / 'broken.toml'}: not a text file (invalid UTF-8 at byte 0)\n"
    assert main(["generate", "--all", "--out", str(tmp_path / "data")]) == 2  # checked before anything renders
    assert str(tmp_path / "broken.toml") in capsys.readouterr().err
    assert not (tmp_path / "data").exists()


# --------------------------------------------------------------------------- extends: a spec that starts from another


def _write(path, text: str):
    path.write_text(text)
    return path


def test_extends_changes_only_what_the_spec_names(tmp_path):
    """Tables merge key by key; a list (``[[lights]]``) replaces the base's whole."""
    from dataclasses import replace

    cloud = load_scene("cloud")
    mine = load_scene(_write(tmp_path / "mine.toml", 'extends = "cloud"\nname = "mine"\n[cameras]\nwidth = 16\n'
                                                     '[volume.params]\nalbedo = [0.5, 0.5, 0.5]\n'
                                                     '[[lights]]\ntype = "constant"\nradiance = [1, 1, 1]\n'))
    assert mine.name == "mine" and mine.description == cloud.description
    assert mine.cameras == replace(cloud.cameras, width=16)
    assert mine.lights == (ConstantLight(radiance=(1.0, 1.0, 1.0)),)
    assert mine.render == cloud.render and mine.world == cloud.world
    assert dict(mine.volume.params) == {**cloud.volume.params, "albedo": (0.5, 0.5, 0.5)}
    written_out = cloud.to_dict()
    written_out.update(name="mine", lights=[{"type": "constant", "radiance": [1, 1, 1]}])
    written_out["cameras"]["width"] = 16
    written_out["volume"]["params"]["albedo"] = [0.5, 0.5, 0.5]
    assert mine.content_hash() == parse_scene(written_out).content_hash()  # as if written out in full


def test_extends_starts_a_table_afresh_when_its_kind_changes(tmp_path):
    """A changed ``type`` (the phase, a light) or ``volume.family`` does not inherit the old kind's keys."""
    iso = load_scene(_write(tmp_path / "iso.toml", 'extends = "cloud_hg85"\nname = "iso"\n'
                                                   '[volume.phase]\ntype = "isotropic"\n'))
    assert iso.volume.phase == load_scene("cloud").volume.phase
    np.save(tmp_path / "g.npy", np.ones((8, 8, 8), np.float32))
    grid = load_scene(_write(tmp_path / "grid.toml", 'extends = "cloud"\nname = "g"\n[volume]\nfamily = "grid"\n'
                                                     'params = { path = "g.npy" }\n'))
    assert grid.volume.family == "grid" and grid.volume.params["path"] == str(tmp_path / "g.npy")
    assert grid.volume.sigma_t_scale == load_scene("cloud").volume.sigma_t_scale  # the rest of the table merges


def test_extends_a_spec_file_relative_to_the_extending_one(tmp_path):
    (tmp_path / "base").mkdir()
    _write(tmp_path / "base" / "wide.toml", 'extends = "cloud"\nname = "wide"\n[cameras]\nfov = 60.0\n')
    spec = load_scene(_write(tmp_path / "mine.toml", 'extends = "base/wide.toml"\nname = "mine"\n'
                                                     '[cameras]\nwidth = 16\n'))
    assert (spec.name, spec.cameras.fov, spec.cameras.width) == ("mine", 60.0, 16)
    assert spec.source == str(tmp_path / "mine.toml")


@pytest.mark.parametrize(("text", "field", "says"), [
    ('extends = "nope"\n', "extends", "unknown scene 'nope'"),
    ("extends = 3\n", "extends", "must be a library scene's name or a spec file's path, got 3"),
    ('extends = "a.toml"\n', "extends", "a cycle: "),
    ('extends = "cloud"\n[[lights]]\ntype = "constant"\n', "lights.0.radiance",
     "missing field (3 numbers >= 0); this spec extends 'cloud': a table merges into the base's key by key, "
     "a list or a value replaces the base's whole"),
], ids=["unknown", "not-a-string", "cycle", "list-replaced"])
def test_extends_errors_name_the_field_and_say_how_specs_merge(tmp_path, text, field, says):
    a = _write(tmp_path / "a.toml", text)
    with pytest.raises(SpecError) as e:
        load_scene(a)
    assert (e.value.where, e.value.field) == (str(a), field) and says in e.value.message
    assert "\n" not in str(e.value)


def test_a_spec_missing_a_table_is_told_it_can_extend_a_library_scene(tmp_path):
    with pytest.raises(SpecError) as e:
        load_scene(_write(tmp_path / "bare.toml", 'name = "bare"\n[cameras]\nwidth = 8\n'))
    assert e.value.field == "volume" and 'extends = "cloud"' in e.value.message


def test_an_extends_cycle_through_two_files_names_the_one_that_closes_it(tmp_path):
    a = _write(tmp_path / "a.toml", 'extends = "b.toml"\n')
    b = _write(tmp_path / "b.toml", 'extends = "a.toml"\n')
    with pytest.raises(SpecError) as e:
        load_scene(a)
    assert (e.value.where, e.value.field) == (str(b), "extends")
    assert e.value.message == f"a cycle: {a} -> {b} -> {a}"
