"""The straight-line floor of issue 13: no channel's reported held-out error above a line's.

Regression records (the ones the carry was built on, so not held-out evidence for it): the
confusion benchmark's seed 23, records #77 and #82 (a structural resonance at 100 kHz, drawn
size and noise seed), where the base cannot beat a straight line of the drive on the gauge:
the gauge reads the displacement, ringing and all, and the rate-independent base has no mode.
The resonance is named on the displacement; carried into the gauge's model (its gains refitted
on the development rows, kept by the validation folds' test), the gauge's error at the end must
be below the line's on the test part. Without the carry (the base's error reported) both fail.
Since session 29 #77's mode is named on the gauge (its mode reads both sensors better held out,
``tracing._mode_reads_both``) and carried into the displacement: the floor asserted is the same.

Beside them: the carry's fold test on constructed problems (a real drop under the noise floor
is refused), and drawn 100 kHz records of the effects the carry applies to, sizes from the
whole range, where the floor must hold unless the tool warns.
"""

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws, stratified_draws
from workbench.calibrate.tracing import trace_effect


def _end_errors(res):
    """Each channel's reported held-out RMS at the end (``error_after``: its model of the drive after
    its last own stage or the carry, else the base's)."""
    return {ch: c["error_after"]["rms"] for ch, c in res["channels"].items()}


@pytest.mark.parametrize("index", (77, 82))
def test_a_channel_the_base_cannot_beat_a_line_on_ends_below_the_line(sn637, index):
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, seed = cc.cases(seed=23)[index - 1]
    assert rate == 1e5 and "resonance" in (e if isinstance(e, tuple) else (e,))
    t, sp, base, _, _, _ = cc.simulated_base(sn637, e, rate, proto, size, seed)
    g = base.channels["gauge"]
    # the case: the base alone is above the line on the gauge's test rows
    assert g.rms_test > g.line_rms_test
    res = trace_effect(base, split=sp)
    named = [(s["effect"], s["channel"]) for s in res["stages"]]
    if ("resonance", "gauge") in named:
        # session 29 (tracing._mode_reads_both): the gauge's mode reads both sensors better held out and is
        # named on the gauge, its own stage (#77: 79.82 Hz, zeta 0.0110 for 79.83, 0.0111; the displacement's
        # 80.14, 0.0082); the displacement carries it, on its own model of the drive refitted under the mode
        # (session 30, tracing._refitted_carry): the displacement is read through the same mode as the gauge,
        # which it ends at its floor, so the mode leaves no more than a tenth of the line's error there (the
        # mode's column on the displacement's base prediction alone left 0.28 of it, the displacement's own
        # mode reading 0.20, the refitted carry 0.04)
        d = res["channels"]["displacement"]
        assert d.get("carried") == ["resonance"], d
        assert d["error_after"]["rms"] < 0.1 * base.channels["displacement"].line_rms_test, d["error_after"]
    else:
        assert ("resonance", "displacement") in named
        assert res["channels"]["gauge"].get("carried") == ["resonance"]
    if index == 77:
        # the charge does not see the mode above its floor: carried, its validation error fell
        # 1 % and its test error rose (9.534e-8 -> 9.626e-8 C); the fold test refuses it (named on the
        # gauge too: since session 30 that carry is tested and reported, tracing._carried_into)
        assert res["channels"]["charge"].get("carry_refused") == ["resonance"]
    assert "carried" not in res["channels"]["charge"]
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


@pytest.mark.parametrize("draw", range(3))
def test_the_carry_passes_the_fold_test_not_any_drop(draw):
    """A carried column that truly lowers every validation fold's error but explains less than
    the noise floor (0.1-0.5 of it in RMS) is refused; the same column 2-10x the floor is kept.
    Drawn: the record's drive, the noise, the sizes, the column (a filtered random walk)."""
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.tracing import MIN_SHARE, _carry_passes, _Problem, _search_rows
    rng = np.random.default_rng(900 + draw)
    n = 40_000
    t = np.arange(n) * 1e-5
    v = 50.0 * np.sin(2 * np.pi * 25.0 * t) + np.cumsum(rng.normal(size=n)) * 0.05
    sp = make_split(t, v, "blocks")
    A = np.column_stack([v, np.ones(n)])
    col = np.convolve(np.cumsum(rng.normal(size=n)), np.ones(50) / 50, "same")
    col = (col - col.mean()) / col.std()
    sigma = 10.0 ** rng.uniform(-9, -1)
    noise = rng.normal(size=n) * sigma
    valid = np.ones(n, bool)
    ctx = {"need": int(np.ceil(0.8 * len(sp.folds))), "penalty": 0.02, "noise_factor": 1.0,
           "min_share": MIN_SHARE}
    for share, keep in ((rng.uniform(0.1, 0.5), False), (rng.uniform(2.0, 10.0), True)):
        r = noise + share * sigma * col
        prob = _Problem(sp, valid, A, [-np.inf, -np.inf], r, _search_rows(sp.train))
        g = prob.grams(col, [-np.inf])
        before = sum(prob.fold_rms(prob.base, tr, va) ** 2 for tr, va in sp.folds)
        after = sum(prob.fold_rms(g, tr, va) ** 2 for tr, va in sp.folds)
        assert after < before                      # a drop: the old rule kept every such carry
        assert _carry_passes(prob, g, 1, (), sp, ctx, sigma) is keep, (share, after / before)


def _floor_draws():
    """(effect, protocol, size, seed) at 100 kHz, ``default_rng(2311)`` fixed before any run."""
    from workbench.calibrate.synthetic import PROTOCOLS
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(2311)
    lo, hi = np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1])
    out = []
    for e in ("creep", "resonance", ("creep", "delay"), ("drift", "resonance")):
        proto = PROTOCOLS[int(rng.integers(len(PROTOCOLS)))]
        out.append((e, proto, float(np.exp(rng.uniform(lo, hi))), int(rng.integers(1 << 30))))
    return out


#: make test: drift + resonance (session 28, for the suite's time: creep alone moved to the full form; session 27's
#: make test ran creep and drift + resonance, session 22's all four); WORKBENCH_FULL=1 all four
@pytest.mark.parametrize("e, proto, size, seed", reduced_draws(_floor_draws(), keep={3}))
def test_the_floor_holds_on_drawn_records_the_carry_applies_to(sn637, e, proto, size, seed):
    """Drawn 100 kHz records (the rate where the gauge sees a mode) of the effects carried from
    the displacement (creep, a resonance, and the benchmark's pairs holding them), sizes
    log-uniform over the benchmark's whole range, protocol and noise seed drawn
    (``default_rng(2311)``, fixed before any run). Every channel's reported held-out error at
    the end is at most the straight line's, unless the base warns about that channel."""
    cc = load_benchmark("calibrate_confusion")
    _, sp, base, _, _, _ = cc.simulated_base(sn637, e, 1e5, proto, size, seed)
    res = trace_effect(base, split=sp)
    for ch, err in _end_errors(res).items():
        warned = any(f"on the {ch} channel" in w for w in base.warnings)
        assert np.isfinite(err) and (err <= base.channels[ch].line_rms_test or warned), \
            (e, proto, size, ch, err, base.channels[ch].line_rms_test)


def _bow_end(sn637, proto, size, seed, rate=1e5, n_rows=None):
    """A gauge-bow benchmark record traced (``n_rows``: default the benchmark's): ``(base, res, gauge's end
    RMS, its line's, its noise floor)``."""
    cc = load_benchmark("calibrate_confusion")
    _, sp, base, _, _, _ = cc.simulated_base(sn637, "gauge_nonlinearity", rate, proto, size, seed, n_rows=n_rows)
    res = trace_effect(base, split=sp)
    g = res["channels"]["gauge"]
    return base, res, g["error_after"]["rms"], base.channels["gauge"].line_rms_test, g["noise_floor"]


def test_a_large_gauge_bow_at_100_khz_ends_clearly_below_the_line(sn637):
    """Regression record (the one the bow's carry was built on, not held-out evidence): seed 67 #74, a
    20.7x gauge bow at 100 kHz under the calibration protocol. The bow bends the gauge's whole map one
    way; the base's play weights are non-negative (each branch bends away from its turning point), so
    its ridge path ends at the straight line and the base *is* the line (0.0202 V on the test rows).
    The bow is named against the recorded displacement; carried into the gauge's model of the drive
    (the bow's column of the displacement's model), the gauge's end error must be clearly below the
    line (the tool's own bar, ``LINE_MARGIN``). Session 17's code reported the base: 1.000x the line,
    1.7e-17 V above it by rounding."""
    from workbench.calibrate.base_fit import LINE_MARGIN
    cc = load_benchmark("calibrate_confusion")
    e, rate, proto, size, seed = cc.cases(seed=67)[74 - 1]
    assert (e, rate, proto) == ("gauge_nonlinearity", 1e5, "calibration")
    base, res, end, line, floor = _bow_end(sn637, proto, size, seed)
    assert np.isinf(base.channels["gauge"].ridge)          # the case: the base is the line
    assert [s["effect"] for s in res["stages"]] == ["gauge_nonlinearity"]
    assert end <= LINE_MARGIN * line, (end, line)
    # and what is left is the gauge's white noise (within 10 %): the bow and the stack explain the rest
    assert end <= 1.1 * floor, (end, floor)
    assert res["channels"]["gauge"].get("carried") == ["gauge_nonlinearity"]


#: gauge bows at 100 kHz, one size per log-band of the benchmark's whole range (``stratified_draws``:
#: ``default_rng(1874)``, fixed before any run), the protocol drawn among the three; make test runs the
#: largest band (where the base's ridge path ends at the line), WORKBENCH_FULL=1 all four
_BOW_DRAWS = stratified_draws(1874, 4)


@pytest.mark.parametrize("proto, size, seed", reduced_draws(_BOW_DRAWS, keep=(3,)))
def test_drawn_gauge_bows_at_100_khz_never_end_above_the_line(sn637, proto, size, seed):
    """The floor on drawn gauge-bow records at 100 kHz, short (0.2 s, 20,000 rows: half the benchmark's;
    the protocol scales to the record): the gauge's reported end error is at most the straight line's,
    and where the bow is named, clearly below it (``LINE_MARGIN``) or within 1.5x the gauge's white
    noise (nothing a model could still explain: on a short record the noise can be most of the line's
    error)."""
    from workbench.calibrate.base_fit import LINE_MARGIN
    base, res, end, line, floor = _bow_end(sn637, proto, size, seed, n_rows=20_000)
    assert end <= line, (proto, size, end, line)
    if "gauge_nonlinearity" in [s["effect"] for s in res["stages"]]:
        assert end <= max(LINE_MARGIN * line, 1.5 * floor), (proto, size, end, line, floor)


@pytest.mark.parametrize("draw", range(3))
@pytest.mark.parametrize("own_stage", (False, True))
def test_a_model_that_is_the_line_reports_the_line_not_above_it(draw, own_stage):
    """A channel whose end model *is* the straight line (its columns the identity play and the offset:
    a base whose ridge path ended at the line) ties the line on every fold up to the Gram route's
    rounding; :func:`_line_fallback` gives the tie to the line, so the reported held-out error is the
    line's own, never above it (seed 67 #74's gauge was 1.7e-17 V above). Drawn: the drive (a sine and
    a random walk), the channel's gain, offset and noise over decades; 20,000 rows. ``own_stage``: the
    same for a channel with stages of its own (their note says so)."""
    from types import SimpleNamespace
    from workbench.calibrate.base_fit import _line
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.tracing import _line_fallback, _Problem, _search_rows
    rng = np.random.default_rng(1875 + draw)
    n = 20_000
    t = np.arange(n) * 1e-4
    v = 50.0 * np.sin(2 * np.pi * rng.uniform(2, 20) * t) + np.cumsum(rng.normal(size=n)) * 0.05
    gain, sigma = 10.0 ** rng.uniform(-9, 1), 10.0 ** rng.uniform(-3, 0)
    y = gain * (v + rng.normal() + sigma * np.std(v) * rng.normal(size=n))
    sp = make_split(t, v, "blocks")
    valid = np.ones(n, bool)
    slope, off, line_rms = _line(v, y, sp.train, sp.test)
    basis = np.column_stack([v, np.ones(n)])
    prob = _Problem(sp, valid, basis, [-slope, -np.inf], y - (slope * v + off), _search_rows(sp.train))
    m = SimpleNamespace(y=y, valid=valid, sampling="sampled", initial_states_v=np.zeros(1))
    base = SimpleNamespace(basis=basis, channels={"displacement": m})
    c = {"units": "m"}
    # (``own_stage`` passed only when set: the same call runs on the code before the own-stage check, where
    # the plain case must fail for its rounding, not for an unknown argument; the review of s18_line)
    _line_fallback(c, "displacement", prob, prob.base, base, sp, int(np.ceil(0.8 * len(sp.folds))),
                   **({"own_stage": True} if own_stage else {}))
    assert c.get("line") is True
    assert c["error_after"]["rms"] <= line_rms, (c["error_after"]["rms"], line_rms)
    assert ("effects found on it" in c["line_note"]) is own_stage


def test_a_carried_term_is_named_only_for_passing_its_own_step(sn637):
    """A creep + gauge bow record (10 kHz calibration, 3x, seed 11): the displacement's creep carried into the
    gauge's model fails the validation folds on its own (the review of s18_line, each subset tested alone: creep
    False, bow True, both True); carried together with the bow it rode in and was named ``carried``. The carry is
    stepwise: the creep's step, then the bow on top of what passed."""
    cc = load_benchmark("calibrate_confusion")
    t, sp, base, _, _, _ = cc.simulated_base(sn637, ("creep", "gauge_nonlinearity"), 1e4, "calibration", 3.0, 11)
    res = trace_effect(base, split=sp)
    g = res["channels"]["gauge"]
    assert "creep" not in (g.get("carried") or []), g.get("carried")
    assert "creep" in (g.get("carry_refused") or []), g.get("carry_refused")


#: Mode records at 100 kHz, one size per log-band of the benchmark's range (``stratified_draws(2611, 4)``:
#: 0.03-0.16, 0.16-0.9, 0.9-5.2, 5.2-30x); make test runs the largest band, WORKBENCH_FULL=1 all four.
@pytest.mark.parametrize("proto, size, seed", reduced_draws(stratified_draws(2611, 4), keep={3}))
def test_a_mode_named_on_the_displacement_leaves_the_gauge_what_its_twin_leaves(sn637, proto, size, seed):
    """The gauge reads the stack's motion, the mode's ringing included: a mode named on the displacement
    and carried to the gauge (the refitted mode's motion ``(H - 1) m``, read as the gauge reads it, its
    gain free) must leave the gauge's held-out error where the same record without the mode leaves it
    (the effect-free twin: the same drive and noise), within 1.25x. Before the carry took the found
    motion, it took the mode on the gauge's own base prediction, a drive the ringing had distorted:
    seed 104 #71 (a 7.2x 77 Hz mode at 100 kHz) left the gauge at 0.166 V, 23x its twin's and above
    its straight line's 0.136 V. Drawn: protocol, size (log-band), noise seed, mode."""
    cc = load_benchmark("calibrate_confusion")
    _, sp, base, _, truth, _ = cc.simulated_base(sn637, "resonance", 1e5, proto, size, seed)
    _, _, base0, _, _, _ = cc.simulated_base(sn637, "none", 1e5, proto, size, seed)
    res = trace_effect(base, split=sp)
    named = ("resonance", "displacement") in [(s["effect"], s["channel"]) for s in res["stages"]]
    if size >= 5.2:
        assert named, (proto, size, truth, res["effect"])
    if not named:
        pytest.skip(f"no mode named on the displacement ({res['effect']}): nothing carried")
    g = res["channels"]["gauge"]
    twin = base0.channels["gauge"].rms_test
    # (a mode the gauge reads under its noise floor is refused by the carry's fold test, and leaves the twin's error)
    assert g["error_after"]["rms"] <= 1.25 * twin, (proto, size, truth, g["error_after"]["rms"], twin, g.get("carried"))


#: The review of s26_modecarry's records (regression records, not held-out evidence): a 2x mode beside a
#: displacement-sensor delay (0.9-1.0 ms, 140-209 Hz) at 100 kHz steps, plant seeds 16, 20, 22, 23; make test runs 16.
@pytest.mark.parametrize("seed", reduced_draws([(16,), (20,), (22,), (23,)], keep={0}))
def test_the_gauge_carries_the_found_motion_beside_its_own_prediction(sn637, monkeypatch, seed):
    """The found motion ``(H - 1) m`` is the displacement *sensor's* reading: beside a displacement delay the stages
    did not name it holds the delay, which the gauge does not read. Carried alone (the first form of the change) the
    folds refused it on seeds 16 and 23 and it left the gauge 1.5-2.2x the mode taken on the gauge's own prediction
    (main's carry): 0.0189 against 0.0087 V on seed 16. Carried beside it, each column holds where the other misses:
    the gauge's carry is kept and its end error is no worse than with its own prediction's column alone, within 2 %."""
    import workbench.calibrate.tracing as tr
    cc = load_benchmark("calibrate_confusion")
    _, sp, base, _, truth, _ = cc.simulated_base(sn637, ("resonance", "delay"), 1e5, "steps", 2.0, seed)
    res = trace_effect(base, split=sp)
    assert [(s["effect"], s["channel"]) for s in res["stages"]] == [("resonance", "displacement")], res["stages"]
    g = res["channels"]["gauge"]
    assert g.get("carried") == ["resonance"], (truth, g)
    monkeypatch.setattr(tr, "_carried_motion", lambda C, fold, base, found_on, other: (np.zeros((C.shape[0], 0)), []))
    own = trace_effect(base, split=sp)["channels"]["gauge"]["error_after"]["rms"]
    assert g["error_after"]["rms"] <= 1.02 * own, (truth, g["error_after"]["rms"], own)


#: Drift + mode records at 1 MHz (0.1 s, the benchmark's 1 MHz length) where the mode is named on the displacement in
#: its plain variant (no refit). Constructed, not benchmark draws: ``(protocol, draw seed, size, noise seed)`` of
#: :func:`~workbench.calibrate.synthetic.plant_with_effect` and :func:`~workbench.calibrate.synthetic.simulate_record`:
#: the first drawn by session 28's check (rng 2828: rate, protocol, size log-uniform over 1-30x), the second 107 #154's
#: drawn plant with other noise. make test runs the first (one 1 MHz tracing); WORKBENCH_FULL=1 both.
PLAIN_MODE_DRAWS = [("steps", 657195613, 23.5, 657195613), ("sine", 343846121, 2.08, 7)]


@pytest.mark.slow
@pytest.mark.parametrize("proto, draw, size, noise", reduced_draws(PLAIN_MODE_DRAWS, keep={0}))
def test_a_plain_mode_beside_a_sensor_drift_leaves_the_gauge_what_its_twin_leaves(sn637, proto, draw, size, noise):
    """The gauge reads the stack's motion, not the displacement sensor's drift: with a mode found on the displacement
    and carried to it as the motion it makes (:func:`~workbench.calibrate.tracing._carried_motion`), its held-out
    error at the end is within 1.25x of what the same record without either effect leaves (the effect-free twin: the
    same drive and noise), and below its straight line's (issue 13's floor). The motion was carried only for a
    refitted mode; a mode found in the plain variant was carried as the mode on the gauge's own base prediction alone,
    which the folds' random terms refused on a large mode: seed 107 #154 at 1 MHz (a 229x 182 Hz mode beside a 437x
    drift) left the gauge at 0.148 V, above its line's 0.144 V (with the motion 0.0083 V, the twin 0.0072 V)."""
    from workbench.calibrate.base_fit import fit_base
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
    cc = load_benchmark("calibrate_confusion")
    t, v = benchmark_protocol(proto, 1e6, cc.ROWS[1e6])
    plant, truth = plant_with_effect(sn637, ("drift", "resonance"), draw, duration_s=float(t[-1]), size=size)
    clean, _ = plant_with_effect(sn637, "none", draw)
    r, r0 = simulate_record(plant, t, v, seed=noise), simulate_record(clean, t, v, seed=noise)
    sp = make_split(t, r["voltage_v"], "blocks")
    kw = dict(train=sp.train, test=sp.test, pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    R = sn637.pzt.series_resistance_ohm
    base = fit_base(cc._record(r, 1e-6), R, **kw)
    twin = fit_base(cc._record(r0, 1e-6), R, **kw).channels["gauge"].rms_test
    res = trace_effect(base, split=sp)
    modes = [s for s in res["stages"] if (s["effect"], s["channel"]) == ("resonance", "displacement")]
    assert modes and not modes[0]["parameters"].get("refit"), res["stages"]       # the case: a plain mode
    g = res["channels"]["gauge"]
    assert g["error_after"]["rms"] <= base.channels["gauge"].line_rms_test, (truth, g)
    assert g["error_after"]["rms"] <= 1.25 * twin, (truth, g["error_after"]["rms"], twin, g.get("carried"))
