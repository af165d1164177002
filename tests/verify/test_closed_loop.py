"""The exported controller in closed loop with the nonlinear plant: the issue-5 targets and the firmware form."""

import json

import numpy as np
import pytest

from workbench.export import run_fixed

from ..conftest import FULL
from workbench.verify.closed_loop import ClosedLoop, controller_from_json
from workbench.verify.scenarios import run_scenario


@pytest.fixture(scope="module")
def data(root):
    return json.loads((root / "controllers" / "sn637_loopshape.json").read_text())


@pytest.fixture(scope="module")
def ctrl(data):
    return controller_from_json(data)


def test_the_default_export_runs_as_the_fixed_point_step(ctrl):
    assert ctrl.form == "fixed" and ctrl.voltage_model is not None


def test_the_loop_runs_the_exported_step_bit_for_bit(sn637_creep, ctrl):
    # replay the errors the closed loop saw through run_fixed (the C header's step, bit for bit):
    # the commands must be the same words
    cl = ClosedLoop(sn637_creep, ctrl, noise=True, seed=3)
    cl.reset(u0=50.0)
    r = cl.run(np.linspace(-0.1, 0.1, 3000))
    u = run_fixed(ctrl.fixed, r.error_v, u0_v=50.0)
    # the loop applies output k at period k + 1; r.u_v[k] is what period k applied
    np.testing.assert_array_equal(u[:-1], r.u_v[1:])


def test_small_step_matches_the_linear_prediction(sn637_creep, ctrl):
    # the issue allows 3 points between the nonlinear overshoot and the linear prediction; with
    # noise the comparison is made on the same step without gauge noise
    m, _ = run_scenario(sn637_creep, ctrl, "small_step", noise=True)
    assert abs(m["overshoot_difference_points"]) <= 3.0
    assert abs(m["final_error_m"]) < 2e-8 and m["settling_noise_free_s"] < 0.05


def test_large_step_anti_windup_prevents_the_limit_cycle(sn637_creep, ctrl):
    with_aw, _ = run_scenario(sn637_creep, ctrl, "large_step", noise=False)
    without, _ = run_scenario(sn637_creep, ctrl, "large_step", noise=False, anti_windup=False)
    # the current limit slews the stack at ~170 V/s; the plain controller winds up and oscillates
    assert without["time_at_current_limit_s"] > 0.1 and without["oscillation_m"] > 1e-7
    assert with_aw["oscillation_m"] < 1e-8 and with_aw["overshoot_percent"] < 1.0
    assert abs(with_aw["final_error_m"]) < 1e-9 and with_aw["settling_s"] < 0.3


def test_slow_triangle_tracks_through_the_hysteresis_with_gauge_noise(sn637_creep, ctrl):
    m, _ = run_scenario(sn637_creep, ctrl, "triangle_0p1hz", noise=True)
    assert m["error_rms_percent_of_stroke"] < 0.1                    # the seed: 0.1 % with gauge feedback
    assert m["hysteresis_open_loop_percent"] > 5 > 0.2 > m["hysteresis_closed_loop_percent"]


def test_hold_drift(sn637_creep, ctrl):
    # 100 s here (make test-full: the 1000 s); the issue allows 1 nm; no limit cycle either
    m, _ = run_scenario(sn637_creep, ctrl, "hold", hold_s=1000.0 if FULL else 100.0)
    assert abs(m["drift_m"]) < 1e-9 < abs(m["open_loop_creep_m"])
    assert not m["oscillating"]


def test_force_step_is_rejected(sn637_creep, ctrl):
    m, _ = run_scenario(sn637_creep, ctrl, "force_step", noise=False)
    assert abs(m["final_deviation_m"]) < 1e-9 < abs(m["open_loop_deflection_m"])


def test_sine_sweep_agrees_with_the_linear_loop_below_the_slew_limit(sn637_creep, ctrl):
    m, _ = run_scenario(sn637_creep, ctrl, "sine_sweep", noise=True)
    f = np.asarray(m["freq_hz"])
    diff_db = np.abs(np.asarray(m["measured_db"]) - np.asarray(m["linear_db"]))
    diff_deg = np.abs(np.asarray(m["measured_phase_deg"]) - np.asarray(m["linear_phase_deg"]))
    low = f <= 200
    assert diff_db[low].max() < 1.0 and diff_deg[low].max() < 10.0
    assert abs(m["bandwidth_hz"] / m["linear_bandwidth_hz"] - 1) < 0.2


def test_unknown_scenario(sn637_creep, ctrl):
    with pytest.raises(ValueError, match="unknown scenario"):
        run_scenario(sn637_creep, ctrl, "cartwheel")


@pytest.mark.parametrize("line_v, found", [(0.05, True), (0.0, False)])
def test_the_oscillation_detector_finds_a_line_in_noise_and_nothing_in_noise_alone(line_v, found):
    from workbench.verify.scenarios import _oscillation
    t = np.arange(10000) * 1e-4
    for seed in range(5):
        u = 0.01 * np.random.default_rng(seed).standard_normal(t.size) + line_v * np.sin(2 * np.pi * 137 * t) + 3 * t
        amp, freq, line = _oscillation(u, 1e-4, line_ratio=20.0)
        assert line == found
        if found:
            assert freq == 137.0 and amp == pytest.approx(line_v, rel=0.05)


def test_a_hanus_json_runs_the_same_loop_as_the_float_cascade(sn637_creep, data, ctrl):
    # the Hanus realization written by HanusController.as_dict is read back by --form hanus: where
    # nothing limits it is the float cascade's controller exactly. In the window the two differ: the
    # Hanus form conditions every state, so while limited it runs the controller's zeros, and the
    # Tustin roll-off puts two at z = -1; the 5 um step then does not settle in 0.5 s, while the
    # exported cascade (only the integrator section conditioned) does. Why the export is the cascade.
    from workbench.design.antiwindup import hanus
    h = hanus(ctrl.linear(), ctrl.output_limits_v, (np.inf, np.inf))
    hanus_json = {**data, "anti_windup": h.as_dict(ctrl.voltage_model)}
    hanus_json.pop("fixed_point")
    forms = {form: controller_from_json(src, form) for form, src in (("hanus", hanus_json), ("float", data))}
    assert forms["hanus"].voltage_model == pytest.approx(ctrl.voltage_model)
    from workbench.verify.scenarios import _to_volts
    pzt = sn637_creep.pzt
    rest_v = float(_to_volts(pzt.k_q2x_m_per_c * pzt.hysteresis.output_at_rest(), sn637_creep.gauge))
    # ~10 nm at 50 Hz about the rest position (at 0 V, the controller at rest): no limit acts
    ref = rest_v + 0.003 * np.sin(2 * np.pi * 50 * np.arange(4000) * 1e-4)
    x = {}
    for form, c in forms.items():
        cl = ClosedLoop(sn637_creep, c, noise=False)
        r = cl.run(ref)
        assert r.samples_rate_limited == 0
        x[form] = r.u_v
    np.testing.assert_allclose(x["hanus"], x["float"], rtol=0, atol=1e-7)   # two realizations: rounding only
    steps = {form: run_scenario(sn637_creep, c, "large_step", noise=False)[0] for form, c in forms.items()}
    assert steps["float"]["settling_s"] < 0.3 and steps["float"]["overshoot_percent"] < 1.0
    assert not steps["hanus"]["settling_s"] < 0.5


# ---------------------------------------------------------------- firmware's lead and gauge linearization
# A controller's sensor block may carry the reference lead 1/K_v and the bridge curvature beta
# (verify/sensors.py: firmware_startup); the gauge scenarios then run them as the sensor loop does.

def _with_block(c, **fields):
    from dataclasses import replace
    c = c if c.sensor is not None else c.with_sensor("gauge")
    return replace(c, sensor=replace(c.sensor, **fields))


def test_a_block_with_no_lead_and_no_curvature_runs_as_the_bare_controller_bit_for_bit(root, sn637_creep):
    from workbench.controller import Controller
    c = Controller.load(root / "controllers" / "sn637_loopshape.json", plant=sn637_creep)
    zero = _with_block(c, ref_lead_s=0.0, gauge_curvature_per_m=0.0)
    assert c.sensor is None and zero.firmware().ref_lead_s == 0.0 == zero.firmware().gauge_curvature_per_m
    for name in ("triangle_0p1hz", "small_step"):
        a, ta = run_scenario(sn637_creep, c.firmware(), name, seed=4)
        b, tb = run_scenario(sn637_creep, zero.firmware(), name, seed=4)
        for key in ("x_m", "u_v", "i_a"):
            np.testing.assert_array_equal(ta[key], tb[key], err_msg=f"{name} {key}")


@pytest.mark.parametrize("path", ["sn637_loopshape.json", "sn637_fused_loopshape.json"])
def test_the_lead_moves_the_type_1_loops_ramp_error_by_slope_times_lead(root, sn637_creep, path):
    """Noise off, the 0.1 Hz triangle over 80 % of the stroke (slope v = 0.8 stroke 2 f). A type-1 loop lags a
    ramp by v / K_v: half the difference of the mean error x - r on the rising and the falling ramps is
    -v / K_v, and a reference led by L moves it by v L (closed form, any L). Two designs (K_v ~620 and
    ~2460 1/s), leads 0.5-2 / K_v: the shift within 3 % of v L, and at L = 1/K_v the lag is gone to 10 %."""
    from workbench.controller import Controller
    from workbench.verify.sensors import velocity_constant_per_s
    c = Controller.load(root / "controllers" / path, plant=sn637_creep)
    c = c.with_sensor("gauge", v_per_m=None if c.sensor is None else c.sensor.v_per_m)
    kv = velocity_constant_per_s(c, c.sensor, sn637_creep)

    def lag(lead_s):
        m, tr = run_scenario(sn637_creep, _with_block(c, ref_lead_s=lead_s).firmware(), "triangle_0p1hz",
                             noise=False)
        e, slope = (tr["x_m"] - tr["ref_m"])[tr["scored"]], np.gradient(tr["ref_m"])[tr["scored"]]
        return 0.5 * (np.mean(e[slope > 0]) - np.mean(e[slope < 0])), 0.8 * m["stroke_m"] * 2 * 0.1

    base, v = lag(0.0)
    assert base == pytest.approx(-v / kv, rel=0.1)
    for mult in (0.5, 1.0, 2.0):
        led, _ = lag(mult / kv)
        assert led - base == pytest.approx(v * mult / kv, rel=0.03), mult
        if mult == 1.0:
            assert abs(led) < 0.1 * v / kv


def test_the_gauge_scenarios_take_the_bridge_curvature_out_with_the_right_sign(root, sn637_creep):
    """Noise off, a 0.5 Hz triangle over 80 % of the stroke about mid-stroke: each reading is the bridge at
    the period's midpoint, quantized by the servo DAC. In metres (firmware's calibration), the reading of a
    controller without curvature is x + beta u^2 (eq. 27, u = x - x_c); with the block's beta it is x, each
    within half a DAC step plus 1 % of the curvature (the arm imbalance's share). The sensor loop's test in
    test_sensors.py holds the same for its conversion: the two harnesses read the gauge alike."""
    from workbench.controller import Controller
    from workbench.plant.gauge import TRIM_CENTER_M, bridge_curvature_per_m
    from workbench.verify.scenarios import X_START_M, stroke_m
    g = sn637_creep.gauge
    beta = bridge_curvature_per_m(g)
    cal = g.calibration_m_per_v
    lsb = 2.0 * g.dac_range_v / 2.0 ** g.dac_bits * abs(cal)
    c = Controller.load(root / "controllers" / "sn637_loopshape.json", plant=sn637_creep)
    dt = c.dt_s
    t = np.arange(int(round(2 / 0.5 / dt))) * dt
    tri = X_START_M + 0.4 * stroke_m(sn637_creep.pzt) * (4 * np.abs((t * 0.5 + 0.25) % 1.0 - 0.5) - 1)
    for lin in (False, True):
        fw = (_with_block(c, gauge_curvature_per_m=beta) if lin else c).firmware()
        assert fw.gauge_curvature_per_m == (beta if lin else 0.0)
        cl = ClosedLoop(sn637_creep, fw, noise=False)
        cl.reset(u0=50.0)
        cl.run((np.full(int(1.0 / dt), tri[0]) - TRIM_CENTER_M) / cal)
        r = cl.run((tri - TRIM_CENTER_M) / cal)
        x_mid = 0.5 * (r.x_m[1:] + r.x_m[:-1])
        curv = beta * (x_mid - TRIM_CENTER_M) ** 2
        assert np.ptp(x_mid) > 0.75 * stroke_m(sn637_creep.pzt) and np.max(np.abs(curv)) > 3 * lsb
        left = r.reading_v[1:] * cal + TRIM_CENTER_M - x_mid - (0.0 if lin else curv)
        assert np.max(np.abs(left)) <= 0.5 * lsb + 0.01 * np.max(np.abs(curv)) + 2e-12


def test_the_lead_is_velocity_feedforward_on_planned_ramps_only(root, sn637_creep):
    """The lead goes on the planned slope: on a ramp r_k = a + v k T the fed reference is r + v L exactly, on a
    hold it is r. The steps are fed as given (a block carrying L = 1/K_v runs the small step bit for bit as the
    bare controller, and its metrics carry no ref_lead_s); the triangles report the lead they were fed."""
    from workbench.controller import Controller
    from workbench.verify.scenarios import planned_slope_lead
    from workbench.verify.sensors import velocity_constant_per_s
    dt, lead = 1e-4, 1.5e-3
    for v in (-3e-4, 2e-6, 0.16):                     # m/s, from slow creep-like ramps to the 1 Hz triangle's
        r = 7e-6 + v * np.arange(101) * dt
        np.testing.assert_allclose(planned_slope_lead(r, dt, lead), r[:-1] + v * lead, rtol=0, atol=1e-15)
    hold = np.full(11, 3e-6)
    np.testing.assert_array_equal(planned_slope_lead(hold, dt, lead), hold[:-1])
    c = Controller.load(root / "controllers" / "sn637_loopshape.json", plant=sn637_creep)
    led = _with_block(c, ref_lead_s=1.0 / velocity_constant_per_s(c, c.with_sensor("gauge").sensor, sn637_creep))
    a, ta = run_scenario(sn637_creep, c.firmware(), "small_step", seed=4)
    b, tb = run_scenario(sn637_creep, led.firmware(), "small_step", seed=4)
    for key in ("x_m", "u_v", "i_a"):
        np.testing.assert_array_equal(ta[key], tb[key], err_msg=key)
    assert "ref_lead_s" not in b
    m, _ = run_scenario(sn637_creep, led.firmware(), "triangle_1hz", noise=False)
    assert m["ref_lead_s"] == led.sensor.ref_lead_s


@pytest.mark.parametrize("seed", range(4))
def test_triangle_reference_is_the_closed_form_triangle(seed):
    # drawn spans (firmware volts or metres), frequencies and servo periods over the range a user may bring
    from workbench.verify.scenarios import triangle_reference
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-1e-5, 1e-5)
    hi = lo + 10 ** rng.uniform(-9, -4)
    f = 10 ** rng.uniform(-1, 1)
    dt = 10 ** rng.uniform(-5, -3.5)
    periods = int(rng.integers(1, 4))
    t, r = triangle_reference(lo, hi, f, periods, dt)
    n = int(periods / f / dt)
    assert t.shape == r.shape == (n + 1,) and t[0] == 0.0 and np.all(np.diff(t) > 0)
    tol = 1e-12 * (abs(lo) + abs(hi))
    assert r[0] == pytest.approx((lo + hi) / 2, abs=tol)                      # mid-span first
    assert r.min() >= lo - tol and r.max() <= hi + tol
    # the closed form: distance from mid-span falls with slope 2 (hi - lo) f, ends at 1/(4f), 3/(4f)
    phase = (t * f) % 1.0
    first = (phase < 0.25) & (t < 1 / f)
    np.testing.assert_allclose(r[first], (lo + hi) / 2 - 2 * (hi - lo) * f * t[first], atol=tol + 1e-9 * (hi - lo))
    rising = (phase > 0.25) & (phase < 0.75)
    np.testing.assert_allclose(r[rising], lo + 2 * (hi - lo) * (phase[rising] - 0.25), atol=tol + 1e-9 * (hi - lo))
    falling = phase > 0.75                                   # from hi back to mid-span, every period
    np.testing.assert_allclose(r[falling], hi - 2 * (hi - lo) * (phase[falling] - 0.75), atol=tol + 1e-9 * (hi - lo))
    later = (phase < 0.25) & (t >= 1 / f)                     # the periods after the first start at mid-span too
    np.testing.assert_allclose(r[later], (lo + hi) / 2 - 2 * (hi - lo) * f * (t[later] % (1 / f)),
                               atol=tol + 1e-8 * (hi - lo))


def test_the_sweeps_triangle_is_verifys(root, monkeypatch):
    # one home: workbench sweep's closed-loop triangle is scenarios.triangle_reference over the case's span at 0.1 Hz
    from workbench.verify import scenarios
    from workbench.verify.sweep_job import run_case
    calls = []
    real = scenarios.triangle_reference

    def spy(*args):
        calls.append(args)
        return real(*args)

    monkeypatch.setattr(scenarios, "triangle_reference", spy)
    row = run_case({"plant": str(root / "plants" / "p888_51_sn637.toml"), "cp_factor": 1.0, "amplitude_v": 2.0,
                    "controller": str(root / "controllers" / "sn637_loopshape.json"), "bias_v": 50.0,
                    "noise": False, "freq_hz": (1.0, 4990.0, 10)})
    assert len(calls) == 1
    lo, hi, f, periods, dt = calls[0]
    assert f == 0.1 and periods == 2 and hi - lo == pytest.approx(row["triangle_span_m"], rel=1e-12)
    assert (lo + hi) / 2 == pytest.approx(scenarios.X_START_M, rel=1e-12)


def test_the_compiled_loop_takes_one_signature_whatever_the_callers_arrays(sn637_creep, data, ctrl):
    """numba compiles ``_loop`` anew (~7 s CPU) for every distinct argument type, and an array's type carries its
    writeable flag: a reference array, a read-only broadcast of one, a list, a constant, a read-only force, with the
    fixed-point and the float cascade (whose unused fixed-point arrays are placeholders), reach the loop as one
    signature (main compiled it 4 times in this file from an empty cache, 5 in the suite)."""
    from workbench.verify import closed_loop
    ref = np.linspace(0.0, 0.05, 200)
    runs = [((ref,), {}), ((np.broadcast_to(ref, ref.shape),), {}), ((list(ref),), {}), ((0.02,), {"periods": 200}),
            ((ref,), {"force_n": np.broadcast_to(0.1, ref.shape)})]
    for c in (ctrl, controller_from_json(data, "float")):
        for args, kw in runs:
            ClosedLoop(sn637_creep, c, noise=True, seed=1).run(*args, **kw)
    assert len(closed_loop._loop.signatures) == 1, closed_loop._loop.signatures
