"""The classical controllers with the gains ``drill-env tune`` wrote for a preset
(``configs/agents/controllers.yaml``); ``lqi_angle_ff`` uses the LQI's. The list of
controllers is :data:`drill_env.agents.registry.CLASSICAL`; this module builds them, apart from
:mod:`drill_env.agents.registry` so that training (:mod:`drill_env.agents.learning.rl`) can build its reference
controllers without the registry, which loads trained policies through :mod:`drill_env.agents.learning.rl`."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from drill_env.agents._locations import PACKAGE_DIR, ROOT
from drill_env.agents.controllers.base import Controller, ControllerSpec
from drill_env.params import load_yaml

__all__ = ["BUILT_ON", "DESIGNED", "classical_controller", "gains_path", "load_gains"]

# Controllers built on another's tuned gains: the LQI with angle-locked adaptive feedforward
# is the tuned LQI plus an adaptation designed per operating point on the nominal model
# (drill_env.agents.controllers.angle_feedforward), with nothing tuned of its own.
BUILT_ON = {"lqi_angle_ff": "lqi"}
# Controllers designed in closed form on the design model by their published rules: no gains
# file entry (drill_env.agents.controllers.soft_torque, drill_env.agents.controllers.z_torque).
DESIGNED = ("soft_torque", "z_torque")


def gains_path() -> Path:
    """``configs/agents/controllers.yaml`` (in the source tree or the installed package)."""
    for d in (PACKAGE_DIR / "_configs" / "agents", ROOT / "configs" / "agents"):
        p = d / "controllers.yaml"
        if p.is_file():
            return p
    return ROOT / "configs" / "agents" / "controllers.yaml"


@functools.lru_cache(maxsize=8)
def _load_gains_cached(path: str) -> dict[str, Any]:
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"gains: no such file {path!r}; run `drill-env tune --out {path}`")
    data = load_yaml(p, what="gains file (written by drill-env tune)", error=ValueError) or {}
    if not isinstance(data, dict) or "presets" not in data:
        raise ValueError(f"gains: {path} has no 'presets' mapping")
    presets = data["presets"] if isinstance(data["presets"], dict) else {}
    for preset, entries in presets.items():  # the feedforward's options, before any run needs them
        ff = entries.get("lqi_angle_ff") if isinstance(entries, dict) else None
        if isinstance(ff, dict) and ff.get("options") is not None:
            from drill_env.agents.controllers.angle_feedforward import LQIAngleFeedforward

            LQIAngleFeedforward.check_options(
                ff["options"], f"gains: {path}: presets.{preset}.lqi_angle_ff.options"
            )
    return data


def load_gains(path: str | Path | None = None) -> dict[str, Any]:
    """The tuned gains file (see :func:`drill_env.agents.controllers.tuning.tune_all`)."""
    return _load_gains_cached(str(Path(path) if path is not None else gains_path()))


def classical_controller(
    kind: str,
    spec: ControllerSpec,
    preset: str,
    gains_file: str | Path | None = None,
    options: Mapping[str, Any] | None = None,
) -> Controller:
    """A classical controller with the tuned gains of ``preset``; ``options`` (``lqi_angle_ff``
    only) set the feedforward's own options over the gains file's."""
    from drill_env.agents.controllers.open_loop import OpenLoop
    from drill_env.agents.controllers.tuning import TUNED_GAINS, make_controller

    if kind == "open_loop":
        return OpenLoop(spec)
    if kind in DESIGNED:
        if options:
            raise ValueError(f"options: {kind!r} takes none, got {dict(options)!r}")
        if kind == "soft_torque":
            from drill_env.agents.controllers.soft_torque import SoftTorque

            return SoftTorque.design(spec)
        from drill_env.agents.controllers.z_torque import ZTorque

        return ZTorque.design(spec)
    known = ["open_loop", *DESIGNED, *TUNED_GAINS, *BUILT_ON]
    if kind not in known:
        raise ValueError(f"controller: {kind!r} is not one of {known}")
    data = load_gains(gains_file)
    presets = data["presets"]
    tuned = BUILT_ON.get(kind, kind)
    if preset not in presets or tuned not in presets[preset]:
        raise ValueError(
            f"gains: no tuned gains for {tuned!r} on preset {preset!r} in {gains_file or gains_path()}; "
            "run `drill-env tune`"
        )
    gains = dict(presets[preset][tuned]["gains"])
    if kind == "lqi_angle_ff":
        from drill_env.agents.controllers.angle_feedforward import LQIAngleFeedforward

        # options of the feedforward itself (e.g. variable_step), beside the LQI's gains; checked
        # when the file was read
        options = {**(presets[preset].get(kind, {}).get("options") or {}), **(options or {})}
        return LQIAngleFeedforward(spec, **gains, **options)
    if options:
        raise ValueError(f"options: {kind!r} takes none, got {dict(options)!r}")
    if kind == "lqi":
        from drill_env.agents.controllers.effect_feedforward import LQIEffectFeedforward, has_position_effect

        if has_position_effect(spec.effects):  # a design model that names a position friction
            return LQIEffectFeedforward(spec, **gains)
    return make_controller(kind, spec, gains)
