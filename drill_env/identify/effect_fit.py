"""Effects of the library fitted jointly with every base parameter.

The joint fit (:mod:`.joint`) is linear in the base parameters on the equation error of
each run. An effect of the library (:mod:`drill_env.recordings.effects`) enters it as

* **columns with free coefficients** (position-dependent friction, string damping, friction
  drift or heating, an eccentric encoder): the residual of the model with the effect is
  ``r_base - X c`` (``X`` the candidate's columns, the look of the effect in the base model's
  residual), so ``-X`` is ``dr/dc``, fitted beside the base parameters;
* **a change of the base columns** for the two lags, exact at a given time constant: a
  motor lag ``tau_m`` turns the motor constant's column ``-K[u]`` into ``-K[lag(u)]``
  (the candidate's column per unit ``k_m``), a friction memory ``tau_f`` evaluates the hump
  terms at the lagged speed ``w`` (``tau_f w' = |x3| - w``) instead of ``|x3|``. The time
  constant is profiled: the joint fit on a grid of it, refined by a parabola in ``log tau``;
  its 95 % interval is where the profile rises by ``chi2_1(0.95)`` residual variances.

The candidates' columns of the multiplicative effects (friction levels scaled by a position
or a time factor) are evaluated at the base parameters the windows are weighted at (the
first fit's), which the identification's second pass refines.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from scipy import stats

from drill_env.identify.joint import LINEAR, JointFit, RunRows, run_rows
from drill_env.recordings.effects import CANDIDATES, Candidate, position_harmonics, reading_centre
from drill_env.recordings.equation_error import RunEquations

__all__ = ["EffectResult", "effect_rows", "effect_results", "candidate", "lag_profile", "LAG_EFFECTS"]

LAG_EFFECTS = ("motor_inductance", "friction_memory")
PROFILE_FACTORS = np.geomspace(1.0 / 3.0, 3.0, 9)  # the lag's grid about its first estimate
CHI2_95_1 = float(stats.chi2.ppf(0.95, 1))


def candidate(name: str) -> Candidate:
    """The library effect ``name``; ValueError naming the allowed ones."""
    for c in CANDIDATES:
        if c.name == name:
            return c
    raise ValueError(f"effects: unknown effect {name!r}; allowed: {', '.join(c.name for c in CANDIDATES)}")


def _lagged(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """``x`` through ``tau y' = x - y`` from its first value (exact for a zero-order hold)."""
    from scipy.signal import lfilter

    e = math.exp(-dt / tau)
    y_next, _ = lfilter([1.0 - e], [1.0, -e], x, zi=[e * x[0]])
    y = np.empty_like(x)
    y[0] = x[0]
    y[1:] = y_next[:-1]
    return y


def effect_rows(
    eq: RunEquations, effects: Mapping[str, float | None], at: Mapping[str, float] | None = None
) -> RunRows:
    """The joint fit's rows of one run with ``effects`` (name -> time constant [s] of a lag
    effect, None for the others) fitted beside the base parameters.

    ``at``: the effects' coefficients of the fit before (``name:i`` -> value). A position
    modulation of the lower friction then enters as a Gauss-Newton step of the product it is,
    ``s(theta) (T_sl + S(w))``, rather than as columns beside an unscaled friction curve: the base
    friction columns carry ``s`` at ``at``, the modulation's columns stay at the fitted curve, and
    the offset ``-X c_at`` makes the coefficients fitted the modulation's own. Its fixed point is
    the least-squares point of the product; the linear one's is not (with the friction curve's
    slow Stribeck term, which the modulation scales too: a hump term too many and T_sl 22 % off)."""
    rows = run_rows(eq)
    cols: list[np.ndarray] = []
    names: list[str] = []
    nu = len(eq.upper)
    for name, tau in effects.items():
        cand = candidate(name)
        if name == "motor_inductance":
            if tau is None or not tau > 0:
                raise ValueError(f"effects: {name} needs a time constant > 0, got {tau!r}")
            km = eq.params.motor_constant
            xu, _ = cand.columns(eq, tau)
            x = rows.x_lin.copy()
            x[:nu, LINEAR.index("motor_constant")] -= xu[:, 0] / km
            rows = dataclasses.replace(rows, x_lin=x)
        elif name == "friction_memory":
            if tau is None or not tau > 0:
                raise ValueError(f"effects: {name} needs a time constant > 0, got {tau!r}")
            if len(eq.lower):
                w = _lagged(np.abs(eq.speed_l), eq.dt, tau)
                # the lag averages the reading error over its time constant: no correction for it
                rows = dataclasses.replace(
                    rows, speed_l=np.abs(eq.gather(w, eq.lower.centers)), speed_var_l=None
                )
        else:
            xu, xl = cand.columns(eq)
            x = -np.vstack([xu, xl])
            cols.append(x)
            keys = [f"{name}:{i}" for i in range(x.shape[1])]
            names += keys
            if name == "position_friction_lower" and at is not None and len(eq.lower):
                if all(k in at for k in keys):
                    rows = _scaled_lower(rows, eq, np.array([float(at[k]) for k in keys]), x)
    if cols:
        rows = dataclasses.replace(rows, x_eff=np.column_stack(cols), effect_names=tuple(names))
    return rows


def _scaled_lower(rows: RunRows, eq: RunEquations, c0: np.ndarray, x: np.ndarray) -> RunRows:
    """``rows`` with the lower static + Stribeck columns scaled by the position modulation of
    coefficients ``c0`` (its columns ``x``), and the offset ``-x c0`` (see :func:`effect_rows`)."""
    th = eq.gather(reading_centre(eq, "lower"), eq.lower.centers)
    s0 = 1.0 + sum(c * h for c, h in zip(c0, position_harmonics(th), strict=True))
    x_lin = rows.x_lin.copy()
    x_lin[len(eq.upper) :, LINEAR.index("lower_static")] = rows.sign_l * (s0 @ rows.kernel)
    offset = (rows.offset if rows.offset is not None else 0.0) - x @ c0
    return dataclasses.replace(rows, x_lin=x_lin, scale_l=s0, offset=offset)


@dataclass(frozen=True)
class EffectResult:
    """One effect of the identified model: its parameters with 95 % intervals."""

    name: str
    kind: str  # "physical" (the plant's effects: section) or "measurement" (the measurement section)
    parameters: dict[str, float]  # the candidate's physical parameters (rig-file fields)
    ci95: dict[str, tuple[float, float]]
    model_fields: dict[str, float]  # the effects:/measurement: entries of the rig file
    admissible: str | None = None  # None, or why the fitted values are not physical

    def as_dict(self) -> dict:
        return {
            "kind": self.kind,
            "parameters": self.parameters,
            "ci95": {k: list(v) for k, v in self.ci95.items()},
            "fields": self.model_fields,
            **({"not_admissible": self.admissible} if self.admissible else {}),
        }


def _delta_intervals(
    conv: Callable[..., dict[str, float]], coef: np.ndarray, cov: np.ndarray
) -> dict[str, tuple[float, float]]:
    """95 % intervals of ``conv(coef)`` by the delta method (central differences)."""
    base = conv(coef)
    keys = list(base)
    jac = np.zeros((len(keys), coef.size))
    scale = max(float(np.max(np.abs(coef))), 1e-12)
    for j in range(coef.size):
        h = 1e-6 * scale
        up, dn = coef.copy(), coef.copy()
        up[j] += h
        dn[j] -= h
        a, b = conv(up), conv(dn)
        for i, k in enumerate(keys):
            d = a[k] - b[k]
            if "phase" in k:  # angles: the short way round
                d = (d + math.pi) % (2 * math.pi) - math.pi
            jac[i, j] = d / (2 * h)
    var = np.einsum("ij,jk,ik->i", jac, cov, jac)
    out = {}
    for i, k in enumerate(keys):
        half = 1.96 * math.sqrt(max(float(var[i]), 0.0))
        lo, hi = base[k] - half, base[k] + half
        if "amp" in k or "eccentricity" in k:
            lo = max(lo, 0.0)
        out[k] = (lo, hi)
    return out


def effect_results(
    fit: JointFit, effects: Mapping[str, float | None], lag_ci: Mapping[str, tuple[float, float]]
) -> dict[str, EffectResult]:
    """The effects' parameters and intervals from the joint fit (``lag_ci``: each lag's profile
    interval)."""
    out: dict[str, EffectResult] = {}
    for name, tau in effects.items():
        cand = candidate(name)
        if name in LAG_EFFECTS:
            assert tau is not None
            par = cand.to_parameters(np.array([1.0]), tau)
            key = next(iter(par))
            lo_hi = lag_ci.get(name, (math.nan, math.nan))
            ci: dict[str, tuple[float, float]] = {key: (float(lo_hi[0]), float(lo_hi[1]))}
        else:
            keys = [n for n in fit.free if n.startswith(name + ":")]
            idx = [fit.free.index(k) for k in keys]
            coef = np.array([fit.values[k] for k in keys])
            par = cand.to_parameters(coef)
            ci = _delta_intervals(cand.to_parameters, coef, fit.cov[np.ix_(idx, idx)])
        model = cand.to_model_effects(par)
        out[name] = EffectResult(
            name=name,
            kind=cand.kind,
            parameters={k: float(v) for k, v in par.items()},
            ci95={k: (float(a), float(b)) for k, (a, b) in ci.items()},
            model_fields={k: float(v) for k, v in model.items()},
            admissible=cand.admissible(par),
        )
    return out


def lag_profile(
    fit_at: Callable[[float], JointFit], tau0: float, bounds: tuple[float, float]
) -> tuple[float, JointFit, tuple[float, float], dict[float, float]]:
    """The lag's best time constant about ``tau0``: the joint fit ``fit_at(tau)`` on a grid,
    refined by a parabola in log tau; returns (tau, its fit, 95 % interval, the profile)."""
    lo, hi = bounds
    grid = np.clip(tau0 * PROFILE_FACTORS, lo, hi)
    grid = np.unique(grid)
    fits = {float(t): fit_at(float(t)) for t in grid}
    taus = np.array(sorted(fits))
    ss = np.array([fits[t].ss for t in taus])
    i = int(np.argmin(ss))
    if 0 < i < taus.size - 1:  # extend nothing: refine inside the bracket
        x = np.log(taus[i - 1 : i + 2])
        y = ss[i - 1 : i + 2]
        a = np.polyfit(x, y, 2)
        if a[0] > 0:
            vertex = float(np.exp(np.clip(-a[1] / (2 * a[0]), x[0], x[-1])))
            if vertex not in fits:
                fits[vertex] = fit_at(vertex)
    best_tau = min(fits, key=lambda t: fits[t].ss)
    best = fits[best_tau]
    s2 = max(1.0, best.residual_variance)
    taus = np.array(sorted(fits))
    prof = np.array([(fits[t].ss - best.ss) / s2 for t in taus])
    ci = _profile_interval(np.log(taus), prof, math.log(best_tau))
    # on a coarse grid the crossing is poorly placed: the curvature of the profile at its
    # minimum (a parabola through the three nearest points) gives the half-width, widened as
    # the fit widens its other intervals (misfit and run-to-run spread over the window noise)
    j = int(np.argmin(np.abs(taus - best_tau)))
    if 0 < j < taus.size - 1:
        a = np.polyfit(np.log(taus[j - 1 : j + 2]), prof[j - 1 : j + 2], 2)[0]
        if a > 0:
            sd_all = np.sqrt(np.maximum(np.diag(best.cov), 0.0))
            ratio = sd_all / np.maximum(best.sd_information * math.sqrt(s2), 1e-300)
            # the lag's own widening is not known (no sandwich of a profiled parameter): the
            # largest of the fit's, so that correlated windows widen it as much as any parameter
            widen = max(1.0, float(np.max(ratio[np.isfinite(ratio)], initial=1.0))) if ratio.size else 1.0
            half = widen * math.sqrt(CHI2_95_1 / a)
            x0 = math.log(best_tau)
            ci = (min(ci[0], x0 - half), max(ci[1], x0 + half))
    return (
        best_tau,
        best,
        (math.exp(ci[0]), math.exp(ci[1])),
        {float(t): float(p) for t, p in zip(taus, prof, strict=True)},
    )


def _profile_interval(x: np.ndarray, prof: np.ndarray, x0: float) -> tuple[float, float]:
    """Where the profile ``prof(x)`` (0 at ``x0``) first reaches chi2_1(0.95) on each side
    (linear interpolation; the grid's end when it never does: the interval is open there)."""
    below = x <= x0
    above = x >= x0
    out = []
    for side, order in ((below, -1), (above, 1)):
        xs, ps = x[side][::order], prof[side][::order]  # from x0 outwards
        edge = xs[-1] if xs.size else x0
        for j in range(1, xs.size):
            if ps[j] >= CHI2_95_1 > ps[j - 1]:
                f = (CHI2_95_1 - ps[j - 1]) / (ps[j] - ps[j - 1])
                edge = xs[j - 1] + f * (xs[j] - xs[j - 1])
                break
        out.append(float(edge))
    return out[0], out[1]
