"""Closed-form describing functions of play and PI operators against sampled first harmonics."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from workbench.linearize.describing import control_df, numerical_df, pi_df, play_df
from workbench.plant.hysteresis import PrandtlIshlinskii


def _one_play(r):
    # a lone play of threshold r (a tiny r = 0 weight keeps the operator invertible-shaped)
    return PrandtlIshlinskii(np.array([0.0, r]), np.array([1e-300, 1.0]), np.zeros(2))


@pytest.mark.parametrize("amp, r", [(1.0, 0.3), (2.0, 1.9), (5.0, 0.01), (1.0, 0.5), (7.0, 3.5)])
def test_play_closed_form_matches_the_first_harmonic(amp, r):
    num = numerical_df(_one_play(r), amp, num_points=200_000)
    assert abs(num / play_df(amp, r) - 1) < 1e-6


def test_play_limits():
    # no threshold: the identity; A <= r: the play never moves; A = 2r: Re = 1/2 exactly
    assert play_df(3.0, 0.0) == pytest.approx(1.0)
    assert play_df([0.5, 1.0], 1.0).tolist() == [0, 0]
    assert play_df(1.0, 0.5) == pytest.approx(0.5 - 1j / np.pi, rel=1e-14)


@settings(max_examples=25, deadline=None)
@given(st.floats(0.05, 30.0), st.floats(-50.0, 50.0))
def test_pi_df_is_the_weighted_sum_and_ignores_the_bias(sn_amp, bias):
    # the SN637 operator driven at any bias: the periodic loop depends on the amplitude only
    from workbench.plant import load_plant
    from pathlib import Path
    op = load_plant(Path(__file__).resolve().parents[2] / "plants" / "p888_51_sn637.toml").pzt.hysteresis
    closed = pi_df(op, sn_amp)
    num = numerical_df(op, sn_amp, bias=bias, num_points=20_000)
    assert abs(num - closed) < 1e-6 * abs(closed)


def test_python_control_on_a_single_play():
    op = _one_play(1.0)
    amps = np.array([1.5, 2.0, 4.0, 8.0])
    closed = play_df(amps, 1.0)
    assert np.max(np.abs(control_df(op, amps, num_points=400) / closed - 1)) < 1e-4
    # the analytic method is what python-control uses when asked normally
    from control import describing_function
    from workbench.linearize.describing import PINonlinearity
    assert describing_function(PINonlinearity(op), 2.0) == pytest.approx(complex(closed[1]), rel=1e-12)


def test_python_control_agrees_when_each_amplitude_is_warmed_up(sn637):
    op = sn637.pzt.hysteresis
    amps = np.array([0.5, 2.0, 5.0, 10.0, 17.0])
    closed = pi_df(op, amps)
    warmed = control_df(op, amps, num_points=400)
    assert np.max(np.abs(warmed / closed - 1)) < 2e-5       # 400 points: rectangle-rule error only
    # one sweep carries the state from one amplitude to the next: off by a few per cent
    swept = control_df(op, amps, num_points=400, warm_each=False)
    err = np.abs(swept / closed - 1)
    assert 0.005 < np.max(err[1:]) < 0.06


def test_phase_lag_grows_with_amplitude_on_the_plant_operator(sn637):
    # the voltage-to-charge operator of the quasi-static PZT (C_h in series with C_pp)
    Q = sn637.pzt.terminal_operator().inverse()
    amps = np.array([0.1, 0.3, 1.0, 3.0, 10.0, 20.0, 35.0, 50.0])
    lag = -np.angle(pi_df(Q, amps), deg=True)
    # grows from none (0.1 V moves only the r = 0 play) to ~6 degrees at full range; with 12
    # plays it flattens above ~35 V, where the last thresholds engage (wiggle < 0.05 degree)
    assert lag[0] == 0 and np.all(lag[1:] > 0) and lag[-1] < 20
    assert np.all(np.diff(lag) > -0.05) and lag[-1] > lag[1] + 4
