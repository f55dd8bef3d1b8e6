"""Cases 2-4: the integrator against Mitsuba's volpath on the same rays, and the mutations it must catch.

The four volpath references are rendered once per module (quick quality: 12x12 pixels,
1024-4096 spp, about 10 s on two cores).
"""

import dataclasses

import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.verify import cases as C
from mitsnerf.verify import mitsuba_refs as M
from mitsnerf.verify.mutations import MUTATIONS
from mitsnerf.verify.runner import Artifacts, evaluate_scenario, prepare_scenario
from mitsnerf.verify.sources import render_image
from mitsnerf.verify.stats import compare

QUALITY = C.QUALITIES["quick"]
SCENARIOS = {s.name: s for s in C.SCENARIOS}


@pytest.fixture(scope="module")
def prepared():
    return {name: prepare_scenario(s, QUALITY) for name, s in SCENARIOS.items()}


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_integrator_agrees_with_volpath(prepared, name):
    result = evaluate_scenario(prepared[name])
    assert result.passed, result.detail


@pytest.mark.parametrize("name,mutation", [(s.name, m) for s in C.SCENARIOS for m in s.detects])
def test_mutation_is_detected(prepared, name, mutation):
    result = evaluate_scenario(prepared[name], MUTATIONS[mutation])
    assert not result.passed, f"{mutation} went unnoticed: {result.detail}"


def test_every_mutation_of_the_values_is_detected_by_some_scenario():
    detected = {m for s in C.SCENARIOS for m in s.detects}
    assert {"off_by_one_T", "delta_wrong_end", "no_background"} <= detected


def test_failing_case_writes_the_images_and_names_the_directory(prepared, tmp_path):
    result = evaluate_scenario(prepared["absorption_constant"], MUTATIONS["no_background"], Artifacts(tmp_path))
    case_dir = tmp_path / "absorption_constant"
    assert str(case_dir) in result.detail
    assert sorted(p.name for p in case_dir.iterdir()) == ["error.exr", "ours.exr", "reference.exr", "z.exr"]


def test_volpath_max_depth_2_is_single_scattering_and_3_is_not(prepared):
    # The single-scattering integrator matches max_depth = 2 (test above); against max_depth = 3
    # (second-order scattering added) the same comparison must fail: it sees multiple scattering.
    p = prepared["single_scatter"]
    s = dataclasses.replace(p.scenario, max_depth=3, spp_factor=1.0)
    ref3 = prepare_scenario(s, QUALITY).reference
    ours = render_image(p.field, QUALITY.camera(), QUALITY.n_samples, p.background)
    cmp = compare(ours, ref3.mean, ref3.var, ref3.n, QUALITY.alpha, s.max_rel_error)
    assert not cmp.passed and cmp.z_mean < 0  # max_depth 3 is brighter
    assert ref3.mean.sum() > p.reference.mean.sum()


def test_white_furnace_sees_the_energy_volpath_loses_at_finite_depth(prepared):
    # The furnace comparison against 1 passes at unlimited depth (test above) and must fail when
    # volpath stops after a few bounces in the same medium.
    s = dataclasses.replace(SCENARIOS["white_furnace"], max_depth=6)
    ref = prepare_scenario(s, QUALITY).reference
    cmp = compare(np.ones_like(ref.mean), ref.mean, ref.var, ref.n, QUALITY.alpha, s.max_rel_error)
    assert not cmp.passed


def test_grids_are_laid_out_as_mitsuba_reads_them():
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
