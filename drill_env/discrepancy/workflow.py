"""The model-discrepancy workflow on a measured dataset: where, calibrate, which, decide, add and show.

:func:`run_discrepancy` loads a dataset folder, computes the nominal model's equation
error and sensor-space gaps on every run (*where*), refits the identified parameters on
the training runs (*calibrate*, :mod:`~drill_env.discrepancy.calibrate`), recomputes the
equation error at the recalibrated parameters, fits and scores the candidate library as
additions to the recalibrated model on training and held-out runs (*which*, *decide*),
checks in sensor space that a named effect makes the held-out runs no worse anywhere,
writes the chosen model (recalibrated parameters, plus the effect if one is named) as a
rig YAML under the output folder, re-simulates the held-out runs with it and writes
``result.json``, ``report.md`` and the figures (*add and show*). It never reads
anything but the dataset folder.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from drill_env.discrepancy.calibrate import (
    CalibrationRule,
    ParameterFit,
    calibrated_params,
    calibration_statistics,
    identify,
    prior_precision,
)
from drill_env.discrepancy.parameter_selection import (
    final_parameters,
    first_calibration,
    moved_fit,
    recalibrated_equations,
)
from drill_env.discrepancy.scoring import CalibrationSetup, DecisionRule, run_statistics
from drill_env.discrepancy.sensor_effects import rotation_explanations
from drill_env.discrepancy.spectral_lines import LineScan, LineSignature, line_scan, line_signature
from drill_env.discrepancy.timing import VoltageLag, shift_voltage, voltage_lag_scan
from drill_env.discrepancy.verdict import (
    NOT_AN_EFFECT,
    Decision,
    decide,
    demote,
    readings_gain,
    second_effect,
    sensor_worse,
)
from drill_env.measurement import MeasurementModel, write_model_yaml
from drill_env.outputs import atomic_write_text, output_lock
from drill_env.params import ParameterError, RigParams, load_params, validity_warnings
from drill_env.recordings.compare import CompareConfig, RunComparison, aggregate, compare_run
from drill_env.recordings.dataset import DatasetError, MeasuredDataset, load_dataset
from drill_env.recordings.effects import CANDIDATES, EFFECT_FIELDS, model_effect_names, with_model_effects
from drill_env.recordings.equation_error import (
    AngleNoise,
    EquationErrorConfig,
    RunEquations,
    estimate_angle_noise,
)
from drill_env.recordings.split import split_runs

__all__ = ["DiscrepancyResult", "analyse", "run_discrepancy", "RESULT_EFFECTS"]

RESULT_EFFECTS = tuple(c.name for c in CANDIDATES) + NOT_AN_EFFECT


@dataclass
class DiscrepancyResult:
    dataset: MeasuredDataset
    params: RigParams
    noise: AngleNoise
    equations: list[RunEquations]
    decision: Decision
    line: LineScan
    corrected: RigParams | None  # the chosen model when it differs from the nominal one
    first_pass: list[ParameterFit]  # the calibration on the nominal model's equation error
    sensor_check: dict[str, Any]  # a named effect against the recalibrated model, held-out runs
    effects: list[str]  # every named effect, strongest first
    second: dict[str, Any]  # the greedy search for a second effect
    where: list[dict[str, Any]]
    nominal: dict[str, RunComparison]
    after: dict[str, RunComparison]
    gap_before: dict[str, float]
    gap_after: dict[str, float]
    timings: dict[str, float]
    signature: LineSignature | None = None  # what an unexplained line is locked to
    # the chosen model against the nominal one in sensor space, held-out runs (see model_check)
    model_check: dict[str, Any] = dataclasses.field(default_factory=dict)
    # the chosen model's measurement model: a named encoder eccentricity (None: exact readings)
    measurement: MeasurementModel | None = None
    # the voltage column's timing against the angles (a recording issue, see timing.py)
    voltage_lag: VoltageLag | None = None
    # runs in which neither disk turns (stuck throughout): left out of every comparison, with why
    left_out: dict[str, str] = dataclasses.field(default_factory=dict)

    @property
    def model_rejected(self) -> bool:
        """The chosen model is worse than the nominal one somewhere on the held-out runs beyond
        the noise: it is not written as the result (``model_rejected.yaml`` instead)."""
        return bool(self.model_check.get("worse"))

    @property
    def effect(self) -> str:
        return self.decision.effect

    @property
    def max_lower_speed(self) -> float:
        """The largest |lower-disk speed| in the data [rad/s]: the encoder angle turned over
        0.1 s windows, so that one count of quantisation moves it by little."""
        top = 0.0
        for run in self.dataset.runs:
            dt = float(run.t[1] - run.t[0]) if run.t.size > 1 else 0.0
            k = max(1, int(round(0.1 / dt))) if dt > 0 else 0
            if k == 0 or run.theta_l.size <= k:
                continue
            top = max(top, float(np.max(np.abs(run.theta_l[k:] - run.theta_l[:-k]))) / (k * dt))
        return top

    @property
    def validity_warnings(self) -> list[str]:
        """Where the data leave the range the preset's model was identified on (the loader
        already refuses voltages beyond the rig's +-5 V): one sentence each."""
        notes = validity_warnings(self.params.name, max_speed=self.max_lower_speed)
        if self.left_out:
            notes = notes + [
                f"{len(self.left_out)} run(s) left out of the comparison: "
                + "; ".join(self.left_out.values())
            ]
        return notes

    def result_json(self) -> dict[str, Any]:
        d = self.decision
        params = d.winner.parameters if (d.winner is not None and d.effect == d.winner.name) else {}
        return {
            "effect": d.effect,
            "confidence": d.confidence,
            "parameters": params,
            "effects": list(self.effects),
            "recalibrated": {f.name: f.as_dict() for f in d.recalibrated},
            "model_written": self.corrected is not None and not self.model_rejected,
            "measurement": self.measurement.to_dict() if self.measurement is not None else {},
            "model_check": self.model_check,
            "left_out": dict(self.left_out),
            "voltage_lag": {
                "found": bool(self.voltage_lag is not None and self.voltage_lag.found),
                "samples": self.voltage_lag.lag if self.voltage_lag is not None else 0,
                "seconds": self.voltage_lag.lag * self.voltage_lag.dt
                if self.voltage_lag is not None
                else 0.0,
                "applied_samples": int(self.dataset.meta.get("voltage_lag_samples", 0)),
                "scan": self.voltage_lag.as_dict() if self.voltage_lag is not None else None,
            },
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "heldout_runs": d.heldout_runs,
            "evidence": {
                "reason": d.reason,
                "train_runs": d.train_runs,
                "candidates": [s.as_dict() for s in d.scores],
                "excess": d.excess,
                "structure": d.structure,
                "spectral_line": {
                    **self.line.as_dict(),
                    "signature": self.signature.as_dict() if self.signature is not None else None,
                },
                "bootstrap_verdicts": d.bootstrap_counts,
                "calibration": {
                    "fixed_scale": {"string_stiffness": self.params.string_stiffness},
                    "first_pass_moved": [f.name for f in self.first_pass if f.moved],
                    "parameters": [
                        {
                            "name": f.name,
                            "nominal": f.nominal,
                            "value": f.value,
                            "sd": f.sd,
                            "identified": f.identified,
                            "moved": f.moved,
                            "ci95": list(f.ci95) if f.moved else None,
                            "interval_excludes_nominal": f.excludes_nominal if f.moved else False,
                            "out_of_prior": f.out_of_prior,
                        }
                        for f in d.parameters
                    ],
                },
                "sensor_check": self.sensor_check,
                "second_effect": self.second,
                "angle_noise": self.noise.as_dict(),
                "where": self.where,
                "preset": self.dataset.preset,
                "encoder_counts_per_rev": self.dataset.encoder_counts_per_rev,
                "max_lower_speed_rad_s": self.max_lower_speed,
                "validity_warnings": self.validity_warnings,
                "timings_s": self.timings,
            },
        }

    def verdict_line(self) -> str:
        line = self._verdict_line()
        if self.voltage_lag is not None and self.voltage_lag.found:
            line += "; " + self.voltage_lag.describe()  # a recording issue, not the rig's physics
        far = [f for f in self.decision.recalibrated if f.out_of_prior]
        if far:
            line += "; OUT OF PRIOR: " + ", ".join(
                f"{f.name} {f.value / f.nominal - 1.0:+.1%} (beyond +-{f.prior_sd / abs(f.nominal):.0%})"
                for f in far
            )
            line += " -- other causes give the same data (see the report)"
        if self.model_rejected:
            line += (
                "; MODEL NOT WRITTEN: the chosen model makes "
                + ", ".join(self.model_check["worse"])
                + " worse than the nominal model on the held-out runs (kept as model_rejected.yaml)"
            )
        return line

    def _verdict_line(self) -> str:
        d = self.decision
        # "moved" is what the interval resolves; the others were refitted with them (the model
        # holds their values) but their intervals hold the nominal
        resolved = [f for f in d.recalibrated if f.excludes_nominal]
        within = [f.name for f in d.recalibrated if not f.excludes_nominal]
        moved = ", ".join(f"{f.name} {f.value / f.nominal - 1.0:+.1%}" for f in resolved)
        if within:
            what = f"refitted, within their intervals: {', '.join(within)}"
            moved = f"{moved} ({what})" if moved else what
        cal = f"; recalibrated: {moved}" if moved else ""
        timing = self.voltage_lag is not None and self.voltage_lag.found
        if d.effect in ("none", "unexplained"):
            extra = ""
            if d.effect == "unexplained" and timing:
                extra = "; the residual follows the voltage steps: a recording issue (RECORDING below), not the rig"
            elif d.effect == "unexplained" and self.signature is not None:
                extra = f"; signature: {self.signature.summary()}"
            elif d.effect == "unexplained" and self.line.significant:
                rel = "locked to rotation" if self.line.related_to_rotation else "unrelated to rotation"
                extra = f"; signature: line at {self.line.frequency_hz:.3g} Hz common to all runs, {rel}"
            return f"verdict: {d.effect} (confidence {d.confidence:.2f}): {d.reason}{extra}{cal}"
        if d.effect == "recalibrated":
            return f"verdict: recalibrated (confidence {d.confidence:.2f}): {moved}"
        par = ", ".join(f"{k}={v:.4g}" for k, v in d.named_winner.parameters.items())
        plus = ""
        if len(self.effects) > 1:
            par2 = ", ".join(f"{k}={v:.4g}" for k, v in self.second["parameters"].items())
            plus = f"; plus {self.effects[1]} ({par2})"
        sensor = ""
        if self.measurement is not None:
            sensor = (
                f"; a sensor effect, no torque: the {' and '.join(self.measurement.active)} encoder reads "
                "wrong once per revolution (look at its mounting)"
            )
        return f"verdict: {d.effect} (confidence {d.confidence:.2f}; {par}){plus}{sensor}{cal}"


def _where_table(eqs: list[RunEquations], nominal: dict[str, RunComparison], rule: DecisionRule):
    rows = []
    for eq in eqs:
        c = nominal.get(eq.run.name)
        row: dict[str, Any] = {"run": eq.run.name, "label": eq.run.label}
        for w in (eq.upper, eq.lower):
            n = len(w)
            ss = float(np.sum(w.z**2)) if n else float("nan")
            row[f"{w.disk}_windows"] = n
            row[f"{w.disk}_ss_per_window"] = ss / n if n else float("nan")
            row[f"{w.disk}_disagrees"] = bool(
                n > 0 and ss > n * (1 + rule.floor_tolerance) + rule.excess_z * math.sqrt(2 * n)
            )
            row[f"{w.disk}_rms_residual_nm"] = float(np.sqrt(np.mean(w.residual**2))) if n else float("nan")
            row[f"{w.disk}_noise_floor_nm"] = float(np.sqrt(np.mean(w.sigma**2))) if n else float("nan")
        if c is not None:
            row.update(c.summary())
            row["short_horizon_angle_over_floor"] = c.short_angle_rms / max(c.floors["angle_rad"], 1e-12)
            row["short_horizon_speed_over_floor"] = c.short_speed_rms / max(c.floors["speed_rad_s"], 1e-12)
        rows.append(row)
    return rows


def _second_parameters(decision: Decision, second: dict[str, Any]) -> None:
    """With two effects, the parameters and the first effect's coefficients are those refitted
    jointly with both."""
    fits = second.get("parameter_fits")
    if fits:
        decision.parameters = fits
    if second.get("first_parameters") and decision.winner is not None:
        decision.winner = dataclasses.replace(decision.winner, parameters=dict(second["first_parameters"]))


def _candidate(name: str):
    """The library candidate named ``name``."""
    return next(c for c in CANDIDATES if c.name == name)


def _with_second(model: RigParams, second: dict[str, Any]) -> RigParams:
    cand = _candidate(second["named"])
    if cand.kind == "measurement":  # the plant is unchanged: see _measurement
        return model.replace(
            name=f"{model.name}+{cand.name}",
            description=f"{model.description}; plus {cand.title} (in its measurement section)",
        )
    return model.replace(**cand.to_model_effects(second["parameters"])).replace(
        name=f"{model.name}+{cand.name}", description=f"{model.description}; plus {cand.title}"
    )


def _measurement(decision: Decision, second: dict[str, Any] | None = None) -> MeasurementModel | None:
    """The measurement model of a decision: the reading errors of the named measurement effects
    (the first, and the second when ``second`` names one); None when neither is one."""
    fields_: dict[str, float] = {}
    named = []
    if decision.named:
        named.append((decision.effect, decision.named_winner.parameters))
    if second and second.get("named"):
        named.append((second["named"], second["parameters"]))
    for name, par in named:
        cand = _candidate(name)
        if cand.kind == "measurement":
            fields_.update(cand.to_model_effects(par))
    return MeasurementModel(**fields_) if fields_ else None


def still_runs(dataset: MeasuredDataset, eqs: list[RunEquations]) -> dict[str, str]:
    """The runs in which neither disk ever turns (0 V, or a voltage below the break-away: stuck
    throughout), each with why it holds nothing to compare: no equation-error window. A
    dataset of such runs alone is refused in one line (:class:`DatasetError`); where others turn,
    the still runs are left out of the comparison and named in the report (they still tell the
    stick boundary to ``drill-env identify``)."""
    still = [eq for eq in eqs if len(eq.upper) == 0 and len(eq.lower) == 0]
    if not still:
        return {}
    eq0 = still[0]
    window = eq0.stride * eq0.dt
    vmin = eq0.config.min_speed_rad_s

    def turned(eq: RunEquations) -> str:
        counts = max(float(np.ptp(eq.run.theta_u)), float(np.ptp(eq.run.theta_l))) / dataset.encoder_step
        return f"turns {counts:.0f} encoder counts at most"

    lack = (
        f"neither disk turns one way at {vmin:g} rad/s or more for a whole {window:.2g} s window (stuck "
        "throughout), so they hold nothing to compare with the model"
    )
    if len(still) == len(eqs):
        named = ", ".join(f"{eq.run.label} {turned(eq)}" for eq in still[:6]) + (
            f" and {len(still) - 6} more" if len(still) > 6 else ""
        )
        where = f"dataset {dataset.path}" if dataset.path is not None else "dataset"
        raise DatasetError(
            f"{where}: no run in which the rig turns ({named}): {lack}; record runs at voltages that "
            "turn the rig (above its break-away voltage)"
        )
    return {eq.run.name: f"{eq.run.label}: stuck throughout, {turned(eq)}" for eq in still}


def _recalibration_harms(nominal: dict, recalibrated: dict, held: list[str], moved: int) -> bool:
    """Whether the recalibrated model's held-out sum of squares exceeds the given model's by more
    than the test a recalibration must pass to be confirmed (one degree of freedom per moved
    parameter): a refit that predicts the held-out runs significantly worse is not taken."""
    if not moved:
        return False
    n_h = sum(nominal[h].n for h in held)
    loss = sum(recalibrated[h].ztz for h in held) - sum(nominal[h].ztz for h in held)
    return loss > max(float(chi2.isf(1e-3, moved)), moved * math.log(max(n_h, 2)))


def analyse(
    dataset: MeasuredDataset,
    *,
    heldout: list[str] | None = None,
    rule: DecisionRule | None = None,
    eq_config: EquationErrorConfig | None = None,
    compare_config: CompareConfig | None = None,
    calibration_rule: CalibrationRule | None = None,
    calibrate: bool = True,
    simulate_gaps: bool = True,
    seed: int = 0,
    progress: Callable[[str, int, int], None] | None = None,
    params: RigParams | None = None,
    simulate_training_runs: bool = True,
) -> DiscrepancyResult:
    """Run the whole workflow in memory (no files); see :func:`run_discrepancy`.

    ``calibrate=False`` scores the effects as additions to the nominal model (the
    parameters are taken as exact). ``params`` is the nominal model (default: the preset
    named by the dataset), e.g. a rig identified by ``drill-env identify``; its effects, if
    any, are part of it. ``simulate_training_runs=False`` simulates the nominal model on the
    held-out runs only (all the decision uses; the training runs' sensor-space gaps are left
    out of the where table)."""
    rule = rule or DecisionRule()
    cal_rule = calibration_rule or CalibrationRule()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    params = load_params(dataset.preset) if params is None else params
    noise = estimate_angle_noise(dataset.runs, dataset.encoder_step, eq_config)
    eqs = []
    stats = {}
    # the nominal model's own library effects are part of it: their torques leave the
    # residual, and they are not candidates again (the tests look for what is still missing)
    known, outside = model_effect_names(params)
    if outside:
        raise ValueError(
            f"params: switches on {', '.join(outside)}, an effect outside the library; the nominal "
            "model may hold library effects only (allowed: "
            + ", ".join(sorted({k for ks in EFFECT_FIELDS.values() for k in ks}))
            + ")"
        )
    candidates = tuple(c for c in CANDIDATES if c.name not in known)
    for i, r in enumerate(dataset.runs):
        eq = with_model_effects(RunEquations(r, params, noise, eq_config))
        eqs.append(eq)
        stats[r.name] = run_statistics(eq)
        if progress:
            progress("equation error", i + 1, len(dataset.runs))
    timings["equation_error"] = time.perf_counter() - t0
    left_out = still_runs(dataset, eqs)
    if left_out:
        if heldout is not None:  # a stuck held-out run is left out as well, not compared
            turning_heldout = [h for h in heldout if h not in left_out]
            if heldout and not turning_heldout:
                raise ValueError(
                    f"heldout: {', '.join(heldout)} never turn(s) (stuck throughout): nothing to compare "
                    "there; hold out runs in which the rig turns"
                )
            heldout = turning_heldout
        dataset = dataclasses.replace(dataset, runs=tuple(r for r in dataset.runs if r.name not in left_out))
        eqs = [eq for eq in eqs if eq.run.name not in left_out]
        stats = {n: v for n, v in stats.items() if n not in left_out}
    if heldout is None:
        train, held = split_runs(dataset.runs)
    else:
        names = [r.name for r in dataset.runs]
        unknown = [h for h in heldout if h not in names]
        if unknown:
            raise ValueError(f"heldout: unknown run(s) {unknown}; runs: {names}")
        held = list(heldout)
        train = [n for n in names if n not in held]
        if not train or not held:
            raise ValueError("heldout: needs at least one training run and one held-out run")
    # calibrate: refit the identified parameters, then recompute the equation error there
    t1 = time.perf_counter()
    first_pass: list[ParameterFit] = []
    setup = None
    eqs_cal, stats_cal, base = eqs, stats, params
    if calibrate:
        cal_stats = {eq.run.name: calibration_statistics(eq, CANDIDATES) for eq in eqs}
        free, _, _ = identify([cal_stats[n] for n in train], params, cal_rule)
        setup0 = CalibrationSetup(
            stats=cal_stats,
            free=free,
            prior=prior_precision(params, cal_rule),
            nominal_ztz={},
            moved=[],
            nominal=params,
            base=params,
            rule=cal_rule,
        )
        moved, first_winner = first_calibration(stats, train, held, setup0, rule=rule, candidates=candidates)
        cand = next((c for c in CANDIDATES if c.name == first_winner), None)
        tr0 = [stats[n] for n in train]
        ho0 = [stats[n] for n in held]
        fit0, _, cal0 = moved_fit(dataclasses.replace(setup0, moved=moved), tr0, ho0, rule, cand)
        first_pass = final_parameters(cal0, fit0, identified=free, moved_all=True)
        try:
            base = calibrated_params(params, first_pass)
        except ParameterError:
            # the refit left the rig's valid range (e.g. a friction that is not dissipative):
            # keep the nominal parameters rather than explain with an impossible model
            first_pass, moved, base = [], [], params
        if base is not params:
            eqs_cal, stats_cal = [], {}
            for i, r in enumerate(dataset.runs):
                eq = with_model_effects(RunEquations(r, base, noise, eq_config))
                eqs_cal.append(eq)
                stats_cal[r.name] = run_statistics(eq)
                if progress:
                    progress("equation error, recalibrated", i + 1, len(dataset.runs))
            cal_stats = {eq.run.name: calibration_statistics(eq, CANDIDATES) for eq in eqs_cal}
            if (cand is None or not cand.is_lag) and _recalibration_harms(stats, stats_cal, held, len(moved)):
                # refitted on the training runs alone, the parameters predict the held-out runs worse
                # than the model given (a change the training runs do not pin, extrapolated): the
                # model given is the one tested, as without a recalibration. Not beside a lag: its
                # time constant trades with the inertia refitted with it, and profiled against the
                # model given a hidden motor lag of 20 ms was found at 8 ms
                first_pass, moved, base = [], [], params
                eqs_cal, stats_cal = eqs, stats
                cal_stats = setup0.stats
        setup = dataclasses.replace(
            setup0,
            stats=cal_stats,
            nominal_ztz={n: s.ztz for n, s in stats.items()},
            moved=moved,
            base=base,
        )
    timings["calibrate"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    # the residual once the parameters are right: a line (and its signature) is scanned there
    eqs_line = recalibrated_equations(eqs_cal, stats_cal, train, held, setup, rule)
    line = line_scan(eqs_line, rule)
    # the timing on the nominal model's residual: a recalibration absorbs part of the pulses a
    # mistimed voltage leaves at each step, and re-timing then leaves the absorbed part behind
    voltage_lag = voltage_lag_scan(eqs, train, held)
    kinds = {r.name: ("constant" if r.is_constant_voltage else "varying") for r in dataset.runs}
    decision = decide(
        stats_cal,
        train,
        held,
        line=line,
        rule=rule,
        seed=seed,
        kinds=kinds,
        calibration=setup,
        progress=(lambda i, n: progress("bootstrap", i, n)) if progress else None,
        candidates=candidates,
    )
    timings["decide"] = time.perf_counter() - t1

    def model_of(decision_: Decision) -> RigParams | None:
        p = calibrated_params(params, decision_.parameters)
        if decision_.named:
            cand = _candidate(decision_.effect)
            if cand.kind == "physical":
                p = p.replace(**cand.to_model_effects(decision_.named_winner.parameters))
            where = (
                " (a measurement effect: in the measurement section)" if cand.kind == "measurement" else ""
            )
            return p.replace(
                name=f"{params.name}+{decision_.effect}",
                description=f"{params.description}; plus {cand.title} identified from measured data{where}"
                + ("; parameters recalibrated" if decision_.recalibrated else ""),
            )
        if decision_.recalibrated:
            return p.replace(
                name=f"{params.name}+recalibrated",
                description=f"{params.description}; parameters recalibrated on measured data",
            )
        return None

    def named_model(decision_: Decision) -> RigParams:
        """The model of a decision that names an effect (never the nominal one)."""
        model = model_of(decision_)
        assert model is not None, decision_.effect
        return model

    t2 = time.perf_counter()
    nominal: dict[str, RunComparison] = {}
    after: dict[str, RunComparison] = {}
    cache: dict = {}
    sensor_check: dict[str, Any] = {}
    effects: list[str] = []
    second: dict[str, Any] = {}
    by_name = {eq.run.name: eq for eq in eqs}
    held_eqs = [by_name[n] for n in decision.heldout_runs]
    if simulate_gaps:
        for i, eq in enumerate(eqs if simulate_training_runs else held_eqs):
            nominal[eq.run.name] = compare_run(
                params, eq, dataset.encoder_counts_per_rev, compare_config, measured_cache=cache
            )
            if progress:
                progress("simulate nominal", i + 1, len(eqs if simulate_training_runs else held_eqs))
        if decision.named:
            # the effect must make the recalibrated model better in sensor space too
            ref_params = calibrated_params(params, decision.reference_parameters)
            ref = {
                eq.run.name: (
                    nominal[eq.run.name]
                    if ref_params is params
                    else compare_run(
                        ref_params, eq, dataset.encoder_counts_per_rev, compare_config, measured_cache=cache
                    )
                )
                for eq in held_eqs
            }
            with_effect = {
                eq.run.name: compare_run(
                    named_model(decision),
                    eq,
                    dataset.encoder_counts_per_rev,
                    compare_config,
                    measured_cache=cache,
                    measurement=_measurement(decision),
                )
                for eq in held_eqs
            }
            floors = {
                k: float(np.mean([c.floors[k] for c in ref.values()])) for k in ("angle_rad", "speed_rad_s")
            }
            before_g, after_g = aggregate(list(ref.values())), aggregate(list(with_effect.values()))
            worse = sensor_worse(before_g, after_g, floors)
            sensor_check = {
                "effect": decision.effect,
                "recalibrated_model": before_g,
                "with_effect": after_g,
                "floors": floors,
                "worse": worse,
            }
            if worse:
                demote(
                    decision,
                    f"{decision.effect} improves the held-out equation error but makes "
                    f"{', '.join(worse)} worse on the held-out runs",
                )
            else:
                after = with_effect
                effects = [decision.effect]
                second = second_effect(decision, stats_cal, setup, rule=rule, candidates=candidates)
                if second.get("named"):
                    kept = decision.parameters, decision.winner
                    _second_parameters(decision, second)  # the parameters refitted with both
                    both = _with_second(named_model(decision), second)
                    both_meas = _measurement(decision, second)
                    decision.parameters, decision.winner = kept
                    with_both = {
                        eq.run.name: compare_run(
                            both,
                            eq,
                            dataset.encoder_counts_per_rev,
                            compare_config,
                            measured_cache=cache,
                            measurement=both_meas,
                        )
                        for eq in held_eqs
                    }
                    both_g = aggregate(list(with_both.values()))
                    worse2 = sensor_worse(after_g, both_g, floors)
                    second["sensor_worse"] = worse2
                    sensor = _candidate(second["named"]).kind == "measurement"
                    seen = readings_gain(after_g, both_g, floors) if sensor else None
                    if sensor:
                        second["readings_gain"] = seen
                    if worse2:
                        second["reason"] += (
                            f"; not named: it makes {', '.join(worse2)} worse on the held-out runs"
                        )
                        second["named"] = None
                    elif sensor and (seen is None or seen <= 1.0):
                        second["reason"] += (
                            "; not named: a reading error must show in the readings, and the held-out "
                            f"angle gap moved by {'nothing measurable' if seen is None else f'{seen:.2f}'}"
                            " of the angle noise (more than 1 needed)"
                        )
                        second["named"] = None
                    else:
                        after = with_both
                        effects.append(second["named"])
                        _second_parameters(decision, second)
        corrected = model_of(decision)
        measurement = _measurement(decision, second if len(effects) > 1 else None)
        if len(effects) > 1:
            corrected = _with_second(named_model(decision), second)
        if corrected is not None and not after:
            for i, eq in enumerate(held_eqs):
                after[eq.run.name] = compare_run(
                    corrected,
                    eq,
                    dataset.encoder_counts_per_rev,
                    compare_config,
                    measured_cache=cache,
                    measurement=measurement,
                )
                if progress:
                    progress("simulate corrected", i + 1, len(held_eqs))
    else:
        corrected = model_of(decision)
        measurement = _measurement(decision)
        if decision.named:
            effects = [decision.effect]
            second = second_effect(decision, stats_cal, setup, rule=rule, candidates=candidates)
            if second.get("named"):
                effects.append(second["named"])
                _second_parameters(decision, second)
                corrected = _with_second(named_model(decision), second)
                measurement = _measurement(decision, second)
    second.pop("parameter_fits", None)  # in decision.parameters now
    timings["simulate"] = time.perf_counter() - t2
    where = _where_table(eqs, nominal, rule)
    held_nom = [nominal[n] for n in decision.heldout_runs if n in nominal]
    n_h = decision.excess["heldout_windows"]
    gap_before = {"equation_error_ss_per_window": decision.excess["heldout_ss_per_window_nominal"]}
    gap_before.update(aggregate(held_nom))
    if corrected is not None:
        if decision.named:
            chosen = decision.named_winner.heldout_ss
        else:  # recalibrated: the recalibration alone is the model
            assert decision.reference is not None
            chosen = decision.reference.heldout_ss
        if len(effects) > 1:
            chosen = second["heldout_ss"]
        gap_after = {"equation_error_ss_per_window": chosen / max(n_h, 1)}
        gap_after.update(aggregate([after[n] for n in decision.heldout_runs if n in after]))
    else:
        gap_after = dict(gap_before)  # no change: the model is the nominal one
    model_check: dict[str, Any] = {}
    if corrected is not None and held_nom and after:
        # never hand out a model worse than the nominal one: the same sensor-space gaps and
        # tolerance as for a named effect, now the chosen model against the nominal one
        floors_nom = {
            k: float(np.mean([c.floors[k] for c in held_nom])) for k in ("angle_rad", "speed_rad_s")
        }
        chosen_g = aggregate([after[n] for n in decision.heldout_runs if n in after])
        nominal_g = aggregate(held_nom)
        model_check = {
            "nominal_model": nominal_g,
            "chosen_model": chosen_g,
            "floors": floors_nom,
            "worse": sensor_worse(nominal_g, chosen_g, floors_nom),
        }
    signature = None
    if decision.effect == "unexplained":
        signature = line_signature(eqs_line, line.frequency_hz)
        if signature.significant and signature.locked_to.endswith("disk rotation"):
            # physical or sensor: a friction that follows the angle, or the angle read wrong
            disk = signature.locked_to.split()[0]
            signature = dataclasses.replace(signature, explanations=rotation_explanations(eqs_line, disk))
    timings["total"] = time.perf_counter() - t0
    return DiscrepancyResult(
        dataset=dataset,
        params=params,
        noise=noise,
        equations=eqs,
        decision=decision,
        line=line,
        corrected=corrected,
        first_pass=first_pass,
        sensor_check=sensor_check,
        effects=effects,
        second=second,
        where=where,
        nominal=nominal,
        after=after,
        gap_before=gap_before,
        gap_after=gap_after,
        timings=timings,
        signature=signature,
        model_check=model_check,
        measurement=measurement,
        voltage_lag=voltage_lag,
        left_out=left_out,
    )


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def run_discrepancy(
    data_dir: str | Path,
    out: str | Path,
    *,
    heldout: list[str] | None = None,
    figures: bool = True,
    seed: int = 0,
    progress: Callable[[str, int, int], None] | None = None,
    rule: DecisionRule | None = None,
    params: RigParams | None = None,
    voltage_lag: int = 0,
) -> DiscrepancyResult:
    """Run the workflow on a dataset folder and write ``report.md``, ``result.json``,
    the figures and the chosen model under ``out``, which is held for this run alone
    (:func:`drill_env.outputs.output_lock`) from the analysis on. The chosen model (when it
    differs from the nominal one) is ``model.yaml``, unless it simulates worse than the
    nominal model on the held-out runs (:attr:`DiscrepancyResult.model_rejected`): then it is
    ``model_rejected.yaml``, with the reason in its description, and no ``model.yaml`` is
    written. ``voltage_lag`` re-times the voltage column by whole samples before the analysis
    (:func:`drill_env.discrepancy.timing.shift_voltage`; 0: as recorded)."""
    dataset = shift_voltage(load_dataset(data_dir), voltage_lag)
    out = Path(out)
    with output_lock(out, "discrepancy"):
        res = analyse(dataset, heldout=heldout, seed=seed, progress=progress, rule=rule, params=params)
        if res.corrected is not None and res.model_rejected:
            worse = ", ".join(res.model_check["worse"])
            rejected = res.corrected.replace(
                description=f"{res.corrected.description}; NOT THE RESULT: it makes {worse} worse than "
                "the nominal model on the held-out runs"
            )
            write_model_yaml(rejected, out / "model_rejected.yaml", res.measurement)
        elif res.corrected is not None:
            write_model_yaml(res.corrected, out / "model.yaml", res.measurement)
        atomic_write_text(out / "result.json", json.dumps(_jsonable(res.result_json()), indent=2) + "\n")
        from drill_env.discrepancy.report import write_report

        write_report(res, out, figures=figures)
    return res
