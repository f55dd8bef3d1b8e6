"""Planted mutations: each still applies to today's source, reaches every caller, and is always restored."""

import dataclasses

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.math import composite as composite_module
from mitsnerf.math.box import UNIT_BOX
from mitsnerf.math.composite import weights
from mitsnerf.render.volume import render_rays
from mitsnerf.verify import cases as C
from mitsnerf.verify.mutations import MUTATION_LIST, MUTATIONS, MutationError, mutated_code, planted, target


@pytest.mark.parametrize("name", list(MUTATIONS))
def test_every_mutation_applies_to_the_current_source_and_changes_the_code(name):
    # A refactor that removes or duplicates a snippet must fail here, not turn the mutation into a no-op.
    m = MUTATIONS[name]
    code = mutated_code(m)
    assert code.co_code != target(m).__code__.co_code or code.co_consts != target(m).__code__.co_consts


@pytest.mark.parametrize("name", list(MUTATIONS))
def test_planting_swaps_the_code_and_restores_it(name):
    m = MUTATIONS[name]
    func = target(m)
    original = func.__code__
    with planted(m):
        assert func.__code__ is not original
    assert func.__code__ is original
    with pytest.raises(RuntimeError, match="inside"):
        with planted(m):
            raise RuntimeError("inside")
    assert func.__code__ is original


def test_a_snippet_that_is_missing_or_ambiguous_is_a_clear_error():
    m = MUTATIONS["T_off_by_one"]
    with pytest.raises(MutationError, match="occurs 0 times"):
        mutated_code(dataclasses.replace(m, snippet="no such code"))
    with pytest.raises(MutationError, match=r"occurs ([2-9]|\d\d+) times"):
        mutated_code(dataclasses.replace(m, snippet="tau"))  # in more than one place
    assert target(m).__code__ is weights.__code__  # nothing was planted


def test_a_planted_bug_reaches_callers_that_imported_the_function_by_name():
    # render_rays imported composite by name; the plant changes what it renders, then nothing is left.
    slab = lambda x, d: (mi.Array3f(0.5, 0.2, 0.1) + 0 * x.x, 2.0 + 0.0 * x.x)  # noqa: E731
    o, d = mi.Array3f(0, 0, -2), mi.Array3f(0, 0, 1)

    def render():
        with dr.suspend_grad():
            return np.array([np.asarray(c)[0] for c in render_rays(slab, o, d, 8, box=UNIT_BOX, background=1.0).rgb])

    clean = render()
    with planted(MUTATIONS["no_background"]):
        broken = render()
    assert not np.allclose(broken, clean)
    np.testing.assert_array_equal(render(), clean)
    assert composite_module.composite.__code__ is target(MUTATIONS["no_background"]).__code__


def test_gradient_mutations_keep_the_values():
    slab = lambda x, d: (mi.Array3f(0.5, 0.2, 0.1) + 0 * x.x, 2.0 + 0.0 * x.x)  # noqa: E731
    o, d = mi.Array3f(0, 0, -2), mi.Array3f(0, 0, 1)
    with dr.suspend_grad():
        clean = np.array([np.asarray(c)[0] for c in render_rays(slab, o, d, 8, box=UNIT_BOX, background=1.0).rgb])
        for m in MUTATION_LIST:
            if m.kind == "gradient":
                with planted(m):
                    out = np.array([np.asarray(c)[0] for c in render_rays(slab, o, d, 8, box=UNIT_BOX, background=1.0).rgb])
                np.testing.assert_allclose(out, clean, rtol=1e-6, err_msg=m.name)


def test_every_mutation_is_claimed_by_some_case():
    claimed = set(C.CLOSED_FORM.detects) | set(C.JITTER.detects) | set(C.TRAINING_PATH.detects)
    for group in (C.SCENARIOS, C.GRADIENT_CASES, C.DRT_CASES, C.PLUGIN_CASES):
        for case in group:
            claimed |= set(case.detects)
    assert claimed == set(MUTATIONS), (set(MUTATIONS) - claimed, claimed - set(MUTATIONS))
