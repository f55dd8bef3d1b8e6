"""The integrator against Mitsuba's volpath on the same rays, and the planted bugs it must catch.

The volpath references are rendered once per module and variant (quick quality: 12x12 pixels,
4096-16384 spp); every test that compares with them runs on each variant the machine can run
(``each_variant``: both, where a GPU is there).
"""

import dataclasses

import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.verify import cases as C
from mitsnerf.verify import mitsuba_refs as M
from mitsnerf.verify.mutations import MUTATIONS, planted
from mitsnerf.verify.runner import Artifacts, _family_result
from mitsnerf.verify.scenarios import (_render, evaluate_scenario, evaluate_training_path, mitsuba_furnace,
                                       prepare_scenario, seed_bias_factor)
from mitsnerf.verify.stats import compare

QUALITY = C.QUALITIES["quick"]
SCENARIOS = {s.name: s for s in C.SCENARIOS}


@pytest.fixture(scope="module")
def prepared_by_variant() -> dict:
    return {}


@pytest.fixture
def prepared(each_variant, prepared_by_variant):
    """The scenarios with their volpath references, rendered on ``each_variant`` (once per module)."""
    if each_variant not in prepared_by_variant:
        prepared_by_variant[each_variant] = {name: prepare_scenario(s, QUALITY) for name, s in SCENARIOS.items()}
    return prepared_by_variant[each_variant]


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_integrator_agrees_with_volpath(prepared, name):
    outcome = evaluate_scenario(prepared[name])
    assert outcome.family.passed, outcome.family.summary()


@pytest.mark.parametrize("name,mutation", [(s.name, m) for s in C.SCENARIOS for m in s.detects])
def test_mutation_is_detected(prepared, name, mutation):
    with planted(MUTATIONS[mutation]):
        outcome = evaluate_scenario(prepared[name])
    assert not outcome.family.passed, f"{mutation} went unnoticed: {outcome.family.summary()}"


def test_each_rule_is_one_comparison_of_one_family(prepared):
    family = evaluate_scenario(prepared["box_absorption"]).family
    assert [t.label.split()[0] for t in family.tests] == ["seed", "midpoint"]
    assert family.n_tests == 2 * (QUALITY.width**2 * 3 + 3)


def test_the_seed_rule_fails_against_raw_volpath_where_the_medium_is_dense_at_the_exit(prepared):
    # The cases are not kind to the quadrature: without the closed-form correction (box) or the
    # midpoint rule (exit-heavy), the seed's first-order exit bias is detected.
    for name in ("box_absorption", "exit_absorption"):
        p = prepared[name]
        ref = p.reference
        seed = _render(p, "seed")
        assert not compare(seed, ref.mean, ref.var, ref.n, QUALITY.alpha).passed, name
    p = prepared["box_absorption"]
    k = seed_bias_factor(p)
    assert float(k.max()) > 1.01  # the correction is not negligible: exp(sigma_t L / 2N) with sigma_t L up to ~2.5


def test_training_path_agrees_with_volpath(prepared):
    outcome = evaluate_training_path(C.TRAINING_PATH, prepared[C.TRAINING_PATH.scenario])
    assert outcome.family.passed, outcome.family.summary()
    assert "N = 512" in outcome.note


def test_failing_case_writes_the_images_and_names_the_directory(prepared, tmp_path):
    with planted(MUTATIONS["no_background"]):
        outcome = evaluate_scenario(prepared["box_absorption"])
    result = _family_result("box_absorption", "integrator", outcome, Artifacts(tmp_path))
    case_dir = tmp_path / "box_absorption"
    assert not result.passed and str(case_dir) in result.detail and result.evidence.startswith("mean z")
    assert sorted(p.name for p in case_dir.iterdir()) == sorted(
        [f"{k}_{q}.exr" for k in ("ours", "error", "z") for q in ("seed", "midpoint")] + ["reference.exr"])


def test_volpath_max_depth_2_is_single_scattering_and_3_is_not(prepared):
    # The single-scattering integrator matches max_depth = 2 (test above); against max_depth = 3
    # (second-order scattering added) the same comparison must fail: it sees multiple scattering.
    p = prepared["single_scatter"]
    s = dataclasses.replace(p.scenario, max_depth=3, spp_factor=1.0)
    ref3 = prepare_scenario(s, QUALITY).reference
    ours = _render(p, "seed")
    cmp = compare(ours, ref3.mean, ref3.var, ref3.n, QUALITY.alpha, s.max_rel_error)
    assert not cmp.passed and cmp.z_mean < 0  # max_depth 3 is brighter
    assert ref3.mean.sum() > p.reference.mean.sum()


def test_mitsuba_furnace_is_one_and_sees_the_energy_volpath_loses_at_finite_depth(each_variant):
    assert mitsuba_furnace(C.MITSUBA_FURNACE, QUALITY).family.passed
    outcome = mitsuba_furnace(dataclasses.replace(C.MITSUBA_FURNACE, max_depth=6), QUALITY)
    assert not outcome.family.passed and outcome.family.z_mean > 0  # 1 is brighter than volpath


def test_grids_are_laid_out_as_mitsuba_reads_them(each_variant):
    # A medium that is dense only in the +x half: Mitsuba's gridvolume (to_world translate(-0.5)
    # over the cube scale(0.5)) must see it there too. One ray each side, 256 spp, albedo 0.
    r = 8
    sigma = np.zeros((r, r, r), np.float32)
    sigma[:, :, r // 2:] = 20.0  # [z, y, x]: x fastest
    scene = mi.load_dict(M.scene_dict(sigma, 0.0, {"env": M.constant_environment((1, 1, 1))}))
    o = np.array([[0.3, -2.0, 0.0], [-0.3, -2.0, 0.0]])
    d = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    ref = M.sample_rays(scene, o, d, 256)
    assert ref.mean[0, 0] < 0.01 and ref.mean[1, 0] == pytest.approx(1.0, abs=1e-6)
