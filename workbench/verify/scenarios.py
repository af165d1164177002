"""Verification scenarios and their metrics, each beside what the linear analysis predicts.

Every scenario starts the same way: the plant at rest, the controller at rest, the
reference ramped over 1 s from the reading at rest to the scenario's start point and
held for 1 s (the approach is not scored). References are displacements, converted to
firmware volts with the serial's calibration and trim centre as firmware does. A controller
whose sensor block carries firmware's reference lead (``ref_lead_s`` = 1/K_v) is fed the
triangles led by their slope times it (scored against the triangle itself, as the sensor
loop of :mod:`.sensors` does: velocity feedforward on the planned slope, :func:`planned_slope_lead`); one
that carries the gauge curvature reads the gauge linearized (:mod:`.closed_loop`). Steps, holds and tones are
fed as they are, and only the triangles report ``ref_lead_s``. The loop closes on its first reading: a
gauge export's ``startup_wait_s`` (one period, the gauge reading's own settle,
:func:`workbench.verify.sensors.firmware_startup`) is run as exported. These scenarios start from rest at
0 V with no step to a bias, so the sensor loop's scenario floor (:func:`workbench.verify.sensors.closing_time_s`:
the plant's creep after the 0 -> 50 V step) has no counterpart here.
"""

import control
import numpy as np

from ..identify.freefree import hysteresis_fraction
from ..plant.gauge import TRIM_CENTER_M
from ..plant.simulator import PZTSimulator
from .closed_loop import ClosedLoop

__all__ = ["SCENARIOS", "run_scenario", "stroke_m", "planned_slope_lead", "triangle_reference", "linear_step_prediction", "nominal_loop_plant"]

SCENARIOS = ("small_step", "large_step", "triangle_0p1hz", "triangle_1hz", "hold", "force_step", "sine_sweep")
SWEEP_FREQ_HZ = (5.0, 10.0, 20.0, 50.0, 100.0, 150.0, 200.0, 300.0, 500.0, 1000.0, 2000.0)
SWEEP_AMPLITUDE_M = 10e-9     # small: 10 nm at 200 Hz already asks ~170 V/s of the 2 mA source
X_START_M = 7.5e-6


def stroke_m(pzt):
    """Quasi-static stroke from rest to 100 V (the seed's ~15 um)."""
    q = pzt.terminal_operator().inverse()(np.array([0.0, 100.0]))
    return float(pzt.k_q2x_m_per_c * q[-1])


def _to_volts(x_m, g):
    return (np.asarray(x_m) - TRIM_CENTER_M) / g.calibration_m_per_v


def _approach(cl, g, x_start, dt):
    n = int(1.0 / dt)
    x_rest = cl.plant.pzt.k_q2x_m_per_c * cl.plant.pzt.hysteresis.output_at_rest()
    ref = np.concatenate([np.linspace(x_rest, x_start, n), np.full(n, x_start)])
    return cl.run(_to_volts(ref, g))


def triangle_reference(lo_m, hi_m, freq_hz, periods, dt_s):
    """The closed-loop triangle both ``verify`` and ``sweep`` run: mid-span first, going down, then lo, hi, ...

    Parameters
    ----------
    lo_m, hi_m : float
        The triangle's ends, m (or firmware V).
    freq_hz : float
        Its frequency, Hz.
    periods : float
        How many periods, n = int(periods / freq_hz / dt_s) samples.
    dt_s : float
        Servo period, s.

    Returns
    -------
    t_s, ref_next : numpy.ndarray
        n + 1 sample times (s, from 0) and the triangle at them: the planned trajectory
        :func:`planned_slope_lead` takes (its last sample gives the last slope); ``ref_next[:n]`` is the reference
        scored. At t = 0 it is mid-span, at 1/(4 f) lo, at 3/(4 f) hi; slope 2 (hi - lo) f.
    """
    n = int(periods / freq_hz / dt_s)
    t = np.arange(n + 1) * dt_s
    tri = 2 * np.abs((t * freq_hz + 0.25) % 1.0 - 0.5)            # 0..1 from mid-span, going down
    return t, lo_m + (hi_m - lo_m) * tri


def planned_slope_lead(ref_next, dt, lead_s):
    """The reference a trajectory generator feeds with velocity feedforward ``lead_s`` on its planned slope.

    Parameters
    ----------
    ref_next : array_like
        The planned trajectory at n + 1 periods, m (or firmware V): the last one gives the last slope.
    dt : float
        Period, s.
    lead_s : float
        The sensor block's ``ref_lead_s`` (1/K_v), s; 0: none.

    Returns
    -------
    numpy.ndarray
        n samples r_k + v_k lead_s with the planned slope v_k = (r_{k+1} - r_k) / dt (the forward slope, the
        one :func:`workbench.verify.sensors.run_sensor_loop` feeds); r_k itself when ``lead_s`` is 0. For
        planned ramps only (triangles): a step's difference would be a one-sample pulse of lead_s / dt times
        its height.
    """
    r = np.asarray(ref_next, float)
    return r[:-1] + (r[1:] - r[:-1]) / dt * lead_s if lead_s > 0 else r[:-1].copy()


def _step_metrics(t, x, x0, x1, band=0.02):
    """(overshoot %, settling s): :func:`workbench.design.step.step_metrics`."""
    from ..design.step import step_metrics
    return step_metrics(t, x, x0, x1, band)


def _rise_time(t, x, x0, x1):
    """10-90 % rise, s: :func:`workbench.design.step.rise_time`."""
    from ..design.step import rise_time
    return rise_time(t, x, x0, x1)


def _ratio(a, b):
    return float(a / b) if np.isfinite(a) and np.isfinite(b) and b > 0 else float("nan")


def nominal_loop_plant(plant, branch="ascending", minimal=True):
    """The nominal plant as firmware sees it: a discrete python-control StateSpace, PZT volts in,
    firmware volts of reading out (sampled gauge chain, one-sample compute delay), at mid-stroke.

    The one definition is :func:`workbench.design.nominal.nominal_plant` (its ``firmware``
    attribute); this is that plant, with the branch and the reduction as options.

    Parameters
    ----------
    plant : Plant or str or path-like
        A plant (:func:`workbench.load_plant`) or its file.
    branch : str, default "ascending"
        Hysteresis branch of the operating point at 50 V: ascending where a step up from the
        approach runs, "reversal" for small tones (minor loops).
    minimal : bool, default True
        Truncate the slow creep modes (:func:`workbench.design.nominal.minimal`): they leave
        nearly cancelling pole/zero pairs within 1e-7 of z = 1, and ``control.feedback`` of the
        unreduced model with a controller puts a spurious closed-loop pole outside the unit
        circle (|z| = 1.015 with the SN637 export). The servo band is unchanged (tests/test_controller.py).
    """
    from ..design.nominal import SLOW_HZ, nominal_plant
    from ..plant.files import as_plant
    plant = as_plant(plant)
    return nominal_plant(plant, slow_hz=SLOW_HZ if minimal else 0.0, branch=branch).firmware


def _nominal_loop_plant(plant, branch="ascending"):
    return nominal_loop_plant(plant, branch)


def linear_step_response(plant, controller, n=2000):
    """(t, y): unit step of the nominal small-signal loop as firmware closes it (the output computed
    from reading k is applied at k + 1), reading over reference."""
    k = controller.linear()
    t = np.arange(n) * controller.dt_s
    y = np.squeeze(control.step_response(control.feedback(k * _nominal_loop_plant(plant), 1), T=t).outputs)
    return t, y


def linear_step_prediction(plant, controller, n=2000):
    """Overshoot (%) and 2 % settling time of the nominal small-signal loop (discrete, sampled chain)."""
    t, y = linear_step_response(plant, controller, n)
    return _step_metrics(t, y, 0.0, 1.0)


def linear_closed_loop(plant, controller, freq_hz, branch="reversal"):
    """T(e^{jwT}) from reference to reading of the small-signal loop on ``branch`` at ``freq_hz``."""
    t = control.feedback(controller.linear() * _nominal_loop_plant(plant, branch), 1)
    return np.asarray(control.frequency_response(t, 2 * np.pi * np.asarray(freq_hz)).complex).ravel()


def _oscillation(e, dt, line_ratio=None):
    """Amplitude and frequency of the strongest line in the tail of a signal (a persistent oscillation).

    With ``line_ratio``: also whether it is a line, i.e. its spectral peak stands ``line_ratio``
    times above the median of the spectrum within +/-30 % of its frequency (noise shaped by
    the loop is smooth there; a limit cycle is not).
    """
    tail = e - np.mean(e)
    if tail.size < 16:
        return (0.0, float("nan")) if line_ratio is None else (0.0, float("nan"), False)
    # a slow trend is not an oscillation: remove the line through the tail, skip the lowest bins
    idx = np.arange(tail.size)
    tail = tail - np.polyval(np.polyfit(idx, tail, 1), idx)
    spec = np.abs(np.fft.rfft(tail * np.hanning(tail.size)))
    k0 = 4
    k = int(np.argmax(spec[k0:])) + k0
    amp = 2 * spec[k] / np.sum(np.hanning(tail.size))
    if line_ratio is None:
        return float(amp), float(k / (tail.size * dt))
    half = max(20, int(0.3 * k))                 # the neighbourhood: +/-30 %, at least 20 bins
    lo, hi = max(k0, k - half), min(spec.size, k + half + 1)
    floor = np.median(np.concatenate([spec[lo:max(lo, k - 3)], spec[min(hi, k + 4):hi]]))
    return float(amp), float(k / (tail.size * dt)), bool(spec[k] > line_ratio * floor)


def _command_oscillation(m, u_v, dt):
    """The command's oscillation (V, where the describing-function prediction lives) into ``m``."""
    amp, freq, line = _oscillation(u_v, dt, line_ratio=20.0)
    m.update(oscillation_command_v=amp, oscillation_command_hz=freq, oscillating=line)


def run_scenario(plant, controller, name, hold_s=1000.0, anti_windup=True, noise=True, seed=0):
    """Run one scenario; returns (metrics dict, traces dict of decimated arrays)."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)} or all")
    g = plant.gauge
    dt = controller.dt_s
    cl = ClosedLoop(plant, controller, noise=noise, anti_windup=anti_windup, seed=seed)
    stroke = stroke_m(plant.pzt)
    m = {"scenario": name, "anti_windup": anti_windup, "noise": noise, "stroke_m": stroke,
         "gauge_curvature_per_m": float(controller.gauge_curvature_per_m)}
    _approach(cl, g, X_START_M, dt)
    if name in ("small_step", "large_step"):
        dx = 0.1e-6 if name == "small_step" else 5e-6
        x1 = X_START_M + dx
        n = int((0.05 if name == "small_step" else 0.5) / dt)
        r = cl.run(_to_volts(np.full(n, x1), g))
        x0 = X_START_M
        ov, st = _step_metrics(r.t_s, r.x_m, x0, x1)
        m.update(step_m=dx, overshoot_percent=ov, settling_s=st, final_error_m=float(np.mean(r.x_m[-n // 5:]) - x1))
        t_lin, y_lin = linear_step_response(plant, controller, n)
        ov_lin, st_lin = _step_metrics(t_lin, y_lin, 0.0, 1.0)
        m.update(linear_overshoot_percent=ov_lin, linear_settling_s=st_lin,
                 overshoot_difference_points=ov - ov_lin, settling_difference_s=st - st_lin,
                 rise_s=_rise_time(r.t_s - r.t_s[0] + dt, r.x_m, x0, x1), linear_rise_s=_rise_time(t_lin, y_lin, 0.0, 1.0))
        window_ms = n * dt * 1e3
        m["settling_ratio"] = _ratio(st, st_lin)
        m["rise_ratio"] = _ratio(m["rise_s"], m["linear_rise_s"])
        if noise:
            # the overshoot of one noisy step is mostly noise (22 nm RMS on a 100 nm step): the comparison
            # with the noise-free linear prediction is made on the same step run without gauge noise
            quiet = ClosedLoop(plant, controller, noise=False, anti_windup=anti_windup, seed=seed)
            _approach(quiet, g, X_START_M, dt)
            rq = quiet.run(_to_volts(np.full(n, x1), g))
            ov_q, st_q = _step_metrics(rq.t_s, rq.x_m, x0, x1)
            m.update(overshoot_noise_free_percent=ov_q, settling_noise_free_s=st_q,
                     overshoot_difference_points=ov_q - ov_lin, settling_difference_s=st_q - st_lin,
                     rise_noise_free_s=_rise_time(rq.t_s - rq.t_s[0] + dt, rq.x_m, x0, x1))
            m["settling_ratio"] = _ratio(st_q, st_lin)            # scored on the noise-free twin
            m["rise_ratio"] = _ratio(m["rise_noise_free_s"], m["linear_rise_s"])
        for key in ("settling_s", "settling_noise_free_s", "settling_ratio", "settling_difference_s"):
            if key in m and not np.isfinite(m[key]):
                m[f"{key}_why"] = (f"the step did not stay within 2 % of its size before the {window_ms:.0f} ms "
                                   f"window ended" if np.isfinite(st_lin) else
                                   f"the linear prediction does not settle within the {window_ms:.0f} ms window")
        for key in ("rise_s", "rise_noise_free_s", "rise_ratio"):
            if key in m and not np.isfinite(m[key]):
                m[f"{key}_why"] = f"the step did not reach 90 % of its size within the {window_ms:.0f} ms window"
        amp, freq = _oscillation(r.x_m[-n // 2:], dt)
        m.update(oscillation_m=amp, oscillation_hz=freq)
        extra = {"ref_m": np.full(r.x_m.size, x1), "x_linear_m": x0 + dx * y_lin[: r.x_m.size],
                 "x_start_m": np.array([x0])}
    elif name.startswith("triangle"):
        f = 0.1 if name == "triangle_0p1hz" else 1.0
        lo, hi = X_START_M - 0.4 * stroke, X_START_M + 0.4 * stroke
        _, ref_next = triangle_reference(lo, hi, f, 2, dt)     # two periods from mid-stroke, going down
        ref = ref_next[:-1]
        # firmware's velocity feedforward on the planned slope (the sensor block's ref_lead_s = 1/K_v): fed
        # r + v lead, scored against r itself; reported on the ramp scenarios only (the others are fed as given)
        fed = planned_slope_lead(ref_next, dt, controller.ref_lead_s)
        m["ref_lead_s"] = float(controller.ref_lead_s)
        # start the triangle at its first value
        r0 = cl.run(_to_volts(np.full(int(0.5 / dt), ref[0]), g))
        dec = max(1, int(round(1.0 / (f * dt * 2000))))
        r = cl.run(_to_volts(fed, g), decimate=dec)
        ref_d = ref[dec - 1::dec][: r.x_m.size]
        after = r.t_s - r0.t_s[-1] > 1.0 / f                      # after the first period
        err = r.x_m[after] - ref_d[after]
        extra = {"ref_m": ref_d, "scored": after}
        m.update(freq_hz=f, error_rms_m=float(np.sqrt(np.mean(err ** 2))), error_peak_m=float(np.max(np.abs(err))),
                 error_peak_percent_of_stroke=float(np.max(np.abs(err)) / stroke * 100),
                 error_rms_percent_of_stroke=float(np.sqrt(np.mean(err ** 2)) / stroke * 100),
                 hysteresis_closed_loop_percent=hysteresis_fraction(ref_d[after], r.x_m[after]) * 100 * (
                     np.ptp(r.x_m[after]) / stroke),
                 hysteresis_open_loop_percent=_open_loop_hysteresis(plant, f) * 100)
        m["hysteresis_ratio"] = _ratio(m["hysteresis_closed_loop_percent"], m["hysteresis_open_loop_percent"])
    elif name == "hold":
        n = int(hold_s / dt)
        dec = max(1, n // 20000)
        r = cl.run(float(_to_volts(X_START_M, g)), decimate=dec, periods=n)
        settled = r.t_s - r.t_s[0] >= 1.0
        xs = r.x_m[settled]
        # drift: the mean over the first and last tenth of the settled hold (noise averaged out)
        k = max(1, xs.size // 10)
        m.update(hold_s=hold_s, current_limit_fraction=r.periods_at_current_limit / max(1, n),
                 drift_m=float(np.mean(xs[-k:]) - np.mean(xs[:k])),
                 noise_rms_m=float(np.std(xs[:k])))
        amp, freq = _oscillation(r.x_m[settled], dt * dec)
        m.update(oscillation_m=amp, oscillation_hz=freq)
        # a persistent oscillation of the settled loop, at full rate on the command (the describing
        # function predicts the PZT voltage's amplitude): one more second after the hold
        tail = cl.run(float(_to_volts(X_START_M, g)), periods=int(1.0 / dt))
        _command_oscillation(m, tail.u_v, dt)
        creep = _open_loop_creep_trace(plant, hold_s)
        m.update(open_loop_creep_m=float(creep[1, -1]))      # from 1 s to the end of the hold, as the trace
        extra = {"ref_m": np.full(r.x_m.size, X_START_M), "open_loop_creep": creep}
    elif name == "force_step":
        n = int(0.2 / dt)
        force = np.concatenate([np.zeros(n // 4), np.full(n - n // 4, -100.0)])   # 100 N compression
        r = cl.run(_to_volts(np.full(n, X_START_M), g), force_n=force)
        dev = r.x_m[n // 4:] - X_START_M
        pz = plant.pzt
        extra = {"ref_m": np.full(r.x_m.size, X_START_M)}
        m.update(force_n=-100.0, peak_deviation_m=float(np.max(np.abs(dev))),
                 final_deviation_m=float(np.mean(dev[-n // 10:])),
                 # open loop the amplifier holds the voltage: the stack yields with its short-circuit
                 # stiffness k_p (the open-circuit stiffness applies only with the charge held)
                 open_loop_deflection_m=float(-100.0 / pz.stiffness_n_per_m))
    elif name == "sine_sweep":
        r, extra = _sine_sweep(cl, plant, controller, g, m)
    m.update(current_limit_source_a=plant.pzt.current_limit_source_a,
             current_limit_sink_a=-plant.pzt.current_limit_sink_a)
    m.update(peak_current_source_a=r.peak_current_a[0], peak_current_sink_a=r.peak_current_a[1],
             time_at_current_limit_s=r.periods_at_current_limit * dt,
             rate_limited_fraction=r.samples_rate_limited / max(1, r.periods),
             command_noise_rms_v=float(np.std(np.diff(r.u_v))) / np.sqrt(2) if r.u_v.size > 2 else 0.0)
    traces = {"t_s": r.t_s, "x_m": r.x_m, "u_v": r.u_v, "i_a": r.i_a, **extra}
    return {k: (float(v) if isinstance(v, np.floating) else v) for k, v in m.items()}, traces


def _sine_sweep(cl, plant, controller, g, m):
    """Closed-loop response from the time domain: one small tone at a time around mid-stroke, the
    reading's first harmonic against the reference's (lock-in over whole periods), beside T(e^{jwT})
    of the nominal loop. The gauge noise is in; 2 s of tone per frequency average it down."""
    dt = controller.dt_s
    f_hz = np.asarray(SWEEP_FREQ_HZ)
    meas, rate_frac, x_amp = [], [], []
    a_v = SWEEP_AMPLITUDE_M / g.calibration_m_per_v
    r = None
    for f in f_hz:
        cycles = max(4, int(round(2.0 * f)))
        n_settle = int(round(max(0.1, 5.0 / f) / dt))
        n = int(round(cycles / f / dt))
        f_eff = cycles / (n * dt)                                     # whole periods in the window
        t = np.arange(n_settle + n) * dt
        ref = float(_to_volts(X_START_M, g)) + a_v * np.sin(2 * np.pi * f_eff * t)
        cl.run(ref[:n_settle])
        r = cl.run(ref[n_settle:])
        ph = np.exp(-2j * np.pi * f_eff * t[n_settle:])
        ref_h = 2 * np.mean((ref[n_settle:] - np.mean(ref[n_settle:])) * ph)
        # reading k answers the reference of period k (e = ref_k - reading_k)
        read_h = 2 * np.mean((r.reading_v - np.mean(r.reading_v)) * ph)
        meas.append(read_h / ref_h)
        x_amp.append(abs(2 * np.mean((r.x_m - np.mean(r.x_m)) * ph)))
        rate_frac.append(r.samples_rate_limited / n)
    lin = linear_closed_loop(plant, controller, f_hz)
    meas = np.asarray(meas)
    # tones the loop attenuates below -20 dB leave ~0.1 nm at the gauge against a ~0.3 nm lock-in
    # noise floor (22 nm RMS over 2e4 readings): the comparison is made where the tone is measurable
    ok = np.abs(lin) > 0.1
    m.update(freq_hz=f_hz.tolist(), amplitude_m=SWEEP_AMPLITUDE_M,
             measured_db=(20 * np.log10(np.abs(meas))).tolist(),
             measured_phase_deg=np.degrees(np.angle(meas)).tolist(),
             linear_db=(20 * np.log10(np.abs(lin))).tolist(), linear_phase_deg=np.degrees(np.angle(lin)).tolist(),
             worst_gain_difference_db=float(np.max(np.abs(20 * np.log10(np.abs(meas[ok] / lin[ok]))))),
             worst_phase_difference_deg=float(np.max(np.abs(np.degrees(np.angle(meas[ok] / lin[ok]))))),
             compared_up_to_hz=float(f_hz[ok][-1]),
             rate_limited_fraction_per_freq=rate_frac, x_amplitude_m=x_amp,
             bandwidth_hz=_bandwidth(f_hz, np.abs(meas)), linear_bandwidth_hz=_bandwidth(f_hz, np.abs(lin)))
    for key, mag in (("bandwidth_hz", np.abs(meas)), ("linear_bandwidth_hz", np.abs(lin))):
        if not np.isfinite(m[key]):
            m[f"{key}_why"] = (f"|T| is already below -3 dB at the first tone, {f_hz[0]:g} Hz" if mag[0] < 10 ** (-3 / 20)
                               else f"|T| stays above -3 dB up to the last tone, {f_hz[-1]:g} Hz")
    return r, {}


def _bandwidth(f_hz, mag):
    """First frequency where |T| falls below -3 dB (log interpolation), Hz; NaN if it never does."""
    below = np.flatnonzero(mag < 10 ** (-3 / 20))
    if not below.size or below[0] == 0:
        return float("nan")
    k = below[0]
    a, b = np.log(mag[k - 1]), np.log(mag[k])
    w = (np.log(10 ** (-3 / 20)) - a) / (b - a)
    return float(np.exp(np.log(f_hz[k - 1]) + w * (np.log(f_hz[k]) - np.log(f_hz[k - 1]))))


def _open_loop_hysteresis(plant, freq_hz):
    """Hysteresis of x against V for the open-loop triangle 10-90 % of 0-100 V (fraction of stroke)."""
    n = 4000
    sim = PZTSimulator(plant.pzt, 1.0 / (freq_hz * n))
    t = np.arange(3 * n) / n
    v = 10 + 80 * 2 * np.abs((t + 0.25) % 1.0 - 0.5)
    tr = sim.run(v)
    last = slice(n, 3 * n)
    return hysteresis_fraction(v[last], tr.x_m[last]) * np.ptp(tr.x_m[last]) / stroke_m(plant.pzt)


def _open_loop_creep_trace(plant, hold_s):
    """(t_s, x_m - x at 1 s) of the open loop holding 50 V, decimated to 0.1 s."""
    sim = PZTSimulator(plant.pzt, 1e-2)
    tr = sim.run(np.full(int(min(hold_s, 1000.0) / 1e-2), 50.0), decimate=10)
    t = (np.arange(tr.x_m.size) + 1) * 0.1
    return np.vstack([t, tr.x_m - tr.x_m[min(9, tr.x_m.size - 1)]])


