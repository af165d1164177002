"""Step metrics against closed forms (first- and second-order responses)."""

import numpy as np
import pytest
from hypothesis import given, strategies as st

from workbench.design.step import rise_time, step_metrics


@given(tau_s=st.floats(1e-4, 1.0), y0=st.floats(-10, 10), span=st.floats(0.01, 10) | st.floats(-10, -0.01))
def test_first_order_settles_at_tau_ln50_and_rises_in_tau_ln9(tau_s, y0, span):
    dt = tau_s / 2000
    t = np.arange(int(12 * tau_s / dt)) * dt
    y = y0 + span * (1 - np.exp(-t / tau_s))
    overshoot, settle = step_metrics(t, y, y0, y0 + span)
    assert overshoot == 0.0
    assert settle == pytest.approx(tau_s * np.log(50), abs=2 * dt)
    assert rise_time(t, y, y0, y0 + span) == pytest.approx(tau_s * np.log(9), abs=2 * dt)


@given(zeta=st.floats(0.05, 0.9), f_hz=st.floats(1.0, 1e3))
def test_second_order_overshoot_is_the_closed_form(zeta, f_hz):
    wn = 2 * np.pi * f_hz
    wd = wn * np.sqrt(1 - zeta ** 2)
    dt = 2 * np.pi / wd / 4000
    t = np.arange(int(20 / (zeta * wn) / dt)) * dt
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / np.sqrt(1 - zeta ** 2) * np.sin(wd * t))
    overshoot, settle = step_metrics(t, y, 0.0, 1.0)
    assert overshoot == pytest.approx(100 * np.exp(-zeta * np.pi / np.sqrt(1 - zeta ** 2)), rel=1e-3, abs=1e-6)
    assert np.isfinite(settle) and settle <= 1.1 * np.log(50 / np.sqrt(1 - zeta ** 2)) / (zeta * wn) + dt


def test_never_settling_is_nan_and_never_leaving_is_zero():
    t = np.arange(100) * 1e-3
    assert np.isnan(step_metrics(t, 0.5 * np.ones(100), 0.0, 1.0)[1])
    assert step_metrics(t, np.ones(100), 0.0, 1.0) == (0.0, 0.0)
    assert np.isnan(rise_time(t, 0.5 * np.ones(100), 0.0, 1.0))
