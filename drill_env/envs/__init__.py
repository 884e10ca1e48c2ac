"""Gymnasium environments of the drill-string rig.

Importing this package (``import drill_env`` does) registers them with Gymnasium (as soon as
Gymnasium is imported, before or after):

* ``DrillString-v0``: the rig with the brake on the lower disk (the paper's experiments);
* ``DrillStringNoBrake-v0``: the rig without the brake;
* ``DrillString-v1``, ``DrillStringNoBrake-v1``: the same rigs with observation version 1
  (the v0 entries followed by the encoder angles and the integrated speed error of the
  lower disk; see ``DrillStringEnv``'s "Version History");
* ``DrillString-v2``, ``DrillStringNoBrake-v2``: the v1 rigs whose action is the
  correction added to the episode's nominal (feedforward) voltage, +-2 V
  (``action_mode="correction"``);
* ``DrillString-v3``, ``DrillStringNoBrake-v3``: the v2 rigs whose reward scores speed
  errors in rad/s at every operating point (``tracking_cost="absolute"``): the version to
  train agents on. The from-scratch policies ``ppo`` and ``ppo_no_brake`` of
  ``results/agents/`` are trained on it, ``sac`` and ``sac_no_brake`` on v2 (see
  ``configs/agents/sac.yaml`` for why).

Earlier ids stay registered unchanged, so the policies trained on them (``results/agents/``
and ``results/agents/v0/``) still load and run.

All have a native vector version: ``gymnasium.make_vec(id, num_envs=N)`` returns a
:class:`~drill_env.envs.vector.DrillStringVectorEnv` that steps all rigs in one compiled
call.
"""

from __future__ import annotations

import importlib.util
import sys
from typing import Any

__all__ = ["register_envs", "make_version", "ENV_IDS", "ENV_VERSIONS", "MAX_EPISODE_STEPS"]

# Every registered id -> its rig preset.
ENV_IDS = {
    "DrillString-v0": "brake",
    "DrillStringNoBrake-v0": "no_brake",
    "DrillString-v1": "brake",
    "DrillStringNoBrake-v1": "no_brake",
    "DrillString-v2": "brake",
    "DrillStringNoBrake-v2": "no_brake",
    "DrillString-v3": "brake",
    "DrillStringNoBrake-v3": "no_brake",
}
# Every registered id -> its version: the observation layout is min(version, 1) (v2 and v3
# observe what v1 does); v2 changes the action, v3 the reward's speed scale (see
# DrillStringEnv's "Version History").
ENV_VERSIONS = {env_id: int(env_id.rsplit("-v", 1)[1]) for env_id in ENV_IDS}
MAX_EPISODE_STEPS = 400  # 20 s at the default control period of 0.05 s


def register_envs() -> None:
    """Register the environments with Gymnasium (safe to call more than once)."""
    import gymnasium

    for env_id, preset in ENV_IDS.items():
        if env_id in gymnasium.registry:
            continue
        kwargs: dict[str, Any] = {"params": preset}  # v0: exactly as before v1 existed
        version = ENV_VERSIONS[env_id]
        if version != 0:
            kwargs["observation_version"] = min(version, 1)
        if version >= 2:
            kwargs["action_mode"] = "correction"
        if version >= 3:
            kwargs["tracking_cost"] = "absolute"
        gymnasium.register(
            id=env_id,
            entry_point="drill_env.envs.drill_string:DrillStringEnv",
            vector_entry_point="drill_env.envs.vector:DrillStringVectorEnv",
            max_episode_steps=MAX_EPISODE_STEPS,
            kwargs=kwargs,
        )


def make_version(env_id: str, **kwargs: Any):
    """``gymnasium.make(env_id, **kwargs)`` without Gymnasium's "out of date, consider vN"
    warning: for code that makes the version a policy was trained on, on purpose (a v1
    residual policy's base, the evaluation env of a v1 config)."""
    import warnings

    import gymnasium

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*is out of date", category=DeprecationWarning)
        return gymnasium.make(env_id, **kwargs)


def __getattr__(name: str):
    # Lazy access to the classes: importing drill_env must stay light.
    if name == "DrillStringEnv":
        from drill_env.envs.drill_string import DrillStringEnv

        return DrillStringEnv
    if name == "DrillStringVectorEnv":
        from drill_env.envs.vector import DrillStringVectorEnv

        return DrillStringVectorEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _AfterGymnasiumImport:
    """A one-shot import hook (a :data:`sys.meta_path` finder): the first import of Gymnasium
    is done by the other finders as usual, and :func:`register_envs` runs right after
    Gymnasium's own ``__init__`` has finished."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname != "gymnasium":
            return None
        sys.meta_path.remove(self)  # once: the real spec comes from the finders after this one
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        loader = spec.loader
        run = loader.exec_module

        def exec_module(module: Any) -> None:
            run(module)
            register_envs()

        loader.exec_module = exec_module  # type: ignore[method-assign]  # this module object only
        return spec


def _register_on_import() -> None:
    """Register the environments with Gymnasium now if it is imported, else right after its
    import: ``import drill_env`` and the command line's ``--help`` then load neither Gymnasium
    nor NumPy, and ``gymnasium.make("DrillString-v3")`` works after ``import drill_env`` in
    either order."""
    if "gymnasium" in sys.modules:
        register_envs()
    elif not any(isinstance(f, _AfterGymnasiumImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterGymnasiumImport())


_register_on_import()
