"""Native batched environment: N rigs stepped in one compiled call.

``gymnasium.make_vec("DrillString-v0", num_envs=N)`` returns a :class:`DrillStringVectorEnv`
(the registered ``vector_entry_point``). Rig i behaves exactly as a
:class:`~drill_env.envs.drill_string.DrillStringEnv` wrapped in ``TimeLimit`` and reset
with seed ``seed + i``: both run the same compiled code and draw from their own
generator in the same order, so a ``SyncVectorEnv`` of N single environments returns the
same observations, rewards and infos, step for step.

Seeds: ``reset(seed=s)`` seeds rig i with ``s + i``; a sequence gives one seed (or None)
per rig; NumPy integers count as integers. A masked reset (``options["reset_mask"]``) must
select at least one rig, and ``step`` raises ``ResetNeeded`` until every rig was reset.

Autoreset: Gymnasium 1.x ``AutoresetMode.NEXT_STEP`` by default (as ``SyncVectorEnv``):
the step after a rig's episode ended resets that rig, ignores its action and returns its
first observation with reward 0 and ``terminated = truncated = False``.
``autoreset_mode=AutoresetMode.SAME_STEP`` resets in the step that ends the episode and
returns the last observation and info in ``info["final_obs"]`` / ``info["final_info"]``.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from drill_env import _layout as L
from drill_env.envs import _core as C
from drill_env.envs.config import MAX_WARMUP_RETRIES, REWARD_NAMES, EnvSettings, check_actions, check_seed
from drill_env.kernel import STATUS_MESSAGES

__all__ = ["DrillStringVectorEnv"]


class DrillStringVectorEnv(VectorEnv):
    """N drill-string rigs in one compiled step (see :class:`DrillStringEnv` for the task,
    spaces, rewards and arguments).

    Args:
        num_envs: number of rigs N.
        max_episode_steps: truncation length (the single env gets it from ``TimeLimit``).
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (default) or ``AutoresetMode.SAME_STEP``.
        **kwargs: the arguments of :class:`DrillStringEnv` (``params``, ``control_dt``,
            ``sensors``, ``task``, ``domain_randomization``, ...), shared by all rigs.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int = 1,
        *,
        max_episode_steps: int | None = 400,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        render_mode: str | None = None,
        **kwargs: Any,
    ):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs: expected an integer >= 1, got {num_envs!r}")
        if max_episode_steps is not None and (
            isinstance(max_episode_steps, bool)
            or not isinstance(max_episode_steps, (int, np.integer))
            or max_episode_steps < 1
        ):
            raise ValueError(
                f"max_episode_steps: expected an integer >= 1 or None, got {max_episode_steps!r}"
            )
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(
                f"autoreset_mode: {autoreset_mode!r} is not one of "
                f"{[AutoresetMode.NEXT_STEP.value, AutoresetMode.SAME_STEP.value]}"
            ) from None
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise ValueError(f"autoreset_mode: {mode.value!r} is not supported; use NextStep or SameStep")
        if render_mode is not None:
            raise ValueError(
                f"render_mode: the native vector env does not render (got {render_mode!r}); render a single "
                "DrillStringEnv or use gymnasium.make_vec(..., vectorization_mode='sync')"
            )
        self.settings = s = EnvSettings(**kwargs)
        if s.schedule is not None:
            raise ValueError(
                f"scenario: {s.schedule.scenario.name!r} changes the set point or friction during the episode, "
                "which the native vector env does not do; use gymnasium.make_vec(..., "
                "vectorization_mode='sync') or a scenario without changes"
            )
        self.num_envs = n = int(num_envs)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.autoreset_mode = mode
        self.metadata = dict(self.metadata, autoreset_mode=mode)
        self.render_mode = None
        self.single_action_space = s.action_space()
        self.single_observation_space = s.observation_space()
        self.action_space = batch_space(self.single_action_space, n)
        self.observation_space = batch_space(self.single_observation_space, n)
        self.control_dt = s.control_dt
        self._ecfg = s.ecfg
        k = s.n_sub
        self._P = np.tile(s.params.as_array(), (n, 1))
        self._SCFG = np.tile(s.sensors.as_array(), (n, 1))
        self._Y = np.zeros((n, L.NY))
        self._MODES = np.zeros((n, 2), dtype=np.int64)
        self._EP = np.zeros((n, C.NEP))
        self._SST = np.zeros((n, s.sensor_state_size))
        self._RNG = np.zeros((n, 4), dtype=np.uint64)
        self._OBS = np.zeros((n, s.n_obs), dtype=np.float32)
        self._v1 = s.observation_version >= 1
        self._OUT = np.zeros((n, C.NOUT))
        self._YBUF = np.zeros((n, k, L.NY))
        self._MBUF = np.zeros((n, k, 2), dtype=np.int64)
        self._UBUF = np.zeros((n, k))
        self._Y0 = np.zeros((n, L.NY))
        self._START = np.zeros(n, dtype=np.int64)
        self._WARM = np.zeros(n, dtype=np.int64)
        self._TARGET = np.zeros(n)
        self._UNOM = np.zeros(n)
        self._points: list[Any] = [None] * n
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._elapsed = np.zeros(n, dtype=np.int64)
        self._done = np.zeros(n, dtype=bool)
        self._started = np.zeros(n, dtype=bool)  # rigs reset at least once
        self._ts = s.sensors.sample_period
        self._action_to_volts = s.action_to_volts
        self._action_offset = s.action_offset

    # -- Gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None):
        n = self.num_envs
        seeds = self._seeds(seed)
        mask = np.ones(n, dtype=bool)
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"])
            if mask.dtype != np.bool_ or mask.shape != (n,):
                raise ValueError(
                    f"options['reset_mask']: expected a bool array of shape ({n},), got {options['reset_mask']!r}"
                )
            if not mask.any():
                raise ValueError(
                    "options['reset_mask']: must select at least one rig (one True), got all False"
                )
        super().reset(seed=seeds[0] if isinstance(seed, (int, np.integer)) else None)
        opts = self.settings.parse_options(options)
        for i in np.flatnonzero(mask):
            if seeds[i] is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(seeds[i])
        self._reset_rigs(mask, opts)
        self._elapsed[mask] = 0  # new episodes: truncation counts from this reset
        self._done[mask] = False
        self._started |= mask
        info = self._info_reset_only(mask)
        # masked reset: the rigs not reset report nothing (zeros, masks False), as SyncVectorEnv
        return self._OBS.copy(), info if mask.all() else _select(info, mask)

    def step(self, actions):
        if not self._started.all():
            never = np.flatnonzero(~self._started).tolist()
            raise ResetNeeded(
                "step: call reset() before step()"
                + (f" (rigs {never} were never reset)" if len(never) < self.num_envs else "")
            )
        n = self.num_envs
        high = float(self.single_action_space.high[0])
        a = check_actions(actions, "actions", (n, 1), high).reshape(n)
        u_req = a * self._action_to_volts
        if self._action_offset:
            u_req = u_req + self._EP[:, C.EP_UNOM]
        resetting = self._done.copy() if self.autoreset_mode == AutoresetMode.NEXT_STEP else np.zeros(n, bool)
        if resetting.any():
            self._reset_rigs(resetting, {})
            self._elapsed[resetting] = 0
        active = ~resetting
        C.batch_step(
            self._P,
            self._Y,
            self._MODES,
            self._EP,
            self._ecfg,
            self._SCFG,
            self._SST,
            self._RNG,
            u_req,
            active,
            self._OBS,
            self._OUT,
            self._YBUF,
            self._MBUF,
            self._UBUF,
        )
        u = self._EP[:, C.EP_U].copy()  # the requests within the amplifier's limit (the core applies it)
        clipped = u != u_req
        self._elapsed[active] += 1
        status = self._OUT[:, C.O_STATUS].astype(np.int64)
        status[resetting] = 0
        rewards = np.where(active, self._OUT[:, C.O_REWARD], 0.0)
        terminated = np.zeros(n, dtype=bool)
        truncated = active & (status != 0)
        if self.max_episode_steps is not None:
            truncated |= active & (self._elapsed >= self.max_episode_steps)
        if np.any(status != 0):
            i = int(np.flatnonzero(status != 0)[0])
            warnings.warn(
                f"DrillStringVectorEnv.step: rig {i}: the simulator stopped ({STATUS_MESSAGES[int(status[i])]}); "
                "its episode is truncated",
                RuntimeWarning,
                stacklevel=2,
            )
        info = self._info(active, resetting, u, u_req, clipped, status)
        obs = self._OBS.copy()
        done = terminated | truncated
        if self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            final_obs = np.full(n, None, dtype=object)
            for i in np.flatnonzero(done):
                final_obs[i] = obs[i].copy()
            final_info = _select(info, done)
            self._reset_rigs(done, {})
            self._elapsed[done] = 0
            obs = self._OBS.copy()
            info = self._info(active & ~done, done, u, u_req, clipped, status)
            info["final_obs"] = final_obs
            info["_final_obs"] = done.copy()
            info["final_info"] = final_info
            info["_final_info"] = done.copy()
            self._done[:] = False
        else:
            self._done = done
        return obs, rewards, terminated, truncated, info

    def _seeds(self, seed: Any) -> list[int | None]:
        """One seed (or None) per rig from ``reset(seed=...)``: an integer s gives s + i."""
        n = self.num_envs
        if seed is None:
            return [None] * n
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            first = check_seed(seed)
            assert first is not None  # an integer was given
            return [first + i for i in range(n)]
        if isinstance(seed, (str, bytes, Mapping)) or not isinstance(seed, (Sequence, np.ndarray)):
            raise ValueError(
                f"seed: expected an integer >= 0, None or a sequence of {n} of them, got {seed!r}"
            )
        seeds = list(seed)
        if len(seeds) != n:
            raise ValueError(f"seed: expected an int, None or {n} seeds, got {len(seeds)}")
        return [check_seed(x, f"seed[{i}]") for i, x in enumerate(seeds)]

    # -- extras ----------------------------------------------------------------------------------
    @property
    def operating_points(self) -> list[Any]:
        """The :class:`~drill_env.envs.task.OperatingPoint` of each rig's episode."""
        return list(self._points)

    # -- internals -------------------------------------------------------------------------------
    def _batch_reset(self, mask: np.ndarray) -> None:
        """Put the rigs with ``mask`` at the start of their (already drawn) episodes."""
        C.batch_reset(
            self._P,
            self._Y,
            self._MODES,
            self._EP,
            self._ecfg,
            self._SCFG,
            self._SST,
            self._RNG,
            self._Y0,
            self._START,
            self._WARM,
            self._TARGET,
            self._UNOM,
            mask,
            self._OBS,
            self._OUT,
            self._YBUF,
            self._MBUF,
            self._UBUF,
        )

    def _reset_rigs(self, mask: np.ndarray, opts: Mapping[str, Any]) -> None:
        s = self.settings
        idx = np.flatnonzero(mask)
        setups = {}
        for i in idx.tolist():
            rng = self._rngs[i]
            assert rng is not None  # every rig's generator is made at its first reset
            setup = s.draw_episode(rng, opts)
            setups[i] = setup
            self._load(i, setup)
        self._batch_reset(mask)
        # Same retry rule as the single env: a failed warm-up is redrawn from the rig's generator.
        for i in idx.tolist():
            rng = self._rngs[i]
            assert rng is not None
            for _ in range(MAX_WARMUP_RETRIES):
                if self._EP[i, C.EP_STATUS] == 0:
                    break
                self._WARM[i] = s.draw_warm_ticks(rng)
                self._RNG[i] = setups[i].rng
                one = np.zeros(self.num_envs, dtype=bool)
                one[i] = True
                self._batch_reset(one)
            if self._EP[i, C.EP_STATUS] != 0:
                raise RuntimeError(
                    f"reset: rig {i}: the warm-up simulation failed: {STATUS_MESSAGES[int(self._EP[i, C.EP_STATUS])]}"
                )

    def _load(self, i: int, setup) -> None:
        self._P[i] = setup.params
        self._SCFG[i] = setup.sensors
        self._Y0[i] = setup.y0
        self._START[i] = setup.start
        self._WARM[i] = setup.warm_ticks
        self._TARGET[i] = setup.point.target_speed
        self._UNOM[i] = setup.point.nominal_voltage
        self._points[i] = setup.point
        self._RNG[i] = setup.rng

    def _common(self, info: dict[str, Any], rows: np.ndarray) -> None:
        out = self._OUT
        info["true_state"] = out[:, C.O_TRUE : C.O_TRUE + C.N_TRUE].copy()
        info["_true_state"] = rows.copy()
        info["upper_stuck"] = out[:, C.O_UPPER_STUCK] != 0.0
        info["_upper_stuck"] = rows.copy()
        info["lower_stuck"] = out[:, C.O_LOWER_STUCK] != 0.0
        info["_lower_stuck"] = rows.copy()
        info["time"] = (self._EP[:, C.EP_TICK] - self._EP[:, C.EP_TICK0]) * self._ts
        info["_time"] = rows.copy()
        if self._v1:
            info["integral_clipped"] = (out[:, C.O_INT_CLIPPED] != 0.0) & rows
            info["_integral_clipped"] = rows.copy()

    def _reset_part(self, info: dict[str, Any], rows: np.ndarray) -> None:
        n = self.num_envs
        info["target_speed"] = np.where(rows, self._TARGET, 0.0)
        info["_target_speed"] = rows.copy()
        info["nominal_voltage"] = np.where(rows, self._UNOM, 0.0)
        info["_nominal_voltage"] = rows.copy()
        regime = np.full(n, None, dtype=object)
        for i in np.flatnonzero(rows):
            regime[i] = self._points[i].regime
        info["regime"] = regime
        info["_regime"] = rows.copy()

    def _info_reset_only(self, rows: np.ndarray) -> dict[str, Any]:
        info: dict[str, Any] = {}
        self._common(info, rows)
        info["voltage"] = np.where(rows, self._EP[:, C.EP_U], 0.0)
        info["_voltage"] = rows.copy()
        self._reset_part(info, rows)
        return info

    def _info(self, stepped, reset_rows, u, u_req, clipped, status) -> dict[str, Any]:
        rows = stepped | reset_rows
        info: dict[str, Any] = {}
        self._common(info, rows)
        info["voltage"] = np.where(stepped, u, np.where(reset_rows, self._EP[:, C.EP_U], 0.0))
        info["_voltage"] = rows.copy()
        if stepped.any():
            info["voltage_requested"] = np.where(stepped, u_req, 0.0)
            info["_voltage_requested"] = stepped.copy()
            info["voltage_clipped"] = clipped & stepped
            info["_voltage_clipped"] = stepped.copy()
            rewards: dict[str, Any] = {}
            for name, j in zip(REWARD_NAMES, C.REWARD_SLOTS, strict=True):
                rewards[name] = np.where(stepped, self._OUT[:, j], 0.0)
                rewards[f"_{name}"] = stepped.copy()
            info["rewards"] = rewards
            info["_rewards"] = stepped.copy()
            info["sim_status"] = np.where(stepped, status, 0)
            info["_sim_status"] = stepped.copy()
        if reset_rows.any():
            self._reset_part(info, reset_rows)
        return info


def _select(info: dict[str, Any], rows: np.ndarray) -> dict[str, Any]:
    """The part of a vector info that belongs to ``rows`` (masks and values outside cleared)."""
    out: dict[str, Any] = {}
    for key, value in info.items():
        if key.startswith("_"):
            out[key] = value & rows
        elif isinstance(value, dict):
            out[key] = _select(value, rows)
        else:
            v = value.copy()
            keep = rows.reshape((-1,) + (1,) * (v.ndim - 1))
            if v.dtype == object:
                v[~rows] = None
            else:
                v = np.where(keep, v, np.zeros_like(v))
            out[key] = v
    return out
