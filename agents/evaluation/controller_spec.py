"""A controller of your own in the benchmark: the protocol it follows and how a text names it.

The protocol is the one every shipped controller follows (:mod:`drill_env.agents.controllers.base`),
stable-baselines3's ``predict``::

    action, state = controller.predict(obs, state=None, episode_start=None, deterministic=True)

``obs`` is the environment's observation (shape ``(n_obs,)`` or a batch ``(n, n_obs)``),
``action`` what the environment accepts, ``state`` the controller's memory (None at the start
of an episode; ``episode_start[i]`` True restarts row i). How the controller is made for one
environment, first that applies:

1. the object has ``from_env(env, preset)`` (a class method or a function attribute): its result;
2. it is a subclass of :class:`~drill_env.agents.controllers.base.Controller`: ``cls(ControllerSpec.from_env(env))``
   (it designs itself on the design model in ``spec.params``, never on the simulated plant);
3. another class: ``cls()``; a function: ``fn(env, preset)``;
4. an object that already has ``predict``: used as it is.

An optional attribute ``env_version`` (the N of ``DrillString-vN``; default that of the
shipped classical controllers, whose observation is every version's first entries and whose
action is the voltage) picks the environment version the controller runs on: its observation
and action (the environments' reference page lists them). The
result must have a callable ``predict``.

A *spec* (the text of ``drill-env benchmark --controller``) is one of

* ``package.module:Name`` -- ``Name`` from an importable module (on ``sys.path`` or
  ``PYTHONPATH``);
* ``path/to/file.py:Name`` -- ``Name`` from a Python file;
* ``path/to/policy.zip`` -- a stable-baselines3 policy saved by ``drill-env train`` (its
  algorithm from ``training_summary.json`` beside it, else the first of PPO, SAC, TQC,
  CrossQ that loads it); loading one unpickles Python objects, so a file from outside the
  committed ``results/agents/`` needs ``trust_policies`` (``--trust-policies``);
* one of the shipped controller names (:data:`drill_env.agents.registry.CONTROLLERS`);

optionally prefixed ``label=``, the name of its rows in ``benchmark.csv`` (default: ``Name``,
or for a zip the folder of a ``policy.zip``, else the file's stem).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import re
import sys
from pathlib import Path
from typing import Any

__all__ = [
    "check_spec",
    "controller_label",
    "resolve_controller",
    "spec_observation_version",
    "split_label",
]

_LABEL = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]{0,63}$")
_MODULE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def split_label(spec: str) -> tuple[str | None, str]:
    """``label=spec`` -> (label, spec); a spec without a label -> (None, spec)."""
    head, sep, tail = spec.partition("=")
    if sep and _LABEL.match(head.strip()) and ":" not in head and "/" not in head:
        return head.strip(), tail.strip()
    return None, spec.strip()


def controller_label(spec: str) -> str:
    """The name the controller of ``spec`` gets in the results (see the module docstring)."""
    label, body = split_label(spec)
    if label is not None:
        return label
    if _is_zip(body):
        path = Path(body)
        name = path.parent.name if path.name == "policy.zip" and path.parent.name else path.stem
    elif ":" in body:
        name = body.rsplit(":", 1)[1]
    else:
        name = body
    if not _LABEL.match(name):
        raise ValueError(
            f"--controller {spec!r}: {name!r} cannot name result rows (letters, digits, _ . -, at most 64); "
            "give one as LABEL=SPEC"
        )
    return name


def _is_zip(body: str) -> bool:
    return body.lower().endswith(".zip")


def _load_object(spec: str, body: str) -> Any:
    """The object named by ``module:Name`` or ``file.py:Name``; ValueError naming what is missing."""
    if ":" not in body:
        raise ValueError(
            f"--controller {spec!r}: expected package.module:Name, path/to/file.py:Name, path/to/policy.zip "
            "or a shipped controller name"
        )
    where, name = body.rsplit(":", 1)
    if not name.isidentifier():
        raise ValueError(f"--controller {spec!r}: {name!r} is not a Python name")
    if where.endswith(".py"):
        path = Path(where)
        if not path.is_file():
            raise ValueError(f"--controller {spec!r}: no such file {where!r}")
        digest = hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:16]
        mod_name = f"_drill_env_user_controller_{digest}"
        module = sys.modules.get(mod_name)
        if module is None:
            loader_spec = importlib.util.spec_from_file_location(mod_name, path)
            if loader_spec is None or loader_spec.loader is None:
                raise ValueError(f"--controller {spec!r}: {where!r} cannot be imported")
            module = importlib.util.module_from_spec(loader_spec)
            sys.modules[mod_name] = module
            try:
                loader_spec.loader.exec_module(module)
            except Exception as exc:
                del sys.modules[mod_name]
                raise ValueError(
                    f"--controller {spec!r}: importing {where} failed: {type(exc).__name__}: {exc}"
                ) from None
    else:
        if not _MODULE.match(where):
            raise ValueError(f"--controller {spec!r}: {where!r} is not a module name (package.module)")
        try:
            module = importlib.import_module(where)
        except ModuleNotFoundError as exc:
            raise ValueError(
                f"--controller {spec!r}: no module {exc.name!r} (is it installed, or on PYTHONPATH?)"
            ) from None
        except Exception as exc:
            raise ValueError(
                f"--controller {spec!r}: importing {where} failed: {type(exc).__name__}: {exc}"
            ) from None
    if not hasattr(module, name):
        raise ValueError(f"--controller {spec!r}: {where} has no attribute {name!r}")
    obj = getattr(module, name)
    if not (hasattr(obj, "from_env") or callable(obj) or hasattr(obj, "predict")):
        raise ValueError(
            f"--controller {spec!r}: {name} is not a controller (a class or factory whose result has predict)"
        )
    return obj


def _check_zip(spec: str, body: str, trust_policies: bool) -> Path:
    from drill_env.agents.learning.rl import check_policy_zip, trust_from_environment, untrusted_policy_note

    path = Path(body)
    if not path.is_file():
        raise ValueError(f"--controller {spec!r}: no such file {body!r}")
    check_policy_zip(path)
    if untrusted_policy_note(path) is not None and not (trust_policies or trust_from_environment()):
        raise ValueError(
            f"--controller {spec!r}: {body} is not one of the committed policies in results/agents/; loading a "
            "policy unpickles Python objects, which can run arbitrary code: pass --trust-policies to load a "
            "file you made or trust"
        )
    return path


def check_spec(spec: str, *, trust_policies: bool = False) -> str:
    """Check, building nothing on an environment, that ``spec`` names a controller (its module,
    name or file exist, a zip is trusted); returns its label. ValueError otherwise."""
    from drill_env.agents.registry import CONTROLLERS

    label = controller_label(spec)
    _, body = split_label(spec)
    if body in CONTROLLERS:
        return label
    if _is_zip(body):
        _check_zip(spec, body, trust_policies)
        return label
    obj = _load_object(spec, body)
    if inspect.isclass(obj) and not (hasattr(obj, "from_env") or hasattr(obj, "predict")):
        raise ValueError(
            f"--controller {spec!r}: class {obj.__name__} has no predict(obs, state, episode_start, deterministic)"
        )
    return label


def spec_observation_version(spec: str, preset: str, agents_dir: str | Path | None = None) -> int:
    """The observation version the controller of ``spec`` reads (see the module docstring)."""
    from drill_env.agents.registry import CONTROLLERS, observation_version

    _, body = split_label(spec)
    if body in CONTROLLERS:
        return observation_version(body, preset, agents_dir)
    if _is_zip(body):
        from drill_env.agents.learning.rl import policy_observation_version

        return policy_observation_version(body)
    from drill_env.agents.evaluation.episodes import ENV_ID_OF

    version = getattr(_load_object(spec, body), "env_version", observation_version("open_loop", preset))
    allowed = sorted(v for p, v in ENV_ID_OF if p == preset)
    if isinstance(version, bool) or version not in allowed:
        raise ValueError(f"--controller {spec!r}: env_version {version!r}; allowed: one of {allowed}")
    return int(version)


def resolve_controller(
    spec: str,
    env: Any,
    preset: str,
    *,
    agents_dir: str | Path | None = None,
    trust_policies: bool = False,
) -> Any:
    """The controller ``spec`` names, made for environment ``env`` of ``preset`` (an object
    with ``predict``; see the module docstring for the forms of ``spec`` and the contract)."""
    from drill_env.agents.registry import CONTROLLERS, build_controller

    _, body = split_label(spec)
    label = controller_label(spec)
    if body in CONTROLLERS:
        return build_controller(body, env, preset, agents_dir=agents_dir, trusted=trust_policies)
    if _is_zip(body):
        path = _check_zip(spec, body, trust_policies)
        return _load_zip(spec, path, env, label)
    obj = _load_object(spec, body)
    try:
        if hasattr(obj, "from_env"):
            ctrl = obj.from_env(env, preset)
        elif inspect.isclass(obj):
            from drill_env.agents.controllers.base import Controller, ControllerSpec

            ctrl = obj(ControllerSpec.from_env(env)) if issubclass(obj, Controller) else obj()
        elif hasattr(obj, "predict"):
            ctrl = obj
        else:
            ctrl = obj(env, preset)
    except Exception as exc:
        raise ValueError(f"--controller {spec!r}: making it failed: {type(exc).__name__}: {exc}") from None
    if not callable(getattr(ctrl, "predict", None)):
        raise ValueError(
            f"--controller {spec!r}: {type(ctrl).__name__} is not a controller (no predict(obs, state, "
            "episode_start, deterministic))"
        )
    return ctrl


def _load_zip(spec: str, path: Path, env: Any, label: str) -> Any:
    import json

    from drill_env.agents.learning.rl import ALGOS, load_policy

    summary = path.parent / "training_summary.json"
    algos: tuple[str, ...] = ALGOS
    if summary.is_file():
        algo = json.loads(summary.read_text()).get("algo")
        if algo in ALGOS:
            algos = (algo,)
    errors = []
    for algo in algos:
        try:
            policy = load_policy(path, algo=algo, name=label, trusted=True)  # trust checked above
        except Exception as exc:  # the next algorithm
            errors.append(f"{algo}: {type(exc).__name__}")
            continue
        policy.check_env(env)
        return policy
    raise ValueError(
        f"--controller {spec!r}: {path} is not a policy any of {list(algos)} loads ({'; '.join(errors)})"
    )
