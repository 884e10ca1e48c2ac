"""End-to-end RL training speed, against the previous training setups timed in the same run.

Two measurements:

1. **Throughput**: env-steps per wall second of ``model.learn`` (rollouts and gradient
   updates, no evaluation), PPO's cases for the same number of steps, baseline and shipped
   config alternating ``--repeats`` times and the best of each kept (on a shared machine the
   best run is the least disturbed); SAC's once each, the shipped config for 10x the
   baseline's steps; ratio new / baseline.

   * PPO: the setup the version-0 policies were trained with (``configs/agents/v0/ppo.yaml``:
     SB3's ``DummyVecEnv`` of 8 single envs, n_steps 512, batch 256, 10 epochs) against the
     shipped ``configs/agents/ppo.yaml`` (128 rigs of the native batched env). Target >= 5x.
   * SAC: the former SAC config (``configs/agents/experiments/sac_v1.yaml``: 4 rigs, one
     gradient step of 256 per env-step) against the shipped ``configs/agents/sac.yaml``
     (many rigs, large batches, few gradient steps per env-step). Target >= 20x.

   * ``--contrib``: also sb3-contrib's TQC and CrossQ on the shipped SAC recipe with the
     algorithm swapped (``configs/agents/experiments/tqc.yaml``, ``crossq.yaml``), for the
     shipped SAC's number of steps, each against the same SAC baseline (no target: what they
     cost against SAC on this CPU).

2. **Time to the target** (``--time-to-policy``): train each algorithm's shipped config of
   each rig on every seed of ``--seeds`` (a list or ranges: ``100-109``) and run the learned
   controllers' target check (``drill_env.agents.evaluation.target_check``: mean suppression
   >= 0.99 in the Hopf-cycle and the stick-slip regime *and* mean RMS speed error within the
   benchmark's tracking limit, 2 x the tuned LQI's + 0.01 rad/s, in every regime, on a grid
   of 3-4 voltages per regime including 5 V and 2 seeds, through the benchmark's own episode
   and metric functions; about a second) every ``--check-every`` env-steps
   (``--check-every-sac`` for SAC). Reports per algorithm and rig how many seeds reached the
   target, the median and the worst training time to it (wall and CPU seconds, the checks
   excluded; a seed that missed counts as infinitely slow in the median), and the median in
   units of a baseline workload timed in the same run, before and after the trainings (the
   version-0 PPO setup for 16 384 env-steps). Target: at least 90 % of the seeds within 5
   minutes of training on 2 cores. ``--from-scratch``: the shipped from-scratch configs
   (``ppo.yaml``, ``ppo_no_brake.yaml``, ``sac.yaml``, ``sac_no_brake.yaml``; no warm
   start, no residual base, no controller anywhere in training); without it, the
   LQI-clone recipes ``ppo_lqi_clone.yaml`` / ``ppo_lqi_clone_no_brake.yaml`` (warm start
   counted in the training time). A run that has not reached the target after ``--budget``
   seconds is reported as missed. ``--full-curves`` trains every run to its budget (or its
   config's ``total_timesteps``) instead of stopping at the target: the learning curves.
   ``--clock cpu`` counts the budget and the 5-minute target in CPU seconds of the training
   process instead of wall seconds: on a machine shared with other work, the time the
   training would take on an idle core (both are reported either way).
   ``--config FILE`` measures a trial config instead (its algorithm and rig); TD3 (``--algos
   td3``) has no shipped recipe and is measured only that way.
   ``--jobs 2`` runs two trainings at a time (each on one torch thread, as configured).
   ``--out DIR`` writes ``time_to_policy.json``, ``curves.csv``, ``learning_curves_<rig>.png``
   and ``summary.md`` there.

Exit code 1 when a target is missed (0 when all measured ones are met).

Run::

    python benchmarks/bench_training.py                    # throughput, ~4 minutes
    python benchmarks/bench_training.py --no-throughput --time-to-policy --from-scratch --seeds 100-109 --jobs 2
    python benchmarks/bench_training.py --algos sac --contrib   # SAC, TQC, CrossQ
    python benchmarks/bench_training.py --quick            # a smoke test, seconds
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

CONTRIB_CONFIGS = {"tqc": "experiments/tqc.yaml", "crossq": "experiments/crossq.yaml"}  # --contrib
SPEEDUP_TARGET = {"ppo": 5.0, "sac": 20.0}  # env-steps per wall second, shipped config over its baseline
THROUGHPUT_BASELINE = {"ppo": "v0/ppo.yaml", "sac": "experiments/sac_v1.yaml"}
# algorithms without a shipped recipe: --time-to-policy of a trial's --config only (no throughput)
TRIAL_ALGOS = ("td3",)
TIME_TO_POLICY_TARGET_S = 300.0  # training wall time to the target, per seed, algorithm and rig
SEED_FRACTION_TARGET = 0.9  # of the seeds must reach it within that time
BASELINE_STEPS = 16_384  # env-steps of the baseline workload timed before and after the runs
SUPPRESSION_TARGET = 0.99  # mean suppression in every regime with a cycle (the target check's)
CYCLE_REGIMES = ("limit_cycle", "stick_slip")
PRESETS = ("brake", "no_brake")
CONFIGS = ROOT / "configs" / "agents"


def config_name(algo: str, preset: str, from_scratch: bool) -> str:
    """The shipped config of ``algo`` on ``preset`` (``ppo.yaml``, ``sac_no_brake.yaml``, ...;
    ``ppo_lqi_clone[_no_brake].yaml`` for the warm-start mode)."""
    name = algo if from_scratch else f"{algo}_lqi_clone"
    return f"{name}.yaml" if preset == "brake" else f"{name}_{preset}.yaml"


def _model(cfg, seed: int = 0):
    import numpy as np
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    from drill_env.agents.learning.rl import _algo_class, algo_kwargs, ignore_observations, make_train_vec_env

    torch.set_num_threads(cfg.torch_threads)
    venv = make_train_vec_env(cfg, seed)
    if cfg.normalize_reward:
        venv = VecNormalize(
            venv, norm_obs=False, norm_reward=True, gamma=float(cfg.hyperparameters.get("gamma", 0.99))
        )
    hp = algo_kwargs(cfg.hyperparameters, n_actions=int(np.prod(venv.action_space.shape)))
    model = _algo_class(cfg.algo)("MlpPolicy", venv, seed=seed, verbose=0, device="cpu", **hp)
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


def target_check(model, cfg, preset: str, checker=None):
    """The learned controllers' target check (``drill_env.agents.evaluation.target_check``:
    suppression >= 0.99 in each cycle regime and RMS speed error within the benchmark's
    tracking limit in every regime, on the check grid) of ``model`` trained with ``cfg``, run
    as the benchmark runs it (its episode and metric functions) on the policy's own
    observation version."""
    from drill_env.agents.evaluation.target_check import TargetCheck
    from drill_env.agents.learning.rl import SB3Policy
    from drill_env.envs import ENV_VERSIONS

    if cfg.residual is not None:
        raise ValueError("target_check: the time to policy measures recipes without a residual base")
    checker = checker or TargetCheck(preset, ENV_VERSIONS[cfg.env_id])
    return checker(SB3Policy(model, cfg.algo))


def _training_return(model) -> float:
    """Mean undiscounted return of the last finished training episodes (SB3's
    ``rollout/ep_rew_mean``, the raw reward: VecMonitor sits below any VecNormalize)."""
    buf = getattr(model, "ep_info_buffer", None) or []
    return float(statistics.fmean(e["r"] for e in buf)) if buf else float("nan")


def time_to_policy(
    config: Path,
    preset: str,
    check_every: int,
    budget_s: float,
    seed: int = 0,
    full: bool = False,
    clock: str = "wall",
) -> dict:
    """Train with ``config`` (as ``drill-env train``: one ``learn`` over the config's
    ``total_timesteps``, so the learning-rate schedule is the run's, without its
    learning-curve evaluations) and run the target check every ``check_every`` env-steps
    and at the end; the training wall and CPU time (checks excluded) at which the policy
    first meets the target. Training stops there (``full``: at ``budget_s`` of training or
    the end of the config's run). ``clock``: ``"wall"`` or ``"cpu"``, the training time the
    budget and the 5-minute target are counted in (CPU seconds of the training process: on a
    shared machine, what the training would take on an idle core)."""
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    from drill_env.agents.evaluation.target_check import TargetCheck
    from drill_env.agents.learning.late_phase import averaged_actor, late_phase_callback
    from drill_env.agents.learning.rl import load_config
    from drill_env.envs import ENV_VERSIONS

    torch.manual_seed(seed)
    cfg = load_config(config)
    checker = TargetCheck(preset, ENV_VERSIONS[cfg.env_id])
    model = _model(cfg, seed)
    late = late_phase_callback(cfg.late_phase, cfg.total_timesteps)  # the config's late phase, as train's
    state: dict = {"train_s": 0.0, "cpu_s": 0.0, "t0": 0.0, "c0": 0.0, "next": check_every}
    state.update(first=None, curve=[])
    tag = f"{cfg.algo} {preset} seed {seed}"

    def start_clock() -> None:
        state["t0"], state["c0"] = time.perf_counter(), time.process_time()

    def check() -> bool:
        state["train_s"] += time.perf_counter() - state["t0"]
        state["cpu_s"] += time.process_time() - state["c0"]
        with averaged_actor(model, late):  # the late phase's averaged actor, when it has one
            result = target_check(model, cfg, preset, checker)
        point = {
            "steps": int(model.num_timesteps),
            "wall_s": state["train_s"],
            "cpu_s": state["cpu_s"],
            "training_return": _training_return(model),
            "met": result.met,
            "margin": result.margin,
            "suppression": result.suppression,
            "rms_error": result.rms_error,
            "rms_limit": result.rms_limit,
            "stalled": result.stalled,
            "check_s": result.wall_s,
        }
        state["curve"].append(point)
        if result.met and state["first"] is None:
            state["first"] = point
        print(
            f"    {tag}: {point['steps']:>9d} steps {point['wall_s']:6.0f} s: suppression "
            + ", ".join(f"{k} {v:.3f}" for k, v in sorted(result.suppression.items()))
            + "; RMS error/limit "
            + ", ".join(f"{k} {v:.3g}/{result.rms_limit[k]:.3g}" for k, v in sorted(result.rms_error.items()))
            + f"; margin {result.margin:.2f}"
            + ("  <- reached" if result.met else ""),
            flush=True,
        )
        start_clock()
        done = state["train_s" if clock == "wall" else "cpu_s"] >= budget_s
        return done or (result.met and not full)

    class _Check(BaseCallback):
        def _on_training_start(self) -> None:
            start_clock()

        def _on_step(self) -> bool:
            if self.num_timesteps < state["next"]:
                return True
            while state["next"] <= self.num_timesteps:
                state["next"] += check_every
            return not check()  # False stops the training

    stop = False
    if cfg.warm_start is not None:  # counted in the training time, checked like any policy
        from drill_env.agents.learning.warm_start import warm_start

        start_clock()
        warm = warm_start(model, cfg.warm_start, cfg.env_id, cfg.env_kwargs, seed)
        print(
            f"    {tag}: warm start: {warm['steps']} steps of {warm['controller']} cloned in "
            f"{warm['wall_time_s']:.0f} s",
            flush=True,
        )
        stop = check()
    if not stop:
        model.learn(cfg.total_timesteps, callback=[_Check()] if late is None else [late, _Check()])
        if not state["curve"] or state["curve"][-1]["steps"] != model.num_timesteps:
            check()
    first = state["first"]
    return {
        "algo": cfg.algo,
        "preset": preset,
        "seed": seed,
        "config": str(config.relative_to(ROOT)) if config.is_relative_to(ROOT) else str(config),
        "clock": clock,
        "met": first is not None and first[f"{clock}_s"] <= TIME_TO_POLICY_TARGET_S,
        "time_to_target_s": None if first is None else first["wall_s"],
        "cpu_to_target_s": None if first is None else first["cpu_s"],
        "steps_to_target": None if first is None else first["steps"],
        "curve": state["curve"],
    }


def _run_case(args: tuple) -> dict:
    config, preset, check_every, budget, seed, full, clock = args
    return time_to_policy(Path(config), preset, check_every, budget, seed, full, clock)


def baseline_workload(steps: int) -> dict:
    """A fixed training workload timed in the same run as the recipes (the version-0 PPO
    setup, ``configs/agents/v0/ppo.yaml``, for ``steps`` env-steps of ``learn``): its wall and
    CPU seconds, the yardstick of the machine's speed and load at the time."""
    from drill_env.agents.learning.rl import load_config

    model = _model(load_config(CONFIGS / THROUGHPUT_BASELINE["ppo"]))
    model.learn(512)  # compiled and warmed up: the same work before and after the runs
    t0, c0 = time.perf_counter(), time.process_time()
    model.learn(steps, reset_num_timesteps=False)
    return {
        "config": THROUGHPUT_BASELINE["ppo"],
        "steps": steps,
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
    }


def _median(values: list[float]) -> float | None:
    """The median, a missed seed (None) counting as infinitely slow; None if that is infinite."""
    m = statistics.median(float("inf") if v is None else v for v in values)
    return None if m == float("inf") else m


def summarise(runs: list[dict], baseline_s: float | None = None, clock: str = "wall") -> list[dict]:
    """Per algorithm and rig: how many seeds reached the target, the median (a seed that
    missed counts as infinitely slow) and the worst training time to it, wall and CPU, and
    the times in units of the baseline workload's wall time (``baseline_s``). Met: at least
    :data:`SEED_FRACTION_TARGET` of the seeds reached the target, each within
    :data:`TIME_TO_POLICY_TARGET_S` of training counted on ``clock`` (``"wall"`` or ``"cpu"``
    seconds)."""
    out = []
    keys = sorted({(r["algo"], r["preset"]) for r in runs}, key=lambda k: (k[0], PRESETS.index(k[1])))
    for algo, preset in keys:
        rs = [r for r in runs if (r["algo"], r["preset"]) == (algo, preset)]
        wall = [r["time_to_target_s"] for r in rs]
        cpu = [r.get("cpu_to_target_s") for r in rs]
        reached = [t for t in wall if t is not None]
        within = [
            t for t in (wall if clock == "wall" else cpu) if t is not None and t <= TIME_TO_POLICY_TARGET_S
        ]
        median = _median(wall)
        out.append(
            {
                "algo": algo,
                "preset": preset,
                "seeds": [r["seed"] for r in rs],
                "config": ", ".join(sorted({r["config"] for r in rs})),
                "clock": clock,
                "reached": len(reached),
                "reached_within_target": len(within),
                "missed_seeds": [r["seed"] for r in rs if r["time_to_target_s"] is None],
                "time_to_target_s": wall,
                "cpu_to_target_s": cpu,
                "steps_to_target": [r["steps_to_target"] for r in rs],
                "median_time_to_target_s": median,
                "median_cpu_to_target_s": _median(cpu),
                # the slowest seed: None when a seed never reached the target
                "worst_time_to_target_s": max(reached) if len(reached) == len(rs) else None,
                "worst_cpu_to_target_s": max(c for c in cpu if c is not None)
                if len(reached) == len(rs)
                else None,
                "median_in_baselines": None if median is None or not baseline_s else median / baseline_s,
                "met": len(within) >= SEED_FRACTION_TARGET * len(rs),
            }
        )
    return out


def _env_id_of(runs: list[dict], algo: str, preset: str) -> str:
    """The env id of the config the runs of ``algo`` on ``preset`` trained with."""
    import yaml

    configs = {r["config"] for r in runs if r["algo"] == algo and r["preset"] == preset}
    ids = sorted({yaml.safe_load((ROOT / c).read_text())["env_id"] for c in configs})
    return ", ".join(ids)


def write_curves(runs: list[dict], out: Path) -> None:
    """``curves.csv`` (one row per check) and ``learning_curves_<rig>.png``: 1 - the smaller
    of the two cycle regimes' suppression and the training return against env-steps and
    training wall seconds, the median over seeds with the range of the seeds shaded."""
    import pandas as pd

    rows = []
    for r in runs:
        for k, p in enumerate(r["curve"]):
            rows.append(
                {
                    "algo": r["algo"],
                    "preset": r["preset"],
                    "seed": r["seed"],
                    "check": k,
                    "steps": p["steps"],
                    "wall_s": round(p["wall_s"], 2),
                    "cpu_s": round(p["cpu_s"], 2) if "cpu_s" in p else float("nan"),
                    "met": p.get("met"),
                    "margin": p.get("margin", float("nan")),
                    "training_return": p["training_return"],
                    **{
                        f"suppression_{g}": p["suppression"].get(g, float("nan"))
                        for g in ("equilibrium", *CYCLE_REGIMES)
                    },
                    **{
                        f"rms_error_{g}": p["rms_error"].get(g, float("nan"))
                        for g in ("equilibrium", *CYCLE_REGIMES)
                    },
                    **{
                        f"rms_limit_{g}": p.get("rms_limit", {}).get(g, float("nan"))
                        for g in ("equilibrium", *CYCLE_REGIMES)
                    },
                }
            )
    df = pd.DataFrame(rows)
    df.to_csv(out / "curves.csv", index=False)
    draw_curves(df, runs, out)


def draw_curves(df, runs: list[dict], out: Path) -> list[Path]:
    """``learning_curves_<rig>.png`` in ``out`` from the rows of ``curves.csv`` (``df``; the
    runs of ``time_to_policy.json`` name the env each config trained on); returns the files."""
    import numpy as np
    from matplotlib.ticker import NullFormatter

    from drill_env._figures import subplots

    df = df.assign(worst=df[[f"suppression_{g}" for g in CYCLE_REGIMES]].min(axis=1))
    colours = {"ppo": "tab:purple", "sac": "tab:brown", "td3": "tab:olive"}
    for preset, dp in df.groupby("preset"):
        font = 9.0  # [pt] on a figure 8 in wide: legible where the docs draw it (drill_env._figures)
        fig, axes = subplots(2, 2, figsize=(8.0, 7.4), sharey="row")
        for algo, da in dp.groupby("algo"):
            # align the seeds by check: the checks fall at the same env-steps in every seed
            g = da.groupby("check")
            n = g.size()
            keep = n[n == da["seed"].nunique()].index
            agg = g.agg(
                steps=("steps", "median"),
                wall=("wall_s", "median"),
                lo=("worst", "min"),
                hi=("worst", "max"),
                mid=("worst", "median"),
                rlo=("training_return", "min"),
                rhi=("training_return", "max"),
                rmid=("training_return", "median"),
            ).loc[keep]
            label = f"{algo} on {_env_id_of(runs, algo, preset)} (median of {da['seed'].nunique()} seeds, range shaded)"
            for col, x in ((0, agg["steps"] / 1e6), (1, agg["wall"])):
                ax = axes[0, col]
                gap = lambda s: np.clip(1.0 - s, 1e-4, None)  # noqa: E731
                ax.plot(x, gap(agg["mid"]), color=colours.get(algo), marker="o", ms=3, label=label)
                ax.fill_between(x, gap(agg["hi"]), gap(agg["lo"]), color=colours.get(algo), alpha=0.2)
                ax = axes[1, col]
                ax.plot(x, agg["rmid"], color=colours.get(algo), marker="o", ms=3)
                ax.fill_between(x, agg["rlo"], agg["rhi"], color=colours.get(algo), alpha=0.2)
        for col in (0, 1):
            axes[0, col].axhline(1.0 - SUPPRESSION_TARGET, color="black", ls="--", lw=1)
            axes[0, col].set_yscale("log")
            axes[1, col].set_xlabel(
                "training env-steps [millions]" if col == 0 else "training wall time [s]\n(dotted: 300 s)",
                fontsize=font,
            )
        for row in (0, 1):  # seconds to minutes: PPO's and SAC's runs differ 10x in length
            axes[row, 1].set_xscale("log")
            # decades labelled only: the minor labels (2x10^1, 3x10^1, ...) overlap at this width
            axes[row, 1].xaxis.set_minor_formatter(NullFormatter())
        axes[1, 1].axvline(TIME_TO_POLICY_TARGET_S, color="gray", ls=":", lw=1)
        axes[0, 1].axvline(TIME_TO_POLICY_TARGET_S, color="gray", ls=":", lw=1)
        axes[0, 0].set_ylabel("1 - suppression, worse cycle\nregime [-] (dashed: target 0.99)", fontsize=font)
        axes[1, 0].set_ylabel("training return per episode [-]\n(each config's own episodes)", fontsize=font)
        for ax in axes.flat:
            ax.tick_params(labelsize=font)
        handles, labels = axes[0, 0].get_legend_handles_labels()
        leg = fig.legend(handles, labels, loc="lower center", fontsize=font, frameon=False)
        rig = "the braked rig" if preset == "brake" else "the rig without the brake"
        fig.suptitle(f"Learning from scratch on {rig} (target check)", fontsize=font + 2)
        height = leg.get_window_extent(fig.canvas.get_renderer()).height / (fig.dpi * fig.get_figheight())
        fig.tight_layout(rect=(0, height + 0.01, 1, 1))
        fig.savefig(out / f"learning_curves_{preset}.png", dpi=110)
    return [out / f"learning_curves_{p}.png" for p in sorted(set(df["preset"]))]


def _s(t: float | None) -> str:
    return "missed" if t is None else f"{t:.0f}"


def summary_line(s: dict) -> str:
    """One line of text per recipe and rig."""
    missed = f"; missed: seeds {s['missed_seeds']}" if s["missed_seeds"] else ""
    if s["median_time_to_target_s"] is None:
        median = "no median (half or more of the seeds missed)"
    else:
        median = f"median {s['median_time_to_target_s']:.0f} s wall / {s['median_cpu_to_target_s']:.0f} s CPU"
    if s["worst_time_to_target_s"] is None:
        worst = "no worst time (a seed missed)"
    else:
        worst = f"worst {s['worst_time_to_target_s']:.0f} s wall / {s['worst_cpu_to_target_s']:.0f} s CPU"
    return (
        f"{s['algo']} {s['preset']}: {s['reached']} of {len(s['seeds'])} seeds reached the target "
        f"({s['reached_within_target']} within {TIME_TO_POLICY_TARGET_S:.0f} s {s.get('clock', 'wall')}){missed}; "
        f"{median}, {worst}; {'target met' if s['met'] else 'target MISSED'}"
    )


def write_summary(result: dict, out: Path) -> None:
    from drill_env.agents.evaluation.target_check import CHECK_SEEDS, CHECK_VOLTAGES

    grid = "; ".join(
        f"{p}: " + ", ".join(f"{r} {'/'.join(f'{v:g}' for v in vs)} V" for r, vs in regimes.items())
        for p, regimes in CHECK_VOLTAGES.items()
    )
    lines = [
        "# Time to the target, from scratch" if result["from_scratch"] else "# Time to the target",
        "",
        f"Target check (`drill_env.agents.evaluation.target_check`): mean suppression >= {SUPPRESSION_TARGET} "
        "in the Hopf-cycle and the stick-slip regime and mean RMS speed error within the benchmark's "
        "tracking limit (2 x the tuned LQI's on the same runs + 0.01 rad/s) in every regime, no run "
        f"stalled, on the check grid ({grid}) with seeds {', '.join(map(str, CHECK_SEEDS))}. "
        "Times: training wall and CPU time to the first check meeting it (the checks excluded); "
        f"target: at least {SEED_FRACTION_TARGET:.0%} of the seeds within {TIME_TO_POLICY_TARGET_S:.0f} s "
        f"of training {'CPU' if result.get('clock') == 'cpu' else 'wall'} time. "
        f"{result['jobs']} training(s) at a time on {result['cpu_count']} cores, one torch thread each.",
        "",
    ]
    baselines = result.get("baseline", [])
    for i, b in enumerate(baselines):
        when = "" if len(baselines) == 1 else (" before the runs" if i == 0 else " after the runs")
        lines.append(
            f"Baseline workload (`configs/agents/{b['config']}`, {b['steps']} env-steps of `learn`){when}: "
            f"{b['wall_s']:.1f} s wall, {b['cpu_s']:.1f} s CPU."
        )
    clock = result.get("clock", "wall")
    lines += [
        "",
        f"| algorithm | rig | config | seeds reaching it | within target | time to target per seed [{clock} s] "
        "| median wall / CPU [s] | worst wall / CPU [s] | median / baseline | target |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in result["summary"]:
        per_seed = s["time_to_target_s"] if clock == "wall" else s["cpu_to_target_s"]
        times = ", ".join(f"{seed}: {_s(t)}" for seed, t in zip(s["seeds"], per_seed, strict=True))
        cfg = (
            s.get("config") or f"configs/agents/{config_name(s['algo'], s['preset'], result['from_scratch'])}"
        )
        ratio = s.get("median_in_baselines")
        lines.append(
            f"| {s['algo']} | {s['preset']} | `{cfg}` | {s['reached']} of {len(s['seeds'])} "
            f"| {s['reached_within_target']} | {times} | {_s(s['median_time_to_target_s'])} / "
            f"{_s(s['median_cpu_to_target_s'])} | {_s(s['worst_time_to_target_s'])} / "
            f"{_s(s['worst_cpu_to_target_s'])} | {'-' if ratio is None else f'{ratio:.1f}x'} "
            f"| {'met' if s['met'] else 'MISSED'} |"
        )
    tp = result.get("throughput")
    if tp:
        lines += ["", "Throughput in the same run (env-steps per wall second of `model.learn`):", ""]
        lines += [
            "| algorithm | baseline config | baseline | shipped | ratio | target |",
            "|---|---|---|---|---|---|",
        ]
        for algo, t in tp.items():
            if algo not in THROUGHPUT_BASELINE:
                continue
            lines.append(
                f"| {algo} | `configs/agents/{THROUGHPUT_BASELINE[algo]}` | {t['baseline']:.0f} | {t['shipped']:.0f} "
                f"| {t['ratio']:.1f}x | >= {SPEEDUP_TARGET[algo]:g}x: {'met' if t['met'] else 'MISSED'} |"
            )
    lines += [
        "",
        "Learning curves (`curves.csv`, one row per target check): `learning_curves_brake.png`, "
        "`learning_curves_no_brake.png`.",
        "",
    ]
    (out / "summary.md").write_text("\n".join(lines))


def _int_list(text: str, name: str, ap: argparse.ArgumentParser) -> list[int]:
    """Comma-separated integers and ranges: ``1,2,3``, ``100-109``."""
    try:
        values = []
        for x in (x.strip() for x in text.split(",")):
            if "-" in x[1:]:
                lo, hi = (int(y) for y in x.split("-", 1))
                if hi < lo:
                    raise ValueError(x)
                values += list(range(lo, hi + 1))
            elif x:
                values.append(int(x))
    except ValueError:
        ap.error(f"--{name}: expected comma-separated integers >= 0 or ranges (100-109), got {text!r}")
    if not values or any(v < 0 for v in values):
        ap.error(f"--{name}: expected comma-separated integers >= 0, got {text!r}")
    return values


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200_000, help="PPO env-steps timed per case")
    ap.add_argument(
        "--sac-steps", type=int, default=20_000, help="SAC env-steps timed per case (the shipped config: 10x)"
    )
    ap.add_argument(
        "--repeats",
        type=int,
        default=2,
        help="PPO cases timed this often, baseline and shipped config alternating; the best of each "
        "(the machine is shared: the best run is the one least disturbed)",
    )
    ap.add_argument("--no-throughput", action="store_true", help="skip the throughput measurement")
    ap.add_argument(
        "--contrib",
        action="store_true",
        help="also time sb3-contrib's TQC and CrossQ on the SAC recipe (needs --algos with sac)",
    )
    ap.add_argument("--time-to-policy", action="store_true", help="also train and run the quick benchmark")
    ap.add_argument("--check-every", type=int, default=250_000, help="PPO env-steps between quick benchmarks")
    ap.add_argument(
        "--check-every-sac",
        type=int,
        default=50_000,
        help="env-steps between quick benchmarks of the off-policy learners (SAC, TD3)",
    )
    ap.add_argument(
        "--budget", type=float, default=300.0, help="training seconds per run (on --clock) before giving up"
    )
    ap.add_argument(
        "--clock",
        choices=("wall", "cpu"),
        default=None,
        help="the training time --budget and the 5-minute target count: wall seconds (the default), or CPU "
        "seconds of the training process (on a shared machine: what it would take on an idle core); with "
        "--report-only, the clock the summary is recounted on (default: the study's own)",
    )
    ap.add_argument(
        "--config",
        type=Path,
        default=None,
        help="--time-to-policy of this training config instead of the shipped one (a trial: one algorithm "
        "in --algos and one rig in --presets, the config's own)",
    )
    ap.add_argument("--from-scratch", action="store_true", help="the from-scratch configs (see above)")
    ap.add_argument(
        "--algos",
        default="ppo,sac",
        help="algorithms measured (ppo, sac; td3 with --time-to-policy --config)",
    )
    ap.add_argument("--presets", default="brake,no_brake", help="rigs of --time-to-policy")
    ap.add_argument("--seeds", default="1", help="training seeds of --time-to-policy, e.g. 1,2,3 or 100-109")
    ap.add_argument(
        "--full-curves", action="store_true", help="train every run to its budget (learning curves)"
    )
    ap.add_argument("--jobs", type=int, default=1, help="trainings run at a time (1 or 2 on 2 cores)")
    ap.add_argument("--out", type=Path, default=None, help="folder for the JSON, curves, figures and summary")
    ap.add_argument("--quick", action="store_true", help="a smoke test: few steps")
    ap.add_argument(
        "--report-only",
        action="store_true",
        help="rewrite curves.csv, the figures and summary.md of --out from its time_to_policy.json (no training)",
    )
    ap.add_argument(
        "--figures-only",
        action="store_true",
        help="draw learning_curves_*.png of --out again from its curves.csv (the env ids from "
        "time_to_policy.json's configs); no other file is rewritten, nothing is trained",
    )
    a = ap.parse_args(argv)
    for name in ("steps", "sac_steps", "repeats", "check_every", "check_every_sac", "jobs"):
        if getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be an integer >= 1, got {getattr(a, name)}")
    if not a.budget > 0:
        ap.error(f"--budget must be > 0, got {a.budget}")
    algos = [x.strip() for x in a.algos.split(",") if x.strip()]
    presets = [x.strip() for x in a.presets.split(",") if x.strip()]
    known = [*SPEEDUP_TARGET, *TRIAL_ALGOS]
    if not algos or any(x not in known for x in algos):
        ap.error(f"--algos: expected a comma-separated subset of {known}, got {a.algos!r}")
    trial_only = [x for x in algos if x in TRIAL_ALGOS]
    if trial_only and (a.config is None or not a.time_to_policy or not a.no_throughput):
        ap.error(
            f"--algos {trial_only[0]}: no shipped recipe; measured only with --no-throughput --time-to-policy "
            "--config (a trial's config)"
        )
    if not presets or any(x not in PRESETS for x in presets):
        ap.error(f"--presets: expected a comma-separated subset of {list(PRESETS)}, got {a.presets!r}")
    if not a.from_scratch and "sac" in algos and a.time_to_policy:
        algos = [x for x in algos if x != "sac"]  # the warm-start mode has PPO recipes only
    if a.contrib and ("sac" not in algos or a.no_throughput):
        ap.error(
            "--contrib: times TQC and CrossQ against SAC's baseline; needs sac in --algos and the throughput"
        )
    seeds = _int_list(a.seeds, "seeds", ap)
    if a.config is not None:
        import yaml

        if not a.config.is_file():
            ap.error(f"--config: no such file {str(a.config)!r}")
        try:
            trial = yaml.safe_load(a.config.read_text())
            trial_algo, trial_env = str(trial["algo"]), str(trial["env_id"])
        except Exception:
            ap.error(f"--config: {str(a.config)!r} is not a training config with algo and env_id")
        trial_preset = "no_brake" if "NoBrake" in trial_env else "brake"
        if algos != [trial_algo] or presets != [trial_preset]:
            ap.error(
                f"--config: {str(a.config)!r} trains {trial_algo} on {trial_env}; pass --algos {trial_algo} "
                f"--presets {trial_preset}"
            )
        a.config = a.config.resolve()
    if a.figures_only:
        if a.report_only:
            ap.error("--figures-only and --report-only: give one (--report-only also draws the figures)")
        if a.out is None or not all((a.out / f).is_file() for f in ("curves.csv", "time_to_policy.json")):
            ap.error("--figures-only: --out must name a folder holding curves.csv and time_to_policy.json")
        import pandas as pd

        runs = json.loads((a.out / "time_to_policy.json").read_text())["runs"]
        paths = draw_curves(pd.read_csv(a.out / "curves.csv"), runs, a.out)
        print(f"drew {', '.join(str(p) for p in paths)} from {a.out / 'curves.csv'}", flush=True)
        return 0
    if a.report_only:
        if a.out is None or not (a.out / "time_to_policy.json").is_file():
            ap.error("--report-only: --out must name a folder holding time_to_policy.json")
        result = json.loads((a.out / "time_to_policy.json").read_text())
        result["clock"] = a.clock or result.get("clock", "wall")
        if "baseline" in result:  # the summary of the runs it holds, by the present criterion
            baseline_s = statistics.fmean(b["wall_s"] for b in result["baseline"])
            result["summary"] = summarise(result["runs"], baseline_s, result["clock"])
            (a.out / "time_to_policy.json").write_text(json.dumps(result, indent=2) + "\n")
        write_curves(result["runs"], a.out)
        write_summary(result, a.out)
        print(f"rewrote {a.out}/curves.csv, learning_curves_*.png, summary.md", flush=True)
        return 0
    a.clock = a.clock or "wall"
    if a.quick:
        a.steps, a.sac_steps, a.repeats = 20_000, 2_000, 1
    met = True
    result: dict = {
        "from_scratch": a.from_scratch,
        "jobs": a.jobs,
        "cpu_count": __import__("os").cpu_count(),
        "clock": a.clock,
    }
    if not a.no_throughput:
        print(
            f"throughput (env-steps/s of model.learn), {a.steps} PPO / {a.sac_steps} SAC steps per case",
            flush=True,
        )
        result["throughput"] = {}
        # SAC's baseline runs ~140 env-steps/s: timed once (a repeat would cost minutes)
        cases = (("ppo", a.steps, a.repeats), ("sac", a.sac_steps, 1))
        for algo, steps, repeats in (c for c in cases if c[0] in algos):
            base = new = 0.0
            for _ in range(repeats):
                base = max(base, throughput(CONFIGS / THROUGHPUT_BASELINE[algo], steps))
                new = max(new, throughput(CONFIGS / f"{algo}.yaml", steps * (10 if algo == "sac" else 1)))
            ok = new / base >= SPEEDUP_TARGET[algo]
            met &= ok
            result["throughput"][algo] = {"baseline": base, "shipped": new, "ratio": new / base, "met": ok}
            print(
                f"  {algo}: baseline ({THROUGHPUT_BASELINE[algo]}) {base:9.0f}   shipped config {new:9.0f}   "
                f"ratio {new / base:5.1f}x   (target >= {SPEEDUP_TARGET[algo]:g}x: {'met' if ok else 'MISSED'})",
                flush=True,
            )
            if algo == "sac" and a.contrib:
                for other, config in CONTRIB_CONFIGS.items():
                    rate = throughput(CONFIGS / config, steps * 10)
                    result["throughput"][other] = {
                        "config": config,
                        "baseline": base,
                        "steps_per_s": rate,
                        "ratio": rate / base,
                        "vs_shipped_sac": rate / new,
                    }
                    print(
                        f"  {other}: ({config}) {rate:9.0f}   ratio {rate / base:5.1f}x the SAC baseline, "
                        f"{rate / new:4.2f}x the shipped SAC",
                        flush=True,
                    )
    if a.time_to_policy:
        cases, case_algos = [], []
        for algo in algos:
            for seed in seeds:  # the rigs alternating: a study cut off has runs of both
                for preset in presets:
                    every = a.check_every if algo == "ppo" else a.check_every_sac
                    if a.quick:
                        every = 50_000
                    config = a.config or CONFIGS / config_name(algo, preset, a.from_scratch)
                    cases.append(
                        (
                            str(config),
                            preset,
                            every,
                            5.0 if a.quick else a.budget,
                            seed,
                            a.full_curves,
                            a.clock,
                        )
                    )
                    case_algos.append(algo)
        print(
            f"time to the target ({len(cases)} trainings, {a.jobs} at a time; target check every "
            f"{a.check_every} PPO / {a.check_every_sac} SAC steps; target: >= {SEED_FRACTION_TARGET:.0%} of the "
            f"seeds within {TIME_TO_POLICY_TARGET_S:.0f} s of training {a.clock} time)",
            flush=True,
        )
        steps = 2048 if a.quick else BASELINE_STEPS
        baselines = [baseline_workload(steps)]
        print(
            f"  baseline ({THROUGHPUT_BASELINE['ppo']}, {steps} env-steps of learn): "
            f"{baselines[0]['wall_s']:.1f} s wall, {baselines[0]['cpu_s']:.1f} s CPU",
            flush=True,
        )
        done: list[dict] = []

        def finished(run: dict) -> None:  # each run as it ends: a long study that is cut off keeps its runs
            done.append(run)
            if a.out is not None:
                a.out.mkdir(parents=True, exist_ok=True)
                partial = {**result, "baseline": baselines, "runs": done}
                (a.out / "time_to_policy.partial.json").write_text(json.dumps(partial, indent=2) + "\n")
            print(f"  done: {run['algo']} {run['preset']} seed {run['seed']}", flush=True)

        if a.jobs == 1:
            for c in cases:
                finished(_run_case(c))
        else:
            import multiprocessing
            from concurrent.futures import as_completed

            with ProcessPoolExecutor(a.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
                for future in as_completed([pool.submit(_run_case, c) for c in cases]):
                    finished(future.result())
        order = {(algo, c[1], c[4]): i for i, (algo, c) in enumerate(zip(case_algos, cases, strict=True))}
        runs = sorted(done, key=lambda r: order[(r["algo"], r["preset"], r["seed"])])
        baselines.append(baseline_workload(steps))
        print(
            f"  baseline again after the runs: {baselines[1]['wall_s']:.1f} s wall, "
            f"{baselines[1]['cpu_s']:.1f} s CPU",
            flush=True,
        )
        result["baseline"] = baselines
        result["runs"] = runs
        result["summary"] = summarise(runs, statistics.fmean(b["wall_s"] for b in baselines), a.clock)
        for s in result["summary"]:
            met &= s["met"]
            print(f"  {summary_line(s)}", flush=True)
        if a.out is not None:
            a.out.mkdir(parents=True, exist_ok=True)
            (a.out / "time_to_policy.json").write_text(json.dumps(result, indent=2) + "\n")
            (a.out / "time_to_policy.partial.json").unlink(missing_ok=True)
            write_curves(runs, a.out)
            write_summary(result, a.out)
            print(
                f"wrote {a.out}/time_to_policy.json, curves.csv, learning_curves_*.png, summary.md",
                flush=True,
            )
    print(json.dumps({"met": met, **{k: v for k, v in result.items() if k != "runs"}}, default=str))
    return 0 if met else 1


if __name__ == "__main__":
    raise SystemExit(main())
