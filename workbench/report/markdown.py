"""GitHub-flavoured Markdown for every report, and the study report (one Markdown file beside its PNGs).

The helpers (:func:`md_cell`, :func:`md_row`, :func:`md_table`, :func:`md_image`,
:func:`readable_quantity`) are the one home of what makes a report render: a ``|`` inside a cell
is escaped (GFM splits cells on every unescaped pipe, even inside code spans), a figure link is
relative to the report file, and a metric key the renderer has no label for is shown as words
with its unit (``oscillation_command_v`` -> "oscillation command", "mV"), never as a raw key.
"""

import os
import re
from pathlib import Path
from urllib.parse import quote

import numpy as np

from ..units import unit_of_key

__all__ = ["write_report", "md_cell", "md_row", "md_table", "md_image", "readable_quantity"]


def md_cell(value):
    """``value`` as the text of one GFM table cell: pipes escaped, line breaks folded to spaces."""
    text = str(value).replace("\\|", "|")          # idempotent: an already escaped pipe is escaped once
    return re.sub(r"\s*[\r\n]+\s*", " ", text).replace("|", "\\|")


def md_row(*cells):
    """One GFM table row of ``cells`` (each escaped by :func:`md_cell`)."""
    return "| " + " | ".join(md_cell(c) for c in cells) + " |"


def md_table(header, rows):
    """Lines of a GFM table: header, delimiter, one line per row; every row padded or checked to the header's width.

    Raises
    ------
    ValueError
        A row with more cells than the header (GFM would drop the extra cells silently).
    """
    header = list(header)
    lines = [md_row(*header), "|" + "---|" * len(header)]
    for r in rows:
        r = list(r)
        if len(r) > len(header):
            raise ValueError(f"table row has {len(r)} cells, the header {len(header)}: {r!r}")
        lines.append(md_row(*(r + [""] * (len(header) - len(r)))))
    return lines


def md_image(alt, figure, report_path):
    """``![alt](link)`` with ``figure``'s path relative to the folder of ``report_path`` (URL-quoted).

    A relative ``figure`` is taken as relative to the current directory (as the run wrote it),
    an absolute one as is; ``report_path`` is the Markdown file the link is written into.
    """
    folder = Path(report_path).resolve().parent
    rel = os.path.relpath(Path(figure).resolve(), folder)
    return f"![{str(alt).replace(']', '')}]({quote(Path(rel).as_posix())})"


_PREFIXES = ((1e9, "n"), (1e6, "u"), (1e3, "m"), (1.0, ""), (1e-3, "k"), (1e-6, "M"))
_UNPREFIXED = {"%", "deg", "dB", "rad", "points", "1", "m/V", "V/m", "V/s"}


def readable_quantity(key, value):
    """``(label, number, unit)`` of a metric known only by its SI key, for a report row.

    The unit is read from the key's suffix (``_v``, ``_s``, ``_m``, ``_a``, ``_hz``, ``_n``,
    ``_percent``, ``_deg``, ``_db``, ...) and the value shown with the SI prefix that puts it
    between 1 and 1000 (``2.3e-08`` m -> ``23`` nm); the label is the rest of the key in words.
    A key without a known suffix keeps its number and gets unit "" (dimensionless).
    Non-numbers are shown as text.
    """
    unit, words = unit_of_key(key)
    label = " ".join(words)
    if isinstance(value, (bool, np.bool_)):
        return label, "yes" if value else "no", ""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return label, str(value), unit
    if not np.isfinite(v):
        return label, "n/a", unit
    if unit == "1" and "fraction" in str(key):
        v, unit = 100 * v, "%"
    factor, prefix = 1.0, ""
    if unit and unit not in _UNPREFIXED and "/" not in unit and v != 0:
        for factor, prefix in _PREFIXES:
            if abs(v) * factor < 1000:
                break
        if abs(v) * factor < 1:
            factor, prefix = _PREFIXES[0]
    v *= factor
    return label, (f"{v:.0f}" if abs(v) >= 1000 else f"{v:.4g}"), prefix + unit


def _f(v, fmt=".1f"):
    return "n/a" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, fmt)


def _reduction_error(ncf):
    bound, measured = ncf["reduction_error_bound"], ncf["reduction_error_measured"]
    if bound is None or not np.isfinite(bound):
        return (f"measured error {measured:.3g}; no bound: the Gramians of the controller's stable part "
                f"could not be computed")
    return f"error bound {bound:.3g}, measured {measured:.3g}"


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
    path = Path(path)
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
             *md_table(("margin", "discrete", "quantized", "continuous (no sampling)", "worst member (quantized)"),
                       ())]
    for (name, v_d, _), (_, v_q, m_q), (_, v_c, _) in zip(_worst_rows(ls["worst_discrete"]),
                                                         _worst_rows(ls["worst_quantized"]),
                                                         _worst_rows(ls["worst_continuous_no_sampling"])):
        lines.append(md_row(name, v_d, v_q, v_c, m_q))
    lines += [""] + summary.get("study_sections", [])      # budgets, binding constraint, nominal (workbench.study)
    lines += ["", "Files: " + ", ".join(f"`{Path(v).name}`" for v in summary["exported"].values()), "",
              md_image("loop", summary["figures"].get("loop_bode", path.parent / "loop_bode.png"), path), "",
              md_image("S and T", summary["figures"].get("sensitivity", path.parent / "sensitivity.png"), path), "",
              md_image("Nyquist", summary["figures"].get("nyquist", path.parent / "nyquist.png"), path), "",
              "Limit cycles predicted by the describing functions: "
              + ("none." if not ls["limit_cycles"] else "; ".join(
                  f"{c['amplitude_v']:.2g} V at {c['freq_hz']:.0f} Hz" for c in ls["limit_cycles"])), "",
              "## Margins per serial and amplitude (quantized controller, worst over C_p and gauge corners)", "",
              *md_table(("serial", "member", "PM (deg)", "GM (dB)", "disk alpha", "crossover (Hz)"), ())]
    for r in table:
        if not np.isfinite(r["crossover_min_hz"]):
            lines.append(md_row(r["serial"], r["member"], "-", "-", "-", f"none: linear only up to "
                                f"{r['linear_up_to_hz']:.2g} Hz, slews above (|L| >> 1 there)"))
            continue
        lines.append(md_row(r["serial"], r["member"], _f(r["phase_margin_deg"]), _f(r["gain_margin_db"]),
                            _f(r["disk_margin"], ".2f"),
                            f"{_f(r['crossover_min_hz'], '.0f')}-{_f(r['crossover_max_hz'], '.0f')}"))
    ncf = d.get("coprime")
    lines += ["", "## Other designs on the same family", ""] + ([
              "- none: run with `--only loopshape`"] if ncf is None else [
              f"- Glover-McFarlane on the same shape: best achievable margin eps_max = {ncf['eps_max']:.3f}, "
              f"controller {ncf['eps']:.3f}; reduced from {ncf['order_full']} to {ncf['order_reduced']} states "
              f"({_reduction_error(ncf)}); "
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
    lines += ["", md_image("steps", summary["figures"]["steps"], path) if "steps" in summary["figures"] else "", "",
              "What the linear analysis does not see: slewing at the current limit (members left out above; the "
              "exported controller carries a rate limit and Hanus anti-windup for it) and the shift of the mean "
              "under the asymmetric current limits. The verification runs are the check.", ""]
    return write_text(path, "\n".join(lines))
