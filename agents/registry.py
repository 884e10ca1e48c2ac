"""The benchmark's controllers by name: classical ones with their tuned gains, learned ones
from their committed policies.

* ``open_loop``, ``pi_upper``, ``pi_lower``, ``torque_feedback``, ``lqi``: built on an
  environment's :class:`~agents.base.ControllerSpec` with the gains that
  ``drill-env tune`` wrote to ``configs/agents/controllers.yaml`` for the preset;
* ``lqi_angle_ff``: that LQI plus adaptive feedforward on harmonics of the lower disk's
  measured angle (:mod:`agents.angle_feedforward`), for friction locked to the bit's angle;
* ``ppo``, ``sac``: the policies trained by ``drill-env train`` and kept under
  ``results/agents/<algo>/policy.zip`` (trained on ``DrillString-v1``, the braked rig)
  and ``results/agents/<algo>_no_brake/policy.zip`` (on ``DrillStringNoBrake-v1``); a
  missing one is an error, never the other rig's policy run in its place. Each runs
  on the observation version it was trained on (:func:`observation_version`), so the
  version-0 policies of ``results/agents/v0/`` are evaluated with ``agents_dir`` pointing
  there;
* ``ppo_robust``: PPO trained with domain randomisation over the standard plant family, kept
  beside the nominal ones as ``results/agents/ppo_robust[_<preset>]/policy.zip``; the
  committed ones are residual policies on ``lqi_angle_ff`` (``configs/agents/ppo_residual*.yaml``,
  :mod:`agents.residual`; a policy's ``config.yaml`` says which it is).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from agents.base import ControllerSpec
from agents.gains import CLASSICAL, classical_controller, gains_path, load_gains

__all__ = [
    "CLASSICAL",
    "LEARNED",
    "CONTROLLERS",
    "build_controller",
    "classical_controller",
    "default_agents_dir",
    "gains_path",
    "load_gains",
    "observation_version",
    "policy_path",
]

LEARNED = ("ppo", "sac", "ppo_robust")
# the algorithm of each learned controller
_ALGO = {"ppo": "ppo", "sac": "sac", "ppo_robust": "ppo"}
# the training config (configs/agents/<name>[_<preset>].yaml) of each
_CONFIG = {"ppo": "ppo", "sac": "sac", "ppo_robust": "ppo_residual"}
CONTROLLERS = CLASSICAL + LEARNED

_ROOT = Path(__file__).resolve().parent.parent


def default_agents_dir() -> Path:
    return _ROOT / "results" / "agents"


def policy_path(algo: str, preset: str, agents_dir: str | Path | None = None) -> Path:
    """The trained policy of ``algo`` for ``preset``: ``<agents_dir>/<algo>/policy.zip`` for
    the braked rig, ``<agents_dir>/<algo>_<preset>/policy.zip`` for any other preset. A
    missing policy is an error naming that file, never a policy trained on another rig."""
    if algo not in LEARNED:
        raise ValueError(f"controller: {algo!r} is not one of {list(LEARNED)}")
    root = Path(agents_dir) if agents_dir is not None else default_agents_dir()
    name = algo if preset == "brake" else f"{algo}_{preset}"
    config = _CONFIG[algo] if preset == "brake" else f"{_CONFIG[algo]}_{preset}"
    path = root / name / "policy.zip"
    if not path.is_file():
        raise ValueError(
            f"policy: no trained {algo} policy for preset {preset!r} at {path}; train one with "
            f"`drill-env train --algo {_ALGO[algo]} --config configs/agents/{config}.yaml --out {root / name}` "
            "or pass --agents-dir"
        )
    return path


def build_controller(
    name: str,
    env: Any,
    preset: str,
    *,
    agents_dir: str | Path | None = None,
    gains_file: str | Path | None = None,
):
    """Any benchmark controller by name for environment ``env`` of ``preset``."""
    if name in CLASSICAL:
        return classical_controller(name, ControllerSpec.from_env(env), preset, gains_file)
    if name in LEARNED:
        from agents.rl import load_policy

        policy = load_policy(policy_path(name, preset, agents_dir), algo=_ALGO[name], name=name)
        policy.check_env(env)
        return policy
    raise ValueError(f"controller: {name!r} is not one of {list(CONTROLLERS)}")


def observation_version(name: str, preset: str, agents_dir: str | Path | None = None) -> int:
    """The observation version of the environment controller ``name`` runs on: the latest
    for the classical controllers (they read the version-0 entries, which every version
    starts with, and every version runs the same episode for the same seed), and for a
    learned policy the version it was trained on, from its observation space."""
    if name in CLASSICAL:
        from drill_env.envs.config import OBSERVATION_VERSIONS

        return max(OBSERVATION_VERSIONS)
    if name not in LEARNED:
        raise ValueError(f"controller: {name!r} is not one of {list(CONTROLLERS)}")
    from agents.rl import policy_observation_version

    return policy_observation_version(policy_path(name, preset, agents_dir))
