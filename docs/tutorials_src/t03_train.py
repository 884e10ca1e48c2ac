"""
Train an agent in minutes
=========================

Train PPO on ``DrillString-v1`` with a tiny budget. The recipe of ``ppo_lqi_clone``
(``configs/agents/ppo_lqi_clone.yaml``) starts the policy as a clone of the tuned LQI
controller and then runs PPO; here both stages are cut down so that the whole run takes
well under a minute. What it shows is the workflow, not a policy as good as the committed
one (that one trains for 1 M steps, about a minute of wall time plus the warm start).
"""

# %%
# Read the shipped config and shrink it: fewer rigs, a short warm start, a few thousand
# PPO steps, an evaluation every 4 096 steps on 3 episodes (one per regime).
import dataclasses
import json
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

from drill_env.agents.commands.train import resolve_config
from drill_env.agents.learning.rl import load_config, train

# The name of a shipped config, as `drill-env train --config ppo_lqi_clone` takes it:
cfg = load_config(resolve_config(Path("ppo_lqi_clone")), n_envs=16, total_timesteps=8192)
print(cfg.algo, cfg.env_id, "warm start:", cfg.warm_start is not None)

# %%
# The config is a frozen dataclass; ``dataclasses.replace`` changes the budgets.
cfg = dataclasses.replace(
    cfg,
    hyperparameters={**cfg.hyperparameters, "n_steps": 256, "batch_size": 1024, "n_epochs": 2},
    evaluation=dataclasses.replace(cfg.evaluation, every_steps=4096, episodes_per_regime=1),
    warm_start=dataclasses.replace(cfg.warm_start, steps=12000, rounds=2, epochs=15),
)
out = Path("runs/tutorials/train")
summary = train(cfg, seed=0, out_dir=out, run_dir=out / "logs", progress_bar=False)
print(json.dumps({k: summary[k] for k in ("total_timesteps", "best_eval_return")}, indent=1))
print("references:", summary.get("reference_returns"))

# %%
# The learning curve: the first evaluation is the clone of the LQI, before any PPO update.
curve = pd.read_csv(out / "eval.csv")
fig, ax = plt.subplots(figsize=(6, 3))
ax.plot(curve["timesteps"], curve["mean_return"], "o-", color="tab:green", label="PPO (tiny budget)")
ax.set_xlabel("environment steps")
ax.set_ylabel("mean evaluation return [-]")
ax.legend(loc="lower right")
fig.tight_layout()

# %%
# ``out`` now holds ``policy.zip``, ``config.yaml``, ``training_summary.json`` and
# ``learning_curve.png``, laid out like ``results/agents/ppo_lqi_clone/``: pass the parent folder to
# ``drill-env benchmark --agents-dir`` to benchmark it.
print(sorted(p.name for p in out.iterdir()))
