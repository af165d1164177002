"""Large effects the calibration missed (branch s11_calbig): a latency or a mode far above the noise
floor answered ``none``, and a sensor drift named creep.

Causes (README, Calibration): a base fitted to a record whose sensor lags by many samples is
itself wrong, so the base shifted is not the lagged motion (the delay's model is now refitted
per trial delay), and the delay bound was a quarter of the excitation period (now a quarter of
the record); a mode's frequency floor was twenty cycles per record (50 Hz on a 0.4 s record, now
the drift's periodic ceiling, ten); a displacement relaxation whose charge (x = k_q2x q) the
charge channel does not show is not the stack's creep.

Drawn records: sizes log-uniform over the benchmark's large band (3-30x the drawn ranges),
``default_rng`` fixed before any run. Regression records of the confusion benchmark's seeds 26
and 28 (which the changes were tuned on: not held-out evidence) are marked as such.
"""

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate.base_fit import fit_base
from workbench.calibrate.effects import Delay, Resonance
from workbench.calibrate.pi_fit import pi_thresholds, play_matrix
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
from workbench.calibrate.tracing import candidate_plan, trace_effect

RNG = np.random.default_rng(1311)
DELAY_DRAWS = [(proto, float(np.exp(RNG.uniform(np.log(3.0), np.log(30.0)))), int(RNG.integers(1 << 30)))
               for proto in ("sine", "steps", "calibration")]
# modes of a heavily loaded stack, the benchmark's 150 Hz / sqrt(30) = 27 Hz to 150 Hz, one draw
# per band (27-50 Hz lay below the old floor of a 0.4 s record)
MODE_DRAWS = [(float(np.exp(RNG.uniform(np.log(lo), np.log(hi)))), int(RNG.integers(1 << 30)))
              for lo, hi in ((27.0, 50.0), (50.0, 90.0), (90.0, 150.0))]
UNIT_DRAWS = [(float(RNG.uniform(0.02, 0.25)), int(RNG.integers(1 << 30))) for _ in range(4)]


def _trace(plant0, effect, rate, proto, size, seed):
    t, sp, base, _, truth, _ = load_benchmark("calibrate_confusion").simulated_base(plant0, effect, rate, proto,
                                                                                    size, seed)
    return base, trace_effect(base, split=sp), truth, t


@pytest.mark.parametrize("share, seed", UNIT_DRAWS)
def test_the_refitted_delay_finds_a_latency_that_biases_the_base(share, seed):
    """y = PI(V(t - d)) + noise with d a share 0.02-0.25 of the record; the base fitted as if
    undelayed is biased. The refitted search finds d within 1 % of it, and
    the base's columns plus the delay's one column leave the noise (closed form: the model is
    exact at the true d)."""
    rng = np.random.default_rng(seed)
    n = 6000
    t = np.arange(n) * 1e-4
    # decaying sines and steps: not periodic, so one latency fits
    v = 50 + 40 * np.exp(-t / 0.4) * np.sin(2 * np.pi * 6.0 * t) + 10 * np.sign(np.sin(2 * np.pi * 1.7 * t + 0.3))
    r = pi_thresholds(v, 10, "quadratic")
    B = np.column_stack([play_matrix(v, r, np.zeros(r.size)), np.ones(n)])
    w = np.r_[rng.uniform(0.2, 1.0, r.size), rng.normal()] * 1e-7
    d = share * n
    clean = B @ w
    y_true = np.interp(np.arange(n) - d, np.arange(n), clean)
    noise = 1e-3 * np.std(y_true)
    y = y_true + rng.normal(size=n) * noise
    yhat = B @ np.linalg.lstsq(B, y, rcond=None)[0]
    train = np.ones(n, bool)
    eff = Delay(max_delay=0.25 * n, basis=B)
    p = eff.fit(t, v, y - yhat, train, y_model=yhat)
    assert p["refit"] and abs(p["delay_samples"] - d) <= 0.01 * d, (p["delay_samples"], d)
    C = eff.term(t, v, p, y_model=yhat)
    X = np.column_stack([B, C])
    res = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    rows = np.arange(n) > d                     # (before d the sensor holds its first reading)
    assert np.sqrt(np.mean(res[rows] ** 2)) <= 3.0 * noise


def test_the_delay_bound_is_a_quarter_of_the_record():
    t = np.arange(40_000) * 1e-5
    v = np.sin(2 * np.pi * 100 * t)             # a 10 ms period: the bound is the record's, not the period's
    plan = candidate_plan({"displacement": None}, t, v)
    (d,) = [e for ch, e, _ in plan if e.name == "delay"]
    assert d.max_delay == pytest.approx(0.25 * (t[-1] - t[0]) / 1e-5)


# make test: 1 of 3 (session 28, for the suite's time; WORKBENCH_FULL=1 all three)
@pytest.mark.parametrize("proto, size, seed", reduced_draws(DELAY_DRAWS, keep={0}))
def test_a_large_latency_at_100_khz_is_named_delay(sn637, proto, size, seed):
    """Delays 0.9-60 ms (0.3-2 ms times 3-30) on 0.4 s records: main answered none or
    inconclusive on three of this kind (seeds 26-28 #83, #94, #72)."""
    base, res, truth, t = _trace(sn637, "delay", 1e5, proto, size, seed)
    assert res["effect"] == "delay" and res["channel"] == "displacement", (res["effect"], res.get("fold_winners"))
    got = res["stages"][0]["parameters"]["delay_s"]
    assert got == pytest.approx(truth["delay_s"], rel=0.1, abs=2e-5), (got, truth)
    assert res["error_after"]["rms"] <= 0.5 * res["error_before"]["rms"]


@pytest.mark.parametrize("freq_hz, seed", reduced_draws(MODE_DRAWS, keep={0, 2}))     # make test: 2 of 3
def test_a_low_mode_on_a_steps_record_is_named_and_not_above_the_line(sn637, freq_hz, seed):
    """A mode of 27-150 Hz (damping drawn from the benchmark's 0.5-2 %) on a 0.4 s steps record at
    100 kHz, ringing 11-60 cycles: the old floor (20 cycles, 50 Hz) left the lowest out (seed 28
    #93: 40.6 Hz, answered none and above the line)."""
    import dataclasses

    from workbench.plant.pzt import Mode
    cc = load_benchmark("calibrate_confusion")
    t, v = benchmark_protocol("steps", 1e5, cc.ROWS[1e5])
    plant, truth = plant_with_effect(sn637, "resonance", seed, duration_s=float(t[-1]))
    mode = Mode(freq_hz, truth["damping_ratio"])
    plant = dataclasses.replace(plant, pzt=dataclasses.replace(plant.pzt, modes=(mode,)))
    r = simulate_record(plant, t, v, seed=seed)
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(cc._record(r, 1e-5), sn637.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    res = trace_effect(base, split=sp)
    assert res["effect"] == "resonance", (res["effect"], res.get("fold_winners"))
    assert res["stages"][0]["parameters"]["f_n_hz"] == pytest.approx(freq_hz, rel=0.02)
    for ch, c in res["channels"].items():
        assert c["error_after"]["rms"] <= base.channels[ch].line_rms_test, ch


def test_the_mode_floor_is_two_cycles_per_record_and_a_slower_mode_must_ring():
    """Session 17 (s17_mhz): the search reaches two cycles over the record (it was ten), and below ten
    cycles a trial's damping is capped at 1/(2 pi) (its ringing outlasts a cycle: heavier is a relaxation,
    creep's). On a 0.4 s record: 5 Hz, the cap below 25 Hz, none above; a 35.5 s record keeps the 1 Hz floor."""
    t = np.arange(40_000) * 1e-5
    dur = t[-1] - t[0]
    lo, _ = Resonance()._range(t)
    assert np.exp(lo) == pytest.approx(2.0 / dur)
    zeta = Resonance()._ring_cap(t)
    assert zeta(0.9 * 10.0 / dur, 0.3) == pytest.approx(1.0 / (2.0 * np.pi))
    assert zeta(1.1 * 10.0 / dur, 0.3) == 0.3
    lo_long, _ = Resonance()._range(np.arange(355_000) * 1e-4)
    assert np.exp(lo_long) == pytest.approx(1.0)


# make test runs 28 #99 and 26 #11 (session 31, s31_suite); 26 #31 (creep + delay 0.2x, 1 kHz steps, both named)
# runs under WORKBENCH_FULL=1: make test's record of its family and kind is test_stages.py's
# test_json_stages_of_a_two_effect_record[creep+delay] (creep + delay 0.18x, 1 kHz steps: both named)
@pytest.mark.parametrize("seed, index, want", reduced_draws([(28, 99, ["resonance", "drift"]), (26, 11, ["drift"]),
                                                            # (26 #31 was a strict xfail after s11_qconv: the delay
                                                            # won 4 of 5 later folds; with its weights refitted per
                                                            # fold, s11_delayfold, it wins the fifth)
                                                            (26, 31, ["creep", "delay"])], keep={0, 1}))
def test_regression_a_drift_is_not_creep_unless_the_charge_shows_it(sn637, seed, index, want):
    """Regression records (tuned on): a drift (with a mode) whose displacement relaxation the
    charge does not show is named drift, not creep (28 #99 was resonance + creep, 26 #11
    inconclusive 3 of 5); a creep record whose charge shows it stays creep (26 #31)."""
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, s = cc.cases(seed=seed)[index - 1]
    _, res, _, _ = _trace(sn637, e, rate, proto, size, s)
    assert [st["effect"] for st in res["stages"]] == want
