"""Identification that includes the structure: the base fit, the discrepancy tests on its
held-out runs, and the joint re-fit of every base parameter with each effect they name.

:func:`identify_structure` runs, in rounds (at most :data:`MAX_ROUNDS`):

1. the identification (:func:`drill_env.identify.identify`) with the effects found so far,
   every base parameter fitted jointly with their parameters;
2. the discrepancy workflow (:func:`drill_env.discrepancy.analyse`) on the same held-out
   runs, with the identified base model as its nominal one;
3. an effect of the library it names that the model lacks is added (with its first
   estimate: a lag's time constant is profiled about it) and the next round re-identifies
   everything; the search stops when nothing more is named, when the verdict is ``none``,
   ``recalibrated`` or ``unexplained``, or when an effect named is not one the user allowed.

A fit refused only because T_sl is extrapolated below the slowest slip of the data (it and the
hump terms tied to it not determined, everything else the model needs determined) keeps its
fitted model beside the refusal (``Identification.provisional``): the tests run on it at the
slips the data cover (the lower disk's windows from the fit's slowest slip up, where T_sl does
not enter), and the result gives their verdict beside the refusal (no rig file; T_sl with the
run that determines it). Any other refusal leaves the structure ``not_tested``.

The result is one model: the last round's (rig.yaml with its ``effects:`` and, for an eccentric
encoder, ``measurement:`` sections), with each round's findings and gaps for the report.

This module sits above both workflows: :mod:`drill_env.identify` and
:mod:`drill_env.discrepancy` do not import each other.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = ["MAX_ROUNDS", "NOT_TESTED", "Round", "StructureSearch", "identify_structure", "check_effect_names"]

MAX_ROUNDS = 3
NOT_TESTED = "not_tested"  # the verdict when the tests never ran
MIN_RUNS_TO_HOLD_OUT = 4  # identify holds runs out from four runs on
MIN_HALF_S = 20.0  # [s] the shortest half of a run cut in two
# the parameters of each library effect's first estimate that are time constants of a lag
_LAG_FIELD = {"motor_inductance": "motor_lag", "friction_memory": "friction_lag"}


def check_effect_names(names: Sequence[str]) -> tuple[str, ...]:
    """``names`` if every one is a library effect; ValueError naming the allowed ones."""
    from drill_env.recordings.effects import candidate_names

    allowed = candidate_names()
    bad = [n for n in names if n not in allowed]
    if bad:
        raise ValueError(
            f"effects: unknown effect(s) {', '.join(map(repr, bad))}; allowed: {', '.join(allowed)}"
        )
    if len(set(names)) != len(names):
        raise ValueError(f"effects: {list(names)} names an effect twice")
    return tuple(names)


@dataclass
class Round:
    """One round of the search: the model it tested, what the tests found, the gaps."""

    number: int
    model_effects: list[str]  # the effects of the model the round tested
    verdict: str  # the discrepancy workflow's: none, recalibrated, unexplained or an effect
    confidence: float
    reason: str
    named: list[str]  # effects named by the tests (strongest first)
    added: list[str]  # of these, the ones added to the model for the next round
    gap_before: float  # held-out equation error per window of the tested model (1: noise floor)
    gap_after: float | None = None  # ... of the next round's model (None: no next model)
    base_changes: dict[str, float] = field(default_factory=dict)  # relative change of each base parameter
    first_estimates: dict[str, dict[str, float]] = field(default_factory=dict)
    refused: list[str] = field(default_factory=list)  # named but not allowed (--effects)
    signature: str = ""  # what an unexplained residual is locked to

    def as_dict(self) -> dict[str, Any]:
        return {
            "round": self.number,
            "model_effects": self.model_effects,
            "verdict": self.verdict,
            "confidence": self.confidence,
            "reason": self.reason,
            "named": self.named,
            "added": self.added,
            "refused": self.refused,
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "base_changes": self.base_changes,
            "first_estimates": self.first_estimates,
            "signature": self.signature,
        }


@dataclass
class StructureSearch:
    """The final identification and every round that led to it."""

    identification: Any  # drill_env.identify.Identification: the final model
    base: Any  # the base-only identification (round 1's model)
    rounds: list[Round]
    allowed: tuple[str, ...]
    stopped: str  # why the search stopped
    suspect: list[str] = field(default_factory=list)  # parameters an unexplained residual moves
    halves: bool = False  # too few runs to hold one out: each run was cut in two (NAMEa, NAMEb)
    # the final fit was refused for an extrapolated T_sl, and the tests ran on its fitted model at
    # the slips the data cover: what is not determined and the run that determines it ("": not so)
    refused: str = ""

    @property
    def effects(self) -> list[str]:
        return list(self.identification.effects)

    @property
    def verdict(self) -> str:
        """``none``, ``recalibrated``, ``unexplained``, the effects found (``a+b``) or
        ``not_tested`` (the tests never ran: the base fit was refused for anything but an
        extrapolated T_sl, or no run could be held out; :attr:`stopped` says why and what to record). An effect
        the tests named that the model could not take (its re-fit not physical, or failed) leaves
        the residual unexplained: the model has no effect that explains it."""
        if self.effects:
            return "+".join(self.effects)
        if not self.rounds:
            return NOT_TESTED  # the tests never ran: a hidden effect is not ruled out
        last = self.rounds[-1]
        if last.verdict in ("none", "recalibrated", "unexplained") or last.refused:
            return last.verdict  # a name the user did not allow (--effects) is reported as named
        return "unexplained"

    @property
    def tested(self) -> bool:
        """Whether the discrepancy tests ran at least once."""
        return bool(self.rounds)

    def as_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "tested": self.tested,
            "effects": self.effects,
            "stopped": self.stopped,
            "allowed": list(self.allowed),
            "rounds": [r.as_dict() for r in self.rounds],
            "suspect_parameters": self.suspect,
            "runs_cut_in_halves": self.halves,
            "refused_fit": self.refused,
        }


def heldout_gap(ident) -> float:
    """Held-out equation error per window of the model fitted without the held-out runs, in
    units of the noise floor (nan without held-out runs)."""
    from drill_env.identify.joint import residual_ss

    fit = ident.train_fit
    if fit is None or not ident.heldout_runs:
        return math.nan
    rows = [ident.rows[n] for n in ident.heldout_runs]
    ss, n = residual_ss(rows, fit)
    return ss / max(n, 1)


def _first_estimates(decision, second: Mapping[str, Any]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    if decision.named and decision.winner is not None:
        out[decision.effect] = dict(decision.winner.parameters)
    if second.get("named"):
        out[str(second["named"])] = dict(second.get("parameters", {}))
    return out


def _suspect(ident) -> list[str]:
    """The base parameters an unexplained residual moves: those whose run-to-run spread (the
    jackknife over the runs) is well beyond what the window noise gives (an error common to a
    run's windows), largest first."""
    from drill_env.params import IDENTIFIED_PARAMETERS

    fit = ident.fit
    out = []
    for i, name in enumerate(fit.free):
        if name not in IDENTIFIED_PARAMETERS:
            continue
        jk, model = float(fit.sd_jackknife[i]), float(fit.sd_information[i])
        if model > 0 and jk > 3.0 * model and jk > 1e-3 * abs(fit.values[name]):
            out.append((jk / model, name))
    return [n for _, n in sorted(out, reverse=True)]


def identify_structure(
    dataset,
    *,
    structure: str | None = None,
    known: Mapping[str, float] | None = None,
    heldout: list[str] | None = None,
    allowed: Sequence[str] | None = None,
    max_rounds: int = MAX_ROUNDS,
    simulate_heldout: bool = True,
    simulate_gaps: bool = True,
    seed: int = 0,
    progress: Callable[[str, int, int], None] | None = None,
) -> StructureSearch:
    """Identify the rig with the effects its data need (see the module docstring).

    Args:
        allowed: the library effects the search may add (default: every one); a verdict that
            names another stops the search and is reported.
        max_rounds: how many times the discrepancy tests run at most (>= 1).
    """
    from drill_env.discrepancy import analyse
    from drill_env.identify import identify
    from drill_env.recordings.effects import candidate_names

    if not (isinstance(max_rounds, int) and max_rounds >= 1):
        raise ValueError(f"max_rounds: {max_rounds!r}; allowed: an integer >= 1")
    allowed_t = check_effect_names(list(allowed)) if allowed is not None else tuple(candidate_names())
    halves = False
    if heldout is None and len(dataset.runs) < MIN_RUNS_TO_HOLD_OUT:
        cut = _halves(dataset)
        if len(cut.runs) >= MIN_RUNS_TO_HOLD_OUT:
            # a staircase and a ramp alone: the tests need runs the fit has not seen, so each run
            # is cut in two (the windows at the cut are lost, nothing else)
            dataset, halves = cut, True

    def run(effects: dict[str, float | None]):
        return identify(
            dataset,
            structure=structure,
            known=known,
            heldout=heldout,
            simulate_heldout=False,
            progress=progress,
            effects=effects,
            # a fit refused for a loose T_sl alone is still tested where the data reach (a hidden
            # effect can be what leaves it loose: position friction in closed-loop PI runs)
            keep_fitted=True,
        )

    base = run({})
    current = base
    held = base.heldout_runs
    effects: dict[str, float | None] = {}
    rounds: list[Round] = []
    stopped = f"{max_rounds} rounds"
    for number in range(1, max_rounds + 1):
        model = tested_model(current)
        if model is None or (current.params is None and not held):
            stopped = _refusal(current)
            break
        if not held:
            stopped = (
                "too few runs to hold one out: the discrepancy tests need held-out runs and never ran, so "
                "a hidden effect is not ruled out; record more runs (drill-env identify --plan)"
            )
            break
        d = analyse(
            dataset,
            params=_base_model(model),
            heldout=held,
            seed=seed,
            eq_config=_covered_slips(current),
            simulate_gaps=simulate_gaps,
            simulate_training_runs=False,  # the tests use the held-out runs' gaps alone
            progress=progress,
        )
        named = list(d.effects)
        rnd = Round(
            number=number,
            model_effects=list(effects),
            verdict=d.effect,
            confidence=float(d.decision.confidence),
            reason=d.decision.reason,
            named=named,
            added=[],
            gap_before=heldout_gap(current),
            first_estimates=_first_estimates(d.decision, d.second),
        )
        if d.signature is not None:
            rnd.signature = d.signature.summary()
        rounds.append(rnd)
        new = [n for n in named if n not in effects]
        rnd.refused = [n for n in new if n not in allowed_t]
        new = [n for n in new if n in allowed_t]
        if not new:
            stopped = (
                f"round {number}: {d.effect}"
                + (f"; named but not allowed: {', '.join(rnd.refused)}" if rnd.refused else "")
                + ("" if named else ": nothing more named")
            )
            break
        # the strongest new effect alone: a second one named beside it against the base model
        # may only soak up what the first leaves there (an eccentric encoder beside two harmonics
        # of position friction), and the next round's tests name it again if the data need it
        new = new[:1]
        trial = dict(effects)
        for n in new:
            est = rnd.first_estimates.get(n, {})
            trial[n] = float(est[_LAG_FIELD[n]]) if n in _LAG_FIELD and _LAG_FIELD[n] in est else None
            if n in _LAG_FIELD and trial[n] is None:
                trial[n] = 0.02  # no estimate: the profile starts at 20 ms
        try:
            nxt = run(trial)
        except ValueError as exc:
            stopped = f"round {number}: re-identification with {', '.join(new)} failed ({exc})"
            break
        if tested_model(nxt) is None:
            from drill_env.identify.identification import refusal_reason

            stopped = (
                f"round {number}: with {', '.join(new)} {refusal_reason(nxt.blocking, nxt.invalid)}; kept "
                "the model without it"
            )
            break
        rnd.added = new
        rnd.gap_after = heldout_gap(nxt)
        rnd.base_changes = {
            n: nxt.parameters[n].value / current.parameters[n].value - 1.0
            for n in current.parameters
            if current.parameters[n].value not in (0.0,) and math.isfinite(current.parameters[n].value)
        }
        effects = {n: (nxt.effects[n].parameters.get(_LAG_FIELD.get(n, ""), None)) for n in trial}
        current = nxt
    else:
        stopped = f"the bound of {max_rounds} rounds"
    # the residual is unexplained when the tests say so, or when what they named is not in the
    # final model (a re-fit with it that failed or was not physical); an effect named again that
    # the model already has is explained (the tests run on the base model, see _base_model)
    left = rounds and (
        rounds[-1].verdict == "unexplained"
        or (
            rounds[-1].verdict not in ("none", "recalibrated")
            and not rounds[-1].added
            and not rounds[-1].refused
            and any(n not in effects for n in rounds[-1].named)
        )
    )
    suspect = _suspect(current) if left else []
    refused = ""
    if rounds and current.params is None:
        # the tests ran on the refused fit's model at the slips its data cover: the verdict stands,
        # and T_sl (with the hump terms tied to it) stays not determined, with the run that fixes it
        refused = _refusal(current, tested=True)
        stopped = f"{stopped}; {refused}"
    if simulate_heldout and current.train_params is not None and held:
        _simulate_heldout(current, dataset)
    return StructureSearch(
        identification=current,
        base=base,
        rounds=rounds,
        allowed=allowed_t,
        stopped=stopped,
        suspect=suspect,
        halves=halves,
        refused=refused,
    )


def tested_model(ident):
    """The model the structure tests run on: the identified rig, or the fitted model kept beside
    a fit refused only for T_sl, extrapolated or loose (tested at the slips its data cover, see
    :func:`_covered_slips`); None when there is none."""
    if ident.params is not None:
        return ident.params
    return getattr(ident, "provisional", None)


def _covered_slips(ident):
    """The equation-error windows the tests compare: every one for an identified rig; for a fit
    refused for an extrapolated T_sl, the lower disk's only where it slips at least as fast as the
    slowest slip of the fit's data (``fit.slowest_slip``) throughout the window. Below it the
    lower friction is the fitted curve carried down to T_sl, not observed; above it T_sl enters
    only as the level the fitted curve is measured from, which the data fix."""
    from drill_env.recordings.equation_error import EquationErrorConfig

    if ident.params is not None:
        return None
    w0 = float(ident.fit.slowest_slip)
    if not (math.isfinite(w0) and w0 > 0.0):
        return None
    return EquationErrorConfig(min_speed_lower_rad_s=w0)


def _refusal(ident, tested: bool = False) -> str:
    """Why the tests cannot run on a refused base fit, with the runs that would determine what
    it lacks; ``tested``: the tests ran on its fitted model all the same (T_sl extrapolated
    alone), so the sentence says what is not determined and where the tests looked."""
    from drill_env.identify.report import SYMBOLS

    blocking = ident.blocking
    if blocking:
        what = "; ".join(
            f"{SYMBOLS.get(p.name, p.name)} ({p.name}) is not determined"
            + (f": {p.note}" if p.note else "")
            + (f"; the run that determines it: {p.needs}" if p.needs else "")
            for p in blocking
        )
    else:
        what = (
            "the fitted parameters make no valid rig (" + (ident.invalid or "outside the model's range") + ")"
        )
    if tested:
        return (
            f"the fit was refused, no rig file: {what}; the tests ran on the fitted model at the slips its "
            f"data cover (the lower disk from {ident.fit.slowest_slip:.3g} rad/s up), where T_sl does not "
            "enter"
        )
    if getattr(ident, "provisional", None) is not None and not ident.heldout_runs:
        what += "; no run could be held out to test the fitted model at the slips the data cover"
    return (
        f"the base fit was refused, so the discrepancy tests never ran and a hidden effect is not ruled "
        f"out: {what}"
    )


def _halves(dataset):
    """``dataset`` with every run of at least :data:`MIN_HALF_S` x 2 cut into its two halves."""
    import dataclasses

    runs = []
    for r in dataset.runs:
        n = r.t.size
        if r.duration < 2 * MIN_HALF_S:
            runs.append(r)
            continue
        h = n // 2
        for tag, sl in (("a", slice(0, h)), ("b", slice(h, n))):
            runs.append(
                dataclasses.replace(
                    r,
                    name=f"{r.name}{tag}",
                    t=r.t[sl],
                    u=r.u[sl],
                    theta_u=r.theta_u[sl],
                    theta_l=r.theta_l[sl],
                )
            )
    return dataclasses.replace(dataset, runs=tuple(runs))


def _base_model(params):
    """``params`` with its effects switched off: the discrepancy workflow tests the base model
    (its equation error is the base model's: an effect already in the model is named again,
    and is not new; a second one is named beside it)."""
    import dataclasses

    from drill_env.params import ModelEffects

    return dataclasses.replace(params, effects=ModelEffects()) if params.effects.active else params


def _simulate_heldout(ident, dataset) -> None:
    from drill_env.recordings.compare import compare_run

    cache: dict = {}
    for name in ident.heldout_runs:
        ident.heldout[name] = compare_run(
            ident.train_params,
            ident.equations[name],
            dataset.encoder_counts_per_rev,
            measured_cache=cache,
            measurement=ident.measurement,
        )
