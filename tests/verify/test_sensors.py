"""verify --sensor: the controller's fixed-point sensor step in the compiled loop with the charge channel."""

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
    charge = run_sensor_loop(setup, Controller.load(FUSED), "charge", seed=7, **SHORT)
    assert fused["hold_noise_rms_m"] < gauge["hold_noise_rms_m"] / 5
    assert abs(fused["hold_drift_m"]) < 3e-9
    assert abs(fused["hold_drift_m"]) < abs(charge["hold_drift_m"])
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
