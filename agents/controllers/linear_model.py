"""What the controllers believe: the nominal rig linearised about a slip equilibrium, sampled
at the control period and seen through the rig's measurement chain.

The equilibria come from :mod:`drill_env.analysis` (eq. 20, with their friction slope d_l
of eq. 24); controllers are designed on the nominal model (the preset's parameters),
never on the plant the environment simulates.

Linearisation of eq. (36) about the slip equilibrium at lower-disk speed w > 0, states
(x1, x2, x3), input u::

    x1' = x2 - x3
    Ju x2' = km u - k_theta x1 - b_up x2
    Jl x3' = k_theta x1 - d_l(w) x3

:func:`sampled_rig` adds what a controller on the rig actually sees (the environment's
observation entries 0-5): the speeds through the Butterworth low-pass of
:class:`~drill_env.sensors.SensorConfig` (its continuous prototype; the 1 kHz
difference quotient in front of it is exact to 0.2 % below 200 rad/s), the twist at the
end of the control period, the encoder speeds averaged over the period, and the voltage
applied during it. The action is held over the period (zero-order hold); the discrete
model is exact for that (matrix exponential). Encoder quantisation is not modelled here
(it is noise, see :data:`MEASUREMENT_NOISE`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from drill_env.analysis import Equilibrium, slip_equilibrium
from drill_env.envs.task import nominal_voltage
from drill_env.params import RigParams
from drill_env.sensors import SensorConfig

__all__ = [
    "sampled_sinusoid_input",
    "MEASURED",
    "MEASUREMENT_NOISE",
    "SampledRig",
    "decay_rate",
    "design_point",
    "equilibrium_observation",
    "linearise",
    "measurement_noise",
    "sampled_drive",
    "sampled_rig",
]

# Observation entries a controller measures (the environment's first six), in order.
MEASURED = ("lower_speed", "upper_speed", "twist", "lower_speed_mean", "upper_speed_mean", "voltage")

# Standard deviation of the encoder quantisation noise on each measured entry at the
# defaults (2000 counts/rev, 1 kHz, 200 rad/s filter, 0.05 s control period), measured on
# the environment at the slip equilibrium: the filtered 1 kHz difference quotient
# (0.03-0.06 rad/s), the twist (one count 3.1 mrad: 1.3-1.6 mrad) and the count difference
# over a period (one count in 0.05 s is 0.063 rad/s: 0.016-0.03 rad/s). The upper ends
# are used; :func:`measurement_noise` rescales them to other encoders and periods.
MEASUREMENT_NOISE = {
    "lower_speed": 0.06,
    "upper_speed": 0.06,
    "twist": 1.6e-3,
    "lower_speed_mean": 0.03,
    "upper_speed_mean": 0.03,
    "voltage": 0.0,
}


def measurement_noise(sensors: SensorConfig, control_dt: float) -> np.ndarray:
    """Noise std of the measured entries (order of :data:`MEASURED`) for a measurement chain."""
    ref = SensorConfig()
    r = sensors.resolution / ref.resolution if sensors.counts_per_rev else 0.0
    base = np.array([MEASUREMENT_NOISE[m] for m in MEASURED])
    scale = np.array([r, r, r, r * 0.05 / control_dt, r * 0.05 / control_dt, 0.0])
    extra = np.array(
        [
            sensors.speed_noise_std,
            sensors.speed_noise_std,
            math.sqrt(2.0) * sensors.angle_noise_std,
            math.sqrt(2.0) * sensors.angle_noise_std / control_dt,
            math.sqrt(2.0) * sensors.angle_noise_std / control_dt,
            0.0,
        ]
    )
    return np.sqrt((base * scale) ** 2 + extra**2)


def design_point(
    params: RigParams, *, voltage: float | None = None, speed: float | None = None
) -> Equilibrium:
    """The slip equilibrium of the nominal model at a voltage [V] or a lower-disk speed [rad/s]."""
    if (speed is None) == (voltage is None):
        raise ValueError("design_point: give exactly one of voltage, speed")
    if voltage is None:
        w = float(speed)
        if not (math.isfinite(w) and w > 0):
            raise ValueError(f"speed: expected a finite speed > 0 rad/s, got {speed!r}")
        voltage = nominal_voltage(params, w)
    u = float(voltage)
    if not (math.isfinite(u) and u > params.uc1):
        raise ValueError(f"voltage: expected a finite voltage > uc1 = {params.uc1:.6g} V, got {voltage!r}")
    eq = slip_equilibrium(params, u)
    if eq is None:  # pragma: no cover - u > uc1 always has one (condition 21)
        raise ValueError(f"voltage: no slip equilibrium at {u:g} V")
    return eq


def linearise(params: RigParams, eq: Equilibrium) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the linearisation about ``eq`` in the states (x1, x2, x3)."""
    ju, jl, k = params.upper_inertia, params.lower_inertia, params.string_stiffness
    A = np.array(
        [
            [0.0, 1.0, -1.0],
            [-k / ju, -params.upper_viscous_pos / ju, 0.0],
            [k / jl, 0.0, -eq.friction_slope / jl],
        ]
    )
    B = np.array([[0.0], [params.motor_constant / ju], [0.0]])
    return A, B


@dataclass(frozen=True)
class SampledRig:
    """The linearised rig at the control clock: ``s(k+1) = F s(k) + G u(k)``, ``y(k) = H s(k)``.

    ``s`` holds (x1, x2, x3), the speed-filter states, the two step-mean speeds and the
    voltage of the last step; ``y`` are the deviations of the measured entries
    :data:`MEASURED` from their equilibrium values. ``u`` is the voltage deviation.
    """

    eq: Equilibrium
    dt: float  # [s] control period
    F: np.ndarray
    G: np.ndarray  # (n,)
    H: np.ndarray  # (6, n)

    @property
    def n(self) -> int:
        return self.F.shape[0]

    @property
    def speed(self) -> float:
        return self.eq.x3

    @property
    def voltage(self) -> float:
        return self.eq.u

    def open_loop_decay_rate(self) -> float:
        """-ln(spectral radius)/dt of the rig alone [1/s] (negative: unstable)."""
        return decay_rate(self.F, self.dt)


def decay_rate(M: np.ndarray, dt: float) -> float:
    """-ln(spectral radius of M) / dt [1/s]; -inf for a zero matrix never occurs here."""
    rho = float(np.max(np.abs(np.linalg.eigvals(M))))
    return -math.log(max(rho, 1e-300)) / dt


def sampled_rig(
    params: RigParams, eq: Equilibrium, dt: float, sensors: SensorConfig | None = None
) -> SampledRig:
    """The discrete model of the rig, its sensors and the zero-order hold about ``eq``."""
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: expected a finite control period > 0 s, got {dt!r}")
    sensors = sensors or SensorConfig()
    A3, B3 = linearise(params, eq)
    wc = sensors.cutoff_rad_s
    order = sensors.filter_order
    nf = order  # filter states per speed
    n = 3 + 2 * nf
    A = np.zeros((n, n))
    B = np.zeros(n)
    A[:3, :3] = A3
    B[:3] = B3[:, 0]
    outs = []
    for j, src in enumerate((2, 1)):  # lower speed x3, upper speed x2
        i0 = 3 + j * nf
        if order == 1:
            A[i0, i0] = -wc
            A[i0, src] = wc
        else:  # Butterworth: f'' + sqrt(2) wc f' + wc^2 f = wc^2 v
            A[i0, i0 + 1] = 1.0
            A[i0 + 1, i0] = -wc * wc
            A[i0 + 1, i0 + 1] = -math.sqrt(2.0) * wc
            A[i0 + 1, src] = wc * wc
        outs.append(i0)
    # Augmented exponential: the state, the held input and the integrals over the period
    # of the lower and the upper speed.
    m = n + 1 + 2
    M = np.zeros((m, m))
    M[:n, :n] = A
    M[:n, n] = B
    M[n + 1, 2] = 1.0
    M[n + 2, 1] = 1.0
    E = expm(M * dt)
    Phi, Gam = E[:n, :n], E[:n, n]
    Psi, Lam = E[n + 1 :, :n] / dt, E[n + 1 :, n] / dt
    # s = [xi (n), mean_lower, mean_upper, u_prev]
    ns = n + 3
    F = np.zeros((ns, ns))
    G = np.zeros(ns)
    F[:n, :n] = Phi
    G[:n] = Gam
    F[n : n + 2, :n] = Psi
    G[n : n + 2] = Lam
    G[n + 2] = 1.0
    H = np.zeros((6, ns))
    H[0, outs[0]] = 1.0
    H[1, outs[1]] = 1.0
    H[2, 0] = 1.0
    H[3, n] = 1.0
    H[4, n + 1] = 1.0
    H[5, n + 2] = 1.0
    return SampledRig(eq=eq, dt=float(dt), F=F, G=G, H=H)


def sampled_sinusoid_input(
    params: RigParams,
    eq: Equilibrium,
    dt: float,
    sensors: SensorConfig | None,
    disk: str,
    omega: float,
) -> np.ndarray:
    """The input column (complex, the size of :func:`sampled_rig`'s state) of a sinusoidal
    torque ``Re(D exp(j omega t))`` [N m] on ``disk`` (``"lower"`` or ``"upper"``, in its direction
    of motion) that is *not* held over the control period: with ``d_k = D exp(j omega k dt)``
    the input's phasor at the start of period k, the sampled state moves by this column times
    ``d_k``. The voltage's column ``G`` of :func:`sampled_rig` is the same with omega = 0 and
    the motor's input."""
    if disk not in ("lower", "upper"):
        raise ValueError(f"disk: {disk!r} is not one of ['lower', 'upper']")
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: expected a finite control period > 0 s, got {dt!r}")
    sensors = sensors or SensorConfig()
    A3, _ = linearise(params, eq)
    wc = sensors.cutoff_rad_s
    nf = sensors.filter_order
    n = 3 + 2 * nf
    A = np.zeros((n, n))
    A[:3, :3] = A3
    b = np.zeros(n)
    if disk == "lower":
        b[2] = 1.0 / params.lower_inertia
    else:
        b[1] = 1.0 / params.upper_inertia
    for j, src in enumerate((2, 1)):  # the speed filters, as in sampled_rig
        i0 = 3 + j * nf
        if nf == 1:
            A[i0, i0] = -wc
            A[i0, src] = wc
        else:
            A[i0, i0 + 1] = 1.0
            A[i0 + 1, i0] = -wc * wc
            A[i0 + 1, i0 + 1] = -math.sqrt(2.0) * wc
            A[i0 + 1, src] = wc * wc
    m = n + 3
    M = np.zeros((m, m), dtype=complex)
    M[:n, :n] = A
    M[:n, n] = b
    M[n, n] = 1j * float(omega)  # the input turns as exp(j omega s) over the period
    M[n + 1, 2] = 1.0
    M[n + 2, 1] = 1.0
    E = expm(M * dt)
    col = np.zeros(n + 3, dtype=complex)
    col[:n] = E[:n, n]
    col[n : n + 2] = E[n + 1 :, n] / dt
    return col


def sampled_drive(
    params: RigParams, eq: Equilibrium, dt: float, sensors: SensorConfig | None = None
) -> SampledRig:
    """The top drive alone: the upper disk and motor with the string cut (its torque is a load
    disturbance), as a drive's speed loop is commissioned. Same measured entries as
    :func:`sampled_rig`; those of the lower disk and the twist are zero."""
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: expected a finite control period > 0 s, got {dt!r}")
    sensors = sensors or SensorConfig()
    nf = sensors.filter_order
    # Upper disk without the string: x2' = (km u - b_up x2) / Ju, its filter, its step mean.
    ju = params.upper_inertia
    A = np.zeros((1 + nf, 1 + nf))
    A[0, 0] = -params.upper_viscous_pos / ju
    B = np.zeros(1 + nf)
    B[0] = params.motor_constant / ju
    wc = sensors.cutoff_rad_s
    if nf == 1:
        A[1, 1] = -wc
        A[1, 0] = wc
    else:
        A[1, 2] = 1.0
        A[2, 1] = -wc * wc
        A[2, 2] = -math.sqrt(2.0) * wc
        A[2, 0] = wc * wc
    m = 1 + nf
    M = np.zeros((m + 2, m + 2))
    M[:m, :m] = A
    M[:m, m] = B
    M[m + 1, 0] = 1.0
    E = expm(M * dt)
    ns = m + 2  # xi, mean_upper, u_prev
    F = np.zeros((ns, ns))
    G = np.zeros(ns)
    F[:m, :m] = E[:m, :m]
    G[:m] = E[:m, m]
    F[m, :m] = E[m + 1, :m] / dt
    G[m] = E[m + 1, m] / dt
    G[m + 1] = 1.0
    H = np.zeros((6, ns))
    H[1, 1] = 1.0  # filtered upper speed
    H[4, m] = 1.0
    H[5, m + 1] = 1.0
    return SampledRig(eq=eq, dt=float(dt), F=F, G=G, H=H)


def equilibrium_observation(params: RigParams, eq: Equilibrium) -> np.ndarray:
    """The environment's observation (SI units, 8 entries) at the slip equilibrium ``eq``."""
    w, u = eq.x3, eq.u
    return np.array([w, w, eq.x1, w, w, u, w, u])
