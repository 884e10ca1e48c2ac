"""The measurement chain against an independent implementation (NumPy floor + SciPy's
Butterworth design and lfilter) and against its specification (quantisation step, -3 dB
at 200 rad/s)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal as sg

from drill_env import sensors as S
from drill_env.sensors import SensorConfig, lowpass_coefficients, measure, quantize_angle

FS = 1000.0
TS = 1.0 / FS


def reference_chain(theta_u, theta_l, counts, cutoff=200.0, order=2, fs=FS):
    """Independent implementation: floor to counts, backward difference, SciPy Butterworth.

    The chain starts at rest at the first angle (the sample before it equals it).
    """
    out = []
    for th in (theta_u, theta_l):
        th = np.concatenate([[th[0]], th])
        q = th if counts is None else np.floor(th / (2 * np.pi / counts)) * (2 * np.pi / counts)
        raw = np.diff(q) * fs
        b, a = sg.butter(order, cutoff / (2 * np.pi), btype="low", fs=fs)  # prewarped bilinear design
        out.append((q[1:], raw, sg.lfilter(b, a, raw)))
    return out


def test_filter_coefficients_match_scipy_butterworth():
    for order in (1, 2):
        for cutoff, fs in ((200.0, 1000.0), (50.0, 2000.0), (1000.0, 1000.0)):
            b, a = lowpass_coefficients(cutoff, fs, order)
            bs, as_ = sg.butter(order, cutoff / (2 * np.pi), fs=fs)
            np.testing.assert_allclose(b[: order + 1], bs, rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(a[: order + 1], as_, rtol=1e-12, atol=1e-15)
            # exactly -3 dB at the cut-off (prewarping)
            _, h = sg.freqz(b, a, worN=[cutoff], fs=2 * np.pi * fs)
            assert abs(abs(h[0]) - 1 / math.sqrt(2)) < 1e-12


@pytest.mark.parametrize("counts", [None, 500, 2000, 4096])
@pytest.mark.parametrize("order", [1, 2])
def test_chain_equals_independent_implementation(counts, order):
    rng = np.random.default_rng(counts or 1)
    t = np.arange(1, 3001) * TS
    theta_u = 2.0 * t + 0.4 * np.sin(3.0 * t) + 0.01 * np.cumsum(rng.normal(size=t.size)) * TS
    theta_l = 1.5 * t - 0.3 * np.sin(5.0 * t + 1.0) + rng.uniform(-1e-3, 1e-3, size=t.size)
    m = measure(theta_u, theta_l, {"counts_per_rev": counts, "filter_order": order})
    (qu, du, vu), (ql, dl, vl) = reference_chain(theta_u, theta_l, counts, order=order)
    np.testing.assert_array_equal(m.upper_angle, qu)
    np.testing.assert_array_equal(m.lower_angle, ql)
    np.testing.assert_allclose(m.upper_speed_raw, du, rtol=0, atol=1e-9)
    np.testing.assert_allclose(m.lower_speed_raw, dl, rtol=0, atol=1e-9)
    np.testing.assert_allclose(m.upper_speed, vu, rtol=0, atol=1e-9)
    np.testing.assert_allclose(m.lower_speed, vl, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(m.twist, qu - ql)


@pytest.mark.parametrize("counts", [360, 2000, 10000])
def test_quantisation_step_and_floor(counts):
    r = 2 * np.pi / counts
    rng = np.random.default_rng(counts)
    theta = np.sort(rng.uniform(-20.0, 20.0, size=20000))
    q = quantize_angle(theta, counts)
    k = q / r
    np.testing.assert_allclose(k, np.round(k), atol=1e-6)  # whole counts
    assert np.all(q <= theta + 1e-12) and np.all(theta - q < r * (1 + 1e-9))  # floor: reading <= angle
    # A slow ramp steps by exactly one count at a time.
    ramp = np.linspace(0.0, 50 * r, 10_000)
    m = measure(ramp, np.zeros_like(ramp), {"counts_per_rev": counts})
    steps = np.diff(m.upper_angle)
    assert set(np.round(steps[steps != 0] / r, 9)) == {1.0}
    assert np.max(np.abs(m.upper_angle - ramp)) < r  # no count is missed


def _gain(order, counts, omega, amp_speed=20.0, n_periods=40):
    """Measured gain of true speed -> filtered estimate at omega [rad/s] (least-squares fit)."""
    n = int(round(n_periods * 2 * np.pi / omega * FS)) + 2000
    t = np.arange(1, n + 1) * TS
    theta = 3.0 * t + (amp_speed / omega) * np.sin(omega * t)  # speed 3 + A cos(w t)
    m = measure(
        theta,
        np.zeros_like(theta),
        {"counts_per_rev": counts, "filter_order": order},
        initial_speeds=(3.0 + amp_speed, 0.0),
    )
    sel = slice(2000, None)  # drop the transient of the filter
    X = np.column_stack([np.cos(omega * t[sel]), np.sin(omega * t[sel]), np.ones(t[sel].size)])
    coef, *_ = np.linalg.lstsq(X, m.upper_speed[sel], rcond=None)
    return math.hypot(coef[0], coef[1]) / amp_speed


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("counts", [None, 2000])
def test_minus_3db_at_200_rad_s_from_frequency_response(order, counts):
    omegas = np.geomspace(100.0, 400.0, 15)
    gains = np.array([_gain(order, counts, w) for w in omegas])
    assert gains[0] > 1 / math.sqrt(2) > gains[-1]
    assert np.all(np.diff(gains) < 0)
    # interpolate the crossing of 1/sqrt(2) on a log-frequency axis
    i = int(np.flatnonzero(gains < 1 / math.sqrt(2))[0])
    x0, x1 = np.log(omegas[i - 1]), np.log(omegas[i])
    g0, g1 = gains[i - 1], gains[i]
    w3 = math.exp(x0 + (1 / math.sqrt(2) - g0) * (x1 - x0) / (g1 - g0))
    assert abs(w3 - 200.0) / 200.0 < 0.05, w3
    # and the pass band is flat: DC gain 1 within the differentiation error
    assert abs(_gain(order, counts, 5.0) - 1.0) < 0.01


def test_steady_speed_reads_exactly_without_quantisation():
    t = np.arange(1, 501) * TS
    m = measure(0.7 * t, -0.2 * t, {"counts_per_rev": None}, initial_speeds=(0.7, -0.2))
    np.testing.assert_allclose(m.upper_speed, 0.7, rtol=1e-9)
    np.testing.assert_allclose(m.lower_speed, -0.2, rtol=1e-9)


def test_delay_shifts_the_measurements():
    t = np.arange(1, 2001) * TS
    thu = 1.3 * t + 0.2 * np.sin(7 * t)
    thl = 0.9 * t
    m0 = measure(thu, thl)
    for d in (1, 7, 40):
        md = measure(thu, thl, {"delay_samples": d})
        np.testing.assert_array_equal(md.upper_angle[d:], m0.upper_angle[:-d])
        np.testing.assert_array_equal(md.lower_speed[d:], m0.lower_speed[:-d])
        # before the delay has passed, the rig seen is the one at rest before the first sample
        np.testing.assert_array_equal(md.upper_angle[:d], quantize_angle(np.full(d, thu[0]), 2000))


def test_state_persists_across_chunks():
    """The env runs the chain 50 samples at a time; chunked and whole runs agree exactly."""
    cfg_obj = SensorConfig(angle_noise_std=2e-4, speed_noise_std=0.02, delay_samples=3)
    cfg = cfg_obj.as_array()
    t = np.arange(1, 1001) * TS
    thu, thl = 2.0 * t + 0.1 * np.sin(4 * t), 1.0 * t
    outs = []
    for chunked in (False, True):
        st = np.zeros(S.state_size(3))
        rng = S.rng_state([11, 22, 33, 44])
        S.sensor_reset(cfg, st, 0.0, 0.0, 0.0, 0.0)
        arrays = [np.empty(t.size) for _ in range(6)]
        bounds = range(0, t.size, 50) if chunked else [0]
        for b in bounds:
            e = b + 50 if chunked else t.size
            S._measure_loop(cfg, st, rng, thu[b:e], thl[b:e], *(a[b:e] for a in arrays))
        outs.append(arrays)
    for a, b in zip(outs[0], outs[1], strict=True):
        np.testing.assert_array_equal(a, b)


def test_noise_levels_and_determinism():
    t = np.arange(1, 40001) * TS
    thu, thl = 2.0 * t, 1.0 * t
    clean = measure(thu, thl, {"counts_per_rev": None})
    a = measure(thu, thl, {"counts_per_rev": None, "speed_noise_std": 0.3}, seed=5)
    b = measure(thu, thl, {"counts_per_rev": None, "speed_noise_std": 0.3}, seed=5)
    c = measure(thu, thl, {"counts_per_rev": None, "speed_noise_std": 0.3}, seed=6)
    np.testing.assert_array_equal(a.upper_speed, b.upper_speed)
    assert not np.array_equal(a.upper_speed, c.upper_speed)
    e = a.upper_speed - clean.upper_speed
    assert abs(np.std(e) - 0.3) < 0.3 * 0.03 and abs(np.mean(e)) < 0.01
    assert abs(np.corrcoef(e, a.lower_speed - clean.lower_speed)[0, 1]) < 0.03
    # angle noise goes through quantisation and differentiation: readings stay whole counts
    n = measure(thu, thl, {"angle_noise_std": 1e-3}, seed=1)
    r = 2 * np.pi / 2000
    np.testing.assert_allclose(n.upper_angle / r, np.round(n.upper_angle / r), atol=1e-6)
    assert np.std(n.upper_angle - thu) > 0.8e-3


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("counts_per_rev", 0),
        ("counts_per_rev", 2.5),
        ("sample_rate_hz", 0.0),
        ("cutoff_rad_s", 4000.0),  # above Nyquist at 1 kHz
        ("cutoff_rad_s", -1.0),
        ("filter_order", 3),
        ("angle_noise_std", -1e-3),
        ("speed_noise_std", float("nan")),
        ("delay_samples", -1),
        ("delay_samples", S.MAX_DELAY_SAMPLES + 1),
    ],
)
def test_config_validation_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        SensorConfig(**{field: value})


def test_measure_rejects_bad_input():
    with pytest.raises(ValueError, match="theta_u"):
        measure([0.0, 1.0], [0.0])
    with pytest.raises(ValueError, match="finite"):
        measure([0.0, np.nan], [0.0, 0.0])
    with pytest.raises(ValueError, match="unknown key"):
        measure([0.0], [0.0], {"resolution": 3})
