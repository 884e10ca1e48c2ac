"""Speed of the Gymnasium environments, measured against Gymnasium's Pendulum-v1 in the same run.

Targets (the environment issue):

* single env: a ``DrillString-v0`` step (exact integration of 0.05 s plus 50 sensor
  samples, through ``gymnasium.make`` with its default wrappers) costs at most 2x a
  ``Pendulum-v1`` step made the same way;
* vector env: ``gymnasium.make_vec("DrillString-v0", num_envs=256)`` reaches at least
  200,000 rig-steps per second on one core (the step is one single-threaded compiled call).

Both single envs are timed in alternating rounds and the median round is reported, so
that a busy machine slows both alike. Step times exclude resets (a DrillString reset
integrates 20-25 s of open-loop warm-up; its cost is reported separately). The vector env
is reported twice: stepping only (a window inside the episodes) and over runs in which
every episode ends and autoresets (one episode = 400 steps). Actions are uniformly random.

Run::

    python benchmarks/bench_env.py            # about a minute
    python benchmarks/bench_env.py --quick    # a few seconds, for a smoke test
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import gymnasium as gym
import numpy as np

import drill_env  # noqa: F401  (registers the environments)

SINGLE_RATIO_TARGET = 2.0
VECTOR_TARGET = 200_000.0


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def time_single(env: gym.Env, n_steps: int, actions: np.ndarray, seed: int) -> tuple[float, int, float, int]:
    """Seconds spent in step() over n_steps (resets excluded), steps, seconds in reset(), resets."""
    env.reset(seed=seed)
    t_step = 0.0
    t_reset = 0.0
    resets = 0
    done_steps = 0
    k = 0
    while done_steps < n_steps:
        block = 0
        t0 = time.perf_counter()
        while done_steps + block < n_steps:
            _, _, terminated, truncated, _ = env.step(actions[k % len(actions)])
            k += 1
            block += 1
            if terminated or truncated:
                break
        t_step += time.perf_counter() - t0
        done_steps += block
        if done_steps < n_steps:
            t0 = time.perf_counter()
            env.reset()
            t_reset += time.perf_counter() - t0
            resets += 1
    return t_step, done_steps, t_reset, resets


def bench_single(rounds: int, n_steps: int) -> dict[str, float]:
    pend = gym.make("Pendulum-v1")
    drill = gym.make("DrillString-v0")
    rng = np.random.default_rng(0)
    a_pend = rng.uniform(-2.0, 2.0, size=(4096, 1)).astype(np.float32)
    a_drill = rng.uniform(-1.0, 1.0, size=(4096, 1)).astype(np.float32)
    _progress(f"single env: {pend}  vs  {drill}")
    time_single(pend, 500, a_pend, 0)  # warm-up, compilation
    time_single(drill, 500, a_drill, 0)
    per_pend, per_drill, per_nominal, reset_ms = [], [], [], []
    for r in range(rounds):
        tp, n, _, _ = time_single(pend, n_steps, a_pend, r)
        td, nd, tr, nr = time_single(drill, n_steps, a_drill, r)
        # the same rig holding its nominal (feedforward) voltage: the smooth case
        drill.reset(seed=r)
        a_nom = np.array([[drill.unwrapped.operating_point.nominal_voltage / 5.0]], np.float32)
        tn, nn, _, _ = time_single(drill, n_steps, np.repeat(a_nom, 1, axis=0), r)
        per_pend.append(tp / n)
        per_drill.append(td / nd)
        per_nominal.append(tn / nn)
        if nr:
            reset_ms.append(1e3 * tr / nr)
        _progress(
            f"  round {r + 1}/{rounds}: Pendulum {1e6 * tp / n:6.2f} us/step, "
            f"DrillString {1e6 * td / nd:6.2f} us/step (random actions), {1e6 * tn / nn:6.2f} (nominal)"
        )
    # per-reset cost measured separately on fresh operating points
    for s in range(20):
        t0 = time.perf_counter()
        drill.reset(seed=1000 + s)
        reset_ms.append(1e3 * (time.perf_counter() - t0))
    p = statistics.median(per_pend)
    d = statistics.median(per_drill)
    return {
        "pendulum_us": 1e6 * p,
        "drill_us": 1e6 * d,
        "drill_nominal_us": 1e6 * statistics.median(per_nominal),
        "ratio": d / p,
        "ratio_nominal": statistics.median(per_nominal) / p,
        "reset_ms": statistics.median(reset_ms),
        "pendulum_sps": 1.0 / p,
        "drill_sps": 1.0 / d,
    }


def bench_vector(num_envs: int, n_steps: int, rounds: int) -> dict[str, float]:
    env = gym.make_vec("DrillString-v0", num_envs=num_envs)
    _progress(f"vector env: {type(env.unwrapped).__name__} with {num_envs} rigs")
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1.0, 1.0, size=(64, num_envs, 1)).astype(np.float32)
    t0 = time.perf_counter()
    env.reset(seed=0)
    reset_all = time.perf_counter() - t0
    for k in range(5):
        env.step(actions[k])
    with_resets, stepping = [], []
    resets_seen = 0
    within = min(n_steps, 300)  # fewer than an episode: no reset inside
    for r in range(rounds):
        # (a) steps only: a fresh batch of episodes, none ends inside the timed window
        env.reset(seed=100 + r)
        t0 = time.perf_counter()
        for k in range(within):
            env.step(actions[k % len(actions)])
        stepping.append(num_envs * within / (time.perf_counter() - t0))
        # (b) a longer run: every rig's episode ends (truncation at 400 steps) and autoresets
        t0 = time.perf_counter()
        for k in range(n_steps):
            _, _, term, trunc, _ = env.step(actions[k % len(actions)])
            resets_seen += int(np.sum(term | trunc))
        with_resets.append(num_envs * n_steps / (time.perf_counter() - t0))
        _progress(
            f"  round {r + 1}/{rounds}: {with_resets[-1]:,.0f} rig-steps/s incl. autoresets, "
            f"{stepping[-1]:,.0f} stepping only"
        )
    return {
        "rig_steps_per_s": statistics.median(with_resets),
        "stepping_per_s": statistics.median(stepping),
        "episodes_ended": resets_seen,
        "reset_all_s": reset_all,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short run (smoke test, figures noisier)")
    ap.add_argument("--rigs", type=int, default=256, help="rigs in the vector env (default 256)")
    ap.add_argument("--rounds", type=int, default=5, help="alternating rounds per measurement (default 5)")
    ap.add_argument("--cpu", type=int, default=None, help="pin the process to this CPU (Linux)")
    args = ap.parse_args(argv)
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
    n_single = 2000 if args.quick else 8000
    n_vector = 100 if args.quick else 800  # 800 steps = two episodes: autoresets included
    rounds = 2 if args.quick else args.rounds
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"machine: {os.cpu_count()} cores, load average {load:.2f}; numpy {np.__version__}, gymnasium {gym.__version__}"
    )
    s = bench_single(rounds, n_single)
    v = bench_vector(args.rigs, n_vector, rounds)
    ok_single = s["ratio"] <= SINGLE_RATIO_TARGET
    ok_vector = v["rig_steps_per_s"] >= VECTOR_TARGET
    ok_stepping = v["stepping_per_s"] >= VECTOR_TARGET
    print(f"Pendulum-v1    step: {s['pendulum_us']:7.2f} us  ({s['pendulum_sps']:,.0f} steps/s)")
    print(
        f"DrillString-v0 step: {s['drill_us']:7.2f} us  ({s['drill_sps']:,.0f} steps/s, random actions; "
        f"{s['drill_nominal_us']:.2f} us holding the nominal voltage)"
    )
    print(f"DrillString-v0 reset: {s['reset_ms']:.3f} ms (20-25 s open-loop warm-up)")
    print(
        f"single-env ratio DrillString/Pendulum: {s['ratio']:.2f}x (nominal actions {s['ratio_nominal']:.2f}x); "
        f"target <= {SINGLE_RATIO_TARGET:g}x: {'PASS' if ok_single else 'FAIL'}"
    )
    per_rig_us = 1e6 / v["rig_steps_per_s"]
    print(
        f"vector env, {args.rigs} rigs: {per_rig_us:.2f} us per rig-step incl. autoresets "
        f"= {per_rig_us / s['pendulum_us']:.2f} Pendulum-v1 steps (for scale on this machine)"
    )
    print(
        f"vector env, {args.rigs} rigs: {v['stepping_per_s']:,.0f} rig-steps/s stepping only; "
        f"target >= {VECTOR_TARGET:,.0f}: {'PASS' if ok_stepping else 'FAIL'}"
    )
    print(
        f"vector env, {args.rigs} rigs: {v['rig_steps_per_s']:,.0f} rig-steps/s incl. autoresets "
        f"({v['episodes_ended']} episodes ended); target >= {VECTOR_TARGET:,.0f}: "
        f"{'PASS' if ok_vector else 'FAIL'}"
    )
    return 0 if (ok_single and ok_vector and ok_stepping) else 1


if __name__ == "__main__":
    raise SystemExit(main())
