"""Tests for workbench.calibrate.residual: residual analysis of one channel (MATLAB resid-like)."""

from pathlib import Path

import numpy as np
import pytest
from scipy import signal, stats

from workbench.calibrate.record import Record
from workbench.calibrate.residual import (_covariance_set, _covariances, _welch, analyze_record,
                                          analyze_residual, charge_from_current)

FS = 1000.0


def _t(n, fs=FS):
    return np.arange(n) / fs


def _ar1(rng, n, a):
    e = signal.lfilter([1.0], [1.0, -a], rng.standard_normal(n + 200))   # e_k = a e_{k-1} + w_k
    return e[200:]                          # drop the start-up transient


# --- 1. white residual, independent of the input ---------------------------------------------

def test_white_independent_residual_passes(rng):
    n = 2000
    u = rng.uniform(-1.0, 1.0, n)
    e = rng.standard_normal(n)
    y = np.sin(np.arange(n) / 50.0)
    rep = analyze_residual(_t(n), u, y + e, y, max_lag=50, confidence=0.99)
    assert rep.white and rep.independent
    assert rep.autocorr[0] == 1.0
    np.testing.assert_array_equal(rep.lags, np.arange(51))
    np.testing.assert_array_equal(rep.crosscorr_lags, np.arange(-50, 51))
    assert rep.autocorr.shape == (51,) and rep.crosscorr.shape == (101,)
    assert rep.autocorr_bound == pytest.approx(stats.norm.ppf(0.995) / np.sqrt(n), rel=1e-12)
    # a white residual: P1 ~ R_e(0) R_u(0), the cross bound is close to the white one
    assert rep.crosscorr_bound == pytest.approx(rep.autocorr_bound, rel=0.15)
    np.testing.assert_allclose(rep.residual, e, atol=1e-12)
    assert rep.rms == pytest.approx(np.sqrt(np.mean(e ** 2)))
    assert rep.max_abs == pytest.approx(np.max(np.abs(e)))


def test_band_holds_the_nominal_fraction_over_seeds():
    n, m, conf = 3000, 50, 0.95
    out_auto = out_cross = 0
    for seed in range(20):
        g = np.random.default_rng(seed)
        u = g.standard_normal(n)
        e = g.standard_normal(n)
        rep = analyze_residual(_t(n), u, e, np.zeros(n), max_lag=m, confidence=conf)
        out_auto += np.count_nonzero(np.abs(rep.autocorr[1:]) > rep.autocorr_bound)
        out_cross += np.count_nonzero(np.abs(rep.crosscorr) > rep.crosscorr_bound)
    assert 0.02 <= out_auto / (20 * m) <= 0.09
    assert 0.02 <= out_cross / (20 * (2 * m + 1)) <= 0.09


def test_cross_bound_widens_for_coloured_residual_and_input():
    # Independent AR(0.9) residual and input: P1 = sum_k R_e(k) R_u(k), i.e. the normalized
    # variance factor 1 + 2 sum 0.81^k = 1 + 2 * 0.81 / 0.19 ~ 9.5. With the white bound about
    # half the lags would fall outside; with Ljung's bound about 1 - confidence.
    n, m, conf = 5000, 30, 0.95
    factor = 1 + 2 * 0.81 / 0.19
    outside, ratios = 0, []
    for seed in range(20):
        g = np.random.default_rng(100 + seed)
        u, e = _ar1(g, n, 0.9), _ar1(g, n, 0.9)
        rep = analyze_residual(_t(n), u, e, np.zeros(n), max_lag=m, confidence=conf)
        ratios.append(rep.crosscorr_bound / rep.autocorr_bound)
        outside += np.count_nonzero(np.abs(rep.crosscorr) > rep.crosscorr_bound)
        assert not rep.white
    assert np.median(ratios) == pytest.approx(np.sqrt(factor), rel=0.2)
    assert outside / (20 * (2 * m + 1)) <= 0.12


@pytest.mark.parametrize("n, max_lag", [(110, 50), (4099, 1), (20000, 200)])
def test_fft_covariances_equal_the_direct_sums(n, max_lag):
    # coloured, offset, differently scaled signals: the FFT route must give the direct sums
    g = np.random.default_rng(n)
    e = 3e-7 + 1e-8 * _ar1(g, n, 0.7)
    u = 40.0 + 10.0 * _ar1(g, n, 0.95)
    r_e, r_u, r_eu = _covariance_set(e, u, max_lag)
    direct = (_covariances(e, e, max_lag)[max_lag:], _covariances(u, u, max_lag)[max_lag:],
              _covariances(e, u, max_lag))
    scales = (r_e[0], r_u[0], np.sqrt(r_e[0] * r_u[0]))
    for fast, slow, scale in zip((r_e, r_u, r_eu), direct, scales):
        assert fast.shape == slow.shape
        np.testing.assert_allclose(fast, slow, rtol=1e-10, atol=1e-10 * scale)
    assert r_e[0] == direct[0][0] and r_u[0] == direct[1][0]      # zero lags: the same sums


# --- 2. coloured residual ----------------------------------------------------------------------

def test_ar1_residual_is_not_white(rng):
    n = 4000
    e = _ar1(rng, n, 0.9)
    u = rng.standard_normal(n)
    rep = analyze_residual(_t(n), u, e, np.zeros(n), max_lag=50)
    assert not rep.white
    assert rep.autocorr[1] == pytest.approx(0.9, abs=0.03)
    assert rep.autocorr[2] == pytest.approx(0.81, abs=0.05)


# --- 3. residual correlated with the input ----------------------------------------------------

@pytest.mark.parametrize("shift", [3, -3])
def test_delayed_input_in_residual_peaks_at_its_lag(rng, shift):
    # shift = +3: e(k) = 0.5 u(k-3), the input leads the residual -> peak at lag +3.
    # shift = -3: e(k) = 0.5 u(k+3), the residual leads (feedback-like) -> peak at lag -3.
    n = 3000
    u = rng.standard_normal(n + 6)
    e = 0.5 * u[3 - shift: 3 - shift + n] + 0.05 * rng.standard_normal(n)
    u = u[3:3 + n]
    rep = analyze_residual(_t(n), u, e, np.zeros(n), max_lag=20)
    assert not rep.independent
    assert rep.white                                  # white input -> white residual
    k = int(np.argmax(np.abs(rep.crosscorr)))
    assert rep.crosscorr_lags[k] == shift
    assert rep.crosscorr[k] == pytest.approx(0.5 / np.sqrt(0.25 + 0.0025), abs=0.02)


def test_single_peak_fails_independence_even_at_high_lag_count(rng):
    # one lag of 2 * 100 + 1 is within a 1 % fraction; the family-wise rule still catches it
    n = 5000
    u = rng.standard_normal(n)
    e = 0.2 * np.r_[np.zeros(7), u[:-7]] + rng.standard_normal(n)
    rep = analyze_residual(_t(n), u, e, np.zeros(n), max_lag=100)
    assert np.count_nonzero(np.abs(rep.crosscorr) > rep.crosscorr_bound) <= 2
    assert not rep.independent


# --- 4. fit percent ---------------------------------------------------------------------------

def test_fit_percent(rng):
    n = 500
    t = _t(n)
    y = np.sin(2 * np.pi * 5 * t) + 0.3 * rng.standard_normal(n)
    u = rng.standard_normal(n)
    perfect = analyze_residual(t, u, y, y.copy())
    assert perfect.fit_percent == 100.0
    assert perfect.rms == 0.0 and perfect.max_abs == 0.0
    assert perfect.white and perfect.independent
    assert analyze_residual(t, u, y, np.full(n, y.mean())).fit_percent == pytest.approx(0.0, abs=1e-12)
    c = 0.17
    expected = 100 * (1 - abs(c) * np.sqrt(n) / np.linalg.norm(y - y.mean()))
    rep = analyze_residual(t, u, y, y + c)
    assert rep.fit_percent == pytest.approx(expected, rel=1e-12)
    assert rep.rms == pytest.approx(c) and rep.max_abs == pytest.approx(c)
    assert rep.white and rep.independent                         # a constant error has no structure
    np.testing.assert_array_equal(rep.autocorr, np.r_[1.0, np.zeros(50)])
    assert analyze_residual(t, u, y, -y).fit_percent < 0          # worse than the mean
    assert np.isnan(analyze_residual(t, u, np.ones(n), np.zeros(n)).fit_percent)


# --- spectrum ---------------------------------------------------------------------------------

def test_psd_of_white_noise_and_of_a_sine(rng):
    n, sigma = 20000, 0.3
    t = _t(n)
    u = rng.standard_normal(n)
    rep = analyze_residual(t, u, sigma * rng.standard_normal(n), np.zeros(n), unit="m")
    assert rep.freq_hz[-1] == pytest.approx(FS / 2)
    # one-sided density of white noise: 2 sigma^2 / fs
    assert np.mean(rep.psd[1:-1]) == pytest.approx(2 * sigma ** 2 / FS, rel=0.05)
    assert rep.units["psd"] == "m^2/Hz" and rep.units["rms"] == "m"
    f0 = 125.0
    rep = analyze_residual(t, u, np.sin(2 * np.pi * f0 * t), np.zeros(n))
    assert rep.freq_hz[np.argmax(rep.psd)] == pytest.approx(f0, abs=FS / 256)
    # Parseval: integral of the density is the variance (1/2 for a unit sine)
    assert np.sum(rep.psd) * (rep.freq_hz[1] - rep.freq_hz[0]) == pytest.approx(0.5, rel=0.02)


@pytest.mark.parametrize("n, nperseg", [(2, 2), (300, 256), (1001, 255), (5000, 64)])
def test_batched_welch_equals_scipy(n, nperseg):
    x = 2e-6 + 1e-7 * np.random.default_rng(n).standard_normal(n)
    f_ref, p_ref = signal.welch(x, fs=FS, nperseg=nperseg, detrend="constant", scaling="density")
    f, p = _welch(x, FS, nperseg)
    np.testing.assert_array_equal(f, f_ref)
    np.testing.assert_allclose(p, p_ref, rtol=1e-10, atol=1e-12 * np.max(p_ref))


# --- 5. drift in holds ------------------------------------------------------------------------

def _staircase(fs=100.0):
    # levels 0, 1, 2 V for 3 s each, joined by 0.2 s ramps, and a 0.5 s hold at 3 V (too short)
    knots_t = [0.0, 3.0, 3.2, 6.2, 6.4, 9.4, 9.6, 10.1]
    knots_u = [0.0, 0.0, 1.0, 1.0, 2.0, 2.0, 3.0, 3.0]
    t = np.arange(round(10.1 * fs) + 1) / fs
    return t, np.interp(t, knots_t, knots_u)


def test_holds_and_their_drift_rates():
    t, u = _staircase()
    spans = [(0.0, 3.0), (3.2, 6.2), (6.4, 9.4)]
    rates = [2e-6, -5e-7, 1.3e-6]                   # m/s
    e = 1e-7 * np.sin(7 * t)                        # whatever the residual does between holds
    for (a, b), r in zip(spans, rates):
        inside = (t >= a - 1e-9) & (t <= b + 1e-9)
        e[inside] = 4e-7 + r * (t[inside] - a)
    y_model = 1e-5 * u
    rep = analyze_residual(t, u, y_model + e, y_model, max_lag=20, hold_min_s=1.0, unit="m")
    assert len(rep.holds) == 3
    for hold, (a, b), r, level in zip(rep.holds, spans, rates, (0.0, 1.0, 2.0)):
        assert hold["t_start_s"] == pytest.approx(a, abs=1e-9)
        assert hold["t_end_s"] == pytest.approx(b, abs=1e-9)
        assert hold["input_value"] == pytest.approx(level, abs=1e-12)
        assert hold["drift_rate_per_s"] == pytest.approx(r, rel=1e-6)
        assert hold["drift_total"] == pytest.approx(r * (b - a), rel=1e-6)
    assert rep.units["drift_rate_per_s"] == "m/s"
    # the 0.5 s hold at 3 V appears once the minimum is lowered
    short = analyze_residual(t, u, y_model + e, y_model, max_lag=20, hold_min_s=0.4)
    assert [h["input_value"] for h in short.holds] == pytest.approx([0.0, 1.0, 2.0, 3.0])


def test_holds_with_input_noise_within_tolerance(rng):
    t, u = _staircase()
    noisy = u + rng.uniform(-2e-4, 2e-4, u.size)     # spread < 1e-3 V
    e = 3e-6 * t + 1e-9 * rng.standard_normal(t.size)
    rep = analyze_residual(t, noisy, e, np.zeros(t.size), max_lag=20, hold_tol=1e-3)
    assert len(rep.holds) == 3
    for hold in rep.holds:
        assert hold["drift_rate_per_s"] == pytest.approx(3e-6, rel=1e-2)
        assert hold["t_end_s"] - hold["t_start_s"] == pytest.approx(3.0, abs=0.02)
    # the default tolerance (1e-3 of the 3 V range = 3 mV) also accepts this noise
    assert len(analyze_residual(t, noisy, e, np.zeros(t.size), max_lag=20).holds) == 3
    # a tolerance below the noise finds no hold of 1 s
    assert analyze_residual(t, noisy, e, np.zeros(t.size), max_lag=20, hold_tol=1e-5).holds == []


def test_a_ramp_is_not_a_hold():
    t = _t(3000, fs=100.0)
    u = 0.01 * t                                     # 0.3 V over 30 s, 1e-4 V per sample
    rep = analyze_residual(t, u, np.zeros_like(t), np.zeros_like(t), hold_min_s=1.0)
    # default tol = 3e-4 V: a run spans at most 3 steps (0.03 s)
    assert rep.holds == []


# --- 6. charge from current -------------------------------------------------------------------

def test_charge_from_constant_current_is_a_ramp():
    t = np.linspace(0.0, 2.0, 2001)
    q = charge_from_current(t, np.full(t.size, 3e-3), q0=1e-6)
    np.testing.assert_allclose(q, 1e-6 + 3e-3 * t, rtol=1e-12, atol=1e-18)
    assert q[0] == 1e-6


def test_charge_from_sine_current_matches_closed_form():
    amp, f = 2e-3, 5.0
    w = 2 * np.pi * f
    t = np.linspace(0.0, 1.0, 100001)
    q = charge_from_current(t, amp * np.sin(w * t))
    exact = amp / w * (1 - np.cos(w * t))
    np.testing.assert_allclose(q, exact, rtol=0, atol=1e-6 * np.max(exact))


def test_charge_from_uneven_time():
    t = np.sort(np.r_[0.0, np.random.default_rng(3).uniform(0, 1, 500), 1.0])
    np.testing.assert_allclose(charge_from_current(t, 2 * t), t ** 2, atol=1e-5)


# --- per-channel helper -----------------------------------------------------------------------

def test_analyze_record_integrates_current_for_charge(rng):
    n = 2000
    t = _t(n)
    v = 50 + 50 * np.sin(2 * np.pi * 2 * t)
    cap = 1e-6                                       # F
    q_true = cap * v
    i = np.gradient(q_true, t)
    x = 1e-7 * v
    rec = Record(Path("synthetic.csv"), {}, t, {"voltage_v": v, "current_a": i,
                                                 "displacement_m": x + 1e-9 * rng.standard_normal(n)},
                 1 / FS)
    reports = analyze_record(rec, {"charge_c": q_true, "displacement_m": x}, max_lag=20)
    assert set(reports) == {"charge_c", "displacement_m"}
    assert reports["charge_c"].units["rms"] == "C"
    assert reports["charge_c"].fit_percent > 99.0
    assert reports["displacement_m"].units["psd"] == "m^2/Hz"
    assert reports["displacement_m"].white
    with pytest.raises(ValueError, match="gauge_v"):
        analyze_record(rec, {"gauge_v": v})


# --- 7. bad inputs ----------------------------------------------------------------------------

@pytest.mark.parametrize("case, match", [
    ("length", "shape"),
    ("nan", "finite"),
    ("inf_t", "finite"),
    ("short", "at least 110"),
    ("uneven", "evenly spaced"),
    ("backwards", "increase strictly"),
    ("2d", "1-D"),
])
def test_bad_arrays_raise(case, match):
    n = 300
    t, u, y, m = _t(n), np.zeros(n), np.zeros(n), np.zeros(n)
    if case == "length":
        m = np.zeros(n - 1)
    elif case == "nan":
        y = y.copy()
        y[10] = np.nan
    elif case == "inf_t":
        t = t.copy()
        t[5] = np.inf
    elif case == "short":
        t, u, y, m = t[:109], u[:109], y[:109], m[:109]
    elif case == "uneven":
        t = t.copy()
        t[100:] += 0.5e-3
    elif case == "backwards":
        t = t.copy()
        t[50] = t[49]
    elif case == "2d":
        t, u, y, m = (a.reshape(2, -1) for a in (t, u, y, m))
    with pytest.raises(ValueError, match=match):
        analyze_residual(t, u, y, m, max_lag=50)


def test_minimum_length_is_accepted():
    n = 2 * 50 + 10
    rep = analyze_residual(_t(n), np.arange(n, dtype=float), np.zeros(n), np.zeros(n))
    assert rep.n == n


@pytest.mark.parametrize("kwargs, match", [
    ({"max_lag": 0}, "max_lag"),
    ({"max_lag": 2.5}, "max_lag"),
    ({"confidence": 1.0}, "confidence"),
    ({"confidence": 0}, "confidence"),
    ({"hold_min_s": -1.0}, "hold_min_s"),
    ({"hold_tol": -1e-3}, "hold_tol"),
    ({"hold_tol": float("nan")}, "hold_tol"),
])
def test_bad_parameters_raise(kwargs, match):
    n = 300
    with pytest.raises(ValueError, match=match):
        analyze_residual(_t(n), np.zeros(n), np.zeros(n), np.zeros(n), **kwargs)


def test_charge_from_current_bad_inputs():
    with pytest.raises(ValueError, match="shape"):
        charge_from_current([0.0, 1.0, 2.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        charge_from_current([0.0, 1.0], [1.0, np.nan])
    with pytest.raises(ValueError, match="increase strictly"):
        charge_from_current([0.0, 0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="at least 2"):
        charge_from_current([0.0], [1.0])
    with pytest.raises(ValueError, match="q0"):
        charge_from_current([0.0, 1.0], [1.0, 1.0], q0=float("inf"))
