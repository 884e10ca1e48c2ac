"""End-to-end RL training speed, against the previous training setup timed in the same run.

Baseline (the setup the version-0 policies were trained with, ``configs/agents/v0/ppo.yaml``
and ``sac.yaml``): SB3's ``DummyVecEnv`` of 8 single ``DrillString-v0`` envs, PPO with
n_steps 512, batch 256, 10 epochs, 64x64, one torch thread; SAC on one env, one gradient
step per env-step. Against it: the v1 recipes (``configs/agents/ppo_lqi_clone.yaml``, the learner of
``experiments/ppo_from_scratch.yaml``, timed without its warm start; ``experiments/sac_v1.yaml``:
many rigs in the native batched env through ``drill_env.sb3_vec_env``; PPO learns each rollout
of 128 x 128 steps in 5 epochs of minibatches of 1024, one torch thread).

Two measurements:

1. **Throughput**: env-steps per wall second of ``model.learn`` (rollouts and gradient
   updates, no evaluation), each case for the same number of steps; PPO's cases are timed
   ``--repeats`` times, baseline and v1 config alternating, and the best of each kept
   (on a shared machine the best run is the least disturbed); ratio new / baseline.
   Target: PPO >= 5x (aim 10x).
2. **Time to a suppressing policy** (``--time-to-policy``): PPO with the warm-start configs
   of both rigs (``configs/agents/ppo_lqi_clone.yaml``, ``ppo_lqi_clone_no_brake.yaml``:
   the policy cloned from the LQI, then PPO; ``--from-scratch``: the recipes
   ``experiments/ppo_from_scratch.yaml``, ``experiments/ppo_from_scratch_no_brake.yaml``), the quick benchmark of the policy after the warm
   start and every ``--check-every`` env-steps; reports the training wall time (warm start
   included, benchmark runs excluded) at which the mean suppression first reaches 0.99 in
   the Hopf-cycle and the stick-slip regime. Target: under 5 minutes per rig on 2 cores. A
   rig that has not reached it after ``--budget`` seconds is reported as missed.

Exit code 1 when a target is missed (0 when all measured ones are met).

Run::

    python benchmarks/bench_training.py                    # throughput, ~3 minutes
    python benchmarks/bench_training.py --time-to-policy   # + both trainings and quick benchmarks
    python benchmarks/bench_training.py --time-to-policy --from-scratch   # ... without the warm start
    python benchmarks/bench_training.py --quick            # a smoke test, seconds
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

PPO_SPEEDUP_TARGET = 5.0  # env-steps per wall second, v1 config over the baseline
TIME_TO_POLICY_TARGET_S = 300.0  # training wall time to a suppressing policy, per rig
SUPPRESSION_TARGET = 0.99  # quick-benchmark mean suppression in every regime with a cycle


def _model(cfg, seed: int = 0):
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    from drill_env.agents.learning.rl import _algo_class, algo_kwargs, ignore_observations, make_train_vec_env

    torch.set_num_threads(cfg.torch_threads)
    venv = make_train_vec_env(cfg, seed)
    if cfg.normalize_reward:
        venv = VecNormalize(
            venv, norm_obs=False, norm_reward=True, gamma=float(cfg.hyperparameters.get("gamma", 0.99))
        )
    model = _algo_class(cfg.algo)(
        "MlpPolicy", venv, seed=seed, verbose=0, device="cpu", **algo_kwargs(cfg.hyperparameters)
    )
    ignore_observations(model, cfg)
    return model


def throughput(config: Path, steps: int, **overrides) -> float:
    """Env-steps per second of ``learn`` over ``steps`` steps (after a short warm-up that
    compiles the env and fills SAC's ``learning_starts``)."""
    from drill_env.agents.learning.rl import load_config

    cfg = load_config(config, **overrides)
    model = _model(cfg)
    warm = int(cfg.hyperparameters.get("learning_starts", 0)) + cfg.n_envs * int(
        cfg.hyperparameters.get("n_steps", 1)
    )
    model.learn(warm)
    t0 = time.perf_counter()
    model.learn(steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - t0)


def quick_suppression(model, algo: str, preset: str, folder: Path) -> tuple[dict, dict]:
    """Mean suppression and RMS speed error per regime of ``model`` in the quick benchmark."""
    import pandas as pd

    from drill_env.agents.evaluation.benchmark import BenchmarkConfig, run_benchmark

    # a folder per check: the benchmark caches controllers per process by their folder
    agents = folder / f"agents_{model.num_timesteps}"
    # where the benchmark looks for it (agents.registry.policy_path: <algo>/ for the braked rig)
    policy = agents / (algo if preset == "brake" else f"{algo}_{preset}") / "policy.zip"
    policy.parent.mkdir(parents=True, exist_ok=True)
    model.save(str(policy))
    bench = BenchmarkConfig.preset_grid((preset,), quick=True, controllers=(algo,), agents_dir=str(agents))
    csv = run_benchmark(bench, folder / f"bench_{preset}", backend="sequential", fresh=True, report=False)
    rows = pd.read_csv(csv)
    failed = rows["error"].dropna() if "error" in rows else []
    if len(failed):
        raise RuntimeError(f"quick benchmark of {policy}: {failed.iloc[0]}")
    supp = {
        r: float(g["suppression"].mean()) for r, g in rows.groupby("regime") if g["suppression"].notna().any()
    }
    rms = {r: float(g["rms_error"].mean()) for r, g in rows.groupby("regime")}
    return supp, rms


def time_to_policy(config: Path, preset: str, folder: Path, check_every: int, budget_s: float) -> dict:
    """Train with ``config`` (as ``drill-env train``: one ``learn`` over the config's
    ``total_timesteps``, so the learning-rate schedule is the run's, without its
    learning-curve evaluations) and run the quick benchmark every ``check_every`` env-steps;
    the training wall time (benchmark time excluded) at which the mean suppression first
    reaches 0.99 in every regime with a cycle."""
    from stable_baselines3.common.callbacks import BaseCallback

    from drill_env.agents.learning.rl import load_config

    cfg = load_config(config)
    model = _model(cfg)
    state: dict = {"train_s": 0.0, "t0": 0.0, "next": check_every, "result": None}

    def check() -> bool:
        state["train_s"] += time.perf_counter() - state["t0"]
        supp, rms = quick_suppression(model, cfg.algo, preset, folder)
        met = bool(supp) and min(supp.values()) >= SUPPRESSION_TARGET
        row = f"{model.num_timesteps:>10d} steps {state['train_s']:6.0f} s: suppression " + ", ".join(
            f"{k} {v:.3f}" for k, v in sorted(supp.items())
        )
        print("    " + row + ("  <- reached" if met else ""), flush=True)
        state["result"] = {
            "wall_s": state["train_s"],
            "steps": model.num_timesteps,
            "met": met,
            "suppression": supp,
            "rms_error": rms,
        }
        state["t0"] = time.perf_counter()
        return met or state["train_s"] > budget_s

    class _Check(BaseCallback):
        def _on_training_start(self) -> None:
            state["t0"] = time.perf_counter()

        def _on_step(self) -> bool:
            if self.num_timesteps < state["next"]:
                return True
            state["next"] += check_every
            return not check()  # False stops the training

    if cfg.warm_start is not None:  # counted in the training time, checked like any policy
        from drill_env.agents.learning.warm_start import warm_start

        state["t0"] = time.perf_counter()
        warm = warm_start(model, cfg.warm_start, cfg.env_id, cfg.env_kwargs, 0)
        print(
            f"    warm start: {warm['steps']} steps of {warm['controller']} cloned in {warm['wall_time_s']:.0f} s "
            f"(action MSE {warm['action_mse_before']:.3g} -> {warm['action_mse_after']:.3g})",
            flush=True,
        )
        if check():
            return state["result"]

    model.learn(cfg.total_timesteps, callback=_Check())
    if state["result"] is None or state["result"]["steps"] != model.num_timesteps:
        check()
    return state["result"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200_000, help="PPO env-steps timed per case")
    ap.add_argument("--sac-steps", type=int, default=20_000, help="SAC env-steps timed per case")
    ap.add_argument(
        "--repeats",
        type=int,
        default=2,
        help="PPO cases timed this often, baseline and v1 config alternating; the best of each "
        "(the machine is shared: the best run is the one least disturbed)",
    )
    ap.add_argument(
        "--time-to-policy", action="store_true", help="also train both rigs and run the quick benchmark"
    )
    ap.add_argument(
        "--check-every",
        type=int,
        default=250_000,
        help="env-steps between quick benchmarks (--time-to-policy)",
    )
    ap.add_argument(
        "--budget",
        type=float,
        default=600.0,
        help="training wall seconds per rig before giving up (--time-to-policy)",
    )
    ap.add_argument(
        "--from-scratch",
        action="store_true",
        help="--time-to-policy with the recipes (experiments/ppo_from_scratch.yaml, experiments/ppo_from_scratch_no_brake.yaml) instead of the "
        "warm-start ones",
    )
    ap.add_argument("--quick", action="store_true", help="a smoke test: few steps")
    a = ap.parse_args(argv)
    for name in ("steps", "sac_steps", "repeats", "check_every"):
        if getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be an integer >= 1, got {getattr(a, name)}")
    if not a.budget > 0:
        ap.error(f"--budget must be > 0, got {a.budget}")
    if a.quick:
        a.steps, a.sac_steps, a.repeats = 20_000, 2_000, 1
    cfgs = ROOT / "configs" / "agents"
    print(
        f"throughput (env-steps/s of model.learn), {a.steps} PPO / {a.sac_steps} SAC steps per case",
        flush=True,
    )
    met = True
    recipes = {"ppo": "ppo_lqi_clone.yaml", "sac": "experiments/sac_v1.yaml"}  # the v1 learners
    for algo, steps, repeats in (("ppo", a.steps, a.repeats), ("sac", a.sac_steps, 1)):
        base = new = 0.0
        for _ in range(repeats):
            base = max(base, throughput(cfgs / "v0" / f"{algo}.yaml", steps))
            new = max(new, throughput(cfgs / recipes[algo], steps))
        line = f"  {algo}: baseline (v0 config) {base:9.0f}   v1 config {new:9.0f}   ratio {new / base:5.1f}x"
        if algo == "ppo":
            ok = new / base >= PPO_SPEEDUP_TARGET
            met &= ok
            line += f"   (target >= {PPO_SPEEDUP_TARGET:g}x: {'met' if ok else 'MISSED'})"
        print(line, flush=True)
    if a.time_to_policy:
        names = (
            ("experiments/ppo_from_scratch.yaml", "experiments/ppo_from_scratch_no_brake.yaml")
            if a.from_scratch
            else ("ppo_lqi_clone.yaml", "ppo_lqi_clone_no_brake.yaml")
        )
        print(
            f"time to a suppressing policy (training with {' and '.join(names)}, the quick benchmark "
            f"every {a.check_every} steps; target < {TIME_TO_POLICY_TARGET_S:.0f} s of training per rig)",
            flush=True,
        )
        with tempfile.TemporaryDirectory() as tmp:
            for preset, name in zip(("brake", "no_brake"), names, strict=True):
                r = time_to_policy(cfgs / name, preset, Path(tmp), a.check_every, a.budget)
                supp = ", ".join(f"{k} {v:.4f}" for k, v in sorted(r["suppression"].items()))
                rms = ", ".join(f"{k} {v:.4f}" for k, v in sorted(r["rms_error"].items()))
                ok = r["met"] and r["wall_s"] < TIME_TO_POLICY_TARGET_S
                met &= ok
                print(
                    f"  {preset}: {r['steps']} steps in {r['wall_s']:.0f} s "
                    f"({'target met' if ok else 'target MISSED'}); suppression {supp}; RMS error [rad/s] {rms}",
                    flush=True,
                )
    return 0 if met else 1


if __name__ == "__main__":
    raise SystemExit(main())
