"""One benchmark run, in whichever process runs it: the controller on the plant at one
(controller, preset, plant, voltage, seed) through the one evaluation path."""

from __future__ import annotations

import json
import math
import time
from typing import Any

from drill_env.agents.evaluation.benchmark.grid import BenchmarkConfig, Job
from drill_env.agents.evaluation.benchmark.store import COLUMNS

# [rad/s] below this open-loop amplitude a plant has no cycle to suppress (suppression NaN):
# the closed loops leave a steady amplitude of 0.005-0.05 rad/s from encoder quantisation on
# the nominal model, so a smaller "cycle" cannot be suppressed measurably (the smallest cycle
# the analysis predicts on the grid is 1.2 rad/s)
OPEN_LOOP_FLOOR = 0.1

NOT_MADE = "not made: "  # the start of the error of a run that cannot be made on the design model

_ENVS: dict[tuple[str, str], Any] = {}


class RunNotMade(ValueError):
    """A run of the grid that the design model has no operating point for (it does not turn
    at that voltage): recorded as a row whose error starts with :data:`NOT_MADE`."""


def check_operating_point(job: Job, cfg: BenchmarkConfig) -> None:
    """RunNotMade if the design model of ``cfg`` (the preset's by default) does not turn at
    ``job.voltage`` (at or below its stick boundary uc1)."""
    from drill_env.params import load_params

    model = cfg.design_model() or load_params(job.preset)
    if not job.voltage > model.uc1:
        raise RunNotMade(
            f"the design model sticks up to uc1 = {model.uc1:.4g} V, so {job.voltage:g} V is no "
            "operating point (no slip equilibrium, no target speed)"
        )


_CONTROLLERS: dict[tuple[Any, ...], Any] = {}


def _worker_init(cycles: dict[tuple[str, float], dict[str, float]] | None = None) -> None:
    """Set up a worker process; ``cycles``: the open-loop cycles the starting process computed."""
    import warnings

    import torch

    from drill_env.envs.task import RegimeAbsentWarning

    torch.set_num_threads(1)
    if cycles:
        from drill_env.agents.evaluation.episodes import known_open_loop_cycles

        known_open_loop_cycles(cycles)
    # the benchmark names the design model's regimes once, before the runs
    warnings.filterwarnings("ignore", category=RegimeAbsentWarning)


def run_job(job: Job, cfg: BenchmarkConfig) -> dict[str, Any]:
    """Evaluate one job; environments and controllers are cached per process. An exception
    becomes a row with NaN metrics and the message in ``error``.

    The controller is built on the design model (the preset's, or ``cfg.design_params``) and
    run on the plant; the target speed and the regime label come from the design model
    whatever the plant (:func:`~drill_env.agents.evaluation.episodes.make_env`)."""
    from drill_env.agents.evaluation.episodes import evaluate, make_env
    from drill_env.agents.registry import build_controller, observation_version

    t0 = time.perf_counter()
    try:
        check_operating_point(job, cfg)
        # cached per process, keyed by everything they are built from
        spec = cfg.spec_of(job.controller)
        if spec is None:
            version = observation_version(job.controller, job.preset, cfg.agents_dir)
        else:
            from drill_env.agents.evaluation.controller_spec import spec_observation_version

            version = spec_observation_version(spec, job.preset, cfg.agents_dir)
        episode_key = json.dumps(cfg.episode.to_dict(), sort_keys=True, default=str)
        design = cfg.design_model()

        def env_of(plant: str | None, v: int):
            key = (job.preset, v, episode_key, plant, cfg.design_params)
            if key not in _ENVS:
                if plant is None:  # the design model as the plant: what the controller is built on
                    _ENVS[key] = make_env(job.preset, cfg.episode, v, design_params=design)
                else:
                    q = cfg.plant(plant)
                    _ENVS[key] = make_env(
                        job.preset,
                        cfg.episode,
                        v,
                        params=q.rig(job.preset),
                        overrides=q.env_overrides(),
                        design_params=design,
                    )
            return _ENVS[key]

        design_env = env_of(None, version)
        ctrl_key = (
            job.controller,
            job.preset,
            version,
            episode_key,
            cfg.agents_dir,
            cfg.gains_file,
            cfg.design_params,
            spec,
        )
        ctrl = _CONTROLLERS.get(ctrl_key)
        if ctrl is None and spec is not None:
            from drill_env.agents.evaluation.controller_spec import resolve_controller

            ctrl = _CONTROLLERS[ctrl_key] = resolve_controller(
                spec, design_env, job.preset, agents_dir=cfg.agents_dir, trust_policies=cfg.trust_policies
            )
        elif ctrl is None:
            ctrl = _CONTROLLERS[ctrl_key] = build_controller(
                job.controller,
                design_env,
                job.preset,
                agents_dir=cfg.agents_dir,
                gains_file=cfg.gains_file,
                trusted=cfg.trust_policies,
            )
        plant = cfg.plant(job.plant)
        reference, regime = (
            (None, None) if cfg.is_design_plant(plant) else _plant_open_loop(job, cfg, env_of(job.plant, 0))
        )
        row = evaluate(
            ctrl,
            job.preset,
            job.voltage,
            job.seed,
            cfg.episode,
            name=job.controller,
            env=env_of(job.plant, version),
            open_loop_amplitude=reference,
            plant_open_loop_regime=regime,
        ).as_dict()
        row["plant"] = job.plant
        row["error"] = ""
    except Exception as exc:  # recorded, the benchmark goes on
        if not isinstance(exc, RunNotMade):
            _drop_envs()  # an env an error left mid-episode is not reused by the next run
        row = {c: math.nan for c in COLUMNS}
        row.update(
            controller=job.controller, preset=job.preset, plant=job.plant, voltage=job.voltage, seed=job.seed
        )
        row.update(regime="", plant_open_loop_regime="", stalled=False)
        row.update(sim_status=-1, wall_time=time.perf_counter() - t0)
        text = str(exc) if isinstance(exc, RunNotMade) else f"{type(exc).__name__}: {exc}"
        row["error"] = (NOT_MADE if isinstance(exc, RunNotMade) else "") + text.replace("\n", " ")[:300]
    return row


def _drop_envs() -> None:
    """Close and forget this process's cached environments (Gymnasium's wrappers, e.g. its
    passive checker, keep state from a reset that raised: one failed run made every later run
    on the same env fail with a TypeError)."""
    for env in _ENVS.values():
        try:
            env.close()
        except Exception:  # closing a broken env must not hide the run's own error
            pass
    _ENVS.clear()


_OPEN_LOOP: dict[tuple[Any, ...], tuple[float, str]] = {}


def _plant_open_loop(job: Job, cfg: BenchmarkConfig, env: Any) -> tuple[float, str]:
    """The open-loop run on ``job``'s plant at its voltage and seed (cached per process): its
    amplitude, the reference of the suppression where the bifurcation analysis of the design
    model does not apply (0 below :data:`OPEN_LOOP_FLOOR`: no cycle, suppression NaN), and
    the regime it shows (:func:`~drill_env.agents.evaluation.episodes.open_loop_regime`)."""
    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.open_loop import OpenLoop
    from drill_env.agents.evaluation.episodes import evaluate, open_loop_regime

    key = (
        job.preset,
        job.plant,
        round(job.voltage, 9),
        job.seed,
        json.dumps(cfg.episode.to_dict(), default=str),
        cfg.design_params,
    )
    if key not in _OPEN_LOOP:
        m = evaluate(
            OpenLoop(ControllerSpec.from_env(env)),
            job.preset,
            job.voltage,
            job.seed,
            cfg.episode,
            env=env,
            open_loop_amplitude=0.0,
        )
        amp = m.amplitude if m.amplitude >= OPEN_LOOP_FLOOR else 0.0
        _OPEN_LOOP[key] = (amp, open_loop_regime(amp, m.stick_fraction))
    return _OPEN_LOOP[key]


def open_loop_cycles_of(jobs: list[Job], cfg: BenchmarkConfig) -> dict[tuple[str, float], dict[str, float]]:
    """The open-loop cycles the runs on the design plant are scored against, computed in this
    process (on an empty cache this compiles the analysis once, not once per worker)."""
    from drill_env.agents.evaluation.episodes import open_loop_cycle

    pairs = {(j.preset, float(j.voltage)) for j in jobs if cfg.is_design_plant(cfg.plant(j.plant))}
    out = {}
    for pair in sorted(pairs):
        try:
            out[pair] = open_loop_cycle(*pair)
        except Exception:  # noqa: BLE001  # left to the run, which reports it in its row
            continue
    return out


def _run_chunk(jobs: list[Job], cfg: BenchmarkConfig) -> list[dict[str, Any]]:
    _worker_init()
    return [run_job(j, cfg) for j in jobs]
