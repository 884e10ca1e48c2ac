"""
From recordings to a corrected model and a better controller
============================================================

The whole loop on a plant the nominal model lacks: a truth plant (the braked rig with the
paper's lower position friction, a1 = 0.12, and k_m +3 %, J_l +5 %) is recorded like the
rig; the discrepancy workflow explains the data and writes a corrected model; the LQI is
retuned on it; and the controllers designed on the nominal and on the corrected model run
on the truth plant. This is ``drill-env sim-to-real --quick`` cut to two controllers; the
full example is in ``results/sim_to_real/``.
"""

# %%
# The quick configuration: short recordings, a coarse tuning, one voltage (1 V) and one
# seed; the closed-loop episodes are lengthened to 50 s so that the angle-locked
# feedforward has time to adapt (its adaptation time is 10 s or more).
import dataclasses
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

from drill_env.agents.evaluation.episodes import EpisodeSettings
from drill_env.agents.evaluation.sim_to_real import quick_config, run_sim_to_real

cfg = quick_config(controllers=("lqi", "lqi_angle_ff"))
cfg = dataclasses.replace(
    cfg, episode=EpisodeSettings(duration=50.0, window=15.0, warmup_time=20.0, warmup_jitter=1.0)
)
res = run_sim_to_real(Path("runs/tutorials/sim_to_real"), cfg, progress=print)

# %%
# What the discrepancy found, and the controllers before (designed on the nominal model)
# and after (designed on the corrected model) on the truth plant:
df = pd.read_csv(Path("runs/tutorials/sim_to_real") / "results.csv")
cols = ["design", "controller", "voltage", "suppression", "rms_error"]
print(df[[c for c in cols if c in df.columns]].round(3).to_string(index=False))

# %%
# The lesson of the full example: retuning a linear design on the corrected parameters
# changes little (the friction that undoes the LQI is no parameter of a linear model);
# what the data contribute is the effect's name, which says which structure to run: the
# angle-locked feedforward of ``lqi_angle_ff`` rejects friction locked to the bit's angle.
designs = df[df.design != "-"]
fig, ax = plt.subplots(figsize=(6, 3.2))
for offset, (design, colour) in enumerate([("nominal", "tab:gray"), ("corrected", "tab:green")]):
    rows = designs[designs.design == design]
    ax.bar(
        [i + 0.38 * offset for i in range(len(rows))],
        rows.suppression,
        width=0.36,
        color=colour,
        label=f"designed on the {design} model",
    )
ax.set_xticks([i + 0.19 for i in range(len(rows))], rows.controller)
ax.axhline(0, color="k", lw=0.8)
ax.set_ylabel("suppression at 1 V [-]")
ax.set_ylim(min(0.0, designs.suppression.min() - 0.1), 1.05)
ax.legend(loc="upper left", fontsize=8)
fig.tight_layout()
