"""What a trained policy file says it was trained on.

``drill-env train`` writes a member ``drill_env.json`` into every stable-baselines3 zip it
saves (stable-baselines3's ``load`` reads only ``data``, ``*.pth`` and ``_stable_baselines3_version``
and leaves any other member alone)::

    {"format": 1,
     "algo": "ppo",
     "env_id": "DrillString-v3",             # the training environment
     "env_kwargs": {...},                    # its DrillStringEnv arguments
     "observation_version": 3,               # the N of the env id: what the policy observes
                                             # and how its action becomes a voltage
     "observation_names": [...],             # the entries of its input, in order
     "drill_env_version": "0.1.0",           # the package that trained it (null: unknown)
     "training_config": {...}}               # the whole training config (residual base, ...)

:func:`policy_training_record` is what every reader of a policy (``load_policy``, the
benchmark's and sim-to-real's observation version) goes through: the member, or for a file
saved before it existed the ``config.yaml`` beside it; a file with neither is refused with one
line naming what is missing, never guessed. Nothing here unpickles anything.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = [
    "POLICY_INFO_MEMBER",
    "POLICY_INFO_FORMAT",
    "REQUIRED_FIELDS",
    "policy_info",
    "read_policy_info",
    "policy_training_record",
    "rewrite_policy_zip",
]

POLICY_INFO_MEMBER = "drill_env.json"
POLICY_INFO_FORMAT = 1
# what a reader needs: the policy is refused when one is missing
REQUIRED_FIELDS = ("algo", "env_id", "env_kwargs", "observation_version", "training_config")
# a fixed time stamp: the same policy and record give the same bytes
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "item") and callable(value.item):  # numpy scalars
        return value.item()
    return value


def policy_info(training_config: Mapping[str, Any], *, drill_env_version: str | None) -> dict[str, Any]:
    """The record of a policy trained with ``training_config`` (a training config as a
    mapping, :meth:`drill_env.agents.learning.rl.TrainConfig.to_dict`) by drill-env
    ``drill_env_version`` (None: not known, a file converted from its ``config.yaml``)."""
    from drill_env.envs import ENV_IDS, ENV_VERSIONS

    cfg = dict(training_config)
    env_id = cfg.get("env_id")
    if env_id not in ENV_IDS:
        raise ValueError(f"env_id: {env_id!r} is not one of {sorted(ENV_IDS)}")
    from drill_env.envs.config import OBSERVATION_NAMES, OBSERVATION_NAMES_V1

    names = list(OBSERVATION_NAMES_V1 if ENV_VERSIONS[env_id] >= 1 else OBSERVATION_NAMES)
    residual = cfg.get("residual")
    if isinstance(residual, Mapping) and residual.get("observe_base") is True:
        from drill_env.agents.learning.residual import BASE_OBSERVATIONS

        names += list(BASE_OBSERVATIONS)
    return _jsonable(
        {
            "format": POLICY_INFO_FORMAT,
            "algo": cfg.get("algo"),
            "env_id": env_id,
            "env_kwargs": dict(cfg.get("env_kwargs") or {}),
            "observation_version": ENV_VERSIONS[env_id],
            "observation_names": names,
            "drill_env_version": drill_env_version,
            "training_config": cfg,
        }
    )


def read_policy_info(path: str | Path) -> dict[str, Any] | None:
    """The record inside the policy zip ``path``, or None when it carries none (or is no
    zip); a record that is not JSON or lacks a field of :data:`REQUIRED_FIELDS` is a
    ValueError naming it."""
    try:
        with zipfile.ZipFile(path) as zf:
            if POLICY_INFO_MEMBER not in zf.namelist():
                return None
            raw = zf.read(POLICY_INFO_MEMBER)
    except (OSError, zipfile.BadZipFile):
        return None
    try:
        info = json.loads(raw)
    except ValueError:
        raise ValueError(f"policy: {path}: its {POLICY_INFO_MEMBER} is not JSON") from None
    if not isinstance(info, dict):
        raise ValueError(f"policy: {path}: its {POLICY_INFO_MEMBER} is not a JSON object")
    missing = [k for k in REQUIRED_FIELDS if k not in info]
    if missing:
        raise ValueError(f"policy: {path}: its {POLICY_INFO_MEMBER} lacks {', '.join(missing)}")
    if info.get("format") != POLICY_INFO_FORMAT:
        raise ValueError(
            f"policy: {path}: its {POLICY_INFO_MEMBER} has format {info.get('format')!r}; "
            f"this drill-env reads format {POLICY_INFO_FORMAT}"
        )
    return info


def policy_training_record(path: str | Path) -> tuple[dict[str, Any], str]:
    """What the policy in ``path`` was trained on and where that was read: the record inside
    the zip (``"zip"``), else one made from the training config beside it (``"config.yaml"``,
    a file saved before policies carried one). Neither: a ValueError in one line naming the
    missing information."""
    path = Path(path)
    info = read_policy_info(path)
    if info is not None:
        return info, "zip"
    config = path.parent / "config.yaml"
    if not config.is_file():
        raise ValueError(
            f"policy: {path} does not say what it was trained on (env_id, env_kwargs, "
            f"observation_version): it carries no {POLICY_INFO_MEMBER} and has no config.yaml beside it; "
            "put its training config beside it as config.yaml and run `drill-env upgrade-policies` on its folder"
        )
    from drill_env.params import load_yaml

    data = load_yaml(config, what="policy config", error=ValueError) or {}
    if not isinstance(data, Mapping):
        raise ValueError(f"policy: {config} must hold a YAML mapping (the training config)")
    data = dict(data)
    if "algo" not in data:
        summary = path.parent / "training_summary.json"
        if summary.is_file():
            algo = json.loads(summary.read_text()).get("algo")
            if algo is not None:
                data["algo"] = algo
    for key in ("algo", "env_id"):
        if key not in data:
            raise ValueError(f"policy: {config} (the training config of {path}) has no {key!r}")
    info = policy_info(data, drill_env_version=None)
    info["converted_from"] = "config.yaml"
    return info, "config.yaml"


def rewrite_policy_zip(
    path: str | Path,
    *,
    info: Mapping[str, Any] | None = None,
    replace: Mapping[str, bytes] | None = None,
    strip_machine_info: bool = False,
) -> None:
    """Rewrite the zip ``path`` in place, every member byte for byte as it was except:
    ``replace`` (member name -> new content), ``info`` written as :data:`POLICY_INFO_MEMBER`
    (added, or replacing the one there) and, with ``strip_machine_info``, the OS line of
    stable-baselines3's ``system_info.txt`` left out (it names the build machine's kernel)."""
    path = Path(path)
    replace = dict(replace or {})
    if info is not None:
        replace[POLICY_INFO_MEMBER] = (json.dumps(_jsonable(dict(info)), indent=2) + "\n").encode()
    with zipfile.ZipFile(path) as zf:
        items = [(i, zf.read(i.filename)) for i in zf.infolist()]
    from drill_env.outputs import atomic_file

    with atomic_file(path, "wb") as f, zipfile.ZipFile(f, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for item, content in items:
            if item.filename in replace:
                content = replace.pop(item.filename)
            if strip_machine_info and item.filename == "system_info.txt":
                lines = content.decode().splitlines()
                content = ("\n".join(ln for ln in lines if not ln.startswith("- OS:")) + "\n").encode()
            zf.writestr(item, content)
        for name, content in replace.items():
            member = zipfile.ZipInfo(name, date_time=_ZIP_TIME)
            member.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(member, content)
