"""Figures of the closed-loop verification: one per scenario of :func:`workbench.verify.scenarios.run_scenario`."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .output import save_figure  # noqa: E402
from .verify_report import NOISE_FLOOR_DB, scaled  # noqa: E402

__all__ = ["plot_scenario"]

UM, NM, MA, MS = 1e6, 1e9, 1e3, 1e3          # SI -> the units on the axes
BOX = dict(boxstyle="round", fc="white", ec="0.7", alpha=0.9)


def _v(m, key, scale=1.0, fmt=".3g"):
    """A metric scaled and formatted; 'n/a' when absent, None or NaN (the figure must still be drawn)."""
    v = scaled(m.get(key), scale)
    if v is None:
        return "n/a"
    return f"{v:.0f}" if fmt.endswith("g") and abs(v) >= 1000 else format(v, fmt)   # 1453, not 1.45e+03


def _finite(m, key):
    v = m.get(key)
    return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)


def _conditions(m):
    return (f"anti-windup {'on' if m.get('anti_windup', True) else 'OFF'}, "
            f"{'noisy run (gauge noise on)' if m.get('noise', True) else 'NOISE-FREE run (gauge noise off)'}")


def _text(ax, lines, x=0.98, y=0.04, ha="right", va="bottom"):
    ax.text(x, y, "\n".join(lines), transform=ax.transAxes, ha=ha, va=va, fontsize=8, bbox=BOX, zorder=10)


def _current_panel(ax, t, runs, m):
    """Stack current with the amplifier's limits: where the limit, not the controller, sets the slew."""
    for tr, label, col in runs:
        ax.plot(t(tr), tr["i_a"] * MA, color=col, lw=0.7, label=label)
    for key, name in (("current_limit_source_a", "source"), ("current_limit_sink_a", "sink")):
        if _finite(m, key):
            ax.axhline(m[key] * MA, color="C3", ls="--", lw=0.8)
            ax.annotate(f"{name} limit {m[key] * MA:+.0f} mA", (0.995, m[key] * MA), xycoords=("axes fraction", "data"),
                        ha="right", va="bottom" if m[key] > 0 else "top", fontsize=7, color="C3")
    ax.set_ylabel("stack current (mA)")
    # keep both limits in view so the reader sees how close the run came to them
    lims = [m[k] * MA for k in ("current_limit_source_a", "current_limit_sink_a") if _finite(m, k)]
    vals = np.concatenate([np.asarray(r[0]["i_a"]) * MA for r in runs] + [np.asarray(lims)])
    lo, hi = np.nanmin(vals), np.nanmax(vals)
    span = (hi - lo) or 1.0
    ax.set_ylim(lo - 0.1 * span, hi + 0.15 * span)


def _finish(fig, axes):
    for ax in axes:
        ax.grid(True, alpha=0.3)
    fig.align_ylabels(axes)


def _rise(tr, key, x0, x1):
    """10-90 % rise time (ms) of a trace: the speed the overshoot and settling metrics do not show."""
    if key not in tr:
        return "n/a"
    y = (np.asarray(tr[key]) - x0) / (x1 - x0)
    if not (np.any(y >= 0.1) and np.any(y >= 0.9)):
        return "n/a"
    t = tr["t_s"]
    return f"{(t[np.argmax(y >= 0.9)] - t[np.argmax(y >= 0.1)]) * MS:.1f}"


def _plot_step(m, tr, path, companion=None):
    t0 = tr["t_s"][0] - (tr["t_s"][1] - tr["t_s"][0])          # the first sample is one period after the step
    t = lambda r: (r["t_s"] - t0) * MS  # noqa: E731
    x0, x1 = float(tr["x_start_m"][0]), float(tr["ref_m"][-1])
    step = x1 - x0
    fig, (ax, au, ai) = plt.subplots(3, 1, sharex=True, figsize=(9, 8.5), gridspec_kw={"height_ratios": [2.2, 1, 1]},
                                     layout="constrained")
    runs = [(tr, f"closed loop ({_conditions(m).split(',')[0]})", "C0")]
    if companion is not None:
        runs.append((companion[1], "same step, anti-windup OFF", "C1"))
    ax.axhspan((x1 - 0.02 * abs(step)) * UM, (x1 + 0.02 * abs(step)) * UM, color="C2", alpha=0.15,
               label="reference +/- 2 % of the step (settling band)")
    ax.plot(t(tr), tr["ref_m"] * UM, "k", lw=1, label="reference")
    if "x_linear_m" in tr:
        ax.plot(t(tr), tr["x_linear_m"] * UM, "C7--", lw=1.2, label="linear prediction (small-signal loop)")
    for r, label, col in runs:
        ax.plot(t(r), r["x_m"] * UM, color=col, lw=0.9, label=label)
        au.plot(t(r), r["u_v"], color=col, lw=0.8, label=label)
    if _finite(m, "settling_s"):
        ax.axvline(m["settling_s"] * MS, color="C0", ls=":", lw=1)
    ax.ticklabel_format(axis="y", useOffset=False)
    ax.set_ylabel("stack displacement x (um)")
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=3, fontsize=8, frameon=False)
    lines = [f"overshoot {_v(m, 'overshoot_percent', fmt='.2f')} % "
             f"(noise-free {_v(m, 'overshoot_noise_free_percent', fmt='.2f')} %, "
             f"linear {_v(m, 'linear_overshoot_percent', fmt='.2f')} %)",
             f"10-90 % rise {_rise(tr, 'x_m', x0, x1)} ms (linear {_rise(tr, 'x_linear_m', x0, x1)} ms)",
             f"settling (2 %) {_v(m, 'settling_s', MS, '.1f')} ms (noise-free {_v(m, 'settling_noise_free_s', MS, '.1f')} ms, "
             f"linear {_v(m, 'linear_settling_s', MS, '.1f')} ms)",
             f"final error {_v(m, 'final_error_m', NM, '.2f')} nm, residual oscillation "
             f"{_v(m, 'oscillation_m', NM, '.2g')} nm",
             f"rate-limited {_v(m, 'rate_limited_fraction', 100, '.1f')} % of samples, "
             f"at current limit {_v(m, 'time_at_current_limit_s', MS, '.0f')} ms"]
    if companion is not None:
        c = companion[0]
        lines += [f"anti-windup OFF: overshoot {_v(c, 'overshoot_percent', fmt='.1f')} %, settling "
                  f"{_v(c, 'settling_s', MS, '.0f')} ms,",
                  f"  {_v(c, 'time_at_current_limit_s', MS, '.0f')} ms at the current limit, oscillation "
                  f"{_v(c, 'oscillation_m', NM, '.3g')} nm at {_v(c, 'oscillation_hz', fmt='.0f')} Hz"]
    _text(ax, lines, y=0.03 if step > 0 else 0.6)
    au.set_ylabel("command u (V)")
    _current_panel(ai, t, runs, m)
    ai.set_xlabel("time after the step (ms)")
    ai.legend(fontsize=7, loc="lower left")
    name = "Small" if m.get("scenario") == "small_step" else "Large"
    size = f"{step * NM:.0f} nm" if abs(step) < 1e-6 else f"{step * UM:.3g} um"
    fig.suptitle(f"{name} step {size} ({x0 * UM:.2f} -> {x1 * UM:.2f} um), {_conditions(m)}", fontsize=11)
    _finish(fig, (ax, au, ai))
    return save_figure(fig, path)


def _plot_triangle(m, tr, path, companion=None):
    t = tr["t_s"] - tr["t_s"][0]
    x, ref = tr["x_m"], tr["ref_m"]
    err = x - ref
    sc = np.asarray(tr.get("scored", np.ones(t.size, bool)), bool)
    stroke = m.get("stroke_m", np.nan)
    fig = plt.figure(figsize=(13, 8.5), layout="constrained")
    gs = fig.add_gridspec(6, 2, width_ratios=[1.5, 1])
    ax = fig.add_subplot(gs[0:2, 0])
    ae = fig.add_subplot(gs[2:4, 0], sharex=ax)
    ai = fig.add_subplot(gs[4:6, 0], sharex=ax)
    ah = fig.add_subplot(gs[0:3, 1])
    al = fig.add_subplot(gs[3:6, 1])
    first = t[~sc]
    for a in (ax, ae, ai):
        if first.size:                                    # the first period is the transient, not scored
            a.axvspan(first[0], first[-1], color="0.85", zorder=0)
    ax.plot(t, ref * UM, "k", lw=1, label="reference")
    ax.plot(t, x * UM, "C0", lw=0.8, label="x (closed loop)")
    ax.plot([], [], color="0.85", lw=6, label="first period: transient, not scored")
    ax.plot([], [], color="C1", lw=1.2, label="error, 1 % of a period running mean")
    ax.set_ylabel("x (um)")
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=4, fontsize=8, frameon=False)
    # the gauge noise hides the direction-dependent error; a short running mean shows it
    smooth = _running_mean(err, max(1, int(round(0.01 * np.sum(t < t[0] + 1 / m.get("freq_hz", 1.0))))), center=True)
    ae.plot(t, err * NM, "C0", lw=0.5, alpha=0.7)
    ae.plot(t, smooth * NM, "C1", lw=1.2)
    ae.set_ylabel("x - reference (nm)")
    if np.isfinite(stroke) and stroke > 0:                # the issue's targets are in % of stroke
        sec = ae.secondary_yaxis("right", functions=(lambda e: e / NM / stroke * 100, lambda p: p / 100 * stroke * NM))
        sec.set_ylabel("% of stroke")
    _current_panel(ai, lambda r: t, [(tr, "stack current", "C0")], m)
    ai.set_xlabel("time (s)")
    # x against the reference: the closed-loop hysteresis loop, then the same loop magnified (error vs ref)
    ah.plot(ref[sc] * UM, ref[sc] * UM, "k", lw=2.5, alpha=0.25, label="x = reference")
    ah.plot(ref[sc] * UM, x[sc] * UM, "C0", lw=0.8, label="closed loop")
    ah.set_xlabel("reference (um)")
    ah.set_ylabel("x (um)")
    ah.set_title("x against reference (scored periods)", fontsize=9)
    ah.legend(fontsize=8, loc="lower right")
    al.plot(ref[sc] * UM, err[sc] * NM, "C0", lw=0.5, alpha=0.7)
    al.plot(ref[sc] * UM, smooth[sc] * NM, "C1", lw=1.2)
    al.set_xlabel("reference (um)")
    al.set_ylabel("x - reference (nm)")
    al.set_title("the same loop magnified: error against reference", fontsize=9)
    _text(ah, [f"tracking error RMS {_v(m, 'error_rms_m', NM, '.3g')} nm = {_v(m, 'error_rms_percent_of_stroke', fmt='.3f')} %",
               f"tracking error peak {_v(m, 'error_peak_m', NM, '.3g')} nm = "
               f"{_v(m, 'error_peak_percent_of_stroke', fmt='.3f')} % of stroke",
               f"hysteresis: closed loop {_v(m, 'hysteresis_closed_loop_percent', fmt='.3g')} %, "
               f"open loop {_v(m, 'hysteresis_open_loop_percent', fmt='.3g')} %",
               f"rate-limited {_v(m, 'rate_limited_fraction', 100, '.2g')} % of samples"], x=0.02, y=0.97, ha="left", va="top")
    fig.suptitle(f"Triangle {_v(m, 'freq_hz', fmt='g')} Hz, {np.min(ref) * UM:.1f}-{np.max(ref) * UM:.1f} um "
                 f"({np.ptp(ref) / stroke * 100:.0f} % of the {stroke * UM:.1f} um stroke), {_conditions(m)}", fontsize=11)
    for a in (ax, ae):
        plt.setp(a.get_xticklabels(), visible=False)
    _finish(fig, (ax, ae, ai, ah, al))
    return save_figure(fig, path)


def _running_mean(y, n, center=False):
    """Mean over n samples (trailing, or centred); NaN where the window is incomplete."""
    if n < 2 or y.size < n:
        return y
    c = np.cumsum(np.insert(y, 0, 0.0))
    out = np.full(y.size, np.nan)
    k = (n - 1) // 2 if center else 0
    out[n - 1 - k:y.size - k] = (c[n:] - c[:-n]) / n
    return out


def _plot_hold(m, tr, path, companion=None):
    t = tr["t_s"] - tr["t_s"][0]
    dev = (tr["x_m"] - tr["ref_m"]) * NM
    dt = t[1] - t[0] if t.size > 1 else 1.0
    avg = _running_mean(dev, max(1, int(round(1.0 / dt))), center=True)   # 1 s mean: the drift under the noise
    fig, (ac, ao) = plt.subplots(2, 1, sharex=True, figsize=(9, 7.5))
    ac.axvspan(0, 1.0, color="0.85", zorder=0, label="first 1 s: settling, not scored")
    ac.plot(t, dev, color="0.6", lw=0.4, label="x - reference")
    ac.plot(t, avg, "C0", lw=1.5, label="1 s running mean")
    ac.axhline(0, color="k", lw=0.6)
    ac.set_ylabel("closed loop: x - reference (nm)")
    # head and foot room for the legend and the numbers: neither covers the trace
    lo, hi = ac.get_ylim()
    ac.set_ylim(lo - 0.45 * (hi - lo), hi + 0.2 * (hi - lo))
    ac.legend(fontsize=8, loc="upper right", ncol=3)
    _text(ac, [f"drift {_v(m, 'drift_m', NM, '.3g')} nm (mean of the last tenth - first tenth)",
               f"x noise RMS {_v(m, 'noise_rms_m', NM, '.3g')} nm",
               f"open-loop creep (metric) {_v(m, 'open_loop_creep_m', NM, '.3g')} nm"])
    ol = tr.get("open_loop_creep")
    if ol is not None:
        ol = np.asarray(ol)
        k = ol[0] >= 1.0                                 # from 1 s: before, the stack is still charging to 50 V
        ao.plot(ol[0][k], ol[1][k] * NM, "C1", lw=1.5, label="open loop at 50 V: x - x(1 s)")
        if k.any():
            ao.annotate(f"{ol[1][k][-1] * NM:.0f} nm at {ol[0][k][-1]:.0f} s", (ol[0][k][-1], ol[1][k][-1] * NM),
                        ha="right", va="top", fontsize=8, color="C1", xytext=(-6, -6), textcoords="offset points")
    ao.plot(t, avg, "C0", lw=1.5, label="closed loop, 1 s running mean")
    ao.axhline(0, color="k", lw=0.6)
    ao.set_ylabel("displacement change (nm)")
    ao.set_xlabel("time into the hold (s)")
    ao.legend(fontsize=8, loc="center right")
    ac.set_title(f"Hold at 7.5 um for {_v(m, 'hold_s', fmt='.0f')} s: closed-loop drift against the open-loop creep, "
                 f"{_conditions(m)}", fontsize=10)
    _finish(fig, (ac, ao))
    fig.tight_layout()
    return save_figure(fig, path)


def _plot_force(m, tr, path, companion=None):
    t = lambda r: (r["t_s"] - r["t_s"][0]) * MS  # noqa: E731
    n = tr["t_s"].size
    t_f = t(tr)[n // 4] if n else 0.0                  # the scenario applies the force a quarter into the run
    fig, (ax, au, ai) = plt.subplots(3, 1, sharex=True, figsize=(9, 8), gridspec_kw={"height_ratios": [2, 1, 1]})
    for a in (ax, au, ai):
        a.axvline(t_f, color="k", ls=":", lw=0.8)
    ax.plot(t(tr), (tr["x_m"] - tr["ref_m"]) * NM, "C0", lw=0.8, label="closed loop: x - reference")
    if _finite(m, "open_loop_deflection_m"):
        ax.axhline(m["open_loop_deflection_m"] * NM, color="C1", ls="--", lw=1.2,
                   label="open loop: static deflection (open-circuit stiffness)")
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylabel("deviation (nm)")
    ax.legend(fontsize=8, loc="center right", bbox_to_anchor=(1, 0.55))
    _text(ax, [f"peak |deviation| {_v(m, 'peak_deviation_m', NM, '.3g')} nm, final {_v(m, 'final_deviation_m', NM, '.2g')} nm",
               f"open-loop deflection {_v(m, 'open_loop_deflection_m', NM, '.3g')} nm",
               f"peak currents {_v(m, 'peak_current_source_a', MA, '+.2f')} / {_v(m, 'peak_current_sink_a', MA, '+.2f')} mA"],
          # clear of the open-loop deflection line, which sits at the bottom (compression) or top (tension)
          **({"y": 0.12} if (scaled(m.get("open_loop_deflection_m")) or 0) <= 0 else {"y": 0.88, "va": "top"}))
    au.plot(t(tr), tr["u_v"], "C0", lw=0.8)
    au.set_ylabel("command u (V)")
    _current_panel(ai, t, [(tr, "stack current", "C0")], m)
    ai.set_xlabel("time (ms)")
    ax.set_title(f"Force step {_v(m, 'force_n', fmt='.0f')} N (compression) at {t_f:.0f} ms, holding 7.5 um, "
                 f"{_conditions(m)}", fontsize=10)
    _finish(fig, (ax, au, ai))
    fig.tight_layout()
    return save_figure(fig, path)


def _plot_sweep(m, tr, path, companion=None):
    f = np.asarray(m["freq_hz"], float)
    lin_ph = np.degrees(np.unwrap(np.radians(m["linear_phase_deg"])))
    # the measured phase on the linear branch: both are only known mod 360 at sparse points
    meas_ph = lin_ph + (np.asarray(m["measured_phase_deg"]) - lin_ph + 180) % 360 - 180
    fig, (am, ap, ar) = plt.subplots(3, 1, sharex=True, figsize=(9, 8.5), gridspec_kw={"height_ratios": [2.2, 2, 1]})
    am.semilogx(f, m["linear_db"], "k-", lw=1.2, label="linear small-signal loop")
    db = np.asarray(m["measured_db"], float)
    low = (db < NOISE_FLOOR_DB) & bool(m.get("noise", True))      # a noise-free run has no noise floor
    for sel, style in ((~low, dict(color="C0", label="measured (nonlinear plant, "
                                                    + ("gauge noise on)" if m.get("noise", True) else "noise-free)"))),
                       (low, dict(mfc="none", color="C0", label=f"measured below {NOISE_FLOOR_DB} dB: "
                                                               "at the noise floor of the lock-in"))):
        if sel.any():
            am.semilogx(f[sel], db[sel], "o", ms=6, ls="none", **style)
            ap.semilogx(f[sel], meas_ph[sel], "o", ms=6, ls="none", **{k: v for k, v in style.items() if k != "label"})
    ap.semilogx(f, lin_ph, "k-", lw=1.2)
    am.axhline(-3, color="C3", lw=0.8, ls="--", label="-3 dB")
    for key, col, ls, who in (("bandwidth_hz", "C0", "--", "measured"), ("linear_bandwidth_hz", "k", ":", "linear")):
        if _finite(m, key):
            for a in (am, ap, ar):
                a.axvline(m[key], color=col, ls=ls, lw=1)
            am.plot([], [], color=col, ls=ls, label=f"{who} bandwidth {m[key]:.0f} Hz")
    am.set_ylabel("|T| reading / reference (dB)")
    am.legend(fontsize=8, loc="lower left")
    ap.set_ylabel("phase of T (deg)")
    ap.set_yticks(np.arange(-360 * 2, 361, 90))
    ap.set_ylim(min(-200, np.nanmin(np.r_[lin_ph, meas_ph]) - 20), 10)
    rate = m.get("rate_limited_fraction_per_freq")
    if rate is not None:
        ar.semilogx(f, np.asarray(rate) * 100, "C2s-", ms=4)
    ar.set_ylabel("rate-limited\nsamples (%)")
    ar.set_xlabel("frequency (Hz)")
    for a in (am, ap, ar):
        a.grid(True, which="both", alpha=0.3)
    fig.align_ylabels((am, ap, ar))
    am.set_title(f"Closed-loop response, {_v(m, 'amplitude_m', NM, '.0f')} nm tones at 7.5 um: bandwidth "
                 f"{_v(m, 'bandwidth_hz', fmt='.0f')} Hz measured, {_v(m, 'linear_bandwidth_hz', fmt='.0f')} Hz linear\n"
                 f"{_conditions(m)}", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


_PLOTS = {"small_step": _plot_step, "large_step": _plot_step, "triangle_0p1hz": _plot_triangle,
          "triangle_1hz": _plot_triangle, "hold": _plot_hold, "force_step": _plot_force, "sine_sweep": _plot_sweep}


def plot_scenario(metrics, traces, path, companion=None):
    """Write the figure of one scenario run to ``path``; returns the path.

    ``companion``: (metrics, traces) of the same step without anti-windup, overlaid on a step figure.
    """
    name = metrics.get("scenario")
    if name not in _PLOTS:
        raise ValueError(f"no figure for scenario {name!r}; known: {', '.join(_PLOTS)}")
    return _PLOTS[name](metrics, traces, path, companion)
