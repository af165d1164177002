"""Wrong and inconclusive answers on large two-effect and later-stage records (branch s12_later).

Causes (README, Calibration, *Later stages on large records*):

* the gauge's bow is fitted against the *recorded* displacement, which carries a displacement
  sensor's delay or drift the stack (and so the gauge) never had: after such a stage the
  gauge's line problem is rebuilt against the displacement advanced by the found delay, the found
  drift's shape free on the gauge (session 26; the found term taken out, session 20, carried the
  displacement model's misfit into the line);
* after a displacement effect, a charge relaxation whose displacement (eq. 10) could hide in what
  the found effects leave on the displacement is undecided against creep, not named absorption;
* the stack's creep or mode winning folds on both the gauge and the displacement is one effect;
  creep decided on some folds, the rest undecided between creep and a charge relaxation, is creep;
* a gauge row beside a DAC-pinned one is not valid (its interval crossed the rail).

Drawn records: sizes log-uniform over the benchmark's large band (3-30x the drawn ranges),
``default_rng`` fixed before any run. Regression records of the confusion benchmark's seeds 28 and
30 (development seeds of this change: not held-out evidence) are marked as such.
"""

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate import stages as st
from workbench.calibrate import tracing as tr
from workbench.calibrate.base_fit import _gauge_valid
from workbench.calibrate.tracing import trace_effect

RNG = np.random.default_rng(1312)


def _size():
    return float(np.exp(RNG.uniform(np.log(3.0), np.log(30.0))))


CREEP_DELAY_DRAWS = [(proto, _size(), int(RNG.integers(1 << 30))) for proto in ("steps", "sine")]
DRIFT_DRAWS = [(proto, _size(), int(RNG.integers(1 << 30))) for proto in ("calibration",)]
DRIFT_MODE_DRAWS = [(proto, _size(), int(RNG.integers(1 << 30))) for proto in ("calibration",)]


def _trace(plant0, effect, rate, proto, size, seed):
    t, sp, base, _, truth, _ = load_benchmark("calibrate_confusion").simulated_base(plant0, effect, rate, proto,
                                                                                    size, seed)
    return base, trace_effect(base, split=sp), truth


@pytest.mark.parametrize("proto, size, seed", reduced_draws(CREEP_DELAY_DRAWS, keep={0}))
def test_a_large_creep_behind_a_delay_at_100_khz_is_never_named_absorption(sn637, proto, size, seed):
    """Creep + a sensor delay, 3-30x the drawn ranges, on 0.4 s records at 100 kHz: every stage
    is creep or delay (main named the creep's charge dielectric_absorption after the delay:
    seeds 28 #86, 30 #97), and one of them is named."""
    _, res, truth = _trace(sn637, ("creep", "delay"), 1e5, proto, size, seed)
    named = [s["effect"] for s in res["stages"]]
    assert set(named) <= {"creep", "delay"}, (named, res.get("fold_winners"), truth)
    assert named, (res["effect"], res.get("fold_winners"))


@pytest.mark.parametrize("proto, size, seed", DRIFT_DRAWS)
def test_a_large_drift_is_never_followed_by_a_gauge_bow(sn637, proto, size, seed):
    """A displacement-sensor drift, 3-30x the drawn range, at 100 kHz: named drift, and no stage is a
    gauge bow (the gauge reads the stack, not the drifting sensor; main: seed 30 #73, 721x, drift
    then gauge_nonlinearity)."""
    _, res, truth = _trace(sn637, "drift", 1e5, proto, size, seed)
    named = [s["effect"] for s in res["stages"]]
    assert named and named[0] == "drift", (named, res.get("fold_winners"))
    assert "gauge_nonlinearity" not in named, (named, truth)


@pytest.mark.parametrize("proto, size, seed", DRIFT_MODE_DRAWS)
def test_a_large_drift_and_mode_are_named_not_inconclusive(sn637, proto, size, seed):
    """Drift + a mode, 3-30x the drawn ranges, 100 kHz calibration protocol: the drift hides the
    displacement's mode on some folds, where the gauge's mode wins (main: inconclusive 3 of 5, seeds
    29 #77, 32 #77). Named, and only these two effects."""
    _, res, truth = _trace(sn637, ("drift", "resonance"), 1e5, proto, size, seed)
    named = [s["effect"] for s in res["stages"]]
    assert sorted(named) == ["drift", "resonance"], (res["effect"], named, res.get("fold_winners"))


# drift + a mode at 100 kHz on both protocols that show it, sizes log-uniform over 3-9x (a 3x span:
# the drift hides the displacement's mode at the first stage at the band's small end, where the
# double naming was seen, 3.3-3.9x; above ~10x the displacement's own mode wins); own stream, fixed
# before any run (the draws above are unchanged)
_RNG_ONE = np.random.default_rng(1314)
ONE_MODE_DRAWS = [(proto, float(np.exp(_RNG_ONE.uniform(np.log(3.0), np.log(9.0)))), int(_RNG_ONE.integers(1 << 30)))
                  for proto in ("sine", "calibration", "sine", "calibration")]


@pytest.mark.parametrize("proto, size, seed", reduced_draws(ONE_MODE_DRAWS, keep={0, 1}))
def test_the_stacks_mode_is_named_once(sn637, proto, size, seed):
    """The gauge and the displacement read one motion: the stack's mode (or creep) is one effect and
    no effect is named twice (main: resonance on the gauge, drift, resonance on the displacement,
    seeds 28 #88, 29 #77, 32 #77)."""
    _, res, truth = _trace(sn637, ("drift", "resonance"), 1e5, proto, size, seed)
    named = [s["effect"] for s in res["stages"]]
    assert len(named) == len(set(named)), ([(s["effect"], s["channel"]) for s in res["stages"]], truth)


R1_MISS_UNTIL_S22 = ("review of s14_creepdelay, 2026-11-26: a joint creep + delay reading names a new effect and keeps the "
           "every-fold rule (it was exempt: a delay beside creep passed 4 of 5 folds on creep-only draws); here the "
           "joint creep passes 4 of 5: delay alone, as in session 13. Session 15 (s15_gram): with B2 fixed alone "
           "it answers delay, creep 5 of 5 (main's fold-2 ratio 3.75 was the SSE's cancellation); with R2 (the "
           "found delay on equal terms, fold by fold) the joint creep explains 0.15-0.72 of the delay's leftover "
           "and fold 5's 0.15 is under the 0.3 share: delay alone again")


# 30 #97 was a strict xfail (R1_MISS) until session 22's s22_drive97: the joint creep's branches on the drive model
# refitted at the found delay (creep_beside_delay._stack_motion) answer delay, creep (the fresh clone's make test).
# make test runs 30 #97 (session 31, s31_suite); 30 #73 (a drift, 100 kHz calibration, the answer named) runs under
# WORKBENCH_FULL=1: make test's record of its family and kind is test_a_large_drift_is_never_followed_by_a_gauge_bow
# (a 12.6x drift at 100 kHz on the calibration protocol: drift named first, no gauge bow, the miss 30 #73 was)
@pytest.mark.parametrize("seed, index, want", reduced_draws([(30, 73, ["drift"]), (30, 97, ["delay", "creep"])],
                                                            keep={1}))
def test_regression_later_stages_on_large_records(sn637, seed, index, want):
    """Regression records (tuned on): a 721x drift (100 kHz calibration) named drift only (main:
    drift, gauge_nonlinearity); creep (10.8x) + a 39 ms delay (186x) (100 kHz steps) named delay
    then creep (session 12: delay, dielectric_absorption; session 13: delay alone; session 14: the
    joint creep + delay model names the creep, :mod:`workbench.calibrate.creep_beside_delay`)."""
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, s = cc.cases(seed=seed)[index - 1]
    _, res, _ = _trace(sn637, e, rate, proto, size, s)
    assert [x["effect"] for x in res["stages"]] == want


def test_a_split_is_not_resolved_to_the_effect_fewer_folds_chose(sn637):
    """Seed 35 #9 (creep 96x + a 30 ms delay 109x, 1 kHz calibration protocol; a fresh seed of the
    session-12 measurement, where it was found): creep won 4 folds (one undecided against a charge
    relaxation), the delay 1; the delay explained what creep left, creep not what the delay left,
    and the delay was named alone at '1 of 5', its test error 1.69x the base's, above a straight
    line's. Item 4: an effect is named only when it wins consistently: the split is the record's
    doubt. The named stages, if any, never make the channel's test error worse than before."""
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, s = cc.cases(seed=35)[9 - 1]
    _, res, _ = _trace(sn637, e, rate, proto, size, s)
    for stage in res["stages"]:
        assert int(stage["agreement"].split()[0]) >= 3 or "resolved" not in stage, stage
    assert res["error_after"]["rms"] <= res["error_before"]["rms"]


@pytest.mark.parametrize("n, start, width", [(50, 10, 5), (200, 0, 7), (200, 193, 7), (31, 14, 1)])
def test_a_gauge_row_beside_a_pinned_one_is_not_valid(n, start, width):
    """Pinned rows (at the DAC rail, either sign) and their two neighbours are invalid; every other row valid."""
    g = np.linspace(-1.0, 1.0, n) * 0.5
    g[start:start + width] = 2.6 * (-1) ** start
    ok = _gauge_valid(g, 2.6)
    bad = np.zeros(n, bool)
    bad[max(start - 1, 0):min(start + width + 1, n)] = True
    assert np.array_equal(ok, ~bad)


@pytest.mark.parametrize("n, bow", [(400, -0.3), (1000, 0.05), (257, 0.6)])
def test_without_a_dac_range_only_the_peak_rows_are_left_out(n, bow):
    """No DAC range declared: the 'rail' is the record's own peak, where a bow is largest; its
    neighbours are readings and stay valid (s12_later dropped them too). With the range declared,
    the same reading pinned at it loses its neighbours as well."""
    x = np.sin(np.linspace(0.0, 4 * np.pi, n, endpoint=False) + 0.3)
    g = 2.0 * x / (1.0 + bow * x)
    ok = _gauge_valid(g, None)
    peak = np.abs(g) >= 0.998 * np.abs(g).max()
    assert peak.any() and np.array_equal(ok, ~peak)
    from workbench.calibrate.base_fit import _gauge_pinned
    pinned, beside = _gauge_pinned(g, None)
    assert np.array_equal(pinned, peak) and not beside.any()
    lim = float(np.abs(g).max())
    pinned, beside = _gauge_pinned(np.clip(g, -lim, lim), lim)
    assert beside.any() and not (pinned & beside).any()
    assert np.array_equal(_gauge_valid(g, lim), ~(pinned | beside))


def _res(winners, scores):
    by = {k: {"score": v, "passes": [True] * len(winners)} for k, v in scores.items()}
    return {"winners": winners, "by": by}


@pytest.mark.parametrize("name", ["resonance", "creep"])
def test_the_stacks_effect_on_both_sensors_is_one_effect(name):
    """3 folds on the gauge and 2 on the displacement: named (need 4) on the lower median ratio."""
    g, x = (name, "gauge"), (name, "displacement")
    res = _res([g, x, g, g, x], {g: 0.43, x: 0.90})
    # named on the displacement when its row passes need folds (the plant file's form), whatever
    # the medians; agreement is the named view's own wins, the compatible folds both views'
    ans, count, note, both = st.stack_effect_on_both_sensors(res, 4)
    assert (ans, count, both) == (x, 2, 5) and note
    res["by"][x]["passes"] = [True, True, False, True, True]
    assert st.stack_effect_on_both_sensors(res, 4)[:2] == (x, 2)
    # the displacement's row passes fewer than need folds: the gauge's, with its own 3 wins
    res["by"][x]["passes"] = [False, True, False, False, True]
    assert st.stack_effect_on_both_sensors(res, 4)[:2] == (g, 3)
    # together under need, or a different effect on the other sensor: not this rule
    assert st.stack_effect_on_both_sensors(_res([g, x, g, "none", "none"], {g: 0.4, x: 0.9}), 4)[0] is None
    assert st.stack_effect_on_both_sensors(_res([g, g, g, ("drift", "displacement")] * 1 + [g],
                                                {g: 0.4, ("drift", "displacement"): 0.5}), 4)[0] is None


def test_creep_decided_with_the_rest_undecided_between_creep_and_a_charge_relaxation():
    c = ("creep", "displacement")
    u = ("undecided", "dielectric_absorption or creep")
    assert st.creep_decided_rest_undecided(_res([c, u, u, c, c], {c: 0.5}), 4) == (c, 3, 2)
    assert st.creep_decided_rest_undecided(_res([u, c, u, c, u], {c: 0.5}), 4) == (c, 2, 3)
    # one decided fold is chance; a fold won by anything else is a dissent; an undecided without creep
    assert st.creep_decided_rest_undecided(_res([u, c, u, u, u], {c: 0.5}), 4)[0] is None
    assert st.creep_decided_rest_undecided(_res([c, c, c, ("delay", "displacement"), u], {c: 0.5}), 4)[0] is None
    assert st.creep_decided_rest_undecided(
        _res([c, c, c, ("undecided", "creep or a displacement-sensor effect"), ("undecided", "leakage or x")],
             {c: 0.5}), 4)[0] is None
    # the creep's row must pass need folds
    res = _res([c, u, u, c, c], {c: 0.5})
    res["by"][c]["passes"] = [True, False, False, True, True]
    assert st.creep_decided_rest_undecided(res, 4)[0] is None
    # a row passing need but not every fold: a majority of the folds decided (3 of 5), not 2
    res = _res([u, c, u, c, u], {c: 0.5})
    res["by"][c]["passes"] = [True, True, False, True, True]
    assert st.creep_decided_rest_undecided(res, 4)[0] is None
    res = _res([u, c, c, c, u], {c: 0.5})
    res["by"][c]["passes"] = [False, True, True, True, True]
    assert st.creep_decided_rest_undecided(res, 4) == (c, 3, 2)


# creep-free records with a charge relaxation and a displacement effect, sizes log-uniform 5-30x,
# 100 kHz (where the rule's records were), both protocols; own stream fixed before any run
_RNG_NC = np.random.default_rng(1316)
NO_CREEP_DRAWS = [(effect, proto, float(np.exp(_RNG_NC.uniform(np.log(5.0), np.log(30.0)))),
                   int(_RNG_NC.integers(1 << 30)))
                  for effect in (("dielectric_absorption", "delay"), ("drift", "dielectric_absorption"))
                  for proto in ("steps", "sine")]


@pytest.mark.parametrize("effect, proto, size, seed", reduced_draws(NO_CREEP_DRAWS, keep={0, 3}))
def test_a_charge_relaxation_beside_a_displacement_effect_is_never_named_creep(sn637, effect, proto, size, seed):
    """No creep in the plant: creep is never named (by creep_decided_rest_undecided or any rule)."""
    _, res, truth = _trace(sn637, effect, 1e5, proto, size, seed)
    named = [(s["effect"], s["channel"], s.get("resolved")) for s in res["stages"]]
    assert "creep" not in [s["effect"] for s in res["stages"]], (named, res.get("fold_winners"), truth)


@pytest.mark.parametrize("name", ["resonance", "creep"])
def test_the_stacks_effect_found_on_one_sensor_is_not_a_candidate_on_the_other(name):
    """Symmetric: after the displacement's creep or mode, not the gauge's, and the reverse."""
    g, x = (name, "gauge"), (name, "displacement")
    assert st.excluded(g, [x]) and st.excluded(x, [g])
    assert not st.excluded(x, [("drift", "displacement")]) and not st.excluded(g, [("delay", "displacement")])


@pytest.mark.parametrize("floor, before", [(1e-9, 20e-9), (1e-9, 2e-9), (3e-9, 5e-9)])
def test_what_the_stack_could_hide_after_a_displacement_effect(floor, before):
    """First stage: 3x the floor. After a displacement effect: also what it leaves above the floor."""
    infos = {"displacement": {"noise_floor": floor}}
    befores = {("displacement", "model"): [before]}
    assert tr._stack_could_hide(0, befores, infos, []) == pytest.approx(3 * floor)
    assert tr._stack_could_hide(0, befores, infos, [("resonance", "gauge")]) == pytest.approx(3 * floor)
    want = max(3 * floor, np.sqrt(before ** 2 - floor ** 2))
    assert tr._stack_could_hide(0, befores, infos, [("delay", "displacement")]) == pytest.approx(want)


def test_the_gauge_line_rebuilt_after_a_sensor_effect_reads_the_displacement_less_the_term(sn637):
    """After a displacement drift or delay the gauge's line problem targets
    gauge - (offset + gain (x - term)) (eq. 27's line on the stack's motion, the sensor's term taken
    out; of its interval mean for the averaged gauge the benchmark declares), its unknowns are corrections to that line (columns 1 and x - term), and its null
    reference is rebuilt (same count) from trace_effect's seed."""
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(1315)
    size, seed = float(np.exp(rng.uniform(np.log(3.0), np.log(30.0)))), int(rng.integers(1 << 30))
    t, sp, base, _, _, _ = cc.simulated_base(sn637, "drift", 1e3, "sine", size, seed, n_rows=4000)
    m, x0 = base.channels["gauge"], base.channels["displacement"].y
    line0, _ = tr._gauge_line(base)
    key = ("gauge", "line")
    old = tr._Problem(sp, m.valid, np.column_stack([np.ones(t.size), x0]), [-np.inf, -np.inf], m.y - line0,
                      tr._search_rows(sp.train & m.valid))
    # any term of the displacement's size: a slow ramp with a bend, drawn
    term = rng.uniform(0.05, 0.5) * np.ptp(x0) * ((t - t[0]) / np.ptp(t)) ** rng.uniform(1.0, 3.0)
    ctx = {"probs": {key: old}, "base": base, "t": t, "cands": [], "seed": 0,
           "nulls": {key: [None, None, None]}}
    st._gauge_reads_corrected(ctx, term, {key: []})
    prob = ctx["probs"][key]
    # the benchmark's gauge is declared averaged: the line reads the interval mean of x - term
    from workbench.calibrate.base_fit import interval_mean
    assert base.gauge_kind == "averaged"
    want = m.y - (base.gauge_offset_v + base.gauge_gain_v_per_m * interval_mean(x0 - term))
    np.testing.assert_allclose(prob.r * prob.scale, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    assert not np.allclose(prob.r * prob.scale, old.r * old.scale)
    assert len(ctx["nulls"][key]) == 3


# ---- the gauge's line after a displacement delay or drift reads the record, not the displacement's model
# (stages._gauge_line_for_sensor). Sizes log-uniform over the benchmark's full range, drawn once.
_LINE_RNG = np.random.default_rng(2026)
LINE_DRAWS = [(float(np.exp(_LINE_RNG.uniform(np.log(0.03), np.log(30.0)))), int(_LINE_RNG.integers(1 << 30)))
              for _ in range(4)]
_LINE = ("gauge", "line")


def _line_ctx(t, sp, base):
    m, x0 = base.channels["gauge"], base.channels["displacement"].y
    line0, _ = tr._gauge_line(base)
    old = tr._Problem(sp, m.valid, np.column_stack([np.ones(t.size), x0]), [-np.inf, -np.inf], m.y - line0,
                      tr._search_rows(sp.train & m.valid))
    return {"probs": {_LINE: old}, "base": base, "t": t, "cands": [], "seed": 0,
            "nulls": {_LINE: [None, None, None]}}


def _line_against(ctx, sp, base, x_stack):
    """The rebuilt line problem's held-out RMS (V), and the gauge's line on the simulated stack motion on the
    same rows (offset and gain fitted on the development rows): what the gauge leaves with no sensor effect."""
    prob = ctx["probs"][_LINE]
    got = tr._test_errors(prob, prob.base, sp.dev_blocks, sp.test_blocks)["rms"]
    m = base.channels["gauge"]
    line, xs = tr._gauge_line(base, x_stack)
    L = np.column_stack([np.ones(xs.size), xs])
    dev, test = sp.train & prob.valid, sp.test & prob.valid
    w = np.linalg.lstsq(L[dev], (m.y - line)[dev], rcond=None)[0]
    return got, float(np.sqrt(np.mean((m.y - line - L @ w)[test] ** 2)))


@pytest.mark.parametrize("size, seed", reduced_draws(LINE_DRAWS, keep={3}))
def test_the_gauge_line_after_a_sensor_delay_reads_the_stack_whatever_creep_the_model_lacks(sn637, size, seed):
    """A creep + delay record: the delay found on the displacement with the drive model's term ``M(t - d) - M(t)``,
    ``M`` the base's model (no creep: a delay found first, creep after). The gauge reads the stack, the
    displacement sensor the stack late by ``d``: the line, rebuilt, must leave what the gauge leaves against the
    stack's own motion (its noise: the displacement's noise through the gain adds < 0.5 % to it), whatever the
    model lacked. With the model's term taken out (the session-20 rebuild) the creep's ``K(t) - K(t - d)`` stays
    on the line: 1.5x and 2.3x the stack's line on this test's draws 2 and 4 (10 kHz, 4000 rows)."""
    from workbench.plant.additions import delayed
    cc = load_benchmark("calibrate_confusion")
    t, sp, base, _, truth, r = cc.simulated_base(sn637, ("creep", "delay"), 1e4, "calibration", size, seed, n_rows=4000)
    yhat = base.channels["displacement"].yhat
    d = truth["delay_s"]
    stage = {"effect": "delay", "channel": "displacement", "parameters": {"delay_s": d},
             "_term": delayed(t, yhat, d) - yhat, "_cand": {}}
    ctx = _line_ctx(t, sp, base)
    st._gauge_line_for_sensor(ctx, [stage], {_LINE: []})
    got, stack = _line_against(ctx, sp, base, r["x_true_m"])
    assert got <= 1.03 * stack
    # the rows whose t + d the record does not hold are out of the line (the last d of it), no others
    n_out = int(np.sum(base.channels["gauge"].valid & ~ctx["probs"][_LINE].valid))
    assert n_out <= int(np.ceil(d * 1e4)) + 1


@pytest.mark.parametrize("size, seed", reduced_draws(LINE_DRAWS, keep={3}))
def test_the_gauge_line_after_a_sensor_drift_reads_the_stack_whatever_the_plays_took(sn637, size, seed):
    """A drift + mode steps record: the drift found on the displacement in a joint fit whose play weights are
    refitted beside it, so its term is the sensor's drift plus any share of the plays (over a staircase the slow
    trend is the plays' and time's alike: 103 #165 at 1 MHz, a term 6.6e-7 m off a 4.8e-7 m drift); here a play
    column of the displacement's basis, 20-100 % of the drift's RMS, drawn. The line, rebuilt with the drift's
    shape free on the gauge, must leave what the gauge leaves against the stack's motion (two free columns of
    4000 rows: < 0.5 %); with the term taken out (the session-20 rebuild) it kept the plays' share: 9.2x the stack's
    line on this test's draw 4 (10 kHz, 4000 rows)."""
    from workbench.calibrate.effects import Drift
    cc = load_benchmark("calibrate_confusion")
    t, sp, base, _, _, r = cc.simulated_base(sn637, ("drift", "resonance"), 1e4, "steps", size, seed, n_rows=4000)
    rng = np.random.default_rng(seed)
    sensor = r["displacement_m"] - r["x_true_m"]
    play = base.channel_basis("displacement")[:, 1]
    play = play - play.mean()
    share = rng.uniform(0.2, 1.0) * rng.choice([-1.0, 1.0]) * np.std(sensor) / np.std(play)
    stage = {"effect": "drift", "channel": "displacement", "_term": sensor + share * play, "_cand": {"eff": Drift()},
             "parameters": {"coefficients": [0.0, 1.0, 1.0], "t0_s": float(t[0]), "t_end_s": float(t[-1])}}
    ctx = _line_ctx(t, sp, base)
    st._gauge_line_for_sensor(ctx, [stage], {_LINE: []})
    got, stack = _line_against(ctx, sp, base, r["x_true_m"])
    assert got <= 1.03 * stack


def test_a_real_gauge_bow_beside_a_displacement_drift_on_steps_is_named(sn637):
    """The review's record (a regression record, not held-out evidence): a 3x gauge bow and drift at 100 kHz steps,
    plant seed 43 (bow -14,900 /m). Both effects are the record's; the bow must be named beside the drift. Session
    26's line (the drift's columns free on the gauge) named the drift alone; the drift's gains fitted beside the
    bow's column, the drift taken out of the record as the gauge reads it (stages._drift_on_gauge): the bow named,
    -15,570 /m."""
    cc = load_benchmark("calibrate_confusion")
    _, sp, base, _, truth, _ = cc.simulated_base(sn637, ("gauge_nonlinearity", "drift"), 1e5, "steps", 3.0, 43)
    res = trace_effect(base, split=sp)
    named = [s["effect"] for s in res["stages"]]
    assert "gauge_nonlinearity" in named, (truth, named)


@pytest.mark.parametrize("size, seed", reduced_draws(LINE_DRAWS, keep={3}))
def test_the_gauge_line_after_a_sensor_drift_keeps_a_real_bow_on_steps(sn637, size, seed):
    """A drift + gauge bow steps record, the bow's size drawn over the benchmark's range (the drift's the same
    draw): the drift found on the displacement, the gauge's line rebuilt (stages._gauge_line_for_sensor). The
    gauge reads the stack, so the line must leave what the gauge leaves against the stack's own motion, the bow
    in it (no more: the drift is out; no less: the drift's shape takes none of the bow), and the bow's column
    must then leave what it leaves on the stack's line. With the drift's powers of time free on the line (session
    26) they took the part of the bow a staircase in time shares with them: on this test's draw 4 (10 kHz, 4000
    rows, a 7.1x bow and drift) the line left 0.70x the stack's, the bow's ratio 0.67 where the stack's is 0.45
    (now 1.01x, 0.44)."""
    from workbench.calibrate.effects import Drift, GaugeNonlinearity
    cc = load_benchmark("calibrate_confusion")
    t, sp, base, _, truth, r = cc.simulated_base(sn637, ("gauge_nonlinearity", "drift"), 1e4, "steps", size, seed,
                                                 n_rows=4000)
    sensor = r["displacement_m"] - r["x_true_m"]
    stage = {"effect": "drift", "channel": "displacement", "_term": sensor, "_cand": {"eff": Drift()},
             "parameters": {"coefficients": [0.0, 1.0, 1.0], "t0_s": float(t[0]), "t_end_s": float(t[-1])}}
    ctx = _line_ctx(t, sp, base)
    ctx["cands"] = [{"key": _LINE, "eff": GaugeNonlinearity()}]
    st._gauge_line_for_sensor(ctx, [stage], {_LINE: []})
    prob, (bow,) = ctx["probs"][_LINE], ctx["cands"]
    # the line's held-out RMS, and with the bow's columns as the tracing searches them on the rebuilt line
    got = tr._test_errors(prob, prob.base, sp.dev_blocks, sp.test_blocks)["rms"]
    got_bow = tr._test_errors(prob, bow["g"], sp.dev_blocks, sp.test_blocks)["rms"]
    m = base.channels["gauge"]
    line, xs = tr._gauge_line(base, r["x_true_m"])
    dev, test = sp.train & prob.valid, sp.test & prob.valid
    for cols in ([], [(xs - xs[dev].mean()) ** 2]):
        L = np.column_stack([np.ones(xs.size), xs] + cols)
        w = np.linalg.lstsq(L[dev], (m.y - line)[dev], rcond=None)[0]
        rms = float(np.sqrt(np.mean((m.y - line - L @ w)[test] ** 2)))
        if not cols:
            stack = rms
        else:
            stack_bow = rms
    assert 0.97 * stack <= got <= 1.03 * stack, (size, got, stack)
    assert got_bow / got <= stack_bow / stack + 0.03, (size, got_bow / got, stack_bow / stack)


def test_the_gauge_line_after_a_drift_on_a_one_megahertz_staircase_is_no_worse_than_the_stacks(sn637):
    """The review of s27_driftbow's records (regression records, not draws): a drift-only 1 MHz steps record (0.1 s:
    the stack's staircase and the drift's powers of time nearly collinear). The drift taken out as the gauge reads it
    (stages._drift_on_gauge) took a second correction larger than the first and kept one worse than none (seed 29:
    3.2e-7 m off a 2.7e-7 m drift; the rebuilt line left 3.46x the stack's). The correction is now kept only where it
    lowers the gauge's misfit on the stack (else the drift's columns free, session 26's line): the rebuilt line leaves
    what the gauge leaves against the stack's motion (< 0.5 % more)."""
    from workbench.calibrate.effects import Drift
    cc = load_benchmark("calibrate_confusion")
    t, sp, base, _, _, r = cc.simulated_base(sn637, ("drift",), 1e6, "steps", 8.0, 29)
    sensor = r["displacement_m"] - r["x_true_m"]
    stage = {"effect": "drift", "channel": "displacement", "_term": sensor, "_cand": {"eff": Drift()},
             "parameters": {"coefficients": [0.0, 1.0, 1.0], "t0_s": float(t[0]), "t_end_s": float(t[-1])}}
    ctx = _line_ctx(t, sp, base)
    st._gauge_line_for_sensor(ctx, [stage], {_LINE: []})
    got, stack = _line_against(ctx, sp, base, r["x_true_m"])
    assert got <= 1.005 * stack, (got, stack)
