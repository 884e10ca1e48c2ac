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
# ``bifurcation_brake.png`` puts every run's steady min/max of the lower-disk speed on the
# bifurcation diagram: a controller that suppresses the cycle sits on the (open-loop
# unstable) equilibrium branch.
from matplotlib import image as mpimg  # noqa: E402
from matplotlib import pyplot as plt  # noqa: E402

fig, ax = plt.subplots(figsize=(9, 6))
ax.imshow(mpimg.imread(out / "bifurcation_brake.png"))
ax.set_axis_off()
fig.tight_layout()
