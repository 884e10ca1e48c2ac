"""Residual policies: a learned correction on top of a classical controller.

The voltage applied to the rig is the classical controller's plus a bounded correction,

    a = clip(a_base(obs) + scale * a_policy(obs), -1, 1)      (normalised actions, 1 = 5 V)

with ``a_policy`` in [-1, 1]: the policy can move the voltage by at most ``scale`` of the
amplifier range either way, and a policy that outputs zero is the classical controller
exactly. This is residual reinforcement learning (Johannink et al., ICRA 2019; for
vibration damping, Yonezawa et al., arXiv 2504.19715): the base controller carries the
regulation it was designed for (tracking, the integral action), the policy learns only what
the base misses on the plants it is trained on.

A training config asks for it with ``residual: {base: lqi, scale: 0.2}``
(:class:`ResidualConfig`). Two options start the learning from the base rather than from an
arbitrary correction, as residual policy learning does (Silver, Allen, Tenenbaum & Kaelbling,
arXiv 1812.06298, Sec. 4): ``zero_start: true`` zeroes the output layer of the policy's mean,
so the untrained policy *is* the base controller, with its exploration spread set by
``initial_log_std``; ``critic_burn_in: N`` (SAC only) trains the critics for the first N
env-steps while the actor stays as it started, so the actor's first updates follow a critic
that has seen the base's returns instead of an untrained one (:func:`start_from_base`,
:func:`critic_burn_in_callback`).

``observe_base: true`` also gives the correction what the base is doing, as residual policy
learning does (Silver et al., Sec. 3): its observation is the rig's followed by
:data:`BASE_OBSERVATIONS`, the base's action and the share of the base's adaptive feedforward
in it (normalised, 1 = 5 V; :func:`step_base`). A correction that sees only the measurements
cannot tell the feedforward, a function of what the base has adapted so far, from the rest
of the voltage. The saved policy's network then takes ``len(BASE_OBSERVATIONS)`` more inputs
than the rig has observations (:func:`observation_with_base`).

``base_options`` (``lqi_angle_ff`` only) set the base's feedforward options over those of the
gains file, e.g. ``{variable_step: true}``, which slows the adaptation where the error it sees
is noise (:mod:`drill_env.agents.controllers.angle_feedforward`); the saved policy's ``config.yaml`` records
them, and the base is rebuilt with them wherever the policy runs.

The base is built with the tuned gains of
``configs/agents/controllers.yaml`` on the nominal model of the training environment (domain
randomisation changes the plant, never the design), during training by
:class:`ResidualVecEnv` and at inference by :class:`ResidualPolicy`, both the same function
of the observation and of the base's state.

A residual policy's ``policy.zip`` holds the correction only: stable-baselines3's
``PPO.load`` / ``SAC.load`` of it alone would give a controller that applies the correction
without its base (about 0 V). Its zip therefore names, as its policy class, one of
:data:`CORRECTION_POLICY_CLASSES`: subclasses of stable-baselines3's classes whose
construction raises :class:`CorrectionOnlyError`, naming
:func:`drill_env.agents.learning.rl.load_policy`, which loads the file with stable-baselines3's
own class and adds the base from the ``config.yaml`` beside it.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from drill_env.agents.learning._config import config_section
from drill_env.envs import make_version

__all__ = [
    "BASE_OBSERVATIONS",
    "CORRECTION_POLICY_CLASSES",
    "CorrectionOnlyError",
    "correction_policy_class",
    "saved_as_correction",
    "RESIDUAL_BASES",
    "ResidualConfig",
    "ResidualPolicy",
    "ResidualVecEnv",
    "base_controller",
    "correction_towards",
    "critic_burn_in_callback",
    "observation_with_base",
    "start_from_base",
    "step_base",
]

# Classical controllers a policy can act on top of (those with integral action and tuned gains).
RESIDUAL_BASES = ("lqi", "lqi_angle_ff", "torque_feedback")

# What an ``observe_base`` correction sees after the rig's observation: the base's action and
# its adaptive feedforward's share, both normalised (1 = 5 V).
BASE_OBSERVATIONS = ("base_action", "base_feedforward")


# -- the policy class a residual policy's zip names ----------------------------------------------

# algorithm -> (the class a residual policy's zip names, the stable-baselines3 class it stands
# for: the MlpPolicy of that algorithm, which drill-env train builds)
CORRECTION_POLICY_CLASSES = {
    "ppo": ("ResidualCorrectionActorCriticPolicy", "stable_baselines3.common.policies", "ActorCriticPolicy"),
    "sac": ("ResidualCorrectionSACPolicy", "stable_baselines3.sac.policies", "SACPolicy"),
}


class CorrectionOnlyError(TypeError):
    """A residual policy's correction was loaded as if it were a whole controller."""


CORRECTION_ONLY_MESSAGE = (
    "this stable-baselines3 file holds only the learned correction of a residual policy "
    "(drill_env.agents.learning.residual), not a whole controller: loaded on its own it would apply "
    "the correction without its base controller (about 0 V). Load it with "
    "drill_env.agents.learning.rl.load_policy(path), which adds the base named in the config.yaml "
    "beside the file"
)


def _refuse_correction_only(self: Any, *args: Any, **kwargs: Any) -> None:
    raise CorrectionOnlyError(CORRECTION_ONLY_MESSAGE)


def _correction_class(name: str) -> type:
    """The class ``name`` of :data:`CORRECTION_POLICY_CLASSES`, built once on first use (so
    that importing this module does not import torch) and kept as a module attribute, under
    which pickle finds it."""
    for class_name, module, base_name in CORRECTION_POLICY_CLASSES.values():
        if class_name == name:
            base = getattr(importlib.import_module(module), base_name)
            cls = type(
                name,
                (base,),
                {
                    "__init__": _refuse_correction_only,
                    "__module__": __name__,
                    "__qualname__": name,
                    "__doc__": f"Names a residual policy's correction in its zip; constructing it raises "
                    f"CorrectionOnlyError (load the file with load_policy, as {base_name}).",
                },
            )
            globals()[name] = cls
            return cls
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __getattr__(name: str) -> Any:  # the classes of CORRECTION_POLICY_CLASSES, built on demand
    return _correction_class(name)


def correction_policy_class(algo: str, *, stable_baselines3: bool = False) -> type:
    """The policy class a residual ``algo`` policy's zip names, or (``stable_baselines3=True``)
    the stable-baselines3 class it is loaded as."""
    if algo not in CORRECTION_POLICY_CLASSES:
        raise ValueError(f"algo: {algo!r} is not one of {list(CORRECTION_POLICY_CLASSES)}")
    name, module, base_name = CORRECTION_POLICY_CLASSES[algo]
    if stable_baselines3:
        return getattr(importlib.import_module(module), base_name)
    return globals().get(name) or _correction_class(name)


@contextmanager
def saved_as_correction(model: Any, algo: str) -> Iterator[None]:
    """While open, ``model.save`` writes the policy class of a residual policy's correction
    (:func:`correction_policy_class`) instead of stable-baselines3's; the model is unchanged."""
    sb3_class = correction_policy_class(algo, stable_baselines3=True)
    if model.policy_class is not sb3_class:
        raise ValueError(f"model: its policy class {model.policy_class.__name__} is not {sb3_class.__name__}")
    model.policy_class = correction_policy_class(algo)
    try:
        yield
    finally:
        model.policy_class = sb3_class


@dataclass(frozen=True)
class ResidualConfig:
    """``residual`` of a training config: the base controller and the correction's bound."""

    base: str = "lqi"
    scale: float = 0.2  # [-] largest correction, fraction of the action range (1 = 5 V)
    zero_start: bool = False  # zero the policy's mean output layer: the untrained policy is the base
    initial_log_std: float | None = None  # with zero_start: log of the initial exploration spread
    critic_burn_in: int = 0  # [env-steps] SAC: critics only, the actor frozen (0: none)
    observe_base: bool = False  # the correction also sees BASE_OBSERVATIONS
    base_options: Mapping[str, Any] | None = None  # lqi_angle_ff's options over the gains file's

    def __post_init__(self) -> None:
        if self.base not in RESIDUAL_BASES:
            raise ValueError(f"residual.base: {self.base!r} is not one of {list(RESIDUAL_BASES)}")
        s = self.scale
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not (math.isfinite(s) and 0 < s <= 1):
            raise ValueError(f"residual.scale: {s!r} is outside the allowed range (0, 1]")
        object.__setattr__(self, "scale", float(s))
        if not isinstance(self.zero_start, bool):
            raise ValueError(f"residual.zero_start: {self.zero_start!r} is not true or false")
        v = self.initial_log_std
        if v is not None:
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not (math.isfinite(v) and -10 <= v <= 2)
            ):
                raise ValueError(f"residual.initial_log_std: {v!r} is outside the allowed range [-10, 2]")
            if not self.zero_start:
                raise ValueError("residual.initial_log_std: allowed only with zero_start: true")
            object.__setattr__(self, "initial_log_std", float(v))
        if not isinstance(self.observe_base, bool):
            raise ValueError(f"residual.observe_base: {self.observe_base!r} is not true or false")
        n = self.critic_burn_in
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise ValueError(f"residual.critic_burn_in: {n!r} is not an integer >= 0")
        if self.base_options is not None:
            if self.base != "lqi_angle_ff":
                raise ValueError(
                    f"residual.base_options: allowed only with base lqi_angle_ff (the feedforward's "
                    f"options), not {self.base!r}"
                )
            from drill_env.agents.controllers.angle_feedforward import LQIAngleFeedforward

            opts = LQIAngleFeedforward.check_options(self.base_options, "residual.base_options")
            object.__setattr__(self, "base_options", opts or None)

    @classmethod
    def from_any(cls, value: Any) -> ResidualConfig | None:
        return config_section(cls, value, "residual")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"base": self.base, "scale": self.scale}
        if self.zero_start:
            out["zero_start"] = True
        if self.initial_log_std is not None:
            out["initial_log_std"] = self.initial_log_std
        if self.critic_burn_in:
            out["critic_burn_in"] = self.critic_burn_in
        if self.observe_base:
            out["observe_base"] = True
        if self.base_options:
            out["base_options"] = dict(self.base_options)
        return out


def start_from_base(model: Any, cfg: ResidualConfig) -> None:
    """Make an untrained SB3 PPO or SAC ``model`` start as its base controller
    (``cfg.zero_start``): the last layer of the action mean is zeroed, so the deterministic
    correction is exactly 0 whatever the observation; its exploration spread is
    ``exp(cfg.initial_log_std)`` (pre-squash for SAC) where given. Nothing happens without
    ``zero_start``."""
    import torch

    if not cfg.zero_start:
        return
    policy = model.policy
    with torch.no_grad():
        if hasattr(policy, "actor"):  # SAC: mu and log_std are linear layers of the latent
            actor = policy.actor
            actor.mu.weight.zero_()
            actor.mu.bias.zero_()
            if cfg.initial_log_std is not None:
                actor.log_std.weight.zero_()
                actor.log_std.bias.fill_(cfg.initial_log_std)
        else:  # PPO: action_net is the mean, log_std a free parameter
            policy.action_net.weight.zero_()
            policy.action_net.bias.zero_()
            if cfg.initial_log_std is not None:
                policy.log_std.fill_(cfg.initial_log_std)


def critic_burn_in_callback(model: Any, cfg: ResidualConfig):
    """An SB3 callback that keeps a SAC actor frozen (no gradient reaches it, its optimiser
    skips it) in every gradient step taken before ``cfg.critic_burn_in`` env-steps have been
    collected, while the critics and the entropy coefficient learn; None where there is no
    burn-in."""
    if not cfg.critic_burn_in:
        return None
    if not hasattr(model.policy, "actor"):
        raise ValueError(
            "residual.critic_burn_in: allowed only for SAC (an actor-critic with a replay buffer)"
        )
    from stable_baselines3.common.callbacks import BaseCallback

    actor = model.policy.actor
    steps = cfg.critic_burn_in

    class _BurnIn(BaseCallback):
        def _set(self, trainable: bool) -> None:
            for p in actor.parameters():
                p.requires_grad_(trainable)

        def _on_training_start(self) -> None:
            self._set(False)

        def _on_step(self) -> bool:
            if self.num_timesteps >= steps:
                self._set(True)
            return True

        def _on_training_end(self) -> None:
            self._set(True)

    return _BurnIn()


def base_controller(cfg: ResidualConfig, env_id: str, env_kwargs: Mapping[str, Any]):
    """The classical base of a residual policy, designed on the nominal model of the training
    environment (``env_kwargs`` without its domain randomisation)."""

    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.gains import classical_controller
    from drill_env.envs import ENV_IDS

    kwargs = {k: v for k, v in env_kwargs.items() if k != "domain_randomization"}
    env = make_version(env_id, **kwargs)
    try:
        spec = ControllerSpec.from_env(env)
    finally:
        env.close()
    return classical_controller(cfg.base, spec, ENV_IDS[env_id], options=cfg.base_options)


def step_base(
    base: Any, observation: np.ndarray, state: np.ndarray | None, episode_start: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step of the base controller on a batch of rigs, as :class:`ResidualVecEnv` and
    :class:`ResidualPolicy` take it (``base.predict``, rows where an episode starts reset
    from their observation), plus the share of the base's adaptive feedforward in its action.

    Returns ``(action (n, 1), feedforward (n, 1), next state)``: the feedforward is
    ``base.feedforward(y, state)`` [V] in action units (1 = 5 V), 0 for a base without one
    (``lqi``, ``torque_feedback``); the base's feedback is ``action - feedforward`` wherever
    the voltage is off the amplifier's limit.
    """
    spec = base.spec
    obs = np.asarray(observation).reshape(-1, len(spec.observation_names))
    y = spec.to_physical(obs)
    state = base.start_state(y, state, episode_start)
    if hasattr(base, "feedforward"):
        volts = np.asarray(base.feedforward(y, state), dtype=np.float64)
    else:
        volts = np.zeros(len(y))
    feedforward = (volts / spec.action_to_volts).astype(np.float32).reshape(-1, 1)
    action, state = base.predict(obs, state=state)
    return action, feedforward, state


def observation_with_base(
    observation: np.ndarray, base_action: np.ndarray, feedforward: np.ndarray
) -> np.ndarray:
    """What an ``observe_base`` correction sees: ``observation`` ((n_obs,) or (n, n_obs))
    followed by the base's action and feedforward (:func:`step_base`), float32."""
    obs = np.asarray(observation, dtype=np.float32)
    rows = obs.reshape(-1, obs.shape[-1])
    extra = np.concatenate(
        [np.reshape(base_action, (len(rows), 1)), np.reshape(feedforward, (len(rows), 1))], axis=1
    ).astype(np.float32)
    out = np.concatenate([rows, extra], axis=1)
    return out[0] if obs.ndim == 1 else out


def correction_towards(base_action: np.ndarray, target: np.ndarray, scale: float) -> np.ndarray:
    """The correction in [-1, 1] that moves ``base_action`` to ``target`` (normalised
    actions): ``clip((target - base) / scale, -1, 1)``, so that the residual action
    ``clip(base + scale * correction, -1, 1)`` is ``target`` wherever neither clip acts."""
    c = (np.asarray(target, dtype=np.float64) - np.asarray(base_action, dtype=np.float64)) / float(scale)
    return np.clip(c, -1.0, 1.0).astype(np.float32)


def _combine(base_action: np.ndarray, correction: np.ndarray, scale: float) -> np.ndarray:
    a = np.asarray(base_action, dtype=np.float32) + np.float32(scale) * np.asarray(
        correction, dtype=np.float32
    )
    return np.clip(a, -1.0, 1.0).astype(np.float32)


class ResidualPolicy:
    """A trained correction ``policy`` on top of ``base`` behind SB3's ``predict`` (the
    benchmark's one evaluation path); the state is the base's. With ``observe_base`` the
    policy's observation is the rig's followed by :data:`BASE_OBSERVATIONS`."""

    def __init__(
        self, policy: Any, base: Any, scale: float, name: str | None = None, *, observe_base: bool = False
    ):
        self.policy, self.base, self.scale = policy, base, float(scale)
        self.observe_base = bool(observe_base)
        self.name = name or getattr(policy, "name", "residual")
        self.path = getattr(policy, "path", None)

    @property
    def observation_space(self):
        """The rig's observation the policy runs on (without the base's entries it adds)."""
        space = self.policy.observation_space
        if not self.observe_base:
            return space
        from gymnasium import spaces

        n = space.shape[0] - len(BASE_OBSERVATIONS)
        return spaces.Box(space.low[:n], space.high[:n], dtype=space.dtype)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        if not self.observe_base:
            base_action, state = self.base.predict(observation, state=state, episode_start=episode_start)
            correction, _ = self.policy.predict(observation, deterministic=deterministic)
            return _combine(base_action, correction, self.scale), state
        obs = np.asarray(observation)
        base_action, feedforward, state = step_base(self.base, obs, state, episode_start)
        seen = observation_with_base(obs, base_action, feedforward)
        correction, _ = self.policy.predict(seen, deterministic=deterministic)
        action = _combine(base_action, np.reshape(correction, base_action.shape), self.scale)
        return (action[0] if obs.ndim == 1 else action), state

    def check_env(self, env: Any) -> None:
        """Raise ValueError unless the env's spaces are the ones the policy was trained on."""
        if not self.observe_base:
            self.policy.check_env(env)
            return
        obs, mo = env.observation_space, self.observation_space
        if obs.shape != mo.shape or not np.allclose(obs.low, mo.low) or not np.allclose(obs.high, mo.high):
            raise ValueError(
                f"observation_space: {obs} differs from the policy's {mo} before its "
                f"{list(BASE_OBSERVATIONS)} ({self.path})"
            )
        act, ma = env.action_space, self.policy.action_space
        if act.shape != ma.shape or not np.allclose(act.low, ma.low) or not np.allclose(act.high, ma.high):
            raise ValueError(f"action_space: {act} differs from the policy's {ma} ({self.path})")

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "path": self.path,
            "residual_on": self.base.describe(),
            "scale": self.scale,
            **({"observes": list(BASE_OBSERVATIONS)} if self.observe_base else {}),
        }


def _vec_env_wrapper():
    from gymnasium import spaces
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class _ResidualVecEnv(VecEnvWrapper):
        """Training rigs whose action is the policy's correction: the base controller (batched
        over the rigs, its state reset where an episode starts) gives its action for every
        observation the rigs return, and the rigs receive ``clip(base + scale * correction,
        -1, 1)``. With ``observe_base`` each observation, the terminal observations of ended
        episodes among them, is followed by :data:`BASE_OBSERVATIONS` (for a terminal one,
        what the base would do there, with its state of that episode)."""

        def __init__(self, venv, base: Any, scale: float, observe_base: bool = False):
            space = venv.observation_space
            if observe_base:
                k = len(BASE_OBSERVATIONS)
                space = spaces.Box(
                    np.concatenate([space.low, np.full(k, -np.inf, dtype=space.dtype)]),
                    np.concatenate([space.high, np.full(k, np.inf, dtype=space.dtype)]),
                    dtype=space.dtype,
                )
            super().__init__(venv, observation_space=space)
            self.base, self.scale, self.observe_base = base, float(scale), bool(observe_base)
            self._base_action: np.ndarray | None = None
            self._state: np.ndarray | None = None

        def _seen(self, obs: np.ndarray, start: np.ndarray | None) -> np.ndarray:
            """Step the base on ``obs`` (``start``: rows where an episode starts; None: all)."""
            if not self.observe_base:  # the feedforward's share is not needed: not computed
                self._base_action, self._state = self.base.predict(
                    obs, state=self._state, episode_start=start
                )
                return obs
            action, feedforward, self._state = step_base(self.base, obs, self._state, start)
            self._base_action = action
            return observation_with_base(obs, action, feedforward)

        def reset(self):
            self._state = None
            return self._seen(self.venv.reset(), None)

        def step_async(self, actions: np.ndarray) -> None:
            base_action = self._base_action
            self.venv.step_async(_combine(base_action, np.reshape(actions, base_action.shape), self.scale))

        def step_wait(self):
            obs, reward, done, info = self.venv.step_wait()
            done = np.asarray(done, dtype=bool)
            if self.observe_base and done.any():
                for i in np.flatnonzero(done):  # the base's action there, on its episode's state
                    terminal = info[i].get("terminal_observation")
                    if terminal is not None:
                        a, ff, _ = step_base(self.base, terminal, self._state[i : i + 1], None)
                        info[i]["terminal_observation"] = observation_with_base(terminal, a, ff)
            return self._seen(obs, done.copy()), reward, done, info

    return _ResidualVecEnv


def ResidualVecEnv(venv, base: Any, scale: float, observe_base: bool = False):  # noqa: N802 (a class built on demand)
    """Wrap SB3 vector env ``venv`` so that its action is a correction on ``base`` (and, with
    ``observe_base``, its observation carries the base's action and feedforward)."""
    return _vec_env_wrapper()(venv, base, scale, observe_base)
