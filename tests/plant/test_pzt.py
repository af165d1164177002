"""The Fig. 3 PZT simulator against closed forms and conservation laws."""

import dataclasses

import numpy as np
import pytest

from workbench.plant import PZTSimulator


def _no_modes(plant):
    return dataclasses.replace(plant.pzt, modes=())


def test_eq10_charge_to_displacement_is_exact(sn637):
    # F_e = 0: x = T_em / (k_p C_p + T_em^2) q at every sample, whatever the hysteresis did
    sim = PZTSimulator(_no_modes(sn637), 1e-4)
    t = np.arange(20000) * 1e-4
    tr = sim.run(60 + 50 * np.sin(2 * np.pi * 3 * t) * np.exp(-t))
    assert np.allclose(tr.x_m, sn637.pzt.k_q2x_m_per_c * tr.q_c, rtol=1e-12, atol=1e-18)


def test_charge_is_the_integral_of_the_recorded_current(sn637):
    sim = PZTSimulator(sn637.pzt, 1e-4, n_sub=3)
    v = np.concatenate([np.full(500, 90.0), np.full(500, 5.0), 50 + 30 * np.sin(np.arange(2000) / 50)])
    tr = sim.run(v)
    assert np.allclose(np.cumsum(tr.i_a) * 1e-4, tr.q_c, rtol=1e-9, atol=1e-15)


def test_quasi_static_and_dynamic_forms_agree_when_slow(sn637):
    t = np.arange(1, 100001) * 1e-4
    v = 50 - 50 * np.cos(2 * np.pi * 0.1 * t)
    qs = PZTSimulator(sn637.pzt.with_resistance(0.0), 1e-4).run(v)
    dyn = PZTSimulator(sn637.pzt, 1e-4).run(v)
    # RC lag at 0.1 Hz: 2 pi f V tau ~ 1e-4 V-level differences, far below 0.1 % of stroke
    assert np.max(np.abs(qs.x_m - dyn.x_m)) < 1e-3 * qs.x_m.max()


def test_rc_pole_of_a_small_step_at_rest(sn637):
    # a step small enough that only the r = 0 plays move: exact first-order response with
    # tau = R / (dG/dq_h) = R C_inc, C_inc the series of C_h's reversal slope and C_pp
    pz = _no_modes(sn637)
    w0 = pz.hysteresis.weights[0]
    c_inc = 1.0 / (1.0 / w0 + 1.0 / pz.c_pp_f)
    tau = pz.series_resistance_ohm * c_inc
    dt = tau / 50
    sim = PZTSimulator(pz, dt)
    tr = sim.run(np.full(200, 0.01))
    t = np.arange(1, 201) * dt
    assert np.allclose(tr.v_t_v, 0.01 * (1 - np.exp(-t / tau)), rtol=1e-9, atol=1e-14)


def test_current_limits_hold_and_bound_the_slew(sn637):
    pz = _no_modes(sn637)
    sim = PZTSimulator(pz, 1e-5)
    sim.run(np.full(20000, 10.0))
    tr = sim.run(np.concatenate([np.full(60000, 90.0), np.full(60000, 10.0)]))
    i_max, i_min = tr.peak_current_a
    assert i_max == pytest.approx(2e-3, rel=1e-9)     # saturates at +2 mA ...
    assert i_min == pytest.approx(-14e-3, rel=1e-9)   # ... and at -14 mA, never beyond
    # the rise takes at least the charge over the source limit
    rise = tr.t_s[np.argmax(tr.v_t_v > 89.0)] - tr.t_s[0]
    dq = tr.q_c[59999] - tr.q_c[0]
    assert rise >= 0.9 * dq / 2e-3
    # near the seed's "about 2 mA over the stack's capacitance, 200 V/s up, 7x faster down"
    rate = np.diff(tr.v_t_v) / 1e-5
    assert 100 < np.median(rate[rate > 1]) < 400
    assert np.max(-rate) / np.max(rate) > 4


def test_substeps_converge(sn637):
    t = np.arange(5000) * 1e-4
    v = 50 + 40 * np.sign(np.sin(2 * np.pi * 5 * t)) + 5 * np.sin(2 * np.pi * 37 * t)
    coarse = PZTSimulator(sn637.pzt, 1e-4, n_sub=1).run(v)
    fine = PZTSimulator(sn637.pzt, 1e-4, n_sub=20).run(v)
    # one exponential step per sample uses the slope at its start; through current-limited
    # 40 V slews and reversals that costs under 1 % of the excursion against 20 sub-steps
    assert np.max(np.abs(coarse.x_m - fine.x_m)) < 0.01 * np.ptp(fine.x_m)
    mid = PZTSimulator(sn637.pzt, 1e-4, n_sub=5).run(v)
    assert np.max(np.abs(mid.x_m - fine.x_m)) < 0.5 * np.max(np.abs(coarse.x_m - fine.x_m))


def test_open_circuit_instron_recovers_t_em(sn637):
    # R_out in the Instron test: leads open (R huge), V_pea = 0, compressed by 800 N.
    # Eq. 6 on the simulated (x, back EMF) returns T_em exactly; the back EMF lands near Table 1's
    # 11.7-12.6 V and x near its -1.2..-1.3 um.
    sim = PZTSimulator(_no_modes(sn637).with_resistance(1e13), 1e-3)
    f = -800 * np.minimum(np.arange(3000) / 1000, 1.0)
    tr = sim.run(np.zeros(3000), f)
    x, emf = tr.x_m[-1], tr.v_t_v[-1]
    assert (2e8 * x - f[-1]) / emf == pytest.approx(46.71, rel=1e-6)
    assert 10.0 < emf < 13.0 and -1.5e-6 < x < -1.1e-6
    assert -f[-1] / -x == pytest.approx(sn637.pzt.open_circuit_stiffness_n_per_m, rel=1e-3)


def test_voltage_is_clipped_to_the_amplifier_range(sn637):
    # R out: the terminal slews at the current limit (2 mA up: ~0.7 s to 120 V; 14 mA down: ~0.12 s to -20 V), to the
    # range's ends and never past them
    sim = PZTSimulator(sn637.pzt.with_resistance(0.0), 1e-3)
    tr = sim.run(np.r_[np.full(1500, 200.0), np.full(500, -50.0)])
    assert tr.v_t_v[1499] == pytest.approx(120.0, abs=1e-12) and tr.v_t_v[-1] == pytest.approx(-20.0, abs=1e-12)
    assert tr.v_t_v.max() <= 120.0 + 1e-12 and tr.v_t_v.min() >= -20.0 - 1e-12
    # an ideal source at the terminal (no amplifier limit) is clipped alike, in one step
    tr = PZTSimulator(sn637.pzt.terminal_driven(), 1e-3).run(np.array([200.0, -50.0]))
    assert tr.v_t_v.tolist() == pytest.approx([120.0, -20.0])


def test_mode_filters_a_fast_step(sn637):
    # 70 kHz stack mode sampled at 1 MHz: ringing with the mode's period, settling to the static value. The step
    # from an ideal source at the terminal: the amplifier's 2 mA would slew these 10 V over ~30 ms (R out or in)
    sim = PZTSimulator(sn637.pzt.terminal_driven(), 1e-6)
    tr = sim.run(np.full(400, 10.0))
    static = sn637.pzt.k_q2x_m_per_c * tr.q_c[-1]
    assert tr.x_m.max() > 1.5 * static                     # light damping overshoots
    assert tr.x_m[-1] == pytest.approx(static, rel=0.05)
    peaks = np.flatnonzero((tr.x_m[1:-1] > tr.x_m[:-2]) & (tr.x_m[1:-1] > tr.x_m[2:])) + 1
    assert np.median(np.diff(peaks)) * 1e-6 == pytest.approx(1 / 70e3, rel=0.1)


def test_mode_adds_no_sample_delay(sn637):
    # a 100 Hz sine at 10 kHz: the 70 kHz mode should pass it unchanged (phase 0.003 degree);
    # a zero-order hold of each step's end value would lag it by a whole step (3.6 degrees)
    t = np.arange(2000) * 1e-4
    v = 50 + 5 * np.sin(2 * np.pi * 100 * t)
    with_mode = PZTSimulator(sn637.pzt, 1e-4).run(v).x_m
    without = PZTSimulator(dataclasses.replace(sn637.pzt, modes=()), 1e-4).run(v).x_m
    swing = np.ptp(without[1000:])
    assert np.max(np.abs(with_mode[1000:] - without[1000:])) < 1e-3 * swing


def test_bad_inputs(sn637):
    sim = PZTSimulator(sn637.pzt, 1e-4)
    with pytest.raises(ValueError, match="finite"):
        sim.run(np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="one length"):
        sim.run(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="dt_s must be positive"):
        PZTSimulator(sn637.pzt, 0.0)
