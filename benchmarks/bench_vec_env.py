"""Speed of the SB3 VecEnv over the native batched env, against SB3's DummyVecEnv in the same run.

What SB3 training uses by default, ``DummyVecEnv([lambda: gymnasium.make("DrillString-v0")] * 8)``,
steps 8 single envs one after the other in Python; ``drill_env.sb3_vec_env`` steps all rigs
in one compiled call and splits the batched info into SB3's per-env dicts. Both go through
SB3's ``VecEnv.step`` (auto-reset, ``terminal_observation``, ``TimeLimit.truncated``) and
return the same observations, rewards and dones for the same seeds and actions
(tests/test_sb3_vec_env.py).

Measured: env-steps per second (one env-step = one rig advanced by one control period),
random actions, over runs in which every episode ends and auto-resets (one episode = 400
steps), on one thread: DummyVecEnv of 8 single envs, the adapter with 8 and 64 rigs, and
the bare native vector env (``gymnasium.make_vec``, same-step autoreset) with 8 and 64
rigs, which shows the adapter's own cost. The cases are timed in alternating rounds and
the median round is reported, so that a busy machine slows all alike.

Target (a floor, not an aim): the adapter with 8 rigs is at least as fast as DummyVecEnv
of 8 envs.

Run::

    python benchmarks/bench_vec_env.py --cpu 0     # about half a minute
    python benchmarks/bench_vec_env.py --quick     # a few seconds, for a smoke test
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

# one thread: set before numpy / torch are imported
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from gymnasium.vector import AutoresetMode  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv  # noqa: E402

import drill_env  # noqa: E402

ENV_ID = "DrillString-v0"
RATIO_TARGET = 1.0


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def make_cases(rigs: list[int]) -> dict[str, tuple[object, int, bool]]:
    """name -> (env, number of envs, is an SB3 VecEnv)."""
    cases: dict[str, tuple[object, int, bool]] = {}
    dummy = DummyVecEnv([lambda: gym.make(ENV_ID) for _ in range(8)])
    cases["DummyVecEnv, 8 envs"] = (dummy, 8, True)
    for n in rigs:
        cases[f"sb3_vec_env, {n} rigs"] = (drill_env.sb3_vec_env(ENV_ID, n), n, True)
    for n in rigs:
        native = gym.make_vec(ENV_ID, num_envs=n, autoreset_mode=AutoresetMode.SAME_STEP)
        cases[f"native vector env, {n} rigs"] = (native, n, False)
    return cases


def run(env, n: int, n_steps: int, actions: np.ndarray) -> float:
    """Env-steps per second over n_steps steps of all n envs (SB3 and Gymnasium ``step`` alike)."""
    t0 = time.perf_counter()
    for k in range(n_steps):
        env.step(actions[k % len(actions), :n])
    return n * n_steps / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short run (smoke test, figures noisier)")
    ap.add_argument("--rigs", type=int, nargs="+", default=[8, 64], help="rigs in the adapter (default 8 64)")
    ap.add_argument("--rounds", type=int, default=5, help="alternating rounds per measurement (default 5)")
    ap.add_argument("--cpu", type=int, default=None, help="pin the process to this CPU (Linux)")
    args = ap.parse_args(argv)
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
    n_steps = 100 if args.quick else 800  # 800 steps = two episodes per env: auto-resets included
    rounds = 2 if args.quick else args.rounds
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"machine: {os.cpu_count()} cores, load average {load:.2f}; numpy {np.__version__}, "
        f"gymnasium {gym.__version__}; {ENV_ID}, random actions, episodes of 400 steps"
    )
    cases = make_cases(args.rigs)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.0, 1.0, size=(256, max(max(args.rigs), 8), 1)).astype(np.float32)
    for env, n, sb3 in cases.values():  # warm-up: compilation, first resets
        if sb3:
            env.seed(0)
            env.reset()
        else:
            env.reset(seed=0)
        run(env, n, 20, actions)
    rates: dict[str, list[float]] = {name: [] for name in cases}
    for r in range(rounds):
        for name, (env, n, _) in cases.items():
            rates[name].append(run(env, n, n_steps, actions))
        _progress(f"  round {r + 1}/{rounds}: " + ", ".join(f"{v[-1]:,.0f}" for v in rates.values()))
    med = {name: statistics.median(v) for name, v in rates.items()}
    base = med["DummyVecEnv, 8 envs"]
    for name, v in med.items():
        print(f"{name:28s} {v:12,.0f} env-steps/s  {1e6 / v:7.2f} us/env-step  {v / base:6.2f}x DummyVecEnv")
    for n in args.rigs:
        a, b = med[f"sb3_vec_env, {n} rigs"], med[f"native vector env, {n} rigs"]
        print(f"adapter cost, {n} rigs: {1e6 / a - 1e6 / b:.2f} us/env-step over the bare vector env")
    ok = True
    if 8 in args.rigs:
        ratio = med["sb3_vec_env, 8 rigs"] / base
        ok = ratio >= RATIO_TARGET
        print(
            f"sb3_vec_env (8 rigs) / DummyVecEnv (8 envs): {ratio:.2f}x; target >= {RATIO_TARGET:g}x: "
            f"{'PASS' if ok else 'FAIL'}"
        )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
