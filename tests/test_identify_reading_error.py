"""The encoders' reading error in the angle columns (errors in the variables).

The columns of the inertias, the viscous frictions and the string stiffness are kernel sums of
the measured angles, so they carry the reading error, and a least-squares fit is drawn towards
the values for which it weighs least. The noise model gives its covariance per window
(:meth:`RunEquations.column_noise`), checked here against Monte Carlo draws of the encoder; the
joint fit compensates the pull, checked against the same rig read by a near-exact encoder."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drill_env.identify import draw_rig, identify
from drill_env.params import load_params
from drill_env.recordings.dataset import MeasuredDataset, MeasuredRun
from drill_env.recordings.equation_error import AngleNoise, RunEquations
from drill_env.recordings.protocols import record_protocol
from drill_env.simulator import simulate


def _columns(eq: RunEquations, theta_u: np.ndarray, theta_l: np.ndarray) -> np.ndarray:
    """The upper windows' three angle columns (inertia, stiffness, viscous) from these angles."""
    c = eq.upper.centers
    th = eq.gather(theta_u, c)
    tw = eq.gather(theta_u - theta_l, c)
    h2 = eq.h**2
    return np.stack([th @ eq.w_d2 / h2, tw @ eq.w_tri / h2, th @ eq.w_rate / h2], axis=1)


def test_the_column_noise_is_what_the_encoder_draws_give():
    """With a count of dither the reading error is white and the model exact. (Undithered, the
    lines' power depends on where the count rate's harmonics alias, which the model knows only as
    well as the rate, averaging over that band: it is checked end to end, below.)"""
    dither_counts = 1.0
    rig = load_params("brake")
    dt, counts = 2e-3, 2000
    step = 2.0 * math.pi / counts
    levels = np.linspace(1.0, 4.0, 100)
    res = simulate(rig, levels, 20.0, dt=dt, control_dt=0.2)
    t, tu, tl = res.t, res.theta_u, res.theta_l
    u = levels[np.minimum(np.floor(t / 0.2 + 1e-9).astype(int), levels.size - 1)]
    rng = np.random.default_rng(7)
    s = dither_counts * step

    def read(theta, offset):
        return np.floor((theta + offset + s * rng.standard_normal(theta.size)) / step) * step - offset

    run = MeasuredRun(name="r", t=t, u=u, theta_u=read(tu, 0.0), theta_l=read(tl, 0.0))
    q = math.sqrt(step**2 / 12.0)
    noise = AngleNoise(upper=math.hypot(q, s), lower=math.hypot(q, s), quantisation=q, samples_used=1)
    eq = RunEquations(run, rig, noise)
    assert len(eq.upper) >= 15
    # the encoder's sub-count offset is unknown (the phase of the quantisation error's lines):
    # each draw reads the same motion with a new offset of each encoder (and new dither)
    draws = np.array(
        [_columns(eq, read(tu, rng.uniform(0, step)), read(tl, rng.uniform(0, step))) for _ in range(600)]
    )
    empirical = np.einsum("dwi,dwj->wij", draws - draws.mean(0), draws - draws.mean(0)) / (draws.shape[0] - 1)
    model = eq.column_noise("upper")
    for i in range(3):
        ratio = np.mean(empirical[:, i, i]) / np.mean(model[:, i, i])
        assert 0.9 < ratio < 1.1, (i, ratio)
    # the cross terms: the inertia's and the stiffness's columns share the upper encoder's error
    corr_e = np.mean(empirical[:, 0, 1]) / math.sqrt(
        np.mean(empirical[:, 0, 0]) * np.mean(empirical[:, 1, 1])
    )
    corr_m = np.mean(model[:, 0, 1]) / math.sqrt(np.mean(model[:, 0, 0]) * np.mean(model[:, 1, 1]))
    assert abs(corr_e - corr_m) < 0.1, (corr_e, corr_m)


def _closed_loop(counts: int):
    """A braked rig drawn far from the paper's, recorded on two closed-loop PI runs whose voltage
    sits near 5 V: the motor and the upper friction nearly balance, the string's torque is 2 % of
    the motor's, and the upper disk's scale is fixed by that 2 % alone."""
    rig = draw_rig("brake", 48, low=0.35, high=3.0)
    syn = record_protocol(
        rig, "closed_loop_pi", seed=48, sample_rate_hz=1000.0, encoder_counts_per_rev=counts, preset="brake"
    )
    ds = MeasuredDataset(preset="brake", encoder_counts_per_rev=counts, runs=tuple(syn.runs))
    return rig, identify(ds, known={"string_stiffness": rig.string_stiffness}, simulate_heldout=False)


UPPER = ("motor_constant", "upper_inertia", "upper_viscous_pos")


def test_the_reading_errors_pull_on_the_upper_disks_scale_is_compensated():
    rig, ident = _closed_loop(4096)
    fit = ident.fit
    assert fit.reading_corrected
    for n in UPPER:
        truth = float(getattr(rig, n))
        p = ident.parameters[n]
        least_squares = p.value - fit.reading_correction[n]
        # the pull is real: the least-squares value is far off (the test can fail) ...
        assert least_squares / truth - 1.0 < -0.15, (n, least_squares / truth - 1.0)
        # ... and the compensated one holds the truth inside its interval
        assert abs(p.value / truth - 1.0) < 0.15, (n, p.value / truth - 1.0)
        assert p.ci95[0] <= truth <= p.ci95[1], (n, p.value, p.ci95, truth)
    # the oracle: the same motion read by a near-exact encoder needs (and makes) no correction
    rig, fine = _closed_loop(1 << 20)
    for n in UPPER:
        assert abs(fine.parameters[n].value / float(getattr(rig, n)) - 1.0) < 0.005
        assert abs(fine.fit.reading_correction[n]) < 0.005 * abs(fine.parameters[n].value)


@pytest.mark.slow
def test_the_closed_loop_rig_without_an_effect_draws_no_discovery():
    from drill_env.structure_search import identify_structure

    rig = draw_rig("brake", 48, low=0.35, high=3.0)
    syn = record_protocol(
        rig, "closed_loop_pi", seed=48, sample_rate_hz=1000.0, encoder_counts_per_rev=4096, preset="brake"
    )
    ds = MeasuredDataset(preset="brake", encoder_counts_per_rev=4096, runs=tuple(syn.runs))
    s = identify_structure(ds, known={"string_stiffness": rig.string_stiffness}, simulate_heldout=False)
    # a motor lag of 74 ms (J_u / b_u) had taken the inertia's part: a false discovery
    assert s.verdict in ("none", "recalibrated"), s.verdict
    assert s.effects == []
