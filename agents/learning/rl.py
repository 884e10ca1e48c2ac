"""Reinforcement learning with stable-baselines3: training configs, training, and trained
policies behind the same ``predict`` as the classical controllers.

A training config (``configs/agents/ppo.yaml``, ``sac.yaml``, ...) is a YAML mapping::

    algo: ppo                       # ppo, sac or td3 (stable-baselines3); tqc or crossq (sb3-contrib)
    env_id: DrillString-v1
    env_kwargs: {}                  # DrillStringEnv arguments
    n_envs: 64                      # parallel rigs
    vec_env: native                 # native: all rigs in one compiled call (drill_env.sb3_vec_env);
                                    # dummy: SB3's DummyVecEnv of single envs (same results, slower)
    total_timesteps: 2000000
    normalize_reward: true          # VecNormalize on the reward only (nothing needed at inference)
    torch_threads: 1
    hyperparameters: {...}          # keyword arguments of PPO(...) / SAC(...) / TD3(...) / TQC(...) /
                                    # CrossQ(...), incl. policy_kwargs;
                                    # learning_rate / clip_range may be lin_<value> (linear decay) or
                                    # {start, end, end_fraction} (linear to end, then held),
                                    # policy_kwargs.activation_fn Tanh or ReLU; action_noise_std
                                    # (off-policy): Gaussian exploration noise of this std on the
                                    # action scaled to [-1, 1], drawn per rig (TD3's exploration)
    evaluation: {every_steps: 50000, episodes_per_regime: 4, seed: 10000}
    convergence: {fraction: 0.25, tolerance: 0.05, min_evaluations: 8}
    residual: {base: lqi, scale: 0.2}   # optional: learn a correction on a classical controller
                                        # (drill_env.agents.learning.residual); absent or null: the policy is the controller;
                                        # observe_base: true adds the base's action and feedforward to its input
                                        # base_options: {variable_step: true} sets lqi_angle_ff's own options
    warm_start: {controller: lqi, steps: 100000}  # optional: clone a classical controller into the
                                        # policy before the first rollout (drill_env.agents.learning.warm_start);
                                        # with residual: {policy: ppo_lqi_clone, ...} distils a trained policy
    ignored_observations: [lower_angle_sin, ...]  # optional: entries the policy network takes
                                        # no weights from (zeroed and frozen; the value still sees them)

Domain randomisation is the environment's ``domain_randomization`` argument in
``env_kwargs`` (:class:`drill_env.envs.config.DomainRandomization`: relative ranges of the
friction, inertia, stiffness and motor constant, ``(low, high)`` ranges of the sensor noise and
of any effect of :class:`drill_env.params.ModelEffects`); it is validated when the config is
read, each bad entry named with its field (``env_kwargs.domain_randomization.effects.<name>``).

Learning curve: every ``every_steps`` environment steps the deterministic policy is run
by :func:`drill_env.agents.evaluation.episodes.run_episode` (the one evaluation path) on a fixed set of
episodes of the training environment: ``episodes_per_regime`` operating points drawn in
each regime (equilibrium, limit cycle, stick-slip) from seeds ``seed, seed + 1, ...``.
Their mean return is the learning curve (``eval.csv``, TensorBoard ``eval/mean_return``);
the policy with the best mean return is kept (``policy.zip``). The same episodes are run
with the open-loop and the LQI controller as references.

Convergence (a plateau criterion): with R the evaluation returns in order, Q_last the
mean of the last ``fraction`` of them and Q_prev the mean of the ``fraction`` before,
training has converged if ``Q_last - Q_prev <= tolerance * |Q_last|``: the last stretch
improved the return by less than ``tolerance`` (5 %) of the level it reached (and at least
``min_evaluations`` evaluations were made).

A policy file says what it was trained on: every zip :func:`train` saves carries
``drill_env.json`` (algo, env id, env kwargs, observation version, drill-env version, the
training config; :mod:`drill_env.agents.learning.policy_info`), which :func:`load_policy` and
:func:`policy_observation_version` read; a file with neither it nor a ``config.yaml`` beside it
is refused. With ``evaluation.target_check`` the kept policy is the best by the learned
controllers' target check instead of the return (:func:`train`).

Policy files are code: a stable-baselines3 ``.zip`` stores some of its objects (the spaces,
the policy class and its arguments, the schedules) as pickles, and unpickling can run
arbitrary code. :func:`load_policy` loads the policies committed under ``results/agents/``
(and their copy installed with the package) and refuses any other file
(:class:`UntrustedPolicyError`) unless told ``trusted=True`` (or the environment sets
:data:`TRUST_ENV_VAR`, as a command does once its user has vouched for the files). :func:`policy_observation_version` reads only the zip's JSON and unpickles
nothing.
"""

from __future__ import annotations

import base64
import copy
import io
import json
import math
import os
import pickle
import pickletools
import platform
import time
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from drill_env.agents._locations import PACKAGE_DIR, ROOT
from drill_env.agents.learning._config import config_section
from drill_env.envs import ENV_IDS, ENV_VERSIONS, make_version
from drill_env.envs.task import REGIMES
from drill_env.outputs import atomic_path, atomic_write_json, atomic_write_text, save_figure
from drill_env.params import load_yaml

__all__ = [
    "ALGOS",
    "TrainConfig",
    "SB3Policy",
    "load_config",
    "load_policy",
    "renamed_objects",
    "is_correction_file",
    "stored_policy_class",
    "upgrade_policy_file",
    "COMMITTED_POLICY_DIR",
    "PACKAGED_POLICY_DIR",
    "UntrustedPolicyWarning",
    "UntrustedPolicyError",
    "MAX_POLICY_INFLATED_BYTES",
    "TRUST_ENV_VAR",
    "check_policy_zip",
    "trust_from_environment",
    "refuse_untrusted",
    "untrusted_policy_note",
    "policy_observation_version",
    "plateau",
    "train",
    "evaluation_episodes",
    "make_train_vec_env",
    "ignore_observations",
    "observation_names",
]

ALGOS = ("ppo", "sac", "td3", "tqc", "crossq")
# Algorithms of sb3-contrib (the ``zoo`` extra): off-policy learners with SAC's actor.
CONTRIB_ALGOS = ("tqc", "crossq")
VEC_ENVS = ("native", "dummy")
# The policies of the repository (reviewed with it); any other policy file is untrusted.
COMMITTED_POLICY_DIR = ROOT / "results" / "agents"
# The same files as the wheel installs them (pyproject.toml, force-include).
PACKAGED_POLICY_DIR = PACKAGE_DIR / "_results" / "agents"


def _algo_class(algo: str):
    """The stable-baselines3 (ppo, sac, td3) or sb3-contrib (tqc, crossq) class of ``algo``."""
    if algo not in ALGOS:
        raise ValueError(f"algo: {algo!r} is not one of {list(ALGOS)}")
    if algo in CONTRIB_ALGOS:
        try:
            import sb3_contrib
        except ImportError:
            raise ValueError(
                f"algo: {algo} needs sb3-contrib, which is not installed; install it with "
                "pip install -c constraints.txt 'drill-env[zoo]'"
            ) from None
        return {"tqc": sb3_contrib.TQC, "crossq": sb3_contrib.CrossQ}[algo]
    from stable_baselines3 import PPO, SAC, TD3

    return {"ppo": PPO, "sac": SAC, "td3": TD3}[algo]


@dataclass(frozen=True)
class EvalConfig:
    every_steps: int = 50_000
    episodes_per_regime: int = 4
    seed: int = 10_000
    # at every evaluation also the learned controllers' target check
    # (drill_env.agents.evaluation.target_check); the kept policy is then the best by its margin
    target_check: bool = False
    stop_at_target: bool = False  # end the training at the first evaluation meeting the target

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "every_steps": self.every_steps,
            "episodes_per_regime": self.episodes_per_regime,
        }
        out["seed"] = self.seed
        if self.target_check or self.stop_at_target:  # absent from the configs that predate them
            out.update(target_check=self.target_check, stop_at_target=self.stop_at_target)
        return out


@dataclass(frozen=True)
class ConvergenceConfig:
    fraction: float = 0.25
    tolerance: float = 0.05
    min_evaluations: int = 8


@dataclass(frozen=True)
class TrainConfig:
    """A validated training config (see the module docstring)."""

    algo: str
    env_id: str = "DrillString-v0"
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    n_envs: int = 1
    vec_env: str = "native"
    total_timesteps: int = 100_000
    normalize_reward: bool = False
    torch_threads: int = 1
    hyperparameters: Mapping[str, Any] = field(default_factory=dict)
    evaluation: EvalConfig = field(default_factory=EvalConfig)
    convergence: ConvergenceConfig = field(default_factory=ConvergenceConfig)
    residual: Any = None  # drill_env.agents.learning.residual.ResidualConfig, or None
    warm_start: Any = None  # drill_env.agents.learning.warm_start.WarmStartConfig, or None
    ignored_observations: tuple[str, ...] = ()  # entries the policy network gets no weights from
    late_phase: Any = None  # drill_env.agents.learning.late_phase.LatePhaseConfig, or None

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ValueError(f"algo: {self.algo!r} is not one of {list(ALGOS)}")
        if self.env_id not in ENV_IDS:
            raise ValueError(f"env_id: {self.env_id!r} is not one of {sorted(ENV_IDS)}")
        for name, lo in (("n_envs", 1), ("total_timesteps", 1), ("torch_threads", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{name}: expected an integer >= {lo}, got {v!r}")
        if self.vec_env not in VEC_ENVS:
            raise ValueError(f"vec_env: {self.vec_env!r} is not one of {list(VEC_ENVS)}")
        if not isinstance(self.normalize_reward, bool):
            raise ValueError(f"normalize_reward: expected true or false, got {self.normalize_reward!r}")
        if not isinstance(self.env_kwargs, Mapping):
            raise ValueError(f"env_kwargs: expected a mapping, got {self.env_kwargs!r}")
        if not isinstance(self.hyperparameters, Mapping):
            raise ValueError(f"hyperparameters: expected a mapping, got {self.hyperparameters!r}")
        for key in ("env", "seed", "tensorboard_log", "verbose", "device"):
            if key in self.hyperparameters:
                raise ValueError(f"hyperparameters: {key!r} is set by the training command")
        algo_kwargs(self.hyperparameters)  # lin_ schedules parse
        if self.algo == "ppo" and "action_noise_std" in self.hyperparameters:
            raise ValueError(
                "hyperparameters.action_noise_std: available with the off-policy algorithms, not ppo"
            )
        e = self.evaluation
        if isinstance(e, Mapping):
            e = config_section(EvalConfig, e, "evaluation")
            object.__setattr__(self, "evaluation", e)
        for name in ("every_steps", "episodes_per_regime"):
            v = getattr(e, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"evaluation.{name}: expected an integer >= 1, got {v!r}")
        if isinstance(e.seed, bool) or not isinstance(e.seed, int) or e.seed < 0:
            raise ValueError(f"evaluation.seed: expected an integer >= 0, got {e.seed!r}")
        for name in ("target_check", "stop_at_target"):
            if not isinstance(getattr(e, name), bool):
                raise ValueError(f"evaluation.{name}: expected true or false, got {getattr(e, name)!r}")
        if e.stop_at_target and not e.target_check:
            raise ValueError("evaluation.stop_at_target: needs evaluation.target_check: true")
        c = self.convergence
        if isinstance(c, Mapping):
            c = config_section(ConvergenceConfig, c, "convergence")
            object.__setattr__(self, "convergence", c)
        if not (isinstance(c.fraction, (int, float)) and 0 < c.fraction <= 0.5):
            raise ValueError(f"convergence.fraction: {c.fraction!r} is outside the allowed range (0, 0.5]")
        if not (isinstance(c.tolerance, (int, float)) and 0 <= c.tolerance < 1):
            raise ValueError(f"convergence.tolerance: {c.tolerance!r} is outside the allowed range [0, 1)")
        if (
            isinstance(c.min_evaluations, bool)
            or not isinstance(c.min_evaluations, int)
            or c.min_evaluations < 2
        ):
            raise ValueError(
                f"convergence.min_evaluations: expected an integer >= 2, got {c.min_evaluations!r}"
            )
        from drill_env.agents.learning.residual import ResidualConfig

        object.__setattr__(self, "residual", ResidualConfig.from_any(self.residual))
        from drill_env.agents.learning.warm_start import WarmStartConfig

        object.__setattr__(self, "warm_start", WarmStartConfig.from_any(self.warm_start))
        from drill_env.agents.learning.late_phase import LatePhaseConfig

        object.__setattr__(self, "late_phase", LatePhaseConfig.from_any(self.late_phase))
        if self.late_phase is not None and self.algo == "ppo":
            raise ValueError("late_phase: available with the off-policy algorithms (sac, tqc, crossq), not ppo")
        if self.late_phase is not None and self.late_phase.tau is not None and self.algo == "crossq":
            raise ValueError("late_phase.tau: crossq has no target networks")
        ws = self.warm_start
        if ws is not None and ws.policy is None and self.residual is not None:
            raise ValueError(
                "warm_start.controller: a residual policy starts as its base controller already; drop "
                "one (warm_start.policy distils a trained policy into a residual policy)"
            )
        if ws is not None and self.residual is not None and self.residual.observe_base:
            raise ValueError(
                "residual.observe_base: not available with warm_start (its demonstrations are "
                "labelled on the rig's observation alone); drop one"
            )
        if ws is not None and ws.policy is not None and self.residual is None:
            raise ValueError(
                "warm_start.policy: allowed only with residual (a trained policy is distilled into "
                "the correction of a residual policy)"
            )
        ignored = self.ignored_observations
        if isinstance(ignored, str) or not isinstance(ignored, (list, tuple)):
            raise ValueError(f"ignored_observations: expected a list of observation names, got {ignored!r}")
        names = observation_names(self.env_id)
        for name in ignored:
            if name not in names:
                raise ValueError(f"ignored_observations: {name!r} is not one of {list(names)}")
        object.__setattr__(self, "ignored_observations", tuple(ignored))
        if self.algo not in ("ppo", "sac") and (self.residual is not None or self.warm_start is not None):
            key = "residual" if self.residual is not None else "warm_start"
            raise ValueError(f"{key}: available with algo ppo or sac, not {self.algo}")
        if self.residual is not None and self.residual.critic_burn_in and self.algo != "sac":
            raise ValueError(
                f"residual.critic_burn_in: allowed only with algo sac (an off-policy critic), not {self.algo}"
            )
        dr = self.env_kwargs.get("domain_randomization")
        if dr is not None:
            from drill_env.envs.config import DomainRandomization

            try:
                DomainRandomization.from_any(dr)
            except ValueError as exc:
                raise ValueError(f"env_kwargs.{exc}") from None
        object.__setattr__(self, "env_kwargs", dict(self.env_kwargs))
        object.__setattr__(self, "hyperparameters", copy.deepcopy(dict(self.hyperparameters)))

    def to_dict(self) -> dict[str, Any]:
        return {
            "algo": self.algo,
            "env_id": self.env_id,
            "env_kwargs": dict(self.env_kwargs),
            "n_envs": self.n_envs,
            "vec_env": self.vec_env,
            "total_timesteps": self.total_timesteps,
            "normalize_reward": self.normalize_reward,
            "torch_threads": self.torch_threads,
            "hyperparameters": copy.deepcopy(dict(self.hyperparameters)),
            "evaluation": self.evaluation.to_dict(),
            "convergence": vars(self.convergence).copy(),
            **({"residual": self.residual.to_dict()} if self.residual is not None else {}),
            **({"warm_start": self.warm_start.to_dict()} if self.warm_start is not None else {}),
            **(
                {"ignored_observations": list(self.ignored_observations)} if self.ignored_observations else {}
            ),
            **({"late_phase": self.late_phase.to_dict()} if self.late_phase is not None else {}),
        }


def load_config(path: str | Path, **overrides: Any) -> TrainConfig:
    """Read a training config from YAML; ``overrides`` replace top-level keys."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"config: no such file {str(path)!r}")
    data = load_yaml(path, what="training config", error=ValueError) or {}
    if not isinstance(data, Mapping):
        raise ValueError(f"config: {path} must hold a YAML mapping")
    data = dict(data)
    data.update({k: v for k, v in overrides.items() if v is not None})
    allowed = set(TrainConfig.__dataclass_fields__)
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ValueError(f"config: unknown key(s) {unknown} in {path}; allowed: {sorted(allowed)}")
    if "algo" not in data:
        raise ValueError(f"config: {path} has no 'algo' (one of {list(ALGOS)})")
    return TrainConfig(**data)


# -- trained policies behind predict ------------------------------------------------------------


class _DeterministicActor:
    """The deterministic action of an SB3 PPO, SAC or TD3 MLP policy (flattened Box observation,
    Box action) as a float32 numpy forward pass: what ``model.predict(obs,
    deterministic=True)`` computes, without torch's per-call overhead (about 20x faster for
    one observation). PPO: ``action_net(policy_net(obs))`` clipped to the action space; SAC:
    ``tanh(mu(latent_pi(obs)))`` mapped onto the action space; TD3: ``mu(obs)`` (ending in a
    tanh) mapped onto it."""

    _ACTIVATIONS = {
        "Tanh": np.tanh,
        "ReLU": lambda x: np.maximum(x, 0.0),
    }

    def __init__(self, layers, squash: bool, low: np.ndarray, high: np.ndarray, n_obs: int):
        self.layers, self.squash = layers, squash
        self.low, self.high, self.n_obs = low.astype(np.float32), high.astype(np.float32), n_obs

    @classmethod
    def of(cls, model: Any) -> _DeterministicActor | None:
        """The fast path for ``model``, or None where its policy is not a plain MLP."""
        from gymnasium import spaces

        pol = getattr(model, "policy", None)
        if not isinstance(model.action_space, spaces.Box) or not isinstance(
            model.observation_space, spaces.Box
        ):
            return None
        if len(model.observation_space.shape) != 1:
            return None
        kind = type(pol).__name__
        try:
            if kind == "ActorCriticPolicy" and not pol.squash_output:
                if type(pol.pi_features_extractor).__name__ != "FlattenExtractor":
                    return None
                modules, squash = [*pol.mlp_extractor.policy_net, pol.action_net], False
            elif kind in ("SACPolicy", "TQCPolicy", "MlpPolicy") and hasattr(pol, "actor"):
                actor = pol.actor
                if type(actor.features_extractor).__name__ != "FlattenExtractor" or getattr(
                    actor, "use_sde", False
                ):
                    return None
                modules, squash = [*actor.latent_pi, actor.mu], True
            elif kind == "TD3Policy":  # mu: the whole MLP, its last module the tanh
                actor = pol.actor
                if type(actor.features_extractor).__name__ != "FlattenExtractor":
                    return None
                modules, squash = [*actor.mu], True
                if not modules or type(modules[-1]).__name__ != "Tanh":
                    return None
                modules = modules[:-1]  # squash applies it
            else:
                return None
        except AttributeError:
            return None
        layers: list[Any] = []
        for m in modules:
            name = type(m).__name__
            if name == "Linear":
                w = m.weight.detach().cpu().numpy().astype(np.float32)
                b = m.bias.detach().cpu().numpy().astype(np.float32)
                layers.append((w.T.copy(), b))
            elif name in cls._ACTIVATIONS:
                layers.append(cls._ACTIVATIONS[name])
            else:
                return None
        return cls(
            layers, squash, model.action_space.low, model.action_space.high, model.observation_space.shape[0]
        )

    def __call__(self, observation) -> np.ndarray | None:
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        if obs.shape[-1:] != (self.n_obs,) or obs.ndim > 2:
            return None  # SB3 raises its own error for this
        x = obs.reshape(-1, self.n_obs)
        for layer in self.layers:
            x = x @ layer[0] + layer[1] if isinstance(layer, tuple) else layer(x)
        if self.squash:
            x = self.low + 0.5 * (np.tanh(x) + 1.0) * (self.high - self.low)
        else:
            x = np.clip(x, self.low, self.high)
        x = x.astype(np.float32)
        return x[0] if single else x


class SB3Policy:
    """A trained SB3 model as a benchmark controller: ``predict`` is the model's own; a
    deterministic ``predict`` of a PPO/SAC MLP policy runs the same network in numpy
    (:class:`_DeterministicActor`, equal to SB3's to float32 rounding, 5e-5 of the action range)."""

    def __init__(self, model: Any, name: str, path: str | None = None):
        self.model = model
        self.name = name
        self.path = path
        self._actor = _DeterministicActor.of(model)

    @property
    def observation_space(self):
        return self.model.observation_space

    @property
    def action_space(self):
        return self.model.action_space

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        if deterministic and state is None and self._actor is not None:
            action = self._actor(observation)
            if action is not None:
                return action, None
        return self.model.predict(
            observation, state=state, episode_start=episode_start, deterministic=deterministic
        )

    def check_env(self, env: Any) -> None:
        """Raise ValueError unless the env's spaces are the ones the policy was trained on."""
        obs, act = env.observation_space, env.action_space
        mo, ma = self.model.observation_space, self.model.action_space
        if obs.shape != mo.shape or not np.allclose(obs.low, mo.low) or not np.allclose(obs.high, mo.high):
            raise ValueError(f"observation_space: {obs} differs from the policy's {mo} ({self.path})")
        if act.shape != ma.shape or not np.allclose(act.low, ma.low) or not np.allclose(act.high, ma.high):
            raise ValueError(f"action_space: {act} differs from the policy's {ma} ({self.path})")

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "path": self.path}


# A policy of this project inflates to about 1 MiB; a zip that would inflate to more than this
# is refused before anything in it is read (a small file can inflate to gigabytes).
MAX_POLICY_INFLATED_BYTES = 64 * 2**20
# Set to 1 (or true/yes) to let a command without a terminal load policies from outside
# results/agents/ (the command-line flag --trust-policies does the same).
TRUST_ENV_VAR = "DRILL_ENV_TRUST_POLICIES"


def check_policy_zip(path: str | Path) -> None:
    """Refuse a policy zip whose members would inflate to more than
    :data:`MAX_POLICY_INFLATED_BYTES` (their declared sizes, which bound what is read), before
    anything in it is decompressed. A file that is no zip is left to the loader to report."""
    try:
        with zipfile.ZipFile(path) as zf:
            total = sum(max(0, i.file_size) for i in zf.infolist())
    except (OSError, zipfile.BadZipFile, ValueError):
        return
    if total > MAX_POLICY_INFLATED_BYTES:
        raise ValueError(
            f"policy: {path} inflates to {total / 2**20:.4g} MiB; allowed: at most "
            f"{MAX_POLICY_INFLATED_BYTES / 2**20:g} MiB (a policy of this project is about 1 MiB)"
        )


def trust_from_environment() -> bool:
    """Whether :data:`TRUST_ENV_VAR` says to trust policy files from outside results/agents/."""
    return os.environ.get(TRUST_ENV_VAR, "").strip().lower() in ("1", "true", "yes")


class UntrustedPolicyWarning(UserWarning):
    """A policy file from outside ``results/agents/`` is loaded: loading it may run code."""


class UntrustedPolicyError(ValueError):
    """A policy file from outside ``results/agents/`` was to be loaded without being trusted
    (nothing in it was unpickled)."""


def refuse_untrusted(path: str | Path, trusted: bool = False) -> None:
    """Raise :class:`UntrustedPolicyError` for a policy file from outside ``results/agents/``
    unless ``trusted`` or :data:`TRUST_ENV_VAR` is set (nothing is read from the file)."""
    note = untrusted_policy_note(path)
    if note is not None and not (trusted or trust_from_environment()):
        raise UntrustedPolicyError(
            f"{note} (pass trusted=True to load one; on the command line --trust-policies, or "
            f"set {TRUST_ENV_VAR}=1)"
        )


def untrusted_policy_note(path: str | Path) -> str | None:
    """Why loading ``path`` needs trust, or None for a policy committed under
    ``results/agents/`` (symbolic links resolved: a link out of it is not committed)."""
    resolved = Path(path).resolve()
    if any(resolved.is_relative_to(d.resolve()) for d in (COMMITTED_POLICY_DIR, PACKAGED_POLICY_DIR)):
        return None
    return (
        f"policy: {path} is not one of the committed policies in results/agents/; loading a "
        "stable-baselines3 .zip unpickles Python objects, which can run arbitrary code: load only "
        "files you made or trust"
    )


# Module paths a saved model may name that have moved since: the package's import name
# before it became ``drill_env.agents`` (a name other distributions also install), and the
# modules of ``drill_env.agents`` before it was split into controllers / learning /
# evaluation. A model pickles the objects of this package it holds (a learning-rate or
# clip-range schedule) by their module path at the time it was saved.
FORMER_PACKAGE = "agents"
MOVED_MODULES = {
    **{
        f"drill_env.agents.{m}": f"drill_env.agents.controllers.{m}"
        for m in (
            "base",
            "open_loop",
            "pi",
            "torque_feedback",
            "lqi",
            "angle_feedforward",
            "linear_model",
            "tuning",
            "gains",
        )
    },
    **{f"drill_env.agents.{m}": f"drill_env.agents.learning.{m}" for m in ("rl", "residual", "warm_start")},
    "drill_env.agents.evaluation": "drill_env.agents.evaluation.episodes",
}
# The project's own linear schedule, before stable-baselines3's replaced it: pickled with its
# start value as ``value``.
_FORMER_SCHEDULE = {"drill_env.agents.rl", "drill_env.agents.learning.rl"}


def _present_module(module: str) -> str:
    if module == FORMER_PACKAGE or module.startswith(FORMER_PACKAGE + "."):
        module = "drill_env.agents" + module[len(FORMER_PACKAGE) :]
    return MOVED_MODULES.get(module, module)


class _FormerLinearSchedule:
    """Unpickles the project's former ``LinearSchedule`` (state ``{"value": v}``) as
    stable-baselines3's ``LinearSchedule(v, 0, 1)``, the same function of the progress."""

    def __setstate__(self, state: dict[str, Any]) -> None:
        from stable_baselines3.common.utils import LinearSchedule as SB3LinearSchedule

        schedule = SB3LinearSchedule(float(state["value"]), 0.0, 1.0)
        self.__class__ = SB3LinearSchedule  # type: ignore[assignment]
        self.__dict__.update(schedule.__dict__)


class _FormerNameUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        module = _present_module(module)
        if name == "LinearSchedule" and (module in _FORMER_SCHEDULE or module in MOVED_MODULES.values()):
            return _FormerLinearSchedule
        return super().find_class(module, name)


def _names_former_package(pickled: bytes) -> bool:
    former = set(MOVED_MODULES) | _FORMER_SCHEDULE
    for _, arg, _ in pickletools.genops(pickled):
        # a module path is a string of its own (protocol >= 2) or the first word of GLOBAL's
        module = arg.split(" ")[0] if isinstance(arg, str) else None
        if module and (_present_module(module) != module or module in former):
            return True
    return False


def renamed_objects(path: str | Path) -> dict[str, Any]:
    """The objects of the model saved in ``path`` that name a module of this package by a
    former path (the import name ``agents`` before the rename, a module before the split
    into controllers / learning / evaluation, the former own ``LinearSchedule``), unpickled
    under the present ones: stable-baselines3's ``custom_objects`` for loading such a model
    without importing whatever top-level ``agents`` is installed. Empty for a model saved
    since, or a file that is no model."""
    try:
        with zipfile.ZipFile(path) as zf:
            data = json.loads(zf.read("data"))
    except (OSError, zipfile.BadZipFile, KeyError, ValueError):
        return {}  # stable-baselines3 reports what is wrong with the file
    out = {}
    for key, value in data.items() if isinstance(data, dict) else ():
        if isinstance(value, dict) and isinstance(value.get(":serialized:"), str):
            pickled = base64.b64decode(value[":serialized:"])
            if _names_former_package(pickled):
                out[key] = _FormerNameUnpickler(io.BytesIO(pickled)).load()
    return out


def _read_data(path: str | Path) -> dict[str, Any] | None:
    """The JSON ``data`` of a stable-baselines3 zip, or None for a file that is no model."""
    try:
        with zipfile.ZipFile(path) as zf:
            data = json.loads(zf.read("data"))
    except (OSError, zipfile.BadZipFile, KeyError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _pickled_global(pickled: bytes) -> tuple[str, str] | None:
    """``(module, name)`` of a pickle that is a reference to a class or function, read from
    its opcodes (nothing is unpickled); None for any other pickle."""
    strings: list[str] = []
    try:
        for op, arg, _ in pickletools.genops(pickled):
            if op.name == "GLOBAL" and isinstance(arg, str):
                module, _, name = arg.partition(" ")
                return module, name
            if op.name == "STACK_GLOBAL" and len(strings) >= 2:
                return strings[-2], strings[-1]
            if isinstance(arg, str) and op.name not in ("MEMOIZE", "PUT", "BINPUT", "LONG_BINPUT"):
                strings.append(arg)
    except ValueError:
        return None
    return None


def stored_policy_class(path: str | Path) -> tuple[str, str] | None:
    """``(module, name)`` of the policy class a saved model names, read without unpickling it
    (None if the file is no model or the entry is not a class reference)."""
    data = _read_data(path)
    entry = (data or {}).get("policy_class")
    if not isinstance(entry, dict) or not isinstance(entry.get(":serialized:"), str):
        return None
    return _pickled_global(base64.b64decode(entry[":serialized:"]))


def is_correction_file(path: str | Path) -> bool:
    """Whether the saved model in ``path`` is tagged as a residual policy's correction
    (:data:`drill_env.agents.learning.residual.CORRECTION_POLICY_CLASSES`): stable-baselines3's
    ``load`` of it alone raises, naming :func:`load_policy`."""
    from drill_env.agents.learning import residual

    names = {(residual.__name__, c[0]) for c in residual.CORRECTION_POLICY_CLASSES.values()}
    return stored_policy_class(path) in names


def upgrade_policy_file(path: str | Path, algo: str | None = None, *, trusted: bool = False) -> list[str]:
    """Bring a policy saved by :func:`train` to the present format, the weights and every
    other entry of the zip byte for byte as they were: the record of what it was trained on
    added where it carries none (:mod:`drill_env.agents.learning.policy_info`, made from the
    ``config.yaml`` beside it; neither is an error naming what is missing), the objects
    pickled under a former module path (:func:`renamed_objects`) stored as their present
    selves, and for a residual policy the policy class as the one that refuses to load
    without its base (:func:`drill_env.agents.learning.residual.correction_policy_class`).
    Returns the entries rewritten or added (empty: the file was up to date and is untouched).
    Unpickles the file's former objects: a file from outside ``results/agents/`` needs
    ``trusted=True``, as in :func:`load_policy`; a zip that inflates beyond
    :data:`MAX_POLICY_INFLATED_BYTES` is refused even then."""
    from stable_baselines3.common.save_util import data_to_json

    from drill_env.agents.learning.policy_info import (
        POLICY_INFO_MEMBER,
        policy_training_record,
        read_policy_info,
        rewrite_policy_zip,
    )
    from drill_env.agents.learning.residual import correction_policy_class

    path = Path(path)
    check_policy_zip(path)
    refuse_untrusted(path, trusted)
    data = _read_data(path)
    if data is None:
        raise ValueError(f"policy: {path} is not a stable-baselines3 model")
    record, source = policy_training_record(path)
    if algo is None:
        algo = record.get("algo")
    if algo not in ALGOS:
        raise ValueError(f"algo: unknown for {path}; pass one of {list(ALGOS)}")
    if source != "zip":
        record = {**record, "algo": algo}
    residual = record["training_config"].get("residual")
    present: dict[str, Any] = dict(renamed_objects(path))
    if residual is not None and not is_correction_file(path):
        sb3_class = correction_policy_class(algo, stable_baselines3=True)
        if stored_policy_class(path) != (sb3_class.__module__, sb3_class.__qualname__):
            raise ValueError(
                f"policy: {path} names the policy class {stored_policy_class(path)}, not "
                f"stable-baselines3's {sb3_class.__qualname__}; not rewritten"
            )
        present["policy_class"] = correction_policy_class(algo)
    add_record = read_policy_info(path) is None
    if not present and not add_record:
        return []
    replace = {}
    if present:
        rewritten = json.loads(data_to_json(present))
        new = {key: rewritten.get(key, value) for key, value in data.items()}
        replace["data"] = json.dumps(new, indent=4).encode()  # as stable-baselines3 writes it
    rewrite_policy_zip(path, replace=replace, info=record if add_record else None)
    return sorted(present) + ([POLICY_INFO_MEMBER] if add_record else [])


def load_policy(
    path: str | Path, algo: str | None = None, name: str | None = None, *, trusted: bool = False
) -> SB3Policy:
    """Load a policy saved by :func:`train` (``policy.zip``). What it was trained on (the
    algorithm, the environment, a residual policy's base) is read from the record inside the
    zip (:mod:`drill_env.agents.learning.policy_info`), or for a file saved before policies
    carried one from the ``config.yaml`` beside it; a file with neither is refused, naming
    what is missing. ``algo``, if given, must be the one the file says.

    A file outside ``results/agents/`` is refused (:class:`UntrustedPolicyError`, before
    anything in it is read: loading unpickles objects stored in it, which can run code) unless
    ``trusted=True`` (a file you made or trust) or :data:`TRUST_ENV_VAR` is set; a zip that
    inflates beyond :data:`MAX_POLICY_INFLATED_BYTES` is refused even when trusted."""
    from drill_env.agents.learning.policy_info import POLICY_INFO_MEMBER, policy_training_record

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"policy: no such file {str(path)!r}")
    check_policy_zip(path)
    refuse_untrusted(path, trusted)
    record, source = policy_training_record(path)
    stored_algo = record.get("algo")
    if algo is None:
        algo = stored_algo
    elif stored_algo is not None and algo != stored_algo:
        where = POLICY_INFO_MEMBER if source == "zip" else "config.yaml"
        raise ValueError(f"algo: {algo!r} given, but {path} was trained with {stored_algo!r} (its {where})")
    if algo not in ALGOS:
        raise ValueError(f"algo: unknown for {path}; pass one of {list(ALGOS)}")
    import torch

    from drill_env.agents.learning.residual import correction_policy_class

    training_config = record["training_config"]
    residual = training_config.get("residual")
    custom_objects = renamed_objects(path)
    if is_correction_file(path) or residual is not None:
        if residual is None:
            raise ValueError(
                f"policy: {path} holds the correction of a residual policy, but its training record "
                f"({POLICY_INFO_MEMBER} or config.yaml beside it) names no base controller (residual: {{base: ...}})"
            )
        # the file names the class that refuses to load alone: stable-baselines3's own instead
        custom_objects["policy_class"] = correction_policy_class(algo, stable_baselines3=True)
    torch.set_num_threads(1)
    model = _algo_class(algo).load(str(path), device="cpu", custom_objects=custom_objects)
    policy = SB3Policy(model, name or algo, str(path))
    if residual is None:
        return policy
    from drill_env.agents.learning.residual import ResidualPolicy, base_controller

    cfg = config_from_mapping(training_config, f"the training record of {path}")
    return ResidualPolicy(
        policy,
        base_controller(cfg.residual, cfg.env_id, cfg.env_kwargs),
        cfg.residual.scale,
        observe_base=cfg.residual.observe_base,
    )


def config_from_mapping(data: Mapping[str, Any], where: str) -> TrainConfig:
    """A :class:`TrainConfig` from a training config mapping (``where`` names it in errors)."""
    data = dict(data)
    allowed = set(TrainConfig.__dataclass_fields__)
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ValueError(f"config: unknown key(s) {unknown} in {where}; allowed: {sorted(allowed)}")
    if "algo" not in data:
        raise ValueError(f"config: {where} has no 'algo' (one of {list(ALGOS)})")
    return TrainConfig(**data)


def _policy_config(path: Path) -> dict[str, Any]:
    """A saved policy's ``config.yaml`` (read by the one YAML reader; a mapping or an error)."""
    data = load_yaml(path, what="policy config", error=ValueError) or {}
    if not isinstance(data, Mapping):
        raise ValueError(f"policy: {path} must hold a YAML mapping (the training config)")
    return dict(data)


def policy_observation_version(path: str | Path) -> int:
    """The env version (the N of ``DrillString-vN``) a saved policy was trained on: its
    ``observation_version`` as the record inside the zip (or, for a file saved before policies
    carried one, the training config beside it) says, checked against the observation space
    stored in the zip (the policy itself is not loaded). A file with neither record is
    refused, never guessed from the observation's size (v1, v2 and v3 observe the same)."""
    from drill_env.agents.learning.policy_info import policy_training_record
    from drill_env.envs import _core as C

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"policy: no such file {str(path)!r}")
    check_policy_zip(path)
    try:
        with zipfile.ZipFile(path) as zf:
            data = json.loads(zf.read("data"))
        shape = tuple(data["observation_space"]["_shape"])
    except (zipfile.BadZipFile, KeyError, ValueError, TypeError) as exc:
        raise ValueError(f"policy: {path} is not a stable-baselines3 model ({exc})") from None
    record, source = policy_training_record(path)
    version = record["observation_version"]
    if isinstance(version, bool) or not isinstance(version, int) or version < 0:
        raise ValueError(f"policy: {path}: observation_version {version!r} is not an env version")
    names = record.get("observation_names")
    expected = (len(names),) if isinstance(names, list) else (C.n_obs(min(version, 1)),)
    if shape != expected:
        raise ValueError(
            f"policy: {path} observes {shape}, not the {expected} of DrillString-v{version} that its "
            f"training record ({source}) names"
        )
    return int(version)


# -- training -------------------------------------------------------------------------------------


def strip_machine_info(path: str | Path) -> None:
    """Keep only the package versions in the ``system_info.txt`` SB3 writes into a saved model
    (its OS line names the build machine's kernel); the model itself is untouched."""
    from drill_env.agents.learning.policy_info import rewrite_policy_zip

    rewrite_policy_zip(path, strip_machine_info=True)


def finish_policy_file(path: str | Path, cfg: TrainConfig) -> None:
    """A zip just saved by stable-baselines3 as :func:`train` keeps it: the record of what it
    was trained on inside (:mod:`drill_env.agents.learning.policy_info`), the build machine's
    OS line out of ``system_info.txt``."""
    from drill_env import __version__
    from drill_env.agents.learning.policy_info import policy_info, rewrite_policy_zip

    info = policy_info(cfg.to_dict(), drill_env_version=__version__)
    rewrite_policy_zip(path, info=info, strip_machine_info=True)


def evaluation_episodes(
    cfg: EvalConfig, regimes: Sequence[str] = REGIMES
) -> list[tuple[int, dict[str, Any]]]:
    """The fixed (seed, reset options) of the learning-curve evaluation: ``episodes_per_regime``
    in each of ``regimes`` (those the rig has; a regime's seeds do not depend on the others)."""
    out = []
    for j, regime in enumerate(REGIMES):
        if regime not in regimes:
            continue
        for i in range(cfg.episodes_per_regime):
            out.append((cfg.seed + j * cfg.episodes_per_regime + i, {"regime": regime}))
    return out


def evaluate_on_episodes(env: Any, controller: Any, episodes: list[tuple[int, dict[str, Any]]]) -> np.ndarray:
    """Returns of ``controller`` on each fixed evaluation episode (the env's own length)."""
    from drill_env.agents.evaluation.episodes import run_episode

    n_steps = env.spec.max_episode_steps if env.spec is not None and env.spec.max_episode_steps else 400
    out = []
    for seed, options in episodes:
        traj = run_episode(env, controller, seed=seed, n_steps=n_steps, options=options)
        out.append(float(np.sum(traj.reward)))
    return np.array(out)


def plateau(
    returns: np.ndarray, fraction: float = 0.25, tolerance: float = 0.05, min_evaluations: int = 8
) -> dict[str, Any]:
    """The plateau criterion of the module docstring on a sequence of evaluation returns."""
    r = np.asarray(returns, dtype=float)
    n = r.size
    out: dict[str, Any] = {"fraction": fraction, "tolerance": tolerance, "min_evaluations": min_evaluations}
    if n < min_evaluations:
        out.update(converged=False, reason=f"only {n} evaluations (< {min_evaluations})")
        return out
    k = max(1, int(math.floor(fraction * n)))
    last, prev = float(np.mean(r[-k:])), float(np.mean(r[-2 * k : -k]))
    gain = last - prev
    level = max(abs(last), 1e-12)
    converged = bool(gain <= tolerance * level)
    out.update(
        converged=converged,
        last_mean=last,
        previous_mean=prev,
        last_gain=gain,
        total_improvement=float(np.max(r) - r[0]),
        reason=(
            f"last {k} evaluations improved the mean return by {gain:.4g} on the {k} before, "
            f"{'<=' if converged else '>'} {tolerance:g} x its level {level:.4g}"
        ),
    )
    return out


def update_convergence(out_dir: str | Path) -> dict[str, Any]:
    """Recompute the plateau verdict of a finished run from its ``eval.csv`` (as :func:`train`
    does at its end), rewrite ``training_summary.json`` and ``learning_curve.png``."""
    import pandas as pd

    out_dir = Path(out_dir)
    summary = json.loads((out_dir / "training_summary.json").read_text())
    curve = pd.read_csv(out_dir / "eval.csv")
    conv = plateau(curve["mean_return"].to_numpy(), **summary["config"]["convergence"])
    summary.update(converged=conv["converged"], convergence=conv)
    atomic_write_json(out_dir / "training_summary.json", summary)
    plot_learning_curve(out_dir, summary)
    return summary


def _reference_returns(cfg: TrainConfig, episodes) -> dict[str, float]:
    """Open-loop and LQI returns on the evaluation episodes (context for the curve)."""

    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.gains import classical_controller
    from drill_env.agents.controllers.open_loop import OpenLoop

    env = make_version(cfg.env_id, **cfg.env_kwargs)
    spec = ControllerSpec.from_env(env)
    preset = ENV_IDS[cfg.env_id]
    refs = {"open_loop": OpenLoop(spec)}
    try:
        refs["lqi"] = classical_controller("lqi", spec, preset)
    except ValueError:
        pass
    out = {name: float(np.mean(evaluate_on_episodes(env, c, episodes))) for name, c in refs.items()}
    env.close()
    return out


# [s] kept free of the wall-time budget for what follows the last evaluation (the final
# policy, the curve, the figure)
_FINISH_RESERVE_S = 2.0
SCHEDULED = ("learning_rate", "clip_range")
# policy_kwargs.activation_fn by name (the activations the numpy forward pass of SB3Policy knows)
ACTIVATIONS = ("Tanh", "ReLU")


def linear_schedule(value: float):
    """rl-zoo3's ``lin_<value>``: from ``value`` at the start of training to 0 at its end
    (stable-baselines3's ``LinearSchedule``, which saved models pickle by name)."""
    from stable_baselines3.common.utils import LinearSchedule

    return LinearSchedule(float(value), 0.0, 1.0)


def _piecewise_linear(key: str, spec: Mapping[str, Any]):
    """``{start, end, end_fraction}``: from ``start`` linearly to ``end`` over the first
    ``end_fraction`` of the run, then ``end`` (stable-baselines3's ``LinearSchedule``)."""
    allowed = ("start", "end", "end_fraction")
    if sorted(spec) != sorted(allowed):
        raise ValueError(f"hyperparameters.{key}: a schedule needs exactly the keys {list(allowed)}, got {sorted(spec)}")
    values = {}
    for name in allowed:
        v = spec[name]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"hyperparameters.{key}.{name}: expected a finite number, got {v!r}")
        values[name] = float(v)
    if not values["start"] > 0 or not 0 <= values["end"] <= values["start"]:
        raise ValueError(
            f"hyperparameters.{key}: expected start > 0 and 0 <= end <= start, got {values['start']!r} / {values['end']!r}"
        )
    if not 0 < values["end_fraction"] <= 1:
        raise ValueError(f"hyperparameters.{key}.end_fraction: expected a fraction in (0, 1], got {spec['end_fraction']!r}")
    from stable_baselines3.common.utils import LinearSchedule

    return LinearSchedule(values["start"], values["end"], values["end_fraction"])


def algo_kwargs(hyperparameters: Mapping[str, Any], n_actions: int = 1) -> dict[str, Any]:
    """The algorithm's keyword arguments from a config's ``hyperparameters``:
    ``learning_rate`` and ``clip_range`` may be ``lin_<value>`` (linear decay to 0, as in
    rl-zoo3's files) or ``{start, end, end_fraction}`` (linear from ``start`` to ``end`` over
    that fraction of the run, then ``end``); ``policy_kwargs.activation_fn`` may name a ``torch.nn`` activation
    (``Tanh``, SB3's default, or ``ReLU``); ``action_noise_std`` becomes SB3's ``action_noise``,
    a :class:`~stable_baselines3.common.noise.NormalActionNoise` of that std on each of the
    ``n_actions`` action entries (scaled to [-1, 1]; SB3 draws it per rig)."""
    hp = copy.deepcopy(dict(hyperparameters))
    if "action_noise_std" in hp:
        std = hp.pop("action_noise_std")
        if isinstance(std, bool) or not isinstance(std, (int, float)) or not (math.isfinite(std) and std > 0):
            raise ValueError(f"hyperparameters.action_noise_std: expected a number > 0, got {std!r}")
        if "action_noise" in hp:
            raise ValueError("hyperparameters: give action_noise_std or action_noise, not both")
        from stable_baselines3.common.noise import NormalActionNoise

        hp["action_noise"] = NormalActionNoise(np.zeros(n_actions), np.full(n_actions, float(std)))
    for key in SCHEDULED:
        v = hp.get(key)
        if isinstance(v, Mapping):
            hp[key] = _piecewise_linear(key, v)
        elif isinstance(v, str):
            if not v.startswith("lin_"):
                raise ValueError(f"hyperparameters.{key}: expected a number or 'lin_<number>', got {v!r}")
            try:
                value = float(v[4:])
            except ValueError:
                raise ValueError(
                    f"hyperparameters.{key}: expected a number or 'lin_<number>', got {v!r}"
                ) from None
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"hyperparameters.{key}: {v!r} must decay from a finite value > 0")
            hp[key] = linear_schedule(value)
    pk = hp.get("policy_kwargs")
    if isinstance(pk, Mapping) and isinstance(pk.get("activation_fn"), str):
        name = pk["activation_fn"]
        if name not in ACTIVATIONS:
            raise ValueError(
                f"hyperparameters.policy_kwargs.activation_fn: expected one of {list(ACTIVATIONS)}, got {name!r}"
            )
        import torch

        hp["policy_kwargs"] = {**pk, "activation_fn": getattr(torch.nn, name)}
    return hp


def observation_names(env_id: str) -> tuple[str, ...]:
    """The names of the observation entries of ``env_id`` (its version's table)."""
    from drill_env.envs import ENV_VERSIONS
    from drill_env.envs.config import OBSERVATION_NAMES, OBSERVATION_NAMES_V1

    return OBSERVATION_NAMES_V1 if ENV_VERSIONS[env_id] >= 1 else OBSERVATION_NAMES


def ignore_observations(model: Any, cfg: TrainConfig) -> None:
    """Zero the weights from ``cfg.ignored_observations`` into the first layer of the policy
    network (PPO: the actor's MLP; SAC, TD3, TQC, CrossQ: the actor's) and keep them zero in training (their
    gradient is masked; Adam then never moves them). The saved policy is a plain MLP that
    does not depend on those entries; the value networks still see them. TD3's target actor
    starts with the same zeros (its Polyak updates then keep them)."""
    if not cfg.ignored_observations:
        return
    import torch

    names = observation_names(cfg.env_id)
    columns = [names.index(n) for n in cfg.ignored_observations]
    pol = model.policy
    if not hasattr(pol, "actor"):
        net = pol.mlp_extractor.policy_net
    else:  # TD3's actor has no latent_pi: its mu is the whole MLP
        net = pol.actor.latent_pi if hasattr(pol.actor, "latent_pi") else pol.actor.mu
    # the first Linear (CrossQ's actor normalises its input first, feature by feature)
    first = next(m for m in net if isinstance(m, torch.nn.Linear))
    mask = torch.ones_like(first.weight)
    mask[:, columns] = 0.0
    with torch.no_grad():
        first.weight.mul_(mask)
        target = getattr(pol, "actor_target", None)
        if target is not None:
            next(m for m in target.mu if isinstance(m, torch.nn.Linear)).weight.mul_(mask)
    first.weight.register_hook(lambda grad: grad * mask)


def make_train_vec_env(cfg: TrainConfig, seed: int):
    """The training rigs of ``cfg``: ``cfg.n_envs`` envs of ``cfg.env_id`` seeded ``seed, seed + 1, ...``
    with episode statistics (``rollout/ep_rew_mean``), as SB3's native batched adapter
    (``vec_env: native``) or a ``DummyVecEnv`` of Monitor-wrapped single envs (``dummy``).
    Both give the same episodes for the same seed and actions."""
    if cfg.vec_env == "native":
        from stable_baselines3.common.vec_env import VecMonitor

        from drill_env.envs.sb3 import sb3_vec_env

        venv = VecMonitor(sb3_vec_env(cfg.env_id, cfg.n_envs, seed=seed, **cfg.env_kwargs))
    else:
        from stable_baselines3.common.env_util import make_vec_env

        venv = make_vec_env(cfg.env_id, n_envs=cfg.n_envs, seed=seed, env_kwargs=dict(cfg.env_kwargs))
    if cfg.residual is None:
        return venv
    from drill_env.agents.learning.residual import ResidualVecEnv, base_controller

    r = cfg.residual
    return ResidualVecEnv(venv, base_controller(r, cfg.env_id, cfg.env_kwargs), r.scale, r.observe_base)


def train(
    cfg: TrainConfig,
    seed: int,
    out_dir: str | Path,
    run_dir: str | Path,
    *,
    progress_bar: bool = True,
    on_eval: Callable[[int, float], None] | None = None,
    teacher: Any = None,
    max_wall_time_s: float | None = None,
) -> dict[str, Any]:
    """Train ``cfg.algo`` on ``cfg.env_id`` with ``seed``; write the run (CSV, TensorBoard,
    checkpoints) to ``run_dir`` and the policy, config, summary and learning curve to
    ``out_dir`` (``drill-env train`` adds the card ``policy.md``,
    :func:`drill_env.agents.learning.cards.write_policy_card`). Returns the summary. A config
    that distils a trained policy (``warm_start.policy``) takes it loaded as ``teacher``
    (:func:`drill_env.agents.registry.teacher_policy`).

    ``max_wall_time_s``: a wall-clock budget from the call on (building the rigs, the warm
    start, the reference returns and every evaluation included). The clock is read at every
    step of the rigs, inside rollouts, for every algorithm: training stops as soon as the
    last evaluation's duration, the longest update between two rollouts seen and 2 s for
    writing the results no longer fit, then runs one last evaluation. The summary records
    the budget, the wall time of the whole call and the overrun (wall time - budget,
    negative when it ended early); ``stopped_by`` says which limit ended the training
    (``total_timesteps``, ``max_wall_time``, or ``target``: ``evaluation.stop_at_target``).

    With ``evaluation.target_check`` every evaluation also runs the learned controllers'
    target check (:mod:`drill_env.agents.evaluation.target_check`: suppression and tracking on
    a grid of the rig's regimes) and the kept policy is the best by its margin (the summary's
    ``best_target_check``); ``evaluation.stop_at_target`` ends training at the first
    evaluation that meets it."""
    import gymnasium as gym
    import stable_baselines3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed: expected an integer >= 0, got {seed!r}")
    if max_wall_time_s is not None and not (
        isinstance(max_wall_time_s, (int, float)) and math.isfinite(max_wall_time_s) and max_wall_time_s > 0
    ):
        raise ValueError(f"max_wall_time_s: expected a positive number of seconds, got {max_wall_time_s!r}")
    t_start = time.perf_counter()  # the wall-time budget counts from here
    out_dir, run_dir = Path(out_dir), Path(run_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    run_dir.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(cfg.torch_threads)
    venv = make_train_vec_env(cfg, seed)
    if cfg.normalize_reward:
        gamma = float(cfg.hyperparameters.get("gamma", 0.99))
        venv = VecNormalize(venv, norm_obs=False, norm_reward=True, gamma=gamma)
    hp = algo_kwargs(cfg.hyperparameters, n_actions=int(np.prod(venv.action_space.shape)))
    model = _algo_class(cfg.algo)("MlpPolicy", venv, seed=seed, verbose=0, device="cpu", **hp)
    ignore_observations(model, cfg)
    model.set_logger(configure(str(run_dir), ["csv", "tensorboard"]))

    eval_env = make_version(cfg.env_id, **cfg.env_kwargs)
    # the regimes the training rig has (an identified rig may lack one): the others are scored
    eval_regimes = eval_env.unwrapped.settings.sampler.regimes_present()
    episodes = evaluation_episodes(cfg.evaluation, eval_regimes)
    base = None
    callbacks: list[Any] = []
    if cfg.residual is not None:
        from drill_env.agents.learning.residual import (
            ResidualPolicy,
            base_controller,
            critic_burn_in_callback,
            start_from_base,
        )

        base = base_controller(cfg.residual, cfg.env_id, cfg.env_kwargs)
        start_from_base(model, cfg.residual)
        burn_in = critic_burn_in_callback(model, cfg.residual)
        if burn_in is not None:
            callbacks.append(burn_in)
    from drill_env.agents.learning.late_phase import averaged_actor, late_phase_callback

    late = late_phase_callback(cfg.late_phase, cfg.total_timesteps)
    if late is not None:
        callbacks.append(late)

    def save(path: Path) -> None:
        # the late phase's averaged actor, when it has one, is the run's policy
        with atomic_path(path, suffix=".zip") as tmp, averaged_actor(model, late):  # never half-written
            if cfg.residual is None:
                model.save(str(tmp))
                return
            from drill_env.agents.learning.residual import saved_as_correction

            with saved_as_correction(model, cfg.algo):  # SB3's load of it alone raises, naming load_policy
                model.save(str(tmp))

    def current_policy() -> Any:
        # built anew for every evaluation: SB3Policy's numpy actor copies the weights of the
        # moment (the late phase's averaged actor, when it has one), and the learner updates
        # them in place
        with averaged_actor(model, late):
            policy: Any = SB3Policy(model, cfg.algo)
        if base is None:
            return policy
        return ResidualPolicy(policy, base, cfg.residual.scale, observe_base=cfg.residual.observe_base)

    rows: list[dict[str, Any]] = []
    best: dict[str, Any] = {"return": -math.inf, "step": 0, "margin": -math.inf, "target": None}
    eval_time = [0.0]
    check = None
    if cfg.evaluation.target_check:
        from drill_env.agents.evaluation.target_check import TargetCheck

        check = TargetCheck(ENV_IDS[cfg.env_id], ENV_VERSIONS[cfg.env_id])
    # the references first, and the modules of the results imported: inside the wall-time
    # budget, nothing but the last evaluation and writing the files after it
    refs = _reference_returns(cfg, episodes)
    import matplotlib.backends.backend_agg  # noqa: F401
    import pandas  # noqa: F401

    def run_eval(step: int) -> None:
        t0 = time.perf_counter()
        policy = current_policy()
        rets = evaluate_on_episodes(eval_env, policy, episodes)
        target = check(policy) if check is not None else None
        eval_time[0] += time.perf_counter() - t0
        k = cfg.evaluation.episodes_per_regime
        row = {
            "timesteps": step,
            "wall_time": time.perf_counter() - t_start,
            "mean_return": float(np.mean(rets)),
            "std_return": float(np.std(rets)),
        }
        for regime in REGIMES:  # NaN for a regime the rig does not have
            j = eval_regimes.index(regime) if regime in eval_regimes else -1
            row[f"return_{regime}"] = float(np.mean(rets[j * k : (j + 1) * k])) if j >= 0 else math.nan
        if target is not None:
            row.update(target_met=target.met, target_margin=target.margin)
            row.update({f"suppression_{r}": v for r, v in target.suppression.items()})
            row.update({f"rms_error_{r}": v for r, v in target.rms_error.items()})
        rows.append(row)
        model.logger.record("eval/mean_return", row["mean_return"])
        for regime in eval_regimes:
            model.logger.record(f"eval/return_{regime}", row[f"return_{regime}"])
        if target is not None:
            model.logger.record("eval/target_margin", target.margin)
        model.logger.dump(step)
        # the kept policy: the best by the target check's margin when there is one, else by return
        better = target.margin > best["margin"] if target is not None else row["mean_return"] > best["return"]
        if better:
            best.update({"return": row["mean_return"], "step": step})
            if target is not None:
                best.update({"margin": target.margin, "target": target.to_dict()})
            save(out_dir / "policy.zip")
            finish_policy_file(out_dir / "policy.zip", cfg)
        # what the last evaluation cost, saving included: the reserve of the wall-time budget
        budget["eval_s"] = max(budget["eval_s"], time.perf_counter() - t0)
        if on_eval is not None:
            on_eval(step, row["mean_return"])
        if target is not None and target.met and cfg.evaluation.stop_at_target:
            if stopped_by[0] == "total_timesteps":  # not the last evaluation after another limit
                stopped_by[0] = "target"

    # wall-time budget: stop while the last evaluation and the longest update seen still fit
    budget = {"eval_s": 0.0, "update_s": 0.0, "rollout_end": None}

    def out_of_time() -> bool:
        if max_wall_time_s is None:
            return False
        reserve = budget["eval_s"] + budget["update_s"] + _FINISH_RESERVE_S
        return time.perf_counter() - t_start + reserve >= max_wall_time_s

    class _Eval(BaseCallback):
        def __init__(self):
            super().__init__()
            self.next_eval = cfg.evaluation.every_steps

        def _on_training_start(self) -> None:
            run_eval(0)

        def _on_rollout_start(self) -> None:
            if budget["rollout_end"] is not None:  # the update between two rollouts
                budget["update_s"] = max(budget["update_s"], time.perf_counter() - budget["rollout_end"])

        def _on_rollout_end(self) -> None:
            budget["rollout_end"] = time.perf_counter()

        def _on_step(self) -> bool:  # every step of the rigs, inside a rollout
            if stopped_by[0] != "total_timesteps":
                return False
            if out_of_time():
                stopped_by[0] = "max_wall_time"
                return False  # SB3 ends learn() here, mid-rollout; the last evaluation follows
            if self.num_timesteps >= self.next_eval:
                run_eval(self.num_timesteps)
                self.next_eval += cfg.evaluation.every_steps
                return stopped_by[0] == "total_timesteps"
            return True

    stopped_by = ["total_timesteps"]
    warm = None
    if cfg.warm_start is not None:  # part of the training's wall time
        from drill_env.agents.learning.warm_start import warm_start

        warm = warm_start(
            model, cfg.warm_start, cfg.env_id, cfg.env_kwargs, seed, residual=cfg.residual, teacher=teacher
        )
    model.learn(
        total_timesteps=cfg.total_timesteps, callback=[*callbacks, _Eval()], progress_bar=progress_bar
    )
    if not rows or rows[-1]["timesteps"] != model.num_timesteps:
        run_eval(model.num_timesteps)
    save(run_dir / "final_policy.zip")
    finish_policy_file(run_dir / "final_policy.zip", cfg)
    venv.close()

    import pandas as pd

    curve = pd.DataFrame(rows)
    atomic_write_text(out_dir / "eval.csv", curve.to_csv(index=False, float_format="%.6g"))
    progress_csv = run_dir / "progress.csv"
    if progress_csv.is_file() and progress_csv.stat().st_size > 0:
        prog = pd.read_csv(progress_csv)
        keep = [c for c in prog.columns if c.startswith(("time/", "rollout/", "train/"))]
        atomic_write_text(out_dir / "progress.csv", prog[keep].to_csv(index=False, float_format="%.6g"))
    conv = plateau(curve["mean_return"].to_numpy(), **vars(cfg.convergence))
    summary = {
        "algo": cfg.algo,
        "env_id": cfg.env_id,
        "seed": seed,
        "total_timesteps": int(model.num_timesteps),
        "env_steps": int(model.num_timesteps),
        "wall_time_s": None,  # below, when everything but the card is written
        "max_wall_time_s": max_wall_time_s,
        "overrun_s": None,
        "stopped_by": stopped_by[0],
        "evaluation_wall_time_s": round(eval_time[0], 1),
        "warm_start": warm,
        "n_evaluations": len(rows),
        "final_eval_return": rows[-1]["mean_return"],
        "best_eval_return": best["return"],
        "best_at_timesteps": best["step"],
        "kept_by": "target_check" if check is not None else "mean_return",
        "best_target_check": best["target"],
        "policy": "policy.zip (the evaluation-best policy)",
        "converged": conv["converged"],
        "convergence": conv,
        "reference_returns": refs,
        "evaluation_episodes": [{"seed": s, **o} for s, o in episodes],
        "config": cfg.to_dict(),
        "versions": {
            "python": platform.python_version(),
            "stable_baselines3": stable_baselines3.__version__,
            "torch": torch.__version__,
            "gymnasium": gym.__version__,
        },
    }
    atomic_write_text(out_dir / "config.yaml", yaml.safe_dump(cfg.to_dict(), sort_keys=False))
    plot_learning_curve(out_dir, summary)
    eval_env.close()
    wall = time.perf_counter() - t_start
    summary["wall_time_s"] = round(wall, 1)
    if max_wall_time_s is not None:
        summary["overrun_s"] = round(wall - max_wall_time_s, 1)
    atomic_write_json(out_dir / "training_summary.json", summary)
    return summary


def plot_learning_curve(out_dir: str | Path, summary: Mapping[str, Any] | None = None) -> Path:
    """``learning_curve.png`` from ``eval.csv`` (and ``progress.csv``) in ``out_dir``."""
    import pandas as pd

    from drill_env._figures import subplots

    out_dir = Path(out_dir)
    if summary is None:
        summary = json.loads((out_dir / "training_summary.json").read_text())
    curve = pd.read_csv(out_dir / "eval.csv")
    font = 9.0  # [pt] on a figure 8 in wide: legible where the docs draw it (drill_env._figures)
    fig, axes = subplots(2, 1, figsize=(8.0, 6.6))
    ax = axes[0]
    ax.plot(curve["timesteps"], curve["mean_return"], "k.-", label="all regimes")
    for regime in REGIMES:
        col = f"return_{regime}"
        if col in curve:
            ax.plot(curve["timesteps"], curve[col], lw=0.8, label=regime)
    for name, value in (summary.get("reference_returns") or {}).items():
        ax.axhline(value, ls="--", lw=0.8, color="gray")
        ax.annotate(name, (curve["timesteps"].iloc[0], value), fontsize=font, va="bottom", color="gray")
    ax.set_xlabel("environment steps", fontsize=font)
    ax.set_ylabel("evaluation return\n(deterministic) [-]", fontsize=font)
    verdict = "converged" if summary.get("converged") else "not converged"
    ax.set_title(f"{summary['algo'].upper()} seed {summary['seed']}: {verdict}", fontsize=font + 1)
    ax.legend(
        fontsize=font, loc="center left", bbox_to_anchor=(1.01, 0.5), title="regime", title_fontsize=font
    )
    ax = axes[1]
    prog_path = out_dir / "progress.csv"
    rows = None
    if prog_path.is_file() and prog_path.read_text().strip():  # blank: SB3 logged nothing yet
        prog = pd.read_csv(prog_path)
        if "rollout/ep_rew_mean" in prog and "time/total_timesteps" in prog:
            rows = prog[["time/total_timesteps", "rollout/ep_rew_mean"]].dropna()
    if rows is not None and len(rows):
        ax.plot(rows["time/total_timesteps"], rows["rollout/ep_rew_mean"], lw=0.8)
    else:
        ax.text(
            0.5,
            0.5,
            "no training episode logged yet\n(the run was shorter than one logging interval)",
            ha="center",
            va="center",
            transform=ax.transAxes,
            fontsize=font,
        )
    ax.set_xlabel("environment steps", fontsize=font)
    ax.set_ylabel("training episode return\n(stochastic) [-]", fontsize=font)
    ax.set_title("training episodes", fontsize=font + 1)
    for a in axes:
        a.tick_params(labelsize=font)
    fig.tight_layout()
    path = out_dir / "learning_curve.png"
    save_figure(fig, path, dpi=110)
    return path
