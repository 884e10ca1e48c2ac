"""Compiled hot path of the environments: one call integrates a control period of a rig,
samples its sensors at the sensor rate and computes the reward terms.

Three clocks (see :mod:`drill_env.simulator`): the adaptive integration clock of the
exact simulator, the sensor clock (``Ts``, 1 kHz by default) at which the dense solution
is sampled and fed through :mod:`drill_env.sensors`, and the control clock
(``control_dt = n_sub * Ts``) at which the voltage changes (zero-order hold). Time is
kept as an integer count of sensor ticks, so sample instants never drift.

The single-rig functions are called directly by :class:`DrillStringEnv` and in a loop by
:class:`DrillStringVectorEnv`, so N single environments and one vector environment of N
rigs run the same compiled code and agree bit for bit.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from drill_env import _layout as L
from drill_env._numba import JIT, JIT_ALLOC
from drill_env.kernel import N_STATS, ST_H, WORK_ROWS, run_ws
from drill_env.sensors import (
    C_ANGLE_NOISE,
    C_INV_RES,
    C_RES,
    C_SPEED_NOISE,
    C_TS,
    S_QL,
    S_QU,
    S_VL,
    S_VU,
    sensor_noise,
    sensor_reset,
    sensor_sample,
)

# Cached on disk in a directory keyed by the package's source (drill_env._cache), so a
# change to the kernel cannot leave a stale copy compiled into these functions.
_JIT = JIT_ALLOC
# Functions that allocate nothing run without reference counting (see drill_env.kernel).
_NO_NRT = JIT


# -- per-rig episode scalars ------------------------------------------------------------------
EP_TICK = 0  # sensor ticks since the rig was switched on (time = tick * Ts)
EP_TICK0 = 1  # tick at which the episode started
EP_H = 2  # step size proposed by the integrator, carried across control periods [s]
EP_U = 3  # last applied voltage [V]
EP_TARGET = 4  # target lower-disk speed [rad/s]
EP_UNOM = 5  # nominal voltage of the operating point [V]
EP_MEAN_U = 6  # upper encoder speed averaged over the last control period [rad/s]
EP_MEAN_L = 7  # lower encoder speed averaged over the last control period [rad/s]
EP_STATUS = 8  # kernel status of the last call (0 = ok)
# The integrated speed error of the lower disk (observation v1) is measured from a base:
EP_INT_TICK0 = 9  # tick t0 of the base: the episode start, re-based when the target changes
EP_INT_QL0 = 10  # lower encoder reading at t0 [rad]
EP_INT_TARGET = 11  # target speed the base was taken for [rad/s]
NEP = 12

# -- environment configuration (shared by all rigs of an env) ------------------------------------
EC_RTOL = 0
EC_ATOL = 1
EC_NSUB = 2  # sensor samples per control period
EC_W_TRACK = 3
EC_W_STICK = 4
EC_W_OSC = 5
EC_W_EFFORT = 6
EC_SPEED_REF = 7  # floor of the speed that normalises the reward terms [rad/s]
EC_VMAX = 8  # amplifier limit [V]
EC_SETTLE = 9  # control periods run at the end of an open-loop warm-up to settle the sensors
EC_MAX_STEPS = 10  # integration step cap per control period
EC_OBS_VERSION = 11  # observation version: 0 (NOBS_V0 entries) or 1 (NOBS entries)
EC_INT_BOUND = 12  # clip bound of the integrated lower speed error [rad]
EC_TRACK_ABS = (
    13  # tracking term: 0 ((x3 - w*) / max(w*, EC_SPEED_REF))^2 (up to v2); 1 |x3 - w*| / EC_SPEED_REF (v3)
)
EC_W_INTEGRAL = 14  # weight of the integral term (0 in every registered version)
EC_W_OVERDRIVE = 15  # weight of the overdrive term (0 in every registered version)
EC_SCALE = 16  # NOBS observation divisors (all 1 for physical units; entries beyond the version's unused)
NOBS_V0 = 8  # entries of observation version 0
NOBS = 13  # entries of observation version 1 (the largest): the v0 entries, then the encoder extras
NEC = EC_SCALE + NOBS

# -- observation entries -----------------------------------------------------------------------
OB_LOWER_SPEED, OB_UPPER_SPEED, OB_TWIST, OB_LOWER_MEAN, OB_UPPER_MEAN, OB_VOLTAGE, OB_TARGET, OB_UNOM = (
    range(NOBS_V0)
)
# version 1 only: encoder angles within the revolution and the integrated lower speed error
OB_LOWER_SIN, OB_LOWER_COS, OB_UPPER_SIN, OB_UPPER_COS, OB_LOWER_ERR_INT = range(NOBS_V0, NOBS)


def n_obs(version: int) -> int:
    """Length of the observation of a version (0 or 1)."""
    return NOBS_V0 if version == 0 else NOBS


# -- per-step outputs ----------------------------------------------------------------------------
O_TRACK, O_STICK, O_OSC, O_EFFORT, O_REWARD, O_STATUS = range(6)
O_TRUE = 6  # twist, upper speed, lower speed, upper angle, lower angle (true values)
O_UPPER_STUCK = 11
O_LOWER_STUCK = 12
O_INT_CLIPPED = 13  # 1 when the integrated lower speed error was clipped to its bound (version 1)
O_INTEGRAL = 14  # reward term: |integrated lower speed error| at the step's end [revolutions]
O_OVERDRIVE = 15  # reward term: voltage requested beyond the amplifier's limit / that limit
NOUT = 16
# the integral term saturates at this many revolutions: an angle the bit cannot win back (at the
# amplifier's limit) then costs the same whatever the voltage asked for
INTEGRAL_TERM_CAP = 0.5
# where each reward term (config.REWARD_NAMES, in that order) is in the per-step outputs
REWARD_SLOTS = (O_TRACK, O_STICK, O_OSC, O_EFFORT, O_INTEGRAL, O_OVERDRIVE)
N_TRUE = 5

# -- start states --------------------------------------------------------------------------------
START_REST, START_EQUILIBRIUM, START_OPEN_LOOP = 0, 1, 2


@nb.njit(**_JIT)
def workspace(n):
    """Scratch arrays for one control period of ``n`` sensor samples: sample times, noise
    (zero unless a rig's chain is noisy; ws[10][0] = 1 while it holds noise), the kernel's
    segment, event and statistics arrays. A batch reuses one for all rigs."""
    return (
        np.empty(n),
        np.zeros((n, 4)),
        np.empty(2),
        np.empty(1),
        np.empty(1),
        np.empty(1, dtype=np.int64),
        np.empty(1, dtype=np.int64),
        np.empty(1, dtype=np.int64),
        np.empty((1, L.NY)),
        np.zeros(N_STATS),
        np.zeros(1),
        np.empty((WORK_ROWS, L.NY)),
    )


@nb.njit(**_NO_NRT)
def _integrate(p, y, modes, t0, t1, u, t_out, ybuf, mbuf, ubuf, ep, ecfg, ws):
    seg_t = ws[2]
    seg_u = ws[3]
    stats = ws[9]
    seg_t[0] = t0
    seg_t[1] = t1
    seg_u[0] = u
    status = run_ws(
        p,
        y,
        modes,
        (seg_t, seg_u, False, np.inf),  # a zero-order hold, no voltage limit
        None,  # no input function
        (ecfg[EC_RTOL], ecfg[EC_ATOL], ep[EP_H], int(ecfg[EC_MAX_STEPS])),
        (t_out, ybuf, mbuf, ubuf),
        (ws[4], ws[5], ws[6], ws[7], ws[8]),
        stats,
        ws[11],
    )
    ep[EP_H] = stats[ST_H]
    return status


@nb.njit(**_NO_NRT)
def _encoder_angle(q, scfg):
    """Position within the revolution [rad, in [0, 2 pi)] of the encoder reading ``q``:
    (counts mod N) * 2 pi / N from the whole count, so it does not degrade as ``q`` grows;
    ideal (unquantised) angles are reduced modulo 2 pi."""
    res = scfg[C_RES]
    if res > 0.0:
        n = math.floor(2.0 * math.pi * scfg[C_INV_RES] + 0.5)  # counts per revolution
        c = math.floor(q * scfg[C_INV_RES] + 0.5)  # q is a whole number of counts
        return (c - n * math.floor(c / n)) * res
    return q - 2.0 * math.pi * math.floor(q / (2.0 * math.pi))


@nb.njit(**_NO_NRT)
def _lower_angle_lost(ep, scfg, sst):
    """theta_l_enc(t) - theta_l_enc(t0) - w* (t - t0) [rad], exact in the encoder readings: the
    integrated lower speed error of observation version 1 and of the reward's integral term."""
    return (sst[S_QL] - ep[EP_INT_QL0]) - ep[EP_TARGET] * ((ep[EP_TICK] - ep[EP_INT_TICK0]) * scfg[C_TS])


@nb.njit(**_NO_NRT)
def _write_obs(y, ep, ecfg, scfg, sst, obs, out):
    obs[OB_LOWER_SPEED] = sst[S_VL] / ecfg[EC_SCALE + OB_LOWER_SPEED]
    obs[OB_UPPER_SPEED] = sst[S_VU] / ecfg[EC_SCALE + OB_UPPER_SPEED]
    obs[OB_TWIST] = (sst[S_QU] - sst[S_QL]) / ecfg[EC_SCALE + OB_TWIST]
    obs[OB_LOWER_MEAN] = ep[EP_MEAN_L] / ecfg[EC_SCALE + OB_LOWER_MEAN]
    obs[OB_UPPER_MEAN] = ep[EP_MEAN_U] / ecfg[EC_SCALE + OB_UPPER_MEAN]
    obs[OB_VOLTAGE] = ep[EP_U] / ecfg[EC_SCALE + OB_VOLTAGE]
    obs[OB_TARGET] = ep[EP_TARGET] / ecfg[EC_SCALE + OB_TARGET]
    obs[OB_UNOM] = ep[EP_UNOM] / ecfg[EC_SCALE + OB_UNOM]
    if ecfg[EC_OBS_VERSION] >= 1.0:
        al = _encoder_angle(sst[S_QL], scfg)
        au = _encoder_angle(sst[S_QU], scfg)
        obs[OB_LOWER_SIN] = math.sin(al)
        obs[OB_LOWER_COS] = math.cos(al)
        obs[OB_UPPER_SIN] = math.sin(au)
        obs[OB_UPPER_COS] = math.cos(au)
        e = _lower_angle_lost(ep, scfg, sst)
        bound = ecfg[EC_INT_BOUND]
        clipped = 0.0
        if e > bound:
            e = bound
            clipped = 1.0
        elif e < -bound:
            e = -bound
            clipped = 1.0
        obs[OB_LOWER_ERR_INT] = e / ecfg[EC_SCALE + OB_LOWER_ERR_INT]
        out[O_INT_CLIPPED] = clipped


@nb.njit(**_NO_NRT)
def _write_true(y, modes, out):
    out[O_TRUE] = y[L.X1]
    out[O_TRUE + 1] = y[L.X2]
    out[O_TRUE + 2] = y[L.X3]
    out[O_TRUE + 3] = y[L.X1] + y[L.THL]
    out[O_TRUE + 4] = y[L.THL]
    out[O_UPPER_STUCK] = 1.0 if modes[0] == 0 else 0.0
    out[O_LOWER_STUCK] = 1.0 if modes[1] == 0 else 0.0


@nb.njit(**_JIT)
def rig_step(p, y, modes, ep, ecfg, scfg, sst, rng, u_req, obs, out, ybuf, mbuf, ubuf):
    """Advance one rig by one control period at the requested voltage ``u_req`` [V].

    The amplifier limits the request to +-``ecfg[EC_VMAX]``; the voltage applied is left in
    ``ep[EP_U]``. Integrates exactly, samples the true state every ``Ts`` into ``ybuf/mbuf/ubuf``,
    runs the sensor chain on each sample, and writes the observation into ``obs`` and the
    reward terms, status and true state into ``out``. Returns the kernel status.
    """
    ws = workspace(int(ecfg[EC_NSUB]))
    return _rig_step(p, y, modes, ep, ecfg, scfg, sst, rng, u_req, obs, out, ybuf, mbuf, ubuf, ws)


@nb.njit(**_NO_NRT)
def _rig_step(p, y, modes, ep, ecfg, scfg, sst, rng, u_req, obs, out, ybuf, mbuf, ubuf, ws):
    vmax = ecfg[EC_VMAX]
    u = min(max(u_req, -vmax), vmax)  # the amplifier's limit, the one place it is applied
    n = int(ecfg[EC_NSUB])
    ts = scfg[1]  # sensors.C_TS
    tick0 = ep[EP_TICK]
    t_out = ws[0]
    for k in range(n):
        t_out[k] = (tick0 + k + 1) * ts
    status = _integrate(p, y, modes, tick0 * ts, (tick0 + n) * ts, u, t_out, ybuf, mbuf, ubuf, ep, ecfg, ws)
    qu0 = sst[S_QU]
    ql0 = sst[S_QL]
    target = ep[EP_TARGET]
    if target != ep[EP_INT_TARGET]:
        # a new target speed: the integrated speed error restarts from here (t0 = now)
        ep[EP_INT_TICK0] = tick0
        ep[EP_INT_QL0] = ql0
        ep[EP_INT_TARGET] = target
    inv_sref = 1.0 / max(target, ecfg[EC_SPEED_REF])
    track_abs = ecfg[EC_TRACK_ABS] != 0.0
    inv_ref = 1.0 / ecfg[EC_SPEED_REF]
    noise = ws[1]
    dirty = ws[10]
    if scfg[C_ANGLE_NOISE] > 0.0 or scfg[C_SPEED_NOISE] > 0.0:
        sensor_noise(scfg, rng, noise)
        dirty[0] = 1.0
    elif dirty[0] != 0.0:
        noise[:, :] = 0.0
        dirty[0] = 0.0
    track = 0.0
    stick = 0.0
    osc = 0.0
    for k in range(n):
        thl = ybuf[k, L.THL]
        sensor_sample(scfg, sst, ybuf[k, L.X1] + thl, thl, noise, k)
        if track_abs:
            track += abs(ybuf[k, L.X3] - target) * inv_ref
        else:
            e = (ybuf[k, L.X3] - target) * inv_sref
            track += e * e
        r = (ybuf[k, L.X2] - ybuf[k, L.X3]) * inv_sref
        osc += r * r
        if mbuf[k, 1] == 0:
            stick += 1.0
    ep[EP_TICK] = tick0 + n
    ep[EP_U] = u
    ep[EP_STATUS] = status
    span = n * ts
    ep[EP_MEAN_U] = (sst[S_QU] - qu0) / span
    ep[EP_MEAN_L] = (sst[S_QL] - ql0) / span
    de = (u - ep[EP_UNOM]) / vmax
    out[O_TRACK] = track / n
    out[O_STICK] = stick / n
    out[O_OSC] = osc / n
    out[O_EFFORT] = de * de
    # the integrated speed error the v1 observation shows, unclipped, in revolutions
    out[O_INTEGRAL] = min(abs(_lower_angle_lost(ep, scfg, sst)) / (2.0 * math.pi), INTEGRAL_TERM_CAP)
    # what was asked of the amplifier beyond its limit: without it a request beyond the limit
    # costs nothing the other terms see, and a policy can wind up there (open loop at the limit)
    out[O_OVERDRIVE] = abs(u_req - u) / vmax
    out[O_REWARD] = -(
        ecfg[EC_W_TRACK] * out[O_TRACK]
        + ecfg[EC_W_STICK] * out[O_STICK]
        + ecfg[EC_W_OSC] * out[O_OSC]
        + ecfg[EC_W_EFFORT] * out[O_EFFORT]
        + ecfg[EC_W_INTEGRAL] * out[O_INTEGRAL]
        + ecfg[EC_W_OVERDRIVE] * out[O_OVERDRIVE]
    )
    out[O_STATUS] = status
    _write_true(y, modes, out)
    _write_obs(y, ep, ecfg, scfg, sst, obs, out)
    return status


@nb.njit(**_JIT)
def rig_reset(
    p,
    y,
    modes,
    ep,
    ecfg,
    scfg,
    sst,
    rng,
    y0,
    start,
    warm_ticks,
    target,
    u_nom,
    obs,
    out,
    ybuf,
    mbuf,
    ubuf,
):
    """Put one rig at the start of an episode.

    ``start``: START_REST (``y0`` at rest, no voltage before), START_EQUILIBRIUM (``y0`` on
    the nominal slip equilibrium, ``u_nom`` applied) or START_OPEN_LOOP (from ``y0`` at rest,
    ``u_nom`` applied open loop for ``warm_ticks`` sensor ticks; the last EC_SETTLE control
    periods run the sensors so that their filters are settled). Returns the kernel status.
    """
    for j in range(L.NY):
        y[j] = y0[j]
    modes[0] = 0
    modes[1] = 0
    for j in range(NEP):
        ep[j] = 0.0
    ep[EP_TARGET] = target
    ep[EP_UNOM] = u_nom
    status = 0
    if start == START_REST:
        sensor_reset(scfg, sst, y[L.X1] + y[L.THL], y[L.THL], 0.0, 0.0)
    elif start == START_EQUILIBRIUM:
        ep[EP_U] = u_nom
        sensor_reset(scfg, sst, y[L.X1] + y[L.THL], y[L.THL], y[L.X2], y[L.X3])
        ep[EP_MEAN_U] = y[L.X2]
        ep[EP_MEAN_L] = y[L.X3]
    else:
        n = int(ecfg[EC_NSUB])
        settle = int(ecfg[EC_SETTLE])
        free = warm_ticks - settle * n
        ts = scfg[1]
        ws = workspace(n)
        if free > 0:
            t_out = np.empty(1)
            t_out[0] = free * ts
            y1 = np.empty((1, L.NY))
            m1 = np.empty((1, 2), dtype=np.int64)
            u1 = np.empty(1)
            status = _integrate(p, y, modes, 0.0, free * ts, u_nom, t_out, y1, m1, u1, ep, ecfg, ws)
            ep[EP_TICK] = free
        else:
            ep[EP_TICK] = 0.0
        sensor_reset(scfg, sst, y[L.X1] + y[L.THL], y[L.THL], y[L.X2], y[L.X3])
        for _ in range(settle):
            if status != 0:
                break
            status = _rig_step(p, y, modes, ep, ecfg, scfg, sst, rng, u_nom, obs, out, ybuf, mbuf, ubuf, ws)
        ep[EP_U] = u_nom
    # modes at the start: a disk at rest is stuck (a moving one slips in its direction)
    if status == 0 and start != START_OPEN_LOOP:
        modes[0] = 0 if y[L.X2] == 0.0 else (1 if y[L.X2] > 0.0 else -1)
        modes[1] = 0 if y[L.X3] == 0.0 else (1 if y[L.X3] > 0.0 else -1)
    ep[EP_TICK0] = ep[EP_TICK]
    ep[EP_INT_TICK0] = ep[EP_TICK]  # the integrated speed error starts with the episode
    ep[EP_INT_QL0] = sst[S_QL]
    ep[EP_INT_TARGET] = target
    ep[EP_STATUS] = status
    for j in range(NOUT):
        out[j] = 0.0
    out[O_STATUS] = status
    _write_true(y, modes, out)
    _write_obs(y, ep, ecfg, scfg, sst, obs, out)
    return status


@nb.njit(**_JIT)
def batch_step(P, Y, MODES, EP, ecfg, SCFG, SST, RNG, U, active, OBS, OUT, YBUF, MBUF, UBUF):
    """``rig_step`` for every rig i with ``active[i]`` at the requested voltage ``U[i]``; one
    compiled call for N rigs."""
    ws = workspace(int(ecfg[EC_NSUB]))
    for i in range(P.shape[0]):
        if active[i]:
            _rig_step(
                P[i],
                Y[i],
                MODES[i],
                EP[i],
                ecfg,
                SCFG[i],
                SST[i],
                RNG[i],
                U[i],
                OBS[i],
                OUT[i],
                YBUF[i],
                MBUF[i],
                UBUF[i],
                ws,
            )


@nb.njit(**_JIT)
def batch_reset(
    P,
    Y,
    MODES,
    EP,
    ecfg,
    SCFG,
    SST,
    RNG,
    Y0,
    START,
    WARM,
    TARGET,
    UNOM,
    which,
    OBS,
    OUT,
    YBUF,
    MBUF,
    UBUF,
):
    """``rig_reset`` for every rig i with ``which[i]``."""
    for i in range(P.shape[0]):
        if which[i]:
            rig_reset(
                P[i],
                Y[i],
                MODES[i],
                EP[i],
                ecfg,
                SCFG[i],
                SST[i],
                RNG[i],
                Y0[i],
                START[i],
                WARM[i],
                TARGET[i],
                UNOM[i],
                OBS[i],
                OUT[i],
                YBUF[i],
                MBUF[i],
                UBUF[i],
            )
