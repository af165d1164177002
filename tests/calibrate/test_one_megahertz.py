"""Records at 1 MHz (issue 13 item 1, session 17): the drive's judgment, a mode under ten cycles, the line.

A 0.1 s record at 1 MHz (the confusion benchmark's ``--rates 1e6``) holds 2.7-7.3 cycles of the
benchmark's slowest modes and carries sensor effects (a drift of microns, a delay of half the record)
that dwarf the term ``R i`` the recorded V and the terminal V - R i differ by. Asserted, on the product
path (simulator -> base fit -> tracing):

* the drive is V - R i (the simulator drives the stack through R: the terminal voltage, a fact of the
  record) whatever the motion channels carry, and the charge, which carries no effect, then fits as on
  the effect-free record (before: 57 #154 chose the recorded V by 0.3 % of the displacement's misfit
  and the charge's base error was 53x the effect-free one's, a spurious R C absorption);
* a lightly damped mode of 2.5-9.5 cycles over the record is named and its frequency found (before: the
  search started at ten cycles, 57 #143 answered ``none``), and a creep record is not named a mode
  (the slow search's damping cap keeps creep's relaxation out);
* no channel's reported error at the end is above a straight line of the drive where the validation
  folds prefer the line (57 #154's gauge, 0.116 V against 0.105 V before).
"""

import dataclasses

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate.base_fit import fit_base
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
from workbench.calibrate.tracing import trace_effect
from workbench.plant.pzt import Mode

RATE_HZ = 1e6


def _bench():
    return load_benchmark("calibrate_confusion")


def _base(cc, plant, t, r, sp):
    return fit_base(cc._record(r, 1.0 / RATE_HZ), plant.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)


@pytest.fixture(scope="module")
def record_57_154(sn637):
    """The benchmark's seed 57 record #154: 1 MHz sine, a 52.5 Hz mode (5.3 cycles) beside a sensor drift."""
    cc = _bench()
    e, rate, proto, size, seed = cc.cases(seed=57, ends=True)[153]
    assert rate == RATE_HZ and tuple(e) == ("drift", "resonance") and proto == "sine"
    t, sp, base, plant, truth, r = cc.simulated_base(sn637, tuple(e), rate, proto, size, seed)
    clean, _ = plant_with_effect(sn637, "none", seed)
    base0 = _base(cc, clean, t, simulate_record(clean, t, benchmark_protocol(proto, rate, t.size)[1], seed=seed), sp)
    return sp, base, base0, truth


def test_the_drive_is_not_chosen_by_a_misfit_the_motion_channels_cannot_resolve(record_57_154):
    _, base, base0, _ = record_57_154
    assert base.voltage_source == "terminal voltage V - R i", base.notes
    assert any("cannot tell them apart" in n for n in base.notes)
    q, q0 = base.channels["charge"].rms_test, base0.channels["charge"].rms_test
    assert q < 1.5 * q0, (q, q0)


@pytest.mark.parametrize("draw", range(4))
def test_drawn_one_megahertz_sensor_effects_leave_the_charge_as_found(sn637, draw):
    """Drawn before any run (``default_rng([1701, draw])``): a displacement-sensor delay or a drift beside a
    mode, size log-uniform over the benchmark's 0.03-30x, sine or steps, 30,000 rows (30 ms; the calibration
    protocol needs 0.1 s at 1 MHz). Whichever reading the drive's judgment takes, the charge (no effect)
    fits as on the effect-free record within 1.5x: the judgment never hands it a spurious relaxation."""
    cc = _bench()
    rng = np.random.default_rng([1701, draw])
    effect = [("delay",), ("drift", "resonance")][int(rng.integers(2))]
    proto = ["sine", "steps"][int(rng.integers(2))]
    size = float(np.exp(rng.uniform(np.log(0.03), np.log(30.0))))
    seed = int(rng.integers(1 << 30))
    n_rows = 30_000
    t, sp, base, plant, truth, r = cc.simulated_base(sn637, effect, RATE_HZ, proto, size, seed, n_rows=n_rows)
    clean, _ = plant_with_effect(sn637, "none", seed)
    base0 = _base(cc, clean, t, simulate_record(clean, t, benchmark_protocol(proto, RATE_HZ, n_rows)[1], seed=seed),
                  sp)
    q, q0 = base.channels["charge"].rms_test, base0.channels["charge"].rms_test
    assert q < 1.5 * q0, (effect, proto, size, q, q0, base.voltage_source)


def test_no_channel_ends_above_the_line_the_folds_prefer(record_57_154):
    sp, base, _, truth = record_57_154
    res = trace_effect(base, split=sp)
    named = [s["effect"] for s in res["stages"]]
    assert named and set(named) <= {"drift", "resonance"}, named
    for ch, c in res["channels"].items():
        assert c["error_after"]["rms"] <= base.channels[ch].line_rms_test, (ch, c["error_after"],
                                                                            base.channels[ch].line_rms_test)
    g = res["channels"]["gauge"]
    assert base.channels["gauge"].rms_test > base.channels["gauge"].line_rms_test      # the case
    # (session 20, s20_modebasis) the 52.5 Hz mode lies below the 62 Hz drive: on the drive model refitted
    # per trial (``Resonance(basis=...)``) it is named at its frequency and the gauge ends well below the
    # line (0.0074 V against 0.105 V); the mode on the base's prediction was found at the drive's 63.1 Hz
    # (zeta at its 0.002 floor), and the gauge then ended on the straight line (its model no better on the folds)
    f, band = truth["freq_hz"], 2 * truth["damping_ratio"] * truth["freq_hz"]
    modes = [s["parameters"]["f_n_hz"] for s in res["stages"] if s["effect"] == "resonance"]
    assert modes and all(abs(fm - f) < 0.25 * band for fm in modes), (modes, truth)
    assert g["error_after"]["rms"] < 0.5 * base.channels["gauge"].line_rms_test, (g["error_after"],
                                                                                   base.channels["gauge"].line_rms_test)


def _mode_record(sn637, rng, n_rows, cycles, effect="none", proto=None):
    proto = proto or ["sine", "steps"][int(rng.integers(2))]
    t, v = benchmark_protocol(proto, RATE_HZ, n_rows)
    seed = int(rng.integers(1 << 30))
    plant, truth = plant_with_effect(sn637, effect, seed, duration_s=float(t[-1]), size=float(
        np.exp(rng.uniform(np.log(3.0), np.log(30.0)))))
    if cycles is not None:
        truth = {"freq_hz": cycles / float(t[-1] - t[0]), "damping_ratio": float(rng.uniform(0.005, 0.02))}
        plant = dataclasses.replace(plant, pzt=dataclasses.replace(
            plant.pzt, modes=(Mode(truth["freq_hz"], truth["damping_ratio"]),)))
    r = simulate_record(plant, t, v, seed=seed)
    sp = make_split(t, r["voltage_v"], "blocks")
    return proto, truth, sp, _base(_bench(), plant, t, r, sp)


# draws 0-5, sine on odd draws, steps on even ones (the first two were the branch's, the rest added by the
# lead after the review of s17_mhz found draw 4 failing); make test runs the first (session 27: two; session 22: three), WORKBENCH_FULL all.
# Draw 4 (steps, 2.84 cycles, 56.8 Hz, zeta 0.019) was a strict xfail from session 17 (answered ['drift', 'resonance',
# 'drift'], the mode fitted at 83.6 Hz); session 27's review of s27_welch found it passing on main (aff5e65: the
# strict xfail XPASSed under WORKBENCH_FULL=1 only, which ``make test`` does not run), so the mark is removed
# make test: draw 0 (steps: its frequency asserted); session 28 moved draw 1 (sine) to the full form for the suite's time
MODE_DRAWS = reduced_draws([pytest.param(d, "sine" if d % 2 else "steps") for d in range(6)], keep={0})


@pytest.mark.parametrize("draw, proto", MODE_DRAWS)
def test_a_mode_under_ten_cycles_a_record_is_named(sn637, draw, proto):
    """Drawn (``default_rng([1702, draw])``): 2.5-9.5 cycles over a 50 ms record (50-190 Hz), damping 0.5-2 %
    (the simulator's range), on sines and on steps. The mode is named and nothing else; on steps (each step rings the
    mode at its own frequency) its frequency is found within 10 %. A sine drive identifies the mode's response
    at the drive's frequency only: draw 1 (83.5 Hz, 4.2 cycles, under the 120 Hz sine) fits 118.6 Hz at the
    damping cap, the same response at 120 Hz, so no frequency is asserted there."""
    rng = np.random.default_rng([1702, draw])
    proto, truth, sp, base = _mode_record(sn637, rng, 50_000, float(rng.uniform(2.5, 9.5)), proto=proto)
    res = trace_effect(base, split=sp)
    modes = [s for s in res["stages"] if s["effect"] == "resonance"]
    assert [s["effect"] for s in res["stages"]] == ["resonance"], (proto, truth, res["fold_winners"])
    f = modes[0]["parameters"]["f_n_hz"]
    assert proto == "sine" or abs(f / truth["freq_hz"] - 1.0) < 0.1, (proto, truth, modes[0]["parameters"])


def test_a_creep_record_at_one_megahertz_is_not_named_a_slow_mode(sn637):
    """Drawn (``default_rng(1703)``): creep 3-30x on a 50 ms record; the slow search's damping cap keeps
    a relaxation from being taken for a mode under ten cycles."""
    rng = np.random.default_rng(1703)
    proto, truth, sp, base = _mode_record(sn637, rng, 50_000, None, effect="creep")
    res = trace_effect(base, split=sp)
    assert "resonance" not in [s["effect"] for s in res["stages"]], (proto, res["fold_winners"], res["stages"])


def _search_draws(n=8):
    """``n`` benchmark 1 MHz mode records (``default_rng(1)``): protocol, size 3-30x (log-uniform), plant seed."""
    rng = np.random.default_rng(1)
    return [(str(rng.choice(["calibration", "sine", "steps"])), float(np.exp(rng.uniform(np.log(3), np.log(30)))),
             int(rng.integers(1 << 30))) for _ in range(n)]


# draws 1 and 7 (calibration, 67.3 and 68.4 Hz) were a strict xfail in session 27: the search ended at the damping
# cap 0.159, leaving 35.8x and 27.7x of what the true mode leaves, its residual spectrum's 4096-sample segments having
# 244 Hz bins at 1 MHz. Session 28 (s28_welch2) adds a long segment's peaks below the frequency 4096 samples resolve to
# +-12 % (:meth:`Resonance._spectral_peaks`): they leave 0.76x and 0.83x of the true mode's (the mode at 67.1 Hz,
# zeta 0.0129 for 0.0091; 68.2 Hz, 0.0192 for 0.0149)
@pytest.mark.parametrize("proto, size, seed", reduced_draws(_search_draws(), keep={1}))
def test_the_mode_search_leaves_no_more_than_the_true_mode(sn637, proto, size, seed):
    """The plain mode search (:meth:`Resonance.fit` on the base's prediction, the training rows) minimizes the
    residual's least squares on one mode column over (f, zeta): the mode it returns leaves no more than the true
    mode of the record does. An optimizer's fact only: the objective, on the base's distorted prediction, need
    not have its minimum at the truth (the found mode may leave less with the wrong frequency or a damping at the
    floor: the review of s27_welch), so it says nothing of the mode's parameters."""
    from workbench.calibrate.effects import Resonance
    cc = _bench()
    t, sp, base, _, truth, _ = cc.simulated_base(sn637, ("resonance",), RATE_HZ, proto, size, seed)
    ch = base.channels["displacement"]
    u, e, mask = ch.yhat, ch.y - ch.yhat, np.asarray(sp.train, bool)
    eff = Resonance()
    p = eff.fit(t, u, e, mask)

    def left(f, z):
        c, r = eff._column(u, f, z, t[1] - t[0])[mask], e[mask]
        return float(np.sum((r - (c @ r) / (c @ c) * c) ** 2))
    assert left(p["f_n_hz"], p["zeta"]) <= (1 + 1e-9) * left(truth["freq_hz"], truth["damping_ratio"]), (p, truth)
