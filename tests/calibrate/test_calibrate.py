"""Acceptance of issue 6: synthetic records with one effect each, the command, the real record.

Each synthetic record is the 35.5 s calibration protocol (decaying 0.5 Hz sines over 0-100 V,
3 s holds, a chirp to 2 kHz) simulated by the project's own PZT with one effect drawn at
random (``plant_with_effect``). The calibration must name that effect, halve the held-out
error on its channel, and answer ``none`` for the clean record. One draw per effect runs in
``make test``; WORKBENCH_FULL=1 runs three.
"""

import dataclasses
import hashlib
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import FULL, PLANTS
from workbench.calibrate.base_fit import fit_base
from workbench.calibrate.protocol import calibration_protocol
from workbench.calibrate.record import Record
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import EFFECTS, plant_with_effect, simulate_record, write_record
from workbench.calibrate.tracing import trace_effect
from workbench.cli import main
from workbench.plant import load_plant

from .test_pi_fit import REAL_CSV, REAL_HEADER

SEEDS = (11, 12, 13) if FULL else (11,)
CHANNEL = {"creep": "displacement", "dielectric_absorption": "charge", "leakage": "charge",
           "resonance": "displacement", "delay": "displacement", "drift": "displacement",
           "gauge_nonlinearity": "gauge"}


@pytest.fixture(scope="module")
def protocol():
    return calibration_protocol()


def _record(plant, protocol, seed):
    t, v = protocol
    r = simulate_record(plant, t, v, seed=seed)
    return Record(Path("synthetic.csv"), {}, r["time_s"],
                  {k: r[k] for k in ("voltage_v", "current_a", "displacement_m", "gauge_v")}, 1e-4)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("effect", ("none",) + EFFECTS)
def test_synthetic_effect_is_named_and_halved(sn637, protocol, effect, seed, request):
    """The 35.5 s protocol with one effect at its nominal size (EFFECT_RANGES): never a wrong
    effect; when the effect is named, its channel's test error is at least halved and its
    parameters match the drawn ones. (~2 min per record on a loaded 2-core machine: slow; the
    fast slice of the confusion benchmark runs in make test.)"""
    if not FULL:
        pytest.skip("~2 min per 355,000-row record: WORKBENCH_FULL=1 (make test runs the confusion benchmark's "
                    "fast slice, tests/calibrate/test_confusion.py)")
    if (effect, seed) == ("delay", 11):
        # measured 2026-11-23: the 0.519 ms delay is found (0.52 ms, 5 of 5) and removed down to
        # the floor -- test RMS 4.527 -> 2.814 nm, and the effect-free seed-11 record's base fit
        # leaves 2.814 nm itself -- but this draw stands only 1.26x above that floor
        # (sqrt(4.527^2 - 2.814^2) = 3.55 nm), so the best reachable ratio is 0.62: halving
        # is asked by the issue of effects >= 3x the floor, and this one cannot reach it
        request.applymarker(pytest.mark.xfail(strict=True, reason="delay seed 11: 4.527 -> 2.814 nm = the "
                                              "effect-free floor (2.814 nm); the effect is 1.26x the floor, "
                                              "halving unreachable"))
    plant, truth = plant_with_effect(sn637, effect, seed)
    rec = _record(plant, protocol, seed)
    split = make_split(rec.t_s, rec.channels["voltage_v"], "blocks")
    base = fit_base(rec, sn637.pzt.series_resistance_ohm, train=split.train, test=split.test, pzt=plant.pzt,
                    dac_range_v=plant.gauge.dac_range_v)
    res = trace_effect(base, split=split)
    named = [st["effect"] for st in res["stages"]]
    print(f"\n{effect} {truth}: -> {res['effect']} on {res['channel']} ({res['agreement']}), stages {named}, test RMS "
          f"{res['error_before']['rms']:.4g} -> {res['error_after']['rms']:.4g} {res['error_before']['units']}")
    assert all(n == effect for n in named), named
    if effect == "none" or not named:
        return
    assert res["channel"] == CHANNEL[effect]
    assert res["error_after"]["rms"] <= 0.5 * res["error_before"]["rms"]
    p = res["parameters"]
    if effect == "leakage":
        assert 1.0 / p["gain_per_s"] == pytest.approx(truth["resistance_ohm"], rel=0.3)
    if effect == "dielectric_absorption":
        assert p["tau_s"] == pytest.approx(truth["time_constant_s"], rel=0.3)
    if effect == "delay":
        assert p["delay_s"] == pytest.approx(truth["delay_s"], rel=0.2)   # the PI absorbs a little lag
    if effect == "gauge_nonlinearity":
        assert p["coefficient_per_m"] == pytest.approx(truth["coefficient_per_m"], rel=0.3)


def test_calibrate_command_writes_report_json_and_a_loadable_plant(sn637, tmp_path, monkeypatch):
    # an in-process main([...]) leaves the process's allocator alone (_malloc's settings are process-wide
    # and permanent: only the console command's own process takes them)
    import workbench._malloc
    called = []
    monkeypatch.setattr(workbench._malloc, "keep_freed_memory", lambda: called.append(1) or True)
    monkeypatch.setattr(workbench._malloc, "small_pages", lambda: called.append(2) or True)
    advised = workbench._malloc.huge_pages_advised()
    import gc
    frozen = gc.get_freeze_count()          # nor its garbage collector (cli.cmd_calibrate's freeze: the command's own)
    t, v = calibration_protocol(sine_cycles=3, stairs_v=(50.0, 20.0), chirp_s=1.0)
    plant, truth = plant_with_effect(sn637, "leakage", 3)
    data = write_record(tmp_path / "rec.csv", simulate_record(plant, t, v, seed=3), {"serial": "SN637"})
    plant_file = PLANTS / "p888_51_sn637.toml"
    before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (data, plant_file)}
    out = tmp_path / "out"
    assert main(["calibrate", str(data), "--plant", str(plant_file), "--out", str(out),
                 "--json", str(tmp_path / "r.json")]) == 0
    res = json.loads((tmp_path / "r.json").read_text())
    assert not called and workbench._malloc.huge_pages_advised() == advised and gc.get_freeze_count() == frozen
    assert res["effect"] == "leakage" and res["channel"] == "charge"
    # the simulated record declares its current convention and the run says which it used (issue 13)
    assert data.read_text().startswith("# serial: SN637\n# current: averaged\n")
    assert res["base_fit"]["current"] == "averaged"
    # and its gauge's: each row the chain's mean over its interval (session 14)
    assert "\n# gauge: averaged\n" in data.read_text()[:200] and res["base_fit"]["gauge"] == "averaged"
    for key in ("error_before", "error_after"):
        assert set(res[key]) == {"rms", "max", "units"} and res[key]["units"] == "C"
    assert res["error_after"]["rms"] <= 0.5 * res["error_before"]["rms"]
    assert {"name", "score", "error_after"} <= set(res["candidates"][0])
    updated = Path(res["updated_plant"])
    assert updated.parent == out
    doc = tomllib.loads(updated.read_text())
    assert doc["leakage"]["resistance_ohm"] == pytest.approx(truth["resistance_ohm"], rel=0.3)
    reloaded = load_plant(updated)
    assert reloaded.additions.leakage_resistance_ohm == doc["leakage"]["resistance_ohm"]
    # C_p stays declared; the core is the refitted or the declared one, as the JSON and the gaps say (choose_core)
    assert reloaded.pzt.working_capacitance_f == sn637.pzt.working_capacitance_f
    core = res["updated_plant_core"]
    declared = np.array_equal(reloaded.pzt.hysteresis.weights, sn637.pzt.hysteresis.weights)
    assert core["core"] == ("declared" if declared else "refitted")
    assert declared == any("declared core is kept" in g for g in res["updated_plant_gaps"])
    assert (out / "report.md").read_text().count("leakage") >= 2
    assert "integrated as **averaged** samples" in (out / "report.md").read_text()
    # which split and why (issue 13 item 3): blocks, though slow candidates are present
    assert res["split"] == "blocks" and "slow candidates" in res["split_reason"]
    assert f"blocks split: {res['split_reason']}" in (out / "report.md").read_text()
    assert all(Path(f).stat().st_size > 10_000 for f in res["figures"])
    assert before == {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (data, plant_file)}


def test_updated_plant_simulates_the_found_effect(sn637, tmp_path):
    """Round trip: the plant file calibration writes, simulated again, carries the effect."""
    from workbench.calibrate.plant_update import updated_plant_text
    plant, truth = plant_with_effect(sn637, "dielectric_absorption", 5)
    short = calibration_protocol(sine_cycles=3, stairs_v=(50.0, 20.0, 80.0, 40.0), chirp_s=1.0)
    base = fit_base(_record(plant, short, 5), 80.0, pzt=plant.pzt, dac_range_v=2.6)
    res = trace_effect(base)
    assert res["effect"] == "dielectric_absorption", (res["effect"], res["fold_winners"])
    text = updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, base, res, Path("rec.csv"))
    (tmp_path / "p.toml").write_text(text)
    again = load_plant(tmp_path / "p.toml")
    assert again.additions.absorption_gain_f == pytest.approx(truth["gain_f"], rel=0.3)
    assert again.additions.absorption_time_constant_s == pytest.approx(truth["time_constant_s"], rel=0.3)


@pytest.mark.parametrize("section, key, value", [
    ("leakage", "resistance_ohm", -1.0), ("dielectric_absorption", "time_constant_s", "nan"),
    ("displacement_sensor", "delay_s", 20.0), ("displacement_sensor", "delay_s", -20.0), ("gauge_nonlinearity", "coefficient_per_m", "'big'")])
def test_plant_additions_are_validated(tmp_path, section, key, value):
    from workbench.errors import PlantDefinitionError
    base = (PLANTS / "p888_51_sn637.toml").read_text()
    rows = {"leakage": ["resistance_ohm = 1e9"], "dielectric_absorption": ["gain_f = 1e-7", "time_constant_s = 2.0"],
            "displacement_sensor": ["delay_s = 0.0", "drift_rate_m_per_s = 0.0", "drift_curvature_m_per_s2 = 0.0"],
            "gauge_nonlinearity": ["coefficient_per_m = 100.0"]}[section]
    rows = [f"{key} = {value}" if r.startswith(key + " ") else r for r in rows]
    p = tmp_path / "p.toml"
    p.write_text(base + f"\n[{section}]\n" + "\n".join(rows) + "\n")
    with pytest.raises(PlantDefinitionError, match=rf"{section}\.{key}"):
        load_plant(p)


def test_calibrate_bad_input_exits_2(tmp_path, capsys):
    rec = tmp_path / "r.csv"
    rec.write_text("time[s],voltage[V]\n" + "\n".join(f"{i * 1e-3},{i % 7}" for i in range(200)) + "\n")
    assert main(["calibrate", str(rec), "--plant", str(PLANTS / "p888_51_sn637.toml")]) == 2
    assert "output" in capsys.readouterr().err
    assert main(["calibrate", str(rec), "--plant", str(tmp_path / "missing.toml")]) == 2
    assert "missing.toml" in capsys.readouterr().err


@pytest.mark.skipif(not REAL_CSV.is_file(), reason="the shared real record is not on this machine")
def test_real_record_same_answer_for_every_training_length(tmp_path):
    """The measured record against plants/generic_stack.toml: the answer (effect, or none, or
    inconclusive) must not depend on how many cycles train, 2 to 5 (issue 13; before it the
    answer was creep at 2, 3, 5 and resonance at 4), and the held-out error is at most the
    issue's 0.07 um. The record's voltage column is the commanded sine, not a measured voltage
    (its README), so it is declared ``# input: command``: the amplifier's lag is fitted by the
    base. Published in-sample 0.0915 um; a straight line leaves ~1.9 um."""
    data = tmp_path / "real.csv"
    data.write_text("# input: command\n" + REAL_HEADER + "\n" + REAL_CSV.read_text())
    answers = {}
    for cycles in (2, 3, 4, 5):
        js = tmp_path / f"r{cycles}.json"
        out = tmp_path / f"out{cycles}" if cycles == 3 else None
        argv = ["calibrate", str(data), "--plant", str(PLANTS / "generic_stack.toml"), "--train-cycles", str(cycles),
                "--json", str(js)] + (["--out", str(out)] if out else [])
        assert main(argv) == 0
        res = json.loads(js.read_text())
        ch = res["base_fit"]["channels"]["displacement"]
        print(f"\nreal record, {cycles} training cycles: test RMS {ch['rms'] * 1e6:.4f} um, answer {res['effect']} "
              f"({res['agreement']}; folds {res['fold_winners']})")
        assert res["split"] == "cycles" and ch["units"] == "m"
        assert ch["rms"] < 0.15e-6
        assert res["error_after"]["rms"] <= res["error_before"]["rms"]
        assert res["error_after"]["rms"] <= 0.07e-6           # the target
        assert res["agreement"].endswith("of 5")
        answers[cycles] = (res["effect"], res["channel"]) if res["effect"] not in ("none", "inconclusive") \
            else res["effect"]
        if out:
            stack = tomllib.loads(Path(res["updated_plant"]).read_text())
            assert len(stack["hysteresis"]["weights_m_per_v"]) == 20
            # item 6: the updated plant, loaded back and run on the record's voltage, reproduces
            # the reported test error within 10 %
            from workbench.calibrate.record import read_record
            from workbench.calibrate.splits import make_split
            from workbench.plant.generic import load_generic_stack
            rec = read_record(data)
            v, x = rec.channels["voltage_v"], rec.channels["displacement_m"]
            test = make_split(rec.t_s, v, "cycles", train_cycles=cycles).test
            # the command's lag is in the JSON (``base_fit.command_map``), not in a generic file
            from workbench.calibrate.base_fit import _lagged
            cmd = res["base_fit"]["command_map"]
            vd = _lagged(rec.t_s, v, lag_s=cmd["lag_s"], delay_s=cmd["delay_s"])
            e = load_generic_stack(Path(res["updated_plant"])).predict(vd) - x
            assert np.sqrt(np.mean(e[test] ** 2)) == pytest.approx(res["error_after"]["rms"], rel=0.1)
    assert len(set(answers.values())) == 1, answers


def test_default_split_names_the_split_and_why():
    """Issue 13 item 3: forward is taken only when asked to and slow candidates are present."""
    from workbench.calibrate.splits import SLOW_EFFECTS, default_split
    from workbench.calibrate.tracing import candidate_plan
    all_names = [e.name for _, e, _ in candidate_plan({"displacement", "charge", "gauge"})]
    fast = [n for n in all_names if n not in SLOW_EFFECTS]
    assert set(SLOW_EFFECTS) <= set(all_names) and fast
    assert default_split("generic_stack", all_names)[0] == "cycles"
    kind, why = default_split("pzt", all_names)
    assert kind == "blocks" and all(n in why for n in SLOW_EFFECTS)
    kind, why = default_split("pzt", all_names, forward_when_slow=True)
    assert kind == "forward" and "drift" in why
    assert default_split("pzt", fast, forward_when_slow=True) == ("blocks", "interleaved blocks: no slow, "
                                                                  "time-driven candidate")


def test_base_fit_recovers_cp_gauge_gain_and_rest(sn637):
    """Eqs. 10-12 on a clean record give the plant's C_p; the gauge line is the serial's calibration."""
    t, v = calibration_protocol(sine_cycles=2, stairs_v=(50.0, 20.0), chirp_s=0.5)
    plant, _ = plant_with_effect(sn637, "none", 2)
    r = simulate_record(plant, t, v, seed=2)
    rec = Record(Path("r.csv"), {}, r["time_s"], {k: r[k] for k in ("voltage_v", "current_a", "displacement_m",
                                                                   "gauge_v")}, 1e-4)
    base = fit_base(rec, 80.0, pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    assert base.starts_from_rest and base.voltage_source.startswith("terminal")
    assert base.k_q2x_m_per_c == pytest.approx(plant.pzt.k_q2x_m_per_c, rel=2e-3)
    assert base.working_capacitance_f == pytest.approx(plant.pzt.working_capacitance_f, rel=0.02)
    assert base.gauge_gain_v_per_m == pytest.approx(1.0 / plant.gauge.calibration_m_per_v, rel=0.02)
    # the noise floor: the displacement model leaves little more than the sensor's 1 nm
    x = base.channels["displacement"]
    assert np.sqrt(np.mean(x.residual[base.test] ** 2)) < 3e-9


def test_updated_plant_carries_every_stage(sn637, tmp_path):
    """A two-stage answer (delay and drift of the displacement sensor, then a mode) is written
    whole: one [displacement_sensor] with both, the mode, and the file loads back with them."""
    from types import SimpleNamespace

    from workbench.calibrate.plant_update import updated_plant_text
    rng = np.random.default_rng(4)
    delay_s, rate, f_n = rng.uniform(1e-4, 3e-3), rng.uniform(1e-9, 1e-8), rng.uniform(100.0, 900.0)
    err = {"rms": 1e-8, "max": 3e-8, "units": "m"}
    stages = [{"effect": "delay", "channel": "displacement", "parameters": {"delay_s": delay_s},
               "error_before": err, "error_after": err},
              {"effect": "drift", "channel": "displacement",
               "parameters": {"coefficients": [0.0, rate * 20.0, 0.0], "t0_s": 0.0, "t_end_s": 20.0},
               "error_before": err, "error_after": err},
              {"effect": "resonance", "channel": "displacement", "parameters": {"f_n_hz": f_n, "zeta": 0.01},
               "error_before": err, "error_after": err}]
    result = {"effect": "delay", "channel": "displacement", "parameters": stages[0]["parameters"],
              "error_before": err, "error_after": err, "stages": stages}
    base = SimpleNamespace(channels={}, v_drive=np.zeros(3))
    text = updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, base, result, Path("rec.csv"))
    (tmp_path / "p.toml").write_text(text)
    again = load_plant(tmp_path / "p.toml")
    assert again.additions.sensor_delay_s == pytest.approx(delay_s)
    assert again.additions.sensor_drift_rate_m_per_s == pytest.approx(rate)
    assert any(m.freq_hz == pytest.approx(f_n) for m in again.pzt.modes)
    assert text.count("[displacement_sensor]") == 1


def test_temperature_cycle_drift_is_drift_not_creep(sn637):
    """Issue 13: a sensor zero that drifts linearly and swings slowly (a temperature cycle), with
    no creep, was named creep. Rate (1-100 kHz), period (a quarter to 0.6 of the record),
    amplitude and slope drawn; 20,000 rows of the scaled protocol."""
    from workbench.calibrate.synthetic import benchmark_protocol
    rng = np.random.default_rng(2026)
    rate = float(np.exp(rng.uniform(np.log(1e3), np.log(1e5))))
    t, v = benchmark_protocol("calibration", rate, 20_000)
    plant, _ = plant_with_effect(sn637, "none", 1)
    r = simulate_record(plant, t, v, seed=1)
    span = t[-1] - t[0]
    period = rng.uniform(0.25, 0.6) * span
    amp, slope = rng.uniform(20e-9, 100e-9), rng.uniform(-50e-9, 50e-9)
    r["displacement_m"] = r["displacement_m"] + slope * (t - t[0]) / span \
        + amp * np.sin(2 * np.pi * (t - t[0]) / period + rng.uniform(0, 2 * np.pi))
    rec = Record(Path("drift.csv"), {}, r["time_s"], {k: r[k] for k in ("voltage_v", "current_a", "displacement_m",
                                                                       "gauge_v")}, 1.0 / rate)
    split = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(rec, 80.0, train=split.train, test=split.test, pzt=plant.pzt, dac_range_v=2.6)
    res = trace_effect(base, split=split)
    print(f"\n{rate:.0f} Hz, period {period:.3g} s, {amp * 1e9:.0f} nm: {res['effect']} ({res['agreement']}), "
          f"stages {[(st['effect'], st['variant']) for st in res['stages']]}")
    assert res["effect"] == "drift" and res["channel"] == "displacement"
    assert res["stages"][0]["variant"] == "periodic"
    assert res["parameters"]["period_s"] == pytest.approx(period, rel=0.05)
    assert res["error_after"]["rms"] <= 0.5 * res["error_before"]["rms"]
    assert all(st["effect"] != "creep" for st in res["stages"])


# (lead s, sample rate Hz): the brief's -0.3 ms at 10 kHz (3 samples) and at a drawn rate
# (a fractional number of samples); WORKBENCH_FULL=1 adds leads drawn over 0.2-2 ms at rates
# drawn over 4-20 kHz
_LEAD_RNG = np.random.default_rng(2613)
_LEADS = [(-0.3e-3, 1e4), (-0.3e-3, float(np.exp(_LEAD_RNG.uniform(np.log(4e3), np.log(2e4)))))] + [
    (-float(_LEAD_RNG.uniform(0.2e-3, 2e-3)), float(np.exp(_LEAD_RNG.uniform(np.log(4e3), np.log(2e4)))))
    for _ in range(5)]


@pytest.mark.parametrize("lead_s, rate_hz", _LEADS if FULL else _LEADS[1:2])     # make test: the drawn rate
def test_sensor_lead_is_found_signed_and_carried_by_the_plant(sn637, tmp_path, lead_s, rate_hz):
    """Issue 13 item 6: a displacement sensor that LEADS the drive (an acquisition timing offset,
    a fractional number of samples) is named ``delay`` with its sign within 20 %, the updated
    plant file carries the signed delay and loads, and simulating the record through it leaves
    ``error_after`` within 10 % (the file carries the refitted core since session 13: it is the fitted
    model, whose PI leaves ~2.2 nm on these records; measured 2.37 / 2.38 nm against 2.25 / 2.22 nm), while
    the same file with its delay set to 0 leaves over 1.5x that: the lead moves the 0.3 ms-early sensor by
    ~3.6 nm RMS on this protocol (the declared plant leaves 3.7 nm where the true one leaves 1.0 nm),
    against the file's ~2.4 nm, so sqrt(1 + (3.6 / 2.4)^2) = 1.8x (measured 4.07 nm, 1.7x; a lead clipped to 0, as
    before, fails here)."""
    from workbench.calibrate.plant_update import updated_plant_text
    from workbench.calibrate.synthetic import SensorNoise
    t, v = calibration_protocol(dt_s=1.0 / rate_hz, sine_cycles=3, stairs_v=(50.0, 20.0, 80.0, 40.0), chirp_s=1.0,
                                chirp_f1_hz=min(2000.0, 0.3 * rate_hz))
    clean, _ = plant_with_effect(sn637, "none", 7)
    plant = dataclasses.replace(clean, additions=dataclasses.replace(clean.additions, sensor_delay_s=lead_s))
    r = simulate_record(plant, t, v, seed=7)
    rec = Record(Path("lead.csv"), {}, r["time_s"], {k: r[k] for k in ("voltage_v", "current_a", "displacement_m",
                                                                       "gauge_v")}, 1.0 / rate_hz)
    split = make_split(rec.t_s, rec.channels["voltage_v"], "blocks")
    base = fit_base(rec, sn637.pzt.series_resistance_ohm, train=split.train, test=split.test, pzt=plant.pzt,
                    dac_range_v=plant.gauge.dac_range_v)
    res = trace_effect(base, split=split)
    print(f"\nlead {lead_s * 1e3:.3f} ms ({-lead_s * rate_hz:.2f} samples at {rate_hz:.0f} Hz) -> {res['effect']} "
          f"{res['parameters']} ({res['agreement']}); test RMS {res['error_before']['rms']:.3g} -> "
          f"{res['error_after']['rms']:.3g} m")
    assert (res["effect"], res["channel"]) == ("delay", "displacement"), res["fold_winners"]
    assert res["parameters"]["delay_s"] == pytest.approx(lead_s, rel=0.2)
    text = updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, base, res, Path("lead.csv"))
    (tmp_path / "p.toml").write_text(text)
    again = load_plant(tmp_path / "p.toml")
    assert again.additions.sensor_delay_s < 0
    assert again.additions.sensor_delay_s == pytest.approx(res["parameters"]["delay_s"])
    quiet = SensorNoise(0.0, 0.0, 0.0)
    x = rec.channels["displacement_m"]
    rms = {name: float(np.sqrt(np.mean((simulate_record(p, t, v, noise=quiet)["displacement_m"] - x)[split.test]
                                       ** 2))) for name, p in (("updated", again), ("true", plant), ("declared", sn637))}
    no_lead = dataclasses.replace(again, additions=dataclasses.replace(again.additions, sensor_delay_s=0.0))
    rms["updated, delay 0"] = float(np.sqrt(np.mean((simulate_record(no_lead, t, v, noise=quiet)["displacement_m"]
                                                     - x)[split.test] ** 2)))
    print(f"simulated through the plant, test RMS: {rms} m")
    assert abs(rms["updated"] - res["error_after"]["rms"]) <= 0.1 * res["error_after"]["rms"]
    assert rms["updated, delay 0"] > 1.5 * rms["updated"]        # the lead is what the file adds


@pytest.mark.parametrize("seed", range(4))
def test_drift_plant_file_form_is_the_fitted_term(sn637, tmp_path, seed):
    """The drift's plant-file form (rate and curvature from the record's start) is the fitted
    polynomial in normalized time less its constant, to rounding: drawn coefficients, start time
    and record length from 0.1 s to 1000 s."""
    from types import SimpleNamespace

    from workbench.calibrate.effects import Drift
    from workbench.calibrate.plant_update import updated_plant_text
    from workbench.plant.additions import drift
    rng = np.random.default_rng(seed)
    t0, span = rng.uniform(-5.0, 5.0), float(np.exp(rng.uniform(np.log(0.1), np.log(1000.0))))
    c = rng.uniform(-400e-9, 400e-9, 3)
    p = {"coefficients": list(c), "t0_s": t0, "t_end_s": t0 + span}
    err = {"rms": 1e-8, "max": 3e-8, "units": "m"}
    st = {"effect": "drift", "channel": "displacement", "parameters": p, "error_before": err, "error_after": err}
    result = {**st, "stages": [st]}
    text = updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, SimpleNamespace(channels={}, v_drive=np.zeros(3)),
                              result, Path("rec.csv"))
    (tmp_path / "p.toml").write_text(text)
    add = load_plant(tmp_path / "p.toml").additions
    t = np.linspace(t0, t0 + span, 1001)
    fitted = Drift().term(t, None, p) - c[0]
    np.testing.assert_allclose(drift(t, add.sensor_drift_rate_m_per_s, add.sensor_drift_curvature_m_per_s2), fitted,
                               rtol=0, atol=1e-12 * np.max(np.abs(c)))


def test_drift_round_trip_through_the_updated_plant(sn637, tmp_path):
    """Issue 13 item 6 for a drift: simulating the record through the updated plant (the refitted
    core plus the fitted drift) reproduces ``error_after`` within 10 % (noise-free simulation,
    the record's test rows). The base's plays absorb part of a linear drift (the record drives them
    up and down, but not symmetrically in time), so the file's rate is off by ~2 % (2.036e-8 m/s against
    the drawn 2.078e-8); with the declared core that left 5.09 nm against error_after 1.88 nm (a strict
    xfail until session 13); the refitted core carries the plays' share: measured 1.876 nm."""
    from workbench.calibrate.plant_update import updated_plant_text
    from workbench.calibrate.synthetic import SensorNoise
    t, v = calibration_protocol(sine_cycles=3, stairs_v=(50.0, 20.0, 80.0, 40.0), chirp_s=1.0)
    plant, truth = plant_with_effect(sn637, "drift", 6, duration_s=float(t[-1]))
    r = simulate_record(plant, t, v, seed=6)
    rec = Record(Path("drift.csv"), {}, r["time_s"], {k: r[k] for k in ("voltage_v", "current_a", "displacement_m",
                                                                       "gauge_v")}, 1e-4)
    split = make_split(rec.t_s, rec.channels["voltage_v"], "blocks")
    base = fit_base(rec, sn637.pzt.series_resistance_ohm, train=split.train, test=split.test, pzt=plant.pzt,
                    dac_range_v=plant.gauge.dac_range_v)
    res = trace_effect(base, split=split)
    assert (res["effect"], res["channel"]) == ("drift", "displacement"), res["fold_winners"]
    text = updated_plant_text(PLANTS / "p888_51_sn637.toml", sn637, base, res, Path("drift.csv"))
    (tmp_path / "p.toml").write_text(text)
    again = load_plant(tmp_path / "p.toml")
    quiet = SensorNoise(0.0, 0.0, 0.0)
    x = rec.channels["displacement_m"]
    rms = {name: float(np.sqrt(np.mean((simulate_record(p, t, v, noise=quiet)["displacement_m"] - x)[split.test] ** 2)))
           for name, p in (("updated", again), ("true", plant), ("declared", sn637))}
    rate = again.additions.sensor_drift_rate_m_per_s
    print(f"\ndrift {truth} -> rate {rate:.4g} m/s, curvature {again.additions.sensor_drift_curvature_m_per_s2:.4g} "
          f"m/s^2; error_after {res['error_after']['rms']:.4g} m; simulated through the plant, test RMS: {rms} m")
    assert rms["declared"] > 2.0 * rms["updated"]        # the drift is what the file adds
    assert abs(rms["updated"] - res["error_after"]["rms"]) <= 0.1 * res["error_after"]["rms"]


@pytest.mark.parametrize("scale, refused", [(1.0, False), (0.5, False), (2.0, False),     # a stack off its model
                                            (1e-3, True), (1e3, True), (1e-6, True)])   # an SI-prefix slip
def test_displacement_unit_slip_is_refused_and_a_stack_off_its_model_is_not(sn637, scale, refused):
    """The recorded stroke against the plant's quasi-static stroke over the recorded voltage: a factor of
    1000 (one SI prefix) is refused naming the column's unit, a factor of 2 is a stack and is calibrated."""
    from workbench.calibrate.run import _check_displacement_scale
    from workbench.errors import DataFileError
    for name in ("p888_51_sn637", "p888_51_sn629", "p888_51_sn618"):
        pzt = load_plant(PLANTS / f"{name}.toml").pzt
        t = np.arange(4000) * 1e-3
        v = pzt.voltage_max_v / 2 * (1.0 - np.cos(2 * np.pi * 1.0 * t))      # rest to the amplifier's top
        rec = Record(Path("r.csv"), {}, t, {"voltage_v": v, "displacement_m": scale * pzt.quasi_static_x_m(v)},
                     1e-3, ())
        if refused:
            with pytest.raises(DataFileError, match="unit slip"):
                _check_displacement_scale("r.csv", rec, pzt, name)
        else:
            _check_displacement_scale("r.csv", rec, pzt, name)
