"""What a trained policy is, read from its folder: how it started, the config it was trained
with, how long it trained and what it reached.

:func:`describe_policy` reads a policy folder written by :func:`drill_env.agents.learning.rl.train`
(``config.yaml`` and ``training_summary.json`` beside ``policy.zip``) and names how the policy
started (:func:`policy_start`):

* ``from scratch``: a randomly initialised network;
* ``clone of <controller>``: the network first fitted to a classical controller's actions
  (``warm_start.controller``, :mod:`drill_env.agents.learning.warm_start`), then trained;
* ``residual on <controller>``: the applied voltage is the classical controller's plus a
  bounded learned correction (``residual``, :mod:`drill_env.agents.learning.residual`);
* ``residual on <controller>, distilled from <policy>``: such a correction first fitted so that
  the residual policy acts as a trained policy plus the base's feedforward
  (``warm_start.policy``), then trained.

``train`` writes the card ``policy.md`` beside every policy it trains (:func:`write_policy_card`);
``drill-env policy-cards DIR`` writes the cards of every policy folder under ``DIR`` and
``DIR/README.md``, a table of them (:func:`write_policy_cards`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from drill_env.agents._locations import PACKAGE_DIR, ROOT, shown_path
from drill_env.yamlio import load_yaml

__all__ = [
    "PolicyDescription",
    "describe_policy",
    "policy_card",
    "policy_start",
    "policies_table",
    "write_policy_card",
    "write_policy_cards",
]

CARD = "policy.md"
# the folders whose configs are the shipped training configs: the source tree's, the installed copy
_CONFIG_DIRS = (ROOT / "configs" / "agents", PACKAGE_DIR / "_configs" / "agents")
_RIGS = {"brake": "the rig with the brake", "no_brake": "the rig without the brake"}


@dataclass(frozen=True)
class PolicyDescription:
    """One trained policy folder, as :func:`describe_policy` reads it."""

    folder: str  # as shown: relative to the project root, or as given
    name: str  # the folder's name (the benchmark's name for the policy and rig)
    algo: str
    env_id: str
    rig: str  # brake or no_brake
    start: str  # see policy_start
    start_details: str  # a sentence on how it started
    config: str | None  # the config file it was trained with (None: not among the shipped ones)
    seed: int
    total_timesteps: int
    wall_time_s: float
    n_envs: int
    randomised: bool  # trained with domain randomisation
    ignored_observations: tuple[str, ...]
    best_eval_return: float
    best_at_timesteps: int
    final_eval_return: float
    converged: bool
    convergence_reason: str
    reference_returns: Mapping[str, float] = field(default_factory=dict)
    residual: bool = False
    versions: Mapping[str, str] = field(default_factory=dict)


_ALGO_NAMES = {"ppo": "PPO", "sac": "SAC", "td3": "TD3", "tqc": "TQC", "crossq": "CrossQ"}


def algo_name(algo: str) -> str:
    """How the algorithm is written in prose (``crossq`` -> ``CrossQ``)."""
    return _ALGO_NAMES.get(algo, algo.upper())


def policy_start(config: Mapping[str, Any]) -> str:
    """How a policy trained with ``config`` (a training config as a mapping) started: ``from
    scratch``, ``clone of X``, ``residual on X`` or ``residual on X, distilled from Y``."""
    residual = config.get("residual")
    warm = config.get("warm_start") or {}
    if residual:
        start = f"residual on {residual.get('base', 'lqi')}"
        return f"{start}, distilled from {warm['policy']}" if warm.get("policy") else start
    if warm:
        return f"clone of {warm.get('controller') or 'lqi'}"
    return "from scratch"


def _start_details(config: Mapping[str, Any], rig: str) -> str:
    residual = config.get("residual")
    warm = config.get("warm_start") or {}
    algo = algo_name(str(config.get("algo", "")))
    if warm:
        rounds = warm.get("rounds", 1)
        how = (
            f"{rounds} round{'s' if rounds != 1 else ''} of {warm.get('steps', 100_000):,} env-steps".replace(
                ",", " "
            )
        )
    if residual:
        scale = float(residual.get("scale", 0.2))
        text = (
            f"The applied voltage is `{residual.get('base', 'lqi')}`'s plus a learned correction of at most "
            f"{scale:g} x 5 V = {scale * 5:g} V either way (`agents/learning/residual.py`)."
        )
        if residual.get("zero_start"):
            text += " The correction started at exactly zero: the untrained policy was its base."
        if residual.get("critic_burn_in"):
            text += f" For the first {residual['critic_burn_in']} env-steps only the critics learned."
        if residual.get("base_options"):
            opts = ", ".join(
                f"{k}: {yaml.safe_dump(v).splitlines()[0]}" for k, v in residual["base_options"].items()
            )
            text += f" The base runs with its options {opts}."
        if warm.get("policy"):
            text += (
                f" Before {algo} trained it, the correction was fitted so that the residual policy acts as "
                f"the trained policy `{warm['policy']}` of {_RIGS.get(rig, rig)} plus the base's feedforward "
                f"(distillation, {how}, `agents/learning/warm_start.py`)."
            )
        return text
    if warm:
        return (
            f"The network was first fitted to the actions of the classical controller "
            f"`{warm.get('controller') or 'lqi'}` (behaviour cloning, {how}, `agents/learning/warm_start.py`), "
            f"then trained by {algo}."
        )
    return f"Trained by {algo} from a randomly initialised network."


def _matches(recorded: Mapping[str, Any], candidate: Mapping[str, Any]) -> bool:
    # every entry the policy's config records is the candidate's (a config written before a
    # key existed records less)
    return all(candidate.get(k) == v for k, v in recorded.items())


def _shipped_config(folder: Path, recorded: Mapping[str, Any]) -> Path | None:
    """The shipped training config equal to the one the policy in ``folder`` was trained with:
    ``configs/agents/<name>.yaml`` for ``results/agents/<name>/`` first, then any other."""
    from drill_env.agents.learning.rl import load_config

    candidates: list[Path] = []
    try:
        relative = folder.resolve().relative_to((ROOT / "results" / "agents").resolve())
        candidates += [d / f"{relative.as_posix()}.yaml" for d in _CONFIG_DIRS]
    except ValueError:
        pass
    for d in _CONFIG_DIRS:
        candidates += sorted(p for p in d.glob("**/*.yaml") if p.parent.name != "rl_zoo3")
    for path in candidates:
        if not path.is_file() or path.name == "controllers.yaml":
            continue
        try:
            if _matches(recorded, load_config(path).to_dict()):
                return path
        except ValueError:
            continue
    return None


def describe_policy(folder: str | Path, config_path: str | Path | None = None) -> PolicyDescription:
    """Describe the trained policy in ``folder`` from its ``config.yaml`` and
    ``training_summary.json``. ``config_path``: the config file it was trained with (default:
    the shipped config equal to its ``config.yaml``, if any)."""
    import json

    from drill_env.envs import ENV_IDS

    folder = Path(folder)
    config_file, summary_file = folder / "config.yaml", folder / "training_summary.json"
    for path in (config_file, summary_file):
        if not path.is_file():
            raise ValueError(f"policy folder: {folder} has no {path.name} (written by drill-env train)")
    config = load_yaml(config_file, what="policy config (written by drill-env train)") or {}
    summary = json.loads(summary_file.read_text())
    if not isinstance(config, Mapping) or "algo" not in config or "env_id" not in config:
        raise ValueError(f"policy folder: {config_file} is not a training config (no algo or env_id)")
    env_id = str(config["env_id"])
    rig = ENV_IDS.get(env_id, "unknown")
    source = Path(config_path) if config_path is not None else _shipped_config(folder, config)
    return PolicyDescription(
        folder=shown_path(folder),
        name=folder.name,
        algo=str(config["algo"]),
        env_id=env_id,
        rig=rig,
        start=policy_start(config),
        start_details=_start_details(config, rig),
        config=shown_path(source) if source is not None else None,
        seed=int(summary["seed"]),
        total_timesteps=int(summary["total_timesteps"]),
        wall_time_s=float(summary["wall_time_s"]),
        n_envs=int(config.get("n_envs", 1)),
        randomised=bool((config.get("env_kwargs") or {}).get("domain_randomization")),
        ignored_observations=tuple(config.get("ignored_observations") or ()),
        best_eval_return=float(summary["best_eval_return"]),
        best_at_timesteps=int(summary["best_at_timesteps"]),
        final_eval_return=float(summary["final_eval_return"]),
        converged=bool(summary["converged"]),
        convergence_reason=str((summary.get("convergence") or {}).get("reason", "")),
        reference_returns=dict(summary.get("reference_returns") or {}),
        residual=bool(config.get("residual")),
        versions=dict(summary.get("versions") or {}),
    )


def _steps(n: int) -> str:
    return f"{n:,}".replace(",", " ")


def policy_card(d: PolicyDescription) -> str:
    """The markdown of ``policy.md`` for policy ``d``."""
    algo = algo_name(d.algo)
    config = f"`{d.config}`" if d.config else "none of the shipped configs (its `config.yaml` is the record)"
    refs = ", ".join(f"{k.replace('_', ' ')} {v:.1f}" for k, v in d.reference_returns.items())
    plants = (
        "domain randomisation around the nominal model (`env_kwargs.domain_randomization`)"
        if d.randomised
        else "the nominal model"
    )
    sb3 = d.versions.get("stable_baselines3")
    lines = [
        f"# `{d.name}`: {algo}, {d.start}",
        "",
        "<!-- Written by `drill-env policy-cards` (or `drill-env train`) from config.yaml and",
        "training_summary.json beside it; regenerate, do not edit. -->",
        "",
        "| | |",
        "|---|---|",
        f"| algorithm | {algo}" + (f" (stable-baselines3 {sb3})" if sb3 else "") + " |",
        f"| environment | `{d.env_id}` ({_RIGS.get(d.rig, d.rig)}) |",
        f"| start | {d.start} |",
        f"| training config | {config} |",
        f"| training | seed {d.seed}, {_steps(d.total_timesteps)} env-steps on {d.n_envs} rig{'s' if d.n_envs != 1 else ''}, "
        f"{d.wall_time_s:.0f} s wall time |",
        f"| training plants | {plants} |",
    ]
    if d.ignored_observations:
        lines.append(f"| inputs ignored | {', '.join(f'`{o}`' for o in d.ignored_observations)} |")
    lines += [
        f"| best evaluation return | {d.best_eval_return:.1f} at {_steps(d.best_at_timesteps)} env-steps "
        f"(the kept `policy.zip`; final {d.final_eval_return:.1f})"
        + (f"; on the same episodes {refs}" if refs else "")
        + " |",
        f"| converged | {'yes' if d.converged else 'no'}"
        + (f" ({d.convergence_reason})" if d.convergence_reason else "")
        + " |",
        "",
        d.start_details,
        "",
        "Load it as a controller (`predict(observation)`, the benchmark's evaluation path):",
        "",
        "```python",
        "from drill_env.agents.learning.rl import load_policy",
        "",
        f'policy = load_policy("{d.folder}/policy.zip")',
        "```",
        "",
    ]
    if d.residual:
        lines += [
            f"`policy.zip` holds only the learned correction: stable-baselines3's `{algo}.load` of it alone "
            "raises `CorrectionOnlyError` instead of giving a policy that acts without its base.",
            "",
        ]
    if d.config:
        lines += [
            "Train it again:",
            "",
            "```bash",
            f"drill-env train --algo {d.algo} --config {d.config} --seed {d.seed} --out {d.folder}",
            "```",
            "",
        ]
    return "\n".join(lines)


def write_policy_card(folder: str | Path, config_path: str | Path | None = None) -> Path:
    """Write ``policy.md`` beside the policy in ``folder`` (see :func:`policy_card`)."""
    from drill_env.outputs import atomic_write_text

    path = Path(folder) / CARD
    atomic_write_text(path, policy_card(describe_policy(folder, config_path)))
    return path


def policy_folders(agents_dir: str | Path) -> list[Path]:
    """Every policy folder under ``agents_dir`` (``policy.zip`` with ``config.yaml`` and
    ``training_summary.json``), the top level first."""
    root = Path(agents_dir)
    found = [
        p.parent
        for p in root.glob("**/policy.zip")
        if (p.parent / "config.yaml").is_file() and (p.parent / "training_summary.json").is_file()
    ]
    return sorted(found, key=lambda f: (len(f.relative_to(root).parts), f.relative_to(root).as_posix()))


def policies_table(descriptions: Sequence[PolicyDescription], agents_dir: str | Path) -> str:
    """The markdown of ``README.md`` in ``agents_dir``: one row per policy."""
    root = Path(agents_dir)
    lines = [
        "# Trained policies",
        "",
        "<!-- Written by `drill-env policy-cards` from each folder's config.yaml and",
        "training_summary.json; regenerate, do not edit. -->",
        "",
        "One folder per policy, each with its card `policy.md` (how it started, its training config, how",
        "long it trained, what it reached). *Start*: `from scratch`; `clone of X`: the network first fitted",
        "to classical controller X's actions; `residual on X`: X's voltage plus a bounded learned correction;",
        "`distilled from Y`: that correction first fitted to act as trained policy Y. Evaluation returns",
        "compare within one environment version: from v3 the reward scores the speed error in rad/s.",
        "",
        "| policy | algorithm | environment | start | training config | env-steps | best evaluation return | converged |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for d in descriptions:
        name = _relative_name(d, root)
        lines.append(
            f"| [`{name}`]({name}/{CARD}) | {algo_name(d.algo)} | `{d.env_id}` | {d.start} | "
            + (f"`{d.config}`" if d.config else "-")
            + f" | {_steps(d.total_timesteps)} | {d.best_eval_return:.1f} | {'yes' if d.converged else 'no'} |"
        )
    return "\n".join(lines) + "\n"


def _relative_name(d: PolicyDescription, root: Path) -> str:
    root_shown = shown_path(root)
    return d.folder[len(root_shown) + 1 :] if d.folder.startswith(root_shown + "/") else d.name


def write_policy_cards(agents_dir: str | Path) -> list[Path]:
    """Write ``policy.md`` in every policy folder under ``agents_dir`` and ``README.md`` (the
    table of them) in ``agents_dir``; returns the files written."""
    from drill_env.outputs import atomic_write_text, check_tree_files

    folders = policy_folders(agents_dir)
    if not folders:
        raise ValueError(
            f"agents_dir: no policy folder (policy.zip, config.yaml, training_summary.json) under {agents_dir}"
        )
    readme = Path(agents_dir) / "README.md"
    # every file it will write, before the first: inside agents_dir, never through a link
    check_tree_files(
        agents_dir, [*(f / CARD for f in folders), readme], "policy-cards", "AGENTS_DIR", accepts=("train",)
    )
    descriptions = [describe_policy(f) for f in folders]
    written = []
    for folder, d in zip(folders, descriptions, strict=True):
        path = folder / CARD
        atomic_write_text(path, policy_card(d))
        written.append(path)
    atomic_write_text(readme, policies_table(descriptions, agents_dir))
    return [*written, readme]
