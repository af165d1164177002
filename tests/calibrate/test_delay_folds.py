"""The refitted delay's fold scores are honest (issue 13, finding 1).

The delay's column carries the drive model's ~26 weights refitted at the searched delay. Fitted
on all development rows, those weights had seen every fold's validation rows while the fold
fitted only the column's gain. Now each fold's column is refitted on that fold's training
search rows only (:meth:`workbench.calibrate.effects.Delay.fold_columns`), so a fold's
prediction on its validation rows cannot depend on the record there: corrupting ``y`` on the
validation rows and on every row outside the fold's training search rows leaves it unchanged
(to rounding), while the shipped single column (weights fitted on the development rows) moves.

Records: the confusion benchmark's simulated records, one per protocol, a delay or a creep
drawn with a size log-uniform over 1-20x the drawn ranges, rate drawn from 1 and 10 kHz;
``default_rng`` fixed before any run. The corruption: ten times the residual's RMS, white.
"""

import numpy as np
import pytest

from tests.conftest import load_benchmark
from workbench.calibrate import tracing as T
from workbench.calibrate.base_fit import fit_base
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record

RNG = np.random.default_rng(1313)
DRAWS = [(proto, str(RNG.choice(["delay", "creep"])), float(RNG.choice([1000.0, 10000.0])),
          float(np.exp(RNG.uniform(0.0, np.log(20.0)))), int(RNG.integers(1 << 30)))
         for proto in ("sine", "steps", "calibration")]


def _problem(plant0, proto, effect, rate, size, seed):
    cc = load_benchmark("calibrate_confusion")
    t, v = benchmark_protocol(proto, rate, cc.ROWS[rate])
    plant, _ = plant_with_effect(plant0, effect, seed, duration_s=float(t[-1]), size=size)
    r = simulate_record(plant, t, v, seed=seed)
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(cc._record(r, 1.0 / rate), plant0.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    m = base.channels["displacement"]
    lower = T._base_lower(base, "displacement")
    search = T._search_rows(sp.train & m.valid)
    plan = T.candidate_plan(base.channels, t, base.v_drive, tau_min_s=sp.block_s, basis=base.basis)
    (dl,) = [e for ch, e, _ in plan if e.name == "delay" and ch == "displacement"]
    return t, sp, base, m, lower, search, dl


@pytest.mark.parametrize("proto, effect, rate, size, seed", DRAWS)
def test_a_fold_prediction_ignores_its_validation_rows(sn637, proto, effect, rate, size, seed):
    t, sp, base, m, lower, search, dl = _problem(sn637, proto, effect, rate, size, seed)
    prob = T._Problem(sp, m.valid, base.basis, lower, m.y - m.yhat, search)
    p, g = T._candidate_columns(dl, t, m.yhat, m.y, m.yhat, prob)
    assert p.get("refit")
    fg = T._fold_grams(dl, p, t, m.y, m.yhat, prob, lower)
    noise = np.random.default_rng(seed).standard_normal(t.size) * 10 * np.std(m.y - m.yhat)
    moved_shipped = []
    for f, (tr, va) in enumerate(sp.folds):
        seen = prob.search & sp.rows(tr)               # the only rows fold f may fit on
        y_bad = np.where(seen, m.y, m.y + noise)
        prob_bad = T._Problem(sp, m.valid, base.basis, lower, y_bad - m.yhat, search)
        fg_bad = T._fold_grams(dl, p, t, y_bad, m.yhat, prob_bad, lower)
        val = sp.rows(va) & m.valid
        clean = prob.predict(fg[f], tr)[0][val]
        bad = prob_bad.predict(fg_bad[f], tr)[0][val]
        scale = np.sqrt(np.mean(clean ** 2))
        assert np.max(np.abs(bad - clean)) <= 1e-6 * scale, (f, np.max(np.abs(bad - clean)) / scale)
        # the shipped column (weights on all development rows, the fold only the gain) moves
        dl_old = type(dl)(max_delay=dl.max_delay, basis=dl.basis)
        p_old = dl_old.fit(t, m.yhat, y_bad - m.yhat, search, y_model=m.yhat)
        p_old = {**p_old, "delay_samples": p["delay_samples"]} if p_old["delay_samples"] != p["delay_samples"] else p_old
        g_old = prob_bad.grams(dl_old.term(t, m.yhat, p_old, y_model=m.yhat), [0.0])
        shipped = prob.predict(g, tr)[0][val]
        moved_shipped.append(np.max(np.abs(prob_bad.predict(g_old, tr)[0][val] - shipped)) / scale)
    # the test has teeth: the old scoring's prediction on the validation rows depends on them
    assert max(moved_shipped) > 1e-3, moved_shipped
