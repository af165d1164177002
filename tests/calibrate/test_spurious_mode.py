"""A large creep's leftover read as a mode (session 15, branch s15_spur): a miss, fixed in session 17 by creep's form.

Seed 40 #2 (a 20x creep, 1 kHz, calibration protocol) is named ``['creep', 'resonance']``: after
creep, a 1.20 Hz, zeta 0.3 (the search's ceiling) "mode" of gain -0.046 wins 5 of 5 folds, and
creep's own rival (further branches, c >= 0) explains none of them. Session 13 answered ``creep``
alone only because the gauge's half-sample lag (a sampling artifact, removed by s14_ends' averaged
gauge model, 19dd668) took one of the five folds as a gauge delay; the mode already won the other 4.

A negative gain is no mode of the stack filtering its motion (``g (H - 1) u`` with ``g < 0`` is a
second-order high-pass, a relaxation of the sign creep's branches cannot take), but bounding
``g >= 0`` is not a fix: a mode above the record's Nyquist frequency is named through its alias
``fs - f`` with a negative gain (seed 40 #27: a 611 Hz mode at 1 kHz, named at 388.5 Hz, gain
-0.55; with the bound it is answered ``none``). Session 15 kept the miss as strict xfails.

Session 17 (s17_creep): creep's branches are driven by the voltage across C_h (``creep_across``), the
simulator's physics, and the fitted creep no longer leaves the hysteretic misfit the mode stood in
for: seed 40 #2 and both drawn misses (14.4x, 15.4x) are ``['creep']`` alone, with no bound on the
mode's gain (the xfails went; the draws are the ones session 15 drew).

Drawn records: creep alone, sizes log-uniform over the benchmark's large band (3-30x the drawn
range) at 1 and 10 kHz, and eight at 1 kHz on the calibration protocol at 10-30x (the seed 40
record's neighbourhood), ``default_rng`` fixed; main names the same mode (1.20 Hz, zeta 0.3, gain
-0.051) on 2 of the eight (14.4x and 15.4x). ``make test`` runs three of the four design draws and the first
miss (14.4x); WORKBENCH_FULL=1 all twelve (the others are skipped in the reduced form).
"""

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate.tracing import trace_effect

_RNG = np.random.default_rng(1515)
CREEP_DRAWS = [(rate, proto, float(np.exp(_RNG.uniform(np.log(3.0), np.log(30.0)))), int(_RNG.integers(1 << 30)))
               for rate, proto in ((1e3, "calibration"), (1e3, "sine"), (1e4, "calibration"), (1e3, "steps"))]
_RNG_1K = np.random.default_rng(77)
CREEP_DRAWS += [(1e3, "calibration", float(np.exp(_RNG_1K.uniform(np.log(10.0), np.log(30.0)))),
                 int(_RNG_1K.integers(1 << 30))) for _ in range(8)]
# session 15's main named ['creep', 'resonance'] on two of them (1039808915, 342190994); since s17_creep, none
#: reduced form: three of the four design draws (1 kHz sine, 10 kHz calibration, 1 kHz steps) and the first of
#: the two of default_rng(77)'s first four that session 15's main missed (draw 6, 14.4x; draw 7, 15.4x, missed
#: the same way at the same rate, protocol and band, runs in the full form, and seed 40 #2 below, 20x, stays
#: the neighbourhood's regression record in make test); the full form runs all twelve. Session 22's reduced
#: form ran the first eight, session 23's five (draws 1, 2, 3, 6, 7), session 28's four (the suite's 10 minutes)
CREEP_DRAWS = reduced_draws(CREEP_DRAWS, keep=(1, 2, 3, 6))


def _trace(plant0, effect, rate, proto, size, seed):
    t, sp, base, _, truth, _ = load_benchmark("calibrate_confusion").simulated_base(plant0, effect, rate, proto,
                                                                                    size, seed)
    return trace_effect(base, split=sp), truth


@pytest.mark.parametrize("rate, proto, size, seed", CREEP_DRAWS)
def test_a_large_creep_alone_names_no_second_effect(sn637, rate, proto, size, seed):
    """Creep alone, 3-30x the drawn range: no stage names another effect."""
    res, truth = _trace(sn637, "creep", rate, proto, size, seed)
    named = [(s["effect"], s["channel"], s["parameters"]) for s in res["stages"]]
    assert {n[0] for n in named} <= {"creep"}, (named, res.get("fold_winners"), truth)


def test_regression_seed_40_2_is_creep_alone(sn637):
    """The confusion benchmark's seed 40 #2 (20x creep, 1 kHz calibration): should be ``['creep']``."""
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, s = cc.cases(seed=40)[1]
    assert e == "creep" and rate == 1e3
    res, _ = _trace(sn637, e, rate, proto, size, s)
    assert [x["effect"] for x in res["stages"]] == ["creep"]


def test_a_mode_above_nyquist_is_named_at_its_alias_with_a_negative_gain(sn637):
    """Why the mode's gain keeps its free sign: seed 40 #27 (a mode drawn at 611 Hz, 1 kHz steps record,
    Nyquist 500 Hz) is named resonance at its alias ``fs - f`` (within a quarter of the drawn mode's
    bandwidth ``2 zeta f``) with a negative gain."""
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, s = cc.cases(seed=40)[26]
    res, truth = _trace(sn637, e, rate, proto, size, s)
    assert e == "resonance" and truth["freq_hz"] > rate / 2
    st = [x for x in res["stages"] if x["effect"] == "resonance"]
    assert st, res.get("fold_winners")
    p = st[0]["parameters"]
    alias = rate - truth["freq_hz"]
    assert abs(p["f_n_hz"] - alias) < 0.25 * 2 * truth["damping_ratio"] * truth["freq_hz"], (p, alias)
    assert p["gain"] < 0, p
