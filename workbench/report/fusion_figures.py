"""Figure and report of the fused-feedback study (:func:`workbench.selfsense.fused_loop.run_fused_study`)."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .output import save_figure, write_json, write_text  # noqa: E402

__all__ = ["plot_fusion", "write_fused_outputs"]

NM = 1e9
TITLES = {"gauge": "gauge", "charge": "charge estimate", "fused": "fused"}


def plot_fusion(data, path):
    """Error amplitude spectra of the sensors and the blend (left), fused error RMS against the blend's
    crossover (middle), the three closed loops' true x during the hold (right)."""
    a = data["_arrays"]
    fc = data["blend"]["crossover_hz"]
    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(15, 4.8))
    f = a["freq_hz"]
    sg = data["noise_per_sample_m"]["gauge"] * NM
    ax1.loglog(f, np.sqrt(a["s_gauge"]) * NM, color="C0", label=f"gauge (white, {sg:.1f} nm per sample)")
    ax1.loglog(f, np.sqrt(a["s_charge"]) * NM, color="C1", label="charge estimate (drift + noise)")
    ax1.loglog(f, np.sqrt(a["s_fused"]) * NM, color="k", lw=1.6, label=f"fused, blend at {fc:.2f} Hz")
    ax1.axvline(fc, color="0.5", ls=":", lw=1)
    ax1.set_xlabel("frequency, Hz")
    ax1.set_ylabel("error amplitude spectral density, nm/sqrt(Hz)")
    ax1.set_title("sensor error spectra (one-sided)")
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), fontsize=8, ncol=1)
    ax2.semilogx(a["grid_hz"], a["j_rms_m"] * NM, color="k")
    ax2.plot([fc], [data["blend"]["fused_error_rms_m"] * NM], "o", color="C3",
             label=f"chosen: {fc:.2f} Hz, {data['blend']['fused_error_rms_m'] * NM:.2f} nm RMS")
    ax2.axhline(data["blend"]["charge_error_rms_m"] * NM, color="C1", ls="--", lw=1,
                label=f"charge alone {data['blend']['charge_error_rms_m'] * NM:.2f} nm")
    ax2.set_xlabel("blend crossover, Hz")
    ax2.set_ylabel("fused error RMS, nm")
    ax2.set_title(f"fused error over {data['blend']['band_hz'][0]:.3g}-{data['blend']['band_hz'][1]:.0f} Hz")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), fontsize=8)
    for s, arr in a["closed"].items():
        t, x, r = arr["t_s"], arr["x_m"], arr["reference_rel_m"]
        n_tri = int(np.flatnonzero(r)[-1]) + 1 if np.any(r) else 0
        dt = float(t[1] - t[0])
        hold = np.arange(min(n_tri + int(round(1.0 / dt)), t.size - 2), t.size)     # after the 1 s settling
        step = max(1, hold.size // 20000)
        xh = x[hold][::step]
        ax3.plot(t[hold][::step] - t[n_tri], (xh - np.mean(xh)) * NM, lw=0.6, label=TITLES[s])
    ax3.set_xlabel("time in the hold (after 1 s settling), s")
    ax3.set_ylabel("true x minus its mean, nm")
    ax3.set_title("closed loops: hold on the nonlinear plant")
    ax3.grid(True, alpha=0.3)
    ax3.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), fontsize=8, ncol=3)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return str(path)


def _report(data, figure):
    b = data["blend"]
    lines = ["# Fused gauge + charge feedback", "",
             f"Plant `{data['plant']}`, stroke {data['stroke_m'] * 1e6:.2f} um, servo {data['sample_hz']:.0f} Hz.", "",
             f"Blend crossover **{b['crossover_hz']:.3g} Hz** (minimum of the fused error over "
             f"{b['band_hz'][0]:.3g}-{b['band_hz'][1]:.0f} Hz; drift spectrum from a {b['drift_record_s']:.0f} s "
             f"staircase, "
             f"stage-4 error {b['drift_record_pp_m'] * NM:.1f} nm p-p). Error RMS over that band: gauge "
             f"{b['gauge_error_rms_m'] * NM:.2f} nm, charge {b['charge_error_rms_m'] * NM:.2f} nm, fused "
             f"{b['fused_error_rms_m'] * NM:.2f} nm.", ""]
    # both controllers' preflight against the plant (verify's), as the console's WARNING lines
    lines += [f"- **WARNING:** {w} (`--strict` refuses it)" for w in data.get("warnings") or ()]
    lines += [""] if data.get("warnings") else []
    lines += ["| sensor | controller | crossover | PM | GM | triangle error RMS | hold drift | hold noise RMS |",
              "|---|---|---|---|---|---|---|---|"]
    for r in data["closed_loops"]:
        m = r["margins"]
        lines.append(f"| {TITLES[r['sensor']]} | `{r['controller'].rsplit('/', 1)[-1]}` | {m['crossover_hz']:.0f} Hz | "
                     f"{m['phase_margin_deg']:.1f} deg | {m['gain_margin_db']:.1f} dB | "
                     f"{r['triangle_rms_percent_stroke']:.4f} % of stroke | {r['hold_drift_m'] * NM:+.2f} nm over "
                     f"{r['hold_s']:.0f} s | {r['hold_noise_rms_m'] * NM:.2f} nm |")
    lines += ["", "Margins and crossover: the nominal loop at 50 V with each sensor's path (the fused one is "
              "F_low L_gauge + F_high L_charge). Triangle: 80 % of the quasi-static stroke about the 50 V closing "
              "point, RMS after the first period, relative to the position at closing (the sensor's offset at "
              "closing, from the true x, added; nothing else subtracted). The loop closes when the reading has "
              "settled (at least 1 s), the reference is led by v/K_v and the gauge reading linearized: the "
              "simulation computes these three (an export carries them with "
              "workbench.verify.sensors.with_firmware_startup).",
              ""]
    if "targets_met" in data:
        tm = data["targets_met"]
        lines.append("Targets (fused): triangle <= 0.01 % of stroke " + ("met" if tm["triangle"] else "MISSED")
                     + "; hold drift <= 1 nm " + ("met" if tm["hold_drift"] else "MISSED")
                     + f" (over {data['closed_loops'][-1]['hold_s']:.0f} s, target 1000 s); PM >= 45 / GM >= 6 dB "
                     + ("met" if tm["margins"] else "MISSED") + ".")
        lines.append("")
    if "fixed_point" in b:
        fp = b["fixed_point"]
        lines += [f"Firmware blend: `fused_blend.h` (fixed point, k = {fp['k']} / 2^{fp['coef_bits']}, state "
                  f"Q{fp['frac_bits']} of {fp['lsb_m']:.3g} m counts; bit for bit with "
                  "`workbench.selfsense.blend_fixed.FixedBlend.run`).", ""]
    lines += [f"![fusion]({figure.rsplit('/', 1)[-1]})", ""]
    return "\n".join(lines)


def write_fused_outputs(out, data):
    """fused.png, fused_report.md (and its self-contained fused_report.html), fused.json and the blend's
    fixed-point C header fused_blend.h in ``out``; returns {"fused": figure path, "header": header path,
    "report_html": HTML path}."""
    from pathlib import Path

    from ..selfsense.blend_fixed import FixedBlend, blend_header
    from ..selfsense.fusion import Blend
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fixed = FixedBlend(Blend(data["blend"]["crossover_hz"], 1.0 / data["sample_hz"]))
    write_text(out / "fused_blend.h", blend_header(fixed))
    data["blend"]["fixed_point"] = {"k": fixed.k, "coef_bits": fixed.coef_bits, "frac_bits": fixed.frac_bits,
                                    "lsb_m": fixed.lsb_m, "header": str(out / "fused_blend.h")}
    fig = plot_fusion(data, out / "fused.png")
    write_text(out / "fused_report.md", _report(data, fig))
    from .html import write_html_report
    html = write_html_report(out / "fused_report.md")
    write_json(out / "fused.json", {k: v for k, v in data.items() if k != "_arrays"})
    return {"fused": fig, "header": str(out / "fused_blend.h"), "report_html": str(html)}
