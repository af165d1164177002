"""The joint creep + sensor delay model (workbench/calibrate/creep_beside_delay.py; issue 13 item 5).

A sensor lagging by ``d`` reads the crept motion late: ``y(t) = x(t - d)``, ``x = base(u) +
creep(u)``. Constructed records (no simulator) make the joint model exact at the true delay, so
the joint search must find it; the delay searched alone (the drive model refitted without the
branches) is biased by the creep's fast branch.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from workbench.calibrate import creep_beside_delay as cbd
from workbench.calibrate.synthetic import EFFECT_RANGES, benchmark_protocol
from workbench.calibrate.tracing import candidate_plan

from tests.conftest import FULL, load_benchmark, reduced_draws

#: drawn with np.random.default_rng(1414), chosen before any run: rate (the benchmark's 1, 10 and
#: 100 kHz at its row counts: 10 s, 2 s, 0.4 s), protocol, the delay over the benchmark's whole range
#: (EFFECT_RANGES' 0.3-2 ms times a size log-uniform over 0.03-30x: 0.01-60 ms), two creep branches
#: of the record's own grid with gains drawn up to a fifth of the model per branch
N_DRAWS = 8


def _draws():
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(1414)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    out = []
    for _ in range(N_DRAWS):
        rate = float(cc.RATES_HZ[int(rng.integers(len(cc.RATES_HZ)))])
        proto = str(rng.choice(("calibration", "sine", "steps")))
        d_s = float(rng.uniform(*EFFECT_RANGES["delay"]["delay_s"]) * np.exp(rng.uniform(lo, hi)))
        out.append((rate, proto, cc.ROWS[rate], d_s, int(rng.integers(1 << 30))))
    return out


def _record(rate, proto, n_rows, d_s, seed):
    """A constructed channel: drive model ``ym`` (three columns), creep on the record's branch grid,
    read ``d_s`` late (linear interpolation, as the search's own); the plan's creep and delay."""
    rng = np.random.default_rng(seed)
    t, u = benchmark_protocol(proto, rate, n_rows)
    B = np.column_stack([u, u * u / 100.0, np.ones_like(u)])
    w0 = np.array([1e-7, 2e-8, 1e-6])                 # m per V, m per V (scaled), m
    ym = B @ w0
    plan = candidate_plan(("displacement",), t, u, basis=B)
    creep = next(e for ch, e, _ in plan if e.name == "creep")
    delay = next(e for ch, e, _ in plan if e.name == "delay")
    taus = np.asarray(creep.taus_s, float)
    K = creep._columns(ym, taus, 1.0 / rate)
    g = np.zeros(taus.size)
    pick = rng.choice(taus.size, 2, replace=False)
    g[pick] = rng.uniform(0.0, 0.2, 2)
    x = ym + K @ g
    y = np.interp(t - d_s, t, x)
    return t, B, ym, y, taus, delay


@pytest.mark.parametrize("draw", _draws())
def test_the_joint_search_explains_creep_behind_a_delay(draw):
    """The delay searched with the creep branches in its refit (:func:`~.creep_beside_delay._joint`):

    - its columns (the base's, the delay's, the delayed branches) leave less of the record than the
      delay searched alone (its refit without the branches) and, where the lag is resolvable (0.3
      sample or more; the construct is exact at the true delay), under 1 % of the record's power;
    - on records with steps (steps, the calibration protocol) it lands on the true lag within the
      search's tolerance (0.1 sample). On a sine a fast branch and a delay trade (``-tau du/dt``
      against ``-d dy/dt``): there only what the columns explain is asserted.
    """
    rate, proto, n_rows, d_s, seed = draw
    t, B, ym, y, taus, delay = _record(rate, proto, n_rows, d_s, seed)
    d_true = d_s * rate
    if d_true > 0.25 * (t[-1] - t[0]) * rate:
        pytest.skip("delay beyond the search's bound (a quarter of the record)")
    base = SimpleNamespace(channels={"displacement": SimpleNamespace(y=y, yhat=ym)})
    every = np.ones(t.size, bool)
    cr = {"channel": "displacement", "params": {"taus_s": taus.tolist()}}
    d, Kd, D = cbd._joint(cr, {"eff": delay}, SimpleNamespace(search=every), base, t)

    def left(X):
        coef = np.linalg.lstsq(X, y - ym, rcond=1e-12)[0]
        return float(np.sqrt(np.mean((y - ym - X @ coef) ** 2)))

    joint = left(np.column_stack([B, D, Kd]))
    _, col = delay._fit_refit(t, y, ym, every)
    alone = left(np.column_stack([B, col]))
    assert joint < alone, (rate, proto, d_true, joint, alone)
    if d_true >= 0.3:
        assert joint < 0.1 * np.sqrt(np.mean((y - ym) ** 2)), (rate, proto, d_true, joint)
        if proto != "sine":
            assert abs(d - d_true) <= 0.1, (rate, proto, d_true, d)


def test_refitted_joint_stage_writes_the_joint_parameters_into_the_replaced_stage():
    """Named, a joint candidate's refit moves into the stage it replaced: the delay's refitted lag and
    its column's gain (creep beside a delay: branches first, delay last), or the branches' gains
    (a delay beside creep: delay first, branches after, negative gains clipped as the spectrum's)."""
    delay_st = {"effect": "delay", "channel": "displacement", "parameters": {"delay_s": 1e-3, "delay_samples": 1.0}}
    creep_st = {"effect": "creep", "channel": "displacement", "_cand": {"replaces": ("delay", "displacement"),
                "refit": {"delay_samples": 1.5, "delay_s": 1.5e-3}}, "_gains": np.array([0.1, 0.2, 0.9])}
    stages = [delay_st, creep_st]
    cbd.refitted_joint_stage(stages)
    assert delay_st["parameters"]["delay_s"] == 1.5e-3 and delay_st["parameters"]["delay_samples"] == 1.5
    assert delay_st["parameters"]["scale"] == 0.9 and "refitted" in delay_st
    creep_st2 = {"effect": "creep", "channel": "displacement", "parameters": {"gains": [0.5], "taus_s": [1.0]}}
    delay_st2 = {"effect": "delay", "channel": "displacement", "_cand": {"replaces": ("creep", "displacement"),
                 "refit": {"taus_s": [1.0, 10.0]}}, "_gains": np.array([1.0, 0.3, -0.1])}
    cbd.refitted_joint_stage([creep_st2, delay_st2])
    assert creep_st2["parameters"]["gains"] == [0.3, 0.0] and creep_st2["parameters"]["taus_s"] == [1.0, 10.0]


def test_a_joint_creep_keeps_the_drive_its_branches_were_fitted_on():
    """The joint candidate's branches are driven as the creep candidate's (session 18, 71 #46: driven by the base
    model beside a V_h-driven creep, the joint model's creep part was a second creep and won with a spurious lead):
    ``_branch_drive`` is the candidate's V_h where it was fitted with one, else None (the base model drives); the
    refitted creep stage keeps ``driver: v_h`` only where the joint fit's branches were V_h's (a base-model fit
    written with ``driver: v_h`` was rebuilt on V_h: review of s17_creep)."""
    from workbench.calibrate.effects import CreepSpectrum
    eff = CreepSpectrum(taus_s=[1.0])
    eff._drive = np.arange(5.0)
    assert cbd._branch_drive({"eff": eff, "params": {"driver": "v_h"}}) is eff._drive
    assert cbd._branch_drive({"eff": eff, "params": {}}) is None
    assert cbd._branch_drive({"params": {"driver": "v_h"}}) is None
    for driver, kept in (("v_h", True), ("model", False)):
        creep_st = {"effect": "creep", "channel": "displacement",
                    "parameters": {"gains": [0.5], "taus_s": [1.0], "driver": "v_h"}}
        delay_st = {"effect": "delay", "channel": "displacement", "_cand": {"replaces": ("creep", "displacement"),
                    "refit": {"taus_s": [1.0], "driver": driver}}, "_gains": np.array([1.0, 0.3])}
        cbd.refitted_joint_stage([creep_st, delay_st])
        assert ("driver" in creep_st["parameters"]) == kept and creep_st["parameters"]["gains"] == [0.3]


@pytest.mark.parametrize("proto, d_s", [("steps", 0.036), ("steps", 0.01), ("calibration", 0.036)])
def test_the_branches_are_driven_by_the_stack_motion_the_found_delay_reads(proto, d_s):
    """A base model fitted to a lagging record as if it were not late is a smeared motion: branches driven by it
    (``lowpass(ym) - ym``) delayed by ``d`` do not hold the creep of the stack's motion read late (seed 88 #97,
    100 kHz steps, creep + 36 ms delay: the joint fit put gain on the 4 ms and 40 s branches only and creep passed
    no fold). Driven by the drive model refitted at the found delay (:func:`~.creep_beside_delay._stack_motion`),
    the joint columns leave less of the record than driven by the base model, and under 1e-3 of what the base
    leaves (the construct: the stack's motion ``B w0`` plus branches of 0.1-1000 s, read ``d`` late, exact with
    the true motion driving the branches)."""
    rate = 1e5
    t, u = benchmark_protocol(proto, rate, 40000)
    B = np.column_stack([u, u * u / 100.0, np.ones_like(u)])
    x0 = B @ np.array([1e-7, 2e-8, 1e-6])
    plan = candidate_plan(("displacement",), t, u, basis=B)
    creep = next(e for ch, e, _ in plan if e.name == "creep")
    delay = next(e for ch, e, _ in plan if e.name == "delay")
    taus = np.asarray(creep.taus_s, float)
    g = np.where((taus >= 0.1) & (taus <= 1000.0), 0.02, 0.0)
    y = np.interp(t - d_s, t, x0 + creep._columns(x0, taus, 1.0 / rate) @ g)
    ym = B @ np.linalg.lstsq(B, y, rcond=None)[0]          # the base fitted as if the record were not late
    base = SimpleNamespace(channels={"displacement": SimpleNamespace(y=y, yhat=ym)})
    prob = SimpleNamespace(search=np.ones(t.size, bool))
    dl = {"eff": delay, "params": {"delay_samples": d_s * rate}}
    cr = {"channel": "displacement", "params": {"taus_s": taus.tolist()}}

    def left(drive):
        d, Kd, D = cbd._joint(cr, dl, prob, base, t, None, None, drive)
        X = np.column_stack([B, D, Kd])
        coef = np.linalg.lstsq(X, y - ym, rcond=1e-12)[0]
        return float(np.sqrt(np.mean((y - ym - X @ coef) ** 2)))

    on_base, on_refit = left(None), left(cbd._stack_motion(dl, prob, base, "displacement", None))
    assert on_refit < on_base, (proto, d_s, on_refit, on_base)
    assert on_refit < 1e-3 * np.sqrt(np.mean((y - ym) ** 2)), (proto, d_s, on_refit)


def test_delayed_creep_takes_the_branches_gains_only():
    """The joint candidate's gains come as branches then the delay's column: the creep's own are the first
    ``len(taus_s)``."""
    eff = cbd.DelayedCreep(taus_s=[0.1, 1.0])
    p = eff.with_gains({"gains": [0.0, 0.0], "taus_s": [0.1, 1.0]}, np.array([0.2, 0.3, 5.0]))
    assert p["gains"] == [0.2, 0.3]


# Records from the benchmark's simulator, drawn with np.random.default_rng(1415), fixed before any
# record was traced: rate from the benchmark's 1, 10 and 100 kHz (its row counts), protocol, size
# log-uniform over the full 0.03-30x, record seed. Creep + delay pairs first, then the guards
# (creep alone, delay alone, the same stream). Full run (WORKBENCH_FULL=1): more of each.
CD_PAIRS = 4 if not FULL else 12
CD_GUARDS = 2 if not FULL else 6


#: and, from np.random.default_rng(1416) (fixed with the rest, before any run), pairs at 100 kHz only, the
#: rate whose 0.4 s records main answered with the delay alone (a 5-13x creep under a ~200x delay,
#: session 13's fresh seeds): protocol, size over the full range, record seed
CD_PAIRS_100K = 3 if not FULL else 9

#: make test traces 4 of the 11 drawn above: the second pair (1 kHz steps 1.43x, the draw's one pair whose
#: effects both stand >= 3x on their own records, 43x and 49x), the first creep guard and the first delay guard
#: and the first 100 kHz pair (calibration, 0.22x); WORKBENCH_FULL=1 traces every draw of its larger set (12
#: pairs, 6 + 6 guards, 9 at 100 kHz). Session 16's make test traced all 11, session 22's 7 (0, 1, 4-8).
REDUCED = (1, 4, 5, 8)


def _record_draws():
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(1415)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    out = []
    for eff in [("creep", "delay")] * CD_PAIRS + ["creep", "delay"] * CD_GUARDS:
        rate = float(cc.RATES_HZ[int(rng.integers(len(cc.RATES_HZ)))])
        proto = str(rng.choice(("calibration", "sine", "steps")))
        out.append((eff, rate, proto, float(np.exp(rng.uniform(lo, hi))), int(rng.integers(1 << 30))))
    rng = np.random.default_rng(1416)
    for _ in range(CD_PAIRS_100K):
        proto = str(rng.choice(("calibration", "sine", "steps")))
        out.append((("creep", "delay"), 1e5, proto, float(np.exp(rng.uniform(lo, hi))), int(rng.integers(1 << 30))))
    return out


@pytest.fixture(scope="module")
def drawn(sn637):
    cc = load_benchmark("calibrate_confusion")
    rows = []
    draws = _record_draws()
    for eff, rate, proto, size, seed in (draws if FULL else [draws[k] for k in REDUCED]):
        r = cc.evaluate(sn637, eff, rate, proto, size, seed, diagnostics=False)
        print(f"\n{r['effect']:12s} {rate / 1e3:4.0f} kHz {proto:11s} size x{size:.3g} own sizes "
              f"{np.round(r['excesses'], 2)} -> stages {r['named']} {r['class']} both {r['both']} "
              f"ratio {r['ratio']:.3f} above the line {r['above_line']}")
        rows.append(r)
    return rows


def test_drawn_creep_and_delay_records_name_nothing_else(drawn):
    """No drawn record gets an effect it lacks (a creep record no delay, a delay record no creep, a
    pair nothing else) and none ends above a straight line (issue 13's floors)."""
    assert not [r for r in drawn if r["class"] == "wrong"], [(r["effect"], r["named"]) for r in drawn]
    assert not [r for r in drawn if r["above_line"]], [(r["effect"], r["above_line"]) for r in drawn]


def test_drawn_creep_and_delay_records_are_answered_with_both(drawn):
    """Issue 13 item 5: each drawn pair whose two effects both stand >= 3x above the floor (each on
    its own record) is answered with both, and the calibration's error after is at most half the
    error before on it."""
    big = [r for r in drawn if "+" in r["effect"] and min(r["excesses"]) >= 3.0]
    print(f"\nboth named: {sum(r['both'] for r in big)} of {len(big)} creep + delay records with both >= 3x")
    assert all(r["both"] and r["ratio"] <= 0.5 for r in big), \
        [(r["rate_hz"], r["protocol"], np.round(r["excesses"], 1), r["named"], round(r["ratio"], 3)) for r in big]


def test_a_split_both_surviving_names_the_majority_first(monkeypatch):
    """Two effects splitting five folds 4:1, each surviving the other (the joint creep + delay model
    lets a lopsided split survive both ways): the effect more folds chose is named first with its
    own 4 folds, even when the other has the better median (seen, 35 #9: the delay, 1 fold, was
    named first at "1 of 5"); a tie goes to the better median (test_effects' 3:2 case)."""
    from workbench.calibrate import stages, tracing
    a, b = ("creep", "displacement"), ("delay", "displacement")
    res = {"winners": [a, a, b, a, a], "by": {a: {"score": 0.4}, b: {"score": 0.3}}}
    monkeypatch.setattr(tracing, "_absorb", lambda *args, **kw: None)
    monkeypatch.setattr(stages, "_later_stage",
                        lambda ctx, ex, found, seen=(): (b if found[-1] == a else a, 5, [], {}, None))
    answer, count, note = stages.resolve_split(res, {"need": 4, "probs": {}, "base": None, "t": None}, {}, [])
    assert answer == a and count == 4 and "(4 and 1)" in note


@pytest.mark.parametrize("third", ["dielectric_absorption", "leakage"])
def test_a_split_takes_the_partner_it_can_be_scored_against_among_tied_counts(monkeypatch, third):
    """resolve_split: creep wins 3 folds on the displacement, a delay there 1 and a charge relaxation
    (creep's own charge) 1. The pair is creep and the delay, the tied partner on creep's channel, not the
    charge's relaxation, which no pair test scores against the displacement (seen, 73 #42: inconclusive
    3 of 5 with the pair taken with the charge); both surviving, creep is named first with its 3 folds."""
    from workbench.calibrate import stages, tracing
    a, b, c = ("creep", "displacement"), ("delay", "displacement"), (third, "charge")
    res = {"winners": [c, a, b, a, a], "by": {a: {"score": 0.5}, b: {"score": 0.4}, c: {"score": 0.3}}}
    monkeypatch.setattr(tracing, "_absorb", lambda *args, **kw: None)
    pairs = []

    def later(ctx, ex, found, seen=()):
        pairs.append((found[-1], seen[0]))
        return seen[0], 5, [], {}, None

    monkeypatch.setattr(stages, "_later_stage", later)
    answer, count, note = stages.resolve_split(res, {"need": 4, "probs": {}, "base": None, "t": None}, {}, [])
    assert sorted(pairs) == sorted([(a, b), (b, a)])
    assert answer == a and count == 3 and "(3 and 1)" in note


#: The creep + delay records of session 18's fresh seeds told apart (both >= 3x beyond the other on the test
#: rows) and missed there, as the benchmark numbers them (seed, index, its end rates drawn): 72 #31 (1 kHz
#: steps: the joint delay refused by a second creep's 12 branches leaving 0.5 % less unpenalized on one fold),
#: 73 #42 (10 kHz calibration: creep 3 folds, the delay and the creep's charge 1 each, the split paired with
#: the charge), 73 #152 (1 MHz sine: every fold the charge's absorption, decided or undecided against creep,
#: the delay passing every fold). Records of the benchmark, so only in the full form (10-30 s each).
MISSED_PAIRS = ((72, 31, False), (73, 42, False), (73, 152, True))


@pytest.mark.skipif(not FULL, reason="full form: WORKBENCH_FULL=1 (make test-full) traces these records")
@pytest.mark.parametrize("seed, index, ends", MISSED_PAIRS)
def test_session_18s_missed_creep_and_delay_pairs_are_answered_with_both(sn637, seed, index, ends):
    """Each of the three records is answered with creep and the delay, nothing else, and the calibration
    leaves at most half the error before (issue 13 item 5's target on a pair the record tells apart)."""
    cc = load_benchmark("calibrate_confusion")
    eff, rate, proto, size, s = cc.cases(1, seed, ends=ends)[index - 1]
    assert eff == ("creep", "delay")
    r = cc.evaluate(sn637, eff, rate, proto, size, s, diagnostics=False)
    assert r["class"] == "right" and r["both"] and r["ratio"] <= 0.5, (r["named"], r["agreement"], r["ratio"])


@pytest.mark.skipif(not FULL, reason="full form: WORKBENCH_FULL=1 (make test-full) traces this record")
def test_creep_behind_a_36_ms_delay_at_100_khz_steps_is_answered_with_both(sn637):
    """Check seed 88 #97 (100 kHz steps, creep 9.8x and a 36 ms delay 198x on their own records): with the branches
    driven by the base model fitted to the lagging record as if not late it was answered with the delay alone
    (session 22); driven by the drive model refitted at the found delay, with both, at most half the error before."""
    cc = load_benchmark("calibrate_confusion")
    eff, rate, proto, size, s = cc.cases(1, 88)[97 - 1]
    assert eff == ("creep", "delay") and rate == 1e5 and proto == "steps"
    r = cc.evaluate(sn637, eff, rate, proto, size, s, diagnostics=False)
    assert r["class"] == "right" and r["both"] and r["ratio"] <= 0.5, (r["named"], r["agreement"], r["ratio"])


#: creep + a sensor delay at 100 kHz on the calibration protocol, drawn with default_rng(2081) before any
#: run over the benchmark's large band (3-30x): the records where the joint delay beside creep is named
#: second and the gauge's line was rebuilt against the displacement less the whole joint term (seeds 75 #75
#: and 81 #75: a spurious gauge bow as a third stage). Full form only (~20 s a record).
_R2081 = np.random.default_rng(2081)
BOW_DRAWS = [(float(np.exp(_R2081.uniform(np.log(3.0), np.log(30.0)))), int(_R2081.integers(1 << 30)))
             for _ in range(6)]


@pytest.mark.parametrize("size, seed", reduced_draws(BOW_DRAWS, keep=()))
def test_creep_and_delay_at_100_khz_calibration_gain_no_gauge_bow(sn637, size, seed):
    """Drawn creep + delay records (100 kHz calibration protocol, 3-30x): no stage names an effect the
    record lacks (the gauge bow fitted to the gauge's creep, left in its line by the whole joint term)."""
    cc = load_benchmark("calibrate_confusion")
    r = cc.evaluate(sn637, ("creep", "delay"), 1e5, "calibration", size, seed, diagnostics=False)
    assert set(r["named"]) <= {"creep", "delay"}, (size, seed, r["named"], r["class"])


#: creep + a sensor delay at 10 kHz on the calibration protocol, the large band (10-30x) of session 20's 82 #42
#: (a 48x creep beside a 24.7 ms delay answered with the delay alone), drawn with default_rng(2121) before any
#: run: size, record seed. Then delay-only records in the same band, from default_rng(2122): the rule asks a
#: second reading of creep after a found delay, so a delay record must gain no creep. Full form only (~10-35 s
#: a record; the pairs' draw 1, a 238-sample delay, is the one main answers with the delay alone).
_R2121 = np.random.default_rng(2121)
LARGE_PAIR_DRAWS = [(float(np.exp(_R2121.uniform(np.log(10.0), np.log(30.0)))), int(_R2121.integers(1 << 30)))
                    for _ in range(8)]
_R2122 = np.random.default_rng(2122)
LARGE_DELAY_DRAWS = [(float(np.exp(_R2122.uniform(np.log(10.0), np.log(30.0)))), int(_R2122.integers(1 << 30)))
                     for _ in range(4)]


def _named_at_10_khz_calibration(plant, effects, size, seed):
    from workbench.calibrate.tracing import trace_effect
    cc = load_benchmark("calibrate_confusion")
    _, sp, base, _, truth, _ = cc.simulated_base(plant, effects, 1e4, "calibration", size, seed)
    res = trace_effect(base, split=sp)
    return [s["effect"] for s in res.get("stages", [])], [s["agreement"] for s in res.get("stages", [])], truth


@pytest.mark.parametrize("size, seed", reduced_draws(LARGE_PAIR_DRAWS, keep=()))
def test_large_creep_and_delay_at_10_khz_calibration_are_answered_with_both(sn637, size, seed):
    """Each drawn pair is answered with creep and the delay, nothing else. The later stage keeps one reading of
    creep per tag (the plain or the joint beside the delay, :func:`~workbench.calibrate.tracing._score_stage`);
    when the kept one loses to a second delay searched on the leftover and the gauge, which no sensor delay
    reaches, shows the creep on every fold, the other reading is asked under the same rivals' rule
    (:func:`~workbench.calibrate.stages._other_reading`; main answered draw 1 with the delay alone)."""
    named, agreement, truth = _named_at_10_khz_calibration(sn637, ("creep", "delay"), size, seed)
    assert sorted(named) == ["creep", "delay"], (size, seed, truth.get("delay_s"), named, agreement)


@pytest.mark.parametrize("size, seed", reduced_draws(LARGE_DELAY_DRAWS, keep=()))
def test_large_delay_at_10_khz_calibration_gains_no_creep(sn637, size, seed):
    """A drawn delay-only record of the same band is answered with the delay alone (no second reading of creep
    is taken behind it: the gauge shows no creep)."""
    named, agreement, truth = _named_at_10_khz_calibration(sn637, "delay", size, seed)
    assert named == ["delay"], (size, seed, truth.get("delay_s"), named, agreement)
