"""Figures and report of the self-sensing study (:mod:`workbench.selfsense.run`)."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .design_figures import db, unwrapped_deg  # noqa: E402
from .output import save_figure, write_json, write_text  # noqa: E402

BOX = dict(boxstyle="round", fc="white", ec="0.7", alpha=0.9)   # text boxes over data

__all__ = ["plot_stage", "plot_noise", "plot_loop", "plot_closed_loop", "write_selfsense_outputs", "plot_force",
           "write_force_outputs", "plot_dynamics", "write_dynamics_outputs"]

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
             f"{data['identification_duration_s']:.0f} s record.", ""]
    # the controller's preflight against the plant (verify's), as the console's WARNING lines
    lines += [f"- **WARNING:** {w} (`--strict` refuses it)" for w in data.get("warnings") or ()]
    lines += [""] if data.get("warnings") else []
    lines += ["| stage | error p-p, nm | % of stroke | error RMS, nm | figure |", "|---|---|---|---|---|"]
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


# ---- force self-sensing (`workbench selfsense --force`) ------------------------------------------

def plot_force(data, path):
    """Estimated against true force: the simulated step (absolute and tared, its error) and the Table 1 runs."""
    arr, step, ins = data["_arrays"], data["force_step"], data["instron"]
    t, f_true = arr["t_s"], arr["f_true_n"]
    last = list(arr["estimates_n"])[-1]
    est = arr["estimates_n"][last]
    fig = plt.figure(figsize=(11, 7.5))
    gs = fig.add_gridspec(2, 2, width_ratios=[1.5, 1])
    ax1 = fig.add_subplot(gs[0, 0])
    ax2 = fig.add_subplot(gs[1, 0], sharex=ax1)
    ax3 = fig.add_subplot(gs[:, 1])
    k = _thin(t.size)
    ax1.plot(t[k], f_true[k], color="0.2", lw=1.6, label="true F_e (simulation)")
    for name, e in arr["estimates_n"].items():
        if name != last:
            ax1.plot(t[k], e[k], lw=0.6, alpha=0.6, label=f"estimate, {name.replace('_', ' ')}")
    ax1.plot(t[k], est[k], color="C3", lw=1.0, label="estimate, all stages (from reset)")
    ax1.plot(t[k], est[k] - arr["tare_n"], color="C1", lw=1.0, ls="--", label="estimate, all stages, tared 1 s before")
    ax1.set_ylabel("environmental force F_e, N")
    ax1.set_title(f"{step['force_n']:+.0f} N force step on the stack held at {step['bias_v']:.0f} V")
    ax1.legend(fontsize=7, loc="lower left", ncol=2)
    lo = min(float(np.min(f_true)), 0.0)
    ax1.set_ylim(lo - 0.5 * abs(step["force_n"]), max(float(np.max(f_true)), 0.0) + 0.5 * abs(step["force_n"]))
    tol = step["target_fraction"] * abs(step["force_n"])
    ax2.plot(t[k], (est - f_true)[k], color="C3", lw=0.8, label="from reset")
    ax2.plot(t[k], (est - arr["tare_n"] - f_true)[k], color="C1", lw=0.8, label="tared")
    ax2.axhspan(-tol, tol, color="C2", alpha=0.15, label=f"+/- {100 * step['target_fraction']:.0f} % of the step")
    ax2.axvline(step["step_at_s"] + 1.0, color="0.5", lw=0.6, ls=":")
    ax2.set_ylim(-8 * tol, 8 * tol)
    ax2.set_xlabel("time, s")
    ax2.set_ylabel("estimate - true, N")
    ax2.legend(fontsize=7, loc="upper left")
    s4 = step["stages"][-1]
    ax2.text(0.98, 0.04, f"1 s to end: {s4['tared_error_max_n']['1s_end']:.2f} N tared, "
             f"{s4['abs_error_max_n']['1s_end']:.2f} N from reset\n1-5 s: {s4['tared_error_max_n']['1_5s']:.2f} N tared",
             transform=ax2.transAxes, ha="right", va="bottom", fontsize=8, bbox=BOX)
    runs = ins["runs"]
    true = np.array([-r["force_n"] for r in runs])
    sim = np.array([-r["simulated"]["peak_force_estimate_n"] for r in runs])
    cfg = np.array([r["config"] for r in runs])
    for c, mk in (("R_in", "o"), ("R_out", "s")):
        m = cfg == c
        ax3.plot(true[m], sim[m], mk, mfc="none", color="C0", label=f"simulated run, {c.replace('_', ' ')}")
    ro = [r for r in runs if "measured_back_emf" in r]
    ax3.plot([-r["force_n"] for r in ro], [-r["measured_back_emf"]["peak_force_estimate_n"] for r in ro], "^",
             color="C3", label="measured back EMF, model gain")
    ax3.plot([-r["force_n"] for r in ro], [-r["measured_back_emf"]["calibrated_leave_one_out"]["peak_force_estimate_n"]
                                            for r in ro], "v", color="C2", label="measured back EMF, gain of the other runs")
    h = ins.get("held_out")
    if h is not None:
        hf = [-d["force_n"] for d in h["runs"]]
        pure = h["nested_pure_back_emf"]
        ax3.plot(hf, [-e for e in pure["estimate_n"]], "P", ms=6, color="C5",
                 label=f"own back EMF only (self-sensing), nested: max {100 * pure['max_error_fraction']:.1f} %")
        ax3.plot(hf, [-e for e in h["reported"]["loo"]["estimate_n"]], "D", ms=5, color="C1",
                 label=f"{h['reported_form_title']}, held out: max {100 * h['reported']['loo']['max_error_fraction']:.1f} %")
        ax3.plot(hf, [-e for e in h["nested"]["estimate_n"]], "x", color="C4",
                 label=f"any form (gauge read), chosen without the run: max {100 * h['nested']['max_error_fraction']:.1f} %")
    every = np.concatenate([true, sim, [-r["measured_back_emf"]["peak_force_estimate_n"] for r in ro]])
    span = np.array([np.floor(every.min() / 50) * 50 - 25, np.ceil(every.max() / 50) * 50 + 25])
    ax3.plot(span, span, color="0.3", lw=0.8)
    ax3.fill_between(span, span * (1 - ins["target_fraction"]), span * (1 + ins["target_fraction"]), color="0.5",
                     alpha=0.15, label=f"+/- {100 * ins['target_fraction']:.0f} %")
    ax3.set_xlim(*span)
    ax3.set_ylim(*span)
    ax3.set_aspect("equal")
    ax3.set_xlabel("Table 1 peak compression, N")
    ax3.set_ylabel("estimated peak compression, N")
    ax3.set_title("Instron runs (seed 000 Table 1)")
    ax3.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14))     # below: the points fill the axes
    for ax in (ax1, ax2, ax3):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def _force_report(data, figure):
    step, ins = data["force_step"], data["instron"]
    yes = lambda b: "met" if b else "MISSED"    # noqa: E731
    lines = ["# Force self-sensing", "",
             f"Plant `{data['plant']}`. Force from the terminal voltage and the drift-compensated charge through "
             "the seed 000 model read backwards (V_h by the exact PI inverse of C_h and its creep branches, "
             "V_p = V_t - V_h, x from eq. 9, F_e from eq. 5).", "",
             f"![]({figure})", "",
             f"## {step['force_n']:+.0f} N step at {step['bias_v']:.0f} V ({step['sample_hz']:.0f} Hz record)", "",
             "| stage | max error 1 s-end, N | tared 1-2 s, N | tared 1-5 s, N | tared 1 s-end, N | x error, nm | x = k_q2x q error, nm |",
             "|---|---|---|---|---|---|---|"]
    for s in step["stages"]:
        a, tr = s["abs_error_max_n"], s["tared_error_max_n"]
        lines.append(f"| {s['title']} | {a['1s_end']:.2f} | {tr['1_2s']:.2f} | {tr['1_5s']:.2f} | {tr['1s_end']:.2f} | "
                     f"{s['x_error_max_m'] * NM:.1f} | {s['x_from_charge_only_error_max_m'] * NM:.1f} |")
    tol = step["target_fraction"] * abs(step["force_n"])
    lines += ["", f"Target {tol:.1f} N ({100 * step['target_fraction']:.0f} %) after 1 s: tared over 1-5 s "
              f"**{yes(step['target_met_tared_1_5s'])}**; tared to the end of the record **{yes(step['target_met_tared_1s_end'])}**; "
              f"from the reset **{yes(step['target_met_absolute_1s_end'])}**.", "",
              "## Instron runs (Table 1)", "",
              "| serial | run | config | F, N | simulated estimate, N | error % | model x / measured x, um | "
              "model / measured back EMF, V | from measured back EMF, N (error %) | gain of the other runs, N (error %) |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in ins["runs"]:
        s = r["simulated"]
        m = r.get("measured_back_emf")
        mtxt = f"{m['peak_force_estimate_n']:.1f} ({100 * m['error_fraction']:+.1f})" if m else "n/a (V_t = 0, no charge in Table 1)"
        ctxt = (f"{m['calibrated_leave_one_out']['peak_force_estimate_n']:.1f} "
                f"({100 * m['calibrated_leave_one_out']['error_fraction']:+.1f})") if m else ""
        flag = " (printed x/gauge swapped?)" if r["suspected_swap"] else ""
        lines.append(f"| {r['serial']} | {r['run']} | {r['config'].replace('_', ' ')} | {r['force_n']:.1f} | "
                     f"{s['peak_force_estimate_n']:.1f} | {100 * s['error_fraction']:+.2f} | "
                     f"{s['model_displacement_m'] * UM:.3f} / {r['displacement_m'] * UM:.3f}{flag} | "
                     f"{s['model_back_emf_v']:.2f} / {r['back_emf_v']:.2f} | {mtxt} | {ctxt} |")
    lines += ["", f"Target: peak force within {100 * ins['target_fraction']:.0f} %: simulated runs "
              f"(max {100 * ins['simulated_max_error_fraction']:.2f} %) **{yes(ins['target_met_simulated'])}**; "
              f"measured R out back EMF with the model's {ins['force_per_back_emf_model_n_per_v']:.2f} N/V "
              f"(max {100 * ins['measured_r_out_max_error_fraction']:.1f} %, mean "
              f"{100 * ins['measured_r_out_mean_error_fraction']:+.1f} %) **{yes(ins['target_met_measured_r_out'])}**; "
              f"with the gain identified on the other runs (seed 002 eq. 2.32; max "
              f"{100 * ins['measured_r_out_calibrated_max_error_fraction']:.1f} %, RMS "
              f"{100 * ins['measured_r_out_calibrated_rms_error_fraction']:.1f} %) "
              f"**{yes(ins['target_met_measured_r_out_calibrated'])}**.", ""]
    if "held_out" in ins:
        lines += _table1_held_out_report(ins["held_out"], ins["held_out_displacement_column"], yes)
    return "\n".join(lines) + "\n"


def _table1_held_out_report(h, hd, yes):
    """The Table 1 R out runs held out: swap decision, each form's loo/loso errors, nested choice, spread."""
    pct = lambda a: "n/a" if a is None or not np.isfinite(a) else f"{100 * a:.2f}"    # noqa: E731
    from ..selfsense.table1 import TABLE1_FORM_TITLES
    pure, mixed = h["nested_pure_back_emf"], h["nested_back_emf_with_gauge"]
    lines = ["## Table 1 R out runs held out (back EMF and gauge)", "",
             f"Force self-sensing from the run's own back EMF (pure back EMF: F = G V, G of the other runs or of the "
             f"serial's other runs, chosen without the run): max {pct(pure['max_error_fraction'])} %, RMS "
             f"{pct(pure['rms_error_fraction'])} % **{yes(h['target_met_nested_pure_back_emf'])}**. With the run's "
             f"gauge read as well (back EMF with gauge: {', '.join(sorted(set(mixed['chosen_form'])))} chosen): max "
             f"{pct(mixed['max_error_fraction'])} % **{yes(h['target_met_nested_back_emf_with_gauge'])}**. The forms "
             f"below that meet the target read the run's gauge; the one marked (reported) reads no back EMF of the run "
             f"at all ({h['reported_form_title']}).", ""]
    if "nested_pure_back_emf_hysteresis_inverse" in h:
        hi = h["nested_pure_back_emf_hysteresis_inverse"]
        lines += [f"With the back EMF also read through the hysteresis inverse, each serial's earlier runs' state "
                  f"carried (back_emf_hysteresis_inverse among the pure back-EMF forms, chosen without the run): max "
                  f"{pct(hi['max_error_fraction'])} %, RMS {pct(hi['rms_error_fraction'])} % "
                  f"**{yes(h['target_met_nested_pure_back_emf_hysteresis_inverse'])}** (without it: max "
                  f"{pct(pure['max_error_fraction'])} %, RMS {pct(pure['rms_error_fraction'])} %). This form enters "
                  f"only that nested choice, not the any-form choice nor the reported form below.", ""]
    for d in h["runs"]:
        if d["swap"]:
            lines.append(f"{d['serial']} run {d['run']} is read with its gauge and displacement exchanged, decided on the "
                         f"gauge alone: as printed gauge x calibration is {100 * d['gauge_disagreement_printed']:.0f} % off "
                         f"the displacement, exchanged {100 * abs(d['gauge_disagreement_swapped']):.1f} %; V/x "
                         f"{d['v_per_x_printed_v_per_m'] * 1e-6:.2f} V/um printed, "
                         f"{d['v_per_x_swapped_v_per_m'] * 1e-6:.2f} V/um exchanged, the serial's other runs "
                         f"{d['v_per_x_others_v_per_m'] * 1e-6:.2f} V/um.")
    lines += ["", "| form | what it reads | loo max % | loo RMS % | loso max % | loso RMS % | x from the displacement "
              "column: loso max % |", "|---|---|---|---|---|---|---|"]
    for form, r in h["forms"].items():
        mark = " (reported)" if form == h["reported_form"] else ""
        lines.append(f"| {form}{mark} | {TABLE1_FORM_TITLES[form]} | {pct(r['loo']['max_error_fraction'])} | {pct(r['loo']['rms_error_fraction'])} | "
                     f"{pct(r['loso']['max_error_fraction'])} | {pct(r['loso']['rms_error_fraction'])} | "
                     f"{pct(hd['forms'][form]['loso']['max_error_fraction'])} |")
    n = h["nested"]
    sp = h["spreads"]
    lines += ["", f"The reported form was chosen among the forms other than back_emf_hysteresis_inverse on the same runs. "
              f"Any of those forms chosen per run without it (nested "
              f"leave-one-out, least inner RMS): max {pct(n['max_error_fraction'])} %, RMS {pct(n['rms_error_fraction'])} % "
              f"**{yes(h['target_met_nested'])}** (chosen: {', '.join(sorted(set(n['chosen_form'])))}). "
              f"Leave one serial out, chosen without the serial's forces: max {pct(h['nested_loso']['max_error_fraction'])} % "
              f"**{yes(h['target_met_nested_loso'])}** (chosen: {', '.join(sorted(set(h['nested_loso']['chosen_form'])))}).",
              "", f"Share of new runs beyond {100 * h['target_fraction']:.0f} % if the errors are normal with the held-out RMS: "
              f"{pct(sp['loo']['exceed_target_fraction_normal'])} % (loo), {pct(sp['loso']['exceed_target_fraction_normal'])} % (loso). "
              f"Repeat-run scatter of F/V: {pct(sp['loo']['pooled_f_per_v_relative_std'])} % (pooled within serials).", ""]
    return lines


def write_force_outputs(out, data):
    """force.png, force_report.md (and its self-contained force_report.html) and force.json into ``out``;
    {name: file}. ``data['_arrays']`` is not written."""
    from .html import write_html_report
    out.mkdir(parents=True, exist_ok=True)
    figures = {"force": plot_force(data, out / "force.png").name}
    write_text(out / "force_report.md", _force_report(data, figures["force"]))
    figures["report"] = "force_report.md"
    figures["report_html"] = write_html_report(out / "force_report.md").name
    write_json(out / "force.json", {**{k: v for k, v in data.items() if k != "_arrays"}, "figures": figures})
    return figures


# ---- identified dynamics (`workbench selfsense --dynamics`) ----------------------------------------

def plot_dynamics(data, path):
    """K D(s) and H(s): model-derived beside identified (Bode), and the dynamic estimators' errors on the staircase."""
    resp, rec = data["_arrays"]["responses"], data["_arrays"]["records"]
    f = resp["freq_hz"]
    fig = plt.figure(figsize=(11, 8.5))
    gs = fig.add_gridspec(3, 2, height_ratios=[1, 0.7, 1])
    # Bode conventions (dB, unwrapped phase): K D in dB re 1 um/V (as the linearize figure), H in dB (V/V).
    for col, (key, title, scale, unit) in enumerate((("kd", "K D(s) = x / V_in", 1e6, "dB re 1 um/V"),
                                                     ("h", "H(s) = V_out / V_in", 1.0, "dB (V/V)"))):
        axm = fig.add_subplot(gs[0, col])
        axp = fig.add_subplot(gs[1, col], sharex=axm)
        ref = None
        for src, color, ls in (("model", "C0", "-"), ("identified", "C3", "--")):
            y = np.asarray(resp[f"{key}_{src}"])
            ph = unwrapped_deg(y)
            if ref is None:
                ref = ph
            else:  # the identified curve on the model's branch (within 180 deg of it at the first point)
                ph = ph - 360.0 * np.round((ph[0] - ref[0]) / 360.0)
            axm.semilogx(f, db(y * scale), color=color, ls=ls, label=f"{src}")
            axp.semilogx(f, ph, color=color, ls=ls)
        axm.set_title(title)
        axm.set_ylabel(f"magnitude, {unit}")
        axp.set_ylabel("phase, deg (unwrapped)")
        axp.set_xlabel("frequency, Hz")
        axm.legend(fontsize=8)
        for ax in (axm, axp):
            ax.grid(alpha=0.3, which="both")
    ax = fig.add_subplot(gs[2, :])
    t = rec["t_s"]
    c = data["comparison"]
    for key, color, label in (("static", "0.6", "static estimate (stage 3)"), ("model", "C0", "dynamic, model E(s)"),
                              ("identified", "C3", "dynamic, identified E(s)")):
        tb, lo, hi = _envelope(t, (rec[f"{key}_m"] - rec["x_m"]) * NM)
        ax.fill_between(tb, lo, hi, color=color, alpha=0.5 if key != "static" else 0.3, lw=0.5,
                        label=f"{label}: {c[key]['error_rms_m'] * NM:.1f} nm RMS, {c[key]['error_pp_m'] * NM:.0f} nm p-p")
    ax.axhline(0, color="0.4", lw=0.6)
    ax.set_xlabel("time, s")
    ax.set_ylabel("estimate - true x, nm")
    ax.set_title(f"Staircase record neither fit saw: identified/model RMS = {c['ratio_rms_identified_over_model']:.2f}")
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def write_dynamics_outputs(out, data):
    """dynamics.png, dynamics_report.md (and dynamics_report.html) and dynamics.json into ``out``; {name: file}."""
    out.mkdir(parents=True, exist_ok=True)
    figures = {"dynamics": plot_dynamics(data, out / "dynamics.png").name}
    dyn, c = data["dynamics"], data["comparison"]
    kd, h = dyn["kd"], dyn["h_r"]
    fmt = lambda g, s: f"{g:.4g} +/- {s:.2g}"   # noqa: E731
    lines = ["# Identified dynamics of the self-sensing estimator", "",
             f"Plant `{data['plant']}`. K D(s) and H(s) fitted on a simulated 20 V step record (seed 002 sec. 2.5.3), "
             f"orders {dyn['order_kd']} and {dyn['order_h']} by BIC; the dynamic estimators compared on a "
             f"{data['evaluation_duration_s']:.0f} s staircase neither fit saw.", "", f"![]({figures['dynamics']})", "",
             f"K: identified {kd['dc_gain'] * UM:.5f} +/- {kd['sigma_dc_gain'] * UM:.1g} um/V (20 V step secant), "
             f"model {data['model']['k_m_per_v'] * UM:.5f} um/V (small signal at 50 V).", "",
             "| relaxation | K D: gain, m/V | tau, s | H_r: gain, V/V | tau, s |", "|---|---|---|---|---|",
             f"| direct | {fmt(kd['direct'], kd['sigma_direct'])} | | {fmt(h['direct'], h['sigma_direct'])} | |"]
    for i in range(max(len(kd["gains"]), len(h["gains"]))):
        a = (f"{fmt(kd['gains'][i], kd['sigma_gains'][i])} | {fmt(kd['time_constants_s'][i], kd['sigma_time_constants_s'][i])}"
             if i < len(kd["gains"]) else " | ")
        b = (f"{fmt(h['gains'][i], h['sigma_gains'][i])} | {fmt(h['time_constants_s'][i], h['sigma_time_constants_s'][i])}"
             if i < len(h["gains"]) else " | ")
        lines.append(f"| {i + 1} | {a} | {b} |")
    lines += ["", "| estimate | error RMS, nm | error p-p, nm |", "|---|---|---|"]
    for key, label in (("static", "static (stage 3)"), ("model", "dynamic, model-derived E"),
                       ("identified", "dynamic, identified E")):
        lines.append(f"| {label} | {c[key]['error_rms_m'] * NM:.1f} | {c[key]['error_pp_m'] * NM:.1f} |")
    lines += ["", f"Target: identified within {data['target_ratio']:.1f}x the model-derived error (RMS): ratio "
              f"{c['ratio_rms_identified_over_model']:.2f}, **{'met' if data['target_met'] else 'MISSED'}**.", ""]
    write_text(out / "dynamics_report.md", "\n".join(lines) + "\n")
    figures["report"] = "dynamics_report.md"
    from .html import write_html_report
    figures["report_html"] = write_html_report(out / "dynamics_report.md").name
    write_json(out / "dynamics.json", {**{k: v for k, v in data.items() if k != "_arrays"}, "figures": figures})
    return figures
