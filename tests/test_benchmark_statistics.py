"""Paired bootstrap statistics of the benchmark against known answers: synthetic rows with a
known difference, scipy.stats.bootstrap as an independent oracle, and the coverage of the
intervals over many synthetic draws."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from drill_env.agents.evaluation.benchmark.statistics import paired_bootstrap


def _rows(scores: dict[str, np.ndarray]) -> pd.DataFrame:
    """Long rows (controller, voltage, seed, score) of per-unit scores."""
    out = []
    for name, s in scores.items():
        for i, v in enumerate(s):
            out.append(
                {"controller": name, "voltage": 0.5 + (i // 5) * 0.25, "seed": i % 5, "score": float(v)}
            )
    return pd.DataFrame(out)


def test_known_difference_is_resolved_and_its_interval_holds_it():
    rng = np.random.default_rng(1)
    unit = rng.normal(0.0, 1.0, 200)  # unit effects far larger than the difference
    a = 0.9 + 0.2 * unit + rng.normal(0, 0.01, 200)
    b = a - 0.02 + rng.normal(0, 0.01, 200)  # b is a minus 0.02 on every unit, plus noise
    st = paired_bootstrap(_rows({"a": a, "b": b}), n_resamples=4000, seed=3)
    (pair,) = st.pairs.to_dict("records")
    assert (pair["a"], pair["b"]) == ("a", "b")
    assert pair["low"] < 0.02 < pair["high"]
    assert pair["low"] > 0 and pair["resolved"] and pair["resolved_holm"]
    # the unpaired intervals overlap widely: only the pairing resolves the difference
    sc = st.scores.set_index("controller")
    assert sc.loc["a", "low"] < sc.loc["b", "high"]
    assert list(st.scores["rank"]) == [1, 2]
    assert list(st.scores["best_rank"]) == [1, 2] and list(st.scores["worst_rank"]) == [1, 2]


def test_equal_controllers_are_not_resolved_and_share_ranks():
    rng = np.random.default_rng(2)
    base = rng.normal(0.5, 0.3, 60)
    rows = _rows({"a": base + rng.normal(0, 0.05, 60), "b": base + rng.normal(0, 0.05, 60), "c": base - 1.0})
    st = paired_bootstrap(rows, n_resamples=2000, seed=0, method="percentile")
    sc = st.scores.set_index("controller")
    assert sc.loc["c", "rank"] == 3 and sc.loc["c", "best_rank"] == 3
    top = {sc.loc["a", "rank"], sc.loc["b", "rank"]}
    assert top == {1, 2}
    for name in ("a", "b"):
        assert (sc.loc[name, "best_rank"], sc.loc[name, "worst_rank"]) == (1, 2)
    ab = st.pairs[(st.pairs["a"].isin(["a", "b"])) & (st.pairs["b"].isin(["a", "b"]))].iloc[0]
    assert not ab["resolved"]
    assert "b" in sc.loc["a", "not_resolved_from"] and "c" not in sc.loc["a", "not_resolved_from"]


@pytest.mark.parametrize("method", ["percentile", "BCa"])
def test_intervals_agree_with_scipy_bootstrap(method):
    """Same statistic, same design: scipy's paired bootstrap of the mean difference and of
    each mean gives the same interval up to the Monte Carlo error."""
    rng = np.random.default_rng(7)
    a = rng.gamma(2.0, 0.2, 80)  # skewed, where BCa and percentile differ
    b = a * 0.8 + rng.normal(0, 0.05, 80)
    st = paired_bootstrap(_rows({"a": a, "b": b}), n_resamples=20000, seed=1, method=method)
    ref = sps.bootstrap(
        (a, b),
        lambda x, y, axis: np.mean(x, axis=axis) - np.mean(y, axis=axis),
        paired=True,
        n_resamples=20000,
        method=method,
        random_state=np.random.default_rng(5),
        vectorized=True,
    ).confidence_interval
    pair = st.pairs.iloc[0]
    width = ref.high - ref.low
    assert abs(pair["low"] - ref.low) < 0.03 * width and abs(pair["high"] - ref.high) < 0.03 * width
    ref_a = sps.bootstrap(
        (a,), np.mean, n_resamples=20000, method=method, random_state=np.random.default_rng(6)
    )
    sa = st.scores.set_index("controller").loc["a"]
    w = ref_a.confidence_interval.high - ref_a.confidence_interval.low
    assert abs(sa["low"] - ref_a.confidence_interval.low) < 0.03 * w
    assert abs(sa["high"] - ref_a.confidence_interval.high) < 0.03 * w


@pytest.mark.parametrize(
    "method,draws", [("BCa", 200), pytest.param("percentile", 600, marks=pytest.mark.slow)]
)
def test_coverage_of_the_paired_interval(method, draws):
    """Over many synthetic benchmarks with a known true difference of 0.01 (skewed noise, as
    suppression scores near 1 are), the 90 % interval holds it in about 90 % of them."""
    rng = np.random.default_rng(11)
    n, hits = 100, 0
    for i in range(draws):
        unit = rng.normal(0, 1, n)
        a = 0.99 - 0.05 * rng.exponential(1.0, n) + 0.1 * unit
        # b: a minus 0.01 in expectation, with skewed paired noise of mean 0
        b = a - 0.01 - 0.02 * (rng.exponential(1.0, n) - 1.0)
        st = paired_bootstrap(
            _rows({"a": a, "b": b}), n_resamples=1000, seed=i, confidence=0.9, method=method
        )
        pair = st.pairs.iloc[0]
        d_lo, d_hi = (pair["low"], pair["high"]) if pair["a"] == "a" else (-pair["high"], -pair["low"])
        hits += d_lo <= 0.01 <= d_hi
    # binomial(200, 0.9): sd 2.1 %; the bootstrap runs slightly narrow (0.88 over 600 draws);
    # unpaired intervals would hold it almost always, the naive ones of the means far less
    assert 0.83 <= hits / draws <= 0.95


def test_units_missing_a_controller_are_counted_and_undefined_ones_skipped():
    rows = _rows({"a": np.linspace(0, 1, 10), "b": np.linspace(0, 1, 10) - 0.1})
    rows.loc[(rows["controller"] == "b") & (rows["seed"] == 0) & (rows["voltage"] == 0.5), "score"] = np.nan
    rows.loc[rows["seed"] == 4, "score"] = np.nan  # no score for anyone: not a unit of it
    st = paired_bootstrap(rows, n_resamples=500)
    assert st.incomplete_units == 1 and st.undefined_units == 2 and st.n_units == 10 - 1 - 2


def test_suite_rows_take_every_other_column_as_unit():
    rng = np.random.default_rng(3)
    rows = [
        {"controller": c, "scenario": sc, "preset": "brake", "seed": s, "score": float(rng.normal(m, 0.01))}
        for c, m in (("x", 0.8), ("y", 0.7))
        for sc in ("start_up", "set_points")
        for s in range(6)
    ]
    st = paired_bootstrap(pd.DataFrame(rows), n_resamples=500)
    assert st.units == ("scenario", "preset", "seed") and st.n_units == 12
    assert st.pairs.iloc[0]["resolved"]


def test_bad_input_is_named():
    rows = _rows({"a": np.arange(5.0), "b": np.arange(5.0)})
    with pytest.raises(ValueError, match="method"):
        paired_bootstrap(rows, method="normal")
    with pytest.raises(ValueError, match="confidence"):
        paired_bootstrap(rows, confidence=1.5)
    with pytest.raises(ValueError, match="no column"):
        paired_bootstrap(rows, score="suppression")
    with pytest.raises(ValueError, match="two rows"):
        paired_bootstrap(pd.concat([rows, rows.iloc[:1]]))
