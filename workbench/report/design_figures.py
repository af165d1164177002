"""Figures of a design study: loop Bode over the family, S and T, Nyquist with -1/N(A), steps."""

import control
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.patches  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402

from .output import save_figure  # noqa: E402

__all__ = ["plot_loop_family", "plot_sensitivities", "plot_nyquist_family", "plot_steps", "db", "unwrapped_deg",
           "label_locus"]

GREY, DF_COLOUR, WORST = "0.65", "C0", "C3"


def _kind(name):
    return "DF" if ", DF " in name else "small-signal"


def db(x):
    """20 log10 |x|, dB; NaN where x is 0, NaN or infinite (a gap in the curve, not a -inf spike)."""
    a = np.abs(np.asarray(x, complex))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 20 * np.log10(a)
    return np.where(np.isfinite(out), out, np.nan)


def unwrapped_deg(x):
    """Phase of the samples ``x`` in degrees, unwrapped along the grid, gaps (NaN) left as gaps.

    Each finite run is unwrapped and shifted by a multiple of 360 deg so that the first run
    starts in (-270, 90] deg: a loop with an integrator starts near -90 deg and a loop falling
    through -180 deg is drawn through it, not folded back to +180.
    """
    x = np.asarray(x, complex)
    out = np.full(x.shape, np.nan)
    ok = np.isfinite(x) & (x != 0)
    if not ok.any():
        return out
    ph = np.unwrap(np.angle(x[ok]))
    ph -= 2 * np.pi * np.floor((ph[0] + 1.5 * np.pi) / (2 * np.pi))
    out[ok] = np.degrees(ph)
    return out


def _margins(freq_hz, loops):
    from ..design.margins import family_margins
    usable = {k: v for k, v in loops.items() if np.isfinite(np.asarray(v)).sum() >= 2}
    return family_margins(freq_hz, usable) if usable else ([], {})


def _legend_below(fig, handles=None, ncol=2):
    """One legend for the figure, below the axes (never over the data)."""
    if handles is None:
        handles = [h for ax in fig.axes for h in ax.get_legend_handles_labels()[0]]
    labels = [h.get_label() for h in handles]
    fig.legend(handles, labels, loc="outside lower center", ncol=ncol, fontsize=8, frameon=False)


def plot_loop_family(freq_hz, loops, path, params):
    """Bode plot of every member's sampled loop: |L| in dB, unwrapped phase, the worst member and its margins.

    Describing-function members in colour above the small-signal branches (grey); the member with
    the smallest phase margin drawn thick in red, with its gain crossover, phase margin and gain
    margin marked; the band of crossover frequencies over the family shaded.
    """
    from matplotlib.lines import Line2D
    rows, worst = _margins(freq_hz, loops)
    fig, (am, ap) = plt.subplots(2, 1, sharex=True, figsize=(9, 8), layout="constrained",
                                 gridspec_kw={"height_ratios": [1.2, 1]})
    for name, l in loops.items():
        df_member = _kind(name) == "DF"
        kw = dict(color=DF_COLOUR if df_member else GREY, lw=0.6, alpha=0.6 if df_member else 0.5,
                  zorder=2 if df_member else 1)
        am.semilogx(freq_hz, db(l), **kw)
        ap.semilogx(freq_hz, unwrapped_deg(l), **kw)
    handles = [Line2D([], [], color=DF_COLOUR, lw=1, label="describing functions (amplitude x serial x C_p x gauge)"),
               Line2D([], [], color=GREY, lw=1, label="small-signal models on each branch")]
    w_pm = worst.get("phase_margin_deg", {}).get("member")
    if w_pm is not None:
        row = next(r for r in rows if r["member"] == w_pm)
        l = loops[w_pm]
        am.semilogx(freq_hz, db(l), color=WORST, lw=2, zorder=4)
        ph = unwrapped_deg(l)
        ap.semilogx(freq_hz, ph, color=WORST, lw=2, zorder=4)
        handles.append(Line2D([], [], color=WORST, lw=2, label=f"worst phase margin: {w_pm}"))
        f_c, pm = row["pm_freq_hz"], row["phase_margin_deg"]
        if np.isfinite(f_c):
            am.plot([f_c], [0], "o", color=WORST, ms=7, mfc="white", mew=2, zorder=5)
            # the phase at the crossover, on the same 360-deg sheet as the drawn (unwrapped) curve
            ph_c = np.interp(np.log(f_c), np.log(freq_hz)[np.isfinite(ph)], ph[np.isfinite(ph)])
            ref = ph_c - pm
            ap.annotate("", (f_c, ph_c), (f_c, ref), arrowprops=dict(arrowstyle="<->", color=WORST, lw=1.5), zorder=5)
            ap.axhline(ref, color="k", lw=0.8)
            ap.text(f_c * 1.08, (ph_c + ref) / 2, f"PM {pm:.1f} deg\nat {f_c:.0f} Hz", color=WORST, fontsize=8,
                    va="center", bbox=dict(fc="white", ec="none", alpha=0.8), zorder=6)
        f_g, gm = row["gm_freq_hz"], row["gain_margin_db"]
        if np.isfinite(f_g) and np.isfinite(gm):
            am.annotate("", (f_g, 0), (f_g, -gm), arrowprops=dict(arrowstyle="<->", color=WORST, lw=1.5), zorder=5)
            am.text(f_g * 1.08, -gm / 2, f"GM {gm:.1f} dB\nat {f_g:.0f} Hz", color=WORST, fontsize=8, va="center",
                    bbox=dict(fc="white", ec="none", alpha=0.8), zorder=6)
    lo, hi = (worst.get("crossover_hz_min", {}).get("value"), worst.get("crossover_hz_max", {}).get("value"))
    if lo is not None and hi is not None and np.isfinite(lo) and np.isfinite(hi):
        for ax in (am, ap):
            ax.axvspan(lo, hi, color="C2", alpha=0.15, zorder=0)
        handles.append(matplotlib.patches.Patch(color="C2", alpha=0.3,
                                                label=f"gain crossovers over the family: {lo:.0f}-{hi:.0f} Hz"))
    am.axhline(0, color="k", lw=0.8)
    for k in (-1, -2):
        ap.axhline(180 * k, color="k", lw=0.5, ls=":")
    am.set_ylabel("|L| (dB)")
    ap.set_ylabel("phase of L (deg, unwrapped)")
    ap.set_xlabel("frequency (Hz)")
    finite = np.concatenate([unwrapped_deg(l)[np.isfinite(unwrapped_deg(l))] for l in loops.values()] or [[0.0]])
    ap.set_ylim(max(np.nanmin(finite), -540) - 10, min(np.nanmax(finite), 90) + 10)
    ap.yaxis.set_major_locator(matplotlib.ticker.MultipleLocator(90))
    mags = np.concatenate([db(l)[np.isfinite(db(l))] for l in loops.values()] or [[0.0]])
    am.set_ylim(max(np.nanmin(mags), -80) - 5, min(np.nanmax(mags), 80) + 5)
    am.set_title(f"Loop over the family: structured controller, nominal crossover {params['fc_hz']:.0f} Hz "
                 f"(sampled at 10 kHz)", fontsize=10)
    for ax in (am, ap):
        ax.grid(True, which="both", alpha=0.3)
    _legend_below(fig, handles)
    return save_figure(fig, path)


def plot_sensitivities(freq_hz, loops, ub, path):
    """|S| and |T| of every member in dB with 1/|W_m| (robust stability needs |T| below it); worst peaks marked."""
    from matplotlib.lines import Line2D
    rows, worst = _margins(freq_hz, loops)
    fig, ax = plt.subplots(figsize=(9, 6), layout="constrained")
    with np.errstate(invalid="ignore", divide="ignore"):      # NaN where a member is left out
        sens = {k: 1 / (1 + np.asarray(l)) for k, l in loops.items()}
        comp = {k: np.asarray(l) / (1 + np.asarray(l)) for k, l in loops.items()}
    for k in loops:
        ax.semilogx(freq_hz, db(sens[k]), color="C0", lw=0.5, alpha=0.4)
        ax.semilogx(freq_hz, db(comp[k]), color="C1", lw=0.5, alpha=0.4)
    w = np.abs(np.asarray(control.frequency_response(ub.fit.weight, 2 * np.pi * freq_hz).complex).ravel())
    ax.semilogx(freq_hz, -db(w), "k--", lw=1.5, label="1 / |W_m|: |T| must stay below")
    handles = [Line2D([], [], color="C0", lw=1, label="|S| of each member"),
               Line2D([], [], color="C1", lw=1, label="|T| of each member")]
    # the worst members in darker shades of their curves' colours, their peaks annotated in the empty upper left
    for key, curves, col, name, y_txt in (("s_peak_db", sens, "#08306b", "S", 0.965), ("t_peak_db", comp, "#a63603",
                                                                                      "T", 0.915)):
        w_m = worst.get(key, {})
        if w_m.get("member") is None or not np.isfinite(w_m["value"]):
            continue
        ax.semilogx(freq_hz, db(curves[w_m["member"]]), color=col, lw=2, zorder=4)
        ax.plot([w_m["freq_hz"]], [w_m["value"]], "v", color=col, mec="k", ms=8, zorder=5)
        ax.annotate(f"peak |{name}| {w_m['value']:.1f} dB at {w_m['freq_hz']:.0f} Hz", (w_m["freq_hz"], w_m["value"]),
                    (0.03, y_txt), textcoords="axes fraction", fontsize=8, color=col, va="center",
                    arrowprops=dict(arrowstyle="->", color=col, lw=0.8), zorder=6)
        handles.append(Line2D([], [], color=col, lw=2, label=f"worst |{name}|: {w_m['member']}"))
    ax.axhline(6, color="C3", lw=0.8, ls=":", label="|S| = 6 dB")
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("magnitude (dB)")
    ax.set_ylim(-60, 20)
    ax.set_title("Sensitivity S = 1/(1 + L) and complementary sensitivity T = L/(1 + L) over the family", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    _legend_below(fig, handles + ax.get_legend_handles_labels()[0])
    return save_figure(fig, path)


def label_locus(ax, locus, amplitudes_v, color="C3", max_labels=8):
    """Write the drive amplitude beside the points of a -1/N(A) locus inside the axes' current limits
    (at most ``max_labels``, the visible ends included); call after setting the limits."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    locus = np.asarray(locus)
    vis = np.flatnonzero((locus.real > x0) & (locus.real < x1) & (locus.imag > y0) & (locus.imag < y1))
    if vis.size == 0:
        return
    pick = vis[np.unique(np.linspace(0, vis.size - 1, min(vis.size, max_labels)).round().astype(int))]
    for i in pick:
        z = locus[i]
        ax.annotate(f"{amplitudes_v[i]:g} V", (z.real, z.imag), (5, -9 if i % 2 else 5), textcoords="offset points",
                    fontsize=7, color=color, bbox=dict(fc="white", ec="none", alpha=0.7, pad=0.5), zorder=6)


def plot_nyquist_family(freq_hz, loops, df, ub, ctrl_d, fw_factor, cycles, path):
    """Nyquist of every member near -1, and -1/N(A) at the nominal's phase crossover, labelled with A.

    A limit cycle is predicted where a loop meets -1/N(A): the point's amplitude is the drive
    amplitude of the oscillation, the loop's frequency there its frequency.
    """
    from matplotlib.lines import Line2D
    rows, worst = _margins(freq_hz, loops)
    fig, ax = plt.subplots(figsize=(8.5, 9.5), layout="constrained")
    for name, l in loops.items():
        df_member = _kind(name) == "DF"
        ax.plot(np.real(l), np.imag(l), color=DF_COLOUR if df_member else GREY, lw=0.6, alpha=0.6 if df_member else 0.5,
                zorder=2 if df_member else 1)
    handles = [Line2D([], [], color=DF_COLOUR, lw=1, label="describing-function members"),
               Line2D([], [], color=GREY, lw=1, label="small-signal members")]
    w_dm = worst.get("disk_margin", {}).get("member")
    if w_dm is not None:
        l = np.asarray(loops[w_dm])
        ax.plot(l.real, l.imag, color=WORST, lw=2, zorder=4)
        handles.append(Line2D([], [], color=WORST, lw=2, label=f"worst disk margin "
                                                                  f"({worst['disk_margin']['value']:.2f}): {w_dm}"))
    c = np.asarray(control.frequency_response(ctrl_d, 2 * np.pi * freq_hz).complex).ravel()
    p_nom = np.asarray(control.frequency_response(ub.nominal, 2 * np.pi * freq_hz).complex).ravel()
    l_nom = c * fw_factor * p_nom
    ax.plot(l_nom.real, l_nom.imag, "k", lw=1.5, zorder=3)
    handles.append(Line2D([], [], color="k", lw=1.5, label="nominal loop"))
    ph = np.angle(l_nom)
    k = int(np.argmin(np.abs(np.abs(ph) - np.pi) + (l_nom.real > 0) * 10))
    n = ub.nominal_gauge_v_per_m * df.x_m_per_v[0, :, k] / p_nom[k]
    ok = np.isfinite(n) & (np.abs(n) > 0)
    locus = -1 / n[ok]
    ax.plot(locus.real, locus.imag, "C1s-", ms=4, zorder=5)
    amps = df.amplitudes_v[ok]
    handles.append(Line2D([], [], color="C1", marker="s", ms=4,
                          label=f"-1/N(A) at {freq_hz[k]:.0f} Hz, A = {amps[0]:g}-{amps[-1]:g} V drive amplitude "
                                f"(labels): a loop through a point predicts a limit cycle of that amplitude"))
    ax.plot([-1], [0], "r+", ms=14, mew=2, zorder=6)
    t = np.linspace(0, 2 * np.pi, 200)
    ax.plot(-1 + 0.5 * np.cos(t), 0.5 * np.sin(t), "C3:", lw=0.8)
    handles.append(Line2D([], [], color="C3", ls=":", label="|1 + L| = 0.5 (|S| = 6 dB)"))
    title = "no limit cycle predicted" if not cycles else "; ".join(
        f"limit cycle {c.amplitude_v:.2g} V at {c.freq_hz:.0f} Hz" for c in cycles)
    ax.set_title(f"Nyquist over the family near -1: {title}", fontsize=10)
    ax.set_xlim(-2.5, 1.5)
    ax.set_ylim(-2.5, 1.5)
    ax.set_aspect("equal")
    label_locus(ax, locus, amps, color="C1")
    ax.set_xlabel("Re L")
    ax.set_ylabel("Im L")
    ax.grid(True, alpha=0.3)
    fig.legend(handles, [h.get_label() for h in handles], loc="outside lower center", ncol=1, fontsize=8,
               frameon=False)
    return save_figure(fig, path)


def plot_steps(plant, serials, ctrl_ls, ctrl_ncf, dt_s, delay_samples, path):
    """Linear closed-loop step responses (small-signal branches, every serial) through the sampled chain."""
    from ..linearize.sampled import firmware_plant
    from ..linearize.small_signal import BRANCHES, operating_point, small_signal_model
    fig, axes = plt.subplots(1, 2, sharey=True, figsize=(11, 4.8))
    n = int(0.02 / dt_s)
    t = np.arange(n) * dt_s * 1e3
    for ax, ctrl, title in ((axes[0], ctrl_ls, "structured loop shape (exported)"),
                            (axes[1], ctrl_ncf, "Glover-McFarlane, reduced")):
        for i, p in enumerate([plant] + list(serials)):
            for branch in BRANCHES:
                c_h = operating_point(p.pzt, 50.0, branch).capacitance_f
                g = firmware_plant(small_signal_model(p.pzt, c_h)[0, 0], p.gauge, 7.5e-6, delay_samples)
                cl = control.feedback(ctrl * g, 1)
                y = control.step_response(cl, T=np.arange(n) * dt_s).outputs
                ax.plot(t, np.squeeze(y), color=f"C{i}", lw=0.8, alpha=0.8,
                        label=f"{p.serial}" if branch == "reversal" else None)
        ax.axhline(1, color="k", lw=0.6)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("time (ms)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("reading / reference (linear prediction)")
    fig.suptitle("Small-step responses predicted by the linear models (4 branches x serials)", fontsize=11)
    return save_figure(fig, path)
