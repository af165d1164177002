"""Figures of the mirror's MIMO study and verification (issue 15, item 6).

Study: the decoupled plant's singular values and diagonal over the family (MIMO Bode), the
loop's simultaneous disk margin over frequency, the structural modes on the nominal diagonal.
Verification: per scenario, the mirror's axes against their references (urad, nm) and each
stack's command and current. Units in the axis labels; log frequency axes in Hz.
"""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .output import save_figure  # noqa: E402

__all__ = ["plot_mimo_bode", "plot_disk_margins", "plot_modes", "plot_mirror_run"]

_AX = ("tip", "tilt", "piston")


def plot_mimo_bode(path, freq_hz, plants, nominal_name):
    """Singular values (max/min) of G_dec over the family and the nominal's diagonal and largest off-diagonal, dB."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for name, g in plants.items():
        s = np.linalg.svd(g, compute_uv=False)
        lw, c = (1.6, "k") if name == nominal_name else (0.6, "0.6")
        a1.semilogx(freq_hz, 20 * np.log10(s[:, 0]), color=c, lw=lw)
        a1.semilogx(freq_hz, 20 * np.log10(s[:, -1]), color=c, lw=lw, ls="--")
    a1.set_title("singular values of the decoupled plant\n(max solid, min dashed; nominal black, family grey)")
    g = plants[nominal_name]
    for i, ax in enumerate(_AX):
        a2.semilogx(freq_hz, 20 * np.log10(np.abs(g[:, i, i])), label=f"{ax} -> {ax}")
    off = np.abs(g * (1 - np.eye(3))[None]).max(axis=(1, 2))
    a2.semilogx(freq_hz, 20 * np.log10(np.maximum(off, 1e-12)), "k:", label="largest off-diagonal")
    a2.set_title(f"nominal member ({nominal_name})")
    for a in (a1, a2):
        a.set_xlabel("frequency, Hz")
        a.grid(True, which="both", alpha=0.3)
    a1.set_ylabel("gain, dB (axis unit per axis unit)")
    a2.legend(fontsize=8)
    a1.set_ylim(-140, 20)
    save_figure(fig, path)
    plt.close(fig)
    return path


def plot_disk_margins(path, freq_hz, loops, worst_alpha, floor=0.4):
    """1 / sigma_max(S - I/2) per frequency (the unstructured disk margin, <= the simultaneous alpha) per member."""
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for name, l in loops.items():
        m = np.linalg.inv(np.eye(3)[None] + l) - 0.5 * np.eye(3)[None]
        s = np.linalg.svd(m, compute_uv=False)[:, 0]
        ax.semilogx(freq_hz, 1.0 / s, lw=0.8, label=name if len(loops) <= 6 else None)
    ax.axhline(floor, color="r", ls="--", label=f"floor alpha = {floor:g}")
    ax.axhline(worst_alpha, color="k", ls=":", label=f"worst simultaneous alpha (mu) = {worst_alpha:.3f}")
    ax.set_ylim(0, 2.5)
    ax.set_xlabel("frequency, Hz")
    ax.set_ylabel("disk margin alpha (1 / sigma_max(S - I/2))")
    ax.set_title("simultaneous disk margin over frequency, every member (axis outputs)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    save_figure(fig, path)
    plt.close(fig)
    return path


def plot_modes(path, freq_hz, nominal_diag, modes_hz, labels, notches):
    """|G_dec,ii| of the nominal member with the structural modes (amplifier-terminated) and the notches marked."""
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for i, a in enumerate(_AX):
        ax.semilogx(freq_hz, 20 * np.log10(np.abs(nominal_diag[:, i])), label=a)
    prev, y = -np.inf, 0.97
    for f, lab in zip(modes_hz, labels):
        ax.axvline(f, color="0.5", lw=0.7, ls=":")
        y = 0.6 if (prev > 0 and f / prev < 1.03 and y > 0.9) else 0.97   # stagger labels of modes a few % apart
        ax.text(f, y, f" {lab}\n {f:.0f} Hz", rotation=90, va="top", fontsize=7, transform=ax.get_xaxis_transform())
        prev = f
    for a, n in notches.items():
        if n is not None:
            ax.plot([n[0]], [0], "v", color="r", ms=6)
    ax.set_xlim(50, freq_hz[-1])
    ax.set_xlabel("frequency, Hz")
    ax.set_ylabel("decoupled diagonal gain, dB")
    ax.set_title("structural modes on the nominal decoupled plant (red: notches)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    save_figure(fig, path)
    plt.close(fig)
    return path


def plot_mirror_run(path, run, title):
    """Axes (tip/tilt urad, piston nm) against the references; per-stack command (V) and current (mA)."""
    dec = max(1, run.t_s.size // 20000)          # at most ~20000 points per trace
    run = _decimated(run, dec)
    t = run.t_s
    fig, axs = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    a = axs[0]
    a.plot(t, run.tip_rad * 1e6, lw=0.7, label="tip")
    a.plot(t, run.tilt_rad * 1e6, lw=0.7, label="tilt")
    a.plot(t, run.ref[:, 0] * 1e6, "k--", lw=0.8, label="tip reference")
    if np.any(run.ref[:, 1]):
        a.plot(t, run.ref[:, 1] * 1e6, "k:", lw=0.8, label="tilt reference")
    a.set_ylabel("angle, urad")
    a.legend(fontsize=8, loc="upper left")
    a2 = a.twinx()
    a2.plot(t, run.piston_m * 1e9, color="tab:green", lw=0.6, alpha=0.7)
    a2.set_ylabel("piston, nm", color="tab:green")
    for j in range(3):
        axs[1].plot(t, run.v_cmd_v[:, j], lw=0.7, label=f"stack {j + 1}")
        axs[2].plot(t, run.i_a[:, j] * 1e3, lw=0.5, label=f"stack {j + 1}")
    axs[1].set_ylabel("command, V")
    axs[2].set_ylabel("current, mA")
    axs[2].set_xlabel("time, s")
    axs[1].legend(fontsize=8, loc="upper left")
    for a in axs:
        a.grid(True, alpha=0.3)
    axs[0].set_title(title)
    save_figure(fig, path)
    plt.close(fig)
    return path


def _decimated(run, k):
    import dataclasses
    if k == 1:
        return run
    return dataclasses.replace(run, **{f.name: getattr(run, f.name)[k - 1::k] for f in dataclasses.fields(run)
                                       if getattr(run, f.name) is not None})
