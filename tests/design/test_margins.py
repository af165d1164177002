"""Loop margins from frequency samples: closed forms, python-control, NaN gaps, families."""

import json
import math
import warnings
from dataclasses import fields

import control
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from workbench.design.margins import Margins, family_margins, loop_margins, margins_of

DT = 1e-4                      # 10 kHz servo
NYQUIST_HZ = 0.5 / DT


def piezo_loop(wn_hz, zeta, ki_hz, kp):
    """Discrete PI x ZOH second-order piezo mode x one sample of compute delay, at 10 kHz."""
    wn = 2 * np.pi * wn_hz
    plant = control.sample_system(control.tf([wn * wn], [1, 2 * zeta * wn, wn * wn]), DT, "zoh")
    ki = 2 * np.pi * ki_hz
    pi_ctrl = control.tf([kp + ki * DT, -kp], [1, -1], DT)
    return pi_ctrl * plant * control.tf([1], [1, 0], DT)


def is_stable(loop):
    return np.max(np.abs(control.feedback(loop, 1).poles())) < 1


def delay_integrator(freq_hz, k, tau):
    """k exp(-s tau) / s on the imaginary axis."""
    s = 2j * np.pi * freq_hz
    return k * np.exp(-s * tau) / s


# A synthetic loop with three gain crossovers at CROSS_HZ: ln|L| is a cubic in ln(f) with
# those roots, and a phase dip centred on the middle one makes its margin the smallest.
CROSS_HZ = np.array([50.0, 200.0, 800.0])
DIP_RAD, DIP_WIDTH = 1.2, 0.5


def three_crossing_loop(freq_hz):
    x, roots = np.log(freq_hz), np.log(CROSS_HZ)
    logmag = -0.5 * (x - roots[0]) * (x - roots[1]) * (x - roots[2])
    phase = -np.pi / 2 - DIP_RAD * np.exp(-((x - roots[1]) / DIP_WIDTH) ** 2)
    return np.exp(logmag + 1j * phase)


def three_crossing_pm_rad():
    return np.pi / 2 - DIP_RAD * np.exp(-((np.log(CROSS_HZ) - np.log(CROSS_HZ[1])) / DIP_WIDTH) ** 2)


@pytest.mark.parametrize("k, a", [(1.0, 1.0), (4e6, 2 * np.pi * 500), (50.0, 0.2)])
def test_type_one_second_order_loop_matches_closed_form(k, a):
    # k / (s (s + a)): |L| = 1 at w^2 = (sqrt(a^4 + 4 k^2) - a^2) / 2, PM = 90 deg - atan(w / a).
    wc = math.sqrt((math.sqrt(a ** 4 + 4 * k * k) - a * a) / 2)
    f = np.geomspace(wc / 1e3, wc * 1e3, 20000) / (2 * np.pi)
    s = 2j * np.pi * f
    m = loop_margins(f, k / (s * (s + a)))
    pm_deg = 90.0 - math.degrees(math.atan(wc / a))
    assert m.crossover_hz == pytest.approx(wc / (2 * np.pi), rel=1e-4)
    assert m.phase_margin_deg == pytest.approx(pm_deg, rel=1e-4)
    assert m.delay_margin_s == pytest.approx(math.radians(pm_deg) / wc, rel=1e-4)
    assert m.gain_margin_db == math.inf and math.isnan(m.gm_freq_hz)


def test_delay_integrator_matches_closed_form():
    # k e^{-s tau} / s: crossover w = k, PM = pi/2 - k tau; the phase reaches -180 deg at
    # w = pi / (2 tau) and -540 deg at 5 pi / (2 tau): the first sets the gain margin.
    k, tau = 2 * np.pi * 300, 2e-4
    f = np.geomspace(1.0, 2e4, 20000)
    m = loop_margins(f, delay_integrator(f, k, tau))
    assert m.crossover_hz == pytest.approx(k / (2 * np.pi), rel=1e-4)
    assert m.phase_margin_deg == pytest.approx(math.degrees(np.pi / 2 - k * tau), rel=1e-4)
    assert m.delay_margin_s == pytest.approx((np.pi / 2 - k * tau) / k, rel=1e-4)
    assert m.gain_margin_db == pytest.approx(20 * math.log10(np.pi / (2 * tau * k)), rel=1e-4)
    assert m.gm_freq_hz == pytest.approx(1 / (4 * tau), rel=1e-4)


def stable_piezo_loops(count, seed=7):
    rng = np.random.default_rng(seed)
    loops = []
    while len(loops) < count:
        loop = piezo_loop(rng.uniform(1500, 4000), rng.uniform(0.05, 0.3), rng.uniform(100, 600),
                          rng.uniform(0, 0.3))
        if is_stable(loop):
            loops.append(loop)
    return loops


def reference_margins(loop, returnall=False):
    # python-control evaluates the integrator pole at z = 1 as a phase-crossing candidate and
    # forces a RuntimeWarning there; that candidate is discarded, so the warning is noise.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return control.stability_margins(loop, returnall=returnall, method="poly")


def test_discrete_loops_match_python_control():
    # Linear interpolation errs by ~h^2 times the curvature; crossovers on a lightly damped
    # resonance need a grid denser than the 2000-point default for 1e-3 on every number.
    f = np.geomspace(0.01, 0.999999 * NYQUIST_HZ, 20000)
    multiple = 0
    for loop in stable_piezo_loops(6):
        m = margins_of(loop, f)
        gm, pm, _, wpc, wgc, _ = reference_margins(loop)
        multiple += len(reference_margins(loop, returnall=True)[4]) > 1
        assert m.gain_margin_db == pytest.approx(20 * math.log10(gm), rel=1e-3)
        assert m.phase_margin_deg == pytest.approx(pm, rel=1e-3)
        assert m.gm_freq_hz == pytest.approx(wpc / (2 * np.pi), rel=1e-3)
        assert m.pm_freq_hz == pytest.approx(wgc / (2 * np.pi), rel=1e-3)
    assert multiple, "the sample should include a loop whose resonance crosses |L| = 1 again"


@pytest.mark.parametrize("k", [-0.5, -0.2, 0.4, 3.0])
def test_disk_margin_of_static_gain(k):
    # L = k: S - 1/2 = (1 - k) / (2 (1 + k)), so alpha = 2 (1 + k) / |1 - k|; for -1 < k < 0
    # the disk gain margin is exactly the gain 1/|k| that puts L on -1.
    f = np.geomspace(1.0, 1e3, 50)
    m = loop_margins(f, np.full(f.shape, k, dtype=complex))
    alpha = 2 * (1 + k) / abs(1 - k)
    assert m.disk_margin == pytest.approx(alpha, rel=1e-12)
    assert m.disk_phase_margin_deg == pytest.approx(math.degrees(2 * math.atan(alpha / 2)), rel=1e-12)
    if k < 0:
        assert m.disk_gain_margin_db == pytest.approx(20 * math.log10(1 / abs(k)), rel=1e-12)
    else:
        assert m.disk_gain_margin_db == math.inf


def test_disk_margin_matches_python_control():
    loop = stable_piezo_loops(1)[0]
    f = np.geomspace(0.01, 0.999999 * NYQUIST_HZ, 5000)
    dm, dgm, dpm = control.disk_margins(loop, 2 * np.pi * f, skew=0.0)
    m = margins_of(loop, f)
    assert m.disk_margin == pytest.approx(dm, rel=1e-3)
    assert m.disk_gain_margin_db == pytest.approx(dgm, rel=1e-3)
    assert m.disk_phase_margin_deg == pytest.approx(dpm, rel=1e-3)


def test_sensitivity_peaks_match_brute_force():
    loop = piezo_loop(2500, 0.08, 300, 0.1)
    m = margins_of(loop)  # default 2000-point grid; the peaks are refined between samples
    f = np.geomspace(0.01, 0.999999 * NYQUIST_HZ, 1_000_000)
    resp = loop(np.exp(2j * np.pi * f * DT))
    sens = 1 / (1 + resp)
    for peak_db, peak_hz, mag in ((m.s_peak_db, m.s_peak_hz, np.abs(sens)),
                                  (m.t_peak_db, m.t_peak_hz, np.abs(resp * sens)),
                                  (-20 * math.log10(m.disk_margin), m.disk_freq_hz, np.abs(sens - 0.5))):
        k = np.argmax(mag)
        assert peak_db == pytest.approx(20 * math.log10(mag[k]), abs=0.01)  # unrefined: 0.04 dB off
        assert peak_hz == pytest.approx(f[k], rel=1e-3)


def test_multiple_gain_crossovers_report_smallest_margin_and_highest_crossover():
    f = np.geomspace(5.0, 8000.0, 20000)
    m = loop_margins(f, three_crossing_loop(f))
    pm = three_crossing_pm_rad()
    delays = pm / (2 * np.pi * CROSS_HZ)
    assert m.phase_margin_deg == pytest.approx(math.degrees(pm.min()), rel=1e-4)
    assert m.pm_freq_hz == pytest.approx(CROSS_HZ[1], rel=1e-4)
    assert m.crossover_hz == pytest.approx(CROSS_HZ[2], rel=1e-4)
    assert m.delay_margin_s == pytest.approx(delays.min(), rel=1e-4)
    assert m.dm_freq_hz == pytest.approx(CROSS_HZ[np.argmin(delays)], rel=1e-4)


def test_gain_margin_is_the_one_nearest_0_db():
    # |L| = (f0 / f)^2 with a phase dip to -270 deg that crosses -180 deg where |L| = 10
    # (GM -20 dB: a conditionally stable loop) and where |L| = 1/2 (GM +6 dB). The +6 dB is
    # the binding one, as in python-control; the signed minimum would report -20 dB.
    f0 = 100.0
    xa, xb = math.log(f0 / math.sqrt(10)), math.log(f0 * math.sqrt(2))
    width = (xb - xa) / 2 / math.sqrt(math.log(2))
    f = np.geomspace(1.0, 1e4, 20000)
    x = np.log(f)
    phase = -np.pi / 2 - np.pi * np.exp(-((x - (xa + xb) / 2) / width) ** 2)
    m = loop_margins(f, (f0 / f) ** 2 * np.exp(1j * phase))
    assert m.gain_margin_db == pytest.approx(20 * math.log10(2), rel=1e-4)
    assert m.gm_freq_hz == pytest.approx(f0 * math.sqrt(2), rel=1e-4)


@pytest.mark.parametrize("gap", [1, 2])
def test_nan_gap_hides_the_crossing_inside_it_only(gap):
    f = np.geomspace(5.0, 8000.0, 20000)
    loop = three_crossing_loop(f)
    loop[(f > 0.8 * CROSS_HZ[gap]) & (f < 1.2 * CROSS_HZ[gap])] = np.nan
    m = loop_margins(f, loop)
    kept = np.arange(3) != gap
    pm = three_crossing_pm_rad()[kept]
    # Interpolating across the gap would find the hidden crossing from the sign change.
    assert m.phase_margin_deg == pytest.approx(math.degrees(pm.min()), rel=1e-4)
    assert m.pm_freq_hz == pytest.approx(CROSS_HZ[kept][np.argmin(pm)], rel=1e-4)
    assert m.crossover_hz == pytest.approx(CROSS_HZ[kept].max(), rel=1e-4)


def test_nan_gap_hides_the_phase_crossing_inside_it():
    k, tau = 2 * np.pi * 300, 2e-4
    f = np.geomspace(1.0, 2e4, 20000)
    loop = delay_integrator(f, k, tau)
    loop[(f > 1000) & (f < 1500)] = np.nan          # around the first crossing, 1250 Hz
    m = loop_margins(f, loop)
    assert m.gm_freq_hz == pytest.approx(5 / (4 * tau), rel=1e-4)
    assert m.gain_margin_db == pytest.approx(20 * math.log10(5 * np.pi / (2 * tau * k)), rel=1e-4)


def test_family_names_the_worst_member():
    k, tau = 2 * np.pi * 300, 2e-4
    f = np.geomspace(1.0, 2e4, 4000)
    base = delay_integrator(f, k, tau)
    scales = {"sn637": 1.0, "sn629@2V": 2.0, "sn618": 0.5, "sn637@tol+": 1.5}
    loops = {name: c * base for name, c in scales.items()}
    loops["sn618"][(f > 3000) & (f < 4000)] = np.nan   # a member left out of one band
    rows, worst = family_margins(f, loops)

    assert [r["member"] for r in rows] == list(scales)
    assert set(rows[0]) == {"member"} | {fld.name for fld in fields(Margins)}
    for metric in ("gain_margin_db", "phase_margin_deg", "delay_margin_s", "disk_margin", "s_peak_db",
                   "t_peak_db", "crossover_hz_max"):
        assert worst[metric]["member"] == "sn629@2V", metric
    assert worst["crossover_hz_min"]["member"] == "sn618"
    assert worst["crossover_hz_min"]["value"] == pytest.approx(0.5 * k / (2 * np.pi), rel=1e-4)
    # Scaling L by c lowers every gain margin by 20 log10(c) at unchanged phase crossovers.
    gm = {r["member"]: r["gain_margin_db"] for r in rows}
    assert worst["gain_margin_db"]["value"] == pytest.approx(gm["sn637"] - 20 * math.log10(2), abs=1e-9)
    assert worst["gain_margin_db"]["freq_hz"] == pytest.approx(1 / (4 * tau), rel=1e-4)
    assert worst["s_peak_db"]["value"] == max(r["s_peak_db"] for r in rows)


def test_as_dict_is_json_ready():
    f = np.geomspace(1.0, 1e3, 200)
    m = loop_margins(f, 10 / (2j * np.pi * f))
    d = m.as_dict()
    assert list(d) == [fld.name for fld in fields(Margins)]
    assert all(type(v) is float for v in d.values())
    assert d["gain_margin_db"] == math.inf
    assert json.loads(json.dumps(d))["phase_margin_deg"] == pytest.approx(90.0)


@given(perturbation=arrays(np.float64, (4, 4), elements=st.floats(-0.4, 0.4)))
@settings(max_examples=20, deadline=None)
def test_margins_invariant_under_similarity_transform(perturbation):
    ss = control.ss(piezo_loop(2500, 0.15, 300, 0.1))
    t = np.eye(4) + perturbation
    assume(np.linalg.cond(t) < 1e3)
    t_inv = np.linalg.inv(t)
    moved = control.ss(t @ ss.A @ t_inv, t @ ss.B, ss.C @ t_inv, ss.D, DT)
    f = np.geomspace(10.0, 0.999999 * NYQUIST_HZ, 400)  # coarse: invariance holds on any grid
    a, b = margins_of(ss, f).as_dict(), margins_of(moved, f).as_dict()
    np.testing.assert_allclose(list(b.values()), list(a.values()), rtol=1e-6)


@pytest.mark.parametrize("freq_hz, loop, match", [
    ([1.0, 3.0, 2.0], [1, 1, 1], "strictly increasing"),
    ([0.0, 1.0, 2.0], [1, 1, 1], "positive"),
    ([1.0, 2.0, 3.0], [1, 1], "shape of freq_hz"),
    ([1.0, 2.0, 3.0], [np.nan] * 3, "no finite sample"),
])
def test_loop_margins_rejects_bad_input(freq_hz, loop, match):
    with pytest.raises(ValueError, match=match):
        loop_margins(freq_hz, loop)


def test_family_and_system_errors_say_what_is_wrong():
    f = [1.0, 2.0, 3.0]
    with pytest.raises(ValueError, match="loops is empty"):
        family_margins(f, {})
    with pytest.raises(ValueError, match="family member 'sn618'.*no finite sample"):
        family_margins(f, {"sn637": [1, 2, 3], "sn618": [np.nan] * 3})
    with pytest.raises(TypeError, match="python-control LTI"):
        margins_of(np.ones(3))
    with pytest.raises(ValueError, match="must be SISO"):
        margins_of(control.ss(-np.eye(2), np.eye(2), np.eye(2), 0))
    with pytest.raises(ValueError, match="unspecified sample time"):
        margins_of(control.tf([1], [1, -0.5], True))
    with pytest.raises(ValueError, match="above the Nyquist frequency 5000.0 Hz"):
        margins_of(control.tf([1], [1, -0.5], DT), np.geomspace(1.0, 6e3, 10))


@pytest.mark.parametrize("dt", [None, 1e-4])
def test_vectorized_response_equals_python_control(dt):
    """design.margins.response: the same values as control.frequency_response (ss and tf, c and d)."""
    import control
    from workbench.design.margins import response
    sys = control.ss(control.tf([1.0, 30.0, 4e4], [1.0, 2.0, 3e5, 1e6, 2e3]))
    if dt is not None:
        sys = control.c2d(sys, dt, "tustin")
    f = np.geomspace(0.1, 4900.0, 200)
    ref = np.asarray(control.frequency_response(sys, 2 * np.pi * f).complex).ravel()
    np.testing.assert_allclose(response(sys, f), ref, rtol=1e-9)
    tf = control.tf(sys)
    ref_tf = np.asarray(control.frequency_response(tf, 2 * np.pi * f).complex).ravel()
    np.testing.assert_allclose(response(tf, f), ref_tf, rtol=1e-9)


def test_nominal_plant_is_minimal_and_keeps_the_servo_band(sn637_creep):
    """The nominal (ascending branch at 50 V, gauge at mid-stroke) drops the five creep states: the servo-band
    response stays within 1 % of the full small-signal model above 5 Hz, and the sampled plant has no pole left
    near z = 1 (the creep branches put five within 1e-6 of it)."""
    import control
    from workbench.design.nominal import nominal_plant
    from workbench.linearize.small_signal import small_signal_model
    nom = nominal_plant(sn637_creep)
    full = nom.gauge_v_per_m * small_signal_model(sn637_creep.pzt, nom.capacitance_f)[0, 0]
    assert nom.truncated == 5 and nom.continuous.nstates == full.nstates - 5
    f = np.geomspace(5.0, 4000.0, 50)
    w = 2 * np.pi * f
    ratio = (np.asarray(control.frequency_response(nom.continuous, w).complex).ravel()
             / np.asarray(control.frequency_response(full, w).complex).ravel())
    assert np.max(np.abs(ratio - 1)) < 0.01
    assert np.min(np.abs(nom.firmware.poles() - 1)) > 1e-3
