"""The residual spectrum's peaks that seed the mode search's fine grid (:meth:`Resonance._spectral_peaks`).

A 4096-sample Welch segment has bins of ``fs / 4096`` (244 Hz at 1 MHz), too wide below
``f_c = fs / (4096 expm1(0.12))`` for the fine grid's +-12 %: session 28 adds a long segment's peaks there,
and only there. Above ``f_c`` the averaged short segments alone seed the grid: session 27's one periodogram of
every row (s27_welch, reverted) lost weak modes there to the noise's unaveraged peaks (its review: seed 20 #88's
1129 Hz mode at 100 kHz). Asserted on a residual made of a weak mode's term on a benchmark drive and white noise
(the term's RMS 0.3-30x the noise's), at 100 kHz and 1 MHz, the mode drawn above ``f_c``: a peak lies within the
fine grid's span of the mode, and the plain search's mode leaves no more than the true one.
"""

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate import effects as E
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import benchmark_protocol
from workbench.calibrate.tracing import _search_rows


def _weak_mode(draw):
    """Draw ``draw`` (``default_rng([2808, draw])``): rate 100 kHz / 1 MHz on even / odd draws, the protocol
    sine, steps, calibration in turn every two draws, the benchmark's rows; the mode log-uniform over 1.5 f_c
    to the lesser of 20 kHz and a twentieth of the search rows' rate, damping 0.5-2 % (the simulator's range),
    its term's RMS 0.3-30x the white noise's (log-uniform; the benchmark's sizes reach 30x)."""
    rng = np.random.default_rng([2808, draw])
    rate = (1e5, 1e6)[draw % 2]
    proto = ("sine", "steps", "calibration")[(draw // 2) % 3]
    t, v = benchmark_protocol(proto, rate, load_benchmark("calibrate_confusion").ROWS[rate])
    rows = _search_rows(np.asarray(make_split(t, v, "blocks").train, bool))
    fs = rate / float(np.median(np.diff(np.flatnonzero(rows))))
    f_c = fs / (E.PEAK_SEGMENT * np.expm1(E.FINE_HALF_LOG))
    f = float(np.exp(rng.uniform(np.log(1.5 * f_c), np.log(min(2e4, fs / 20)))))
    z = float(rng.uniform(0.005, 0.02))
    u = 1e-7 * v                                    # the base's prediction (m): the mode's column has unit DC gain
    term = E.Resonance._column(u, f, z, 1.0 / rate)
    e = float(np.exp(rng.uniform(np.log(0.3), np.log(30.0)))) * term / np.std(term) * 1e-9 \
        + 1e-9 * rng.standard_normal(t.size)
    return t, u, e, rows, fs, f, z


#: draws 1 (8.9 kHz at 1 MHz steps) and 6 (2.2 kHz at 100 kHz calibration): the peak is found, but the search ends at
#: 3.1x and 3.2x the mode's frequency, leaving 1.010x and 1.110x of what the true mode leaves: no grid point about the
#: peak (11 frequencies over +-12 %, 7 dampings 0.002-0.3) lies in the light mode's narrow valley, and the three
#: starts go elsewhere. Main the same (above the cutoff the branch's peaks are main's, and its search leaves no more
#: than main's by construction: _varpro's added_from): open, not this slice's
GRID_MISS = ("open (session 28): the peak is found but the grid about it misses the light mode's valley; main the "
             "same")
DRAWS = reduced_draws([pytest.param(d, marks=[pytest.mark.xfail(strict=True, reason=GRID_MISS)] if d in (1, 6) else [])
                       for d in range(12)], keep={0, 2})


# draw 0 (a 543 Hz mode under the 100 kHz sine) is the review's failure: session 27's one periodogram of every row
# has no peak within +-12 % of it, and its search ends at 971 Hz leaving 1.019x the true mode's
@pytest.mark.parametrize("draw", DRAWS)
def test_a_weak_mode_above_the_cutoff_keeps_its_peak(draw):
    t, u, e, rows, fs, f, z = _weak_mode(draw)
    r = E.Resonance()
    lf_lo, lf_hi = r._range(t)
    peaks, added = r._spectral_peaks(e[rows], fs, lf_lo, lf_hi)
    assert all(q < fs / (E.PEAK_SEGMENT * np.expm1(E.FINE_HALF_LOG)) for q in added), (added, fs)
    assert any(abs(np.log(q / f)) <= E.FINE_HALF_LOG for q in peaks + added), (f, z, peaks, added)
    p = r.fit(t, u, e, rows)

    def left(f_hz, zeta):
        c, y = r._column(u, f_hz, zeta, t[1] - t[0])[rows], e[rows]
        return float(np.sum((y - (c @ y) / (c @ c) * c) ** 2))
    assert left(p["f_n_hz"], p["zeta"]) <= (1 + 1e-9) * left(f, z), (f, z, p)
