"""Second-order sections: round trips, pairing order, normalization, odd orders, delays, errors."""

import control
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from workbench.export import ExportError, from_sos, to_sos

DT = 1e-4
F_HZ = np.geomspace(1.0, 4000.0, 200)
Z = np.exp(2j * np.pi * F_HZ * DT)


def _pairs(draw, n, radius):
    out = []
    for _ in range(n):
        p = draw(radius) * np.exp(1j * draw(st.floats(0.05, 3.0)))
        out += [p, p.conjugate()]
    return out


@st.composite
def controllers(draw):
    """Random stable controllers, order 1 to 10, optionally with an integrator."""
    integrator = draw(st.booleans())
    n_real = draw(st.integers(0, 4))
    n_pair = draw(st.integers(0 if n_real + integrator else 1, 3))
    poles = [1.0] * integrator + [draw(st.floats(-0.95, 0.95)) for _ in range(n_real)]
    poles += _pairs(draw, n_pair, st.floats(0.0, 0.95))
    n_zero_pair = draw(st.integers(0, len(poles) // 2))
    n_zero_real = draw(st.integers(0, len(poles) - 2 * n_zero_pair))
    zeros = [draw(st.one_of(st.just(-1.0), st.floats(-1.5, 1.5))) for _ in range(n_zero_real)]
    zeros += _pairs(draw, n_zero_pair, st.floats(0.0, 1.5))
    gain = draw(st.floats(0.01, 100.0)) * draw(st.sampled_from([-1.0, 1.0]))
    return control.zpk(zeros, poles, gain, DT)


def _realistic():
    s = control.tf("s")
    w_i, w_z, w_p, w_r = 2 * np.pi * np.array([30.0, 200.0, 800.0, 2000.0])
    ctrl = 5.0 * (1 + w_i / s) * (1 + s / w_z) / (1 + s / w_p) * w_r**2 / (s**2 + 1.4 * w_r * s + w_r**2)
    return control.sample_system(ctrl, DT, method="tustin")


def _relative_error(ctrl, other):
    h = ctrl(Z)
    return np.abs(other(Z) - h) / np.abs(h)


def _evaluation_error(ctrl):
    """Relative error bound of evaluating a transfer function's polynomials in double precision.

    A polynomial p with coefficients c cannot be evaluated (or even stored) more
    accurately than eps * sum|c_i| / |p(z)| on |z| = 1; near a cluster of poles
    (an integrator next to slow lags, at 1 Hz) that exceeds 1e-9 for any method.
    """
    tf = control.tf(ctrl)
    num, den = tf.num[0][0], tf.den[0][0]
    eps = np.finfo(float).eps
    return eps * (np.sum(np.abs(num)) / np.abs(np.polyval(num, Z)) + np.sum(np.abs(den)) / np.abs(np.polyval(den, Z)))


@settings(max_examples=60, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(controllers())
def test_round_trip_matches_the_frequency_response(ctrl):
    """1e-9 relative, plus (at ill-conditioned frequencies) what double-precision polynomials can resolve."""
    gain, sos = to_sos(ctrl)
    tol = 1e-9 + 1000 * _evaluation_error(ctrl)
    assert np.all(_relative_error(ctrl, from_sos(gain, sos, DT)) < tol)


@pytest.mark.parametrize("as_ss", [False, True])
def test_round_trip_of_a_realistic_controller_is_within_1e_9(as_ss):
    """PI (30 Hz), lead 200-800 Hz, 2 kHz roll-off by Tustin, as TF or SS: 1e-9 at every frequency."""
    ctrl = control.ss(_realistic()) if as_ss else _realistic()
    gain, sos = to_sos(ctrl)
    assert np.all(_relative_error(ctrl, from_sos(gain, sos, DT)) < 1e-9)


@settings(max_examples=30, deadline=None, derandomize=True, database=None)
@given(controllers())
def test_sections_are_normalized_and_ordered(ctrl):
    gain, sos = to_sos(ctrl)
    assert np.all(sos[:, 3] == 1.0)
    assert np.all(np.max(np.abs(sos[:, :3]), axis=1) == 1.0)   # the largest numerator coefficient is +/-1 ...
    assert np.all(np.max(sos[:, :3], axis=1) == 1.0)           # ... and it is +1
    # poles nearest the unit circle last
    distance = [np.min(np.abs(1 - np.abs(np.roots(row[3:])))) for row in sos]
    assert np.all(np.diff(distance) <= 1e-12)
    # an integrator is exact and in the last section
    if np.any(np.abs(ctrl.poles() - 1.0) < 1e-6):
        assert abs(1.0 + sos[-1, 4] + sos[-1, 5]) < 1e-15


@pytest.mark.parametrize("num, den", [
    ([1.2, -1.0], [1.0, -1.0]),                                        # PI: one first-order section
    ([1.0], [1.0, -0.5]),                                              # one pole, one sample of delay
    ([2.0, -1.5, 0.2], np.poly([0.8, 0.6, 0.3])),                      # order 3, one sample of delay
    (np.poly([0.3, -1.0, 0.9]), np.convolve([1.0, -1.0], np.poly([0.5 + 0.3j, 0.5 - 0.3j])).real),  # integrator
])
def test_odd_orders_have_one_first_order_section(num, den):
    ctrl = control.tf(num, den, DT)
    gain, sos = to_sos(ctrl)
    first_order = (sos[:, 2] == 0.0) & (sos[:, 5] == 0.0)
    assert first_order.sum() == 1
    assert np.all(_relative_error(ctrl, from_sos(gain, sos, DT)) < 1e-9)


def test_delay_is_kept():
    """1/(z - 0.5) is z^-1 / (1 - 0.5 z^-1): the numerator tap moves right, not a zero at z = 0."""
    gain, sos = to_sos(control.tf([1.0], [1.0, -0.5], DT))
    assert gain == 1.0
    np.testing.assert_array_equal(sos, [[0.0, 1.0, 0.0, 1.0, -0.5, 0.0]])


def test_static_gain_is_one_trivial_section():
    """The form of controllers/example_p250_limit_cycle.json."""
    gain, sos = to_sos(control.tf([250.0], [1.0], DT))
    assert gain == 250.0
    np.testing.assert_array_equal(sos, [[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]])


def test_integrator_is_exact_after_roots():
    """Tustin leaves the integrator a few ulp off z = 1; the last section holds exactly (1 - z^-1)(1 - p z^-1)."""
    ctrl = _realistic()
    assert np.min(np.abs(np.roots(ctrl.den[0][0]) - 1.0)) > 0.0
    gain, sos = to_sos(ctrl)
    assert sos[-1, 4] == -(1.0 + sos[-1, 5])


def test_from_sos_drops_shared_origin_factors():
    tf = from_sos(2.0, [[1.0, -0.5, 0.0, 1.0, -1.0, 0.0]], DT)
    np.testing.assert_array_equal(tf.num[0][0], [2.0, -1.0])
    np.testing.assert_array_equal(tf.den[0][0], [1.0, -1.0])
    assert tf.dt == DT


@pytest.mark.parametrize("ctrl, error, match", [
    (control.tf([1.0], [1.0, 1.0]), ExportError, "continuous-time.*sample_system"),
    (control.ss(np.eye(2) * 0.5, np.eye(2), np.eye(2), 0, DT), ExportError, "SISO"),
    (control.tf([1.0, 0.0, 0.0], [1.0, -0.5], DT), ExportError, "improper.*add 1 roll-off"),
    (control.tf([0.0], [1.0], DT), ExportError, "identically zero"),
    ([1.0, 2.0], TypeError, "TransferFunction or StateSpace"),
])
def test_bad_controllers_are_refused(ctrl, error, match):
    with pytest.raises(error, match=match):
        to_sos(ctrl)


@pytest.mark.parametrize("sos, dt, match", [
    ([[1.0, 0.0, 0.0, 1.0, 0.0]], DT, "rows"),
    ([[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]], DT, "a0 != 0"),
    ([[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]], 0.0, "positive sample time"),
])
def test_from_sos_refuses_bad_input(sos, dt, match):
    with pytest.raises(ExportError, match=match):
        from_sos(1.0, sos, dt)
