"""Issue 13 item 6: the updated plant, loaded back, with the record's drive simulated through it.

``updated_plant_error`` replays the record's terminal voltage through a plant file noise-free; its
test RMS is the record's noise plus what the file gets wrong. Facts asserted: through the plant that
made the record it leaves the sensor's noise; the gauge chain's own noise is switched off when asked;
a creep spectrum is written as fractions of the instant response; the warning fires beyond 10 % only.
The issue's round trip on drawn two-effect records (sizes 3-30x, log-uniform, ``default_rng`` fixed
before any run), the file written as ``workbench calibrate`` writes it (the refitted or the declared core,
``choose_core``), is a strict xfail where it is a miss, with the measured reason.
"""

import copy
import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate.plant_update import (ROUND_TRIP_TOLERANCE, _terminal_secant, choose_core, creep_branches,
                                              plant_file_gaps,
                                              round_trip_note, round_trip_warning, updated_plant_error,
                                              updated_plant_error_reason, updated_plant_text)
from workbench.calibrate.synthetic import SensorNoise, benchmark_protocol, simulate_record
from workbench.calibrate.tracing import trace_effect
from workbench.plant import load_plant

PLANTS = Path(__file__).resolve().parents[2] / "plants"
RNG = np.random.default_rng(1306)
#: (effect, rate Hz, protocol, size, seed): sizes 3-30x, protocols and rates drawn
DRAWS = [(eff, float(RNG.choice([1e3, 1e4])), str(RNG.choice(["calibration", "sine", "steps"])),
          float(np.exp(RNG.uniform(np.log(3.0), np.log(30.0)))), int(RNG.integers(1 << 30)))
         for eff in (("drift", "resonance"), ("creep", "delay")) for _ in range(2)]
#: one-effect records whose effect the simulator applies exactly (a sensor's delay and drift, the charge's
#: leakage): the plant that made the record must leave the sensor noise
EXACT = [(eff, float(np.exp(RNG.uniform(np.log(0.3), np.log(30.0)))), int(RNG.integers(1 << 30)))
         for eff in ("none", "delay", "drift", "leakage")]


@pytest.fixture(scope="module")
def sn637():
    return load_plant(PLANTS / "p888_51_sn637.toml")


@pytest.mark.parametrize("effect, size, seed", EXACT)
def test_the_plant_that_made_the_record_leaves_the_noise(sn637, effect, size, seed):
    """Replayed through its own plant, a 10 kHz record's displacement leaves the sensor's white noise
    (1 nm RMS, ``SensorNoise``) within 10 %: the replay (terminal drive, series resistor out, drive
    linear between samples) adds nothing of its own."""
    cc = load_benchmark("calibrate_confusion")
    t, sp, base, plant, _, r = cc.simulated_base(sn637, effect, 1e4, "calibration", size, seed)
    err = updated_plant_error(plant, base, "displacement", sp.test, train=sp.train)
    assert err["units"] == "m"
    assert err["rms"] == pytest.approx(SensorNoise().displacement_m, rel=0.10), (effect, err)


def test_gauge_noise_switch(sn637):
    """``gauge_noise=False``: the gauge column no longer depends on the noise seed; with the chain's
    noise on it does (a quiet ``SensorNoise`` used to leave it on: a round trip compared two draws)."""
    t, v = benchmark_protocol("sine", 1e4, 4000)
    quiet = SensorNoise(0.0, 0.0, 0.0)
    a, b = (simulate_record(sn637, t, v, seed=s, noise=quiet, gauge_noise=False)["gauge_v"] for s in (1, 2))
    assert np.array_equal(a, b)
    c, d = (simulate_record(sn637, t, v, seed=s, noise=quiet)["gauge_v"] for s in (1, 2))
    assert not np.array_equal(c, d)


def _creep_file(sn637, tmp_path, gains, taus, v):
    """The updated plant of a creep found on a displacement-only record (no charge channel)."""
    st = {"effect": "creep", "channel": "displacement", "parameters": {"gains": gains, "taus_s": taus},
          "error_before": {"rms": 1.0, "max": 1.0, "units": "m"}, "error_after": {"rms": 0.5, "max": 0.5, "units": "m"}}
    res = dict(st, stages=[st])
    text = updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, SimpleNamespace(channels={}, v_drive=v), res,
                              Path("rec.csv"))
    (tmp_path / "p.toml").write_text(text)
    return text, load_plant(tmp_path / "p.toml")


@pytest.mark.parametrize("gains, taus, v0", [([0.05], [0.02], 100.0), ([0.1, 0.15], [0.01, 0.1], 60.0),
                                             ([0.3], [0.05], 120.0)])
def test_written_creep_steps_to_the_fitted_ratio_and_time_constant(sn637, tmp_path, gains, taus, v0):
    """The spectrum ``u (1 - sum c) + sum c_j lowpass_j(u)`` settles at ``1 / (1 - sum c)`` of its instant
    response, and a single branch is 1 - 1/e of the way at its fitted ``tau``. The written file (no charge
    channel: C_h from the declared core), simulated on a step and hold, must do the same: settled over
    the declared core's own response within 3 % (measured 2026-11-26: -0.2 %, -1.8 %, -2.4 %: C_h not
    linear) and 1 - 1/e reached within 20 % of ``tau`` (measured +4 %, -14 %). The former write-out
    (c_j / (1 - sum c) x the terminal secant) was 4-7x off in the creep share."""
    rate = 1e4
    t = np.arange(int((12 * max(taus) + 0.01) * rate)) / rate
    v = np.where(t >= 0.005, v0, 0.0)
    text, again = _creep_file(sn637, tmp_path, gains, taus, v)
    assert "[creep]" in text

    def x(pl):
        q = dataclasses.replace(pl, pzt=pl.pzt.terminal_driven())       # V_t in, as the replay drives it
        return simulate_record(q, t, v, noise=SensorNoise(0.0, 0.0, 0.0), gauge=False)["displacement_m"]
    core, crept = x(sn637), x(again)
    assert crept[-1] / core[-1] == pytest.approx(1.0 / (1.0 - sum(gains)), rel=0.03)
    if len(gains) == 1:
        k = np.searchsorted(t, 0.005 + taus[0])
        frac = (crept[k] - core[k]) / (crept[-1] - core[-1])
        assert -taus[0] / np.log(1.0 - frac) == pytest.approx(taus[0], rel=0.20)


def test_written_creep_settles_branch_by_branch(sn637, tmp_path):
    """Time constants far apart (2 ms, 0.5 s; c = 0.1, 0.2): 25 ms after the step the fast branch has
    settled and the slow one moved 5 %: the spectrum reads 1 + (0.1 + 0.2 (1 - exp(-0.05))) / 0.7 = 1.157 of
    the instant response, 1 / 0.7 settled. The branches are sized in order of time constant (the map from
    ratio to capacitance is not linear near the ceiling); measured 2026-11-26: 1.143 (-1.2 %), 1.396 (-2.3 %).
    Shared in proportion to c_j the fast branch would take a third of the total, ~1.30 at 25 ms."""
    rate = 1e4
    t = np.arange(int(6.0 * rate)) / rate
    v = np.where(t >= 0.005, 100.0, 0.0)
    _, again = _creep_file(sn637, tmp_path, [0.1, 0.2], [0.002, 0.5], v)

    def x(pl):
        q = dataclasses.replace(pl, pzt=pl.pzt.terminal_driven())       # V_t in, as the replay drives it
        return simulate_record(q, t, v, noise=SensorNoise(0.0, 0.0, 0.0), gauge=False)["displacement_m"]
    core, crept = x(sn637), x(again)
    k = np.searchsorted(t, 0.030)
    assert crept[k] / core[k] == pytest.approx(1.0 + (0.1 + 0.2 * (1.0 - np.exp(-0.05))) / 0.7, rel=0.03)
    assert crept[-1] / core[-1] == pytest.approx(1.0 / 0.7, rel=0.03)


def test_creep_above_the_ceiling_is_not_written(sn637, tmp_path):
    """Branches across C_h cannot take the settled response beyond ``1 + C_pp / C_h`` of the instant one
    (C_S -> infinity); a spectrum above it (and one with ``sum c >= 1``) gets no ``[creep]``, the header says why."""
    v = np.linspace(0.0, 100.0, 200)
    c_s, c_pp, _, _ = _terminal_secant(SimpleNamespace(v_drive=v), sn637)
    ceil = 1.0 + c_pp / (1.0 / (1.0 / c_s - 1.0 / c_pp))
    for total in (1.0 - 1.0 / (ceil * 1.05), 1.2):
        text, again = _creep_file(sn637, tmp_path, [total], [0.1], v)
        assert "\n[creep]\n" not in text and "creep found on the displacement is not written" in text
        assert again.pzt.creep is None
    ok = creep_branches([1.0 - 1.0 / (ceil * 0.95)], [0.1], c_s, c_pp)
    assert ok["capacitances_f"] is not None


@pytest.mark.parametrize("ratio, warned, noted", [(1.0, False, False), (1.0 + 0.99 * ROUND_TRIP_TOLERANCE, False, False),
                                                  (1.0 - 0.99 * ROUND_TRIP_TOLERANCE, False, False),
                                                  (1.0 + 1.01 * ROUND_TRIP_TOLERANCE, True, False), (0.4, False, True),
                                                  (6.0, True, False)])
def test_round_trip_warning_beyond_the_tolerance(ratio, warned, noted):
    """Above 1 + 10 %: a warning; below 1 - 10 % the file does better than the fitted model: a note, not a
    warning; within: neither."""
    ea = {"rms": 2.0e-9, "max": 9e-9, "units": "m"}
    pe = {"rms": ratio * 2.0e-9, "max": 9e-9, "units": "m"}
    w = round_trip_warning(ea, pe, [{"effect": "delay", "channel": "displacement"}])
    n = round_trip_note(ea, pe)
    assert (w is not None, n is not None) == (warned, noted)
    if warned:
        assert f"{ratio * 2.0e-9:.4g} m" in w and "2e-09 m" in w and ("declared core" in w)
    if noted:
        assert f"{ratio * 2.0e-9:.4g} m" in n and "better" in n


def test_the_warning_names_only_the_causes_that_apply(sn637):
    """A delay on the displacement has a plant-file form, a unit-gain mode too: only the declared core is
    named. A resonance of gain 0.8, a drift's periodic term, a gauge's delay and a creep beyond the ceiling
    are each named when found, and not otherwise."""
    v = np.linspace(0.0, 100.0, 200)
    base = SimpleNamespace(channels={}, v_drive=v)
    ea, pe = {"rms": 1e-9, "max": 3e-9, "units": "m"}, {"rms": 3e-9, "max": 9e-9, "units": "m"}
    plain = [{"effect": "delay", "channel": "displacement", "parameters": {"delay_s": 1e-4}},
             {"effect": "resonance", "channel": "gauge", "parameters": {"f_n_hz": 200.0, "zeta": 0.02, "gain": 1.0}}]
    gaps = plant_file_gaps(plain, base, sn637)
    assert gaps == []
    w = round_trip_warning(ea, pe, plain, gaps=gaps)
    assert "declared core" in w and "gain 1" not in w and "periodic" not in w and "creep" not in w
    each = {"gain 0.8": {"effect": "resonance", "channel": "displacement",
                         "parameters": {"f_n_hz": 200.0, "zeta": 0.02, "gain": 0.8}},
            "periodic term": {"effect": "drift", "channel": "displacement",
                              "parameters": {"coefficients": [0, 1e-9], "t0_s": 0.0, "t_end_s": 1.0, "period_s": 0.5}},
            "delay on the gauge": {"effect": "delay", "channel": "gauge", "parameters": {"delay_s": 1e-4}},
            "creep was not written": {"effect": "creep", "channel": "displacement",
                                      "parameters": {"gains": [0.9], "taus_s": [0.1]}}}
    for phrase, st in each.items():
        gaps = plant_file_gaps([st], base, sn637)
        w = round_trip_warning(ea, pe, [st], gaps=gaps)
        assert phrase in w and all(other not in w for other in each if other != phrase), (phrase, w)


def test_updated_plant_error_reason():
    """A null ``updated_plant_error`` says why: a generic stack, no effect, an amplifier command."""
    res = {"stages": [{"effect": "delay", "channel": "displacement"}]}
    term = SimpleNamespace(input_kind="terminal", channels={"displacement": None})
    assert updated_plant_error_reason("pzt", res, term, "displacement") is None
    assert "generic stack" in updated_plant_error_reason("generic_stack", res, term, "displacement")
    assert "no effect" in updated_plant_error_reason("pzt", {"stages": []}, term, None)
    cmd = SimpleNamespace(input_kind="command", channels={"displacement": None})
    assert "amplifier command" in updated_plant_error_reason("pzt", res, cmd, "displacement")


_TRACED, _ROUND_TRIPS = {}, {}


def _traced(sn637, effect, rate, proto, size, seed):
    """``(t, sp, base, plant, truth, r, res)``: the confusion benchmark's record of a draw and its tracing. Several
    tests take the same draw (the creep+delay draws four tests, seed 24 #55 two): it is simulated and traced once
    in this module, and each caller gets its own deep copy (what one test changes, no other sees)."""
    key = (effect, rate, proto, size, seed)
    if key not in _TRACED:
        cc = load_benchmark("calibrate_confusion")
        t, sp, base, plant, truth, r = cc.simulated_base(sn637, effect, rate, proto, size, seed)
        _TRACED[key] = (t, sp, base, plant, truth, r, trace_effect(base, split=sp))
    return copy.deepcopy(_TRACED[key])


def _round_trip(sn637, effect, rate, proto, size, seed, tmp_path):
    """The tracing's updated plant file written to ``tmp_path / "p.toml"`` and the record replayed through it:
    ``(res, err, base, sp)``, computed once per draw in this module (the two creep+delay round-trip tests take the
    same draws), a deep copy to each caller and the file written to each caller's ``tmp_path``."""
    key = (effect, rate, proto, size, seed)
    if key not in _ROUND_TRIPS:
        t, sp, base, plant, truth, r, res = _traced(sn637, effect, rate, proto, size, seed)
        # the core as ``workbench calibrate`` writes it: refitted or declared, by the development rows' replay
        core, _, _ = choose_core(PLANTS / "p888_51_sn637.toml", sn637, base, res, Path("rec.csv"), sp.train)
        text = updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, base, res, Path("rec.csv"), core=core)
        (tmp_path / "p.toml").write_text(text)
        again = load_plant(tmp_path / "p.toml")
        ch = res["channel"] or "displacement"
        err = updated_plant_error(again, base, ch, sp.test, train=sp.train)
        true = updated_plant_error(plant, base, ch, sp.test, train=sp.train)
        _ROUND_TRIPS[key] = (res, err, base, sp, text, true)
    res, err, base, sp, text, true = copy.deepcopy(_ROUND_TRIPS[key])
    (tmp_path / "p.toml").write_text(text)
    print(f"\n{effect} {rate:g} Hz {proto} {size:.3g}x: stages {[(s['effect'], s['channel']) for s in res['stages']]}; "
          f"error_after {res['error_after']['rms']:.4g}, updated plant {err['rms']:.4g}, true plant {true['rms']:.4g}")
    return res, err, base, sp


CREEP_MISS = ("measured 2026-11-26 (s14_rtcreep): a creep+delay record at 1 kHz sine (18.6x, drawn delay 5.8 ms) is "
              "answered creep alone; the file's C_h and Kelvin-Voigt branches are fitted together to the record "
              "(core_refit.direct_core_and_branches) and replay it to 1.37e-8 m (4.78e-9 m with the fitted model's offset, "
              "s14_rtfix: 0.17x), HALF error_after or less (2.78e-8 m: the fitted "
              "model, the spectrum's lowpass of the base's output, is the poorer form; the plant that made the record "
              "1.6e-9 m): outside 10 % below. Session 13's file (the fitted model's instant core, branches refitted to "
              "the spectrum's creep) left 8.7e-8 m, 3.1x. Since s17_creep (creep driven by V_h) error_after is 5.05e-9 m "
              "and the file 7.53e-9 m: ABOVE by 49 % (CREEP_ABOVE), still outside 10 %.")
JOINT_MISS = ("measured 2026-11-26 (main after s14_creepdelay, s14_rtcreep, s14_rtfix): the creep+delay record at 1 kHz "
              "calibration (28x) is answered creep then delay (the joint creep + delay model); error_after 5.29e-8 m, "
              "the file (C_h and Kelvin-Voigt branches fitted together to the record, the fitted model's offset, the "
              "delay re-searched) 8.70e-9 m: 0.16x, BELOW by 84 %, outside 10 % (the plant that made the record "
              "1.46e-9 m): the plant's own form fits the record better than the fitted spectrum; not met. Session 17: the "
              "same 8.709e-9 m after the review of s17_creep's fix (the joint's refitted branches keep no V_h driver: "
              "before it the merged branch wrote 3.53e-8 m, 0.67x, and no test told). Session 18 (s18_creepdelay2: the "
              "joint's branches driven by the found creep's V_h, its driver kept in the file): error_after 1.255e-8 m, "
              "the file 1.864e-9 m (the plant that made the record 1.462e-9 m): 0.149x, both 4-5x better, still BELOW "
              "by 85 %")
# CREEP_MISS's record since the review of s17_creep: the file 5.366e-9 m against error_after 5.052e-9 m (1.06x), met
DRIVE_MISS = ("measured 2026-11-26 (s18_creepdelay): since creep_drive solves V_h on the grid with its midpoints and "
              "backs off an overshooting pass, the 1 kHz sine creep+delay record's fitted model leaves error_after "
              "4.857e-9 m (main 5.052e-9 m, 4 % better) while the written file replays 5.403e-9 m (main 5.366e-9 m): "
              "1.112x, above by 11 % (main 1.06x); the file's form does not follow the better fitted model (the plant "
              "that made the record 1.565e-9 m). Diagnosed by the review of s18_creepdelay: V_h is solved on the grid "
              "with its midpoints (17 branches) while the fitted model and the file carry the record's 9; with the grid "
              "alone 5.052e-9 / 5.366e-9 m (1.06x, met), with midpoints below the record's length only 1.19x. The same "
              "figures after the back-off fix (1595499)")
_MISSES = {(("creep", "delay"), 1e3, "calibration"): JOINT_MISS, (("creep", "delay"), 1e3, "sine"): DRIVE_MISS}


@pytest.mark.parametrize("effect, rate, proto, size, seed", reduced_draws([
    pytest.param(*d, marks=pytest.mark.xfail(strict=True, reason=_MISSES[d[:3]])) if d[:3] in _MISSES
    else d for d in DRAWS], keep={0, 2}))
def test_two_effect_round_trip_reproduces_error_after(sn637, tmp_path, effect, rate, proto, size, seed):
    """Issue 13 item 6 on drawn two-effect records (3-30x): the record's drive simulated through the
    updated plant leaves the fitted model's ``error_after`` within 10 %."""
    res, err, _, _ = _round_trip(sn637, effect, rate, proto, size, seed, tmp_path)
    assert res["stages"], res["reason"]
    ea = res["error_after"]["rms"]
    assert abs(err["rms"] - ea) <= ROUND_TRIP_TOLERANCE * ea


CREEP_ABOVE = ("measured 2026-11-26 (s17_creep): since the creep branches are driven by V_h (creep_across) the "
               "1 kHz sine creep+delay record's fitted model leaves error_after 5.05e-9 m (2.78e-8 m with the "
               "base-model-driven spectrum) and the written file replays 7.53e-9 m (main's file 4.78e-9 m; 7.86e-9 m "
               "with the file's fitted-model rebuild on the base model instead of V_h): 1.49x, above by 49 %. The review "
               "of s17_creep found most of it: the instant core took the branches' held part as c u0, a V_h-driven "
               "branch holds c s V_h; with the plays' fit of the drive (core_refit.refitted_core) the file is 5.94e-9 m, "
               "1.18x; with the offset column in that fit (review of the lead's fix) 5.366e-9 m, 1.06x: met, the xfail went "
               "(lead, 2026-11-26)")


# make test runs the 1 kHz calibration draw; the 1 kHz sine draw's strict xfail (a known miss, ~3.5 s) runs under
# WORKBENCH_FULL=1 only (session 31, s31_suite)
@pytest.mark.parametrize("effect, rate, proto, size, seed", reduced_draws([
    pytest.param(*d, marks=pytest.mark.xfail(strict=True, raises=AssertionError, reason=DRIVE_MISS))
    if d[:3] == (("creep", "delay"), 1e3, "sine") else d for d in DRAWS if d[0] == ("creep", "delay")], keep={0}))
def test_two_effect_round_trip_is_not_above_error_after(sn637, tmp_path, effect, rate, proto, size, seed):
    """The one-sided half of the round trip on the creep+delay draws (the two-sided test above is a strict
    xfail on both, the file replaying BELOW error_after): the updated plant leaves at most 10 % more than
    the fitted model's ``error_after``."""
    res, err, base, sp = _round_trip(sn637, effect, rate, proto, size, seed, tmp_path)
    assert res["stages"], res["reason"]
    # the plant file's rebuild of the tracing's fitted model (what choose_core and the joint core fit start from)
    # is that model: on the test rows within 25 % of its error_after (the delay's re-search and the offset
    # apart). The review of s17_creep: a joint-refitted creep rebuilt on V_h stood at 5x (2.64e-7 m against
    # 5.29e-8 m, the error_after of then) while the file still passed the line below
    from workbench.calibrate.plant_update import _fitted_motion
    x, _, _ = _fitted_motion(base, res["core_fit"], sp.train, terms=None)
    ch = res["channel"] or "displacement"
    e = (base.channels[ch].y - x)[sp.test & base.channels[ch].valid]
    assert np.sqrt(np.mean(e * e)) <= 1.25 * res["error_after"]["rms"]
    assert err["rms"] <= (1.0 + ROUND_TRIP_TOLERANCE) * res["error_after"]["rms"]


@pytest.mark.parametrize("channel", ["displacement", "gauge"])
def test_a_mode_named_on_either_sensor_is_the_stacks_mode_in_the_file(sn637, tmp_path, channel):
    """A resonance named on the gauge (where a drifting displacement sensor hid it: fixlater's rule)
    is the stack's mechanical mode, the gauge reading the stack's strain: the file carries it as a
    ``[[mechanics.modes]]`` entry, loaded back with its frequency and damping, and says nothing of
    'no plant-file form' (before: no mode was written for it)."""
    from types import SimpleNamespace
    err = {"rms": 1e-8, "max": 3e-8, "units": "m" if channel == "displacement" else "V"}
    st = {"effect": "resonance", "channel": channel, "parameters": {"f_n_hz": 195.6, "zeta": 0.0142},
          "error_before": err, "error_after": err}
    result = {"effect": "resonance", "channel": channel, "parameters": st["parameters"], "error_before": err,
              "error_after": err, "stages": [st]}
    text = updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, SimpleNamespace(channels={}), result,
                              Path("rec.csv"))
    assert "no plant-file form" not in text and text.count("[[mechanics.modes]]") >= 1
    (tmp_path / "p.toml").write_text(text)
    modes = load_plant(tmp_path / "p.toml").pzt.modes
    before = load_plant(PLANTS / "p888_51_sn637.toml").pzt.modes
    assert len(modes) == len(before) + 1
    assert any(m.freq_hz == pytest.approx(195.6) and m.damping_ratio == pytest.approx(0.0142) for m in modes)


def _replay_base(plant, t, v, channel, y):
    return SimpleNamespace(t=t, v_drive=v, input_kind="terminal",
                           channels={channel: SimpleNamespace(y=y, valid=np.ones(t.size, bool),
                                                              units={"charge": "C"}.get(channel, "m"))})


@pytest.mark.parametrize("current", ["averaged", "sampled"])
def test_charge_replay_is_the_simulated_charge_whatever_the_records_convention(sn637, current):
    """The simulator logs a per-sample mean current; the replay's charge is the simulated charge itself, so
    a noise-free record of the plant's own charge replayed through that plant leaves nothing (to rounding)
    under either convention of the record. Integrating the simulated current as "sampled" (the record's
    convention) lagged it half a sample: on a 3 Hz, 40 V sine at 1 kHz that left 5e-3 of the charge's span at most."""
    import dataclasses as dc
    from workbench.calibrate.plant_update import replay_upsample
    t = np.arange(4000) / 1e3
    v = 50.0 + 40.0 * np.sin(2 * np.pi * 3.0 * t)
    quasi = dc.replace(sn637, pzt=sn637.pzt.terminal_driven())          # the replay's own model
    q = simulate_record(quasi, t, v, noise=SensorNoise(0.0, 0.0, 0.0), gauge=False,
                        upsample=replay_upsample(quasi, 1e3))["q_true_c"]
    base = _replay_base(sn637, t, v, "charge", q + 3e-6)       # an integrated charge has no absolute zero
    train = t < 2.0
    err = updated_plant_error(sn637, base, "charge", ~train, train=train, current=current)
    assert err["units"] == "C" and err["max"] <= 1e-9 * np.ptp(q)


def test_replay_memory_is_the_records_not_the_upsampled_commands(sn637):
    """The replay upsamples the drive 8x at 10 kHz (the 70 kHz mode): its peak memory (tracemalloc) per
    record sample stays below 16 float columns (measured 2026-11-26: 96 B a sample at 2^19 samples) and falls
    with the length (the fine command is simulated in chunks; was 272 B a sample at every length: 8 x 3 fine
    columns), so a 35.5 s record at 1 MHz no longer needs ~10 GB."""
    import tracemalloc
    per = []
    for n in (1 << 15, 1 << 19):
        t = np.arange(n) / 1e4
        v = 50.0 + 40.0 * np.sin(2 * np.pi * 3.0 * t)
        base = _replay_base(sn637, t, v, "displacement", np.zeros(n))
        tracemalloc.start()
        try:
            updated_plant_error(sn637, base, "displacement", np.ones(n, bool))
            per.append(tracemalloc.get_traced_memory()[1] / n)
        finally:
            tracemalloc.stop()
    assert per[1] < 16 * 8 and per[1] < 0.6 * per[0], per


def test_replay_upsample_follows_the_record_and_the_highest_mode(sn637):
    """A fine step of at most 12.5 us (the held command's half-step lag) and 8 a period of the 70 kHz mode:
    8 points a sample at 1-10 kHz, 6 at 100 kHz, none at 1 MHz; a plant whose only mode is at 200 Hz still
    gets 8 at 1-10 kHz (the lag), none at 100 kHz and above."""
    import dataclasses as dc
    from workbench.calibrate.plant_update import replay_upsample
    from workbench.plant.pzt import Mode
    assert [replay_upsample(sn637, r) for r in (1e3, 1e4, 1e5, 1e6)] == [8, 8, 6, 1]
    low = dc.replace(sn637, pzt=dc.replace(sn637.pzt, modes=(Mode(200.0, 0.01),)))
    assert [replay_upsample(low, r) for r in (1e3, 1e4, 1e5, 1e6)] == [8, 8, 1, 1]


def test_chunked_replay_is_the_whole_one(sn637, monkeypatch):
    """The simulator keeps its state between calls: the upsampled record simulated in chunks of an odd
    length (777 samples) is bit for bit the one simulated whole."""
    import workbench.calibrate.synthetic as syn
    t = np.arange(5000) / 1e4
    v = 50.0 + 40.0 * np.sin(2 * np.pi * 3.0 * t)
    whole = simulate_record(sn637, t, v, upsample=8)
    monkeypatch.setattr(syn, "REPLAY_CHUNK", 777)
    parts = simulate_record(sn637, t, v, upsample=8)
    assert all(np.array_equal(whole[k], parts[k]) for k in whole)


def test_no_creep_is_written_from_an_amplifier_command(sn637):
    """An amplifier-command record's drive is in command volts: the declared core's C_h read over it
    would size the branches from the wrong voltage, so the creep is a gap, not a [creep] section
    (review of the session: it was written whenever sum c stayed under the ceiling)."""
    v = np.linspace(0.0, 3.6, 2001)                              # a 0-3.6 V command
    st = {"effect": "creep", "channel": "displacement", "parameters": {"gains": [0.02, 0.01], "taus_s": [0.1, 1.0]}}
    terminal = plant_file_gaps([st], SimpleNamespace(v_drive=v * 30.0, input_kind="terminal"), sn637)
    command = plant_file_gaps([st], SimpleNamespace(v_drive=v, input_kind="command"), sn637)
    assert not any("creep" in g for g in terminal)
    assert any("creep was not written" in g and "amplifier command" in g for g in command)


def _pair_draws():
    """Leakage + absorption records the joint names with both: the confusion benchmark's seed 24 #10
    (1 kHz calibration, 7.7x) and one drawn at 1 kHz, 3-30x, protocol drawn (``default_rng(1332)``)."""
    rng = np.random.default_rng(1332)
    pair = ("leakage", "dielectric_absorption")
    return [(pair, 1e3, "calibration", 7.690262443434084, 33231382),
            (pair, 1e3, str(rng.choice(["calibration", "sine", "steps"])),
             float(np.exp(rng.uniform(np.log(3.0), np.log(30.0)))), int(rng.integers(1 << 30)))]


@pytest.mark.parametrize("effect, rate, proto, size, seed", _pair_draws())
def test_a_leakage_named_beside_the_absorption_round_trips(sn637, tmp_path, effect, rate, proto, size, seed):
    """The leakage scored jointly in the found absorption's place (``replaces``): the plant file's
    fitted model (``core_fit``) takes the refitted absorption and the leak from the last joint fit, and
    the record's drive simulated through the file leaves ``error_after`` within 10 %, both sections
    written (the absorption at its refitted tau)."""
    res, err, _, _ = _round_trip(sn637, effect, rate, proto, size, seed, tmp_path)
    named = [s["effect"] for s in res["stages"]]
    again = load_plant(tmp_path / "p.toml").additions
    da = next(s for s in res["stages"] if s["effect"] == "dielectric_absorption")
    print(f"named {named}; file k {again.absorption_gain_f:.4g} F tau {again.absorption_time_constant_s:.4g} s "
          f"R {again.leakage_resistance_ohm}")
    if "leakage" in named:
        assert again.leakage_resistance_ohm and "refitted" in da
        assert again.absorption_time_constant_s == pytest.approx(da["parameters"]["tau_s"], rel=1e-9)
    ea = res["error_after"]["rms"]
    assert abs(err["rms"] - ea) <= ROUND_TRIP_TOLERANCE * ea


def test_choose_core_takes_no_part_of_the_test_rows(sn637):
    """The core's choice, its branches and the development rows' replay errors are the same when the record's
    test rows are changed (noise and a step of 100x the sensor's noise there, a drawn creep+delay record):
    ``choose_core`` scores on the development rows alone; only its test error moves."""
    import copy
    d = next(d for d in DRAWS if d[0] == ("creep", "delay") and d[1:3] != (1e3, "sine"))
    t, sp, base, plant, truth, r, res = _traced(sn637, *d)
    ch = res["channel"] or "displacement"
    out = []
    for pert in (0.0, 1e-7):
        b = copy.deepcopy(base)
        m = b.channels[ch]
        rng = np.random.default_rng(0)
        m.y[sp.test] = m.y[sp.test] + pert * (1.0 + rng.standard_normal(int(sp.test.sum())))
        core, dev, err = choose_core(PLANTS / "p888_51_sn637.toml", sn637, b, res, Path("rec.csv"), sp.train,
                                     test=sp.test)
        out.append((core, dev, err))
    (a, da, ea), (c, dc, ec) = out
    # the path under test: C_h and the branches fitted together (the one that reads the record's rows)
    assert a.get("joint") is True and c.get("joint") is True, (a["reason"], a["how"])
    assert a["offset_m"] == c["offset_m"] and a["sensor_delay_s"] == c["sensor_delay_s"]
    assert (a["hysteresis"] is None) == (c["hysteresis"] is None) and da == dc
    if a["hysteresis"] is not None:
        np.testing.assert_array_equal(a["hysteresis"].weights, c["hysteresis"].weights)
        for x, y in zip(a.get("refined_branches", ())[:2], c.get("refined_branches", ())[:2]):
            np.testing.assert_array_equal(x, y)
    assert ea is not None and ec["rms"] > ea["rms"]


_RNG15 = np.random.default_rng(1501)
#: (effect, rate Hz, protocol, size, seed): creep + delay records drawn at 10 and 100 kHz, calibration or steps,
#: sizes 10-30x log-uniform (``default_rng(1501)``, drawn before any run; the first two on main, s14's final code:
#: 2.89x and 3.22x the tracing model)
BIG_CREEP_DELAY = [(("creep", "delay"), float(_RNG15.choice([1e4, 1e5])), str(_RNG15.choice(["calibration", "steps"])),
                    float(np.exp(_RNG15.uniform(np.log(10.0), np.log(30.0)))), int(_RNG15.integers(1 << 30)))
                   for _ in range(4)]
#: the 100 kHz steps draw (27x) was answered delay alone, its file at 1.71x the tracing model's test error (s15_rt:
#: a strict xfail); with creep_beside_delay's branches driven by the drive model refitted at the found delay
#: (session 22, s22_drive97) it is answered delay + creep (4 of 5), the file 1.848e-9 m against the model's
#: 4.288e-9 m (0.43x; the plant that made the record 1.019e-9 m)


@pytest.mark.parametrize("effect, rate, proto, size, seed", reduced_draws(BIG_CREEP_DELAY, keep={1, 3}))
def test_a_large_creep_beside_a_delay_is_not_written_worse_than_found(sn637, tmp_path, effect, rate, proto, size,
                                                                     seed):
    """Issue 13 item 6, one-sided, on large creep + delay draws: the updated plant (C_h and the branches fitted
    together through the delay, :func:`~workbench.calibrate.core_refit.direct_core_and_branches`) replays the
    record to at most 10 % above the tracing model's test error. The causes this draws over (session 15): the
    direct fit's Gram matrix summed over the rows made its ridge 3e-14 relative and its bounded solve diverge
    (3.22x); the stand-in off the fit's rows, the base alone with its creep-biased offset, where the tracing's
    delay gain came out 3.75 (2.89x); the delay's bracket search walking off to its far end; the fitted model's
    instant core with no C_h at any creep share (the first draw after s15_gram's R2: reversal slope 1268 F), where
    the declared core dropped the creep (37.9x) and the joint fit now runs from the base's thresholds."""
    res, err, _, _ = _round_trip(sn637, effect, rate, proto, size, seed, tmp_path)
    assert res["stages"], res["reason"]
    assert err["rms"] <= (1.0 + ROUND_TRIP_TOLERANCE) * res["error_after"]["rms"], err["rms"] / res["error_after"]["rms"]


def test_the_direct_fits_bounded_solve_meets_its_optimality_conditions():
    """The direct fit's bounded least squares (``core_refit._bounded_gram_solve``) on drawn problems of its
    shape (unit-RMS centred play and lowpass columns per row, plays that never move: zero columns; a lower bound
    on the first): the Karush-Kuhn-Tucker conditions hold (the gradient zero on the free weights, not negative
    on the bound ones), and the objective is not above the one at the bounds."""
    from scipy import signal

    from workbench.calibrate.core_refit import DIRECT_RIDGE, _bounded_gram_solve
    from workbench.calibrate.pi_fit import play_matrix
    rng0 = np.random.default_rng(1502)
    for _ in range(6):
        rng = np.random.default_rng(rng0.integers(1 << 30))
        n, dt = int(np.exp(rng.uniform(np.log(2e4), np.log(1e5)))), 1e-4
        v = np.cumsum(rng.normal(0.0, 1.0, n))
        v = 50.0 + 40.0 * v / np.abs(v).max()
        r = np.r_[0.0, np.sort(rng.uniform(0.0, 60.0, 12)), 200.0 + np.arange(int(rng.integers(1, 4)))]
        taus = 10.0 ** np.arange(np.log10(10 * dt), np.log10(10 * n * dt), 0.5)
        X = np.column_stack([play_matrix(v, r, np.zeros(r.size))]
                            + [signal.lfilter([-np.expm1(-dt / tau)], [1.0, -np.exp(-dt / tau)], v) for tau in taus])
        w = np.abs(rng.normal(0.0, 1.0, X.shape[1])) * (rng.uniform(size=X.shape[1]) < 0.5)
        q = 1e-7 * (X @ w + rng.normal(0.0, 0.01 * np.std(X @ w) + 1e-12, n))
        Xc, qc = X - X.mean(axis=0), q - q.mean()
        sc = np.sqrt(np.mean(Xc * Xc, axis=0))
        sc[sc == 0] = 1.0
        A = Xc / sc
        G, h = A.T @ A / n + DIRECT_RIDGE * np.eye(A.shape[1]), A.T @ qc / n
        lower = np.zeros(A.shape[1])
        lower[0] = rng.uniform(0.0, 1.0) * float(np.linalg.lstsq(G, h, rcond=None)[0][0] ** 2) ** 0.5
        x = _bounded_gram_solve(G, h, lower)
        g = G @ x - h
        size = float(np.linalg.norm(h))
        free = x > lower + 1e-9 * float(np.max(np.abs(x)))
        assert np.all(x >= lower - 1e-12 * float(np.max(np.abs(x))))
        assert np.max(np.abs(g[free]), initial=0.0) <= 1e-6 * size, (np.max(np.abs(g[free])), size)
        assert np.min(g[~free], initial=0.0) >= -1e-6 * size
        start = np.maximum(lower, 0.0)
        assert x @ G @ x - 2 * h @ x <= start @ G @ start - 2 * h @ start


def _calibrated(tmp_path, sn637, effect, size, seed, monkeypatch, replays=None):
    """``workbench calibrate``'s library call on a drawn record: (its JSON-ready result, the base fit it made, its
    split). ``replays``: a list that gets each replay's (plant, its path left out, pickled; channel)."""
    import pickle

    import workbench.calibrate.run as run
    from workbench.calibrate import plant_update
    from workbench.calibrate.protocol import calibration_protocol
    from workbench.calibrate.synthetic import plant_with_effect, write_record
    seen = {}
    fit_base, make_split = run.fit_base, run.make_split
    monkeypatch.setattr(run, "fit_base", lambda *a, **k: seen.setdefault("base", fit_base(*a, **k)))
    monkeypatch.setattr(run, "make_split", lambda *a, **k: seen.setdefault("split", make_split(*a, **k)))
    if replays is not None:
        replay = plant_update._replay

        def counted(plant, base, channel):
            replays.append((pickle.dumps(dataclasses.replace(plant, source=None)), channel))
            return replay(plant, base, channel)
        monkeypatch.setattr(plant_update, "_replay", counted)
    t, v = calibration_protocol(sine_cycles=3, stairs_v=(50.0, 20.0), chirp_s=1.0)
    plant, _ = plant_with_effect(sn637, effect, seed, duration_s=float(t[-1]), size=size)
    data = write_record(tmp_path / "rec.csv", simulate_record(plant, t, v, seed=seed), {"serial": "SN637"})
    res = run.run_calibrate(data, PLANTS / "p888_51_sn637.toml", out_dir=tmp_path / "out", figures=False)
    return res, seen["base"], seen["split"]


_RNG16 = np.random.default_rng(1503)
#: (effect, size, seed): two records with an effect the file carries, sizes 3-30x (``default_rng(1503)``)
REPORTED = [(str(_RNG16.choice(["creep", "delay", "drift", "leakage", "resonance", "dielectric_absorption"])),
             float(np.exp(_RNG16.uniform(np.log(3.0), np.log(30.0)))), int(_RNG16.integers(1 << 30))) for _ in range(2)]


@pytest.mark.parametrize("effect, size, seed", reduced_draws(REPORTED, keep={1}))
def test_the_reported_error_after_is_the_written_files_replay(sn637, tmp_path, monkeypatch, effect, size, seed):
    """Session 15 (the lead's decision): the ``error_after`` ``workbench calibrate`` reports is the error of what
    the user gets. The file it wrote, loaded back from disk and the record's drive simulated through it, leaves
    on the test rows the JSON's ``error_after`` to 1e-9 relative (the same replay: a figure from anywhere else,
    the tracing model's, fails this); ``error_after_source`` says so and the tracing model's own figure is
    ``error_after_model``. Every plant is replayed once a run (session 24: the file with every stage was replayed
    by ``choose_core``, again by ``carried_stages`` and, with a stage left out, the file written once more; the
    same plant gives the same noise-free replay)."""
    replays = []
    res, base, sp = _calibrated(tmp_path, sn637, effect, size, seed, monkeypatch, replays)
    repeated = len(replays) - len(set(replays))
    assert replays and repeated == 0, f"{repeated} of {len(replays)} replays repeat a plant ({[c for _, c in replays]})"
    assert res["stages"], res["reason"]
    assert res["error_after_source"] == "updated plant"
    again = load_plant(Path(res["updated_plant"]))
    err = updated_plant_error(again, base, res["channel"], sp.test, train=sp.train)
    assert err["rms"] == pytest.approx(res["error_after"]["rms"], rel=1e-9)
    assert err["max"] == pytest.approx(res["error_after"]["max"], rel=1e-9)
    on_channel = [st for st in res["stages"] if st["channel"] == res["channel"]]
    assert res["error_after_model"] == on_channel[-1]["error_after"]
    md = (tmp_path / "out" / "report.md").read_text()
    assert "**updated plant**" in md and "tracing model's own" in md
    # the base fit's per-channel error_after is the tracing model's, and says so (review of s15_rt)
    ch = res["base_fit"]["channels"][res["channel"]]
    assert ch["error_after_source"] == "tracing model"


_RNG17 = np.random.default_rng(1504)
#: (effect, rate Hz, protocol, size, seed): drift + resonance records at 10 kHz, protocol drawn, sizes 3-30x
#: log-uniform (``default_rng(1504)``, drawn before any run)
MODE_DRAWS = [(("drift", "resonance"), 1e4, str(_RNG17.choice(["calibration", "sine", "steps"])),
               float(np.exp(_RNG17.uniform(np.log(3.0), np.log(30.0)))), int(_RNG17.integers(1 << 30)))
              for _ in range(3)]
#: and the confusion benchmark's seed 24 #55 (10 kHz sine, 14.4x), where main's file (s14) left 1.99x: the three
#: draws above pass on main too (their tracing's gains 0.99, 0.98, 0.86; frequencies within the tolerance)
MODE_DRAWS.append((("drift", "resonance"), 1e4, "sine", 14.419072932627795, 90769602))


@pytest.mark.parametrize("effect, rate, proto, size, seed", reduced_draws(MODE_DRAWS, keep={1, 3}))
def test_the_written_mode_is_the_plants_mode(sn637, tmp_path, effect, rate, proto, size, seed):
    """The file's modes have unit gain and filter the quasi-static motion; the tracing's resonance has its gain
    free, and where it came out off 1 its frequency and damping compensate (seed 24 #55: gain 0.85, 45.06 Hz
    against the drawn 44.84 Hz, the file 1.9x the tracing model's error). The mode written (refitted by replay
    through the file on the development rows, ``plant_update._refit_mode``) is within a quarter of the drawn
    mode's half-power bandwidth ``2 zeta f`` of the drawn frequency, and the file replays the record to at most
    10 % above the tracing model's test error."""
    truth = _traced(sn637, effect, rate, proto, size, seed)[4]
    res, err, _, _ = _round_trip(sn637, effect, rate, proto, size, seed, tmp_path)
    assert res["stages"], res["reason"]
    assert err["rms"] <= (1.0 + ROUND_TRIP_TOLERANCE) * res["error_after"]["rms"], err["rms"] / res["error_after"]["rms"]
    if any(st["effect"] == "resonance" for st in res["stages"]):
        f = max(m.freq_hz for m in load_plant(tmp_path / "p.toml").pzt.modes if m.freq_hz < 1e4)
        f0, z0 = float(truth["freq_hz"]), float(truth["damping_ratio"])
        assert abs(f - f0) <= 0.25 * 2 * z0 * f0, (f, f0, z0)


@pytest.mark.parametrize("delay_ms, gain, best_ms", [(1.0, 3.0, 5.0), (-1.0, 3.0, -5.0), (1.0, 0.5, 0.3),
                                                     (-1.0, 0.5, -0.3), (-0.02, 15.3, -0.25), (2.0, 0.0, 1.5)])
def test_the_delay_re_search_brackets_either_sign(monkeypatch, delay_ms, gain, best_ms):
    """The re-search brackets [min(|d|, |g d|) / 2, max(|d|, |g d|) * 2] with d's sign: a cost whose minimum is
    inside that bracket (either sign) is found, and a zero end (gain 0) does not raise (review of s15_rt: d -1 ms, g 3 was bracketed [-2, -1.5] ms)."""
    import workbench.calibrate.core_refit as cr
    from workbench.calibrate import plant_update as pu
    tried = []

    def cost(plant, base, rows, delay_s=0.0, **k):
        tried.append(delay_s)
        return {"residual_m": (delay_s - best_ms * 1e-3) ** 2 + 1e-12}
    monkeypatch.setattr(cr, "direct_core_and_branches", cost)
    n = 1000
    m = SimpleNamespace(valid=np.ones(n, bool), y=np.random.default_rng(0).normal(size=n))
    base = SimpleNamespace(t=np.arange(n) * 1e-4, channels={"displacement": m})
    out = pu._delay_with_branches(None, base, np.ones(n, bool), delay_ms * 1e-3, None, gain=gain)
    mags = [abs(delay_ms), abs(gain * delay_ms)]
    mags = [x for x in mags if x > 0]
    lo, hi = min(mags) / pu.DELAY_SEARCH_FACTOR, max(mags) * pu.DELAY_SEARCH_FACTOR
    tried = np.asarray(tried)
    tried = tried[tried != 0.0]  # a zero end (g d = 0) is itself a trial
    assert np.all(np.sign(tried) == np.sign(delay_ms))
    assert min(np.abs(tried)) == pytest.approx(lo * 1e-3) and max(np.abs(tried)) == pytest.approx(hi * 1e-3)
    assert out == pytest.approx(best_ms * 1e-3, abs=2e-6)  # the golden section's xatol is 0.02 dt = 2 us


def test_the_delay_re_search_keeps_a_zero_delay(monkeypatch):
    """A delay stage of 0 s has no log bracket: the stage's delay is kept, no trial fit is run."""
    import workbench.calibrate.core_refit as cr
    from workbench.calibrate import plant_update as pu
    monkeypatch.setattr(cr, "direct_core_and_branches", lambda *a, **k: pytest.fail("no trial at a zero delay"))
    n = 100
    m = SimpleNamespace(valid=np.ones(n, bool), y=np.zeros(n))
    base = SimpleNamespace(t=np.arange(n) * 1e-4, channels={"displacement": m})
    assert pu._delay_with_branches(None, base, np.ones(n, bool), 0.0, None, gain=3.0) == 0.0


def test_a_resonance_gain_the_mode_refit_compensated_is_no_gap():
    """The file's mode refitted (``core["mode"]``, :func:`plant_update._refit_mode`) compensates the tracing's
    gain off 1: no gap; not refitted, the gain is a gap, and where the refit could not run the gap says why
    (review of s15_rt)."""
    from workbench.calibrate.plant_update import declared_core, plant_file_gaps
    stages = [{"effect": "resonance", "channel": "displacement",
               "parameters": {"f_n_hz": 45.06, "zeta": 0.0072, "gain": 0.85}}]
    core = declared_core("kept by the test")

    def gain_gaps(c):
        return [g for g in plant_file_gaps(stages, None, None, core=c) if "resonance's gain" in g]
    assert len(gain_gaps(core)) == 1
    assert gain_gaps({**core, "mode": (44.9, 0.0069, 45.06, 0.0072)}) == []
    assert "the mode refit did not run: no replay" in gain_gaps({**core, "mode_refit_skipped": "no replay"})[0]


def test_the_mode_is_refitted_with_the_declared_core_too(monkeypatch):
    """choose_core with no refitted core (the declared one kept at once) still refits the found mode through the
    file (it returned before the refit: review of s15_rt); where no file can be replayed it says the refit did
    not run."""
    from workbench.calibrate import plant_update as pu
    calls = []
    monkeypatch.setattr(pu, "core_for", lambda *a: pu.declared_core("no core fit"))
    monkeypatch.setattr(pu, "updated_plant_error_reason", lambda *a: None)

    def refit(plant_path, plant, base, result, data_path, core, rows, tmp):
        calls.append(tmp)
        return {**core, "mode": (44.9, 0.0069, 45.06, 0.0072)}
    monkeypatch.setattr(pu, "_refit_mode", refit)
    core, dev, err = pu.choose_core(None, None, None, {"channel": "displacement"}, None, None)
    assert len(calls) == 1 and core["mode"][0] == 44.9 and core["hysteresis"] is None and dev is None
    monkeypatch.setattr(pu, "updated_plant_error_reason", lambda *a: "no replay")
    core, _, _ = pu.choose_core(None, None, None, {"channel": "displacement"}, None, None)
    assert len(calls) == 1 and "mode" not in core and core["mode_refit_skipped"] == "no replay"


@pytest.mark.parametrize("draw, path", [(MODE_DRAWS[-1], "mode refit"),
                                        (next(d for d in DRAWS if d[0] == ("creep", "delay")
                                              and d[1:3] != (1e3, "sine")), "stand-in")])
def test_the_written_file_takes_no_part_of_the_test_rows(sn637, monkeypatch, draw, path):
    """The record's test rows changed after the tracing (noise and a step of 100x the sensor's noise there, on
    the base's displacement only): the file written (the core's choice, the mode refitted by replay through the
    file, the joint fit's stand-in for the record off the development rows) is the same text to the bit and the
    development rows' replay errors the same; only the test error moves (review of s15_rt, as its leak3.py).
    Each path is checked to have run: the mode refitted (seed 24 #55) or the stand-in built (a creep+delay draw)."""
    import copy

    from workbench.calibrate import plant_update as pu
    t, sp, base, plant, truth, r, res = _traced(sn637, *draw)
    stand_ins = []
    real = pu._fitted_motion
    monkeypatch.setattr(pu, "_fitted_motion", lambda *a, **k: stand_ins.append(1) or real(*a, **k))
    out = []
    for pert in (0.0, 1e-7):
        b = copy.deepcopy(base)
        m = b.channels["displacement"]
        rng = np.random.default_rng(0)
        m.y[sp.test] = m.y[sp.test] + pert * (1.0 + rng.standard_normal(int(sp.test.sum())))
        core, dev, err = choose_core(PLANTS / "p888_51_sn637.toml", sn637, b, res, Path("rec.csv"), sp.train,
                                     test=sp.test)
        text = pu.updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, b, res, Path("rec.csv"), core=core)
        out.append((core, dev, err, text))
    (a, da, ea, ta), (c, dc, ec, tc) = out
    if path == "mode refit":
        assert a.get("mode") is not None, a["reason"]
    else:
        assert stand_ins and a.get("joint") is True, (a["reason"], a["how"])
    assert ta == tc
    assert da == dc
    assert ea is not None and ec["rms"] > ea["rms"]


@pytest.mark.parametrize("gain", [0.40, 0.45, 0.49, 0.497, 0.499])
def test_creep_branches_never_write_a_branch_the_plant_file_cannot_load(gain):
    """One branch across C_h (closed form C = A C_h (C_h + C_pp) / (C_pp - A C_h), A = c / (1 - c)): near the
    ceiling A C_h -> C_pp it diverges past the plant file's 1 mF per branch; then no branches and a reason
    (session 15: a declared core's file with 3.5 mF did not load and the calibration stopped)."""
    from workbench.calibrate.plant_update import creep_branches
    c_pp, c_s = 10e-6, 5e-6
    c_h = 1.0 / (1.0 / c_s - 1.0 / c_pp)                        # 10 uF
    a = gain / (1.0 - gain)
    closed = a * c_h * (c_h + c_pp) / (c_pp - a * c_h)
    out = creep_branches([gain], [0.5], c_s, c_pp)
    if closed <= 1e-3:
        assert out["capacitances_f"] is not None and out["capacitances_f"][0] == pytest.approx(closed, rel=1e-9)
    else:
        assert out["capacitances_f"] is None and out["time_constants_s"] is None
        assert "1 mF" in out["reason"] or "0.001 F" in out["reason"]


def test_a_bow_beyond_the_plant_files_range_is_a_gap_not_a_file_that_will_not_load(sn637, tmp_path):
    """The benchmark draws gauge bows up to 6e3 x 30 = 1.8e5 /m; the plant file takes ``coefficient_per_m`` within
    +-1e5 /m. A fitted bow beyond it made ``workbench calibrate`` exit 2 "internal: the updated plant would not
    load" (s18_line, found on main). Drawn (``default_rng(1890)``, the second of 10-30x draws): a 25.8x bow,
    -1.29e5 /m, on the 1 kHz calibration protocol. The written file loads, carries no bow, and the gaps say why."""
    from workbench.calibrate.plant_update import plant_file_gaps
    from workbench.plant.files import PLANT_FIELDS
    res, err, base, sp = _round_trip(sn637, "gauge_nonlinearity", 1e3, "calibration", 25.76261493601214, 18545206,
                                     tmp_path)
    bows = [s for s in res["stages"] if s["effect"] == "gauge_nonlinearity"]
    assert bows, res["stages"]
    b = bows[0]["parameters"]["coefficient_per_m"]
    f = PLANT_FIELDS["gauge_nonlinearity"]["coefficient_per_m"]
    assert not f.lo <= b <= f.hi, b                      # the draw does exercise the bound
    text = (tmp_path / "p.toml").read_text()
    assert "[gauge_nonlinearity]" not in text
    gaps = plant_file_gaps(res["stages"], base, sn637)
    assert any("gauge bow" in g and "beyond the plant file" in g for g in gaps), gaps


@pytest.mark.parametrize("gain, written", [(0.012, True), (0.9, False)])
def test_a_mode_found_on_a_structure_plant_is_a_mode_of_its_structure(tmp_path, gain, written):
    """s22_outsider B2: a resonance named against a ``[structure]`` plant was written as ``[[mechanics.modes]]``,
    which the loader refuses beside ``[structure]`` (the structure is the whole M(.)): the run stopped on its own
    file. The tracing's mode is ``x (1 + g (H - 1))``, a share g of the quasi-static motion through a unit-gain mode;
    in the modal model that is one more mode holding g of the static compliance, taken from the residual: the
    file loads, the static stiffness is the declared one and the new mode holds g (``1 / (m w^2)`` of
    ``1 / k_static``). A share above what the declared modes leave cannot be held: not written, and said."""
    from types import SimpleNamespace
    path = PLANTS / "p888_51_sn637_on_flexure.toml"
    declared = load_plant(path)
    err = {"rms": 1e-8, "max": 3e-8, "units": "m"}
    p = {"f_n_hz": 310.0, "zeta": 0.015, "gain": gain}
    st = {"effect": "resonance", "channel": "displacement", "parameters": p, "error_before": err, "error_after": err}
    result = {"effect": "resonance", "channel": "displacement", "parameters": p, "error_before": err,
              "error_after": err, "stages": [st]}
    text = updated_plant_text(path, declared, SimpleNamespace(channels={}), result, Path("rec.csv"))
    (tmp_path / "p.toml").write_text(text)
    again = load_plant(tmp_path / "p.toml")
    k0 = 1.0 / declared.structure.static_compliance_m_per_n()[0, 0]
    assert 1.0 / again.structure.static_compliance_m_per_n()[0, 0] == pytest.approx(k0, rel=1e-9)
    assert "[[mechanics.modes]]" not in text and not again.pzt.modes
    modal, before = again.structure.modal, declared.structure.modal
    if not written:
        assert np.array_equal(modal["freqs_hz"], before["freqs_hz"])
        assert "resonance found on the displacement (310 Hz) is not written" in text and "residual compliance" in text
        return
    assert list(modal["freqs_hz"]) == [*before["freqs_hz"], 310.0]
    assert modal["damping_ratios"][-1] == pytest.approx(0.015)
    w = 2 * np.pi * 310.0
    share = k0 * float(modal["psi"][-1, 0]) ** 2 / (modal["modal_masses_kg"][-1] * w * w)
    assert share == pytest.approx(gain, rel=1e-9)
    r0 = float(declared.structure.residual_compliance_m_per_n[0])
    assert float(again.structure.residual_compliance_m_per_n[0]) == pytest.approx(r0 - gain / k0, rel=1e-9)
