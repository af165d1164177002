"""Small-signal models: operating points on each branch, the three capacitances, poles and gains."""

import dataclasses

import control
import numpy as np
import pytest

from workbench.linearize.small_signal import (BRANCHES, capacitances, dc_gain_m_per_v, operating_point,
                                              small_signal_model)


def _series(a, b):
    return 1.0 / (1.0 / a + 1.0 / b)


def test_three_capacitances_side_by_side(sn637):
    pzt = sn637.pzt
    caps = capacitances(pzt, 50.0)
    # reversal: only the r = 0 play moves; in series with C_pp it is the spec sheet's 6.0 uF
    assert caps["reversal_f"] == pytest.approx(pzt.hysteresis.weights[0], rel=1e-12)
    assert _series(caps["reversal_f"], pzt.c_pp_f) == pytest.approx(6.0e-6, rel=1e-3)
    assert caps["secant_from_rest_f"] == pytest.approx(30.5e-6, rel=0.01)          # seed Fig. 7
    assert caps["reversal_f"] < caps["ascending_f"] and caps["reversal_f"] < caps["loop_secant_f"]
    # the loop is symmetric about its centre: both branches have one slope at mid-range
    assert caps["ascending_f"] == pytest.approx(caps["descending_f"], rel=1e-9)
    # on the virgin curve at 50 V (V_h ~ 20 V > the largest threshold) every play moves
    assert caps["initial_f"] == pytest.approx(np.sum(pzt.hysteresis.weights), rel=1e-12)


def test_branches_differ_off_centre(sn637):
    up = operating_point(sn637.pzt, 25.0, "ascending")
    down = operating_point(sn637.pzt, 25.0, "descending")
    # below mid-range the ascending branch is near its reversal (few plays), the descending far from it
    assert up.capacitance_f < down.capacitance_f
    assert down.x_m > up.x_m                      # hysteresis: the descending branch lies above


def test_electrical_pole_sits_at_one_over_r_c(sn637):
    pzt = sn637.pzt
    assert pzt.series_resistance_ohm == 80.0
    for branch in BRANCHES:
        c = operating_point(pzt, 50.0, branch).capacitance_f
        sys = small_signal_model(pzt, c)
        electrical = [p for p in sys.poles() if abs(p) < 2 * np.pi * 10e3]
        assert len(electrical) == 1
        expected = 1.0 / (pzt.series_resistance_ohm * _series(c, pzt.c_pp_f))
        assert -electrical[0].real == pytest.approx(expected, rel=1e-9)
    # reversal: 80 ohm with 9.36 uF in series with C_pp -> 332 Hz
    c_rev = operating_point(pzt, 50.0, "reversal").capacitance_f
    f = 1 / (2 * np.pi * 80.0 * _series(c_rev, pzt.c_pp_f))
    assert 320 < f < 340


def test_gains_and_current(sn637, sn637_creep):
    for plant in (sn637, sn637_creep):
        pzt = plant.pzt
        c = 20e-6
        sys = small_signal_model(pzt, c)
        dc = control.dcgain(sys)
        assert dc[0] == pytest.approx(dc_gain_m_per_v(pzt, c), rel=1e-6)     # V -> x, creep settled
        assert abs(dc[1]) < 1e-12                                            # no DC current into a capacitor
        # far above the electrical pole (below the mode) the current is V / R
        i_hf = complex(sys(2j * np.pi * 20e3)[1, 0])
        assert abs(i_hf) == pytest.approx(1 / pzt.series_resistance_ohm, rel=0.02)
    # creep adds its capacitance at DC only
    c = 20e-6
    assert dc_gain_m_per_v(sn637_creep.pzt, c) > dc_gain_m_per_v(sn637.pzt, c)


def test_quasi_static_form(sn637, sn637_creep):
    c = 15e-6
    qs = small_signal_model(sn637.pzt.with_resistance(0.0), c)
    assert qs.noutputs == 1 and qs.output_labels == ["x"]
    assert control.dcgain(qs) == pytest.approx(sn637.pzt.k_q2x_m_per_c * _series(c, sn637.pzt.c_pp_f), rel=1e-6)
    qsc = small_signal_model(sn637_creep.pzt.with_resistance(0.0), c)
    assert control.dcgain(qsc) == pytest.approx(dc_gain_m_per_v(sn637_creep.pzt, c), rel=1e-6)
    # the dynamic form tends to the quasi-static one well below its electrical pole
    dyn = small_signal_model(sn637_creep.pzt, c)
    w = 2j * np.pi * 0.05
    assert complex(dyn(w)[0, 0]) == pytest.approx(complex(np.squeeze(qsc(w))), rel=1e-3)   # RC phase 2.5e-4


def test_mode_is_in_the_model(sn637):
    sys = small_signal_model(sn637.pzt, 20e-6)
    mode = [p for p in sys.poles() if abs(p) > 2 * np.pi * 10e3]
    assert len(mode) == 2
    assert abs(mode[0]) / (2 * np.pi) == pytest.approx(70e3, rel=1e-9)
    assert small_signal_model(dataclasses.replace(sn637.pzt, modes=()), 20e-6).nstates == 1


def test_bad_operating_points(sn637):
    with pytest.raises(ValueError, match="unknown branch"):
        operating_point(sn637.pzt, 50.0, "sideways")
    with pytest.raises(ValueError, match="outside the loop range"):
        operating_point(sn637.pzt, 110.0, "ascending")
    with pytest.raises(ValueError, match="amplifier range"):
        operating_point(sn637.pzt, 50.0, "ascending", v_range=(0.0, 150.0))
    with pytest.raises(ValueError, match="positive"):
        small_signal_model(sn637.pzt, 0.0)
