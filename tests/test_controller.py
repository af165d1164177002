"""The one Controller: round trips, from_lti against the committed export, validation on load, plant comparison."""

import copy
import json
from dataclasses import replace

import control
import numpy as np
import pytest

from workbench.controller import NO_WINDOW_TEXT, Controller, ControllerError
from workbench.export import from_sos, quantize, run_fixed
from workbench.plant import load_plant

from .conftest import PLANTS, ROOT

COMMITTED = ROOT / "controllers" / "sn637_loopshape.json"


@pytest.fixture(scope="module")
def data():
    return json.loads(COMMITTED.read_text())


@pytest.fixture(scope="module")
def ctrl():
    return Controller.load(COMMITTED)


def test_json_round_trip_is_byte_identical_and_mat_carries_everything(ctrl, tmp_path, rng):
    paths = ctrl.write(tmp_path)
    for ext in ("json", "h", "csv"):
        assert paths[ext].read_bytes() == COMMITTED.with_suffix(f".{ext}").read_bytes(), ext
    for mat in (paths["mat"], COMMITTED.with_suffix(".mat")):      # the committed .mat is re-exported too
        m = Controller.load(mat)
        assert m.voltage_model == ctrl.voltage_model and m.window_source == "file"
        assert m.provenance == ctrl.provenance and m.output_limits_v == ctrl.output_limits_v
        np.testing.assert_array_equal(m.fixed.b, ctrl.fixed.b)
        np.testing.assert_array_equal(m.fixed.a, ctrl.fixed.a)
        # a record through the window and the limits: the firmware step bit for bit
        e = np.concatenate([rng.normal(0, 0.05, 3000), np.full(2000, 1.5), np.full(2000, -2.0)])
        np.testing.assert_array_equal(m.run(e), ctrl.run(e))
    np.testing.assert_array_equal(ctrl.run(e), run_fixed(ctrl.fixed, e))
    assert np.min(ctrl.run(e)) >= -20.0 and np.max(ctrl.run(e)) <= 120.0


def test_from_lti_reproduces_the_committed_export(ctrl, data):
    # the study exports through Controller.from_lti: from the committed float design and the SN637
    # creep plant it must give the committed words and window (to the last bit)
    plant = load_plant(PLANTS / "p888_51_sn637_creep.toml")
    k = from_sos(ctrl.gain, ctrl.sos, ctrl.dt_s)
    c = Controller.from_lti(k, plant, output_limits_v=(-20.0, 120.0), input_range_v=2.6,
                            f_max_hz=data["fixed_point"]["f_max_hz"])
    np.testing.assert_array_equal(c.fixed.b, ctrl.fixed.b)
    np.testing.assert_array_equal(c.fixed.a, ctrl.fixed.a)
    np.testing.assert_array_equal(c.fixed.signal_frac_bits, ctrl.fixed.signal_frac_bits)
    assert c.voltage_model == pytest.approx(ctrl.voltage_model, rel=1e-12)
    assert c.provenance["plant_sha256"] == data["provenance"]["plant_sha256"]
    assert c.provenance["gauge_v_per_m"] == pytest.approx(data["gauge_chain"]["volts_per_meter"], rel=1e-9)
    assert c.compare_plant(plant) == []


@pytest.mark.parametrize("fc_hz", [20.0, 150.0, 900.0])
def test_from_lti_tustin_and_window_from_the_plant(fc_hz):
    # a continuous PI is discretized by Tustin; the window is alpha = 1 - exp(-T / (R C_max)),
    # h = R I (80 ohm x 2 mA = 0.16 V up, x 14 mA = 1.12 V down for SN629)
    plant = load_plant(PLANTS / "p888_51_sn629.toml")
    s = control.tf("s")
    k_c = 3.0 * (s + 2 * np.pi * fc_hz) / s
    c = Controller.from_lti(k_c, plant)
    dt = plant.gauge.period_s
    for f in (1.0, 100.0, 2000.0):
        z = np.exp(2j * np.pi * f * dt)
        w = 2 / dt * (z - 1) / (z + 1)                                  # Tustin's s of z
        want = 3.0 * (w + 2 * np.pi * fc_hz) / w
        assert complex(c.as_lti()(z)) == pytest.approx(want, rel=1e-9)
        assert complex(c.as_lti(quantized=True)(z)) == pytest.approx(want, rel=1e-6)
    alpha, h_up, h_down = c.voltage_model
    assert h_up == pytest.approx(80 * 2e-3) and h_down == pytest.approx(80 * 14e-3)
    assert 0 < alpha < 1 and c.window_source == "file"
    assert c.output_limits_v == (-20.0, 120.0) and c.provenance["serial"] == "SN629"


def test_bare_controller_window_from_plant_or_said_to_be_off(tmp_path):
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps({"sample_rate_hz": 1e4, "gain": 250.0, "sos": [[1, 0, 0, 1, 0, 0]]}))
    alone = Controller.load(bare)
    assert alone.voltage_model is None and NO_WINDOW_TEXT in alone.describe()
    plant = load_plant(PLANTS / "p888_51_sn637_creep.toml")
    with_plant = Controller.load(bare, plant=plant)
    assert with_plant.window_source == "plant" and "derived from the plant" in with_plant.describe()
    assert with_plant.voltage_model[1] == pytest.approx(plant.pzt.series_resistance_ohm * plant.pzt.current_limit_source_a)
    assert with_plant.output_limits_v == (plant.pzt.voltage_min_v, plant.pzt.voltage_max_v)
    # a gain no reading can use: one 79 uV LSB commands more than the 140 V range at every frequency
    # (1e300, and also the smallest such gain, 140 V / 79 uV = 1.8e6, with 2x margin); 250 passes
    for gain in (1e300, 3.6e6):
        bare.write_text(json.dumps({"sample_rate_hz": 1e4, "gain": gain, "sos": [[1, 0, 0, 1, 0, 0]]}))
        with pytest.raises(ControllerError, match=r"bare.json: \[gain\].*switch between its limits"):
            Controller.load(bare, plant=plant)
    bare.write_text(json.dumps({"sample_rate_hz": 1e4, "gain": 1.0e6, "sos": [[1, 0, 0, 1, 0, 0]]}))
    assert Controller.load(bare, plant=plant).gain == 1.0e6                 # 79 V per LSB: within range


def _set(d, path, value):
    keys = path.split("/")
    for k in keys[:-1]:
        d = d[int(k)] if isinstance(d, list) else d[k]
    last = keys[-1]
    if value is _DROP:
        del d[last]
    elif isinstance(d, list):
        d[int(last)] = value
    else:
        d[last] = value


class _Dropped:
    """The key removed; a fixed repr so test ids agree between pytest-xdist workers."""

    def __repr__(self):
        return "<dropped>"


_DROP = _Dropped()
# (mutation of the committed JSON, the key the message must name)
BAD = [
    ("sample_rate_hz", 0, "sample_rate_hz"), ("sample_rate_hz", -1e4, "sample_rate_hz"),
    ("sample_rate_hz", "fast", "sample_rate_hz"), ("sample_rate_hz", _DROP, "sample_rate_hz"),
    ("gain", float("nan"), "gain"), ("gain", 0.0, "gain"), ("gain", 1e300, "fixed_point.sections[0].b"),
    ("sos/0/1", float("nan"), "sos"), ("sos/0/3", 2.0, "sos[0]"), ("sos/1", [1.0, 0.5, 0.0, 1.0, -1.0], "sos"),
    ("sos", [], "sos"), ("sos", _DROP, "sos"),
    ("output_limits_v", [120.0, -20.0], "output_limits_v"), ("output_limits_v", [120.0], "output_limits_v"),
    ("anti_windup/output_limits_v", [-20.0, 100.0], "anti_windup.output_limits_v"),
    ("anti_windup/voltage_model/alpha", 5.0, "anti_windup.voltage_model.alpha"),
    ("anti_windup/voltage_model/alpha", 0.0, "anti_windup.voltage_model.alpha"),
    ("anti_windup/voltage_model/headroom_v", [-0.16, 1.12], "anti_windup.voltage_model.headroom_v"),
    ("fixed_point/output/voltage_model/alpha", 0.2, "fixed_point.output.voltage_model"),
    ("fixed_point/sections/0/b/0", 123456, "fixed_point.sections[0].b"),
    ("fixed_point/sections/1/a/1", -(1 << 28), "fixed_point.sections[1]"),      # the integrator's identity
    ("fixed_point/sections/0/a/1", 1 << 20, "fixed_point.sections[0].a"),
    ("fixed_point/sections/0/b/1", 1.5, "fixed_point.sections[0].b"),
    ("fixed_point/sections/0/b", [1, 2], "fixed_point.sections[0].b"),
    ("fixed_point/coeff_bits", 64, "fixed_point.coeff_bits"),
    ("fixed_point/f_max_hz", _DROP, "fixed_point.f_max_hz"),
    ("fixed_point/sections/0/integrator", True, "fixed_point.sections[0]"),
]


@pytest.mark.parametrize("path, value, key", BAD, ids=[f"{p}={v!r}"[:40] for p, v, _ in BAD])
def test_bad_controllers_name_the_file_and_key(data, tmp_path, path, value, key):
    bad = copy.deepcopy(data)
    _set(bad, path, value)
    f = tmp_path / "ctrl.json"
    f.write_text(json.dumps(bad))
    with pytest.raises(ControllerError) as err:
        Controller.load(f)
    assert str(f) in str(err.value) and f"[{key}" in str(err.value), str(err.value)


def test_quantized_pole_outside_the_circle_is_refused_whatever_max_pole_radius_says(data, tmp_path):
    # words for poles at |z| = 1.41 in the first section, with the float section and the recorded
    # radius (0.876) left as they were: the loader computes the radius from the words
    bad = copy.deepcopy(data)
    f_a = bad["fixed_point"]["a_frac_bits"]
    bad["fixed_point"]["sections"][0]["a"] = [0, int(2.0 * 2 ** f_a) - 1]       # z^2 + 2 -> |z| = 1.41
    f = tmp_path / "c.json"
    f.write_text(json.dumps(bad))
    with pytest.raises(ControllerError, match=r"fixed_point.sections\[0\].a.*\|z\| = 1.41"):
        Controller.load(f)


def test_unstable_float_poles_refused_unless_allowed(tmp_path):
    f = tmp_path / "u.json"
    f.write_text(json.dumps({"sample_rate_hz": 1e4, "sos": [[1, 0, 0, 1, -1.5, 0], [1, 0, 0, 1, -1, 0]]}))
    with pytest.raises(ControllerError, match=r"u.json: \[sos\[0\]\].*1.5.*--allow-unstable"):
        Controller.load(f)
    assert Controller.load(f, allow_unstable=True).max_pole_radius == pytest.approx(1.5)
    # an integrator is fine in the last section only
    f.write_text(json.dumps({"sample_rate_hz": 1e4, "sos": [[1, 0, 0, 1, -1, 0], [1, 0, 0, 1, -0.5, 0]]}))
    with pytest.raises(ControllerError, match=r"\[sos\[0\]\].*integrator outside the last section"):
        Controller.load(f)


def test_unreadable_files(tmp_path):
    for name, payload in (("x.json", b"{not json"), ("y.json", b"\xff\xfe\x00"), ("z.mat", b"not a mat"),
                          ("w.json", b"[1, 2]")):
        f = tmp_path / name
        f.write_bytes(payload)
        with pytest.raises(ControllerError, match=name):
            Controller.load(f)
    with pytest.raises(ControllerError, match="missing.json.*cannot be read"):
        Controller.load(tmp_path / "missing.json")


def _plant_with_limits(tmp_path, source_a, sink_a):
    text = (PLANTS / "p888_51_sn637_creep.toml").read_text()
    text = text.replace("current_limit_source_a = 2.0e-3", f"current_limit_source_a = {source_a}")
    text = text.replace("current_limit_sink_a = 14.0e-3", f"current_limit_sink_a = {sink_a}")
    assert f"current_limit_source_a = {source_a}" in text
    path = tmp_path / "sn637_20ma.toml"
    path.write_text(text)
    return load_plant(path)


def test_compare_plant_flags_other_serials_and_another_amplifier(ctrl, tmp_path):
    assert [p["check"] for p in ctrl.compare_plant(load_plant(PLANTS / "p888_51_sn637_creep.toml"))] \
        == ["not recorded"]                                              # the committed JSON has no serial
    for serial in ("sn629", "sn618"):
        checks = {p["check"] for p in ctrl.compare_plant(load_plant(PLANTS / f"p888_51_{serial}.toml"))}
        assert {"plant_sha256", "trim_scale", "trim_bias_v", "gauge_v_per_m", "window"} <= checks, serial
    checks = {p["check"]: p["message"] for p in ctrl.compare_plant(_plant_with_limits(tmp_path, 20e-3, 20e-3))}
    assert set(checks) == {"plant_sha256", "window", "not recorded"}
    assert "+1.6/-1.6 V" in checks["window"]                              # 80 ohm x 20 mA


def test_feedback_of_the_nominal_loop_is_stable_and_matches_the_frequency_response(ctrl):
    # control.feedback of the exported controller with the API's nominal plant: poles inside the unit
    # circle, and margins of the LTI product equal those of the pointwise frequency response of the
    # unreduced plant (what family_margins uses) to 0.5 deg / 0.2 dB
    import workbench as wb
    plant = load_plant(PLANTS / "p888_51_sn637_creep.toml")
    p = wb.nominal_loop_plant(plant)
    k = ctrl.as_lti(quantized=True)
    assert np.max(np.abs(control.feedback(k * p, 1).poles())) < 1.0
    full = wb.nominal_loop_plant(plant, minimal=False)
    f = np.geomspace(0.01, 4990.0, 6000)
    z = np.exp(2j * np.pi * f * ctrl.dt_s)
    loop = np.array([complex(k(x)) * complex(full(x)) for x in z])
    ref, got = wb.loop_margins(f, loop), wb.margins_of(k * p)
    assert got.phase_margin_deg == pytest.approx(ref.phase_margin_deg, abs=0.5)
    assert got.gain_margin_db == pytest.approx(ref.gain_margin_db, abs=0.2)
    assert 30 < ref.phase_margin_deg < 90 and 50 < ref.crossover_hz < 500


def test_quantize_agrees_with_from_dict_words(ctrl):
    # the loader's LSB check accepts what quantize produces for any coefficient width it allows
    for bits in (16, 24, 32):
        fxp = quantize(ctrl.gain, ctrl.sos, ctrl.dt_s, input_range_v=2.6, output_limits_v=(-20.0, 120.0),
                       f_max_hz=500.0, coeff_bits=bits, max_error_db=1.0, max_error_deg=5.0,
                       voltage_model=ctrl.voltage_model)
        from workbench.export.writers import controller_json
        back = Controller.from_dict(json.loads(controller_json({"name": "q"}, fxp)), source=f"q{bits}")
        np.testing.assert_array_equal(back.fixed.b, fxp.b)
        assert back.max_pole_radius == pytest.approx(fxp.max_pole_radius, abs=1e-12)


def test_series_resistor_out_gives_a_slew_window_from_the_largest_capacitance():
    """R = 0 (seed 000's free-free configuration): the current is C dV/dt, so the window is a slew of I T / C a
    sample around the last output (alpha = 1), C the largest terminal capacitance (every play's weight and the
    creep branches' capacitances summed, in series with C_pp: derived here from the file's numbers)."""
    import control
    plant = load_plant(PLANTS / "p888_51_sn637_creep.toml", overrides={"electrical.series_resistor_in": False})
    pz = plant.pzt
    assert pz.series_resistance_ohm == 0.0
    c_h = float(np.sum(pz.hysteresis.weights)) + float(np.sum(pz.creep.capacitances_f))
    c_max = c_h * pz.c_pp_f / (c_h + pz.c_pp_f)
    k = control.c2d(control.tf([50.0, 50.0 * 2 * np.pi * 20.0], [1.0, 0.0]), 1e-4, "tustin")   # a PI
    ctrl = Controller.from_lti(k, plant)
    alpha, h_up, h_down = ctrl.voltage_model
    assert alpha == 1.0 and ctrl.fixed.limit_words[2] == 1 << 30
    assert h_up == pytest.approx(2e-3 * 1e-4 / c_max, rel=1e-12) and h_down == pytest.approx(14e-3 * 1e-4 / c_max, rel=1e-12)
    assert "slew window" in ctrl.describe() and NO_WINDOW_TEXT not in ctrl.describe()
    # a large error: the integrator is held to the slew, the charge per sample C_max du never passes I T
    u = ctrl.run(np.full(2000, 1.0), u0_v=50.0)
    du = np.diff(np.concatenate([[50.0], u]))
    assert du.max() <= h_up and c_max * du.max() <= 2e-3 * 1e-4 * (1 + 1e-12)
    assert du.max() > h_up - 2.0 ** -ctrl.fixed.output_frac_bits          # and it slews at the window
    free = Controller.from_lti(k, plant, window=False).run(np.full(2000, 1.0), u0_v=50.0)
    assert np.diff(free).max() > 10 * h_up                                 # what the window holds back
    assert [c for c in ctrl.compare_plant(plant) if c["check"] == "window"] == []
    # a controller exported without the window (session 37's R-out export) is named, and so is an R-in window
    bare = Controller.from_lti(k, plant, window=False)
    msg = [c["message"] for c in bare.compare_plant(plant) if c["check"] == "window"]
    assert len(msg) == 1 and NO_WINDOW_TEXT in msg[0] and "series resistor out" in msg[0]
    windowed = Controller.from_lti(k, load_plant(PLANTS / "p888_51_sn637_creep.toml"))
    assert windowed.voltage_model[0] < 1
    assert [c["check"] for c in windowed.compare_plant(plant) if c["check"] == "window"] == ["window"]
    # the JSON round trip keeps alpha = 1 and the headroom
    back = Controller.from_dict(json.loads(json.dumps(ctrl.to_dict())))
    assert back.voltage_model == ctrl.voltage_model
    np.testing.assert_array_equal(back.fixed.limit_words, ctrl.fixed.limit_words)
    from workbench.design.budgets import plant_budgets
    assert plant_budgets(plant, 1e-4, None, "study.toml")["current_window"].value == ctrl.voltage_model


def test_an_r_in_window_is_unchanged():
    """The R-in window of the committed controller (written before the R-out window existed) is what the plant
    gives now, bit for bit: alpha = 1 - exp(-T / (R C_max)), headroom R I."""
    from workbench.controller import plant_window
    data = json.loads((ROOT / "controllers" / "sn637_loopshape.json").read_text())
    plant = load_plant(PLANTS / "p888_51_sn637_creep.toml")
    vm = data["anti_windup"]["voltage_model"]
    assert plant_window(plant, 1e-4) == (vm["alpha"], *vm["headroom_v"])
    # the JSON block and the window's words as the committed export has them
    from workbench.controller import _anti_windup_block
    block = _anti_windup_block(plant_window(plant, 1e-4), data["anti_windup"]["output_limits_v"], plant)
    assert block == {k: v for k, v in data["anti_windup"].items() if k != "output_slew_limit_v_per_s"}
    c = Controller.load(ROOT / "controllers" / "sn637_loopshape.json")
    fxp = quantize(c.gain, np.array(c.sos), c.dt_s, input_range_v=c.fixed.input_range_v,
                   output_limits_v=c.output_limits_v, f_max_hz=c.fixed.f_max_hz, voltage_model=plant_window(plant, 1e-4))
    np.testing.assert_array_equal(fxp.limit_words, c.fixed.limit_words)
    np.testing.assert_array_equal(fxp.b, c.fixed.b)
    np.testing.assert_array_equal(fxp.a, c.fixed.a)


@pytest.mark.parametrize("r_ohm", [0.01, 0.1, 0.0])
def test_resistor_out_is_the_plants_r_not_an_alpha_of_one(r_ohm, tmp_path):
    """With R in, alpha = 1 - exp(-T / (R C_max)) rounds to exactly 1.0 once T / (R C) > ~37 (R < ~0.23 ohm on
    SN637 with creep): the window is still the R-in one (headroom R I: 0.2 mV up at 0.1 ohm, not I T / C), and the
    describe line, the JSON's anti_windup block and the C header's comment must say so; R = 0 is the slew window.
    Everything is read back from the written files and from a reloaded controller."""
    from workbench.controller import recorded_resistor_out
    over = ({"electrical.series_resistor_in": False} if r_ohm == 0 else
            {"electrical.series_resistor_ohm": r_ohm})
    plant = load_plant(PLANTS / "p888_51_sn637_creep.toml", overrides=over)
    pz = plant.pzt
    c_h = float(np.sum(pz.hysteresis.weights)) + float(np.sum(pz.creep.capacitances_f))
    c_max = c_h * pz.c_pp_f / (c_h + pz.c_pp_f)              # the largest terminal capacitance, from the file
    k = control.c2d(control.tf([50.0, 50.0 * 2 * np.pi * 20.0], [1.0, 0.0]), 1e-4, "tustin")   # a PI
    ctrl = Controller.from_lti(k, plant, name="ctrl")
    alpha, h_up, h_down = ctrl.voltage_model
    assert alpha == 1.0                                        # the float cannot tell R in from R out here
    files = ctrl.write(tmp_path)
    header = files["h"].read_text()
    data = json.loads(files["json"].read_text())
    block = data["anti_windup"]
    back = Controller.load(files["json"])
    mat = Controller.load(files["mat"])
    assert mat.series_resistor_out == back.series_resistor_out == (r_ohm == 0)       # the .mat carries it too
    fw_text = ctrl.firmware().describe()
    if r_ohm > 0:
        assert h_up == pytest.approx(r_ohm * pz.current_limit_source_a, rel=1e-12)     # R I, far below I T / C
        assert h_down == pytest.approx(r_ohm * pz.current_limit_sink_a, rel=1e-12)
        for text in (ctrl.describe(), back.describe(), fw_text):
            assert "series resistor out" not in text and "slew window" not in text, text
            assert "around a stack-voltage model" in text, text
        assert "series resistor out" not in block["description"] and "the series R" in block["description"]
        assert block["voltage_model"]["time_constant_s"] == pytest.approx(r_ohm * c_max, rel=1e-12)     # R C_max
        assert "slew_v_per_s" not in block["voltage_model"]
        assert "series resistor out" not in header and "the current (u - v) / R stays within" in header
        assert recorded_resistor_out(block) is False and back.series_resistor_out is False
    else:
        assert h_up == pytest.approx(pz.current_limit_source_a * 1e-4 / c_max, rel=1e-12)     # I T / C_max
        for text in (ctrl.describe(), back.describe(), fw_text):
            assert "slew window, series resistor out" in text, text
        assert "series resistor out" in block["description"] and "time_constant_s" not in block["voltage_model"]
        assert "series resistor out" in header and "(u - v) / R" not in header
        assert recorded_resistor_out(block) is True and back.series_resistor_out is True
    # a window given without a plant or a record is not called either
    bare = replace(ctrl, series_resistor_out=None)
    assert "series resistor out" not in bare.describe()


# ----------------------------------------------------------------------------- the sensor block

FUSED = ROOT / "controllers" / "sn637_fused_loopshape.json"

SENSOR_MAIN_C = r"""
#include <stdio.h>
#include <inttypes.h>
#include "ctrl.h"
int main(void)
{
    long n; long long u0, y0; ctrl_sensor_state st;
    if (scanf("%ld %lld %lld", &n, &u0, &y0) != 3) return 1;
    for (long i = 0; i < n; i++) {
        long long r, g, c; int64_t f;
        if (scanf("%lld %lld %lld", &r, &g, &c) != 3) return 1;
        if (i == 0) { ctrl_sensor_reset(&st, (int32_t)u0, (int32_t)g, (int32_t)c); st.y = (int64_t)y0; }
        int32_t u = ctrl_sensor_step(&st, (int32_t)r, (int32_t)g, (int32_t)c, &f);
        printf("%" PRId32 " %" PRId64 "\n", u, f);
    }
    printf("%" PRId64 "\n", st.y);
    return 0;
}
"""


def test_gauge_only_controller_has_no_sensor_block_and_its_files_are_unchanged(ctrl, tmp_path):
    # the committed gauge controller loads as before: no block, the header without a sensor step
    assert ctrl.sensor is None and ctrl.sensor_kind == "gauge" and "sensor" not in ctrl.to_dict()
    paths = ctrl.write(tmp_path)
    assert b"sensor_step" not in paths["h"].read_bytes()
    assert paths["h"].read_bytes() == COMMITTED.with_suffix(".h").read_bytes()


@pytest.mark.parametrize("kind, fc_hz", [("gauge", None), ("charge", None), ("fused", 0.89), ("fused", 37.0)])
def test_sensor_block_round_trips_json_and_mat(kind, fc_hz, tmp_path):
    c = Controller.load(FUSED).with_sensor(kind, fc_hz)
    paths = c.write(tmp_path, "ctrl")
    for p in (paths["json"], paths["mat"]):
        back = Controller.load(p)
        assert back.sensor == c.sensor and back.sensor_kind == kind
    # the cascade is untouched by the block
    np.testing.assert_array_equal(Controller.load(paths["json"]).fixed.b, c.fixed.b)


BAD_SENSOR = [
    ("kind", "strain", "sensor.kind"),
    ("crossover_hz", -1.0, "sensor.crossover_hz"),
    ("crossover_hz", float("nan"), "sensor.crossover_hz"),
    ("crossover_hz", 6000.0, "sensor"),                 # above the 5 kHz Nyquist frequency
    ("crossover_hz", 0.5, "sensor"),                    # k no longer the crossover quantized
    ("blend/k", 9400, "sensor"),
    ("blend/k", 9380.5, "sensor"),
    ("error_scale/q", 12345, "sensor"),
    ("v_per_m", 0.0, "sensor.v_per_m"),
    ("v_per_m", _DROP, "sensor.v_per_m"),
]


@pytest.mark.parametrize("path, value, key", BAD_SENSOR, ids=[f"{p}={v!r}" for p, v, _ in BAD_SENSOR])
def test_bad_sensor_blocks_name_the_file_and_key(path, value, key, tmp_path):
    data = Controller.load(FUSED).with_sensor("fused", 0.89).to_dict()
    assert data["sensor"]["blend"]["k"] == 9379
    _set(data["sensor"], path, value)
    f = tmp_path / "ctrl.json"
    f.write_text(json.dumps(data, allow_nan=True))
    with pytest.raises(ControllerError) as err:
        Controller.load(f)
    assert str(f) in str(err.value) and f"[{key}" in str(err.value), str(err.value)


def test_sensor_block_is_refused_on_a_float_only_controller():
    with pytest.raises(ControllerError, match=r"x.json: \[sensor\]"):
        Controller.from_dict({"sample_rate_hz": 1e4, "gain": 1.0, "sos": [[1, 0, 0, 1, -0.5, 0]],
                              "sensor": {"kind": "gauge", "v_per_m": 1e5}}, source="x.json")


@pytest.mark.parametrize("seed", range(4))
def test_fused_step_is_exactly_complementary_in_its_words(seed):
    """F_low + F_high = 1 in the firmware words: adding any sequence t to both readings adds t to the
    fused reading, count for count (the blend sees only g - c), and two agreeing sensors pass unchanged."""
    from workbench.export.sensor import run_sensor
    r = np.random.default_rng(seed)
    dt = 1.0 / r.choice([2e3, 1e4, 4e4])
    fc = float(np.exp(r.uniform(np.log(0.05), np.log(0.2 / dt))))
    c = Controller.load(FUSED).with_sensor("fused", fc)
    sb = replace(c.sensor, dt_s=dt, k=None)
    n = 4000
    g = r.integers(-2 ** 24, 2 ** 24, n)
    ch = g - r.integers(-2 ** 22, 2 ** 22) + r.integers(-3000, 3000, n)
    t = np.cumsum(r.integers(-10 ** 5, 10 ** 5, n))
    ref = np.zeros(n, np.int64)
    _, f1, y1 = run_sensor(sb, c.fixed, ref, g, ch)
    _, f2, y2 = run_sensor(sb, c.fixed, ref, g + t, ch + t)
    np.testing.assert_array_equal(f2 - f1, t)
    assert y1 == y2
    _, f3, _ = run_sensor(sb, c.fixed, ref, g, g)
    np.testing.assert_array_equal(f3, g)


@pytest.mark.parametrize("kind, fc_hz, seed", [("fused", 0.89, 1), ("fused", 150.0, 2), ("charge", None, 3),
                                               ("gauge", None, 4)])
def test_sensor_step_bit_for_bit_with_the_c_header(kind, fc_hz, seed, tmp_path):
    """NAME_sensor_step compiled with gcc (the sanitizer on when available) gives every output word, every
    fused reading and the final blend state of Controller.run_sensors, through the output limits."""
    import shutil
    import subprocess
    from workbench.export.sensor import run_sensor
    cc = shutil.which("gcc")
    if cc is None:
        pytest.skip("no gcc: the header cannot be compiled here")
    c = Controller.load(FUSED).with_sensor(kind, fc_hz)
    c.write(tmp_path, "ctrl")
    (tmp_path / "main.c").write_text(SENSOR_MAIN_C)
    base = [cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(tmp_path / "main"), str(tmp_path / "main.c")]
    for extra in (["-fsanitize=undefined", "-fno-sanitize-recover=all"], []):
        if subprocess.run(base + extra, capture_output=True, cwd=tmp_path).returncode == 0:
            break
    else:
        pytest.fail("the header does not compile")
    r = np.random.default_rng(seed)
    n = 30000
    sb = c.sensor
    x = 7e-6 + 6e-6 * np.sin(2 * np.pi * r.uniform(0.5, 5.0) * np.arange(n) * c.dt_s)
    ref = sb.counts(np.concatenate([np.full(n // 3, 7e-6), np.full(n // 3, 20e-6), np.full(n - 2 * (n // 3), -5e-6)]))
    g = sb.counts(x + r.standard_normal(n) * 22e-9)
    ch = sb.counts(x - r.uniform(-10e-6, 10e-6) + np.linspace(0, 50e-9, n) + r.standard_normal(n) * 0.3e-9)
    u0_v = 50.0
    u0_q = int(np.rint(u0_v * 2.0 ** c.fixed.output_frac_bits))
    y0 = int(r.integers(-2 ** 36, 2 ** 36))
    u_v, fused, y_end = run_sensor(sb, c.fixed, ref, g, ch, u0_v=u0_v, y0=y0)
    stdin = f"{n} {u0_q} {y0}\n" + "".join(f"{a} {b} {d}\n" for a, b, d in zip(ref, g, ch))
    out = subprocess.run([str(tmp_path / "main")], input=stdin, capture_output=True, text=True, check=True).stdout.split()
    vals = np.array(out, dtype=np.int64)
    u_q, f_c = vals[:-1:2], vals[1:-1:2]
    np.testing.assert_array_equal(u_q * 2.0 ** -c.fixed.output_frac_bits, u_v)
    np.testing.assert_array_equal(f_c, fused)
    if kind == "fused":
        assert int(vals[-1]) == y_end
    lo, hi = c.output_limits_v
    assert u_v.min() == lo and u_v.max() == hi          # the record drives both output limits
    # and Controller.run_sensors (metres in) is the same step
    u_m, f_m = c.run_sensors(ref * sb.lsb_m, g * sb.lsb_m, ch * sb.lsb_m, u0_v=u0_v, y0=y0)
    np.testing.assert_array_equal(u_m, u_v)


def test_a_mat_files_logical_or_complex_array_gets_matlab_advice():
    """Review 3 item 21: the JSON advice ("without quotes") is wrong for a .mat array."""
    from workbench.controller import ControllerError, _array
    for bad in (np.array([True, False]), np.array([1.0 + 2.0j, 0.0])):
        with pytest.raises(ControllerError, match="double array in MATLAB"):
            _array("k.mat", "A", bad, "a vector", 1)
    with pytest.raises(ControllerError, match="without quotes"):
        _array("k.json", "A", [1.0, "0.5"], "a vector", 1)


@pytest.mark.parametrize("frac_bits", [0, 7, 22, 29, 31])
def test_clamp_words_beyond_int32_are_refused_by_the_object_itself(ctrl, frac_bits):
    """The input and output clamp words are int32 in the firmware (INT32_C in the header): the object refuses
    any clamp whose word passes 2^31 - 1, whether built through the API or read from a file, and accepts the
    largest one that fits (its word exactly 2^31 - 1)."""
    fxp = ctrl.fixed
    top = 2 ** 31 - 1
    edge_v = top / 2.0 ** frac_bits                          # the largest clamp whose word fits
    over_v = 2.0 ** 31 / 2.0 ** frac_bits                    # one LSB more: the word 2^31
    ok = replace(fxp, input_frac_bits=frac_bits, input_range_v=edge_v)
    assert ok.input_limit == top
    with pytest.raises(ControllerError, match=r"\[fixed_point\.input\.range_v\].*outside \+/-\(2\^31 - 1\).*give a range below"):
        replace(fxp, input_frac_bits=frac_bits, input_range_v=over_v)
    sig = fxp.signal_frac_bits.copy()
    sig[-1] = frac_bits
    ok = replace(fxp, signal_frac_bits=sig, output_limits_v=(-edge_v, edge_v))
    assert ok.output_limits == (-top, top) and ok.limit_words[1] == top
    for lim in ((-over_v, 0.0), (0.0, over_v)):
        with pytest.raises(ControllerError, match=r"\[fixed_point\.output\.limits_v\].*outside \+/-\(2\^31 - 1\).*give limits of magnitude below"):
            replace(fxp, signal_frac_bits=sig.copy(), output_limits_v=lim)


@pytest.mark.parametrize("field, value, key", [
    ("input", {"range_v": 1e6}, "fixed_point.input.range_v"),
    ("output", {"limits_v": [-3e5, 3e5]}, "fixed_point.output.limits_v")])
def test_clamp_words_beyond_int32_in_a_file_name_the_file_and_field(data, tmp_path, field, value, key):
    bad = copy.deepcopy(data)
    bad["fixed_point"][field].update(value)
    path = tmp_path / "wide.json"
    path.write_text(json.dumps(bad), encoding="utf-8")
    with pytest.raises(ControllerError) as info:
        Controller.load(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: [{key}]") and "outside +/-(2^31 - 1)" in msg and "\n" not in msg


@pytest.mark.parametrize("frac_bits", [0, 7, 29, 31])
def test_the_clamp_messages_fix_is_accepted(ctrl, frac_bits):
    """The bound the message gives is the refused word's: a clamp just below it loads (the advice
    does not name a value that is itself refused, as '+/-4 V' for a refused 4 V once did)."""
    import re
    fxp = ctrl.fixed
    over_v = 2.0 ** 31 / 2.0 ** frac_bits
    with pytest.raises(ControllerError) as info:
        replace(fxp, input_frac_bits=frac_bits, input_range_v=over_v)
    bound = float(re.search(r"give a range below (\S+) V", str(info.value)).group(1))
    assert bound == over_v                                   # exact: a power of two
    ok = replace(fxp, input_frac_bits=frac_bits, input_range_v=np.nextafter(min(bound, over_v), 0.0))
    assert ok.input_limit <= 2 ** 31 - 1


@pytest.mark.parametrize("frac_bits", [-1, 32, 1100, -2000, 2.5])
def test_input_fraction_bits_outside_int32_are_refused(ctrl, frac_bits):
    """An input word's fraction bits outside 0..31 cannot be an int32 format (1100 raised an
    OverflowError traceback from 2.0 ** 1100; -2000 made the scale 0 and passed the clamp check)."""
    with pytest.raises(ControllerError, match=r"\[fixed_point\.input\.frac_bits\].*0\.\.31"):
        replace(ctrl.fixed, input_frac_bits=frac_bits)
