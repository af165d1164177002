"""Study report sections: budgets and where they came from, the binding constraint, the nominal loop, failures.

Lines of GitHub Markdown for :func:`workbench.report.markdown.write_report` (through the
summary's ``study_sections``), and the whole report of a study that failed.
"""

import math
from pathlib import Path

import numpy as np

__all__ = ["study_lines", "failure_report"]

_CONSTRAINT_TEXT = {
    "noise budget": "the gauge-noise budget (RMS lead of the command over the modelled stack voltage, V)",
    "phase margin": "the phase-margin target on the worst member (deg)",
    "gain margin": "the gain-margin target on the worst member (dB)",
    "overshoot": "the nominal small-step overshoot limit (%)",
    "crossover search range": "the top of the crossover search range (loop_shape.fc_max_hz, Hz)",
    "triangle tracking": "the triangle target's tracking budget on the nominal loop (fraction of stroke RMS)",
}


def _g(v, fmt=".3g"):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    if isinstance(v, (list, tuple)):
        return ", ".join(_g(x, fmt) for x in v)
    return format(v, fmt)


def _budget_lines(summary):
    b = summary["budgets"]
    noise, win, slew = b["noise_command_v"], b["current_window"], b["slew_v_per_s"]
    window = ("none (series resistor out)" if win["value"] is None else
              "headroom {1:.3g} V up, {2:.3g} V down; alpha {0:.3g}".format(*win["value"]))
    lines = ["## Budgets", "",
             "Derived from the plant file unless the study overrides them ("
             + ("overrides: " + ", ".join(f"`{k} = {v}`" for k, v in summary["overrides"].items())
                if summary.get("overrides") else "no `--set` overrides") + ").", "",
             "| budget | value | from | derivation |", "|---|---|---|---|",
             f"| gauge-noise command budget | {_g(noise['value'])} V RMS | {noise['source']} | {noise['derivation']} |",
             f"| current-limit window | {window} | "
             f"{win['source']} | {win['derivation']} |",
             f"| slew limits | {slew['value'][0]:.4g} V/s up, {slew['value'][1]:.4g} V/s down | {slew['source']} | "
             f"{slew['derivation']} |"]
    rn = b.get("reading_noise_v")
    if rn:
        lines.append(f"| noise of one reading (the sensor's) | {_g(rn['value'], '.4g')} V RMS | {rn['source']} | "
                     f"{rn['derivation']} |")
    tr = b.get("triangle_tracking")
    if tr:
        value = "none" if tr["value"] is None else f"{100 * tr['value']:.3g} % of stroke RMS"
        lines.append(f"| triangle tracking | {value} | {tr['source']} | {tr['derivation']} |")
    return lines + [""]


def _sensor_lines(summary):
    s = summary.get("sensor")
    if not s or s["kind"] == "gauge":
        return []
    n = s["noise_per_reading_m"]
    e = s["error_rms_m"]
    lines = ["## Sensor", "",
             f"Feedback on the **{s['kind']}** signal (`[sensor] kind`); each member's loop is taken on its path: "
             f"{s['member_path']} (R: the charge path over the gauge path of the nominal, from the self-sensing "
             f"model; `workbench/study/sensor.py`).", "",
             "| | gauge | charge estimate | reading |", "|---|---|---|---|",
             f"| noise per reading | {n['gauge'] * 1e9:.3g} nm | {n['charge'] * 1e9:.3g} nm | "
             f"{n['reading'] * 1e9:.3g} nm |",
             f"| error RMS over {e['band_hz'][0]:.2g}-{e['band_hz'][1]:.4g} Hz | {e['gauge_error_rms_m'] * 1e9:.3g} nm | "
             f"{e['charge_error_rms_m'] * 1e9:.3g} nm | "
             + (f"{e['fused_error_rms_m'] * 1e9:.3g} nm |" if "fused_error_rms_m" in e else "(the charge's) |"), ""]
    b = s.get("blend")
    if b:
        lines += [f"Blend crossover **{b['crossover_hz']:.3g} Hz** ({'chosen from the two error spectra' if b['source'] == 'spectra' else 'given by the study'}: "
                  f"the charge's drift over a {e['drift_record_s']:.0f} s staircase, {e['drift_pp_m'] * 1e9:.3g} nm "
                  f"p-p, against the gauge's white noise); firmware: {b['form']}, a = {b['pole']:.6f}.", ""]
    ls = summary.get("designs", {}).get("loop_shape", {})
    t = ls.get("tracking")
    if t:
        lines += [f"Triangle tracking on the nominal loop, fed the triangle as it is (no reference lead): "
                  f"{100 * t['rms']:.3g} % of stroke RMS (limit {100 * t['limit']:.3g} %, {t['harmonics']} odd "
                  f"harmonics, |S_k r_k|); {len(t['ruled_out'])} shapes were ruled out by it at their highest "
                  f"admissible crossover. This is the search's constraint: it does not count the lead."]
        if t.get("rms_with_lead") is not None:
            lines += [f"With the velocity feedforward the export carries on the planned slope (ref_lead_s = "
                      f"{t['lead_s'] * 1e3:.4g} ms = 1/K_v; r + v L fed on ramps), the same nominal loop predicts "
                      f"{100 * t['rms_with_lead']:.3g} % of stroke RMS (|S_k (1 - D_k L L_k) r_k|, D_k the forward "
                      f"difference (e^(j w_k T) - 1) / T)."]
        lines += [""]
    return lines


def _binding_lines(summary):
    b = summary.get("binding")
    if not b:
        return []
    name = b["constraint"]
    lines = ["## Binding constraint", ""]
    if name == "crossover search range":
        lines.append(f"The crossover is bound by **{_CONSTRAINT_TEXT[name]}**: the best shape meets every "
                     f"constraint at the top of the range, f_c = {b['value']:.0f} Hz.")
    else:
        lines.append(f"The crossover is bound by **{name}** ({_CONSTRAINT_TEXT[name]}): at the next nominal "
                     f"crossover of the grid, f_c = {b['at_fc_hz']:.0f} Hz, it reaches {b['value']:.4g} against "
                     f"the limit {b['limit']:.4g} {b['unit']}.")
    r = b.get("relaxed")
    if r:
        if "error" in r:
            lines.append(f"With it {r['by']} ({r['field']} = {_g(r['limit'])}): no design ({r['error']}).")
        else:
            lines.append(f"With it {r['by']} ({r['field']} = {_g(r['limit'])}): lowest crossover over the family "
                         f"{r['crossover_hz_min']:.0f} Hz (now {summary['designs']['loop_shape']['crossover_hz']:.0f}"
                         f" Hz), nominal f_c {r['fc_hz']:.0f} Hz, then bound by {r['then_binding']}.")
    return lines + [""]


def _nominal_lines(summary):
    n = summary["nominal_plant"]
    ls = summary["designs"]["loop_shape"]
    lines = ["## Nominal loop", "",
             f"Nominal plant (one definition for study, sweep, verify and selfsense): {n['definition']}: "
             f"bias {n['bias_v']:g} V, C_h {n['capacitance_f'] * 1e6:.3g} uF, gauge {n['gauge_v_per_m']:.4g} V/m, "
             f"{n['states']} states ({n['creep_states_truncated']} creep states below 5 Hz truncated)."]
    for key, what in (("nominal", "discrete controller"), ("nominal_quantized", "quantized controller")):
        if key in ls:
            m = ls[key]
            lines.append(f"- {what}: crossover {_g(m['crossover_hz'], '.1f')} Hz, PM {_g(m['phase_margin_deg'], '.1f')}"
                         f" deg at {_g(m['pm_freq_hz'], '.0f')} Hz, GM {_g(m['gain_margin_db'], '.1f')} dB at "
                         f"{_g(m['gm_freq_hz'], '.0f')} Hz")
    c = summary.get("family_cache", {})
    lines += ["", f"Family: {'read from the cache' if c.get('hit') else 'computed'} in {c.get('seconds', 0):.1f} s"
              + (f" (`{c['path']}`)" if c.get("path") else " (no cache)") + ".", ""]
    return lines


def study_lines(summary):
    """Markdown lines on budgets, the binding constraint and the nominal loop of a finished study."""
    return (_budget_lines(summary) + _sensor_lines(summary) + _startup_lines(summary) + _binding_lines(summary)
            + _nominal_lines(summary))


def _startup_lines(summary):
    """The firmware startup settings the export carries (``firmware_startup``), one line each."""
    fw = summary.get("firmware_startup")
    if not fw:
        return []
    wait = fw.get("startup_wait_s")
    lines = ["## Firmware startup (carried by the export)", ""]
    lines.append("- wait before closing: " + ("none derived (the reading does not settle; verify closes at its "
                                                  "floor)" if wait is None else
                                                  f"{wait:.6g} s (the reading's own settle after the start; the "
                                                  f"verify harness's 1 s creep floor is its scenario's, not exported)"))
    lines.append(f"- reference lead `ref_lead_s` = {fw['ref_lead_s'] * 1e3:.5g} ms = 1/K_v: velocity feedforward "
                 f"on the trajectory generator's planned slope (ramps: r + v L), not on steps or tones")
    lines.append(f"- gauge curvature beta = {fw['gauge_curvature_per_m']:.6g} 1/m (firmware's gauge metres: "
                 f"x = x_lin - beta (x_lin - x_c)^2)")
    return lines + [""]


def _fix_lines(summary):
    f = summary["failure"]
    fix = f.get("fix")
    lines = ["## What would make it pass", ""]
    if not fix:
        lines.append(f"- {f.get('message', '')}")
        return lines + [""]
    budget = summary["budgets"]["noise_command_v"]
    for step in fix["changes"]:
        text = f"- relax {step['constraint']}: `{step['field']}` to {_g(step['limit'])}"
        r_ohm = budget.get("series_resistance_ohm") or 0.0
        if step["constraint"] == "noise budget" and budget["source"] == "plant" and r_ohm > 0:
            text += (f" (the budget is R min(I_source, I_sink) / 3: an amplifier limited at "
                     f"{3 * step['limit'] / r_ohm * 1e3:.3g} mA or more both ways, e.g. "
                     f"`--set electrical.current_limit_source_a={3 * step['limit'] / r_ohm * 1e3:.3g}mA`; "
                     f"another amplifier also changes the family's slewing points: re-run with that `--set` "
                     f"to confirm)")
        lines.append(text)
    if fix["passes"]:
        lines.append(f"\nWith these changes the lowest crossover over the family is {fix['crossover_hz_min']:.0f} Hz "
                     f">= {f['limit']:g} Hz: the study passes.")
    else:
        lines.append(f"\nEven with these changes the lowest crossover is {fix['crossover_hz_min']:.0f} Hz < "
                     f"{f['limit']:g} Hz: lower `targets.min_crossover_hz` or change the plant.")
    lines.append(f"Or lower `targets.min_crossover_hz` to {f['value']:.0f} Hz or less.")
    return lines + [""]


def failure_report(out, spec, summary, freq, family, ub, ls):
    """Write ``report.md`` of a study whose best design misses a target; returns (path, one-line message)."""
    from ..report import design_figures as figs
    from ..report.output import write_text
    from .run import _loops_discrete, _members_table
    f = summary["failure"]
    lines = [f"# Design study `{spec.name}`: FAILED", ""]
    if ls is None:
        message = f"no design meets the targets: {f['message']}"
        lines += [f"No structured controller was found: {f['message']}", ""]
    else:
        message = (f"the best design's lowest crossover over the family is {f['value']:.0f} Hz, below "
                   f"targets.min_crossover_hz = {f['limit']:g} Hz (bound by {summary['binding']['constraint']})")
        lines += [f"The best design found misses **targets.min_crossover_hz = {f['limit']:g} Hz**: its lowest "
                  f"crossover over the family is {f['value']:.0f} Hz, bound by **{summary['binding']['constraint']}**. "
                  f"Nothing was exported.", ""]
        lines += _fix_lines(summary)
        p = ls.params
        d = summary["designs"]["loop_shape"]
        lines += ["## Best design found", "",
                  f"PI with integral corner f_c/{p['integral_ratio']:g}, lead ratio {p['lead_ratio']:g}, roll-off at "
                  f"{p['rolloff_ratio']:g} f_c; nominal f_c {p['fc_hz']:.0f} Hz, gain {p['k']:.4g} V per firmware V; "
                  f"nominal crossover {d['nominal']['crossover_hz']:.1f} Hz, PM {d['nominal']['phase_margin_deg']:.1f} "
                  f"deg; worst PM {ls.worst['phase_margin_deg']['value']:.1f} deg "
                  f"({ls.worst['phase_margin_deg']['member']}), worst GM {ls.worst['gain_margin_db']['value']:.1f} dB "
                  f"({ls.worst['gain_margin_db']['member']}).", ""]
        lines += _binding_lines(summary)
        loops = _loops_discrete(ls.controller_d, freq, family.members, 1)
        summary["figures"]["loop_bode"] = str(figs.plot_loop_family(freq, loops, Path(out) / "loop_bode.png",
                                                                    ls.params))
        lines += ["![loop](loop_bode.png)", ""]
    lines += _budget_lines(summary)
    lines += ["## Family", "",
              f"{summary['members']} members (describing functions and small-signal models over the serials, C_p and "
              f"gauge tolerances), {summary['excluded_points']} slewing points left out; uncertainty weight order "
              f"{summary['uncertainty']['weight']['order']}.", ""]
    if ls is not None:
        lines += ["| serial | member | PM (deg) | GM (dB) | crossover (Hz) |", "|---|---|---|---|---|"]
        for r in _members_table(ls.rows, freq, family.members):
            cross = (f"{r['crossover_min_hz']:.0f}-{r['crossover_max_hz']:.0f}" if np.isfinite(r["crossover_min_hz"])
                     else f"none (linear only up to {r['linear_up_to_hz']:.2g} Hz)")
            lines.append(f"| {r['serial']} | {r['member']} | {_g(r['phase_margin_deg'], '.1f')} | "
                         f"{_g(r['gain_margin_db'], '.1f')} | {cross} |")
        lines.append("")
    return write_text(Path(out) / "report.md", "\n".join(lines)), message
