"""The base's plays include the declared core's own terminal-voltage thresholds (s22_triangle).

The clean stack's charge is ``G^{-1}[V_t]``, ``G = C_h^{-1} + (1/C_pp) I``: a PI operator of the terminal
voltage whose thresholds are Kuhnen's inverse of the file's, not the file's. The base's quadratic grid of 24
thresholds over the span straddles them; on a slow clean triangle its misfit (3.3e-9 m RMS, mid-ramp where a
straddled play engages) was three times the sensor's 1e-9 m, and a mode 10x above the drive took it, 5 of 5
folds (s22_outsider finding A1). With the declared thresholds in the grid, a noise-free clean record is
fitted to the simulator's own precision.
"""

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import PLANTS, load_benchmark
from workbench.calibrate.base_fit import declared_thresholds, fit_base
from workbench.calibrate.record import Record
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import SensorNoise, plant_with_effect, simulate_record
from workbench.plant import load_plant


def _triangle(rate_hz, duration_s, f_hz, hi_v=100.0):
    t = np.arange(int(round(duration_s * rate_hz))) / rate_hz
    ph = np.clip(t - 0.1 * duration_s, 0.0, None) * f_hz
    return t, hi_v * 2.0 * np.abs(ph - np.floor(ph + 0.5))


def _triangle_record(plant, seed=1, clean=True, rate=250.0, f=0.2, dur=30.0):
    """A 0.2 Hz 0-100 V triangle at 250 Hz simulated on ``plant`` (R in; ``clean``: noise-free), as a record
    with its blocks split: ``(t, r, rec, sp)``."""
    t, v = _triangle(rate, dur, f)
    kw = dict(noise=SensorNoise(0, 0, 0), gauge_noise=False) if clean else {}
    r = simulate_record(plant, t, v, seed=seed, **kw)
    rec = Record(Path("tri.csv"), {"current": "averaged", "gauge": "averaged"}, t,
                 {k: r[k] for k in ("voltage_v", "current_a", "displacement_m")}, 1 / rate)
    return t, r, rec, make_split(t, r["voltage_v"], "blocks")


def test_declared_thresholds_are_the_terminal_operators_inverse():
    """Kuhnen's inverse moves the file's thresholds: the V_t -> q map's are G^{-1}'s, not the file's C_h ones."""
    pzt = load_plant(PLANTS / "p888_51_sn637.toml").pzt
    r = declared_thresholds(pzt)
    assert np.allclose(r, pzt.terminal_operator().inverse().thresholds)
    assert r.size == pzt.hysteresis.thresholds.size and r[0] == 0.0 and np.all(np.diff(r) > 0)
    assert r[-1] > 1.5 * pzt.hysteresis.thresholds[-1]          # 39.8 V against the file's 17 V
    assert declared_thresholds(None).size == 0


def test_clean_slow_triangle_base_fits_to_the_simulators_precision():
    """Noise-free clean SN637 record, 250 Hz, 0.2 Hz triangle 0-100 V, R in: the displacement's base residual
    on the test rows is below 1e-11 m (a span of 15 um); the 24-play grid alone left ~3e-9 m."""
    plant, _ = plant_with_effect(load_plant(PLANTS / "p888_51_sn637.toml"), "none", 1)
    t, r, rec, sp = _triangle_record(plant)
    b = fit_base(rec, 80.0, train=sp.train, test=sp.test, pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    m = b.channels["displacement"]
    assert np.ptp(r["displacement_m"]) > 1e-5
    assert m.rms_test < 1e-11, m.rms_test
    # the declared thresholds inside the grid's range replace grid ones: the play count stays the grid's 24 (joined
    # beside the grid, s23: near-copies of columns, +29 % CPU on the speed record) and each of them is a play
    d = declared_thresholds(plant.pzt)
    inside = d[(d > 0) & (d < m.thresholds_v[-1])]
    assert m.thresholds_v.size + b.dropped_thresholds_v.size == 24
    assert inside.size >= 5 and np.all(np.isin(inside, m.thresholds_v)), (inside, m.thresholds_v)


def test_declared_threshold_beyond_the_grid_stays_out_of_a_creep_record():
    """A 100 kHz calibration-protocol record with a 14x creep (the confusion benchmark's seed 88 #68 draw): the
    recorded voltage's span (39.97 V) barely passes the declared core's top threshold (39.84 V). A play there moves
    only in the rows at the record's peak (0.13 V), less than the grid's own top play; with it the base took the
    creep held at the peak into that play (weight 8x the identity's), judged the recorded V the better drive, and
    its test error rose 1.85e-8 -> 2.49e-8 m (the creep then left 9.9e-9 m against 1.8e-9 m and a delay was
    named beside it). Every play of the base moves on the
    training rows at least as much as the grid's top play, and the declared thresholds leave the base's held-out
    error no worse than the grid's alone."""
    import workbench.calibrate.base_fit as bf
    from workbench.calibrate.pi_fit import pi_thresholds, play_matrix
    from workbench.calibrate.synthetic import benchmark_protocol

    plant0 = load_plant(PLANTS / "p888_51_sn637.toml")
    rate, n = 1e5, 40_000
    t, v = benchmark_protocol("calibration", rate, n)
    plant, _ = plant_with_effect(plant0, "creep", 125800809, duration_s=float(t[-1]), size=14.255376095587389)
    r = simulate_record(plant, t, v, seed=125800809)
    rec = Record(Path("creep.csv"), {"current": "averaged", "gauge": "averaged"}, t,
                 {k: r[k] for k in ("voltage_v", "current_a", "displacement_m", "gauge_v")}, 1 / rate)
    sp = make_split(t, r["voltage_v"], "blocks")
    kw = dict(train=sp.train, test=sp.test, pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    b = fit_base(rec, plant0.pzt.series_resistance_ohm, **kw)
    m = b.channels["displacement"]
    vd = np.asarray(b.v_drive, float)
    last = int(np.flatnonzero(sp.train)[-1])
    grid = pi_thresholds(vd[: last + 1], 24, "quadratic")
    # the top declared threshold lies inside the recorded voltage's span (V leads V_t through the 80 ohm: 39.97 V
    # against 39.81 V), where the trial's play moved 0.13 V and won V the drive's judgment
    v_rec = r["voltage_v"][: last + 1]
    assert declared_thresholds(plant.pzt)[-1] < float(np.max(np.abs(v_rec - v_rec[0])))
    moves = np.ptp(play_matrix(vd, m.thresholds_v, m.initial_states_v)[sp.train], axis=0)
    top = np.ptp(play_matrix(vd, grid[-1:], np.zeros(1))[sp.train])
    assert moves.min() >= top * (1 - 1e-9), (m.thresholds_v[np.argmin(moves)], moves.min(), top)
    orig = bf.declared_thresholds
    try:
        bf.declared_thresholds = lambda pzt: np.zeros(0)
        m0 = fit_base(rec, plant0.pzt.series_resistance_ohm, **kw).channels["displacement"]
    finally:
        bf.declared_thresholds = orig
    assert m.rms_test <= m0.rms_test, (m.rms_test, m0.rms_test)


def test_charge_keeps_the_grid_beside_the_motions_declared_thresholds():
    """The declared thresholds enter the motion's base only (s25_triangle3): the charge is the summed current, the
    monitor's white noise a random walk on it, and on the declared thresholds' closer charge base that walk's slow
    bend passed as an absorption (seed 92 #103 at 100 Hz, a 0.24x leakage named absorption; s24_triangle2). On the
    clean slow triangle the displacement's plays hold the declared thresholds inside the grid's range, the charge's
    none of them (the grid's on the same judged drive), and each channel's model is its own columns times its
    weights: ``plays_basis(ch) @ [w, offset]`` is its ``yhat`` (the columns the tracing and core refit use)."""
    from workbench.calibrate.pi_fit import pi_thresholds

    plant, _ = plant_with_effect(load_plant(PLANTS / "p888_51_sn637.toml"), "none", 1)
    t, r, rec, sp = _triangle_record(plant)
    b = fit_base(rec, 80.0, train=sp.train, test=sp.test, pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    d, q = b.channels["displacement"], b.channels["charge"]
    inside = declared_thresholds(plant.pzt)
    inside = inside[(inside > 0) & (inside < d.thresholds_v[-1])]
    assert inside.size >= 5 and np.all(np.isin(inside, d.thresholds_v))
    last = int(np.flatnonzero(sp.train)[-1])
    grid = pi_thresholds(np.asarray(b.v_drive, float)[: last + 1], 24, "quadratic")
    assert np.all(np.isin(q.thresholds_v, grid)) and not np.any(np.isin(inside, q.thresholds_v)), q.thresholds_v
    for name, m in (("displacement", d), ("charge", q)):
        B = b.plays_basis(name)
        assert B.shape[1] == m.thresholds_v.size + 1
        yhat = B @ np.r_[m.weights, m.offset]
        assert np.max(np.abs(yhat - m.yhat)) <= 1e-9 * np.ptp(m.y), name


def _stretched(plant, s):
    """The plant with its C_h thresholds scaled by ``s``: a stack whose core the file has ~10 % wrong."""
    import dataclasses

    from workbench.plant.hysteresis import PrandtlIshlinskii
    h = plant.pzt.hysteresis
    h2 = PrandtlIshlinskii(h.thresholds * s, h.weights, h.initial_states)
    return dataclasses.replace(plant, pzt=dataclasses.replace(plant.pzt, hysteresis=h2))


def test_a_file_whose_core_is_not_the_stacks_fits_no_worse_than_the_grid(monkeypatch):
    """The session 25 review: the file's core is a guess for the stack (its C_h shape assumed, C_p +-20 %). A
    stack whose C_h thresholds are 0.9x the file's, calibrated against the file (250 Hz, 0.2 Hz triangle, the
    seed's sensor noise): the file's thresholds sit between the stack's and the grid's. The base must fit the
    displacement's held-out rows no worse than the grid alone does (the declared thresholds forced: 4.54e-9 against
    2.71e-9 m, and the tracing named a resonance). Sessions 25 and 26 gated on the training misfit and split
    benchmark records from their effect-free twins (the two fits' own ridge choices moved the statistic); the gate
    now compares the two threshold sets at one common ridge on held-out training blocks (s27_ridge)."""
    import workbench.calibrate.base_fit as bf
    plant0 = load_plant(PLANTS / "p888_51_sn637.toml")
    truth, _ = plant_with_effect(_stretched(plant0, 0.9), "none", 1)
    t, r, rec, sp = _triangle_record(truth, seed=3, clean=False)
    kw = dict(train=sp.train, test=sp.test, pzt=plant0.pzt, dac_range_v=plant0.gauge.dac_range_v)
    b = fit_base(rec, 80.0, **kw)
    monkeypatch.setattr(bf, "declared_thresholds", lambda pzt: np.zeros(0))
    g = fit_base(rec, 80.0, **kw)
    assert b.channels["displacement"].rms_test <= 1.01 * g.channels["displacement"].rms_test


def test_a_clean_slow_triangle_is_calibrated_to_no_effect(tmp_path):
    """The capability s25_triangle3 merged, in ``make test`` (``test_outsider_records``' triangles run only under
    ``WORKBENCH_FULL=1``): a clean SN637 stack under the 250 Hz, 0.2 Hz triangle with the seed's sensor noise,
    calibrated against its own file by the command's function. Before the declared thresholds the grid's misfit
    mid-ramp (3.3e-9 m) was named a resonance 5 of 5 (s22_outsider A1); now nothing, and the error the user is
    told is left is not above the error before."""
    from workbench.calibrate.run import run_calibrate
    from workbench.calibrate.synthetic import write_record
    plant, _ = plant_with_effect(load_plant(PLANTS / "p888_51_sn637.toml"), "none", 1)
    t, r, _, _ = _triangle_record(plant, seed=3, clean=False)
    path = write_record(tmp_path / "tri.csv", {k: r[k] for k in ("time_s", "voltage_v", "current_a",
                                                                  "displacement_m", "gauge_v")})
    res = run_calibrate(path, PLANTS / "p888_51_sn637.toml", figures=False)
    assert res["effect"] in ("none", "inconclusive"), (res["effect"], res["agreement"], res.get("parameters"))
    assert res["error_after"]["rms"] <= res["error_before"]["rms"]


def test_a_large_creep_on_file_keeps_the_declared_thresholds_like_its_twin():
    """The confusion benchmark's seed 45 #90: a 8.56x creep on the file's own stack, 100 kHz steps. At a common ridge
    the grid's plays predict the held-out training blocks a little better (the grid's other thresholds take a part
    of the creep held through the steps: z 3.45 over 81 blocks with their scatter alone, above the t bar 3.20; 2.90
    with their correlation, Newey-West, session 27), and their held-out RMS is only 0.974 of the declared set's; the
    effect-free twin keeps the declared thresholds (z -2.69). The
    grid replaces the file's core only when clearly better (at most ``LINE_MARGIN`` of the declared set's
    held-out RMS, the margin the tracing asks of an effect): record and twin get the same base."""
    from workbench.calibrate.synthetic import benchmark_protocol
    from workbench.calibrate.base_fit import LINE_MARGIN

    plant0 = load_plant(PLANTS / "p888_51_sn637.toml")
    rate, seed = 1e5, 653338470
    t, v = benchmark_protocol("steps", rate, 40_000)
    R = plant0.pzt.series_resistance_ohm
    gates = []
    for effect in ("creep", "none"):
        plant, _ = plant_with_effect(plant0, effect, seed, duration_s=float(t[-1]), size=8.556783441298613)
        r = simulate_record(plant, t, v, seed=seed)
        rec = Record(Path("x.csv"), {"current": "averaged", "gauge": "averaged"}, t,
                     {k: r[k] for k in ("voltage_v", "current_a", "displacement_m", "gauge_v")}, 1 / rate)
        sp = make_split(t, r["voltage_v"], "blocks")
        b = fit_base(rec, R, train=sp.train, test=sp.test, pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
        g = b.threshold_gate
        assert g is not None and not g["grid"], (effect, g)
        d = declared_thresholds(plant0.pzt)
        inside = d[(d > 0) & (d < b.channels["displacement"].thresholds_v[-1])]
        assert inside.size and np.all(np.isin(inside, b.channels["displacement"].thresholds_v)), effect
        gates.append(g)
    # the record's grid is not clearly better, the twin's is worse than the declared core's
    assert gates[0]["ratio"] > LINE_MARGIN and gates[1]["ratio"] > 1.0, gates


def test_the_gate_allows_for_the_blocks_correlation():
    """The review of s27_ridge's record (a regression record): the confusion benchmark's seed 88 #156, a 8.36x creep
    on the file's own stack at 1 MHz steps. Neighbouring blocks' differences correlate (lag 1 ~ +0.4 there); with
    the blocks' scatter alone the standard error was ~1.5x too small and z passed (4.28 over 81 blocks against the
    bar 3.20; the twin -0.07), the base kept only by the margin (ratio 0.872). With the correlation (Newey-West)
    the record is decided by z as its twin is (2.99)."""
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, seed = cc.cases(seed=88, ends=True)[155]
    assert (e, rate, proto) == ("creep", 1e6, "steps")
    _, _, base, _, _, _ = cc.simulated_base(load_plant(PLANTS / "p888_51_sn637.toml"), (e,), rate, proto, size, seed)
    g = base.threshold_gate
    assert g is not None and g["z"] <= g["bar"], g


def test_a_drift_on_file_leaves_the_gate_where_its_twin_has_it():
    """The gate's drift columns (s27_driftbow's review): a sensor drift is a polynomial of time, in the span of the
    tracing's drift columns both threshold sets carry free, so it moves neither set's held-out block errors beyond
    the target's scale, which ``z`` and ``ratio`` do not see: a drift record on the file's own stack must get its
    effect-free twin's gate (the confusion benchmark's seed 105 #40, a 2.04x drift at 10 kHz calibration; without
    the drift columns in both sets the drift moved z toward the grid, 3.74 against the twin's -3.77, session 27).
    Both records share the seed's noise, so the two statistics agree to rounding."""
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, seed = cc.cases(seed=105, ends=True)[39]
    assert (e, rate, proto) == ("drift", 1e4, "calibration")
    plant0 = load_plant(PLANTS / "p888_51_sn637.toml")
    gates = [cc.simulated_base(plant0, eff, rate, proto, size, seed)[2].threshold_gate for eff in (("drift",), "none")]
    assert all(g is not None and g["channel"] == "displacement" for g in gates), gates
    rec, twin = gates
    # the drift's excursion (100-400 nm x size) is tens of times the motion's misfit: without the columns it is
    # no rounding
    assert rec["z"] == pytest.approx(twin["z"], rel=1e-4, abs=1e-4), (rec, twin)
    assert rec["ratio"] == pytest.approx(twin["ratio"], rel=1e-4), (rec, twin)
    assert rec["ridge"] == twin["ridge"] and rec["grid"] == twin["grid"], (rec, twin)


def test_the_gate_compares_both_sets_at_one_ridge_with_the_drift_free():
    """The gate's design (s27_ridge, s27_driftbow), against an independent computation: both threshold sets, each
    with the ones and the drift columns (``s``, ``s^2`` of normalized time) free, are fitted at ONE ridge, the one
    least in the two sets' summed blocked cross-validation, with every split block held out in turn; ``mean`` is
    the mean over the blocks of the declared set's squared prediction error minus the grid's, ``ratio`` the root of
    the grid's summed error over the declared set's. Here each held-out fit is bounded least squares on the stacked
    rows (the ridge as ``sqrt(ridge n)`` rows; their QR factors, then :func:`scipy.optimize.lsq_linear`), not the
    gate's Gram algebra.
    The record (the confusion benchmark's seed 105 #14, a 4.8x absorption at 1 kHz sines on the file's own stack)
    is one whose two sets pick different ridges on their own (the declared set 1e-5, the grid 1e-8): the
    per-set ridges moved ``ratio`` 2.84 -> 2.26, the drift columns dropped 2.84 -> 2.83 (both must fail here)."""
    from scipy.optimize import lsq_linear

    import workbench.calibrate.base_fit as bf
    from workbench.calibrate.splits import block_length_s
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, seed = cc.cases(seed=105, ends=True)[13]
    assert (e, rate, proto) == ("dielectric_absorption", 1e3, "sine")
    seen = {}
    gate = bf._grid_predicts_better

    def spy(*a, **k):
        seen["args"] = a
        return gate(*a, **k)

    orig, bf._grid_predicts_better = bf._grid_predicts_better, spy
    try:
        g = cc.simulated_base(load_plant(PLANTS / "p888_51_sn637.toml"), (e,), rate, proto, size, seed)[2].threshold_gate
    finally:
        bf._grid_predicts_better = orig
    P_d, r_d, P_g, r_g, y, rows, t = seen["args"]
    idx = np.flatnonzero(rows)
    n = idx.size
    s = (t - t[0]) / (t[-1] - t[0])
    b = y[rows] / np.sqrt(np.mean(y[rows] ** 2))
    block = np.floor((t[idx] - t[0]) / block_length_s(t)).astype(int)
    problems = []
    for P, r in ((P_d, r_d), (P_g, r_g)):
        A = np.column_stack([P, np.ones(t.size), s, s * s])[rows]
        A = A / np.sqrt(np.mean(A * A, axis=0))
        k = r.size
        free = np.r_[r == 0, True, True, True]          # the identity play, the offset and the drift unpenalized
        lower = np.r_[np.zeros(k), np.full(3, -np.inf)]
        problems.append((A, free, lower, bf._ridge_cv(A, b, lower, (~free).astype(float))))
    lam = bf.RIDGE_GRID[int(np.argmin(problems[0][3] + problems[1][3]))]
    assert g["ridge"] == lam and 0 < lam < np.inf
    errs = []
    for A, free, lower, _ in problems:
        pen = np.sqrt(lam * n) * np.diag((~free).astype(float))[~free]
        err = []
        for blk in np.unique(block):
            out = block == blk
            # the stacked rows' least squares through their QR factors (the same problem, columns x columns)
            Q, R = np.linalg.qr(np.vstack([A[~out], pen]))
            w = lsq_linear(R, Q.T @ np.r_[b[~out], np.zeros(pen.shape[0])], bounds=(lower, np.inf), method="bvls",
                           tol=1e-12).x
            err.append(float(np.sum((A[out] @ w - b[out]) ** 2)))
        errs.append(np.asarray(err))
    assert g["blocks"] == errs[0].size
    assert g["mean"] == pytest.approx(float(np.mean(errs[0] - errs[1])), rel=1e-5), (g, errs)
    assert g["ratio"] == pytest.approx(float(np.sqrt(errs[1].sum() / errs[0].sum())), rel=1e-5), g
