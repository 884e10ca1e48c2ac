"""The drill-string rig as a Gymnasium environment: the exact simulator seen through the
rig's amplifier and sensors."""

from __future__ import annotations

import dataclasses
import warnings
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from drill_env import _layout as L
from drill_env.envs import _core as C
from drill_env.envs.config import (
    MAX_WARMUP_RETRIES,
    REWARD_NAMES,
    DomainRandomization,
    EnvSettings,
    EpisodeSetup,
    RewardWeights,
    check_actions,
    check_seed,
)
from drill_env.envs.task import TaskConfig
from drill_env.kernel import STATUS_MESSAGES
from drill_env.params import RigParams
from drill_env.sensors import SensorConfig
from drill_env.simulator import DEFAULT_ATOL, DEFAULT_RTOL

__all__ = ["DrillStringEnv"]


class DrillStringEnv(gym.Env):
    """
    ## Description

    The torsional drill-string rig of Mihajlovic et al. (2004): a DC motor drives an
    upper disk, a soft steel string carries the torque down to a lower disk (the bit),
    whose friction (a brake in ``DrillString-v3``) has a Stribeck "hump" that makes the
    slip equilibrium lose stability: torsional limit cycles and stick-slip. The task is
    to keep the lower disk turning at a target speed without stick-slip or torsional
    oscillation, using only the motor voltage and what the rig measures.

    Under the hood the exact event-driven simulator (set-valued friction, stick phases
    with speed exactly 0) integrates each control period; the true state is sampled
    every sensor period (1 ms) and fed through the rig's measurement chain
    (:mod:`drill_env.sensors`): incremental encoders on both disks, backward
    differences of the encoder angles, and a Butterworth low-pass with its -3 dB point at
    200 rad/s (Sec. 2.1 of the paper), plus optional noise and delay.

    Clocks: integration is adaptive; sensors run at ``sensors.sample_rate_hz`` (1 kHz);
    the action is held for ``control_dt`` (0.05 s = 50 sensor samples, an integer number
    of sensor periods is required).

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: the amplifier input voltage divided by 5 V, held over
    the control period (zero-order hold). With ``action_mode="voltage"`` the action is the
    voltage itself, ``Box(-5, 5, (1,), float32)``.

    | Num | Action                    | Min | Max | Unit          |
    |-----|---------------------------|-----|-----|---------------|
    | 0   | amplifier input voltage/5 | -1  | 1   | - (x 5 V)     |

    In v2 (``action_mode="correction"``) the action is the voltage *added to the episode's
    nominal voltage* (entry 7 of the observation, the feedforward of the operator's set
    point), ``u = u_nom + action_range * a`` with ``action_range`` 2 V by default: action 0
    is the open loop at the set point, and a policy only has to learn the correction (the
    tuned LQI's largest over the benchmark grid is 1.55 V). Why: with the absolute voltage
    a policy must first reproduce ``u_nom`` from its observation to a few mV before any
    correction is worth anything; PPO from scratch reached quick-benchmark suppression
    0.966 (Hopf) / 0.992 (stick-slip) after 5 minutes of training on v1 and 0.999 / 0.995
    after 14 s on v2 (same recipe, braked rig, seed 0).

    The rig's amplifier accepts only ``[-5, 5] V`` (Sec. 2.1): any larger request (an
    action outside the box) is clipped to that range, as the rig does, and reported in
    ``info["voltage_clipped"]`` with the request in ``info["voltage_requested"]``. NaN or
    infinite actions raise ``ValueError``, as do actions that are not real numbers (a bool,
    a string such as ``"0.5"``, a complex value): they are never converted.

    ## Observation Space

    ``Box(low, high, (13,), float32)`` (``observation_version=1``; 8 entries in v0, see the
    Version History): only what a controller on the rig has. Each entry
    is divided by its scale (``normalize_observation=True``, the default) so that typical
    values are of order one; with ``normalize_observation=False`` the entries are in the
    units given. The bounds (before scaling) are the amplifier's +-5 V for the voltages
    and safe limits of 1000 rad/s and 1000 rad for speeds and twist: in a 20 s episode the
    motor at +-5 V cannot give the string more than ~810 J, i.e. speeds below ~230 rad/s.

    | Num | Observation        | Unit  | Scale | What it is                                                              |
    |-----|--------------------|-------|-------|-------------------------------------------------------------------------|
    | 0   | `lower_speed`      | rad/s | 10    | filtered speed estimate of the lower disk (bit) at the end of the step |
    | 1   | `upper_speed`      | rad/s | 10    | filtered speed estimate of the upper disk                               |
    | 2   | `twist`            | rad   | 2     | encoder twist theta_u - theta_l (quantised angles)                      |
    | 3   | `lower_speed_mean` | rad/s | 10    | lower encoder counts over the step / control_dt                         |
    | 4   | `upper_speed_mean` | rad/s | 10    | upper encoder counts over the step / control_dt                         |
    | 5   | `voltage`          | V     | 5     | voltage applied during the last step (after the +-5 V limit)            |
    | 6   | `target_speed`     | rad/s | 10    | target lower-disk speed of this episode                                 |
    | 7   | `nominal_voltage`  | V     | 5     | voltage whose nominal-model equilibrium gives the target speed         |

    Version 1 appends what else the encoders give:

    | Num | Observation                  | Unit | Scale | What it is                                                   |
    |-----|------------------------------|------|-------|--------------------------------------------------------------|
    | 8   | `lower_angle_sin`            | -    | 1     | sin of the lower encoder angle within the revolution          |
    | 9   | `lower_angle_cos`            | -    | 1     | cos of the lower encoder angle within the revolution          |
    | 10  | `upper_angle_sin`            | -    | 1     | sin of the upper encoder angle within the revolution          |
    | 11  | `upper_angle_cos`            | -    | 1     | cos of the upper encoder angle within the revolution          |
    | 12  | `lower_speed_error_integral` | rad  | 2 pi  | theta_l(t) - theta_l(t0) - w* (t - t0) from the encoder counts |

    The angles within the revolution are (counts mod N) 2 pi / N from the whole encoder
    count, so they do not lose precision as the disks turn: a policy can learn effects
    that depend on where the disks are (position-dependent friction, Sec. 4.1 of the
    paper). Entry 12 is the lag of the bit behind its reference angle, the integral of the
    lower-disk speed error measured exactly by the encoder (no drift from integrating an
    estimate): t0 is the start of the episode (the controller's switch-on) and it restarts
    from 0 whenever the target speed changes; it is clipped to +-100 pi rad (50
    revolutions, far beyond what a 20 s episode reaches), and ``info["integral_clipped"]``
    says when it is.

    Why 3, 4 and 7: the count difference over a control period is a speed estimate every
    rig controller can form from the same encoders, far less noisy than the 1 kHz
    difference (one count in 50 ms is 0.063 rad/s at 2000 counts/rev, against 3.14 rad/s
    per count at 1 kHz), and it shows the average over the period where 0 and 1 show the
    end value; the nominal voltage is the feedforward that the operator's set point implies
    through the nominal model (eq. 20), known to any controller designer. The true state
    is never in the observation; it is in ``info["true_state"]``.

    ## Rewards

    Six non-negative cost terms per step, reported unweighted in ``info["rewards"]``
    (averages over the ``control_dt / Ts`` true samples of the step; ``w*`` is the target
    speed, ``s = max(w*, 1 rad/s)``):

    * ``tracking``: the lower-disk speed error, by ``tracking_cost``: from v3 (``"absolute"``)
      the mean of ``|x3 - w*| / (1 rad/s)``; up to v2 (``"relative_squared"``) the mean of
      ``((x3 - w*) / s)^2``;
    * ``stick``: fraction of the samples at which the lower disk is stuck;
    * ``oscillation``: mean of ``((x2 - x3) / s)^2``, the twist rate, zero only when the
      string turns as a rigid body (no torsional vibration);
    * ``effort``: ``((u - u_nom) / 5 V)^2``, the voltage beyond the feedforward;
    * ``integral``: ``|theta_l(t) - theta_l(t0) - w* (t - t0)| / (2 pi rad)`` at the end of
      the step, from the lower encoder (the unclipped ``lower_speed_error_integral`` of
      version 1, in revolutions), saturating at 0.5 (``_core.INTEGRAL_TERM_CAP``): the angle
      the bit has lost or gained against its target since the episode began, zero on
      average only when the mean speed is the target. The cap keeps an angle that cannot be
      won back (a bit held below its target at the 5 V limit) from costing more and more;
    * ``overdrive``: ``(|u_req| - 5 V) / 5 V`` where the voltage requested ``u_req`` is beyond
      the amplifier's limit, else 0: the other terms see only the voltage applied, so without
      this one a request beyond the limit costs nothing more than the limit itself.

    ``reward = -(1.0 tracking + 1.0 stick + 0.5 oscillation + 0.1 effort + 0 integral
    + 0 overdrive)`` with the default ``reward_weights`` (no registered version weights the
    integral or overdrive terms; a training config may). The reward uses the true state (the
    simulator knows it), the integral term the lower encoder (as the observation does); a
    perfect controller at a stable operating point earns 0.

    ## Starting State

    Each episode draws an operating point (see ``task``): by default a regime uniformly
    from ``equilibrium``, ``limit_cycle`` (Hopf cycle without stick) and ``stick_slip``,
    then the nominal voltage uniformly within that regime's voltage range, computed from
    the nominal model (:func:`drill_env.envs.task.operating_regimes`: the Hopf point by
    Routh-Hurwitz, the stick-slip onset by simulation; with the brake 0.583 V and
    1.785 V). The target speed is the slip-equilibrium speed at that voltage.

    ``start="open_loop"`` (default): the rig is switched on at rest and driven open loop
    at the nominal voltage for ``warmup_time + U(0, warmup_jitter)`` seconds (20-25 s by
    default) with the sensors running for the last 0.2 s. The episode therefore starts
    where the paper's experiments are: on the open-loop behaviour at that operating point
    (equilibrium, limit cycle or stick-slip) at a random phase, and the controller is
    switched on. From rest the stick-slip cycles settle within about 10 s and the Hopf
    cycles within 20 s, except close to the Hopf point, where the cycle grows at a rate
    proportional to the distance from it and no fixed warm-up reaches it. Starting at rest (``start="rest"``) makes every episode a start-up
    transient through stick-slip, whatever the operating point; ``start="equilibrium"``
    puts the rig exactly on the (possibly unstable) slip equilibrium.

    ## Episode End

    There is no terminal state (``terminated`` is always False). Episodes are truncated
    after ``max_episode_steps`` (400 steps = 20 s, about five periods of the torsional
    cycle) by the registration's ``TimeLimit``, and early, with a ``RuntimeWarning`` and
    ``info["sim_status"] != 0``, if the simulator cannot continue.

    ## Arguments

    ```python
    env = gymnasium.make("DrillString-v3", control_dt=0.05, sensors={"counts_per_rev": 4096})
    ```

    * ``params``: preset name (``"brake"``, ``"no_brake"``), YAML path or ``RigParams``.
    * ``params_overrides``: dict of parameter changes, e.g. ``{"lower_static": 0.1}``.
    * ``design_params``: the *design model* (preset name, YAML path or ``RigParams``; default:
      ``params`` without its effects): the target speed, nominal voltage and regime of each
      episode, and what :meth:`ControllerSpec.from_env
      <drill_env.agents.controllers.base.ControllerSpec.from_env>` hands a controller, come from
      it; ``params`` is only the simulated plant (the truth).
    * ``control_dt`` [s]: hold period of the action, a multiple of the sensor period (0.05).
    * ``sensors``: :class:`~drill_env.sensors.SensorConfig` or a dict of its fields:
      ``counts_per_rev`` (2000, an assumption: the paper does not give it),
      ``sample_rate_hz`` (1000), ``cutoff_rad_s`` (200), ``filter_order`` (2),
      ``angle_noise_std`` [rad] (0), ``speed_noise_std`` [rad/s] (0), ``delay_samples`` (0).
    * ``task``: :class:`~drill_env.envs.task.TaskConfig` or a dict: ``regimes``,
      ``voltage_range`` [V], ``target_speed_range`` [rad/s], ``min_target_speed``
      [rad/s] (0.1: the equilibrium regime starts at uc1 where the speed is 0).
    * ``start``: ``"open_loop"`` (default), ``"rest"`` or ``"equilibrium"``;
      ``warmup_time`` [s] (20), ``warmup_jitter`` [s] (5).
    * ``reward_weights``: dict with ``tracking``, ``stick``, ``oscillation``, ``effort``,
      ``integral``, ``overdrive``.
    * ``tracking_cost``: ``"relative_squared"`` (default up to v2) or ``"absolute"`` (v3's):
      the form of the tracking term (see Rewards).
    * ``domain_randomization``: None/False (default), True (defaults of
      :class:`~drill_env.envs.config.DomainRandomization`: friction +-10 %, inertias
      +-5 %, encoders of 1000/2000/4000 counts, angle noise up to 0.5 mrad, speed noise up
      to 0.05 rad/s), or a dict of its fields. Drawn per episode from ``self.np_random``.
    * ``action_mode``: ``"normalized"`` (default up to v1), ``"voltage"`` or
      ``"correction"`` (v2's default); ``action_range`` [V] (correction only, in (0, 10],
      default 2): the voltage added at action 1.
    * ``normalize_observation``: True (default) or False.
    * ``rtol``, ``atol``: integration tolerances, by default those of
      :func:`drill_env.simulate` (1e-9, 1e-9); switching instants are located to 1e-12 s
      whatever the tolerances.
    * ``render_mode``: None, ``"rgb_array"`` or ``"human"``.
    * ``observation_version``: 0 or 1 (set by the registered id: 0 for ``-v0``, 1 from ``-v1`` on).
    * ``start_angle`` [rad]: where the disks stand (untwisted) before the warm-up, in
      ``[0, 2 pi)`` (default 0), or ``"random"``: uniform per episode. From the same angle
      every episode, the encoder angle at switch-on is tied to the phase of the open-loop
      cycle there, a correlation a policy observing the angles (v1) can learn and the rig
      does not have; training with ``"random"`` removes it. On the nominal model the angle
      changes nothing else (friction depends on it only with position-dependent effects).

    * ``scenario``: None (default) or a name of the scenario suite
      (:data:`drill_env.envs.scenarios.SCENARIO_NAMES`, e.g. ``"start_up"``,
      ``"set_point_steps"``, ``"friction_drift"``): it sets ``start`` and fields of ``sensors``,
      makes its first set point the default operating point, and changes the set point and the
      plant's lower friction during the episode (:mod:`drill_env.envs.scenarios`); step infos
      then carry ``scenario``, ``target_speed``, ``nominal_voltage`` and ``friction_scale``.

    ``reset(seed=...)`` takes None or an integer >= 0 (NumPy integers included).
    ``reset(options=...)`` may fix the operating point with ``target_speed`` [rad/s],
    ``nominal_voltage`` [V] or ``regime`` (one of them), and the start with ``start``.

    ## Info

    ``true_state`` (twist, upper speed, lower speed, upper angle, lower angle; SI),
    ``upper_stuck``, ``lower_stuck``, ``time`` [s since the episode start], ``voltage``
    [V]; after a step also ``voltage_requested``, ``voltage_clipped``, ``rewards``,
    ``sim_status``; after a reset ``target_speed``, ``nominal_voltage``, ``regime``.
    :meth:`last_step_samples` returns the true 1 kHz samples of the last step.

    ## Version History

    * v3: the tracking term is the absolute speed error ``|x3 - w*|`` in rad/s
      (``tracking_cost="absolute"``); action, observation, dynamics and episodes as v2 (the
      same seed gives the same episode). v2's ``((x3 - w*) / max(w*, 1 rad/s))^2`` made a
      steady error at a target of 8 rad/s cost 1/64 of the same error at 1 rad/s and a
      0.02 rad/s error 1/2500 of a 1 rad/s transient: from scratch, policies kept steady
      errors of 0.02-0.26 rad/s at 1.35-5 V, up to ten times the LQI's, where the benchmark
      scores the error in rad/s. The absolute square, tried first, let the transients of the
      fast stick-slip cycles outweigh everything else (PPO with the brake left errors of
      0.1-0.8 rad/s everywhere).
    * v2: the action is the correction to the nominal voltage, +-2 V
      (``action_mode="correction"``, ``action_range=2.0``); observation, dynamics, reward
      and episodes as v1 (the same seed gives the same episode). Learning from scratch
      takes seconds where it took more than 5 minutes on v1 (see Action Space).
    * v1: the observation adds sin/cos of both encoder angles and the integrated lower
      speed error (entries 8-12); dynamics, reward, action and episodes unchanged (the
      same seed gives the same episode as v0). ``info["integral_clipped"]``.
    * v0: initial version (8 observation entries); kept registered so that v0 policies
      (``results/agents/v0/``) load and run.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 20}

    def __init__(
        self,
        params: RigParams | str | Path = "brake",
        params_overrides: Mapping[str, Any] | None = None,
        control_dt: float = 0.05,
        sensors: SensorConfig | Mapping[str, Any] | None = None,
        task: TaskConfig | Mapping[str, Any] | None = None,
        start: str = "open_loop",
        warmup_time: float = 20.0,
        warmup_jitter: float = 5.0,
        reward_weights: RewardWeights | Mapping[str, float] | None = None,
        domain_randomization: DomainRandomization | Mapping[str, Any] | bool | None = None,
        action_mode: str = "normalized",
        normalize_observation: bool = True,
        rtol: float = DEFAULT_RTOL,
        atol: float = DEFAULT_ATOL,
        render_mode: str | None = None,
        observation_version: int = 0,
        start_angle: float | str = 0.0,
        design_params: RigParams | str | Path | None = None,
        action_range: float | None = None,
        tracking_cost: str = "relative_squared",
        scenario: str | None = None,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode: {render_mode!r} is not one of {self.metadata['render_modes']} or None"
            )
        self.settings = s = EnvSettings(
            params=params,
            params_overrides=params_overrides,
            control_dt=control_dt,
            sensors=sensors,
            task=task,
            start=start,
            warmup_time=warmup_time,
            warmup_jitter=warmup_jitter,
            reward_weights=reward_weights,
            domain_randomization=domain_randomization,
            action_mode=action_mode,
            normalize_observation=normalize_observation,
            rtol=rtol,
            atol=atol,
            observation_version=observation_version,
            start_angle=start_angle,
            design_params=design_params,
            action_range=action_range,
            tracking_cost=tracking_cost,
            scenario=scenario,
        )
        self.render_mode = render_mode
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / s.control_dt)))
        self.control_dt = s.control_dt
        self.action_space = s.action_space()
        self.observation_space = s.observation_space()
        self._action_to_volts = s.action_to_volts
        # the action space's bound with its float32 rounding (check_actions's)
        self._action_high = float(s.action_space().high[0]) * (1.0 + float(np.finfo(np.float32).eps))
        self._action_offset = s.action_offset
        self._ecfg = s.ecfg
        n = s.n_sub
        self._p = s.params.as_array()
        self._scfg = s.sensors.as_array()
        self._y = np.zeros(L.NY)
        self._modes = np.zeros(2, dtype=np.int64)
        self._ep = np.zeros(C.NEP)
        self._sst = np.zeros(s.sensor_state_size)
        self._rng = np.zeros(4, dtype=np.uint64)
        self._obs = np.zeros(s.n_obs, dtype=np.float32)
        self._v1 = s.observation_version >= 1
        self._out = np.zeros(C.NOUT)
        self._ybuf = np.zeros((n, L.NY))
        self._mbuf = np.zeros((n, 2), dtype=np.int64)
        self._ubuf = np.zeros(n)
        self._samples_valid = False
        self._episode: EpisodeSetup | None = None
        self._ts = s.sensors.sample_period
        self._history: deque | None = None
        self._renderer = None
        self._schedule = s.schedule  # the scenario's changes during an episode (None: none)
        self._points: list[Any] = []
        self._p_base = self._p.copy()

    # -- Gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=check_seed(seed))
        opts = self.settings.parse_options(options)
        setup = self.settings.draw_episode(self.np_random, opts)
        status = self._reset_rig(setup)
        for _ in range(MAX_WARMUP_RETRIES):
            if status == 0:
                break
            # The simulator stopped during the warm-up: a different warm-up length avoids
            # the failing instant.
            setup = _with_warm_ticks(setup, self.settings.draw_warm_ticks(self.np_random))
            status = self._reset_rig(setup)
        if status != 0:
            raise RuntimeError(f"reset: the warm-up simulation failed: {STATUS_MESSAGES[status]}")
        self._episode = setup
        self._samples_valid = setup.start == C.START_OPEN_LOOP
        if self.render_mode is not None:
            self._history = deque(maxlen=int(round(10.0 / self.control_dt)) + 1)
            self._record_history()
            if self.render_mode == "human":
                self.render()
        return self._obs.copy(), self._reset_info(setup)

    def step(self, action):
        if (
            type(action) is np.ndarray
            and action.shape == (1,)
            and action.dtype.kind == "f"
            and abs(float(action[0])) <= self._action_high
        ):
            a = float(action[0])  # the common case, checked at once
        else:
            a = float(check_actions(action, "action", (1,), self._action_high)[0])
        if self._episode is None:
            raise gym.error.ResetNeeded("step: call reset() before step()")
        u_req = a * self._action_to_volts
        if self._action_offset:
            u_req = u_req + float(self._ep[C.EP_UNOM])
        out = self._out
        status = C.rig_step(
            self._p,
            self._y,
            self._modes,
            self._ep,
            self._ecfg,
            self._scfg,
            self._sst,
            self._rng,
            u_req,
            self._obs,
            out,
            self._ybuf,
            self._mbuf,
            self._ubuf,
        )
        u = float(self._ep[C.EP_U])  # the request within the amplifier's limit (the core applies it)
        clipped = u != u_req
        self._samples_valid = True
        t = float(self._ep[C.EP_TICK] - self._ep[C.EP_TICK0]) * self._ts
        if self._schedule is not None:
            # the scenario's set point and friction from now on (the observation shows the set point)
            self._schedule.apply(
                t, self._points, self._p_base, self._p, self._ep, self._obs,
                C.OB_TARGET, C.OB_UNOM, C.EP_TARGET, C.EP_UNOM,
            )  # fmt: skip
        info = {
            "true_state": out[C.O_TRUE : C.O_TRUE + C.N_TRUE].copy(),
            "upper_stuck": bool(out[C.O_UPPER_STUCK]),
            "lower_stuck": bool(out[C.O_LOWER_STUCK]),
            "time": t,
            "voltage": u,
            "voltage_requested": u_req,
            "voltage_clipped": clipped,
            "rewards": {name: float(out[j]) for name, j in zip(REWARD_NAMES, C.REWARD_SLOTS, strict=True)},
            "sim_status": status,
        }
        if self._v1:
            info["integral_clipped"] = bool(out[C.O_INT_CLIPPED])
        if self.settings.scenario is not None:
            self._scenario_info(info, t)
        truncated = False
        if status != 0:
            truncated = True
            warnings.warn(
                f"DrillStringEnv.step: the simulator stopped ({STATUS_MESSAGES[status]}); "
                "the episode is truncated",
                RuntimeWarning,
                stacklevel=2,
            )
        if self._history is not None:
            self._record_history()
            if self.render_mode == "human":
                self.render()
        return self._obs.copy(), float(out[C.O_REWARD]), False, truncated, info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn(
                "render: no render_mode was given; use gymnasium.make(..., render_mode='rgb_array')"
            )
            return None
        if self._renderer is None:
            from drill_env.envs.rendering import RigRenderer

            self._renderer = RigRenderer(self.render_mode, fps=self.metadata["render_fps"])
        return self._renderer.draw(self._render_state())

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- extras ----------------------------------------------------------------------------------
    @property
    def operating_point(self):
        """The current episode's :class:`~drill_env.envs.task.OperatingPoint` (None before reset)."""
        return None if self._episode is None else self._episode.point

    @property
    def true_params(self) -> RigParams:
        """The plant simulated in this episode (randomised, or the nominal parameters)."""
        return self.settings.params if self._episode is None else self._episode.plant

    @property
    def sensor_config(self) -> SensorConfig:
        """The measurement chain of this episode (randomised, or as configured)."""
        return self.settings.sensors if self._episode is None else self._episode.sensor_config

    def last_step_samples(self) -> dict[str, np.ndarray]:
        """True state at each sensor sample of the last step (or of the end of the warm-up).

        Keys: ``t`` [s since the episode start], ``upper_angle``, ``lower_angle``,
        ``twist`` [rad], ``upper_speed``, ``lower_speed`` [rad/s], ``upper_stuck``,
        ``lower_stuck`` (bool), ``voltage`` [V].
        """
        if not self._samples_valid:
            raise RuntimeError("last_step_samples: no step has been simulated since the reset")
        n = self.settings.n_sub
        ticks = self._ep[C.EP_TICK] - self._ep[C.EP_TICK0] - n + 1 + np.arange(n)
        yb = self._ybuf
        return {
            "t": ticks * self._ts,
            "upper_angle": yb[:, L.X1] + yb[:, L.THL],
            "lower_angle": yb[:, L.THL].copy(),
            "twist": yb[:, L.X1].copy(),
            "upper_speed": yb[:, L.X2].copy(),
            "lower_speed": yb[:, L.X3].copy(),
            "upper_stuck": self._mbuf[:, 0] == 0,
            "lower_stuck": self._mbuf[:, 1] == 0,
            "voltage": self._ubuf.copy(),
        }

    # -- internals -------------------------------------------------------------------------------
    def _scenario_info(self, info: dict[str, Any], t: float) -> None:
        # the set point and friction factor in force for the next control period
        scenario = self.settings.scenario
        assert scenario is not None  # called only for a scenario
        info["scenario"] = scenario.name
        info["target_speed"] = float(self._ep[C.EP_TARGET])
        info["nominal_voltage"] = float(self._ep[C.EP_UNOM])
        info["friction_scale"] = scenario.friction_factor(t)

    def _reset_rig(self, setup: EpisodeSetup) -> int:
        self._p = setup.params.copy()
        if self._schedule is not None:
            # the warm-up runs with the friction of the switch-on
            self._p_base = setup.params.copy()
            self._points = self._schedule.episode_points(setup.point)
            self._schedule.scale_friction(0.0, self._p_base, self._p)
        self._scfg = setup.sensors.copy()
        self._rng[:] = setup.rng
        pt = setup.point
        return int(
            C.rig_reset(
                self._p,
                self._y,
                self._modes,
                self._ep,
                self._ecfg,
                self._scfg,
                self._sst,
                self._rng,
                setup.y0,
                setup.start,
                setup.warm_ticks,
                pt.target_speed,
                pt.nominal_voltage,
                self._obs,
                self._out,
                self._ybuf,
                self._mbuf,
                self._ubuf,
            )
        )

    def _reset_info(self, setup: EpisodeSetup) -> dict[str, Any]:
        out = self._out
        info = {
            "true_state": out[C.O_TRUE : C.O_TRUE + C.N_TRUE].copy(),
            "upper_stuck": bool(out[C.O_UPPER_STUCK]),
            "lower_stuck": bool(out[C.O_LOWER_STUCK]),
            "time": 0.0,
            "voltage": float(self._ep[C.EP_U]),
            "target_speed": setup.point.target_speed,
            "nominal_voltage": setup.point.nominal_voltage,
            "regime": setup.point.regime,
        }
        if self._v1:
            info["integral_clipped"] = bool(out[C.O_INT_CLIPPED])
        if self.settings.scenario is not None:
            info["scenario"] = self.settings.scenario.name
            info["friction_scale"] = self.settings.scenario.friction_factor(0.0)
        return info

    def _physical_obs(self) -> np.ndarray:
        return self._obs.astype(np.float64) * self._ecfg[C.EC_SCALE : C.EC_SCALE + self.settings.n_obs]

    def _record_history(self) -> None:
        assert self._history is not None  # recorded only while rendering
        phys = self._physical_obs()
        self._history.append(
            (
                (self._ep[C.EP_TICK] - self._ep[C.EP_TICK0]) * self._ts,
                self._y[L.X2],
                self._y[L.X3],
                phys[C.OB_UPPER_SPEED],
                phys[C.OB_LOWER_SPEED],
                phys[C.OB_TARGET],
                phys[C.OB_VOLTAGE],
            )
        )

    def _render_state(self) -> dict[str, Any]:
        hist = np.array(self._history) if self._history else np.zeros((0, 7))
        return {
            "upper_angle": self._y[L.X1] + self._y[L.THL],
            "lower_angle": self._y[L.THL],
            "lower_stuck": self._modes[1] == 0,
            "voltage": self._ep[C.EP_U],
            "history": hist,
            "params_name": self.settings.params.name,
            "regime": None if self._episode is None else self._episode.point.regime,
        }

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_renderer"] = None  # figures do not pickle; a new one is made on demand
        return state


def _with_warm_ticks(setup: EpisodeSetup, warm_ticks: int) -> EpisodeSetup:
    return dataclasses.replace(setup, warm_ticks=warm_ticks)
