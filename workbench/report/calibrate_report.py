"""The calibration report: one Markdown text beside the figures of :mod:`.calibrate_figures`.

:func:`calibration_markdown` reads the engine's objects as they are (a
:class:`~workbench.calibrate.base_fit.BaseFit`, the dict of
:func:`~workbench.calibrate.tracing.trace_effect`, the holds of
:func:`~workbench.calibrate.creep_holds.fit_holds`) and returns the text; the caller writes it
(:func:`~workbench.report.output.write_text`, atomic). Every error is on the held-out rows;
values are shown with the prefix that puts them between 1 and 1000 (nm, uC, mV).
"""

from pathlib import Path

import numpy as np

from ..calibrate.residual import fit_percent
from .calibrate_figures import PENALTY, si_scale
from .markdown import md_image, md_row

__all__ = ["calibration_markdown", "parameter_rows"]

FIGURE_TITLES = {
    "overview": "Record and base fit (held-out blocks shaded)",
    "residual": "Residual before and after, with a zoom where the effect acts",
    "correlation": "Whiteness and independence of the residual (as MATLAB resid)",
    "spectrum": "Spectrum of the residual",
    "candidates": "Every candidate's score",
    "creep_holds": "Creep per hold (seed 001)",
}

# effect parameter -> (label, unit); "@" stands for the channel's unit, "@/V" per volt of drive
_PARAMETERS = {
    "delay_samples": ("delay", "samples"),
    "delay_s": ("delay", "s"),
    "tau_s": ("time constant tau", "s"),
    "f_n_hz": ("natural frequency f_n", "Hz"),
    "zeta": ("damping ratio zeta", "1"),
    "gain_per_s": ("leakage gain k (charge per volt-second)", "S"),
    "c0": ("offset c0 of the bow fit", "V"),
    "c1": ("slope change c1", "V/m"),
    "c2": ("curvature c2", "V/m^2"),
    "x_ref": ("reference displacement x_ref", "m"),
    "coefficient_per_m": ("bow coefficient beta (eq. 27)", "1/m"),
    "t0_s": ("drift start t0", "s"),
    "t_end_s": ("drift end t_end", "s"),
}
_GAIN = {"creep": ("gain c (of the model's output)", "1"),
         "resonance": ("gain g (of the model's output)", "1"),
         "dielectric_absorption": ("gain k (charge per volt, k_s)", "F")}


def _finite(v):
    try:
        return bool(np.isfinite(float(v)))
    except (TypeError, ValueError):
        return False


def _num(v, nd=4):
    """4 significant digits, no exponent between 1e-3 and 1e6; 'n/a' for None, NaN, non-numbers."""
    if not _finite(v):
        return "n/a"
    v = float(v)
    if v == 0:
        return "0"
    if 1e-3 <= abs(v) < 1e6:
        return f"{v:.{nd}g}" if abs(v) < 1000 else f"{v:.0f}"
    return f"{v:.{nd - 1}e}"


def _q(v, unit, scale=None):
    """A quantity in SI ``unit`` shown with a readable prefix: ``'12.35 nm'``."""
    if not _finite(v):
        return "n/a"
    f, lab = scale if scale is not None else si_scale(unit, v)
    return f"{_num(float(v) * f)} {lab}"


_row = md_row


def _table(header, rows):
    return [_row(*header), "|" + "---|" * len(header)] + [_row(*r) for r in rows]


def _figure_link(stem, fig, folder):
    """The figure's image line, its link relative to the report's folder (a file name without one)."""
    if folder is None:
        return f"![{stem}]({Path(fig).name})"
    return md_image(stem, fig, Path(folder) / "report.md")


def parameter_rows(effect, parameters, channel_unit):
    """``(parameter, value, unit)`` rows of an effect's fitted parameters, readable units.

    Unknown keys are shown as the engine gives them (SI), so nothing is hidden.
    """
    rows = []
    p = dict(parameters or {})
    if effect == "creep" and "gains" in p and "taus_s" in p:
        gains, taus = np.asarray(p.pop("gains"), float), np.asarray(p.pop("taus_s"), float)
        active = np.flatnonzero(gains != 0)
        rows.append(("relaxation branches (non-zero of the fitted spectrum)", f"{active.size} of {gains.size}", ""))
        for k in active:
            rows.append((f"branch tau = {_q(taus[k], 's')}", _num(gains[k]), "1 (gain c_j of the model's output)"))
        rows.append(("total creep gain sum c_j", _num(gains.sum()), "1"))
    if effect == "drift" and "coefficients" in p:
        coef = np.asarray(p.pop("coefficients"), float)
        scale = si_scale(channel_unit, np.max(np.abs(coef)) if coef.size else 0.0)
        for i, c in enumerate(coef):
            rows.append((f"coefficient p{i} of s^{i}, s = (t - t0)/(t_end - t0)", _num(c * scale[0]), scale[1]))
    for key, v in p.items():
        if key == "gain" and effect in _GAIN:
            label, unit = _GAIN[effect]
        elif key in _PARAMETERS:
            label, unit = _PARAMETERS[key]
        else:
            rows.append((key, v if isinstance(v, str) else (_num(v) if _finite(v) else str(v)), "SI"))
            continue
        if unit in ("1", "samples", "Hz"):
            rows.append((label, _num(v), unit))
        elif unit in ("V/m", "V/m^2"):
            per_um = float(v) * (1e-6 if unit == "V/m" else 1e-12) if _finite(v) else float("nan")
            f, lab = si_scale("V", per_um)
            rows.append((label, _num(per_um * f), f"{lab}/{'um' if unit == 'V/m' else 'um^2'}"))
        elif unit == "1/m":
            rows.append((label, _num(v), "1/m"))
        elif unit == "S":
            rows.append((label, _num(v), "S (A/V)"))
            if _finite(v) and float(v) != 0:
                rows.append(("equivalent leakage resistance 1/|k|", _q(1.0 / abs(float(v)), "ohm"), ""))
        else:
            rows.append((label, *_q(v, unit).split(" ", 1)) if _finite(v) else (label, "n/a", unit))
    return rows


def _base_section(base):
    test = base.test if getattr(base, "test", None) is not None else ~np.asarray(base.train, bool)
    rows = []
    for name, m in base.channels.items():
        r = test & m.valid
        e = m.residual[r]
        rms = float(np.sqrt(np.mean(e * e))) if e.size else float("nan")
        mx = float(np.max(np.abs(e))) if e.size else float("nan")
        fit = fit_percent(m.y[r], m.yhat[r]) if r.sum() > 1 else float("nan")
        scale = si_scale(m.units, mx)
        span = si_scale(m.units, np.ptp(m.y[m.valid]) if m.valid.any() else float("nan"))
        rows.append((name, _q(np.ptp(m.y[m.valid]) if m.valid.any() else float("nan"), m.units, span),
                     _q(rms, m.units, scale), _q(mx, m.units, scale), _num(fit), f"{int(r.sum())}"
                     + ("" if m.valid.all() else f" ({int((~m.valid).sum())} rows at the rails left out)")))
    lines = ["## Base fit", "",
             f"Each recorded channel is fitted as a Prandtl-Ishlinskii operator of the driving voltage plus an "
             f"offset (non-negative weights, training rows only). Driving voltage: **{base.voltage_source}**. "
             f"Starts from rest: **{'yes' if base.starts_from_rest else 'no'}**. "
             + (f"Charge: the current integrated as **{base.current_kind}** samples "
                f"({'running sum i dt' if base.current_kind == 'averaged' else 'trapezoid'}; the record's "
                f"'# current:'). " if base.current_kind else "")
             + f"Training rows "
             f"{100 * float(np.mean(base.train)):.0f} %, held out {100 * float(np.mean(test)):.0f} % "
             f"({'blocks through the whole record' if np.any(test[: test.size // 2]) else 'the record after the training cycles'}).", ""]
    lines += _table(("channel", "span (peak-to-peak)", "held-out RMS", "held-out max", "fit (%)", "held-out rows"),
                    rows)
    gains = []
    if base.k_q2x_m_per_c is not None:
        gains.append(("k_q2x, displacement per charge (eq. 11)", f"{_num(base.k_q2x_m_per_c * 1e3)} nm/uC"))
    if base.working_capacitance_f is not None:
        gains.append(("C_p, working capacitance (eq. 12, plant's T_em and k_p)", _q(base.working_capacitance_f, "F")))
    if base.gauge_gain_v_per_m is not None:
        gains.append(("gauge gain against the recorded displacement", f"{_num(base.gauge_gain_v_per_m * 1e-3)} mV/um"))
    if base.gauge_offset_v is not None:
        gains.append(("gauge offset", _q(base.gauge_offset_v, "V")))
    if gains:
        lines += [""] + _table(("gain", "value"), gains)
    return lines


def _error_table(base, result):
    """Held-out error per channel before and after every effect found (the calibrated plant's)."""
    ch = result.get("channel")
    eff = result.get("effect", "none")
    rows = []
    note = []
    for name, err in (result.get("channels") or {}).items():
        before = err
        after = err.get("error_after", err) if eff not in ("none", "inconclusive") else err
        if eff not in ("none", "inconclusive") and name == ch:
            before, after = result.get("error_before", err), result.get("error_after", err)
            if _finite(err.get("rms")) and _finite(before.get("rms")) and \
                    not np.isclose(float(before["rms"]), float(err["rms"]), rtol=1e-9):
                note.append(f"The {name}'s 'before' is the model the effect is added to ("
                            + ("the line gauge offset + gain x of the recorded displacement"
                               if eff == "gauge_nonlinearity" else "as the tracing scored it")
                            + f"), not its base PI model (held-out RMS {_q(err['rms'], err.get('units', ''))}).")
            if result.get("error_after_source") == "updated plant" and _finite(before.get("rms")) \
                    and float(before["rms"]) > 0:
                model = result.get("error_after_model") or {}
                r_model = float(model["rms"]) / float(before["rms"]) if _finite(model.get("rms")) else float("nan")
                note.append(f"The {name}'s 'after' is the written plant file's replay on the test rows, and its "
                            f"'RMS after / before' that over the tracing's 'before'; the tracing model's own "
                            f"RMS after / before: {r_model:.3f} (review of s15_rt).")
        if err.get("line") and after is err.get("error_after"):
            note.append(f"The {name}'s 'after' is a straight line of the drive: {err.get('line_note', '')}.")
        elif err.get("line"):
            # the effect's channel whose end model lost to the line on the folds (tracing._line_fallback):
            # the table keeps the effect's model, the note gives the line's error the channel reports
            line_err = err.get("error_after") or {}
            note.append(f"On the {name}, {err.get('line_note', '')}: held-out RMS "
                        f"{_q(line_err.get('rms'), line_err.get('units', ''))}.")
        unit = err.get("units", "")
        scale = si_scale(unit, max(abs(float(before.get("max", 0) or 0)), abs(float(after.get("max", 0) or 0))))
        ratio = (float(after["rms"]) / float(before["rms"]) if _finite(after.get("rms")) and _finite(before.get("rms"))
                 and float(before["rms"]) > 0 else float("nan"))
        changed = eff not in ("none", "inconclusive") and (
            name == ch or not (_finite(after.get("rms")) and _finite(before.get("rms"))
                               and float(after["rms"]) == float(before["rms"])))
        rows.append((f"**{name}**" if changed else name, _num(float(before["rms"]) * scale[0]),
                     _num(float(before["max"]) * scale[0]), _num(float(after["rms"]) * scale[0]),
                     _num(float(after["max"]) * scale[0]), scale[1],
                     (f"{ratio:.3f}" if _finite(ratio) else "n/a") if changed else "1 (unchanged)"))
    lines = _table(("channel", "before RMS", "before max", "after RMS", "after max", "unit", "RMS after / before"), rows)
    return lines + ([""] + note if note else [])


def _carried_lines(carried):
    """The stages the tracing found that the updated plant file does not carry, and why (a list; [] when none)."""
    left = [c for c in carried or () if not c.get("written", True)]
    if not left:
        return []
    return (["Found by the tracing but **not carried by the plant file**:", ""]
            + [f"* {c['effect']} on the {c['channel']}: {c.get('reason') or 'no plant-file form'}" for c in left] + [""])


def _after_source(result):
    """Which model the channel's 'after' is (``error_after_source``) and the other one's figure, a paragraph."""
    src, model, after = result.get("error_after_source"), result.get("error_after_model"), result.get("error_after")
    if src is None or not model or not after:
        return []
    u = model.get("units", "")
    if src == "updated plant":
        r = float(after["rms"]) / float(model["rms"]) if _finite(model.get("rms")) and float(model["rms"]) > 0 \
            else float("nan")
        return [f"The {result.get('channel')}'s 'after' is the **updated plant**'s: the record's drive simulated "
                f"through the written file, on the test rows (RMS {_q(after['rms'], u)}, max {_q(after['max'], u)}). "
                f"The tracing model's own: RMS {_q(model['rms'], u)}, max {_q(model['max'], u)} (file / model "
                f"{r:.3g}).", ""]
    return [f"The {result.get('channel')}'s 'after' is the **tracing model**'s (no plant file was replayed): RMS "
            f"{_q(model['rms'], u)}.", ""]


def _candidate_table(result, max_ratio=None):
    chosen = {(st["effect"], st["channel"]) for st in (result.get("stages") or [])}
    if result.get("effect") not in (None, "none", "inconclusive"):
        chosen.add((result.get("effect"), result.get("channel")))
    channels = result.get("channels") or {}
    n_folds = result.get("n_folds") or len((result.get("candidates") or [{}])[0].get("ratios") or []) or "n"
    rows = []
    for i, c in enumerate(result.get("candidates") or [], 1):
        eb, ea = c.get("error_before") or {}, c.get("error_after") or {}
        unit = ea.get("units", eb.get("units", ""))
        # the error table's prefix for the channel (its held-out max), so the two tables read alike
        scale = si_scale(unit, (channels.get(c["channel"]) or eb).get("max", float("nan")))
        mark = "**chosen**" if (c["name"], c["channel"]) in chosen else ""
        npar = f"{c.get('n_params', 'n/a')}" + (f" ({c['variant']})" if c.get("variant") else "")
        rows.append((i, c["name"], c["channel"], npar, _q(eb.get("rms"), unit, scale),
                     _q(ea.get("rms"), unit, scale) if ea else "-",
                     f"{float(c['score']):.3f}" if _finite(c.get("score")) else "n/a",
                     f"{c.get('passes', 'n/a')} of {n_folds}", mark))
    if not rows:
        return ["No candidate could be fitted."]
    return _table(("rank", "effect", "channel", "parameters", "test RMS before", "test RMS after",
                   "median validation ratio", "folds passed", ""), rows)


def _stages_table(result):
    rows = []
    for k, st in enumerate(result.get("stages") or [], 1):
        eb, ea = st["error_before"], st["error_after"]
        scale = si_scale(eb.get("units", ""), eb.get("max", float("nan")))
        rows.append((k, st["effect"], st["channel"], st["agreement"], _q(eb["rms"], eb.get("units", ""), scale),
                     _q(ea["rms"], ea.get("units", ""), scale)))
    return _table(("stage", "effect", "channel", "folds won", "test RMS before", "test RMS after"), rows)


def _holds_table(holds):
    l0s = [abs(h["l0"]) for h in holds if _finite(h.get("l0"))]
    scale = si_scale("m", max(l0s) if l0s else 1e-6)
    rows = []
    for i, h in enumerate(holds, 1):
        fitted = _finite(h.get("gamma"))
        rows.append((i, _num(h.get("start_s")), _num(h.get("duration_s")), _num(h.get("voltage_v")),
                     _num(h.get("step_v")),
                     f"{_num(h['l0'] * scale[0])} ± {_num(h['sigma_l0'] * scale[0], 2)}" if fitted else "n/a",
                     f"{_num(h['gamma'])} ± {_num(h['sigma_gamma'], 2)}" if fitted else "n/a",
                     _num(h.get("chi2_reduced"), 3), h.get("n", 0) if fitted else 0,
                     "" if fitted else h.get("skip_reason", "")))
    return _table(("hold", "start (s)", "length (s)", "voltage (V)", "step (V)", f"L0 ± sigma ({scale[1]})",
                   "gamma ± sigma", "chi2_red", "samples", "skipped because"), rows)


def calibration_markdown(record_path, plant_path, base, result, holds, figures, updated_plant_path, elapsed_s,
                         *, report_dir=None):
    """The calibration report as Markdown text.

    Parameters
    ----------
    record_path, plant_path : path-like
        The measured record and the declared plant file.
    base : BaseFit
        From :func:`~workbench.calibrate.base_fit.fit_base`.
    result : dict
        From :func:`~workbench.calibrate.tracing.trace_effect`.
    holds : list of dict or None
        From :func:`~workbench.calibrate.creep_holds.fit_holds`; None or empty for no holds table.
    figures : list of path-like
        From :func:`~workbench.report.calibrate_figures.calibration_figures`; linked by file
        stem (``overview``, ``residual``, ...).
    updated_plant_path : path-like or None
        The plant file written with the effect added (None: nothing written).
    elapsed_s : float
        Run time, s.
    report_dir : path-like, optional
        The report's folder: figure links are made relative to it (default: file names, the
        figures sitting beside the report).

    The penalty is ``result["penalty"]`` when the result states it, else the tracing's default
    (0.02).

    Returns
    -------
    str
    """
    eff = result.get("effect", "none")
    ch = result.get("channel")
    penalty = float(result.get("penalty", PENALTY))
    lines = [f"# Calibration of `{Path(plant_path).name}` against `{Path(record_path).name}`", "",
             f"Record: `{record_path}`, {base.t.size} samples over {base.t[-1] - base.t[0]:.4g} s "
             f"({_num((base.t.size - 1) / (base.t[-1] - base.t[0]))} samples/s); channels "
             f"{', '.join(base.channels)}. Declared plant: `{plant_path}`. Run time {_num(elapsed_s, 3)} s.",
             "", f"Every error below is on the **test** rows (a part of the record no fit and no choice saw; "
             f"{result.get('split', 'blocks')} split, {_num(result.get('block_s'))} s blocks); the effect is chosen on "
             f"{result.get('n_folds', 'several')} validation folds of the other rows.", ""]
    lines += ["## Answer", ""]
    # s22_outsider C1: the file's replay above the error before, said first (it was only among the base's warnings)
    lines += [f"**Warning:** {w}" for w in result.get("warnings") or ()] + ([""] if result.get("warnings") else [])
    agreement = result.get("agreement")
    if eff == "none":
        lines += [f"**No effect added.** {result.get('reason', '')}.".replace("..", "."), "",
                  "No candidate explains more of the held-out error than the record's noise floor, a random term "
                  "of its size and the base model's own misfit allow, consistently over the validation folds"
                  + (f" ({agreement} folds answer none)" if agreement else "") + ".", ""]
    elif eff == "inconclusive":
        lead = ", ".join(f"{x['answer']} ({x['folds']} folds)" for x in result.get("leading") or [])
        lines += [f"**Inconclusive.** {result.get('reason', '')}.".replace("..", "."), "",
                  f"Leading answers: {lead}. No effect is added: the folds do not agree on one.", ""]
    else:
        others = {c: k for c, k in ((result.get("agreement_counts") or {}).get("by_channel") or {}).items() if c != ch}
        # s22_outsider C2: the named effect's folds on another channel said beside the named view's own
        also = "".join(f"; the {eff} on the {c} won {k} more" for c, k in others.items())
        lines += [f"**{eff}** on the **{ch}** channel (wins {agreement} validation folds{also}): "
                  f"{result.get('reason', '')}.", ""]
        prow = parameter_rows(eff, result.get("parameters"), (result.get("error_before") or {}).get("units", ""))
        if prow:
            lines += _table(("parameter", "value", "unit"), prow) + [""]
        if len(result.get("stages") or []) > 1:
            lines += ["Staged tracing (each effect added to the model before the next search):", ""]
            lines += _stages_table(result) + [""]
    lines += (["Updated plant: `" + str(updated_plant_path) + "`.", ""] if updated_plant_path
              else ["No plant file written.", ""])
    lines += _carried_lines(result.get("updated_plant_stages"))
    lines += ["## Error before and after (held out)", ""] + _error_table(base, result) + [""]
    lines += _after_source(result)
    lines += _base_section(base) + [""]
    lines += ["## Candidates", "",
              f"Each candidate is fitted to one channel's residual jointly with the base model on each validation "
              f"fold's training rows and scored on the fold by RMS after x (1 + {penalty:g} n_params) / RMS before. "
              f"It passes a fold when that ratio is below 1, what it explains stands above the channel's noise floor "
              f"and above what a random term of the residual's size and spectrum explains, and it explains at least "
              f"{100 * float(result.get('min_share', 0.3)):.0f} % of the fold's held-out variance; each fold's "
              f"winner is the passing candidate with the lowest ratio. Test errors are on rows no choice saw.",
              ""] + _candidate_table(result) + [""]
    if holds:
        lines += ["## Creep per hold (seed 001)", "",
                  "L(t) = L0 (1 + gamma log10(t / 0.1 s)) fitted on each hold of the displacement; L0 is the "
                  "change 0.1 s after the step, gamma its creep per decade (uncertainty by eq. 7).", ""]
        lines += _holds_table(holds) + [""]
    if figures:
        lines += ["## Figures", ""]
        for fig in figures:
            stem = Path(fig).stem
            lines += [f"### {FIGURE_TITLES.get(stem, stem)}", "", _figure_link(stem, fig, report_dir), ""]
    # the base fit's warnings are at the top among the run's warnings: not repeated in the notes
    said = set(result.get("warnings") or ())
    notes = [n for n in base.notes or [] if not (n.startswith("warning: ") and n[len("warning: "):] in said)]
    if "gauge" in base.channels and not base.channels["gauge"].valid.all():
        notes.append("gauge rows at the DAC rails are left out of the gauge's errors and drawn apart in the "
                     "figures (zero residual in the correlation tests, which need evenly spaced samples)")
    notes += list(result.get("notes") or [])
    if notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in notes] + [""]
    return "\n".join(lines)
