"""mitsnerf.volumes: every family's contract (determinism, shapes, ranges, margins) and what it stresses."""

from __future__ import annotations

import dataclasses
import importlib
import inspect

import numpy as np
import pytest

import mitsnerf  # noqa: F401  (sets up LLVM before drjit loads anywhere)
from mitsnerf.volumes import VolumeGrids, families, generate_volume, make_params

R = 32
NAMES = sorted(name for name, family in families().items() if not family.files)  # the procedural families
SEED_UNUSED = {"shell"}  # fully determined by its parameters; its docstring says so
# mean density at R = 32 over seeds (measured 0.031-0.050, 0.002-0.005, 0.0089, 0.034, 0.071, 0.032-0.040)
MASS = {
    "cloud": (0.015, 0.1),
    "plume": (0.001, 0.02),
    "blobs": (0.004, 0.02),
    "shell": (0.02, 0.05),
    "lattice": (0.04, 0.1),
    "nebula": (0.015, 0.08),
}
CENTRES = (np.arange(R) + 0.5) / R - 0.5


@pytest.fixture(scope="module")
def grids() -> dict[tuple[str, int], VolumeGrids]:
    """Default grids at R = 32 for seeds 0 and 1, generated once."""
    return {(name, seed): generate_volume(name, R, seed) for name in NAMES for seed in (0, 1)}


def components(mask: np.ndarray) -> int:
    """Number of 6-connected components of a boolean 3-D mask (label propagation)."""
    labels = np.where(mask, np.arange(1, mask.size + 1).reshape(mask.shape), 0)
    while True:
        grown = labels.copy()
        for axis in range(3):
            for shift in (1, -1):
                grown = np.maximum(grown, np.roll(labels, shift, axis=axis))  # no wrap: edges are empty
        grown = np.where(mask, grown, 0)
        if np.array_equal(grown, labels):
            return len(np.unique(labels[mask]))
        labels = grown


def test_registry_lists_the_six_families_read_only():
    assert set(NAMES) >= {"cloud", "plume", "blobs", "shell", "lattice", "nebula"}
    with pytest.raises(TypeError):
        families()["fog"] = families()["cloud"]  # type: ignore[index]


@pytest.mark.parametrize("name", NAMES)
def test_family_record_and_params_are_complete(name):
    fam = families()[name]
    assert fam.name == name and fam.description
    params = fam.params_type()  # every field has a default
    assert dataclasses.is_dataclass(params)
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(params, dataclasses.fields(params)[0].name, 1)
    module = importlib.import_module(fam.generate.__module__)
    source = inspect.getsource(module)
    assert source.isascii()
    assert ("seed is unused" in module.__doc__) == (name in SEED_UNUSED)


@pytest.mark.parametrize("name", NAMES)
def test_deterministic_in_params_resolution_and_seed(name, grids):
    a, again = grids[(name, 0)], generate_volume(name, R, 0)
    np.testing.assert_array_equal(a.density, again.density)
    np.testing.assert_array_equal(a.albedo, again.albedo)
    b = grids[(name, 1)]
    same = np.array_equal(a.density, b.density) and np.array_equal(a.albedo, b.albedo)
    assert same == (name in SEED_UNUSED)


@pytest.mark.parametrize("name", NAMES)
def test_shapes_dtypes_and_ranges(name, grids):
    g = grids[(name, 0)]
    assert g.density.shape == (R, R, R) and g.albedo.shape == (R, R, R, 3)
    assert g.density.dtype == np.float32 and g.albedo.dtype == np.float32
    assert g.density.flags.c_contiguous and g.albedo.flags.c_contiguous
    for arr in (g.density, g.albedo):
        assert np.isfinite(arr).all() and arr.min() >= 0.0 and arr.max() <= 1.0
    assert g.density.max() > 0.5


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("seed", [0, 1])
def test_mass_and_margin(name, seed, grids):
    d = grids[(name, seed)].density
    lo, hi = MASS[name]
    assert lo < d.mean() < hi
    outer = max(abs(d[[0, -1]]).max(), d[:, [0, -1]].max(), d[:, :, [0, -1]].max())
    assert outer <= 0.01
    # bounding box of the visible medium stays inside [-0.45, 0.45]^3 (voxel centres)
    for axis_index in np.nonzero(d > 0.05):
        assert np.abs(CENTRES[axis_index]).max() <= 0.45


@pytest.mark.parametrize("name", NAMES)
def test_looks_the_same_at_another_resolution(name, grids):
    coarse, fine = grids[(name, 0)].density, generate_volume(name, 2 * R, 0).density
    assert fine.mean() == pytest.approx(coarse.mean(), rel=0.25)
    # box-filtering the fine grid down to R lands near the coarse grid
    pooled = fine.reshape(R, 2, R, 2, R, 2).mean(axis=(1, 3, 5))
    assert np.abs(pooled - coarse).mean() < 0.5 * coarse.mean()


def test_cloud_has_density_contrast_not_a_uniform_ball(grids):
    d = grids[("cloud", 0)].density
    z, y, x = np.meshgrid(CENTRES, CENTRES, CENTRES, indexing="ij")
    core = d[np.sqrt(x**2 + y**2 + z**2) < 0.2]
    assert core.std() > 0.2  # clumps and holes inside
    assert (core > 0.9).mean() > 0.05 and (core < 0.3).mean() > 0.1
    np.testing.assert_array_equal(np.unique(grids[("cloud", 0)].albedo), np.float32([0.8]))


def test_plume_rises_along_z_and_is_high_frequency(grids):
    d = grids[("plume", 0)].density
    gz, gy, gx = (np.abs(np.diff(d, axis=a)).mean() for a in range(3))
    assert gx > 1.8 * gz and gy > 1.8 * gz  # stretched along the world's up axis z
    cloud = grids[("cloud", 0)].density
    sharpness = lambda g: np.abs(np.diff(g, axis=2)).mean() / g.mean()  # noqa: E731
    assert sharpness(d) > 2 * sharpness(cloud)


@pytest.mark.parametrize("seed", [0, 1])
def test_blobs_are_separate_lobes_in_empty_space(seed, grids):
    d = grids[("blobs", seed)].density
    n_blobs = families()["blobs"].params_type().n_blobs
    assert components(d > 0) == n_blobs
    assert (d == 0).mean() > 0.8
    three = generate_volume("blobs", R, seed, {"n_blobs": 3, "sigma": 0.04})
    assert components(three.density > 0) == 3


def test_shell_is_hollow_and_sharp(grids):
    d = grids[("shell", 0)].density
    assert d[R // 2 - 2 : R // 2 + 2, R // 2 - 2 : R // 2 + 2, R // 2 - 2 : R // 2 + 2].max() == 0.0
    # along the +x axis from the centre: zero, then the wall in at most 2 voxels, then zero
    ray = d[R // 2, R // 2, R // 2 :]
    assert np.count_nonzero(ray) <= 2 and ray.max() > 0.5
    # the wall's optical depth (thickness 0.03 at density 1) is kept even though it is under a voxel
    assert ray.sum() / R == pytest.approx(0.03, rel=0.25)
    torus = generate_volume("shell", R, 0, {"shape": "torus"}).density
    i_ring = np.argmin(np.abs(CENTRES - 0.3))  # the ring at x = 0.3, y = z ~ 0 passes through the tube
    assert torus[R // 2, R // 2, R // 2] == 0.0 and torus[R // 2, R // 2, i_ring] == 0.0  # hollow tube
    assert torus.max() > 0.5 and not np.array_equal(torus, d)


def test_lattice_values_are_exactly_zero_or_one(grids):
    for seed in (0, 1):
        assert set(np.unique(grids[("lattice", seed)].density).tolist()) == {0.0, 1.0}
    full = generate_volume("lattice", R, 0, {"fill_fraction": 1.0, "cube_fraction": 1.0, "half_extent": 0.25})
    inside = np.abs(CENTRES) < 0.25
    expected = inside[:, None, None] & inside[None, :, None] & inside[None, None, :]
    np.testing.assert_array_equal(full.density, expected.astype(np.float32))


def test_nebula_albedo_varies_in_colour(grids):
    g = grids[("nebula", 0)]
    seen = g.albedo[g.density > 0.05]
    assert seen.std(axis=0).min() > 0.05  # every channel varies where the medium is
    hue = seen / seen.sum(axis=1, keepdims=True)
    assert np.ptp(hue[:, 2]) > 0.2  # a change of colour, not only of brightness
    palette = np.asarray(families()["nebula"].params_type().palette)
    assert (seen >= palette.min(axis=0) - 1e-6).all() and (seen <= palette.max(axis=0) + 1e-6).all()


# ---------------------------------------------------------------- make_params / generate_volume


def test_make_params_builds_from_toml_like_values():
    p = make_params("cloud", {"octaves": 3, "radius": 0.3, "albedo": [1, 0.5, 0.25]})
    assert p.octaves == 3 and p.albedo == (1.0, 0.5, 0.25) and isinstance(p.albedo[0], float)
    assert make_params("cloud", {}) == families()["cloud"].params_type()
    n = make_params("nebula", {"palette": [[0, 0, 0], [1, 1, 1]]})
    assert n.palette == ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    contrast = make_params("cloud", {"contrast": 3}).contrast  # TOML ints are fine for floats
    assert contrast == 3.0 and isinstance(contrast, float)


def test_make_params_unknown_family_names_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown volume family 'fog' \(known: blobs, cloud"):
        make_params("fog", {})
    with pytest.raises(ValueError, match="unknown volume family"):
        generate_volume("fog", R, 0)


@pytest.mark.parametrize(
    "family, values, field",
    [
        ("cloud", {"octave": 3}, "octave"),  # unknown key
        ("cloud", {"octaves": "3"}, "octaves"),  # wrong type
        ("cloud", {"octaves": 3.0}, "octaves"),
        ("cloud", {"albedo": "white"}, "albedo"),
        ("cloud", {"albedo": [0.5, 0.5]}, "albedo"),
        ("shell", {"shape": "cube"}, "shape"),
        ("shell", {"radius": True}, "radius"),
        ("cloud", {"octaves": 0}, "octaves"),  # out of range
        ("cloud", {"radius": 0.6}, "radius"),
        ("cloud", {"albedo": [0.5, 0.5, 1.5]}, "albedo"),
        ("cloud", {"radius": 0.4, "displacement": 0.2}, "displacement"),  # would touch the box
        ("cloud", {"octaves": 12}, "octaves"),  # beyond the noise lattice's period
        ("blobs", {"n_blobs": 16}, "n_blobs"),  # do not fit
        ("lattice", {"fill_fraction": 0}, "fill_fraction"),
        ("nebula", {"palette": [[1, 0, 0]]}, "palette"),
        ("nebula", {"palette": [[1, 0, 0], [0, 2, 0]]}, "palette.1"),  # list items by index, as in overrides
        ("plume", {"radius_top": 0.42}, "turbulence"),
        ("shell", {"shape": "torus", "tube_radius": 0.3}, "tube_radius"),
    ],
)
def test_make_params_errors_start_with_the_field(family, values, field):
    with pytest.raises(ValueError) as e:
        make_params(family, values)
    assert str(e.value).startswith(field + ": ")


def test_make_params_message_example():
    with pytest.raises(ValueError, match=r"^octaves: must be an integer >= 1, got 0$"):
        make_params("cloud", {"octaves": 0})


@pytest.mark.parametrize("resolution", [7, 513, 32.0, True])
def test_generate_volume_rejects_bad_resolution(resolution):
    with pytest.raises(ValueError, match="^resolution: "):
        generate_volume("cloud", resolution, 0)


def test_generate_volume_accepts_none_mapping_or_params_instance():
    params = make_params("blobs", {"n_blobs": 2})
    a = generate_volume("blobs", 8, 3, params)
    b = generate_volume("blobs", 8, 3, {"n_blobs": 2})
    np.testing.assert_array_equal(a.density, b.density)
    assert generate_volume("blobs", 8, 3).density.shape == (8, 8, 8)
    with pytest.raises(ValueError, match="^seed: "):
        generate_volume("blobs", 8, -1)
    with pytest.raises(ValueError, match="^params: "):
        generate_volume("blobs", 8, 0, make_params("cloud", {}))


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_128_cubed_is_quick(name):
    import time

    start = time.perf_counter()
    generate_volume(name, 128, 0)
    assert time.perf_counter() - start < 3.0


# sha256 of density and albedo bytes at R = 20 for each shipped scene's family, seed and parameters,
# computed before the parameters moved to config metadata (commit 04756f5): the grids are bit-identical.
SHIPPED_GRIDS = {
    "blobs": "050399ecf555b33632834ef45e986a814c53d5758b6b4ace61a0cdcb17d252f6",
    "cloud": "649ae5c3569a57d26db1bc1d8bb59ad7dd7a40a7b66fe8790010781a7d1ed77c",
    "cloud_thick": "cac379fb602399efc87e51dec5f4c062effa027db611f3ab80c4a60adc154fca",
    "lattice": "a50f9f4c362a7cef4526b15f980848580847f4c0e3fda859c0314996e575c520",
    "nebula": "0c69fad6f37d2cb9154a6ac898e4c25f3204e77785dbf1623ec2bf00e9a81414",
    "plume": "cebb7ee66ca554723a5599c39918206de5fa0f08d4bbbd3d32995060e7d235c4",
    "shell": "b62f0e92fb7e45f83a1a8f9c9c121b0de2ac5afb8d9e3a6d2139bb4c2aa42332",
}


@pytest.mark.parametrize("scene", sorted(SHIPPED_GRIDS))
def test_shipped_scene_grids_are_bit_identical(scene):
    import hashlib

    from mitsnerf.scene.spec import load_scene

    v = load_scene(scene).volume
    g = generate_volume(v.family, 20, v.seed, dict(v.params))
    assert hashlib.sha256(g.density.tobytes() + g.albedo.tobytes()).hexdigest() == SHIPPED_GRIDS[scene]

