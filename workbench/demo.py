"""The default job (``make demo``): the seed's figures reproduced from the plant files."""

from pathlib import Path

import numpy as np

__all__ = ["run_demo", "creep_hold", "slew_step"]

PLANTS = ("plants/p888_51_sn637.toml", "plants/p888_51_sn629.toml", "plants/p888_51_sn618.toml")
CREEP_PLANT = "plants/p888_51_sn637_creep.toml"
TABLE1 = "plants/data/p888_51_instron_table1.csv"


def creep_hold(plant, *, v_hold_v=100.0, hold_s=1000.0, sample_s=1e-3, fit_from_s=1.0):
    """Step from rest to ``v_hold_v`` and hold; fit seed 001's law on the creep.

    The amplifier's current limit makes the step a ~0.5 s slew (2 mA into ~1 mC), so
    the fit starts at ``fit_from_s``, after the dynamic response, as seed 001 excludes
    it. The fit uses samples evenly spaced in log time so every decade weighs the same
    (gamma is a per-decade rate).
    """
    from .plant import PZTSimulator, log_creep_fit
    sim = PZTSimulator(plant.pzt, sample_s)
    n = int(round(hold_s / sample_s))
    dec = max(1, n // 20000)
    tr = sim.run(np.full(n, v_hold_v), decimate=dec)
    t_fit = np.geomspace(fit_from_s, tr.t_s[-1], 200)
    return tr, log_creep_fit(t_fit, np.interp(t_fit, tr.t_s, tr.x_m))


def slew_step(plant, *, v0_v=10.0, v1_v=90.0, sample_s=1e-5, duration_s=1.2):
    """A large voltage step through R and the current limit, up then down."""
    from .plant import PZTSimulator
    sim = PZTSimulator(plant.pzt, sample_s)
    n = int(round(duration_s / sample_s))
    v = np.where(np.arange(n) * sample_s < duration_s / 2, v1_v, v0_v)
    sim.run(np.full(int(0.2 / sample_s), v0_v))
    return sim.run(v, decimate=10)


def _plot_creep(tr, fit, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .plant import log_creep
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    keep = tr.t_s >= 0.01
    ax[0].semilogx(tr.t_s[keep], tr.x_m[keep] * 1e6, label="simulated (Kelvin-Voigt branches)")
    ax[0].semilogx(tr.t_s[keep], log_creep(tr.t_s[keep], fit.l0, fit.gamma) * 1e6, "--",
                   label=f"seed 001 eq. 1: L0 = {fit.l0 * 1e6:.3f} um, gamma = {fit.gamma:.4f}")
    ax[0].set_xlabel("time since the step [s]")
    ax[0].set_ylabel("x [um]")
    ax[0].legend(fontsize=8)
    ax[0].set_title("Creep after a 0-100 V step (log time)")
    ax[0].axvspan(tr.t_s[keep][0], 1.0, color="0.9", label="slew at the 2 mA limit (not fitted)")
    ax[0].legend(fontsize=8)
    late = tr.t_s >= 1.0
    resid = tr.x_m[late] - log_creep(tr.t_s[late], fit.l0, fit.gamma)
    ax[1].semilogx(tr.t_s[late], resid * 1e9)
    ax[1].set_xlabel("time since the step [s]")
    ax[1].set_ylabel("residual [nm]")
    ax[1].set_title("Departure from the logarithmic law (fit window)")
    for a in ax:
        a.grid(alpha=0.3, which="both")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def _plot_slew(tr, plant, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    t = (tr.t_s - tr.t_s[0]) * 1e3
    ax[0].plot(t, tr.v_pea_v, label="V_pea (amplifier)")
    ax[0].plot(t, tr.v_t_v, label="V_h + V_p (stack terminals)")
    ax[0].set_ylabel("V")
    ax[0].legend(fontsize=8)
    ax[1].plot(t, tr.i_a * 1e3)
    ax[1].axhline(plant.pzt.current_limit_source_a * 1e3, color="r", ls="--", lw=0.8, label="+2 mA source limit")
    ax[1].axhline(-plant.pzt.current_limit_sink_a * 1e3, color="r", ls=":", lw=0.8, label="-14 mA sink limit")
    ax[1].set_ylabel("i [mA]")
    ax[1].legend(fontsize=8)
    ax[2].plot(t, tr.x_m * 1e6)
    ax[2].set_ylabel("x [um]")
    ax[2].set_xlabel("time [ms]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].set_title("10-90 V step through R = 80 ohm and the amplifier current limit (slew-limited)")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def _plot_gauge(plant, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .plant import bridge_gain, bridge_output, gauge_run, gauge_run_equivalent
    from .plant.gauge import bridge_output_eq27
    g = plant.gauge
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    x = np.linspace(-3e-6, 18e-6, 200)
    k0 = bridge_gain(0.0, g)
    ax[0].plot(x * 1e6, (bridge_output(x, g) - x * k0) * 1e6, label="eq. 26 with imbalance - linear")
    ax[0].plot(x * 1e6, (bridge_output_eq27(x, g) - x * k0) * 1e6, label="eq. 27 (no imbalance) - linear")
    ax[0].set_xlabel("x [um]")
    ax[0].set_ylabel(f"bridge output minus {k0:.2f} V/m x [uV]")
    ax[0].set_title("Bridge nonlinearity and imbalance")
    ax[0].legend(fontsize=8)
    n = 40
    xs = np.where(np.arange(n) >= 10, 5e-6, 0.0)
    per = gauge_run(xs, g, noise=False)
    eq = gauge_run_equivalent(xs, g, noise=False)
    k = np.arange(n)
    ax[1].step(k * 100, xs * 1e6, where="post", label="x at the period ends [um]")
    ax[1].plot(k * 100, (per.dac_v - per.dac_v[0]) * g.calibration_m_per_v * 1e6, "o", ms=4,
               label="DAC, sample by sample (80 ADC samples/period)")
    ax[1].plot(k * 100, (eq.dac_v - eq.dac_v[0]) * g.calibration_m_per_v * 1e6, "x",
               label="DAC, per-period equivalent")
    ax[1].set_xlabel("time [us]")
    ax[1].set_ylabel("x [um]")
    ax[1].set_title("5 um step seen through the sampled chain")
    ax[1].set_xlim(600, 1600)
    ax[1].legend(fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def run_demo(out_dir, progress=None):
    """Run every reproduction, write figures into ``out_dir``, return the summary dict."""
    from .identify.freefree import plot_freefree, run_freefree
    from .identify.transducer import identify_transducer
    from .plant import load_plant
    from .plant.gauge import gauge_summary
    from .report import save_figure

    say = progress or (lambda line: None)
    out = Path(out_dir)
    summary = {"figures": []}

    def fig(f, name):
        path = save_figure(f, out / name)
        summary["figures"].append(str(path))
        say(f"  figure {path}")

    say("T_em from Table 1 (eq. 6)...")
    tr = identify_transducer(TABLE1).to_json()
    summary["transducer"] = tr
    say(f"  T_em = {tr['t_em_n_per_v']:.2f} N/V over {len(tr['runs_used'])} runs, "
        f"{len(tr['runs_flagged'])} runs flagged (seed 46.71 N/V)")
    summary["gauge"] = {}
    summary["freefree"] = {}
    for path in PLANTS:
        plant = load_plant(path)
        gs = gauge_summary(plant)
        summary["gauge"][plant.serial] = gs
        say(f"{plant.serial}: bridge {gs['bridge_v_per_m']:.2f} V/m at 7.5 um, chain {gs['chain_v_per_m']:.0f} V/m, "
            f"bias {gs['bias_v'] * 1e3:.3f} mV")
        res = run_freefree(plant)
        summary["freefree"][plant.serial] = res.summary()
        say(f"  free-free: stroke {res.stroke_m * 1e6:.2f} um, V_h/V {res.v_h_over_v_pea:.3f}, hysteresis "
            f"{100 * res.hysteresis_x_fraction:.1f} %, C_p {res.cp_recovered_f * 1e6:.4f} uF")
        fig(plot_freefree(res, f"{plant.name}: free-free test (seed 000 sec. 3.3, Figs. 7 and 9)"),
            f"freefree_{plant.serial.lower()}.png")
    plant = load_plant(PLANTS[0])
    fig(_plot_gauge(plant, f"{plant.name}: gauge chain (seed 000 sec. 5)"), "gauge_chain.png")
    say("current-limited step through R...")
    st = slew_step(plant)
    up = np.diff(st.v_t_v) / np.diff(st.t_s)
    summary["slew"] = {"max_rate_up_v_per_s": float(up.max()), "max_rate_down_v_per_s": float(-up.min()),
                       "peak_current_a": list(st.peak_current_a)}
    say(f"  terminal slew up to {up.max():.0f} V/s rising, {-up.min():.0f} V/s falling")
    fig(_plot_slew(st, plant, plant.name), "slew_step.png")
    say("creep: 1000 s hold at 100 V...")
    creep_plant = load_plant(CREEP_PLANT)
    tr_c, fit = creep_hold(creep_plant)
    summary["creep"] = {"l0_m": fit.l0, "gamma": fit.gamma, "sigma_l0_m": fit.sigma_l0,
                        "sigma_gamma": fit.sigma_gamma, "chi2_reduced": fit.chi2_reduced}
    say(f"  L0 = {fit.l0 * 1e6:.3f} um, gamma = {fit.gamma:.4f} +/- {fit.sigma_gamma:.4f}")
    fig(_plot_creep(tr_c, fit, f"{creep_plant.name}: creep (seed 001)"), "creep_hold.png")
    say("linearization: describing functions, small-signal models, W_m over the three serials...")
    from .linearize.run import run_linearize
    lin = run_linearize(CREEP_PLANT, PLANTS[1:], out_dir=Path(out_dir) / "linearize")
    u = lin["uncertainty"]
    say(f"  W_m order {u['weight']['order']}, {u['weight']['gain']:.3f} at DC; coverage margin "
        f"{u['coverage_margin_db']:.2f} dB set by {u['worst_member']}")
    summary["linearize"] = {"capacitances": lin["capacitances"], "uncertainty": {k: u[k] for k in (
        "weight", "coverage_margin_db", "worst_member", "nominal")}, "figures": lin["figures"]}
    summary["figures"] += list(lin["figures"].values())
    return summary
