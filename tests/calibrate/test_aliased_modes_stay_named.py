"""Right modes on 100 Hz records that a rule refusing "rings no fold shows" would lose (session 38).

Session 38's branch s38_wrong refused a named mode whose gain fails the band, whose column "fits something else"
and whose folds' own rings have gains consistent with zero (``ring_not_shown``). Its independent review found it
refusing right modes main named, on the confusion benchmark's 100 Hz records: the folds find the ring at different
members of its alias family, so their gains differ in sign and average near zero although every fold fits a ring
(seed 106 #104), or sit 1.75 standard errors from zero (107 #121, a drift beside the mode; 108 #115 at 3.67x the
noise floor, inside the issue's ">= 3" band). The rule was withdrawn; these records guard against its return. Each
is the benchmark's own record (``calibrate_confusion.py --seed S --rates 100 --index N``), its truth simulated.
"""

import pytest

from tests.conftest import load_benchmark

#: (seed, 1-based index in the seed's full run with the end rates, the names the answer must include)
CASES = [(106, 104, ("resonance",)), (107, 121, ("drift", "resonance")), (108, 115, ("resonance",))]


@pytest.mark.parametrize("seed, index, names", CASES)
def test_right_modes_at_100_hz_stay_named(sn637, seed, index, names):
    cc = load_benchmark("calibrate_confusion")
    effect, rate_hz, protocol, size, rec_seed = cc.cases(1, seed, False, ends=True)[index - 1]
    assert rate_hz == 100.0 and "resonance" in ((effect,) if isinstance(effect, str) else effect)
    r = cc.evaluate(sn637, effect, rate_hz, protocol, size, rec_seed, diagnostics=False)
    assert r["class"] == "right" and all(n in r["named"] for n in names), (r["answer"], r["named"], r["class"])
