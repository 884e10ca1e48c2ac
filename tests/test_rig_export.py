"""Policy export: every shipped plain policy gives the same actions through ONNX Runtime and the
numpy runner as through load_policy (largest difference 1e-5 of the action, measured ~1e-7);
a residual policy's correction combines with its base as documented."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

ort = pytest.importorskip("onnxruntime")

from drill_env.rig.numpy_policy import NumpyPolicy  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
AGENTS = ROOT / "results" / "agents"
PLAIN = sorted(
    str(p.parent.relative_to(AGENTS))
    for p in AGENTS.rglob("policy.zip")
    if "residual" not in (p.parent / "config.yaml").read_text()
)
RESIDUAL = sorted(
    str(p.parent.relative_to(AGENTS))
    for p in AGENTS.rglob("policy.zip")
    if "residual" in (p.parent / "config.yaml").read_text()
)
TOL = 1e-5


def _export(folder: str, tmp_path: Path):
    from drill_env.agents.evaluation.rig_runs import resolve_controller
    from drill_env.agents.learning.export import export_policy

    preset = "no_brake" if "no_brake" in folder else "brake"
    env, policy, _ = resolve_controller(str(AGENTS / folder / "policy.zip"), preset, 2000, 1000.0)
    paths = export_policy(policy, env, tmp_path)
    return env, policy, paths


def _observations(env, n: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Physical observations around the rig's operating range, and the env's normalised ones."""
    from drill_env.envs import _core as C

    s = env.unwrapped.settings
    scales = np.asarray(s.ecfg[C.EC_SCALE : C.EC_SCALE + s.n_obs])
    rng = np.random.default_rng(seed)
    z = rng.normal(size=(n, s.n_obs)) * np.where(scales > 1.5, 0.6, 0.7)
    z[:, C.OB_VOLTAGE] = rng.uniform(0, 1, n)
    z[:, C.OB_UNOM] = rng.uniform(0.1, 1, n)
    z[:, C.OB_TARGET] = rng.uniform(0.05, 1.2, n)
    physical = (z * scales).astype(np.float32)
    return physical, (physical / scales.astype(np.float32)).astype(np.float32)


@pytest.mark.parametrize(
    "folder", [f if f in ("ppo", "sac") else pytest.param(f, marks=pytest.mark.slow) for f in PLAIN]
)
def test_plain_policy_exports_the_same_actions(folder, tmp_path):
    env, policy, paths = _export(folder, tmp_path)
    physical, normalised = _observations(env)
    want = np.stack([policy.predict(o, deterministic=True)[0] for o in normalised]).reshape(-1, 1)
    torch_path = policy.model.predict(normalised, deterministic=True)[0].reshape(-1, 1)
    session = ort.InferenceSession(str(paths["onnx"]), providers=["CPUExecutionProvider"])
    action, voltage = session.run(["action", "voltage"], {"observation": physical})
    runner = NumpyPolicy(paths["npz"])
    np_action = runner.action(physical)
    d_onnx = float(np.max(np.abs(action - want)))
    d_np = float(np.max(np.abs(np_action - want)))
    assert d_onnx <= TOL and d_np <= TOL and float(np.max(np.abs(torch_path - want))) <= TOL
    s = env.unwrapped.settings
    u = want[:, 0].astype(np.float64) * s.action_to_volts + (physical[:, 7] if s.action_offset else 0.0)
    np.testing.assert_allclose(voltage[:, 0], u, atol=1e-5)
    np.testing.assert_allclose(runner.voltage(physical), u, atol=1e-5)
    meta = json.loads(paths["json"].read_text())
    assert meta["onnx"]["outputs"] == ["action", "voltage"] and len(meta["observation"]["scales"]) == s.n_obs


@pytest.mark.parametrize(
    "folder", [f if i == 0 else pytest.param(f, marks=pytest.mark.slow) for i, f in enumerate(RESIDUAL)]
)
def test_residual_policy_exports_its_correction(folder, tmp_path):
    from drill_env.agents.learning.residual import observation_with_base, step_base

    env, policy, paths = _export(folder, tmp_path)
    physical, normalised = _observations(env, n=60)
    session = ort.InferenceSession(str(paths["onnx"]), providers=["CPUExecutionProvider"])
    runner = NumpyPolicy(paths["npz"])
    meta = json.loads(paths["json"].read_text())
    assert meta["residual"]["scale"] == policy.scale
    for k, obs in enumerate(normalised):
        want, _ = policy.predict(obs, state=None, deterministic=True)
        base_action, feedforward, _ = step_base(policy.base, obs, None, None)
        feeds = {"observation": physical[k : k + 1]}
        extra = None
        if policy.observe_base:
            extra = observation_with_base(obs, base_action, feedforward)[-2:].reshape(1, 2)
            feeds["base"] = extra.astype(np.float32)
        (correction,) = session.run(["correction"], feeds)
        combined = runner.combine(np.reshape(base_action, (1, 1)), correction)  # the documented rule
        np.testing.assert_allclose(combined.reshape(-1), np.reshape(want, -1), atol=TOL)
        np.testing.assert_allclose(runner.action(physical[k : k + 1], extra), correction, atol=TOL)
