"""The three sensors' closed loops on the nonlinear plant: gauge, charge estimate, fused.

One compiled loop at the servo rate (:func:`workbench.verify.sensors.run_sensor_loop`, the loop
`workbench verify --sensor` runs): the PZT step (creep, hysteresis, the 80 ohm and the amplifier's
current limits), the gauge chain (per-period equivalent with its noise, firmware's metres), the
charge amplifier on the stack's terminals (leakage, bias current, dielectric absorption, ADC
noise; as :class:`~.charge_amp.ChargeAmpStream`), the stage-4 estimator (as
:class:`~.estimator.StreamingEstimator`) and its dynamic part E(z), and the exported controller's
fixed-point sensor step (:meth:`workbench.Controller.run_sensors`: for ``sensor="fused"`` the
complementary blend's fixed-point step, then the cascade with its output range and current-limit
window), whose output from reading k is applied in period k + 1.

Scenario (:func:`closed_loop_run`): open loop at ``bias_v`` for ``settle_s`` (the stack
charges, the integrator was reset at t = 0; by default until the reading's startup error has
settled, :func:`workbench.verify.sensors.startup_settle_s`), then the loop closes with its reference at the
reading of that moment; a triangle of ``triangle_periods`` periods at ``triangle_hz`` spanning
80 % of the stroke about that point (at 50 V on SN637: 7.8-87.8 % of it); then a hold of ``hold_s`` at the centre. Metrics on the true x:

- triangle RMS error over the periods after the first, relative to the position at closing (the
  reference plus the sensor's offset at closing, taken from the true x; the mean reported beside
  it), % of the quasi-static stroke (:func:`workbench.verify.scenarios.stroke_m`), as
  :mod:`workbench.verify.sensors` scores it;
- hold drift: mean true x over the last second of the hold minus over the first second
  after a 1 s settling, m;
- hold noise: RMS of the true x about its 1 s running mean during the hold, m.
"""

from pathlib import Path

import numpy as np

from ..errors import DataFileError

__all__ = ["triangle_reference", "closed_loop_run", "SENSORS", "FUSED_CONTROLLER", "fused_loop_response",
           "run_fused_study"]

SENSORS = ("gauge", "charge", "fused")


def triangle_reference(t_s, amplitude_m, freq_hz):
    """A triangle of peak ``amplitude_m`` about 0 starting at 0 going up, m (period 1 / freq_hz)."""
    ph = np.mod(np.asarray(t_s, float) * freq_hz + 0.25, 1.0)
    return amplitude_m * (4.0 * np.abs(ph - 0.5) - 1.0) * -1.0


def closed_loop_run(plant, ident, amp, e_d, controller, sensor="fused", blend=None, stroke_m=15e-6,
                    bias_v=50.0, settle_s=None, triangle_hz=0.1, triangle_periods=2, hold_s=10.0, seed=4,
                    progress=None):
    """Run one sensor's closed loop (see the module notes); returns metrics and the records.

    The loop is :func:`workbench.verify.sensors.run_sensor_loop` (compiled): the controller's
    fixed-point sensor step, blend included, with the streamed charge amplifier and estimator.

    Parameters
    ----------
    plant : Plant
    ident : Identified
        The estimator's identified parameters (stage 4 is run).
    amp : ChargeAmpParams
    e_d : discrete LTI
        The dynamic estimator E(z) at the servo period (``loop_analysis(...)["systems"]["E_d"]``).
    controller : workbench.Controller or path
        An exported controller (its fixed-point words run).
    sensor : {"gauge", "charge", "fused"}
    blend : Blend or FixedBlend, optional
        For ``sensor="fused"``: the crossover of the controller's sensor block (default: the block the
        controller already has).
    stroke_m : float
        Stroke the triangle's 80 % and the percentages refer to, m.
    hold_s : float
        Hold after the triangle, s (>= 3 s: 1 s settling and two 1 s windows).
    """
    from ..controller import Controller
    from ..verify.sensors import SensorSetup, run_sensor_loop

    if sensor not in SENSORS:
        raise ValueError(f"sensor must be one of {', '.join(SENSORS)}; got {sensor!r}")
    if not isinstance(controller, Controller):
        controller = Controller.load(controller)
    if sensor == "fused":
        if blend is not None:
            controller = controller.with_sensor("fused", float(getattr(blend, "blend", blend).crossover_hz))
        elif controller.sensor_kind != "fused":
            raise ValueError("sensor='fused' needs a Blend (or a controller with a fused sensor block)")
    if not hold_s >= 3.0:
        raise ValueError(f"hold_s must be at least 3 s; got {hold_s}")
    r = run_sensor_loop(SensorSetup(plant, ident, amp, e_d, {}), controller, sensor, bias_v=bias_v,
                        settle_s=settle_s, triangle_hz=triangle_hz, triangle_periods=triangle_periods, hold_s=hold_s,
                        stroke_m=stroke_m, seed=seed, progress=progress, sweep=False)
    out = {k: v for k, v in r.items() if not k.startswith("_")}
    out.update({"blend_fixed_point": sensor == "fused", "t_s": r["_t_s"], "x_m": r["_x_m"],
                "reading_m": r["_reading_m"], "reference_rel_m": r["_reference_rel_m"]})
    return out


FUSED_CONTROLLER = Path(__file__).resolve().parents[2] / "controllers" / "sn637_fused_loopshape.json"


def fused_loop_response(freq_hz, l_gauge, l_self, blend):
    """L_fused = F_low(z) L_gauge + F_high(z) L_self at ``freq_hz`` (discrete blend at ``blend.dt_s``)."""
    z = np.exp(2j * np.pi * np.asarray(freq_hz, float) * blend.dt_s)
    a = blend.pole
    f_low = (1 - a) * z / (z - a)
    return f_low * np.asarray(l_gauge) + (1 - f_low) * np.asarray(l_self)


def run_fused_study(plant_path, gauge_controller=None, fused_controller=None, amp=None, seed=2,
                    drift_duration_s=1000.0, triangle_hz=0.1, triangle_periods=2, hold_s=100.0, sensors=SENSORS,
                    progress=None, strict=False):
    """The fused-feedback study: spectra, the blend's crossover, the loops' margins, the three closed loops.

    Parameters
    ----------
    plant_path : path
        Plant TOML (e.g. plants/p888_51_sn637_creep.toml).
    gauge_controller, fused_controller : path, optional
        Controller JSONs: the gauge-only design (default controllers/sn637_loopshape.json) and
        the design on the fused signal (default controllers/sn637_fused_loopshape.json); the
        charge-only loop runs the fused design.
    drift_duration_s : float
        Length of the staircase record whose stage-4 error gives the charge's drift spectrum, s.
    triangle_hz, triangle_periods, hold_s : float, int, float
        Closed-loop scenario (:func:`closed_loop_run`).
    strict : bool, default False
        Both controllers are first compared with the plant (verify's preflight,
        :func:`~workbench.verify.run.check_controller_for_plant`): one exported for another plant
        warns (:class:`~workbench.errors.ControllerMismatchWarning`, and the JSON's ``warnings``), or
        with ``strict`` raises :class:`~workbench.errors.ControllerMismatchError` before any work.

    Returns
    -------
    dict
        JSON-ready results; ``_arrays`` holds the spectra and the closed-loop records for the figure.
    """
    from ..design.margins import loop_margins
    from ..controller import Controller
    from ..plant.files import load_plant
    from .blend_fixed import FixedBlend
    from .charge_amp import charge_amp_params
    from .fusion import (Blend, choose_crossover, drift_record, fused_error_variance, fused_noise_rms_per_sample,
                         fused_psd, sensor_spectra)
    from .identify import identify, simulate_identification
    from ..verify.scenarios import stroke_m as quasi_static_stroke
    from .run import DEFAULT_CONTROLLER, loop_analysis, noise_comparison

    gauge_controller = Path(DEFAULT_CONTROLLER if gauge_controller is None else gauge_controller)
    fused_controller = Path(FUSED_CONTROLLER if fused_controller is None else fused_controller)
    for pth in (gauge_controller, fused_controller):
        if not pth.is_file():
            raise DataFileError(f"{pth}: no such controller JSON; give --controller / --fused-controller, e.g. "
                                f"controllers/sn637_loopshape.json and controllers/sn637_fused_loopshape.json")
    say = progress or (lambda stage: None)
    plant = load_plant(plant_path)
    from ..verify.run import check_controller_for_plant
    warnings = []
    for flag, pth in (("--controller", gauge_controller), ("--fused-controller", fused_controller)):
        bad = check_controller_for_plant(plant, Controller.load(pth, plant=plant), strict=strict)
        warnings += [f"preflight ({flag} {pth.name}) {p['check']}: {p['message']}" for p in bad]
    amp = charge_amp_params(plant) if amp is None else amp
    dt = plant.gauge.period_s
    say("identification record")
    idrec = simulate_identification(plant.pzt, amp, hold_s=700.0, seed=seed + 100, dt_s=dt)
    ident = identify(idrec, amp)
    say("drift record")
    t_d, e_d_m, _ = drift_record(plant, amp, ident, duration_s=drift_duration_s, dt_s=dt, seed=seed)
    # one stroke for every percentage, as verify divides by: rest to 100 V, quasi-static (not the
    # staircase's p-p, which includes its creep)
    stroke = quasi_static_stroke(plant.pzt)
    say("noise")
    noise = noise_comparison(plant, ident, amp, seed=seed, dt_s=dt)
    spectra = sensor_spectra(noise["gauge_rms_m"], noise["self_rms_m"], dt, t_d, e_d_m)
    fc = choose_crossover(spectra)
    blend = Blend(fc, dt)
    grid = np.geomspace(spectra.freq_hz[0], 0.05 / dt, 120)
    j_rms = np.sqrt([fused_error_variance(spectra, f) for f in grid])
    say("loops")
    la_g = loop_analysis(plant, ident, amp, gauge_controller)
    la_f = loop_analysis(plant, ident, amp, fused_controller)
    f = la_f["freq_hz"]
    m_fused = loop_margins(f, fused_loop_response(f, la_f["l_gauge"], la_f["l_self"], blend)).as_dict()
    margins = {"gauge": la_g["margins_gauge"], "charge": la_f["margins_self_sensed"], "fused": m_fused}
    c_g = Controller.load(gauge_controller)
    c_f = Controller.load(fused_controller)
    e_dyn = la_g["systems"]["E_d"]
    rows, arrays = [], {}
    for s in sensors:
        say(f"closed loop: {s}")
        r = closed_loop_run(plant, ident, amp, e_dyn, c_g if s == "gauge" else c_f, sensor=s, blend=FixedBlend(blend),
                            stroke_m=stroke, triangle_hz=triangle_hz, triangle_periods=triangle_periods,
                            hold_s=hold_s, seed=seed + 2)
        arrays[s] = {k: v for k, v in r.items() if isinstance(v, np.ndarray)}
        rows.append({**{k: v for k, v in r.items() if not isinstance(v, np.ndarray)},
                     "controller": str(gauge_controller if s == "gauge" else fused_controller),
                     "margins": margins[s]})
    by = {r["sensor"]: r for r in rows}
    fused_row = by.get("fused")
    data = {
        "plant": str(plant_path), "sample_hz": 1.0 / dt, "stroke_m": stroke, "warnings": warnings,
        "noise_per_sample_m": {"gauge": noise["gauge_rms_m"], "charge": noise["self_rms_m"],
                               "fused_white_equivalent": fused_noise_rms_per_sample(spectra, fc)},
        "blend": {"crossover_hz": fc, "pole": blend.pole,
                  "form": "fused = charge + (1 - a)/(1 - a z^-1) (gauge - charge)",
                  "fused_error_rms_m": float(np.sqrt(fused_error_variance(spectra, fc))),
                  "gauge_error_rms_m": float(np.sqrt(np.trapezoid(spectra.gauge_m2_per_hz, spectra.freq_hz))),
                  "charge_error_rms_m": float(np.sqrt(np.trapezoid(spectra.charge_m2_per_hz, spectra.freq_hz))),
                  "band_hz": [float(spectra.freq_hz[0]), float(spectra.freq_hz[-1])],
                  "drift_record_s": float(t_d[-1]), "drift_record_pp_m": float(np.ptp(e_d_m))},
        "closed_loops": rows,
        "targets": {"triangle_rms_percent_stroke": 0.01, "hold_drift_m": 1e-9, "hold_s_target": 1000.0},
    }
    if fused_row is not None:
        data["targets_met"] = {
            "triangle": bool(fused_row["triangle_rms_percent_stroke"] <= 0.01),
            "hold_drift": bool(abs(fused_row["hold_drift_m"]) <= 1e-9),
            "margins": bool(m_fused["phase_margin_deg"] >= 45 and m_fused["gain_margin_db"] >= 6)}
    data["_arrays"] = {"freq_hz": spectra.freq_hz, "s_gauge": spectra.gauge_m2_per_hz,
                       "s_charge": spectra.charge_m2_per_hz, "s_fused": fused_psd(spectra, fc),
                       "grid_hz": grid, "j_rms_m": j_rms, "closed": arrays}
    return data
