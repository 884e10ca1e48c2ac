"""Paired statistics of a benchmark: each controller's score with a bootstrap confidence
interval, every pair's difference with its paired interval, and a ranking that says which
differences are resolved.

Every controller of a benchmark runs on the same *units* (the same preset, plant,
operating point and seed; in a scenario suite also the same scenario): its episodes
start from the same state with the same sensor noise, so the difference between two
controllers on one unit carries none of the variation between units. The bootstrap here
keeps that pairing: it resamples the units with replacement, *jointly for all
controllers* (one resampled set of units per bootstrap replicate, every controller's
score and every difference computed on it), so that

* a controller's score is the mean of its scores over the units, with a percentile or
  BCa interval (Efron and Tibshirani, *An Introduction to the Bootstrap*, 1993, ch. 13-14);
* a pair's difference is the mean over the units of the paired differences, with its own
  interval from the same replicates; the pair is *resolved* when the interval excludes 0;
* ``resolved_holm`` adds Holm's step-down correction over all pairs (two-sided bootstrap
  p-values), for a reader who wants every claim of the table to hold at once;
* the ranking gives each controller its rank by score and the range of ranks the
  resolved differences allow (best: one plus the number of controllers resolved above it;
  worst: the number of controllers minus those resolved below it), and the controllers it
  is not resolved from.

The statistics take any table of rows (a pandas DataFrame) with a controller column, a
score column and the unit columns (by default every other column): the benchmark's
``benchmark.csv`` (units: preset, plant, voltage, seed) and a scenario suite's rows
(controller, scenario, preset, seed, score) alike. A unit where the score is undefined
for every controller (no open-loop cycle to suppress) is not a unit of this score; a unit
where it is missing for some controllers only (a failed run) cannot be paired and is left
out, counted in :attr:`PairedStatistics.incomplete_units` and named in the report.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "METHODS",
    "PairedStatistics",
    "paired_bootstrap",
    "paired_units",
    "ranking_lines",
]

METHODS = ("percentile", "BCa")
MAX_RESAMPLES = 1_000_000
_CHUNK = 2000  # replicates computed at once (memory: chunk x units x controllers floats)


@dataclass(frozen=True)
class PairedStatistics:
    """The result of :func:`paired_bootstrap`.

    ``scores``: one row per controller (score, low, high, rank, best_rank, worst_rank,
    not_resolved_from), best first; ``pairs``: one row per pair (a, b, difference a - b,
    low, high, resolved, p_value, resolved_holm), a the better of the two.
    """

    score: str
    units: tuple[str, ...]
    n_units: int
    confidence: float
    method: str
    n_resamples: int
    seed: int
    scores: Any  # pandas DataFrame
    pairs: Any  # pandas DataFrame
    incomplete_units: int = 0
    undefined_units: int = 0
    incomplete_examples: tuple[str, ...] = field(default=())

    def record(self) -> dict[str, Any]:
        """The settings (for a results folder's provenance)."""
        return {
            "score": self.score,
            "units": list(self.units),
            "n_units": self.n_units,
            "confidence": self.confidence,
            "method": self.method,
            "n_resamples": self.n_resamples,
            "seed": self.seed,
            "incomplete_units": self.incomplete_units,
            "undefined_units": self.undefined_units,
        }


def paired_units(
    rows: Any,
    *,
    score: str = "score",
    controller: str = "controller",
    units: Sequence[str] | None = None,
) -> tuple[Any, tuple[str, ...], int, int, list[str]]:
    """The matrix of scores, one row per unit and one column per controller (a DataFrame),
    from long-format ``rows``; also the unit columns, the number of units left out because
    some controllers lack a score there, the number where none has one, and a few of the
    former (as text)."""
    import pandas as pd

    df = pd.DataFrame(rows)
    for c in (controller, score):
        if c not in df.columns:
            raise ValueError(f"rows: no column {c!r}; columns: {list(df.columns)}")
    if units is None:
        units = tuple(c for c in df.columns if c not in (controller, score))
    units = tuple(units)
    missing = [c for c in units if c not in df.columns]
    if missing:
        raise ValueError(f"units: no column(s) {missing} in the rows; columns: {list(df.columns)}")
    if not units:
        raise ValueError("units: at least one column must say which unit (seed, operating point) a row is")
    dup = df.duplicated([*units, controller])
    if dup.any():
        first = df[dup].iloc[0]
        raise ValueError(
            f"rows: controller {first[controller]!r} has two rows for the unit "
            f"{dict((u, first[u]) for u in units)}; a unit is one run per controller"
        )
    values = pd.to_numeric(df[score], errors="raise").astype(float)
    wide = df.assign(**{score: values}).pivot(index=list(units), columns=controller, values=score)
    defined = wide.notna()
    undefined = ~defined.any(axis=1)
    incomplete = defined.any(axis=1) & ~defined.all(axis=1)
    examples = [
        f"{k if isinstance(k, tuple) else (k,)} (no {score} for {list(wide.columns[~defined.loc[k]])})"
        for k in list(wide.index[incomplete])[:3]
    ]
    return wide[defined.all(axis=1)], units, int(incomplete.sum()), int(undefined.sum()), examples


def paired_bootstrap(
    rows: Any,
    *,
    score: str = "score",
    controller: str = "controller",
    units: Sequence[str] | None = None,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    method: str = "BCa",
    seed: int = 0,
    higher_is_better: bool = True,
) -> PairedStatistics:
    """Each controller's mean score over the paired units with a bootstrap interval, every
    pair's paired difference with its interval, and the ranking (see the module docstring).

    Parameters
    ----------
    rows
        Long-format table (DataFrame or records): one row per controller and unit.
    score, controller
        The score's column and the controller's column.
    units
        The columns that name a unit (default: every column other than ``controller`` and
        ``score``).
    confidence
        Two-sided level of every interval, in (0, 1).
    n_resamples
        Bootstrap replicates (the units resampled jointly for all controllers), 100 to 10**6.
    method
        ``"percentile"`` or ``"BCa"`` (bias-corrected and accelerated; the acceleration
        from the jackknife over the units).
    seed
        Seed of the resampling: the same rows and seed give the same intervals.
    higher_is_better
        Whether a larger score ranks first.
    """
    import pandas as pd

    if method not in METHODS:
        raise ValueError(f"method: {method!r} is not one of {list(METHODS)}")
    if not (isinstance(confidence, float | int) and 0.0 < float(confidence) < 1.0):
        raise ValueError(f"confidence: {confidence!r}; allowed: a number in (0, 1)")
    if isinstance(n_resamples, bool) or not isinstance(n_resamples, int | np.integer):
        raise ValueError(f"n_resamples: {n_resamples!r}; allowed: an integer from 100 to {MAX_RESAMPLES:,}")
    if not 100 <= n_resamples <= MAX_RESAMPLES:
        raise ValueError(f"n_resamples: {n_resamples!r}; allowed: an integer from 100 to {MAX_RESAMPLES:,}")
    wide, unit_cols, n_incomplete, n_undefined, examples = paired_units(
        rows, score=score, controller=controller, units=units
    )
    names = [str(c) for c in wide.columns]
    x = wide.to_numpy(dtype=float)  # (units, controllers)
    n, k = x.shape
    if k < 1 or n < 2:
        raise ValueError(
            f"rows: {n} complete unit(s) of {k} controller(s) for {score!r}; the bootstrap needs at least 2 units"
        )
    sign = 1.0 if higher_is_better else -1.0
    ia, ib = np.triu_indices(k, 1)
    # statistics of one set of units: the k means, then the k(k-1)/2 differences
    means = x.mean(axis=0)
    theta = np.concatenate([means, means[ia] - means[ib]])
    reps = _replicates(x, ia, ib, n_resamples, seed)  # (B, k + pairs)
    alpha = 1.0 - float(confidence)
    if method == "percentile":
        lo_q = np.full(theta.shape, alpha / 2)
        hi_q = np.full(theta.shape, 1 - alpha / 2)
    else:
        lo_q, hi_q = _bca_levels(x, ia, ib, theta, reps, alpha)
    low = np.array([np.quantile(reps[:, j], lo_q[j]) for j in range(theta.size)])
    high = np.array([np.quantile(reps[:, j], hi_q[j]) for j in range(theta.size)])
    # an interval of a statistic that does not vary over the units is the point itself
    flat = np.ptp(np.concatenate([x, x[:, ia] - x[:, ib]], axis=1), axis=0) == 0
    low[flat], high[flat] = theta[flat], theta[flat]
    # two-sided bootstrap p-value of each difference (share of replicates across 0, doubled)
    d_reps = reps[:, k:]
    p = np.minimum(
        1.0,
        2
        * np.minimum(
            (np.sum(d_reps <= 0, axis=0) + 1) / (n_resamples + 1),
            (np.sum(d_reps >= 0, axis=0) + 1) / (n_resamples + 1),
        ),
    )
    p[flat[k:] & (theta[k:] == 0)] = 1.0
    p[flat[k:] & (theta[k:] != 0)] = 0.0
    holm = _holm(p, alpha)

    order = sorted(range(k), key=lambda i: (-sign * means[i], names[i]))
    pair_rows = []
    resolved_with: dict[tuple[int, int], bool] = {}
    for j, (a, b) in enumerate(zip(ia, ib, strict=True)):
        d, lo, hi = theta[k + j], low[k + j], high[k + j]
        if sign * d < 0:  # the better of the two first
            a, b, d, lo, hi = b, a, -d, -hi, -lo
        resolved = bool(lo > 0 or hi < 0)
        resolved_with[(a, b)] = resolved_with[(b, a)] = resolved
        pair_rows.append(
            {
                "a": names[a],
                "b": names[b],
                "difference": float(d),
                "low": float(lo),
                "high": float(hi),
                "resolved": resolved,
                "p_value": float(p[j]),
                "resolved_holm": bool(holm[j]),
            }
        )
    score_rows = []
    for rank, i in enumerate(order, start=1):
        others = [m for m in range(k) if m != i]
        above = sum(1 for m in others if sign * means[m] > sign * means[i] and resolved_with[(i, m)])
        below = sum(1 for m in others if sign * means[m] <= sign * means[i] and resolved_with[(i, m)])
        ties = [names[m] for m in order if m != i and not resolved_with[(i, m)]]
        score_rows.append(
            {
                "controller": names[i],
                "score": float(means[i]),
                "low": float(low[i]),
                "high": float(high[i]),
                "rank": rank,
                "best_rank": 1 + above,
                "worst_rank": k - below,
                "not_resolved_from": ties,
            }
        )
    pairs = pd.DataFrame(
        pair_rows, columns=["a", "b", "difference", "low", "high", "resolved", "p_value", "resolved_holm"]
    )
    rank_of = {r["controller"]: r["rank"] for r in score_rows}
    if len(pairs):
        pairs = pairs.assign(
            _r=[(rank_of[a], rank_of[b]) for a, b in zip(pairs["a"], pairs["b"], strict=True)]
        )
        pairs = pairs.sort_values("_r").drop(columns="_r").reset_index(drop=True)
    return PairedStatistics(
        score=score,
        units=unit_cols,
        n_units=n,
        confidence=float(confidence),
        method=method,
        n_resamples=int(n_resamples),
        seed=int(seed),
        scores=pd.DataFrame(score_rows),
        pairs=pairs,
        incomplete_units=n_incomplete,
        undefined_units=n_undefined,
        incomplete_examples=tuple(examples),
    )


def _replicates(x: np.ndarray, ia: np.ndarray, ib: np.ndarray, n_resamples: int, seed: int) -> np.ndarray:
    """Bootstrap replicates of the k means and the pair differences: the units (rows of
    ``x``) resampled with replacement, the same resample for every controller."""
    n, k = x.shape
    rng = np.random.default_rng(seed)
    out = np.empty((n_resamples, k + ia.size))
    for start in range(0, n_resamples, _CHUNK):
        m = min(_CHUNK, n_resamples - start)
        idx = rng.integers(0, n, size=(m, n))
        # counts of each unit in each resample: the means as one matrix product
        flat = (idx + n * np.arange(m)[:, None]).ravel()
        counts = np.bincount(flat, minlength=m * n).reshape(m, n).astype(float)
        means = counts @ x / n
        out[start : start + m, :k] = means
        out[start : start + m, k:] = means[:, ia] - means[:, ib]
    return out


def _bca_levels(
    x: np.ndarray, ia: np.ndarray, ib: np.ndarray, theta: np.ndarray, reps: np.ndarray, alpha: float
) -> tuple[np.ndarray, np.ndarray]:
    """The BCa quantile levels of every statistic: bias correction from the share of
    replicates below the estimate, acceleration from the jackknife over the units."""
    from scipy.special import ndtr, ndtri

    n, k = x.shape
    below = np.mean(reps < theta, axis=0) + 0.5 * np.mean(reps == theta, axis=0)
    z0 = ndtri(np.clip(below, 1.0 / (reps.shape[0] + 1), 1 - 1.0 / (reps.shape[0] + 1)))
    jack_means = (x.sum(axis=0) - x) / (n - 1)  # (n, k): each unit left out
    jack = np.concatenate([jack_means, jack_means[:, ia] - jack_means[:, ib]], axis=1)
    dev = jack.mean(axis=0) - jack
    num = np.sum(dev**3, axis=0)
    den = 6.0 * np.sum(dev**2, axis=0) ** 1.5
    a = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
    levels = []
    for z_alpha in (ndtri(alpha / 2), ndtri(1 - alpha / 2)):
        z = z0 + (z0 + z_alpha) / (1 - a * (z0 + z_alpha))
        levels.append(np.clip(ndtr(z), 0.0, 1.0))
    return levels[0], levels[1]


def _holm(p: np.ndarray, alpha: float) -> np.ndarray:
    """Holm's step-down rejections of the hypotheses with p-values ``p`` at family level ``alpha``."""
    m = p.size
    reject = np.zeros(m, dtype=bool)
    for step, j in enumerate(np.argsort(p, kind="stable")):
        if p[j] > alpha / (m - step):
            break
        reject[j] = True
    return reject


def _num(x: float, digits: int = 3) -> str:
    t = f"{x:.{digits}f}"
    return t[1:] if t.startswith("-") and float(t) == 0.0 else t


def ranking_lines(stats: PairedStatistics, *, title: str, digits: int = 4, level: int = 3) -> list[str]:
    """Markdown of the ranking: the scores with their intervals and ranks, then every pair's
    difference with its interval (the resolved ones marked)."""
    pct = f"{100 * stats.confidence:g} %"
    n_pairs = len(stats.pairs)
    lines = [
        f"{'#' * level} {title}",
        "",
        f"Mean {stats.score} over {stats.n_units} paired units ({', '.join(stats.units)}), every controller on "
        f"the same units; {pct} {stats.method} bootstrap intervals from {stats.n_resamples:,} resamples of "
        f"the units, drawn jointly for all controllers (seed {stats.seed}). *Ranks* is the range of ranks the "
        "resolved differences allow; *not resolved from*: the controllers whose difference to this one has "
        "an interval containing 0.",
        "",
    ]
    if stats.incomplete_units:
        lines += [
            f"**{stats.incomplete_units} unit(s) left out** (a score missing for some controllers only, e.g. "
            + "; ".join(stats.incomplete_examples)
            + ").",
            "",
        ]
    lines += [
        f"| rank | controller | {stats.score} | {pct} interval | ranks | not resolved from |",
        "|---|---|---|---|---|---|",
    ]
    for r in stats.scores.to_dict("records"):
        span = (
            str(r["best_rank"])
            if r["best_rank"] == r["worst_rank"]
            else f"{r['best_rank']}-{r['worst_rank']}"
        )
        ties = ", ".join(r["not_resolved_from"]) or "-"
        lines.append(
            f"| {r['rank']} | {r['controller']} | {_num(r['score'], digits)} | "
            f"[{_num(r['low'], digits)}, {_num(r['high'], digits)}] | {span} | {ties} |"
        )
    if n_pairs:
        n_res = int(stats.pairs["resolved"].sum())
        n_holm = int(stats.pairs["resolved_holm"].sum())
        lines += [
            "",
            f"Paired differences (a - b, a ranked above b): {n_res} of {n_pairs} pairs resolved (the {pct} "
            f"interval excludes 0; intervals per pair), {n_holm} with Holm's correction over all {n_pairs} "
            "pairs (p: two-sided bootstrap p-value).",
            "",
            "| a | b | a - b | interval | resolved | p | resolved (Holm) |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in stats.pairs.to_dict("records"):
            lines.append(
                f"| {r['a']} | {r['b']} | {_num(r['difference'], digits + 1)} | "
                f"[{_num(r['low'], digits + 1)}, {_num(r['high'], digits + 1)}] | "
                f"{'**yes**' if r['resolved'] else 'no'} | {_pval(r['p_value'])} | "
                f"{'yes' if r['resolved_holm'] else 'no'} |"
            )
    lines.append("")
    return lines


def _pval(p: float) -> str:
    if not math.isfinite(p):
        return "-"
    return f"{p:.2g}" if p >= 1e-3 else "<0.001"
