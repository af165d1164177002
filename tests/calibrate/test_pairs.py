"""Two-effect records answered with both where the record tells them apart (issue 13 item 5, session 16).

A later stage of the tracing (:mod:`workbench.calibrate.stages`) is judged on each validation fold,
and an effect that won no fold of the first stage must pass every fold: on each it must stand above
the noise floor and explain ``tracing.MIN_SHARE`` of what the found effect leaves there. The
benchmark's pair measure on the folds (``calibrate_confusion._beyond``) says how far each
effect stands beyond the other's form on each fold and what share of the other's leftover it is.
"""

import numpy as np
import pytest

from tests.conftest import FULL, leak_and_absorption_fits, load_benchmark, reduced_draws, stratified_draws
from workbench.calibrate.tracing import MIN_SHARE


def _bench():
    return load_benchmark("calibrate_confusion")


def _leak_and_absorption(sn637, tau_s):
    """The leak + absorption steps record's ``(base, base0, split)`` (:func:`tests.conftest.leak_and_absorption_fits`)."""
    return leak_and_absorption_fits(sn637, tau_s)


def _leak_and_absorption_beyond(sn637, tau_s):
    """``calibrate_confusion._beyond``'s figures for the pair of :func:`_leak_and_absorption`."""
    base, base0, sp = _leak_and_absorption(sn637, tau_s)
    return _bench()._beyond(base, base0, ("leakage", "dielectric_absorption"), sp)


def _fold_rms_by_hand(base, ch, sp):
    """Per fold, the base's columns refitted (their corrections bounded as the base's: ``tracing._base_lower``)
    to what the base leaves, by scipy's bounded least squares on the fold's training rows only, and the RMS
    of what they leave on the fold's validation rows: an independent computation of ``_left_by``'s
    ``names=[]`` fold figures."""
    from scipy.optimize import lsq_linear

    from workbench.calibrate.tracing import _base_lower
    m = base.channels[ch]
    e0 = m.y - m.yhat
    lo = _base_lower(base, ch)
    out = []
    for tr, va in sp.folds:
        rt, rv = sp.rows(tr) & m.valid, sp.rows(va) & m.valid
        assert not np.any(rt & rv) and not np.any((rt | rv) & sp.test)
        A = base.plays_basis(ch)            # the channel's own plays, as the tracing's
        scale = np.sqrt(np.mean(A[rt] ** 2, axis=0))
        scale[scale == 0] = 1.0
        sol = lsq_linear(A[rt] / scale, e0[rt], bounds=(lo * scale, np.inf), method="bvls", tol=1e-14)
        out.append(float(np.sqrt(np.mean((e0 - A @ (sol.x / scale))[rv] ** 2))))
    return out


def test_the_pair_measure_on_every_fold_follows_the_forms(sn637):
    """On each validation fold as on the test rows: an absorption relaxing within the record (tau =
    T/20) bends and a leak ramps over every block set, so each stands >= 3x beyond the other on every
    fold and explains most of what the other leaves there; one relaxing over 30 record lengths is the
    leak's own form to O(T / 2 tau) = 2 % on every block set, so neither stands 1x beyond the other on
    any fold. The fold figures' test-row one is :func:`beyond_sizes`' (the same fit)."""
    cc = _bench()
    base, base0, sp = _leak_and_absorption(sn637, 0.5)
    fast = cc._beyond(base, base0, ("leakage", "dielectric_absorption"), sp)
    slow = _leak_and_absorption_beyond(sn637, 300.0)
    # the fold plumbing: weights from each fold's training rows, figures on its validation rows, no test
    # row: the base's own fold figures against an independent per-fold bounded solve, and the fold
    # figures are not the test rows' (each fold's validation rows are other blocks than the test part's)
    test_rms, fold_rms = cc._left_by(base, "charge", [], sp, folds=True)
    hand = _fold_rms_by_hand(base, "charge", sp)
    print(f"\nbase on charge: folds {np.round(fold_rms, 6)} by hand {np.round(hand, 6)} test {test_rms:.6g}")
    # two bounded solvers agree to ~1e-5; fitting on all development rows, scoring on the training rows or on
    # the test rows moves a fold's figure by 1-34 % here (measured): 1e-4 tells them apart
    np.testing.assert_allclose(fold_rms, hand, rtol=1e-4)
    assert len(set(np.round(fold_rms, 12))) == len(fold_rms)        # five different row sets
    assert all(abs(f - test_rms) > 1e-6 * test_rms for f in fold_rms)
    for x in fast:
        assert all(abs(f - x["test"]) > 1e-3 * x["test"] for f in x["folds"])
    for name, b in (("tau 0.5 s", fast), ("tau 300 s", slow)):
        print(f"\n{name}: test {[round(x['test'], 2) for x in b]} folds {[np.round(x['folds'], 2) for x in b]} "
              f"shares {[np.round(x['shares'], 2) for x in b]}")
    assert all(len(x["folds"]) == 5 and len(x["shares"]) == 5 for x in fast + slow)
    assert all(min(x["folds"]) >= 3.0 and min(x["shares"]) > MIN_SHARE for x in fast)
    assert all(max(x["folds"]) < 1.0 for x in slow)
    assert all(0.0 <= s <= 1.0 for x in fast + slow for s in x["shares"])


# creep + sensor delay records at 1 kHz (the rate of session 15's separable misses, where the delay is
# a sample or less), drawn with np.random.default_rng(1617), fixed before any record was traced: protocol,
# size multiplier log-uniform and stratified (one draw in each of CD_1K equal log-bands of the benchmark's
# 0.03-30x, so the draw spans the whole range: session 16's unstratified four fell in 0.03-0.6x), record seed
CD_1K = 4 if not FULL else 12


def _draws():
    return stratified_draws(1617, CD_1K)


@pytest.fixture(scope="module")
def drawn_1k(sn637):
    cc = _bench()
    rows = []
    for proto, size, seed in _draws():
        r = cc.evaluate(sn637, ("creep", "delay"), 1e3, proto, size, seed)
        print(f"\ncreep+delay 1 kHz {proto:11s} size x{size:.3g} own {np.round(r['excesses'], 2)} beyond "
              f"{np.round(r['beyond'], 2)} on every fold {np.round(r['beyond_folds'], 2)} share "
              f"{np.round(r['share_folds'], 2)} -> {r['named']} {r['class']}")
        rows.append(r)
    return rows


def test_drawn_1khz_creep_and_delay_name_both_where_every_fold_tells_them_apart(drawn_1k):
    """Nothing the record lacks is named, and a pair whose two effects each stand >= 3x beyond the other
    on every validation fold and explain more than ``MIN_SHARE`` of what the other leaves there (what a
    later stage must show on every fold, the tracing's own share rule: a check that the benchmark's
    measure and the tracing agree, not independent evidence) is answered with both. The draw spans the
    size range, and at least one record is told apart on every fold (else the test says nothing)."""
    cc = _bench()
    sizes = sorted(r["size"] for r in drawn_1k)
    edges = np.exp(np.linspace(np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1]), CD_1K + 1))
    assert np.all(np.histogram(sizes, edges)[0] == 1), sizes      # one in every log-band of 0.03-30x
    assert not [r for r in drawn_1k if r["class"] == "wrong"], [r["named"] for r in drawn_1k]
    fsep = [r for r in drawn_1k if min(r["beyond_folds"]) >= 3.0]
    sep = [r for r in fsep if min(r["share_folds"]) > MIN_SHARE]
    print(f"\nsizes {np.round(sizes, 3)}; >= 3x beyond on every fold: {len(fsep)} of {len(drawn_1k)}, "
          f"and above MIN_SHARE: {len(sep)}; both named: {sum(r['both'] for r in sep)}")
    assert sep, "no drawn record is told apart on every fold: the test would pass vacuously"
    assert all(r["both"] for r in sep), [(r["protocol"], r["size"], r["named"]) for r in sep]


def test_a_1khz_delay_behind_a_large_creep_is_named_where_creeps_form_leaves_much(sn637):
    """Confusion seed 47 #9 (1 kHz calibration, creep 21.5x, a 1.56 ms delay 6.1x on its own record): the
    delay stands 5.5-16.9x beyond creep on every fold (the benchmark's measure, with the model-driven creep
    spectrum), but that spectrum left 14.7x the floor on fold 4, of which the delay explained 23 %, under
    MIN_SHARE: creep alone (session 16, a strict xfail here). With the branches driven by the voltage across
    C_h (:mod:`workbench.calibrate.creep_across`, session 17) creep's first stage leaves 0.18 of the record's
    error (0.33 before) and the delay's later stage passes every fold: both, MIN_SHARE unchanged."""
    cc = _bench()
    e, rate, proto, size, seed = cc.cases(1, 47)[8]
    assert (e, rate, proto) == (("creep", "delay"), 1e3, "calibration")
    # the beyond-the-other sizes quoted above are the benchmark's diagnostics (printed by calibrate_confusion.py);
    # the test asserts the answer only, so it skips them (diagnostics=False: the answer is the same)
    r = cc.evaluate(sn637, e, rate, proto, size, seed, diagnostics=False)
    print(f"\n47 #9: own sizes {np.round(r['excesses'], 2)} -> {r['named']} first {r['ratio_first']:.3f}")
    assert r["class"] == "right"
    assert r["both"]


def _creep_and_delay_fits(sn637, protocol, delay_s):
    """A 1 kHz record (10 s) of ``protocol`` with 78 #20's creep (five Kelvin-Voigt branches across C_h of
    16.7 uF each at 0.1-1000 s: the confusion benchmark's seed 78 record 20, size 14) and a sensor delay of
    ``delay_s`` (0: none), and its effect-free twin (same noise), base-fitted as the benchmark does:
    ``(base, base0, split)``."""
    import dataclasses

    from workbench.calibrate.base_fit import fit_base
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
    from workbench.plant.creep import CreepParams
    cc = _bench()
    clean, _ = plant_with_effect(sn637, "none", 0)
    tau = np.array([0.1, 1.0, 10.0, 100.0, 1000.0])
    plant = dataclasses.replace(clean, pzt=dataclasses.replace(clean.pzt, creep=CreepParams(tau, np.full(5, 1.67e-5))),
                                additions=dataclasses.replace(clean.additions, sensor_delay_s=delay_s))
    t, v = benchmark_protocol(protocol, 1e3, 10_000)
    r, r0 = simulate_record(plant, t, v, seed=5), simulate_record(clean, t, v, seed=5)
    sp = make_split(t, r["voltage_v"], "blocks")
    kw = dict(train=sp.train, test=sp.test, pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    R = sn637.pzt.series_resistance_ohm
    return fit_base(cc._record(r, 1e-3), R, **kw), fit_base(cc._record(r0, 1e-3), R, **kw), sp


@pytest.mark.parametrize("protocol", reduced_draws([("steps",), ("sine",)], keep={0}))
def test_a_record_without_a_delay_is_not_told_apart_as_creep_and_delay(sn637, protocol):
    """The pair measure asks whether an effect stands beyond what the other's forms explain; "the
    other's forms" are every one the tracing has (``_left_by``'s variants): the simulator's creep is
    Kelvin-Voigt branches across C_h driven by the voltage across it (:mod:`workbench.plant.creep`), the
    tracing's branches are so driven (``tracing.creep_loops``), and driven by the base model's prediction
    (a record without a declared PZT). A record with a large creep and **no delay** has nothing a delay
    can add beyond the creep but the creep form's own misfit: with the V_h-driven form among the creep's
    forms the delay stands under the benchmark's 3x line; with the model-driven form alone (``loops={}``,
    the measure before session 20) the delay's column takes up that form's misfit and reads >= 3x beyond
    the creep, a pair "told apart" on a record that has one effect. The creep itself stands far beyond
    the delay either way."""
    cc = _bench()
    base, base0, sp = _creep_and_delay_fits(sn637, protocol, 0.0)
    creep, delay = cc._beyond(base, base0, ("creep", "delay"), sp)
    print(f"\n{protocol}, no delay: beyond (creep, delay) {creep['test']:.2f}, {delay['test']:.2f}; "
          f"least fold {min(creep['folds']):.2f}, {min(delay['folds']):.2f}")
    assert creep["test"] >= 3.0
    assert delay["test"] < 3.0
    if FULL:        # the two creep forms disagree on this record (the contrast, in the full form only)
        _, model_only = cc._beyond(base, base0, ("creep", "delay"), sp, loops={})
        print(f"model-driven creep only: the delay beyond it {model_only['test']:.2f}")
        assert model_only["test"] >= 3.0
