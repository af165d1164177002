"""The `workbench selfsense` job: identify on one record, evaluate the stages on another.

1. An identification record (:mod:`.identify`, ~2500 s) with the creep plant; the estimator's
   parameters are identified on it with an interferometer-grade reference.
2. An evaluation record: a staircase (:func:`staircase_voltage`, steps between 0 and 100 V,
   holds of 20-60 s, like seed 002 Fig. 2.14) of ``duration_s``, simulated at 10 kHz and
   read by the charge amplifier; the estimate of each stage against the simulated true x:
   uncompensated (alpha only), + leakage and bias, + dielectric absorption, + hysteresis and
   creep (stage 4). The gauge chain reads the same record for comparison.
3. Noise: a 1 s hold at 50 V (mid-stroke), per 10 kHz sample, the final estimate beside the
   gauge chain (both against the true x).
4. The loop: the dynamic estimator (eqs. 2.42-2.48) and the committed controller, margins
   with the self-sensed signal in place of the gauge chain (python-control objects).
"""

from dataclasses import replace
from pathlib import Path

import control
import numpy as np

from ..errors import DataFileError
from ..plant.files import load_plant
from ..plant.gauge import displacement_from_reading, gauge_run_equivalent
from ..plant.simulator import PZTSimulator
from .charge_amp import ChargeAmpStream, charge_amp_params, measure
from .estimator import (StreamingEstimator, band_limited, charge_transfer, dynamic_estimator, dynamic_gains, output_transfer,
                        static_estimate, static_transfer)
from .identify import identify, simulate_identification

__all__ = ["STAGES", "staircase_voltage", "run_selfsense", "stage_errors", "loop_analysis", "noise_comparison",
           "closed_loop_step", "DEFAULT_CONTROLLER"]

STAGES = ("uncompensated", "leakage_bias", "dielectric_absorption", "hysteresis_creep")
STAGE_TITLES = {"uncompensated": "uncompensated (alpha only)", "leakage_bias": "+ leakage and bias current",
                "dielectric_absorption": "+ dielectric absorption", "hysteresis_creep": "+ hysteresis and creep"}
from .defaults import DEFAULT_CONTROLLER  # noqa: E402  (its home: the CLI reads it without this module)
MINREAL_RANK_TOL = 1e-7   # slycot tb01pd relative rank tolerance for the estimator's minimal realization (see loop_analysis)


def staircase_voltage(duration_s, dt_s, seed=2, v_max=100.0):
    """Steps between random levels in [0, v_max] V (0 and v_max both visited), holds 20-60 s.

    The amplifier's current limit turns each step into a slew (160-230 V/s up).
    """
    rng = np.random.default_rng(seed)
    levels, holds, total = [], [], 0.0
    while total < duration_s:
        h = float(rng.uniform(20.0, 60.0))
        levels.append(float(np.round(rng.uniform(0.0, v_max), 1)))
        holds.append(h)
        total += h
    if len(levels) >= 3:
        levels[1], levels[2] = v_max, 0.0
    n = int(round(duration_s / dt_s))
    edges = np.concatenate([[0.0], np.cumsum(holds)])
    idx = np.searchsorted(edges, np.arange(n) * dt_s, side="right") - 1
    return np.asarray(levels)[np.clip(idx, 0, len(levels) - 1)]


def _pp_rms(e):
    return float(np.ptp(e)), float(np.sqrt(np.mean(e * e)))


def stage_errors(rec, ident, stages=STAGES):
    """{stage: (estimate, error)} on a ChargeRecord, error = estimate - true x."""
    out = {}
    for name in stages:
        est = static_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, ident.stage(name))
        out[name] = (est, est - rec.x_m)
    return out


def noise_comparison(plant, ident, amp, seed=5, dt_s=1e-4, level_v=50.0, settle_s=20.0, window_s=1.0):
    """RMS noise per 10 kHz sample on a hold: final self-sensed estimate and the gauge chain, m."""
    n = int(round((settle_s + window_s) / dt_s))
    traj = PZTSimulator(plant.pzt, dt_s).run(np.full(n, level_v))
    rec = measure(traj, amp, seed=seed)
    est = static_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, ident.stage(STAGES[-1]))
    w = slice(n - int(round(window_s / dt_s)), n)
    t = rec.t_s[w]

    def detrended(e):
        c = np.polyfit(t - t[0], e, 1)
        return e - np.polyval(c, t - t[0])

    e_self = detrended(est[w] - rec.x_m[w])
    g = gauge_run_equivalent(rec.x_m[w], plant.gauge, x_prev_m=float(rec.x_m[w.start - 1]), seed=seed)
    e_gauge = detrended(displacement_from_reading(g.demod_v, plant.gauge) - rec.x_m[w])
    return {"t_s": t, "self_error_m": e_self, "gauge_error_m": e_gauge,
            "self_rms_m": float(np.std(e_self)), "gauge_rms_m": float(np.std(e_gauge)),
            "x_m": float(np.mean(rec.x_m[w]))}


def loop_analysis(plant, ident, amp, controller_path=DEFAULT_CONTROLLER, bias_v=50.0):
    """Margins of the committed controller with the gauge chain and with the dynamic self-sensed estimate.

    Small-signal models at ``bias_v`` on the ascending branch (as `verify` takes its nominal):
    G1 = K D(s) = x/V_in with V_in the stack's terminal voltage, H(s) from the charge
    amplifier with the IDENTIFIED leakage and absorption (standing in for the seed's ARMAX
    fit of a step, sec. 2.5.3), the estimator of stage 3 (the stage-4 operator is
    nonlinear and left out). The self-sensed path from the controller's output V_pea is
    V_t/V_pea (the 80 ohm) -> delta_s/V_t through the TRUE circuit (zero-order hold: the
    DAC holds V_pea, the ADC samples the charge amplifier at t_k) -> E(z) as firmware runs
    it (:func:`~.estimator.band_limited`, Tustin) -> one sample of compute delay, scaled
    by the gauge chain's firmware gain so the controller sees the units it was designed
    for. For this stack E reduces (minimal realization) to the 70 kHz mode times
    alpha_id/alpha and two nearly cancelled slow pole-zero pairs: the dynamic part has
    nothing to correct in the servo band because the charge already tracks x there.
    """
    from ..linearize.sampled import compute_delay, gauge_gain_v_per_m
    from ..linearize.small_signal import operating_point, small_signal_model
    from ..design.margins import margins_of
    from ..design.nominal import nominal_plant
    from ..verify.run import load_controller_json

    pzt, g = plant.pzt, plant.gauge
    _, ctrl = load_controller_json(controller_path)
    c = ctrl.linear()
    dt = g.period_s
    c_h = operating_point(pzt, bias_v, "ascending").capacitance_f
    pz0 = replace(pzt, series_resistance_ohm=0.0)
    kd = small_signal_model(pz0, c_h)                                   # x / V_t, creep and mode
    qv = small_signal_model(replace(pz0, modes=()), c_h) * (1.0 / pzt.k_q2x_m_per_c)   # q / V_t
    full = small_signal_model(pzt, c_h)
    x_of_vpea, i_of_vpea = full[0, 0], full[1, 0]
    vt_of_vpea = 1.0 - pzt.series_resistance_ohm * control.ss(i_of_vpea)
    p3 = ident.stage("dielectric_absorption")
    h_true = output_transfer(charge_transfer(qv, amp.r_leak_ohm, amp.da_gains_f, amp.da_time_constants_s),
                             amp.c_int_f, amp.c_ref_f)
    h_id = output_transfer(charge_transfer(qv, p3.r_leak_ohm, (p3.da_gain_f,), (p3.da_time_constant_s,)),
                           amp.c_int_f, amp.c_ref_f)
    g1, g2, g3 = dynamic_gains(kd, h_id, p3)
    e_full = dynamic_estimator(g1, g2, g3)
    # the leakage integrators of H and of c3/s cancel exactly in G2 + G3 (identified values in both):
    # remove the cancelled pairs so that a time-domain filter has no spurious pole at s = 0.
    # ``tol`` is slycot's relative rank tolerance (not a pole-zero distance): at 1e-9 the count
    # depended on rounding (8 states instead of 2 after a 1e-16 change in the plant kernel's x sum
    # moved the identified parameters in their last digits); 1e-8 to 1e-5 all give the 2 states of
    # the 70 kHz mode on SN637, so the middle of that band is used.
    e = control.minreal(e_full, tol=MINREAL_RANK_TOL, verbose=False)
    # firmware runs E at 10 kHz: the 70 kHz mode it carries is residualized, then Tustin
    e_d = control.c2d(band_limited(e, dt), dt, "tustin")
    ps_true = static_transfer(h_true, p3)
    sens = control.ss(e) * ps_true * vt_of_vpea                          # V_pea -> delta_d (continuous E)
    k_fw = gauge_gain_v_per_m(7.5e-6, g)
    l_self = c * compute_delay(dt, 1) * e_d * control.c2d(ps_true * vt_of_vpea, dt, "zoh") * k_fw
    l_gauge = c * nominal_plant(plant, bias_v).firmware          # the one nominal plant (design/nominal.py)
    f = np.geomspace(0.01, 0.4999 / dt, 1500)
    m_self, m_gauge = margins_of(l_self, f), margins_of(l_gauge, f)
    band = np.geomspace(0.1, 1000.0, 200)
    w = 2j * np.pi * band
    ratio = np.asarray(sens(w)).ravel() / np.asarray(x_of_vpea(w)).ravel()
    e_band = np.asarray(e(w)).ravel()
    return {"controller": str(controller_path), "bias_v": bias_v, "firmware_gain_v_per_m": k_fw,
            "margins_gauge": m_gauge.as_dict(), "margins_self_sensed": m_self.as_dict(),
            "estimate_over_true_max_dev_0p1_1khz": float(np.max(np.abs(ratio - 1.0))),
            "e_max_dev_0p1_1khz": float(np.max(np.abs(e_band - 1.0))),
            "e_states_full": int(e_full.nstates), "e_states_minimal": int(e.nstates),
            "e_poles_hz": sorted(float(abs(p_) / (2 * np.pi)) for p_ in e.poles()),
            "linear_step_self": _linear_step(l_self), "linear_step_gauge": _linear_step(l_gauge),
            "freq_hz": f, "l_gauge": np.asarray(l_gauge(np.exp(2j * np.pi * f * dt))).ravel(),
            "l_self": np.asarray(l_self(np.exp(2j * np.pi * f * dt))).ravel(),
            "systems": {"G1": g1, "G2": g2, "G3": g3, "E": e, "E_d": e_d, "sensor": sens}}


def _step_metrics(t, y, y0, y1, band=0.02):
    """Overshoot (% of the step) and 2 % settling, s (:func:`workbench.design.step.step_metrics`)."""
    from ..design.step import step_metrics
    overshoot, settle = step_metrics(t, y, y0, y1, band)
    return {"overshoot_percent": overshoot, "settling_s": settle}


def _linear_step(loop, n=3000):
    """Overshoot and settling of the reading for a unit reference step of feedback(loop, 1)."""
    t = np.arange(n) * loop.dt
    y = np.squeeze(control.step_response(control.feedback(loop, 1), T=t).outputs)
    return _step_metrics(t, y, 0.0, 1.0)


def closed_loop_step(plant, ident, amp, e_d, controller_path=DEFAULT_CONTROLLER, bias_v=50.0, settle_s=1.0,
                     run_s=0.3, step_m=0.1e-6, step_at_s=0.1, seed=4, sensor="self"):
    """The committed controller closing the loop on the self-sensed estimate, nonlinear plant, small step.

    The plant (compiled step, 10 kHz), the charge amplifier and the stage-4 estimator one
    sample at a time (:class:`~.charge_amp.ChargeAmpStream`, :class:`~.estimator.StreamingEstimator`),
    then the dynamic part E(z) (``e_d``, the firmware's discrete E), scaled to firmware
    volts; the linear controller (no output window: a 0.1 um step stays far from the
    current limits) computes from reading k the output applied in period k + 1. The loop
    closes after ``settle_s`` at ``bias_v`` (the controller's output is added to the bias,
    its reference the estimate at that moment), and the reference steps by ``step_m`` at
    ``step_at_s``. The run is repeated without the step (same noise); the metrics are
    those of the difference of the true x, which removes the transient of closing the
    loop on a still-creeping stack. ``sensor="gauge"`` runs the same scenario on the
    noise-free gauge chain's reading instead (the per-period equivalent chain, read as
    displacement), for the comparison.
    """
    from ..linearize.sampled import gauge_gain_v_per_m
    from ..plant import kernels as K
    from ..verify.run import load_controller_json
    _, ctrl = load_controller_json(controller_path)
    c = control.ss(ctrl.linear())
    dt = float(c.dt)
    ca, cb, cc, cd = (np.asarray(m_, float) for m_ in (c.A, c.B, c.C, c.D))
    ed = control.ss(e_d)
    ea, eb, ec, edd = (np.asarray(m_, float) for m_ in (ed.A, ed.B, ed.C, ed.D))
    k_fw = gauge_gain_v_per_m(7.5e-6, plant.gauge)
    n = int(round(run_s / dt))
    t = np.arange(1, n + 1) * dt

    def one_run(step_size):
        sim = PZTSimulator(plant.pzt, dt)
        step, m, st = sim.step_function()
        out = np.empty(K.N_OUT)
        amp_s, est = ChargeAmpStream(amp, dt, seed), StreamingEstimator(ident.stage(STAGES[-1]), dt)
        xe, xc = np.zeros(ea.shape[0]), np.zeros(ca.shape[0])
        reading, x_prev = 0.0, 0.0
        for k in range(int(round(settle_s / dt)) + n):
            u = bias_v
            if k >= int(round(settle_s / dt)):
                j = k - int(round(settle_s / dt))
                if j == 0:
                    ref0, y = reading, 0.0
                u = bias_v + y
            step(m, st, u, 0.0, out)
            if sensor == "x":
                reading = float(out[0])
            elif sensor == "gauge":
                gr = gauge_run_equivalent(np.array([out[0]]), plant.gauge, x_prev_m=x_prev, noise=False)
                reading = float(displacement_from_reading(gr.demod_v, plant.gauge)[0])
                x_prev = out[0]
            else:
                d_s = est.update(*amp_s.update(out[1], out[5]))
                reading = float(ec[0] @ xe + edd[0, 0] * d_s)
                xe = ea @ xe + eb[:, 0] * d_s
            if k >= int(round(settle_s / dt)):
                ref = ref0 + (step_size if t[j] > step_at_s else 0.0)
                err = k_fw * (ref - reading)
                y = float(cc[0] @ xc + cd[0, 0] * err)
                xc = ca @ xc + cb[:, 0] * err
                xs[j], ds[j], us[j] = out[0], reading, u
        return xs.copy(), ds.copy(), us.copy()

    xs, ds, us = np.empty(n), np.empty(n), np.empty(n)
    x1, d1, u1 = one_run(step_m)
    x0, d0, u0 = one_run(0.0)           # same noise, no step: the difference removes the loop-closing transient
    after = t > step_at_s
    dx = x1 - x0
    metrics = _step_metrics(t[after] - step_at_s, dx[after], 0.0, step_m)
    return {"t_s": t, "x_m": x1, "reading_m": d1, "u_v": u1, "x_no_step_m": x0, "step_response_m": dx,
            "step_m": step_m, "bias_v": bias_v, "step_at_s": step_at_s,
            "final_error_m": float(np.mean(dx[-200:]) - step_m), **metrics}


def run_selfsense(plant_path, duration_s=1000.0, out_dir=None, amp=None, seed=2,
                  controller_path=DEFAULT_CONTROLLER, dt_s=1e-4, eval_hz=1000.0, id_hold_s=700.0,
                  loop=True, progress=None, strict=False):
    """The staged study; returns the JSON dict (``stages`` first), writes figures when ``out_dir``.

    With ``loop``, the controller is first compared with the plant (verify's preflight,
    :func:`~workbench.verify.run.check_controller_for_plant`): a controller exported for another plant
    warns (:class:`~workbench.errors.ControllerMismatchWarning`, and the JSON's ``warnings``), or with
    ``strict`` raises :class:`~workbench.errors.ControllerMismatchError` before any work.

    ``amp``: the charge channel (default :func:`~.charge_amp.charge_amp_params` of the plant: the assumed
    circuit with the plant file's ``[leakage]`` / ``[dielectric_absorption]`` when given)."""
    plant_path = Path(plant_path)
    plant = load_plant(plant_path)
    amp = charge_amp_params(plant) if amp is None else amp
    if not duration_s >= 100.0:
        raise ValueError(f"--duration must be at least 100 s (a few steps of 20-60 s); got {duration_s} s")
    if loop and not Path(controller_path).is_file():
        raise DataFileError(f"{controller_path}: no such controller JSON; give --controller "
                            f"controllers/sn637_loopshape.json or --no-loop")
    mismatches = []
    if loop:
        from ..controller import Controller
        from ..verify.run import check_controller_for_plant
        mismatches = check_controller_for_plant(plant, Controller.load(controller_path, plant=plant), strict=strict)

    def tick(stage):
        if progress:
            progress(stage)

    tick("identification record")
    idrec = simulate_identification(plant.pzt, amp, hold_s=id_hold_s, seed=seed + 100, dt_s=dt_s)
    ident = identify(idrec, amp)
    tick("evaluation record")
    dec = max(1, int(round(1.0 / (eval_hz * dt_s))))
    v = staircase_voltage(duration_s, dt_s, seed)
    n = (v.size // dec) * dec
    traj = PZTSimulator(plant.pzt, dt_s).run(v[:n], decimate=dec)
    rec = measure(traj, amp, seed=seed, average=dec)
    stroke = float(np.ptp(rec.x_m))
    errs = stage_errors(rec, ident)
    stages = []
    for name in STAGES:
        pp, rms = _pp_rms(errs[name][1])
        stages.append({"name": name, "title": STAGE_TITLES[name], "error_pp_m": pp, "error_rms_m": rms,
                       "error_pp_percent_stroke": 100 * pp / stroke})
    creep_part, hyst_part = ident.correction.parts(rec.t_s, rec.v_in_v)
    g = gauge_run_equivalent(rec.x_m, plant.gauge, seed=seed)
    e_gauge = displacement_from_reading(g.demod_v, plant.gauge) - rec.x_m
    gpp, grms = _pp_rms(e_gauge)
    tick("noise")
    noise = noise_comparison(plant, ident, amp, seed=seed, dt_s=dt_s)
    truth = {"alpha_c_per_m": 1.0 / plant.pzt.k_q2x_m_per_c, "i_bias_a": amp.i_bias_a, "r_leak_ohm": amp.r_leak_ohm,
             "da_gains_f": list(amp.da_gains_f), "da_time_constants_s": list(amp.da_time_constants_s)}
    data = {
        "plant": str(plant_path), "duration_s": float(rec.t_s[-1]), "sample_hz": 1.0 / float(rec.t_s[1] - rec.t_s[0]),
        "stroke_m": stroke, "stages": stages,
        "warnings": [f"preflight {p['check']}: {p['message']}" for p in mismatches],
        "target_last_stage_pp_percent_stroke": 1.0,
        "target_met": bool(stages[-1]["error_pp_m"] <= 0.01 * stroke),
        "stage4_parts_rms_m": {"creep": float(np.sqrt(np.mean(creep_part ** 2))),
                               "hysteresis": float(np.sqrt(np.mean(hyst_part ** 2)))},
        "gauge_on_same_record": {"error_pp_m": gpp, "error_rms_m": grms},
        "noise_per_10khz_sample": {"self_sensed_rms_m": noise["self_rms_m"], "gauge_rms_m": noise["gauge_rms_m"],
                                   "hold_v": 50.0, "x_m": noise["x_m"]},
        "identified": ident.as_dict(), "true": truth,
        "charge_amplifier": {k: (list(v) if isinstance(v, tuple) else v) for k, v in amp.__dict__.items()},
        "v_out_clipped_fraction": max(rec.clipped_fraction, idrec.record.clipped_fraction),
        "identification_duration_s": float(idrec.record.t_s[-1]),
    }
    la = None
    if loop:
        tick("loop")
        la = loop_analysis(plant, ident, amp, controller_path)
        data["loop"] = {k: v for k, v in la.items() if k not in ("freq_hz", "l_gauge", "l_self", "systems")}
        tick("closed loop")
        cl = closed_loop_step(plant, ident, amp, la["systems"]["E_d"], controller_path, seed=seed)
        cg = closed_loop_step(plant, ident, amp, la["systems"]["E_d"], controller_path, seed=seed, sensor="gauge")
        la["closed_loop"], la["closed_loop_gauge"] = cl, cg
        data["loop"]["closed_loop_small_step"] = {k: v for k, v in cl.items() if not isinstance(v, np.ndarray)}
        data["loop"]["closed_loop_small_step_gauge_noise_free"] = {k: v for k, v in cg.items()
                                                                   if not isinstance(v, np.ndarray)}
    if out_dir is not None:
        tick("figures")
        from ..report.selfsense_figures import write_selfsense_outputs
        data["figures"] = write_selfsense_outputs(Path(out_dir), data, rec, errs, noise, la)
    return data
