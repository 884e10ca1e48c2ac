"""Decide which effect, if any, explains the equation error: fit, hold out, test, bootstrap.

All statistics are in noise units: every window's residual and candidate columns are
divided by that window's noise standard deviation, so that the nominal model with
the right noise floor gives a sum of squares ~ chi^2 with one degree of freedom per
window. The floor is the encoder's, spectral lines of the quantisation error included
(:mod:`drill_env.discrepancy.equation_error`): a window where a line of an undithered
encoder aliases into its pass band weighs little, one where none does weighs much. Per run the sufficient statistics (X'X, X'z, z'z) are kept, so refits on
other sets of runs, and the bootstrap over runs, cost nothing.

The rule (all numbers in :class:`DecisionRule`):

1. Fit each candidate on the training runs; its *held-out gain* is the drop of the
   held-out sum of squares ``D = Q0 - Q_c``, divided by ``max(1, Q_c/n)`` so that a
   residual left far above the noise floor cannot make a partial fit look significant.
2. A candidate is *significant* when its gain exceeds ``max(chi2_{k}(1 - alpha),
   k ln n)`` (a likelihood-ratio test at level alpha and the BIC penalty, k fitted
   parameters, n held-out windows) and its fitted parameters are physical.
3. The *excess* of the nominal model is its held-out sum of squares above what noise
   gives (n, with a tolerance for the noise-floor estimate). The best significant
   candidate (largest gain above its threshold) is named when it removes at least
   ``min_explained`` of a significant excess (or when there is no significant excess
   left to explain).
4. Otherwise the answer is ``unexplained`` if the residual has structure, and ``none``
   if it does not. Structure is what the quantisation error cannot make: a significant
   excess over the floor; a spectral line at one frequency common to the runs,
   significant without the run that contributes most to it and shown by at least
   ``line_run_fraction`` of them on their own (the lines of the quantisation error sit
   at each run's own count rate); a correlation of neighbouring windows that
   stays significant without the run that contributes most to it (at a constant count
   rate the lines can make the windows of one run depend on each other; a torque the
   model lacks acts in every run).
5. The confidence is the fraction of bootstrap replicates (training and held-out runs
   each resampled with replacement, within each kind of run: constant or varying
   voltage) that reach the same answer. A named effect that wins in fewer than
   ``min_confidence`` of the replicates is not named: the answer falls back to rule 4.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from drill_env.discrepancy.effects import CANDIDATES, Candidate
from drill_env.discrepancy.equation_error import RunEquations

__all__ = [
    "DecisionRule",
    "RunStatistics",
    "run_statistics",
    "CandidateScore",
    "Decision",
    "decide",
    "line_scan",
    "LineScan",
    "split_runs",
]


@dataclass(frozen=True)
class DecisionRule:
    alpha: float = 1e-3  # level of the likelihood-ratio test of a candidate
    floor_tolerance: float = 0.15  # relative error allowed on the noise floor
    excess_z: float = 4.0  # sigmas of chi^2 above which the excess is significant
    min_explained: float = 0.5  # fraction of the excess the named effect must remove
    min_confidence: float = 0.5  # a named effect must win in at least this share of the bootstrap
    line_alpha: float = 1e-4  # level of the spectral-line test (Bonferroni over frequencies)
    line_run_fraction: float = 0.5  # share of runs that must show the line on their own (p < 0.01)
    autocorr_z: float = 4.5  # z-score of the neighbour correlation that counts as structure
    bootstrap: int = 200
    ridge: float = 1e-9


@dataclass
class RunStatistics:
    """Sufficient statistics of one run for every candidate (noise units)."""

    name: str
    n: int  # windows (both disks)
    ztz: float  # nominal sum of squares
    linear: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # X'X, X'z
    lag: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # per tau: x'z, x'x
    neighbour: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sum z_i z_i+1, sum z_i^2, sum z_i+1^2
    n_pairs: int = 0


def _weighted(eq: RunEquations, xu: np.ndarray, xl: np.ndarray) -> np.ndarray:
    return np.vstack([xu / eq.upper.sigma[:, None], xl / eq.lower.sigma[:, None]])


def run_statistics(eq: RunEquations, candidates: tuple[Candidate, ...] = CANDIDATES) -> RunStatistics:
    z = np.concatenate([eq.upper.z, eq.lower.z])
    st = RunStatistics(name=eq.run.name, n=int(z.size), ztz=float(z @ z))
    for c in candidates:
        if c.is_lag:
            a = np.empty(c.tau_grid.size)
            b = np.empty(c.tau_grid.size)
            for i, tau in enumerate(c.tau_grid):
                x = _weighted(eq, *c.columns(eq, float(tau)))[:, 0]
                a[i] = x @ z
                b[i] = x @ x
            st.lag[c.name] = (a, b)
        else:
            X = _weighted(eq, *c.columns(eq))
            st.linear[c.name] = (X.T @ X, X.T @ z)
    # correlation of neighbouring windows (adjacent on the window grid)
    s_ab = s_aa = s_bb = 0.0
    pairs = 0
    for w in (eq.upper, eq.lower):
        if len(w) < 2:
            continue
        step = np.diff(w.centers)
        adj = step == _grid_step(eq)
        za, zb = w.z[:-1][adj], w.z[1:][adj]
        s_ab += float(za @ zb)
        s_aa += float(za @ za)
        s_bb += float(zb @ zb)
        pairs += int(adj.sum())
    st.neighbour = (s_ab, s_aa, s_bb)
    st.n_pairs = pairs
    return st


def _grid_step(eq: RunEquations) -> int:
    return 2 * (eq.L + eq.g_half) + 1


@dataclass
class CandidateScore:
    name: str
    gain: float  # held-out drop of the sum of squares, normalised (see module doc)
    raw_gain: float  # held-out drop of the sum of squares
    threshold: float
    significant: bool
    admissible: bool
    note: str
    parameters: dict[str, float]
    heldout_ss: float  # held-out sum of squares with the candidate

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _fit_linear(stats_list, name, ridge):
    A = sum(s.linear[name][0] for s in stats_list)
    b = sum(s.linear[name][1] for s in stats_list)
    k = A.shape[0]
    scale = max(float(np.trace(A)) / k, 1e-300)
    return np.linalg.solve(A + ridge * scale * np.eye(k), b)


def _gain_linear(stats_list, name, coef):
    A = sum(s.linear[name][0] for s in stats_list)
    b = sum(s.linear[name][1] for s in stats_list)
    return float(2.0 * coef @ b - coef @ A @ coef)


def _score(c: Candidate, train, held, rule: DecisionRule) -> CandidateScore:
    n_h = sum(s.n for s in held)
    q0_h = sum(s.ztz for s in held)
    if c.is_lag:
        gain_train = sum(2.0 * s.lag[c.name][0] - s.lag[c.name][1] for s in train)
        i = int(np.argmax(gain_train))
        tau = float(c.tau_grid[i])
        if 0 < i < c.tau_grid.size - 1:
            # parabola through the best grid point and its neighbours, in log tau
            y0, y1, y2 = gain_train[i - 1], gain_train[i], gain_train[i + 1]
            den = y0 - 2.0 * y1 + y2
            if den < 0.0:
                step = math.log(c.tau_grid[i + 1] / c.tau_grid[i])
                tau = float(c.tau_grid[i] * math.exp(0.5 * (y0 - y2) / den * step))
        raw = float(sum(2.0 * s.lag[c.name][0][i] - s.lag[c.name][1][i] for s in held))
        params = c.to_parameters(np.array([1.0]), tau)
        if gain_train[i] <= 0.0:
            raw = 0.0  # no lag improves the training fit: the candidate stays at zero
            params = c.to_parameters(np.array([1.0]), 0.0)
    else:
        coef = _fit_linear(train, c.name, rule.ridge)
        raw = _gain_linear(held, c.name, coef)
        params = c.to_parameters(coef)
    q_c = q0_h - raw
    gain = raw / max(1.0, q_c / max(n_h, 1))
    k = c.n_params
    thr = max(float(stats.chi2.isf(rule.alpha, k)), k * math.log(max(n_h, 2)))
    why = c.admissible(params)
    return CandidateScore(
        name=c.name,
        gain=float(gain),
        raw_gain=float(raw),
        threshold=float(thr),
        significant=bool(gain > thr and why is None),
        admissible=why is None,
        note=why or "",
        parameters={k_: float(v) for k_, v in params.items()},
        heldout_ss=float(q_c),
    )


@dataclass(frozen=True)
class LineScan:
    """Best common spectral line of the nominal residual (per-run amplitude and phase)."""

    frequency_hz: float
    reduction: float  # drop of the sum of squares (noise units), without the run contributing most
    threshold: float
    significant: bool
    dof: int
    rotation_ratio: list[float]  # line frequency / lower-disk rotation rate, per run
    related_to_rotation: bool
    amplitude_nm: dict[str, float]  # per run, fitted amplitude [N m] (lower disk)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def line_scan(eqs: list[RunEquations], rule: DecisionRule, n_freq: int = 240) -> LineScan:
    """Scan for a sinusoid at one frequency common to the runs in the nominal residual.

    Each run and disk gets its own amplitude and phase; the line is significant when the
    drop of the sum of squares, leaving out the run that contributes most to it, passes a
    Bonferroni-corrected chi^2 test and at least ``line_run_fraction`` of the runs show
    it on their own."""
    groups = []
    for eq in eqs:
        for w in (eq.upper, eq.lower):
            if len(w) >= 8:
                groups.append((eq, w))
    if not groups:
        return LineScan(float("nan"), 0.0, float("inf"), False, 0, [], False, {})
    stride_t = min(_grid_step(eq) * eq.dt for eq, _ in groups)
    t_max = max(eq.run.duration for eq, _ in groups)
    f_lo = 3.0 / t_max
    f_hi = 0.45 / stride_t
    freqs = np.geomspace(f_lo, f_hi, n_freq)
    red_g = np.zeros((len(groups), freqs.size))
    for g, (_, w) in enumerate(groups):
        z = w.z
        s = 1.0 / w.sigma
        for i, f in enumerate(freqs):
            ph = 2.0 * math.pi * f * w.t
            X = np.column_stack([np.cos(ph) * s, np.sin(ph) * s])
            A = X.T @ X
            b = X.T @ z
            try:
                red_g[g, i] = float(b @ np.linalg.solve(A, b))
            except np.linalg.LinAlgError:
                pass
    red = red_g.sum(axis=0)
    dof = 2 * len(groups)
    # A line of the quantisation error sits at one run's count rate, and on the grid of
    # windows it can alias anywhere; a torque the model lacks acts in every run. So the
    # line is scored without the run that contributes most to it at its frequency.
    run_of = [eq.run.name for eq, _ in groups]
    names = sorted(set(run_of))
    if len(names) > 1:
        member = np.array([[n == name for n in run_of] for name in names])  # runs x groups
        per_run = member.astype(float) @ red_g
        top = np.argmax(per_run, axis=0)
        robust = red - per_run[top, np.arange(freqs.size)]
        i = int(np.argmax(robust))
        dof_robust = dof - 2 * int(member[top[i]].sum())
    else:
        robust = red
        i = int(np.argmax(red))
        dof_robust = dof
    thr = float(stats.chi2.isf(rule.line_alpha / freqs.size, max(dof_robust, 1)))
    f = float(freqs[i])
    # a line common to the runs shows in most of them on its own, not in one or two
    # (an undithered encoder at constant speed can alias into a line of a single run)
    single = float(stats.chi2.isf(0.01, 2))
    shown = {}
    for g, (eq, _) in enumerate(groups):
        shown[eq.run.name] = shown.get(eq.run.name, False) or bool(red_g[g, i] > single)
    common = sum(shown.values()) >= rule.line_run_fraction * len(shown)
    ratios = []
    amps = {}
    for eq in eqs:
        mean_speed = float(np.mean(np.abs(eq.speed_l)))
        rot = mean_speed / (2.0 * math.pi)
        ratios.append(f / rot if rot > 1e-3 else float("inf"))
        w = eq.lower
        if len(w) >= 8:
            ph = 2.0 * math.pi * f * w.t
            X = np.column_stack([np.cos(ph), np.sin(ph)]) / w.sigma[:, None]
            coef, *_ = np.linalg.lstsq(X, w.z, rcond=None)
            amps[eq.run.name] = float(math.hypot(*coef))
    near = [min(abs(r - 1.0), abs(r - 2.0)) < 0.1 for r in ratios if math.isfinite(r)]
    related = bool(near) and sum(near) >= 0.5 * len(near)
    return LineScan(
        frequency_hz=f,
        reduction=float(robust[i]),
        threshold=thr,
        significant=bool(robust[i] > thr and common),
        dof=dof,
        rotation_ratio=ratios,
        related_to_rotation=related,
        amplitude_nm=amps,
    )


@dataclass
class Decision:
    effect: str
    confidence: float
    reason: str
    scores: list[CandidateScore]
    winner: CandidateScore | None
    excess: dict[str, float]
    structure: dict[str, Any]
    bootstrap_counts: dict[str, int]
    train_runs: list[str]
    heldout_runs: list[str]

    def score(self, name: str) -> CandidateScore:
        for s in self.scores:
            if s.name == name:
                return s
        raise KeyError(name)


def _verdict(train, held, rule: DecisionRule, line: LineScan | None, candidates):
    scores = [_score(c, train, held, rule) for c in candidates]
    n_h = sum(s.n for s in held)
    q0_h = sum(s.ztz for s in held)
    n_all = n_h + sum(s.n for s in train)
    q0_all = q0_h + sum(s.ztz for s in train)

    def excess_significant(q, n):
        return q > n * (1.0 + rule.floor_tolerance) + rule.excess_z * math.sqrt(2.0 * n)

    s_ab = sum(s.neighbour[0] for s in train + held)
    s_aa = sum(s.neighbour[1] for s in train + held)
    s_bb = sum(s.neighbour[2] for s in train + held)
    pairs = sum(s.n_pairs for s in train + held)
    rho = s_ab / math.sqrt(s_aa * s_bb) if s_aa > 0 and s_bb > 0 else 0.0
    rho_z = rho * math.sqrt(max(pairs, 1))
    # At a constant count rate the quantisation error of an encoder is a sum of spectral
    # lines that can make all windows of one run depend on each other; a torque the model
    # lacks acts in every run. So the correlation counts only if it stays significant
    # without whichever run contributes most to it.
    rho_z_robust = rho_z
    if len(train + held) > 1:
        for st in train + held:
            a, b, c = s_ab - st.neighbour[0], s_aa - st.neighbour[1], s_bb - st.neighbour[2]
            p = max(pairs - st.n_pairs, 1)
            rho_z_robust = min(rho_z_robust, a / math.sqrt(b * c) * math.sqrt(p) if b > 0 and c > 0 else 0.0)
    excess_h = q0_h - n_h
    structure = {
        "excess_heldout": bool(excess_significant(q0_h, n_h)),
        "excess_all": bool(excess_significant(q0_all, n_all)),
        "neighbour_correlation": float(rho),
        "neighbour_correlation_z": float(rho_z),
        "neighbour_correlation_z_without_top_run": float(rho_z_robust),
        "correlated": bool(rho_z_robust > rule.autocorr_z),
        "line": bool(line.significant) if line is not None else False,
    }
    has_structure = structure["excess_all"] or structure["correlated"] or structure["line"]
    sig = [s for s in scores if s.significant]
    winner = max(sig, key=lambda s: s.gain - s.threshold) if sig else None
    if winner is not None:
        if structure["excess_heldout"] and excess_h > 0:
            explained = winner.raw_gain / excess_h
        else:
            explained = 1.0
        if explained >= rule.min_explained:
            reason = (
                f"{winner.name} removes {min(explained, 1.0):.0%} of the held-out excess "
                f"(gain {winner.gain:.1f} > threshold {winner.threshold:.1f})"
            )
            return winner.name, reason, scores, winner, structure, explained
        reason = (
            f"the best candidate {winner.name} removes only {explained:.0%} of the held-out excess "
            f"(< {rule.min_explained:.0%}): the residual has structure no candidate explains"
        )
        return "unexplained", reason, scores, winner, structure, explained
    if has_structure:
        what = [k for k in ("excess_all", "correlated", "line") if structure[k]]
        return (
            "unexplained",
            f"no candidate is significant but the residual has structure ({', '.join(what)})",
            scores,
            None,
            structure,
            0.0,
        )
    return (
        "none",
        "no candidate is significant and the residual is at the noise floor",
        scores,
        None,
        structure,
        0.0,
    )


def split_runs(runs) -> tuple[list[str], list[str]]:
    """Held-out runs: every third run, in order of voltage, separately for constant-voltage
    and varying-voltage runs (at least one of each kind held out when it has two or more)."""
    const = sorted([r for r in runs if r.is_constant_voltage], key=lambda r: (r.voltage, r.name))
    vary = sorted([r for r in runs if not r.is_constant_voltage], key=lambda r: r.name)
    held: list[str] = []
    for group in (const, vary):
        if len(group) >= 2:
            held += [r.name for i, r in enumerate(group) if i % 3 == 1]
    if not held:
        raise ValueError("the dataset needs at least two runs of one kind to hold one out")
    train = [r.name for r in runs if r.name not in held]
    return train, held


def decide(
    stats_by_run: dict[str, RunStatistics],
    train: list[str],
    heldout: list[str],
    *,
    line: LineScan | None = None,
    rule: DecisionRule | None = None,
    candidates: tuple[Candidate, ...] = CANDIDATES,
    seed: int = 0,
    kinds: dict[str, str] | None = None,
    progress=None,
) -> Decision:
    rule = rule or DecisionRule()
    tr = [stats_by_run[n] for n in train]
    ho = [stats_by_run[n] for n in heldout]
    effect, reason, scores, winner, structure, explained = _verdict(tr, ho, rule, line, candidates)
    rng = np.random.default_rng(seed)
    counts: dict[str, int] = {}
    kinds = kinds or {}

    def resample(group):
        # stratified by kind of run, so that every replicate keeps the kinds of the original sets
        out = []
        for kind in sorted({kinds.get(s.name, "") for s in group}):
            members = [s for s in group if kinds.get(s.name, "") == kind]
            out += [members[i] for i in rng.integers(0, len(members), len(members))]
        return out

    for b in range(rule.bootstrap):
        tr_b = resample(tr)
        ho_b = resample(ho)
        e_b = _verdict(tr_b, ho_b, rule, line, candidates)[0]
        counts[e_b] = counts.get(e_b, 0) + 1
        if progress is not None:
            progress(b + 1, rule.bootstrap)
    confidence = counts.get(effect, 0) / max(rule.bootstrap, 1)
    if effect not in ("none", "unexplained") and rule.bootstrap > 0 and confidence < rule.min_confidence:
        # significant on these runs but not stable over resampled runs: do not force a name
        has_structure = structure["excess_all"] or structure["correlated"] or structure["line"]
        fallback = "unexplained" if has_structure else "none"
        reason = (
            f"{effect} was significant but wins in only {confidence:.0%} of the bootstrap replicates "
            f"(< {rule.min_confidence:.0%}); answer {fallback}"
        )
        effect = fallback
        confidence = counts.get(effect, 0) / max(rule.bootstrap, 1)
        winner = None
    n_h = sum(s.n for s in ho)
    q0_h = sum(s.ztz for s in ho)
    excess = {
        "heldout_windows": int(n_h),
        "heldout_ss_nominal": float(q0_h),
        "heldout_ss_per_window_nominal": float(q0_h / max(n_h, 1)),
        "heldout_ss_per_window_chosen": float(winner.heldout_ss / max(n_h, 1)) if winner else float("nan"),
        "explained_fraction": float(explained),
    }
    return Decision(
        effect=effect,
        confidence=float(confidence),
        reason=reason,
        scores=scores,
        winner=winner,
        excess=excess,
        structure=structure,
        bootstrap_counts=counts,
        train_runs=list(train),
        heldout_runs=list(heldout),
    )
