"""The creep branches driven by the voltage across C_h (:mod:`workbench.calibrate.creep_across`, session 17).

The simulator's branches sit across C_h and relax toward ``C_j V_h``, ``V_h = V_t - q / C_pp``: a driver the
creep itself pulls back. The calibration's creep spectrum was driven by the base model's displacement, which
follows neither the pull-back nor C_h's reversal under it, and left 12-15x the noise floor beside a 1 kHz delay.
"""

import numpy as np
import pytest

from tests.conftest import FULL, FULL_ONLY, load_benchmark, reduced_draws, stratified_draws
from workbench.calibrate.kernels import plays_rows
from workbench.calibrate.pi_fit import play_matrix


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_plays_on_rows_are_the_play_matrix_rows(seed):
    """The compiled plays at the search rows equal the full play matrix's rows bit for bit (same clamp)."""
    rng = np.random.default_rng(seed)
    v = np.cumsum(rng.standard_normal(4000)) * rng.uniform(0.1, 10)
    th = np.r_[0.0, np.sort(rng.uniform(0, 5, 9))]
    z0 = rng.uniform(-2, 2, th.size)
    rows = np.flatnonzero(rng.uniform(size=v.size) < rng.uniform(0.05, 0.9))
    np.testing.assert_array_equal(plays_rows(v, th, z0, rows), play_matrix(v, th, z0)[rows])


def _noise_free_creep(sn637, size, protocol="steps", rate=1e3):
    from workbench.calibrate.synthetic import SensorNoise, simulate_record
    cc = load_benchmark("calibrate_confusion")
    t, v = cc.benchmark_protocol(protocol, rate, cc.ROWS[rate])
    plant, _ = cc.plant_with_effect(sn637, "creep", 5, duration_s=float(t[-1]), size=size)
    r = simulate_record(plant, t, v, seed=5, noise=SensorNoise(0.0, 0.0, 0.0), gauge_noise=False)
    sp = cc.make_split(t, r["voltage_v"])
    base = cc.fit_base(cc._record(r, 1.0 / rate), sn637.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                       pzt=sn637.pzt, dac_range_v=sn637.gauge.dac_range_v)
    return t, r, sp, base


@pytest.mark.parametrize("protocol, rate, size", [("steps", 1e3, 0.3), ("steps", 1e3, 3.0), ("steps", 1e3, 20.0),
                                                  ("sine", 1e4, 3.0), ("sine", 1e4, 20.0)])
def test_the_drive_recovers_the_voltage_across_c_h(sn637, protocol, rate, size):
    """On a noise-free creep record, ``creep_drive``'s V_h solved on the displacement is the simulator's
    ``V_t - q / C_pp`` far closer than the creep-free estimate ``V_t - a x_model`` (the base model, which lacks
    the creep's charge) is: the fixed point recovers the branches' pull-back of their own driver (eqs. 9-12),
    from the model's prediction alone. Sizes from the drawn range's small end to its large one (the loop gain
    passes one near 20x). On the 10 kHz sine (session 18) the fixed point's second pass overshoots: it used to
    stop there and return the first pass's drive, the creep-free estimate itself (0.119 against 0.123 V at 3x;
    now 0.012 V); at 0.3x there the creep's pull-back is below the base model's own V_h error (both 0.016 V).
    (The tracing solves it on the gauge when there is one, :func:`creep_loops`: there it is 0.043-0.051 V off
    at these sizes, the gauge model's own error: see the leftover test below.)"""
    import dataclasses

    from workbench.calibrate.creep_across import creep_drive
    from workbench.calibrate.tracing import _search_rows, creep_loops
    t, r, sp, base = _noise_free_creep(sn637, size, protocol, rate)
    pz = sn637.pzt
    c_pp = pz.working_capacitance_f + pz.transducer_constant_n_per_v ** 2 / pz.stiffness_n_per_m
    vh_true = r["v_t_v"] - r["q_true_c"] / c_pp
    m = base.channels["displacement"]
    loop = dataclasses.replace(creep_loops(base)["displacement"], shared={})     # solved on the displacement
    a = loop.v_per_unit
    assert a == pytest.approx(pz.stiffness_n_per_m / pz.transducer_constant_n_per_v)
    taus = 10.0 ** np.arange(np.log10(sp.block_s), np.log10(100 * t[-1]) + 1e-9, 0.5)
    vh = creep_drive(loop, m.y, taus, float(t[1] - t[0]), _search_rows(sp.train & m.valid))
    vh_model = base.v_drive - a * (m.yhat - m.offset)
    err, err_model = (float(np.sqrt(np.mean((x - vh_true)[sp.test] ** 2))) for x in (vh, vh_model))
    print(f"\n{protocol} {rate / 1e3:g} kHz size {size}: V_h error {err:.4g} V, the creep-free estimate's "
          f"{err_model:.4g} V (V_h RMS {np.sqrt(np.mean(vh_true ** 2)):.3g} V)")
    assert err < 0.25 * err_model


def test_the_drive_backs_off_an_overshoot_to_a_better_pass(sn637, monkeypatch):
    """The back-off alone (the record's grid without the midpoints of :func:`drive_taus`): on the noise-free
    10 kHz sine at 3x the fixed point's second pass overshoots. Backing off with half the step *in the fit and
    in the gains alike* tends to the best pass as the step shrinks, so a later pass can improve on it: V_h ends
    0.062 V off (measured; 0.079 V with the review's prototype, which quartered the step). Blending the fit alone with the new gains in
    full tended to another SSE, never returned below the best, and kept the first pass, the creep-free
    ``V_t - a PI[V_t]`` (0.119 against 0.123 V: 0.97x the creep-free estimate's error)."""
    import dataclasses

    from workbench.calibrate import creep_across
    from workbench.calibrate.tracing import _search_rows, creep_loops
    monkeypatch.setattr(creep_across, "drive_taus", lambda taus: np.asarray(taus, float))
    t, r, sp, base = _noise_free_creep(sn637, 3.0, "sine", 1e4)
    pz = sn637.pzt
    c_pp = pz.working_capacitance_f + pz.transducer_constant_n_per_v ** 2 / pz.stiffness_n_per_m
    vh_true = r["v_t_v"] - r["q_true_c"] / c_pp
    m = base.channels["displacement"]
    loop = dataclasses.replace(creep_loops(base)["displacement"], shared={})
    taus = 10.0 ** np.arange(np.log10(sp.block_s), np.log10(100 * t[-1]) + 1e-9, 0.5)
    vh = creep_across.creep_drive(loop, m.y, taus, float(t[1] - t[0]), _search_rows(sp.train & m.valid))
    vh_model = base.v_drive - loop.v_per_unit * (m.yhat - m.offset)
    err, err_model = (float(np.sqrt(np.mean((x - vh_true)[sp.test] ** 2))) for x in (vh, vh_model))
    print(f"\ngrid only, 10 kHz sine 3x: V_h error {err:.4g} V, the creep-free estimate's {err_model:.4g} V")
    assert err < 0.8 * err_model


# creep-only 1 kHz records drawn with np.random.default_rng(1717), fixed before any was traced: protocol,
# size multiplier log-uniform and stratified (one draw in each of CREEP_1K equal log-bands of 0.03-30x)
CREEP_1K = 4 if not FULL else 12


def _draws():
    return stratified_draws(1717, CREEP_1K)


@pytest.fixture(scope="module")
def creep_1k(sn637):
    cc = load_benchmark("calibrate_confusion")
    rows = []
    for proto, size, seed in _draws():
        r = cc.evaluate(sn637, "creep", 1e3, proto, size, seed)
        r["left"] = r["ratio"] * np.sqrt(r["excess"] ** 2 + 1.0)      # what is left, in floors
        print(f"\ncreep 1 kHz {proto:11s} size x{size:.3g}: {r['excess']:.3g}x -> {r['named']} ratio "
              f"{r['ratio']:.3f}, left {r['left']:.2f}x the floor")
        rows.append(r)
    return rows


#: What the fitted creep may leave, in noise floors: under 3x (the issue's bar for an effect), what is left
#: could not itself be named, so an effect beside the creep that stands >= 3x on its own record is not hidden
#: in it. The physics' own bound is the floor (1x: a model of the simulator's form); the driven spectrum leaves
#: the hysteresis of the pull-back out (:mod:`workbench.calibrate.creep_across`), which grows with the creep.
LEFT_FLOORS = 3.0


def test_creep_at_1khz_is_named_over_the_size_range(creep_1k):
    """Every drawn creep record at or above the floor is named creep, and nothing else is named."""
    cc = load_benchmark("calibrate_confusion")
    sizes = sorted(r["size"] for r in creep_1k)
    edges = np.exp(np.linspace(np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1]), CREEP_1K + 1))
    assert np.all(np.histogram(sizes, edges)[0] == 1), sizes
    assert not [r for r in creep_1k if r["class"] == "wrong"]
    above = [r for r in creep_1k if r["excess"] >= 3.0]
    assert above and all(r["class"] == "right" for r in above)


@pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "the tracing solves V_h on the gauge when the record has one (a displacement sensor's delay is not the "
    "stack's: solved on the displacement, the 1 kHz creep + delay pairs of test_pairs and 61 #31 lost their delay); "
    "the gauge's model leaves V_h 0.043-0.051 V off on noise-free records (0.004-0.03 V on the displacement), and "
    "the drawn records keep 7.48x (steps, 0.58x), 4.09x (calibration, 5.25x) and 2.20x (sine, 7.24x) the floor, "
    "against 1.90x, 2.08x and 1.60x with V_h solved on the displacement (session 17, measured; session 18's drive, the "
    "overshoot backed off and the grid's midpoints: 7.48x, 2.98x, 2.20x)"))
def test_creep_at_1khz_leaves_under_three_floors(creep_1k):
    """What the fitted creep leaves on the test rows is under :data:`LEFT_FLOORS` floors at every drawn size
    (the model-driven spectrum left 0.21-0.42 of the creep at every size: 12-15x beside session 16's delays)."""
    named = [r for r in creep_1k if r["class"] == "right"]
    assert named
    assert all(r["left"] < LEFT_FLOORS for r in named), [(r["protocol"], round(r["size"], 3), round(r["left"], 2))
                                                         for r in named]


# creep-only sine records drawn with np.random.default_rng(1818), fixed before any was traced: one size in each
# of CREEP_SINE equal log-bands of the benchmark's 0.03-30x, the rate drawn among the benchmark's (1, 10, 100 kHz)
CREEP_SINE = 6


def _sine_draws():
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(1818)
    edges = np.linspace(np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1]), CREEP_SINE + 1)
    return [(float(rng.choice(cc.RATES_HZ)), float(np.exp(rng.uniform(lo, hi))), int(rng.integers(1 << 30)))
            for lo, hi in zip(edges[:-1], edges[1:])]


#: the record the fix was made on (seed 67 #46 of the confusion benchmark: a regression check, not evidence)
CREEP_SINE_67_46 = (1e4, 13.444140898726538, 8670178)
#: a second, found after that fix (seed 71 #46: a 27.6x creep on the 10 kHz sine), answered creep + a 3.3-sample
#: lead by the joint creep + delay candidate whose branches the base model drove, not the creep's V_h (session 18)
CREEP_SINE_71_46 = (1e4, 27.579080767041777, 11918613)


# 67 #46 runs under WORKBENCH_FULL=1 only (session 31, s31_suite): make test keeps 71 #46, the same family (creep
# alone, 10 kHz sine) and assertion (nothing but creep named), 2x larger and the later of the two fixes; 67 #46
# reaches no line or branch of workbench/ that the kept tests do not (session 31's per-test coverage)
@pytest.mark.parametrize("rate, size, seed", reduced_draws(_sine_draws(), keep=(5,))
                         + [pytest.param(*CREEP_SINE_67_46, id="seed67-46", marks=FULL_ONLY),
                            pytest.param(*CREEP_SINE_71_46, id="seed71-46")])
def test_a_creep_on_a_sine_record_is_not_answered_with_a_delay(sn637, rate, size, seed):
    """A creep-only record on the sine protocol, traced as ``workbench calibrate`` does: no delay (nor any other
    effect the record lacks) is named beside the creep. On a sine a sensor delay and a creep's lag are near-twins;
    with the branches' drive ``V_h`` left at the first fixed-point pass (no pull-back), a 13x creep at 10 kHz
    was answered creep + a 0.33 ms lead (67 #46, session 17); a 27.6x one (71 #46, the last case) was answered
    the same by the joint creep + delay candidate while its branches were driven by the base model instead of the
    creep's ``V_h`` (:func:`~workbench.calibrate.creep_beside_delay._branch_drive`). ``make test`` runs the
    largest band's draw (the misfit grows with the creep), 67 #46 and 71 #46, ``WORKBENCH_FULL=1`` every band. (Measured: main 709a969
    answers the six drawn records without a delay too; of 67's 10 kHz sine records only #46 failed, and six more
    drawn at 3-30x answered creep alone on main: the failure is the drive's overshoot on that record's noise,
    which the drive test above checks on noise-free records.)"""
    cc = load_benchmark("calibrate_confusion")
    from workbench.calibrate.tracing import trace_effect
    t, sp, base, _, _, _ = cc.simulated_base(sn637, "creep", rate, "sine", size, seed)
    res = trace_effect(base, split=sp)
    named = [s["effect"] for s in res["stages"]]
    print(f"\ncreep {rate / 1e3:g} kHz sine size x{size:.3g}: {named}")
    assert not set(named) - {"creep"}, (named, res.get("stage_notes"), res["fold_winners"])
