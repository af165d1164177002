"""A sensor drift must show in the drive's holds (workbench/calibrate/drift_holds.py).

Closed forms: a staircase's holds less their settling, the residual's gain on a drift's
within-hold motion (1 when the residual carries the drift, 0 when it does not) and its standard
error for white noise; slopes, noise, hold lengths and sample rates drawn over wide ranges.
"""

import numpy as np
import pytest

from tests.conftest import FULL, reduced_draws
from workbench.calibrate.drift_holds import (MAX_SE, NO_HOLDS_NOTE, SETTLE_FRACTION, drift_in_holds,
                                            drive_noise_rms_v, hold_spans)


def _staircase(rng, rate_hz):
    """A ramp-and-hold staircase: (t, v, true hold spans (i, j))."""
    # levels >= 10 V apart, ramps of 2-20 samples: every ramp step leaves the 1e-3 tolerance
    levels = rng.permutation(np.arange(10.0, 100.0, 12.0))[:int(rng.integers(3, 8))]
    hold_n = int(rng.integers(200, 3000))
    ramp_n = int(rng.integers(2, 21))
    v, spans, k, prev = [], [], 0, 0.0
    for lv in levels:
        v.extend(np.linspace(prev, lv, ramp_n, endpoint=False)[1:] if ramp_n > 1 else [])
        k = len(v)
        v.extend([lv] * hold_n)
        spans.append((k, k + hold_n))
        prev = lv
    v = np.asarray(v)
    return np.arange(v.size) / rate_hz, v, spans, hold_n / rate_hz


@pytest.mark.parametrize("seed", range(5))
def test_hold_spans_are_the_staircase_holds_less_their_settling(seed):
    rng = np.random.default_rng(seed)
    rate = float(np.exp(rng.uniform(np.log(100.0), np.log(1e6))))
    t, v, spans, hold_s = _staircase(rng, rate)
    got = hold_spans(t, v, min_hold_s=0.5 * hold_s)
    assert len(got) == len(spans)
    for (i, j), (a, b) in zip(got, spans):
        assert j == b
        assert i == a + np.ceil(SETTLE_FRACTION * (b - a))
    assert hold_spans(t, np.sin(2 * np.pi * 3.0 * t / t[-1]), min_hold_s=0.5 * hold_s).shape == (0, 2)


@pytest.mark.parametrize("seed", range(8))
def test_gain_is_one_with_the_drift_and_zero_without(seed):
    """Residual = the drift's motion + white noise: gain 1 within 4 standard errors, ``shows``;
    noise alone: gain 0 within 4 standard errors, not ``shows``; the standard error is
    sigma / sqrt(sum of the centred term squared)."""
    rng = np.random.default_rng(100 + seed)
    rate = float(np.exp(rng.uniform(np.log(100.0), np.log(1e5))))
    t, v, _, hold_s = _staircase(rng, rate)
    sigma = float(np.exp(rng.uniform(np.log(1e-10), np.log(1e-8))))
    span = t[-1] - t[0]
    # a drift far above the noise over the holds: 30-3000 sigma over the record
    excursion = sigma * float(np.exp(rng.uniform(np.log(30.0), np.log(3000.0))))
    shape = (0.7 * (t / span) + 0.3 * (t / span) ** 2) * rng.choice([-1.0, 1.0])
    rows = rng.random(t.size) < 0.8
    spans = hold_spans(t, v, min_hold_s=0.5 * hold_s)
    den1 = sum(float(np.sum((shape[i:j][rows[i:j]] - shape[i:j][rows[i:j]].mean()) ** 2)) for i, j in spans)
    # every draw informs (no skip that could turn a case into a no-op): the excursion is raised, when the
    # draw's is too small, to where the standard error is half of MAX_SE
    excursion = max(excursion, 2.0 * sigma / (MAX_SE * np.sqrt(den1)))
    term = excursion * shape
    den = excursion ** 2 * den1
    se = sigma / np.sqrt(den)
    assert se <= MAX_SE
    noise = sigma * rng.standard_normal(t.size)
    # a different level in every hold (the base's misfit there) does not count: levels are removed
    levels = np.zeros(t.size)
    for i, j in spans:
        levels[i:j] = rng.normal(0.0, 100 * sigma)
    with_drift = drift_in_holds(term + noise + levels, term, rows, spans, sigma)
    assert with_drift["se"] == pytest.approx(se, rel=1e-9)
    assert abs(with_drift["gain"] - 1.0) <= 4 * se + 1e-3 and with_drift["shows"] is True
    without = drift_in_holds(noise + levels, term, rows, spans, sigma)
    assert abs(without["gain"]) <= 4 * se and without["shows"] is False


def test_the_holds_cannot_tell_when_the_drift_hardly_moves_within_them_or_there_are_none():
    rng = np.random.default_rng(7)
    t, v, _, hold_s = _staircase(rng, 1e4)
    spans = hold_spans(t, v, min_hold_s=0.5 * hold_s)
    sigma = 1e-9
    tiny = 1e-4 * sigma * t / t[-1]          # far below the noise within any hold
    out = drift_in_holds(sigma * rng.standard_normal(t.size), tiny, np.ones(t.size, bool), spans, sigma)
    assert out["se"] > MAX_SE and out["shows"] is None
    none = drift_in_holds(np.zeros(t.size), t, np.ones(t.size, bool), np.empty((0, 2), int), sigma)
    assert none["holds"] == 0 and none["shows"] is None
    # a veto that switches itself off says so
    assert none["note"] == NO_HOLDS_NOTE and "could not judge" in out["note"]


@pytest.mark.parametrize("seed", range(6))
def test_holds_survive_the_voltage_channels_noise(seed):
    """A staircase with white noise on the voltage channel, 1 mV to 0.3 V RMS (0.001-0.3 % of the
    100 V span; review 3 measured 0 holds at 30 mV with the old 1e-3-of-span tolerance): every
    hold is still found, inside its true hold, and the noise estimate is the drawn RMS."""
    rng = np.random.default_rng(300 + seed)
    rate = float(np.exp(rng.uniform(np.log(1e3), np.log(1e5))))
    t, v, spans, hold_s = _staircase(rng, rate)
    sigma_v = float(np.exp(rng.uniform(np.log(1e-3), np.log(0.3))))
    vn = v + sigma_v * rng.standard_normal(v.size)
    # second differences see the noise, not the staircase's few steps (sampling spread of a
    # median over >= 600 samples: a few per cent)
    assert drive_noise_rms_v(vn) == pytest.approx(sigma_v, rel=0.1)
    got = hold_spans(t, vn, min_hold_s=0.5 * hold_s)
    assert len(got) == len(spans)
    hold_n = spans[0][1] - spans[0][0]
    for (i, j), (a, b) in zip(got, spans):
        assert a <= (i + j) // 2 < b                      # inside its true hold
        assert j - i >= (1 - SETTLE_FRACTION) * hold_n - 25   # at most the ramp's samples short


def test_drive_noise_ignores_a_sines_slope():
    """A 10 Hz, 50 V sine at 10 kHz with 10 mV of noise: the estimate is the noise, not the slope
    (a first difference would see 50 V x 2 pi 10 Hz / 10 kHz = 0.3 V per sample)."""
    rng = np.random.default_rng(5)
    t = np.arange(20_000) / 1e4
    v = 50.0 + 50.0 * np.sin(2 * np.pi * 10.0 * t) + 0.01 * rng.standard_normal(t.size)
    assert drive_noise_rms_v(v) == pytest.approx(0.01, rel=0.1)


# make test runs the effect-free record and the 10x drift; the 30x drift (the same family, protocol, rate and
# assertion, 3x further above the bar) runs under WORKBENCH_FULL=1 (session 31, s31_suite)
@pytest.mark.parametrize("effect, size, seed", reduced_draws([("none", 1.0, 3), ("drift", 10.0, 3), ("drift", 30.0, 4)],
                                                             keep={0, 1}))
def test_the_tracer_vetoes_the_effect_free_records_drift_and_keeps_a_drift_records(sn637, effect, size, seed):
    """End to end (review 3 item 16), 1 kHz records of the calibration protocol: on the effect-free record
    the displacement's drift candidate moves the holds it does not move (``shows`` False) and passes no
    fold; on a drift record (10x, 30x) the holds move with it (``shows`` True, gain >= MIN_GAIN); a
    channel whose holds cannot judge says so in a note."""
    from tests.calibrate.test_confusion import _traced
    from workbench.calibrate.drift_holds import MIN_GAIN
    base, res, truth = _traced(sn637, effect, 1e3, "calibration", size, seed)
    rows = {c["channel"]: c for c in res["candidates"] if c["name"] == "drift"}
    h = rows["displacement"]["holds"]
    assert h["holds"] >= 3
    if effect == "none":
        # (until session 24 ``shows`` was False here: the base's 24-play grid straddled the declared core's
        # thresholds and left 2.3e-9 m, 2.3x the sensor's floor, which the drift fitted and the holds vetoed;
        # on the core's thresholds the base leaves 1.0e-9 m, the drift fits noise and its gain's standard
        # error (2.0) is too wide to judge: the veto says so and stays off, and the drift passes no fold)
        assert h["shows"] is not True and rows["displacement"]["passes"] == 0, h
    else:
        assert h["shows"] is True and h["gain"] >= MIN_GAIN and rows["displacement"]["passes"] >= 3, h
    for c in rows.values():
        assert (c["holds"]["shows"] is None) == ("note" in c["holds"]), c["holds"]


# ---- session 17: the fitted drift's own prediction error in the hold check ----

@pytest.mark.parametrize("seed", range(3))
def test_weights_cov_gives_the_closed_form_prediction_variance_of_a_polynomial_fitted_to_noise(seed):
    """A quadratic in time fitted to white noise on a split's development rows (``_Problem``, the joint
    fit's machinery): the variance of its value at the record's start, from :meth:`_Problem.weights_cov`,
    is the closed form ``sigma^2 x' (X'X)^-1 x`` (``X`` the development rows' ``[1, t, t^2]``) within the
    residual mean square's own spread, and the predictions of 400 independent noise draws spread by it.
    Rate, length and noise drawn over decades."""
    from workbench.calibrate import tracing as T
    from workbench.calibrate.splits import make_split
    rng = np.random.default_rng(1700 + seed)
    rate = float(np.exp(rng.uniform(np.log(1e3), np.log(1e5))))
    n = int(rng.integers(3000, 8000))
    sigma = float(np.exp(rng.uniform(np.log(1e-10), np.log(1e-6))))
    t = np.arange(n) / rate
    sp = make_split(t, np.sin(2 * np.pi * 5.0 * t / t[-1]))
    dev = sp.train
    X = np.column_stack([np.ones(n), t, t ** 2])
    Xd = X[dev]
    closed = sigma ** 2 * X[0] @ np.linalg.solve(Xd.T @ Xd, X[0])
    preds, var_cov = [], []
    n_dev = int(dev.sum())
    for _ in range(400):
        r = sigma * rng.standard_normal(n)
        prob = T._Problem(sp, np.ones(n, bool), X[:, :1], [-np.inf], r, T._search_rows(dev))
        g = prob.grams(X[:, 1:], [-np.inf, -np.inf])
        w = prob.solve(g, sp.dev_blocks)
        x0 = np.r_[prob.A[0], g["C"][0]] * prob.scale       # the fit at t[0] is x0 @ w (channel units)
        preds.append(float(x0 @ w))
        var_cov.append(float(x0 @ prob.weights_cov(g, sp.dev_blocks, w) @ x0))
    var_cov = np.asarray(var_cov)
    # s^2's relative spread is sqrt(2 / (n - 3)): every draw within 5 of it
    assert np.all(np.abs(var_cov / closed - 1.0) <= 5.0 * np.sqrt(2.0 / (n_dev - 3)))
    # the sample variance of 400 normal draws: relative spread sqrt(2 / 399), 4 of it
    assert np.var(preds, ddof=1) == pytest.approx(closed, rel=4.0 * np.sqrt(2.0 / 399))


@pytest.mark.parametrize("seed", range(4))
def test_the_hold_checks_standard_error_counts_the_fitted_drifts_error_in_the_hold(seed):
    """The sine protocol's shape: one hold at the record's start, the rest moving, where the model's
    misfit (here white, ``misfit`` = 3-100x the channel's noise) sets the fitted drift's error. The
    drift (a real one, 3-300x the misfit over the record) is fitted by least squares on the moving rows
    and extrapolated into the hold. Over 600 draws of the noise, the gain ``k``'s spread is the check's
    standard error (the noise's and the term's parts in quadrature), not the noise's part alone, and the
    check refuses the real drift (``shows`` False) in at most 1 % of the draws that inform."""
    rng = np.random.default_rng(1710 + seed)
    rate = float(np.exp(rng.uniform(np.log(1e4), np.log(1e5))))
    n = 4000
    t = np.arange(n) / rate
    dur = t[-1]
    hold = (int(0.007 * n), int(0.035 * n))                         # the hold's rows after its settling
    spans = np.array([hold])
    sigma = float(np.exp(rng.uniform(np.log(1e-10), np.log(1e-8))))
    misfit = sigma * float(np.exp(rng.uniform(np.log(3.0), np.log(100.0))))
    excursion = misfit * float(np.exp(rng.uniform(np.log(3.0), np.log(300.0))))
    a1, a2 = rng.uniform(-1.0, 1.0, 2)
    X = np.column_stack([np.ones(n), t / dur, (t / dur) ** 2])
    D = excursion * (a1 * X[:, 1] + a2 * X[:, 2])
    fit_rows = np.ones(n, bool)
    fit_rows[:hold[1]] = False
    Xf = X[fit_rows]
    XtX_inv = np.linalg.inv(Xf.T @ Xf)
    ks, ses, se_noise, shows = [], [], [], []
    for _ in range(600):
        noise = np.where(fit_rows, misfit, sigma) * rng.standard_normal(n)
        y = D + noise
        w = XtX_inv @ Xf.T @ y[fit_rows]
        s2 = float(np.sum((y[fit_rows] - Xf @ w) ** 2)) / (fit_rows.sum() - 3)
        term = X[:, 1:] @ w[1:]
        chk = drift_in_holds(y, term, np.ones(n, bool), spans, sigma, term_columns=X[:, 1:],
                             term_cov=s2 * XtX_inv[1:, 1:])
        if chk["shows"] is None and not np.isfinite(chk["se"]):
            continue
        ks.append(chk["gain"])
        ses.append(chk["se"])
        se_noise.append(chk["se_noise"])
        shows.append(chk["shows"])
    ks, ses = np.asarray(ks), np.asarray(ses)
    assert ks.size >= 590
    spread = float(np.std(ks, ddof=1))
    # the reported se is the spread (the ratio's linearization; 600 draws: ~6 % sampling), the noise
    # part alone is not when the term's error dominates
    assert spread == pytest.approx(float(np.median(ses)), rel=0.2)
    informed = [s for s in shows if s is not None]
    assert sum(s is False for s in informed) <= 0.01 * max(len(informed), 1)
    if np.median(ses) > 2.0 * np.median(se_noise):
        assert spread > 1.5 * float(np.median(se_noise))


# drift + a slow mode at 100 kHz on the sine protocol (the cell of seeds 57 and 59, #88, where the one
# 14 ms hold at the record's start refused the drift), one size per log-band of the benchmark's full
# range (0.03-30x), default_rng(1717), drawn before any record was traced: main (7953044) answers the
# four as this branch does (a regression check over the range, not the fix's evidence). The fix's
# evidence is the lead's seed 57 #88 (13.97x; main: resonance only, 4 of 5, ratio 0.64), reproduced
# from the benchmark's own draw. make test runs 57 #88; WORKBENCH_FULL=1 also the four draws.
_RNG_MODE = np.random.default_rng(1717)
_EDGES = np.linspace(np.log(0.03), np.log(30.0), 5)
MODE_DRAWS = [(float(np.exp(_RNG_MODE.uniform(a, b))), int(_RNG_MODE.integers(1 << 30)))
              for a, b in zip(_EDGES[:-1], _EDGES[1:])]


@pytest.fixture(scope="module")
def drift_beside_mode_rows(sn637):
    from tests.conftest import load_benchmark
    cc = load_benchmark("calibrate_confusion")
    effect, rate, proto, size57, seed57 = cc.cases(1, 57)[88 - 1]
    assert (tuple(effect), rate, proto) == (("drift", "resonance"), 1e5, "sine")
    rows = []
    for size, seed in [(size57, seed57)] + (MODE_DRAWS if FULL else []):
        r = cc.evaluate(sn637, ("drift", "resonance"), 1e5, "sine", size, seed)
        print(f"\nsize x{size:.3g} own sizes {np.round(r['excesses'], 1)} beyond on every fold "
              f"{np.round(r['beyond_folds'], 1)} -> {r['named']} {r['class']} ratio {r['ratio']:.2f}")
        rows.append(r)
    return rows


@pytest.mark.skipif(not FULL,
                    reason="reduced form (the suite's time budget, session 17): WORKBENCH_FULL=1 runs 57 #88 and the "
                           "four draws; make test keeps the check's closed-form and spread tests above, which fail "
                           "on the noise-only and block-only standard errors")
def test_drift_beside_a_slow_mode_on_one_hold_names_both_when_told_apart(drift_beside_mode_rows):
    """No effect the record lacks is named; a record whose drift and mode each stand >= 3x beyond the
    other on every validation fold (``calibrate_confusion._beyond``) is answered with both: the one hold
    does not refuse a drift its fit cannot place within the hold."""
    rows = drift_beside_mode_rows
    assert not [r for r in rows if r["class"] in ("wrong", "crash")], [(r["excesses"], r["named"]) for r in rows]
    apart = [r for r in rows if min(r["beyond_folds"]) >= 3.0]
    assert apart                        # 57 #88 is: 1148x and 661x beyond on every fold
    assert all(r["both"] for r in apart), [(np.round(r["excesses"], 1), r["named"]) for r in apart]


@pytest.mark.parametrize("amp", [0.3, 3.0])
def test_the_hold_checks_se_counts_every_fitted_columns_error(amp):
    """The check's standard error carries the error of *every* fitted part within the holds.

    A base (offset + gain on the drive), a found mode ringing in the first hold (49 Hz, decaying
    over 50 ms) and a real quadratic drift, fitted jointly on the development rows with a
    structured misfit 20x the noise on the moving rows (session 17's review, its case). What the
    drift is fitted to in a hold carries the mode's and the base's fitted error as well as the
    drift's (module notes), so (1) the code's se equals an independent least-squares one over all
    the columns (``s^2 (Z'Z)^-1``, ``a = sum Z_c' d_c``) on every draw, (2) the gain's spread over
    draws is not above it (the left-out cross term errs towards "cannot tell"), and (3) the real
    drift is refused on at most 1 % of draws. With the drift's block alone the se was 0.09 against
    a spread of 0.31 at ``amp = 0.3`` and the real drift was refused on 21 of 200 draws.
    """
    from workbench.calibrate import tracing as T
    from workbench.calibrate.splits import make_split

    gains, ses, refused = [], [], 0
    for seed in range(100):
        rng = np.random.default_rng([1731, seed])
        n, rate = 6000, 1e4
        t = np.arange(n) / rate
        dur = t[-1]
        spans = np.array([(50, 300), (2000, 2400), (4500, 4700)])
        inhold = np.zeros(n, bool)
        v = np.sin(2 * np.pi * 3 * t / dur)
        for i, j in spans:
            inhold[i - 20:j] = True
            v[i - 20:j] = v[i - 20]
        sp = make_split(t, v)
        A = np.column_stack([np.ones(n), v])
        ring = np.exp(-t / 0.05)
        F = np.column_stack([ring * np.sin(2 * np.pi * 49 * t), ring * np.cos(2 * np.pi * 49 * t)]) * 1e-7
        D = np.column_stack([t / dur, (t / dur) ** 2]) * 1e-8
        sigma = 1e-10
        misfit = np.where(inhold, 0.0, 2e-9 * rng.standard_normal(n) + 1e-9 * np.sin(2 * np.pi * 11 * t))
        y = (A @ [1e-9, 2e-8] + F @ [0.3, -0.2] + D @ (amp * np.array([2.0, -1.0]))
             + sigma * rng.standard_normal(n) + misfit)
        prob = T._Problem(sp, np.ones(n, bool), A, [-np.inf] * 2, y, T._search_rows(sp.train))
        row = {"g": prob.grams(D, [-np.inf] * 2), "key": "k"}
        chk = T._drift_hold_check(prob, [(F, [-np.inf] * 2)], row, sp, spans, sigma)
        # the independent least-squares se over all the columns
        blk = prob.rows_dev
        Z = np.column_stack([A, F, D])
        w, *_ = np.linalg.lstsq(Z[blk], y[blk], rcond=None)
        res = y[blk] - Z[blk] @ w
        C = (res @ res / (blk.sum() - Z.shape[1])) * np.linalg.inv(Z[blk].T @ Z[blk])
        term = D @ w[-2:]
        a, den = np.zeros(Z.shape[1]), 0.0
        for i, j in spans:
            sel = np.flatnonzero(blk[i:j]) + i
            dc = term[sel] - term[sel].mean()
            a += (Z[sel] - Z[sel].mean(axis=0)).T @ dc
            den += dc @ dc
        se_indep = float(np.hypot(sigma / np.sqrt(den), np.sqrt(a @ C @ a) / den))
        assert chk["se"] == pytest.approx(se_indep, rel=1e-6)
        gains.append(chk["gain"])
        ses.append(chk["se"])
        refused += chk["shows"] is False
    assert float(np.std(gains, ddof=1)) <= 1.2 * float(np.median(ses))
    assert refused <= 1


@pytest.mark.parametrize("seed", range(4))
def test_a_drift_bending_in_the_hold_is_not_refused_for_its_fitted_slope(seed):
    """Seed 89 #88's mechanism (drift + a 53 Hz mode at 100 kHz sine): the sine protocol's one hold at
    the record's start, a true drift ``r t + c t^2`` whose vertex lies inside it (so it bends there and
    hardly slopes), and a slow misfit of the model during the motion (a 1-5 Hz sinusoid, 10-100x the
    channel's noise, off in the hold) that tilts the polynomial fitted by least squares over the record.
    Extrapolated into the hold the fitted term mostly slopes, the residual there bends, and ordinary least
    squares' covariance (white residual) calls the term's error small: the gain is refused (``shows``
    False). With the drift's form, the holds' own motion of that form (chi-square beyond 3 standard
    errors) turns the refusal into "cannot tell" (``None``), never ``False``; the same record without the
    drift (flat hold, the same misfit) is still refused whenever the gain refused it."""
    rng = np.random.default_rng(8988 + seed)
    rate, n = 1e5, 40000
    t = np.arange(n) / rate
    dur = t[-1]
    hold = (286, 1430)                       # 2.9-14.3 ms: the sine protocol's hold after its settling
    spans = np.array([hold])
    X = np.column_stack([np.ones(n), t / dur, (t / dur) ** 2])
    moving = np.ones(n, bool)
    moving[:hold[1]] = False
    th = t[hold[0]:hold[1]]
    h2 = float(np.mean((th - th.mean()) ** 2))
    refused = kept = flipped = 0
    for _ in range(10):
        sigma = float(np.exp(rng.uniform(np.log(1e-10), np.log(1e-8))))
        # the drift's bend within the hold: 8-30 noise standard errors of the hold's mean (its RMS there)
        bend = float(np.exp(rng.uniform(np.log(8.0), np.log(30.0)))) * sigma / np.sqrt(th.size)
        q = th - th.mean()
        c = -bend / float(np.std(q ** 2 - h2))
        vertex = float(rng.uniform(th[0] + 0.2 * (th[-1] - th[0]), th[-1] - 0.2 * (th[-1] - th[0])))
        D = c * (t - vertex) ** 2
        A = sigma * float(np.exp(rng.uniform(np.log(10.0), np.log(100.0))))
        mis = np.where(moving, A * np.sin(2 * np.pi * rng.uniform(1.0, 5.0) * t + rng.uniform(0, 2 * np.pi)), 0.0)
        for real in (True, False):
            y = (D if real else 0.0) + mis + sigma * rng.standard_normal(n)
            w = np.linalg.lstsq(X, y, rcond=None)[0]
            cov = float(np.sum((y - X @ w) ** 2)) / (n - 3) * np.linalg.inv(X.T @ X)
            e, term = y - w[0], X[:, 1:] @ w[1:]
            old = drift_in_holds(e, term, np.ones(n, bool), spans, sigma, term_columns=X, term_cov=cov)
            new = drift_in_holds(e, term, np.ones(n, bool), spans, sigma, term_columns=X, term_cov=cov,
                                 form_columns=X[:, 1:])
            if real:
                # never False, unless the holds move against the fitted term (gain 3 standard errors below
                # zero: the review of s22_hold88 keeps that refusal, as a creep tail's)
                assert (new["shows"] is not False) == (new["gain"] > -3.0 * new["se"]) or old["shows"] is not False, \
                    (old, new)
                refused += old["shows"] is False
                flipped += old["shows"] is False and new["shows"] is None
            elif old["shows"] is False:
                assert new["shows"] is False, (old, new)
                kept += 1
    # the mechanism is exercised: the gain alone refuses real drifts (some now "cannot tell"), and refuses the
    # drift-free records
    assert refused and kept and flipped


def test_holds_moving_against_the_drift_keep_the_refusal():
    """The review of s22_hold88 (32 #90: a 25.7x creep on 100 kHz steps, no drift): a creep tail in the holds
    moves in a polynomial's form (chi-square 2e5) but against the fitted drift (gain -1.05 +- 0.008); the holds
    contradict the drift, so the refusal stands. Built: holds relaxing as a decaying exponential after each
    step, a drift term fitted to the motion's misfit sloping the other way within them."""
    rng = np.random.default_rng(3290)
    n, sigma = 20000, 1e-9
    t = np.arange(n) / 1e4
    spans = np.array([(2000, 4000), (8000, 10000), (14000, 16000)])
    term = 2e-8 * (t / t[-1]) + 1e-8 * (t / t[-1]) ** 2
    e = sigma * rng.standard_normal(n)
    for i, j in spans:
        e[i:j] -= 4e-8 * (1.0 - np.exp(-(t[i:j] - t[i]) / 0.05))       # the tail, against the term's rise
    X = np.column_stack([np.ones(n), t / t[-1], (t / t[-1]) ** 2])
    cov = np.diag([1e-22, 1e-22, 1e-22])
    out = drift_in_holds(e + term, term, np.ones(n, bool), spans, sigma, term_columns=X, term_cov=cov,
                         form_columns=X[:, 1:])
    assert out["gain"] < -3.0 * out["se"], out
    from workbench.calibrate.drift_holds import _form_motion
    Fc = np.vstack([X[i:j, 1:] - X[i:j, 1:].mean(axis=0) for i, j in spans])
    Ec = np.concatenate([(e + term)[i:j] - (e + term)[i:j].mean() for i, j in spans])
    assert _form_motion(Fc, Ec, sigma)[0] > 100.0          # the holds do move in the form (hold88's switch)
    assert out["shows"] is False, out
