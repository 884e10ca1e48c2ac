"""Flow of the nominal rig together with its sensitivities, across friction switches.

The state ``x = (x1, x2, x3)`` (twist, upper and lower disk speeds) is integrated with
the 3 x 4 sensitivity matrix ``S = d x(t) / d (x1(0), x2(0), x3(0), u)``. Within one
friction mode the vector field is smooth and ``S' = J S + df/du e4^T``, with the
analytic Jacobian ``J`` of that mode (the rows of a stuck disk are zero). At every
switch the sensitivity jumps by the saltation matrix

    S+ = (I + (f+ - f-) n^T / (n^T f-)) S-

where ``n`` is the gradient (in x and u) of the event function: the disk speed for a
slipping disk that comes to rest or reverses, the required torque minus the edge of
the static band for a stuck disk that breaks away. For a disk that enters stick the
new field has zero acceleration of that disk, so the jump is the projection that
removes the stuck speed (``I - e3 e3^T`` at the lower disk); at break-away the friction
is continuous (``T_fl(0+) = T_sl``), so ``f+ = f-`` and nothing jumps.

The integrator is the numerical core of :mod:`drill_env.integrator` -- the DOP853 step,
its error norm and step-size factors, the dense output, the Illinois bracket with its
one time tolerance and the grazing rules of a slipping disk (a dip of its speed to zero
inside one step, which the sign test at the step ends alone would miss; a step that
starts with the disk at rest) -- shared with the simulator's kernel
(:mod:`drill_env.kernel`) and run here on the augmented 15-component system with its
own stage loop. The switching rules are the kernel's; this module adds the return to a
Poincare section and the extrema of the speeds and the twist.

Only the paper's model (no :class:`~drill_env.params.ModelEffects`) is covered: the
lower angle does not feed back and is not carried.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from drill_env import _layout as L
from drill_env._numba import INLINE, JIT_ALLOC
from drill_env.dynamics import hump, hump_slope
from drill_env.integrator import (
    H_MIN,
    INSIDE,
    INTERP,
    MAX_BRACKET_ITERATIONS,
    MAX_EVENTS_AT_ONE_INSTANT,
    N_EXT,
    N_EXTRA,
    N_STAGES,
    SURFACE_WALK_START,
    bracket_closed,
    dense_coefficients,
    dense_eval,
    error_norm,
    events_at_instant,
    extra_stage_state,
    growth_factor,
    illinois_point,
    illinois_update,
    shrink_factor,
    solution,
    speed_dip,
    speed_zero,
    stage_state,
)

_JIT = JIT_ALLOC
_INLINE = INLINE

NX = 3  # x1, x2, x3
NS = 4  # sensitivity columns: d/dx1(0), d/dx2(0), d/dx3(0), d/du
NZ = NX + NX * NS  # augmented state: x, then S row-major

# Poincare section: h(x) = x2 - x3 = -x1' crosses zero downwards (the twist is at a maximum).
SECTION_NORMAL = np.array([0.0, 1.0, -1.0])

# Slots of the info vector returned by :func:`flow`.
(
    I_T,
    I_STATUS,
    I_EVENTS,
    I_STICK_U,
    I_STICK_L,
    I_X1MIN,
    I_X1MAX,
    I_X2MIN,
    I_X2MAX,
    I_X3MIN,
    I_X3MAX,
    I_STEPS,
    I_REJECTED,
    I_MODE_U,
    I_MODE_L,
    I_STICK_PHASES_L,
    I_REVERSALS,
) = range(17)
N_INFO = 17

FLOW_STATUS = {
    0: "returned to the Poincare section",
    1: "reached the end time without returning to the section",
    2: "step size fell below its minimum",
    3: "switching events repeated at one instant (chattering)",
    4: "the start point leaves the section on the wrong side (x1 is not at a maximum)",
    5: "too many steps",
}


# Every component of the augmented state is under error control.
ERR_MASK = np.ones(NZ)

# Event-log codes: the kind of switch and which disk.
EV_UPPER, EV_LOWER = 0, 1


@nb.njit(**_JIT)
def field(x1, x2, x3, u, p, mu, ml):
    """Eq. (36) in modes (mu, ml): returns (x1', x2', x3')."""
    ts = p[L.KTH] * x1
    f1 = x2 - x3
    if mu == 0:
        f2 = 0.0
    elif mu > 0:
        f2 = (p[L.KM] * u - ts - p[L.TSUP] - p[L.BUP] * x2) / p[L.JU]
    else:
        f2 = (p[L.KM] * u - ts + p[L.TSUN] - p[L.BUN] * x2) / p[L.JU]
    if ml == 0:
        f3 = 0.0
    else:
        f3 = (ts - ml * (p[L.TSL] + hump(p, ml * x3)) - p[L.BL] * x3) / p[L.JL]
    return f1, f2, f3


@nb.njit(**_INLINE)
def slip_jacobian(x3, p, mu, ml):
    """The entries of the Jacobian of :func:`field` in modes (mu, ml) that are not 0 or +-1:
    (dx2'/dx1, dx2'/dx2, dx2'/du, dx3'/dx1, dx3'/dx3); zero for a stuck disk."""
    a10 = a11 = a13 = a20 = a22 = 0.0
    if mu != 0:
        a10 = -p[L.KTH] / p[L.JU]
        a11 = -(p[L.BUP] if mu > 0 else p[L.BUN]) / p[L.JU]
        a13 = p[L.KM] / p[L.JU]
    if ml != 0:
        a20 = p[L.KTH] / p[L.JL]
        a22 = -(hump_slope(p, ml * x3) + p[L.BL]) / p[L.JL]
    return a10, a11, a13, a20, a22


@nb.njit(**_JIT)
def jacobian(x3, p, mu, ml, J):
    """Jacobian of :func:`field` with respect to (x1, x2, x3, u), into J (3 x 4)."""
    for i in range(NX):
        for j in range(NS):
            J[i, j] = 0.0
    J[0, 1] = 1.0
    J[0, 2] = -1.0
    J[1, 0], J[1, 1], J[1, 3], J[2, 0], J[2, 2] = slip_jacobian(x3, p, mu, ml)


@nb.njit(**_JIT)
def aug_rhs(z, u, p, mu, ml, dz):
    """Augmented field: the state and its sensitivity S' = J S + (df/du) e4^T."""
    f1, f2, f3 = field(z[0], z[1], z[2], u, p, mu, ml)
    dz[0] = f1
    dz[1] = f2
    dz[2] = f3
    a10, a11, a13, a20, a22 = slip_jacobian(z[2], p, mu, ml)
    for j in range(NS):
        s0 = z[NX + j]
        s1 = z[NX + NS + j]
        s2 = z[NX + 2 * NS + j]
        dz[NX + j] = s1 - s2
        dz[NX + NS + j] = a10 * s0 + a11 * s1 + (a13 if j == NS - 1 else 0.0)
        dz[NX + 2 * NS + j] = a20 * s0 + a22 * s2


@nb.njit(**_JIT)
def _step(z, f0, h, u, p, mu, ml, K, z_new, ztmp, rtol, atol):
    """One DOP853 step of the augmented system; returns the scaled error norm."""
    for j in range(NZ):
        K[0, j] = f0[j]
    for s in range(1, N_STAGES):
        stage_state(s, z, K, h, NZ, ztmp)
        aug_rhs(ztmp, u, p, mu, ml, K[s])
    solution(z, K, h, NZ, z_new)
    aug_rhs(z_new, u, p, mu, ml, K[N_STAGES])
    return error_norm(z, z_new, K, h, NZ, ERR_MASK, rtol, atol)


@nb.njit(**_JIT)
def _prepare_dense(z, z_new, h, u, p, mu, ml, K, F, ztmp):
    """The extra stages of the interpolant and its coefficients F."""
    for k in range(N_EXTRA):
        extra_stage_state(k, z, K, h, NZ, ztmp)
        aug_rhs(ztmp, u, p, mu, ml, K[N_STAGES + 1 + k])
    dense_coefficients(z, z_new, K, h, NZ, F)


# -- indicators: functions of the state whose sign changes mark events -------------------
K_UPPER, K_LOWER, K_SECTION, K_F1, K_F2, K_F3 = 0, 1, 2, 3, 4, 5


@nb.njit(**_JIT)
def _upper_violation(z, u, p, mu):
    """<= 0 while the upper disk's mode holds."""
    if mu != 0:
        return -mu * z[1]
    need = p[L.KM] * u - p[L.KTH] * z[0]
    return max(need - p[L.TSUP], -p[L.TSUN] - need)


@nb.njit(**_JIT)
def _lower_violation(z, p, ml):
    if ml != 0:
        return -ml * z[2]
    need = p[L.KTH] * z[0]
    return max(need - p[L.TSL], -p[L.TSL] - need)


@nb.njit(**_JIT)
def _indicator(kind, z, u, p, mu, ml):
    if kind == K_UPPER:
        return _upper_violation(z, u, p, mu)
    if kind == K_LOWER:
        return _lower_violation(z, p, ml)
    if kind == K_SECTION:
        return z[1] - z[2]
    f1, f2, f3 = field(z[0], z[1], z[2], u, p, mu, ml)
    if kind == K_F1:
        return f1
    if kind == K_F2:
        return f2
    return f3


@nb.njit(**_JIT)
def _locate(kind, sgn, a, b, ga, gb, h, z, F, u, p, mu, ml, ztmp):
    """First fraction in [a, b] where sgn * indicator >= 0, given ga < 0 <= gb (Illinois)."""
    side = 0
    for _ in range(MAX_BRACKET_ITERATIONS):
        if bracket_closed(a, b, h):
            break
        c = illinois_point(a, b, ga, gb, h)
        dense_eval(c, z, F, NX, ztmp)
        gc = sgn * _indicator(kind, ztmp, u, p, mu, ml)
        a, b, ga, gb, side = illinois_update(a, b, ga, gb, side, c, gc)
    return b


@nb.njit(**_JIT)
def _edge_leaves(kind, z, F, u, p, mu, ml, ztmp):
    """Whether a stuck disk whose load sits exactly on an edge of its band at the start of
    the step leaves the band at once: the simulator's rule (``drill_env.kernel``), by the
    rate of the load, k_theta times that of the twist, or where that is zero by the side to
    which the load first moves on the dense output."""
    twist_rate = z[1] - z[2]
    if kind == K_UPPER:
        need = p[L.KM] * u - p[L.KTH] * z[0]
        high = need - p[L.TSUP] >= -p[L.TSUN] - need
        rate = -p[L.KTH] * twist_rate if high else p[L.KTH] * twist_rate
    else:
        rate = p[L.KTH] * twist_rate if z[0] >= 0.0 else -p[L.KTH] * twist_rate
    if rate != 0.0:
        return rate > 0.0
    c = SURFACE_WALK_START
    while c < 1.0:
        dense_eval(c, z, F, NX, ztmp)
        g = _indicator(kind, ztmp, u, p, mu, ml)
        if g != 0.0:
            return g > 0.0
        c *= 2.0
    return False


@nb.njit(**_JIT)
def _locate_from_edge(kind, gb, h, z, F, u, p, mu, ml, ztmp):
    """First fraction at which a stuck disk's load, on its band edge at the start and moving
    into the band, is beyond the edge (> 0, not on it); > 0 at the end of the step."""
    a = 0.0
    b = 1.0
    ga = -INSIDE
    side = 0
    for _ in range(MAX_BRACKET_ITERATIONS):
        if bracket_closed(a, b, h):
            break
        c = illinois_point(a, b, ga, gb, h)
        dense_eval(c, z, F, NX, ztmp)
        gc = _indicator(kind, ztmp, u, p, mu, ml)
        if gc == 0.0:
            gc = -INSIDE
        a, b, ga, gb, side = illinois_update(a, b, ga, gb, side, c, gc)
    return b


@nb.njit(**_JIT)
def _extremum(comp, theta, z, F, u, p, mu, ml, ztmp, info):
    """Record the value of component ``comp`` at fraction ``theta`` in its min/max slots."""
    dense_eval(theta, z, F, NX, ztmp)
    v = ztmp[comp]
    lo = I_X1MIN + 2 * comp
    if v < info[lo]:
        info[lo] = v
    if v > info[lo + 1]:
        info[lo + 1] = v


@nb.njit(**_JIT)
def _track_extrema(theta_end, h, z, F, d0, d1, u, p, mu, ml, ztmp, info):
    """Extrema of x1, x2, x3 inside [0, theta_end] of a step, where a derivative changes sign."""
    for comp in range(NX):
        a0 = d0[comp]
        a1 = d1[comp]
        if a0 == 0.0 or a1 == 0.0 or (a0 > 0.0) == (a1 > 0.0):
            continue
        sgn = 1.0 if a0 < 0.0 else -1.0
        th = _locate(K_F1 + comp, sgn, 0.0, 1.0, sgn * a0, sgn * a1, h, z, F, u, p, mu, ml, ztmp)
        if th <= theta_end:
            _extremum(comp, th, z, F, u, p, mu, ml, ztmp, info)


@nb.njit(**_JIT)
def _dip(disk, h, z, F, d0, d1, mu, ml):
    """Fraction at which a slipping disk's speed first reaches zero inside a step whose ends
    both have it moving (a grazing dip), or 2.0 when there is none."""
    m = mu if disk == 0 else ml
    if m == 0:
        return 2.0
    c = 1 + disk  # speed component
    if not (m * d0[c] < 0.0 and m * d1[c] > 0.0):  # |speed| must have a minimum inside the step
        return 2.0
    b0 = speed_dip(c, m, z, F)
    if b0 > 1.0:
        return 2.0
    return speed_zero(c, m, z, F, h, b0)


@nb.njit(**_JIT)
def _apply_switch(disk, z, u, p, mu, ml, new_mode, release_sign):
    """Saltation jump of the sensitivity at a switch of ``disk`` from its current mode."""
    old = mu if disk == 0 else ml
    fm1, fm2, fm3 = field(z[0], z[1], z[2], u, p, mu, ml)
    if disk == 0:
        fp1, fp2, fp3 = field(z[0], z[1], z[2], u, p, new_mode, ml)
    else:
        fp1, fp2, fp3 = field(z[0], z[1], z[2], u, p, mu, new_mode)
    # Gradient n of the event function in (x1, x2, x3, u).
    n0 = 0.0
    n1 = 0.0
    n2 = 0.0
    n3 = 0.0
    if old != 0:  # a slipping disk reached zero speed: g = -old * speed
        if disk == 0:
            n1 = -old
        else:
            n2 = -old
    else:  # a stuck disk breaks away: g = +-(required torque) - band edge
        if disk == 0:
            n0 = -release_sign * p[L.KTH]
            n3 = release_sign * p[L.KM]
        else:
            n0 = release_sign * p[L.KTH]
    den = n0 * fm1 + n1 * fm2 + n2 * fm3
    if den == 0.0:
        return False
    d1 = (fp1 - fm1) / den
    d2 = (fp2 - fm2) / den
    d3 = (fp3 - fm3) / den
    for j in range(NS):
        nts = n0 * z[NX + j] + n1 * z[NX + NS + j] + n2 * z[NX + 2 * NS + j]
        if j == NS - 1:
            nts += n3
        z[NX + j] += d1 * nts
        z[NX + NS + j] += d2 * nts
        z[NX + 2 * NS + j] += d3 * nts
    return True


@nb.njit(**_JIT)
def _decide(disk, z, u, p):
    """Mode of a disk at zero speed: stick when its required torque lies in the closed band."""
    if disk == 0:
        need = p[L.KM] * u - p[L.KTH] * z[0]
        if need > p[L.TSUP]:
            return 1
        if need < -p[L.TSUN]:
            return -1
        return 0
    need = p[L.KTH] * z[0]
    if need > p[L.TSL]:
        return 1
    if need < -p[L.TSL]:
        return -1
    return 0


@nb.njit(**_JIT)
def initial_modes(z, u, p):
    """Modes from the state: a moving disk slips, a disk at rest is decided by its torques."""
    mu = 1 if z[1] > 0.0 else (-1 if z[1] < 0.0 else _decide(0, z, u, p))
    ml = 1 if z[2] > 0.0 else (-1 if z[2] < 0.0 else _decide(1, z, u, p))
    return mu, ml


@nb.njit(**_JIT)
def flow(z, u, p, modes, t_max, to_section, rtol, atol, h_max, max_steps, info, ev_t, ev_kind):
    """Integrate the state and its sensitivity from t = 0; ``z`` (NZ) is updated in place.

    ``modes`` (int64[2]) gives the starting modes and receives the final ones. With
    ``to_section`` the integration stops at the first downward crossing of
    x2 - x3 = 0 after having been above it (the start point is expected on the section,
    leaving it downwards). ``info`` (N_INFO) receives the time, status and measures of the
    path; ``ev_t``/``ev_kind`` log the switches (kind = 10*disk + 3 + new mode, capacity
    permitting). Returns the status (see FLOW_STATUS).
    """
    K = np.empty((N_EXT, NZ))
    F = np.empty((INTERP, NZ))
    f0 = np.empty(NZ)
    z_new = np.empty(NZ)
    ztmp = np.empty(NZ)
    zev = np.empty(NZ)
    d0 = np.empty(NX)
    d1 = np.empty(NX)
    for j in range(N_INFO):
        info[j] = 0.0
    for c in range(NX):
        info[I_X1MIN + 2 * c] = z[c]
        info[I_X1MAX + 2 * c] = z[c]
    mu = modes[0]
    ml = modes[1]
    t = 0.0
    status = 1
    n_ev = 0
    events_here = 0
    last_event_t = -1.0
    aug_rhs(z, u, p, mu, ml, f0)
    if to_section and f0[1] - f0[2] >= 0.0:
        info[I_STATUS] = 4
        return 4
    armed = False
    h = min(h_max, 1e-2)
    rejected = False
    n_steps = 0
    n_rej = 0
    while t < t_max:
        if n_steps >= max_steps:
            status = 5
            break
        last = False
        if t + h >= t_max:
            h = t_max - t
            last = True
        err = _step(z, f0, h, u, p, mu, ml, K, z_new, ztmp, rtol, atol)
        if not (err <= 1.0):
            n_rej += 1
            rejected = True
            h *= shrink_factor(err)
            if h < H_MIN:
                status = 2
                break
            continue
        n_steps += 1
        for c in range(NX):
            d0[c] = f0[c]
            d1[c] = K[N_STAGES, c]
        _prepare_dense(z, z_new, h, u, p, mu, ml, K, F, ztmp)
        # Earliest event inside the step.
        th_u = 2.0
        th_l = 2.0
        th_s = 2.0
        gu0 = _upper_violation(z, u, p, mu)
        gu1 = _upper_violation(z_new, u, p, mu)
        if mu == 0 and gu0 == 0.0 and _edge_leaves(K_UPPER, z, F, u, p, mu, ml, ztmp):
            th_u = 0.0  # on the band's edge and leaving it, however briefly
        elif (gu1 > 0.0) if mu == 0 else (gu1 >= 0.0):
            if mu != 0:
                th_u = speed_zero(1, mu, z, F, h, 1.0)
            elif gu0 < 0.0:
                th_u = _locate(K_UPPER, 1.0, 0.0, 1.0, gu0, gu1, h, z, F, u, p, mu, ml, ztmp)
            elif gu0 == 0.0:
                th_u = _locate_from_edge(K_UPPER, gu1, h, z, F, u, p, mu, ml, ztmp)
            else:
                th_u = 0.0
        else:
            th_u = _dip(0, h, z, F, d0, d1, mu, ml)
        gl0 = _lower_violation(z, p, ml)
        gl1 = _lower_violation(z_new, p, ml)
        if ml == 0 and gl0 == 0.0 and _edge_leaves(K_LOWER, z, F, u, p, mu, ml, ztmp):
            th_l = 0.0  # on the band's edge and leaving it, however briefly
        elif (gl1 > 0.0) if ml == 0 else (gl1 >= 0.0):
            if ml != 0:
                th_l = speed_zero(2, ml, z, F, h, 1.0)
            elif gl0 < 0.0:
                th_l = _locate(K_LOWER, 1.0, 0.0, 1.0, gl0, gl1, h, z, F, u, p, mu, ml, ztmp)
            elif gl0 == 0.0:
                th_l = _locate_from_edge(K_LOWER, gl1, h, z, F, u, p, mu, ml, ztmp)
            else:
                th_l = 0.0
        else:
            th_l = _dip(1, h, z, F, d0, d1, mu, ml)
        if to_section and armed:
            s0 = z[1] - z[2]
            s1 = z_new[1] - z_new[2]
            if s0 > 0.0 and s1 <= 0.0:
                th_s = _locate(K_SECTION, -1.0, 0.0, 1.0, -s0, -s1, h, z, F, u, p, mu, ml, ztmp)
        th = min(th_u, th_l, th_s)
        if th > 1.0:
            _track_extrema(1.0, h, z, F, d0, d1, u, p, mu, ml, ztmp, info)
            if mu == 0:
                info[I_STICK_U] += h
            if ml == 0:
                info[I_STICK_L] += h
            for j in range(NZ):
                z[j] = z_new[j]
                f0[j] = K[N_STAGES, j]
            t += h
            for c in range(NX):
                _v = z[c]
                if _v < info[I_X1MIN + 2 * c]:
                    info[I_X1MIN + 2 * c] = _v
                if _v > info[I_X1MAX + 2 * c]:
                    info[I_X1MAX + 2 * c] = _v
            if z[1] - z[2] > 0.0:
                armed = True
            fac = growth_factor(err)
            if rejected:
                fac = min(fac, 1.0)
                rejected = False
            if not last:
                h = min(h * fac, h_max)
            continue
        # An event at fraction th: move there.
        _track_extrema(th, h, z, F, d0, d1, u, p, mu, ml, ztmp, info)
        dense_eval(th, z, F, NZ, zev)
        if mu == 0:
            info[I_STICK_U] += th * h
        if ml == 0:
            info[I_STICK_L] += th * h
        t_ev = t + th * h
        if th_s == th:
            for j in range(NZ):
                z[j] = zev[j]
            t = t_ev
            status = 0
            break
        disk = 0 if th_u == th else 1
        m_old = mu if disk == 0 else ml
        c = 1 + disk
        release = 0.0
        if m_old != 0:
            zev[c] = 0.0  # a slipping disk that reached zero speed is put exactly at rest
            new = _decide(disk, zev, u, p)
        else:
            if disk == 0:
                need = p[L.KM] * u - p[L.KTH] * zev[0]
                new = 1 if need - p[L.TSUP] >= -p[L.TSUN] - need else -1
            else:
                need = p[L.KTH] * zev[0]
                new = 1 if need >= 0.0 else -1
            release = float(new)
        if not _apply_switch(disk, zev, u, p, mu, ml, new, release):
            status = 2
            for j in range(NZ):
                z[j] = zev[j]
            t = t_ev
            break
        if n_ev < ev_t.shape[0]:
            ev_t[n_ev] = t_ev
            ev_kind[n_ev] = 10 * disk + 3 + new
        n_ev += 1
        if disk == 1 and new == 0:
            info[I_STICK_PHASES_L] += 1.0
        if m_old != 0 and new == -m_old:
            info[I_REVERSALS] += 1.0
        if disk == 0:
            mu = new
        else:
            ml = new
        events_here = events_at_instant(t_ev, last_event_t, events_here)
        if events_here > MAX_EVENTS_AT_ONE_INSTANT:
            status = 3
            for j in range(NZ):
                z[j] = zev[j]
            t = t_ev
            break
        last_event_t = t_ev
        for j in range(NZ):
            z[j] = zev[j]
        t = t_ev
        for cc in range(NX):
            _v = z[cc]
            if _v < info[I_X1MIN + 2 * cc]:
                info[I_X1MIN + 2 * cc] = _v
            if _v > info[I_X1MAX + 2 * cc]:
                info[I_X1MAX + 2 * cc] = _v
        if z[1] - z[2] > 0.0:
            armed = True
        aug_rhs(z, u, p, mu, ml, f0)
        h = max(min(h, h_max), 1e-6)
        rejected = False
    info[I_T] = t
    info[I_STATUS] = status
    info[I_EVENTS] = n_ev
    info[I_STEPS] = n_steps
    info[I_REJECTED] = n_rej
    info[I_MODE_U] = mu
    info[I_MODE_L] = ml
    modes[0] = mu
    modes[1] = ml
    return status


def augmented_initial(x: np.ndarray) -> np.ndarray:
    """Augmented state (x, S = [I | 0]) to start :func:`flow` from."""
    z = np.zeros(NZ)
    z[:NX] = x
    for i in range(NX):
        z[NX + i * NS + i] = 1.0
    return z


def split_augmented(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, S) from an augmented state; S is 3 x 4 (columns x1(0), x2(0), x3(0), u)."""
    return z[:NX].copy(), z[NX:].reshape(NX, NS).copy()


def flow_map(
    p: np.ndarray,
    u: float,
    x0: np.ndarray,
    t_end: float,
    *,
    rtol: float = 1e-11,
    atol: float = 1e-13,
    h_max: float = 0.1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """State and sensitivity after ``t_end`` seconds from x0 at voltage u.

    Returns (x, S, modes, info): S = d x(t_end) / d (x0, u) (3 x 4), the final modes and
    the info vector (see the I_* slots).
    """
    x0 = np.asarray(x0, dtype=float)
    z = augmented_initial(x0)
    mu, ml = initial_modes(z, float(u), p)
    modes = np.array([mu, ml], dtype=np.int64)
    info = np.zeros(N_INFO)
    ev_t = np.zeros(1)
    ev_k = np.zeros(1, dtype=np.int64)
    status = flow(z, float(u), p, modes, float(t_end), False, rtol, atol, h_max, 10_000_000, info, ev_t, ev_k)
    if status != 1:  # 1: the end time was reached (no section requested)
        raise RuntimeError(f"flow_map: {FLOW_STATUS[status]}")
    x, S = split_augmented(z)
    return x, S, modes, info
