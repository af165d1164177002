"""Dielectric absorption or leakage (workbench/calibrate/absorption_or_leakage.py).

The closed form the rule rests on (an absorption's bend beyond leakage's line over a record),
the rule's branches on constructed fold scores, and drawn records: leakage and absorption at
10 kHz, 2 s, sizes log-uniform over the confusion benchmark's whole range, the absorption's time
constant log-uniform from 1/20 to 20 record lengths. What the physics distinguishes must never
be confused: a leakage (no bend at all) named absorption, an absorption that settles within half
the record (its shape is in the record) named leakage, or any other effect named.
"""

import dataclasses

import numpy as np
import pytest

from tests.conftest import FULL, load_benchmark, reduced_draws
from workbench.calibrate import absorption_or_leakage as al


@pytest.mark.parametrize("records_per_tau", [0.02, 0.05, 0.1, 0.2])
def test_the_bend_beyond_leakages_line_is_the_closed_form(records_per_tau):
    """k (1 - exp(-t / tau)) on [0, T] less its best line (offset and slope, as the base's offset
    and leakage's column take): RMS sqrt(3/5) / 12 x T / tau of the line's term, to first order."""
    T, tau = 1.0, 1.0 / records_per_tau
    t = np.linspace(0.0, T, 200_001)
    y = 1.0 - np.exp(-t / tau)
    A = np.column_stack([np.ones_like(t), t])
    c = np.linalg.lstsq(A, y, rcond=None)[0]
    bend = np.sqrt(np.mean((y - A @ c) ** 2))
    line = abs(c[1]) * T / np.sqrt(3.0)
    # the next order is relative T / tau smaller
    assert bend / line == pytest.approx(al.BEND_PER_RECORD * T / tau, rel=records_per_tau)


def _rows(tau_s, a_lk, a_da, E, n_folds=5):
    """Constructed fold scores: leakage explains E and leaves a_lk, the absorption leaves a_da."""
    b = float(np.hypot(E, a_lk))
    key = ("charge", "model")
    befores = {key: [b] * n_folds}
    lk = {"name": "leakage", "channel": "charge", "key": key, "n_params": 1, "params": {},
          "ratios": [a_lk * 1.02 / b] * n_folds}
    da = {"name": "dielectric_absorption", "channel": "charge", "key": key, "n_params": 2,
          "params": {"tau_s": tau_s}, "ratios": [a_da * 1.04 / b] * n_folds, "eff": _Eff(CEILING)}
    return lk, da, befores


#: the absorption's search ceiling in record lengths (tracing's plan: ``DielectricAbsorption(tau_max_fraction=100)``)
CEILING = 100.0
_Eff = dataclasses.make_dataclass("Eff", [("tau_max_fraction", float)])


@pytest.mark.parametrize("T", [0.1, 2.0, 35.0])
def test_the_rules_branches(T):
    floor = 1.0
    infos = {"duration_s": T, "charge": {"noise_floor": floor}}
    need = al.SETTLED_RECORDS / (al.BEND_PER_RECORD)        # E / a at which tau_bound = T / 2

    def decide(tau_s, a_lk, a_da, E):
        lk, da, befores = _rows(tau_s, a_lk, a_da, E)
        tags = {("leakage", "charge"): lk, ("dielectric_absorption", "charge"): da}
        out = al.absorption_or_leakage(lk, tags, 0, befores, infos, 0.02, 1.0, 0.3)
        return None if out is None else out["name"]

    a = 10.0 * floor
    # settled within half the record: the fold's ranking stands (here leakage ranked first)
    assert decide(0.4 * T, a, a, 100 * a) == "leakage"
    # a bend beyond the floor on every fold: absorption, whatever its time constant
    assert decide(3.0 * T, a, np.sqrt(a * a - 4 * floor ** 2), 5 * a) == "dielectric_absorption"
    assert decide(100.0 * T, a, 0.5 * a, 5 * a) == "dielectric_absorption"
    # no bend, the fit ran to the search's ceiling (leakage's limit), and the record rules out every
    # absorption settling within half of it: leakage; just short of that: undecided
    assert decide(CEILING * T, a, a, 1.01 * need * a) == "leakage"
    assert decide(CEILING * T, a, a, 0.99 * need * a) is None
    # no bend, but a finite time constant fitted beyond the record (inside the search): the record
    # cannot tell the two apart, whatever it rules out below half its length (seed 45 #69, 31 #135)
    for tau_records in (al.LEAKAGE_TAU_RECORDS, 52.0, 0.98 * CEILING):
        assert decide(tau_records * T, a, a, 100 * need * a) is None
    # no bend but a time constant within ten records: undecided
    assert decide(0.99 * al.LEAKAGE_TAU_RECORDS * T, a, a, 100 * need * a) is None
    lk, _, befores = _rows(1.0, a, a, 3.0 * a)
    assert al.tau_bound_s(lk, 0, befores, 0.02, T) == pytest.approx(al.BEND_PER_RECORD * T * 3.0)


def _draws(n, seed):
    """(effect, protocol, size, tau over the record or None, seed) for ``n`` leakage and ``n``
    absorption records: sizes log-uniform over the benchmark's range, tau from 1/20 to 20 records."""
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(seed)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    out = []
    for k in range(n):
        proto = ("calibration", "sine", "steps")[k % 3]
        for e in ("leakage", "dielectric_absorption"):
            size = float(np.exp(rng.uniform(lo, hi)))
            tau_records = float(np.exp(rng.uniform(np.log(0.05), np.log(20.0)))) if e != "leakage" else None
            out.append((e, proto, size, tau_records, int(rng.integers(1 << 30))))
    return out


def _trace(sn637, effect, protocol, size, tau_records, seed):
    from workbench.calibrate.base_fit import fit_base
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
    from workbench.calibrate.tracing import trace_effect
    cc = load_benchmark("calibrate_confusion")
    rate = 1e4
    t, v = benchmark_protocol(protocol, rate, cc.QUICK_ROWS)
    T = float(t[-1] - t[0])
    plant, truth = plant_with_effect(sn637, effect, seed, duration_s=float(t[-1]), size=size)
    if tau_records is not None:
        plant = dataclasses.replace(plant, additions=dataclasses.replace(
            plant.additions, absorption_time_constant_s=tau_records * T))
    r = simulate_record(plant, t, v, seed=seed)
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(cc._record(r, 1.0 / rate), sn637.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    return trace_effect(base, split=sp), T


#: make test traces 7 of seed 0's 12 records (session 30; session 29 traced all 12): per protocol one leakage and
#: one absorption, the draw's ends kept: leakage 0.036x (steps, the smallest), 11.2x (calibration) and 11.7x (sine,
#: the largest); absorption 0.040x (calibration, the smallest, tau 0.055 records), 1.98x (sine, tau 3.96 records,
#: the slowest) and 8.4x (steps, the largest, tau 0.051, the fastest); and the 1.28x steps leakage, one of the three
#: mid-size leakages the rule leaves undecided between absorption and leakage (5 of 5 folds), the records nearest the
#: confusion this test forbids (the review, session 30). Left to WORKBENCH_FULL=1: the other two undecided leakages
#: (2.44x calibration, 8.26x sine) and three absorptions named 5 of 5, inside the kept ends on every axis (10 kHz,
#: the same protocols)
DRAWN_REDUCED = (1, 3, 4, 5, 6, 8, 10)


@pytest.mark.parametrize("seed", (0, 1) if FULL else (0,))
def test_drawn_records_confuse_nothing_the_physics_tells_apart(sn637, seed):
    """Leakage and absorption records drawn over the whole size range and time constants from
    1/20 to 20 record lengths: a leakage is never named absorption, an absorption settling within
    half the record never leakage, and nothing else is named. An absorption slower than that may
    be named leakage (its bend below what the record resolves: the nested, simpler reading); such
    records are printed, not asserted. A named leakage carries the note."""
    wrong, unresolved, named = [], [], []
    draws = _draws(6, seed)
    for e, proto, size, tau_records, s in (draws if FULL else [draws[k] for k in DRAWN_REDUCED]):
        res, T = _trace(sn637, e, proto, size, tau_records, s)
        names = [st["effect"] for st in res["stages"]]
        print(f"\n{e:22s} {proto:11s} x{size:7.3f} tau/T {tau_records if tau_records is None else round(tau_records, 2)}"
              f" -> {names} {res['fold_winners']}")
        named.append(names)
        if set(names) - {"leakage", "dielectric_absorption"}:
            wrong.append((e, proto, size, tau_records, names))
        elif e == "leakage" and "dielectric_absorption" in names:
            wrong.append((e, proto, size, tau_records, names))
        elif e == "dielectric_absorption" and "leakage" in names:
            (unresolved if tau_records >= al.SETTLED_RECORDS else wrong).append((e, proto, size, tau_records, names))
        for st in res["stages"]:
            if st["effect"] == "leakage" and st.get("note"):
                assert "would look the same" in st["note"]
    print(f"\nslow absorptions named leakage (unresolved by the record): {unresolved}")
    assert not wrong, wrong
    # the draws must reach the rule: some records named at all (not a test passed by silence)
    assert sum(bool(n) for n in named) >= 3, named


# ---- the nested pair over the folds, and the settled absorption measured (branch s11_calleak)

L, D, U = ("leakage", "charge"), ("dielectric_absorption", "charge"), al.UNDECIDED


F5, T5 = [False] * 5, [True] * 5


@pytest.mark.parametrize("winners, need, no_worse, named, decided", [
    ([L, L, U, L, U], 4, F5, L, 3),              # decided folds unanimous, the rest undecided
    ([L, U, U, U, L], 4, F5, L, 2),
    ([L, U, U, U, L], 4, T5, L, 2),              # leakage no worse held out does not block leakage
    ([D, U, U, D, U], 4, F5, D, 2),              # the absorption alike
    ([D, U, U, D, U], 4, [False, True, False, False, False], None, 0),  # an undecided fold leans leakage
    ([D, U, U, D, U], 4, [True, False, False, False, False], D, 2),     # ... a decided fold's flag is moot
    ([L, L, "none", U, U], 4, F5, L, 2),         # one dissenting fold, as the plain consensus tolerates
    ([L, U, U, U, U], 4, F5, None, 0),           # one decided fold is no more than the tolerated dissent
    ([L, U, U, U, D], 4, F5, None, 0),           # the decided folds disagree
    ([L, L, U, U, D], 4, F5, None, 0),           # ... even with two of one side (review finding 3)
    ([D, D, U, U, L], 4, F5, None, 0),
    ([U, U, U, U, U], 4, F5, None, 0),           # nothing decided: inconclusive
    ([L, L, "none", "none", U], 4, F5, None, 0), # three compatible folds of five
    ([L, U, U, U, U], 5, F5, None, 0),           # 5 of 5 asked: still two decided folds (finding 2)
    ([L, L, U, U, U], 5, F5, L, 2),
    ([L, L, "none", U, U], 5, F5, None, 0),      # 5 of 5 asked: no dissent tolerated
    ([L, U, U, U], 4, [False] * 4, None, 0),     # four folds at 4 of 4: not one decided fold
    ([L, L, U, U], 4, [False] * 4, L, 2),
    ([D, D, U, U], 4, [False, False, True, False], None, 0),
    ([L, L] + [U] * 8, 8, [False] * 10, None, 0),  # ten folds: three must decide
    ([L, L, L] + [U] * 7, 8, [False] * 10, L, 3),
])
def test_nested_consensus_names_only_from_unanimous_decided_folds(winners, need, no_worse, named, decided):
    ans, k, und = al.nested_consensus(winners, need, no_worse)
    assert ans == named
    if named is not None:
        assert k == decided and und == sum(1 for w in winners if w == U)
        note = al.nested_note(ans, k, und, len(winners))
        assert f"{k + und} of {len(winners)} folds compatible" in note and f"{k} decided" in note
        assert f"{und} fold" in note
        neither = len(winners) - k - und
        assert (f"{neither} name" in note) == bool(neither)


@pytest.mark.parametrize("n_folds", range(3, 13))
def test_the_decided_folds_needed_do_not_fall_as_the_bar_rises(n_folds):
    """More decided folds than the default agreement's tolerated dissent, never one, and the same
    whatever agreement a user asks (review finding 2: ``n - need + 1`` fell to 1 at 5 of 5)."""
    k = al.decided_needed(n_folds)
    assert k >= 2 and k > n_folds - int(np.ceil(0.8 * n_folds))
    L1 = [L] + [U] * (n_folds - 1)
    for need in range(int(np.ceil(0.8 * n_folds)), n_folds + 1):
        assert al.nested_consensus(L1, need, [False] * n_folds)[0] is None
        Lk = [L] * k + [U] * (n_folds - k)
        assert al.nested_consensus(Lk, need, [False] * n_folds)[0] == L


@pytest.mark.parametrize("T", [0.4, 10.0])
@pytest.mark.parametrize("tau_records", [0.6, 4.8, 9.5])
def test_two_chance_folds_do_not_name_the_absorption(T, tau_records):
    """Review finding 1: with the absorption fitted between half a record and ten (seed 24 #4, a
    7.3x leakage, came out 4.8), leakage cannot win a fold outright; two folds where the absorption
    bends into the base's misfit (0.8 of leakage's RMS) and three where leakage does better held
    out (1.02) must not name the absorption; with the three a hair in the absorption's favour
    (0.999, under the noise floor) the two decided folds do name it."""
    floor, share, a, E = 1.0, 0.3, 10.0, 30.0
    infos = {"duration_s": T, "charge": {"noise_floor": floor}}

    def run(rest):
        lk, da, befores = _rows(tau_records * T, a, a, E)
        b = befores[lk["key"]][0]
        da["ratios"] = [x * 1.04 / b for x in (0.8 * a, 0.8 * a, rest * a, rest * a, rest * a)]
        tags = {L: lk, D: da}
        w = []
        for f in range(5):
            best = lk if lk["ratios"][f] <= da["ratios"][f] else da
            out = al.absorption_or_leakage(best, tags, f, befores, infos, 0.02, 1.0, share)
            w.append(U if out is None else (out["name"], "charge"))
        assert w == [D, D, U, U, U]                       # the guard is what is tested
        return al.nested_consensus(w, 4, al.leakage_no_worse(tags, befores, 0.02))[0]

    assert run(1.02) is None
    assert run(0.999) == D


def test_the_leakage_note_says_what_ruled_the_settled_absorption_out():
    """The bound is the record length only when the measured test decided a leakage fold; a time
    constant at the search's ceiling is said to be the ceiling; one record length is singular."""
    T = 10.0
    lk, da, befores = _rows(1000.0, 10.0, 10.0, 20.0)     # tau_bound: 0.13 records (BEND x E / a)
    da["eff"] = dataclasses.make_dataclass("Eff", [("tau_max_fraction", float)])(100.0)
    by = {L: lk, D: da}
    bound = np.median([al.tau_bound_s(lk, f, befores, 0.02, T) for f in range(5)])
    da["settled_rms"] = [20.0] * 5                        # computed, but no fold decided by it
    lk["leakage_folds"] = {0: "bound"}
    note = al.leakage_note(by, befores, 0.02, T)
    assert f"about {bound:.3g} s ({bound / T:.2g} record lengths)" in note
    assert "not a fit: the search ran to its ceiling, 1e+03 s = 100 record lengths" in note and "fitted" not in note
    lk["leakage_folds"] = {0: "bound", 3: "measured"}
    note = al.leakage_note(by, befores, 0.02, T)
    assert "about 10 s (1 record length)" in note
    da["params"]["tau_s"] = 120.0
    assert "fitted 120 s" in al.leakage_note(by, befores, 0.02, T)


def test_the_written_plants_leakage_section_says_the_time_constant_is_unidentified(sn637, tmp_path):
    """Review finding 6: the note is a comment line of ``[leakage]``; the file loads back with the
    leakage's resistance."""
    from pathlib import Path
    from types import SimpleNamespace

    from tests.conftest import PLANTS
    from workbench.calibrate.plant_update import updated_plant_text
    from workbench.plant import load_plant
    err = {"rms": 1e-7, "max": 3e-7, "units": "C"}
    note = "leakage is the simpler reading: ... its time constant is what the record cannot identify (fitted 120 s)"
    st = {"effect": "leakage", "channel": "charge", "parameters": {"gain_per_s": 1e-7}, "note": note,
          "error_before": err, "error_after": err}
    result = {"effect": "leakage", "channel": "charge", "parameters": st["parameters"], "error_before": err,
              "error_after": err, "stages": [st]}
    text = updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, SimpleNamespace(channels={}), result,
                              Path("rec.csv"))
    section = text[text.index("[leakage]"):].splitlines()
    assert section[1] == f"# {note}" and section[2].startswith("resistance_ohm = ")
    (tmp_path / "p.toml").write_text(text)
    assert load_plant(tmp_path / "p.toml").additions.leakage_resistance_ohm == pytest.approx(1e7)


@pytest.mark.parametrize("T", [0.4, 2.0, 10.0])
def test_a_settled_absorption_ruled_out_on_the_fold_names_leakage(T):
    """The measured ruling-out: the record-length absorption in leakage's place leaves more than
    leakage by the candidate bar (noise floor squared and min_share of leakage's power) -> leakage
    when the fitted absorption came out ten records or slower; just under the bar, or without the
    measurement: undecided (the tau_bound estimate alone fails here: E / a = 3)."""
    floor, share = 1.0, 0.3
    infos = {"duration_s": T, "charge": {"noise_floor": floor}}
    a = 10.0 * floor

    def decide(tau_s, settled):
        lk, da, befores = _rows(tau_s, a, a, 3.0 * a)
        if settled is not None:
            da["settled_rms"] = [settled] * 5
        tags = {L: lk, D: da}
        out = al.absorption_or_leakage(lk, tags, 0, befores, infos, 0.02, 1.0, share)
        return None if out is None else out["name"]

    assert decide(CEILING * T, np.sqrt(1.01 * (1 + share)) * a) == "leakage"
    assert decide(CEILING * T, np.sqrt(0.99 * (1 + share)) * a) is None
    assert decide(CEILING * T, None) is None
    # fitted inside the search, beyond the record: not told apart, ruled out or not (session 15)
    for tau_records in (al.LEAKAGE_TAU_RECORDS, 30.0):
        assert decide(tau_records * T, np.sqrt(2.0 * (1 + share)) * a) is None
    # a fitted absorption between half the record and ten records stays undecided though the
    # record-length one is ruled out (an 18x absorption of 0.4 s, seed 24 #80, was named leakage)
    for tau_records in (0.6, 3.0, 0.99 * al.LEAKAGE_TAU_RECORDS):
        assert decide(tau_records * T, np.sqrt(2.0 * (1 + share)) * a) is None
    # the bar's other half: a loss above min_share but under the noise floor is no evidence
    b = 0.1 * floor
    lk, da, befores = _rows(3 * T, b, b, 3 * b)
    da["settled_rms"] = [np.sqrt(b * b + 0.9 * floor ** 2)] * 5
    assert al.absorption_or_leakage(lk, {L: lk, D: da}, 0, befores, infos, 0.02, 1.0, share) is None


def _drawn_records(effects, n, seed):
    """(effect, rate, protocol, size, seed): sizes log-uniform over the benchmark's whole range."""
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(seed)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    out = []
    for k in range(n):
        for e in effects:
            rate = (1e3, 1e4)[k % 2]
            proto = ("calibration", "steps", "sine")[k % 3]
            out.append((e, rate, proto, float(np.exp(rng.uniform(lo, hi))), int(rng.integers(1 << 30))))
    return out


#: make test traces 6 of each effect's 8 records (session 30; session 29 traced all 8): every cell of rate (1, 10 kHz)
#: and protocol once, the size range's ends and the records nearest the 3x bar kept. Leakage: 0.196x (10 kHz steps,
#: the smallest), 16.2x (10 kHz sine, the largest, named 3 of 5) and 0.387x (1 kHz calibration, 4.1x above the
#: floor, named 2 of 5) kept; left to WORKBENCH_FULL=1 the 1 kHz calibration 4.5x (named 5 of 5 at 50x above the
#: floor, the kept 0.387x's cell) and the 10 kHz steps 0.327x (none, inside the kept 0.196x's cell). The pair:
#: 0.032x (10 kHz sine, the smallest), 13.8x (10 kHz steps, the largest) and 0.110x (1 kHz calibration, 3.7x above
#: the floor, the record nearest the bar) kept; left to the full form the 1 kHz calibration 3.18x (154x above the
#: floor, the kept 0.110x's cell) and the 10 kHz steps 0.035x (none, the kept 13.8x's cell, beside the kept 0.032x)
LEAKAGE_REDUCED = {"leakage": (2, 3, 4, 5, 6, 7), "pair": (0, 1, 2, 3, 4, 5)}


@pytest.mark.parametrize("effect", ["leakage", ("leakage", "dielectric_absorption")])
def test_leakage_and_pairs_standing_3x_above_the_floor_are_named(sn637, effect):
    """Leakage and leakage + absorption records at 1 and 10 kHz, three protocols, sizes over the
    benchmark's whole range (0.03-30x; ``default_rng(1311)``/``(1312)`` fixed before any run):
    every record whose effect stands >= 3x above the effect-free record's floor is named right
    (leakage; for the pair either of its two, the first stage) with its test error halved, and
    no record of any size is named an effect it does not have. On main before this branch the
    leakages among them were ``inconclusive`` (the fitted absorption's time constant came out
    3-9 record lengths, short of ten, and the tau_bound estimate under half a record)."""
    cc = load_benchmark("calibrate_confusion")
    seed = 1311 if effect == "leakage" else 1312
    rows = []
    draws = _drawn_records([effect], 8, seed)
    keep = LEAKAGE_REDUCED["leakage" if effect == "leakage" else "pair"]
    for e, rate, proto, size, s in (draws if FULL else [draws[k] for k in keep]):
        r = cc.evaluate(sn637, e, rate, proto, size, s, diagnostics=False)
        print(f"\n{r['effect']:32s} {rate:6.0f} {proto:11s} x{size:7.3f} excess {r['excess']:7.2f} -> {r['answer']} "
              f"{r['agreement']} {r['named']} {r['class']} ratio {r['ratio']:.2f} {r['fold_winners']}")
        rows.append(r)
    assert not [r for r in rows if r["class"] == "wrong"]
    big = [r for r in rows if r["excess"] >= 3.0]
    assert len(big) >= 3, [round(r["excess"], 2) for r in rows]      # the draws reach the claim
    missed = [(r["size"], r["excess"], r["answer"], r["fold_winners"]) for r in big
              if r["class"] != "right" or r["ratio"] > 0.5]
    assert not missed, missed


# regression records (the confusion benchmark's seeds 27 and 28, the seeds s11_calleak was tuned on),
# answered inconclusive on main before s11_calleak. The two leakages are named by the plain vote
# (leakage on 4 of 5 folds): the record-length absorption's measured ruling-out
# (``settled_ruled_out``) decides their folds, not ``nested_consensus``.
PLAIN_VOTE_27_28 = [("leakage", 1000.0, "calibration", 7.016543055638025, 999881126),     # 27 #4, 17x
                    ("leakage", 10000.0, "calibration", 19.342973875147397, 133463090)]   # 28 #37, 7.6x
# The two pairs (10 kHz steps, the absorption's tau 0.8-1.3 record lengths) were named by
# ``nested_consensus`` from 2 decided folds (D U U D U); on one undecided fold leakage leaves 5-6 %
# less than the absorption held out, so under the stricter rule (review of s11_calleak, finding 1)
# they are inconclusive again: a miss, reported in the README, not asserted away.
NESTED_PAIRS_27_28 = [(("leakage", "dielectric_absorption"), 10000.0, "steps", 0.41778799554157237, 782366254),
                      (("leakage", "dielectric_absorption"), 10000.0, "steps", 0.7085757336901202, 114342319)]


@pytest.mark.parametrize("case", PLAIN_VOTE_27_28, ids=["27-4", "28-37"])
def test_leakages_whose_folds_the_settled_test_decides_are_named_by_the_plain_vote(sn637, case):
    cc = load_benchmark("calibrate_confusion")
    r = cc.evaluate(sn637, *case, diagnostics=False)
    print(f"\n{r['effect']} excess {r['excess']:.2f} -> {r['answer']} {r['agreement']} {r['fold_winners']}")
    assert r["class"] == "right" and r["ratio"] <= 0.5, (r["answer"], r["fold_winners"])
    assert sum(w == "leakage on the charge" for w in r["fold_winners"]) >= 4, r["fold_winners"]


# 28 #65 runs under WORKBENCH_FULL=1 only (session 31, s31_suite): make test keeps 27 #65, the same pair, rate,
# protocol and assertion; 28 #65 reaches no line or branch of workbench/ the kept tests do not
@pytest.mark.parametrize("case", reduced_draws([(c,) for c in NESTED_PAIRS_27_28], keep={0}), ids=["27-65", "28-65"])
def test_pairs_with_an_undecided_fold_leaning_leakage_name_nothing_wrong(sn637, case):
    cc = load_benchmark("calibrate_confusion")
    r = cc.evaluate(sn637, *case, diagnostics=False)
    print(f"\n{r['effect']} excess {r['excess']:.2f} -> {r['answer']} {r['agreement']} {r['fold_winners']}")
    assert r["class"] != "wrong", (r["answer"], r["fold_winners"])


@pytest.mark.parametrize("winners, lean, named", [([L, U, U, U, L], 1, L), ([D, U, U, D, U], None, D),
                                                  ([D, U, U, D, U], 4, None)])
def test_the_stage_says_the_compatible_folds_beside_the_decided(monkeypatch, winners, lean, named):
    """stages.run_stages: a name from decided folds carries ``agreement_compatible`` (decided +
    undecided, what scripts compare with ``agree_needed``) beside its count of decided folds; an
    undecided fold where leakage leaves less than the absorption held out (``lean``) blocks the
    absorption there too (review finding 4, and finding 1 through the stage loop)."""
    from workbench.calibrate import stages, tracing
    lk, da, befores = _rows(3.0, 10.0, 9.99, 30.0)
    b = befores[lk["key"]][0]
    if lean is not None:
        da["ratios"][lean] = 11.0 * 1.04 / b
    res = {"winners": winners, "by": {L: lk, D: da}, "befores": befores}
    monkeypatch.setattr(tracing, "_score_stage", lambda *args, **kw: res)
    monkeypatch.setattr(tracing, "_absorb", lambda *args, **kw: None)
    monkeypatch.setattr(stages, "resolve_split", lambda *args: (None, 0, None))
    monkeypatch.setattr(stages, "_creep_behind_a_displacement_effect", lambda answer, count, note, *args, **kw:
                        (answer, count, note))
    monkeypatch.setattr(stages, "_stage_entry", lambda c, count, ctx, extra, resolved=None:
                        {"count": count, "resolved": resolved})
    monkeypatch.setattr(stages, "_later_stage", lambda *args, **kw: (None, 0, [], {"by": {}}, None))
    ctx = {k: None for k in ("cands", "nulls", "split", "noise_factor", "infos", "min_share", "base", "t")}
    ctx.update(probs={}, need=4, penalty=0.02)
    first, st, _ = stages.run_stages(ctx)
    if named is None:
        assert first["answer"] is None and not st
        return
    assert first["answer"] == named and st[0]["count"] == 2 and st[0]["agreement_compatible"] == 5
    assert "2 folds it wins are the decided ones" in st[0]["resolved"] and "3 folds cannot tell" in st[0]["resolved"]


# ---- leakage beside a found absorption: the joint model (session 13, issue 13 item 5)

def test_a_refitting_candidate_takes_the_found_columns_place():
    """tracing._stacked leaves out the found effect a candidate ``replaces``; tracing._absorb puts
    the candidate's columns in its place (copies of the found list keep theirs)."""
    from types import SimpleNamespace

    from workbench.calibrate import tracing
    rng = np.random.default_rng(5)
    n = 64
    a, b, c = (rng.normal(size=(n, 1)) for _ in range(3))
    seen = []
    prob = SimpleNamespace(base="base", A=np.zeros((n, 2)),
                           grams=lambda C, lows, own=False: seen.append((np.asarray(C).copy(), list(lows))) or {"C": C})
    found = [tracing.FoundColumns(a, [0.0], al.ABSORPTION), tracing.FoundColumns(b, [-np.inf], ("resonance", "x"))]
    cand = {"g": {"C": c, "norms": np.ones(1), "lb": np.r_[0.0, 0.0, 0.0]}, "replaces": al.ABSORPTION}
    tracing._stacked(prob, found, cand)
    assert np.array_equal(seen[-1][0], np.column_stack([b, c])) and seen[-1][1] == [-np.inf, 0.0]
    tracing._stacked(prob, found, {**cand, "replaces": None})
    assert np.array_equal(seen[-1][0], np.column_stack([a, b, c]))
    key = ("charge", "model")
    extra = {key: list(found)}
    kept = {k: list(v) for k, v in extra.items()}
    tracing._absorb({**cand, "key": key, "name": "leakage", "channel": "charge"}, extra, {key: prob}, None, None)
    assert [x.tag for x in extra[key]] == [("resonance", "x"), al.LEAKAGE]
    assert [x.tag for x in kept[key]] == [al.ABSORPTION, ("resonance", "x")]


def test_the_absorption_stage_carries_what_was_refitted_beside_the_leakage():
    da = {"effect": "dielectric_absorption", "channel": "charge", "parameters": {"gain": 5.8e-6, "tau_s": 2.0}}
    lk = {"effect": "leakage", "channel": "charge", "parameters": {"gain_per_s": 2.9e-7},
          "_cand": {"refit": {"tau_s": 1.23}}, "_gains": np.array([2.9e-7, 3.6e-6])}
    al.refitted_absorption_stage([da, lk])
    assert da["parameters"] == {"gain": 3.6e-6, "tau_s": 1.23}
    assert "alone 2 s" in da["refitted"]



def test_the_core_fit_takes_each_stage_from_the_last_joint_fit_with_a_replaced_absorption():
    """tracing._core_fit (the plant file's fitted model): with the leakage refitting the found
    absorption in its place, the last joint fit's columns are the leakage's, the refitted
    absorption's and any later stage's; the replaced absorption has none of its own there (its
    parameters are the refit's). Counted as its own column, the leakage took the absorption's
    gain, the third stage the leakage's, and a one-column third stage found none left (a crash)."""
    from types import SimpleNamespace

    from workbench.calibrate import tracing
    from workbench.calibrate.effects import DielectricAbsorption, Leakage

    class Third:
        columns = None

        @staticmethod
        def with_gains(p, gains):
            return {**p, "gain": float(gains[0])}

    def cand(eff, n, **kw):
        return {"eff": eff, "params": {}, "g": {"ok": np.ones(n, bool)}, **kw}

    da_refit = {"gain": 3.6e-6, "tau_s": 1.23}
    joint = np.array([2.9e-7, 3.6e-6, 7.0e-9])          # leakage, the refitted absorption, the third stage
    same = [{"effect": "dielectric_absorption", "channel": "charge", "parameters": da_refit,
             "_cand": cand(DielectricAbsorption(), 1)},
            {"effect": "leakage", "channel": "charge", "parameters": {"gain_per_s": 2.8e-7},
             "_cand": cand(Leakage(), 2, replaces=al.ABSORPTION)},
            {"effect": "third", "channel": "charge", "parameters": {"gain": 6.0e-9}, "_cand": cand(Third(), 1),
             "_base_weights": np.r_[1.0, 2.0, 0.5], "_joint_gains": joint}]
    base = SimpleNamespace(channels={"charge": SimpleNamespace(thresholds_v=np.zeros(2),
                                                               initial_states_v=np.zeros(2))})
    cf = tracing._core_fit(same, base)
    got = {s["effect"]: s["parameters"] for s in cf["stages"]}
    assert got["dielectric_absorption"] == da_refit
    assert got["leakage"]["gain_per_s"] == joint[0] and got["third"]["gain"] == joint[2]
    assert list(cf["weights"]) == [1.0, 2.0]      # (the offset: not carried, s13_rtfix)

PAIR = ("leakage", "dielectric_absorption")
#: make test: default_rng(1313)'s first 14 draws (sizes 0.03-13x, every rate and protocol; the separable pairs
#: named with both, 1 kHz sine 4.6x and 1 kHz steps 13x, and the strict xfail's 10 kHz sine 2.5x among them);
#: WORKBENCH_FULL=1 the first 40 (session 16's make test ran 20: draws 14-19 add 1 and 100 kHz, 0.3-22x)
N_PAIR_DRAWS = 14 if not FULL else 40
#: session 23: make test traces 5 of the 14 (10 kHz calibration 3.1x, 100 kHz sine 7.8x, and the three separable
#: pairs: 1 kHz sine 4.6x and 1 kHz steps 13x named with both, the strict xfail's 10 kHz sine 2.5x); session 22's
#: make test traced all 14
PAIR_REDUCED = (1, 7, 10, 11, 13)


def _pair_trace(sn637, effect, rate, proto, size, seed):
    """One benchmark record traced as ``workbench calibrate`` does; (result, truth, T, own sizes)."""
    from workbench.calibrate.tracing import trace_effect
    cc = load_benchmark("calibrate_confusion")
    t, sp, base, plant, truth, r = cc.simulated_base(sn637, effect, rate, proto, size, seed)
    res = trace_effect(base, split=sp)
    effects = (effect,) if isinstance(effect, str) else effect
    own = cc.own_sizes(sn637, effects, rate, proto, size, seed, sp=sp)
    return res, truth, float(t[-1] - t[0]), own


@pytest.fixture(scope="module")
def drawn_pairs(sn637):
    """Leakage + absorption records: rate (1, 10, 100 kHz) and protocol drawn, the size
    log-uniform over the benchmark's whole 0.03-30x, the absorption's tau and gain and the
    leakage's resistance from ``EFFECT_RANGES`` (tau 0.5-5 s); ``default_rng(1313)`` fixed before
    any record was traced."""
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(1313)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    rows = []
    for k in range(N_PAIR_DRAWS):
        rate = float(rng.choice(cc.RATES_HZ))
        proto = str(rng.choice(("calibration", "sine", "steps")))
        size = float(np.exp(rng.uniform(lo, hi)))
        seed = int(rng.integers(1 << 30))
        if not FULL and k not in PAIR_REDUCED:
            continue
        res, truth, T, own = _pair_trace(sn637, PAIR, rate, proto, size, seed)
        st = {s["effect"]: s["parameters"] for s in res["stages"]}
        print(f"\n{rate:7.0f} {proto:11s} x{size:7.3f} tau/T {truth['time_constant_s'] / T:6.2f} own {np.round(own, 2)}"
              f" -> {list(st)} {res['fold_winners']}")
        rows.append({"res": res, "truth": truth, "T": T, "own": own, "named": list(st), "params": st})
    return rows


def test_drawn_pairs_name_nothing_the_record_lacks(drawn_pairs):
    assert not [r["named"] for r in drawn_pairs if set(r["named"]) - set(PAIR)]


def _separable(rows):
    """The pairs whose two effects each stand >= 3x above the floor and whose absorption settles
    within half the record (its shape a line cannot give)."""
    return [r for r in rows if min(r["own"]) >= 3.0 and r["truth"]["time_constant_s"] < al.SETTLED_RECORDS * r["T"]]


def test_pairs_answered_with_both_recover_the_drawn_truth(drawn_pairs):
    """Where both are named, the absorption's refitted tau and k and the leakage's R are the drawn
    ones to 10 % (seed 24 #10 of the confusion benchmark: 0.5 %, 0.4 %, 0.05 %), and the draws
    reach such records among the separable ones."""
    both = [r for r in drawn_pairs if set(r["named"]) == set(PAIR)]
    assert [r for r in both if r in _separable(drawn_pairs)], "the draws reach no separable pair named with both"
    for r in both:
        p, tr = r["params"], r["truth"]
        assert p["dielectric_absorption"]["tau_s"] == pytest.approx(tr["time_constant_s"], rel=0.1)
        assert p["dielectric_absorption"]["gain"] == pytest.approx(tr["gain_f"], rel=0.1)
        assert 1.0 / p["leakage"]["gain_per_s"] == pytest.approx(tr["resistance_ohm"], rel=0.1)


@pytest.mark.xfail(strict=True, reason="measured 3 of 4 separable pairs of default_rng(1313)'s 20 draws named with "
                   "both: a 10 kHz sine record (leakage 3.1x, absorption 10.7x, tau 0.34 T) is answered with the "
                   "absorption alone (the joint model leaves 0-10 % less than the absorption alone on the folds, "
                   "under min_share: README, session 13)")
def test_drawn_pairs_whose_absorption_settles_are_answered_with_both(drawn_pairs):
    """A leakage and an absorption that settles within half the record, both >= 3x above the
    floor: both named (issue 13 item 5)."""
    sep = _separable(drawn_pairs)
    assert sep
    missed = [(r["own"], r["named"]) for r in sep if set(r["named"]) != set(PAIR)]
    assert not missed, missed


@pytest.mark.parametrize("effect", ["dielectric_absorption", "leakage"])
def test_a_single_charge_effect_never_gets_the_other_named_beside_it(sn637, effect):
    """Absorption records (tau 0.5-5 s from ``EFFECT_RANGES``) and leakage records, rate and
    protocol drawn, sizes over the whole 0.03-30x (``default_rng(1314)``/``(1315)`` fixed before any
    run): no stage names the other of the two (nor anything else). The absorption draws' fourth
    (1 kHz steps, 702x, tau 1.098 s) was named absorption + leakage while the absorption's search
    stopped short of its tau (1.060 s: the forward difference in the projected column's rounding,
    ``test_effects.py::test_the_absorption_search_ends_at_a_minimum_of_its_own_cost``)."""
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(1314 if effect == "leakage" else 1315)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    out = []
    for _ in range(3 if not FULL else 18):          # make test: the first 3 (session 22: 6)
        rate = float(rng.choice(cc.RATES_HZ))
        proto = str(rng.choice(("calibration", "sine", "steps")))
        r = cc.evaluate(sn637, effect, rate, proto, float(np.exp(rng.uniform(lo, hi))), int(rng.integers(1 << 30)),
                        diagnostics=False)
        print(f"\n{effect} {rate:7.0f} {proto:11s} x{r['size']:7.3f} excess {r['excess']:7.2f} -> {r['named']}")
        out.append(r)
    assert not [(r["rate_hz"], r["protocol"], r["size"], r["named"]) for r in out if r["class"] == "wrong"]
    assert any(r["named"] for r in out)        # the draws reach named records


# ---- records shorter than the relaxation (session 15, branch s15_ends)

def _slow_draws(n, seed, tau_lo, tau_hi):
    """``n`` absorption records: protocols cycled, sizes log-uniform over the benchmark's whole range,
    the time constant log-uniform over ``[tau_lo, tau_hi]`` record lengths."""
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(seed)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    return [(("calibration", "sine", "steps")[k % 3], float(np.exp(rng.uniform(lo, hi))),
             float(np.exp(rng.uniform(np.log(tau_lo), np.log(tau_hi)))), int(rng.integers(1 << 30)))
            for k in range(n)]


@pytest.fixture(scope="module")
def slow_absorptions(sn637):
    """Absorptions relaxing over 5-50 record lengths (the 0.5-5 s of seed 002 on a 0.1 s 1 MHz
    record) on 2 s 10 kHz records, sizes over the benchmark's whole range (``default_rng(1515)``,
    fixed before any run): ``(size, tau over the record, result, names)``."""
    rows = []
    # make test traces 5 of the 16 (session 30; session 23's 6, session 22's all 16): two of the three the strict
    # xfail below measured named leakage (25 and 6.9 record lengths), two answered inconclusive undecided (the rule
    # the test asks of), one none (tau 42 records, the slowest); session 30 left draw 12 (calibration 0.70x, tau 21
    # records, none) to WORKBENCH_FULL=1: inside the kept draws on every axis (0.57-8.7x, tau 6.9-42 records, two
    # calibration records kept)
    draws = _slow_draws(16, 1515, 5.0, 50.0)
    for proto, size, tau_records, s in (draws if FULL else [draws[k] for k in (1, 2, 3, 9, 13)]):
        res, T = _trace(sn637, "dielectric_absorption", proto, size, tau_records, s)
        names = [st["effect"] for st in res["stages"]]
        print(f"\n{proto:11s} x{size:7.3f} tau/T {tau_records:5.1f} -> {res['effect']} {names} {res['fold_winners']}")
        rows.append((size, tau_records, res, names))
    return rows


def test_slow_absorptions_name_nothing_else_and_an_undecided_record_says_it_is_too_short(slow_absorptions):
    """Over the record the charge is leakage's ramp: nothing but the absorption or leakage is
    named, and an inconclusive answer whose folds were undecided between the two carries both as
    open and the note that the record is too short (with the length it would need). On main
    (dc1b914) such an answer had no note."""
    rows = slow_absorptions
    wrong = [(size, tau, names) for size, tau, _, names in rows
             if set(names) - {"dielectric_absorption", "leakage"}]
    assert not wrong, wrong
    undecided = [res for *_, res, _ in rows if res["effect"] == "inconclusive"
                 and "undecided: dielectric_absorption or leakage" in res["fold_winners"]]
    assert len(undecided) >= 2          # the draw reaches the rule
    for res in undecided:
        assert res.get("open") == ["dielectric_absorption", "leakage"], res["reason"]
        assert "too short to tell a dielectric absorption from leakage" in res["note"]
        assert "too short" in res["reason"]


@pytest.mark.xfail(strict=True, reason="measured (s15_ends): 3 of the 16 draws (6.9, 25 and 28 record lengths, "
                                       "x3-21) are named leakage, as on main: the absorption's search ran to its "
                                       "ceiling and the record-length absorption is ruled out, the same evidence "
                                       "as the leakages named at 1 and 10 kHz (seed 41 #15, #26, #48)")
def test_an_absorption_slower_than_the_record_is_never_named_leakage(slow_absorptions):
    """The brief's floor for records shorter than the relaxation: never leakage."""
    named = [(round(size, 2), round(tau, 1)) for size, tau, _, names in slow_absorptions if "leakage" in names]
    assert not named, named


def test_the_too_short_note_says_the_record_the_fitted_time_constant_needs():
    """The note's length is the one the fitted absorption settles within half of (step 1's line);
    at the ceiling (leakage's limit) no length is said; none within the record or without an undecided fold."""
    T = 0.1
    lk, da, befores = _rows(3.2, 10.0, 10.0, 50.0)
    by = {L: lk, D: da}
    note = al.too_short_note(by, [U, L, U, U, U], T)
    assert "fitted time constant, 3.2 s, is 32 lengths of this 0.1 s record" in note
    assert f"a record of about {3.2 / al.SETTLED_RECORDS:.3g} s" in note
    assert al.too_short_note(by, [L] * 5, T) is None
    da["params"]["tau_s"] = CEILING * T
    assert "ran to its ceiling, 10 s (100 lengths" in al.too_short_note(by, [U] * 5, T)
    da["params"]["tau_s"] = 0.4 * T
    assert al.too_short_note(by, [U] * 5, T) is None


# the confusion benchmark's two slow absorptions named leakage by session 14's final code (dc1b914):
# seed 45 #69 (100 kHz, 0.4 s, truth tau 3.2 records, fitted 52: leakage 5 of 5) and seed 31 #135
# (1 MHz, 0.1 s, truth tau 12.4 records, fitted 11.1: leakage 4 of 5)
SLOW_ABSORPTIONS = [("dielectric_absorption", 1e5, "calibration", 17.456045423751334, 802597311),
                    ("dielectric_absorption", 1e6, "calibration", 29.808332061368976, 448431204)]


@pytest.mark.parametrize("case", SLOW_ABSORPTIONS, ids=["45-69", "31-135"])
def test_the_benchmarks_slow_absorptions_are_inconclusive_with_the_note(sn637, case):
    cc = load_benchmark("calibrate_confusion")
    r = cc.evaluate(sn637, *case, diagnostics=False)
    res_names = r["named"]
    assert "leakage" not in res_names and r["class"] != "wrong", (r["answer"], r["fold_winners"])
    assert r["answer"] in ("inconclusive", "dielectric_absorption"), r["answer"]
