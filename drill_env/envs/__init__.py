"""Gymnasium environments of the drill-string rig.

Importing this package (``import drill_env`` does) registers them:

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


register_envs()
