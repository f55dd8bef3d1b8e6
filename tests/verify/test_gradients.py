"""Case 5: Dr.Jit derivatives of a rendered loss against central finite differences."""

import pytest

from mitsnerf.verify import cases as C
from mitsnerf.verify.gradients import check_gradients
from mitsnerf.verify.mutations import MUTATIONS

QUALITY = C.QUALITIES["quick"]
CASES = {g.name: g for g in C.GRADIENT_CASES}


@pytest.mark.parametrize("name", list(CASES))
def test_reverse_and_forward_mode_match_finite_differences(name):
    r = check_gradients(CASES[name], QUALITY)
    assert r.passed, r.failures
    # Forward mode and reverse mode agree with each other far more tightly than with FD.
    assert r.forward_ad == pytest.approx(r.forward_from_reverse, rel=1e-4)


@pytest.mark.parametrize("name,mutation", [(g.name, m) for g in C.GRADIENT_CASES for m in g.detects])
def test_gradient_mutations_are_detected(name, mutation):
    r = check_gradients(CASES[name], QUALITY, MUTATIONS[mutation])
    assert not r.passed
