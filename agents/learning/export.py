"""Policy export for rigs that run neither Python's torch nor stable-baselines3.

:func:`export_policy` writes a trained MLP policy (PPO or SAC, as :func:`load_policy
<drill_env.agents.learning.rl.load_policy>` loads it) as

* ``policy.onnx``: input ``observation`` (float32, (n, n_obs), the *physical* observation in
  the SI units of the environment's observation table), the environment's normalisation
  inside; outputs ``action`` (float32 (n, 1): the deterministic action ``load_policy`` gives)
  and ``voltage`` (float32 (n, 1): the voltage it asks for [V], before the amplifier's +-5 V:
  ``action * action_to_volts``, plus the observed nominal voltage for a correction action);
* ``policy.npz``: the same network for :class:`drill_env.rig.numpy_policy.NumpyPolicy`;
* ``policy.json``: what the inputs and outputs are (names, units, scales, the environment).

A *residual* policy is exported as its correction network: ``policy.onnx`` has the output
``correction`` (its action in [-1, 1]) and, for a correction that observes its base, a second
input ``base`` (float32 (n, 2): the base's action and feedforward, in action units). The
classical base runs beside it (its gains in ``configs/agents/controllers.yaml``; on a rig
without Python it is re-implemented from them), and the action is
``clip(base_action + scale * correction, -1, 1)``, its voltage as for a plain policy
(``policy.json``: ``residual.scale``, ``residual.base``, ``residual.combine``).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["ONNX_OPSET", "export_policy", "network_modules"]

ONNX_OPSET = 17


def network_modules(model: Any) -> tuple[list[Any], bool]:
    """The torch modules of an SB3 PPO or SAC MLP policy's deterministic action, and whether
    the action is tanh-squashed (SAC) rather than clipped (PPO); ValueError for any other."""
    pol = model.policy
    kind = type(pol).__name__
    if kind == "ActorCriticPolicy" and not pol.squash_output:
        if type(pol.pi_features_extractor).__name__ != "FlattenExtractor":
            raise ValueError(
                "policy: its features extractor is not a plain flatten (only MLP policies export)"
            )
        return [*pol.mlp_extractor.policy_net, pol.action_net], False
    actor = getattr(pol, "actor", None)
    if actor is not None and hasattr(actor, "latent_pi"):
        if type(actor.features_extractor).__name__ != "FlattenExtractor" or getattr(actor, "use_sde", False):
            raise ValueError("policy: its actor is not a plain MLP without gSDE (only MLP policies export)")
        return [*actor.latent_pi, actor.mu], True
    raise ValueError(f"policy: a {kind} is not a PPO or SAC MLP policy")


_ACTIVATION_NAMES = {"Tanh": "tanh", "ReLU": "relu"}


def _module(modules, squash, scales, low, high, a2v, offset, unom_index, n_extra, residual):  # noqa: ANN001, ANN202
    import torch

    class Exported(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = torch.nn.Sequential(*copy.deepcopy(modules)).float().eval()
            self.register_buffer("scales", torch.tensor(scales, dtype=torch.float32))
            self.register_buffer("low", torch.tensor(low, dtype=torch.float32))
            self.register_buffer("high", torch.tensor(high, dtype=torch.float32))

        def _action(self, physical, base=None):  # noqa: ANN001, ANN202
            x = physical / self.scales
            if base is not None:
                x = torch.cat([x, base], dim=1)
            y = self.net(x)
            if squash:
                return self.low + 0.5 * (torch.tanh(y) + 1.0) * (self.high - self.low)
            return torch.maximum(torch.minimum(y, self.high), self.low)

        def forward(self, physical, base=None):  # noqa: ANN001, ANN201
            a = self._action(physical, base)
            if residual:
                return a
            v = a * a2v
            if offset:
                v = v + physical[:, unom_index : unom_index + 1]
            return a, v

    return Exported()


def _onnx_export(torch, module, dummy, buf, inputs, outputs) -> None:  # noqa: ANN001
    torch.onnx.export(
        module,
        dummy,
        buf,
        input_names=inputs,
        output_names=outputs,
        dynamic_axes={name: {0: "batch"} for name in inputs + outputs},
        opset_version=ONNX_OPSET,
        dynamo=False,
    )


def export_policy(policy: Any, env: Any, out: str | Path) -> dict[str, Path]:
    """Write ``policy`` (an ``SB3Policy`` or ``ResidualPolicy``) for environment ``env`` (the
    one it runs on: its observation scales and action mapping) into folder ``out``; returns
    the paths written."""
    import torch

    from drill_env.envs import _core as C
    from drill_env.outputs import atomic_file, atomic_write_text

    residual = hasattr(policy, "base")
    sb3 = policy.policy if residual else policy
    observe_base = bool(getattr(policy, "observe_base", False))
    modules, squash = network_modules(sb3.model)
    settings = env.unwrapped.settings
    n_obs = int(settings.n_obs)
    scales = np.asarray(settings.ecfg[C.EC_SCALE : C.EC_SCALE + n_obs], dtype=np.float32)
    space = sb3.model.action_space
    low, high = np.asarray(space.low, np.float32), np.asarray(space.high, np.float32)
    n_extra = 2 if observe_base else 0
    if sb3.model.observation_space.shape[0] != n_obs + n_extra:
        raise ValueError(
            f"policy: its network takes {sb3.model.observation_space.shape[0]} entries; the environment "
            f"gives {n_obs}{' + 2 of its base' if n_extra else ''}"
        )
    a2v = float(settings.action_to_volts)
    offset = bool(settings.action_offset)
    unom = int(C.OB_UNOM)
    module = _module(modules, squash, scales, low, high, a2v, offset, unom, n_extra, residual)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    dummy = (torch.zeros((1, n_obs)),) + ((torch.zeros((1, n_extra)),) if n_extra else ())
    inputs = ["observation"] + (["base"] if n_extra else [])
    outputs = ["correction"] if residual else ["action", "voltage"]
    import io
    import warnings

    buf = io.BytesIO()
    with warnings.catch_warnings():
        # the TorchScript exporter is chosen on purpose: it needs no onnxscript, and an MLP
        # exports the same through it
        warnings.simplefilter("ignore", DeprecationWarning)
        _onnx_export(torch, module, dummy, buf, inputs, outputs)
    with atomic_file(out / "policy.onnx", "wb") as f:
        f.write(buf.getvalue())
    # the numpy runner's file
    arrays: dict[str, Any] = {"scales": scales, "low": low, "high": high}
    acts: list[str] = []
    i = 0
    pending: tuple[np.ndarray, np.ndarray] | None = None
    for m in modules:
        name = type(m).__name__
        if name == "Linear":
            if pending is not None:
                arrays[f"w{i}"], arrays[f"b{i}"] = pending
                acts.append("none")
                i += 1
            pending = (
                m.weight.detach().cpu().numpy().astype(np.float32).T.copy(),
                m.bias.detach().cpu().numpy().astype(np.float32),
            )
        elif name in _ACTIVATION_NAMES and pending is not None:
            arrays[f"w{i}"], arrays[f"b{i}"] = pending
            acts.append(_ACTIVATION_NAMES[name])
            pending = None
            i += 1
        else:
            raise ValueError(f"policy: layer {name} is not Linear, Tanh or ReLU")
    if pending is not None:
        arrays[f"w{i}"], arrays[f"b{i}"] = pending
        acts.append("none")
    scale = float(policy.scale) if residual else 0.0
    arrays.update(
        activations=np.array(acts),
        squash=np.array(int(squash)),
        action_to_volts=np.array(a2v),
        action_offset=np.array(int(offset)),
        unom_index=np.array(unom),
        residual_scale=np.array(scale),
    )
    with atomic_file(out / "policy.npz", "wb") as f:
        np.savez(f, **arrays)
    names = list(getattr(settings, "observation_names", []))
    meta = {
        "source": str(getattr(sb3, "path", "")),
        "env_id": getattr(getattr(env, "spec", None), "id", None),
        "observation": {
            "input": "observation",
            "names": names,
            "units": "SI, as the environment's observation table (rad/s, rad, V)",
            "scales": [float(s) for s in scales],
            "normalised_as": "observation / scales",
        },
        "action": {
            "low": [float(v) for v in low],
            "high": [float(v) for v in high],
            "squash": "tanh" if squash else "clip",
            "action_to_volts": a2v,
            "action_offset": offset,
            "voltage": "action * action_to_volts" + (" + observation[nominal_voltage]" if offset else ""),
        },
        "onnx": {"inputs": inputs, "outputs": outputs, "opset": ONNX_OPSET},
    }
    if residual:
        meta["residual"] = {
            "base": policy.base.describe(),
            "scale": scale,
            "observes_base": observe_base,
            "combine": "action = clip(base_action + scale * correction, -1, 1); voltage = action * "
            f"{a2v:g} V" + (" + observation[nominal_voltage]" if offset else ""),
        }
    atomic_write_text(out / "policy.json", json.dumps(meta, indent=2, default=str) + "\n")
    return {"onnx": out / "policy.onnx", "npz": out / "policy.npz", "json": out / "policy.json"}
