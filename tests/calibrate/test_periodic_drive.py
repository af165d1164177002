"""The periodic-drive rule's parts, each against a fact of the signal (issue 13; review of s35_harm, B1 and B3).

:class:`~workbench.calibrate.tracing.PeriodicDrive` finds a repeating drive's frequency (``of``), says whether the
drive repeats as far as a candidate's evidence goes (``repeats_for``: a decaying sine does not), picks the harmonics
a term's repeating part needs (``harmonics_of``: where the loop's line and the term's stand above a line's noise,
``detectable``) and writes a term's repeating part at many harmonics as one column (``repeating_part``: the competitor's
harmonics beyond :data:`~workbench.calibrate.tracing.PERIODIC_FREE_HARMONICS` free pairs). Drives, rates, cycles and
line powers are drawn; each test is a few milliseconds.
"""

import numpy as np
import pytest

from tests.conftest import reduced_draws
from workbench.calibrate.protocol import calibration_protocol
from workbench.calibrate.tracing import PERIODIC_FREE_HARMONICS, PeriodicDrive

_RNG = np.random.default_rng(3590)
#: (shape, rate, f_drive, cycles, seed): 100 Hz-100 kHz, 0.1-50 Hz at >= 40 samples a period, 4-20 cycles, at most
#: 40,000 rows (the estimate's cost grows with the rows times the cycles)
DRIVES = []
for _k in range(8):
    _shape = ("sine", "triangle")[_k % 2]
    while True:
        _rate = float(_RNG.choice([100.0, 1e3, 1e4, 1e5]))
        _f = float(np.exp(_RNG.uniform(np.log(0.1), np.log(50.0))))
        _cyc = int(_RNG.integers(4, 21))
        if _rate / _f >= 40 and _cyc / _f * _rate <= 4e4:
            break
    DRIVES.append((_shape, _rate, _f, _cyc, int(_RNG.integers(1 << 30))))


def _drive(shape, rate, f, cycles, seed, decay_s=None, noise_v=0.01):
    """Rest for a quarter period, then ``cycles`` periods of a 0-100 V sine or triangle (an amplitude decaying with
    time constant ``decay_s`` when given), plus white noise ``noise_v`` (V RMS)."""
    t = np.arange(int(round((cycles + 0.25) / f * rate))) / rate
    ph = np.clip(t - 0.25 / f, 0.0, None) * f
    u = 0.5 * (1.0 - np.cos(2 * np.pi * ph)) if shape == "sine" else 2.0 * np.abs(ph - np.floor(ph + 0.5))
    if decay_s is not None:
        u = u * np.exp(-np.clip(t - 0.25 / f, 0.0, None) / decay_s)
    return t, 100.0 * u + noise_v * np.random.default_rng(seed).standard_normal(t.size)


@pytest.mark.parametrize("shape, rate, f, cycles, seed", DRIVES)
def test_the_drive_frequency_is_found_to_a_hundredth_of_a_cycle_over_the_record(shape, rate, f, cycles, seed):
    """The fundamental's phase, run over the whole record at the estimated frequency, stays within 1 % of a cycle
    of the true one (the harmonic columns' phase at order k drifts k times that)."""
    t, v = _drive(shape, rate, f, cycles, seed)
    d = PeriodicDrive.of(t, v)
    assert d is not None
    assert abs(d.f_hz - f) * (t[-1] - t[0]) < 0.01, (d.f_hz, f)


def test_the_calibration_protocol_and_steps_are_no_periodic_drive():
    """The calibration protocol (three sines, then a chirp) and a staircase of held levels do not repeat."""
    for dt in (1e-3, 1e-4):
        t, v = calibration_protocol(dt_s=dt)
        assert PeriodicDrive.of(t, v) is None
    rng = np.random.default_rng(3591)
    v = np.repeat(rng.uniform(0.0, 100.0, 8), 2000) + 0.01 * rng.standard_normal(16000)
    assert PeriodicDrive.of(np.arange(v.size) * 1e-3, v) is None


@pytest.mark.parametrize("shape, rate, f, cycles, seed", DRIVES[:4])
def test_a_steady_drive_repeats_and_a_decaying_one_does_not(shape, rate, f, cycles, seed):
    """A steady drive's cycle-to-cycle change is its noise (the difference of two noisy samples over sqrt 2: 0.01 V)
    plus the error of reading the previous cycle between samples (linear interpolation: at most ``max|v''| dt^2 / 8``
    on a sine, half a sample's rise at a triangle's corner); a drive decaying by a third over the record changes by
    far more, and a candidate explaining less than that change through the channel's gain is not asked to beat the
    harmonics (``repeats_for`` False) where the steady drive's is."""
    t, v = _drive(shape, rate, f, cycles, seed)
    d = PeriodicDrive.of(t, v)
    dt = 1.0 / rate
    interp = 50.0 * (2 * np.pi * f * dt) ** 2 / 8 if shape == "sine" else 0.5 * 200.0 * f * dt
    assert 0.5 * 0.01 < d.change_v < 2.0 * 0.01 + interp, (d.change_v, interp)
    dur = cycles / f
    t, w = _drive(shape, rate, f, cycles, seed, decay_s=dur / np.log(1.5))
    dd = PeriodicDrive.of(t, w)
    if dd is None:          # (a decay can also spread the reversals past the periodic test: then no rule at all)
        return
    # the drop of a cycle's amplitude: ~100 V (1 - exp(-1 / (f tau))) at the peaks, a fraction of that in RMS
    drop = 100.0 * (1.0 - np.exp(-np.log(1.5) / cycles))
    assert dd.change_v > 0.1 * drop, (dd.change_v, drop)
    assert dd.change_v > 3 * d.change_v, (dd.change_v, d.change_v)
    gain = 1e-7                                         # m/V: a carrier of the drive's shape
    explained = gain * np.sqrt(d.change_v * dd.change_v)     # between what the two drives' changes could carry
    assert d.repeats_for(gain * v, explained)
    assert not dd.repeats_for(gain * w, explained)


def test_noise_alone_makes_a_line_at_one_of_the_harmonics_asked_about_five_percent_of_the_time():
    """White noise records (whole cycles, from row 0): the least-squares line powers at every harmonic below Nyquist
    exceed :meth:`PeriodicDrive.detectable` somewhere in about PERIODIC_LINE_ALPHA of the records (the chi-square of
    two degrees of freedom and Bonferroni over the harmonics asked: at most alpha, close to it for independent lines);
    a line at four times that power is seen in most records."""
    rng = np.random.default_rng(3593)
    rate, f, sig = 1e3, 20.0, 1e-3
    t = np.arange(int(10 * rate / f)) / rate
    d = PeriodicDrive(f, 0)
    ks = np.arange(1, int(0.5 * rate / f))                        # below Nyquist (the 25th is at it)
    X = d.columns(t, ks)
    thr = d.detectable(t, sig, n_tested=ks.size)

    def powers(y):
        a = np.linalg.lstsq(X, y, rcond=None)[0].reshape(-1, 2)
        return 0.5 * (a ** 2).sum(axis=1)                       # mean square of each line
    n = 300
    hits = sum(bool(np.any(powers(sig * rng.standard_normal(t.size)) > thr)) for _ in range(n))
    # binomial(300, 0.05): mean 15, sd 3.8
    assert 5 <= hits <= 27, hits
    line = np.sqrt(2 * 4 * thr) * np.cos(2 * np.pi * 7 * f * t + 0.3)
    seen = sum(bool(powers(line + sig * rng.standard_normal(t.size))[6] > thr) for _ in range(100))
    assert seen >= 90, seen


def test_the_harmonics_asked_are_where_the_loop_shows_free_where_the_term_shows_too():
    """Lines of known power (whole cycles, from row 0): a harmonic is asked when the loop's line, scaled by the
    misfit's share of the loop, is detectable (above :meth:`PeriodicDrive.detectable`), free when the term's is too (the strongest at most
    PERIODIC_FREE_HARMONICS), lumped otherwise; harmonics the loop does not show are neither."""
    rng = np.random.default_rng(3592)
    for _ in range(8):
        rate, f = 1e4, float(rng.uniform(5.0, 40.0))
        n_cyc = int(rng.integers(5, 30))
        f = rate / round(rate / f)                          # an integer period: the lines sit on bins
        t = np.arange(int(round(n_cyc * rate / f))) / rate
        floor = 1e-3
        d = PeriodicDrive(f, 0)
        thr = d.detectable(t, floor)
        ks = np.arange(1, 101)
        p_term = thr * np.exp(rng.uniform(np.log(0.05), np.log(20.0), ks.size))
        p_loop = thr * np.exp(rng.uniform(np.log(0.05), np.log(2000.0), ks.size))
        ph = rng.uniform(0, 2 * np.pi, ks.size)
        term = sum(np.sqrt(2 * p) * np.cos(2 * np.pi * k * f * t + q) for k, p, q in zip(ks, p_term, ph))
        carrier = sum(np.sqrt(2 * p) * np.cos(2 * np.pi * k * f * t) for k, p in zip(ks, p_loop))
        free, lumped = d.harmonics_of(term, t, floor, carrier)
        loop = ks[p_loop > thr]
        both = ks[(p_loop > thr) & (p_term > thr)]
        assert np.array_equal(np.union1d(free, lumped), loop)
        assert free.size == min(both.size, PERIODIC_FREE_HARMONICS) and np.all(np.isin(free, both))
        if both.size > free.size:
            assert p_term[free - 1].min() >= p_term[np.setdiff1d(both, free) - 1].max()
        # a loop shape a hundredth of the loop's power reaches the harmonics where a hundredth of its line shows
        free, lumped = d.harmonics_of(term, t, floor, carrier, share=0.01)
        assert np.array_equal(np.union1d(free, lumped), ks[0.01 * p_loop > thr])


#: make test: the 10 kHz record (103 harmonics: 64 free, 39 lumped) and the 1 kHz one; the 100 kHz one (0.9 s) in full
SPAN_DRAWS = [(1e5, 41.3, 4.3), (1e4, 43.3, 12.7), (1e3, 3.78, 6.1)]


@pytest.mark.parametrize("rate, f, cycles", reduced_draws(SPAN_DRAWS, keep=(1, 2)))
def test_a_periodic_term_is_in_the_span_of_the_free_pairs_and_its_lumped_rest(rate, f, cycles):
    """A term that repeats (hundreds of harmonics, a ramp of ``1 / k`` amplitudes) is, to rounding, a sum of the
    :data:`PERIODIC_FREE_HARMONICS` strongest free pairs and one column, its repeating part at the others: the
    candidate can take none of its repeating part from the competitor; a ring that dies within the first cycle
    (not repeating) keeps at most its share of the average."""
    t = np.arange(int(round((cycles + 0.5) / f * rate))) / rate
    start = int(round(0.5 / f * rate))
    d = PeriodicDrive(f, start)
    kmax = min(int(0.45 * rate / f), 400)
    rng = np.random.default_rng(int(rate))
    ks = np.arange(1, kmax + 1)
    amp = rng.uniform(0.5, 1.0, kmax) / ks
    ph = rng.uniform(0, 2 * np.pi, kmax)
    tt = np.clip(t - t[start], 0.0, None)
    rep = np.zeros(t.size)
    for k, a, q in zip(ks, amp, ph):
        rep[start:] += a * np.cos(2 * np.pi * k * f * tt[start:] + q)
    free = ks[np.argsort(amp)[::-1][:PERIODIC_FREE_HARMONICS]]
    rest = np.setdiff1d(ks, free)
    cols = np.column_stack([d.columns(t, free), d.repeating_part(rep, t, rest)])
    fit, *_ = np.linalg.lstsq(cols, rep, rcond=None)
    assert np.sqrt(np.mean((cols @ fit - rep) ** 2)) < 1e-6 * np.sqrt(np.mean(rep ** 2))
    ring = np.where(tt > 0, np.exp(-tt * f * 5.0) * np.sin(2 * np.pi * 0.37 * kmax * f * tt), 0.0)
    share = d.repeating_part(ring, t, ks)
    assert np.sqrt(np.sum(share ** 2)) < 2.0 / np.sqrt(np.floor(cycles)) * np.sqrt(np.sum(ring ** 2))
