"""The candidate library: effects the nominal model leaves out.

Most candidates are *physical* (a torque the plant lacks); the two encoder eccentricities
are *measurement* effects (an angle read wrong, no torque), whose columns are the equation
error's response to the reading error and whose parameters go to the measurement model
(:class:`drill_env.measurement.MeasurementModel`), not the plant. Each candidate has a parametric form (the one the simulator implements, see
:class:`drill_env.params.ModelEffects`), a signature in the equation error (which disk,
which measured signal it follows) and a map from its fitted parameters to the
``effects:`` entries of a rig YAML. In the equation error every candidate is a set of
columns ``K[basis]/h^2`` at the windows of :class:`~drill_env.recordings.equation_error.RunEquations`,
added to the nominal torques with coefficients to fit; the two lag effects are
nonlinear in one time constant, which is found on a grid with the coefficient fixed
by physics (1). Friction heating has a free coefficient (kappa) as well as a time
constant: it is fitted linearly as a mix of two fixed lags, see ``THERMAL_TIMES_S``.

Notation: ``sgn`` the direction of slip, ``S(w)`` the Stribeck part of the lower
friction, ``T_sl`` its static level, ``T_su`` the static level of the upper friction
on the current side.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drill_env.measurement import MAX_ENCODER_ECCENTRICITY
from drill_env.recordings.equation_error import RunEquations, stribeck, stribeck_slope

__all__ = [
    "Candidate",
    "CANDIDATES",
    "candidate_names",
    "thermal_state",
    "thermal_trajectory",
    "THERMAL_TIMES_S",
    "eccentricity_columns",
    "reading_centre",
    "position_harmonics",
    "EFFECT_FIELDS",
    "model_effect_names",
    "model_effect_torques",
    "with_model_effects",
]


@dataclass(frozen=True)
class Candidate:
    """One effect of the library."""

    name: str
    title: str
    form: str  # the physical parametric form
    signature: str  # what it looks like in the residual
    n_params: int  # fitted parameters (for the lag effects: the time constant)
    columns: Callable[..., tuple[np.ndarray, np.ndarray]]  # (eq[, tau]) -> (X_upper, X_lower)
    to_parameters: Callable[..., dict[str, float]]  # (coef[, tau]) -> physical parameters
    to_model_effects: Callable[[dict[str, float]], dict[str, float]]
    admissible: Callable[[dict[str, float]], str | None]  # None, or why the fit is unphysical
    tau_grid: np.ndarray | None = None  # time constants tried [s] (lag effects)
    # "physical": to_model_effects gives RigParams effect fields (the plant); "measurement": it
    # gives MeasurementModel fields (how the angles are read)
    kind: str = "physical"

    @property
    def is_lag(self) -> bool:
        return self.tau_grid is not None

    @property
    def lags(self) -> np.ndarray:
        """The time constants tried [s] (``tau_grid`` of a lag effect)."""
        if self.tau_grid is None:
            raise ValueError(f"{self.name}: not a lag effect (no tau_grid)")
        return self.tau_grid


def _zeros(n: int, k: int) -> np.ndarray:
    return np.zeros((n, k))


def _lower_level(eq: RunEquations) -> np.ndarray:
    """-sgn (T_sl + S(|x3|)) per sample: the friction part that position and drift scale."""
    p = eq.params
    return -np.sign(eq.speed_l) * (p.lower_static + stribeck(p, np.abs(eq.speed_l)))


def reading_centre(eq: RunEquations, disk: str) -> np.ndarray:
    """The disk's angle at the middle of the count each reading is in [rad]: the encoder floors
    the angle to whole counts, so a reading lies half a count below the disk's angle on average
    (a phase of an effect locked to the angle, fitted against the readings themselves, came out
    half a count off, outside its interval at 1024 counts)."""
    theta = eq.theta_l if disk == "lower" else eq.theta_u
    return theta + 0.5 * eq.noise.step


def position_harmonics(theta: np.ndarray) -> list[np.ndarray]:
    """The basis of a position modulation, ``cos, -sin`` of ``theta`` and of ``2 theta``: its
    coefficients ``c`` give ``1 + a1 cos(theta + phi1) + a2 cos(2 theta + phi2)`` as ``1 + sum c_i
    h_i`` (see :func:`_position_parameters`)."""
    return [np.cos(theta), -np.sin(theta), np.cos(2 * theta), -np.sin(2 * theta)]


def _harmonics(eq: RunEquations, level: np.ndarray, theta: np.ndarray, disk: str) -> np.ndarray:
    return np.column_stack([eq.kernel(level * h, disk) for h in position_harmonics(theta)])


def _cols_position_lower(eq: RunEquations):
    xl = _harmonics(eq, _lower_level(eq), reading_centre(eq, "lower"), "lower")
    return _zeros(len(eq.upper), 4), xl


def _cols_position_upper(eq: RunEquations):
    p = eq.params
    level = np.where(eq.speed_u >= 0.0, -p.upper_static_pos, p.upper_static_neg)
    xu = _harmonics(eq, level, reading_centre(eq, "upper"), "upper")
    return xu, _zeros(len(eq.lower), 4)


def _position_parameters(prefix: str):
    def conv(coef, tau=None):
        a1, a2 = math.hypot(coef[0], coef[1]), math.hypot(coef[2], coef[3])
        return {
            f"{prefix}_position_amp_1": a1,
            f"{prefix}_position_phase_1": math.atan2(coef[1], coef[0]) % (2 * math.pi),
            f"{prefix}_position_amp_2": a2,
            f"{prefix}_position_phase_2": math.atan2(coef[3], coef[2]) % (2 * math.pi),
        }

    return conv


def _position_admissible(prefix: str):
    def check(par):
        total = par[f"{prefix}_position_amp_1"] + par[f"{prefix}_position_amp_2"]
        return None if total < 0.95 else f"|a1| + |a2| = {total:.3g} would make the friction change sign"

    return check


def _cols_string_damping(eq: RunEquations):
    twist = eq.theta_u - eq.theta_l
    xu = -eq.kernel_rate(twist, "upper")[:, None]
    xl = eq.kernel_rate(twist, "lower")[:, None]
    return xu, xl


def _cols_drift(eq: RunEquations):
    xl = eq.kernel(_lower_level(eq) * eq.t_rel, "lower")[:, None]
    return _zeros(len(eq.upper), 1), xl


def _cols_motor_lag(eq: RunEquations, tau: float):
    km = eq.params.motor_constant
    u = eq.u
    e = math.exp(-eq.dt / tau)
    # Motor torque of the lagged motor, exact for a zero-order-hold voltage, from its
    # steady value at the first sample.
    from scipy.signal import lfilter

    tm_next, _ = lfilter([1.0 - e], [1.0, -e], km * u, zi=[e * km * u[0]])
    tm = np.empty_like(u)
    tm[0] = km * u[0]
    tm[1:] = tm_next[:-1]
    xu = eq.kernel_lag(tm - km * u, tau, "upper")[:, None]
    return xu, _zeros(len(eq.lower), 1)


def _cols_friction_memory(eq: RunEquations, tau: float):
    from scipy.signal import lfilter

    p = eq.params
    speed = np.abs(eq.speed_l)
    e = math.exp(-eq.dt / tau)
    w_next, _ = lfilter([1.0 - e], [1.0, -e], speed, zi=[e * speed[0]])
    w = np.empty_like(speed)
    w[0] = speed[0]
    w[1:] = w_next[:-1]
    # the Stribeck part at the measured speed is the same for every tau: once per run and model
    cached = getattr(eq, "_stribeck_at_speed", None)
    if cached is None or cached[0] is not p or cached[1] is not eq.speed_l:
        cached = (p, eq.speed_l, stribeck(p, speed))
        eq._stribeck_at_speed = cached  # type: ignore[attr-defined]
    basis = -np.sign(eq.speed_l) * (stribeck(p, w) - cached[2])
    return _zeros(len(eq.upper), 1), eq.kernel(basis, "lower")[:, None]


# Thermal time constants of the friction-heating candidate [s]: the rise of its thermal
# state is fitted as a mix of these two lags of the dissipated power (linear; see
# _cols_temperature).
THERMAL_TIMES_S: tuple[float, float] = (40.0, 200.0)
# |kappa| [1/W] beyond which the heated friction would change sign at the rig's largest
# dissipated power (about 0.8 W at 5 V, braked rig): no such fit is physical.
MAX_FRICTION_HEATING = 1.0


def dissipated_power(eq: RunEquations) -> np.ndarray:
    """P = T_l(|x3|) |x3| [W] per sample: the nominal lower friction at the measured lower speed."""
    p = eq.params
    speed = np.abs(eq.speed_l)
    return (p.lower_static + stribeck(p, speed) + p.lower_viscous * speed) * speed


def thermal_state(eq: RunEquations, tau: float) -> np.ndarray:
    """Thermal state [W] per sample: :func:`dissipated_power` through tau Th' = P - Th from
    Th = 0 at the first sample (exact for P held over each sample interval)."""
    from scipy.signal import lfilter

    power = dissipated_power(eq)
    e = math.exp(-eq.dt / tau)
    th_next = lfilter([1.0 - e], [1.0, -e], power)
    th = np.empty_like(power)
    th[0] = 0.0
    th[1:] = th_next[:-1]
    return th


def thermal_trajectory(eq: RunEquations, params) -> np.ndarray:
    """The thermal state [W] per sample of a run under ``params`` (a rig with friction
    heating), for simulations started from the measured state: the lag of the dissipated
    power from the start of the recording plus the heat already there, ``Th0 exp(-t/tau)``,
    with ``Th0 >= 0`` fitted to the run's lower-disk equation error (least squares; the
    recording does not say how warm the contact was when it began)."""
    e = params.effects
    tau = e.thermal_time
    cold = params.replace(friction_heating=0.0, thermal_time=0.0)
    ref = RunEquations(eq.run, cold, eq.noise, eq.config)
    rise = thermal_state(ref, tau)
    decay = np.exp(-ref.t_rel / tau)
    level = _lower_level(ref)
    sigma = ref.lower.sigma
    x_rise = e.friction_heating * ref.kernel(level * rise, "lower") / sigma
    x_decay = e.friction_heating * ref.kernel(level * decay, "lower") / sigma
    den = float(x_decay @ x_decay)
    th0 = max(0.0, float(x_decay @ (ref.lower.z - x_rise)) / den) if den > 0.0 else 0.0
    return th0 * decay + rise


def _cols_temperature(eq: RunEquations):
    # A recording rarely starts with the contact cold: the rig turned before, and its state
    # at the first sample is unknown. Th(t) = Th0 exp(-t/tau) + (the lag of P from zero);
    # with Th0 a share of the run's mean power, that is the run's mean power (the part
    # heated before the recording) plus the rise from zero minus its decay. The columns:
    # level x mean power, and level x the rise through each of two lags.
    level = _lower_level(eq)
    mean_power = float(np.mean(dissipated_power(eq)))
    cols = [eq.kernel(level * mean_power, "lower")]
    cols += [eq.kernel(level * thermal_state(eq, tau), "lower") for tau in THERMAL_TIMES_S]
    return _zeros(len(eq.upper), 1 + len(THERMAL_TIMES_S)), np.column_stack(cols)


def _temperature_parameters(coef, tau=None) -> dict[str, float]:
    """kappa: the sum of the coefficients (the steady change per W); tau_th: the
    coefficient-weighted mean time constant of the rise (one lag of the same area and
    first moment); ``preheated``: the share of the steady change already there at the
    start of a recording."""
    coef = np.asarray(coef, dtype=float)
    kappa = float(np.sum(coef))
    rise = float(np.sum(coef[1:]))
    tau_th = float(np.dot(coef[1:], THERMAL_TIMES_S)) / rise if rise != 0.0 else 0.0
    return {
        "friction_heating": kappa,
        "thermal_time": tau_th,
        "preheated": float(coef[0]) / kappa if kappa != 0.0 else 0.0,
    }


def _temperature_admissible(par: dict[str, float]) -> str | None:
    kappa, tau = par["friction_heating"], par["thermal_time"]
    if kappa == 0.0 or tau == 0.0:
        return "no heating fitted"
    lo, hi = 0.5 * THERMAL_TIMES_S[0], 2.0 * THERMAL_TIMES_S[-1]
    if not lo <= tau <= hi:
        return (
            f"thermal_time = {tau:.3g} s is outside [{lo:g}, {hi:g}] s: the two lags pull in opposite "
            "directions, not one rise"
        )
    if not -0.25 <= par["preheated"] <= 1.25:
        return (
            f"the rise during the recording and the steady change have opposite signs "
            f"(preheated share {par['preheated']:.3g}, expected in [0, 1])"
        )
    if abs(kappa) >= MAX_FRICTION_HEATING:
        return f"|friction_heating| = {abs(kappa):.3g} 1/W would make the heated friction change sign"
    return None


def _nonneg(key: str):
    def check(par):
        return None if par[key] >= 0.0 else f"{key} = {par[key]:.3g} < 0 is not physical"

    return check


CANDIDATES: tuple[Candidate, ...] = (
    Candidate(
        name="position_friction_lower",
        title="position-dependent friction, lower disk",
        form="T_fl = sgn (T_sl + S(|x3|)) (1 + a1 cos(theta_l + phi1) + a2 cos(2 theta_l + phi2)) + b_l x3",
        signature="lower-disk residual following cos/sin of theta_l and 2 theta_l: lines at the lower disk's "
        "rotation rate and its double, moving with the voltage",
        n_params=4,
        columns=_cols_position_lower,
        to_parameters=_position_parameters("lower"),
        to_model_effects=lambda par: dict(par),
        admissible=_position_admissible("lower"),
    ),
    Candidate(
        name="position_friction_upper",
        title="position-dependent friction, upper disk",
        form="T_fu = sgn T_su (1 + a1 cos(theta_u + phi1) + a2 cos(2 theta_u + phi2)) + b_u x2",
        signature="upper-disk residual following cos/sin of theta_u and 2 theta_u",
        n_params=4,
        columns=_cols_position_upper,
        to_parameters=_position_parameters("upper"),
        to_model_effects=lambda par: dict(par),
        admissible=_position_admissible("upper"),
    ),
    Candidate(
        name="string_damping",
        title="torsional damping of the string",
        form="T_string = k_theta x1 + b_theta (x2 - x3)",
        signature="equal and opposite residuals on both disks proportional to the twist rate x2 - x3",
        n_params=1,
        columns=_cols_string_damping,
        to_parameters=lambda coef, tau=None: {"string_damping": float(coef[0])},
        to_model_effects=lambda par: {"string_damping": par["string_damping"]},
        admissible=_nonneg("string_damping"),
    ),
    Candidate(
        name="motor_inductance",
        title="rotor inductance (lag of the motor torque)",
        form="tau_m T_m' = k_m u - T_m, tau_m = L_r / (R_i + R_r)",
        signature="upper-disk residual decaying after each voltage step, proportional to the step",
        n_params=1,
        columns=_cols_motor_lag,
        to_parameters=lambda coef, tau=None: {"motor_lag": float(tau)},
        to_model_effects=lambda par: {"motor_lag": par["motor_lag"]},
        admissible=lambda par: None,
        tau_grid=np.geomspace(5e-4, 0.3, 28),
    ),
    Candidate(
        name="friction_memory",
        title="friction memory (frictional lag of the Stribeck part)",
        form="T_fl = sgn (T_sl + S(w)) + b_l x3, tau_f w' = |x3| - w",
        signature="lower-disk residual while the lower speed changes, of the sign of its acceleration",
        n_params=1,
        columns=_cols_friction_memory,
        to_parameters=lambda coef, tau=None: {"friction_lag": float(tau)},
        to_model_effects=lambda par: {"friction_lag": par["friction_lag"]},
        admissible=lambda par: None,
        tau_grid=np.geomspace(5e-3, 3.0, 28),
    ),
    Candidate(
        name="friction_drift",
        title="slow drift of the lower friction level",
        form="T_fl = sgn (T_sl + S(|x3|)) (1 + d t) + b_l x3, t from the start of the recording",
        signature="lower-disk residual growing linearly with time since the start of each run",
        n_params=1,
        columns=_cols_drift,
        to_parameters=lambda coef, tau=None: {"friction_drift": float(coef[0])},
        to_model_effects=lambda par: {"friction_drift": par["friction_drift"]},
        admissible=lambda par: None,
    ),
    Candidate(
        name="friction_temperature",
        title="temperature-dependent lower friction (heating by the dissipated power)",
        form="T_fl = sgn (T_sl + S(|x3|)) (1 + kappa Th) + b_l x3, tau_th Th' = |T_fl x3| - Th",
        signature="lower-disk residual following the friction level times the lagged power the lower "
        "friction dissipates: slow (tens to hundreds of seconds), larger in the faster runs, "
        "absent where the disk barely turns",
        n_params=1 + len(THERMAL_TIMES_S),
        columns=_cols_temperature,
        to_parameters=_temperature_parameters,
        to_model_effects=lambda par: {
            "friction_heating": par["friction_heating"],
            "thermal_time": par["thermal_time"],
        },
        admissible=_temperature_admissible,
    ),
)


def eccentricity_columns(eq: RunEquations, encoder: str) -> tuple[np.ndarray, np.ndarray]:
    """(X_upper, X_lower) [N m per rad of reading error]: the equation error's response at the
    windows of each disk to a reading error ``cos theta`` and ``sin theta`` of ``encoder``
    ("upper" or "lower"): on the disk whose encoder errs, its inertia, string, viscous and
    Stribeck terms of the error; on the other disk, the string's (the twist)."""
    p = eq.params
    theta = reading_centre(eq, encoder)
    speed = eq.speed_l if encoder == "lower" else eq.speed_u
    basis = [np.cos(theta), np.sin(theta)]
    rates = [-np.sin(theta) * speed, np.cos(theta) * speed]  # d/dt of the basis
    h2 = eq.h**2
    out: dict[str, np.ndarray] = {}
    for disk in ("upper", "lower"):
        w = eq.upper if disk == "upper" else eq.lower
        cols = []
        for e, de in zip(basis, rates, strict=True):
            g = eq.gather(e, w.centers) if len(w) else np.zeros((0, eq.offsets.size))
            if disk == encoder:
                if disk == "lower":
                    lin = (
                        p.lower_inertia * eq.w_d2
                        + p.string_stiffness * eq.w_tri
                        + p.lower_viscous * eq.w_rate
                    )
                    col = g @ lin / h2
                    slope = stribeck_slope(p, np.abs(eq.speed_l)) * np.sign(eq.speed_l)
                    col = col + w.sign * eq.kernel(slope * de, "lower")
                else:
                    b = np.where(w.sign > 0, p.upper_viscous_pos, p.upper_viscous_neg)
                    col = (p.upper_inertia * (g @ eq.w_d2) + p.string_stiffness * (g @ eq.w_tri)) / h2
                    col = col + b * (g @ eq.w_rate) / h2
            else:
                col = -p.string_stiffness * (g @ eq.w_tri) / h2
            cols.append(col)
        out[disk] = np.column_stack(cols) if len(w) else np.zeros((0, 2))
    return out["upper"], out["lower"]


def _eccentricity_parameters(disk: str):
    # e = c cos(theta) + s sin(theta) = a sin(theta + phi): c = a sin(phi), s = a cos(phi)
    def conv(coef, tau=None):
        return {
            f"{disk}_encoder_eccentricity": math.hypot(coef[0], coef[1]),
            f"{disk}_encoder_phase": math.atan2(coef[0], coef[1]) % (2 * math.pi),
        }

    return conv


def _eccentricity_admissible(disk: str):
    def check(par):
        a = par[f"{disk}_encoder_eccentricity"]
        if a >= MAX_ENCODER_ECCENTRICITY:
            return (
                f"{disk}_encoder_eccentricity = {a:.3g} rad >= {MAX_ENCODER_ECCENTRICITY:g} rad is no "
                "small once-per-revolution reading error"
            )
        return None

    return check


def _eccentricity(disk: str) -> Candidate:
    return Candidate(
        name=f"encoder_eccentricity_{disk}",
        title=f"eccentric {disk} encoder (once-per-revolution angle reading error)",
        form=f"theta_{disk[0]},read = theta_{disk[0]} + a sin(theta_{disk[0]} + phi): a measurement effect, no torque",
        signature=f"residual on both disks following the model's response to a reading error cos/sin of "
        f"theta_{disk[0]}: a line at the {disk} disk's rotation rate, largest where the {disk} disk "
        "accelerates",
        n_params=2,
        columns=lambda eq: eccentricity_columns(eq, disk),
        to_parameters=_eccentricity_parameters(disk),
        to_model_effects=lambda par: dict(par),
        admissible=_eccentricity_admissible(disk),
        kind="measurement",
    )


CANDIDATES = CANDIDATES + (_eccentricity("lower"), _eccentricity("upper"))


def candidate_names() -> list[str]:
    return [c.name for c in CANDIDATES]


# the fields of :class:`drill_env.params.ModelEffects` each library effect sets
EFFECT_FIELDS: dict[str, tuple[str, ...]] = {
    "position_friction_lower": (
        "lower_position_amp_1",
        "lower_position_phase_1",
        "lower_position_amp_2",
        "lower_position_phase_2",
    ),
    "position_friction_upper": (
        "upper_position_amp_1",
        "upper_position_phase_1",
        "upper_position_amp_2",
        "upper_position_phase_2",
    ),
    "string_damping": ("string_damping",),
    "motor_inductance": ("motor_lag",),
    "friction_memory": ("friction_lag",),
    "friction_drift": ("friction_drift",),
    "friction_temperature": ("friction_heating", "thermal_time"),
}


def model_effect_names(params) -> tuple[list[str], list[str]]:
    """(library effects switched on in ``params``, effect fields on that no library effect
    covers: the external torque)."""
    active = set(params.effects.active)
    named = [name for name, keys in EFFECT_FIELDS.items() if active & set(keys)]
    covered = {k for keys in EFFECT_FIELDS.values() for k in keys}
    return named, sorted(active - covered)


def model_effect_torques(eq: RunEquations) -> tuple[np.ndarray, np.ndarray]:
    """K[torque]/h^2 at the windows of each disk (upper, lower) [N m] of the library effects
    switched on in the run's model ``eq.params``: the part of the equation error that the
    model's effects explain. Each is its candidate's columns (:data:`CANDIDATES`) at the
    coefficients its parameters give (a lag effect: its columns at its time constant, which
    carry the effect whole; friction heating: its thermal state from the start of the
    recording, :func:`thermal_trajectory`)."""
    e = eq.params.effects
    tu, tl = np.zeros(len(eq.upper)), np.zeros(len(eq.lower))
    named, _ = model_effect_names(eq.params)
    for name in named:
        if name.startswith("position_friction_"):
            disk = name.rsplit("_", 1)[1]
            a1, p1 = getattr(e, f"{disk}_position_amp_1"), getattr(e, f"{disk}_position_phase_1")
            a2, p2 = getattr(e, f"{disk}_position_amp_2"), getattr(e, f"{disk}_position_phase_2")
            coef = np.array([a1 * math.cos(p1), a1 * math.sin(p1), a2 * math.cos(p2), a2 * math.sin(p2)])
            xu, xl = (_cols_position_lower if disk == "lower" else _cols_position_upper)(eq)
        elif name == "string_damping":
            coef = np.array([e.string_damping])
            xu, xl = _cols_string_damping(eq)
        elif name == "motor_inductance":
            coef = np.array([1.0])
            xu, xl = _cols_motor_lag(eq, e.motor_lag)
        elif name == "friction_memory":
            coef = np.array([1.0])
            xu, xl = _cols_friction_memory(eq, e.friction_lag)
        elif name == "friction_drift":
            coef = np.array([e.friction_drift])
            xu, xl = _cols_drift(eq)
        else:  # friction_temperature
            if e.thermal_time <= 0.0:
                continue  # no thermal state without a time constant (the simulator's too)
            th = thermal_trajectory(eq, eq.params)
            coef = np.array([e.friction_heating])
            xu = _zeros(len(eq.upper), 1)
            xl = eq.kernel(_lower_level(eq) * th, "lower")[:, None]
        tu = tu + xu @ coef
        tl = tl + xl @ coef
    return tu, tl


def with_model_effects(eq: RunEquations) -> RunEquations:
    """``eq`` with each window's residual less what the model's own library effects explain
    (:func:`model_effect_torques`): the equation error of the whole model, effects included.
    ``eq`` itself when its model has none."""
    import copy
    import dataclasses

    if not model_effect_names(eq.params)[0]:
        return eq
    tu, tl = model_effect_torques(eq)
    out = copy.copy(eq)  # shares everything but the windows' residuals
    out.upper = dataclasses.replace(eq.upper, residual=eq.upper.residual - tu)
    out.lower = dataclasses.replace(eq.lower, residual=eq.lower.residual - tl)
    return out
