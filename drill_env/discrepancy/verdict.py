"""The verdict: which effect, if any, explains the equation error: fit, hold out, test, bootstrap.

All statistics are in noise units: every window's residual and candidate columns are
divided by that window's noise standard deviation, so that the nominal model with
the right noise floor gives a sum of squares ~ chi^2 with one degree of freedom per
window. The floor is the encoder's, spectral lines of the quantisation error included
(:mod:`drill_env.recordings.equation_error`): a window where a line of an undithered
encoder aliases into its pass band weighs little, one where none does weighs much. The
per-run statistics and the candidates' held-out scores are in
:mod:`~drill_env.discrepancy.scoring`, the spectral lines in
:mod:`~drill_env.discrepancy.spectral_lines`, the parameters that moved and their intervals
in :mod:`~drill_env.discrepancy.parameter_selection`.

The rule (all numbers in :class:`DecisionRule`):

0. With a :class:`CalibrationSetup` (see :mod:`~drill_env.discrepancy.calibrate`), the
   statistics are those of the recalibrated model and every fit below refits the
   identified parameters jointly: effects are scored as additions to the recalibrated
   model, against recalibration alone.
1. Fit each candidate on the training runs; its *held-out gain* is the drop of the
   held-out sum of squares ``D = Q_ref - Q_c``, divided by ``max(1, Q_c/n)`` so that a
   residual left far above the noise floor cannot make a partial fit look significant.
   Each held-out sum is predictive: whitened by the uncertainty of the parameters refitted
   on the training runs (:func:`_predictive`), so that a refit extrapolated to held-out
   runs that fix a parameter more sharply than the training runs is not read as a gain.
2. A candidate is *significant* when it passes the Benjamini-Hochberg step-up rule at
   false-discovery level alpha over the admissible candidates (p-values of the gain,
   chi^2 with k degrees of freedom) and its gain exceeds the BIC penalty ``k ln n``
   (k fitted parameters, n held-out windows), and its fitted parameters are physical.
3. The *excess* of the recalibrated model is its held-out sum of squares above what
   noise gives (n, with a tolerance for the noise-floor estimate). The best significant
   candidate (largest gain above its threshold) is named when it removes at least
   ``min_explained`` of a significant excess (or when there is no significant excess
   left to explain).
4. Otherwise the answer is ``unexplained`` if the residual has structure,
   ``recalibrated`` if the recalibrated model lowers the held-out sum of squares of the
   nominal one significantly, and ``none`` if neither. Structure is what the quantisation
   error cannot make: a significant excess over the floor; a spectral line at one
   frequency common to the runs, significant without the run that contributes most to it
   and shown by at least ``line_run_fraction`` of them on their own (the lines of the
   quantisation error sit at each run's own count rate); a correlation of neighbouring
   windows that stays significant without the run that contributes most to it (at a
   constant count rate the lines can make the windows of one run depend on each other; a
   torque the model lacks acts in every run).
5. The confidence is the fraction of bootstrap replicates (training and held-out runs
   each resampled with replacement, within each kind of run: constant or varying
   voltage) that reach the same answer. A named effect that wins in fewer than
   ``min_confidence`` of the replicates is not named: the answer falls back to rule 4.
6. The workflow also withdraws a named effect that makes a held-out sensor-space gap
   worse (:func:`sensor_worse`, :func:`demote`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from drill_env.discrepancy.calibrate import (
    ParameterFit,
    parameter_fits,
)
from drill_env.discrepancy.parameter_selection import (
    _gram_fit,
    _is_lag,
    _parameter_change,
    admissible_fits,
    final_parameters,
    jackknife_var,
    marginal_sd,
    moved_fit,
    selection_sd,
)
from drill_env.discrepancy.scoring import (
    _EDGE_NOTE,
    CalibrationSetup,
    CandidateScore,
    DecisionRule,
    JointFit,
    RunStatistics,
    _fit_linear_joint,
    _no_calibration,
    _score,
    _significance,
)
from drill_env.discrepancy.spectral_lines import LineScan
from drill_env.recordings.effects import CANDIDATES, Candidate
from drill_env.recordings.regression import CALIBRATED

__all__ = [
    "NOT_AN_EFFECT",
    "Decision",
    "decide",
    "demote",
    "second_effect",
    "sensor_worse",
    "readings_gain",
    "SENSOR_CHECKS",
    "SENSOR_RELATIVE_TOLERANCE",
]


NOT_AN_EFFECT = ("none", "recalibrated", "unexplained")  # verdicts that name no effect


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
    parameters: list[ParameterFit] = field(default_factory=list)  # the chosen model's calibration
    reference: JointFit | None = field(default=None, repr=False)  # recalibration alone
    reference_parameters: list[ParameterFit] = field(default_factory=list)  # ... and its parameters
    calibration: CalibrationSetup | None = field(default=None, repr=False)

    @property
    def named(self) -> bool:
        return self.effect not in NOT_AN_EFFECT

    @property
    def named_winner(self) -> CandidateScore:
        """The score of the named effect (a named decision has one)."""
        if self.winner is None:
            raise ValueError(f"decision {self.effect!r}: no winning candidate")
        return self.winner

    @property
    def recalibrated(self) -> list[ParameterFit]:
        return [f for f in self.parameters if f.moved]

    def score(self, name: str) -> CandidateScore:
        for s in self.scores:
            if s.name == name:
                return s
        raise KeyError(name)


def _recalibration_gain(held, cal: CalibrationSetup) -> tuple[float, float]:
    """Held-out drop of the sum of squares from the nominal to the recalibrated model, and the
    threshold it must pass (the candidates' rule with one degree of freedom per moved parameter)."""
    k = len(cal.moved)
    if k == 0 or not cal.nominal_ztz:
        return 0.0, float("inf")
    n_h = sum(s.n for s in held)
    gain = sum(cal.nominal_ztz[s.name] for s in held) - sum(s.ztz for s in held)
    thr = max(float(stats.chi2.isf(1e-3, k)), k * math.log(max(n_h, 2)))
    return float(gain), thr


def _neighbour_after(st: RunStatistics, cal: CalibrationSetup, ref: JointFit) -> tuple[float, float, float]:
    """Neighbour sums of one run's residual after the parameter changes of ``ref``."""
    cs = cal.stats.get(st.name)
    if not cal.free or cs is None or cs.neighbour is None:
        return st.neighbour
    return cs.neighbour_sums(_parameter_change(cal, ref))


def _verdict(train, held, rule: DecisionRule, line: LineScan | None, candidates, cal: CalibrationSetup):
    n_h = sum(s.n for s in held)
    ref = _fit_linear_joint(train, held, cal, None, rule)  # recalibration alone
    scores = [_score(c, train, held, rule, cal, ref) for c in candidates]
    _significance(scores, candidates, n_h, rule)
    q0_h = ref.heldout_ss
    n_all = n_h + sum(s.n for s in train)
    q0_all = q0_h + ref.train_ss

    def excess_significant(q, n):
        return q > n * (1.0 + rule.floor_tolerance) + rule.excess_z * math.sqrt(2.0 * n)

    # the neighbour correlation of the residual of the recalibrated model (the structure a
    # parameter change removes is not a missing effect)
    neighbour = {s.name: _neighbour_after(s, cal, ref) for s in train + held}
    s_ab = sum(neighbour[s.name][0] for s in train + held)
    s_aa = sum(neighbour[s.name][1] for s in train + held)
    s_bb = sum(neighbour[s.name][2] for s in train + held)
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
            nb = neighbour[st.name]
            a, b, c = s_ab - nb[0], s_aa - nb[1], s_bb - nb[2]
            p = max(pairs - st.n_pairs, 1)
            rho_z_robust = min(rho_z_robust, a / math.sqrt(b * c) * math.sqrt(p) if b > 0 and c > 0 else 0.0)
    excess_h = q0_h - n_h
    cal_gain, cal_thr = _recalibration_gain(held, cal)
    structure = {
        "excess_heldout": bool(excess_significant(q0_h, n_h)),
        "excess_all": bool(excess_significant(q0_all, n_all)),
        "neighbour_correlation": float(rho),
        "neighbour_correlation_z": float(rho_z),
        "neighbour_correlation_z_without_top_run": float(rho_z_robust),
        "correlated": bool(rho_z_robust > rule.autocorr_z),
        "line": bool(line.significant) if line is not None else False,
        "recalibration_gain": cal_gain,
        "recalibration_threshold": cal_thr,
        "recalibration_confirmed": bool(cal_gain > cal_thr),
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
                f"{winner.name} removes {min(explained, 1.0):.0%} of the held-out excess of the "
                f"{'recalibrated' if cal.free else 'nominal'} model "
                f"(gain {winner.gain:.1f} > threshold {winner.threshold:.1f})"
            )
            return winner.name, reason, scores, winner, structure, explained, ref
        reason = (
            f"the best candidate {winner.name} removes only {explained:.0%} of the held-out excess "
            f"(< {rule.min_explained:.0%}): the residual has structure no candidate explains"
        )
        return "unexplained", reason, scores, winner, structure, explained, ref
    if has_structure:
        what = [k for k in ("excess_all", "correlated", "line") if structure[k]]
        return (
            "unexplained",
            f"no candidate is significant but the residual has structure ({', '.join(what)})",
            scores,
            None,
            structure,
            0.0,
            ref,
        )
    if structure["recalibration_confirmed"]:
        return (
            "recalibrated",
            f"new parameter values lower the held-out sum of squares by {cal_gain:.1f} "
            f"(> {cal_thr:.1f}); no candidate is significant on top of them and the residual is "
            "at the noise floor",
            scores,
            None,
            structure,
            0.0,
            ref,
        )
    return (
        "none",
        "no candidate is significant and the residual is at the noise floor",
        scores,
        None,
        structure,
        0.0,
        ref,
    )


def _fallback(structure) -> str:
    if structure["excess_all"] or structure["correlated"] or structure["line"]:
        return "unexplained"
    return "recalibrated" if structure["recalibration_confirmed"] else "none"


# Sensor-space metrics a named effect must not make worse (compare.aggregate keys), with the
# absolute part of the tolerance: "angle" and "speed" stand for the angle noise and the noise of
# the smooth speed; the relative part is SENSOR_RELATIVE_TOLERANCE of the recalibrated model's gap.
SENSOR_CHECKS: dict[str, tuple[str, float]] = {
    "short_horizon_angle_rms_rad": ("angle", 1.0),
    "short_horizon_speed_rms_rad_s": ("speed", 1.0),
    "steady_mean_speed_abs_error": ("speed", 1.0),
    "steady_min_speed_abs_error": ("speed", 3.0),
    "steady_max_speed_abs_error": ("speed", 3.0),
    "steady_stick_fraction_abs_error": ("one", 0.05),
    "steady_period_abs_error_s": ("one", 0.25),
}
SENSOR_RELATIVE_TOLERANCE = 0.25


# What a reading error must improve to be named on top of another effect: the gap of the
# angle readings themselves (compare.aggregate key), by more than the angle noise.
READINGS_CHECK = "short_horizon_angle_rms_rad"


def readings_gain(
    before: dict[str, float], after: dict[str, float], floors: dict[str, float]
) -> float | None:
    """How much closer the model ``after`` reads the held-out angles than ``before``, in units
    of the angle noise (``READINGS_CHECK``; None where either gap is missing). A measurement
    effect named as the second effect must give more than 1: an equation-error gain that the
    readings do not show is the first effect's residual, not a sensor (a 0.6 mrad
    eccentricity on top of position friction under 8 % time-stamp jitter moved the angle gap
    by 0.5 of the noise)."""
    b, a = before.get(READINGS_CHECK), after.get(READINGS_CHECK)
    floor = floors.get("angle_rad", 0.0)
    if b is None or a is None or not (math.isfinite(a) and math.isfinite(b)) or floor <= 0.0:
        return None
    return (b - a) / floor


def sensor_worse(before: dict[str, float], after: dict[str, float], floors: dict[str, float]) -> list[str]:
    """The sensor-space gaps that the model ``after`` makes worse than ``before`` by more than
    their noise: ``after > (1 + SENSOR_RELATIVE_TOLERANCE) before + c floor``."""
    worse = []
    scale = {"angle": floors.get("angle_rad", 0.0), "speed": floors.get("speed_rad_s", 0.0), "one": 1.0}
    for key, (unit, c) in SENSOR_CHECKS.items():
        if key not in before or key not in after:
            continue
        b, a = before[key], after[key]
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        if a > (1.0 + SENSOR_RELATIVE_TOLERANCE) * b + c * scale[unit]:
            worse.append(key)
    return worse


def second_effect(
    decision: Decision,
    stats_by_run: dict[str, RunStatistics],
    cal: CalibrationSetup | None,
    *,
    rule: DecisionRule | None = None,
    candidates: tuple[Candidate, ...] = CANDIDATES,
) -> dict[str, Any]:
    """Greedy forward step: with the named effect in the model, is a second candidate needed?

    Tried only when the held-out residual of the recalibrated model with the first effect
    still shows a significant excess; each other candidate is fitted jointly with the
    identified parameters and the first effect (a lag effect at its fitted time constant)
    and scored on the held-out runs by the same rule as the first (Benjamini-Hochberg over
    the remaining candidates, BIC penalty, physical parameters, at least ``min_explained``
    of the remaining excess)."""
    rule = rule or DecisionRule()
    out: dict[str, Any] = {"tried": False, "named": None}
    if not decision.named or cal is None or not cal.stats:
        return out
    if any(st.gram is None for st in cal.stats.values()):
        return out
    tr = [stats_by_run[n] for n in decision.train_runs]
    ho = [stats_by_run[n] for n in decision.heldout_runs]
    n_h = sum(s.n for s in ho)
    first = next(c for c in candidates if c.name == decision.effect)
    if first.is_lag:
        tau = decision.named_winner.fit.tau
        i_w = int(np.argmin(np.abs(np.log(first.lags / tau)))) if tau else 0
        f_free, f_off = [], [(first.name, i_w)]
    else:
        f_free, f_off = [first.name], []
    _, q_tr0, q_h0 = _gram_fit(tr, cal, f_free, f_off, ho, rule)
    excess = q_h0 - n_h
    out["heldout_ss_per_window_with_first"] = q_h0 / max(n_h, 1)
    if not q_h0 > n_h * (1.0 + rule.floor_tolerance) + rule.excess_z * math.sqrt(2.0 * n_h):
        out["reason"] = f"the held-out residual with {first.name} is at the noise floor"
        return out
    out["tried"] = True
    rest = tuple(c for c in candidates if c.name != first.name)
    scores = []
    for c in rest:
        if c.is_lag:
            fits = [_gram_fit(tr, cal, f_free, f_off + [(c.name, i)], ho, rule) for i in range(c.lags.size)]
            i = int(np.argmin([f[1] for f in fits]))
            raw = q_h0 - fits[i][2] if fits[i][1] < q_tr0 else 0.0
            edge = i == 0 and raw > 0.0
            params = c.to_parameters(np.array([1.0]), float(c.lags[i]) if fits[i][1] < q_tr0 else 0.0)
        else:
            theta, _, q_h = _gram_fit(tr, cal, f_free + [c.name], f_off, ho, rule)
            raw = q_h0 - q_h
            params = c.to_parameters(theta[-c.n_params :])
        q_c = q_h0 - raw
        gain = raw / max(1.0, q_c / max(n_h, 1))
        why = c.admissible(params)
        if c.is_lag and why is None and edge:
            why = _EDGE_NOTE
        sc = CandidateScore(
            name=c.name,
            gain=float(gain),
            raw_gain=float(raw),
            threshold=float("nan"),
            significant=False,
            admissible=why is None,
            note=why or "",
            parameters={k: float(v) for k, v in params.items()},
            heldout_ss=float(q_c),
        )
        sc.p_value = float(stats.chi2.sf(max(gain, 0.0), c.n_params))
        scores.append(sc)
    _significance(scores, rest, n_h, rule)
    out["candidates"] = [s.as_dict() for s in scores]
    sig = [s for s in scores if s.significant]
    if not sig:
        out["reason"] = "no second candidate is significant"
        return out
    best = max(sig, key=lambda s: s.gain - s.threshold)
    keys: dict[str, list] = {}
    for c in rest:
        if c.name == best.name:
            if c.is_lag:
                tau = best.parameters[next(iter(best.parameters))]
                i = int(np.argmin(np.abs(np.log(c.lags / tau)))) if tau else 0
                keys = {"free": f_free, "off": f_off + [(c.name, i)]}
            else:
                keys = {"free": f_free + [c.name], "off": f_off}
    explained = best.raw_gain / excess if excess > 0 else 1.0
    out["explained_fraction"] = float(explained)
    if explained < rule.min_explained:
        out["reason"] = f"{best.name} removes only {explained:.0%} of the excess left by {first.name}"
        return out
    # One model holds both effects: the moved parameters and the coefficients of both effects
    # fitted together. The first effect's coefficients from its fit alone carry the second
    # effect's share (string damping against the position friction of the upper disk, a drift
    # against the lower friction level), and a model that mixes them with the second effect's
    # fitted on top simulates worse than either.
    second_c = next(c for c in rest if c.name == best.name)
    cal_m = dataclasses.replace(cal, free=list(cal.moved))
    theta, q_tr, _, cov = _gram_fit(tr, cal_m, keys["free"], keys["off"], ho, rule, with_cov=True)
    nf = len(cal_m.free)
    coef = theta[nf:]
    if first.is_lag:
        first_params = dict(decision.named_winner.parameters)
    else:
        first_params = first.to_parameters(coef[: first.n_params])
        coef = coef[first.n_params :]
    second_params = best.parameters if second_c.is_lag else second_c.to_parameters(coef[: second_c.n_params])
    why = first.admissible(first_params) or second_c.admissible(second_params)
    if why is not None:
        out["reason"] = (
            f"{best.name} is significant but the joint fit with {first.name} is not physical ({why})"
        )
        return out
    out["named"] = best.name
    out["parameters"] = {k: float(v) for k, v in second_params.items()}
    out["first_parameters"] = {k: float(v) for k, v in first_params.items()}
    out["heldout_ss"] = best.heldout_ss
    # the moved parameters refitted with both effects; those no longer significant stay nominal
    if cal.moved and cal.nominal is not None and cal.base is not None:  # set together
        n_tr = sum(s_.n for s_ in tr)
        scale = max(1.0, q_tr / max(n_tr - theta.size, 1))
        # intervals at least as wide as with every calibrated parameter free under its prior
        # (see final_parameters): those held at nominal are known only to within it
        second_tau = best.parameters[next(iter(best.parameters))] if _is_lag(rest, best.name) else None
        first_tau = decision.named_winner.fit.tau if first.is_lag else None
        both = [(first, first_tau), (second_c, second_tau)]
        marginal = marginal_sd(cal, tr, ho, rule, both, with_estimate=True)
        sd_own = np.sqrt(np.maximum(np.diag(cov[:nf, :nf]) * scale, 0.0))
        sd_interval = np.maximum(sd_own, selection_sd(theta[:nf], cal_m.free, marginal))
        if len(tr) >= 3:  # and at least the jackknife over the training runs, as for one effect
            var_jk = jackknife_var(
                lambda runs: _gram_fit(runs, cal_m, keys["free"], keys["off"], ho, rule)[0][:nf], tr
            )
            sd_interval = np.maximum(sd_interval, np.sqrt(var_jk))
        fits = parameter_fits(
            cal.nominal,
            cal.base,
            cal_m.free,
            theta[:nf],
            cov[:nf, :nf] * scale,
            cal.rule,
            identified=cal.free,
            sd_interval=sd_interval,
        )
        # every moved parameter keeps its joint value, as with one effect (final_parameters,
        # moved_all): the effects' coefficients were fitted with these values, and one set back
        # to nominal because its change is within the test's threshold no longer matches them
        free_names = {CALIBRATED[j] for j in cal_m.free}
        fits = [dataclasses.replace(f, moved=True) if f.name in free_names else f for f in fits]
        out["parameter_fits"] = admissible_fits(cal.nominal, fits)
    out["reason"] = (
        f"{best.name} removes {min(explained, 1.0):.0%} of the held-out excess left by {first.name} "
        f"(gain {best.gain:.1f} > threshold {best.threshold:.1f})"
    )
    return out


def demote(decision: Decision, reason: str) -> None:
    """Withdraw the named effect (e.g. it makes the model worse in sensor space)."""
    decision.effect = _fallback(decision.structure)
    decision.reason = f"{reason}; answer {decision.effect}"
    decision.confidence = decision.bootstrap_counts.get(decision.effect, 0) / max(
        sum(decision.bootstrap_counts.values()), 1
    )
    decision.winner = None
    decision.parameters = decision.reference_parameters
    if decision.effect == "recalibrated" and not any(f.moved for f in decision.parameters):
        decision.effect = "none"


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
    calibration: CalibrationSetup | None = None,
    progress=None,
) -> Decision:
    """The verdict on the held-out runs, with effects scored as additions to the recalibrated
    model when ``calibration`` is given (else to the model the statistics were computed at)."""
    rule = rule or DecisionRule()
    cal = calibration if calibration is not None else _no_calibration(stats_by_run)
    tr = [stats_by_run[n] for n in train]
    ho = [stats_by_run[n] for n in heldout]
    effect, reason, scores, winner, structure, explained, ref = _verdict(tr, ho, rule, line, candidates, cal)
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
        e_b = _verdict(tr_b, ho_b, rule, line, candidates, cal)[0]
        counts[e_b] = counts.get(e_b, 0) + 1
        if progress is not None:
            progress(b + 1, rule.bootstrap)
    confidence = counts.get(effect, 0) / max(rule.bootstrap, 1)
    if effect not in NOT_AN_EFFECT and rule.bootstrap > 0 and confidence < rule.min_confidence:
        # significant on these runs but not stable over resampled runs: do not force a name
        fallback = _fallback(structure)
        reason = (
            f"{effect} was significant but wins in only {confidence:.0%} of the bootstrap replicates "
            f"(< {rule.min_confidence:.0%}); answer {fallback}"
        )
        effect = fallback
        confidence = counts.get(effect, 0) / max(rule.bootstrap, 1)
        winner = None
    named = winner is not None and effect == winner.name
    ref_params: list[ParameterFit] = []
    params: list[ParameterFit] = []
    if calibration is not None and calibration.nominal is not None:
        fit_m, refit_m, cal_m = moved_fit(calibration, tr, ho, rule, None)
        marginal = marginal_sd(calibration, tr, ho, rule, [], with_estimate=True)
        ref_params = admissible_fits(
            calibration.nominal,
            final_parameters(
                cal_m, fit_m, refit_m, tr, marginal=marginal, identified=calibration.free, moved_all=True
            ),
        )
        params = ref_params
        if named:
            cand = next(c for c in candidates if c.name == winner.name)
            fit_m, refit_m, cal_m = moved_fit(calibration, tr, ho, rule, cand)
            if cand.is_lag and fit_m.tau:
                # the model's time constant is the one its parameters were refitted at
                winner = dataclasses.replace(
                    winner, parameters=cand.to_parameters(np.array([1.0]), fit_m.tau)
                )
            marginal = marginal_sd(calibration, tr, ho, rule, [(cand, fit_m.tau)], with_estimate=True)
            params = admissible_fits(
                calibration.nominal,
                final_parameters(
                    cal_m, fit_m, refit_m, tr, marginal=marginal, identified=calibration.free, moved_all=True
                ),
            )
    if effect == "recalibrated" and not any(f.moved for f in params):
        effect, reason = (
            "none",
            "the recalibration is confirmed but no parameter differs from nominal beyond its interval",
        )
    n_h = sum(s.n for s in ho)
    q0_h = sum(cal.nominal_ztz[s.name] for s in ho) if cal.nominal_ztz else sum(s.ztz for s in ho)
    excess = {
        "heldout_windows": int(n_h),
        "heldout_ss_nominal": float(q0_h),
        "heldout_ss_per_window_nominal": float(q0_h / max(n_h, 1)),
        "heldout_ss_per_window_recalibrated": float(ref.heldout_ss / max(n_h, 1)),
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
        parameters=params,
        reference=ref,
        reference_parameters=ref_params,
        calibration=calibration,
    )
