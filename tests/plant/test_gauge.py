"""Gauge chain: seed numbers, eq. 26/27 identity, the four-probe solve, the sampled chain."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from workbench.plant import (bridge_gain, bridge_output, four_probe_measure, four_probe_solve, gauge_run,
                             gauge_run_equivalent)
from workbench.plant.gauge import (bridge_gain_eq28_printed, bridge_output_eq27, displacement_from_reading,
                                   gauge_summary)


def test_bridge_gain_at_7_5_um_is_the_seeds(sn637):
    # seed 000 sec. 5.2: 354.18 V/m at x0 = 7.5 um, from the derivative of eq. 27
    assert bridge_gain(7.5e-6, sn637.gauge) == pytest.approx(354.18, abs=0.01)
    # the printed eq. 28 (x_pzt in the numerator) cannot give it: it is off by a factor x0
    assert bridge_gain_eq28_printed(7.5e-6, sn637.gauge) < 0.01


@given(st.floats(-30e-6, 30e-6))
@settings(max_examples=100, deadline=None)
def test_eq26_without_imbalance_is_eq27(sn637, x):
    g = sn637.gauge.replace(imbalance_ohm=(0.0, 0.0, 0.0, 0.0))
    # (eq. 26 differences two ratios near 1/2: float rounding leaves ~1e-16 V)
    assert bridge_output(x, g) == pytest.approx(bridge_output_eq27(x, g), rel=1e-9, abs=1e-14)


def test_bridge_gain_is_the_derivative_of_eq27(sn637):
    g, h = sn637.gauge, 1e-9
    for x0 in (0.0, 7.5e-6, 15e-6):
        numeric = (bridge_output_eq27(x0 + h, g) - bridge_output_eq27(x0 - h, g)) / (2 * h)
        assert bridge_gain(x0, g) == pytest.approx(numeric, rel=1e-7)


def test_imbalance_bias_closed_form(sn637):
    # at x = 0 eq. 26 is V_mod [(R_WB - R_WY)/(R_WB + R_WY) - (R_GB - R_YG)/(R_GB + R_YG)]
    g = sn637.gauge
    wy, gb, yg, wb = (350.0 + d for d in g.imbalance_ohm)
    expected = g.modulation_v * ((wb - wy) / (wb + wy) - (gb - yg) / (gb + yg))
    assert gauge_summary(sn637)["bias_v"] == pytest.approx(expected, rel=1e-12)


@given(st.lists(st.floats(349.0, 351.0), min_size=4, max_size=4))
@settings(max_examples=100, deadline=None)
def test_four_probe_solve_round_trip(arms):
    measured = four_probe_measure(arms)
    assert np.allclose(four_probe_solve(measured), arms, rtol=1e-10)


def test_four_probe_refuses_nonsense():
    with pytest.raises(ValueError, match="four positive"):
        four_probe_solve([262.5, np.nan, 262.5, 262.5])


def test_chain_reproduces_the_serial_calibration(any_serial):
    s = gauge_summary(any_serial)
    assert s["calibration_implied_um_per_v"] == pytest.approx(s["calibration_um_per_v"], rel=1e-6)
    assert s["chain_v_per_m"] == pytest.approx(s["bridge_v_per_m"] * 300 * 2 * any_serial.gauge.trim_scale)


def test_sampled_chain_static_reading_and_quantization(sn637):
    g = sn637.gauge
    x = np.full(5, 7.5e-6)
    r = gauge_run(x, g, x_prev_m=7.5e-6, noise=False)
    exact = 2 * 300 * bridge_output(7.5e-6, g)
    lsb = 5.0 / 2 ** 14
    assert np.all(np.abs(r.demod_v - exact) <= lsb)             # ADC quantization only
    assert np.all(np.abs(r.dac_v) <= g.trim_scale * lsb + 5.2 / 2 ** 16)  # mid-stroke reads ~0 V


def test_sampled_chain_delays_by_half_a_period(sn637):
    # a ramp: the average over the two half periods reads x half a period before the period end
    g = sn637.gauge
    slope = 1e-6 / 1e-4                                  # 1 um per period
    x = 7.5e-6 + slope * 1e-4 * np.arange(1, 21)
    r = gauge_run(x, g, x_prev_m=7.5e-6, noise=False)
    reading = displacement_from_reading(r.demod_v, g)
    lag = (x - reading) / slope
    assert np.median(lag[5:]) == pytest.approx(0.5 / g.modulation_hz, rel=0.02)


def test_equivalent_chain_matches_sample_by_sample(sn637):
    g = sn637.gauge
    t = np.arange(4000) * 1e-4
    x = 7.5e-6 + 5e-6 * np.sin(2 * np.pi * 10 * t)
    per = gauge_run(x, g, seed=1)
    eq = gauge_run_equivalent(x, g, seed=2)
    to_m = g.trim_scale * g.calibration_m_per_v
    clean_per = gauge_run(x, g, noise=False)
    clean_eq = gauge_run_equivalent(x, g, noise=False)
    # same signal: the noise-free readings agree to well under an ADC step (referred to x)
    assert np.max(np.abs(clean_per.demod_v - clean_eq.demod_v)) * to_m < 2e-9
    # same noise: the seed's 22 nm RMS (sec. 3.1) in both
    noise = np.std(per.demod_v - clean_per.demod_v) * to_m
    noise_eq = np.std(eq.demod_v - clean_eq.demod_v) * to_m
    assert noise == pytest.approx(22e-9, rel=0.1)
    assert noise_eq == pytest.approx(noise, rel=0.1)


@given(L=st.floats(5e-3, 40e-3), w_frac=st.floats(0.1, 0.9), k=st.floats(1.5, 4.0), xc=st.floats(0.0, 30e-6))
@settings(max_examples=60, deadline=None)
def test_bridge_curvature_is_eq27s_second_derivative_over_twice_its_first(sn637, L, w_frac, k, xc):
    from workbench.plant.gauge import bridge_curvature_per_m
    g = sn637.gauge.replace(rest_length_m=L, rest_width_m=w_frac * L, gauge_factor=k)
    h = 1e-7
    d1 = bridge_gain(xc, g)
    d2 = (bridge_output_eq27(xc + h, g) - 2 * bridge_output_eq27(xc, g) + bridge_output_eq27(xc - h, g)) / h ** 2
    assert bridge_curvature_per_m(g, xc) == pytest.approx(d2 / (2 * d1), rel=1e-4)


def test_linearized_reading_takes_the_bridge_curvature_out(any_serial):
    # a linear calibration at x_c reads x + beta u^2 (u = x - x_c: ~1.4 nm at the ends of the 15 um stroke);
    # with eq. 27's curvature taken out what is left is beta^2 u^3 and the arm imbalance's share: < 1 % of it
    from workbench.plant.gauge import TRIM_CENTER_M, bridge_curvature_per_m, linearized_displacement
    g = any_serial.gauge
    beta = bridge_curvature_per_m(g)
    x = np.linspace(0.0, 15e-6, 61)
    x_lin = displacement_from_reading(g.demodulation_gain * g.amplifier_gain * bridge_output(x, g), g)
    raw = np.max(np.abs(x_lin - x))
    assert raw == pytest.approx(abs(beta) * TRIM_CENTER_M ** 2, rel=0.02)
    assert np.max(np.abs(linearized_displacement(x_lin, beta) - x)) < 0.01 * raw
