"""The three sensors' closed loops on the nonlinear plant: gauge, charge estimate, fused.

One sample at a time at the servo rate: the compiled PZT step (creep, hysteresis, the 80 ohm
and the amplifier's current limits), the charge amplifier on the stack's terminals
(:class:`~.charge_amp.ChargeAmpStream`: leakage, bias current, dielectric absorption, ADC
noise), the stage-4 estimator (:class:`~.estimator.StreamingEstimator`) and its dynamic part
E(z), the gauge chain (per-period equivalent, noise-free, plus its white noise of
``gauge.noise_rms_m`` per reading from an independent generator), and for ``sensor="fused"``
the complementary blend (:class:`~.fusion.Blend`). A linear controller (the exported
controller's linear part, no output window) computes from reading k the output applied in
period k + 1, added to the bias.

Scenario (:func:`closed_loop_run`): open loop at ``bias_v`` for ``settle_s`` (the stack
charges, the integrator was reset at t = 0), then the loop closes with its reference at the
reading of that moment; a triangle of ``triangle_periods`` periods at ``triangle_hz`` spanning
10-90 % of the stroke around it; then a hold of ``hold_s`` at the centre. Metrics on the true x:

- triangle RMS error over the periods after the first, its mean removed (the reference is
  relative to the reading at closing, so a constant offset is a choice of origin), % of stroke;
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
                    bias_v=50.0, settle_s=1.0, triangle_hz=0.1, triangle_periods=2, hold_s=10.0, seed=4,
                    progress=None):
    """Run one sensor's closed loop (see the module notes); returns metrics and the records.

    Parameters
    ----------
    plant : Plant
    ident : Identified
        The estimator's identified parameters (stage 4 is run).
    amp : ChargeAmpParams
    e_d : discrete LTI
        The dynamic estimator E(z) at the servo period (``loop_analysis(...)["systems"]["E_d"]``).
    controller : FirmwareController
        Its ``linear()`` discrete system is run; input firmware V (the gauge chain's gain), output V.
    sensor : {"gauge", "charge", "fused"}
    blend : Blend or FixedBlend
        Needed for ``sensor="fused"``; a :class:`~.blend_fixed.FixedBlend` runs the firmware's
        fixed-point step.
    stroke_m : float
        Stroke the triangle's 10-90 % refers to, m.
    hold_s : float
        Hold after the triangle, s (>= 3 s: 1 s settling and two 1 s windows).
    """
    import control

    from ..linearize.sampled import gauge_gain_v_per_m
    from ..plant import kernels as K
    from ..plant.gauge import displacement_from_reading, gauge_run_equivalent
    from ..plant.simulator import PZTSimulator
    from .charge_amp import ChargeAmpStream
    from .estimator import StreamingEstimator
    from .run import STAGES

    if sensor not in SENSORS:
        raise ValueError(f"sensor must be one of {', '.join(SENSORS)}; got {sensor!r}")
    if sensor == "fused" and blend is None:
        raise ValueError("sensor='fused' needs a Blend")
    if not hold_s >= 3.0:
        raise ValueError(f"hold_s must be at least 3 s; got {hold_s}")
    c = control.ss(controller.linear())
    dt = float(c.dt)
    ca, cb, cc, cd = (np.asarray(m_, float) for m_ in (c.A, c.B, c.C, c.D))
    ed = control.ss(e_d)
    ea, eb, ec, edd = (np.asarray(m_, float) for m_ in (ed.A, ed.B, ed.C, ed.D))
    k_fw = gauge_gain_v_per_m(7.5e-6, plant.gauge)
    sigma_g = float(plant.gauge.noise_rms_m)
    from .blend_fixed import FixedBlend
    fixed = blend if isinstance(blend, FixedBlend) else None
    a_bl = (fixed.blend if fixed else blend).pole if blend is not None else 0.0
    n_settle = int(round(settle_s / dt))
    n_tri = int(round(triangle_periods / triangle_hz / dt))
    n_hold = int(round(hold_s / dt))
    n = n_tri + n_hold
    amp_tri = 0.4 * stroke_m
    t = np.arange(1, n + 1) * dt
    r_rel = np.where(np.arange(n) < n_tri, triangle_reference(t, amp_tri, triangle_hz), 0.0)

    sim = PZTSimulator(plant.pzt, dt)
    step, m, st = sim.step_function()
    out = np.empty(K.N_OUT)
    amp_s, est = ChargeAmpStream(amp, dt, seed), StreamingEstimator(ident.stage(STAGES[-1]), dt)
    rng = np.random.default_rng(seed + 1000)
    g_noise = rng.standard_normal(n_settle + n) * sigma_g
    xe, xc = np.zeros(ea.shape[0]), np.zeros(ca.shape[0])
    x_prev, y_bl, y = 0.0, None, 0.0
    xs, rd = np.empty(n), np.empty(n)
    ref0 = 0.0
    for k in range(n_settle + n):
        j = k - n_settle
        u = bias_v + (y if j >= 0 else 0.0)
        step(m, st, u, 0.0, out)
        gr = gauge_run_equivalent(np.array([out[0]]), plant.gauge, x_prev_m=x_prev, noise=False)
        x_prev = out[0]
        gauge = float(displacement_from_reading(gr.demod_v, plant.gauge)[0]) + g_noise[k]
        if sensor != "gauge":
            d_s = est.update(*amp_s.update(out[1], out[5]))
            charge = float(ec[0] @ xe + edd[0, 0] * d_s)
            xe = ea @ xe + eb[:, 0] * d_s
        if sensor == "gauge":
            reading = gauge
        elif sensor == "charge":
            reading = charge
        else:
            if fixed is not None:        # the firmware's fixed-point blend, on counts of fixed.lsb_m
                gq, cq = int(round(gauge / fixed.lsb_m)), int(round(charge / fixed.lsb_m))
                if y_bl is None:
                    y_bl = (gq - cq) << int(fixed.frac_bits)
                y_bl, fq = fixed.step(y_bl, gq, cq)
                reading = fq * fixed.lsb_m
            else:
                diff = gauge - charge
                y_bl = diff if y_bl is None else a_bl * y_bl + (1.0 - a_bl) * diff
                reading = charge + y_bl
        if j == -1:
            ref0 = reading
        if j >= 0:
            err = k_fw * (ref0 + r_rel[j] - reading)
            y = float(cc[0] @ xc + cd[0, 0] * err)
            xc = ca @ xc + cb[:, 0] * err
            xs[j], rd[j] = out[0], reading
        if progress and k % 10000 == 0:
            progress(k, n_settle + n)
    # metrics on the true x
    per = int(round(1.0 / triangle_hz / dt))
    w = slice(per, n_tri)
    e_tri = xs[w] - r_rel[w]
    e_tri = e_tri - np.mean(e_tri)
    one = int(round(1.0 / dt))
    h0 = n_tri + one
    hold_x = xs[n_tri:]
    drift = float(np.mean(xs[n - one:]) - np.mean(xs[h0:h0 + one]))
    run_mean = np.convolve(hold_x, np.ones(one) / one, mode="valid")
    noise = float(np.std(hold_x[one - 1:] - run_mean))
    return {"sensor": sensor, "triangle_rms_m": float(np.sqrt(np.mean(e_tri ** 2))),
            "triangle_rms_percent_stroke": float(100 * np.sqrt(np.mean(e_tri ** 2)) / stroke_m),
            "hold_s": float(hold_s), "hold_drift_m": drift, "hold_noise_rms_m": noise, "stroke_m": float(stroke_m),
            "blend_crossover_hz": None if blend is None else float(getattr(blend, "blend", blend).crossover_hz),
            "blend_fixed_point": fixed is not None,
            "t_s": t, "x_m": xs, "reading_m": rd, "reference_rel_m": r_rel}


FUSED_CONTROLLER = Path(__file__).resolve().parents[2] / "controllers" / "sn637_fused_loopshape.json"


def fused_loop_response(freq_hz, l_gauge, l_self, blend):
    """L_fused = F_low(z) L_gauge + F_high(z) L_self at ``freq_hz`` (discrete blend at ``blend.dt_s``)."""
    z = np.exp(2j * np.pi * np.asarray(freq_hz, float) * blend.dt_s)
    a = blend.pole
    f_low = (1 - a) * z / (z - a)
    return f_low * np.asarray(l_gauge) + (1 - f_low) * np.asarray(l_self)


def run_fused_study(plant_path, gauge_controller=None, fused_controller=None, amp=None, seed=2,
                    drift_duration_s=1000.0, triangle_hz=0.1, triangle_periods=2, hold_s=100.0, sensors=SENSORS,
                    progress=None):
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

    Returns
    -------
    dict
        JSON-ready results; ``_arrays`` holds the spectra and the closed-loop records for the figure.
    """
    from ..design.margins import loop_margins
    from ..plant.files import load_plant
    from ..verify.run import load_controller_json
    from .blend_fixed import FixedBlend
    from .charge_amp import ChargeAmpParams
    from .fusion import (Blend, choose_crossover, drift_record, fused_error_variance, fused_noise_rms_per_sample,
                         fused_psd, sensor_spectra)
    from .identify import identify, simulate_identification
    from .run import DEFAULT_CONTROLLER, loop_analysis, noise_comparison

    amp = ChargeAmpParams() if amp is None else amp
    gauge_controller = Path(DEFAULT_CONTROLLER if gauge_controller is None else gauge_controller)
    fused_controller = Path(FUSED_CONTROLLER if fused_controller is None else fused_controller)
    for pth in (gauge_controller, fused_controller):
        if not pth.is_file():
            raise DataFileError(f"{pth}: no such controller JSON; give --controller / --fused-controller, e.g. "
                                f"controllers/sn637_loopshape.json and controllers/sn637_fused_loopshape.json")
    say = progress or (lambda stage: None)
    plant = load_plant(plant_path)
    dt = plant.gauge.period_s
    say("identification record")
    idrec = simulate_identification(plant.pzt, amp, hold_s=700.0, seed=seed + 100, dt_s=dt)
    ident = identify(idrec, amp)
    say("drift record")
    t_d, e_d_m, stroke = drift_record(plant, amp, ident, duration_s=drift_duration_s, dt_s=dt, seed=seed)
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
    _, c_g = load_controller_json(gauge_controller)
    _, c_f = load_controller_json(fused_controller)
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
        "plant": str(plant_path), "sample_hz": 1.0 / dt, "stroke_m": stroke,
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
