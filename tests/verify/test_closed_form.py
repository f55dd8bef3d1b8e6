"""The quadrature rules against closed forms, and the planted bugs that must break them."""

import pytest

from mitsnerf.verify import cases as C
from mitsnerf.verify.closed_form import EXPECTED_ORDERS, convergence, run_closed_form
from mitsnerf.verify.mutations import MUTATIONS, planted


def test_the_quadrature_meets_every_closed_form(each_variant):
    r = run_closed_form(C.CLOSED_FORM)
    assert r.passed, r.failures
    assert r.max_rel_error < C.CLOSED_FORM.rtol / 5  # the tolerance is float32 round-off, not slack
    assert set(r.orders) == set(EXPECTED_ORDERS)


def test_first_order_error_is_half_the_exit_density_times_h_and_the_midpoint_rule_is_second_order():
    # (tau_hat - tau) / h -> -sigma_t(t_f) / 2 for a linear density (midpoint rule exact inside).
    conv = convergence(ns=(16, 32, 64, 128))
    assert conv["coef_linear"] == pytest.approx(1.0, abs=0.02)
    assert conv["order_exit0"] == pytest.approx(2.0, abs=C.CLOSED_FORM.order_tol)
    assert conv["order_midpoint"] == pytest.approx(2.0, abs=0.05)  # dense at the exit, still second order


@pytest.mark.parametrize("mutation", C.CLOSED_FORM.detects)
def test_mutations_are_detected(mutation, each_variant):
    with planted(MUTATIONS[mutation]):
        r = run_closed_form(C.CLOSED_FORM)
    assert not r.passed


def test_a_mutation_that_only_breaks_gradients_passes_the_value_checks():
    # T_detached changes no value: the closed forms (values) cannot and should not see it.
    with planted(MUTATIONS["T_detached"]):
        assert run_closed_form(C.CLOSED_FORM).passed
