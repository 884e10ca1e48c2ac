"""Warm start: behaviour cloning of a classical controller before reinforcement learning.

A training config asks for it with ``warm_start: {controller: lqi, steps: 100000, ...}``
(:class:`WarmStartConfig`). Before the first rollout, the controller (built with the tuned
gains of ``configs/agents/controllers.yaml`` on the nominal model of the training
environment, as the base of a residual policy) drives ``n_envs`` rigs of the training
environment for ``steps`` env-steps, and the policy's deterministic action is fitted to the
controller's by least squares over those observations. Reinforcement learning then starts
from a policy that already regulates the rig instead of from noise.

The rigs receive the controller's action plus Gaussian noise of ``action_noise`` (in action
units, 1 = 5 V), while the label stays the controller's clean action: the data then covers
the states a slightly wrong policy drives the rig into, and the clone learns how the
controller recovers from them (noise injection, Laskey et al., "DART", CoRL 2017), which a
clone of noise-free rollouts never sees. With ``rounds`` > 1, each further round lets the
clone drive (plus the same noise) for another ``steps`` env-steps while the controller labels
what it would have done, and the policy is fitted again on everything collected (DAgger,
Ross, Gordon & Bagnell, AISTATS 2011): the states the clone itself reaches are then in the
data.

The value network is fitted too, to the discounted returns of the same rollouts (rewards as
the training sees them: divided by the running return scale of ``VecNormalize`` when the
config normalises the reward), so that the first policy-gradient steps use advantages of a
critic that knows the cloned policy rather than of a random one.

The observation of the policy must carry what the controller uses (in ``DrillString-v1``
the integrated speed error plays the LQI's integrator); the clone is a function of the
current observation only, the controller may keep state.

Distillation into a residual policy
-----------------------------------
A residual config (:mod:`drill_env.agents.learning.residual`) starts as its base controller already,
so ``warm_start.controller`` is refused there; ``warm_start: {policy: ppo_lqi_clone, ...}`` instead
starts it as a *trained* policy (the teacher: a learned controller of the benchmark,
:data:`WARM_START_POLICIES`, loaded as the benchmark loads it for the training env's preset,
from the default agents folder) plus the base's adaptive feedforward. The correction
labelling each observation is

    label = clip((a_teacher + a_ff - a_base) / scale, -1, 1)

with ``a_base`` the base's action and ``a_ff`` the share of its feedforward in it
(:func:`drill_env.agents.learning.residual.step_base`; for ``lqi_angle_ff`` the angle-locked
harmonics, 0 for a base without feedforward): the residual action ``base + scale * label``
is the teacher's voltage plus the feedforward wherever the clip is inactive, and the label
is ``(a_teacher - a_base_feedback) / scale`` wherever the base is off the voltage limit. The
base's state is stepped by its own ``predict`` at every observation and reset at episode
starts, as the residual training rigs and the residual policy step it. The first round's
rigs are driven by teacher + feedforward (plus the noise), the later rounds' by the residual
policy being fitted (base + scale * correction, plus the noise), labelled as above (DAgger).
Without ``residual``, ``policy`` is refused (a plain policy is not distilled).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from drill_env.agents.learning._config import config_section
from drill_env.envs import make_version

__all__ = [
    "WARM_START_CONTROLLERS",
    "WARM_START_POLICIES",
    "WarmStartConfig",
    "collect_demonstrations",
    "warm_start",
]

# The classical controllers a policy can be cloned from: those with tuned gains.
WARM_START_CONTROLLERS = ("lqi", "lqi_angle_ff", "torque_feedback", "pi_upper", "pi_lower")
# The trained policies a residual policy can be distilled from: the plain learned controllers
# of the benchmark (drill_env.agents.registry.LEARNED without ppo_robust and sac_robust,
# themselves residual policies on lqi_angle_ff whose voltage carries the feedforward already).
WARM_START_POLICIES = ("ppo", "sac", "ppo_lqi_clone")


@dataclass(frozen=True)
class WarmStartConfig:
    """``warm_start`` of a training config (see the module docstring)."""

    controller: str | None = None  # classical controller to clone; neither this nor policy: lqi
    policy: str | None = None  # trained policy to distil into a residual policy
    steps: int = 100_000  # env-steps of the controller's rollouts
    epochs: int = 20  # passes of the regression over the rollouts
    batch_size: int = 1024
    learning_rate: float = 1.0e-3  # Adam step of the regression, decayed linearly to 0 in each fit
    action_noise: float = 0.1  # [action units, 1 = 5 V] std of the noise on the applied action
    rounds: int = 1  # data-aggregation rounds: after the first, the clone drives and the controller labels

    def __post_init__(self) -> None:
        if self.controller is not None and self.policy is not None:
            raise ValueError(
                "warm_start: give controller (a classical controller to clone) or policy "
                "(a trained policy to distil into a residual policy), not both"
            )
        if self.policy is not None:
            if not isinstance(self.policy, str) or self.policy not in WARM_START_POLICIES:
                raise ValueError(
                    f"warm_start.policy: {self.policy!r} is not one of {list(WARM_START_POLICIES)}"
                )
        elif self.controller is None:
            object.__setattr__(self, "controller", "lqi")
        elif not isinstance(self.controller, str) or self.controller not in WARM_START_CONTROLLERS:
            raise ValueError(
                f"warm_start.controller: {self.controller!r} is not one of {list(WARM_START_CONTROLLERS)}"
            )
        for name in ("steps", "epochs", "batch_size", "rounds"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"warm_start.{name}: expected an integer >= 1, got {v!r}")
        lr = self.learning_rate
        if (
            isinstance(lr, bool)
            or not isinstance(lr, (int, float))
            or not (math.isfinite(lr) and 0 < lr <= 1)
        ):
            raise ValueError(f"warm_start.learning_rate: {lr!r} is outside the allowed range (0, 1]")
        s = self.action_noise
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not (math.isfinite(s) and 0 <= s <= 1):
            raise ValueError(f"warm_start.action_noise: {s!r} is outside the allowed range [0, 1]")
        object.__setattr__(self, "learning_rate", float(lr))
        object.__setattr__(self, "action_noise", float(s))

    @classmethod
    def from_any(cls, value: Any) -> WarmStartConfig | None:
        return config_section(cls, value, "warm_start")

    def to_dict(self) -> dict[str, Any]:
        teacher = {"policy": self.policy} if self.policy is not None else {"controller": self.controller}
        return {
            **teacher,
            "steps": self.steps,
            "epochs": self.epochs,
            "batch_size": self.batch_size,
            "learning_rate": self.learning_rate,
            "action_noise": self.action_noise,
            "rounds": self.rounds,
        }


def collect_demonstrations(
    venv: Any,
    controller: Any,
    steps: int,
    action_noise: float,
    gamma: float,
    seed: int,
    driver: Callable[[np.ndarray], np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """Run ``controller`` (plus noise) on the SB3 ``venv`` for at least ``steps`` env-steps;
    with ``driver`` (observations -> actions), the driver's action (plus noise) is applied
    and the controller only labels the observations (data aggregation).

    Returns ``obs`` (n, n_obs), the controller's clean ``action`` (n, n_act) and the
    discounted ``returns`` (n,) of the rewards from each observation on (episodes cut by the
    rollout's end are completed with the last reward's geometric tail) and the
    ``running_returns`` (n,), the discounted sum of the episode's rewards up to each step.
    """
    rng = np.random.default_rng(seed)
    n_envs = venv.num_envs
    n_rounds = -(-steps // n_envs)
    obs = venv.reset()
    state, start = None, np.ones(n_envs, dtype=bool)
    low, high = venv.action_space.low, venv.action_space.high
    all_obs, all_act = [], []
    rewards = np.zeros((n_rounds, n_envs))
    dones = np.zeros((n_rounds, n_envs), dtype=bool)
    for k in range(n_rounds):
        action, state = controller.predict(obs, state=state, episode_start=start)
        action = np.asarray(action, dtype=np.float32).reshape(n_envs, -1)
        all_obs.append(np.array(obs, dtype=np.float32))
        all_act.append(action)
        if driver is not None:
            action_applied = np.asarray(driver(obs), dtype=np.float32).reshape(n_envs, -1)
        else:
            action_applied = action
        applied = action_applied + (action_noise * rng.standard_normal(action.shape)).astype(np.float32)
        obs, reward, done, _ = venv.step(np.clip(applied, low, high))
        rewards[k], dones[k] = reward, done
        start = np.asarray(done, dtype=bool).copy()
    running = np.zeros_like(rewards)  # VecNormalize's statistic: the return so far, discounted
    acc = np.zeros(n_envs)
    for k in range(n_rounds):
        acc = acc * gamma + rewards[k]
        running[k] = acc
        acc[dones[k]] = 0.0
    returns = np.zeros_like(rewards)
    tail = rewards[-1] / (1.0 - gamma)
    for k in range(n_rounds - 1, -1, -1):
        tail = rewards[k] + gamma * np.where(dones[k], 0.0, tail)
        returns[k] = tail
    return {
        "obs": np.concatenate(all_obs),
        "action": np.concatenate(all_act),
        "returns": returns.reshape(-1),
        "running_returns": running.reshape(-1),
    }


def _fit(model: Any, data: dict[str, np.ndarray], cfg: WarmStartConfig, seed: int) -> dict[str, float]:
    """Least-squares fit of the policy's deterministic action (and of the value, if the
    policy has one) to the demonstrations; the losses before and after."""
    import torch

    policy = model.policy
    obs = torch.as_tensor(data["obs"])
    target = np.clip(data["action"], model.action_space.low, model.action_space.high)
    if getattr(policy, "squash_output", False) or hasattr(policy, "actor"):
        target = policy.scale_action(target)  # SAC acts in [-1, 1] before unscaling
    target_t = torch.as_tensor(target, dtype=torch.float32)
    has_value = hasattr(policy, "predict_values")
    returns = torch.as_tensor(data["returns"], dtype=torch.float32).reshape(-1, 1)

    def actor_out(x):
        return policy._predict(x, deterministic=True).reshape(x.shape[0], -1)

    params = list(policy.parameters())
    opt = torch.optim.Adam(params, lr=cfg.learning_rate)
    gen = torch.Generator().manual_seed(seed)
    n = obs.shape[0]

    def losses() -> tuple[float, float]:
        with torch.no_grad():
            a = float(torch.mean((actor_out(obs) - target_t) ** 2))
            v = float(torch.mean((policy.predict_values(obs) - returns) ** 2)) if has_value else math.nan
        return a, v

    before = losses()
    policy.set_training_mode(True)
    n_steps, step = cfg.epochs * -(-n // cfg.batch_size), 0
    for _ in range(cfg.epochs):
        perm = torch.randperm(n, generator=gen)
        for i in range(0, n, cfg.batch_size):
            idx = perm[i : i + cfg.batch_size]
            # the step decays linearly to 0: a fit ends at the minimum rather than in the noise
            # a constant step leaves around it
            for group in opt.param_groups:
                group["lr"] = cfg.learning_rate * (1.0 - step / n_steps)
            step += 1
            loss = torch.mean((actor_out(obs[idx]) - target_t[idx]) ** 2)
            if has_value:
                loss = loss + 0.5 * torch.mean((policy.predict_values(obs[idx]) - returns[idx]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
    policy.set_training_mode(False)
    after = losses()
    return {
        "action_mse_before": before[0],
        "action_mse_after": after[0],
        "value_mse_before": before[1],
        "value_mse_after": after[1],
    }


def nominal_controller(kind: str, env_id: str, env_kwargs: Mapping[str, Any]) -> Any:
    """Classical controller ``kind`` with its tuned gains, designed on the nominal model of the
    training environment (``env_kwargs`` without its domain randomisation)."""

    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.gains import classical_controller
    from drill_env.envs import ENV_IDS

    kwargs = {k: v for k, v in env_kwargs.items() if k != "domain_randomization"}
    env = make_version(env_id, **kwargs)
    try:
        spec = ControllerSpec.from_env(env)
    finally:
        env.close()
    return classical_controller(kind, spec, ENV_IDS[env_id])


class ResidualLabels:
    """The labeller of a distillation (module docstring) behind ``predict``, for
    :func:`collect_demonstrations`: ``predict(obs, state, episode_start)`` returns the
    correction labels and the state (the teacher's, the base's). Each call also keeps, for
    the rollout's driver, the base's action (``base_action``) and the action the residual
    policy should apply (``target``: teacher + feedforward) at those observations."""

    def __init__(self, teacher: Any, base: Any, scale: float):
        self.teacher, self.base, self.scale = teacher, base, float(scale)
        self.base_action: np.ndarray | None = None
        self.target: np.ndarray | None = None

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        from drill_env.agents.learning.residual import correction_towards, step_base

        teacher_state, base_state = (None, None) if state is None else state
        obs = np.asarray(observation, dtype=np.float32)
        a_teacher, teacher_state = self.teacher.predict(
            obs, state=teacher_state, episode_start=episode_start, deterministic=True
        )
        a_base, a_ff, base_state = step_base(self.base, obs, base_state, episode_start)
        a_teacher = np.asarray(a_teacher, dtype=np.float32).reshape(a_base.shape)
        self.base_action = a_base
        self.target = a_teacher + a_ff
        return correction_towards(a_base, self.target, self.scale), (teacher_state, base_state)


def warm_start(
    model: Any,
    cfg: WarmStartConfig,
    env_id: str,
    env_kwargs: Mapping[str, Any],
    seed: int,
    residual: Any = None,
    teacher: Any = None,
) -> dict:
    """Clone ``cfg.controller`` into ``model``'s policy, or distil ``cfg.policy`` into the
    correction of a residual policy on ``residual`` (a
    :class:`~drill_env.agents.learning.residual.ResidualConfig`; see the module docstring), on
    ``model.n_envs`` rigs seeded apart from the training rigs; ``teacher`` is the loaded
    ``cfg.policy`` (:func:`drill_env.agents.registry.teacher_policy`: the registry sits above
    this module). Returns what it did: the teacher, steps, wall time, losses."""
    from stable_baselines3.common.vec_env import VecNormalize

    from drill_env.agents.learning.residual import _combine, base_controller
    from drill_env.envs.sb3 import sb3_vec_env

    t0 = time.perf_counter()

    def clone(obs: np.ndarray) -> np.ndarray:
        return model.predict(obs, deterministic=True)[0]

    first_driver: Callable[[np.ndarray], np.ndarray] | None = None
    later_driver: Callable[[np.ndarray], np.ndarray] = clone
    if cfg.policy is not None:
        if residual is None:
            raise ValueError(
                "warm_start.policy: allowed only with residual (a trained policy is distilled into "
                "the correction of a residual policy)"
            )
        if teacher is None:
            raise ValueError(
                f"warm_start.policy: {cfg.policy!r} must be loaded by the caller and passed as the "
                "teacher (drill_env.agents.registry.teacher_policy)"
            )
        labels = ResidualLabels(
            teacher,
            base_controller(residual, env_id, env_kwargs),
            residual.scale,
        )
        controller: Any = labels

        def teacher_drives(obs: np.ndarray) -> np.ndarray:
            return labels.target  # teacher + feedforward at these observations

        def residual_drives(obs: np.ndarray) -> np.ndarray:
            return _combine(labels.base_action, clone(obs), labels.scale)

        first_driver, later_driver = teacher_drives, residual_drives
        source = {"policy": cfg.policy}
    else:
        if residual is not None:
            raise ValueError(
                "warm_start.controller: a residual policy starts as its base controller already; "
                "drop one (warm_start.policy distils a trained policy into it)"
            )
        controller = nominal_controller(cfg.controller, env_id, env_kwargs)
        source = {"controller": cfg.controller}
    gamma = float(getattr(model, "gamma", 0.99))
    train_env = model.get_env()
    return_scale = 1.0
    # seeds after the training rigs' (seed .. seed + n_envs - 1)
    venv = sb3_vec_env(env_id, model.n_envs, seed=seed + model.n_envs, **env_kwargs)
    data: dict[str, np.ndarray] = {}
    fits = []
    try:
        for r in range(cfg.rounds):
            driver = first_driver if r == 0 else later_driver
            new = collect_demonstrations(
                venv, controller, cfg.steps, cfg.action_noise, gamma, seed + r, driver=driver
            )
            if r == 0 and isinstance(train_env, VecNormalize) and train_env.norm_reward:
                # the learner sees rewards / sqrt(var of the running discounted return)
                # (VecNormalize): start the normaliser from the controller's statistics and fit
                # the value in its units
                train_env.ret_rms.update(new["running_returns"])
                return_scale = float(np.sqrt(train_env.ret_rms.var + train_env.epsilon))
            new["returns"] = new["returns"] / return_scale
            data = {k: np.concatenate([data[k], v]) if data else v for k, v in new.items()}
            fits.append(_fit(model, data, cfg, seed + r))
    finally:
        venv.close()
    return {
        **source,
        "steps": int(data["obs"].shape[0]),
        "rounds": cfg.rounds,
        "wall_time_s": time.perf_counter() - t0,
        "action_mse_before": fits[0]["action_mse_before"],
        "action_mse_after": fits[-1]["action_mse_after"],
        "value_mse_before": fits[0]["value_mse_before"],
        "value_mse_after": fits[-1]["value_mse_after"],
    }
