"""Fixed-point quantization: response error, exact integrator, rounding bound, worst-case inputs, refusals."""

import control
import numpy as np
import pytest
from scipy import signal

from workbench.export import (ExportError, fixed_point_peaks, node_impulse_responses, quantize, run_fixed,
                              run_float, to_sos)

DT = 1e-4
LIMITS_V = (-20.0, 120.0)
RANGE_V = 2.6
F_MAX_HZ = 3000.0


def _tustin(ctrl):
    return control.sample_system(ctrl, DT, method="tustin")


def _pi_lead_rolloff(gain=5.0):
    """PI with its integral corner at 30 Hz, lead 200-800 Hz, second-order roll-off at 2 kHz."""
    s = control.tf("s")
    w_i, w_z, w_p, w_r = 2 * np.pi * np.array([30.0, 200.0, 800.0, 2000.0])
    return _tustin(gain * (1 + w_i / s) * (1 + s / w_z) / (1 + s / w_p) * w_r**2 / (s**2 + 1.4 * w_r * s + w_r**2))


def _notched():
    """The same with a lag 5-50 Hz and a 1.5 kHz notch: four sections."""
    s = control.tf("s")
    w_n, w_l = 2 * np.pi * 1500.0, 2 * np.pi * np.array([5.0, 50.0])
    notch = (s**2 + 0.1 * w_n * s + w_n**2) / (s**2 + w_n * s + w_n**2)
    return _pi_lead_rolloff() * _tustin(notch * (1 + s / w_l[1]) / (1 + s / w_l[0]))


def _quantize(ctrl, **options):
    gain, sos = to_sos(ctrl)
    return quantize(gain, sos, DT, input_range_v=RANGE_V, output_limits_v=LIMITS_V, f_max_hz=F_MAX_HZ, **options)


CONTROLLERS = {"pi_lead_rolloff": _pi_lead_rolloff, "notched": _notched}


@pytest.fixture(scope="module", params=list(CONTROLLERS))
def design(request):
    ctrl = CONTROLLERS[request.param]()
    return ctrl, _quantize(ctrl)


@pytest.fixture(scope="module")
def fxp(design):
    return design[1]


def test_formats_of_the_realistic_controller():
    fxp = _quantize(_pi_lead_rolloff())
    q = fxp.q_formats
    assert (q["input"], q["a"]) == ("Q2.29", "Q2.29")     # 2.6 V fits 2^2; |a1| <= 2 fits Q2
    assert q["output"] == q["signals"][-1]
    assert fxp.integrator.tolist() == [False, True]
    assert fxp.output_limits == (-20 * 2**fxp.output_frac_bits, 120 * 2**fxp.output_frac_bits)


def test_response_error_is_within_0_1_db_and_1_degree(design):
    """Independently of quantize's own check: python-control's response of the controller as
    designed against the linear controller the integers implement."""
    ctrl, fxp = design
    w = 2 * np.pi * np.geomspace(0.3, F_MAX_HZ, 3000) * DT
    gain_q, sos_q = fxp.quantized_sos()
    ratio = gain_q * signal.sosfreqz(sos_q, worN=w)[1] / ctrl(np.exp(1j * w))
    err_db, err_deg = np.abs(20 * np.log10(np.abs(ratio))), np.abs(np.angle(ratio, deg=True))
    assert err_db.max() < 0.1 and err_deg.max() < 1.0
    assert err_db.max() < 1e-3 and err_deg.max() < 1e-2          # 32-bit coefficients leave a wide margin
    assert fxp.error_db < 1e-3 and fxp.error_deg < 1e-2


def test_integrator_stays_exactly_at_one_and_other_poles_inside(fxp):
    one = 1 << fxp.a_frac_bits
    a1, a2 = fxp.a[-1]
    assert one + a1 + a2 == 0                                     # (1 - z^-1) is a factor, in integers
    radius = [np.max(np.abs(np.roots([one, *a]))) for a in fxp.a[:-1]] + [abs(a2) / one]
    assert max(radius) == pytest.approx(fxp.max_pole_radius, abs=1e-12)
    assert fxp.max_pole_radius < 1.0


def test_tustin_zeros_at_nyquist_stay_exact():
    """The roll-off's zeros at z = -1 stay there, so the error stays tiny up to the Nyquist frequency."""
    gain, sos = to_sos(_notched())
    fxp = quantize(gain, sos, DT, input_range_v=RANGE_V, output_limits_v=LIMITS_V, f_max_hz=4999.0)
    at_nyquist = np.abs(sos[:, 0] - sos[:, 1] + sos[:, 2]) < 1e-12
    assert at_nyquist.any()
    b0, b1, b2 = fxp.b[at_nyquist].T
    np.testing.assert_array_equal(b0 - b1 + b2, 0)
    assert fxp.error_db < 1e-3


def _l1(h):
    return np.sum(np.abs(h))


def _deviation_bound(fxp, e):
    """Largest |run_fixed - run_float| a linear analysis allows over the record ``e`` (no output clamping).

    - coefficients: max|e| * L1(h_q - h), h and h_q the impulse responses of the
      design and of the quantized cascade over len(e) samples (the integrator
      makes their difference grow, the truncated sum stays finite);
    - input rounding: 2^-(f_in + 1) * L1(h_q);
    - in section k, y, s1 and s2 are each rounded once (at most half a word LSB,
      2^-(f_k + 1), plus one floored b product, 2^-(f_k + F)); each error enters
      through 1/A_k and the sections after k (TDF-II: Y A = B X + E_y + z^-1 E_1
      + z^-2 E_2), so it is bounded by 3 (2^-(f_k + 1) + 2^-(f_k + F)) L1(g_k).
    """
    n = len(e)
    impulse = np.zeros(n)
    impulse[0] = 1.0
    gain_q, sos_q = fxp.quantized_sos()
    h = run_float(fxp.gain, fxp.sos, impulse)
    h_q = run_float(gain_q, sos_q, impulse)
    bound = np.max(np.abs(e)) * _l1(h_q - h) + 2.0 ** -(fxp.input_frac_bits + 1) * _l1(h_q)
    for k, f_k in enumerate(fxp.signal_frac_bits):
        g_k = run_float(1.0, np.vstack([[1.0, 0.0, 0.0, *sos_q[k, 3:]], sos_q[k + 1:]]), impulse)
        bound += 3 * (2.0 ** -(f_k + 1) + 2.0 ** -(f_k + fxp.a_frac_bits)) * _l1(g_k)
    return bound


@pytest.mark.parametrize("name, largest_bound_v", [
    # Worst cases over n = 5000 samples; they grow with n because the integrator sums rounding errors
    # (a closed loop removes that drift). Observed deviations are 100-300 times smaller.
    ("pi_lead_rolloff", 1e-2),   # integrator with the 800 Hz lead pole: noise gain ~ n / (1 - 0.60)
    ("notched", 1.0),            # integrator with the 5 Hz lag pole: noise gain ~ n / (1 - 0.997)
])
def test_run_fixed_tracks_run_float_within_the_rounding_bound(name, largest_bound_v, rng):
    """A random record inside the input range (differenced noise keeps the integrator inside the limits)."""
    fxp = _quantize(CONTROLLERS[name]())
    w = rng.uniform(-1.0, 1.0, 5001)
    e = 0.5 * RANGE_V * np.diff(w)
    u_float = run_float(fxp.gain, fxp.sos, e)
    assert np.abs(e).max() <= RANGE_V and LIMITS_V[0] < u_float.min() and u_float.max() < LIMITS_V[1]
    bound = _deviation_bound(fxp, e)
    assert np.abs(run_fixed(fxp, e) - u_float).max() <= bound < largest_bound_v


def test_run_float_is_scipy_sosfilt_without_limits(rng):
    gain, sos = to_sos(_notched())
    e = rng.uniform(-1.0, 1.0, 2000)
    # the same operations, except that sosfilt applies the gain last: the integrator accumulates the difference
    np.testing.assert_allclose(run_float(gain, sos, e), gain * signal.sosfilt(sos, e), rtol=1e-9)


def test_output_clamp_holds_the_integrator(fxp):
    """A full-range step drives the output into the limit; it stays there and recovers at once (anti-windup)."""
    e = np.concatenate([np.full(20000, RANGE_V), np.full(20, -RANGE_V)])
    u = run_fixed(fxp, e)
    assert u[:20000].max() == LIMITS_V[1] and u[19000:20000].min() == LIMITS_V[1]
    assert u[-1] < LIMITS_V[1] - 1.0          # no wound-up integral to unwind
    # the float cascade clamps the same way (up to the open-loop drift of the bound test above)
    np.testing.assert_allclose(u, run_float(fxp.gain, fxp.sos, e, output_limits_v=LIMITS_V), atol=0.05)


def test_worst_case_inputs_do_not_saturate(fxp):
    """For each y, s1, s2 before the last section: the input sign(h) reversed, at full range, reaches
    its L1 bound at the last sample. Nothing saturates, and the bound is used (scaling is tight)."""
    n = 4096
    h = node_impulse_responses(fxp.gain, fxp.sos, n)
    for k in range(len(h) - 1):
        for j in range(3):
            e = RANGE_V * np.sign(h[k, j, ::-1])
            peaks = fixed_point_peaks(fxp, e)
            assert peaks[:-1].max() < 1.0 and peaks[-1, 1:].max() < 1.0
        assert max(fixed_point_peaks(fxp, RANGE_V * np.sign(h[k, j, ::-1]))[k, j] for j in range(3)) > 0.45


def test_no_state_saturates_on_full_range_noise(fxp, rng):
    peaks = fixed_point_peaks(fxp, rng.choice([-RANGE_V, RANGE_V], 20000))
    assert peaks[:-1].max() < 1.0 and peaks[-1, 1:].max() < 1.0


def test_too_few_coefficient_bits_fail_the_response_check():
    with pytest.raises(ExportError, match=r"dB.*Raise coeff_bits \(now 16, at most 32\), lower f_max_hz"):
        _quantize(_pi_lead_rolloff(), coeff_bits=16)


@pytest.mark.parametrize("with_integrator", [False, True])
def test_a_pole_rounded_onto_the_unit_circle_is_refused(with_integrator):
    """A lag pole at 0.9995 (0.8 Hz): with 12-bit coefficients (Q2.9) it rounds to 1."""
    ctrl = control.tf([1.0, -0.99], [1.0, -0.9995], DT)
    if with_integrator:
        ctrl = ctrl * control.tf([1.0, -0.98], [1.0, -1.0], DT)
    with pytest.raises(ExportError, match=r"moves to \|z\| = 1\.0.*raise coeff_bits \(now 12"):
        _quantize(ctrl, coeff_bits=12)


@pytest.mark.parametrize("sections, change, match", [
    ("designed", {"f_max_hz": 5000.0}, "Nyquist frequency 5000 Hz"),
    ("designed", {"coeff_bits": 40}, "coeff_bits must be an integer from 8 to 32"),
    ("designed", {"output_limits_v": (120.0, -20.0)}, "lo < hi"),
    ("reversed", {}, "section 0 of 2 holds an integrator.*Reorder"),
    ("unstable", {}, r"section 0 has a pole at \|z\| = 1.1"),
])
def test_bad_arguments_are_refused(sections, change, match):
    gain, sos = to_sos(_pi_lead_rolloff())
    sos = {"designed": sos, "reversed": sos[::-1], "unstable": np.vstack([[1, 0, 0, 1, -1.1, 0], sos[1:]])}[sections]
    args = {"input_range_v": RANGE_V, "output_limits_v": LIMITS_V, "f_max_hz": F_MAX_HZ, **change}
    with pytest.raises(ExportError, match=match):
        quantize(gain, sos, DT, **args)
