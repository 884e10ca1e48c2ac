"""The benchmark's controllers by name: classical ones with their tuned gains, learned ones
from their committed policies.

* ``open_loop``, ``pi_upper``, ``pi_lower``, ``torque_feedback``, ``lqi``: built on an
  environment's :class:`~drill_env.agents.controllers.base.ControllerSpec` with the gains that
  ``drill-env tune`` wrote to ``configs/agents/controllers.yaml`` for the preset;
* ``soft_torque``, ``z_torque``: the industry's stick-slip controllers, designed on the
  design model by their published rules with nothing tuned
  (:mod:`drill_env.agents.controllers.soft_torque`, :mod:`drill_env.agents.controllers.z_torque`);
* ``lqi_angle_ff``: that LQI plus adaptive feedforward on harmonics of the lower disk's
  measured angle (:mod:`drill_env.agents.controllers.angle_feedforward`), for friction locked to the bit's angle;
* ``ppo``, ``sac``: the policies trained by ``drill-env train`` and kept under
  ``results/agents/<algo>/policy.zip`` (trained on the braked rig) and
  ``results/agents/<algo>_no_brake/policy.zip`` (on the rig without the brake), each by its
  recipe ``configs/agents/<name>.yaml``; a missing one is an error, never the other rig's
  policy run in its place. Each runs on the observation version it was trained on
  (:func:`observation_version`), so the version-0 policies of ``results/agents/v0/`` are
  evaluated with ``agents_dir`` pointing there;
* ``ppo_lqi_clone``: PPO started as a behaviour clone of the tuned LQI
  (:mod:`drill_env.agents.learning.warm_start`) and fine-tuned on ``DrillString-v1`` /
  ``DrillStringNoBrake-v1``, kept as ``results/agents/ppo_lqi_clone[_<preset>]/policy.zip``
  (``configs/agents/ppo_lqi_clone.yaml``, ``ppo_lqi_clone_no_brake.yaml``);
* ``ppo_robust``: PPO trained with domain randomisation over the standard plant family, kept
  beside the nominal ones as ``results/agents/ppo_robust[_<preset>]/policy.zip``; the
  committed ones are residual policies on ``lqi_angle_ff`` (:mod:`drill_env.agents.learning.residual`;
  a policy's ``config.yaml`` says which it is): with the brake trained from the base
  (``configs/agents/ppo_robust.yaml``), without it started as ``ppo_lqi_clone`` plus the
  base's angle-locked feedforward (``configs/agents/ppo_robust_no_brake.yaml``,
  :mod:`drill_env.agents.learning.warm_start`);
* ``sac_robust``: SAC trained with the same randomisation, kept as
  ``results/agents/sac_robust[_<preset>]/policy.zip``: residual policies on ``lqi_angle_ff``
  that start as their base (zero start, the critics trained before the actor moves;
  ``configs/agents/sac_robust.yaml``, ``sac_robust_no_brake.yaml``).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from drill_env.agents._locations import PACKAGE_DIR, ROOT

if TYPE_CHECKING:  # re-exported on first use (__getattr__ below)
    from drill_env.agents.controllers.gains import classical_controller, gains_path, load_gains

__all__ = [
    "CLASSICAL",
    "LEARNED",
    "AGENTS_DIR_ENV",
    "CONTROLLERS",
    "STYLES",
    "ControllerStyle",
    "PACKAGED_AGENTS_DIR",
    "agents_dir_source",
    "build_controller",
    "classical_controller",
    "controller_style",
    "default_agents_dir",
    "gains_path",
    "load_gains",
    "observation_version",
    "policy_path",
    "teacher_policy",
    "training_config",
]


def __getattr__(name: str):
    # the gains' readers, re-exported here, import the controllers' design (SciPy): only on use,
    # so that the lists below (the command line's help) cost nothing
    if name in ("classical_controller", "gains_path", "load_gains"):
        from drill_env.agents.controllers import gains

        return getattr(gains, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# The one list of the benchmark's controllers, in the order of its tables and legends: the
# figures, the command-line help and the checks of a controller name all derive from these.
CLASSICAL = (
    "open_loop",
    "pi_upper",
    "pi_lower",
    "torque_feedback",
    "soft_torque",
    "z_torque",
    "lqi",
    "lqi_angle_ff",
)
LEARNED = ("ppo", "sac", "ppo_lqi_clone", "ppo_robust", "sac_robust")
# the algorithm of each learned controller
_ALGO = {"ppo": "ppo", "sac": "sac", "ppo_lqi_clone": "ppo", "ppo_robust": "ppo", "sac_robust": "sac"}
CONTROLLERS = CLASSICAL + LEARNED


class ControllerStyle(NamedTuple):
    """How a controller is drawn in every figure (matplotlib colour and marker)."""

    colour: str
    marker: str


STYLES = {
    "open_loop": ControllerStyle("black", "o"),
    "pi_upper": ControllerStyle("tab:red", "v"),
    "pi_lower": ControllerStyle("tab:orange", "^"),
    "torque_feedback": ControllerStyle("tab:green", "s"),
    "lqi": ControllerStyle("tab:blue", "D"),
    "lqi_angle_ff": ControllerStyle("tab:cyan", "d"),
    "ppo": ControllerStyle("tab:purple", "P"),
    "sac": ControllerStyle("tab:brown", "X"),
    "ppo_lqi_clone": ControllerStyle("darkgoldenrod", "H"),
    "soft_torque": ControllerStyle("limegreen", "+"),
    "z_torque": ControllerStyle("indigo", "x"),
}
# Styles of controllers added without one of their own, in the order of CONTROLLERS: none of
# these colours or markers is in STYLES, so a new controller is told apart from every other.
_SPARE_COLOURS = ("tab:pink", "tab:olive", "tab:gray", "gold", "navy", "teal")
_SPARE_MARKERS = ("*", "h", "p", "<", ">", "8")


def controller_style(name: str) -> ControllerStyle:
    """The colour and marker of controller ``name`` in the figures: its entry in
    :data:`STYLES`, else a spare style by its place among the unstyled :data:`CONTROLLERS`
    (and grey dots for a name the registry does not know, e.g. from an old results file)."""
    if name in STYLES:
        return STYLES[name]
    unstyled = [c for c in CONTROLLERS if c not in STYLES]
    if name not in unstyled:
        return ControllerStyle("gray", "o")
    i = unstyled.index(name)
    return ControllerStyle(_SPARE_COLOURS[i % len(_SPARE_COLOURS)], _SPARE_MARKERS[i % len(_SPARE_MARKERS)])


_ROOT = ROOT
# the variable naming the folder of trained policies when --agents-dir is not given
AGENTS_DIR_ENV = "DRILL_ENV_AGENTS_DIR"
# the committed policies as the wheel installs them (pyproject.toml, force-include)
PACKAGED_AGENTS_DIR = PACKAGE_DIR / "_results" / "agents"


def _checkout_agents_dir() -> Path | None:
    """``results/agents/`` of the source tree this package runs from, or None when it runs
    from an installed wheel (no ``pyproject.toml`` beside the packages)."""
    path = _ROOT / "results" / "agents"
    return path if (_ROOT / "pyproject.toml").is_file() and path.is_dir() else None


def agents_dir_source(agents_dir: str | Path | None = None) -> tuple[Path, str]:
    """The folder of trained policies and where it came from, first found of: ``agents_dir``
    (``--agents-dir``), the environment variable ``DRILL_ENV_AGENTS_DIR`` (if set and not
    empty), ``results/agents/`` of the source tree when running from a checkout, the copy of
    the committed policies installed with the package."""
    if agents_dir is not None:
        return Path(agents_dir), "--agents-dir"
    env = os.environ.get(AGENTS_DIR_ENV, "")
    if env:
        return Path(env), AGENTS_DIR_ENV
    checkout = _checkout_agents_dir()
    if checkout is not None:
        return checkout, "source tree"
    return PACKAGED_AGENTS_DIR, "installed package"


def default_agents_dir() -> Path:
    """Where the trained policies are found without ``--agents-dir``: see
    :func:`agents_dir_source`."""
    return agents_dir_source()[0]


def training_config(algo: str, preset: str) -> str:
    """The name of the shipped training config of the committed policy of learned controller
    ``algo`` for ``preset``: the policy's own folder name (``configs/agents/<name>.yaml`` is
    the recipe of ``results/agents/<name>/``)."""
    if algo not in LEARNED:
        raise ValueError(f"controller: {algo!r} is not one of {list(LEARNED)}")
    return algo if preset == "brake" else f"{algo}_{preset}"


def policy_path(algo: str, preset: str, agents_dir: str | Path | None = None) -> Path:
    """The trained policy of ``algo`` for ``preset``: ``<agents_dir>/<algo>/policy.zip`` for
    the braked rig, ``<agents_dir>/<algo>_<preset>/policy.zip`` for any other preset
    (``agents_dir`` as :func:`agents_dir_source` finds it). A missing policy is an error
    naming that file, never a policy trained on another rig."""
    base_config = training_config(algo, preset)  # checks the name
    root, source = agents_dir_source(agents_dir)
    name = algo if preset == "brake" else f"{algo}_{preset}"
    path = root / name / "policy.zip"
    if not path.is_file():
        # The config's name works from any folder (train resolves it against the packaged
        # configs); without a folder of the user's own, train writes a fresh run folder.
        config = (
            f"{root.name}/{base_config}"
            if root.name.startswith("v") and root.name[1:].isdigit()
            else base_config
        )
        if source in ("--agents-dir", AGENTS_DIR_ENV):
            how = f"`drill-env train --algo {_ALGO[algo]} --config {config} --out {root / name}`"
        else:
            how = (
                f"`drill-env train --algo {_ALGO[algo]} --config {config}` and pass the folder it prints "
                f"with --agents-dir or {AGENTS_DIR_ENV}"
            )
        raise ValueError(
            f"policy: no trained {algo} policy for preset {preset!r} at {path} "
            f"(agents folder from {source}); train one with {how}"
        )
    return path


def build_controller(
    name: str,
    env: Any,
    preset: str,
    *,
    agents_dir: str | Path | None = None,
    gains_file: str | Path | None = None,
    trusted: bool = False,
):
    """Any benchmark controller by name for environment ``env`` of ``preset``. A learned
    controller's policy from outside ``results/agents/`` needs ``trusted`` (see
    :func:`drill_env.agents.learning.rl.load_policy`)."""
    if name in CLASSICAL:
        from drill_env.agents.controllers.base import ControllerSpec
        from drill_env.agents.controllers.gains import classical_controller

        return classical_controller(name, ControllerSpec.from_env(env), preset, gains_file)
    if name in LEARNED:
        from drill_env.agents.learning.policy_info import policy_training_record
        from drill_env.agents.learning.rl import load_policy
        from drill_env.envs import ENV_IDS

        path = policy_path(name, preset, agents_dir)
        trained_on = policy_training_record(path)[0]["env_id"]
        if ENV_IDS.get(trained_on) != preset:
            raise ValueError(
                f"policy: {path} was trained on {trained_on} (preset {ENV_IDS.get(trained_on)!r}), "
                f"not on preset {preset!r}"
            )
        policy = load_policy(path, algo=_ALGO[name], name=name, trusted=trusted)
        policy.check_env(env)
        _rebase(policy, env, preset)
        return policy
    raise ValueError(f"controller: {name!r} is not one of {list(CONTROLLERS)}")


def _rebase(policy: Any, env: Any, preset: str) -> None:
    """A residual policy's classical base designed on ``env``'s design model where that is not
    the preset's own (``benchmark --design-params``): the base is a design like the classical
    controllers, the trained correction stays as it was trained."""
    import dataclasses

    import numpy as np

    from drill_env.params import load_params

    base = getattr(policy, "base", None)
    if base is None or not hasattr(base, "redesigned"):
        return
    from drill_env.agents.controllers.base import ControllerSpec

    design = ControllerSpec.from_env(env)
    own = load_params(preset)
    if not design.effects.active and np.array_equal(design.params.as_array(), own.as_array()):
        return
    policy.base = base.redesigned(
        dataclasses.replace(base.spec, params=design.params, effects=design.effects)
    )


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
    from drill_env.agents.learning.rl import policy_observation_version

    return policy_observation_version(policy_path(name, preset, agents_dir))


def teacher_policy(name: str, env_id: str, env_kwargs: Mapping[str, Any], *, trusted: bool = False) -> Any:
    """The trained policy ``name`` of a distillation (``warm_start.policy``, one of
    :data:`drill_env.agents.learning.warm_start.WARM_START_POLICIES`) as the benchmark loads it for the
    preset of ``env_id`` from the default agents folder (:func:`build_controller`: a missing
    file is an error naming it), checked against the spaces of the training environment."""

    from drill_env.agents.learning.warm_start import WARM_START_POLICIES
    from drill_env.envs import ENV_IDS

    if name not in WARM_START_POLICIES:
        raise ValueError(f"warm_start.policy: {name!r} is not one of {list(WARM_START_POLICIES)}")
    from drill_env.envs import make_version

    env = make_version(env_id, **env_kwargs)
    try:
        return build_controller(name, env, ENV_IDS[env_id], trusted=trusted)
    finally:
        env.close()
