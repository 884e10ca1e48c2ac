"""
Train an agent from scratch in seconds
======================================

Train PPO on ``DrillString-v3`` (the action is the correction added to the nominal
voltage, the reward scores the speed error in rad/s) with the shipped recipe
``configs/agents/ppo.yaml``: no warm start, no classical controller anywhere in training. The
committed ``results/agents/ppo`` trains for 2 M steps; here the run is cut to 1 000 000
steps, which is enough to suppress the Hopf cycle, and the policy then runs one benchmark
episode. The training's own wall time is printed below (``wall_time_s``, measured while this
page was built: the figure depends on the machine and on what else it runs).
"""

# %%
# Read the shipped config and shorten it: 1 000 000 steps, an evaluation every 250 000 steps on
# 3 episodes (one per regime).
import dataclasses
import json
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

from drill_env.agents.commands.train import resolve_config
from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env
from drill_env.agents.learning.rl import load_config, load_policy, train

# The name of a shipped config, as `drill-env train --config ppo` takes it:
cfg = load_config(resolve_config(Path("ppo")), total_timesteps=1_000_000)
print(cfg.algo, cfg.env_id, "warm start:", cfg.warm_start is not None, "residual:", cfg.residual is not None)
cfg = dataclasses.replace(
    cfg, evaluation=dataclasses.replace(cfg.evaluation, every_steps=250_000, episodes_per_regime=1)
)
out = Path("runs/tutorials/train")
summary = train(cfg, seed=0, out_dir=out, run_dir=out / "logs", progress_bar=False)
print(json.dumps({k: summary[k] for k in ("total_timesteps", "wall_time_s", "best_eval_return")}, indent=1))
print("references:", summary.get("reference_returns"))

# %%
# The learning curve: the first evaluation is the untrained network (action 0 is the open
# loop at the set point).
curve = pd.read_csv(out / "eval.csv")
fig, ax = plt.subplots(figsize=(6, 3))
ax.plot(
    curve["timesteps"],
    curve["mean_return"],
    "o-",
    color="tab:purple",
    label="PPO from scratch (1 000 000 steps)",
)
ax.set_xlabel("environment steps")
ax.set_ylabel("mean evaluation return [-]")
ax.legend(loc="lower right")
fig.tight_layout()

# %%
# The kept policy on one benchmark episode at 1 V, inside the Hopf regime of the braked rig:
# 60 s of open loop, then 90 s under the policy, scored on the last 20 s, on the env
# version the policy was trained on (v3).
policy = load_policy(out / "policy.zip", trusted=True)  # this process just wrote it
settings = EpisodeSettings()
env = make_env("brake", settings, observation_version=3)
m = evaluate(policy, "brake", 1.0, seed=0, settings=settings, env=env, name="ppo (1 000 000 steps)")
print(f"suppression {m.suppression:.3f}, RMS speed error {m.rms_error:.4f} rad/s, stalled {m.stalled}")

# %%
# ``out`` now holds ``policy.zip``, ``config.yaml``, ``training_summary.json``
# and ``learning_curve.png``, laid out like ``results/agents/ppo/``: pass the parent folder
# to ``drill-env benchmark --agents-dir`` to benchmark it.
print(sorted(p.name for p in out.iterdir()))
