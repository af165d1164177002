"""The multiplicative uncertainty weight covers its envelope, tightly, with a stable minimum-phase W(s)."""

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from workbench.linearize.weight import coverage, envelope, fit_weight

F = np.logspace(-1, 4, 200)
S = control.tf("s")


def mag(weight, f_hz):
    return np.abs(weight(2j * np.pi * f_hz))


def test_recovers_a_known_lead_weight():
    w0 = 0.2 * (1 + S / (2 * np.pi * 50)) / (1 + S / (2 * np.pi * 2000))
    ell = mag(w0, F)
    fit = fit_weight(F, ell)
    margin_db = 20 * np.log10(mag(fit.weight, F) / ell)
    assert margin_db.min() >= 0                                   # covered at every grid point
    assert fit.coverage_margin_db == pytest.approx(0.5, abs=1e-9)  # exactly the guard
    assert fit.tightness_db < 2.0
    assert fit.order == 1
    assert np.all(fit.weight.poles().real < 0) and np.all(fit.weight.zeros().real < 0)
    num, den = fit.weight.num[0][0], fit.weight.den[0][0]
    assert len(num) == len(den) == 2                             # biproper, first order
    # the corners are W0's (the weight is W0 up to the guard)
    assert fit.zeros_hz[0] == pytest.approx(50, rel=1e-3)
    assert fit.poles_hz[0] == pytest.approx(2000, rel=1e-3)
    assert fit.gain == pytest.approx(0.2 * 10 ** (0.5 / 20), rel=1e-6)


def test_flat_envelope_gives_a_constant():
    fit = fit_weight(F, np.full(F.size, 0.3), guard_db=1.0)
    assert fit.order == 0 and fit.zeros_hz == () and fit.poles_hz == ()
    assert fit.weight.dt == 0
    assert fit.gain == pytest.approx(0.3 * 10 ** (1.0 / 20), rel=1e-12)
    assert mag(fit.weight, F) == pytest.approx(np.full(F.size, fit.gain), rel=1e-12)


def test_zero_envelope_points_impose_nothing():
    ell = np.full(F.size, 0.1)
    ell[::7] = 0.0
    fit = fit_weight(F, ell, max_order=1)
    assert fit.order == 0
    assert fit.tightness_db == pytest.approx(0.5, abs=1e-9)     # the zeros did not enter the mean


corner = st.floats(np.log10(0.3), np.log10(3000))
factor = st.tuples(corner, corner)


@settings(max_examples=15, deadline=None)
@given(factors=st.lists(factor, max_size=2), gain=st.floats(1e-3, 10), seed=st.integers(0, 2 ** 32 - 1),
       guard=st.sampled_from([0.0, 0.5, 2.0]))
def test_fit_always_covers_and_is_stable_minimum_phase(factors, gain, seed, guard):
    f = np.logspace(-1, 4, 60)
    ell = gain * np.random.default_rng(seed).uniform(0.7, 1.0, f.size)
    for lz, lp in factors:   # first-order lead (lz < lp) or lag (lz > lp)
        ell = ell * np.abs((1 + 1j * f / 10 ** lz) / (1 + 1j * f / 10 ** lp))
    fit = fit_weight(f, ell, max_order=2, guard_db=guard)
    assert np.all(20 * np.log10(mag(fit.weight, f) / ell) >= guard - 1e-9)
    assert np.all(fit.weight.poles().real < 0)
    assert np.all(fit.weight.zeros().real < 0)
    assert len(fit.weight.num[0][0]) == len(fit.weight.den[0][0]) == fit.order + 1


def test_coverage_names_the_member_that_breaks_it():
    w = 0.1 * (1 + S / (2 * np.pi * 100)) / (1 + S / (2 * np.pi * 1000))
    f = np.logspace(0, 4, 41)                                      # 10 points per decade: f[20] = 100 Hz
    safe = 0.5 * mag(w, f) * np.exp(1j * f)                        # 6 dB inside everywhere
    bump = np.zeros(f.size, complex)
    bump[20] = 3.0 * mag(w, f[20:21])[0] * 1j                      # three times |W| at 100 Hz only
    cov = coverage(w, f, {"safe": safe, "bump": bump})
    assert cov.member == "bump"
    assert cov.freq_hz == pytest.approx(100.0)
    assert cov.margin_db == pytest.approx(-20 * np.log10(3.0), abs=1e-9)
    assert not cov.covered
    cov = coverage(w, f, {"safe": safe})
    assert cov.member == "safe" and cov.covered
    assert cov.margin_db == pytest.approx(20 * np.log10(2.0), abs=1e-9)


def test_envelope_is_the_largest_magnitude_per_frequency():
    a = np.array([1 + 1j, 0.1, -3.0])
    b = np.array([0.5, -2j, 1.0])
    assert envelope({"a": a, "b": b}) == pytest.approx([np.sqrt(2), 2.0, 3.0])


@pytest.mark.parametrize("freq, ell, kwargs, match", [
    (F, np.ones(F.size - 1), {}, "shape"),
    (F, np.where(F > 10, np.nan, 1.0), {}, "finite"),
    (F, np.where(F > 10, -0.1, 1.0), {}, ">= 0"),
    (F[::-1], np.ones(F.size), {}, "increasing"),
    (np.linspace(0, 10, 5), np.ones(5), {}, "positive"),
    (F, np.zeros(F.size), {}, "zero everywhere"),
    (F, np.ones(F.size), {"max_order": -1}, "max_order"),
    (F[:2], np.ones(2), {}, "at least 3"),
    (F, np.ones(F.size), {"guard_db": -1.0}, "guard_db"),
])
def test_fit_weight_rejects_bad_input(freq, ell, kwargs, match):
    with pytest.raises(ValueError, match=match):
        fit_weight(freq, ell, **kwargs)


def test_coverage_and_envelope_reject_bad_input():
    w = control.tf([1.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="shape"):
        coverage(w, F, {"a": np.ones(3)})
    with pytest.raises(ValueError, match="nothing to cover"):
        coverage(w, F, {"a": np.zeros(F.size)})
    with pytest.raises(ValueError, match="continuous"):
        coverage(control.tf([1.0], [1.0, 0.5], dt=0.1), F, {"a": np.ones(F.size)})
    with pytest.raises(ValueError, match="empty"):
        envelope({})
    with pytest.raises(ValueError, match="shape"):
        envelope({"a": np.ones(3), "b": np.ones(4)})
