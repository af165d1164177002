"""A slow mode or a drift (session 18): a mode under ten cycles a record must beat the drift in time.

The mode search reaches two cycles over the record (``effects.RING_CYCLES_PER_RECORD``, session 17, for the
27-73 Hz modes of 0.1 s records at 1 MHz). A mode that slow is a slow shape over the record, and a small
sensor drift was fitted by one: seed 66 #73 (a 0.14x drift, 100 kHz calibration protocol, 0.4 s) was named
``resonance`` 4 of 5 with a 5 Hz, zeta 0.002 mode at the search's floor, while the drift left less on every
fold (its hold check vetoed it). :func:`~workbench.calibrate.tracing._slow_mode_against_drift` lets a slow
mode pass only the folds where it beats its channel's drift. Asserted, on the product path (simulator ->
base fit -> tracing):

* drawn drifts on short high-rate records, sizes one per log-band of the benchmark's 0.03-30x, protocol
  drawn among the three, are never named a resonance (66 #73 itself among them);
* a genuine lightly damped mode of 3-8 cycles over the record (the plant's closed-form second-order mode,
  the simulator's damping range), drawn on the calibration protocol, the drive with holds where the drift
  row is scored beside it, is still named, and its frequency found within 10 %.
"""

import dataclasses

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws, stratified_draws
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
from workbench.calibrate.tracing import trace_effect
from workbench.plant.pzt import Mode

RATE_HZ = 1e5
N_ROWS = 20_000          # 0.2 s at 100 kHz: half the benchmark's 0.4 s (the calibration protocol's chirp needs
                         # 0.1 s at 1 MHz, twice this test's rows there)


def _bench():
    return load_benchmark("calibrate_confusion")


def _named(base, sp):
    res = trace_effect(base, split=sp)
    return [s["effect"] for s in res["stages"]], res


def test_64_154_a_slow_mode_beside_a_drift_keeps_its_folds(sn637):
    """A genuine slow mode beside a genuine drift (64 #154: a 61.9 Hz mode, 6 cycles over the 0.1 s record,
    beside an 18x drift, 1 MHz sine) is scored with the drift polynomial in its model, not against it side by
    side: set side by side the drift took a fold and a 128 Hz gauge mode was named 2 of 5 (the s18_slowmode
    review). A regression check on a check seed of session 17, not fresh evidence."""
    cc = _bench()
    e, rate, proto, size, seed = cc.cases(seed=64, ends=True)[153]
    assert (tuple(e), rate, proto) == (("drift", "resonance"), 1e6, "sine")
    t, sp, base, _, truth, _ = cc.simulated_base(sn637, e, rate, proto, size, seed)
    named, res = _named(base, sp)
    assert named and named[0] == "resonance", (named, res["fold_winners"])
    # session 30 (tracing._mode_reads_both): named on the gauge, whose mode reads both sensors better held out
    # (the gauge's 61.96 Hz, zeta 0.0203; the displacement's, beside its drift, 67.68 Hz at the 0.002 damping
    # floor; the truth 61.91 Hz, 0.0181): either view, the named mode is the record's, its damping too
    assert res["stages"][0]["channel"] in ("displacement", "gauge"), res["stages"][0]
    par = res["stages"][0]["parameters"]
    assert abs(par["f_n_hz"] / truth["freq_hz"] - 1.0) < 0.1, (truth, res["stages"][0])
    assert abs(np.log(par["zeta"] / truth["damping_ratio"])) < np.log(1.5), (truth, res["stages"][0])


def test_66_73_a_small_drift_is_not_named_a_slow_mode(sn637):
    """The record the fix is for (a regression check, not evidence: it was tuned on)."""
    cc = _bench()
    e, rate, proto, size, seed = cc.cases(seed=66)[72]
    assert (e, rate, proto) == ("drift", 1e5, "calibration")
    t, sp, base, _, _, _ = cc.simulated_base(sn637, e, rate, proto, size, seed)
    named, res = _named(base, sp)
    assert "resonance" not in named, (named, res["fold_winners"])


# one size per log-band of the benchmark's range, drawn before any run (conftest.stratified_draws(1801, 6));
# make test runs one (0.33x, near the floor), WORKBENCH_FULL all six (the suite is at its time budget)
DRIFT_DRAWS = reduced_draws(stratified_draws(1801, 6), keep=(2,))


@pytest.mark.parametrize("proto, size, seed", DRIFT_DRAWS)
def test_a_drift_on_a_short_record_is_never_named_a_mode(sn637, proto, size, seed):
    cc = _bench()
    t, sp, base, _, truth, _ = cc.simulated_base(sn637, "drift", RATE_HZ, proto, size, seed, n_rows=N_ROWS)
    named, res = _named(base, sp)
    assert "resonance" not in named, (proto, size, truth, named, res["fold_winners"])


def _mode_record(sn637, draw):
    rng = np.random.default_rng([1802, draw])
    t, v = benchmark_protocol("calibration", RATE_HZ, N_ROWS)
    dur = float(t[-1] - t[0])
    truth = {"freq_hz": float(rng.uniform(3.0, 8.0)) / dur, "damping_ratio": float(rng.uniform(0.005, 0.02))}
    seed = int(rng.integers(1 << 30))
    plant, _ = plant_with_effect(sn637, "none", seed)
    plant = dataclasses.replace(plant, pzt=dataclasses.replace(
        plant.pzt, modes=(Mode(truth["freq_hz"], truth["damping_ratio"]),)))
    r = simulate_record(plant, t, v, seed=seed)
    sp = make_split(t, r["voltage_v"], "blocks")
    cc = _bench()
    from workbench.calibrate.base_fit import fit_base
    base = fit_base(cc._record(r, 1.0 / RATE_HZ), plant.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    return truth, sp, base


# make test runs draw 1 (22 Hz, 4.4 cycles): the draw a rule that counted the drift's free sinusoid as a rival
# loses (the s18_slowmode review; draw 0, 7.7 cycles, passes under that rule too)
@pytest.mark.parametrize("draw", reduced_draws([(d,) for d in range(4)], keep=(1,)))
def test_a_slow_mode_beside_the_drift_row_is_still_named(sn637, draw):
    truth, sp, base = _mode_record(sn637, draw)
    named, res = _named(base, sp)
    assert named == ["resonance"], (truth, named, res["fold_winners"])
    f = res["stages"][0]["parameters"]["f_n_hz"]
    assert abs(f / truth["freq_hz"] - 1.0) < 0.1, (truth, res["stages"][0]["parameters"])
