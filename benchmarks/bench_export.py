"""Exported policies against ``load_policy``: the largest action difference and the time per action.

    python benchmarks/bench_export.py [--agents results/agents] [--n 10000] [--out results/rig_export] [--quick]

Exports every shipped policy under ``--agents`` (every ``policy.zip``: the plain PPO and SAC
policies and the residual policies' corrections) with ``drill-env export-policy``'s own
function (:func:`drill_env.agents.learning.export.export_policy`) into a temporary folder,
then runs, on the same ``--n`` observations per policy, the policy as ``load_policy`` loads it
(the reference: its deterministic ``predict``, one observation per call, as the benchmark
and ``run-controller`` call it), the ONNX file through ONNX Runtime and the numpy-only runner
(:class:`drill_env.rig.numpy_policy.NumpyPolicy`). The observations: half from closed-loop
rollouts of the policy itself on its environment (set points 0.6 V to 4 V, seeds 0, 1, ...),
a quarter drawn uniformly over the environment's observation space, a quarter drawn around
the rig's operating range (speeds and angles within a few of their scales); in the drawn ones
the set point's entries (target speed, nominal voltage) are those of one of the rollouts' set
points (a rig runs at a set point). A residual
policy's action is its classical base's combined with the exported correction by the
documented rule (``NumpyPolicy.combine``: ``clip(base + scale * correction, -1, 1)``).

Prints per policy the largest absolute difference of the action (1 = 5 V) and of the voltage
asked for [V] of each runner from the reference, and the median time per action of each
runner (one observation per call, on one core, timed in the same run), and writes the table
to ``OUT/export_check.md`` and ``OUT/export_check.json``. The target: every action difference
at most 1e-5 (float32 rounding) on the observations a rig gives (the rollouts' and those around
the operating range); the largest over the whole observation space is printed beside it.
Exit code 1 when the target is missed. ``--quick``: 400 observations
of two policies, a smoke test of the script (nothing written unless ``--out`` is given).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

TOL = 1e-5
ROLLOUT_VOLTAGES = (0.6, 1.0, 1.6, 2.0, 3.0, 4.0)
TIMED_CALLS = 2000


def _policies(agents: Path) -> list[Path]:
    return sorted(p.parent for p in agents.rglob("policy.zip"))


def _preset(folder: Path) -> str:
    return "no_brake" if "no_brake" in folder.name else "brake"


def _rollouts(env, policy, n: int) -> np.ndarray:  # noqa: ANN001
    """``n`` normalised observations the policy meets in its own closed loop."""
    per = int(np.ceil(n / len(ROLLOUT_VOLTAGES)))
    rows = []
    for seed, v in enumerate(ROLLOUT_VOLTAGES):
        obs, _ = env.reset(seed=seed, options={"nominal_voltage": v})
        state, start = None, np.ones((1,), dtype=bool)
        for _ in range(per):
            rows.append(np.asarray(obs, dtype=np.float32).copy())
            action, state = policy.predict(obs, state=state, episode_start=start, deterministic=True)
            start = np.zeros((1,), dtype=bool)
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                obs, _ = env.reset(seed=seed + 100, options={"nominal_voltage": v})
                state, start = None, np.ones((1,), dtype=bool)
    return np.stack(rows)[:n]


def _space_draws(env, n: int, seed: int, set_points: np.ndarray) -> np.ndarray:  # noqa: ANN001
    """``n // 2`` normalised observations uniform over the observation space and ``n - n // 2``
    around the rig's operating range (the scales of the observation table)."""
    from drill_env.envs import _core as C

    space = env.observation_space
    rng = np.random.default_rng(seed)
    low = np.where(np.isfinite(space.low), space.low, -10.0)
    high = np.where(np.isfinite(space.high), space.high, 10.0)
    uniform = rng.uniform(low, high, size=(n // 2, low.size))
    m = n - n // 2
    s = env.unwrapped.settings
    scales = np.asarray(s.ecfg[C.EC_SCALE : C.EC_SCALE + s.n_obs])
    z = rng.normal(size=(m, s.n_obs)) * np.where(scales > 1.5, 0.6, 0.7)
    z[:, C.OB_VOLTAGE] = rng.uniform(0, 1, m)
    out = np.concatenate([uniform, z])
    # a rig runs at a set point: the entries that give it (target speed, nominal voltage) are
    # those of one of the rollouts' set points (a residual policy's classical base designs
    # itself, once, for each set point it meets)
    pick = rng.integers(0, len(set_points), size=len(out))
    out[:, C.OB_TARGET] = set_points[pick, 0]
    out[:, C.OB_UNOM] = set_points[pick, 1]
    return out.astype(np.float32)


def _median_time(fn, inputs: list) -> float:  # noqa: ANN001
    """Median seconds per call of ``fn`` over ``inputs`` (after one call not timed)."""
    fn(inputs[0])
    times = np.empty(len(inputs))
    for k, x in enumerate(inputs):
        t0 = time.perf_counter()
        fn(x)
        times[k] = time.perf_counter() - t0
    return float(np.median(times))


def check_policy(folder: Path, agents: Path, n: int, seed: int, work: Path) -> dict:
    import onnxruntime as ort

    from drill_env.agents.evaluation.rig_runs import resolve_controller
    from drill_env.agents.learning.export import export_policy
    from drill_env.envs import _core as C
    from drill_env.rig.numpy_policy import NumpyPolicy

    preset = _preset(folder)
    env, policy, _ = resolve_controller(str(folder / "policy.zip"), preset, 2000, 1000.0, trusted=True)
    paths = export_policy(policy, env, work / folder.relative_to(agents))
    s = env.unwrapped.settings
    scales = np.asarray(s.ecfg[C.EC_SCALE : C.EC_SCALE + s.n_obs], dtype=np.float32)
    n_roll = n // 2
    rolled = _rollouts(env, policy, n_roll)
    set_points = np.unique(rolled[:, [C.OB_TARGET, C.OB_UNOM]], axis=0)
    normalised = np.concatenate([rolled, _space_draws(env, n - n_roll, seed, set_points)])
    physical = (normalised * scales).astype(np.float32)
    normalised = (physical / scales).astype(np.float32)  # what the exported networks compute from it
    session = ort.InferenceSession(
        str(paths["onnx"]), providers=["CPUExecutionProvider"], sess_options=_one_thread(ort)
    )
    runner = NumpyPolicy(paths["npz"])
    residual = hasattr(policy, "base")

    def reference(o):  # noqa: ANN001, ANN202
        return policy.predict(o, state=None, deterministic=True)[0]

    want = np.stack([np.reshape(reference(o), -1) for o in normalised]).astype(np.float64)
    if residual:
        from drill_env.agents.learning.residual import observation_with_base, step_base

        base_action, feedforward, _ = step_base(policy.base, normalised, None, None)
        feeds = {"observation": physical}
        extra = None
        if policy.observe_base:
            extra = observation_with_base(normalised, base_action, feedforward)[:, -2:].astype(np.float32)
            feeds["base"] = extra
        (correction,) = session.run(["correction"], feeds)
        a_onnx = runner.combine(np.reshape(base_action, (-1, 1)), correction)
        a_np = runner.combine(np.reshape(base_action, (-1, 1)), runner.action(physical, extra))
        v_onnx = runner.voltage(physical, a_onnx)
        v_np = runner.voltage(physical, a_np)

        def onnx_one(k):  # noqa: ANN001, ANN202
            b, f, _ = step_base(policy.base, normalised[k], None, None)
            fd = {"observation": physical[k : k + 1]}
            if policy.observe_base:
                fd["base"] = observation_with_base(normalised[k], b, f)[-2:].reshape(1, 2)
            return runner.combine(np.reshape(b, (1, 1)), session.run(["correction"], fd)[0])

        def numpy_one(k):  # noqa: ANN001, ANN202
            b, f, _ = step_base(policy.base, normalised[k], None, None)
            ex = (
                observation_with_base(normalised[k], b, f)[-2:].reshape(1, 2) if policy.observe_base else None
            )
            return runner.combine(np.reshape(b, (1, 1)), runner.action(physical[k : k + 1], ex))
    else:
        a_onnx, v_onnx = session.run(["action", "voltage"], {"observation": physical})
        a_np = runner.action(physical)
        v_np = runner.voltage(physical)

        def onnx_one(k):  # noqa: ANN001, ANN202
            return session.run(["action", "voltage"], {"observation": physical[k : k + 1]})

        def numpy_one(k):  # noqa: ANN001, ANN202
            return runner.voltage(physical[k : k + 1])

    either = np.maximum(
        np.abs(np.reshape(a_onnx, -1) - want[:, 0]), np.abs(np.reshape(a_np, -1) - want[:, 0])
    )
    k = np.arange(len(normalised))
    n_uniform = (n - n_roll) // 2
    parts = {
        "rollout": k < n_roll,
        "space": (k >= n_roll) & (k < n_roll + n_uniform),
        "operating": k >= n_roll + n_uniform,
    }
    u_want = want[:, 0] * s.action_to_volts + (
        physical[:, C.OB_UNOM].astype(np.float64) if s.action_offset else 0.0
    )
    idx = list(range(min(TIMED_CALLS, len(normalised))))
    row = {
        "policy": folder.relative_to(agents).as_posix(),
        "kind": ("residual " if residual else "")
        + type(policy.model if not residual else policy.policy.model).__name__,
        "env": env.spec.id,
        "observations": int(len(normalised)),
        "onnx_action_max_abs": float(np.max(np.abs(np.reshape(a_onnx, -1) - want[:, 0]))),
        "numpy_action_max_abs": float(np.max(np.abs(np.reshape(a_np, -1) - want[:, 0]))),
        # the larger of the two runners' differences on each kind of observation
        **{
            f"{kind}_action_max_abs": float(np.max(either[part])) if np.any(part) else 0.0
            for kind, part in parts.items()
        },
        "action_to_volts": float(s.action_to_volts),
        "onnx_voltage_max_abs_V": float(np.max(np.abs(np.reshape(v_onnx, -1) - u_want))),
        "numpy_voltage_max_abs_V": float(np.max(np.abs(np.reshape(v_np, -1) - u_want))),
        "load_policy_us": 1e6 * _median_time(lambda k: reference(normalised[k]), idx),
        "onnx_us": 1e6 * _median_time(onnx_one, idx),
        "numpy_us": 1e6 * _median_time(numpy_one, idx),
    }
    env.close()
    return row


def _one_thread(ort):  # noqa: ANN001, ANN202
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    return opts


def markdown(rows: list[dict], header: dict) -> str:
    lines = [
        "# Exported policies against load_policy",
        "",
        f"Written by `{header['command']}`. Every shipped policy (`results/agents/**/policy.zip`) exported by "
        "`drill-env export-policy`'s function, then run on the same "
        f"{header['n']} observations per policy (half from its own closed-loop rollouts at "
        f"{', '.join(f'{v:g}' for v in ROLLOUT_VOLTAGES)} V, a quarter uniform over the observation space, a "
        "quarter around the rig's operating range) by ONNX Runtime and by the numpy-only runner, against the "
        "policy as `load_policy` loads it. A residual policy's action is its classical base's combined with the "
        "exported correction by the documented rule, `clip(base + scale * correction, -1, 1)`.",
        "",
        f"**On the observations a rig gives (the closed loop's and those around the operating range) the "
        f"largest action difference of either runner over all policies is {header['max_rig']:.2e} (action "
        f"units, 1 = 5 V); target at most {TOL:g}: {'met' if header['passed'] else 'MISSED'}.** Over the whole "
        f"observation space (uniform over its bounds: speeds up to 100 times their scale, far beyond a rig's) "
        f"it is {header['max_space']:.2e} (column 'whole space'). "
        f"Largest over all observations: ONNX Runtime {header['max_onnx']:.2e}, numpy runner "
        f"{header['max_numpy']:.2e}.",
        "",
        "Time per action: the median of one-observation calls (as a rig calls it every period), one thread, "
        f"load average {header['load_average']:.1f} at the start (wall times on a shared machine: compare the "
        "runners with each other, within a row).",
        "",
        "| policy | kind | env | max abs diff, action: ONNX | numpy | either: rollouts | operating range "
        "| whole space | voltage [V]: ONNX | numpy | time per action [us]: load_policy | ONNX Runtime | numpy |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['policy']} | {r['kind']} | {r['env']} | {r['onnx_action_max_abs']:.2e} | "
            f"{r['numpy_action_max_abs']:.2e} | {r['rollout_action_max_abs']:.2e} | {r['operating_action_max_abs']:.2e} | "
            f"{r['space_action_max_abs']:.2e} | "
            f"{r['onnx_voltage_max_abs_V']:.2e} | {r['numpy_voltage_max_abs_V']:.2e} | "
            f"{r['load_policy_us']:.0f} | {r['onnx_us']:.0f} | {r['numpy_us']:.0f} |"
        )
    lines.append("")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--agents", type=Path, default=Path("results/agents"), help="folder of shipped policies")
    ap.add_argument("--n", type=int, default=10_000, help="observations per policy")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="folder for export_check.md and .json")
    ap.add_argument("--quick", action="store_true", help="400 observations of two policies: a smoke test")
    args = ap.parse_args()
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        print(
            'error: onnxruntime is not installed; pip install -c constraints.txt -e ".[rig]"', file=sys.stderr
        )
        return 2
    if args.n < 10:
        print(f"error: --n: {args.n}; allowed: at least 10", file=sys.stderr)
        return 2
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    except (AttributeError, OSError):
        pass
    import torch

    torch.set_num_threads(1)
    load = os.getloadavg()[0]
    print(f"load average at the start: {load:.2f}", flush=True)
    folders = _policies(args.agents)
    if not folders:
        print(f"error: --agents: no policy.zip under {args.agents}", file=sys.stderr)
        return 2
    n = args.n
    if args.quick:
        folders = [f for f in folders if f.name in ("ppo", "ppo_robust") and f.parent == args.agents][:2]
        n = min(n, 400)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for folder in folders:
            t0 = time.perf_counter()
            row = check_policy(folder, args.agents, n, args.seed, Path(tmp))
            rows.append(row)
            print(
                f"{row['policy']:<26} {row['kind']:<13} max |diff| action: onnx {row['onnx_action_max_abs']:.2e} "
                f"numpy {row['numpy_action_max_abs']:.2e}; voltage: onnx {row['onnx_voltage_max_abs_V']:.2e} V "
                f"numpy {row['numpy_voltage_max_abs_V']:.2e} V; us per action: load_policy "
                f"{row['load_policy_us']:.0f} onnx {row['onnx_us']:.0f} numpy {row['numpy_us']:.0f} "
                f"({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    max_onnx = max(r["onnx_action_max_abs"] for r in rows)
    max_np = max(r["numpy_action_max_abs"] for r in rows)
    # the target is judged on the observations a rig gives: the closed loop's and those around
    # the operating range; the whole observation space (speeds up to 100 times their scale) is
    # reported beside it
    passed = all(r[k] <= TOL for r in rows for k in ("rollout_action_max_abs", "operating_action_max_abs"))
    max_space = max(r["space_action_max_abs"] for r in rows)
    max_rig = max(max(r["rollout_action_max_abs"], r["operating_action_max_abs"]) for r in rows)
    command = "python benchmarks/bench_export.py" + (f" --out {args.out.as_posix()}" if args.out else "")
    if args.n != 10_000:
        command += f" --n {args.n}"
    print(
        f"largest action difference over {len(rows)} policies: {max_rig:.2e} on the observations a rig gives "
        f"(rollouts, operating range): target <= {TOL:g}: {'PASS' if passed else 'FAIL'}; {max_space:.2e} over the "
        f"whole observation space; over all: onnx {max_onnx:.2e}, numpy {max_np:.2e}"
    )
    if args.out is not None:
        header = {
            "max_rig": max_rig,
            "max_space": max_space,
            "command": command,
            "n": n,
            "load_average": load,
            "max_onnx": max_onnx,
            "max_numpy": max_np,
            "passed": passed,
        }
        from drill_env.outputs import atomic_write_text

        args.out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out / "export_check.md", markdown(rows, header))
        record = {**header, "tolerance": TOL, "rollout_voltages": list(ROLLOUT_VOLTAGES), "policies": rows}
        atomic_write_text(args.out / "export_check.json", json.dumps(record, indent=2) + "\n")
        print(f"wrote {args.out / 'export_check.md'} and export_check.json")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
