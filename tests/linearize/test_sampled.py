"""Sampled-data model: hold + plant + period average, compute delay, gauge gain with imbalance."""

import control
import numpy as np
import pytest
from scipy.integrate import simpson

from workbench.linearize.sampled import (compute_delay, firmware_plant, gauge_gain_v_per_m, period_average,
                                         sampled_elements)
from workbench.plant.gauge import bridge_output, chain_gain, gauge_run

T = 1e-4


def three_pole_system():
    """A real pole at 300 Hz, a 2 kHz pair with damping 0.05 and a feedthrough D = 0.3."""
    p, w, z = 2 * np.pi * 300, 2 * np.pi * 2000, 0.05
    g = control.tf([0.7 * p], [1, p]) + control.tf([w * w], [1, 2 * z * w, w * w]) + control.tf(0.3, 1)
    return control.ss(g)


def pzt_like_system():
    """V -> m: 0.15 um/V, a 55 Hz series-RC lag and the 70 kHz stack mode (damping 0.02)."""
    p, w = 2 * np.pi * 55, 2 * np.pi * 70e3
    return control.tf([1.5e-7 * p * w * w], np.polymul([1, p], [1, 2 * 0.02 * w, w * w]))


def brute_force_period_means(ss, u, dt, sub=2000):
    """Mean of y over each hold period: exact ZOH steps of dt/sub, then Simpson over the period."""
    fine = control.sample_system(ss, dt / sub, "zoh")
    a, b = np.asarray(fine.A), np.asarray(fine.B)[:, 0]
    c, d = np.asarray(ss.C)[0], float(ss.D[0, 0])
    n = a.shape[0]
    powers = np.empty((sub + 1, n, n))        # a^i, and sum_{j<i} a^j b: states within a period
    powers[0] = np.eye(n)
    forced = np.zeros((sub + 1, n))
    for i in range(sub):
        powers[i + 1] = a @ powers[i]
        forced[i + 1] = a @ forced[i] + b
    x, means = np.zeros(n), []
    for uk in u:
        xs = powers @ x + forced * uk
        y = xs @ c + d * uk                   # the left limit at the period end still sees uk
        means.append(simpson(y, dx=dt / sub) / dt)
        x = xs[-1]
    return np.array(means)


def on_circle(freqs_hz, dt=T):
    return np.exp(1j * 2 * np.pi * np.asarray(freqs_hz) * dt)


def test_period_average_matches_brute_force(rng):
    ss = three_pole_system()
    u = rng.normal(size=50)
    means = brute_force_period_means(ss, u, T)
    r = control.forced_response(period_average(ss, T), U=u).outputs
    # r_k is the mean over period k-1: r_0 = 0 from rest, then the brute-force means shifted by one
    assert r[0] == 0.0
    assert np.max(np.abs(r[1:] - means[:-1])) <= 1e-8 * np.max(np.abs(means))


def test_period_average_is_strictly_proper_with_dc_gain_of_sys_c():
    ss = three_pole_system()
    pa = period_average(ss, T)
    assert pa.dt == T and np.all(pa.D == 0)
    assert control.dcgain(pa) == pytest.approx(control.dcgain(ss), rel=1e-12)


def test_static_gain_gives_gain_times_one_sample_delay():
    # a constant held over a period has that constant as its mean: r_k = D u_{k-1}, i.e. D / z
    pa = period_average(control.tf(0.3, 1), T)
    assert pa.nstates == 1
    for z in (*on_circle([10, 1e3, 4.9e3]), 0.5 + 0.2j, -2.0):
        assert pa(z) == pytest.approx(0.3 / z, rel=1e-14)


def test_first_order_lag_matches_closed_form_mean_of_period():
    a = 2 * np.pi * 500
    lag = control.tf([a], [1, a])
    pa = period_average(lag, T)
    phi = np.exp(-a * T)

    def closed_form(z):
        # x_{k+1} = phi x_k + (1 - phi) u_k; the mean over a period from x with u held is
        # u + (x - u)(1 - phi)/(aT); that mean is the reading one sample later
        x_over_u = (1 - phi) / (z - phi)
        return (1 + (x_over_u - 1) * (1 - phi) / (a * T)) / z

    for f in (10.0, 500.0, 2e3, 4.9e3):
        z = on_circle(f)
        assert pa(z) == pytest.approx(closed_form(z), rel=1e-12)
    # at low frequency the hold and the average each lag by T/2: the phase is the plant's minus omega T
    w = 2 * np.pi * 10.0
    assert np.angle(pa(on_circle(10.0))) == pytest.approx(np.angle(lag(1j * w)) - w * T, abs=1e-6 * w * T)


def test_poles_are_the_sampled_poles_plus_one_at_the_origin():
    ss = three_pole_system()
    pd = period_average(ss, T).poles()
    expected = np.exp(ss.poles() * T)
    assert len(pd) == len(expected) + 1
    for z in expected:
        assert np.min(np.abs(pd - z)) < 1e-12
    assert np.sum(np.abs(pd) < 1e-12) == 1
    assert np.min(np.abs(pd - 1)) > 0.1       # no spurious integrator from the hold or the average


def test_integrator_is_the_delayed_trapezoid():
    # A = 0 is singular; the block exponential needs no inverse. x_{k+1} = x_k + T u_k and the
    # mean over a period is x_k + T u_k / 2, so r = T (z + 1) / (2 z (z - 1)): one pole at z = 1
    pa = period_average(control.tf([1], [1, 0]), T)
    for z in (*on_circle([10, 1e3, 4.9e3]), 0.5 + 0.2j, -2.0):
        assert pa(z) == pytest.approx(T * (z + 1) / (2 * z * (z - 1)), rel=1e-12)
    assert np.sum(np.abs(pa.poles() - 1) < 1e-12) == 1


def test_compute_delay():
    d0 = compute_delay(T, 0)
    assert d0.nstates == 0 and d0.dt == T and float(d0.D[0, 0]) == 1.0
    d3 = compute_delay(T, 3)
    y = control.forced_response(d3, U=np.eye(1, 8)[0]).outputs
    assert np.array_equal(y, np.eye(1, 8, 3)[0])
    z = on_circle([100.0, 3e3])
    assert np.allclose(d3(z), z ** -3, rtol=1e-14)


def test_firmware_plant_gain_and_delay(sn637):
    g, x0, sys = sn637.gauge, 7.5e-6, pzt_like_system()
    fp1 = firmware_plant(sys, g, x0)
    fp2 = firmware_plant(sys, g, x0, delay_samples=2)
    assert fp1.dt == g.period_s
    assert control.dcgain(fp1) == pytest.approx(gauge_gain_v_per_m(x0, g) * control.dcgain(sys), rel=1e-10)
    # one more sample of delay multiplies by 1/z: a phase rotation of exactly -omega T
    z = on_circle([10.0, 500.0, 3e3], g.period_s)
    assert np.allclose(fp2(z) / fp1(z), 1 / z, rtol=1e-10)
    # the named pieces multiply to the plant
    e = sampled_elements(sys, g, x0)
    assert set(e) == {"zoh_and_average", "gauge_gain_v_per_m", "compute_delay"}
    product = e["gauge_gain_v_per_m"] * e["compute_delay"](z) * e["zoh_and_average"](z)
    assert np.allclose(fp1(z), product, rtol=1e-10)
    assert np.allclose(e["zoh_and_average"](z), period_average(sys, g.period_s)(z), rtol=1e-14)


def test_gauge_gain_is_the_slope_of_eq26(sn637):
    g, x0, h = sn637.gauge, 7.5e-6, 1e-7
    numeric = (bridge_output(x0 + h, g) - bridge_output(x0 - h, g)) / (2 * h)
    chain = g.amplifier_gain * g.demodulation_gain * g.trim_scale
    assert gauge_gain_v_per_m(x0, g) == pytest.approx(numeric * chain, rel=1e-8)


def test_gauge_gain_against_chain_gain(sn637):
    g, x0 = sn637.gauge, 7.5e-6
    rel = abs(gauge_gain_v_per_m(x0, g) / chain_gain(x0, g) - 1)
    assert 1e-8 < rel < 5e-3                   # the imbalance moves the slope, slightly
    g0 = g.replace(imbalance_ohm=(0.0, 0.0, 0.0, 0.0))
    for x in (0.0, x0, 15e-6):
        assert gauge_gain_v_per_m(x, g0) == pytest.approx(chain_gain(x, g0), rel=1e-9)


def test_gauge_gain_against_sampled_chain(sn637):
    # Steps of +/-2 um, not nm: with noise off each demod value is off by at most 1 ADC LSB
    # (5 V / 2^14), so the difference is off by at most 2 LSB = 0.61 mV out of ~0.85 V (7e-4),
    # while the curvature of eq. 26 over +/-2 um moves a central difference by only ~3e-9.
    g, x0, h = sn637.gauge, 7.5e-6, 2e-6
    up, down = (gauge_run(np.full(4, x), g, x_prev_m=x, noise=False).demod_v.mean() for x in (x0 + h, x0 - h))
    assert (up - down) / (2 * h) * g.trim_scale == pytest.approx(gauge_gain_v_per_m(x0, g), rel=1e-3)


@pytest.mark.parametrize("dt", [0.0, -1e-4, np.nan, np.inf, "fast"])
def test_bad_sample_time(dt):
    with pytest.raises(ValueError, match="dt_s"):
        period_average(control.tf([1], [1, 1]), dt)
    with pytest.raises(ValueError, match="dt_s"):
        compute_delay(dt)


@pytest.mark.parametrize("sys, match", [
    (control.tf([1], [1, 1], 1e-4), "discrete"),
    (control.tf([1, 1, 1], [1, 1]), "improper"),
    (control.ss(-np.eye(2), np.eye(2), np.eye(2), np.zeros((2, 2))), "SISO"),
    (control.ss([[np.nan]], [[1.0]], [[1.0]], [[0.0]]), "non-finite"),
    (np.ones((1, 1)), "StateSpace or TransferFunction"),
])
def test_bad_system(sys, match):
    with pytest.raises(ValueError, match=match):
        period_average(sys, T)


@pytest.mark.parametrize("samples", [-1, 1.5, 1.0, True])
def test_bad_delay(samples, sn637):
    with pytest.raises(ValueError, match="non-negative integer"):
        compute_delay(T, samples)
    with pytest.raises(ValueError, match="non-negative integer"):
        firmware_plant(control.tf([1], [1e-3, 1]), sn637.gauge, 7.5e-6, delay_samples=samples)
