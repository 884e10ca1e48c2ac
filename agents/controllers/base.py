"""The controller protocol: stable-baselines3's ``predict`` for classical and learned controllers.

Every controller of the benchmark answers

    action, state = controller.predict(obs, state=None, episode_start=None, deterministic=True)

exactly as an SB3 model does (``PolicyPredictor``): ``obs`` is what the environment returns
(one observation of shape ``(8,)`` or a batch ``(n, 8)``), ``action`` what it accepts, and
``state`` the controller's memory (PI integrators, filter states, scheduled gains; SB3's
recurrent hidden state plays the same role). ``state=None`` or ``episode_start[i] = True``
starts row i afresh from its observation. Classical controllers keep no memory of their own
between calls: the same object can drive any number of rigs, in any process.

A classical controller sees the rig through a :class:`ControllerSpec` built from the
environment: which entry of the observation is which measurement, the scale that turns
it into SI units, the control period and how an action maps to volts. It designs itself
on the *nominal* model (the preset's parameters, ``spec.params``), never on the plant the
environment simulates, which may be randomised or carry extra effects.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from drill_env.envs.config import OBSERVATION_NAMES, OBSERVATION_SCALES
from drill_env.envs.task import VOLTAGE_LIMIT, nominal_params
from drill_env.params import RigParams, resolve_params
from drill_env.sensors import SensorConfig

__all__ = ["ControllerSpec", "Controller", "PolicyPredictor", "VOLTAGE_LIMIT"]


@runtime_checkable
class PolicyPredictor(Protocol):
    """What the evaluation needs: SB3's ``predict`` (models and our controllers alike)."""

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]: ...


@dataclass(frozen=True)
class ControllerSpec:
    """How a controller talks to one environment configuration.

    ``physical = obs * observation_scales`` entry by entry (SI units, see the env's
    observation table); ``volts = action * action_to_volts``, plus the observed nominal
    voltage where ``action_offset`` (the correction action of ``DrillString-v2``).
    """

    params: RigParams  # the design model, effects left out (its linear, paper model)
    control_dt: float  # [s] hold period of the action
    observation_names: tuple[str, ...] = OBSERVATION_NAMES
    observation_scales: tuple[float, ...] = OBSERVATION_SCALES
    action_to_volts: float = VOLTAGE_LIMIT  # [V per action unit]
    voltage_limit: float = VOLTAGE_LIMIT  # [V] the amplifier range
    action_offset: bool = False  # the action is the correction to the nominal voltage (v2)
    # the action space's bound [action units]: the env refuses an action beyond it
    action_limit: float = math.inf
    sensors: SensorConfig = field(default_factory=SensorConfig)  # the measurement chain
    env_id: str | None = None
    # the design model's named effects (ModelEffects; None: those of ``params`` as given, then
    # removed from it): what an effect-aware design uses (drill_env.agents.controllers.effect_feedforward)
    effects: Any = None
    _index: dict[str, int] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.control_dt) and self.control_dt > 0):
            raise ValueError(f"control_dt: expected a finite number > 0 s, got {self.control_dt!r}")
        if len(self.observation_names) != len(self.observation_scales):
            raise ValueError(
                f"observation_scales: expected {len(self.observation_names)} entries, "
                f"got {len(self.observation_scales)}"
            )
        if not (math.isfinite(self.action_to_volts) and self.action_to_volts > 0):
            raise ValueError(f"action_to_volts: expected a finite number > 0, got {self.action_to_volts!r}")
        full = resolve_params(self.params)
        if self.effects is None:
            object.__setattr__(self, "effects", full.effects)
        object.__setattr__(self, "params", nominal_params(full))
        object.__setattr__(self, "observation_scales", tuple(float(s) for s in self.observation_scales))
        self._index.update({n: i for i, n in enumerate(self.observation_names)})

    @classmethod
    def from_env(cls, env: Any) -> ControllerSpec:
        """The spec of a :class:`~drill_env.envs.drill_string.DrillStringEnv` (wrapped or not) or
        of its vector version."""
        base = getattr(env, "unwrapped", env)
        settings = getattr(base, "settings", None)
        if settings is None:
            raise ValueError(
                f"env: expected a drill-string environment (with .settings), got {type(base).__name__}"
            )
        from drill_env.envs import _core as C

        n_obs = getattr(settings, "n_obs", C.NOBS_V0)
        scales = settings.ecfg[C.EC_SCALE : C.EC_SCALE + n_obs]
        names = getattr(settings, "observation_names", OBSERVATION_NAMES)
        spec = getattr(env, "spec", None)
        return cls(
            # the design model, not the simulated plant: what a controller may know
            params=getattr(settings, "design_params", settings.params),
            control_dt=settings.control_dt,
            observation_names=tuple(names),
            observation_scales=tuple(float(s) for s in scales),
            action_to_volts=float(settings.action_to_volts),
            action_offset=bool(getattr(settings, "action_offset", False)),
            action_limit=float(settings.action_space().high[0])
            if hasattr(settings, "action_space")
            else math.inf,
            sensors=settings.sensors,
            env_id=None if spec is None else spec.id,
        )

    @classmethod
    def default(cls, preset: str | RigParams = "brake", control_dt: float = 0.05) -> ControllerSpec:
        """The spec of the registered environments with their default arguments."""
        return cls(params=resolve_params(preset), control_dt=control_dt)

    def index(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise ValueError(
                f"observation: no entry {name!r}; entries: {list(self.observation_names)}"
            ) from None

    def to_physical(self, obs: np.ndarray) -> np.ndarray:
        """Observations (n, 8) in SI units (float64)."""
        return np.asarray(obs, dtype=np.float64) * np.asarray(self.observation_scales)

    def to_observation(self, physical: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_physical` (float32, as the environment returns it)."""
        return (np.asarray(physical, dtype=np.float64) / np.asarray(self.observation_scales)).astype(
            np.float32
        )

    def to_action(self, volts: np.ndarray, physical: np.ndarray | None = None) -> np.ndarray:
        """Voltages (n,) -> actions (n, 1), float32, within the amplifier range and the action
        space (``action_limit``: the environment refuses an action outside it).

        With ``action_offset`` the action is relative to the nominal voltage, read from the
        physical observations ``physical`` (n, ...), which are then required; a correction
        beyond the action space's range (``action_to_volts``) is held at its end, as the
        environment clipped it before it refused such actions."""
        v = np.clip(np.asarray(volts, dtype=np.float64), -self.voltage_limit, self.voltage_limit)
        if self.action_offset:
            if physical is None:
                raise ValueError(
                    "physical: the observations are needed to form a correction action (action_offset)"
                )
            v = v - np.asarray(physical, dtype=np.float64)[:, self.index("nominal_voltage")]
        a = np.clip(v / self.action_to_volts, -self.action_limit, self.action_limit)
        return a.astype(np.float32).reshape(-1, 1)


class Controller:
    """Base of the classical controllers.

    Subclasses implement :meth:`initial_state` and :meth:`control` on observations in SI
    units, row-wise for a batch of rigs; this class turns them into SB3's ``predict``.
    ``state`` is a float array of shape ``(n, state_size)``.
    """

    name = "controller"
    state_size = 0

    def __init__(self, spec: ControllerSpec):
        if not isinstance(spec, ControllerSpec):
            raise ValueError(f"spec: expected a ControllerSpec, got {type(spec).__name__}")
        self.spec = spec
        i = spec.index
        self._i_lower, self._i_upper, self._i_twist = i("lower_speed"), i("upper_speed"), i("twist")
        self._i_lower_mean, self._i_upper_mean = i("lower_speed_mean"), i("upper_speed_mean")
        self._i_voltage, self._i_target, self._i_unom = i("voltage"), i("target_speed"), i("nominal_voltage")

    # -- to implement ----------------------------------------------------------------------------
    def initial_state(self, y: np.ndarray) -> np.ndarray:
        """State (n, state_size) at the start of an episode, from its first observation (SI)."""
        return np.zeros((y.shape[0], self.state_size))

    def control(self, y: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Voltages (n,) [V] and the next state for observations ``y`` (n, 8) in SI units."""
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:
        """Name and parameters (for result files)."""
        return {"name": self.name}

    # -- SB3's protocol --------------------------------------------------------------------------
    def predict(
        self,
        observation: np.ndarray,
        state: np.ndarray | None = None,
        episode_start: np.ndarray | Sequence[bool] | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Action(s) for ``observation`` and the next state (see the module docstring).

        ``deterministic`` is accepted for compatibility; classical controllers are.
        """
        obs = np.asarray(observation)
        n_obs = len(self.spec.observation_names)
        single = obs.ndim == 1
        if obs.shape[-1:] != (n_obs,) or obs.ndim > 2:
            raise ValueError(f"observation: expected shape ({n_obs},) or (n, {n_obs}), got {obs.shape}")
        y = self.spec.to_physical(obs.reshape(-1, n_obs))
        volts, state = self.control(y, self.start_state(y, state, episode_start))
        action = self.spec.to_action(volts, y)
        return (action[0] if single else action), state

    def start_state(
        self,
        y: np.ndarray,
        state: np.ndarray | None,
        episode_start: np.ndarray | Sequence[bool] | None = None,
    ) -> np.ndarray:
        """The state :meth:`control` is called with for physical observations ``y`` (n, ...):
        a copy of ``state``, its rows where an episode starts set to :meth:`initial_state`
        (all of them where ``state`` is None)."""
        n = y.shape[0]
        if state is None:
            return self.initial_state(y)
        state = np.array(state, dtype=np.float64, copy=True)
        if state.shape != (n, self.state_size):
            raise ValueError(f"state: expected shape ({n}, {self.state_size}), got {state.shape}")
        if episode_start is not None:
            start = np.asarray(episode_start, dtype=bool).reshape(-1)
            if start.size == 1 and n > 1:
                start = np.repeat(start, n)
            if start.shape != (n,):
                raise ValueError(f"episode_start: expected {n} flags, got shape {np.shape(episode_start)}")
            if start.any():
                state[start] = self.initial_state(y[start])
        return state

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.describe().items() if k != "name")
        return f"{type(self).__name__}({args})"
