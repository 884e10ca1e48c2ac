"""
Compare controllers across voltages against the predicted cycles
================================================================

The project's main question: which controller removes the limit cycles that the
bifurcation analysis predicts, at which operating points? This runs a small benchmark on
the braked rig: four controllers at three voltages (a stable equilibrium, a Hopf cycle and
stick-slip), one seed, and draws each run on the nominal model's bifurcation diagram.
``drill-env benchmark --quick`` is the same on a larger grid; the full grid is in
``results/benchmark/``.
"""

# %%
# A benchmark is a grid of controllers x voltages x seeds, each run through the one
# evaluation path: open loop from rest at the nominal voltage (so the controller is
# switched on at a random phase of the open-loop cycle), then closed loop, scored on the
# last 20 s. Shorter episodes keep this tutorial quick.
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

from drill_env.agents.evaluation.benchmark.backends import run_benchmark
from drill_env.agents.evaluation.benchmark.grid import BenchmarkConfig
from drill_env.agents.evaluation.episodes import EpisodeSettings

cfg = BenchmarkConfig(
    presets=("brake",),
    controllers=("open_loop", "pi_upper", "lqi", "ppo"),
    voltages={"brake": (0.4, 1.0, 2.0)},
    seeds=(0,),
    episode=EpisodeSettings(duration=40.0, window=20.0, warmup_time=30.0),
)
out = Path("runs/tutorials/benchmark")
csv = run_benchmark(cfg, out, workers=1, fresh=True)

# %%
# ``benchmark.csv`` has one row per run. ``suppression`` is 1 - (steady amplitude of the
# lower-disk speed) / (amplitude of the open-loop cycle the analysis predicts at that
# voltage): 1 removes the cycle, 0 leaves it, negative makes it larger. At 0.4 V the open
# loop is stable and there is no cycle to suppress.
df = pd.read_csv(csv)
table = df.pivot_table(index="voltage", columns="controller", values="suppression")
print(table.round(3).to_string())
print(df.pivot_table(index="voltage", columns="controller", values="rms_error").round(4).to_string())

# %%
# Against the prediction: the dashed line is the amplitude of the open-loop cycle the
# analysis predicts at each voltage (0 where the equilibrium is stable), the markers each
# controller's steady amplitude. ``bifurcation_brake.png`` in the output folder draws every
# run on the whole bifurcation diagram, as ``results/benchmark/`` does for the full grid.
styles = {
    "open_loop": ("k", "o"),
    "pi_upper": ("tab:red", "v"),
    "lqi": ("tab:blue", "D"),
    "ppo": ("tab:purple", "s"),
}
fig, ax = plt.subplots(figsize=(6.5, 3.5))
predicted = df.groupby("voltage")["open_loop_amplitude"].first()
ax.plot(predicted.index, predicted.values, "k--", lw=1, label="predicted open-loop cycle")
for name, (colour, marker) in styles.items():
    runs = df[df.controller == name]
    ax.plot(runs.voltage, runs.amplitude, marker, color=colour, ls="none", ms=7, mfc="none", label=name)
ax.set_xlabel("nominal voltage [V]")
ax.set_ylabel("steady amplitude of the\nlower-disk speed [rad/s]")
ax.legend(loc="upper left", fontsize=8)
fig.tight_layout()
