"""The straight-line floor of issue 13: no channel's reported held-out error above a line's.

The records are the confusion benchmark's own draws (``benchmarks/calibrate_confusion.py``,
seed 23, records #77 and #82: a structural resonance at 100 kHz, drawn size and noise seed)
where the base cannot beat a straight line of the drive on the gauge: the gauge reads the
displacement, ringing and all, and the rate-independent base has no mode. The resonance is
named on the displacement; carried into the gauge's model (its gains refitted on the
development rows, kept by the validation folds), the gauge's error at the end must be below
the line's on the test part. Without the carry (the base's error reported) both fail.
"""

import numpy as np
import pytest

from tests.conftest import load_benchmark
from workbench.calibrate.base_fit import fit_base
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
from workbench.calibrate.tracing import trace_effect


def _end_errors(res):
    """Each channel's reported held-out RMS at the end: its last own stage's, else ``error_after``."""
    out = {ch: c["error_after"]["rms"] for ch, c in res["channels"].items()}
    for s in res["stages"]:
        out[s["channel"]] = s["error_after"]["rms"]
    return out


@pytest.mark.parametrize("index", (77, 82))
def test_a_channel_the_base_cannot_beat_a_line_on_ends_below_the_line(sn637, index):
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, seed = cc.cases(seed=23)[index - 1]
    assert rate == 1e5 and "resonance" in (e if isinstance(e, tuple) else (e,))
    t, v = benchmark_protocol(proto, rate, cc.ROWS[rate])
    plant, _ = plant_with_effect(sn637, e, seed, duration_s=float(t[-1]), size=size)
    r = simulate_record(plant, t, v, seed=seed)
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(cc._record(r, 1.0 / rate), sn637.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    g = base.channels["gauge"]
    # the case: the base alone is above the line on the gauge's test rows
    assert g.rms_test > g.line_rms_test
    res = trace_effect(base, split=sp)
    assert ("resonance", "displacement") in [(s["effect"], s["channel"]) for s in res["stages"]]
    assert res["channels"]["gauge"].get("carried") == ["resonance"]
    end = _end_errors(res)
    for ch, err in end.items():
        assert np.isfinite(err) and err <= base.channels[ch].line_rms_test, (ch, err, base.channels[ch].line_rms_test)


@pytest.mark.parametrize("draw", range(3))
def test_the_ridge_grids_last_entry_is_the_straight_line_itself(draw):
    """``ridge = inf`` (RIDGE_GRID's last entry) is the line of ``_line`` on the same rows, to the
    bit: the base nests the line exactly, so a cross-validation that picks it cannot end above
    it. Drawn: a hysteretic channel (PI weights, gain, offset, noise) of a random-walk drive."""
    from workbench.calibrate import base_fit as bf
    from workbench.calibrate.pi_fit import pi_thresholds, play_matrix
    rng = np.random.default_rng(400 + draw)
    n = 4000
    v = np.cumsum(rng.normal(size=n)) * 10.0 ** rng.uniform(-1, 1)
    r = pi_thresholds(v, 12, "quadratic")
    P = play_matrix(v, r, np.zeros(r.size))
    y = P @ rng.uniform(0, 1, r.size) * 10.0 ** rng.uniform(-9, 1) + rng.normal() \
        + rng.normal(size=n) * 10.0 ** rng.uniform(-3, 0) * np.std(P[:, 0])
    train = np.arange(n) < 3 * n // 4
    valid = np.ones(n, bool)
    assert bf.RIDGE_GRID[-1] == np.inf
    m = bf._fit_channel("displacement", P, y, train, valid, r, np.zeros(r.size), ridge=np.inf)
    slope, off, line_rms = bf._line(v, y, train, ~train)
    assert np.all(m.weights[1:] == 0) and m.weights[0] == slope and m.offset == off
    assert bf.rms(m.residual[~train]) == line_rms
