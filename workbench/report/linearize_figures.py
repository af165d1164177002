"""Figures of ``workbench linearize``: describing-function Bode family, capacitances, W_m cover, loop."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .design_figures import db, label_locus  # noqa: E402
from .output import save_figure  # noqa: E402

__all__ = ["plot_df_bode", "plot_capacitances", "plot_uncertainty", "plot_sampled", "plot_nyquist"]


def _freq_response(sys, f):
    """Complex response of a SISO system at ``f`` Hz (on the unit circle when discrete)."""
    import control
    return np.asarray(control.frequency_response(sys, 2 * np.pi * np.asarray(f)).complex).ravel()


def plot_df_bode(df, models, bias_v, path):
    """Bode family of P(jw; A) at one bias; slewing points hollow; small-signal models dashed."""
    fig, (am, ap) = plt.subplots(2, 1, sharex=True, figsize=(9, 8), layout="constrained")
    cmap = plt.get_cmap("viridis")
    f = df.freq_hz
    for a, amp in enumerate(df.amplitudes_v):
        col = cmap(a / max(1, df.amplitudes_v.size - 1))
        h = df.x_m_per_v[0, a]
        ok = df.linear_ok[0, a]
        am.semilogx(f, db(h * 1e6), color=col, lw=1.2, label=f"A = {amp:g} V")
        ap.semilogx(f, np.degrees(np.unwrap(np.angle(h))), color=col, lw=1.2)
        ph = np.degrees(np.unwrap(np.angle(h)))
        for mask, mk in ((~ok & df.periodic[0, a], "o"), (~df.periodic[0, a], "x")):
            am.semilogx(f[mask], db(h[mask] * 1e6), mk, mfc="none", color=col, ms=4)
            ap.semilogx(f[mask], ph[mask], mk, mfc="none", color=col, ms=4)
    fd = np.geomspace(f[0], f[-1], 300)
    for (branch, b), ss in models.items():
        if b != bias_v or branch not in ("reversal", "ascending", "initial"):
            continue
        h = _freq_response(ss[0, 0], fd)
        am.semilogx(fd, db(h * 1e6), "--", color="k", lw=0.9, alpha=0.7)
        ap.semilogx(fd, np.degrees(np.unwrap(np.angle(h))), "--", color="k", lw=0.9, alpha=0.7)
        # label where the branches are apart (below the electrical pole), not where R merges them
        i = int(np.searchsorted(fd, 20.0 if branch != "ascending" else 2.0))
        am.annotate(f"small-signal, {branch}", (fd[i], db(h[i] * 1e6)), fontsize=7,
                    va="bottom" if branch != "reversal" else "top")
    am.set_ylabel("|x / V_pea|  (dB re 1 um/V)")
    ap.set_ylabel("phase (deg, unwrapped)")
    ap.set_xlabel("frequency (Hz)")
    am.set_title(f"Describing functions of the PZT at bias {bias_v:g} V \n(o: current-limited, slewing; x: not periodic; dashed: small-signal models)", fontsize=10)
    fig.legend(*am.get_legend_handles_labels(), loc="outside lower center", ncol=min(6, df.amplitudes_v.size),
               fontsize=8, frameon=False)
    for ax in (am, ap):
        ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def plot_capacitances(pzt, caps, spec, path):
    """The C_h loop (q_h against V_h) over the major loop with the three slopes drawn on it."""
    lo, hi = spec.v_range
    v = np.concatenate([np.linspace(0, hi, 400), np.linspace(hi, lo, 400), np.linspace(lo, hi, 400)])
    q_op = pzt.terminal_operator().inverse()
    qh = q_op(v)
    vh = v - qh / pzt.c_pp_f
    fig, ax = plt.subplots(figsize=(8, 6))
    ax.plot(vh, qh * 1e6, color="0.3", lw=1.5, label="C_h: virgin curve, then the 0-100 V loop")
    from dataclasses import replace
    from ..linearize.small_signal import operating_point
    # the loop drawn is C_h alone, so the operating point is taken on it (creep branches aside)
    op = operating_point(replace(pzt, creep=None), spec.bias_v, "ascending", spec.v_range)
    q0 = np.interp(op.v_h_v, vh[800:], qh[800:])
    dv = np.linspace(-6, 6, 2)
    for name, c, col in (("reversal slope", caps["reversal_f"], "C3"),
                         ("on-branch slope (ascending)", op.capacitance_f, "C0")):
        ax.plot(op.v_h_v + dv, (q0 + c * dv) * 1e6, color=col, lw=2, label=f"{name}: {c * 1e6:.1f} uF")
    i_pk = 399
    ax.plot([0, vh[i_pk]], [0, qh[i_pk] * 1e6], ":", color="C2", lw=2,
            label=f"secant from rest to peak: {caps['secant_from_rest_f'] * 1e6:.1f} uF (seed ~30.5 uF)")
    ax.plot(op.v_h_v, q0 * 1e6, "ko")
    ax.annotate(f"  {spec.bias_v:g} V on the ascending branch", (op.v_h_v, q0 * 1e6), fontsize=8, va="top")
    ax.set_xlabel("V_h (V)")
    ax.set_ylabel("q_h (uC)")
    ax.set_title(f"Capacitances side by side (loop secant {caps['loop_secant_f'] * 1e6:.1f} uF)")
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(True, alpha=0.3)
    return save_figure(fig, path)


def plot_uncertainty(freq_hz, ub, path):
    """Every member's |G_i/G_nom - 1| in dB, their envelope and the fitted |W_m|; the member setting the margin."""
    fig, ax = plt.subplots(figsize=(9, 6), layout="constrained")
    for name, d in ub.deltas.items():
        ax.semilogx(freq_hz, db(d), color="0.7", lw=0.6)
    ax.semilogx(freq_hz, db(ub.envelope), "k", lw=1.5, label="envelope over members")
    fd = np.geomspace(freq_hz[0], freq_hz[-1], 400)
    w = _freq_response(ub.fit.weight, fd)
    ax.semilogx(fd, db(w), "C3", lw=2, label=f"|W_m|, order {ub.fit.order}: zeros {np.round(ub.fit.zeros_hz, 1)} Hz, "
                                            f"poles {np.round(ub.fit.poles_hz, 1)} Hz")
    y_c = db(np.interp(ub.coverage.freq_hz, freq_hz, ub.envelope))
    ax.plot([ub.coverage.freq_hz], [y_c], "C3o")
    # the note in the empty lower left (low frequency, small deviation), a line to the point
    ax.annotate(f"sets the margin ({ub.coverage.margin_db:.2f} dB):\n{ub.coverage.member}",
                (ub.coverage.freq_hz, y_c), fontsize=8, va="bottom", ha="left", xytext=(0.03, 0.05),
                textcoords="axes fraction", arrowprops={"arrowstyle": "-", "color": "C3", "lw": 0.8})
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("relative deviation from the nominal (dB)")
    ax.set_title(f"Multiplicative uncertainty: {len(ub.deltas)} members "
                 f"(nominal: small-signal with C_h = {ub.nominal_capacitance_f * 1e6:.1f} uF)", fontsize=10)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=2, fontsize=8, frameon=False)
    ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def plot_sampled(nominal, fw, path):
    """Continuous nominal loop plant against the sampled one firmware sees (hold, average, delay)."""
    nyq = 0.5 / fw.dt
    fd = np.geomspace(1, nyq * 0.999, 400)
    hc = _freq_response(nominal, fd)
    hd = _freq_response(fw, fd)
    fig, (am, ap) = plt.subplots(2, 1, sharex=True, figsize=(8, 6.5))
    am.semilogx(fd, db(hc), label="continuous K_g P_nom(s)")
    am.semilogx(fd, db(hd), "--", label="as firmware sees it: hold, period average, compute delay")
    ap.semilogx(fd, np.degrees(np.unwrap(np.angle(hc))))
    ap.semilogx(fd, np.degrees(np.unwrap(np.angle(hd))), "--")
    am.set_ylabel("firmware V per V (dB)")
    ap.set_ylabel("phase (deg, unwrapped)")
    ap.set_xlabel("frequency (Hz)")
    am.set_title(f"Sampled-data loop plant at {1 / fw.dt:g} Hz (Nyquist {nyq:g} Hz)")
    am.legend(fontsize=8)
    for ax in (am, ap):
        ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def plot_nyquist(ctrl, fw, df, loops, ub, lc, path):
    """Nyquist of the nominal loop, the describing-function loops, the -1/N(A) locus, limit cycles."""
    fd = np.geomspace(0.5, 0.4999 / fw.dt, 2000)
    l_nom = _freq_response(ctrl, fd) * _freq_response(fw, fd)
    fig, ax = plt.subplots(figsize=(8.5, 8.5), layout="constrained")
    ax.plot(l_nom.real, l_nom.imag, "k", lw=1.5, label="nominal loop C(z) G_fw(z)")
    cmap = plt.get_cmap("viridis")
    for a, amp in enumerate(df.amplitudes_v):
        la = loops[a]
        ax.plot(la.real, la.imag, ".-", color=cmap(a / max(1, df.amplitudes_v.size - 1)), lw=0.6, ms=2,
                label=f"L_A, A = {amp:g} V" if a in (0, df.amplitudes_v.size - 1) else None)
    # -1/N(A) with N = P(jw; A) / P_nom(jw) at the nominal loop's phase crossover (or nearest)
    ph = np.angle(l_nom)
    k = int(np.argmin(np.abs(np.abs(ph) - np.pi) + (l_nom.real > 0) * 10))
    f_pc = fd[k]
    p_nom = complex(ub.nominal(2j * np.pi * f_pc)) / ub.nominal_gauge_v_per_m
    i_f = int(np.argmin(np.abs(np.log(df.freq_hz / f_pc))))
    n = df.x_m_per_v[0, :, i_f] / p_nom
    locus = -1.0 / n
    ax.plot(locus.real, locus.imag, "C3s-", ms=4, label=f"-1/N(A) at {df.freq_hz[i_f]:.0f} Hz, A = {df.amplitudes_v[0]:g}-"
                                                        f"{df.amplitudes_v[-1]:g} V drive amplitude (labels):\nwhere "
                                                        f"L_A meets it, a limit cycle of that amplitude is predicted")
    for c in lc["limit_cycles"]:
        # where the locus meets the nominal curve: -1/N at the predicted amplitude
        la = np.log(df.amplitudes_v)
        n_star = np.interp(np.log(c["amplitude_v"]), la, n.real) + 1j * np.interp(np.log(c["amplitude_v"]), la, n.imag)
        ax.plot([(-1 / n_star).real], [(-1 / n_star).imag], "C1*", ms=16, label=f"limit cycle: {c['amplitude_v']:.2g} V at {c['freq_hz']:.0f} Hz "
                                                f"({'stable' if c['stable'] else 'unstable'})")
    ax.plot([-1], [0], "r+", ms=14, mew=2, label="-1 (where each L_A must not pass)")
    ax.set_xlim(-3, 1.5)
    ax.set_ylim(-2.5, 2)
    ax.set_aspect("equal")
    label_locus(ax, locus, df.amplitudes_v)
    ax.set_xlabel("Re")
    ax.set_ylabel("Im")
    ttl = "no limit cycle predicted" if not lc["limit_cycles"] else f"{len(lc['limit_cycles'])} limit cycle(s) predicted"
    ax.set_title(f"Loop with the describing function: {ttl}")
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=2, fontsize=8, frameon=False)
    ax.grid(True, alpha=0.3)
    return save_figure(fig, path)
