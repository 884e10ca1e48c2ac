"""The false-discovery step of the candidate scoring against the hand-written step-up rule."""

from __future__ import annotations

import numpy as np
import pytest

from drill_env.discrepancy.scoring import CandidateScore, DecisionRule, _significance, benjamini_hochberg
from drill_env.recordings.effects import CANDIDATES


def _step_up(p: np.ndarray, alpha: float) -> np.ndarray:
    """Benjamini-Hochberg as first written: reject the i smallest, i the largest rank with
    p_(i) <= alpha i / m."""
    m = max(p.size, 1)
    order = np.argsort(p, kind="stable")
    last = 0
    for i, j in enumerate(order, start=1):
        if p[j] <= alpha * i / m:
            last = i
    out = np.zeros(p.size, dtype=bool)
    out[order[:last]] = True
    return out


def _bh_adjusted(p: np.ndarray) -> np.ndarray:
    """BH-adjusted p-values from their definition: min over j >= i of m p_(j) / j, capped at 1."""
    m = p.size
    order = np.argsort(p)
    ranked = p[order] * m / np.arange(1, m + 1)
    adj = np.minimum(np.minimum.accumulate(ranked[::-1])[::-1], 1.0)
    out = np.empty(m)
    out[order] = adj
    return out


@pytest.mark.parametrize("seed", range(20))
def test_benjamini_hochberg_matches_the_step_up_rule(seed):
    rng = np.random.default_rng(seed)
    from scipy import stats

    for _ in range(50):
        m = int(rng.integers(1, 15))
        # a mixture of null p-values and strong effects, on the scale of the rule's alpha
        p = np.where(rng.random(m) < 0.4, rng.random(m) * 1e-3, rng.random(m))
        alpha = float(rng.choice([1e-3, 1e-2, 0.05, 0.2]))
        np.testing.assert_array_equal(benjamini_hochberg(p, alpha), _step_up(p, alpha))
        np.testing.assert_allclose(stats.false_discovery_control(p, method="bh"), _bh_adjusted(p), rtol=1e-12)
    assert benjamini_hochberg([], 1e-3).size == 0


def _score(name, p, gain=100.0, admissible=True):
    return CandidateScore(
        name=name,
        gain=gain,
        raw_gain=gain,
        threshold=float("nan"),
        significant=False,
        admissible=admissible,
        note="",
        parameters={},
        heldout_ss=0.0,
        p_value=p,
    )


@pytest.mark.parametrize("seed", range(10))
def test_significance_decisions_match_the_step_up_rule(seed):
    """Which candidates are significant: the step-up rule over the admissible ones, the BIC
    penalty and admissibility, exactly as the hand-written rule decided."""
    rng = np.random.default_rng(100 + seed)
    rule = DecisionRule()
    n_h = int(rng.integers(50, 5000))
    names = [c.name for c in CANDIDATES]
    k_of = {c.name: c.n_params for c in CANDIDATES}
    p = np.where(rng.random(len(names)) < 0.5, rng.random(len(names)) * 3e-3, rng.random(len(names)))
    adm = rng.random(len(names)) < 0.8
    gains = rng.uniform(0.0, 40.0, len(names))
    scores = [
        _score(n, float(pi), float(g), bool(a)) for n, pi, g, a in zip(names, p, gains, adm, strict=True)
    ]
    _significance(scores, CANDIDATES, n_h, rule)
    pool = np.flatnonzero(adm)
    passed = np.zeros(len(names), dtype=bool)
    passed[pool] = _step_up(p[pool], rule.alpha)
    bic = np.array([k_of[n] for n in names]) * np.log(n_h)
    expected = passed & (gains > bic) & adm
    assert [s.significant for s in scores] == list(expected)


def test_a_candidate_whose_gain_is_not_a_number_is_never_rejected():
    """A singular candidate fit gives a NaN gain and p-value: no evidence (p = 1), where scipy's
    step-up rule would raise and stop the whole discrepancy test."""
    p = np.array([1e-9, np.nan, 0.5, 1e-6])
    np.testing.assert_array_equal(benjamini_hochberg(p, 0.01), [True, False, False, True])
