"""Timing of the voltage column against the angles: a voltage recorded on another clock.

A lab that records the amplifier input with a separate generator or DAQ channel can get a
voltage column shifted by whole samples against the angles: a step appears in the file one
sample after it reached the motor (or before). The model then sees the motor torque change
at the wrong instant; at every voltage step the upper disk's equation error shows a short
pulse, which no friction or parameter change explains and which a line search reads as an
``unexplained`` residual.

The upper-disk residual holds the motor torque
``-k_m K[u]/h^2``; if the voltage column lags the angles by ``k`` samples (``u_file[i] =
u_motor[i - k]``), the motor saw ``u_file[i + k]`` and the residual with the right timing is

    r_k = r + k_m (K[u](c) - K[u](c + k)) / h^2

at the same windows. Parameters a few percent off (the motor constant, the inertias) also
leave a response at every step, and re-timing alone would trade one for the other (with 5 %
parameter errors and no lag, three datasets of four claimed lags of 2-3 samples). So each
residual is first refitted on the parameters' own columns (those of the recalibration,
:func:`~drill_env.recordings.regression.calibration_columns`, coefficients free per run), at
every shift alike: :func:`voltage_lag_scan` computes the drop of what is left of the sum of
squares (noise units) ``D_k = min |z - A d|^2 - min |z_k - A d|^2`` for ``k`` in ``-3..3``
over every run, on the training and the held-out runs separately. A lag is claimed only when the best nonzero ``k`` drops the
sum of squares by more than the chi-square level over all runs, is the best on the training
runs and improves them, the held-out runs do not contradict it (no other lag better there, and
no worse, by the level), and it beats every other lag by the chi-square level. Constant-voltage runs
carry no information (a shift of a constant is nothing); only runs with voltage steps count.

The data are never shifted here: the finding goes into the verdict and the report as a
recording issue; ``drill-env discrepancy --voltage-lag K`` (:func:`shift_voltage`) applies
a shift the user chooses.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import chi2

from drill_env.recordings.regression import calibration_columns

__all__ = ["MAX_VOLTAGE_LAG", "VoltageLag", "shift_voltage", "voltage_lag_scan"]

MAX_VOLTAGE_LAG = 3  # samples either way: the scan's range and --voltage-lag's bound
LAG_LEVEL = 0.001  # chi-square level a lag's drop must pass on each run set


@dataclass
class VoltageLag:
    """What the timing scan found: the lag of the voltage column behind the angles."""

    lag: int  # samples the voltage column lags the angles (negative: it leads); 0: none claimed
    dt: float  # sample period [s]
    drops_train: dict[int, float]  # per lag, drop of the sum of squares on the training runs
    drops_heldout: dict[int, float]  # the same on the held-out runs
    threshold: float  # the drop a lag must pass over all runs (and beat every other lag by)
    runs: list[str] = field(default_factory=list)  # runs with voltage steps (the evidence)
    best: int = 0  # the best nonzero lag, claimed or not

    @property
    def found(self) -> bool:
        return self.lag != 0

    def as_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["drops_train"] = {str(k): v for k, v in self.drops_train.items()}
        d["drops_heldout"] = {str(k): v for k, v in self.drops_heldout.items()}
        d["found"] = self.found
        return d

    def describe(self) -> str:
        """One sentence for the verdict line and the report."""
        k = self.lag if self.found else self.best
        n = abs(k)
        ms = n * self.dt * 1e3
        way = "lags" if k > 0 else "leads"
        score = f"drop {self.drops_train[k]:.4g} (training) and {self.drops_heldout[k]:.4g} (held-out)"
        if not self.found:
            return f"no timing offset of the voltage column (best {k:+d} samples: {score}, level {self.threshold:.3g})"
        return (
            f"RECORDING: the voltage column {way} the angles by {n} sample{'s' if n > 1 else ''} "
            f"({ms:.3g} ms; {score} of the equation error's sum of squares, level {self.threshold:.3g}): "
            f"the voltage was recorded by another clock; shift it (drill-env discrepancy --voltage-lag {k}) "
            "or record both on one DAQ"
        )


def _lag_drop(eq, k: int, xu: np.ndarray) -> float:
    """Drop of the upper disk's sum of squares (noise units) when the motor saw ``u[i + k]``,
    each residual refitted on the parameter columns ``xu`` (the upper windows')."""
    w = eq.upper
    if len(w) == 0 or k == 0:
        return 0.0
    km = eq.params.motor_constant
    c = w.centers
    n = eq.u.size
    ok = (c + k + eq.offsets[0] >= 0) & (c + k + eq.offsets[-1] < n)
    if not ok.any():
        return 0.0
    c = c[ok]
    du = (eq.gather(eq.u, c) - eq.gather(eq.u, c + k)) @ eq.w_zoh
    z = w.residual[ok] / w.sigma[ok]
    zk = (w.residual[ok] + km * du / eq.h**2) / w.sigma[ok]
    a = xu[ok] / w.sigma[ok][:, None]

    def left(v: np.ndarray) -> float:
        coef, *_ = np.linalg.lstsq(a, v, rcond=None)
        r = v - a @ coef
        return float(r @ r)

    return left(z) - left(zk)


def voltage_lag_scan(eqs, train: list[str], heldout: list[str], max_lag: int = MAX_VOLTAGE_LAG) -> VoltageLag:
    """Scan whole-sample offsets of the voltage column against the angles (module docstring).

    ``eqs`` are the runs' equations at the nominal parameters (a recalibration absorbs part of
    the pulses and hides the lag); ``train`` and
    ``heldout`` name the two run sets on which a lag must win."""
    lags = [k for k in range(-max_lag, max_lag + 1) if k != 0]
    stepped = [eq for eq in eqs if not eq.run.is_constant_voltage]
    cols = {eq.run.name: calibration_columns(eq)[0] for eq in stepped}
    drops = {k: {eq.run.name: _lag_drop(eq, k, cols[eq.run.name]) for eq in stepped} for k in lags}
    tr = {k: float(sum(v for n, v in d.items() if n in train)) for k, d in drops.items()}
    ho = {k: float(sum(v for n, v in d.items() if n in heldout)) for k, d in drops.items()}
    # a fixed hypothesis (no fitted coefficient): one degree of freedom, Bonferroni over the lags
    threshold = float(chi2.isf(LAG_LEVEL / len(lags), 1))
    dt = float(eqs[0].dt) if eqs else float("nan")
    best = max(lags, key=lambda k: tr[k] + ho[k]) if lags else 0
    others = [tr[k] + ho[k] for k in lags if k != best]
    clear = not others or tr[best] + ho[best] > max(others) + threshold
    found = (
        tr[best] + ho[best] > threshold
        and tr[best] > 0.0
        and max(lags, key=lambda k: tr[k]) == best
        # the held-out runs must not contradict it (they may hold few steps): no worse by the
        # level, and no other lag better there by the level
        and ho[best] > -threshold
        and all(ho[best] > ho[k] - threshold for k in lags)
        and clear
    )
    return VoltageLag(
        lag=best if found else 0,
        dt=dt,
        drops_train=tr,
        drops_heldout=ho,
        threshold=threshold,
        runs=[eq.run.name for eq in stepped],
        best=best,
    )


def shift_voltage(dataset, lag: int):
    """The dataset with its voltage column moved ``lag`` samples earlier against the angles
    (``lag > 0``: the column lagged the angles; the motor saw ``u[i + lag]`` at sample i).
    Each run loses ``|lag|`` samples at one end: the first ones for a negative lag, the last
    ones for a positive lag; nothing is padded."""
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or abs(int(lag)) > MAX_VOLTAGE_LAG:
        raise ValueError(
            f"voltage_lag: expected a whole number of samples in [-{MAX_VOLTAGE_LAG}, {MAX_VOLTAGE_LAG}], got {lag!r}"
        )
    lag = int(lag)
    if lag == 0:
        return dataset
    runs = []
    for r in dataset.runs:
        n = r.t.size
        if lag > 0:
            keep, u = slice(0, n - lag), r.u[lag:]
        else:
            keep, u = slice(-lag, n), r.u[: n + lag]
        runs.append(
            dataclasses.replace(r, t=r.t[keep], u=u, theta_u=r.theta_u[keep], theta_l=r.theta_l[keep])
        )
    meta = dict(dataset.meta)
    meta["voltage_lag_samples"] = lag
    return dataclasses.replace(dataset, runs=tuple(runs), meta=meta)
