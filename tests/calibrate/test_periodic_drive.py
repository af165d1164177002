"""The periodic-drive rule's parts, each against a fact of the signal (issue 13; review of s35_harm, B1 and B3).

:class:`~workbench.calibrate.tracing.PeriodicDrive` finds a repeating drive's frequency (``of``), says whether the
drive repeats as far as a candidate's evidence goes (``repeats_for``: a decaying sine does not), picks the harmonics
a term's repeating part needs (``harmonics_of``: the strongest until what is left out is below the noise floor's
power) and writes a term's repeating part at many harmonics as one column (``repeating_part``: the competitor's
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


def test_the_harmonics_kept_leave_out_less_than_the_floor_and_no_fewer_would():
    """Lines of known power (whole cycles, from row 0): the harmonics kept are the strongest ones, and the power
    of those left out is below ``floor ** 2`` while leaving out the weakest kept one too would not be."""
    rng = np.random.default_rng(3592)
    for _ in range(8):
        rate, f = 1e4, float(rng.uniform(5.0, 40.0))
        n_cyc = int(rng.integers(5, 30))
        f = rate / round(rate / f)                          # an integer period: the lines sit on bins
        t = np.arange(int(round(n_cyc * rate / f))) / rate
        floor = 1e-3
        ks = np.arange(1, 31)
        p_term = floor ** 2 * np.exp(rng.uniform(np.log(0.01), np.log(100.0), ks.size))
        ph = rng.uniform(0, 2 * np.pi, ks.size)
        term = sum(np.sqrt(2 * p) * np.cos(2 * np.pi * k * f * t + q) for k, p, q in zip(ks, p_term, ph))
        carrier = sum(1.0 / k * np.cos(2 * np.pi * k * f * t) for k in ks)     # every line above floor ** 2
        d = PeriodicDrive(f, 0)
        kept = d.harmonics_of(term, t, floor, carrier)
        left = np.setdiff1d(ks, kept)
        assert p_term[left - 1].sum() < floor ** 2
        assert np.all(p_term[kept - 1][:, None] >= p_term[left - 1][None, :] - 1e-12 * floor ** 2)
        weakest = kept[np.argmin(p_term[kept - 1])]
        assert p_term[left - 1].sum() + p_term[weakest - 1] >= floor ** 2


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
