"""A delay and a mode that one record cannot tell apart (sessions 23-24, branches s23_hz100, s24_hz100).

At 100 Hz a stack mode above the record's Nyquist frequency (the confusion benchmark draws 150-400 Hz) is
out of the mode search's reach, yet it shows in the samples: the drive is held between samples, its
staircase excites the mode at the sample rate's harmonics, and the samples see that at zero frequency, a
term in the drive's slope -- a delay's, of either sign. ``tracing._delay_or_mode`` (session 24): a mode keeps
a fold only where the difference of its held-out mean squared error from its rival's (the delay, or the
model's slope as one column, "the phase reading") stands beyond its own standard error over the fold's
validation blocks (``resolved_beyond``); a delay that leads (no sensor's latency) beside a passing mode is
undecided unless resolved beyond the phase reading; a lagging delay keeps the fold as before. The undecided fold names its channel.

Constructed records (a linear stack, the mode discretised exactly for the held drive), scored by the
tracing's own ``_score_stage``, and constructed fold scores: cheap (~2 s).
"""

import numpy as np
from scipy import signal

from tests.calibrate.hand_scored import KEY, score_delay_and_mode
from workbench.calibrate import tracing as T
from workbench.calibrate.synthetic import benchmark_protocol

RATE, ROWS, SIG = 100.0, 4000, 1e-9          # the benchmark's 100 Hz record (40 s), the displacement's noise
UNDECIDED = T.delay_or_mode_label("displacement")


def _record(f_mode, zeta, protocol, seed=0):
    """A linear stack (0.1 um/V) driven by the benchmark's command, held between samples, through a mode."""
    t, v = benchmark_protocol(protocol, RATE, ROWS)
    y = 1e-7 * v
    w = 2 * np.pi * f_mode
    b, a, _ = signal.cont2discrete(([w * w], [1.0, 2 * zeta * w, w * w]), 1.0 / RATE, method="zoh")
    b = np.ravel(b)[1:]              # the value held over (t_{k-1}, t_k] read at t_k, as the simulator's
    x = signal.lfilter(b, a, y - y[0]) + y[0]
    return t, v, y, x + SIG * np.random.default_rng(seed).standard_normal(t.size)


def _scored(f_mode, zeta, protocol):
    """The first stage scored with the delay and the mode as the only candidates (the base: the stack's line)."""
    t, v, y, x = _record(f_mode, zeta, protocol)
    res = score_delay_and_mode(t, v, y, x, SIG)
    return res, res["by"][("delay", "displacement")], res["by"][("resonance", "displacement")]


def _raw(res, row):
    return np.array([T._raw_rms(row, f, res["befores"], 0.02) for f in range(len(row["ratios"]))])


def test_a_mode_above_nyquist_under_a_slow_sine_is_undecided_against_a_delay():
    """A 311.6 Hz mode (zeta 0.0068, 90 #115's) under the 0.15 Hz sine at 100 Hz: the delay (read as a lead)
    and a mode of at most 50 Hz both pass every fold and leave the same held-out RMS within 5 % (the
    mechanism: one phase at the drive's harmonics); every fold is undecided, the label naming the channel,
    and no effect is named (main: the delay 5 of 5)."""
    res, delay, mode = _scored(311.6, 0.0068, "sine")
    assert all(delay["passes"]) and all(mode["passes"]), (delay["ratios"], mode["ratios"])
    assert delay["params"]["delay_samples"] < 0, delay["params"]
    a_d, a_m = _raw(res, delay), _raw(res, mode)
    assert np.all(np.abs(a_d / a_m - 1.0) < 0.05), (a_d, a_m)
    assert np.all(a_d < 0.5 * np.array(res["befores"][KEY])), (a_d, res["befores"][KEY])   # a real term
    assert res["winners"] == [("undecided", "delay or resonance on the displacement")] * 5, res["winners"]
    assert T._consensus(res["winners"], 4)[0] is None
    assert T.delay_or_mode_consensus(res["winners"], 4)[0] is None


def test_a_mode_the_record_shows_is_still_named():
    """The guard: a 30 Hz mode (below Nyquist) ringing after the 100 Hz steps is the mode on every fold, and
    the 311.6 Hz mode under steps (its alias rings at 11.6 Hz after each step) keeps the mode on the fold
    the delay passes too: what the mode explains beyond the delay is resolved there."""
    res, delay, mode = _scored(30.0, 0.02, "steps")
    assert res["winners"] == [("resonance", "displacement")] * 5, res["winners"]
    res, delay, mode = _scored(311.6, 0.0068, "steps")
    both = [f for f in range(5) if delay["passes"][f] and mode["passes"][f]]
    assert both, (delay["passes"], mode["passes"])
    for f in both:
        assert res["winners"][f] == ("resonance", "displacement"), res["winners"]
    assert UNDECIDED not in res["winners"], res["winners"]


DELAY, MODE = ("delay", "displacement"), ("resonance", "displacement")


def test_a_reading_decided_on_some_folds_and_undecided_on_the_rest_is_named():
    """As the absorption and leakage (``nested_consensus``): an undecided fold is compatible with both
    readings on its channel; one is named from at least 2 decided folds when the other wins none and the
    two fill the agreement (92 #127, a 0.04-sample delay under 100 Hz steps: delay on 3 folds, a
    noise-filled fold undecided). All folds undecided, or both readings deciding folds: nothing named. A fold
    undecided on another channel (the gauge) is no vote for the displacement's reading."""
    named = T.delay_or_mode_consensus([DELAY, UNDECIDED, "none", DELAY, DELAY], 4)
    assert named == (DELAY, 3, 1)
    assert T.delay_or_mode_consensus([UNDECIDED, UNDECIDED, UNDECIDED, MODE, MODE], 4) == (MODE, 2, 3)
    assert T.delay_or_mode_consensus([UNDECIDED] * 5, 4)[0] is None
    assert T.delay_or_mode_consensus([DELAY, MODE, UNDECIDED, UNDECIDED, DELAY], 4)[0] is None
    assert T.delay_or_mode_consensus([DELAY, UNDECIDED, UNDECIDED, UNDECIDED, "none"], 4)[0] is None   # 1 decided
    assert T.delay_or_mode_consensus([DELAY, DELAY, UNDECIDED, "none", "none"], 4)[0] is None          # 3 of 4
    on_gauge = T.delay_or_mode_label("gauge")
    assert on_gauge != UNDECIDED and "gauge" in on_gauge[1] and "displacement" in UNDECIDED[1]
    assert T.delay_or_mode_consensus([DELAY, DELAY, on_gauge, on_gauge, "none"], 4)[0] is None
    assert T.delay_or_mode_consensus([DELAY, DELAY, UNDECIDED, on_gauge, UNDECIDED], 4) == (DELAY, 2, 2)


def _blocks(a, d, m=15, n=40):
    """Per-block held-out SSEs of ``m`` validation blocks of ``n`` rows whose total gives the RMS ``a``, with
    ``d`` (length ``m``) added to the blocks' SSEs and the total kept (``d`` summing to zero)."""
    base = np.full(m, a * a * n)
    return base + np.asarray(d, float), np.full(m, float(n))


def test_the_bar_is_the_difference_beyond_its_own_standard_error():
    """``resolved_beyond``: the difference of two readings' held-out mean squared errors, sum(d_b) / sum(n_b),
    is a_other^2 - a_best^2, and its standard error over equal blocks is the blocks' per-row differences'
    sample deviation over sqrt(m) (closed form). The same difference is resolved when the blocks agree on
    it and not when one block carries it all."""
    m, n = 15, 40
    rng = np.random.default_rng(0)
    d = 0.5 + 0.05 * rng.standard_normal(m)              # every block: the rival leaves 0.5 more
    best, N = _blocks(1.0, np.zeros(m), m, n)
    other = best + d
    ok, D, se = T.resolved_beyond(best, other, N)
    assert np.isclose(D, other.sum() / N.sum() - best.sum() / N.sum(), rtol=1e-12)
    assert np.isclose(se, np.std(d / n, ddof=1) / np.sqrt(m), rtol=1e-12)
    assert ok and D > 5 * se
    lumped = np.zeros(m)
    lumped[3] = d.sum()                                  # the same total, from one block
    ok2, D2, se2 = T.resolved_beyond(best, best + lumped, N)
    assert np.isclose(D2, D, rtol=1e-12) and not ok2 and D2 < se2
    assert not T.resolved_beyond(best, best - d, N)[0]   # the rival is the better one
    assert not T.resolved_beyond(best[:1], other[:1], N[:1])[0]   # one block: no scatter to measure


def _mode_row(a, before=1.0):
    return {"name": "resonance", "channel": "displacement", "key": KEY, "n_params": 3,
            "ratios": [a / before * 1.06], "params": {"f_n_hz": 3.97, "zeta": 0.3, "gain": 0.1}}


def _delay_row(a, d_samples, before=1.0):
    return {"name": "delay", "channel": "displacement", "key": KEY, "n_params": 1,
            "ratios": [a / before * 1.02], "params": {"delay_samples": d_samples}}


def test_a_mode_keeps_a_fold_only_resolved_beyond_its_rival():
    """A mode against the delay or its phase reading: kept where the difference is resolved over the fold's
    blocks, whatever the noise floor (the reverted slice's bar, ``beyond > floor^2``, refused a resolved
    difference under the floor and kept an unresolved one above it). Constructed fold scores (before 1)."""
    m, n = 15, 40
    d = 0.002 + 0.0002 * np.random.default_rng(1).standard_normal(m)     # resolved, beyond^2 ~ 5e-5
    mode_sse, N = _blocks(0.5, np.zeros(m), m, n)
    a_mode = 0.5
    a_rival = float(np.sqrt((mode_sse + d).sum() / N.sum()))
    mode, delay = _mode_row(a_mode), _delay_row(a_rival, 0.3)
    infos = {"displacement": {"noise_floor": 0.1}}                       # floor^2 = 0.01 > beyond
    args = ({KEY: [1.0]}, infos, 0.02, 1.0, T.MIN_SHARE)
    sse = {id(mode): [(mode_sse, N)], id(delay): [(mode_sse + d, N)]}
    assert T._delay_or_mode(mode, {MODE: mode}, 0, *args, block_sse=sse) is mode          # no rival: kept
    assert T._delay_or_mode(mode, {MODE: mode, DELAY: delay}, 0, *args, block_sse=sse) is mode
    # the same rival as the phase reading (it passes the fold), or failing it (no rival)
    assert T._delay_or_mode(mode, {MODE: mode}, 0, *args, phase=[(a_rival, True, (mode_sse + d, N))],
                            block_sse=sse) is mode
    # a large difference from one block: above the floor and MIN_SHARE of what the rival leaves, unresolved
    lumped = np.zeros(m)
    lumped[0] = 0.3 * N.sum()
    a_far = float(np.sqrt((mode_sse + lumped).sum() / N.sum()))
    assert a_far ** 2 - a_mode ** 2 > max(0.01, T.MIN_SHARE * a_far ** 2)
    far = _delay_row(a_far, 0.3)
    sse[id(far)] = [(mode_sse + lumped, N)]
    assert T._delay_or_mode(mode, {MODE: mode, DELAY: far}, 0, *args, block_sse=sse) is None
    assert T._delay_or_mode(mode, {MODE: mode}, 0, *args, phase=[(a_far, True, (mode_sse + lumped, N))],
                            block_sse=sse) is None
    assert T._delay_or_mode(mode, {MODE: mode}, 0, *args, phase=[(a_far, False, (mode_sse + lumped, N))],
                            block_sse=sse) is mode


def test_a_delay_that_leads_beside_a_mode_is_undecided_and_a_lag_keeps_the_fold():
    """A lead is no sensor's latency: beside a passing mode, a lead no more than the model's slope (its phase
    reading, resolved by the block bar) is undecided (91 #115: 2.7 samples, a mode at 100 Hz under the slow
    sine); a lead resolved beyond the slope (an acquisition offset under a chirp,
    test_calibrate's sensor lead) keeps the fold; a lag keeps it either way (right sine delays at 100 Hz -
    10 kHz, whose difference from the fitted mode the record does not resolve), and a delay alone keeps
    it whatever its sign. Constructed fold scores."""
    m, n = 15, 40
    infos = {"t": np.arange(1000) / 100.0, "displacement": {"noise_floor": 0.1}}
    args = ({KEY: [1.0]}, infos, 0.02, 1.0, T.MIN_SHARE)
    mode = _mode_row(0.5)
    lead, lag = _delay_row(0.49, -0.38), _delay_row(0.49, 0.41)
    d_sse, N = _blocks(0.49, np.zeros(m), m, n)
    sse = {id(lead): [(d_sse, N)], id(lag): [(d_sse, N)]}
    tie = 0.01 * np.random.default_rng(2).standard_normal(m)
    tie -= tie.mean()                                            # the slope leaves the same, block by block
    clear = 0.2 * n + 0.01 * np.random.default_rng(3).standard_normal(m)   # the slope leaves 0.2 more a row
    for sse_phase, kept in ((d_sse + tie, False), (d_sse + clear, True)):
        a_ph = float(np.sqrt(sse_phase.sum() / N.sum()))
        phase = [(a_ph, True, (sse_phase, N))]
        got = T._delay_or_mode(lead, {DELAY: lead, MODE: mode}, 0, *args, phase=phase, block_sse=sse)
        assert got is (lead if kept else None), (kept, got)
        assert T._delay_or_mode(lag, {DELAY: lag, MODE: mode}, 0, *args, phase=phase, block_sse=sse) is lag
        assert T._delay_or_mode(lead, {DELAY: lead}, 0, *args, phase=phase, block_sse=sse) is lead
    # the phase reading failing the fold: the lead's phase is no first-order one
    phase = [(0.49, False, (d_sse + tie, N))]
    assert T._delay_or_mode(lead, {DELAY: lead, MODE: mode}, 0, *args, phase=phase, block_sse=sse) is lead


def test_the_phase_reading_column_is_the_models_central_slope():
    """``phase_column``: the model's central difference per sample. For a sampled sine ``A sin(w n dt)`` it
    is ``A cos(w n dt) sin(w dt)`` inside the record (closed form), and a lag of ``d`` samples of that
    sine, fitted on the model and this column, takes the column's gain ``-sin(d w dt) / sin(w dt)``
    exactly (``-d`` to second order): the column is a sub-sample delay's form (a one-sided difference
    would leave a quadrature part and a gain off at first order in ``w dt``)."""
    n, A, wdt = 2000, 3.0, 2 * np.pi / 97.0
    k = np.arange(n)
    y = A * np.sin(wdt * k)
    col = T.phase_column(y)
    assert np.allclose(col[1:-1], A * np.cos(wdt * k[1:-1]) * np.sin(wdt), rtol=0, atol=1e-12 * A)
    for d in (0.3, -0.38, 2.7):
        x = A * np.sin(wdt * (k - d))
        X = np.column_stack([y, col])[1:-1]
        w, *_ = np.linalg.lstsq(X, x[1:-1], rcond=None)
        assert np.isclose(w[1], -np.sin(d * wdt) / np.sin(wdt), rtol=1e-9, atol=1e-12), (d, w)
        assert np.isclose(w[0], np.cos(d * wdt), rtol=1e-9), (d, w)
        assert abs(w[1] + d) < 0.01 * abs(d)
