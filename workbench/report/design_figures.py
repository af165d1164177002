"""Figures of a design study: loop Bode over the family, S and T, Nyquist with -1/N(A), steps."""

import control
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .output import save_figure  # noqa: E402

__all__ = ["plot_loop_family", "plot_sensitivities", "plot_nyquist_family", "plot_steps"]


def _kind(name):
    return "DF" if ", DF " in name else "small-signal"


def plot_loop_family(freq_hz, loops, path, params):
    """|L| and phase of every member's sampled loop; describing functions in colour."""
    fig, (am, ap) = plt.subplots(2, 1, sharex=True, figsize=(9, 7.5))
    for name, l in loops.items():
        col = "C0" if _kind(name) == "DF" else "0.6"
        am.loglog(freq_hz, np.abs(l), color=col, lw=0.6, alpha=0.6)
        ph = np.degrees(np.angle(l))
        ph = np.where(ph > 0, ph - 360, ph)
        ap.semilogx(freq_hz, ph, color=col, lw=0.6, alpha=0.6)
    am.axhline(1, color="k", lw=0.8)
    ap.axhline(-180, color="k", lw=0.8)
    ap.axhline(-135, color="C3", lw=0.8, ls="--", label="45 deg phase margin")
    am.plot([], [], "C0", label="describing functions (amplitude x serial x C_p x gauge)")
    am.plot([], [], color="0.6", label="small-signal models on each branch")
    am.set_ylabel("|L|")
    ap.set_ylabel("phase of L (deg)")
    ap.set_xlabel("frequency (Hz)")
    ap.set_ylim(-360, 0)
    am.set_title(f"Loop over the family: structured controller, nominal crossover {params['fc_hz']:.0f} Hz "
                 f"(sampled at 10 kHz)")
    am.legend(fontsize=8)
    ap.legend(fontsize=8)
    for ax in (am, ap):
        ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def plot_sensitivities(freq_hz, loops, ub, path):
    """|S| and |T| of every member with 1/|W_m| (robust stability needs |T| below it)."""
    fig, ax = plt.subplots(figsize=(9, 5.5))
    for l in loops.values():
        with np.errstate(invalid="ignore"):        # NaN where a member is left out
            ax.loglog(freq_hz, np.abs(1 / (1 + l)), color="C0", lw=0.5, alpha=0.5)
            ax.loglog(freq_hz, np.abs(l / (1 + l)), color="C1", lw=0.5, alpha=0.5)
    w = np.abs(np.asarray(control.frequency_response(ub.fit.weight, 2 * np.pi * freq_hz).complex).ravel())
    ax.loglog(freq_hz, 1 / w, "k--", lw=1.5, label="1 / |W_m|: |T| must stay below")
    ax.plot([], [], "C0", label="|S| of each member")
    ax.plot([], [], "C1", label="|T| of each member")
    ax.axhline(2, color="C3", lw=0.8, ls=":", label="|S| = 6 dB")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("magnitude")
    ax.set_ylim(1e-3, 10)
    ax.set_title("Sensitivity and complementary sensitivity over the family")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def plot_nyquist_family(freq_hz, loops, df, ub, ctrl_d, fw_factor, cycles, path):
    """Nyquist of every member near -1, and -1/N(A) at the nominal's phase crossover."""
    fig, ax = plt.subplots(figsize=(8, 7))
    for name, l in loops.items():
        ax.plot(l.real, l.imag, color="C0" if _kind(name) == "DF" else "0.6", lw=0.6, alpha=0.6)
    c = np.asarray(control.frequency_response(ctrl_d, 2 * np.pi * freq_hz).complex).ravel()
    p_nom = np.asarray(control.frequency_response(ub.nominal, 2 * np.pi * freq_hz).complex).ravel()
    l_nom = c * fw_factor * p_nom
    ax.plot(l_nom.real, l_nom.imag, "k", lw=1.5, label="nominal loop")
    ph = np.angle(l_nom)
    k = int(np.argmin(np.abs(np.abs(ph) - np.pi) + (l_nom.real > 0) * 10))
    n = ub.nominal_gauge_v_per_m * df.x_m_per_v[0, :, k] / p_nom[k]
    ok = np.isfinite(n) & (np.abs(n) > 0)
    locus = -1 / n[ok]
    ax.plot(locus.real, locus.imag, "C3s-", ms=4, label=f"-1/N(A), A = {df.amplitudes_v[ok][0]:g}-"
                                                        f"{df.amplitudes_v[ok][-1]:g} V at {freq_hz[k]:.0f} Hz")
    ax.plot([-1], [0], "r+", ms=14, mew=2)
    t = np.linspace(0, 2 * np.pi, 200)
    ax.plot(-1 + 0.5 * np.cos(t), 0.5 * np.sin(t), "C3:", lw=0.8, label="|1 + L| = 0.5 (|S| = 6 dB)")
    title = "no limit cycle predicted" if not cycles else "; ".join(
        f"limit cycle {c.amplitude_v:.2g} V at {c.freq_hz:.0f} Hz" for c in cycles)
    ax.set_title(f"Nyquist over the family: {title}")
    ax.set_xlim(-2.5, 1.5)
    ax.set_ylim(-2.5, 1.5)
    ax.set_aspect("equal")
    ax.set_xlabel("Re L")
    ax.set_ylabel("Im L")
    ax.legend(fontsize=8, loc="lower left")
    ax.grid(True, alpha=0.3)
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
