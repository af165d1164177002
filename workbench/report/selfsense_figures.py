"""Figures and report of the self-sensing study (:mod:`workbench.selfsense.run`)."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .design_figures import db, unwrapped_deg  # noqa: E402
from .output import save_figure, write_json, write_text  # noqa: E402

__all__ = ["plot_stage", "plot_noise", "plot_loop", "plot_closed_loop", "write_selfsense_outputs"]

UM, NM = 1e6, 1e9
MAX_POINTS = 20000


def _thin(n):
    return slice(None, None, max(1, n // MAX_POINTS))


def _envelope(t, y, n_bins=4000):
    """(t, min, max) per bin: peaks survive the thinning of a long record."""
    edges = np.linspace(0, t.size, min(n_bins, t.size) + 1).astype(int)
    tb = 0.5 * (t[edges[:-1]] + t[np.maximum(edges[1:] - 1, edges[:-1])])
    lo = np.array([y[a:b].min() for a, b in zip(edges[:-1], edges[1:])])
    hi = np.array([y[a:b].max() for a, b in zip(edges[:-1], edges[1:])])
    return tb, lo, hi


def plot_stage(t, x_m, est_m, stage, stroke_m, path):
    """True and estimated displacement (top), estimation error (bottom) for one stage."""
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True, gridspec_kw={"height_ratios": [1, 1]})
    k = _thin(t.size)
    ax1.plot(t[k], x_m[k] * UM, lw=1.2, color="0.3", label="true x (simulation)")
    ax1.plot(t[k], est_m[k] * UM, lw=0.8, color="C1", ls="--", label="self-sensed estimate")
    ax1.set_ylabel("displacement, um")
    ax1.legend(loc="best", fontsize=8)
    ax1.set_title(f"Self-sensing, {stage['title']}")
    e = est_m - x_m
    tb, lo, hi = _envelope(t, e * NM)
    ax2.fill_between(tb, lo, hi, color="C3", lw=0.5, alpha=0.8)
    ax2.axhline(0.0, color="0.5", lw=0.6)
    ax2.set_ylabel("estimate - true, nm")
    ax2.set_xlabel("time, s")
    # the numbers in the panel's title: a box inside the axes would cover the error wherever it goes
    ax2.set_title(f"error peak-to-peak {stage['error_pp_m'] * NM:.1f} nm "
                  f"({100 * stage['error_pp_m'] / stroke_m:.2f} % of {stroke_m * UM:.2f} um), "
                  f"RMS {stage['error_rms_m'] * NM:.1f} nm", fontsize=9)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_noise(noise, path):
    """The final estimate's error and the gauge chain's, per 10 kHz sample, on a 1 s hold."""
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    t = noise["t_s"] - noise["t_s"][0]
    ax1.plot(t * 1e3, noise["gauge_error_m"] * NM, lw=0.4, color="C0",
             label=f"gauge chain: {noise['gauge_rms_m'] * NM:.1f} nm RMS")
    ax1.plot(t * 1e3, noise["self_error_m"] * NM, lw=0.6, color="C1",
             label=f"self-sensed: {noise['self_rms_m'] * NM:.2f} nm RMS")
    ax2.plot(t * 1e3, noise["self_error_m"] * NM, lw=0.6, color="C1", label="self-sensed alone (zoomed)")
    ax2.set_xlim(0, 100)
    ax2.set_xlabel("time in the hold, ms (first 100 ms of 1 s shown)")
    for ax in (ax1, ax2):
        ax.set_ylabel("reading - true x, nm")
        lo, hi = ax.get_ylim()
        ax.set_ylim(lo, hi + 0.3 * (hi - lo))          # head room: the legend above the trace, not on it
        ax.legend(loc="upper right", fontsize=8, ncol=2)
        ax.grid(alpha=0.3)
    ax1.set_title("Noise per 10 kHz sample at mid-stroke (50 V hold, detrended)")
    fig.tight_layout()
    return save_figure(fig, path)


def plot_closed_loop(cl_self, cl_gauge, path):
    """0.1 um reference step, nonlinear plant, committed controller: true x with either sensor."""
    fig, ax = plt.subplots(figsize=(8, 4))
    for cl, label, color in ((cl_gauge, "gauge chain (noise-free)", "C0"), (cl_self, "self-sensed estimate", "C1")):
        t = (cl["t_s"] - cl["step_at_s"]) * 1e3
        ax.plot(t, cl["step_response_m"] * NM, color=color,
                label=f"{label}: overshoot {cl['overshoot_percent']:.2f} %, settles (2 %) in "
                      f"{cl['settling_s'] * 1e3:.1f} ms")
    ax.axhline(cl_self["step_m"] * NM, color="0.5", lw=0.6)
    ax.set_xlim(-10, 60)
    ax.set_xlabel("time after the reference step, ms")
    ax.set_ylabel("true x change, nm")
    ax.set_title(f"Closed loop at {cl_self['bias_v']:.0f} V, nonlinear plant, committed controller")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_loop(la, path):
    """Loop gain and phase with the committed controller: gauge chain vs dynamic self-sensed estimate."""
    f = la["freq_hz"]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for key, label, color in (("l_gauge", "gauge chain", "C0"), ("l_self", "self-sensed (dynamic estimator)", "C1")):
        m = la["margins_gauge" if key == "l_gauge" else "margins_self_sensed"]
        lab = f"{label}: PM {m['phase_margin_deg']:.1f} deg, GM {m['gain_margin_db']:.1f} dB, " \
              f"f_c {m['crossover_hz']:.0f} Hz"
        ax1.semilogx(f, db(la[key]), color=color, label=lab)
        ph = unwrapped_deg(la[key])
        ax2.semilogx(f, ph, color=color)
        # crossover on 0 dB; phase margin as the gap from the crossover's phase down to -180 deg
        f_c, pm = m.get("pm_freq_hz", float("nan")), m.get("phase_margin_deg", float("nan"))
        if np.isfinite(f_c) and np.isfinite(pm):
            ax1.plot([f_c], [0], "o", color=color, mfc="white", mew=1.5, ms=6, zorder=5)
            ph_c = np.interp(np.log(f_c), np.log(f)[np.isfinite(ph)], ph[np.isfinite(ph)])
            ax2.annotate("", (f_c, ph_c), (f_c, ph_c - pm), arrowprops=dict(arrowstyle="<->", color=color, lw=1.2))
    ax1.axhline(0, color="0.5", lw=0.6)
    ax2.axhline(-180, color="0.5", lw=0.6)
    lo, hi = ax1.get_ylim()
    ax1.set_ylim(max(lo, -100), hi)        # the notch at the Nyquist frequency would take the axis to -200 dB
    ax1.set_ylabel("|L|, dB")
    ax2.set_ylabel("phase of L, deg")
    ax2.set_xlabel("frequency, Hz")
    ax1.legend(fontsize=8, loc="lower left")
    ax1.set_title("Loop with the committed controller (sampled, 10 kHz)")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return save_figure(fig, path)


def _report(data, figures):
    nm = lambda v: f"{v * NM:.1f}"   # noqa: E731
    lines = ["# Self-sensing study", "",
             f"Plant `{data['plant']}`; evaluation record {data['duration_s']:.0f} s staircase sampled at "
             f"{data['sample_hz']:.0f} Hz, stroke {data['stroke_m'] * UM:.2f} um; identification on a separate "
             f"{data['identification_duration_s']:.0f} s record.", "",
             "| stage | error p-p, nm | % of stroke | error RMS, nm | figure |", "|---|---|---|---|---|"]
    for s in data["stages"]:
        lines.append(f"| {s['title']} | {nm(s['error_pp_m'])} | {s['error_pp_percent_stroke']:.2f} | "
                     f"{nm(s['error_rms_m'])} | ![{s['name']}]({figures.get(s['name'], '')}) |")
    g = data["gauge_on_same_record"]
    n = data["noise_per_10khz_sample"]
    lines += ["", f"Target: last stage <= 1 % of stroke peak-to-peak: **{'met' if data['target_met'] else 'MISSED'}**.",
              "", f"Gauge chain on the same record: {nm(g['error_pp_m'])} nm p-p, {nm(g['error_rms_m'])} nm RMS.",
              f"Noise per 10 kHz sample at 50 V: self-sensed {n['self_sensed_rms_m'] * NM:.2f} nm RMS, "
              f"gauge chain {n['gauge_rms_m'] * NM:.1f} nm RMS (![noise]({figures.get('noise', '')})).", ""]
    idf, tru = data["identified"], data["true"]
    lines += ["| parameter | identified | true (simulation) |", "|---|---|---|",
              f"| alpha, C/m | {idf['alpha_c_per_m']:.4f} | {tru['alpha_c_per_m']:.4f} |",
              f"| i_bias, pA | {idf['i_bias_a'] * 1e12:.1f} | {tru['i_bias_a'] * 1e12:.1f} |",
              f"| R_FP, GOhm | {idf['r_leak_ohm'] * 1e-9:.4f} | {tru['r_leak_ohm'] * 1e-9:.4f} |",
              f"| absorption k_s, uF / tau, s | {idf['da_gain_f'] * 1e6:.3f} / {idf['da_time_constant_s']:.1f} | "
              + ", ".join(f"{k * 1e6:.3f} / {t:.1f}" for k, t in zip(tru['da_gains_f'], tru['da_time_constants_s']))
              + " |", "",
              f"Stage 4 held-out residual: creep operator {idf['stage4_validation_rms_m'].get('creep', float('nan')) * NM:.2f} nm, "
              f"with the PI operator {idf['stage4_validation_rms_m'].get('creep_and_pi', float('nan')) * NM:.2f} nm: "
              f"PI part {'kept' if idf['stage4_pi_kept'] else 'dropped'} (the stack's charge has no hysteresis "
              f"against its displacement in the seed 000 model).", ""]
    if "loop" in data:
        lp = data["loop"]
        mg, ms = lp["margins_gauge"], lp["margins_self_sensed"]
        lines += ["## Loop with the committed controller", "",
                  "| sensor | PM, deg | GM, dB | crossover, Hz | disk margin |", "|---|---|---|---|---|",
                  f"| gauge chain | {mg['phase_margin_deg']:.1f} | {mg['gain_margin_db']:.1f} | {mg['crossover_hz']:.0f} | "
                  f"{mg['disk_margin']:.3f} |",
                  f"| self-sensed, dynamic estimator | {ms['phase_margin_deg']:.1f} | {ms['gain_margin_db']:.1f} | "
                  f"{ms['crossover_hz']:.0f} | {ms['disk_margin']:.3f} |", "",
                  f"![loop]({figures.get('loop', '')})", ""]
        cs, cg = lp.get("closed_loop_small_step"), lp.get("closed_loop_small_step_gauge_noise_free")
        if cs and cg:
            ls, lg = lp["linear_step_self"], lp["linear_step_gauge"]
            lines += ["0.1 um reference step at 50 V, nonlinear plant (true x):", "",
                      "| sensor | overshoot, % | settling (2 %), ms | linear prediction |", "|---|---|---|---|",
                      f"| self-sensed (with its noise) | {cs['overshoot_percent']:.2f} | {cs['settling_s'] * 1e3:.1f} | "
                      f"{ls['overshoot_percent']:.3f} %, {ls['settling_s'] * 1e3:.1f} ms |",
                      f"| gauge chain (noise-free) | {cg['overshoot_percent']:.2f} | {cg['settling_s'] * 1e3:.1f} | "
                      f"{lg['overshoot_percent']:.3f} %, {lg['settling_s'] * 1e3:.1f} ms |", "",
                      f"![closed_loop]({figures.get('closed_loop', '')})", ""]
    return "\n".join(lines) + "\n"


def write_selfsense_outputs(out, data, rec, errs, noise, la):
    """Stage figures, noise and loop figures, report.md and selfsense.json into ``out``; {name: file}."""
    out.mkdir(parents=True, exist_ok=True)
    figures = {}
    for s in data["stages"]:
        est, _ = errs[s["name"]]
        figures[s["name"]] = plot_stage(rec.t_s, rec.x_m, est, s, data["stroke_m"], out / f"stage_{s['name']}.png").name
    figures["noise"] = plot_noise(noise, out / "noise.png").name
    if la is not None:
        figures["loop"] = plot_loop(la, out / "loop.png").name
        if "closed_loop" in la:
            figures["closed_loop"] = plot_closed_loop(la["closed_loop"], la["closed_loop_gauge"],
                                                      out / "closed_loop.png").name
    write_text(out / "report.md", _report(data, figures))
    figures["report"] = "report.md"
    from .html import write_html_report
    figures["report_html"] = write_html_report(out / "report.md").name
    write_json(out / "selfsense.json", {**data, "figures": figures})
    return figures
