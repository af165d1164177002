"""The sensors side by side in verify's report: a Markdown table and one figure (``sensors.png``)."""

import numpy as np

from .sensors import MIN_OPEN_LOOP_S

__all__ = ["sensor_lines", "plot_sensors"]

TITLES = {"gauge": "gauge", "charge": "charge estimate", "fused": "fused (gauge + charge blend)"}
COLORS = {"gauge": "tab:blue", "charge": "tab:orange", "fused": "tab:green"}
# issue 16's floors for the fused loop (plants/p888_51_sn637_creep.toml, 22 nm gauge noise)
TRIANGLE_TARGET_PERCENT = 0.01
DRIFT_TARGET_M = 1e-9


def _f(v, scale=1.0, fmt=".3g"):
    if v is None or not np.isfinite(v):
        return "n/a"
    return format(v * scale, fmt)


def _closes(r):
    """The "closes at" cell: the settle time, or "not settled within H s" and where the loop closed instead."""
    if r.get("settle_why"):
        return f"{_f(r.get('settle_s'), 1, '.2f')} s (not settled within {r.get('settle_horizon_s', 10.0):g} s)"
    return f"{_f(r.get('settle_s'), 1, '.2f')} s"


def sensor_lines(rows, figure=None):
    """Markdown lines of the side-by-side table (``rows`` from :func:`workbench.verify.sensors.compare_sensors`)."""
    if not rows:
        return []
    hold = rows[0]["hold_s"]
    r0 = rows[0]
    kvs = [f"{TITLES[r['sensor']]} {r['velocity_constant_per_s']:.4g} 1/s" for r in rows
           if r.get("velocity_constant_per_s")]
    lead = (f"led by its slope over each loop's velocity constant K_v ({', '.join(kvs)}; the type-1 loop's "
            f"ramp error fed forward)" if kvs else "(no ramp feedforward)")
    lin = ("the gauge reading with eq. 27's curvature taken out" if r0.get("gauge_linearized") else
           "the gauge reading on the serial's linear calibration")
    src = {r["sensor"]: r.get("settle_source") for r in rows}
    from_c = sorted(k for k, v in src.items() if v == "controller")
    carried = (f"The wait, the lead and the gauge curvature of the {', '.join(TITLES[k] for k in from_c)} loop are "
               f"the controller's own (its sensor block's startup_wait_s, ref_lead_s, gauge_curvature_per_m, in "
               f"the JSON and the header; the loop closes at that wait or the scenario's 1 s creep floor, whichever is "
               f"later); elsewhere this harness computes them." if from_c else
               "The wait, the lead and the gauge linearization are computed by this harness around the export, "
               "which carries none of them.")
    out = ["## Sensors side by side", "",
           f"The controller's fixed-point sensor step closing on each reading, on the nonlinear plant with the "
           f"charge amplifier's leakage, bias current and dielectric absorption, creep and the gauge noise all "
           f"present. Open loop at {r0['bias_v']:g} V until the reading's startup error has settled within its own "
           f"noise, at least {MIN_OPEN_LOOP_S:g} s (\"closes at\"), then {r0['triangle_hz']:g} Hz triangle spanning "
           f"80 % of the {r0['stroke_m'] * 1e6:.4g} um quasi-static stroke about that point (two periods, scored after the first), {lead}, then a "
           f"{hold:g} s hold; {lin}. {carried} Triangle RMS: the true x against the reference "
           f"relative to the position at closing (the sensor's offset at closing, from the true x, added); \"commanded\": x's motion from where it was at closing "
           f"against the triangle alone. "
           f"Bandwidth: -3 dB of the true x against the reference, measured after the hold with 10 nm tones "
           f"(5 Hz-2 kHz, as verify's sine sweep), beside the nominal linear loop's (ascending branch at 50 V). "
           f"Crossover and margins: that nominal loop on the sensor's path.", "",
           "| sensor | bandwidth (measured / linear) | crossover | PM / GM | closes at | triangle RMS (commanded) "
           "| hold drift | hold noise RMS |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        name = TITLES[r["sensor"]] + (f" at {r['blend_crossover_hz']:.3g} Hz" if r.get("blend_crossover_hz") else "")
        out.append(f"| {name} | {_f(r.get('bandwidth_hz'), 1, '.0f')} / {_f(r.get('linear_bandwidth_hz'), 1, '.0f')} Hz | "
                   f"{_f(r.get('crossover_hz'), 1, '.0f')} Hz | "
                   f"{_f(r.get('phase_margin_deg'), 1, '.1f')} deg / {_f(r.get('gain_margin_db'), 1, '.1f')} dB | "
                   f"{_closes(r)} | "
                   f"{_f(r['triangle_rms_percent_stroke'], 1, '.4f')} % "
                   f"({_f(r.get('triangle_commanded_rms_percent_stroke'), 1, '.4f')} %) of stroke | "
                   f"{_f(r['hold_drift_m'], 1e9, '+.2f')} nm over {r['hold_s']:g} s | "
                   f"{_f(r['hold_noise_rms_m'], 1e9, '.2f')} nm |")
    why = [f"- {TITLES[r['sensor']]}: measured bandwidth n/a: {r['bandwidth_why']}" for r in rows
           if r.get("bandwidth_why")]
    if why:
        out += [""] + why
    fused = next((r for r in rows if r["sensor"] == "fused"), None)
    if fused is not None:
        tri_ok = fused["triangle_rms_percent_stroke"] <= TRIANGLE_TARGET_PERCENT
        drift_ok = abs(fused["hold_drift_m"]) <= DRIFT_TARGET_M
        out += ["", f"Issue 16's floors for the fused loop: triangle <= {TRIANGLE_TARGET_PERCENT:g} % of stroke: "
                    f"**{'met' if tri_ok else 'MISSED'}**; hold drift <= 1 nm over 1000 s"
                    + ("" if fused["hold_s"] == 1000.0 else f" (over {fused['hold_s']:g} s here)")
                    + f": **{'met' if drift_ok else 'MISSED'}**."]
    if figure:
        out += ["", f"![sensors]({figure})"]
    return out + [""]


def plot_sensors(rows, traces, path):
    """Triangle error and hold position per sensor (two panels), saved atomically; returns the path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..report.output import save_figure
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for r in rows:
        s = r["sensor"]
        tr = traces[s]
        t, x, ref = tr["t_s"], tr["x_m"], tr["reference_rel_m"]
        n_tri = int(np.count_nonzero(ref)) and int(np.flatnonzero(ref)[-1]) + 1
        per = int(round(1.0 / r["triangle_hz"] / (t[1] - t[0])))
        e = x[:n_tri] - ref[:n_tri]
        # the scored frame (the pinned reference plus the sensor's offset at closing): the trace's
        # relative reference differs from it by a constant, so its mean is set to the scored mean
        e = e - np.mean(e[per:n_tri]) + r.get("triangle_mean_m", 0.0)
        lab = f"{TITLES[s]}: {r['triangle_rms_percent_stroke']:.3f} % RMS"
        a1.plot(t[:n_tri], e * 1e9, color=COLORS[s], lw=0.6, label=lab)
        one = max(1, per // 10)                       # 1 s of rows (the triangle's period is 10 s)
        h = x[n_tri:]
        h1 = np.convolve(h, np.ones(one) / one, mode="valid")[::max(1, one // 20)]    # 1 s means, 20 a second
        th = (t[n_tri:][one - 1:] - t[n_tri])[::max(1, one // 20)]
        a2.plot(th, (h1 - h1[0]) * 1e9, color=COLORS[s], lw=0.9,
                label=f"{TITLES[s]}: noise {r['hold_noise_rms_m'] * 1e9:.2f} nm RMS, drift "
                      f"{r['hold_drift_m'] * 1e9:+.2f} nm")
    a1.axvspan(0, rows[0]["triangle_hz"] ** -1 + t[0], color="0.9", zorder=0, label="first period (not scored)")
    a1.set(xlabel="time after closing the loop (s)", ylabel="true x - reference (nm, scored frame)",
           title=f"{rows[0]['triangle_hz']:g} Hz triangle, 80 % of stroke about the closing point")
    a2.set(xlabel="time into the hold (s)", ylabel="true x, 1 s running mean, from its start (nm)",
           title="hold: drift (noise RMS about the 1 s mean in the legend)")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
        a.legend(fontsize=7, loc="best")
    fig.suptitle("The controller's fixed-point sensor step on each reading (nonlinear plant, all drifts, noise on)",
                 fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)
