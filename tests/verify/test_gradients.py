"""Dr.Jit derivatives of a rendered loss against central finite differences."""

import pytest

from mitsnerf.verify import cases as C
from mitsnerf.verify.gradients import check_gradients
from mitsnerf.verify.mutations import MUTATIONS, planted

QUALITY = C.QUALITIES["quick"]
CASES = {g.name: g for g in C.GRADIENT_CASES}


@pytest.mark.parametrize("name", list(CASES))
def test_reverse_and_forward_mode_match_finite_differences(name, each_variant):
    r = check_gradients(CASES[name], QUALITY)
    assert r.passed, r.failures
    # Forward mode and reverse mode agree with each other far more tightly than with FD, and the
    # FD along v is well inside the 1e-3 that a 0.3% gradient error must exceed.
    assert r.forward_ad == pytest.approx(r.forward_from_reverse, rel=1e-5)
    assert r.direction_rel_error < CASES[name].rtol_direction / 3


@pytest.mark.parametrize("name,mutation", [(g.name, m) for g in C.GRADIENT_CASES for m in g.detects])
def test_gradient_mutations_are_detected(name, mutation, each_variant):
    with planted(MUTATIONS[mutation]):
        r = check_gradients(CASES[name], QUALITY)
    assert not r.passed


def test_a_gradient_off_by_0_3_percent_fails_every_case():
    for name, case in CASES.items():
        with planted(MUTATIONS["C_grad_x1.003"]):
            r = check_gradients(case, QUALITY)
        assert not r.passed and r.direction_rel_error == pytest.approx(0.003, abs=5e-4), name
