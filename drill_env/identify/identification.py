"""Identify every parameter of the rig model from a measured dataset.

The steps, in the rig's order (Sec. 2.3 of the paper did them by hand on its rig):

1. **Steady states** of the constant-voltage runs (:mod:`drill_env.recordings.steady_state`): stuck, slip
   equilibrium or cycle; the upper disk's mean balance and the lower friction curve's
   points at the equilibria, relative to the one known value (the *scale*).
2. **Dynamics** (:mod:`.dynamics`): the period of the cycles gives the string's resonance,
   hence a first lower inertia; these first values only weight the equation error's
   windows of the first pass.
3. **Joint fit** (:mod:`.joint`) of every parameter on the filtered equation error of all
   runs, twice: first with a cheap model of each window's noise, then with the full one
   (the discrepancy workflow's) weighted at the first fit.
4. **Identifiable or not**: a parameter the runs do not excite (the 95 % interval from the
   window noise alone wider than its value) is named with the run that would fix it (:data:`.plan.RUN_THAT_IDENTIFIES`);
   when one the model needs is among them, no rig file is offered. The negative side of
   the upper friction without a run that turns the upper disk backwards, and hump terms
   that a hump-free friction curve does not need, are set to stated values (the positive
   side's; zero) and said so.
5. **Held-out runs**: the model fitted without them is simulated on their input.

The data fix the parameters up to one common scale of every torque and inertia: the
string stiffness (or the motor constant) given by the user, or the paper's string
stiffness when none is given (the result then says so first).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drill_env.identify.dynamics import oscillation_frequency
from drill_env.identify.effect_fit import LAG_EFFECTS, EffectResult, effect_results, effect_rows, lag_profile
from drill_env.identify.joint import HUMP_AMPLITUDES, HUMP_RATES, JointFit, fitted_params, joint_fit, run_rows
from drill_env.identify.plan import RUN_THAT_IDENTIFIES
from drill_env.params import (
    IDENTIFIED_PARAMETERS,
    ModelEffects,
    ParameterError,
    RigParams,
    available_presets,
    load_params,
)
from drill_env.recordings.dataset import MeasuredDataset
from drill_env.recordings.equation_error import EquationErrorConfig, RunEquations, estimate_angle_noise
from drill_env.recordings.steady_state import SteadyState, UpperBalance, steady_states, upper_balance

__all__ = [
    "EXCITED_PARAMETERS",
    "Identification",
    "ParameterResult",
    "identify",
    "parse_known",
    "SCALE_PARAMETERS",
]

SCALE_PARAMETERS = ("string_stiffness", "motor_constant")
# the parameters that every protocol of a lab excites once the string stiffness is given: the
# motor, both inertias and the friction levels (the lower viscous term and the hump terms are
# determined only by runs that reach their speeds); the accuracy targets are stated on these
EXCITED_PARAMETERS: tuple[str, ...] = tuple(
    n
    for n in IDENTIFIED_PARAMETERS
    if n not in ("string_stiffness", "lower_viscous", *HUMP_AMPLITUDES, *HUMP_RATES)
)
# the parameters without which the model cannot be simulated at all
ESSENTIAL = (
    "motor_constant",
    "string_stiffness",
    "upper_inertia",
    "lower_inertia",
    "upper_static_pos",
    "upper_viscous_pos",
    "lower_static",
)
FIRST_PASS_NOISE = EquationErrorConfig(quantisation_harmonics=16, rate_span_factors=(1,))
MAX_RELATIVE_HALF_WIDTH = 1.0  # a 95 % half-width above |value| x this: not identifiable
# the same for a parameter the model can run without (a hump term, a slope, the negative side):
# a value the data leave this loose is reported as not determined, never as a plain number
NOT_DETERMINED_HALF_WIDTH = 0.25
FLAT_HALF_WIDTH = 0.25  # a direction of the fit looser than this (relative units) is flat
EFFECT_ITERATIONS = 5  # re-evaluations of the effects' columns at the fitted base parameters


@dataclass(frozen=True)
class ParameterResult:
    """One parameter: value, 95 % interval and how it was identified."""

    name: str
    value: float
    ci95: tuple[float, float]
    method: str  # "steady-state friction curve", "dynamic fit", "fixed by the user", "assumed", ...
    identified: bool
    note: str = ""
    needs: str = ""  # the run that would identify it, when it is not

    def as_dict(self) -> dict[str, Any]:
        d = {
            "value": self.value,
            "ci95": list(self.ci95),
            "method": self.method,
            "identified": self.identified,
        }
        if self.note:
            d["note"] = self.note
        if self.needs:
            d["run_that_identifies_it"] = self.needs
        return d


@dataclass
class Identification:
    """What ``drill-env identify`` found (see :func:`identify`)."""

    dataset: MeasuredDataset
    structure: str
    scale: tuple[str, float]
    scale_assumed: bool  # no --known: the paper's string stiffness
    states: list[SteadyState]
    balance: UpperBalance | None
    fit: JointFit
    train_fit: JointFit | None
    parameters: dict[str, ParameterResult]
    params: RigParams | None  # None: a parameter the model needs is not identifiable
    train_params: RigParams | None
    train_runs: list[str]
    heldout_runs: list[str]
    equations: dict[str, RunEquations]
    oscillation_hz: float
    rows: dict[str, Any] = field(default_factory=dict)  # run -> the joint fit's rows (RunRows)
    timings: dict[str, float] = field(default_factory=dict)
    heldout: dict[str, Any] = field(default_factory=dict)  # run -> RunComparison
    # the library effects fitted with the base parameters (name -> parameters, intervals)
    effects: dict[str, EffectResult] = field(default_factory=dict)
    lag_profiles: dict[str, dict[float, float]] = field(default_factory=dict)  # lag -> profile
    measurement: Any = None  # MeasurementModel of a fitted encoder eccentricity (None: exact readings)
    invalid: str = ""  # why the fitted parameters make no valid rig (params None with nothing blocking)
    # a fit refused for one reason only, T_sl carried below the slowest slip of the data or (with
    # keep_fitted) loose (it and the hump terms tied to it not determined, every other parameter
    # the model needs determined): the fitted model, kept beside the refusal (never written as the rig) so that
    # the structure tests can run at the slips the data cover (from ``fit.slowest_slip`` up,
    # where T_sl does not enter); None otherwise
    provisional: RigParams | None = None

    @property
    def not_identifiable(self) -> list[ParameterResult]:
        return [p for p in self.parameters.values() if not p.identified and p.name != self.scale[0]]

    @property
    def flat_directions(self) -> list[dict[str, Any]]:
        """The flat directions of the fit: eigenvectors of the base parameters' covariance in
        relative units (d p / p) whose 95 % half-width exceeds :data:`FLAT_HALF_WIDTH`; each
        with the parameters it moves (loading above 0.2) and the runs that would fix them."""
        f = self.fit
        names = [
            n for n in f.free if n in IDENTIFIED_PARAMETERS and n != self.scale[0] and f.values[n] != 0.0
        ]
        if not names:
            return []
        idx = [f.free.index(n) for n in names]
        v = np.array([abs(f.values[n]) for n in names])
        info_sd = f.sd_information[idx]
        corr = f.cov[np.ix_(idx, idx)] / np.outer(
            np.maximum(np.sqrt(np.diag(f.cov)[idx]), 1e-300), np.maximum(np.sqrt(np.diag(f.cov)[idx]), 1e-300)
        )
        # what the data excite (the window noise alone), in relative units
        c_rel = corr * np.outer(info_sd / v, info_sd / v)
        out = []
        # a parameter whose variance is not finite (data that barely excite it) is a flat
        # direction of its own, with no bound; the eigen-directions are those of the rest
        finite = np.isfinite(c_rel).all(axis=0) & np.isfinite(c_rel).all(axis=1)
        for i in np.flatnonzero(~finite):
            out.append(
                {
                    "half_width": math.inf,
                    "loadings": {names[i]: 1.0},
                    "run_that_identifies_it": RUN_THAT_IDENTIFIES[names[i]],
                }
            )
        names = [n for n, ok in zip(names, finite, strict=True) if ok]
        if not names:
            return out
        c_rel = c_rel[np.ix_(finite, finite)]
        lam, vec = np.linalg.eigh(c_rel)
        for k in np.argsort(lam)[::-1]:
            half = 1.96 * math.sqrt(max(float(lam[k]), 0.0))
            if half <= FLAT_HALF_WIDTH:
                break
            load = {
                names[i]: float(vec[i, k]) for i in np.argsort(-np.abs(vec[:, k])) if abs(vec[i, k]) > 0.2
            }
            needs = sorted({RUN_THAT_IDENTIFIES[n] for n in load})
            out.append({"half_width": half, "loadings": load, "run_that_identifies_it": "; ".join(needs)})
        return out

    @property
    def blocking(self) -> list[ParameterResult]:
        """Parameters the model needs that the data do not fix."""
        return [
            p
            for p in self.not_identifiable
            if p.name in ESSENTIAL and p.method not in ("assumed", REFUSED_METHOD)
        ]

    @property
    def hump(self) -> dict[str, Any]:
        """How many hump terms the lower friction got, and the shape of the identified curve."""
        out: dict[str, Any] = {"terms": self.fit.hump_terms, "tests": self.fit.hump_tests}
        p = self.params or self.train_params
        if p is not None:
            from drill_env.friction import lower_friction_curve, lower_friction_slope

            top = max(self.max_lower_speed, 1.0)
            w = np.linspace(1e-3, top, 400)
            slope = lower_friction_slope(p, w)
            falls = slope < 0
            out["monotone"] = bool(not falls.any())
            if falls.any():
                out["falls_between_rad_s"] = [float(w[falls][0]), float(w[falls][-1])]
            out["curve_at_rad_s"] = {f"{x:g}": float(lower_friction_curve(p, x)) for x in (0.0, 1.0, 5.0)}
        return out

    @property
    def max_lower_speed(self) -> float:
        top = 0.0
        for run in self.dataset.runs:
            k = max(1, int(round(0.1 / run.dt)))
            if run.theta_l.size > k:
                top = max(top, float(np.max(np.abs(run.theta_l[k:] - run.theta_l[:-k]))) / (k * run.dt))
        return top

    def scale_sentence(self) -> str:
        name, value = self.scale
        if self.scale_assumed:
            return (
                f"The scale is ASSUMED: {name} = {value:g} N m/rad, the paper's rig's string. The data fix "
                "every parameter only up to one common factor of every torque and inertia; if this rig's "
                "string differs, every torque, inertia and the motor constant here are off by the same "
                "factor. Give the string's stiffness (k = G pi d^4 / (32 L)) with --known "
                "string_stiffness=VALUE, or the motor constant with --known motor_constant=VALUE."
            )
        unit = "N m/rad" if name == "string_stiffness" else "N m/V"
        return f"The scale is fixed by the user: {name} = {value:g} {unit} (--known)."


# The range a known scale parameter may take [N m/rad or N m/V]: from a bench-top rig far
# softer than the paper's (0.078 N m/rad, 3.5 N m/V) to field drill strings (10^3-10^5 N m/rad);
# beyond it the regression's columns overflow and the fit is meaningless.
KNOWN_SCALE_RANGE = (1e-6, 1e6)


def parse_known(items: list[str] | tuple[str, ...] | None) -> dict[str, float]:
    """``["string_stiffness=0.08"]`` -> ``{"string_stiffness": 0.08}``; ValueError naming the item."""
    out: dict[str, float] = {}
    for item in items or ():
        if "=" not in item:
            raise ValueError(
                f"known: {item!r} is not NAME=VALUE; allowed names: {', '.join(SCALE_PARAMETERS)}"
            )
        name, _, text = item.partition("=")
        name = name.strip()
        if name not in SCALE_PARAMETERS:
            raise ValueError(f"known: {name!r} cannot be given; allowed: {', '.join(SCALE_PARAMETERS)}")
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"known: {name}={text!r} is not a number") from None
        lo, hi = KNOWN_SCALE_RANGE
        if not (math.isfinite(value) and lo <= value <= hi):
            raise ValueError(f"known: {name}={text}; allowed: a number from {lo:g} to {hi:g}")
        if name in out:
            raise ValueError(f"known: {name} given twice")
        out[name] = value
    if len(out) > 1:
        raise ValueError(
            "known: give one of string_stiffness, motor_constant (one value fixes the one scale the data "
            "cannot; a second would contradict the data)"
        )
    return out


def _split(runs, heldout: list[str] | None) -> tuple[list[str], list[str]]:
    names = [r.name for r in runs]
    if heldout is not None:
        unknown = [h for h in heldout if h not in names]
        if unknown:
            raise ValueError(f"heldout: unknown run(s) {unknown}; runs: {names}")
        train = [n for n in names if n not in heldout]
        if heldout and len(train) < 2:
            raise ValueError("heldout: leaves fewer than two runs to identify on")
        return train, list(heldout)
    from drill_env.recordings.split import split_runs

    if len(runs) < 4:
        return names, []  # too few runs to spare one
    try:
        return split_runs(runs)
    except ValueError:
        return names, []


def _initial(
    scale: tuple[str, float], balance: UpperBalance | None, states: list[SteadyState], freq_hz: float
) -> RigParams:
    """First values, for the noise weights of the first pass only (the fit itself starts
    from nothing: it is linear in all but the Stribeck rates, which are searched on a grid)."""
    name, value = scale
    if balance is not None:
        kth, km = balance.string_stiffness, balance.motor_constant
        tsu, bu = max(balance.static, 0.0), max(balance.viscous, 0.0)
    else:
        # the torque scale of the weights only: a string twisted a few radians at a few volts
        kth = value if name == "string_stiffness" else 0.02 * value
        km = value if name == "motor_constant" else 50.0 * value
        tsu, bu = 4.0 * kth, 25.0 * kth
    if not (kth > 0 and km > 0):
        kth = value if name == "string_stiffness" else 0.02 * value
        km = value if name == "motor_constant" else 50.0 * value
    w_n = 2.0 * math.pi * (freq_hz if math.isfinite(freq_hz) and freq_hz > 0 else 0.25)
    jl = kth / w_n**2
    eq = [s for s in states if s.kind == "equilibrium"]
    tsl = kth * min((abs(s.mean_twist) for s in eq), default=1.0)
    return RigParams(
        motor_constant=km,
        upper_inertia=15.0 * jl,
        upper_static_pos=tsu,
        upper_static_neg=tsu,
        upper_viscous_pos=bu,
        upper_viscous_neg=bu,
        lower_inertia=jl,
        string_stiffness=kth,
        lower_static=max(tsl, 1e-6),
        lower_viscous=0.0,
        lower_hump_1=0.0,
        lower_hump_2=0.0,
        lower_hump_rate_1=0.0,
        lower_hump_rate_2=0.0,
        name="first-pass",
    )


def _method(name: str, fit: JointFit, scale: tuple[str, float], assumed: bool) -> str:
    if name == scale[0]:
        return "assumed" if assumed else "fixed by the user"
    share = fit.info_constant.get(name, 0.0)
    if name in ("upper_inertia", "lower_inertia", "string_stiffness") or (
        name == "motor_constant" and share < 0.5
    ):
        where = "the cycles of constant-voltage runs" if share >= 0.5 else "the random-level runs"
        return f"dynamic fit (joint equation-error fit; most information from {where})"
    if share >= 0.5:
        return "steady-state friction curve (joint equation-error fit; most information from constant-voltage runs)"
    return "dynamic fit (joint equation-error fit; most information from the random-level runs)"


# a static level of which the fitted curve puts more than this share of its spread below the
# slowest slip of the data is extrapolated: not determined (see _extrapolated_static)
EXTRAPOLATED_SHARE = 0.5
EXTRAPOLATED_MIN = 0.03  # ... and only when that part is this share of T_sl or more
# ... and the hump does half its change below this share of the slowest slip: the change is
# not seen at all (a hump whose change reaches into the data is fixed by its curvature there)
UNSEEN_HALF = 1.0 / 3.0
# ... or, whatever the rate, this share of the spread lies below the slowest slip: the data see
# only the curve's flat tail
TAIL_ONLY_SHARE = 0.9


# the slowest slip below which a lab rig's Stribeck hump does its change [rad/s], and the tanh
# argument below which a hump term is a straight slope over [w0, 2 w0] (tanh(0.5) is 7.6 % below
# its tangent): a lower friction seen only from faster slips, and straight where the data begin,
# has its static level carried down as a line across the slips where a hump would do its change
# (study rigs seen from 0.55, 0.99 and 1.07 rad/s up: T_sl +718 %, +90 %, +395 %, each with an
# interval that excluded the truth); one that bends there fixes its hump by that curvature
STICK_NEAR_RAD_S = 0.4
STRAIGHT_TANH = 0.5


def slip_too_fast(fit: JointFit) -> bool:
    """Whether T_sl is the fitted curve carried down as a line from slips the data show only
    above :data:`STICK_NEAR_RAD_S`: every fitted hump term is straight over the slowest slips
    the data see (``b w0 <= STRAIGHT_TANH``, its tanh over [w0, 2 w0]), so the curve's value at
    zero is that line's, not observed. A hump the data do not reach leaves no trace in them (a
    sharp term below the slowest slip and T_sl trade exactly), so the fit's own interval, which
    holds the curve's form, cannot say so."""
    w0 = fit.slowest_slip
    if not (math.isfinite(w0) and w0 > STICK_NEAR_RAD_S):
        return False
    rates = [
        fit.values[b]
        for a, b in zip(HUMP_AMPLITUDES, HUMP_RATES, strict=True)
        if a in fit.free and fit.values[a] != 0.0 and fit.values[b] > 0.0
    ]
    return all(b * w0 <= STRAIGHT_TANH for b in rates)


def _extrapolated_static(fit: JointFit) -> tuple[float, float, float] | None:
    """How much of the fitted lower friction curve lies below the slowest slip the data show.

    The curve ``C(w) = T_sl + S(w) + b_l w`` is seen from the slowest slip ``w0`` up; its static
    level ``C(0) = T_sl`` is the curve carried down to zero by the hump's form. Returns (the
    change ``C(0) - C(w0)``, the curve's spread over [0, the fastest hump speed], the speed below
    which half the hump's change lies [rad/s]), or None without a hump term or a slowest slip.
    A sharp hump the data only see the tail of gives a change near the spread (the static level
    extrapolated, whatever the fit's interval says); one the data follow down to the stick
    boundary a change near zero."""
    w0 = fit.slowest_slip
    terms = [
        (fit.values[a], fit.values[b])
        for a, b in zip(HUMP_AMPLITUDES, HUMP_RATES, strict=True)
        if a in fit.free and fit.values[a] != 0.0 and fit.values[b] > 0.0
    ]
    if not terms or not math.isfinite(w0):
        return None
    w_end = max(10.0 * w0, *(20.0 / b for _, b in terms))  # where every hump term has saturated
    w = np.concatenate([[0.0], np.geomspace(1e-6 * w_end, w_end, 600)])
    hump = sum(t * np.tanh(0.5 * b * w) for t, b in terms)
    curve = fit.values["lower_static"] + hump + fit.values["lower_viscous"] * w
    at_w0 = fit.values["lower_static"] + sum(t * math.tanh(0.5 * b * w0) for t, b in terms)
    at_w0 += fit.values["lower_viscous"] * w0
    change = float(curve[0] - at_w0)
    spread = float(np.max(curve) - np.min(curve))
    a = np.abs(hump)
    half = float(w[np.argmax(a >= 0.5 * a.max())]) if a.max() > 0 else w0
    return change, spread, half


def static_extrapolated(fit: JointFit) -> bool:
    """Whether the fit's static level T_sl is carried below the data: seen only from fast slips
    (:func:`slip_too_fast`), or by the hump: more than
    :data:`EXTRAPOLATED_SHARE` of the fitted curve's spread lies between zero and the slowest
    slip, that part is :data:`EXTRAPOLATED_MIN` of T_sl or more, and the hump does half its
    change below :data:`UNSEEN_HALF` of the slowest slip (so none of it is seen) or
    :data:`TAIL_ONLY_SHARE` of the spread lies below it (the data see only the flat tail)."""
    if slip_too_fast(fit):
        return True
    ext = _extrapolated_static(fit)
    if ext is None:
        return False
    change, spread, half = ext
    return bool(
        abs(change) > EXTRAPOLATED_SHARE * spread
        and abs(change) > EXTRAPOLATED_MIN * abs(fit.values["lower_static"])
        and (half < UNSEEN_HALF * fit.slowest_slip or abs(change) > TAIL_ONLY_SHARE * spread)
    )


def _results(
    fit: JointFit, scale: tuple[str, float], assumed: bool, structure: str
) -> dict[str, ParameterResult]:
    out: dict[str, ParameterResult] = {}
    ext = _extrapolated_static(fit)
    extrapolated = ""
    if slip_too_fast(fit):
        extrapolated = (
            f"the lower friction is seen only from {fit.slowest_slip:.3g} rad/s up, where the fitted curve "
            f"is straight: the static level {fit.values['lower_static']:.4g} N m is that line carried to "
            f"zero across the slips below {STICK_NEAR_RAD_S:g} rad/s where a hump would do its change, "
            "not observed"
        )
        ramp = (
            "a slow voltage ramp down to the stick boundary (the lower disk slipping slower than "
            f"{STICK_NEAR_RAD_S:g} rad/s; these data: {fit.slowest_slip:.3g} rad/s at the slowest)"
        )
    elif ext is not None:
        change, spread, half = ext
        if static_extrapolated(fit):
            extrapolated = (
                f"the lower friction is seen only down to {fit.slowest_slip:.3g} rad/s: the static level "
                f"{fit.values['lower_static']:.4g} N m is the curve there ({fit.values['lower_static'] - change:.4g} "
                f"N m) carried to zero by the hump ({change:+.4g} N m, {abs(change) / spread:.0%} of the "
                "fitted curve's spread), not observed"
            )
            ramp = (
                f"a slow voltage ramp down to the stick boundary (the lower disk slipping slower than "
                f"{half:.2g} rad/s, where the fitted hump does half its change; these data: "
                f"{fit.slowest_slip:.3g} rad/s at the slowest)"
            )
    for name in IDENTIFIED_PARAMETERS:
        if extrapolated and name in ("lower_static", *HUMP_AMPLITUDES, *HUMP_RATES) and name in fit.free:
            v = fit.values[name]
            sd = fit.sd(name)
            out[name] = ParameterResult(
                name,
                v,
                (v - 1.96 * sd, v + 1.96 * sd),
                "not identifiable from these data" if name in ESSENTIAL else "not determined by these data",
                False,
                extrapolated
                if name == "lower_static"
                else f"tied to T_sl, which is extrapolated: {extrapolated}",
                ramp,
            )
            continue
        v = fit.values[name]
        if name == scale[0]:
            note = "the paper's string stiffness: give --known to fix this rig's own" if assumed else ""
            out[name] = ParameterResult(
                name, v, (v, v), "assumed" if assumed else "fixed by the user", not assumed, note
            )
            continue
        if name not in fit.free:
            if name in ("upper_static_neg", "upper_viscous_neg"):
                pos = name.replace("_neg", "_pos")
                out[name] = ParameterResult(
                    name,
                    v,
                    (math.nan, math.nan),
                    "not identifiable from these data",
                    False,
                    f"the upper disk never turned backwards: set equal to {pos} (a symmetric friction assumed)",
                    RUN_THAT_IDENTIFIES[name],
                )
            else:  # a hump term the curve does not need
                # not an identified zero: the data cannot tell this term from none (a hump that
                # saturates below the slowest slip seen, or one the viscous slope absorbs over
                # the speeds seen), so it has no interval and is not marked identified
                out[name] = ParameterResult(
                    name,
                    0.0,
                    (math.nan, math.nan),
                    "not needed by the data (no hump term)",
                    False,
                    f"the lower friction curve needs {fit.hump_terms} hump term(s): adding this one does not "
                    "lower the equation error significantly; set to 0, its value not determined",
                    RUN_THAT_IDENTIFIES[name],
                )
            continue
        sd = fit.sd(name)
        lo, hi = v - 1.96 * sd, v + 1.96 * sd
        if name not in HUMP_AMPLITUDES:
            lo = max(lo, 0.0)
        # identifiable: the runs excite it (a misfit, e.g. a missing effect, widens the interval
        # but is named in the report, not taken for a lack of excitation)
        limit = MAX_RELATIVE_HALF_WIDTH if name in ESSENTIAL else NOT_DETERMINED_HALF_WIDTH
        identified = 1.96 * fit.sd_excited(name) <= limit * abs(v)
        note = needs = ""
        if name not in ESSENTIAL:
            # a term the model can run without: an interval wider than the limit (whatever widened
            # it: the runs' spread, correlated windows) leaves it not determined
            identified = identified and 1.96 * sd <= limit * abs(v)
        alt = fit.alternatives.get(name)
        if alt is not None:
            # another friction curve fits the data as well: the interval spans its value too, and a
            # value the curves disagree on by more than the limit is not determined
            lo, hi = min(lo, alt[0]), max(hi, alt[1])
            if max(v - alt[0], alt[1] - v) > limit * abs(v):
                identified = False
                note = (
                    f"another lower friction curve fits these data as well with {name} from "
                    f"{alt[0]:.4g} to {alt[1]:.4g}"
                )
        if not identified:
            needs = RUN_THAT_IDENTIFIES[name]
            if name in HUMP_AMPLITUDES + HUMP_RATES + ("lower_viscous",):
                note = "; ".join(
                    x
                    for x in (
                        note,
                        "the friction curve is fixed better than this term of it: the hump terms and the "
                        "viscous slope trade off over the speeds in the data",
                    )
                    if x
                )
        out[name] = ParameterResult(
            name,
            v,
            (lo, hi),
            _method(name, fit, scale, assumed)
            if identified
            else (
                "not identifiable from these data" if name in ESSENTIAL else "not determined by these data"
            ),
            identified,
            note,
            needs,
        )
    t_sl = out["lower_static"]
    if not t_sl.identified:
        # a hump's amplitude is the static level less the kinetic one (T_sl - T and a hump of T
        # trade over the windows the data have), and its rate sets where between them: neither
        # is determined when the static level is not
        for name in HUMP_AMPLITUDES + HUMP_RATES:
            p = out[name]
            if p.identified:
                out[name] = dataclasses.replace(
                    p,
                    method="not determined by these data",
                    identified=False,
                    note=f"tied to T_sl, which these data do not determine ({t_sl.note or t_sl.method})",
                    needs=t_sl.needs,
                )
    return out


def identify(
    dataset: MeasuredDataset,
    *,
    structure: str | None = None,
    known: Mapping[str, float] | None = None,
    heldout: list[str] | None = None,
    simulate_heldout: bool = True,
    progress: Callable[[str, int, int], None] | None = None,
    effects: Mapping[str, float | None] | None = None,
    keep_fitted: bool = False,
) -> Identification:
    """Identify every parameter of the rig model from ``dataset`` (see the module docstring).

    Args:
        dataset: a loaded dataset (:func:`drill_env.recordings.dataset.load_dataset`).
        structure: ``brake`` or ``no_brake`` (default: the dataset's ``preset``); names the
            identified rig and, without ``known``, which preset's string stiffness is assumed.
        known: at most one of ``{"string_stiffness": k}`` [N m/rad] or ``{"motor_constant": k_m}``
            [N m/V]: the scale the data cannot fix.
        heldout: run names kept out of the fit for validation (default: every third run by
            voltage, as ``drill-env discrepancy``; none with fewer than four runs).
        effects: library effects (:mod:`drill_env.recordings.effects` names) fitted jointly with
            every base parameter (:mod:`.effect_fit`): name -> the first estimate of a lag
            effect's time constant [s] (profiled about it), None for the others.
        keep_fitted: keep the fitted model beside a fit refused for T_sl alone even when T_sl is
            not extrapolated but loose (:attr:`Identification.provisional`): the structure
            search's re-fit with an effect, whose tests run at the slips the data cover.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    structure = structure or dataset.preset
    if structure not in available_presets():
        raise ValueError(f"structure: {structure!r}; allowed: {available_presets()}")
    known = dict(known or {})
    bad = sorted(set(known) - set(SCALE_PARAMETERS))
    if bad or len(known) > 1:
        raise ValueError(f"known: {sorted(known)}; allowed: one of {list(SCALE_PARAMETERS)}")
    for k, v in known.items():
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"known: {k} = {v!r}; allowed: a finite number > 0")
    if known:
        scale = next(iter(known.items()))
        scale = (scale[0], float(scale[1]))
        assumed = False
    else:
        scale = ("string_stiffness", float(load_params(structure).string_stiffness))
        assumed = True
    train, held = _split(dataset.runs, heldout)

    states = steady_states(dataset.runs, dataset.encoder_step)
    balance = upper_balance(states, scale, 1)
    freq = oscillation_frequency(dataset.runs, states)
    timings["steady_states"] = time.perf_counter() - t0

    noise = estimate_angle_noise(dataset.runs, dataset.encoder_step)
    p0 = _initial(scale, balance, states, freq)
    eqs: dict[str, RunEquations] = {}
    rows: dict[str, Any] = {}
    effects = dict(effects or {})
    lags = {n: t for n, t in effects.items() if n in LAG_EFFECTS}
    lag_ci: dict[str, tuple[float, float]] = {}
    profiles: dict[str, dict[float, float]] = {}

    def rows_of(eq: RunEquations, at: Mapping[str, float] | None = None):
        return effect_rows(eq, effects, at) if effects else run_rows(eq)

    def fit_pass(pass_: int, previous: JointFit | None) -> JointFit:
        t1 = time.perf_counter()
        weights_at = p0 if previous is None else _weights_params(previous, p0)
        # the first pass only finds the parameters the second weights its windows at: a cheap
        # noise model (16 harmonics of the quantisation error, the count rate over one support)
        # does; the windows are the same
        config = FIRST_PASS_NOISE if previous is None else None
        for i, r in enumerate(dataset.runs):
            eqs[r.name] = RunEquations(r, weights_at, noise, config)
            rows[r.name] = rows_of(eqs[r.name])
            if progress:
                progress(f"equation error, pass {pass_}", i + 1, len(dataset.runs))
        if sum(len(x.sigma) for x in rows.values()) < 20:
            raise ValueError(
                f"{dataset.path or 'dataset'}: fewer than 20 windows in which a disk turns one way; the rig "
                "barely moved in these runs. Record on the plan of `drill-env identify --plan`"
            )
        fit = joint_fit([rows[r.name] for r in dataset.runs], scale)
        at_eqs = dict(eqs)  # the equations with the effects' columns at the latest fit
        built_at: dict[str, float] | None = None  # the fit whose effect coefficients the rows hold

        for _ in range(EFFECT_ITERATIONS if (previous is not None and effects) else 0):
            # an effect that scales a friction level (position, drift, heating) has columns that
            # depend on the base parameters, and a position modulation's rows the coefficients of
            # the fit before (a Gauss-Newton step, see effect_rows): re-evaluate them at this
            # fit's until it settles
            built_at = fit.values
            at = _weights_params(fit, weights_at)
            for r in dataset.runs:
                moved = copy.copy(eqs[r.name])
                moved.params = at
                at_eqs[r.name] = moved
                rows[r.name] = rows_of(moved, built_at)
            again = joint_fit([rows[r.name] for r in dataset.runs], scale)
            change = max(
                abs(again.values[n] - fit.values[n]) / max(abs(fit.values[n]), 1e-12)
                for n in IDENTIFIED_PARAMETERS
            )
            fit = again
            if change < 1e-4:
                break
        for name in lags if previous is not None else ():
            # the lag's time constant: the profile of the joint fit about its estimate
            cand_bounds = (1e-4, 5.0)

            # the rates move little with the lag: each fit of the profile refines from this one's
            warm = tuple(fit.values[r] for r in HUMP_RATES[: fit.hump_terms]) or None

            def fit_at(tau: float, name: str = name, terms: int = fit.hump_terms, warm=warm) -> JointFit:
                effects[name] = tau
                return joint_fit(
                    [rows_of(at_eqs[r.name], built_at) for r in dataset.runs],
                    scale,
                    hump_terms=terms,
                    warm_rates=warm,
                )

            first = effects[name]
            assert first is not None
            tau, _, lag_ci[name], profiles[name] = lag_profile(fit_at, first, cand_bounds)
            effects[name] = tau
            for r in dataset.runs:
                rows[r.name] = rows_of(at_eqs[r.name], built_at)
            fit = joint_fit([rows[r.name] for r in dataset.runs], scale)
        timings[f"pass_{pass_}"] = time.perf_counter() - t1
        return fit

    fit = fit_pass(2, fit_pass(1, None))
    parameters = _results(fit, scale, assumed, structure)
    t1 = time.perf_counter()
    train_fit = joint_fit([rows[n] for n in train], scale, hump_terms=fit.hump_terms) if held else None
    timings["train_fit"] = time.perf_counter() - t1
    desc = (
        f"{structure} rig identified from {dataset.path.name if dataset.path else 'measured data'} "
        f"({len(dataset.runs)} runs) by drill-env identify; scale: {scale[0]} = {scale[1]:g}"
        + (" (assumed, the paper's)" if assumed else " (given)")
    )
    blocking = [
        p for p in parameters.values() if not p.identified and p.name in ESSENTIAL and p.name != scale[0]
    ]
    found = effect_results(fit, effects, lag_ci) if effects else {}
    if found:
        desc += "; with " + ", ".join(found) + " (fitted jointly)"
    params = None
    invalid = ""
    if not blocking:
        try:
            params = _with_effects(
                fitted_params(fit, name=f"{structure}-identified", description=desc), found
            )
        except ParameterError as exc:
            params, invalid = None, str(exc)
    provisional = None
    if (
        params is None
        and [p.name for p in blocking] == ["lower_static"]
        and (static_extrapolated(fit) or keep_fitted)
    ):
        # refused only for an extrapolated (or, asked for, a loose) T_sl: the model as fitted,
        # for the structure tests at the slips the data cover (not offered as the rig)
        try:
            provisional = _with_effects(
                fitted_params(
                    fit,
                    name=f"{structure}-fitted-refused",
                    description=desc + "; T_sl not determined by the data: not a rig",
                ),
                found,
            )
        except ParameterError:
            provisional = None
    if params is None:
        parameters = _refused(parameters, blocking, invalid, scale)
    train_params = None
    if train_fit is not None and params is not None:
        try:
            train_found = effect_results(train_fit, effects, lag_ci) if effects else {}
            train_params = _with_effects(
                fitted_params(train_fit, name=f"{structure}-identified-train", description=desc), train_found
            )
        except ParameterError:
            train_params = None
    measurement = _measurement(found)
    ident = Identification(
        dataset=dataset,
        structure=structure,
        scale=scale,
        scale_assumed=assumed,
        states=states,
        balance=balance,
        fit=fit,
        train_fit=train_fit,
        parameters=parameters,
        params=params,
        train_params=train_params,
        train_runs=train,
        heldout_runs=held,
        equations=eqs,
        rows=rows,
        oscillation_hz=freq,
        timings=timings,
        effects=found,
        lag_profiles=profiles,
        measurement=measurement,
        invalid=invalid,
        provisional=provisional,
    )
    if simulate_heldout and held and train_params is not None:
        from drill_env.recordings.compare import compare_run

        t1 = time.perf_counter()
        cache: dict = {}
        for i, name in enumerate(held):
            ident.heldout[name] = compare_run(
                train_params,
                eqs[name],
                dataset.encoder_counts_per_rev,
                measured_cache=cache,
                measurement=measurement,
            )
            if progress:
                progress("simulate held-out runs", i + 1, len(held))
        timings["heldout"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0
    return ident


REFUSED_METHOD = "fitted beside a refused parameter"


def refusal_reason(blocking: list[ParameterResult], invalid: str) -> str:
    """Why a fit was refused, in the words every parameter fitted beside the refusal carries."""
    if blocking:
        return "the fit was refused (" + ", ".join(f"{p.name} not determined" for p in blocking) + ")"
    return f"the fit was refused (the fitted parameters make no valid rig: {invalid or 'outside the range'})"


def _refused(
    parameters: dict[str, ParameterResult],
    blocking: list[ParameterResult],
    invalid: str,
    scale: tuple[str, float],
) -> dict[str, ParameterResult]:
    """The parameters of a refused fit: none is marked identified (the user's scale aside).

    A parameter the data do not fix, fitted jointly with the others, moves them as far as it is
    off (an inertia at -51 % beside a T_sl the data never saw): their own intervals do not say
    so, since they hold the refused parameter at its fitted value. Each keeps its value and
    interval, for a look, with the refusal as its note and the runs that determine the refused
    parameters as what would identify it."""
    why = refusal_reason(blocking, invalid)
    if blocking:
        needs = "; ".join(dict.fromkeys(p.needs for p in blocking if p.needs))
    else:
        needs = "runs that excite the rig more widely (drill-env identify --plan)"
    out = dict(parameters)
    for name, p in parameters.items():
        if p.identified and name != scale[0]:
            out[name] = dataclasses.replace(
                p,
                method=REFUSED_METHOD,
                identified=False,
                note=f"{why}: a value fitted beside a parameter the data do not fix is not trusted",
                needs=needs or RUN_THAT_IDENTIFIES.get(name, ""),
            )
    return out


def _with_effects(params: RigParams, found: Mapping[str, EffectResult]) -> RigParams:
    """``params`` with the physical effects of ``found`` switched on (ParameterError when the
    fitted values are not physical)."""
    fields_: dict[str, float] = {}
    for e in found.values():
        if e.admissible is not None:
            raise ParameterError(f"{e.name}: {e.admissible}")
        if e.kind == "physical":
            fields_.update(e.model_fields)
    return params.replace(**fields_) if fields_ else params


def _measurement(found: Mapping[str, EffectResult]):
    """The measurement model of the fitted encoder eccentricities (None: none fitted)."""
    fields_: dict[str, float] = {}
    for e in found.values():
        if e.kind == "measurement":
            fields_.update(e.model_fields)
    if not fields_:
        return None
    from drill_env.measurement import MeasurementModel

    return MeasurementModel(**fields_)


def _weights_params(fit: JointFit, fallback: RigParams) -> RigParams:
    """The first fit as parameters for the second pass's noise weights (the first values where
    the fit left the valid range)."""
    values = {n: fit.values[n] for n in IDENTIFIED_PARAMETERS}
    for n in ("motor_constant", "upper_inertia", "lower_inertia", "string_stiffness"):
        if not values[n] > 0:
            values[n] = getattr(fallback, n)
    try:  # values holds the numeric fields; the rest by name
        return RigParams(**values, effects=ModelEffects(), name="first-fit", description="")
    except ParameterError:
        values.update({h: 0.0 for h in HUMP_AMPLITUDES})
        try:
            return RigParams(**values, effects=ModelEffects(), name="first-fit", description="")
        except ParameterError:
            return fallback
