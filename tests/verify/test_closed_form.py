"""Case 1: the quadrature against closed forms, and the mutations that must break it."""

import pytest

from mitsnerf.verify import cases as C
from mitsnerf.verify.closed_form import convergence, run_closed_form
from mitsnerf.verify.mutations import MUTATIONS


def test_the_quadrature_meets_every_closed_form():
    r = run_closed_form(C.CLOSED_FORM)
    assert r.passed, r.failures
    assert r.max_rel_error < C.CLOSED_FORM.rtol / 5  # the tolerance is float32 round-off, not slack


def test_first_order_error_is_half_the_exit_density_times_h():
    # (tau_hat - tau) / h -> -sigma_t(t_f) / 2 for a linear density (midpoint rule exact inside).
    conv = convergence(ns=(16, 32, 64, 128))
    assert conv["coef_linear"] == pytest.approx(1.0, abs=0.02)
    assert conv["order_exit0"] == pytest.approx(2.0, abs=C.CLOSED_FORM.order_tol)


@pytest.mark.parametrize("mutation", C.CLOSED_FORM.detects)
def test_mutations_are_detected(mutation):
    r = run_closed_form(C.CLOSED_FORM, MUTATIONS[mutation])
    assert not r.passed


def test_a_mutation_that_only_breaks_gradients_passes_the_value_checks():
    # detach_T changes no value: the closed forms (values) cannot and should not see it.
    assert run_closed_form(C.CLOSED_FORM, MUTATIONS["detach_T"]).passed
