"""A stack mode driven through the held command's path between samples (session 31, s31_alias; issue 13's 100 Hz floor).

At 100 Hz the amplifier's command is held from sample to sample: each sample's step moves the stack's charge at
the current limit, then settles through the series resistor (RC ~0.46 ms on the P-888.51), all within the 10 ms
sample. A mode of the stack rings after each step; the samples see that ring at its alias, with an amplitude and
phase set by the path, not by a straight line between samples (the first-order hold the mode search assumed).
:class:`~workbench.calibrate.effects.HeldDrive` is that path from the declared R, current limits and the
record's charge; :func:`~workbench.calibrate.effects.held_mode_column` the mode driven through it, which tells a
mode above the record's Nyquist frequency from its alias (the same poles, different responses to the path).

The records here are simulated with the mode resolved (``n_sub=64``: 0.16 ms sub-steps; the alias-family
tests on the simulator's own, ``synthetic.substeps``: 125 at 100 Hz since session 32). Until session 32 the
confusion benchmark's records used ``n_sub=4``: at 100 Hz its 2.5 ms sub-steps ramped each step's 0.46 ms settle
over 2.5 ms, so what its records showed of a mode above ~100 Hz was partly the simulator's sub-stepping.
"""

import dataclasses

import numpy as np
import pytest
from scipy import signal

from tests.conftest import FULL_ONLY, load_benchmark, reduced_draws
from workbench.calibrate.effects import HeldDrive, held_mode_column

R_OHM, C_F, LIMITS_A = 80.0, 5.8e-6, (2e-3, 14e-3)    # the P-888.51 file's resistor, ~its capacitance, its limits


def _amplifier_charge(levels_v, dt, n_fine):
    """The stack's charge under a held command (``levels_v``, one per sample), integrated on ``n_fine`` sub-steps
    a sample: ``dq/dt = (V_cmd - q / C) / R`` clipped at the current limits (exact per sub-step: the time at the
    limit, then the settle), independently
    of :class:`HeldDrive`'s closed form. Returns the fine charge (C) and its times (s)."""
    vc = np.repeat(levels_v, n_fine)
    h, rc = dt / n_fine, R_OHM * C_F
    q = np.zeros(vc.size + 1)
    for j in range(vc.size):
        i = (vc[j] - q[j] / C_F) / R_OHM
        lim = LIMITS_A[0] if i > 0 else -LIMITS_A[1]
        # at the limit until the resistor's current falls to it (q = C (V - R lim)), then the RC settle
        t_lim = min(max((C_F * (vc[j] - R_OHM * lim) - q[j]) / lim, 0.0), h) if abs(i) > abs(lim) else 0.0
        q1 = q[j] + lim * t_lim
        q[j + 1] = vc[j] * C_F + (q1 - vc[j] * C_F) * np.exp(-(h - t_lim) / rc)
    return q, np.arange(q.size) * h


@pytest.mark.parametrize("f_hz, zeta", [(38.0, 0.012), (83.0, 0.015), (277.0, 0.018)])
def test_the_held_mode_column_is_the_mode_under_a_current_limited_amplifier(f_hz, zeta):
    """At 100 Hz, steps small (settled by R C) and large (slewing at the 2 mA source and 14 mA sink limits): the
    column from the sampled charge alone equals a fine simulation of the mode driven by the amplifier's charge
    to 1e-4 of its peak (measured 1e-6 - 5e-5 on 0.02 ms sub-steps), below and above the 50 Hz Nyquist
    frequency; the compiled pass equals the numpy form.
    The first-order hold (the drive a straight line between samples), its gain free, leaves over 30 times
    as much (13-90 % of the column's RMS)."""
    from workbench.calibrate.effects import Resonance
    dt, n_fine = 0.01, 500
    levels = np.r_[0.0, np.repeat([30.0, 31.0, 29.5, 80.0, 10.0, 12.0, 60.0], 6)]
    q, tf = _amplifier_charge(levels, dt, n_fine)
    u_fine = 0.1 * q                               # the motion in proportion to the charge (m)
    w = 2 * np.pi * f_hz
    _, y_fine, _ = signal.lsim(([w * w], [1.0, 2 * zeta * w, w * w]), u_fine, tf)
    ref = (y_fine - u_fine)[::n_fine]
    qs = q[::n_fine]
    held = HeldDrive(np.diff(qs, prepend=qs[0]), dt, R_OHM * C_F, LIMITS_A)
    got = held_mode_column(0.1 * qs, held, f_hz, zeta)
    peak = np.max(np.abs(ref))
    assert np.max(np.abs(got - ref)) < 1e-4 * peak
    _assert_numpy_form_equals_compiled(0.1 * qs, held, f_hz, zeta, got, peak)
    foh = Resonance._column(0.1 * qs, f_hz, zeta, dt)
    g = float(foh @ ref / (foh @ foh))
    assert np.sqrt(np.mean((ref - g * foh) ** 2)) > 30 * np.max(np.abs(got - ref))


def _assert_numpy_form_equals_compiled(u, held, f_hz, zeta, got, peak):
    """The held column's numpy form equals the compiled pass ``got`` to 1e-12 of the column's ``peak``."""
    import workbench.calibrate.effects as E
    try:
        E._HELD_COMPILED = False
        numpy_form = held_mode_column(u, held, f_hz, zeta)
    finally:
        E._HELD_COMPILED = True
    assert np.max(np.abs(got - numpy_form)) < 1e-12 * peak


def _amplifier_charge_per_step(levels_v, caps_f, dt, n_fine):
    """As :func:`_amplifier_charge` on a stack whose capacitance is ``caps_f[k]`` over sample ``k``'s step (a
    hysteretic stack's incremental capacitance along its loop: smallest at a reversal, larger on a continuing step):
    the terminal voltage ``v = v_k + (q - q_k) / C_k`` from the step's start. Returns the fine charge (C), the
    terminal voltage at the samples (V) and the fine times (s)."""
    h = dt / n_fine
    q = [0.0]
    v_s = [0.0]
    qk, vk = 0.0, 0.0
    for lev, C in zip(levels_v, caps_f):
        for _ in range(n_fine):
            v = vk + (q[-1] - qk) / C
            i = (lev - v) / R_OHM
            lim = LIMITS_A[0] if i > 0 else -LIMITS_A[1]
            q_end = qk + C * (lev - vk)                  # the charge the step settles to
            t_lim = min(max((q_end - C * R_OHM * lim - q[-1]) / lim, 0.0), h) if abs(i) > abs(lim) else 0.0
            q1 = q[-1] + lim * t_lim
            q.append(q_end + (q1 - q_end) * np.exp(-(h - t_lim) / (R_OHM * C)))
        vk = vk + (q[-1] - qk) / C
        qk = q[-1]
        v_s.append(vk)
    q = np.asarray(q)
    return q, np.asarray(v_s), np.arange(q.size) * h


def test_held_drive_settles_each_step_at_the_records_capacitance_within_the_declared_range():
    """:func:`~workbench.calibrate.tracing.held_drive` builds the path with each interval's ``R dq / dv`` (the
    record's charge over its terminal-voltage step), clipped to the declared ``R C_min .. R C_pp``, and ``R C_min``
    where the step has no voltage: the wiring the placement of 100 Hz modes rests on (review of s34_hold S2: with
    ``rc_k`` dropped from ``held_drive`` the make-test form still passed)."""
    from types import SimpleNamespace

    from workbench.calibrate.tracing import held_drive
    c_min, c_pp, dt = 6.0e-6, 16.7e-6, 0.01
    t = dt * np.arange(300)
    v = np.round(5.0 * np.sin(2 * np.pi * 1.3 * t), 1)              # steps, some of them of no voltage
    dv = np.diff(v, prepend=v[0])
    rng = np.random.default_rng(34)
    caps = rng.uniform(0.5 * c_min, 1.5 * c_pp, t.size)             # beyond the declared range on both sides
    q = np.cumsum(caps * dv)
    base = SimpleNamespace(series_resistance_ohm=R_OHM, current_limits_a=LIMITS_A,
                           settle_time_constant_s=R_OHM * c_min, settle_time_constant_max_s=R_OHM * c_pp,
                           channels={"charge": SimpleNamespace(y=q)}, t=t, v_drive=v, input_kind="terminal")
    held = held_drive(base)
    assert held is not None and held.rc == R_OHM * c_min
    moved = dv != 0
    assert moved.sum() > 100 and (~moved).sum() > 10
    np.testing.assert_allclose(held.rc_k[moved], R_OHM * np.clip(caps[moved], c_min, c_pp), rtol=1e-9)
    assert np.all(held.rc_k[~moved] == R_OHM * c_min)
    # the clip bites on both sides (the draw reaches beyond the range)
    assert np.any(caps[moved] < c_min) and np.any(caps[moved] > c_pp)


@pytest.mark.parametrize("f_hz, zeta", [(83.0, 0.015), (252.7, 0.0129)])
def test_the_held_path_settles_at_each_step_s_own_capacitance(f_hz, zeta):
    """A stack whose capacitance changes along its loop (the P-888.51's 6.0 uF at a reversal, 11.6 uF on a
    continuing step) settles each step through the resistor at that step's ``R C``. The record tells it: the charge
    moved over the step's terminal-voltage step (:func:`~workbench.calibrate.tracing.settle_time_constants`, within
    the declared ``R C_min .. R C_pp``). The held column on those settles equals a fine simulation of the mode to
    1e-4 of its peak; the path settled at ``R C_min`` throughout misses by more than ten times as much (a mode's ring
    excited by a settle of the wrong length has the wrong amplitude and phase), and the compiled pass equals the
    numpy form."""
    from types import SimpleNamespace

    from workbench.calibrate.tracing import settle_time_constants
    dt, n_fine, c_min, c_cont, c_pp = 0.01, 500, 6.0e-6, 11.6e-6, 16.7e-6
    # a sine's staircase (5 V, 1.3 Hz: each step ramps at the limit for at most 2.4 ms, then settles); a step
    # just after a reversal at C_min, the capacitance rising toward a continuing step's over the next ones
    levels = 5.0 * np.sin(2 * np.pi * 1.3 * dt * np.arange(1, 150))
    d = np.diff(levels, prepend=0.0)
    since = np.zeros(d.size)
    for k in range(1, d.size):
        since[k] = since[k - 1] + 1 if np.sign(d[k]) == np.sign(d[k - 1]) else 0
    caps = c_min + (c_cont - c_min) * -np.expm1(-since / 3.0)
    q, v_s, tf = _amplifier_charge_per_step(levels, caps, dt, n_fine)
    u_fine = 0.1 * q
    w = 2 * np.pi * f_hz
    _, y_fine, _ = signal.lsim(([w * w], [1.0, 2 * zeta * w, w * w]), u_fine, tf)
    ref = (y_fine - u_fine)[::n_fine]
    qs, vs = q[::n_fine], v_s               # sample k ends interval k, the step of levels[k - 1]
    dq = np.diff(qs, prepend=qs[0])
    base = SimpleNamespace(series_resistance_ohm=R_OHM, settle_time_constant_max_s=R_OHM * c_pp, v_drive=vs)
    rc_k = settle_time_constants(base, dq, R_OHM * c_min)
    # (the steps that settle within their sample: a slew at the current limit runs on into the next ones)
    settled = (np.abs(np.diff(vs, prepend=vs[0])) > 0) & (np.abs(vs - np.r_[0.0, levels]) < 1e-3)
    assert settled.sum() >= 100
    assert np.allclose(rc_k[settled], R_OHM * np.r_[c_min, caps][settled], rtol=1e-3)
    held = HeldDrive(dq, dt, R_OHM * c_min, LIMITS_A, rc_k=rc_k)
    got = held_mode_column(0.1 * qs, held, f_hz, zeta)
    peak = np.max(np.abs(ref))
    assert np.max(np.abs(got - ref)) < 1e-4 * peak
    at_min = held_mode_column(0.1 * qs, HeldDrive(dq, dt, R_OHM * c_min, LIMITS_A), f_hz, zeta)
    assert np.max(np.abs(at_min - ref)) > 10 * np.max(np.abs(got - ref))
    _assert_numpy_form_equals_compiled(0.1 * qs, held, f_hz, zeta, got, peak)


def _traced(plant0, kind, protocol, value, zeta=0.01, seed=1):
    """A 100 Hz, 40 s record of the benchmark's protocol on ``plant0`` (no creep) with one mode (``kind``
    "mode": ``value`` Hz), a displacement-sensor latency ("delay": ``value`` s) or neither ("none"), simulated
    with the mode resolved (``n_sub=64``), split, base-fitted and traced as the benchmark does."""
    from workbench.calibrate.base_fit import fit_base
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.synthetic import benchmark_protocol, simulate_record
    from workbench.calibrate.tracing import trace_effect
    from workbench.plant.additions import Additions
    from workbench.plant.pzt import Mode
    cc = load_benchmark("calibrate_confusion")
    rate = 100.0
    t, v = benchmark_protocol(protocol, rate, cc.ROWS[rate])
    pzt = dataclasses.replace(plant0.pzt, creep=None, modes=(Mode(value, zeta),) if kind == "mode" else ())
    add = Additions(sensor_delay_s=value) if kind == "delay" else Additions()
    plant = dataclasses.replace(plant0, pzt=pzt, additions=add)
    r = simulate_record(plant, t, v, seed=seed, n_sub=64)
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(cc._record(r, 1.0 / rate), plant0.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    return trace_effect(base, split=sp)


# modes above the 50 Hz Nyquist frequency up to the held search's ceiling (the settle's corner, 343 Hz), damping
# over the benchmark's drawn range (synthetic.EFFECT_RANGES: 0.005-0.02), on steps and the calibration
# protocol alternately; default_rng(3131), drawn before any record was traced. make test runs the first.
# Each is placed too (its alias family resolved, the plant file carries it): on main (session 33) 4 of 6 were, the
# 159.5 Hz steps draw (make test's) and the 252.7 Hz calibration draw named right and left out, their folds leaving
# the named member unresolved beyond members whose columns enter with a negative gain (140.3, 540-1240 Hz) and the
# held path settling every step at R C_min while the record's steps moved at ~10.6 uF; measured 6 of 6 since
# s34_hold (each step's own settle, :func:`~workbench.calibrate.tracing.settle_time_constants`; a member with a
# negative gain on every fold no rival)
_RNG = np.random.default_rng(3131)
MODES = reduced_draws([(("steps", "calibration")[k % 2], float(np.exp(_RNG.uniform(np.log(55.0), np.log(340.0)))),
                        float(_RNG.uniform(0.005, 0.02)), int(_RNG.integers(1 << 30))) for k in range(6)], keep=(0,))


@pytest.mark.slow
@pytest.mark.parametrize("protocol, f_hz, zeta, seed", MODES)
def test_a_mode_above_nyquist_is_named_at_its_frequency(sn637, protocol, f_hz, zeta, seed):
    """Named ``resonance`` (first, on 4 of 5 folds at least), at its frequency within a quarter of its
    half-power bandwidth ``2 zeta f``, its damping within 25 %, the held-out error at least halved, and placed: its
    alias family resolved and the plant file carrying it (``unplaced_modes``). Before session 31 these were answered
    ``none`` or ``inconclusive`` (the search stopped at Nyquist, its mode a first-order hold's)."""
    from workbench.calibrate.plant_update import unplaced_modes
    res = _traced(sn637, "mode", protocol, f_hz, zeta, seed)
    assert res["effect"] == "resonance", (res["effect"], res.get("fold_winners"))
    assert all(s["effect"] == "resonance" for s in res["stages"]), [s["effect"] for s in res["stages"]]
    p = res["stages"][0]["parameters"]
    assert abs(p["f_n_hz"] - f_hz) < 0.25 * 2 * zeta * f_hz, (p, f_hz)
    assert p["zeta"] == pytest.approx(zeta, rel=0.25)
    assert res["error_after"]["rms"] <= 0.5 * res["error_before"]["rms"]
    fam = res["stages"][0]["alias_family"]
    assert fam["resolved"] and not unplaced_modes(res["stages"]), fam.get("note")


# the discriminator's nulls at 100 Hz: a displacement-sensor latency over the benchmark's 100 Hz range
# (0.3-2 ms times its 0.03-30 sizes, here 0.3-20 ms, log-uniform) and records without a mode, on steps and the
# calibration protocol; default_rng(3132), drawn before any record was traced. make test runs the first delay
# (the effect-free records, every protocol, in WORKBENCH_FULL=1 only: test_rate_ends holds 100 Hz ones)
_RNG2 = np.random.default_rng(3132)
DELAYS = reduced_draws([(("steps", "calibration")[k % 2], float(np.exp(_RNG2.uniform(np.log(3e-4), np.log(2e-2)))),
                         int(_RNG2.integers(1 << 30))) for k in range(2)], keep=(0,))


@pytest.mark.slow
@pytest.mark.parametrize("protocol, delay_s, seed", DELAYS)
def test_a_displacement_latency_at_100_hz_is_still_a_delay(sn637, protocol, delay_s, seed):
    """A latency of the displacement sensor alone is named ``delay``, and no mode is named beside it."""
    res = _traced(sn637, "delay", protocol, delay_s, seed=seed)
    assert res["effect"] == "delay", (res["effect"], res.get("fold_winners"))
    assert "resonance" not in [s["effect"] for s in res["stages"]]


@pytest.mark.slow
@pytest.mark.parametrize("protocol, seed", reduced_draws([("steps", 11), ("calibration", 12), ("sine", 13)],
                                                         keep=()))
def test_a_record_without_a_mode_names_no_mode_at_100_hz(sn637, protocol, seed):
    """No effect in the plant: no mode (and no effect) named."""
    res = _traced(sn637, "none", protocol, 0.0, seed=seed)
    assert [s["effect"] for s in res["stages"]] == [], (res["effect"], res.get("fold_winners"))


def _resolved_base(plant0, protocol, f_hz, zeta, seed, n_sub=64):
    """A 100 Hz record of the benchmark's protocol with one resolved mode (``n_sub=64``; None: the simulator's
    own, ``synthetic.substeps``): its plant, split and base fit (as :func:`_traced`, without the tracing)."""
    from workbench.calibrate.base_fit import fit_base
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.synthetic import benchmark_protocol, simulate_record
    from workbench.plant.additions import Additions
    from workbench.plant.pzt import Mode
    cc = load_benchmark("calibrate_confusion")
    rate = 100.0
    t, v = benchmark_protocol(protocol, rate, cc.ROWS[rate])
    plant = dataclasses.replace(plant0, pzt=dataclasses.replace(plant0.pzt, creep=None, modes=(Mode(f_hz, zeta),)),
                                additions=Additions())
    r = simulate_record(plant, t, v, seed=seed, n_sub=n_sub)
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(cc._record(r, 1.0 / rate), plant0.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    return plant, sp, base


# the plant file's replay at 100 Hz (session 31, s31_replay): modes over the held search's range (55-340 Hz), the
# benchmark's damping range, steps and the calibration protocol alternately; default_rng(3133), drawn before any
# record was replayed. make test runs the first
_RNG3 = np.random.default_rng(3133)
_REPLAY_DRAWS = [(("steps", "calibration")[k % 2], float(np.exp(_RNG3.uniform(np.log(55.0), np.log(340.0)))),
                  float(_RNG3.uniform(0.005, 0.02)), int(_RNG3.integers(1 << 30))) for k in range(4)]
REPLAYS = reduced_draws(_REPLAY_DRAWS, keep=(0,))
# the written file: ~6-9 s a draw (the tracing and the core's choice), in WORKBENCH_FULL=1 only. The 264 Hz
# calibration draw misses (measured 2026-11-28: the file 1.85e-9 m, the tracing 1.36e-9, 1.36x; the plant that
# made the record replays at 2.22e-9 itself: the replay's floor, the quasi-static form and the path's charge-
# proportional terminal voltage, above a tracing that reaches the sensor's noise)
_FLOOR = pytest.mark.xfail(strict=True, reason="the replay's floor (~2e-9 m) above the tracing's 1.36e-9: a 264 Hz "
                                               "mode's small share (5.3e-9) on the calibration protocol")
FILE_REPLAYS = reduced_draws([pytest.param(*d, marks=[_FLOOR]) if k == 1 else d for k, d in enumerate(_REPLAY_DRAWS)],
                             keep=())


@pytest.mark.parametrize("protocol, f_hz, zeta, seed", REPLAYS)
def test_the_plant_that_made_a_100_hz_record_replays_it(sn637, protocol, f_hz, zeta, seed):
    """The record's drive replayed through the plant that made it (``plant_update.updated_plant_error``: the
    quasi-static plant driven by the recorded terminal voltage, along the held drive's path between samples)
    leaves at most 2.5x the displacement sensor's 1 nm noise, and at most half of what the same replay without
    the mode leaves (the mode is replayed, not only the noise). Measured on the four draws: 1.9-2.2e-9 m
    (without the mode 5.3e-9 - 8.8e-8); the straight line between samples (the replay before s31_replay)
    4.3e-9 - 5.6e-8, 0.6-1.4x the mode's share. The floor: the sensor's 1 nm and the quasi-static replay's own
    (a 120 Hz steps record driven by the exact fine terminal voltage: 1.36e-9 against the record's 0.97e-9)."""
    from workbench.calibrate.plant_update import updated_plant_error
    plant, sp, base = _resolved_base(sn637, protocol, f_hz, zeta, seed)
    true = updated_plant_error(plant, base, "displacement", sp.test, train=sp.train)["rms"]
    bare = dataclasses.replace(plant, pzt=dataclasses.replace(plant.pzt, modes=()))
    without = updated_plant_error(bare, base, "displacement", sp.test, train=sp.train)["rms"]
    assert true <= 2.5e-9, (true, without)
    assert true <= 0.5 * without, (true, without)


@pytest.mark.slow
@pytest.mark.parametrize("protocol, f_hz, zeta, seed", FILE_REPLAYS)
def test_a_100_hz_mode_written_to_the_plant_file_replays_the_tracing_error(sn637, protocol, f_hz, zeta, seed,
                                                                           tmp_path):
    """Issue 13 item 6 at 100 Hz: the updated plant file (the mode written and refitted by replay, as
    ``workbench calibrate`` writes it) replays the record within 10 % of the tracing's held-out error, or below it."""
    from pathlib import Path

    from workbench.calibrate.plant_update import choose_core, updated_plant_error, updated_plant_text
    from workbench.calibrate.tracing import trace_effect
    from workbench.plant import load_plant
    from tests.conftest import PLANTS
    plant, sp, base = _resolved_base(sn637, protocol, f_hz, zeta, seed)
    res = trace_effect(base, split=sp)
    assert res["effect"] == "resonance", res["effect"]
    path = PLANTS / "p888_51_sn637.toml"
    core, _, _ = choose_core(path, sn637, base, res, Path("record.csv"), sp.train, test=sp.test)
    p = tmp_path / "p.toml"
    p.write_text(updated_plant_text(path, sn637, base, res, Path("record.csv"), core=core), encoding="utf-8")
    file_err = updated_plant_error(load_plant(p), base, "displacement", sp.test, train=sp.train)["rms"]
    assert file_err <= 1.1 * res["error_after"]["rms"], (file_err, res["error_after"]["rms"])


# the alias family (session 32, the review of s31_alias B1): a mode above Nyquist rings in the samples at its alias,
# and so does every ``k fs +- f_a`` in the held search's band. Modes over the held search's range (55-340 Hz), the
# benchmark's damping range, the three protocols in turn, on converged records (synthetic.substeps);
# default_rng(3202), drawn before the family test was run on any. 7-10 s a draw: WORKBENCH_FULL=1 only (make test
# runs the family's arithmetic, test_the_alias_family_is_every_image_in_the_band). The 151 Hz sine draw misses
# (measured 2026-11-28): named 204.9 Hz, zeta 0.035, gain -0.23, ratio 0.28, 5 of 5 folds, outside the drawn mode's
# family (its alias 49 Hz, the named one's 4.9 Hz), the family test resolved about the wrong alias: under the slow
# sine's small steps the held search fits a phase, not the mode (README, session 31's "not done" (2)). The plant file
# does not carry it (since session 33 the placement rule: not a stack mode's gain, plant_update.unplaced_modes); the
# JSON names it. Measured on the other five: four
# resolved at the drawn frequency, the 216.6 Hz calibration draw named 216.9 Hz but resolved on 3 of 5 folds only
# (said, not written)
_RNG4 = np.random.default_rng(3202)
_SINE_MISS = pytest.mark.xfail(strict=True, reason="a mode under the 100 Hz sine named off its alias family "
                                                   "(151 Hz named 204.9 Hz, gain -0.23): not an alias confusion")
_FAMILY_DRAWS = [(("steps", "calibration", "sine")[k % 3], float(np.exp(_RNG4.uniform(np.log(55.0), np.log(340.0)))),
                  float(_RNG4.uniform(0.005, 0.02)), int(_RNG4.integers(1 << 30))) for k in range(6)]
FAMILIES = reduced_draws([pytest.param(*d, marks=[_SINE_MISS]) if k == 5 else d for k, d in enumerate(_FAMILY_DRAWS)],
                         keep=())


def test_the_alias_family_is_every_image_in_the_band():
    """``alias_members``: a 200.4 Hz mode at 100 Hz in a 5-343 Hz band is one of 99.6 / 100.4 / 199.6 / 200.4 /
    299.6 / 300.4 Hz (each ``k fs +- 0.4``; 0.4 Hz under the band's floor); a 30 Hz mode below Nyquist has 70, 130,
    170, 230, 270, 330 Hz as images; the member nearest the named frequency is the named frequency itself."""
    from workbench.calibrate.tracing import alias_members
    got = alias_members(200.4, 100.0, 5.0, 343.0)
    assert np.allclose(got, [99.6, 100.4, 199.6, 200.4, 299.6, 300.4])
    assert np.allclose(alias_members(30.0, 100.0, 5.0, 343.0), [30, 70, 130, 170, 230, 270, 330])
    f = 151.0814
    assert f in alias_members(f, 100.0, 5.0, 343.0)


def _traced_default(plant0, protocol, f_hz, zeta, seed):
    """As :func:`_traced` with one mode, on the simulator's own converged sub-steps (``synthetic.substeps``)."""
    from workbench.calibrate.tracing import trace_effect
    plant, sp, base = _resolved_base(plant0, protocol, f_hz, zeta, seed, n_sub=None)
    return trace_effect(base, split=sp), base


@pytest.mark.slow
@pytest.mark.parametrize("protocol, f_hz, zeta, seed", FAMILIES)
def test_a_held_mode_is_placed_in_its_alias_family_or_said_not_to_be(sn637, protocol, f_hz, zeta, seed):
    """Where a mode is named through the held drive's path, its alias family is tested on the folds: a family
    reported resolved, its mode written to the file (``unplaced_modes``: not a gain <= 0), has the drawn frequency named (within a quarter of the half-power bandwidth ``2 zeta f``);
    one reported unresolved holds the drawn frequency among the members it says the record cannot tell apart,
    and says so in the stage's note. Either way the named frequency is a member. The drawn frequencies' images
    in the band are the test's own arithmetic (``k fs +- f_a``), not the code's."""
    res, _ = _traced_default(sn637, protocol, f_hz, zeta, seed)
    held = [s for s in res["stages"] if s["effect"] == "resonance" and s["parameters"].get("held")]
    if not held:
        pytest.skip(f"no held mode named ({res['effect']}, {[s['effect'] for s in res['stages']]})")
    st = held[0]
    fam = st["alias_family"]
    f_named = st["parameters"]["f_n_hz"]
    bw = 2 * zeta * f_hz
    fa = min(f_hz % 100.0, 100.0 - f_hz % 100.0)
    images = [k * 100.0 + s * fa for k in range(5) for s in (-1, 1)]
    assert min(abs(f_named - m) for m in images) < bw, (f_named, f_hz)       # the named one rings at the alias
    assert any(abs(m - f_named) < 1e-9 for m in fam["members_hz"])
    from workbench.calibrate.plant_update import unplaced_modes
    if fam["resolved"] and (st["effect"], st["channel"]) not in unplaced_modes(res["stages"]):
        # placed: what the plant file carries as measured is the drawn mode
        assert abs(f_named - f_hz) < 0.25 * bw, (fam, f_hz)
    else:
        # not placed: the note says why (the family unresolved: the drawn frequency among the members it names); a
        # column whose gain is no stack mode's is no evidence of the mode's frequency: no candidate is said (session
        # 33's review: a 404.9 Hz draw named 265.8 Hz, its family listed without the truth)
        if not fam["gain"]["consistent"]:
            assert "one of " not in fam["note"] and "ring at the same alias" not in fam["note"], fam["note"]
            assert "does not tell the mode's frequency" in fam["note"], fam["note"]
        if "one of " in fam["note"]:
            said = [float(x) for x in fam["note"].split("one of ")[1].split(" Hz")[0].split(" / ")]
            assert min(abs(m - f_hz) for m in said) < bw, (fam, f_hz)
        assert st["note"] == fam["note"] and "not placed" in fam["note"]


def test_the_plant_file_leaves_out_a_held_mode_it_cannot_place():
    """``unplaced_modes``: a held mode whose family is not placed is left out with its reason; a placed one, and any
    mode without a family (not the held drive's), are written (the gain is tested in the family, on the folds)."""
    from workbench.calibrate.plant_update import unplaced_modes
    fam = {"members_hz": [100.4, 200.4, 300.4], "named_hz": 100.4, "resolved": False, "note": "a mode at one of ..."}
    st = [{"effect": "resonance", "channel": "displacement", "parameters": {"f_n_hz": 100.4, "gain": 1.0, "held": True},
           "alias_family": fam}]
    assert "a mode at one of" in unplaced_modes(st)[("resonance", "displacement")]
    st[0]["alias_family"] = {**fam, "resolved": True}
    assert unplaced_modes(st) == {}
    assert unplaced_modes([{"effect": "resonance", "channel": "gauge", "parameters": {"gain": -0.5}}]) == {}
    # a first-order hold's mode on a held record carries its family too (s34_hold): left out alike
    st = [{"effect": "resonance", "channel": "displacement", "parameters": {"f_n_hz": 3.68, "zeta": 0.3, "gain": 0.79},
           "alias_family": fam}]
    assert "a mode at one of" in unplaced_modes(st)[("resonance", "displacement")]


@pytest.mark.slow
@FULL_ONLY
def test_a_first_order_hold_s_mode_is_placed_through_the_held_path(sn637):
    """The review of s33_alias (6): default_rng(3319)'s drift + 103.9 Hz mode on the 100 Hz sine (the benchmark's
    generator) was named a 3.68 Hz mode at the damping cap (zeta 0.30) by the first-order hold's column, outside every
    test, and written. On a record with a held drive every named mode is tested in its alias family through the held
    path: whatever the plant file carries is the drawn mode (a quarter of its half-power bandwidth), and a mode left
    out says why."""
    from workbench.calibrate.plant_update import unplaced_modes
    from workbench.calibrate.tracing import trace_effect
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(3319)
    protos = ("sine", "calibration", "steps")
    draws = [(protos[k % 3], float(np.exp(rng.uniform(np.log(0.1), np.log(30.0)))), int(rng.integers(1 << 30)))
             for k in range(7)]
    proto, size, s = draws[6]
    _, sp, base, _, truth, _ = cc.simulated_base(sn637, ("drift", "resonance"), 100.0, proto, size, s)
    res = trace_effect(base, split=sp)
    un = unplaced_modes(res["stages"])
    f, z = truth["freq_hz"], truth["damping_ratio"]
    modes = [st for st in res["stages"] if st["effect"] == "resonance"]
    for st in modes:
        assert st.get("alias_family") is not None
        if (st["effect"], st["channel"]) in un:
            assert "not placed" in st["note"]
        else:
            assert abs(st["parameters"]["f_n_hz"] - f) < 0.5 * z * f, (st["parameters"], f)


def test_the_folds_jackknife_is_the_standard_error_of_a_mean():
    """The folds' jackknife (each fold's estimate from the other folds' blocks): for the mean of ``n`` group means,
    the leave-one-group-out means' jackknife standard error is the classical ``sd / sqrt(n)``."""
    from workbench.calibrate.tracing import _jackknife
    x = np.random.default_rng(3303).normal(1.0, 0.2, 5)
    loo = [(x.sum() - v) / (x.size - 1) for v in x]
    m, se = _jackknife(loo)
    assert m == pytest.approx(x.mean(), rel=1e-12)
    assert se == pytest.approx(x.std(ddof=1) / np.sqrt(x.size), rel=1e-12)


def test_a_held_mode_s_gain_is_a_stack_mode_s_share():
    """``gain_is_a_modes``: the column ``(H - 1) x`` of a stack mode enters with its share of the motion, ~1 (the
    simulator's single mode: 1 exactly); per-fold gains about 1 (a 107 #126-like spread, 0.86-0.92) are a mode's,
    a steady 0.35 (the review's 490 Hz mode named 285.6 Hz), a steady -0.25 (105 #121) or a scattered 2.6 (106
    #121 on this branch: 93.2 Hz named 81.2 Hz) are not. The band's ends are the physics' (``8 / pi^2``, 1), not
    fitted to these."""
    from workbench.calibrate.tracing import MODE_GAIN_BAND, gain_is_a_modes
    assert MODE_GAIN_BAND[0] == pytest.approx(0.8106, abs=1e-4) and MODE_GAIN_BAND[1] == 1.0
    assert gain_is_a_modes([0.915, 0.864, 0.876, 0.856, 0.857])[0]
    assert gain_is_a_modes([1.061, 1.039, 1.026, 1.127, 1.048])[0]
    assert not gain_is_a_modes([0.351, 0.346, 0.354, 0.348, 0.354])[0]
    assert not gain_is_a_modes([-0.257, -0.146, -0.235, -0.297, -0.256])[0]
    assert not gain_is_a_modes([2.96, 2.63, 2.64, 2.60, 2.71])[0]
    assert not gain_is_a_modes([1.0])[0]           # one fold: no scatter, no test


def test_each_fold_s_own_search_must_name_the_mode():
    """``folds_name_the_mode``: a fold names the mode when its own search lands in the named mode's half-power band
    (``zeta f``) and nearer it than any other alias member: the review's 107 #121 folds (285.3 / 292.7 / 306.6 /
    285.7 / 306.5 Hz about 285.7 Hz, zeta 0.0083: 2.4 Hz) name it on 2; 108 #110's (207.8-207.9 Hz and one fold at
    107.3 Hz about 207.9 Hz) on 4; a fold without a ring names nothing."""
    from workbench.calibrate.tracing import alias_members, folds_name_the_mode
    f0, z0 = 285.64, 0.008305
    fam = alias_members(f0, 100.0, 5.0, 331.6)
    fits = [{"f_n_hz": f} for f in (285.32, 292.66, 306.59, 285.67, 306.52)]
    assert folds_name_the_mode(f0, z0, fam, fits) == [True, False, False, True, False]
    f0, z0 = 207.9, 0.01726
    fam = alias_members(f0, 100.0, 5.0, 331.6)
    fits = [{"f_n_hz": f} for f in (207.81, 207.87, 207.88, 107.31, 207.85)] + [None]
    assert folds_name_the_mode(f0, z0, fam, fits) == [True, True, True, False, True, False]


# the placement rule scored on draws it never saw (the review of s32_alias, B1 (d)): single modes 27-600 Hz (past the
# held search's 331.6 Hz ceiling, to the review's 490 and 588 Hz), the benchmark's damping range, the sine, the
# calibration and the steps protocols in turn; default_rng(3304), drawn after the rule was fixed and before it was
# run on any. Measured (2026-11-28): 9 right and written, 2 right but not placed (said: 234.8 Hz, its family unresolved
# beyond the 334.8 Hz member above the band; 193.8 Hz, the folds' own searches), 4 wrong and not written, 3 no mode
# named, 0 wrong written (s32_alias's rules on the same draws: 11 right written, 1 WRONG written -- 378.9 Hz named
# 278.8 Hz, gain 0.64 -- 3 wrong not written, 3 none). ~3-9 s a draw (~17 s the first in a
# worker): WORKBENCH_FULL=1 only; make test guards the rule by its pieces (test_each_fold_s_own_search_must_name_the_mode,
# test_a_held_mode_s_gain_is_a_stack_mode_s_share, test_the_folds_jackknife_is_the_standard_error_of_a_mean)
_RNG6 = np.random.default_rng(3304)
_PLACEMENT_DRAWS = [(("sine", "calibration", "steps")[k % 3], float(np.exp(_RNG6.uniform(np.log(27.0), np.log(600.0)))),
                     float(_RNG6.uniform(0.005, 0.02)), int(_RNG6.integers(1 << 30))) for k in range(18)]
PLACEMENTS = reduced_draws(_PLACEMENT_DRAWS, keep=())


@pytest.mark.slow
@pytest.mark.parametrize("protocol, f_hz, zeta, seed", PLACEMENTS)
def test_a_held_mode_written_to_the_plant_file_is_the_drawn_mode(sn637, protocol, f_hz, zeta, seed):
    """Whatever the 100 Hz record names through the held drive's path, the mode the plant file carries
    (``unplaced_modes`` leaves out what the folds do not place) is the drawn one: within a quarter of its half-power
    bandwidth ``2 zeta f``. A mode not placed is said in the stage's note. The truth is the draw's, not the code's."""
    from workbench.calibrate.plant_update import unplaced_modes
    res, _ = _traced_default(sn637, protocol, f_hz, zeta, seed)
    un = unplaced_modes(res["stages"])
    for st in res["stages"]:
        # (every mode of a held-drive record: the first-order hold's column's too, since s34_hold)
        if st["effect"] != "resonance":
            continue
        if (st["effect"], st["channel"]) in un:
            assert "not placed" in st["note"] and st["note"] == st["alias_family"]["note"]
        else:
            assert abs(st["parameters"]["f_n_hz"] - f_hz) < 0.25 * 2 * zeta * f_hz, (st, f_hz)


@pytest.mark.slow
@FULL_ONLY
@pytest.mark.parametrize("seed, index", [(107, 121), (105, 121), (108, 115)])
def test_the_review_s_off_family_modes_are_not_placed(sn637, seed, index):
    """The review of s32_alias's off-family readings (B1): 107 #121 (a 490 Hz mode under the sine, drift beside it)
    was named 285.6 Hz, gain 0.35, "resolved 5 of 5" and written; 105 #121 (31.7 Hz) 102.7 Hz, gain -0.24; 108 #115
    (588 Hz) 302.1 Hz. Whatever the record names through the held path, the plant file carries no held mode away from
    the drawn frequency (a quarter of its half-power bandwidth)."""
    from workbench.calibrate.plant_update import unplaced_modes
    from workbench.calibrate.tracing import trace_effect
    cc = load_benchmark("calibrate_confusion")
    eff, rate, proto, size, s = cc.cases(1, seed, ends=True)[index - 1]
    assert rate == 100.0 and "resonance" in (eff if isinstance(eff, tuple) else (eff,))
    _, sp, base, _, truth, _ = cc.simulated_base(sn637, eff, rate, proto, size, s)
    res = trace_effect(base, split=sp)
    un = unplaced_modes(res["stages"])
    f, z = truth["freq_hz"], truth["damping_ratio"]
    for st in res["stages"]:
        if st["effect"] == "resonance" and (st["effect"], st["channel"]) not in un:
            assert abs(st["parameters"]["f_n_hz"] - f) < 0.5 * z * f, (st["parameters"], f)


@pytest.mark.slow
@FULL_ONLY
def test_a_family_the_record_cannot_resolve_is_said_and_not_written(sn637, tmp_path):
    """A record whose mode the held path does not describe: seed 94 #104 of the benchmark (a 200.4 Hz mode on
    the calibration protocol at 100 Hz) simulated on the 4 sub-steps a sample the benchmark used before session 32
    (2.5 ms: each 0.48 ms settle ramped over a sub-step). The search names the 100.4 Hz member (the review of
    s31_alias, B1); the folds do not resolve it beyond 200.4 and 300.4 Hz: the stage says so (the drawn 200.4 Hz
    among the members it names) and the plant file does not carry the mode (``carried_stages``: omitted, with
    the family as its reason)."""
    from workbench.calibrate.base_fit import fit_base
    from workbench.calibrate.plant_update import carried_stages
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
    from workbench.calibrate.tracing import trace_effect
    cc = load_benchmark("calibrate_confusion")
    eff, rate, proto, size, s = cc.cases(1, 94, ends=True)[103]
    assert (eff, rate, proto) == ("resonance", 100.0, "calibration")
    t, v = benchmark_protocol(proto, rate, cc.ROWS[rate])
    plant, truth = plant_with_effect(sn637, eff, s, duration_s=float(t[-1]), size=size)
    r = simulate_record(plant, t, v, seed=s, n_sub=4)
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(cc._record(r, 1.0 / rate), sn637.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    res = trace_effect(base, split=sp)
    st = res["stages"][0]
    assert st["effect"] == "resonance" and st["parameters"].get("held")
    fam = st["alias_family"]
    assert not fam["resolved"], fam
    if fam["gain"]["consistent"]:
        said = [float(x) for x in fam["note"].split("one of ")[1].split(" Hz")[0].split(" / ")]
        assert min(abs(m - truth["freq_hz"]) for m in said) < 2 * truth["damping_ratio"] * truth["freq_hz"], (said, truth)
    else:
        # the column is no stack mode's (session 33): no candidate frequency is said
        assert "one of " not in fam["note"] and "does not tell the mode's frequency" in fam["note"], fam
    assert fam["note"] in res["reason"]
    omit, carried = carried_stages(sn637.source, sn637, base, res, tmp_path / "r.csv", {"hysteresis": None},
                                   sp.train)
    assert ("resonance", st["channel"]) in omit
    assert [c["written"] for c in carried if c["effect"] == "resonance"] == [False]


# a latency of a small part of a sample (the benchmark's 0.3-2 ms times its smallest sizes) at 100 Hz: the held
# search's most damped trial reads its phase at the drive's harmonics (107 #127: a 0.28 ms latency named a 301.9 Hz,
# zeta 0.159 mode); default_rng(3203), drawn before the damping-cap rule was run on any
_RNG5 = np.random.default_rng(3203)
SUBSAMPLE_LAGS = reduced_draws([(p, float(np.exp(_RNG5.uniform(np.log(5e-5), np.log(1e-3)))), int(_RNG5.integers(1 << 30)))
                                for p in ("steps", "calibration")], keep=())


@pytest.mark.slow
@pytest.mark.parametrize("protocol, delay_s, seed", SUBSAMPLE_LAGS)
def test_a_sub_sample_latency_at_100_hz_names_no_mode(sn637, protocol, delay_s, seed):
    """A displacement latency of 0.005-0.1 samples: no mode named (the held fit at its damping cap is no mode's).
    These two draws name none with or without the damping-cap rule (measured): nulls over the range; the record
    that needs the rule is the next test's."""
    res = _traced(sn637, "delay", protocol, delay_s, seed=seed)
    assert "resonance" not in [s["effect"] for s in res["stages"]], (res["effect"], res.get("fold_winners"))


@pytest.mark.slow
@FULL_ONLY
def test_the_benchmark_s_sub_sample_latency_107_127_names_no_mode(sn637):
    """Seed 107 #127 of the benchmark at 100 Hz (steps, a 0.28 ms displacement latency, 2.99x): named a 301.9 Hz,
    zeta 0.159 (the held search's damping cap) mode on 2 of 5 folds before the rule, a wrong answer; no mode now."""
    from workbench.calibrate.tracing import trace_effect
    cc = load_benchmark("calibrate_confusion")
    eff, rate, proto, size, s = cc.cases(1, 107, ends=True)[126]
    assert (eff, rate, proto) == ("delay", 100.0, "steps")
    _, sp, base, _, _, _ = cc.simulated_base(sn637, eff, rate, proto, size, s)
    res = trace_effect(base, split=sp)
    assert "resonance" not in [st["effect"] for st in res["stages"]], (res["effect"], res.get("fold_winners"))
