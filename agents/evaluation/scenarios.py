"""The scenario suite's runner: every controller through every scenario of
:mod:`drill_env.envs.scenarios`, scored per run, per scenario and over the suite.

Each run is one episode of :func:`~drill_env.agents.evaluation.episodes.run_episode` (the one
evaluation path: SB3's ``predict`` on the registered environment, scored from the true state)
on the environment made with ``scenario=<name>``; the controller is built by the registry on
the registered environment *without* the scenario: it knows the design model, never the
delay, the noise or the friction change (it is told each new set point through the
observation, as an operator's command). The same seed gives every controller the same
warm-up, noise and schedule: the runs are paired.

Scores (one per run, ``score`` of :func:`run_suite`'s table; 1 is perfect):

* ``tracking_score = max(-1, 1 - IAE / IAE_open_loop)``, ``IAE`` the mean of
  ``|x3(t) - w*(t)|`` over the whole closed-loop episode at the 1 kHz true samples (``w*(t)``
  the design model's target speed of the set point in force), ``IAE_open_loop`` the same for
  the open loop (the nominal voltage of each set point, no feedback) on the same scenario,
  preset and seed: the fraction of the open loop's speed error the controller removes, in
  transients and in steady state alike. A controller that stalls the bit or runs away scores
  below 0; the floor -1 keeps one disaster from deciding a mean;
* the ``effort`` scenario scores ``tracking_score * min(1, E_ref / E)``, ``E`` the motor's
  work on the upper disk, ``km sum_k u_k (theta_u(t_k+1) - theta_u(t_k))`` [J] (exact: the
  voltage is held over each period), ``E_ref`` the work the design model's equilibrium
  needs, ``km u_nom w* T``: suppression per energy used. Every run also records the effort
  beside the score (``energy_j``, ``energy_ratio``, ``u_rms``, ``u_peak_abs``,
  ``du_dt_peak``, ``du_dt_rms``).

Per phase (the time between set-point changes): ``settling_time`` [s], the mean over phases
of the time after which ``|x3 - w*|`` stays within ``max(0.1 w*, 0.05 rad/s)`` (the phase's
length if it never does), and over the last :data:`STEADY_WINDOW` seconds of each phase the
largest ``steady_amplitude`` (max - min of x3) and ``steady_error`` (``|mean x3 - w*|``), and
``stick_fraction`` over the episode.

Aggregation: a controller's score on a scenario is the mean over presets and seeds; its
``suite_score`` the mean of its scenario scores (every scenario weighs the same, whatever its
length). The per-run table is what paired statistics resample.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from drill_env.envs.scenarios import SCENARIO_NAMES, Scenario, get_scenario

__all__ = [
    "REFERENCE",
    "RUN_COLUMNS",
    "STEADY_WINDOW",
    "SuiteConfig",
    "run_suite",
    "scenario_table",
    "scenario_trajectory",
    "score_runs",
    "suite_scores",
]

REFERENCE = "open_loop"  # the controller every score is relative to
STEADY_WINDOW = 10.0  # [s] end of each phase where the steady amplitude and error are measured
SCORE_FLOOR = -1.0
SETTLE_BAND = 0.1  # [-] of the target speed ...
SETTLE_BAND_MIN = 0.05  # [rad/s] ... at least

# the per-run table, in order (run_suite's columns)
RUN_COLUMNS = (
    "controller",
    "scenario",
    "preset",
    "seed",
    "score",
    "tracking_score",
    "iae",
    "iae_open_loop",
    "settling_time",
    "steady_amplitude",
    "steady_error",
    "stick_fraction",
    "energy_j",
    "energy_ref_j",
    "energy_ratio",
    "u_mean_abs",
    "u_rms",
    "u_peak_abs",
    "du_dt_peak",
    "du_dt_rms",
    "u_limit_fraction",
    "x3_peak_abs",
    "sim_status",
    "wall_time",
    "error",
)


@dataclass(frozen=True)
class SuiteConfig:
    """What the suite runs: controllers x scenarios x presets x seeds ``0 .. seeds-1``."""

    controllers: tuple[str, ...]
    scenarios: tuple[str, ...] = SCENARIO_NAMES
    presets: tuple[str, ...] = ("brake", "no_brake")
    seeds: int = 2
    warmup_jitter: float = 4.0  # [s] random extra warm-up (the phase of the cycle at switch-on)
    agents_dir: str | None = None

    def __post_init__(self) -> None:
        from drill_env.agents.registry import CONTROLLERS
        from drill_env.params import PRESETS

        for c in self.controllers:
            if c not in CONTROLLERS:
                raise ValueError(f"controllers: {c!r} is not one of {list(CONTROLLERS)}")
        if not self.controllers:
            raise ValueError("controllers: expected at least one")
        for s in self.scenarios:
            get_scenario(s)
        for p in self.presets:
            if p not in PRESETS:
                raise ValueError(f"presets: {p!r} is not one of {list(PRESETS)}")
        if isinstance(self.seeds, bool) or not isinstance(self.seeds, int) or not 1 <= self.seeds <= 1000:
            raise ValueError(f"seeds: {self.seeds!r} is outside the allowed range [1, 1000]")

    def jobs(self) -> list[tuple[str, str, str, int]]:
        """(controller, scenario, preset, seed) of every run, the reference's included."""
        names = (REFERENCE, *[c for c in self.controllers if c != REFERENCE])
        return [
            (c, s, p, k)
            for c in names
            for s in self.scenarios
            for p in self.presets
            for k in range(self.seeds)
        ]


def _settings(scenario: Scenario, warmup_jitter: float):
    from drill_env.agents.evaluation.episodes import EpisodeSettings

    return EpisodeSettings(
        duration=scenario.duration,
        window=scenario.duration,
        warmup_time=scenario.warmup_time,
        warmup_jitter=warmup_jitter,
        env_kwargs={"scenario": scenario.name},
    )


_CONTROLLERS: dict[tuple[Any, ...], Any] = {}
_ENVS: dict[tuple[Any, ...], Any] = {}


def _controller(name: str, preset: str, version: int, agents_dir: str | None):
    """The controller built on the registered environment without the scenario (cached)."""
    from drill_env.agents.evaluation.episodes import EpisodeSettings, make_env
    from drill_env.agents.registry import build_controller

    key = (name, preset, version, agents_dir)
    if key not in _CONTROLLERS:
        env = make_env(preset, EpisodeSettings(), version)
        _CONTROLLERS[key] = build_controller(name, env, preset, agents_dir=agents_dir)
    return _CONTROLLERS[key]


def _env(scenario: Scenario, preset: str, version: int, warmup_jitter: float):
    from drill_env.agents.evaluation.episodes import make_env

    key = (scenario.name, preset, version, warmup_jitter)
    if key not in _ENVS:
        _ENVS[key] = make_env(preset, _settings(scenario, warmup_jitter), version)
    return _ENVS[key]


def scenario_trajectory(
    controller: str,
    scenario: str,
    preset: str,
    seed: int,
    *,
    warmup_jitter: float = 4.0,
    agents_dir: str | None = None,
) -> dict[str, np.ndarray]:
    """One run's record: per control period ``t`` [s], ``voltage`` [V], ``true_state``, the
    set point ``target`` [rad/s] and ``nominal_voltage`` [V] in force, and the 1 kHz true samples
    ``t_fast``, ``lower_speed``, ``lower_stuck``; ``switch_on_state`` is the true state at the
    switch-on."""
    from drill_env.agents.evaluation.episodes import run_episode
    from drill_env.agents.registry import observation_version

    sc = get_scenario(scenario)
    version = observation_version(controller, preset, agents_dir)
    env = _env(sc, preset, version, warmup_jitter)
    ctrl = _controller(controller, preset, version, agents_dir)
    n = int(round(sc.duration / env.unwrapped.control_dt))
    traj = run_episode(env, ctrl, seed=seed, n_steps=n, window_steps=n)
    base = env.unwrapped
    # the set point of each period: the first from the reset, then the scenario's changes
    t_start = traj.t - base.control_dt
    points = _episode_points(base, traj.reset_info)
    phase = np.array([_phase_of(sc, t) for t in t_start])
    target = np.array([points[k][0] for k in phase])
    unom = np.array([points[k][1] for k in phase])
    return {
        "t": traj.t,
        "voltage": traj.voltage,
        "voltage_requested": traj.voltage_requested,
        "true_state": traj.true_state,
        "target": target,
        "nominal_voltage": unom,
        "t_fast": traj.window_t,
        "lower_speed": traj.window_lower_speed,
        "lower_stuck": traj.window_lower_stuck,
        "switch_on_state": np.asarray(traj.reset_info["true_state"], dtype=float),
        "sim_status": np.array(traj.sim_status),
        "control_dt": np.array(base.control_dt),
        "motor_constant": np.array(base.true_params.motor_constant),
    }


def _phase_of(sc: Scenario, t: float) -> int:
    return int(np.searchsorted(np.asarray(sc.change_times, dtype=float), t + 1e-9, side="right"))


def _episode_points(base: Any, reset_info: dict[str, Any]) -> list[tuple[float, float]]:
    first = (float(reset_info["target_speed"]), float(reset_info["nominal_voltage"]))
    schedule = base.settings.schedule
    if schedule is None:
        return [first]
    return [first, *[(p.target_speed, p.nominal_voltage) for p in schedule.points[1:]]]


def run_metrics(rec: dict[str, np.ndarray], sc: Scenario) -> dict[str, float]:
    """The raw metrics of one run's record (:func:`scenario_trajectory`), before the scores."""
    dt = float(rec["control_dt"])
    tf, x3, stuck = rec["t_fast"], rec["lower_speed"], rec["lower_stuck"]
    # the set point of each 1 kHz sample: that of its control period
    k = np.clip(np.searchsorted(rec["t"], tf - 1e-12, side="left"), 0, len(rec["t"]) - 1)
    w = rec["target"][k]
    err = np.abs(x3 - w)
    settle, amps, errs = [], [], []
    for a, b in sc.phase_bounds():
        m = (tf > a + 1e-12) & (tf <= b + 1e-12)
        if not m.any():
            continue
        wt = float(w[m][-1])
        band = max(SETTLE_BAND * wt, SETTLE_BAND_MIN)
        out = np.flatnonzero(err[m] > band)
        settle.append(
            0.0 if out.size == 0 else (b - a) if out[-1] == m.sum() - 1 else float(tf[m][out[-1]] - a)
        )
        s = m & (tf > b - STEADY_WINDOW)
        amps.append(float(np.ptp(x3[s])))
        errs.append(float(abs(np.mean(x3[s]) - wt)))
    u = rec["voltage"]
    state = rec["true_state"]
    theta_u = np.concatenate([[rec["switch_on_state"][3]], state[:, 3]])
    km = float(rec["motor_constant"])
    energy = float(km * np.sum(u * np.diff(theta_u)))
    energy_ref = float(km * np.sum(rec["nominal_voltage"] * rec["target"]) * dt)
    du = np.diff(np.concatenate([[rec["nominal_voltage"][0]], u])) / dt
    return {
        "iae": float(np.mean(err)) if err.size else math.nan,
        "settling_time": float(np.mean(settle)) if settle else math.nan,
        "steady_amplitude": max(amps) if amps else math.nan,
        "steady_error": max(errs) if errs else math.nan,
        "stick_fraction": float(np.mean(stuck)) if stuck.size else math.nan,
        "energy_j": energy,
        "energy_ref_j": energy_ref,
        "energy_ratio": energy / energy_ref if energy_ref > 0 else math.nan,
        "u_mean_abs": float(np.mean(np.abs(u))),
        "u_rms": float(np.sqrt(np.mean(u * u))),
        "u_peak_abs": float(np.max(np.abs(u))),
        "du_dt_peak": float(np.max(np.abs(du))),
        "du_dt_rms": float(np.sqrt(np.mean(du * du))),
        "u_limit_fraction": float(np.mean(np.abs(rec["voltage_requested"]) >= 5.0 - 1e-9)),
        "x3_peak_abs": float(np.max(np.abs(x3))) if x3.size else math.nan,
        "sim_status": int(rec["sim_status"]),
    }


def run_one(job: tuple[str, str, str, int], warmup_jitter: float, agents_dir: str | None) -> dict[str, Any]:
    """The raw metrics of one (controller, scenario, preset, seed); an exception becomes a row
    with NaN metrics and the message in ``error`` (the suite goes on)."""
    controller, scenario, preset, seed = job
    t0 = time.perf_counter()
    row: dict[str, Any] = {"controller": controller, "scenario": scenario, "preset": preset, "seed": seed}
    try:
        rec = scenario_trajectory(
            controller, scenario, preset, seed, warmup_jitter=warmup_jitter, agents_dir=agents_dir
        )
        row.update(run_metrics(rec, get_scenario(scenario)))
        row["error"] = ""
    except Exception as exc:  # recorded, the suite goes on
        row["sim_status"] = -1
        row["error"] = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:300]
    row["wall_time"] = time.perf_counter() - t0
    return row


def _run_chunk(jobs: list[tuple[str, str, str, int]], warmup_jitter: float, agents_dir: str | None):
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover - torch is a dependency
        pass
    return [run_one(j, warmup_jitter, agents_dir) for j in jobs]


def score_runs(raw: Any) -> Any:
    """The per-run table (:data:`RUN_COLUMNS`) from the raw metrics of :func:`run_one`: each
    run scored against the reference (open loop) run of its scenario, preset and seed."""
    import pandas as pd

    df = pd.DataFrame(raw).copy()
    ref = df[df["controller"] == REFERENCE].set_index(["scenario", "preset", "seed"])["iae"]
    if ref.empty:
        raise ValueError(f"runs: the reference controller {REFERENCE!r} has no runs")
    keys = list(zip(df["scenario"], df["preset"], df["seed"], strict=True))
    df["iae_open_loop"] = [float(ref.get(k, math.nan)) for k in keys]
    ok = df["error"].fillna("") == ""
    tracking = np.maximum(SCORE_FLOOR, 1.0 - df["iae"] / df["iae_open_loop"])
    df["tracking_score"] = np.where(ok, tracking, math.nan)
    energy_factor = np.minimum(1.0, df["energy_ref_j"] / df["energy_j"].where(df["energy_j"] > 0))
    per_energy = np.array([get_scenario(s).score == "tracking_per_energy" for s in df["scenario"]])
    score = np.where(per_energy, df["tracking_score"] * energy_factor.fillna(1.0), df["tracking_score"])
    # a failed run (simulator stopped, exception) scores the floor: never silently dropped
    failed = ~ok | (df["sim_status"].fillna(-1) != 0)
    df["score"] = np.where(failed, SCORE_FLOOR, score)
    for c in RUN_COLUMNS:
        if c not in df:
            df[c] = math.nan
    return df[list(RUN_COLUMNS)].reset_index(drop=True)


def run_suite(
    cfg: SuiteConfig,
    *,
    workers: int = 1,
    progress: Callable[[int, int, dict[str, Any]], None] | None = None,
) -> Any:
    """Run the suite; returns the per-run table (a pandas DataFrame, :data:`RUN_COLUMNS`:
    ``controller, scenario, preset, seed, score, ...``), the reference's runs included."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers: expected an integer >= 1, got {workers!r}")
    jobs = cfg.jobs()
    # one chunk per (controller, preset): the controller is built once per process
    chunks: dict[tuple[str, str], list] = {}
    for j in jobs:
        chunks.setdefault((j[0], j[2]), []).append(j)
    raw: list[dict[str, Any]] = []
    total = len(jobs)
    if workers == 1:
        for chunk in chunks.values():
            for row in _run_chunk(chunk, cfg.warmup_jitter, cfg.agents_dir):
                raw.append(row)
                if progress:
                    progress(len(raw), total, row)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(_run_chunk, c, cfg.warmup_jitter, cfg.agents_dir) for c in chunks.values()]
            for f in futures:
                for row in f.result():
                    raw.append(row)
                    if progress:
                        progress(len(raw), total, row)
    df = score_runs(raw)
    order = {c: i for i, c in enumerate((REFERENCE, *cfg.controllers))}
    sorder = {s: i for i, s in enumerate(SCENARIO_NAMES)}
    df = df.sort_values(
        by=["controller", "scenario", "preset", "seed"],
        key=lambda col: (
            col.map(order) if col.name == "controller" else col.map(sorder) if col.name == "scenario" else col
        ),
    ).reset_index(drop=True)
    return df


def scenario_table(runs: Any) -> Any:
    """Mean score per controller (rows) and scenario (columns), over presets and seeds, with
    the ``suite_score`` (mean over the scenarios) as the last column, best suite score first."""
    table = runs.pivot_table(index="controller", columns="scenario", values="score", aggfunc="mean")
    table = table[[s for s in SCENARIO_NAMES if s in table.columns]]
    table["suite_score"] = table.mean(axis=1)
    return table.sort_values("suite_score", ascending=False)


def suite_scores(runs: Any) -> Any:
    """Each controller's suite score (a pandas Series, best first)."""
    return scenario_table(runs)["suite_score"]


def headroom(runs: Any, exclude: Sequence[str] = (REFERENCE,)) -> Any:
    """Per scenario: the best controller (``exclude`` left out) and its mean score."""
    import pandas as pd

    table = scenario_table(runs[~runs["controller"].isin(list(exclude))]).drop(columns="suite_score")
    return pd.DataFrame({"best_controller": table.idxmax(axis=0), "best_score": table.max(axis=0)})
