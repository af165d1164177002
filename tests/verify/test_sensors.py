"""verify --sensor: the controller's fixed-point sensor step in the compiled loop with the charge channel."""

from pathlib import Path

import numpy as np
import pytest

from workbench.cli import main
from workbench.controller import Controller
from workbench.errors import StudyDefinitionError
from workbench.export.sensor import run_sensor
from workbench.plant import load_plant
from workbench.verify.run import load_verify_sensor, load_verify_targets
from workbench.verify.sensors import charge_channel_missing, run_sensor_loop, sensor_setup

from ..conftest import PLANTS, ROOT

GAUGE = ROOT / "controllers" / "sn637_loopshape.json"
FUSED = ROOT / "controllers" / "sn637_fused_loopshape.json"
CREEP = PLANTS / "p888_51_sn637_creep.toml"
SHORT = dict(triangle_hz=0.5, triangle_periods=2, hold_s=3.0)


@pytest.fixture(scope="module")
def setup():
    plant = load_plant(CREEP)
    # a shorter identification record than selfsense's 700 s: the estimator is still the staged one
    return sensor_setup(plant, Controller.load(FUSED), ident_hold_s=150.0)


@pytest.mark.parametrize("kind, seed", [("fused", 5), ("charge", 6)])
def test_the_loop_runs_the_controllers_sensor_step_bit_for_bit(setup, kind, seed):
    """Every output the compiled loop applied is what the controller's sensor step (NAME_sensor_step's twin)
    computes from the counts the loop fed it: the loop runs the exported firmware step, blend included."""
    c = Controller.load(FUSED)
    r = run_sensor_loop(setup, c, kind, seed=seed, decimate=1, **SHORT)
    sb = c.sensor if kind == "fused" else c.with_sensor(kind).sensor
    y0 = r["_blend_state_at_closing"] if kind == "fused" else None
    u, fused, _ = run_sensor(sb, c.fixed, r["_reference_counts"], r["_gauge_counts"], r["_charge_counts"],
                             u0_v=r["_u0_v"], y0=y0)
    np.testing.assert_array_equal(u, r["_u_v"])
    np.testing.assert_array_equal(fused * sb.lsb_m, r["_reading_m"])
    # the loop moved: the triangle spans 10-90 % of the stroke and the command follows it
    assert np.ptp(r["_x_m"]) > 0.7 * r["stroke_m"] and np.ptp(u) > 50.0


def test_fused_loop_holds_quieter_than_the_gauge_loop_without_its_drift(setup):
    """The committed designs on the nonlinear plant with every drift and the 22 nm gauge noise: the fused
    loop's hold noise is far below the gauge loop's (the charge estimate is ~80x quieter per sample), the
    charge loop's drift does not pass the blend (the gauge owns DC), and the fused design's measured
    bandwidth exceeds the gauge design's."""
    gauge = run_sensor_loop(setup, Controller.load(GAUGE), "gauge", seed=7, **SHORT)
    fused = run_sensor_loop(setup, Controller.load(FUSED), "fused", seed=7, **SHORT)
    assert fused["hold_noise_rms_m"] < gauge["hold_noise_rms_m"] / 5
    assert abs(fused["hold_drift_m"]) < 3e-9
    # the charge estimate's own drift (bias current, leakage, the absorption the estimator misses: ~1 nm per
    # 100 s here) needs a hold longer than the startup the loop now waits out (startup_settle_s) to show
    long = dict(hold_s=300.0, triangle_hz=0.5, triangle_periods=2, seed=7, sweep=False)
    fused_l = run_sensor_loop(setup, Controller.load(FUSED), "fused", **long)
    charge_l = run_sensor_loop(setup, Controller.load(FUSED), "charge", **long)
    assert abs(fused_l["hold_drift_m"]) < abs(charge_l["hold_drift_m"]) / 2
    assert fused["triangle_rms_m"] < gauge["triangle_rms_m"]
    # the quiet reading buys bandwidth: measured on x with 10 nm tones after the hold
    assert fused["bandwidth_hz"] > 1.2 * gauge["bandwidth_hz"]


def test_a_stack_in_a_structure_has_no_charge_channel(tmp_path, capsys):
    flex = PLANTS / "p888_51_sn637_on_flexure.toml"
    assert charge_channel_missing(load_plant(flex)) and charge_channel_missing(load_plant(CREEP)) is None
    out = tmp_path / "out"
    assert main(["verify", str(flex), "--controller", str(FUSED), "--sensor", "fused", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "charge channel" in err and str(flex) in err and "--sensor gauge" in err and "Traceback" not in err
    assert not out.exists()


def test_fused_needs_a_controller_with_a_blend(tmp_path, capsys):
    assert main(["verify", str(CREEP), "--controller", str(GAUGE), "--sensor", "all",
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "with_sensor('fused'" in err and "Traceback" not in err


def test_a_sensor_other_than_the_controllers_block_is_a_preflight_mismatch(tmp_path, capsys):
    # --strict turns the warning into the refusal, before any work: the message is the warning's
    assert main(["verify", str(CREEP), "--controller", str(FUSED), "--sensor", "gauge", "--strict",
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "sensor: --sensor gauge, but the controller's sensor block says 'fused'" in err


def test_verify_table_sensor_key(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('[verify]\nsensor = "fused"\nhold_drift_m = 2e-9\n')
    assert load_verify_sensor(f) == "fused" and load_verify_targets(f) == {"hold_drift_m": 2e-9}
    f.write_text('[verify]\nsensor = "strain"\n')
    with pytest.raises(StudyDefinitionError, match=r"verify.sensor.*gauge, charge, fused, all"):
        load_verify_sensor(f)


@pytest.mark.parametrize("fc_hz", [3.0, 47.0, 410.0])
def test_closed_loop_bandwidth_of_an_integrator_loop_is_its_crossover(fc_hz):
    # L = w_c / s: T = w_c / (s + w_c), whose -3 dB point is f_c exactly
    from workbench.design.margins import closed_loop_bandwidth_hz
    f = np.geomspace(0.01, 4999.0, 1500)
    loop = fc_hz / (1j * f)
    assert closed_loop_bandwidth_hz(f, loop) == pytest.approx(fc_hz, rel=2e-3)
    # a type-0 loop 3 / (1 + s/w_p): T = 3 / (4 + s/w_p), -3 dB below T(0) = 3/4 at 4 f_p
    type0 = 3.0 / (1 + 1j * f / (fc_hz / 4))
    assert closed_loop_bandwidth_hz(f, type0, reference="low_frequency") == pytest.approx(fc_hz, rel=2e-3)


def test_a_fused_controller_on_the_gauge_scenarios_is_flagged(tmp_path, capsys):
    assert main(["verify", str(CREEP), "--controller", str(FUSED), "--scenario", "small_step", "--strict",
                 "--out", str(tmp_path / "o")]) == 2
    assert "the scenarios close on the gauge, but the controller's sensor block says 'fused'" in capsys.readouterr().err


def test_cli_sensor_run_writes_the_side_by_side_report(tmp_path, capsys):
    import json
    out = tmp_path / "out"
    assert main(["verify", str(CREEP), "--controller", str(FUSED), "--sensor", "fused", "--hold", "3s",
                 "--out", str(out), "--json", str(tmp_path / "v.json")]) == 0
    text = capsys.readouterr().out
    assert "sensor fused: bandwidth" in text and "hold noise" in text
    rows = json.loads((tmp_path / "v.json").read_text())["sensors"]
    assert [r["sensor"] for r in rows] == ["fused"] and rows[0]["blend_crossover_hz"] == pytest.approx(0.8939, rel=1e-4)
    report = (out / "report.md").read_text()
    assert "## Sensors side by side" in report and "![sensors](sensors.png)" in report
    assert (out / "sensors.png").stat().st_size > 10000 and (out / "verify.json").exists()


@pytest.mark.parametrize("amp_m, tau_s, tol_m", [(1e-9, 0.3, 1e-11), (40e-9, 2.0, 0.4e-9), (3e-6, 25.0, 5e-9)])
def test_settled_time_of_an_exponential_is_tau_log_amplitude_over_tolerance(amp_m, tau_s, tol_m):
    # e = A exp(-t / tau) decays monotonically to 0: it stays within tol of e(t) from then on exactly when
    # e(t) - e(end) <= tol, i.e. t = -tau ln(tol / A + exp(-T / tau)) for a horizon T
    from workbench.verify.sensors import settled_time_s
    t_end = 16 * tau_s                  # settled within the first half: the required settled stretch
    t = np.linspace(0.0, t_end, 200001)
    e = amp_m * np.exp(-t / tau_s)
    want = -tau_s * np.log(tol_m / amp_m + np.exp(-t_end / tau_s))
    assert settled_time_s(t, e, tol_m) == pytest.approx(want, abs=2 * (t[1] - t[0]))
    assert settled_time_s(t, -e, tol_m) == pytest.approx(want, abs=2 * (t[1] - t[0]))     # sign-blind
    assert settled_time_s(t, e, 2 * amp_m) == 0.0                                       # settled at once


@pytest.mark.parametrize("rate_m_per_s, horizon_s", [(1e-12, 0.5), (3e-10, 10.0), (1e-8, 20.0), (4e-7, 200.0)])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_channel_that_drifts_linearly_is_not_settled(rate_m_per_s, horizon_s, sign):
    """A pure linear drift e = v t over a horizon T stays within tol of e(t_i) from t_i exactly when
    |v| (T - t_i) <= tol, i.e. t_i = T - tol / |v|: with the settled stretch required to last T / 2 it is
    "not settled" (NaN) whenever tol / |v| < T / 2, however the horizon is chosen, and settles at T - tol/|v|
    otherwise (four decades of v and T; tolerance from 1e-3 to 0.99 of the stretch and beyond)."""
    from workbench.verify.sensors import settled_time_s
    t = np.linspace(0.0, horizon_s, 100001)
    dt = t[1] - t[0]
    e = sign * rate_m_per_s * t + 3e-9
    for frac in (1e-3, 0.1, 0.49):                          # tol / v as a fraction of T: never settles
        tol = frac * horizon_s * rate_m_per_s
        assert np.isnan(settled_time_s(t, e, tol))
    for frac in (0.51, 0.8, 0.99):                          # settles, at T - tol / v
        tol = frac * horizon_s * rate_m_per_s
        assert settled_time_s(t, e, tol) == pytest.approx(horizon_s * (1 - frac), abs=2 * dt)
    # the required stretch is what decides: with none, the drift "settles" near the end of the horizon
    tol = 1e-3 * horizon_s * rate_m_per_s
    assert settled_time_s(t, e, tol, min_settled_s=0.0) == pytest.approx(horizon_s * (1 - 1e-3), abs=2 * dt)


def test_the_loop_closes_later_when_the_charge_estimate_moves_more(setup):
    """The settle time is derived from the charge channel: with four times the dielectric absorption (which
    the estimator identifies but, with one relaxation for two, imperfectly), the fused reading's startup error
    is larger and the loop closes later; the tolerance is the reading's noise, a fraction of a nanometre."""
    from workbench.selfsense.charge_amp import ChargeAmpParams
    from workbench.verify.sensors import startup_settle_s
    c = Controller.load(FUSED)
    base = startup_settle_s(setup, c, "fused")
    amp4 = ChargeAmpParams(da_gains_f=(1.0e-6, 0.48e-6))
    more = startup_settle_s(sensor_setup(load_plant(CREEP), c, amp=amp4, ident_hold_s=150.0), c, "fused")
    assert 0.05e-9 < base["noise_rms_m"] < 2e-9
    assert more["settle_s"] > base["settle_s"] > c.dt_s


def test_the_charge_estimate_alone_is_not_settled_and_closes_at_the_floor(setup):
    """The charge estimate drifts (bias current, leakage): its startup error keeps moving by more than its
    sub-nanometre noise, so it is "not settled" within the horizon (not the end of the horizon), and the
    loop closes at MIN_OPEN_LOOP_S and says why."""
    from workbench.verify.sensors import MIN_OPEN_LOOP_S, startup_settle_s
    c = Controller.load(FUSED)
    for h in (10.0, 20.0):
        st = startup_settle_s(setup, c, "charge", horizon_s=h)
        assert np.isnan(st["settle_s"]) and f"within {h:g} s" in st["settle_why"]
    r = run_sensor_loop(setup, c, "charge", sweep=False, seed=3, **SHORT)
    assert r["settle_s"] == pytest.approx(MIN_OPEN_LOOP_S) and r["settle_why"]


def test_the_wait_does_not_depend_on_the_scored_noise_draw(setup):
    """The settle tolerance is pooled over fixed draws, none the scored run's: two runs with different seeds
    close at the same period; the tolerance is the reading's noise (~0.4 nm for the blend)."""
    c = Controller.load(FUSED)
    a = run_sensor_loop(setup, c, "fused", sweep=False, seed=1, **SHORT)
    setup.__dict__.pop("_settle_cache", None)             # recomputed, not the cached value
    b = run_sensor_loop(setup, c, "fused", sweep=False, seed=29, **SHORT)
    assert a["settle_s"] == b["settle_s"] and a["settle_noise_rms_m"] == b["settle_noise_rms_m"]
    assert a["triangle_rms_m"] != b["triangle_rms_m"]       # the draws themselves differ


def test_velocity_constant_of_an_integrator_controller_is_its_gain_times_the_loops(tmp_path):
    # C(s) = k / s (Tustin): lim s C = k; the loop's K_v = k v_per_m P0 with P0 = quasi-static stroke / 100 V
    import control

    from workbench.verify.scenarios import stroke_m
    from workbench.verify.sensors import velocity_constant_per_s
    plant = load_plant(CREEP)
    p0 = stroke_m(plant.pzt) / 100.0
    for k in (3.0, 40.0, 900.0):
        c = Controller.from_lti(control.tf([k], [1.0, 0.0]), plant, window=False).with_sensor("gauge")
        assert velocity_constant_per_s(c, c.sensor, plant) == pytest.approx(k * c.sensor.v_per_m * p0, rel=1e-3)
    # type 0: no ramp-error to feed forward
    c0 = Controller.from_lti(control.tf([5.0], [0.01, 1.0]), plant, window=False).with_sensor("gauge")
    assert velocity_constant_per_s(c0, c0.sensor, plant) is None


def test_the_ramp_feedforward_takes_out_the_type_1_loops_ramp_error(setup):
    """Same noise draw, with and without the reference led by slope / K_v: a 0.5 Hz triangle's ramp error
    v / K_v (~5 nm here) dominates without it; with it the error falls at least twice and the feedforward the
    sensor step received is the triangle plus that lead (the recorded reference counts)."""
    c = Controller.load(FUSED)
    args = dict(seed=11, settle_s=5.0, **SHORT)
    off = run_sensor_loop(setup, c, "fused", ramp_feedforward=False, sweep=False, **args)
    on = run_sensor_loop(setup, c, "fused", ramp_feedforward=True, sweep=False, **args)
    v = 0.8 * on["stroke_m"] * 2 * SHORT["triangle_hz"]
    assert off["velocity_constant_per_s"] is None and on["velocity_constant_per_s"] > 0
    assert off["triangle_rms_m"] > 0.5 * v / on["velocity_constant_per_s"]
    assert on["triangle_rms_m"] < 0.5 * off["triangle_rms_m"]
    lead = (on["_reference_counts"] - off["_reference_counts"]) * c.sensor.lsb_m
    moving = np.abs(np.diff(on["_reference_rel_m"], append=0.0)) > 0
    assert np.allclose(np.abs(lead[moving][5:-5]), v / on["velocity_constant_per_s"], rtol=0.02)


def test_the_charge_channel_has_one_adc_and_one_recursion():
    """The charge amplifier's step, its ADC and the estimator's step live in selfsense/charge_amp.py and
    estimator.py only: verify's compiled loop calls them, and no other module re-implements them."""
    import re
    from workbench.selfsense.charge_amp import adc_convert
    lsb = 0.5
    # ties to even, as IEEE rint; clipped to the range after rounding
    assert [adc_convert(v, lsb, 10.0) for v in (0.25, 0.75, -0.25, 1.3, 11.0, -12.0)] == [0.0, 1.0, -0.0, 1.5, 10.0,
                                                                                      -10.0]
    assert adc_convert(0.123, 0.0, 10.0) == 0.123
    src = ROOT / "workbench"
    homes = {"selfsense/charge_amp.py", "selfsense/estimator.py"}
    for path in src.rglob("*.py"):
        rel = path.relative_to(src).as_posix()
        text = path.read_text()
        if rel not in homes:
            assert not re.search(r"q_leak|/ *c_int|2\.0 \*\* int\(.*(adc|vin)", text), rel
            # the copies verify/mirror.py once held: the amplifier over a per-stack table's C_int column, the
            # ADC's rounding to a per-stack LSB, the LSB from a charge amplifier's bits
            assert not re.search(r"\) */ *[a-z_]+\[[a-z_]+, *1\]|np\.rint\([^)]*/ *[a-z_]+\[[^]]*\]\) *\* *[a-z_]+\["
                                 r"|2(\.0)? \*\* *(int\()?(amp|a_j|br|self\.amp)[^ ]*adc_bits", text), rel
    for name in ("sensors.py", "mirror.py"):
        text = (src / "verify" / name).read_text()
        assert "charge_amp_step(" in text and "adc_convert(" in text, name
    assert "estimator_step(" in (src / "verify" / "sensors.py").read_text()


def test_the_loop_takes_the_bridge_curvature_out_with_the_right_sign(setup):
    """Noise off, the gauge design on the gauge over a triangle spanning 80 % of the stroke: each reading is the
    bridge at the period's midpoint (quarter- and three-quarter-period positions, demodulated), quantized by the
    servo DAC. Against x at the midpoint, the reading on the linear calibration is x + beta u^2 (eq. 27,
    u = x - x_c, ~1 nm at the ends) and the linearized one is x, each within half a DAC step plus 1 % of the
    curvature (the arm imbalance's share); a curvature taken out with the wrong sign would leave 2 beta u^2."""
    from workbench.plant.gauge import TRIM_CENTER_M, bridge_curvature_per_m
    g = setup.plant.gauge
    beta = bridge_curvature_per_m(g)
    lsb = 2.0 * g.dac_range_v / 2.0 ** g.dac_bits * abs(g.calibration_m_per_v)
    c = Controller.load(GAUGE)
    for lin in (False, True):
        r = run_sensor_loop(setup, c, "gauge", noise=False, settle_s=1.0, sweep=False, decimate=1,
                            gauge_linearized=lin, **SHORT)
        x_mid = 0.5 * (r["_x_m"][1:] + r["_x_m"][:-1])
        curv = beta * (x_mid - TRIM_CENTER_M) ** 2
        assert np.ptp(x_mid) > 0.75 * r["stroke_m"] and np.max(np.abs(curv)) > 4 * lsb
        left = r["_reading_m"][1:] - x_mid - (0.0 if lin else curv)
        assert np.max(np.abs(left)) <= 0.5 * lsb + 0.01 * np.max(np.abs(curv)) + 2e-12


@pytest.mark.slow
def test_the_fused_loop_meets_issue_16s_floors_with_the_harness_wait_lead_and_linearization():
    """Issue 16's fused floors on the SN637 creep plant (700 s identification as `workbench selfsense`, all noise
    and drift on): 0.1 Hz triangle <= 0.01 % of stroke RMS after the first period and |hold drift| <= 1 nm.
    They hold with what the verify harness adds around the export (the startup wait, the v/K_v lead, the
    linearized gauge); closed at 1 s with the other two the triangle is worse (the wait is load-bearing,
    README: 0.0130 % at seed 0, a miss). `make test` runs one draw and a 20 s hold; WORKBENCH_FULL=1 three draws
    and the issue's 1000 s hold."""
    from workbench.verify.sensor_report import DRIFT_TARGET_M, TRIANGLE_TARGET_PERCENT
    from ..conftest import FULL
    c = Controller.load(FUSED)
    st = sensor_setup(load_plant(CREEP), c)
    hold = 1000.0 if FULL else 20.0
    for seed in ((0, 3, 6) if FULL else (0,)):
        r = run_sensor_loop(st, c, "fused", hold_s=hold, seed=seed, sweep=False)
        assert r["triangle_rms_percent_stroke"] <= TRIANGLE_TARGET_PERCENT
        assert abs(r["hold_drift_m"]) <= DRIFT_TARGET_M
        early = run_sensor_loop(st, c, "fused", hold_s=3.0, seed=seed, sweep=False, settle_s=1.0)
        assert early["triangle_rms_m"] > r["triangle_rms_m"]


def test_the_export_carries_the_wait_the_lead_and_the_gauge_curvature(setup, tmp_path):
    """with_firmware_startup puts the harness's three settings into the sensor block: they survive a write and
    load (JSON, exact doubles), the header gets their macros and the gauge-metres helper (and compiles), a run
    of the exported controller reads them and reproduces the harness run bit for bit, and an export without
    them is unchanged byte for byte; a negative wait is refused with the key named."""
    import json
    import shutil
    import subprocess
    from workbench.errors import ControllerError
    from workbench.plant.gauge import bridge_curvature_per_m
    from workbench.verify.sensors import velocity_constant_per_s, with_firmware_startup
    from dataclasses import replace
    committed = Controller.load(FUSED)                  # the committed export carries them (700 s identification)
    assert committed.sensor.startup_wait_s >= 1.0
    kept = committed.write(tmp_path / "kept", "sn637_fused_loopshape")
    assert Path(kept["json"]).read_bytes() == FUSED.read_bytes()
    assert Path(kept["h"]).read_bytes() == FUSED.with_suffix(".h").read_bytes()
    c = replace(committed, sensor=replace(committed.sensor, startup_wait_s=None, ref_lead_s=None,
                                          gauge_curvature_per_m=None))
    bare = c.write(tmp_path / "bare", "sn637_fused_loopshape")    # without them: the export as before
    want = json.loads(FUSED.read_text())
    for key in ("startup_wait_s", "ref_lead_s", "gauge_curvature_per_m"):
        want["sensor"].pop(key)
    assert json.loads(Path(bare["json"]).read_text()) == want
    h_bare, h_full = Path(bare["h"]).read_text(), FUSED.with_suffix(".h").read_text()
    assert "STARTUP_WAIT_S" not in h_bare and "gauge_metres" not in h_bare
    assert [ln for ln in h_full.splitlines() if ln not in h_bare.splitlines()][0].startswith("/* open loop")
    assert len(h_full.splitlines()) - len(h_bare.splitlines()) == 13
    # the lead's macro says it is velocity feedforward on the planned slope of ramps, not a derivative of any r
    assert "planned slope" in h_full and "not on steps or tones" in h_full
    c2 = with_firmware_startup(setup, c)
    sb = c2.sensor
    assert sb.ref_lead_s == pytest.approx(1.0 / velocity_constant_per_s(c, c.sensor, setup.plant), rel=1e-12)
    assert sb.gauge_curvature_per_m == bridge_curvature_per_m(setup.plant.gauge) < 0
    files = c2.write(tmp_path / "carried", "fw")
    back = Controller.load(files["json"]).sensor
    assert (back.startup_wait_s, back.ref_lead_s, back.gauge_curvature_per_m) == \
        (sb.startup_wait_s, sb.ref_lead_s, sb.gauge_curvature_per_m)
    h = Path(files["h"]).read_text()
    for macro in ("FW_STARTUP_WAIT_S", "FW_REF_LEAD_S", "FW_GAUGE_CURVATURE_PER_M", "fw_gauge_metres"):
        assert macro in h
    if shutil.which("gcc"):
        src = tmp_path / "t.c"
        src.write_text(f'#include "{files["h"]}"\nint main(void) {{ return fw_gauge_metres(7.5e-6) != 7.5e-6; }}\n')
        subprocess.run(["gcc", "-std=c99", "-Wall", "-Werror", "-o", str(tmp_path / "t"), str(src), "-lm"],
                       check=True)
        assert subprocess.run([str(tmp_path / "t")]).returncode == 0
    harness = run_sensor_loop(setup, c, "fused", seed=3, sweep=False, **SHORT)
    carried = run_sensor_loop(setup, Controller.load(files["json"]), "fused", seed=3, sweep=False, **SHORT)
    assert carried["settle_source"] == "controller" and harness["settle_source"] == "harness"
    assert carried["settle_s"] == harness["settle_s"] == pytest.approx(sb.startup_wait_s, abs=c.dt_s)
    assert np.array_equal(carried["_x_m"], harness["_x_m"]) and np.array_equal(carried["_u_v"], harness["_u_v"])
    bad = json.loads(Path(files["json"]).read_text())
    bad["sensor"]["startup_wait_s"] = -1.0
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(ControllerError, match="startup_wait_s"):
        Controller.load(tmp_path / "bad.json")


def test_the_gauge_needs_no_wait_of_its_own_and_its_settings_need_no_charge_channel(setup):
    """The gauge chain keeps no state across periods: its simulated startup error settles at its first reading,
    one period, and firmware_startup gives the gauge exactly that (not the sensor loop's scenario floor, which
    closing_time_s applies when that harness closes), without simulating, from the plant alone (a SensorSetup
    with no estimator: a plant without a charge channel gets its gauge settings too); the lead and the
    curvature are those of the charge-channel setup."""
    from workbench.verify.sensors import (MIN_OPEN_LOOP_S, OFFSET_WINDOW_S, SensorSetup, closing_time_s,
                                          firmware_startup, startup_settle_s, velocity_constant_per_s)
    c = Controller.load(GAUGE)
    st = startup_settle_s(setup, c, "gauge")
    plant_only = SensorSetup(setup.plant, None, None, None, {})
    fw = firmware_startup(plant_only, c, "gauge")
    assert fw["startup_wait_s"] == st["settle_s"] == pytest.approx(c.dt_s, rel=1e-9)
    assert closing_time_s(fw["startup_wait_s"]) == MIN_OPEN_LOOP_S > OFFSET_WINDOW_S
    assert closing_time_s(None) == closing_time_s(float("nan")) == MIN_OPEN_LOOP_S
    assert closing_time_s(4.7) == 4.7
    assert fw["ref_lead_s"] == pytest.approx(1.0 / velocity_constant_per_s(c, c.with_sensor("gauge").sensor,
                                                                           setup.plant), rel=1e-12)
    assert fw == firmware_startup(setup, c, "gauge")
