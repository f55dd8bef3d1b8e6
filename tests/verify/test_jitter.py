"""The training sampler's jitter, tested as ``mitsnerf check`` tests it."""

import pytest

from mitsnerf.verify import cases as C
from mitsnerf.verify.jitter import check_jitter
from mitsnerf.verify.mutations import MUTATIONS, planted


@pytest.mark.parametrize("quality", list(C.QUALITIES))
def test_training_jitter_is_uniform_and_independent_and_the_intervals_exact(quality):
    r = check_jitter(C.JITTER, C.QUALITIES[quality])
    assert r.passed, (r.failures, r.rejected)
    assert r.max_interval_error < C.JITTER.rtol / 5
    assert r.n_tests == C.QUALITIES[quality].n_samples + 3


@pytest.mark.parametrize("mutation", C.JITTER.detects)
def test_broken_jitter_or_intervals_are_detected(mutation):
    with planted(MUTATIONS[mutation]):
        r = check_jitter(C.JITTER, C.QUALITIES["quick"])
    assert not r.passed


def test_ignored_jitter_fails_the_uniformity_and_frozen_jitter_the_independence_across_steps():
    with planted(MUTATIONS["jitter_ignored"]):
        assert "KS uniform" in check_jitter(C.JITTER, C.QUALITIES["quick"]).rejected
    with planted(MUTATIONS["jitter_frozen"]):
        assert check_jitter(C.JITTER, C.QUALITIES["quick"]).rejected == ("steps independent",)
