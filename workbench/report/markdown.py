"""The study report: one Markdown file beside its PNG figures."""

from pathlib import Path

import numpy as np

__all__ = ["write_report"]


def _f(v, fmt=".1f"):
    return "n/a" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, fmt)


def _worst_rows(worst):
    return [
        ("phase margin (deg)", _f(worst["phase_margin_deg"]["value"]), worst["phase_margin_deg"]["member"]),
        ("gain margin (dB)", _f(worst["gain_margin_db"]["value"]), worst["gain_margin_db"]["member"]),
        ("delay margin (us)", _f(worst["delay_margin_s"]["value"] * 1e6, ".0f"), worst["delay_margin_s"]["member"]),
        ("disk margin alpha", _f(worst["disk_margin"]["value"], ".2f"), worst["disk_margin"]["member"]),
        ("peak |S| (dB)", _f(worst["s_peak_db"]["value"]), worst["s_peak_db"]["member"]),
        ("peak |T| (dB)", _f(worst["t_peak_db"]["value"]), worst["t_peak_db"]["member"]),
        ("crossover, lowest (Hz)", _f(worst["crossover_hz_min"]["value"], ".0f"), worst["crossover_hz_min"]["member"]),
        ("crossover, highest (Hz)", _f(worst["crossover_hz_max"]["value"], ".0f"), worst["crossover_hz_max"]["member"]),
    ]


def write_report(path, spec, summary, table):
    """Write ``report.md`` for the study summary; returns its path."""
    from .output import write_text
    d = summary["designs"]
    ls = d["loop_shape"]
    p = ls["params"]
    lines = [f"# Design study `{spec.name}`", "",
             f"Plant `{summary['plant']}` (nominal) with {', '.join(f'`{s}`' for s in summary['serials']) or 'no other serials'}; "
             f"{summary['members']} family members (describing functions and small-signal models, C_p and gauge "
             f"tolerances), {summary['excluded_points']} slewing points left out. Run time {summary['seconds']:.0f} s.",
             "", "## Exported controller (structured loop shape)", "",
             f"PI with integral corner f_c/{p['integral_ratio']:g}, lead ratio {p['lead_ratio']:g}, roll-off at "
             f"{p['rolloff_ratio']:g} f_c (damping {p['rolloff_damping']:g}); nominal crossover "
             f"{p['fc_hz']:.0f} Hz, gain {p['k']:.4g} V per firmware V. Targets met on every member and on the "
             f"quantized controller: **{'yes' if ls['meets_targets'] else 'NO'}**.", "",
             "| margin | discrete | quantized | continuous (no sampling) | worst member (quantized) |",
             "|---|---|---|---|---|"]
    for (name, v_d, _), (_, v_q, m_q), (_, v_c, _) in zip(_worst_rows(ls["worst_discrete"]),
                                                         _worst_rows(ls["worst_quantized"]),
                                                         _worst_rows(ls["worst_continuous_no_sampling"])):
        lines.append(f"| {name} | {v_d} | {v_q} | {v_c} | {m_q} |")
    lines += [""] + summary.get("study_sections", [])      # budgets, binding constraint, nominal (workbench.study)
    lines += ["", "Files: " + ", ".join(f"`{Path(v).name}`" for v in summary["exported"].values()), "",
              "![loop](loop_bode.png)", "", "![S and T](sensitivity.png)", "", "![Nyquist](nyquist.png)", "",
              "Limit cycles predicted by the describing functions: "
              + ("none." if not ls["limit_cycles"] else "; ".join(
                  f"{c['amplitude_v']:.2g} V at {c['freq_hz']:.0f} Hz" for c in ls["limit_cycles"])), "",
              "## Margins per serial and amplitude (quantized controller, worst over C_p and gauge corners)", "",
              "| serial | member | PM (deg) | GM (dB) | disk alpha | crossover (Hz) |", "|---|---|---|---|---|---|"]
    for r in table:
        if not np.isfinite(r["crossover_min_hz"]):
            lines.append(f"| {r['serial']} | {r['member']} | - | - | - | none: linear only up to "
                         f"{r['linear_up_to_hz']:.2g} Hz, slews above (|L| >> 1 there) |")
            continue
        lines.append(f"| {r['serial']} | {r['member']} | {_f(r['phase_margin_deg'])} | {_f(r['gain_margin_db'])} | "
                     f"{_f(r['disk_margin'], '.2f')} | {_f(r['crossover_min_hz'], '.0f')}-"
                     f"{_f(r['crossover_max_hz'], '.0f')} |")
    ncf = d.get("coprime")
    lines += ["", "## Other designs on the same family", ""] + ([
              "- none: run with `--only loopshape`"] if ncf is None else [
              f"- Glover-McFarlane on the same shape: best achievable margin eps_max = {ncf['eps_max']:.3f}, "
              f"controller {ncf['eps']:.3f}; reduced from {ncf['order_full']} to {ncf['order_reduced']} states "
              f"(error bound {ncf['reduction_error_bound']:.3g}, measured {ncf['reduction_error_measured']:.3g}); "
              f"worst PM {_f(ncf['worst_discrete']['phase_margin_deg']['value'])} deg, GM "
              f"{_f(ncf['worst_discrete']['gain_margin_db']['value'])} dB."])
    for key, title in (("hinf", "H-infinity mixed sensitivity (slycot)"), ("convex", "Convex Youla FIR design (cvxpy)")):
        if key in d:
            h = d[key]
            if "error" in h:
                lines.append(f"- {title}: {h['error']}")
            else:
                w = h["worst_discrete"]
                lines.append(f"- {title}: gamma {h['gamma']:.3f} (weighted peaks |W_s S| {h['norms']['S']:.3f}, "
                             f"|W_ks KS| {h['norms']['KS']:.3f}, |W_t T| {h['norms']['T']:.3f}), order {h['order']}, "
                             f"crossover {_f(w['crossover_hz_min']['value'], '.0f')}-"
                             f"{_f(w['crossover_hz_max']['value'], '.0f')} Hz over the family, worst PM "
                             f"{_f(w['phase_margin_deg']['value'])} deg, GM {_f(w['gain_margin_db']['value'])} dB, "
                             f"{h['seconds']:.1f} s.")
    if "cross_check" in d:
        lines.append(f"- Cross-check on the same weights (200 Hz target, W_m on T): the H-infinity controller's "
                     f"stacked weighted norm is {d['cross_check']['hinf_over_convex_stacked_norm']:.3f} x the "
                     f"convex design's (continuous plant with a Pade delay against the exact sampled plant, "
                     f"60 FIR taps, plant without the creep branches).")
    lines += ["", "![steps](steps.png)" if "steps" in summary["figures"] else "", "",
              "What the linear analysis does not see: slewing at the current limit (members left out above; the "
              "exported controller carries a rate limit and Hanus anti-windup for it) and the shift of the mean "
              "under the asymmetric current limits. The verification runs are the check.", ""]
    return write_text(path, "\n".join(lines))
