"""
The bifurcation diagram
=======================

Compute the paper's bifurcation diagram of the rig without the brake (Fig. 8) on the exact
nonsmooth model: the equilibria and their stability, the Hopf points, the periodic orbits
continued from them with their Floquet multipliers, and the paper's points A-F.
"""

# %%
# ``bifurcation_diagram`` finds the equilibria (the stick set and the slip equilibria),
# the Hopf points, and continues the periodic orbits by shooting with saltation matrices at
# every switch.
import matplotlib.pyplot as plt

from drill_env.analysis import bifurcation_diagram, limit_cycle

d = bifurcation_diagram("no_brake", u_max=2.5)
for name, point in sorted(d.points.items()):
    print(f"{name}: u = {point.u:.4f} V")

# %%
# The diagram draws itself: the lower-disk speed's min/max along every branch, stable
# solid and unstable dashed, with the points A-F.
d.plot("fig8")
plt.gcf().set_size_inches(7, 4.5)
plt.tight_layout()

# %%
# One periodic orbit on its own: the braked rig's stick-slip cycle at 2 V, with its
# amplitude, period, fraction of time stuck and stability (Floquet multipliers).
cyc = limit_cycle("brake", 2.0)
print(f"amplitude {cyc.amplitude:.3f} rad/s, period {cyc.period:.3f} s, stuck {cyc.stick_fraction:.1%}")
print(f"stable: {cyc.stable}")
