"""Index layout of the flat parameter and state vectors read by the compiled kernels.

Kept in one place so :meth:`RigParams.as_array`, the kernels and the analysis agree.
"""

# -- parameter vector -------------------------------------------------------------------
KM, JU, TSUP, TSUN, BUP, BUN, JL, KTH, TSL, BL, T1, T2, BETA1, BETA2 = range(14)
BTH = 14  # string damping
TAU_M = 15  # motor torque lag
POSL_A1, POSL_P1, POSL_A2, POSL_P2 = 16, 17, 18, 19
POSU_A1, POSU_P1, POSU_A2, POSU_P2 = 20, 21, 22, 23
TAU_F = 24  # friction lag
DRIFT = 25  # lower friction drift rate
DIST_A, DIST_W, DIST_P = 26, 27, 28
ANY_EFFECT = 29  # 1.0 when any effect is on: the paper's model takes a short path
INV_JU, INV_JL = 30, 31  # 1/J_u, 1/J_l (derived, for the hot path)
HEAT = 32  # friction heating kappa: lower friction level scaled by 1 + kappa * thermal state
TAU_TH = 33  # thermal time constant of the lower friction contact
NP = 34

# -- state vector -----------------------------------------------------------------------
# x1 = theta_u - theta_l is integrated directly (not as a difference of two large angles).
X1, X2, X3, THL, TM, WL, TH = range(7)
# twist, upper speed, lower speed, lower angle, motor torque, lagged lower speed, thermal state
NY = 7
NY_LAG = 6  # the components that evolve with a motor or friction lag but no friction heating

# -- disk modes --------------------------------------------------------------------------
SLIP_NEG, STICK, SLIP_POS = -1, 0, 1
