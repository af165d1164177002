"""The full-PZT describing-function family against closed forms and the small-signal models."""

import dataclasses

import control
import numpy as np
import pytest

from workbench.linearize.describing import pi_df
from workbench.linearize.pzt_describing import pzt_describing_function
from workbench.linearize.small_signal import capacitances, operating_point, small_signal_model


def _resp(sys, f):
    return complex(np.squeeze(sys(2j * np.pi * f))[()] if sys.noutputs == 1 else sys(2j * np.pi * f)[0, 0])


@pytest.fixture(scope="module")
def family(sn637):
    return pzt_describing_function(sn637.pzt, [0.1, 1.0, 3.0, 10.0, 20.0, 30.0, 50.0], [0.1, 1.0, 10.0, 100.0, 1000.0])


def test_quasi_static_family_is_the_closed_form(sn637):
    # R = 0, no creep: x = k_q2x Q[V] with Q the PI operator V -> q; where the amplifier's current limit does not
    # bind, the simulated first harmonic of the whole plant equals k_q2x times the closed-form describing function
    # of Q. Where the closed form's own charge rate dQ[V]/dt on the periodic loop passes a limit (50 V at 1 Hz: ~4 mA
    # against the 2 mA source), the point is saturated (the amplifier slews: R out too since session 37)
    pzt = sn637.pzt.with_resistance(0.0)
    amps = np.array([0.1, 1.0, 5.0, 20.0, 50.0])
    fam = pzt_describing_function(pzt, amps, [1.0])
    q_op = pzt.terminal_operator().inverse()
    closed = pzt.k_q2x_m_per_c * pi_df(q_op, amps)
    t = np.arange(3 * 100_000) / 100_000                   # three periods of 1 Hz, from rest at the bias (50 V)
    rise = np.linspace(pzt.terminal_operator().output_at_rest(), 50.0, 1000)     # rest to the bias
    binds = []
    for amp in amps:
        q = q_op(np.r_[rise, 50.0 + amp * np.sin(2 * np.pi * t)])[rise.size:]
        rate = np.diff(q[200_000:]) * 100_000               # the last period, C/s
        binds.append(rate.max() > pzt.current_limit_source_a or -rate.min() > pzt.current_limit_sink_a)
    binds = np.array(binds)
    assert binds.tolist() == [False, False, False, False, True]
    np.testing.assert_array_equal(fam.saturated[0, :, 0], binds)
    assert np.max(np.abs(fam.x_m_per_v[0, ~binds, 0] / closed[~binds] - 1)) < 2e-5


def test_small_amplitude_tends_to_the_reversal_model(sn637, family):
    # 0.1 V moves only the r = 0 play: the plant is linear with the reversal slope
    c_rev = operating_point(sn637.pzt, 50.0, "reversal").capacitance_f
    rev = small_signal_model(sn637.pzt, c_rev)
    for k, f in enumerate(family.freq_hz[:4]):
        assert family.x_m_per_v[0, 0, k] == pytest.approx(_resp(rev, f), rel=2e-3)
    assert family.thd_x[0, 0, 0] < 1e-6


def test_full_range_tends_to_the_large_signal_secant(sn637, family):
    pzt = sn637.pzt
    caps = capacitances(pzt, 50.0, (0.0, 100.0))
    secant_gain = pzt.k_q2x_m_per_c / (1 / caps["loop_secant_f"] + 1 / pzt.c_pp_f)
    reversal_gain = pzt.k_q2x_m_per_c / (1 / caps["reversal_f"] + 1 / pzt.c_pp_f)
    mags = np.abs(family.x_m_per_v[0, :, 0])                   # 0.1 Hz: quasi-static, no slewing
    assert abs(mags[-1] / secant_gain - 1) < 0.05              # 0-100 V: within 5 % of the loop secant
    assert mags[0] == pytest.approx(reversal_gain, rel=1e-3)
    assert np.all(np.diff(mags) > 0)                           # the gain grows with amplitude in between


def test_phase_lag_at_1_hz(family):
    k = list(family.freq_hz).index(1.0)
    ok = family.linear_ok[0, :, k]
    lag = -np.degrees(np.angle(family.x_m_per_v[0, ok, k]))
    assert ok[:5].all()                                        # up to 20 V the current stays inside its limits
    assert np.all((lag > 0) & (lag < 20))
    assert np.all(np.diff(lag) > 0)                            # grows with amplitude
    # 50 V at 1 Hz needs 314 V/s: more than the 2 mA source limit allows, flagged and not linear
    assert family.saturated[0, -1, k] and not family.linear_ok[0, -1, k]


def test_slewing_is_flagged_where_the_current_limit_says(sn637, family):
    # the current amplitude a linear response would need: 2 pi f A |i/V| against 2 mA
    c_rev = operating_point(sn637.pzt, 50.0, "reversal").capacitance_f
    rev = small_signal_model(sn637.pzt, c_rev)
    for a, amp in enumerate(family.amplitudes_v):
        for k, f in enumerate(family.freq_hz):
            need = amp * abs(complex(rev(2j * np.pi * f)[1, 0]))
            if need < 0.5 * sn637.pzt.current_limit_source_a:
                assert not family.saturated[0, a, k]
            if need > 2.0 * sn637.pzt.current_limit_source_a:
                assert family.saturated[0, a, k]
                assert family.thd_x[0, a, k] > 0.05           # a slewing response is no sine


def test_bias_does_not_matter_for_the_periodic_loop(sn637):
    fam = pzt_describing_function(sn637.pzt, [10.0], [2.0], biases_v=[30.0, 70.0])
    assert fam.x_m_per_v[0, 0, 0] == pytest.approx(fam.x_m_per_v[1, 0, 0], rel=1e-5)


def test_creep_branches_reach_their_periodic_state(sn637_creep):
    # 0.1 V is linear: the family must match the small-signal model with its creep branches,
    # which needs every branch (tau up to 1000 s) at its periodic state after a few periods
    pzt = sn637_creep.pzt
    fam = pzt_describing_function(pzt, [0.1], [0.1, 3.0])
    rev = small_signal_model(pzt, pzt.hysteresis.weights[0])
    for k, f in enumerate(fam.freq_hz):
        assert fam.x_m_per_v[0, 0, k] == pytest.approx(_resp(rev, f), rel=2e-3)
    assert fam.periodic.all() and fam.cycles.max() < 20


def test_current_first_harmonic_and_frd(sn637, family):
    # i = dq/dt and x = k_q2x q: the two harmonics are tied by j w / k_q2x (mode aside, at 10 Hz)
    k = list(family.freq_hz).index(10.0)
    ratio = family.i_a_per_v[0, 0, k] / family.x_m_per_v[0, 0, k]
    assert ratio == pytest.approx(2j * np.pi * 10.0 / sn637.pzt.k_q2x_m_per_c, rel=1e-4)
    frd = family.frd(0, 0)
    assert isinstance(frd, control.FRD) and frd.omega.size == int(family.linear_ok[0, 0].sum())
    rows = family.records()
    assert len(rows) == family.x_m_per_v.size and {"amplitude_v", "bias_v", "freq_hz", "mag_m_per_v",
                                                   "phase_deg"} <= set(rows[0])


def test_bad_grid(sn637):
    with pytest.raises(ValueError, match="multiple of 4"):
        pzt_describing_function(sn637.pzt, [1.0], [1.0], samples_per_period=30)
    with pytest.raises(ValueError, match="positive"):
        pzt_describing_function(sn637.pzt, [0.0], [1.0])
    with pytest.raises(ValueError, match="positive"):
        pzt_describing_function(dataclasses.replace(sn637.pzt), [1.0], [np.nan])


def test_quasi_static_column_matches_the_full_computation(sn637_creep):
    """At 0.1 Hz the quasi-static limit (R and modes left out, creep kept) is the full describing
    function to within the electrical lag 2 pi f R C it neglects; saturation is judged alike."""
    from dataclasses import replace
    from workbench.linearize.pzt_describing import pzt_describing_function, quasi_static_below_hz
    f_hz, phase = 0.1, 1e-3
    f_qs = quasi_static_below_hz(sn637_creep.pzt, phase)
    assert f_hz < f_qs < 1.0                   # the 0.1 Hz column qualifies, the 1 Hz one does not
    lag = phase * f_hz / f_qs                  # 2 pi f tau of the slowest neglected time constant
    weak = replace(sn637_creep.pzt, current_limit_source_a=0.2e-3)    # 50 V at 0.1 Hz draws ~0.4 mA
    for pzt, amps in ((sn637_creep.pzt, (1.0, 20.0)), (weak, (3.0, 50.0))):
        qs = pzt_describing_function(pzt, amps, (f_hz,), quasi_static_phase_rad=phase)
        full = pzt_describing_function(pzt, amps, (f_hz,))
        np.testing.assert_array_equal(qs.saturated, full.saturated)
        ok = full.linear_ok
        assert np.all(np.abs(qs.x_m_per_v[ok] / full.x_m_per_v[ok] - 1) <= 2 * lag)
    assert full.saturated[0, 1, 0] and not full.saturated[0, 0, 0]
