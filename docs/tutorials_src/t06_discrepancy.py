"""
Find the missing effect in your recordings
==========================================

The paper saw the measured lower-disk speed oscillate once per revolution at low voltage,
which its model lacks. Here a small dataset is recorded like the rig from a *truth* model
that has such a position-dependent friction (hidden from the analysis), and the
discrepancy workflow finds where the nominal model disagrees and which missing effect
explains it.
"""

# %%
# Record the truth like the rig: 3 constant-voltage runs and one quasi-random run, 40 s
# each at 500 Hz, through 2000-count encoders with no added noise. The hidden effect and
# its parameters go to the answer only, never into the dataset.
import json
from pathlib import Path

import drill_env
from drill_env.discrepancy import SynthConfig, make_dataset, run_discrepancy, write_synthetic

out = Path("runs/tutorials/discrepancy")
design = SynthConfig(
    preset="brake",
    voltages=(0.5, 1.0, 3.0),
    random_runs=1,
    duration_s=40.0,
    pre_roll_s=20.0,
    angle_noise_std=0.0,
)
data = make_dataset("position_friction_lower", seed=1, magnitude=0.12, config=design)
write_synthetic(data, out / "data", out / "answer.json", preset="brake")
print(sorted(p.name for p in (out / "data").iterdir()))

# %%
# The dataset is a folder of CSV runs (``t,u,theta_u,theta_l``) and ``dataset.json``: the
# format a real recording is written in (see the how-to on the data format).
print((out / "data" / "dataset.json").read_text())

# %%
# Run the workflow: the filtered equation error shows where the model is wrong, the
# identified parameters are recalibrated, and every candidate effect of the library is
# fitted on the training runs and scored on the held-out ones.
res = run_discrepancy(out / "data", out / "analysis", figures=False)
result = json.loads((out / "analysis" / "result.json").read_text())
print("verdict:", result["effect"], "confidence", result["confidence"])
print("fitted:", {k: round(v, 4) for k, v in result["parameters"].items()})

# %%
# Against the truth it was made from:
answer = json.loads((out / "answer.json").read_text())
truth = {k: round(v, 4) for k, v in answer["model_effects"].items()}
print("truth:", answer["effect"], truth)

# %%
# ``model.yaml`` is the corrected model: the preset with the recalibrated values and the
# named effect, which ``drill_env.simulate`` and ``drill_env.load_params`` accept.
corrected = drill_env.load_params(out / "analysis" / "model.yaml")
print(corrected.effects)
