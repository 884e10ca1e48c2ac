"""The model-discrepancy workflow on a measured dataset: where, which, decide, add and show.

:func:`run_discrepancy` loads a dataset folder, computes the nominal model's equation
error and sensor-space gaps on every run (*where*), fits and scores the candidate
library on training and held-out runs (*which*, *decide*), writes the chosen effect as
a rig YAML under the output folder, re-simulates the held-out runs with it and writes
``result.json``, ``report.md`` and the figures (*add and show*). It never reads
anything but the dataset folder.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.discrepancy.compare import CompareConfig, RunComparison, aggregate, compare_run
from drill_env.discrepancy.dataset import MeasuredDataset, load_dataset
from drill_env.discrepancy.decide import (
    Decision,
    DecisionRule,
    LineScan,
    decide,
    line_scan,
    run_statistics,
    split_runs,
)
from drill_env.discrepancy.effects import CANDIDATES
from drill_env.discrepancy.equation_error import (
    AngleNoise,
    EquationErrorConfig,
    RunEquations,
    estimate_angle_noise,
)
from drill_env.outputs import atomic_write_text, output_lock
from drill_env.params import RigParams, load_params

__all__ = ["DiscrepancyResult", "analyse", "run_discrepancy", "RESULT_EFFECTS"]

RESULT_EFFECTS = tuple(c.name for c in CANDIDATES) + ("none", "unexplained")


@dataclass
class DiscrepancyResult:
    dataset: MeasuredDataset
    params: RigParams
    noise: AngleNoise
    equations: list[RunEquations]
    decision: Decision
    line: LineScan
    corrected: RigParams | None
    where: list[dict[str, Any]]
    nominal: dict[str, RunComparison]
    after: dict[str, RunComparison]
    gap_before: dict[str, float]
    gap_after: dict[str, float]
    timings: dict[str, float]

    @property
    def effect(self) -> str:
        return self.decision.effect

    def result_json(self) -> dict[str, Any]:
        d = self.decision
        params = d.winner.parameters if (d.winner is not None and d.effect == d.winner.name) else {}
        return {
            "effect": d.effect,
            "confidence": d.confidence,
            "parameters": params,
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "heldout_runs": d.heldout_runs,
            "evidence": {
                "reason": d.reason,
                "train_runs": d.train_runs,
                "candidates": [s.as_dict() for s in d.scores],
                "excess": d.excess,
                "structure": d.structure,
                "spectral_line": self.line.as_dict(),
                "bootstrap_verdicts": d.bootstrap_counts,
                "angle_noise": self.noise.as_dict(),
                "where": self.where,
                "preset": self.dataset.preset,
                "encoder_counts_per_rev": self.dataset.encoder_counts_per_rev,
                "timings_s": self.timings,
            },
        }

    def verdict_line(self) -> str:
        d = self.decision
        if d.effect in ("none", "unexplained"):
            extra = ""
            if d.effect == "unexplained" and self.line.significant:
                rel = "locked to rotation" if self.line.related_to_rotation else "unrelated to rotation"
                extra = f"; signature: line at {self.line.frequency_hz:.3g} Hz common to all runs, {rel}"
            return f"verdict: {d.effect} (confidence {d.confidence:.2f}): {d.reason}{extra}"
        par = ", ".join(f"{k}={v:.4g}" for k, v in d.winner.parameters.items())
        return f"verdict: {d.effect} (confidence {d.confidence:.2f}; {par})"


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


def analyse(
    dataset: MeasuredDataset,
    *,
    heldout: list[str] | None = None,
    rule: DecisionRule | None = None,
    eq_config: EquationErrorConfig | None = None,
    compare_config: CompareConfig | None = None,
    simulate_gaps: bool = True,
    seed: int = 0,
    progress: Callable[[str, int, int], None] | None = None,
) -> DiscrepancyResult:
    """Run the whole workflow in memory (no files); see :func:`run_discrepancy`."""
    rule = rule or DecisionRule()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    params = load_params(dataset.preset)
    noise = estimate_angle_noise(dataset.runs, dataset.encoder_step, eq_config)
    eqs = []
    stats = {}
    for i, r in enumerate(dataset.runs):
        eq = RunEquations(r, params, noise, eq_config)
        eqs.append(eq)
        stats[r.name] = run_statistics(eq)
        if progress:
            progress("equation error", i + 1, len(dataset.runs))
    timings["equation_error"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    line = line_scan(eqs, rule)
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
    kinds = {r.name: ("constant" if r.is_constant_voltage else "varying") for r in dataset.runs}
    decision = decide(
        stats,
        train,
        held,
        line=line,
        rule=rule,
        seed=seed,
        kinds=kinds,
        progress=(lambda i, n: progress("bootstrap", i, n)) if progress else None,
    )
    timings["decide"] = time.perf_counter() - t1
    corrected = None
    if decision.winner is not None and decision.effect == decision.winner.name:
        cand = next(c for c in CANDIDATES if c.name == decision.effect)
        fields_ = cand.to_model_effects(decision.winner.parameters)
        corrected = params.replace(**fields_).replace(
            name=f"{params.name}+{decision.effect}",
            description=f"{params.description}; plus {cand.title} identified from measured data",
        )
    t2 = time.perf_counter()
    nominal: dict[str, RunComparison] = {}
    after: dict[str, RunComparison] = {}
    cache: dict = {}
    if simulate_gaps:
        for i, eq in enumerate(eqs):
            nominal[eq.run.name] = compare_run(
                params, eq, dataset.encoder_counts_per_rev, compare_config, measured_cache=cache
            )
            if progress:
                progress("simulate nominal", i + 1, len(eqs))
        if corrected is not None:
            for i, eq in enumerate(e for e in eqs if e.run.name in decision.heldout_runs):
                after[eq.run.name] = compare_run(
                    corrected, eq, dataset.encoder_counts_per_rev, compare_config, measured_cache=cache
                )
                if progress:
                    progress("simulate corrected", i + 1, len(decision.heldout_runs))
    timings["simulate"] = time.perf_counter() - t2
    where = _where_table(eqs, nominal, rule)
    held_nom = [nominal[n] for n in decision.heldout_runs if n in nominal]
    n_h = decision.excess["heldout_windows"]
    gap_before = {"equation_error_ss_per_window": decision.excess["heldout_ss_per_window_nominal"]}
    gap_before.update(aggregate(held_nom))
    if corrected is not None:
        gap_after = {"equation_error_ss_per_window": decision.winner.heldout_ss / max(n_h, 1)}
        gap_after.update(aggregate([after[n] for n in decision.heldout_runs if n in after]))
    else:
        gap_after = dict(gap_before)  # no effect added: the model is unchanged
    timings["total"] = time.perf_counter() - t0
    return DiscrepancyResult(
        dataset=dataset,
        params=params,
        noise=noise,
        equations=eqs,
        decision=decision,
        line=line,
        corrected=corrected,
        where=where,
        nominal=nominal,
        after=after,
        gap_before=gap_before,
        gap_after=gap_after,
        timings=timings,
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
) -> DiscrepancyResult:
    """Run the workflow on a dataset folder and write ``report.md``, ``result.json``,
    the figures and (when an effect is named) ``model.yaml`` under ``out``, which is held
    for this run alone (:func:`drill_env.outputs.output_lock`) from the analysis on."""
    dataset = load_dataset(data_dir)
    out = Path(out)
    with output_lock(out, "discrepancy"):
        res = analyse(dataset, heldout=heldout, seed=seed, progress=progress)
        if res.corrected is not None:
            res.corrected.to_yaml(out / "model.yaml")
        atomic_write_text(out / "result.json", json.dumps(_jsonable(res.result_json()), indent=2) + "\n")
        from drill_env.discrepancy.report import write_report

        write_report(res, out, figures=figures)
    return res
