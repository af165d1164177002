"""Staged tracing (workbench/calibrate/stages.py; issue 13 item 5): two-effect records, exclusions,
the joint re-search's projection, JSON ``stages``."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tests.conftest import FULL, FULL_ONLY, load_benchmark
from workbench.calibrate import stages
from workbench.calibrate.stages import excluded

ROOT = Path(__file__).resolve().parents[2]


def _bench():
    return load_benchmark("calibrate_confusion")


@pytest.mark.parametrize("found, cand, out", [
    # the bow is eq. 27's reading of x: the gauge model's leftover after it is the bow's
    ([("gauge_nonlinearity", "gauge")], ("creep", "gauge"), True),
    ([("gauge_nonlinearity", "gauge")], ("delay", "gauge"), True),
    ([("gauge_nonlinearity", "gauge")], ("creep", "displacement"), False),
    # creep's relaxation is in the charge too (it moves the stack); a slow branch and a slow
    # polynomial are one trend
    ([("creep", "displacement")], ("dielectric_absorption", "charge"), True),
    ([("creep", "displacement")], ("leakage", "charge"), True),
    ([("creep", "displacement")], ("drift", "displacement"), True),
    ([("creep", "displacement")], ("delay", "displacement"), False),
    # below the mode its phase lag is a delay, and the reverse, on one channel only
    ([("delay", "displacement")], ("resonance", "displacement"), True),
    ([("resonance", "displacement")], ("delay", "displacement"), True),
    # the stack's mode found on the gauge is carried into the displacement's model (session 16, s16_drift):
    # no displacement delay after it (drawn drift + mode records at 100 kHz named a wrong delay 5 of 5)
    ([("resonance", "gauge")], ("delay", "displacement"), True),
    ([("resonance", "gauge")], ("delay", "charge"), True),
    # the stack's mode is in the gauge's model too: no gauge delay after it (seed 14 #99)
    ([("resonance", "displacement")], ("delay", "gauge"), True),
    # the stack's creep or mode is in the gauge's model once found on the displacement
    ([("resonance", "displacement")], ("resonance", "gauge"), True),
    ([("creep", "displacement")], ("creep", "gauge"), True),
    # and, symmetric, the gauge's once found there (one motion: 28 #88 named the mode twice)
    ([("resonance", "gauge")], ("resonance", "displacement"), True),
    ([("creep", "gauge")], ("creep", "displacement"), True),
    # the pairs stay possible in both orders
    ([("leakage", "charge")], ("dielectric_absorption", "charge"), False),
    ([("dielectric_absorption", "charge")], ("leakage", "charge"), False),
    ([("drift", "displacement")], ("resonance", "displacement"), False),
    ([("resonance", "displacement")], ("drift", "displacement"), False),
    ([("delay", "displacement")], ("creep", "displacement"), False),
])
def test_exclusions(found, cand, out):
    assert excluded(cand, found) is out


def test_joint_projection_removes_base_and_found_columns():
    """The joint re-search's projection leaves nothing of the base's or a found effect's columns
    and keeps what is orthogonal to both (an idempotent orthogonal projector)."""
    from workbench.calibrate.stages import _joint_projection
    rng = np.random.default_rng(int(np.random.SeedSequence().entropy % (1 << 31)) if FULL else 3)
    n, k, m = 400, int(rng.integers(2, 30)), int(rng.integers(1, 6))
    search = rng.random(n) < 0.5
    A = rng.normal(size=(n, k)) * 10.0 ** rng.uniform(-6, 6, k)
    F = rng.normal(size=(n, m)) * 10.0 ** rng.uniform(-9, 3, m)
    prob = SimpleNamespace(As=A[search], search=search, project=None)
    P = _joint_projection(prob, [(F, [0.0] * m)])
    X = rng.normal(size=(int(search.sum()), 3))
    PX = P(X)
    E = np.column_stack([A[search], F[search]])
    Q, _ = np.linalg.qr(E / np.linalg.norm(E, axis=0))
    assert np.abs(Q.T @ PX).max() < 1e-8 * np.abs(X).max()
    assert np.allclose(P(PX), PX, atol=1e-10 * np.abs(X).max())
    R = X - Q @ (Q.T @ X)                      # the part orthogonal to both is kept whole
    assert np.allclose(PX, R, atol=1e-8 * np.abs(X).max())


PAIRS_DRAWN = 2 if not FULL else 4
#: make test traces the first of each pair's two draws (creep + delay 3.2x, leakage + absorption 29x, drift +
#: resonance 0.36x: each effect >= 3x on its own record, and the leakage + absorption the xfail's miss);
#: WORKBENCH_FULL=1 all four of each pair's draws (session 16's make test traced both of the two)
PAIRS_RUN = 1 if not FULL else PAIRS_DRAWN


@pytest.fixture(scope="module")
def pair_rows(sn637):
    """Two-effect records (creep + delay, leakage + absorption, drift + resonance), sizes drawn
    log-uniform over the benchmark's 0.03x-30x, protocols drawn, 2 s at 10 kHz; each effect's
    own size measured on the record simulated with it alone (same draw, same noise)."""
    cc = _bench()
    rng = np.random.default_rng(2024)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    rows = []
    for pair in cc.PAIRS:
        for k in range(PAIRS_DRAWN):
            size = float(np.exp(rng.uniform(lo, hi)))
            proto = str(rng.choice(("calibration", "sine", "steps")))
            seed = int(rng.integers(1 << 30))
            if k >= PAIRS_RUN:
                continue
            r = cc.evaluate(sn637, pair, 1e4, proto, size, seed, n_rows=cc.QUICK_ROWS, diagnostics=False)
            print(f"\n{r['effect']:30s} {proto:11s} size x{size:.3g} own sizes {np.round(r['excesses'], 2)} "
                  f"-> stages {r['named']} {r['class']} both {r['both']}")
            rows.append(r)
    return rows


def test_two_effect_records_name_no_wrong_effect(pair_rows):
    """No effect the record lacks is named at any stage (the issue's <= 2 %: none of these three; twelve in
    the full form),
    and the draw reaches records whose two effects both stand >= 3x above the floor."""
    rows = pair_rows
    assert not [r for r in rows if r["class"] == "wrong"], [(r["effect"], r["named"]) for r in rows]
    assert any(min(r["excesses"]) >= 3.0 for r in rows)


@pytest.mark.xfail(strict=True, reason="issue 13 item 5 not met: of the drawn two-effect records with both "
                   "effects >= 3x the floor, fewer than all are answered with both (README, Calibration)")
def test_two_effect_records_are_answered_with_both(pair_rows):
    """The issue's target: a record with two effects, both >= 3x above the floor, is answered
    with both (``stages``)."""
    big = [r for r in pair_rows if min(r["excesses"]) >= 3.0]
    both = [r for r in big if r["both"]]
    print(f"\nboth named: {len(both)} of {len(big)} records with both >= 3x; "
          f"{sum(r['both'] for r in pair_rows)} of {len(pair_rows)} in all")
    assert len(both) == len(big), [(r["effect"], np.round(r["excesses"], 1), r["named"]) for r in big]


def _calibrate_json(sn637, tmp_path, pair, size, seed):
    """``workbench calibrate --json`` on a drawn two-effect record (1 kHz steps, 10 s); (JSON, truth)."""
    from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record, write_record
    from workbench.cli import main
    t, v = benchmark_protocol("steps", 1e3, 10_000)
    plant, truth = plant_with_effect(sn637, pair, seed, duration_s=float(t[-1]), size=size)
    data = write_record(tmp_path / "rec.csv", simulate_record(plant, t, v, seed=seed), {"serial": "SN637"})
    assert main(["calibrate", str(data), "--plant", str(ROOT / "plants" / "p888_51_sn637.toml"),
                 "--json", str(tmp_path / "r.json")]) == 0
    return json.loads((tmp_path / "r.json").read_text()), truth


# The first two draws of np.random.default_rng(13) (the rule is test_json_draws_are_the_first_two;
# the draw seed chosen before any record was traced): pair from the benchmark's PAIRS, size
# log-uniform over its full SIZE_RANGE (0.03-30x), record seed; 1 kHz steps, 10 s, pinned literally.
# Both name their two effects. Of draws 2-11 (measured 2026-11-26), the two creep + delay records
# at 6.4x and 20.7x name creep only (creep wins every first-stage fold; the delay does not pass
# every later fold): a miss, counted by test_two_effect_records_are_answered_with_both's xfail.
JSON_DRAWS = [(("drift", "resonance"), 11.041518374660312, 928569338),
              (("creep", "delay"), 0.18258300013731726, 870829743)]


def test_json_draws_are_the_first_two():
    """The pinned records are the first two draws of the rule above, not picked sizes."""
    cc = _bench()
    rng = np.random.default_rng(13)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    for pair, size, seed in JSON_DRAWS:
        assert cc.PAIRS[int(rng.integers(len(cc.PAIRS)))] == pair
        assert float(np.exp(rng.uniform(lo, hi))) == size and int(rng.integers(1 << 30)) == seed


# With the record's current integrated as it was simulated (``# current: averaged``, s11_qconv) the creep+delay
# draw named creep only: stage 1 is creep on every fold, so the delay, not "seen" in stage 1, needs every later
# fold (run_stages) and won 4 of 5 (a strict xfail). With the delay's weights refitted on each fold's training
# rows (s11_delayfold, issue 13 finding 1) it wins 5 of 5 and both are named: the mark is gone.
# s17_creep's V_h-driven creep lost the creep + delay draw (1 kHz steps, creep 11.9x, delay 5.9x on their own records):
# creep alone (a strict xfail, JSON_CD_MISS). Session 18: both are named again (5 of 5, then the delay 5 of 5: test
# RMS 1.753e-8 -> 6.917e-9 -> 3.787e-9 m) and the mark is gone. s18_creepdelay2 credited its V_h-driven joint
# candidate (creep_beside_delay._branch_drive); its review found the lead's back-off fix of creep_drive (1595499)
# alone names both here too: this test guards the drive, the joint's drive is guarded by test_creep_beside_delay.


@pytest.mark.parametrize("pair, size, seed", [JSON_DRAWS[0], JSON_DRAWS[1]], ids=["drift+resonance", "creep+delay"])
def test_json_stages_of_a_two_effect_record(sn637, tmp_path, pair, size, seed):
    """``workbench calibrate`` on a drawn two-effect record: the JSON's ``stages`` lists both,
    each with its channel, parameters, agreement and test errors; ``effect`` is the first stage;
    each stage lowers what the earlier ones left on its channel, and starts from exactly that (the
    last earlier stage's ``error_after`` on the channel, else the base fit's test error)."""
    res, truth = _calibrate_json(sn637, tmp_path, pair, size, seed)
    st = res["stages"]
    assert {s["effect"] for s in st} == set(pair), (st, res["stage_notes"])
    assert res["effect"] == st[0]["effect"] and res["channel"] == st[0]["channel"]
    chans = res["base_fit"]["channels"]
    for k, s in enumerate(st):
        units = chans[s["channel"]]["units"]
        assert set(s["error_after"]) == {"rms", "max", "units"} and s["error_after"]["units"] == units
        assert s["error_before"]["units"] == units
        assert s["error_after"]["rms"] < s["error_before"]["rms"]
        assert s["agreement"].endswith("of 5") and int(s["agreement"].split()[0]) >= 4 or "resolved" in s
        assert isinstance(s["parameters"], dict) and s["parameters"]
        earlier = [e for e in st[:k] if e["channel"] == s["channel"]]
        start = earlier[-1]["error_after"]["rms"] if earlier else chans[s["channel"]]["rms"]
        assert s["error_before"]["rms"] == pytest.approx(start, rel=1e-9)
    # the tracing model's own error after: after every effect found on the first effect's channel (each
    # stage starts from the last), so at most the first stage's alone
    on_first = [s for s in st if s["channel"] == res["channel"]]
    assert res["error_before"] == st[0]["error_before"]
    assert res["error_after_model"] == on_first[-1]["error_after"] == chans[res["channel"]]["error_after"]
    assert res["error_after_model"]["rms"] <= st[0]["error_after"]["rms"]
    # the reported one is what the user gets (session 15): the updated plant file's replay when one was replayed
    assert res["error_after"] == (res["updated_plant_error"] if res["error_after_source"] == "updated plant"
                                  else res["error_after_model"])
    by = {s["effect"]: s["parameters"] for s in st}
    if "resonance" in by:
        # within the record's frequency resolution, 1 / T (10 s)
        assert abs(by["resonance"]["f_n_hz"] - truth["freq_hz"]) < 1.0 / 10.0
    if "delay" in by:
        # within one sample (1 ms at 1 kHz): this draw's delay is under a sample
        assert abs(by["delay"]["delay_s"] - truth["delay_s"]) < 1e-3


# a regression record: WORKBENCH_FULL=1 only (session 31, s31_suite); make test's record of its family and kind is
# test_json_stages_of_a_two_effect_record[creep+delay] (creep + delay, 1 kHz steps, ``workbench calibrate --json``:
# both named, the delay within a sample)
@FULL_ONLY
def test_creep_and_an_8ms_delay_are_both_named_in_the_json(sn637, tmp_path):
    """The record with creep and a long sensor delay (8.4 ms, 5x, steps at 1 kHz): both are in the
    JSON's ``stages``, the delay within 30 %. After the plant kernel's KCL fix the folds split
    3 creep / 2 delay, and with creep in the model the delay wins 4 of 5 re-scored folds but left
    5 % more than creep alone on the fifth; the rival (a second creep, changing what creep leaves
    by 1e-6) then refused it for that fold (a strict xfail). A rival counts only on the folds it
    explains (stages._beats_rivals), and both are named again. (The JSON's structure is checked
    on drawn records: test_json_stages_of_a_two_effect_record.)"""
    res, truth = _calibrate_json(sn637, tmp_path, ("creep", "delay"), 5.0, 508431090)
    st = res["stages"]
    assert {s["effect"] for s in st} == {"creep", "delay"}, (st, res["stage_notes"])
    d = next(s for s in st if s["effect"] == "delay")["parameters"]
    assert d["delay_s"] == pytest.approx(truth["delay_s"], rel=0.3)


@pytest.mark.parametrize("gauge_passes, both", [([True] * 5, True), ([True] * 4 + [False], True),
                                               ([True] * 3 + [False] * 2, False)])
def test_a_gauge_mode_renamed_to_the_displacements_survives_on_its_own_passes(monkeypatch, gauge_passes, both):
    """A displacement drift and the gauge's mode split the folds 3:2. With the drift in the model,
    the fold decision names the mode the displacement's (the gauge reads the same motion), so the
    later stage's answer is ("resonance", "displacement"): the gauge's mode survives when its own
    row passes ``need`` (4 of 5) folds, and the note then says both are in the record; on 3 passes
    the drift alone explains what the mode cannot (review 4 bug 1)."""
    from workbench.calibrate import tracing
    d, m = ("drift", "displacement"), ("resonance", "gauge")
    res = {"winners": [d, d, d, m, m], "by": {d: {"score": 0.3}, m: {"score": 0.4}}}
    monkeypatch.setattr(tracing, "_absorb", lambda *args, **kw: None)

    def later(ctx, ex, found, seen=()):
        if found[-1] == d:      # the drift in the model: the mode is found, renamed to the displacement
            return ("resonance", "displacement"), 5, [], {"by": {m: {"passes": gauge_passes}}}, None
        return d, 5, [], {"by": {d: {"passes": [True] * 5}}}, None

    monkeypatch.setattr(stages, "_later_stage", later)
    answer, count, note = stages.resolve_split(res, {"need": 4, "probs": {}, "base": None, "t": None}, {}, [])
    assert answer == d and count == 3
    assert ("both are in the record" in note) == both, note


@pytest.mark.parametrize("promote", [True, False])
def test_after_creep_behind_promotion_creep_not_the_relaxation_has_the_lower_bar(monkeypatch, promote):
    """Absorption on the charge wins 4 of 5 first-stage folds, a delay the fifth. When the
    creep-behind rule promotes the delay (the absorption is creep's own charge), the next stage's
    lower bar (``need`` folds, for an effect that won a first-stage fold) goes to the displacement's
    creep, not to the absorption it just ruled out (review 4 bug 5); without a promotion the
    first stage's fold winners keep it."""
    from workbench.calibrate import tracing
    a, dl = ("dielectric_absorption", "charge"), ("delay", "displacement")
    res = {"winners": [a, a, a, a, dl], "by": {a: {"score": 0.3}, dl: {"score": 0.2}}}
    monkeypatch.setattr(tracing, "_score_stage", lambda *args, **kw: res)
    monkeypatch.setattr(tracing, "_absorb", lambda *args, **kw: None)
    monkeypatch.setattr(stages, "_creep_behind_a_displacement_effect",
                        lambda answer, count, note, *args, **kw: (dl, 1, "promoted") if promote else (answer, count, note))
    monkeypatch.setattr(stages, "_stage_entry", lambda c, count, ctx, extra, resolved=None: {"count": count})
    got = {}

    def later(ctx, extra, found, seen=()):
        got["seen"] = seen
        return None, 0, [], {"by": {}}, None

    monkeypatch.setattr(stages, "_later_stage", later)
    ctx = {k: None for k in ("cands", "nulls", "split", "penalty", "noise_factor", "infos", "min_share",
                             "base", "t")}
    ctx.update(probs={}, need=4)
    first, st, notes = stages.run_stages(ctx)
    assert first["answer"] == (dl if promote else a)
    assert (a in got["seen"]) != promote and (("creep", "displacement") in got["seen"]) == promote


@pytest.mark.parametrize("creep_folds, outcome", [(0, "stands"), (1, "inconclusive"), (2, "inconclusive"),
                                                  (3, "promoted"), (5, "promoted")])
def test_creep_behind_a_displacement_effect_each_branch(monkeypatch, creep_folds, outcome):
    """The three branches of stages._creep_behind_a_displacement_effect (review of the KCL fix,
    item 3): an absorption won the charge's folds while a delay passes 4 of 5 displacement folds.
    With the delay in the model the folds are re-scored; the displacement's creep then wins
    ``creep_folds`` of 5 (one of them as an ``undecided`` fold that includes creep, which counts).
    At least half (3 of 5): the absorption is creep's charge and the delay is named first; some
    fold but fewer than half: the record cannot tell, ``None`` (inconclusive); no fold: the
    absorption stands. Deleting or inverting either test of creep_folds changes an outcome here."""
    from workbench.calibrate import tracing
    tag, charge, creep = ("delay", "displacement"), ("dielectric_absorption", "charge"), ("creep", "displacement")
    d = {"name": "delay", "channel": "displacement", "passes": [True, True, True, True, False], "score": 0.5}
    res = {"rows": [d], "winners": [charge, charge, charge, charge, tag]}
    won = [creep] * creep_folds
    if creep_folds >= 2:      # an undecided fold between creep and another effect counts for creep
        won[-1] = ("undecided", "delay or creep")
    rescored = {"winners": won + ["none"] * (5 - creep_folds)}
    monkeypatch.setattr(tracing, "_absorb", lambda *a, **k: None)
    monkeypatch.setattr(stages, "_later_candidates", lambda *a, **k: [])
    monkeypatch.setattr(tracing, "_score_stage", lambda *a, **k: rescored)
    ctx = {"probs": {}, "split": SimpleNamespace(folds=[0] * 5), "need": 4, "base": None, "t": None,
           "cands": [], "nulls": [], "penalty": 0.02, "noise_factor": 1.0, "infos": {}, "min_share": 0.0}
    answer, count, note = stages._creep_behind_a_displacement_effect(charge, 4, "kept", res, ctx, {}, [])
    if outcome == "promoted":
        assert answer == tag and count == 1 and f"creep wins {creep_folds} of 5" in note
    elif outcome == "inconclusive":
        assert answer is None and count == 4 and note is None
    else:
        assert (answer, count, note) == (charge, 4, "kept")


@pytest.mark.parametrize("decided_creep", [0, 1])
def test_creep_behind_asked_of_undecided_folds_needs_a_decided_creep_fold(monkeypatch, decided_creep):
    """stages._creep_behind_a_displacement_effect with ``decided`` (asked when no first-stage fold
    was decided for the relaxation; review of s19_creepdelay, finding 2): with the delay in the model
    the re-scored folds are undecided between creep and another effect on 4 of 5, decided for creep
    on ``decided_creep``. Without a fold decided for creep the answer stands (no promotion on
    undecided folds alone); with one, the delay is promoted and ``info`` gets the folds it passes."""
    from workbench.calibrate import tracing
    tag, charge = ("delay", "displacement"), ("dielectric_absorption", "charge")
    d = {"name": "delay", "channel": "displacement", "passes": [True] * 5, "score": 0.5}
    und = ("undecided", "dielectric_absorption or creep")
    res = {"rows": [d], "winners": [und, und, und, und, charge]}
    won = [("creep", "displacement")] * decided_creep + [("undecided", "delay or creep")] * (4 - decided_creep)
    monkeypatch.setattr(tracing, "_absorb", lambda *a, **k: None)
    monkeypatch.setattr(stages, "_later_candidates", lambda *a, **k: [])
    monkeypatch.setattr(tracing, "_score_stage", lambda *a, **k: {"winners": won + ["none"]})
    ctx = {"probs": {}, "split": SimpleNamespace(folds=[0] * 5), "need": 4, "base": None, "t": None,
           "cands": [], "nulls": [], "penalty": 0.02, "noise_factor": 1.0, "infos": {}, "min_share": 0.0}
    info = {}
    got = stages._creep_behind_a_displacement_effect(charge, 0, None, res, ctx, {}, [], decided=True, info=info)
    if decided_creep:
        assert got[0] == tag and got[1] == 0 and info == {"passes": 5}
    else:
        assert got == (charge, 0, None) and info == {}
    # without ``decided`` (a named relaxation) undecided folds count for creep, as before
    assert stages._creep_behind_a_displacement_effect(charge, 0, None, res, ctx, {}, [])[0] == tag


def test_creep_behind_rule_is_skipped_once_creep_is_found_or_no_displacement_effect_passes(monkeypatch):
    """The rule's guards: with the displacement's creep already found, or no displacement effect
    passing ``need`` folds, the answer stands and nothing is re-scored."""
    from workbench.calibrate import tracing
    charge = ("dielectric_absorption", "charge")
    monkeypatch.setattr(tracing, "_score_stage", lambda *a, **k: pytest.fail("re-scored"))
    ctx = {"probs": {}, "split": SimpleNamespace(folds=[0] * 5), "need": 4, "base": None, "t": None}
    d = {"name": "delay", "channel": "displacement", "passes": [True] * 4 + [False], "score": 0.5}
    res = {"rows": [d], "winners": [charge] * 5}
    assert stages._creep_behind_a_displacement_effect(charge, 5, "n", res, ctx, {}, [("creep", "displacement")]) \
        == (charge, 5, "n")
    d3 = {**d, "passes": [True] * 3 + [False] * 2}
    assert stages._creep_behind_a_displacement_effect(charge, 5, "n", {**res, "rows": [d3]}, ctx, {}, []) \
        == (charge, 5, "n")


@pytest.mark.parametrize("rival_rms, beaten", [
    # the rival (a second creep) changes what creep leaves by 1e-6 on every fold: it explains no fold,
    # and the candidate, worse than creep alone on fold 2 only, is not refused for it
    ([1.0 - 1e-6, 1.0 - 1e-6, 1.0 - 1e-6, 1.0 - 1e-6, 1.0 - 1e-6], True),
    # the rival explains fold 2 (half of what creep leaves there): the candidate, worse there, is refused
    ([1.0, 0.5, 1.0, 1.0, 1.0], False),
    # the rival explains folds 1 and 3 but leaves more than the candidate on both: not refused
    ([0.5, 1.0, 0.5, 1.0, 1.0], True),
])
def test_a_rival_counts_on_the_folds_it_explains(monkeypatch, rival_rms, beaten):
    """stages._beats_rivals: the candidate must leave less than the rival on every fold where the
    rival passes the stage's own fold test against the found effects alone (here: removes more
    than the noise floor's power); folds the rival does not explain are left to the candidate's
    own test. Found effects alone leave 1 on every fold, the candidate 0.3, and 1.05 on fold 2."""
    from workbench.calibrate import tracing
    table = {"cand": [0.3, 1.05, 0.3, 0.3, 0.3], "rival": rival_rms}
    monkeypatch.setattr(tracing, "_stacked", lambda prob, extra, row: row["name"])
    prob = SimpleNamespace(fold_rms=lambda g, tr, va: table[g][tr])
    split = SimpleNamespace(folds=[(f, f) for f in range(5)])
    res = {"befores": {"k": [1.0] * 5}, "null_gain": {"k": [0.0] * 5}}
    ctx = {"noise_factor": 1.0, "infos": {"displacement": {"noise_floor": 0.01}}, "penalty": 0.0, "min_share": 0.0}
    row = {"name": "cand", "key": "k", "channel": "displacement", "n_params": 1}
    rival = {"name": "rival", "key": "k", "n_params": 3}
    ok, who = stages._beats_rivals(row, [rival], {"k": prob}, {"k": []}, split, res, ctx)
    assert ok is beaten and who == (None if beaten else "rival")


def test_a_rival_is_charged_for_its_parameters_as_the_fold_test_charges_them(monkeypatch):
    """stages._beats_rivals compares candidate and rival as the fold test and the fold winner's choice
    do, each ``rms (1 + penalty n_params)``: a 12-branch second creep (4 parameters) leaving 0.5 % less
    than a one-parameter candidate on the one fold it explains leaves more once charged (0.02 per
    parameter: 1.08 x 0.3625 against 1.02 x 0.3645), and the candidate stands; a rival leaving 10 %
    less there still refuses it. (72 #31: a sub-sample delay beside a 13x creep, refused unpenalized.)"""
    from workbench.calibrate import tracing
    monkeypatch.setattr(tracing, "_stacked", lambda prob, extra, row: row["name"])
    split = SimpleNamespace(folds=[(f, f) for f in range(5)])
    res = {"befores": {"k": [1.0] * 5}, "null_gain": {"k": [0.0] * 5}}
    ctx = {"noise_factor": 1.0, "infos": {"displacement": {"noise_floor": 0.01}}, "penalty": 0.02, "min_share": 0.0}
    row = {"name": "cand", "key": "k", "channel": "displacement", "n_params": 1}
    rival = {"name": "rival", "key": "k", "n_params": 4}
    for rival_fold2, beaten in ((0.3625, True), (0.9 * 0.3645, False)):
        # the rival explains fold 2 only (the others: it leaves what the found effects leave)
        table = {"cand": [0.3, 0.3645, 0.3, 0.3, 0.3], "rival": [1.0, rival_fold2, 1.0, 1.0, 1.0]}
        prob = SimpleNamespace(fold_rms=lambda g, tr, va: table[g][tr])
        ok, who = stages._beats_rivals(row, [rival], {"k": prob}, {"k": []}, split, res, ctx)
        assert ok is beaten and who == (None if beaten else "rival"), rival_fold2


def test_folds_all_a_charge_relaxation_ask_whether_it_is_creep_behind_a_displacement_effect(monkeypatch):
    """run_stages: a first stage with no answer whose every fold is a charge relaxation's (decided,
    or undecided between it and creep) asks the question a named charge relaxation asks
    (_creep_behind_a_displacement_effect: with the displacement's dominant effect in the model, does
    the displacement's creep win the folds?), of the relaxation most folds chose; promoted, the
    displacement effect is named first and the displacement's creep is a fold-winner seen (``need``
    folds later). Not promoted, the answer stays none. (73 #152 at 1 MHz: a 20x creep behind an
    11 ms delay, absorption-or-creep 4 folds, absorption 1: inconclusive.)"""
    from workbench.calibrate import tracing
    da, und = ("dielectric_absorption", "charge"), ("undecided", "dielectric_absorption or creep")
    dl = ("delay", "displacement")
    rows = {da: {"name": da[0], "channel": "charge", "passes": [True] * 5, "score": 0.04},
            dl: {"name": "delay", "channel": "displacement", "passes": [True] * 5, "score": 0.1}}
    res = {"winners": [und, da, und, und, und], "by": rows, "rows": list(rows.values()), "befores": {}}
    monkeypatch.setattr(tracing, "_score_stage", lambda *a, **k: res)
    monkeypatch.setattr(tracing, "_absorb", lambda *a, **k: None)
    monkeypatch.setattr(stages, "nested_consensus", lambda *a, **k: (None, 0, 0))
    monkeypatch.setattr(stages, "leakage_no_worse", lambda *a, **k: None)
    monkeypatch.setattr(stages, "_stage_entry", lambda c, count, *a, **k: {"effect": c["name"], "channel": c["channel"],
                                                                            "agreement": count})
    asked, seen_later = [], []
    monkeypatch.setattr(stages, "_later_stage",
                        lambda ctx, ex, found, seen=(): seen_later.append(seen) or (None, 0, [], {"by": {}}, None))
    ctx = {"cands": [], "probs": {}, "nulls": {}, "split": SimpleNamespace(folds=[0] * 5), "penalty": 0.02,
           "noise_factor": 1.0, "infos": {}, "min_share": 0.3, "need": 4, "base": None, "t": None}
    for promote in (True, False):
        asked.clear()
        seen_later.clear()

        def behind(answer, count, note, res_, ctx_, extra, found, decided=False, info=None):
            asked.append((answer, decided))
            if promote:
                info["passes"] = 5
            return (dl, 0, "creep's charge") if promote else (answer, count, note)

        monkeypatch.setattr(stages, "_creep_behind_a_displacement_effect", behind)
        first, st, _ = stages.run_stages(ctx)
        assert asked == [(da, True)]       # asked needing a decided creep fold (review finding 2)
        if promote:
            assert [(s["effect"], s["channel"]) for s in st] == [dl] and first["answer"] == dl
            # the promoted delay won no fold (agreement 0) but passes 5: what scripts compare with
            # agree_needed (review finding 1)
            assert st[0]["agreement"] == 0 and st[0]["agreement_compatible"] == 5
            assert ("creep", "displacement") in seen_later[0] and da not in seen_later[0]
        else:
            assert st == [] and first["answer"] is None


def _later(monkeypatch, winners, passes, seen=(), n=5, first=("delay", "displacement"), disjoint=False):
    """stages._later_stage on a scored later stage (the delay found first): fold ``winners`` and
    each row's fold ``passes`` ({tag: [bool] * n}); rivals beaten; the candidate's band ``disjoint``
    from the found effects' or not (:func:`~workbench.calibrate.stages._band_disjoint`, which needs
    the terms: these rows have none)."""
    monkeypatch.setattr(stages, "_band_disjoint", lambda *a, **k: disjoint)
    by = {tag: {"passes": p, "score": 0.5, "name": tag[0], "channel": tag[1]} for tag, p in passes.items()}
    res = {"winners": winners, "by": by, "rows": list(by.values())}
    found = list(first) if isinstance(first, list) else [first]
    ctx = {"need": int(np.ceil(0.8 * n)), "split": SimpleNamespace(folds=[0] * n), "probs": {},
           "later_cache": {tuple(found): (stages._extra_signature({}), res, {"rivals": []})}}
    monkeypatch.setattr(stages, "_beats_rivals", lambda *a, **k: (True, None))
    return stages._later_stage(ctx, {}, found, seen=seen)[:2]


CD, CG = ("creep", "displacement"), ("creep", "gauge")
DA, DLY_G = ("dielectric_absorption", "charge"), ("delay", "gauge")


@pytest.mark.parametrize("winners, passes, seen, answer", [
    # the stack's creep won 3 folds on the displacement and 2 on the gauge behind a 25 ms sensor delay
    # (25 #64): one motion on every fold, named on the displacement (its row passes 4 folds)
    ([CD, CD, CG, CD, CG], {CD: [True, True, False, True, True], CG: [True] * 5}, (), CD),
    # ... on the gauge when the displacement's row passes fewer than ``need`` (the plant file's form needs it)
    ([CD, CD, CG, CD, CG], {CD: [True, True, False, True, False], CG: [True] * 5}, (), CG),
    # one fold neither view wins: not every fold, and creep won no first-stage fold
    ([CD, CD, CG, CD, "none"], {CD: [True] * 4 + [False], CG: [True] * 5}, (), None),
    # ... but it did (a fold undecided between the charge's absorption and creep): ``need`` folds
    ([CD, CD, CG, CD, "none"], {CD: [True] * 4 + [False], CG: [True] * 5},
     (("undecided", "dielectric_absorption or creep"),), CD),
    # the gauge's creep seen in the first stage is the stack's: the displacement's needs ``need`` folds
    ([CD, CD, CD, CD, "none"], {CD: [True] * 4 + [False]}, (CG,), CD),
    # the charge's absorption won a fold where the stack's creep passes too: compatible with creep
    ([CD, CD, DA, CD, CD], {CD: [True] * 5, DA: [True] * 5}, (), CD),
    # ... not where neither view of the stack's creep passes it (27 #42)
    ([CD, CD, DA, CD, CD], {CD: [True, True, False, True, True], CG: [False] * 5, DA: [True] * 5}, (), None),
    # a gauge effect that is not creep does not join the displacement's creep
    ([CD, CD, DLY_G, CD, CD], {CD: [True] * 5, DLY_G: [True] * 5}, (), None),
])
def test_a_later_stage_counts_the_stacks_creep_on_every_fold_it_explains(monkeypatch, winners, passes, seen, answer):
    """stages._later_stage after a sensor delay: the stack's creep is one effect read by both sensors
    and relaxes the charge too (seed 002), so its folds are the displacement's, the gauge's and the
    folds a charge relaxation wins while the stack's creep passes them; the bar stays every fold, or
    ``need`` for an effect a first-stage fold chose (creep on either sensor or undecided with a charge
    relaxation). Deleting either reading changes an outcome here."""
    got, _ = _later(monkeypatch, winners, passes, seen)
    assert (got if got not in (None, "none") else None) == answer


@pytest.mark.parametrize("disjoint", [False, True])
def test_an_unseen_later_effect_needs_every_fold_unless_its_band_is_disjoint(monkeypatch, disjoint):
    """An effect no first-stage fold chose needs every fold at a later stage, ``need`` when its band is
    disjoint from the found effects' (it cannot be their misfit): a mode winning 4 of 5 folds behind a
    drift (83 #11)."""
    mode = ("resonance", "displacement")
    got, _ = _later(monkeypatch, [mode] * 4 + ["none"], {mode: [True] * 4 + [False]},
                    first=("drift", "displacement"), disjoint=disjoint)
    assert (got if got not in (None, "none") else None) == (mode if disjoint else None)


def test_a_charge_relaxations_fold_counts_for_creep_only_behind_a_sensor_effect(monkeypatch):
    """The charge's fold is read as creep's only after a displacement-sensor effect (the first stage
    judged it against a displacement model without that effect); after the charge's absorption, a
    leakage fold where the stack's creep passes stays the leakage's (a leakage + absorption record)."""
    lk = ("leakage", "charge")
    winners, passes = [CD, CD, lk, CD, CD], {CD: [True] * 5, lk: [True] * 5}
    assert _later(monkeypatch, winners, passes)[0] == CD
    got = _later(monkeypatch, winners, passes, first=DA)[0]
    assert got in (None, "none")
    # ... and after a sensor effect AND the charge's absorption (review of d0cfbc6: creep was named at 2 of 5)
    winners = [CD, lk, lk, CD, lk]
    got = _later(monkeypatch, winners, passes, first=[("drift", "displacement"), DA])[0]
    assert got in (None, "none")


@pytest.mark.parametrize("joint", [True, False])
def test_a_split_whose_minority_survives_only_after_the_majority(monkeypatch, joint):
    """A sensor delay wins 3 first-stage folds, creep 2 (26 #64's shape). With the delay in the model
    creep is accepted; with creep in the model the delay is refused (a creep branch of tau ~ d mimics
    it: -tau du/dt against -d dy/dt). The survivor won fewer folds, so it is not named alone (the
    session-12 rule); when the two together beat creep alone on ``need`` folds
    (stages._joint_beats_alone) both are named, the majority's delay first; otherwise inconclusive."""
    from workbench.calibrate import tracing
    dl = ("delay", "displacement")
    res = {"winners": [dl, dl, dl, CD, CD], "by": {dl: {"score": 0.3}, CD: {"score": 0.4}}}
    monkeypatch.setattr(tracing, "_absorb", lambda *args, **kw: None)

    def later(ctx, ex, found, seen=()):
        return (CD, 5, [], {"by": {}}, None) if found[-1] == dl else (None, 2, [], {"by": {}}, None)

    monkeypatch.setattr(stages, "_later_stage", later)
    monkeypatch.setattr(stages, "_joint_beats_alone", lambda x, y, *a: (x, y) == (dl, CD) and joint)
    answer, count, note = stages.resolve_split(res, {"need": 4, "probs": {}, "base": None, "t": None}, {}, [])
    if joint:
        assert answer == dl and count == 3 and "both are in the record" in note
    else:
        assert answer is None and count == 3 and note is None


# Session 13 (creep + sensor delay): records drawn with np.random.default_rng(1313), chosen before any
# record was traced: rate from the benchmark's 1, 10 and 100 kHz (its row counts: 10 s, 2 s, 0.4 s),
# protocol, size log-uniform over the full 0.03-30x (the delay 0.01-60 ms, the creep's branches
# 0.01-42 uF), record seed. Pairs first, then the single-effect guards (creep alone, delay alone).
CD_DRAWN = 3 if not FULL else 9
#: single-effect guards after the pairs (the same stream: the first ones are the full run's first ones);
#: the benchmark's creep and delay records carry the guard at scale (README, session 13)
CD_SINGLES = 1 if not FULL else 9


def _cd_draws():
    cc = _bench()
    rng = np.random.default_rng(1313)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    out = []
    for eff in [("creep", "delay")] * CD_DRAWN + ["creep", "delay"] * CD_SINGLES:
        rate = float(cc.RATES_HZ[int(rng.integers(len(cc.RATES_HZ)))])
        proto = str(rng.choice(("calibration", "sine", "steps")))
        out.append((eff, rate, proto, float(np.exp(rng.uniform(lo, hi))), int(rng.integers(1 << 30))))
    return out


@pytest.fixture(scope="module")
def cd_rows(sn637):
    cc = _bench()
    rows = []
    for eff, rate, proto, size, seed in _cd_draws():
        r = cc.evaluate(sn637, eff, rate, proto, size, seed, diagnostics=False)
        print(f"\n{r['effect']:12s} {rate / 1e3:4.0f} kHz {proto:11s} size x{size:.3g} own sizes "
              f"{np.round(r['excesses'], 2)} -> stages {r['named']} {r['class']} both {r['both']} "
              f"above the line {r['above_line']}")
        rows.append(r)
    return rows


def test_creep_and_delay_records_name_nothing_else_and_stay_below_the_line(cd_rows):
    """The single-effect guards of the drawn records: a creep record never gets a delay named, a
    delay record never creep (nor any pair record an effect it lacks), and no record ends with a
    held-out error above a straight line's (issue 13's floors)."""
    assert not [r for r in cd_rows if r["class"] == "wrong"], [(r["effect"], r["named"]) for r in cd_rows]
    assert not [r for r in cd_rows if r["above_line"]], [(r["effect"], r["above_line"]) for r in cd_rows]


# (a strict xfail until session 17: the 10 kHz calibration draw (9.2x creep, 11.4x delay, 1.6 ms) was inconclusive,
# its first-stage folds split five ways; with the creep branches driven by V_h (creep_across) both are named)
def test_creep_and_delay_records_are_answered_with_both(cd_rows):
    """Issue 13 item 5 on the drawn creep + delay records: each whose two effects both stand >= 3x
    above the floor (each on its own record) is answered with both."""
    big = [r for r in cd_rows if "+" in r["effect"] and min(r["excesses"]) >= 3.0]
    print(f"\nboth named: {sum(r['both'] for r in big)} of {len(big)} creep + delay records with both >= 3x")
    assert all(r["both"] for r in big), [(r["rate_hz"], r["protocol"], np.round(r["excesses"], 1), r["named"])
                                         for r in big]


def test_a_later_stage_named_from_compatible_folds_says_how_many(monkeypatch):
    """The JSON's ``agreement`` is the named view's own wins (3 of 5 here); the later stage keeps the
    folds compatible with the name (both sensors' creep: 5) for ``agreement_compatible``."""
    monkeypatch.setattr(stages, "_beats_rivals", lambda *a, **k: (True, None))
    by = {CD: {"passes": [True] * 5}, CG: {"passes": [True] * 5}}
    res = {"winners": [CD, CD, CG, CD, CG], "by": by, "rows": list(by.values())}
    found = [("delay", "displacement")]
    ctx = {"need": 4, "split": SimpleNamespace(folds=[0] * 5), "probs": {},
           "later_cache": {tuple(found): (stages._extra_signature({}), res, {"rivals": []})}}
    answer, count, _, res_k, _ = stages._later_stage(ctx, {}, found)
    assert answer == CD and count == 3 and res_k["compatible_folds"] == {CD: 5}


def _later_alt(monkeypatch, gauge_passes, dropped, winners=(CD,) * 5, seen=(), rival="delay"):
    """stages._later_stage after a found displacement delay, the displacement's creep winning ``winners``:
    its kept reading leaves 7.04 on fold 0 against a second delay's 6.81 (82 #42's fold 0, 1e-8 m; the other
    folds, the found effects' 10 and one parameter each, charged 1 + 0.02, are constructed), so the real
    :func:`~workbench.calibrate.stages._beats_rivals` refuses it; the tag's dropped reading (``alt``) leaves
    ``dropped["rms"]`` and passes ``dropped["passes"]``; the gauge's creep passes ``gauge_passes`` (``None``: no
    gauge row). The rival is the re-searched found ``rival`` on the displacement's problem, explaining every fold
    (10 -> 6.81). (answer, note, the answer's row)."""
    from workbench.calibrate import tracing
    monkeypatch.setattr(tracing, "_stacked", lambda prob, extra, row: row["label"])
    table = {"kept": [7.04, 6.0, 6.0, 6.0, 6.0], "rival": [6.81] * 5, "dropped": dropped["rms"]}
    prob = SimpleNamespace(fold_rms=lambda g, tr, va: table[g][tr])
    row = {"name": "creep", "channel": "displacement", "key": "k", "n_params": 1}
    alt = {**row, "label": "dropped", "passes": dropped["passes"], "score": 0.65}
    by = {CD: {**row, "label": "kept", "passes": [True] * 5, "score": 0.6, "alt": [alt]}}
    if gauge_passes is not None:
        by[CG] = {**row, "channel": "gauge", "key": "g", "label": "gauge", "passes": gauge_passes, "score": 0.7}
    res = {"winners": list(winners), "by": by, "rows": list(by.values()),
           "befores": {"k": [10.0] * 5}, "null_gain": {"k": [0.0] * 5}}
    found = [("delay", "displacement")] + ([(rival, "displacement")] if rival != "delay" else [])
    extra = {"k": []}
    rv = {"name": rival, "key": "k", "n_params": 1, "label": "rival"}
    ctx = {"need": 4, "split": SimpleNamespace(folds=[(f, f) for f in range(5)]), "probs": {"k": prob},
           "penalty": 0.02, "noise_factor": 1.0, "infos": {"displacement": {"noise_floor": 0.1}}, "min_share": 0.0,
           "later_cache": {tuple(found): (stages._extra_signature(extra), res, {"rivals": [rv]})}}
    answer, _, _, res_k, note = stages._later_stage(ctx, extra, found, seen=seen)
    return (answer if answer not in (None, "none") else None), note, res_k["by"].get(CD)


BEATS = {"rms": [6.52] * 5, "passes": [True] * 5}


@pytest.mark.parametrize("gauge_passes, dropped, winners, seen, rival, answered", [
    # (1) the kept reading refused by the second delay, the gauge's creep on every fold, the dropped reading
    # passing every fold and beating the delay on each: the stack's creep is named with the dropped reading
    ([True] * 5, BEATS, (CD,) * 5, (), "delay", True),
    # (2) the gauge's creep fails a fold: the sensor's delay may be what the displacement's creep takes
    ([True] * 4 + [False], BEATS, (CD,) * 5, (), "delay", False),
    # ... or the stage has no gauge creep at all
    (None, BEATS, (CD,) * 5, (), "delay", False),
    # (3) the dropped reading leaves more than the second delay on one fold
    ([True] * 5, {**BEATS, "rms": [6.52] * 4 + [6.9]}, (CD,) * 5, (), "delay", False),
    # ... or passes 4 folds where the kept one (no first-stage fold chose creep) was counted for every fold
    ([True] * 5, {**BEATS, "passes": [True] * 4 + [False]}, (CD,) * 5, (), "delay", False),
    # ... 4 are enough where creep won a first-stage fold and the kept one was counted for ``need`` (4) ...
    ([True] * 5, {**BEATS, "passes": [True] * 4 + [False]}, (CD,) * 4 + ("none",), (CD,), "delay", True),
    # ... 3 are not
    ([True] * 5, {**BEATS, "passes": [True] * 3 + [False] * 2}, (CD,) * 4 + ("none",), (CD,), "delay", False),
    # a rival of the stack's own kind (a second mode beside a found one) is not the displacement sensor's:
    # the kept reading's refusal stands
    ([True] * 5, BEATS, (CD,) * 5, (), "resonance", False),
], ids=["answered", "gauge-fails-a-fold", "no-gauge-row", "dropped-loses-a-fold", "dropped-4-of-every",
        "dropped-4-of-need", "dropped-3-of-need", "rival-not-sensor"])
def test_the_dropped_creep_reading_is_asked_when_a_sensor_effects_rival_refuses_the_kept_one(
        monkeypatch, gauge_passes, dropped, winners, seen, rival, answered):
    """stages._later_stage / _other_reading (session 21, s21_altreading; 82 #42): the displacement's creep
    reading kept by _score_stage is refused by a re-searched found delay; the tag's dropped reading is asked
    under the same rule, no looser, only when the gauge's creep (which never sees the sensor's delay) passes
    every fold: it must pass the folds the kept one was counted for and beat the rival on every fold the rival
    explains. Answered, the row is the dropped reading; refused, the kept one's note stands."""
    answer, note, row = _later_alt(monkeypatch, gauge_passes, dropped, winners, seen, rival)
    if answered:
        assert answer == CD and note is None and row["label"] == "dropped"
    else:
        assert answer is None and note == f"creep does not beat a second {rival} on the leftover"
