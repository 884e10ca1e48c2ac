"""Stable-Baselines3 ``VecEnv`` over the native batched environment.

``drill_env.sb3_vec_env("DrillString-v0", n_envs=64)`` returns a
:class:`DrillStringSB3VecEnv`: all rigs advance in one compiled call per step (the native
:class:`~drill_env.envs.vector.DrillStringVectorEnv`), seen through SB3's conventions, so
it is a drop-in replacement for ``DummyVecEnv([lambda: gymnasium.make(env_id) ...])``:

* ``step`` returns ``(obs, rewards, dones, infos)`` with ``dones = terminated | truncated``;
  a rig whose episode ended is reset in the same step, its last observation is in
  ``infos[i]["terminal_observation"]`` and its reset info in ``reset_infos[i]``;
  ``infos[i]["TimeLimit.truncated"]`` is True when the episode was truncated and not
  terminated; ``infos[i]`` is the single environment's step info.
* ``seed(s)`` sets the seeds ``s, s+1, ...`` used by the next ``reset()`` only (as every
  SB3 ``VecEnv`` since Gymnasium 0.26), ``set_options`` the options of the next reset.

For the same seeds and actions it returns exactly what that ``DummyVecEnv`` returns
(both run the same compiled code; rig i draws from its own generator). Rendering is not
supported; ``get_attr`` reads attributes of the vector env (shared by all rigs) and the
per-rig ``operating_point``.

This module imports Stable-Baselines3 (and so torch): ``import drill_env`` does not
import it; ``drill_env.sb3_vec_env`` loads it on first use.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

__all__ = ["DrillStringSB3VecEnv", "sb3_vec_env"]

# per-rig attributes of a single env -> the vector env's attribute listing them per rig
_PER_RIG_ATTRS = {"operating_point": "operating_points"}


def sb3_vec_env(env_id: str, n_envs: int, seed: int | None = 0, **env_kwargs: Any) -> DrillStringSB3VecEnv:
    """An SB3 ``VecEnv`` of ``n_envs`` rigs of ``env_id`` stepped in one compiled call.

    Args:
        env_id: a registered drill-env id (``drill_env.envs.ENV_IDS``).
        n_envs: number of rigs (integer >= 1).
        seed: the first reset uses seeds ``seed, seed + 1, ...`` (SB3's ``VecEnv.seed``);
            None: unseeded.
        **env_kwargs: the environment's arguments (as for ``gymnasium.make(env_id, ...)``,
            including ``max_episode_steps``), shared by all rigs.
    """
    if isinstance(n_envs, bool) or not isinstance(n_envs, (int, np.integer)) or n_envs < 1:
        raise ValueError(f"n_envs: expected an integer >= 1, got {n_envs!r}")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
        raise ValueError(f"seed: expected an integer or None, got {seed!r}")
    if "autoreset_mode" in env_kwargs:
        raise ValueError(
            "autoreset_mode: not an argument of sb3_vec_env (SB3 resets a finished episode in the same "
            "step and returns its last observation in infos[i]['terminal_observation'])"
        )
    from drill_env.envs import ENV_IDS

    if env_id not in ENV_IDS:  # another package's env (CartPole-v1) has no drill-env vector env
        raise ValueError(
            f"env_id: {env_id!r} is not a drill-env id (no native vector env); allowed: {sorted(ENV_IDS)}"
        )
    spec = gym.spec(env_id)
    if spec.vector_entry_point is None:
        raise ValueError(f"env_id: {env_id!r} has no native vector env; use one of {sorted(ENV_IDS)}")
    venv = gym.make_vec(
        env_id,
        num_envs=int(n_envs),
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
        **env_kwargs,
    )
    out = DrillStringSB3VecEnv(venv)
    if seed is not None:
        out.seed(int(seed))
    return out


class DrillStringSB3VecEnv(VecEnv):
    """SB3 ``VecEnv`` over a Gymnasium vector env with ``AutoresetMode.SAME_STEP`` (the
    native :class:`~drill_env.envs.vector.DrillStringVectorEnv`); see the module docstring.

    Args:
        vector_env: the Gymnasium vector env, available as ``self.vector_env``.
    """

    def __init__(self, vector_env: gym.vector.VectorEnv):
        mode = vector_env.metadata.get("autoreset_mode")
        if mode != AutoresetMode.SAME_STEP:
            raise ValueError(
                f"vector_env: expected a vector env with autoreset_mode=AutoresetMode.SAME_STEP, got {mode!r}"
            )
        self.vector_env = vector_env
        self._actions: np.ndarray | None = None
        super().__init__(
            vector_env.num_envs, vector_env.single_observation_space, vector_env.single_action_space
        )
        self.metadata = {**vector_env.metadata, "render_modes": []}

    # -- SB3 VecEnv API --------------------------------------------------------------------------
    def reset(self) -> VecEnvObs:
        n = self.num_envs
        seeds = list(self._seeds)
        groups: list[tuple[dict[str, Any], np.ndarray]] = []  # rigs sharing the same options
        for i, opts in enumerate(self._options):
            opts = opts or {}
            if "reset_mask" in opts:
                raise ValueError("set_options: 'reset_mask' is not an environment option")
            for g_opts, g_mask in groups:
                if _same_options(g_opts, opts):
                    g_mask[i] = True
                    break
            else:
                mask = np.zeros(n, dtype=bool)
                mask[i] = True
                groups.append((opts, mask))
        if len(groups) == 1:
            opts = groups[0][0]
            # a seed per rig: VectorEnv.reset is annotated int | None, its implementations take lists
            obs, info = self.vector_env.reset(seed=seeds, options=dict(opts) if opts else None)  # type: ignore[arg-type]
            infos = _split_info(info, n)
        else:
            infos = [{} for _ in range(n)]
            for opts, mask in groups:
                obs, info = self.vector_env.reset(seed=seeds, options={**opts, "reset_mask": mask})  # type: ignore[arg-type]
                part = _split_info(info, n)
                for i in np.flatnonzero(mask).tolist():
                    infos[i] = part[i]
        self.reset_infos = infos
        self._actions = None
        # seeds and options are used once
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError(
                "step_wait: call step_async(actions) first (and reset() before the first step)"
            )
        actions, self._actions = self._actions, None
        obs, rewards, terminated, truncated, info = self.vector_env.step(actions)
        n = self.num_envs
        dones = terminated | truncated
        time_limit = (truncated & ~terminated).tolist()
        infos = _split_info(info, n, skip=("final_obs", "final_info"))
        if dones.any():
            final_infos = _split_info(info["final_info"], n)
            final_obs = info["final_obs"]
            for i in np.flatnonzero(dones).tolist():
                self.reset_infos[i] = infos[i]
                infos[i] = final_infos[i]
                infos[i]["terminal_observation"] = final_obs[i]
        for i in range(n):
            infos[i]["TimeLimit.truncated"] = time_limit[i]
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self.vector_env.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The attribute of the vector env (the same for every rig), or per rig for
        ``operating_point``."""
        idx = list(self._get_indices(indices))
        env = self.vector_env
        if attr_name in _PER_RIG_ATTRS and hasattr(env, _PER_RIG_ATTRS[attr_name]):
            values = getattr(env, _PER_RIG_ATTRS[attr_name])
            return [values[i] for i in idx]
        try:
            value = getattr(env, attr_name)
        except AttributeError:
            raise AttributeError(
                f"get_attr: {type(env.unwrapped).__name__} has no attribute {attr_name!r} (the SB3 adapter "
                f"reads attributes of the native vector env, shared by all rigs, and per rig "
                f"{sorted(_PER_RIG_ATTRS)})"
            ) from None
        return [value for _ in idx]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute of the vector env: all rigs share it, so ``indices`` must cover them all."""
        idx = sorted(set(self._get_indices(indices)))
        if idx != list(range(self.num_envs)):
            raise NotImplementedError(
                f"set_attr({attr_name!r}): the rigs of the native vector env share their attributes; "
                f"set it for all envs (indices=None), got indices={indices!r}"
            )
        setattr(self.vector_env, attr_name, value)

    def env_method(
        self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs
    ) -> list[Any]:
        raise NotImplementedError(
            f"env_method({method_name!r}): the rigs are stepped in one compiled call and have no per-env "
            "methods; call the vector env's methods on .vector_env, or use DummyVecEnv of single envs"
        )

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        """False: the rigs are not ``gymnasium.Wrapper``-wrapped (truncation at
        ``max_episode_steps`` is built into the vector env)."""
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        raise NotImplementedError(_NO_RENDER)

    def render(self, mode: str | None = None) -> np.ndarray | None:
        raise NotImplementedError(_NO_RENDER)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.vector_env!r})"


_NO_RENDER = (
    "render: the native vector env does not render; render a single env "
    "(gymnasium.make(env_id, render_mode=...)) or use DummyVecEnv of single envs"
)


def _same_options(a: dict[str, Any], b: dict[str, Any]) -> bool:
    if a.keys() != b.keys():
        return False
    for k in a:
        x, y = a[k], b[k]
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not np.array_equal(x, y):
                return False
        elif isinstance(x, dict) and isinstance(y, dict):
            if not _same_options(x, y):
                return False
        elif x is not y and x != y:
            return False
    return True


def _split_info(info: dict[str, Any], n: int, skip: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """Per-env dicts from a Gymnasium vector info (arrays with ``_key`` masks): env i gets
    the keys whose mask is set for i, scalars as Python scalars (as the single env)."""
    out: list[dict[str, Any]] = [{} for _ in range(n)]
    for key, value in info.items():
        if key.startswith("_") or key in skip:
            continue
        mask = info.get("_" + key)
        rows = range(n) if mask is None else np.flatnonzero(mask).tolist()
        if isinstance(value, dict):
            sub = _split_info(value, n)
            for i in rows:
                out[i][key] = sub[i]
        else:
            value = np.asarray(value)
            vals = value.tolist() if value.ndim == 1 else value
            for i in rows:
                out[i][key] = vals[i]
    return out
