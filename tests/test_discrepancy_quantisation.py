"""Undithered encoders: the quantisation error is spectral lines, not white noise, and the
workflow's noise floor and structure tests know it."""

from __future__ import annotations

import math

import numpy as np
import pytest

import drill_env
from drill_env.discrepancy.scoring import DecisionRule, RunStatistics
from drill_env.discrepancy.verdict import decide
from drill_env.discrepancy.workflow import analyse
from drill_env.recordings.dataset import MeasuredDataset, MeasuredRun
from drill_env.recordings.equation_error import (
    AngleNoise,
    RunEquations,
    estimate_angle_noise,
    line_variance,
    quantisation_weights,
)
from drill_env.recordings.synth import SynthConfig, make_dataset

STEP = 1.0  # one count, in the units of the angle


def _noise(additive: float) -> AngleNoise:
    q = STEP / math.sqrt(12.0)
    total = math.sqrt(q * q + additive * additive)
    return AngleNoise(upper=total, lower=total, quantisation=q, samples_used=0)


def _second_difference_window(n_box: int = 51, span: int = 100, n: int = 301) -> np.ndarray:
    """Box-smoothed second difference over +-span samples: the inertia part of a window."""
    d2 = np.zeros(2 * span + 1)
    d2[0], d2[span], d2[-1] = 1.0, -2.0, 1.0
    coef = np.convolve(d2, np.full(n_box, 1.0 / n_box))
    return np.pad(coef, (0, n - coef.size))


def _monte_carlo(coef, rate, additive, draws, rng):
    """Variance of sum_k coef_k e_k, e the floor-quantisation error of a ramp at ``rate`` counts
    per sample (known to +-1/N) from a uniform sub-count offset, with Gaussian dither."""
    N = coef.size
    k = np.arange(N) - 0.5 * (N - 1)
    c = rate + rng.uniform(-1.0 / N, 1.0 / N, size=(draws, 1))
    x = rng.uniform(0.0, 1.0, size=(draws, 1)) + c * k[None, :]
    read = np.floor(x + additive * rng.standard_normal(x.shape))
    return float(np.var((read - x) @ coef))


@pytest.mark.parametrize("rate", [1.0021, 0.4987, 0.1083, 2.37, 3.2, 5.731])
@pytest.mark.parametrize("additive", [0.0, 0.1])
def test_line_variance_matches_a_simulated_encoder(rate, additive):
    coef = _second_difference_window()
    weights, white = quantisation_weights(_noise(additive), "upper", 256)
    predicted = (
        white * float(coef @ coef) + line_variance(coef[None, :], np.array([rate]), np.zeros(1), weights)[0]
    )
    simulated = _monte_carlo(coef, rate, additive, 8000, np.random.default_rng(11))
    assert predicted == pytest.approx(simulated, rel=0.12)


def test_line_variance_is_far_from_white_without_dither():
    # the white model (step^2/12 per sample) is wrong by more than a factor 10 both ways
    coef = _second_difference_window()
    weights, white = quantisation_weights(_noise(0.0), "upper", 256)
    white_model = float(coef @ coef) / 12.0
    near_integer = line_variance(coef[None, :], np.array([1.002]), np.zeros(1), weights)[0]
    between = line_variance(coef[None, :], np.array([2.37]), np.zeros(1), weights)[0]
    assert near_integer > 10.0 * white_model
    assert between < 0.1 * white_model


def test_heavy_dither_gives_the_white_model():
    # Widrow, Kollar & Liu: with dither of a count or more the error is white, s^2 + step^2/12
    coef = _second_difference_window()
    weights, white = quantisation_weights(_noise(1.0), "upper", 256)
    var = (
        white * float(coef @ coef) + line_variance(coef[None, :], np.array([1.002]), np.zeros(1), weights)[0]
    )
    assert var == pytest.approx((1.0 + 1.0 / 12.0) * float(coef @ coef), rel=1e-6)


def test_a_changing_rate_spreads_the_lines():
    # the same window while the rate sweeps over a whole count per sample sees the average line
    coef = _second_difference_window()
    weights, white = quantisation_weights(_noise(0.0), "upper", 256)
    swept = line_variance(coef[None, :], np.array([1.002]), np.array([2.0]), weights)[0]
    assert swept == pytest.approx(float(coef @ coef) * (1.0 / 12.0 - white), rel=1e-6)


def _constant_rate_floor(rate, twist_counts, seed, counts=2000, fs=500.0, duration_s=200.0):
    """Mean z^2 of the windows of both disks turning at ``rate`` counts per sample with a constant
    twist, undithered: the equation error of the quantised angles minus that of the true angles
    (the quantisation error through the same window coefficients) over the noise floor."""
    rng = np.random.default_rng(seed)
    step = 2.0 * math.pi / counts
    n = int(duration_s * fs) + 1
    k = np.arange(n)
    upper = (rng.uniform() + rate * k) * step
    lower = upper - twist_counts * step
    q = step / math.sqrt(12.0)
    noise = AngleNoise(upper=q, lower=q, quantisation=q, samples_used=0)
    params = drill_env.load_params("brake")

    def run(a, b):
        return MeasuredRun(name="ramp", t=k / fs, u=np.zeros(n), theta_u=a, theta_l=b)

    read = RunEquations(run(np.floor(upper / step) * step, np.floor(lower / step) * step), params, noise)
    true = RunEquations(run(upper, lower), params, noise)
    out = {}
    for disk in ("upper", "lower"):
        w, w_true = getattr(read, disk), getattr(true, disk)
        assert np.array_equal(w.centers, w_true.centers) and len(w) > 100
        out[disk] = float(np.mean(((w.residual - w_true.residual) / w.sigma) ** 2))
    return out


def test_noise_floor_at_constant_rates():
    # disks at constant rates, near-rational count rates included (0.3913 ~ 9/23, 0.8571 ~ 6/7,
    # 2.0047 ~ 2): all windows of a run see their lines at the same frequencies, so a floor that
    # knows the rate only to 1/N is off by the same factor in every window (0.3 to 3.8 here)
    cases = [(0.3913, 0.3), (0.1457, 4.6), (0.6129, 0.0), (0.8571, 11.2), (2.0047, 2.5)]
    z2 = [z for rate, twist in cases for z in _constant_rate_floor(rate, twist, seed=5).values()]
    assert all(0.4 < z < 2.0 for z in z2), z2
    assert 0.8 < np.mean(z2) < 1.25, z2


# -- the workflow on undithered data -------------------------------------------------------------

CONDITIONS = {
    # counts/rev, sample rate [Hz], duration [s], constant voltages [V], quasi-random runs
    "500 counts @ 100 Hz": SynthConfig(
        voltages=(0.2, 0.7, 2.0, 4.5), random_runs=2, duration_s=60.0, pre_roll_s=30.0,
        sample_rate_hz=100.0, encoder_counts_per_rev=500, angle_noise_std=0.0,
    ),
    "2000 counts @ 500 Hz": SynthConfig(
        voltages=(0.2, 0.7, 2.0, 4.5), random_runs=2, duration_s=40.0, pre_roll_s=30.0,
        sample_rate_hz=500.0, encoder_counts_per_rev=2000, angle_noise_std=0.0,
    ),
    "10000 counts @ 10 kHz": SynthConfig(
        voltages=(0.5, 1.0, 3.0), random_runs=2, duration_s=12.0, pre_roll_s=20.0,
        sample_rate_hz=10_000.0, encoder_counts_per_rev=10_000, angle_noise_std=0.0,
    ),
    "constant voltages only": SynthConfig(
        voltages=(0.2, 0.5, 0.7, 1.0, 2.0, 3.0, 4.5), random_runs=0, duration_s=30.0, pre_roll_s=30.0,
        sample_rate_hz=500.0, encoder_counts_per_rev=2000, angle_noise_std=0.0,
    ),
    "quasi-random voltages only": SynthConfig(
        voltages=(), random_runs=4, duration_s=40.0, pre_roll_s=20.0,
        sample_rate_hz=1000.0, encoder_counts_per_rev=1000, angle_noise_std=0.0,
    ),
}  # fmt: skip


def _verdict(effect, seed, cfg, magnitude=None, bootstrap=20):
    syn = make_dataset(effect, seed=seed, magnitude=magnitude, config=cfg)
    ds = MeasuredDataset(
        preset=cfg.preset, encoder_counts_per_rev=cfg.encoder_counts_per_rev, runs=tuple(syn.runs)
    )
    return analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=bootstrap), seed=seed)


@pytest.mark.parametrize("condition", list(CONDITIONS))
def test_pure_quantisation_gives_none(condition):
    res = _verdict("none", 61, CONDITIONS[condition])
    assert res.effect == "none", res.decision.reason


@pytest.mark.slow
@pytest.mark.parametrize("condition", list(CONDITIONS))
def test_pure_quantisation_gives_none_in_95_percent_of_seeds(condition):
    verdicts = [_verdict("none", seed, CONDITIONS[condition], bootstrap=0).effect for seed in range(70, 90)]
    assert verdicts.count("none") >= 19, verdicts


def test_noise_floor_is_calibrated_without_dither():
    # the mean of z^2 over all windows is near one (the white model: 0.4 here, with runs at 10)
    cfg = CONDITIONS["2000 counts @ 500 Hz"]
    syn = make_dataset("none", seed=62, config=cfg)
    noise = estimate_angle_noise(syn.runs, 2.0 * math.pi / cfg.encoder_counts_per_rev)
    assert noise.additive("upper") == 0.0 and noise.additive("lower") == 0.0
    z2 = []
    for r in syn.runs:
        eq = RunEquations(r, drill_env.load_params("brake"), noise)
        z2 += list(eq.upper.z**2) + list(eq.lower.z**2)
    assert 0.6 < np.mean(z2) < 1.25


@pytest.mark.parametrize(
    ("effect", "magnitude"), [("position_friction_lower", 0.045), ("motor_inductance", 0.01)]
)
def test_a_real_effect_is_still_named_without_dither(effect, magnitude):
    res = _verdict(effect, 63, CONDITIONS["2000 counts @ 500 Hz"], magnitude=magnitude)
    assert res.effect == effect, res.decision.reason


# -- neighbouring windows: correlation must hold across runs -----------------------------------------


def _stats(name, s_ab, pairs=100):
    return RunStatistics(
        name=name, n=pairs + 1, ztz=float(pairs + 1), neighbour=(s_ab, pairs, pairs), n_pairs=pairs
    )


def test_correlation_of_one_run_is_not_structure():
    # one run whose windows all depend on each other (a quantisation line), the others not
    runs = {"a": _stats("a", 120.0)} | {
        k: _stats(k, s) for k, s in zip("bcdef", (3.0, -4.0, 5.0, -2.0, 1.0), strict=True)
    }
    d = decide(runs, ["a", "b", "c", "d"], ["e", "f"], rule=DecisionRule(bootstrap=0), candidates=())
    assert d.structure["neighbour_correlation_z"] > DecisionRule().autocorr_z
    assert not d.structure["correlated"]
    assert d.structure["neighbour_correlation_z_without_top_run"] < 2.0
    assert d.effect == "none"


def test_correlation_common_to_the_runs_is_structure():
    runs = {k: _stats(k, s) for k, s in zip("abcdef", (25.0, 30.0, 22.0, 35.0, 28.0, 20.0), strict=True)}
    d = decide(runs, ["a", "b", "c", "d"], ["e", "f"], rule=DecisionRule(bootstrap=0), candidates=())
    assert d.structure["correlated"]
    assert d.effect == "unexplained"
