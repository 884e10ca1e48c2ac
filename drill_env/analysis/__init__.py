"""Bifurcation analysis of the rig on the exact nonsmooth model (Sec. 3 of the paper).

* :func:`equilibria`, :func:`hopf_points`: the stick set (26), the slip equilibria (20)/(22),
  their stability (eigenvalues, cross-checked by Routh-Hurwitz) and the Hopf points with
  their first Lyapunov coefficient;
* :func:`limit_cycle`: a periodic orbit at one voltage by shooting on a Poincare section
  (Newton on the monodromy matrix, saltation matrices at every switch), with its
  amplitude, period, stick fraction and Floquet multipliers;
* :func:`bifurcation_diagram`: pseudo-arclength continuation from every Hopf point and
  the paper's points A-F (Fig. 6 and 8);
* :func:`brute_force_check`: an independent check by long simulations and sweeps;
* :func:`rig_comparison`: the model against the measurements quoted in the paper.

Example::

    from drill_env.analysis import bifurcation_diagram, limit_cycle
    d = bifurcation_diagram("no_brake", u_max=2.5)
    d.points["F"].u, d.plot("fig8")
    limit_cycle("brake", 2.0).amplitude
"""

from drill_env.analysis.continuation import (
    BranchEvent,
    ContinuationSettings,
    PeriodicBranch,
    continue_from_hopf,
)
from drill_env.analysis.diagram import (
    BifurcationDiagram,
    EquilibriumBranch,
    PeriodicSegment,
    SpecialPoint,
    bifurcation_diagram,
)
from drill_env.analysis.equilibria import (
    Equilibrium,
    HopfPoint,
    critical_friction_slope,
    equilibria,
    first_lyapunov_coefficient,
    hopf_points,
    routh_hurwitz,
    slip_equilibrium,
    stick_set,
)
from drill_env.analysis.rig_comparison import RigComparison, rig_comparison
from drill_env.analysis.shooting import LimitCycle, ShootingError, limit_cycle
from drill_env.analysis.sweep import BruteForceCheck, brute_force_check

__all__ = [
    "BifurcationDiagram",
    "BranchEvent",
    "BruteForceCheck",
    "ContinuationSettings",
    "Equilibrium",
    "EquilibriumBranch",
    "HopfPoint",
    "LimitCycle",
    "PeriodicBranch",
    "PeriodicSegment",
    "RigComparison",
    "ShootingError",
    "SpecialPoint",
    "bifurcation_diagram",
    "brute_force_check",
    "continue_from_hopf",
    "critical_friction_slope",
    "equilibria",
    "first_lyapunov_coefficient",
    "hopf_points",
    "limit_cycle",
    "rig_comparison",
    "routh_hurwitz",
    "slip_equilibrium",
    "stick_set",
]
