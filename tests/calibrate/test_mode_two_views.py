"""The stack's one mode, read by two sensors: named on the view whose mode reads both better (session 29).

The gauge and the displacement sensor read the same motion; where both views' mode rows pass a fold the mode
was named on the displacement (the plant file's form), its parameters the displacement's search's. A
displacement-sensor drift beside the mode biases that search (the confusion benchmark's 22 #154 at 1 MHz
sine: the displacement's 53.6 Hz at the 0.002 damping floor for a 54.2 Hz, zeta 0.0159 mode, the gauge's
54.1 Hz, zeta 0.0167), and the gauge, carrying that mode, ended 9x above its own. ``tracing._mode_reads_both``
carries each view's mode as naming it would, scores both sensors held out (every development block once)
and names the gauge's when its joint misfit is resolved below the displacement's; a tie stays the
displacement's.

Constructed records (a linear stack through a mode discretised for the held drive; a displacement sensor
(1 nm noise) and a gauge (22 nm, the benchmark's gauge chain per 10 kHz sample) of the same motion; a slow
sensor drift, a quadratic in time, on one of them), each view's mode searched by the tracing's own
``_candidate_columns`` and scored by its ``_score_stage``: cheap (~0.5 s a record).
"""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from workbench.calibrate import tracing as T
from workbench.calibrate.effects import Resonance
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import benchmark_protocol

DX, GX = ("displacement", "model"), ("gauge", "model")
SIG_D, SIG_G = 1e-9, 22e-9


def _named(rate, rows, f_mode, zeta, protocol, drift_d=0.0, drift_g=0.0, seed=0):
    """The first stage's fold winners and each view's mode (``{channel: params}``).

    ``drift_d`` / ``drift_g``: the displacement's / the gauge's sensor drift over the record (m), against a
    ~1e-5 m motion."""
    t, v = benchmark_protocol(protocol, rate, rows)
    y = 1e-7 * v                                    # a linear stack, 0.1 um/V: the base's prediction
    w = 2 * np.pi * f_mode
    b, a, _ = signal.cont2discrete(([w * w], [1.0, 2 * zeta * w, w * w]), 1.0 / rate, method="zoh")
    x = signal.lfilter(np.ravel(b)[1:], a, y - y[0]) + y[0]
    rng = np.random.default_rng(seed)
    s = (t - t[0]) / (t[-1] - t[0])
    slow = s - 0.8 * s * s
    sp = make_split(t, v, "blocks")
    probs, cands, nulls = {}, [], {}
    infos = {"duration_s": float(t[-1] - t[0]), "t": t}
    for key, drift, sig in ((DX, drift_d, SIG_D), (GX, drift_g, SIG_G)):
        xo = x + drift * slow + sig * rng.standard_normal(t.size)
        prob = T._Problem(sp, np.ones(t.size, bool), np.column_stack([y, np.ones(t.size)]), [-np.inf, -np.inf],
                          xo - y, T._search_rows(sp.train))
        probs[key] = prob
        eff = Resonance()
        p, g = T._candidate_columns(eff, t, y, xo, y, prob)
        cands.append({"name": "resonance", "channel": key[0], "key": key, "eff": eff, "g": g, "n_params": 3,
                      "params": p, "yhat": y})
        e_dev = np.where(prob.rows_dev, prob.r, 0.0)
        nulls[key] = [prob.grams(T._phase_randomized(e_dev, rng), [-np.inf]) for _ in range(3)]
        infos[key[0]] = {"noise_floor": sig}
    # what :func:`tracing._absorb` reads of the base: the time and each channel's prediction and sampling
    infos["base"] = SimpleNamespace(t=t, channels={ch: SimpleNamespace(yhat=y, sampling="instant")
                                                   for ch in ("displacement", "gauge")})
    res = T._score_stage(cands, probs, nulls, {DX: [], GX: []}, sp, 0.02, 1.0, infos, [], T.MIN_SHARE)
    return res["winners"], {c["channel"]: c["params"] for c in cands}


def _err(p, zeta):
    return abs(p["zeta"] / zeta - 1.0)


#: Noise seeds per constructed record: the rule is a held-out test, and one seed shows only that one draw passes
#: (session 30's review: the pooled one-sided test of session 29 passed the tie test's seed 0 and flipped seeds
#: 7, 10, 15, 16 and 19 of 20 to the gauge)
SEEDS = range(12)


def _on_gauge(seeds, **kw):
    """Per noise seed, the folds that name the mode on the gauge, and each seed's views' parameters."""
    out = [_named(seed=s, **kw) for s in seeds]
    return [sum(1 for w in winners if tuple(w) == ("resonance", "gauge")) for winners, _ in out], [p for _, p in out]


@pytest.mark.parametrize("rate, rows, f_mode, zeta, protocol, drift", [
    (1e4, 1000, 54.2, 0.0159, "sine", 3e-5),          # 22 #154's mode and record length (0.1 s, 5.4 cycles)
    (1e4, 1000, 120.0, 0.010, "calibration", 2e-5),
])
def test_a_mode_beside_a_displacement_drift_is_named_on_the_gauge(rate, rows, f_mode, zeta, protocol, drift):
    """The displacement sensor drifts (2-3x the stack's motion over the record), the gauge does not: the
    displacement's search leaves the damping >= 10 % off, the gauge's within 5 %, and every fold names the
    mode on the gauge, its damping the gauge's (before: on the displacement, 5 of 5), on every noise seed."""
    folds, params = _on_gauge(range(4), rate=rate, rows=rows, f_mode=f_mode, zeta=zeta, protocol=protocol,
                              drift_d=drift)
    for p in params:
        assert _err(p["displacement"], zeta) > 0.10 and _err(p["gauge"], zeta) < 0.05, p   # the premise
    assert folds == [5] * 4, folds


def test_a_mode_beside_a_gauge_drift_stays_on_the_displacement():
    """The guard, the sensors' roles swapped: the gauge drifts, the displacement does not; the mode stays the
    displacement's on every fold and noise seed (the rule follows the better reading, not a sensor)."""
    folds, params = _on_gauge(range(4), rate=1e4, rows=1000, f_mode=54.2, zeta=0.0159, protocol="sine",
                              drift_g=3e-5)
    assert all(_err(p["displacement"], 0.0159) < 0.05 for p in params), params
    assert folds == [0] * 4, folds


@pytest.mark.parametrize("f_mode, zeta, protocol", [(54.2, 0.0159, "sine"), (80.0, 0.010, "steps")])
def test_one_mode_both_views_found_stays_on_the_displacement(f_mode, zeta, protocol):
    """No drift: both views find one mode (the same frequency to 3 digits); the gauge's reading is not
    resolved beyond the displacement's, and the mode keeps the plant file's form, on the displacement, on
    every fold of every noise seed (a tie decided by chance would flip about one seed in six: session 29's
    pooled test flipped 5 of 20 sine seeds and 6 of 20 steps seeds)."""
    folds, params = _on_gauge(SEEDS, rate=1e4, rows=1000, f_mode=f_mode, zeta=zeta, protocol=protocol)
    for p in params:
        assert abs(p["gauge"]["f_n_hz"] / p["displacement"]["f_n_hz"] - 1) < 1e-3, p
    assert folds == [0] * len(SEEDS), folds


def _own_then_carried(mode_hz, carried_hz, seed=0):
    """A displacement with its own stage (a drift, its columns found) and a mode its own stages do not model;
    the mode named on the gauge is carried at ``carried_hz`` (the true ``mode_hz``, or a wrong one).
    Returns ``(c, out, drift_only_rms)`` after :func:`tracing._carry_beside_own`."""
    t, v = benchmark_protocol("steps", 1e4, 1000)
    y = 1e-7 * v
    x = y + Resonance._column(y, mode_hz, 0.01, 1e-4)     # the mode as the tracing's column models it
    s = (t - t[0]) / (t[-1] - t[0])
    drift = np.column_stack([s, s * s])
    rng = np.random.default_rng(seed)
    xo = x + 2e-6 * (drift @ [1.0, -0.8]) + SIG_D * rng.standard_normal(t.size)
    sp = make_split(t, v, "blocks")
    prob = T._Problem(sp, np.ones(t.size, bool), np.column_stack([y, np.ones(t.size)]), [-np.inf, -np.inf],
                      xo - y, T._search_rows(sp.train))
    mine = T.FoundColumns(drift, [-np.inf, -np.inf], ("drift", "displacement"))
    carried = (Resonance._column(y, carried_hz, 0.01, 1e-4)[:, None], [-np.inf])
    drift_only = T._test_errors(prob, T._stacked(prob, [mine], None), sp.dev_blocks, sp.test_blocks)
    c = {"error_after": {**drift_only, "units": "m"}, "units": "m"}
    out = {"channel": "displacement", "error_after": dict(c["error_after"])}
    e_dev = np.where(prob.rows_dev, prob.r, 0.0)
    ctx = {"nulls": {DX: [prob.grams(T._phase_randomized(e_dev, rng), [-np.inf]) for _ in range(3)]},
           "penalty": 0.02, "noise_factor": 1.0, "min_share": T.MIN_SHARE, "need": 4,
           "infos": {"displacement": {"noise_floor": SIG_D}}}
    stages = [{"effect": "drift", "channel": "displacement", "_cand": {"key": DX}},
              {"effect": "resonance", "channel": "gauge", "_cand": {"key": GX}}]
    T._carry_beside_own(out, c, "displacement", stages, [mine, carried], prob, sp, ctx)
    return c, out, drift_only["rms"]


def test_the_gauges_mode_carried_beside_the_displacements_own_stage_enters_its_error():
    """105 #165's order (a drift on the displacement, then the stack's mode named on the gauge): the mode's
    column carried into the displacement takes its error after from the drift stage's to the sensor's noise
    (1 nm), and the answer's error follows (before: the drift stage's error, the carried mode left out)."""
    c, out, before = _own_then_carried(80.0, 80.0)
    assert c.get("carried") == ["resonance"], c
    assert c["error_after"]["rms"] < 2 * SIG_D < 0.1 * before, (c["error_after"], before)
    assert out["error_after"]["rms"] == c["error_after"]["rms"]


def test_a_carried_mode_the_record_does_not_hold_is_refused():
    """The guard: the column carried at 2.2x the record's mode explains nothing of it held out; the folds refuse
    it and the error after stays the drift stage's."""
    c, out, before = _own_then_carried(80.0, 176.0)
    assert c.get("carry_refused") == ["resonance"] and "carried" not in c, c
    assert c["error_after"]["rms"] == before == out["error_after"]["rms"]
