"""The validators the third outside pass added (README "Bad input", fuzz3), each at its boundary: what it refuses
and, beside it, the legal values a user may bring.

- :meth:`workbench.Controller.check_firmware_settings`: a carried gauge curvature or reference lead worse than none;
- :func:`workbench.selfsense.force.check_force_table` and the force step's floor :func:`force_resolution_n`;
- :meth:`workbench.export.mimo.MimoController.check_mirror`: a damped export's windows and corner against its mirror;
- the sensor block's and the MIMO iff block's unknown keys.
"""

import dataclasses
import importlib.util
import json

import numpy as np
import pytest

from workbench.controller import Controller
from workbench.errors import ControllerError, ControllerMismatchError, DataFileError, FlagRangeError, \
    MimoControllerError, WorkbenchError
from workbench.plant import load_plant
from workbench.plant.gauge import bridge_curvature_per_m

SERIALS = ("p888_51_sn637", "p888_51_sn629", "p888_51_sn618", "p888_51_sn637_creep")


@pytest.fixture(scope="module")
def fused(root):
    return Controller.load(root / "controllers" / "sn637_fused_loopshape.json")


def _with(ctrl, **kw):
    return dataclasses.replace(ctrl, sensor=dataclasses.replace(ctrl.sensor, **kw))


@pytest.mark.parametrize("serial", SERIALS)
def test_a_carried_curvature_is_refused_only_where_it_reads_worse_than_the_linear_calibration(root, fused, serial):
    """Taking beta out of a bridge curving by beta_p leaves (beta_p - beta) u^2: worse than the linear
    calibration's beta_p u^2 exactly when beta leaves [0, 2 beta_p] (beta_p < 0 for the P-888.51 bridges)."""
    plant = load_plant(root / "plants" / f"{serial}.toml")
    bp = bridge_curvature_per_m(plant.gauge)
    assert bp < 0
    for ok in (0.0, bp, 0.01 * bp, 0.999 * 2 * bp, 1.5 * bp):          # within: accepted
        _with(fused, gauge_curvature_per_m=ok).check_firmware_settings(plant)
    for bad in (1.001 * 2 * bp, -0.001 * bp, -bp, 1e6, -1e9, 1e300):
        with pytest.raises(ControllerMismatchError, match=r"\[sensor.gauge_curvature_per_m\]"):
            _with(fused, gauge_curvature_per_m=bad).check_firmware_settings(plant)


@pytest.mark.parametrize("serial", SERIALS)
def test_a_carried_lead_is_refused_beyond_twice_one_over_k_v(root, fused, serial):
    """A lead lambda / K_v leaves the ramp lag v (1 - lambda) / K_v: worse than no lead for lambda > 2; K_v is this
    controller's on this plant (the exported lead is 1/K_v on the design's plant, within a few % on the others)."""
    from workbench.verify.sensors import velocity_constant_per_s
    plant = load_plant(root / "plants" / f"{serial}.toml")
    kv = velocity_constant_per_s(fused, fused.sensor, plant)
    assert kv is not None and 0.5 < fused.sensor.ref_lead_s * kv < 1.5      # the export's own lead fits every serial
    fused.check_firmware_settings(plant)
    for ok in (0.0, 1.0 / kv, 1.999 / kv):
        _with(fused, ref_lead_s=ok).check_firmware_settings(plant)
    for bad in (2.001 / kv, 1e3, 1e300):
        with pytest.raises(ControllerMismatchError, match=r"\[sensor.ref_lead_s\].*2/K_v"):
            _with(fused, ref_lead_s=bad).check_firmware_settings(plant)


def test_the_sensor_block_refuses_unknown_keys_and_names_startup_fields(root):
    data = json.loads((root / "controllers" / "sn637_fused_loopshape.json").read_text(encoding="utf-8"))
    Controller.from_dict(data, source="f.json")                              # every key the exporter writes
    for block, key in (({"startup_wait_ms": 4707.6}, "sensor.startup_wait_ms"),
                       ({"startup_wait_s": -1.0}, "sensor.startup_wait_s"),
                       ({"ref_lead_s": "0.0004"}, "sensor.ref_lead_s"),
                       ({"gauge_curvature_per_m": float("nan")}, "sensor.gauge_curvature_per_m"),
                       ({"blend": {**data["sensor"]["blend"], "kk": 1}}, "sensor.blend.kk")):
        bad = {**data, "sensor": {**data["sensor"], **block}}
        with pytest.raises(ControllerError, match=rf"f.json: \[{key}\]"):
            Controller.from_dict(bad, source="f.json")


def test_a_mimo_controller_is_named_where_a_single_stack_one_is_needed(tmp_path):
    from workbench.export.mimo import MIMO_SCHEMA
    with pytest.raises(ControllerError, match=r"\[schema\] is a MIMO mirror controller"):
        Controller.from_dict({"schema": MIMO_SCHEMA, "sample_rate_hz": 1e4}, source="m.json")


# ---------------------------------------------------------------------------------------------
# the force study: its table and its step

def _table_variants(root, tmp_path):
    text = (root / "plants" / "data" / "p888_51_instron_table1.csv").read_text(encoding="utf-8")
    rows = text.splitlines()
    out = {}
    out["back_emf_zero"] = text.replace(",11.68", ",0.0")                   # one R_out run without its back EMF
    out["r_in_only"] = "\n".join(r for r in rows if "R_out" not in r) + "\n"
    keep = [r for r in rows if "R_out" not in r or r.startswith("SN637,1,") or r.startswith("SN637,2,")]
    out["two_r_out"] = "\n".join(keep) + "\n"
    out["back_emf_mv"] = text.replace("back_emf[V]", "back_emf[mV]")       # a unit slip: T_em 1000x
    paths = {}
    for name, t in out.items():
        paths[name] = tmp_path / f"{name}.csv"
        paths[name].write_text(t, encoding="utf-8")
    (tmp_path / "folder.csv").mkdir()
    paths["folder"] = tmp_path / "folder.csv"
    paths["latin1"] = tmp_path / "latin1.csv"
    paths["latin1"].write_bytes(text.encode("utf-8").replace(b"Instron", b"Instr\xf6n", 1))
    return paths


def test_a_table_the_force_study_cannot_score_is_refused_before_any_simulation(root, tmp_path):
    from workbench.selfsense.force import check_force_table, run_force_study
    from workbench.identify.transducer import _read_table, DEFAULT_CALIBRATIONS_M_PER_V
    good = root / "plants" / "data" / "p888_51_instron_table1.csv"
    check_force_table(good, _read_table(good, DEFAULT_CALIBRATIONS_M_PER_V)[0])
    stages = []
    for name, path in _table_variants(root, tmp_path).items():
        with pytest.raises(WorkbenchError) as err:
            run_force_study(root / "plants" / "p888_51_sn637_creep.toml", table_path=path, progress=stages.append)
        assert path.name in str(err.value), (name, str(err.value))
    assert stages == []                                                       # nothing was simulated


def test_the_table1_held_out_scores_refuse_the_same_tables(root, tmp_path):
    from workbench.selfsense.table1 import table1_held_out
    paths = _table_variants(root, tmp_path)
    for name in ("back_emf_zero", "r_in_only", "two_r_out", "back_emf_mv"):
        with pytest.raises(DataFileError, match=paths[name].name):
            table1_held_out(paths[name])


@pytest.mark.parametrize("serial", SERIALS)
def test_the_force_step_floor_is_the_target_over_one_adc_step(root, serial):
    """k_p / T_em C_int LSB: a force F moves the charge by T_em F / k_p, read in steps of C_int LSB; the step is
    refused where its 2 % target is finer than that, on both signs, and accepted just above."""
    from workbench.selfsense.charge_amp import ChargeAmpParams
    from workbench.selfsense.force import FORCE_TARGET_STEP_FRACTION, check_step_force, force_resolution_n
    pzt = load_plant(root / "plants" / f"{serial}.toml").pzt
    amp = ChargeAmpParams()
    res = force_resolution_n(pzt, amp)
    assert res == pytest.approx(pzt.stiffness_n_per_m / pzt.transducer_constant_n_per_v * amp.c_int_f
                                * 2 * amp.adc_range_v / 2 ** amp.adc_bits, rel=1e-12)
    floor = res / FORCE_TARGET_STEP_FRACTION
    assert floor < 100.0                                # the study's default -100 N step is well above it
    for sign in (-1.0, 1.0):
        check_step_force(pzt, sign * 1.01 * floor)
        with pytest.raises(FlagRangeError, match="ADC step"):
            check_step_force(pzt, sign * 0.99 * floor)
    with pytest.raises(FlagRangeError):
        check_step_force(pzt, 1e-12)


# ---------------------------------------------------------------------------------------------
# the mirror's damped export against the mirror it runs on

@pytest.fixture(scope="module")
def damped(root):
    from workbench.export.mimo import MimoController
    from workbench.plant.mirror import load_mirror
    spec = importlib.util.spec_from_file_location("mirror_cases", root / "tests" / "verify" / "mirror_cases.py")
    cases = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cases)
    fsm = load_mirror(root / "plants" / "fsm_p888_51.toml")
    design, _ = cases.quick_design(fsm, iff=True)
    return MimoController.from_design(design, fsm, name="mimo"), fsm


def test_a_damped_export_is_checked_against_its_mirrors_stacks(damped):
    from workbench.export.mimo import stack_windows
    ctrl, fsm = damped
    ctrl.check_mirror(fsm)                                                    # the exporter's own numbers
    want = stack_windows(fsm, ctrl.dt_s)
    for key in ("alpha", "headroom_v"):
        for factor in (1.001, 0.999, 5.0):
            iff = {**ctrl.iff, "stack_window": {**ctrl.iff["stack_window"], key: [want[key][0] * factor] + want[key][1:]}}
            with pytest.raises(MimoControllerError, match=rf"\[iff.stack_window.{key}\]"):
                dataclasses.replace(ctrl, iff=iff).check_mirror(fsm)
    for corner in (1.01 * ctrl.iff["bridge"]["corner_hz"], 88.0, 1e300):
        iff = {**ctrl.iff, "bridge": {**ctrl.iff["bridge"], "corner_hz": corner}}
        with pytest.raises(MimoControllerError, match=r"\[iff.bridge.corner_hz\]"):
            dataclasses.replace(ctrl, iff=iff).check_mirror(fsm)
    # exported for another mirror file (its SHA-256): verify warns of that; the windows are not compared
    other = {**ctrl.record, "provenance": {**ctrl.record["provenance"], "plant_sha256": "0" * 64}}
    iff = {**ctrl.iff, "stack_window": {**ctrl.iff["stack_window"], "alpha": [0.5] * 3}}
    dataclasses.replace(ctrl, iff=iff, record=other).check_mirror(fsm)


def test_the_iff_tables_refuse_unknown_keys_and_a_noise_over_the_adc_range(damped, tmp_path):
    from workbench.export.mimo import MimoController
    ctrl, _ = damped
    data = json.loads(json.dumps(ctrl.to_dict()))
    MimoController.from_dict(data, source="m.json")
    for change, key in ((lambda d: d["iff"].__setitem__("stack_windows", {}), "iff.stack_windows"),
                        (lambda d: d["iff"]["bridge"].__setitem__("corner", 8.8), "iff.bridge.corner"),
                        (lambda d: d["iff"]["stack_window"].__setitem__("beta", [1, 1, 1]), "iff.stack_window.beta"),
                        (lambda d: d["iff"]["bridge"].__setitem__("out_noise_v_rms", d["iff"]["bridge"]["adc_range_v"]),
                         "iff.bridge.out_noise_v_rms")):
        bad = json.loads(json.dumps(data))
        change(bad)
        with pytest.raises(MimoControllerError, match=rf"m.json: \[{key}\]"):
            MimoController.from_dict(bad, source="m.json")
    assert np.isfinite(data["iff"]["bridge"]["out_noise_v_rms"])


def test_the_verify_run_size_counts_each_sensor_loop_and_the_carried_wait(root, monkeypatch):
    """Each sensor loop runs the controller's startup_wait_s (when its block carries one for that sensor), the 20 s
    triangle and the hold; the legal export passes, a wait whose trace outgrows the machine is refused."""
    from workbench.cli import build_parser
    from workbench.preflight import RUN_COSTS, estimate_run
    monkeypatch.chdir(root)
    parse = build_parser().parse_args
    base = ["verify", "plants/p888_51_sn637_creep.toml", "--controller", "controllers/sn637_fused_loopshape.json",
            "--hold", "3s"]
    wait = Controller.load(root / "controllers" / "sn637_fused_loopshape.json").sensor.startup_wait_s
    s_p, b_p = RUN_COSTS["verify_sensor_period"]
    for sensors, n_loops in ((["--sensor", "fused"], 1), (["--sensor", "all"], 3)):
        what, seconds, nbytes = estimate_run(parse(base + sensors))
        fused_periods = (wait + 20.0 + 3.0) * 1e4
        others = (n_loops - 1) * (1.0 + 20.0 + 3.0) * 1e4      # the harness's own wait: its 1 s floor
        assert seconds == pytest.approx((fused_periods + others) * s_p, rel=1e-9)
        assert nbytes == pytest.approx((fused_periods + others) * b_p, rel=1e-9)
        assert "[sensor.startup_wait_s]" in what
    what, seconds, _ = estimate_run(parse(base + ["--scenario", "small_step"]))
    assert seconds == 0.0                                       # no hold, no sensor loop
