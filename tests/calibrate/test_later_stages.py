"""Wrong and inconclusive answers on large two-effect and later-stage records (branch s12_later).

Causes (README, Calibration, *Later stages on large records*):

* the gauge's bow is fitted against the *recorded* displacement, which carries a displacement
  sensor's delay or drift the stack (and so the gauge) never had: after such a stage the
  gauge's line problem is rebuilt against the displacement with the found term taken out;
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

from tests.conftest import load_benchmark
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


@pytest.mark.parametrize("proto, size, seed", CREEP_DELAY_DRAWS)
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
    assert named and set(named) <= {"drift", "resonance"}, (res["effect"], named, res.get("fold_winners"))


@pytest.mark.parametrize("seed, index, want", [(30, 73, ["drift"]), (30, 97, ["delay"])])
def test_regression_later_stages_on_large_records(sn637, seed, index, want):
    """Regression records (tuned on): a 721x drift (100 kHz calibration) named drift only (main:
    drift, gauge_nonlinearity); creep + a 39 ms delay (100 kHz steps) named delay only (main:
    delay, dielectric_absorption)."""
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, s = cc.cases(seed=seed)[index - 1]
    _, res, _ = _trace(sn637, e, rate, proto, size, s)
    assert [x["effect"] for x in res["stages"]] == want


@pytest.mark.parametrize("n, start, width", [(50, 10, 5), (200, 0, 7), (200, 193, 7), (31, 14, 1)])
def test_a_gauge_row_beside_a_pinned_one_is_not_valid(n, start, width):
    """Pinned rows (at the DAC rail, either sign) and their two neighbours are invalid; every other row valid."""
    g = np.linspace(-1.0, 1.0, n) * 0.5
    g[start:start + width] = 2.6 * (-1) ** start
    ok = _gauge_valid(g, 2.6)
    bad = np.zeros(n, bool)
    bad[max(start - 1, 0):min(start + width + 1, n)] = True
    assert np.array_equal(ok, ~bad)


def _res(winners, scores):
    by = {k: {"score": v, "passes": [True] * len(winners)} for k, v in scores.items()}
    return {"winners": winners, "by": by}


@pytest.mark.parametrize("name", ["resonance", "creep"])
def test_the_stacks_effect_on_both_sensors_is_one_effect(name):
    """3 folds on the gauge and 2 on the displacement: named (need 4) on the lower median ratio."""
    g, x = (name, "gauge"), (name, "displacement")
    res = _res([g, x, g, g, x], {g: 0.43, x: 0.90})
    ans, count, note = st.stack_effect_on_both_sensors(res, 4)
    assert (ans, count) == (g, 5) and note
    res = _res([g, x, g, g, x], {g: 0.9, x: 0.5})
    assert st.stack_effect_on_both_sensors(res, 4)[0] == x
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


@pytest.mark.parametrize("floor, before", [(1e-9, 20e-9), (1e-9, 2e-9), (3e-9, 5e-9)])
def test_what_the_stack_could_hide_after_a_displacement_effect(floor, before):
    """First stage: 3x the floor. After a displacement effect: also what it leaves above the floor."""
    infos = {"displacement": {"noise_floor": floor}}
    befores = {("displacement", "model"): [before]}
    assert tr._stack_could_hide(0, befores, infos, []) == pytest.approx(3 * floor)
    assert tr._stack_could_hide(0, befores, infos, [("resonance", "gauge")]) == pytest.approx(3 * floor)
    want = max(3 * floor, np.sqrt(before ** 2 - floor ** 2))
    assert tr._stack_could_hide(0, befores, infos, [("delay", "displacement")]) == pytest.approx(want)
