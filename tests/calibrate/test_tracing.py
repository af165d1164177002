"""The tracing's linear problem (:class:`workbench.calibrate.tracing._Problem`): numerically honest SSEs."""

import numpy as np
import pytest

from tests.conftest import reduced_draws
from workbench.calibrate import tracing as T
from workbench.calibrate.splits import make_split
from workbench.calibrate.tracing import _Problem

DRAWS = 8


def _ill_conditioned_problem(rng):
    """A problem whose base and candidate columns together have a condition number drawn log-uniform
    in 1e8-1e12, its target ``X w_true + e`` with ``e`` orthogonal to every column (on all rows) and
    ``w_true`` up to ~1e8 along the columns' weakest direction (30 #97's joint fit: scaled weights to
    1.7e8): the SSE of ``w_true`` on any rows is ``sum(e^2)`` there, a closed form.

    Returns ``(prob, g, w_true_scaled, e_scaled, kappa)``: ``w`` and ``e`` in the problem's scaled units.
    """
    n = int(rng.integers(20_000, 60_000))
    k0, m = int(rng.integers(3, 12)), int(rng.integers(1, 8))     # base columns, candidate columns
    p = k0 + m
    kappa = 10.0 ** rng.uniform(8, 12)
    t = np.arange(n) / 1e4
    v = 50 + 40 * np.sin(2 * np.pi * rng.uniform(2, 20) * t)
    sp = make_split(t, v, "blocks")
    Q, _ = np.linalg.qr(rng.standard_normal((n, p + 1)))
    V, _ = np.linalg.qr(rng.standard_normal((p, p)))
    s = np.sqrt(n) * np.geomspace(1.0, 1.0 / kappa, p)
    units = 10.0 ** rng.uniform(-9, 3, p)                          # columns in any units
    X = (Q[:, :p] * s) @ V.T * units                               # X = Q S V' U
    share = 10.0 ** rng.uniform(-3, 0)                             # the residual's share of the target
    e = Q[:, p] * np.sqrt(n * share)                               # orthogonal to X on all rows
    # X w = Q a for w = U^-1 V S^-1 a; the weakest direction's coefficient makes the weights (in units
    # of unit-RMS columns) up to 1e6-1e8
    a = rng.standard_normal(p)
    a[-1] = np.sign(a[-1]) * 10.0 ** rng.uniform(6, 8) / kappa
    w_true = (V @ (a / s)) / units
    r = X @ w_true + e
    A, C = X[:, :k0], X[:, k0:]
    prob = _Problem(sp, np.ones(n, bool), A, np.full(k0, -np.inf), r, sp.train)
    g = prob.grams(C, np.full(m, -np.inf))
    assert prob.A.shape[1] == k0 and g["C"].shape[1] == m
    w_s = np.r_[w_true[:k0] * prob.col_norms, w_true[k0:] * g["norms"]] / prob.scale
    return prob, g, w_s, e / prob.scale, kappa


def _rows_sse(prob, g, w, blocks):
    """The SSE summed from the rows in extended precision (the reference)."""
    rows = np.concatenate([prob.idx[b] for b in np.flatnonzero(blocks)])
    k = prob.A.shape[1]
    L = np.longdouble
    e = prob.A[rows].astype(L) @ w[:k].astype(L) + g["C"][rows].astype(L) @ w[k:].astype(L) - prob.r[rows].astype(L)
    return float(np.sum(e * e))


@pytest.mark.parametrize("draw", range(DRAWS))
def test_sse_is_the_rows_sse_on_ill_conditioned_columns(draw):
    """Review B2: ``w'Gw - 2 w'h + c`` cancels when the columns are nearly dependent and the weights
    large (30 #97: 4.9e-8 against 5.2e-9 from the rows). On columns of condition number 1e8-1e12 the
    SSE the tracing compares equals the closed form ``sum(e^2)`` for the weights that leave ``e``,
    and the rows' SSE for the weights its own solve returns, on every fold's validation rows and on
    the development rows, to 1e-8 relative."""
    rng = np.random.default_rng(1500 + draw)
    prob, g, w_true, e, kappa = _ill_conditioned_problem(rng)
    sp = prob.split
    for tr, va in sp.folds + [(sp.dev_blocks, sp.dev_blocks)]:
        rows = np.concatenate([prob.idx[b] for b in np.flatnonzero(va)])
        closed = float(np.sum(e[rows] ** 2))
        assert prob.sse(g, w_true, va)[0] == pytest.approx(closed, rel=1e-8), f"kappa {kappa:.3g}"
        w = prob.solve(g, tr)
        ref = _rows_sse(prob, g, w, va)
        assert prob.sse(g, w, va)[0] == pytest.approx(ref, rel=1e-8), f"kappa {kappa:.3g}, max |w| {abs(w).max():.3g}"
        n = prob.n_rows(va)
        assert prob.fold_rms(g, tr, va) == pytest.approx(np.sqrt(ref / n) * prob.scale, rel=1e-8)


def test_sse_on_well_conditioned_columns_is_the_gram_estimate():
    """On independent columns (condition ~1) the Gram estimate is kept (no row sums) and equals the rows'
    SSE to 1e-12: the fast path is exact where it should be."""
    rng = np.random.default_rng(1510)
    n = 30_000
    t = np.arange(n) / 1e4
    sp = make_split(t, np.sin(2 * np.pi * 5 * t), "blocks")
    A = rng.standard_normal((n, 4))
    C = rng.standard_normal((n, 2))
    r = A @ rng.standard_normal(4) + C @ rng.standard_normal(2) + rng.standard_normal(n)
    prob = _Problem(sp, np.ones(n, bool), A, np.full(4, -np.inf), r, sp.train)
    g = prob.grams(C, np.full(2, -np.inf))
    calls = []
    prob._sse_rows = lambda *a: calls.append(1) or 0.0
    for tr, va in sp.folds:
        w = prob.solve(g, tr)
        assert prob.sse(g, w, va)[0] == pytest.approx(_rows_sse(prob, g, w, va), rel=1e-12)
    assert not calls


RNG_R2 = np.random.default_rng(1520)
R2_DRAWS = [(proto, str(RNG_R2.choice(["delay", "creep+delay"])), float(RNG_R2.choice([1000.0, 10000.0])),
             float(np.exp(RNG_R2.uniform(0.0, np.log(30.0)))), int(RNG_R2.integers(1 << 30)))
            for proto in ("sine", "steps", "calibration")]


@pytest.mark.parametrize("proto, effect, rate, size, seed", R2_DRAWS)
def test_a_found_refitted_delay_is_scored_later_as_it_was_named(sn637, proto, effect, rate, size, seed):
    """Review R2: a found refitted delay enters a later stage's model with the columns it was named
    with, fold for fold (each fold's drive-model weights fitted on that fold's training search rows,
    bounded as the base's), as the joint creep + delay reading's delay column is: the later stage's
    ``before`` on every fold equals the delay's own validation RMS of the stage that named it, and it
    does not move when the record is corrupted outside the fold's training search rows. (It was the
    search's unbounded column fitted on all development rows: validation rows seen, 30 #97's befores
    1.4-2.6e-8 m against 0.66-1.3e-8 m.) Records: the confusion benchmark's, a delay or creep + delay
    drawn 1-30x, ``default_rng(1520)``."""
    from tests.conftest import load_benchmark
    effects = tuple(effect.split("+")) if "+" in effect else effect
    t, sp, base, _, _, _ = load_benchmark("calibrate_confusion").simulated_base(sn637, effects, rate, proto, size,
                                                                              seed)
    key = ("displacement", "model")
    n = len(sp.folds)

    def problem(y, p=None):
        m = base.channels["displacement"]
        B = base.channel_basis("displacement")
        lower = T._base_lower(base, "displacement")
        prob = T._Problem(sp, m.valid, B, lower, y - m.yhat, T._search_rows(sp.train & m.valid))
        plan = T.candidate_plan(base.channels, t, base.v_drive, tau_min_s=sp.block_s, basis={"displacement": B})
        (dl,) = [e for ch, e, _ in plan if e.name == "delay" and ch == "displacement"]
        if p is None:
            p, _ = T._candidate_columns(dl, t, m.yhat, y, m.yhat, prob)
        g, fold_g = T._refit_grams(dl, p, t, y, m.yhat, prob, lower)
        return prob, {"name": "delay", "channel": "displacement", "key": key, "g": g, "fold_g": fold_g, "p": p}

    m = base.channels["displacement"]
    prob, cand = problem(m.y)
    assert cand["fold_g"] is not None
    named = T._cand_grams(prob, [], cand, n)
    extra = {key: []}
    T._absorb(cand, extra, {key: prob}, base, t)
    later = T._cand_grams(prob, extra[key], None, n)
    for f, (tr, va) in enumerate(sp.folds):
        assert prob.fold_rms(later[f], tr, va) == pytest.approx(prob.fold_rms(named[f], tr, va), rel=1e-9)
    # the later stage's fold-f prediction on its validation rows ignores the record outside its training rows
    noise = np.random.default_rng(seed).standard_normal(t.size) * 10 * np.std(m.y - m.yhat)
    for f, (tr, va) in enumerate(sp.folds):
        seen = prob.search & sp.rows(tr)
        y_bad = np.where(seen, m.y, m.y + noise)
        # (the lag itself is searched on all development rows, the module's known limitation: kept)
        prob_bad, cand_bad = problem(y_bad, cand["p"])
        extra_bad = {key: []}
        T._absorb(cand_bad, extra_bad, {key: prob_bad}, base, t)
        val = sp.rows(va) & m.valid
        clean = prob.predict(later[f], tr)[0][val]
        bad = prob_bad.predict(T._cand_grams(prob_bad, extra_bad[key], None, n)[f], tr)[0][val]
        assert np.max(np.abs(bad - clean)) <= 1e-6 * np.sqrt(np.mean(clean ** 2)), f


# ---- a displacement-sensor drift against a gauge bow (session 16, branch s16_mhz)

RNG_DRIFT = np.random.default_rng(1616)
DRIFT_DRAWS = [(effect, rate, float(np.exp(RNG_DRIFT.uniform(np.log(0.03), np.log(30.0)))),
                int(RNG_DRIFT.integers(1 << 30)))
               for effect in ("drift", "drift+resonance") for rate in (1e5, 1e6)]
#: the confusion benchmark's 48 #165 (1 MHz, 0.1 s steps; drift 9.4x, resonance 6.4x on their own records),
#: named a gauge bow 5 of 5 by main ecdf16d
DRIFT_48_165 = (("drift", "resonance"), 1e6, "steps", 1.0120432388136424, 606078135)


# make test: the drift at 100 kHz (session 28, for the suite's time: the drift + resonance at 1 MHz moved to the full
# form; make test keeps a drift + mode at 1 MHz in test_line_floor's plain-mode carry); WORKBENCH_FULL=1 all four
@pytest.mark.parametrize("effect, rate, size, seed", reduced_draws(DRIFT_DRAWS, keep={0}))
def test_a_displacement_sensor_drift_is_never_named_a_gauge_bow(sn637, effect, rate, size, seed):
    """The gauge reads the stack; a drift of the displacement sensor moves the recorded displacement
    only, so the gauge's misfit against a line of the recorded displacement (the bow's problem) is a
    function of time, not of the displacement. On steps records (the displacement a staircase in time,
    over which a bow's quadratic in x takes part of a drift's t, t^2) at 100 kHz and 1 MHz, sizes
    log-uniform over the benchmark's whole range (``default_rng(1616)``, fixed before any run), a
    gauge bow is never named, nor anything else the record lacks."""
    from tests.conftest import load_benchmark
    cc = load_benchmark("calibrate_confusion")
    effects = tuple(effect.split("+"))
    r = cc.evaluate(sn637, effects if len(effects) > 1 else effects[0], rate, "steps", size, seed, diagnostics=False)
    print(f"\n{effect} {rate:g} x{size:.3f} excess {r['excess']:.2f} -> {r['answer']} {r['named']} {r['fold_winners']}")
    assert "gauge_nonlinearity" not in r["named"], r["fold_winners"]
    assert r["class"] != "wrong", r["named"]


def test_the_drift_a_gauge_bow_took_is_named(sn637):
    """48 #165: the drift stands 9.4x above the floor on its own record; the bow's fit to the gauge
    against the recorded displacement was the drift's imprint (a drift in time fits it better held
    out on every fold). The drift is named (and nothing the record lacks)."""
    from tests.conftest import load_benchmark
    r = load_benchmark("calibrate_confusion").evaluate(sn637, *DRIFT_48_165, diagnostics=False)
    print(f"\n-> {r['answer']} {r['named']} {r['fold_winners']} ratio {r['ratio']:.2f}")
    assert r["class"] == "right" and "drift" in r["named"], (r["named"], r["fold_winners"])


# ---- the cost side of the bow's drift rival: a true bow on a rising staircase (review of s16_mhz)

def _rising_staircase(rate_hz, n_rows, n_steps=8):
    """Eight rising holds 10 -> 100 V filling the benchmark's record (a monotone staircase: the
    displacement a function of time across the steps, constant within each hold)."""
    from workbench.calibrate.protocol import calibration_protocol
    dt = 1.0 / rate_hz
    dur = n_rows * dt
    rest = 0.5 * dur / 14.5
    return calibration_protocol(dt_s=dt, rest_s=rest, sine_cycles=0, stairs_v=tuple(np.linspace(10, 100, n_steps)),
                                hold_s=(dur - rest) / n_steps, chirp_s=0.0)


RNG_BOW = np.random.default_rng(1623)
#: one size per band of the benchmark's upper range (3-10x, 10-30x) at 100 kHz and 1 MHz, drawn before any run
BOW_DRAWS = [(rate, float(np.exp(RNG_BOW.uniform(np.log(lo), np.log(hi)))), int(RNG_BOW.integers(1 << 30)))
             for rate in (1e5, 1e6) for lo, hi in ((3.0, 10.0), (10.0, 30.0))]


# make test: the 100 kHz draw (session 28, for the suite's time: the 1 MHz 10-30x draw moved to the full form);
# WORKBENCH_FULL=1 all four
@pytest.mark.parametrize("rate, size, seed", reduced_draws(BOW_DRAWS, keep={0}))
def test_a_gauge_bow_on_a_rising_staircase_is_not_taken_by_the_drift_rival(sn637, monkeypatch, rate, size, seed):
    """On a monotone staircase time is a function of the displacement across the steps, so a drift's
    ``t, t^2`` can fit the bow's misfit about as well as the bow's own ``x^2``; within a hold the
    displacement stands still while time runs, so a bow leaves the misfit constant there. The rival
    counts only where the holds show its motion (``drift_in_holds``): a true bow is never named a drift
    or anything else the record lacks, and where it stands >= 3x above the floor on the record
    (``excess``) it is named. Without the hold check 100 kHz x3 / x10 / x30 and 1 MHz x10 went
    inconclusive in the review's runs."""
    from tests.conftest import load_benchmark
    cc = load_benchmark("calibrate_confusion")
    orig = cc.benchmark_protocol
    monkeypatch.setattr(cc, "benchmark_protocol",
                        lambda kind, rate_hz, n_rows: _rising_staircase(rate_hz, n_rows) if kind == "rising"
                        else orig(kind, rate_hz, n_rows))
    r = cc.evaluate(sn637, "gauge_nonlinearity", rate, "rising", size, seed, diagnostics=False)
    print(f"\n{rate:g} x{size:.2f} excess {r['excess']:.2f} -> {r['answer']} {r['named']} {r['fold_winners']}")
    assert r["class"] != "wrong", r["named"]
    if r["excess"] >= 3.0:
        assert r["class"] == "right", r["fold_winners"]
