"""The verification report: one Markdown file beside the scenario figures of :mod:`.verify_figures`."""

from pathlib import Path

import numpy as np

from .markdown import md_image, md_row, readable_quantity
from .output import write_text

__all__ = ["write_verify_report"]

TITLES = {"small_step": "Small step", "large_step": "Large step", "triangle_0p1hz": "Triangle 0.1 Hz",
          "triangle_1hz": "Triangle 1 Hz", "hold": "Hold", "force_step": "Force step",
          "sine_sweep": "Sine sweep (closed-loop frequency response)",
          "large_step_no_anti_windup": "Large step"}

WHAT = {"small_step": "A step up from 7.5 um, against the step response of the linear small-signal loop.",
        "large_step": "A step the current limit slews: what the anti-windup and the current-limit window are for.",
        "triangle_0p1hz": "Tracking a triangle over 80 % of the stroke through the hysteresis, scored after the "
                          "first period.",
        "triangle_1hz": "The same triangle ten times faster.",
        "hold": "Holding 7.5 um: closed-loop drift against the creep of the open loop.",
        "force_step": "A 100 N compressive force step while holding 7.5 um.",
        "sine_sweep": "Small tones one frequency at a time around 7.5 um; reading over reference by lock-in, "
                      "beside T of the linear small-signal loop."}

# metric key -> (label, factor from SI, unit shown); the order is the order of the tables
METRICS = {
    "step_m": ("step", 1e6, "um"),
    "overshoot_percent": ("overshoot", 1, "%"),
    "overshoot_noise_free_percent": ("overshoot, same step without gauge noise", 1, "%"),
    "linear_overshoot_percent": ("overshoot, linear prediction", 1, "%"),
    "overshoot_difference_points": ("overshoot - linear (noise-free run when noise is on)", 1, "points"),
    "settling_s": ("settling time to 2 % of the step", 1e3, "ms"),
    "settling_noise_free_s": ("settling time without gauge noise", 1e3, "ms"),
    "linear_settling_s": ("settling time, linear prediction", 1e3, "ms"),
    "settling_difference_s": ("settling - linear (noise-free run when noise is on)", 1e3, "ms"),
    "final_error_m": ("final error (mean of the last fifth)", 1e9, "nm"),
    "freq_hz": ("triangle frequency", 1, "Hz"),
    "error_rms_m": ("tracking error RMS", 1e9, "nm"),
    "error_rms_percent_of_stroke": ("tracking error RMS", 1, "% of stroke"),
    "error_peak_m": ("tracking error peak", 1e9, "nm"),
    "error_peak_percent_of_stroke": ("tracking error peak", 1, "% of stroke"),
    "hysteresis_closed_loop_percent": ("hysteresis, closed loop (x against reference)", 1, "% of stroke"),
    "hysteresis_open_loop_percent": ("hysteresis, open loop (x against V, 10-90 V)", 1, "% of stroke"),
    "hold_s": ("hold", 1, "s"),
    "drift_m": ("drift (last tenth - first tenth, after 1 s)", 1e9, "nm"),
    "noise_rms_m": ("x noise RMS", 1e9, "nm"),
    "open_loop_creep_m": ("open-loop creep over the same hold", 1e9, "nm"),
    "force_n": ("force", 1, "N"),
    "peak_deviation_m": ("peak |deviation|", 1e9, "nm"),
    "final_deviation_m": ("final deviation", 1e9, "nm"),
    "open_loop_deflection_m": ("open-loop static deflection (open-circuit stiffness)", 1e9, "nm"),
    "oscillation_m": ("residual oscillation (strongest line of the tail)", 1e9, "nm"),
    "oscillation_hz": ("residual oscillation frequency", 1, "Hz"),
    "amplitude_m": ("tone amplitude", 1e9, "nm"),
    "bandwidth_hz": ("-3 dB bandwidth, measured", 1, "Hz"),
    "linear_bandwidth_hz": ("-3 dB bandwidth, linear loop", 1, "Hz"),
    "worst_gain_difference_db": ("worst |measured - linear| gain, all tones", 1, "dB"),
    "worst_phase_difference_deg": ("worst |measured - linear| phase, all tones", 1, "deg"),
    "peak_current_source_a": ("peak stack current, source", 1e3, "mA"),
    "peak_current_sink_a": ("peak stack current, sink", 1e3, "mA"),
    "time_at_current_limit_s": ("time at the current limit (plant steps clipped at it; with the series resistor out a "
                                "sample whose command the stack reaches is not counted)", 1e3, "ms"),
    "rate_limited_fraction": ("samples held by the current-limit window", 100, "%"),
    "command_noise_rms_v": ("command noise RMS", 1e3, "mV"),
}
# plant properties, the same in every run: stated once in the header
NOT_IN_TABLE = {"scenario", "anti_windup", "noise", "stroke_m", "current_limit_source_a", "current_limit_sink_a"}
# 22 nm RMS of gauge noise per reading over the sweep's 2 s lock-in (20000 readings) leaves ~0.3 nm of noise
# on the tone estimate: -30 dB of the 10 nm tones. Below it the measured gain and phase are noise.
NOISE_FLOOR_DB = -30


def scaled(v, scale=1.0):
    """``v * scale`` as a float, or None for None, NaN, infinities and non-numbers."""
    try:
        v = float(v) * scale
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def _num(v, scale=1.0):
    """Readable number: 4 significant digits, no exponent above 1000; 'n/a' for None, NaN, non-numbers."""
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    v = scaled(v, scale)
    if v is None:
        return "n/a"
    return f"{v:.0f}" if abs(v) >= 1000 else f"{v:.4g}"


_row = md_row


def _title(key):
    """A scenario's or target's readable name: its title, else its key in words."""
    return TITLES.get(key, str(key).replace("_", " "))


def _finite(v):
    try:
        return np.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def _targets(targets):
    if not targets:
        return ["No targets given."]
    met = sum(1 for v, _, _, ok in targets.values() if ok and _finite(v))
    lines = [f"**{met} of {len(targets)} targets met.**", "", "| target | value | required | result |", "|---|---|---|---|"]
    for name, (value, target, unit, ok) in targets.items():
        # a target without a value is not met, whatever the flag says
        result = "**not measured**" if not _finite(value) else ("met" if ok else "**MISSED**")
        req = f"{_num(target)} {unit}" if _finite(target) else f"{target} {unit}"
        val = f"{_num(value)} {unit}" if _finite(value) else "n/a"
        lines.append(_row(_title(name), val, req.strip(), result))
    return lines


def _metric_table(m):
    rows = [(label, _num(m[k], scale), unit) for k, (label, scale, unit) in METRICS.items()
            if k in m and not isinstance(m[k], (list, tuple, np.ndarray))]
    # keys this table has no label for yet: shown in words with the unit of their suffix rather than hidden
    rows += [readable_quantity(k, v) for k, v in m.items()
             if k not in METRICS and k not in NOT_IN_TABLE and not isinstance(v, (list, tuple, np.ndarray, str, dict))]
    return ["| metric | value | unit |", "|---|---|---|"] + [_row(*r) for r in rows]


def _sweep_table(m):
    cols = (("freq_hz", "frequency (Hz)", 1), ("measured_db", "measured |T| (dB)", 1),
            ("linear_db", "linear |T| (dB)", 1), ("measured_phase_deg", "measured phase (deg)", 1),
            ("linear_phase_deg", "linear phase (deg)", 1), ("x_amplitude_m", "x amplitude (nm)", 1e9),
            ("rate_limited_fraction_per_freq", "rate-limited (%)", 100))
    cols = [c for c in cols if isinstance(m.get(c[0]), (list, tuple, np.ndarray))]
    if not cols or cols[0][0] != "freq_hz":
        return []
    n = len(m["freq_hz"])
    get = lambda k, i: m[k][i] if i < len(m[k]) else None  # noqa: E731
    lines = (["", _row(*(c[1] for c in cols)), "|" + "---|" * len(cols)]
             + [_row(*(_num(get(k, i), s) for k, _, s in cols)) for i in range(n)])
    low = [f for f, db in zip(m["freq_hz"], m.get("measured_db", []))
           if _finite(db) and db < NOISE_FLOOR_DB and m.get("noise", True)]     # noise-free: no noise floor
    if low:
        lines += ["", f"Tones measured below {NOISE_FLOOR_DB} dB ({', '.join(_num(f) for f in low)} Hz) are at the "
                      "noise floor of the lock-in (about 0.3 nm of reading): their gain and phase, and the worst "
                      "differences above when they come from them, are noise."]
    return lines


def _figure_path(fig, report_path):
    """Where the figure is: a bare file name sits beside the report; any other path is taken as given."""
    p = Path(fig)
    return Path(report_path).parent / p if len(p.parts) == 1 else p


def _plant_line(ms):
    m = next((m for m in ms if "stroke_m" in m), {})
    return (f"Stroke (0-100 V) {_num(m.get('stroke_m'), 1e6)} um; amplifier current limits "
            f"{_num(m.get('current_limit_source_a'), 1e3)} mA source, {_num(m.get('current_limit_sink_a'), 1e3)} mA sink.")


def write_verify_report(path, header, results):
    """Write the Markdown verification report to ``path``; returns its path.

    ``header``: plant, controller, controller_form (str) and targets {name: (value, target, unit, met)}.
    ``results``: [{"metrics": metrics of run_scenario, "figure": file name or None}, ...].
    """
    path = Path(path)
    lines = [f"# Closed-loop verification: `{header.get('controller', '?')}` on `{header.get('plant', '?')}`", "",
             f"Controller form: {header.get('controller_form', 'n/a')}. Every run starts at rest, ramps to 7.5 um in "
             f"1 s and holds 1 s before the scenario (not scored). Units: nm, um, ms, mA; % of stroke where stated.",
             "", _plant_line([r.get("metrics") or {} for r in results]), "", "## Targets", ""] + _targets(header.get("targets") or {})
    for r in results:
        m = r.get("metrics") or {}
        name = m.get("scenario", "?")
        off = [s for k, s in (("anti_windup", "anti-windup OFF"), ("noise", "no gauge noise")) if m.get(k) is False]
        lines += ["", f"## {TITLES.get(name, name)}{' (' + ', '.join(off) + ')' if off else ''}", "",
                  f"{WHAT.get(name, '')} Anti-windup {'on' if m.get('anti_windup', True) else 'OFF'}, gauge noise "
                  f"{'on' if m.get('noise', True) else 'off'}.".strip(), ""]
        lines += [md_image(_title(name), _figure_path(r["figure"], path), path) if r.get("figure")
                  else "_No figure._", ""]
        lines += _metric_table(m) + _sweep_table(m)
    return write_text(path, "\n".join(lines) + "\n")
