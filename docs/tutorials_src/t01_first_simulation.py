"""
First simulation and its events
===============================

Simulate the braked rig at 2 V, where the paper's model predicts stick-slip, and look at
what the exact simulator returns: the states, the stick phases and every switching event.
"""

# %%
# One call simulates the rig: a preset (``"brake"`` is the rig of the paper's experiments),
# the amplifier voltage [V] and the end time [s]. The first call compiles the simulator
# (cached on disk afterwards).
import matplotlib.pyplot as plt

import drill_env

res = drill_env.simulate("brake", u=2.0, t_final=60.0)
print(res.message)
print(f"{res.t.size} samples, {len(res.events)} switching events")

# %%
# ``x3`` is the lower-disk (bit) speed [rad/s], ``stick_l`` is True while the lower disk
# sticks: its speed is then exactly 0, not a small number, because the friction law is
# set-valued and the simulator switches to the stuck dynamics.
window = res.t > 40.0
print(f"lower disk stuck {res.stick_l[window].mean():.0%} of the last 20 s")
print(f"exactly zero while stuck: {bool((res.x3[res.stick_l] == 0.0).all())}")

# %%
# Every switch between slipping and sticking is an event, located by root finding on the
# integrator's dense output. ``events.to_pandas()`` lists them: time, disk, mode before
# and after, and the state at the switch.
events = res.events.to_pandas()
print(events.tail(6).to_string())

# %%
# The steady stick-slip cycle: the lower disk stops, the string winds up until the static
# friction lets go, the disk overshoots and sticks again.
fig, ax = plt.subplots(figsize=(7, 3.2))
ax.plot(res.t, res.x2, color="tab:blue", label="upper disk $\\dot\\theta_u$")
ax.plot(res.t, res.x3, color="tab:red", label="lower disk $\\dot\\theta_l$")
ax.set_xlim(40, 60)
ax.set_xlabel("time [s]")
ax.set_ylabel("speed [rad/s]")
ax.legend(loc="upper right")
ax.set_title("braked rig at 2 V: stick-slip")
fig.tight_layout()

# %%
# The whole result as a table (one row per output sample), e.g. to save it:
df = res.to_pandas()
print(df.columns.tolist())
