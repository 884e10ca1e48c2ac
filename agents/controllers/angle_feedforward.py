"""LQI with adaptive feedforward locked to the lower disk's angle: rejects friction that
varies with where the bit is in its revolution, without a model of that variation.

The problem
-----------
The paper's rig has a once-per-revolution variation of the lower-disk friction (Sec. 4.1,
:class:`~drill_env.params.ModelEffects` ``lower_position_amp_1``): a torque
``d(theta_l) = a1 T(x3) cos(theta_l + phi1)`` (+ a second harmonic) on the lower disk. At a
steady lower-disk speed w* it is a sinusoid of frequency w* [rad/s], which for the braked
rig at 0.7-1.5 V (w* = 1-2.5 rad/s) is at or next to the torsional resonance
``sqrt(k_theta / J_l)`` = 1.55 rad/s: the LQI's damping of the mode does not stop it from
being driven. The motor acts on the upper disk and the friction on the lower one
(non-collocated): the disturbance cannot be cancelled where it enters, only through the
string, whose phase at w* decides the sign of any correction.

The design
----------
The feedforward is a sum of harmonics of the *measured* lower-disk angle theta_l (the
encoder count: the environment's ``lower_angle_sin``/``lower_angle_cos`` in observation
version 1, or the sum of the count differences ``lower_speed_mean * dt`` in version 0; the
two differ by a constant angle, which the adapted coefficients absorb)::

    u     = u_LQI + sum_h Re(C_h exp(j h theta_l(k)))                   h = 1, 2
    C_h  <- C_h - g_h e(k) exp(-j h theta_l(k)),  g_h = 2 mu / G_h,  mu = dt / adaptation_time

with ``e = lower_speed_mean - w*`` (the lower encoder counts over the period; its
periodic part is what the feedforward should remove) and ``G_h`` the *nominal closed-loop*
frequency response, at ``z = exp(j h w* dt)``, from a voltage added to the LQI's output to
the measured lower speed: the nominal rig linearised at the slip equilibrium of w*, sampled
with its zero-order hold and encoder chain (:func:`drill_env.agents.controllers.linear_model.sampled_rig`), closed
by the LQI's own update (probed by :func:`drill_env.agents.controllers.tuning.controller_matrices`). ``G_h``
carries the string's phase at the rotation frequency: the correction is pushed through the
string with the phase that cancels, not the one that would feed the mode. This is adaptive
feedforward cancellation (Bodson, Sacks & Khosla, *Harmonic generation in adaptive
feedforward cancellation schemes*, IEEE TAC 39(9), 1994; Bodson, *Rejection of periodic
disturbances of unknown and time-varying frequency*, Int. J. Adapt. Control Signal Process.
19, 2005) with the regressor in the angle domain, as in angle-domain repetitive and
harmonic control of rotating machines: the disturbance is locked to theta_l, so its phase is
exact however the speed varies, and a friction that is not locked to theta_l leaves the
coefficients at zero on average.

Stability
---------
While the lower disk turns at w* (theta_l(k) = w* k dt + const), the update is linear and
time invariant in ``W_h = C_h exp(j h theta_l)``::

    W_h(k+1) = exp(j h w* dt) (W_h(k) - g_h e(k)),   u_ff(k) = sum_h Re W_h(k),

an internal model of the harmonics h w* (Bodson et al. 1994 show the equivalence). The
closed loop of the linearised nominal rig, the LQI and this filter is an ordinary
discrete linear system; :func:`feedforward_closed_loop` builds it and :func:`design` reads
its decay rate. Averaging explains why it is stable: with the adaptation slow against the
closed loop's response at h w*, the coefficients see the steady-state error
``E_h = G_true C_h + D_h`` (``D_h``: the disturbance's share), and the update averages to
``C_h <- C_h - mu (G_true / G_h) (C_h + D_h / G_true)``: a first-order convergence with
time constant ``adaptation_time`` wherever ``Re(G_true / G_h) > 0``, i.e. the rig's phase
at h w* is within 90 deg of the nominal one. J_l +8 %, k_m -5 % and T_sl +10 % move it by
at most 7 deg at 0.7-1.5 V (:func:`phase_error`). Where ``|G_h|`` is small (the string
passes little of the motor's torque at h w*: high speeds, second harmonic) the gain 1/G_h
is large and acts on the torsional mode as well; averaging then needs a slower
adaptation, and it passes more of the encoder's quantisation noise. :func:`design`
therefore picks, per operating point and harmonic, the shortest of 10, 20, 40, 80 s for
which the exact linear loop keeps at least half of min(the LQI's decay rate, 1 / adaptation
time) and the lower-disk speed's noise from quantisation (as :mod:`drill_env.agents.controllers.tuning` bounds
the voltage's) grows by at most 30 %, and leaves a harmonic out where none does or where it
would not turn half a revolution per adaptation time (``h w* T < pi``, a drift rather than a
harmonic: with half a turn the regressor ``exp(-j h theta_l)`` changes sign, so a constant
error, which the LQI's integral removes, is not learnt as a harmonic). Half a turn, not a whole
one: at the lowest speeds a turn per adaptation time forced 40 s where 20 s is as stable, and
the braked rig's lower position friction at 0.3 V was still half uncancelled after 90 s
(suppression 0.55 against 0.91 with half a turn, README). The nominal loop is then stable at
every design point of the envelope (:func:`drill_env.agents.controllers.tuning.design_points`) of both
rigs; with the brake at 0.7-1.5 V the first
harmonic adapts in 10 s (the second in 10 s up to 1 V, 40 s at 1.25 V, not at 1.5 V),
decay rate 0.025-0.12 1/s against the LQI's 0.10-0.15 (``tests/test_angle_rejection.py``,
which also checks that the analysed matrix reproduces the controller's code on the
sampled rig).

Away from the linear regime: the adaptation starts after ``hold_decays`` = 2 time
constants 1/alpha of the LQI's loop (the switch-on transient, not locked to the angle,
would otherwise be learnt as a harmonic: on the nominal rig at 1.5 V it drove C_2 to volts
and the loop into stick-slip), sees the error clipped to +-0.25 w* (a sinusoidal error keeps
its phase, only its first steps shrink) and pauses while the amplifier is at its limit (the
error then says nothing about the coefficients). The LQI is unchanged, with the tuned gains
of ``configs/agents/controllers.yaml``; nothing here is tuned on a plant other than the
nominal model.

Variable step (option ``variable_step``, off by default)
-------------------------------------------------------
Where nothing is locked to the angle the coefficients random-walk on the error's noise
(encoder quantisation, angle noise) and feed it back at the rotation frequency. With the
option each harmonic's step is scaled by how significant the error's harmonic content is,
in the line of robust variable-step-size LMS (Aboulnasr & Mayyas, IEEE TSP 45(3), 1997:
a step driven by a time-averaged error correlation, insensitive to uncorrelated noise;
Kwong & Johnston, IEEE TSP 40(7), 1992) with the harmonic regressor in place of the
error's lagged copy::

    P_h <- P_h + lam_h (e exp(-j h theta_l) - P_h)
    N_h <- N_h + lam_h (r^2 - N_h),   r = e - sum_h 2 Re(P_h exp(j h theta_l))
    n_h = N_h lam_h / (2 - lam_h),    s_h = |P_h|^2 / (|P_h|^2 + c n_h)
    C_h <- C_h - s_h g_h e(k) exp(-j h theta_l(k))

with ``lam_h = dt / T_d``, ``T_d = averaging_times`` (0.5) adaptation times of the harmonic
and ``c = significance`` (2). ``n_h`` is the variance ``P_h`` would have were the error
white noise of the mean square of r, the error less the harmonics seen so far (else the
first harmonic's error, while it is learnt, hides the second): a harmonic well above it
adapts at the designed rate (``s_h`` near 1), noise alone much more slowly. ``C_h`` itself
is not scaled: the feedforward keeps what it learned once the error's harmonic is
cancelled. The averages move only while the coefficients may (after the hold, off the
voltage limit).

T_d is short, half an adaptation time, against the "few adaptation times" of a slow
significance test: while a harmonic is learnt its error phasor turns (the second harmonic
first learns part of the switch-on transient, then unlearns it), its long average passes
near zero and the gate shut the adaptation where it was needed. On a pure lower position
friction (a1 = 0.15, 60 s runs, seed 3) and with 3 mrad angle noise on the nominal rig
(seeds 5, 2), T_d = 0.25-2 and c = 1-4 were tried; 0.5 and 2 halve the feedforward's RMS on
the noise for at most +21 % of residual amplitude on the friction. Not better in every cell
of the plant family's quick grid (README), it is an option, off by default.

Stability: the averaged argument above holds for any gain in (0, g_h] (convergence needs
``Re(G_true / G_h) > 0``, not a gain size), and the exact linear loop with the gains frozen
at ``s g_h`` is stable for s over (0, 1] at every design point, decaying at s / T of the
slowest harmonic where s is small (``tests/test_angle_rejection.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import solve_discrete_lyapunov

from drill_env.agents.controllers.base import ControllerSpec
from drill_env.agents.controllers.effect_feedforward import EffectFeedforward, has_position_effect
from drill_env.agents.controllers.linear_model import (
    SampledRig,
    decay_rate,
    design_point,
    measurement_noise,
    sampled_rig,
)
from drill_env.agents.controllers.lqi import LQI
from drill_env.agents.controllers.lqi_loop import _LOWER_MEAN, _loop, _response
from drill_env.agents.controllers.pi import _gain
from drill_env.params import RigParams

__all__ = [
    "LQIAngleFeedforward",
    "FeedforwardDesign",
    "adaptation_gains",
    "design",
    "feedforward_closed_loop",
    "phase_error",
    "step_scale",
    "voltage_to_lower_speed",
]

HARMONICS = (1, 2)  # of the lower disk's revolution
ADAPTATION_TIME = 10.0  # [s]
LADDER = 4  # adaptation times tried: ADAPTATION_TIME * 2**k, k < LADDER
HOLD_DECAYS = 2.0  # the adaptation starts after this many time constants 1/alpha of rig + LQI
ERROR_CLIP = 0.25  # the error the adaptation sees is clipped to +-ERROR_CLIP * w*
AVERAGING_TIMES = 0.5  # variable step: T_d of the harmonic's significance, in adaptation times
SIGNIFICANCE = 2.0  # variable step: c, how far above its noise the error's harmonic must be
NOISE_RATIO = 1.3  # the feedforward may raise the quantisation noise on x3 by this factor
MIN_TURNS = 0.5  # a harmonic is adapted only if it turns this many revolutions per adaptation time


def voltage_to_lower_speed(
    params: RigParams,
    speed: float,
    lqi: LQI,
    harmonics: tuple[int, ...] = HARMONICS,
    rig: SampledRig | None = None,
) -> np.ndarray:
    """G_h [rad/s per V]: the closed-loop (rig + ``lqi``) frequency response from a voltage
    added to the LQI's output to the measured lower speed (``lower_speed_mean``) at
    ``h * speed`` rad/s for each harmonic h, the rig linearised at the slip equilibrium of
    lower-disk speed ``speed`` [rad/s] of ``params``."""
    dt = lqi.spec.control_dt
    if rig is None:
        rig = sampled_rig(params, design_point(params, speed=speed), dt, lqi.spec.sensors)
    A, b, c, _ = _loop(rig, lqi)
    return np.array([_response(A, b, c, h * rig.speed, dt) for h in harmonics])


def feedforward_closed_loop(
    rig: SampledRig, lqi: LQI, g: np.ndarray, harmonics: tuple[int, ...] = HARMONICS
) -> np.ndarray:
    """The transition matrix of rig + LQI + the feedforward's linear-time-invariant form
    (module docstring) at the rig's equilibrium, the lower disk turning at ``rig.speed``;
    ``g`` the complex adaptation gains g_h (0: harmonic not adapted, left out)."""
    return _feedforward_matrices(rig, lqi, g, harmonics)[0]


def _feedforward_matrices(
    rig: SampledRig, lqi: LQI, g: np.ndarray, harmonics: tuple[int, ...] = HARMONICS
) -> tuple[np.ndarray, np.ndarray]:
    """(M, B): :func:`feedforward_closed_loop` and the input of the measurement noise on the
    six measured entries (the feedforward reads the lower_speed_mean one)."""
    A, b, c, Bn = _loop(rig, lqi)
    on = [(h, gh) for h, gh in zip(harmonics, np.asarray(g, dtype=complex), strict=True) if gh != 0]
    n, m = A.shape[0], 2 * len(on)
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    B = np.zeros((n + m, Bn.shape[1]))
    B[:n] = Bn
    for i, (h, gh) in enumerate(on):
        r, q = n + 2 * i, n + 2 * i + 1  # Re W_h, Im W_h
        M[:n, r] += b  # u_ff = sum Re W_h
        phi = h * rig.speed * rig.dt
        rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
        # W <- rot (W - g e), e = c x
        M[[r, q], r : q + 1] = rot
        M[[r, q], :n] = -rot @ np.outer([gh.real, gh.imag], c)
        B[[r, q], _LOWER_MEAN] = -rot @ np.array([gh.real, gh.imag])
    return M, B


def _lower_speed_noise(M: np.ndarray, B: np.ndarray, sigma: np.ndarray) -> float:
    """Std [rad/s] of the lower-disk speed x3 from measurement noise of std ``sigma`` (inf if
    the loop is unstable)."""
    if np.max(np.abs(np.linalg.eigvals(M))) >= 1.0:
        return math.inf
    X = solve_discrete_lyapunov(M, B @ np.diag(sigma**2) @ B.T)
    return math.sqrt(max(float(X[2, 2]), 0.0))


def adaptation_gains(G: np.ndarray, dt: float, adaptation_times: np.ndarray) -> np.ndarray:
    """g_h = 2 mu_h / G_h with mu_h = dt / adaptation_time_h; 0 where the time is inf."""
    G = np.asarray(G, dtype=complex)
    T = np.broadcast_to(np.asarray(adaptation_times, dtype=float), G.shape)
    out = np.zeros(G.shape, dtype=complex)
    on = np.isfinite(T)
    out[on] = 2.0 * (dt / T[on]) / G[on]
    return out


@dataclass(frozen=True)
class FeedforwardDesign:
    """The feedforward at one operating point of the nominal model (see :func:`design`)."""

    speed: float  # [rad/s] w*, the lower disk's target speed
    response: np.ndarray  # G_h [rad/s per V], complex, per harmonic
    adaptation_time: np.ndarray  # [s] per harmonic; inf: not adapted
    gains: np.ndarray  # g_h [V s/rad], complex
    lqi_decay_rate: float  # [1/s] rig + LQI
    decay_rate: float  # [1/s] rig + LQI + feedforward
    noise_ratio: float  # [-] std of x3 from encoder quantisation, with / without feedforward


def design(
    params: RigParams,
    speed: float,
    lqi: LQI,
    adaptation_time: float = ADAPTATION_TIME,
    harmonics: tuple[int, ...] = HARMONICS,
) -> FeedforwardDesign:
    """The feedforward's adaptation at lower-disk speed ``speed`` [rad/s] on ``params``.

    Harmonic by harmonic, the shortest of ``adaptation_time * 2**k`` (k = 0..3) for which the
    exact linear loop (rig + LQI + the harmonics chosen so far + this one) keeps a decay rate
    of at least half of min(the LQI's, 1 / adaptation time) and raises the lower-disk speed's
    noise from encoder quantisation (:func:`drill_env.agents.controllers.linear_model.measurement_noise`, through
    a discrete Lyapunov equation as in :mod:`drill_env.agents.controllers.tuning`) by at most ``NOISE_RATIO``,
    among those in which the harmonic turns at least half a revolution (``h w* T >= pi``,
    :data:`MIN_TURNS`); none: the harmonic is not adapted there. (Where |G_h| is small, a fast
    adaptation needs a large gain 1/G_h that acts on the torsional mode and passes the noise
    too.)
    """
    dt = lqi.spec.control_dt
    rig = sampled_rig(params, design_point(params, speed=speed), dt, lqi.spec.sensors)
    A, b, c, Bn = _loop(rig, lqi)
    G = np.array([_response(A, b, c, h * rig.speed, dt) for h in harmonics])
    alpha0 = decay_rate(A, dt)
    sigma = measurement_noise(lqi.spec.sensors, dt)
    noise0 = _lower_speed_noise(A, Bn, sigma)
    times = np.full(len(harmonics), math.inf)
    alpha, ratio = alpha0, 1.0
    for i in range(len(harmonics) if alpha0 > 0 else 0):  # nothing to add to an unstable loop
        for k in range(LADDER):
            trial = times.copy()
            trial[i] = adaptation_time * 2.0**k
            if harmonics[i] * rig.speed * trial[i] < MIN_TURNS * 2.0 * math.pi:
                continue  # not half a period of the harmonic per adaptation time: a drift, not a harmonic
            M, B = _feedforward_matrices(rig, lqi, adaptation_gains(G, dt, trial), harmonics)
            a, r = decay_rate(M, dt), _lower_speed_noise(M, B, sigma) / noise0
            if a >= 0.5 * min(alpha0, 1.0 / trial[i]) and r <= NOISE_RATIO:
                times, alpha, ratio = trial, a, r
                break
    return FeedforwardDesign(
        speed=float(rig.speed),
        response=G,
        adaptation_time=times,
        gains=adaptation_gains(G, dt, times),
        lqi_decay_rate=alpha0,
        decay_rate=alpha,
        noise_ratio=ratio,
    )


def phase_error(nominal: RigParams, true: RigParams, speed: float, lqi: LQI) -> np.ndarray:
    """The angle of G_true / G_nominal [rad] per harmonic at lower-disk speed ``speed``: the
    averaged adaptation converges while it is within +-pi/2."""
    return np.angle(voltage_to_lower_speed(true, speed, lqi) / voltage_to_lower_speed(nominal, speed, lqi))


def step_scale(
    harmonic_content: np.ndarray, noise: np.ndarray, significance: float = SIGNIFICANCE
) -> np.ndarray:
    """s_h = |P_h|^2 / (|P_h|^2 + c n_h) in [0, 1]: the variable step's factor on g_h for the
    error's averaged harmonic content P_h (complex) and the variance n_h of that average
    were the error white noise (0 where both are 0: nothing seen yet)."""
    p2 = np.abs(harmonic_content) ** 2
    den = p2 + significance * noise
    return np.where(den > 0, p2 / np.where(den > 0, den, 1.0), 0.0)


def _flag(name: str, value: Any) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name}: expected true or false, got {value!r}")
    return bool(value)


class LQIAngleFeedforward(LQI):
    """The tuned LQI plus adaptive feedforward on harmonics of the lower disk's measured
    angle (see the module docstring).

    Args:
        spec: the environment's :class:`~drill_env.agents.controllers.base.ControllerSpec`.
        adaptation_time: time constant of the averaged adaptation [s], > 0 (the shortest
            one :func:`design` tries at each operating point).
        hold_decays: the adaptation starts after this many time constants of the LQI's
            loop, >= 0.
        error_clip: the error the adaptation sees is clipped to +- this times w*, > 0.
        variable_step: scale each harmonic's gain by how far the error's harmonic content
            stands above its noise (module docstring, *Variable step*); off by default.
        averaging_times: T_d of the variable step, in the harmonic's adaptation times, > 0.
        significance: c of the variable step, > 0.
        **lqi_gains: the LQI's gains (:class:`~drill_env.agents.controllers.lqi.LQI`).
    """

    name = "lqi_angle_ff"
    harmonics = HARMONICS
    # LQI (6), the lower angle [rad], then per harmonic Re C_h, Im C_h [V], then per
    # harmonic Re g_h, Im g_h (constant per episode, scheduled on w* like K), then the time
    # left before the adaptation starts [s]; then the variable step's: per harmonic
    # Re P_h, Im P_h [rad/s], per harmonic the average of e^2 [rad^2/s^2] and its weight
    # dt / T_d (constant per episode; 0 with the variable step off)
    state_size = 6 + 1 + 4 * len(HARMONICS) + 1 + 4 * len(HARMONICS)
    # constructor arguments a gains file may set under presets.<preset>.lqi_angle_ff.options
    OPTIONS = (
        "adaptation_time",
        "hold_decays",
        "error_clip",
        "variable_step",
        "averaging_times",
        "significance",
    )

    @classmethod
    def check_options(cls, options: Any, where: str = "options") -> dict[str, Any]:
        """``options`` (a gains file's ``lqi_angle_ff.options``) checked without building the
        controller: a mapping of :data:`OPTIONS` to allowed values; a ValueError naming
        ``where.<option>`` and the allowed range otherwise."""
        if not isinstance(options, dict) or not set(options) <= set(cls.OPTIONS):
            raise ValueError(f"{where}: expected a mapping of {list(cls.OPTIONS)}, got {options!r}")
        for name, value in options.items():
            if name == "variable_step":
                _flag(f"{where}.variable_step", value)
            else:
                _gain(f"{where}.{name}", value, positive=name != "hold_decays")
        return dict(options)

    def __init__(
        self,
        spec: ControllerSpec,
        adaptation_time: float = ADAPTATION_TIME,
        hold_decays: float = HOLD_DECAYS,
        error_clip: float = ERROR_CLIP,
        variable_step: bool = False,
        averaging_times: float = AVERAGING_TIMES,
        significance: float = SIGNIFICANCE,
        **lqi_gains: Any,
    ):
        super().__init__(spec, **lqi_gains)
        self.lqi = LQI(spec, **lqi_gains)  # the feedback alone: what G_h is computed with
        # an effect the design model names (a position friction): its feedforward, an input
        # added to the feedback like the adaptive one (drill_env.agents.controllers.effect_feedforward)
        self.effect = EffectFeedforward(spec, self.lqi) if has_position_effect(spec.effects) else None
        self.adaptation_time = _gain("adaptation_time", adaptation_time, positive=True)
        self.hold_decays = _gain("hold_decays", hold_decays)
        self.error_clip = _gain("error_clip", error_clip, positive=True)
        self.variable_step = _flag("variable_step", variable_step)
        self.averaging_times = _gain("averaging_times", averaging_times, positive=True)
        self.significance = _gain("significance", significance, positive=True)
        nh = len(self.harmonics)
        self._hold = 7 + 4 * nh  # state index of the time left before the adaptation starts
        self._vs = self._hold + 1  # first state index of the variable step's entries
        names = spec.observation_names
        self._angle = (
            (spec.index("lower_angle_sin"), spec.index("lower_angle_cos"))
            if "lower_angle_sin" in names and "lower_angle_cos" in names
            else None
        )
        self._designs: dict[float, FeedforwardDesign] = {}

    def redesigned(self, spec: ControllerSpec) -> LQIAngleFeedforward:
        """The same controller (the LQI's gains, the feedforward's options) designed on another
        spec's model."""
        return LQIAngleFeedforward(
            spec,
            adaptation_time=self.adaptation_time,
            hold_decays=self.hold_decays,
            error_clip=self.error_clip,
            variable_step=self.variable_step,
            averaging_times=self.averaging_times,
            significance=self.significance,
            voltage_scale=self.voltage_scale,
            speed_rel=self.speed_rel,
            speed_min=self.speed_min,
            integral_time=self.integral_time,
            anti_windup=self.anti_windup,
        )

    def design(self, speed: float) -> FeedforwardDesign:
        """The feedforward's design at a target speed [rad/s] (cached)."""
        w = float(speed)
        if w not in self._designs:
            self.gain(w)  # validates the speed
            self._designs[w] = design(self.spec.params, w, self.lqi, self.adaptation_time, self.harmonics)
        return self._designs[w]

    def _lower_angle(self, y: np.ndarray, state: np.ndarray) -> np.ndarray:
        if self._angle is not None:
            return np.arctan2(y[:, self._angle[0]], y[:, self._angle[1]])
        return state[:, 6] + self.spec.control_dt * y[:, self._i_lower_mean]

    def initial_state(self, y: np.ndarray) -> np.ndarray:
        s = super().initial_state(y)  # the LQI's entries, zeros after them
        nh = len(self.harmonics)
        for i, w in enumerate(y[:, self._i_target]):
            d = self.design(w)
            s[i, 7 + 2 * nh : 7 + 4 * nh : 2] = d.gains.real
            s[i, 8 + 2 * nh : 7 + 4 * nh : 2] = d.gains.imag
            s[i, self._hold] = self.hold_decays / max(d.lqi_decay_rate, 1e-3)
            if self.variable_step:
                T_d = self.averaging_times * d.adaptation_time  # inf: harmonic not adapted
                s[i, self._vs + 3 * nh : self._vs + 4 * nh] = self.spec.control_dt / T_d
        if self._angle is None:
            s[:, 6] = -self.spec.control_dt * y[:, self._i_lower_mean]  # theta = 0 at the start
        return s

    def _harmonics(self, y: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(theta_l (n,), C_h (n, nh), exp(j h theta_l) (n, nh)) for observations ``y`` in ``state``."""
        nh = len(self.harmonics)
        theta = self._lower_angle(y, state)
        coef = state[:, 7 : 7 + 2 * nh]
        C = coef[:, 0::2] + 1j * coef[:, 1::2]
        return theta, C, np.exp(1j * np.outer(theta, self.harmonics))

    def feedforward(self, y: np.ndarray, state: np.ndarray) -> np.ndarray:
        """u_ff [V] (n,): the adaptive feedforward's share of the voltage :meth:`control`
        requests for observations ``y`` (SI) in ``state`` (the state :meth:`control` is called
        with, episode starts already reset); the rest of the request is the LQI's feedback."""
        _, C, rot = self._harmonics(y, state)
        return np.sum((C * rot).real, axis=1)

    def control(self, y: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nh = len(self.harmonics)
        theta, C, rot = self._harmonics(y, state)
        g = state[:, 7 + 2 * nh : 7 + 4 * nh : 2] + 1j * state[:, 8 + 2 * nh : 7 + 4 * nh : 2]
        u_ff = np.sum((C * rot).real, axis=1)
        if self.effect is not None:
            u_ff = u_ff + self.effect.voltage(y)
        u, out, u_req = self._step(y, state, u_ff)
        w = y[:, self._i_target]
        e = np.clip(y[:, self._i_lower_mean] - w, -self.error_clip * w, self.error_clip * w)
        # adapt after the hold and off the voltage limit
        free = ((u_req == u) & (state[:, self._hold] <= 0.0))[:, None]
        step = g * e[:, None] * np.conj(rot)
        if self.variable_step:
            step = step * self._variable_step(e, rot, free, state, out)
        C_next = C - np.where(free, step, 0.0)
        out[:, self._hold] = np.maximum(state[:, self._hold] - self.spec.control_dt, 0.0)
        out[:, 6] = theta
        out[:, 7 : 7 + 2 * nh : 2] = C_next.real
        out[:, 8 : 8 + 2 * nh : 2] = C_next.imag
        return u, out

    def _variable_step(
        self, e: np.ndarray, rot: np.ndarray, free: np.ndarray, state: np.ndarray, out: np.ndarray
    ) -> np.ndarray:
        """s_h (n, nh) for error ``e`` and exp(j h theta_l) ``rot``; writes the updated
        averages P_h and e^2 into ``out`` (they move only while the coefficients may)."""
        nh, v = len(self.harmonics), self._vs
        lam = state[:, v + 3 * nh : v + 4 * nh]
        P = state[:, v : v + 2 * nh : 2] + 1j * state[:, v + 1 : v + 2 * nh : 2]
        e2 = state[:, v + 2 * nh : v + 3 * nh]
        lam = np.where(free, lam, 0.0)
        # the noise is what the harmonics seen so far leave of the error: the first
        # harmonic's error, while it is learnt, must not hide the second
        noise = e - np.sum(2.0 * (P * rot).real, axis=1)
        P = P + lam * (e[:, None] * np.conj(rot) - P)
        e2 = e2 + lam * (noise[:, None] ** 2 - e2)
        out[:, v : v + 2 * nh : 2] = P.real
        out[:, v + 1 : v + 2 * nh : 2] = P.imag
        out[:, v + 2 * nh : v + 3 * nh] = e2
        # variance of the average of white noise of variance e2: e2 lam / (2 - lam)
        return step_scale(P, e2 * lam / (2.0 - lam), self.significance)

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d.update(
            name=self.name,
            adaptation_time=self.adaptation_time,
            hold_decays=self.hold_decays,
            error_clip=self.error_clip,
        )
        if self.variable_step:  # off: described as before the option existed
            d.update(variable_step=True, averaging_times=self.averaging_times, significance=self.significance)
        return d
