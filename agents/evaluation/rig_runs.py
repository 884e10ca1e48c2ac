"""The benchmark's side of ``run-controller``: the controller by the benchmark's own path, and
the run scored by the benchmark's own metric functions.

* :func:`resolve_controller`: a benchmark name (through
  :func:`drill_env.agents.registry.build_controller`, as the benchmark builds it), a policy
  zip (:func:`drill_env.agents.learning.rl.load_policy`) or ``module:Class`` (a class taking a
  :class:`~drill_env.agents.controllers.base.ControllerSpec`), each with the environment it
  runs on (its observation version; the rig's encoder resolution and sample clock);
* :func:`measured_metrics`: suppression and tracking from what the rig measured;
* :func:`truth_metrics`: the same from the true state an emulated rig logged (``emulate-rig
  --truth``), exactly as :func:`~drill_env.agents.evaluation.episodes.evaluate` scores an
  episode: the check that the loop on the wire does what the benchmark's episode does.
"""

from __future__ import annotations

import importlib
import math
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.agents.evaluation.episodes import (
    EpisodeSettings,
    is_stalled,
    make_env,
    open_loop_cycle,
    suppression,
)
from drill_env.metrics import stick_slip_metrics

__all__ = ["measured_metrics", "resolve_controller", "truth_metrics"]


def resolve_controller(
    controller: str,
    preset: str,
    counts_per_rev: int,
    sample_rate_hz: float,
    *,
    agents_dir: str | Path | None = None,
    trusted: bool = False,
) -> tuple[Any, Any, str]:
    """``(env, controller, name)`` for ``controller`` (module docstring) on ``preset``'s design
    model, seen through encoders of ``counts_per_rev`` sampled at ``sample_rate_hz``."""
    from drill_env.agents.registry import CONTROLLERS, build_controller, observation_version

    overrides = {"sensors": {"counts_per_rev": int(counts_per_rev), "sample_rate_hz": float(sample_rate_hz)}}
    settings = EpisodeSettings()
    if controller in CONTROLLERS:
        version = observation_version(controller, preset, agents_dir)
        env = make_env(preset, settings, version, overrides=overrides)
        return env, build_controller(controller, env, preset, agents_dir=agents_dir), controller
    path = Path(controller)
    if path.suffix == ".zip":
        from drill_env.agents.learning.rl import load_policy, policy_observation_version

        if not path.is_file():
            raise ValueError(f"CONTROLLER: no policy file {controller!r}")
        env = make_env(preset, settings, policy_observation_version(path), overrides=overrides)
        policy = load_policy(path, trusted=trusted)
        policy.check_env(env)
        return env, policy, path.parent.name or path.stem
    module, sep, cls_name = controller.partition(":")
    if sep and module and cls_name:
        from drill_env.agents.controllers.base import ControllerSpec
        from drill_env.envs.config import OBSERVATION_VERSIONS

        try:
            cls = getattr(importlib.import_module(module), cls_name)
        except (ImportError, AttributeError) as exc:
            raise ValueError(f"CONTROLLER: cannot import {controller!r} ({exc})") from None
        env = make_env(preset, settings, max(OBSERVATION_VERSIONS), overrides=overrides)
        obj = cls(ControllerSpec.from_env(env))
        if not callable(getattr(obj, "predict", None)):
            raise ValueError(
                f"CONTROLLER: {controller} has no predict(obs, state, episode_start, deterministic)"
            )
        return env, obj, cls_name
    raise ValueError(
        f"CONTROLLER: {controller!r} is none of: a benchmark controller ({', '.join(CONTROLLERS)}), "
        "a policy file (.zip) or module:Class"
    )


def _score(
    t: np.ndarray, x3: np.ndarray, stuck: np.ndarray, preset: str, voltage: float, target: float
) -> dict[str, Any]:
    m = stick_slip_metrics(t, x3, stuck)
    ol = open_loop_cycle(preset, float(voltage))
    supp = suppression(m.amplitude, ol["amplitude"])
    stalled = is_stalled(m.stick_fraction, m.mean_speed, target)
    if stalled and math.isfinite(supp):
        supp = min(supp, 0.0)
    err = x3 - target
    return {
        "amplitude": m.amplitude,
        "open_loop_amplitude": ol["amplitude"],
        "suppression": supp,
        "stalled": stalled,
        "stick_fraction": m.stick_fraction,
        "mean_speed": m.mean_speed,
        "rms_error": float(np.sqrt(np.mean(err * err))),
    }


def measured_metrics(res: Any) -> dict[str, Any]:
    """Suppression and tracking over the last ``window`` seconds of a run (a
    :class:`~drill_env.rig.loop.LoopResult`), by the benchmark's functions, on the lower-disk
    speed the encoder measures: its counts over each control period / the period (the
    environment's ``lower_speed_mean``), stuck where no count changed in a period."""
    rows = [r for r in res.log if r["phase"] == "control"]
    out: dict[str, Any] = {"control_periods": len(rows)}
    if not rows:
        return out
    t = np.array([r["t"] for r in rows])
    w = np.array([r["lower_speed_mean"] for r in rows])
    win = t >= t[-1] - res.settings.window + 1e-9
    out["window_s"] = float(np.count_nonzero(win) * res.control_dt)
    out.update(
        _score(
            t[win], w[win], w[win] == 0.0, res.settings.preset, res.settings.nominal_voltage, res.target_speed
        )
    )
    u = np.array([r["u_applied"] for r in rows])
    out.update(u_mean_abs=float(np.mean(np.abs(u))), u_peak_abs=float(np.max(np.abs(u))))
    return out


def truth_metrics(
    truth_csv: str | Path, t_from: float, t_to: float, preset: str, voltage: float, target: float
) -> dict[str, Any]:
    """The benchmark's metrics of the true lower-disk speed an emulated rig logged
    (``emulate-rig --truth``) over ``t_from < t <= t_to`` [s of rig time]: the 1 kHz true
    samples of the window, as :func:`~drill_env.agents.evaluation.episodes.evaluate` scores."""
    import pandas as pd

    df = pd.read_csv(truth_csv)
    win = (df["t"] > t_from + 1e-9) & (df["t"] <= t_to + 1e-9)
    d = df[win]
    if len(d) < 2:
        raise ValueError(f"truth: {truth_csv} has no samples in ({t_from:g}, {t_to:g}] s")
    return _score(
        d["t"].to_numpy(), d["x3"].to_numpy(), d["lower_stuck"].to_numpy() != 0, preset, voltage, target
    )
