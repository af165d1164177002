"""The fast slice of the confusion benchmark (benchmarks/calibrate_confusion.py, issue 13 item 7).

The effect-free record and one record of every effect, each effect's size drawn log-uniform
from 0.03x to 30x its nominal range (from well below the noise floor to large), 2 s at 10 kHz
on the calibration protocol scaled to the record. Asserted: the wrong-effect rate (an effect
named that the record does not have, at any stage) is within the issue's 2 %; with 8 records
that is none. A ``none`` or ``inconclusive`` is not wrong. WORKBENCH_FULL=1 adds a second draw.
"""


import numpy as np
import pytest

from tests.conftest import FULL, leak_and_absorption_fits, load_benchmark, reduced_draws



def _bench():
    return load_benchmark("calibrate_confusion")


@pytest.mark.parametrize("seed", (0, 1) if FULL else (0,))
def test_fast_slice_names_no_wrong_effect(sn637, seed):
    cc = _bench()
    rows = []
    for e, rate, proto, size, s in cc.cases(seed=seed, quick=True):
        r = cc.evaluate(sn637, e, rate, proto, size, s, n_rows=cc.QUICK_ROWS, diagnostics=False)
        print(f"\n{r['effect']:22s} size x{size:.3g} excess {r['excess']:.3g} -> {r['answer']} {r['agreement']} "
              f"stages {r['named']} {r['class']} ratio {r['ratio']:.2f}")
        rows.append(r)
    table, head = cc.summarize(rows)
    print("\n" + table)
    assert len(rows) == 8
    assert head["wrong"] <= 0.02 * len(rows), [(r["effect"], r["named"]) for r in rows if r["class"] == "wrong"]
    # a right answer improves its channel's test error
    assert all(r["ratio"] < 1.0 for r in rows if r["class"] == "right")


def test_a_crash_counts_as_wrong_in_the_headline_and_the_table():
    """A crashed record is no answer: the headline's wrong count (the <= 2 % target) includes it,
    as the per-effect table does (review 3, bug 4)."""
    cc = _bench()
    rows = [{"effect": "none", "excess": 0.0, "class": "crash", "ratio": 1.0, "named": [], "above_line": {}},
            {"effect": "none", "excess": 0.0, "class": "none", "ratio": 1.0, "named": [], "above_line": {}},
            {"effect": "creep", "excess": 5.0, "class": "wrong", "ratio": 1.0, "named": ["drift"],
             "above_line": {}}]
    table, head = cc.summarize(rows)
    assert head["wrong"] == 2 and head["crashed"] == 1
    assert head["wrong_rate"] == pytest.approx(2 / 3)
    none_row = [ln for ln in table.splitlines() if ln.startswith("| none |")][0]
    assert none_row.split("|")[6].strip() == "1"          # the crash in the table's wrong column


def _traced(sn637, effects, rate_hz, protocol, size, seed):
    from workbench.calibrate.tracing import trace_effect
    _, sp, base, _, truth, _ = _bench().simulated_base(sn637, effects, rate_hz, protocol, size, seed)
    return base, trace_effect(base, split=sp), truth


@pytest.fixture(scope="module")
def large_leakage(sn637):
    """The 25x leakage record (1 kHz calibration protocol, seed 5) traced once in the module; the two
    tests below only read it."""
    return _traced(sn637, "leakage", 1e3, "calibration", 25.0, 5)


def test_a_large_leakage_does_not_choose_the_drive(large_leakage):
    """A 25x leakage (R_FP ~ 1-10 Mohm) fits the charge better with the recorded V = V_t + R i,
    which leads V_t by ~R C; the drive is judged on the stack's motion, so it stays V - R i and
    the displacement shows no spurious delay (before: a 0.65 ms 'delay' stage)."""
    base, res, truth = large_leakage
    assert base.voltage_source == "terminal voltage V - R i"
    named = [s["effect"] for s in res["stages"]]
    # the false-positive side, asserted by name (an empty answer must not pass by itself, review 3 item 14)
    assert "delay" not in named and "dielectric_absorption" not in named, (named, res["fold_winners"])
    assert all(s["effect"] == "leakage" for s in res["stages"]), named


def test_a_large_leakage_is_named(large_leakage):
    """The same 25x leakage record: the leakage itself is named (the positive side; it was a strict
    xfail, inconclusive 3 of 5 with 2 folds undecided against a slow absorption, until the record
    had to rule out absorptions settling within the whole record rather than half of it:
    calibrate/absorption_or_leakage.py), with the note that a slower absorption would look the same."""
    base, res, truth = large_leakage
    assert [s["effect"] for s in res["stages"]] == ["leakage"], res["fold_winners"]
    assert "would look the same" in res["stages"][0]["note"] and "would look the same" in res["reason"]


# Seed 15's records, pinned literally (effects, rate, protocol, size, seed) as drawn by
# benchmarks/calibrate_confusion.py's cases(1, 15) on 2026-11-25, so a change to the benchmark's
# draw order cannot silently swap them for other records (review 3 item 13).
SEED15 = {11: (("drift", "resonance"), 1000.0, "calibration", 13.953172790562634, 350511676),
          47: ("dielectric_absorption", 10000.0, "sine", 0.7447080106502547, 783069092),
          75: (("creep", "delay"), 100000.0, "calibration", 3.1195924809887052, 1072630000)}


def _seed_case(seed, index):
    """Seed 15's record ``index`` (1-based): (effects, rate, protocol, size, seed), pinned."""
    assert seed == 15
    return SEED15[index]


def test_a_mode_on_the_gauge_and_a_drift_of_the_displacement_are_both_named(sn637):
    """Seed 15's record 11 (drift + resonance, 1 kHz, calibration protocol, 14x): the folds split
    between the drift of the displacement (3) and the stack's mode on the gauge (2), so it was
    inconclusive. Two effects of different sensors: each added in turn, the other is accepted as
    a later stage (the gauge's mode through its own passes, though the fold decision names the
    displacement's: review 4 bug 1), so the split note says both are in the record; both are
    named, and nothing else; the first halves its channel's test error."""
    base, res, truth = _traced(sn637, *_seed_case(15, 11))
    named = [s["effect"] for s in res["stages"]]
    assert set(named) == {"drift", "resonance"}, (named, res["fold_winners"])
    assert "both are in the record" in res["stages"][0].get("resolved", ""), res["stages"][0].get("resolved")
    assert res["error_after"]["rms"] <= 0.5 * res["error_before"]["rms"]


def test_a_slow_absorption_that_bends_on_every_fold_is_named(sn637):
    """Seed 15's record 47 (absorption, tau 2.8 s over a 2 s sine record at 10 kHz): it beats
    leakage on every fold by more than the charge's noise floor, though by less than 30 % of
    what leakage leaves (the base's misfit): named (it was undecided), and halved."""
    base, res, truth = _traced(sn637, *_seed_case(15, 47))
    assert [s["effect"] for s in res["stages"]] == ["dielectric_absorption"], res["fold_winners"]
    assert res["parameters"]["tau_s"] == pytest.approx(truth["time_constant_s"], rel=0.6)
    assert res["error_after"]["rms"] <= 0.5 * res["error_before"]["rms"]


def test_creeps_charge_behind_a_long_delay_is_not_named_absorption(sn637):
    """Seed 15's record 75 (creep + a 2.25 ms delay, 100 kHz, 0.4 s): the delay hid the
    displacement's creep, so its charge relaxation was named dielectric_absorption (wrong). No
    absorption may be named; the answer is ``inconclusive``. (Until the plant kernel's KCL fix of
    2026-11-26 the creep branches' charge reached the terminal without passing R, a charge relaxation
    the absorption term fitted in 4 of 5 folds, and this record exercised the rule that withholds an
    absorption behind a displacement effect; with the creep charge through R the absorption wins 2 of
    5 folds and the delay 3, so no answer reaches 4 and the rule is not reached; its three branches
    are unit-tested in test_stages.py, test_creep_behind_a_displacement_effect_each_branch.) With the
    delay's model refitted per trial delay (branch s11_calbig) the delay won every fold and the
    creep followed as the second stage (measured there). Asserted is what must hold either way: no
    absorption, nothing outside the record's two effects, and a first answer of delay or none."""
    base, res, truth = _traced(sn637, *_seed_case(15, 75))
    named = [s["effect"] for s in res["stages"]]
    assert "dielectric_absorption" not in named, (named, res["fold_winners"])
    assert set(named) <= {"delay", "creep"}, (named, res["fold_winners"])
    assert res["effect"] in ("inconclusive", "delay"), (named, res["fold_winners"])


def test_creep_behind_a_displacement_effect_reports_its_fold_wins_not_its_passes(monkeypatch):
    """The promotion branch of stages._creep_behind_a_displacement_effect (review 3, bug 2): the
    displacement effect named first passes 4 of 5 folds but won only 1 (the charge relaxation won
    the rest); once it is in the model the displacement's creep wins 3 of 5. The agreement
    reported must be its 1 fold win, the 4 passes only in the note. The folds are re-scored on
    the joint re-search's candidates with the effect among the found ones (review 4 bug 4)."""
    from types import SimpleNamespace

    from workbench.calibrate import stages, tracing
    tag = ("delay", "displacement")
    charge = ("dielectric_absorption", "charge")
    d = {"name": "delay", "channel": "displacement", "passes": [True, True, True, True, False], "score": 0.5}
    res = {"rows": [d], "winners": [charge, charge, tag, charge, "none"]}
    rescored = {"winners": [("creep", "displacement")] * 3 + ["none", "none"]}
    researched = [{"name": "creep", "channel": "displacement", "researched": True}]
    seen = {}
    monkeypatch.setattr(tracing, "_absorb", lambda *a, **k: None)
    monkeypatch.setattr(stages, "_later_candidates",
                        lambda cands, probs, extra, found, t, base: seen.update(found=list(found)) or researched)
    monkeypatch.setattr(tracing, "_score_stage",
                        lambda cands, *a, **k: seen.update(scored=cands) or rescored)
    ctx = {"probs": {}, "split": SimpleNamespace(folds=[0] * 5), "need": 3, "base": None, "t": None,
           "cands": [], "nulls": [], "penalty": 0.02, "noise_factor": 1.0, "infos": {}, "min_share": 0.0}
    answer, count, note = stages._creep_behind_a_displacement_effect(charge, 3, None, res, ctx, {}, [])
    assert answer == tag
    assert count == sum(1 for w in res["winners"] if w == tag) == 1
    assert "creep wins 3 of 5" in note and "passes 4 folds" in note
    assert seen["scored"] is researched and seen["found"] == [tag]


# Leakage-only records of the held-out seeds 17 and 18 (pinned as drawn by cases(1, seed)), sizes 2-15x,
# 1/10/100 kHz, two protocols (steps, sine): the absorption's bend rule must not name absorption on any (review 3 item 14).
LEAKAGE_17_18 = [("leakage", 1000.0, "steps", 2.3274258051873336, 299673796),
                 ("leakage", 10000.0, "sine", 7.2478899527183085, 485639728),
                 ("leakage", 10000.0, "steps", 15.487405966584307, 556913422),
                 ("leakage", 100000.0, "sine", 5.790953900103864, 457695041),
                 ("leakage", 1000.0, "sine", 2.267877476215541, 908609146),
                 ("leakage", 10000.0, "sine", 4.056513810711598, 809162113)]
#: make test: every rate (1, 10, 100 kHz) and both protocols, with the size range's ends (10 kHz steps x15.5,
#: the largest; 100 kHz sine x5.8; 1 kHz sine x2.3, the smallest); WORKBENCH_FULL=1 all six (main 922fa0c's
#: make test ran all six)
LEAKAGE_KEEP = {2, 3, 4}


@pytest.mark.parametrize("case", reduced_draws([(c,) for c in LEAKAGE_17_18], keep=LEAKAGE_KEEP),
                         ids=[f"{c[1] / 1e3:g}kHz-{c[2]}-x{c[3]:.1f}" for c in LEAKAGE_17_18])
def test_a_leakage_is_never_named_absorption(sn637, case):
    base, res, truth = _traced(sn637, *case)
    named = [s["effect"] for s in res["stages"]]
    assert "dielectric_absorption" not in named, (named, res["fold_winners"])
    assert not set(named) - {"leakage"}, (named, res["fold_winners"])


# Creep + delay records of the benchmark's seeds 19 and 20 (cases(1, seed), pinned literally on
# 2026-11-26): after the plant kernel's KCL fix the sensor delay (13 ms, 27 ms) hid the
# displacement's creep and creep's charge was named dielectric_absorption (wrong: a later stage
# after the delay on the first, the first stage on the second), while the gauge, which the
# displacement sensor's delay does not touch, showed the stack's creep on 4-5 folds.
CREEP_BEHIND_DELAY = [(("creep", "delay"), 10000.0, "sine", 9.385398848283357, 933896889),
                      (("creep", "delay"), 100000.0, "calibration", 17.964340824037386, 47562072)]


SEED20_MISS = ("session 17 (fresh clone of 12c6725, after the s17 merges; not bisected): the 100 kHz calibration "
               "record is answered inconclusive (fold winners: absorption on the charge 1, creep on the gauge 2, "
               "undecided absorption or creep 2): creep no longer wins 4 of 5 folds; no wrong effect named")


# seed 20's strict xfail stays in make test although it costs ~5 s: no other make-test test reaches
# stages.resolve_split's early return for a pair it cannot score (session 31's per-test coverage, s31_suite)
@pytest.mark.parametrize("case", [CREEP_BEHIND_DELAY[0], pytest.param(CREEP_BEHIND_DELAY[1], marks=pytest.mark.xfail(
    strict=True, reason=SEED20_MISS))], ids=["seed19-10kHz-sine", "seed20-100kHz-calibration"])
def test_creeps_charge_is_not_absorption_when_the_gauge_shows_the_creep(sn637, case):
    """The cross-channel rule (tracing._stack_shows_it) takes the gauge's creep when the
    displacement's is hidden by a displacement-sensor effect: no absorption or leakage named,
    creep named (the stack's, on either sensor), nothing the record lacks."""
    base, res, truth = _traced(sn637, *case)
    named = [s["effect"] for s in res["stages"]]
    assert "creep" in named, (named, res["fold_winners"])
    assert not set(named) - {"creep", "delay"}, (named, res["fold_winners"])


@pytest.mark.parametrize("draw", range(4))
def test_the_gauges_creep_is_turned_into_metres_by_its_gain(draw):
    """``_stack_shows_it`` with the gauge's creep: what the gauge explains (V) divided by its gain
    (V/m) is metres, compared with the charge term as displacement (C x m/C). The ratio branch
    is kept out (the gauge's ratio above the square root of the charge's), so the gain decides:
    the gauge explaining 0.7x the charge's displacement is the stack's creep, 0.3x is not.
    Multiplying by the gain, or leaving it out, calls both creep (gain >= 1e3 V/m). Drawn: the
    gain (1e3..1e7 V/m, the sensor's range; 3.58e5 on the reference plant), k_q2x, the sizes."""
    from workbench.calibrate.tracing import _stack_shows_it
    rng = np.random.default_rng(700 + draw)
    penalty, n = 0.02, 4
    g = 10.0 ** rng.uniform(3, 7)                      # V/m
    k = 10.0 ** rng.uniform(-2, 0)                     # m/C
    b_q = 10.0 ** rng.uniform(-9, -6)                  # C, the charge fold's error before
    e_q = b_q * np.sqrt(1 - 0.2 ** 2)                  # what the charge term explains (C)
    charge = {"key": ("charge", "model"), "channel": "charge", "n_params": n,
              "ratios": [0.2 * (1 + penalty * n)]}
    for share, expect in ((0.7, True), (0.3, False)):
        b_g = share * e_q * k * g / 0.6                # V: the gauge explains 0.6 b_g = share x_equiv g
        gauge = {"key": ("gauge", "model"), "channel": "gauge", "n_params": n,
                 "ratios": [0.8 * (1 + penalty * n)]}
        assert gauge["ratios"][0] > np.sqrt(charge["ratios"][0])
        befores = {("charge", "model"): [b_q], ("gauge", "model"): [b_g]}
        infos = {"k_q2x": k, "gauge_gain": g}
        assert _stack_shows_it(charge, gauge, 0, befores, infos, penalty) is expect, (share, g)


def _leak_and_absorption(sn637, tau_s):
    """``beyond_sizes`` of the leak + absorption steps record (:func:`tests.conftest.leak_and_absorption_fits`)."""
    base, base0, sp = leak_and_absorption_fits(sn637, tau_s)
    return _bench().beyond_sizes(base, base0, ("leakage", "dielectric_absorption"), sp)


def test_a_leak_stands_beyond_a_fast_absorption_and_not_beyond_a_slow_one(sn637):
    """The pair diagnostic (``beyond_sizes``) against the physics of the two forms: an absorption
    relaxing within the record (tau = T/20) bends, a leak ramps, and each stands far beyond the
    other; one relaxing over 30 record lengths is k/tau int V dt to O(T / 2 tau) = 2 %, the leak's
    own form, so neither adds anything of note beyond the other (measured 0.15x and 0.0x). Both
    effects are the same size in the two records."""
    fast = _leak_and_absorption(sn637, 0.5)
    slow = _leak_and_absorption(sn637, 300.0)
    print(f"\nbeyond the other (leakage, absorption): tau 0.5 s {np.round(fast, 2)}, tau 300 s {np.round(slow, 2)}")
    assert min(fast) >= 3.0
    assert max(slow) < 1.0 and min(fast) > 10.0
