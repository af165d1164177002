"""Verification scenarios and their metrics, each beside what the linear analysis predicts.

Every scenario starts the same way: the plant at rest, the controller at rest, the
reference ramped over 1 s from the reading at rest to the scenario's start point and
held for 1 s (the approach is not scored). References are displacements, converted to
firmware volts with the serial's calibration and trim centre as firmware does.
"""

import control
import numpy as np

from ..identify.freefree import hysteresis_fraction
from ..plant.gauge import TRIM_CENTER_M
from ..plant.simulator import PZTSimulator
from .closed_loop import ClosedLoop

__all__ = ["SCENARIOS", "run_scenario", "stroke_m", "linear_step_prediction"]

SCENARIOS = ("small_step", "large_step", "triangle_0p1hz", "triangle_1hz", "hold", "force_step")
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


def _step_metrics(t, x, x0, x1, band=0.02):
    """Overshoot (% of the step) and settling time into +/- band of the step."""
    span = x1 - x0
    y = (x - x0) / span
    overshoot = max(0.0, float(np.max(y) - 1.0)) * 100
    outside = np.flatnonzero(np.abs(y - 1.0) > band)
    settle = float(t[outside[-1] + 1] - t[0]) if outside.size and outside[-1] + 1 < t.size else (
        float("nan") if outside.size else 0.0)
    return overshoot, settle


def linear_step_prediction(plant, controller, n=2000):
    """Overshoot (%) and 2 % settling time of the nominal small-signal loop (discrete, sampled chain)."""
    from ..linearize.sampled import firmware_plant
    from ..linearize.small_signal import operating_point, small_signal_model
    c_h = operating_point(plant.pzt, 50.0, "ascending").capacitance_f
    g = firmware_plant(small_signal_model(plant.pzt, c_h)[0, 0], plant.gauge, X_START_M, 1)
    k = control.ss(controller.a, controller.b, controller.c, [[controller.d]], controller.dt_s)
    t = np.arange(n) * controller.dt_s
    # the loop as firmware closes it: the output computed from reading k is applied at k + 1
    y = np.squeeze(control.step_response(control.feedback(k * g, 1), T=t).outputs)
    return _step_metrics(t, y, 0.0, 1.0)


def _oscillation(e, dt):
    """Amplitude and frequency of the strongest line in the tail of a signal (a persistent oscillation)."""
    tail = e - np.mean(e)
    if tail.size < 16:
        return 0.0, float("nan")
    spec = np.abs(np.fft.rfft(tail * np.hanning(tail.size)))
    k = int(np.argmax(spec[1:])) + 1
    amp = 2 * spec[k] / np.sum(np.hanning(tail.size))
    return float(amp), float(k / (tail.size * dt))


def run_scenario(plant, controller, name, hold_s=1000.0, anti_windup=True, noise=True, seed=0):
    """Run one scenario; returns (metrics dict, traces dict of decimated arrays)."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)} or all")
    g = plant.gauge
    dt = controller.dt_s
    cl = ClosedLoop(plant, controller, noise=noise, anti_windup=anti_windup, seed=seed)
    stroke = stroke_m(plant.pzt)
    m = {"scenario": name, "anti_windup": anti_windup, "noise": noise, "stroke_m": stroke}
    _approach(cl, g, X_START_M, dt)
    if name in ("small_step", "large_step"):
        dx = 0.1e-6 if name == "small_step" else 5e-6
        x1 = X_START_M + dx
        n = int((0.05 if name == "small_step" else 0.5) / dt)
        r = cl.run(_to_volts(np.full(n, x1), g))
        x0 = X_START_M
        ov, st = _step_metrics(r.t_s, r.x_m, x0, x1)
        m.update(overshoot_percent=ov, settling_s=st, final_error_m=float(np.mean(r.x_m[-n // 5:]) - x1))
        if name == "small_step":
            ov_lin, st_lin = linear_step_prediction(plant, controller)
            m.update(linear_overshoot_percent=ov_lin, linear_settling_s=st_lin,
                     overshoot_difference_points=ov - ov_lin)
        amp, freq = _oscillation(r.x_m[-n // 2:], dt)
        m.update(oscillation_m=amp, oscillation_hz=freq)
    elif name.startswith("triangle"):
        f = 0.1 if name == "triangle_0p1hz" else 1.0
        lo, hi = X_START_M - 0.4 * stroke, X_START_M + 0.4 * stroke
        periods = 2
        n = int(periods / f / dt)
        t = np.arange(n) * dt
        tri = 2 * np.abs((t * f + 0.25) % 1.0 - 0.5)            # 0..1 triangle starting mid-way up
        ref = lo + (hi - lo) * tri
        # start the triangle at its first value
        r0 = cl.run(_to_volts(np.full(int(0.5 / dt), ref[0]), g))
        dec = max(1, int(round(1.0 / (f * dt * 2000))))
        r = cl.run(_to_volts(ref, g), decimate=dec)
        ref_d = ref[dec - 1::dec][: r.x_m.size]
        after = r.t_s - r0.t_s[-1] > 1.0 / f                      # after the first period
        err = r.x_m[after] - ref_d[after]
        m.update(freq_hz=f, error_rms_m=float(np.sqrt(np.mean(err ** 2))), error_peak_m=float(np.max(np.abs(err))),
                 error_rms_percent_of_stroke=float(np.sqrt(np.mean(err ** 2)) / stroke * 100),
                 hysteresis_closed_loop_percent=hysteresis_fraction(ref_d[after], r.x_m[after]) * 100 * (
                     np.ptp(r.x_m[after]) / stroke),
                 hysteresis_open_loop_percent=_open_loop_hysteresis(plant, f) * 100)
    elif name == "hold":
        n = int(hold_s / dt)
        dec = max(1, n // 20000)
        r = cl.run(_to_volts(np.full(n, X_START_M), g), decimate=dec)
        settled = r.t_s - r.t_s[0] >= 1.0
        xs = r.x_m[settled]
        # drift: the mean over the first and last tenth of the settled hold (noise averaged out)
        k = max(1, xs.size // 10)
        m.update(hold_s=hold_s, drift_m=float(np.mean(xs[-k:]) - np.mean(xs[:k])),
                 noise_rms_m=float(np.std(xs[:k])), open_loop_creep_m=_open_loop_creep(plant, hold_s))
    elif name == "force_step":
        n = int(0.2 / dt)
        force = np.concatenate([np.zeros(n // 4), np.full(n - n // 4, -100.0)])   # 100 N compression
        r = cl.run(_to_volts(np.full(n, X_START_M), g), force_n=force)
        dev = r.x_m[n // 4:] - X_START_M
        pz = plant.pzt
        m.update(force_n=-100.0, peak_deviation_m=float(np.max(np.abs(dev))),
                 final_deviation_m=float(np.mean(dev[-n // 10:])),
                 open_loop_deflection_m=float(-100.0 / pz.open_circuit_stiffness_n_per_m))
    m.update(peak_current_source_a=r.peak_current_a[0], peak_current_sink_a=r.peak_current_a[1],
             time_at_current_limit_s=r.periods_at_current_limit * dt,
             rate_limited_fraction=r.samples_rate_limited / max(1, r.periods),
             command_noise_rms_v=float(np.std(np.diff(r.u_v))) / np.sqrt(2) if r.u_v.size > 2 else 0.0)
    traces = {"t_s": r.t_s, "x_m": r.x_m, "u_v": r.u_v, "i_a": r.i_a}
    return m, traces


def _open_loop_hysteresis(plant, freq_hz):
    """Hysteresis of x against V for the open-loop triangle 10-90 % of 0-100 V (fraction of stroke)."""
    n = 4000
    sim = PZTSimulator(plant.pzt, 1.0 / (freq_hz * n))
    t = np.arange(3 * n) / n
    v = 10 + 80 * 2 * np.abs((t + 0.25) % 1.0 - 0.5)
    tr = sim.run(v)
    last = slice(n, 3 * n)
    return hysteresis_fraction(v[last], tr.x_m[last]) * np.ptp(tr.x_m[last]) / stroke_m(plant.pzt)


def _open_loop_creep(plant, hold_s):
    """Open-loop creep over the hold at the voltage that gives the start point (for comparison)."""
    sim = PZTSimulator(plant.pzt, 1e-2)
    v = 50.0
    tr = sim.run(np.full(int(min(hold_s, 1000.0) / 1e-2), v), decimate=100)
    return float(tr.x_m[-1] - tr.x_m[int(1.0 / 1.0)])
