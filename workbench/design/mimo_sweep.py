"""What damping buys as the mirror's first flexure mode moves through the servo band (issue 15, item 4).

The committed mirror (``plants/fsm_p888_51.toml``) has its tip/tilt flexure modes at ~1.07 kHz,
four times the notch-only design's delay-limited crossover (~250 Hz), so damping them cannot
buy bandwidth there. This sweep makes the statement general: the mirror's moving mass and
inertia are scaled by a factor s (``dataclasses.replace`` of the loaded mirror, the file's
values untouched), which moves the three flexure modes by ~1/sqrt(s) and leaves every static
gain (kinematics, stroke, DC loop gain) unchanged; at each point the notch-only and the
IFF-damped decoupled designs (:func:`~workbench.design.mimo.design_mimo`) and optionally the
MIMO H-infinity design (:func:`~workbench.design.mimo_hinf.design_hinf`) are run on the same
small-signal family, and their worst-member closed-loop bandwidths and crossovers are compared
against the mode frequency over the delay-limited crossover (the notch-only crossover with the
modes far above the band, the sweep's stiffest point).

``PYTHONPATH=. .venv/bin/python -m workbench.design.mimo_sweep [plants/fsm_p888_51.toml] [--hinf]``
prints the Markdown table and writes ``out/mimo_sweep.png`` and ``out/mimo_sweep.json``.

The second sweep, :func:`rate_sweep`, keeps the committed mirror and changes the servo rate
(:func:`rate_spec`: the chain's hold, averaging and compute delay all scale with dt_s), with each
rate's lag-limited crossover f_d measured on the mirror with its modes far above the band; it
reports three bandwidths (|T| and |S| at the gauge-estimated axes, and the mirror angle's own,
:func:`mirror_closed_loop`) and the margins against the issue's floors.
``PYTHONPATH=. .venv/bin/python -m workbench.design.mimo_sweep plants/fsm_p888_51.toml --rates``
prints the tables and writes ``out/mimo_rate_sweep.json`` (``--rates --bridge``: the IFF from each stack's
charge bridge, the one that exports; ``out/mimo_rate_sweep_bridge.json``).

:func:`mirror_angle_limit` says why no gauge-fed design, damped or not, reaches 2x on the mirror's
own angle: the transfer from the stack voltages to the mirror's tip/tilt has transmission zeros at
the housing's rocking frequency with the mirror free, f_rock sqrt(1 + J / I_h), and feedback does not
move a plant's zeros. ``... -m workbench.design.mimo_sweep plants/fsm_p888_51.toml --limit`` prints them.
"""

import dataclasses
import sys
import time

import numpy as np

from ..errors import DesignError
from ..linearize.mimo import mirror_family
from .mimo import AXIS_NAMES, MIMO_SPEC, axis_resonances_hz, default_freq_hz, design_mimo, nominal_name

__all__ = ["scaled_mirror", "damping_sweep", "sweep_markdown", "DEFAULT_MODES_HZ",
           "rate_spec", "rate_sweep", "rate_markdown", "sensitivity_bandwidth_hz", "mirror_closed_loop",
           "mirror_bandwidth_hz", "DEFAULT_RATES_HZ", "transmission_zeros", "zero_output_directions", "mirror_angle_limit",
           "limit_markdown"]

DEFAULT_RATES_HZ = (10e3, 20e3, 40e3)   # servo sample rates, Hz (space FSMs run 5-40 kHz)

DEFAULT_MODES_HZ = (250.0, 400.0, 600.0, None, 2000.0, 4000.0)   # None: the committed mirror


def scaled_mirror(fsm, mass_scale):
    """The mirror with its moving mass and inertia times ``mass_scale`` (the loaded object; the file is untouched)."""
    if not mass_scale > 0:
        raise ValueError(f"mass_scale must be positive; got {mass_scale!r}")
    return dataclasses.replace(fsm, mass_kg=fsm.mass_kg * mass_scale, inertia_kg_m2=fsm.inertia_kg_m2 * mass_scale)


def damping_sweep(fsm, modes_hz=DEFAULT_MODES_HZ, hinf=False, branches=("ascending", "reversal"), progress=None,
                  hinf_kwargs=None):
    """Notch-only, IFF-damped (and H-inf) designs with the tip flexure mode near each of ``modes_hz``.

    Returns a list of dicts (one per point): ``mass_scale``, ``tip_mode_hz`` (the decoupled
    nominal's tip resonance, measured), and per design ``{axis: (bandwidth Hz, lowest crossover Hz)}``.
    """
    nom0 = mirror_family(fsm, branches=("ascending",))[nominal_name()]
    f1 = axis_resonances_hz(fsm, nom0)[0]
    rows = []
    for i, target in enumerate(modes_hz):
        scale = 1.0 if target is None else (f1 / target) ** 2
        m = scaled_mirror(fsm, scale)
        fam = mirror_family(m, branches=branches)
        tip_hz = axis_resonances_hz(m, fam[nominal_name()])[0]
        row = {"mass_scale": scale, "tip_mode_hz": tip_hz, "designs": {}}
        t0 = time.perf_counter()
        designs = {"notch only": design_mimo(m, fam, damping=False), "IFF damped": design_mimo(m, fam, damping=True)}
        if hinf:
            from .mimo_hinf import design_hinf
            try:
                designs["MIMO H-inf"] = design_hinf(m, fam, **(hinf_kwargs or {}))
            except DesignError as err:             # no controller meets the weights at the floor: a result
                designs["MIMO H-inf"] = None
                row["hinf_error"] = str(err)
        for label, d in designs.items():
            if d is None:
                row["designs"][label] = {ax: (np.nan, np.nan) for ax in ("tip", "tilt", "piston")}
                continue
            s = d.summary()["axes"]
            row["designs"][label] = {ax: (s[ax]["bandwidth_hz"]["value"], s[ax]["crossover_hz_min"]["value"])
                                     for ax in ("tip", "tilt", "piston")}
        if getattr(designs["IFF damped"], "iff_info", None):
            row["iff_zeta"] = (designs["IFF damped"].iff_info["zeta_min_open"],
                               designs["IFF damped"].iff_info["zeta_min_damped"])
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        if progress is not None:
            progress(i + 1, len(modes_hz))
    # the delay-limited crossover: the notch-only tip crossover at the stiffest point
    top = max(rows, key=lambda r: r["tip_mode_hz"])
    f_d = top["designs"]["notch only"]["tip"][1]
    for r in rows:
        r["delay_limited_crossover_hz"] = f_d
    return rows


def sweep_markdown(rows):
    """GitHub Markdown table of :func:`damping_sweep`'s rows (tip axis), ratios damped / notch-only."""
    labels = list(rows[0]["designs"])   # (NaN: no H-inf controller meets the weights at the W_s floor)
    head = ["tip mode Hz", "mode / f_d", "mass x"] + [f"{lb} BW / f_c, Hz" for lb in labels] + \
        ["IFF / notch BW", "IFF / notch f_c"] + (["H-inf / notch BW"] if "MIMO H-inf" in labels else []) + \
        ["flexure damping open -> IFF"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in sorted(rows, key=lambda r: r["tip_mode_hz"]):
        d = r["designs"]
        cells = [f"{r['tip_mode_hz']:.0f}", f"{r['tip_mode_hz'] / r['delay_limited_crossover_hz']:.2f}",
                 f"{r['mass_scale']:.3g}"]
        cells += [f"{d[lb]['tip'][0]:.0f} / {d[lb]['tip'][1]:.0f}" for lb in labels]
        cells += [f"{d['IFF damped']['tip'][0] / d['notch only']['tip'][0]:.2f}",
                  f"{d['IFF damped']['tip'][1] / d['notch only']['tip'][1]:.2f}"]
        if "MIMO H-inf" in labels:
            cells.append(f"{d['MIMO H-inf']['tip'][0] / d['notch only']['tip'][0]:.2f}")
        z = r.get("iff_zeta")
        cells.append("" if z is None else f"{100 * z[0]:.2f} % -> {100 * z[1]:.2f} %")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _ratio(row, label, axis, k):
    """design / notch-only for entry k (0 bandwidth, 1 crossover); NaN where missing (JSON stores NaN as null)."""
    a, b = row["designs"][label][axis][k], row["designs"]["notch only"][axis][k]
    return np.nan if a is None or b is None else a / b


def plot_sweep(rows, path):
    """Damped / notch-only ratios (closed-loop bandwidth, and crossover) against mode / delay-limited crossover; PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from ..report.output import save_figure
    rows = sorted(rows, key=lambda r: r["tip_mode_hz"])
    x = np.array([r["tip_mode_hz"] / r["delay_limited_crossover_hz"] for r in rows])
    fig, axes = plt.subplots(1, 2, figsize=(11.0, 4.4), sharey=True)
    for k, (ax, what) in enumerate(zip(axes, ("closed-loop bandwidth (|T_ii| -3 dB)", "lowest gain crossover"))):
        for axis, mk in (("tip", "o"), ("tilt", "s"), ("piston", "^")):
            y = [_ratio(r, "IFF damped", axis, k) for r in rows]
            ax.semilogx(x, y, mk + "-", label=f"{axis}: IFF damped / notch only")
        if "MIMO H-inf" in rows[0]["designs"]:
            y = [_ratio(r, "MIMO H-inf", "tip", k) for r in rows]
            ax.semilogx(x, y, "x--", label="tip: MIMO H-inf / notch only")
        ax.axhline(2.0, color="k", ls=":", lw=1, label="issue target (2x)")
        ax.axhline(1.0, color="0.6", lw=0.8)
        ax.axvline(1.0, color="0.6", ls="--", lw=0.8)
        ax.set_xlabel("tip flexure mode / delay-limited crossover")
        ax.set_title(f"ratio of the worst member's {what}", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("damped (or H-inf) / notch-only")
    axes[0].legend(fontsize=8, loc="upper left")
    fig.suptitle("What damping buys as the mirror's flexure modes move through the servo band")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def rate_spec(rate_hz, spec=MIMO_SPEC):
    """``spec`` at servo rate ``rate_hz``: dt_s = 1/rate, crossover search up to 0.15 rate (1.5 kHz at 10 kHz).

    The chain's hold, period-averaging gauge and compute delay are all in units of dt_s
    (:func:`~workbench.linearize.limit_cycle.sampled_factor`, the Pade of 2 dt_s in the IFF loop), so they
    scale with the rate. The search's upper end scales with it too (at 10 kHz it is the committed
    1500 Hz), with as many grid points per decade as at 10 kHz, so the range never binds first.
    """
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be positive; got {rate_hz!r}")
    lo, hi = spec.fc_range_hz[0], spec.fc_range_hz[1] * rate_hz * spec.dt_s
    per_decade = (spec.fc_points - 1) / np.log10(spec.fc_range_hz[1] / lo)
    return dataclasses.replace(spec, dt_s=1.0 / rate_hz, fc_range_hz=(lo, hi),
                               fc_points=int(round(per_decade * np.log10(hi / lo))) + 1)


def sensitivity_bandwidth_hz(freq_hz, loop):
    """Per axis: the first frequency where |S_ii| of the MIMO loop rises to 1/sqrt(2) (-3 dB), Hz.

    ``loop``: (freqs, 3, 3) at the axis outputs, S = (I + L)^-1. Skogestad and Postlethwaite's
    omega_B (sec. 2.4.5): up to it feedback attenuates errors by at least 3 dB. Unlike the |T|
    bandwidth it is not fooled by a loop whose |L| hovers near 1 with ~-120 deg of phase (then
    |T| ~ |S| ~ 1). Linear interpolation in log f between grid points; NaN if never reached.
    """
    f = np.asarray(freq_hz, float)
    sens = np.abs(np.einsum("fii->fi", np.linalg.inv(np.eye(3)[None] + np.asarray(loop))))
    out = []
    for s in sens.T:
        above = np.nonzero(s >= 1 / np.sqrt(2))[0]
        if above.size == 0:
            out.append(np.nan)
            continue
        k = above[0]
        if k == 0:
            out.append(float(f[0]))
            continue
        y0, y1 = np.log(s[k - 1]), np.log(s[k])
        t = (np.log(1 / np.sqrt(2)) - y0) / (y1 - y0)
        out.append(float(np.exp(np.log(f[k - 1]) + t * (np.log(f[k]) - np.log(f[k - 1])))))
    return np.array(out)


MIRROR_OUTPUTS = ["tip_rad", "tilt_rad", "piston_m"]


def mirror_closed_loop(fsm, member, design, loop_out, dt_s, delay_samples=1):
    """Reference (axes) -> mirror ``tip_rad``, ``tilt_rad``, ``piston_m`` of one member, shape (freqs, 3, 3).

    T = P_m In C (I + L)^-1 on ``design.freq_hz``: P_m the member's response from the stack
    voltages to the mirror outputs (with the design's IFF closed per stack), In the decoupler's
    axes -> stacks matrix, C the sampled axis controllers times the chain, L = ``loop_out``
    (the member's loop at the gauge-estimated axes).
    """
    from ..linearize.limit_cycle import sampled_factor
    from .margins import response
    from .mimo import force_estimate, iff_response, member_responses
    f = design.freq_hz
    ctrl = np.array([response(design.axes[ax].controller_d, f) for ax in AXIS_NAMES]).T
    cdiag = np.einsum("fi,ij->fij", ctrl * sampled_factor(f, dt_s, delay_samples)[:, None], np.eye(3))
    pm = member_responses(member, f, MIRROR_OUTPUTS)
    if design.iff is not None:
        c = iff_response(design.iff, f, dt_s, delay_samples)
        pm = pm @ np.linalg.inv(np.eye(3)[None] + c[:, None, None] * force_estimate(fsm, member, f, design.iff.source,
                                                                                design.iff.bridge_capacitance_f))
    return pm @ design.decoupler.in_v_per_q[None] @ cdiag @ np.linalg.inv(np.eye(3)[None] + loop_out)


def mirror_bandwidth_hz(fsm, family, design, dt_s, delay_samples=1):
    """Per axis, lowest over ``family``: where |T_ii| from the reference to the *mirror's* angle falls 3 dB, Hz.

    The designs' bandwidths are measured at the gauge-estimated axes (the stacks' elongations
    through the kinematics); above the flexure modes the mirror (behind the levers) no longer
    follows them. Here T = P_m C (I + L)^-1 with P_m the member's (IFF-damped) response from the
    outer loop's axis commands to ``tip_rad``, ``tilt_rad``, ``piston_m`` and C the sampled axis
    controllers with the chain, normalized by its value at the grid's first frequency (a gauge-gain
    corner member tracks a scaled angle). NaN if it never falls.

    Returns
    -------
    bandwidth_hz, peak : ndarray, shape (3,)
        The bandwidth (lowest over the members) and the largest normalized |T_ii| over the grid and
        the members (the mirror's resonances in the closed loop, e.g. the housing's rocking modes,
        which the gauges do not see).
    """
    f = design.freq_hz
    out, peak = np.full(3, np.inf), np.zeros(3)
    for n, m in family.items():
        t = mirror_closed_loop(fsm, m, design, design.loop_out[n], dt_s, delay_samples)
        mag = np.abs(np.einsum("fii->fi", t))
        for a in range(3):
            below = np.nonzero(mag[:, a] < mag[0, a] / np.sqrt(2))[0]
            out[a] = min(out[a], f[below[0]] if below.size else np.nan)
            peak[a] = max(peak[a], float(np.max(mag[:, a] / mag[0, a])))
    return out, peak


def _design_row(d, mirror_bw=None):
    """Per axis (|T| bandwidth Hz, lowest crossover Hz, PM deg, GM dB, |S| bandwidth Hz) and the alphas of a MimoDesign."""
    s = d.summary()
    wb = np.nanmin([sensitivity_bandwidth_hz(d.freq_hz, l) for l in d.loop_out.values()], axis=0)
    ax = {a: tuple(float(s["axes"][a][k]["value"]) for k in
                   ("bandwidth_hz", "crossover_hz_min", "phase_margin_deg", "gain_margin_db")) + (float(wb[i]),)
          for i, a in enumerate(AXIS_NAMES)}
    return {"axes": ax, "mirror_bw_hz": None if mirror_bw is None else [float(v) for v in mirror_bw[0]],
            "mirror_peak": None if mirror_bw is None else [float(v) for v in mirror_bw[1]],
            "alpha_in": float(d.disk_in["alpha"]), "alpha_out": float(d.disk_out["alpha"]),
            "alpha_member": d.disk_in["member"]}


def rate_sweep(fsm, rates_hz=DEFAULT_RATES_HZ, branches=("ascending", "reversal"), reference_mode_ratio=12.0,
               progress=None, iff_source="charge+gauge"):
    """Notch-only and IFF-damped designs of the mirror ``fsm`` (as loaded) at each servo rate.

    At each rate also the notch-only design with the flexure modes moved (``scaled_mirror``) to
    ``reference_mode_ratio`` x 0.03 rate (~12 x the crossover the delay alone allows, i.e. far
    above the band, below Nyquist): its tip crossover is that rate's delay-limited crossover f_d.
    The committed mirror's notch-only design is mode-limited at a rate where its crossover falls
    clearly (< 0.8x) below f_d. ``iff_source``: the IFF design's force estimate
    (:func:`~workbench.design.mimo.force_estimate`; ``"bridge"``: the charge bridge, which exports).

    Returns a list of dicts (one per rate): ``rate_hz``, ``tip_mode_hz``, ``delay_limited_crossover_hz``,
    ``reference_tip_mode_hz``, ``designs`` {"notch only", "IFF damped"} -> :func:`_design_row`,
    ``iff`` (gain V/N, damping open -> damped), ``seconds``.
    """
    fam = mirror_family(fsm, branches=branches)
    f1 = axis_resonances_hz(fsm, fam[nominal_name()])[0]
    rows = []
    for i, rate in enumerate(rates_hz):
        t0 = time.perf_counter()
        spec = rate_spec(rate)
        nd = design_mimo(fsm, fam, damping=False, spec=spec)
        dd = design_mimo(fsm, fam, damping=True, spec=spec, iff_source=iff_source)
        ref_target = reference_mode_ratio * 0.03 * rate
        ref = scaled_mirror(fsm, (f1 / ref_target) ** 2)
        ref_fam = mirror_family(ref, branches=branches)
        rd = design_mimo(ref, ref_fam, damping=False, spec=spec)
        rows.append({"rate_hz": float(rate), "tip_mode_hz": float(f1),
                     "reference_tip_mode_hz": float(axis_resonances_hz(ref, ref_fam[nominal_name()],
                                                                          default_freq_hz(spec.dt_s))[0]),
                     "delay_limited_crossover_hz": float(rd.summary()["axes"]["tip"]["crossover_hz_min"]["value"]),
                     "designs": {"notch only": _design_row(nd, mirror_bandwidth_hz(fsm, fam, nd, spec.dt_s,
                                                                                   spec.delay_samples)),
                                 "IFF damped": _design_row(dd, mirror_bandwidth_hz(fsm, fam, dd, spec.dt_s,
                                                                                   spec.delay_samples))},
                     "iff": {"gain_v_per_n": dd.iff.gain_v_per_n, "zeta_open": dd.iff_info["zeta_min_open"],
                             "zeta_damped": dd.iff_info["zeta_min_damped"]},
                     "seconds": time.perf_counter() - t0})
        if progress is not None:
            progress(i + 1, len(rates_hz))
    return rows


def _mirror_cell(n, d, axis):
    a = AXIS_NAMES.index(axis)
    if n.get("mirror_bw_hz") is None or d.get("mirror_bw_hz") is None:
        return "-"
    return (f"{n['mirror_bw_hz'][a]:.0f} / {d['mirror_bw_hz'][a]:.0f} (peak {n['mirror_peak'][a]:.1f} / "
            f"{d['mirror_peak'][a]:.1f})")


def rate_markdown(rows, axis="tip", pm_deg=40.0, gm_db=6.0, alpha=0.4, ratio=2.0):
    """GitHub Markdown table of :func:`rate_sweep` for one axis, with the issue's floors judged per rate.

    Met: IFF / notch-only >= ``ratio`` on both bandwidths (|T| -3 dB and |S| -3 dB, worst member
    each), the IFF design's worst loop-at-a-time PM and GM and its simultaneous alpha (stack inputs
    and axis outputs) at their floors.
    """
    head = ["servo rate kHz", "f_d Hz", "mode / f_d", "notch only BW_T / BW_S / f_c Hz",
            "IFF BW_T / BW_S / f_c Hz", "IFF / notch BW_T", "IFF / notch BW_S", "PM deg notch / IFF", "GM dB notch / IFF", "alpha notch / IFF",
            "mirror-angle BW notch / IFF Hz (peak \\|T\\|)", "flexure damping open -> IFF", "2x target"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        n, d = r["designs"]["notch only"], r["designs"]["IFF damped"]
        na, da = n["axes"][axis], d["axes"][axis]
        rat, rat_s = da[0] / na[0], da[4] / na[4]
        ok = (rat >= ratio and rat_s >= ratio and da[2] >= pm_deg and da[3] >= gm_db and d["alpha_in"] >= alpha
              and min(d["alpha_in"], d["alpha_out"]) >= alpha)
        cells = [f"{r['rate_hz'] / 1e3:g}", f"{r['delay_limited_crossover_hz']:.0f}",
                 f"{r['tip_mode_hz'] / r['delay_limited_crossover_hz']:.2f}",
                 f"{na[0]:.0f} / {na[4]:.0f} / {na[1]:.0f}", f"{da[0]:.0f} / {da[4]:.0f} / {da[1]:.0f}",
                 f"{rat:.2f}", f"{rat_s:.2f}",
                 f"{na[2]:.1f} / {da[2]:.1f}", f"{na[3]:.2f} / {da[3]:.2f}",
                 f"{min(n['alpha_in'], n['alpha_out']):.3f} / {min(d['alpha_in'], d['alpha_out']):.3f}",
                 _mirror_cell(n, d, axis),
                 f"{100 * r['iff']['zeta_open']:.2f} % -> {100 * r['iff']['zeta_damped']:.2f} %",
                 "**met**" if ok else "missed"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def transmission_zeros(sys, inputs, outputs):
    """Invariant (transmission) zeros of the square channel ``inputs`` -> ``outputs`` of a StateSpace, rad/s.

    Parameters
    ----------
    sys : control.StateSpace
        A model with labelled inputs and outputs (e.g. a :func:`~workbench.linearize.mimo.mirror_family` member).
    inputs, outputs : sequence of str
        Equally many labels.

    Returns
    -------
    ndarray of complex
        The finite generalized eigenvalues (|z| < 1e12) of the Rosenbrock pencil
        ([[A, B], [C, D]], [[I, 0], [0, 0]]) by QZ, rad/s, sorted by magnitude.

    Raises
    ------
    ValueError
        Unequal numbers of inputs and outputs, or a label the model does not have.

    Notes
    -----
    python-control 0.10.2's ``zeros()`` (slycot's AB08ND, which reduces the pencil first) gives the same
    |z| on a plant member (3e-9 to 7e-7 relative on the mirror's nominal) but drifts on the same plant closed on its
    gauges with a static gain, whose zeros are exactly the open loop's: 1.5e-8 / 2.5e-7 / 1.3e-5 relative at
    loop gains 0.3 / 3 / 30, where this direct QZ gives the open loop's to the last bit
    (``tests/design/test_mirror_limit.py::test_feedback_does_not_move_the_zeros``). Hence this QZ.
    """
    import scipy.linalg
    ii, oo = _channel(sys, inputs, outputs)
    a, b, c, d = sys.A, sys.B[:, ii], sys.C[oo], sys.D[np.ix_(oo, ii)]
    n = a.shape[0]
    pencil = np.block([[a, b], [c, d]])
    mass = np.zeros_like(pencil)
    mass[:n, :n] = np.eye(n)
    z = scipy.linalg.eigvals(pencil, mass)
    z = z[np.isfinite(z) & (np.abs(z) < 1e12)]
    return z[np.argsort(np.abs(z))]


def _channel(sys, inputs, outputs):
    if len(inputs) != len(outputs):
        raise ValueError(f"transmission zeros need a square channel; got {len(inputs)} inputs, {len(outputs)} outputs")
    try:
        return ([list(sys.input_labels).index(i) for i in inputs], [list(sys.output_labels).index(o) for o in outputs])
    except ValueError as err:
        raise ValueError(f"unknown channel label ({err}); inputs {list(sys.input_labels)}, "
                         f"outputs {list(sys.output_labels)}") from err


def zero_output_directions(sys, inputs, outputs, zeros):
    """Which output each transmission zero blocks: the output zero direction y (y^T G(z) = 0), per zero.

    y is the output part of the left null vector of the Rosenbrock pencil [[A - z I, B], [C, D]] at z,
    with the outputs scaled by their static gains' row norms (so rad and m compare): a zero of the tip
    row alone has y = e_tip.

    Returns
    -------
    ndarray, (len(zeros), len(outputs))
        |y| per zero, normalized to a largest entry of 1 (the blocked output is its argmax).
    """
    ii, oo = _channel(sys, inputs, outputs)
    a, b, c, d = sys.A, sys.B[:, ii], sys.C[oo], sys.D[np.ix_(oo, ii)]
    n = a.shape[0]
    zs = np.asarray(zeros, complex)
    w_low = 1e-3 * (np.min(np.abs(zs)) if zs.size else 1.0)      # practically static, clear of any pole at 0
    g0 = c @ np.linalg.solve(1j * w_low * np.eye(n) - a, b) + d
    scale = np.linalg.norm(g0, axis=1)
    scale[scale == 0] = 1.0
    out = np.empty((zs.size, len(oo)))
    for k, z in enumerate(zs):
        u = np.linalg.svd(np.block([[a - z * np.eye(n), b], [c, d]]))[0]
        y = np.abs(u[n:, -1]) * scale                               # y' = S y for outputs scaled by 1/S
        out[k] = y / y.max()
    return out


def mirror_angle_limit(fsm, member):
    """The zeros that cap the mirror angle's closed-loop bandwidth, against their closed form.

    The stacks push mirror and housing apart (internal forces). At the frequency where the housing
    alone (inertia I_h) resonates on its bracket, the bracket takes the stacks' reaction and the
    housing moves so as to cancel the mirror's inertial angle: with the bracket stiffness
    k_b = (2 pi f_rock)^2 (I_h + J) of the plant file (f_rock: rocking with the mirror locked), the
    tip (tilt) angle's zero is at

        f_z = sqrt(k_b / I_h) / (2 pi) = f_rock sqrt(1 + J / I_h).

    A transmission zero of the plant stays a zero of every closed loop around it (output feedback,
    the IFF loop included, only adds the controller's poles as zeros), so |T| from the reference to
    the mirror's angle has a notch at f_z, whatever the gauges' loop does, and the angle's -3 dB
    bandwidth stays below f_z. The notch is shallower than the plant's 2 zeta_z where the closed loop
    resonates next to it (0.31 of DC on the committed mirror's notch-only design). A sensor on the mirror changes what is measured, not the zero: only a
    change of the actuation (another input) or of the structure (f_rock, I_h, J) moves it.

    Parameters
    ----------
    fsm : FastSteeringMirror
    member : control.StateSpace
        A small-signal member of :func:`~workbench.linearize.mimo.mirror_family`.

    Returns
    -------
    dict
        ``zeros_hz`` (|z| / 2 pi of every transmission zero v0..v2 -> tip/tilt/piston below 10 kHz,
        one per conjugate pair), ``zeros_zeta``, ``zeros_axis`` (the output each zero blocks, by its
        output direction: :func:`zero_output_directions`), ``closed_form_hz`` {"tip": .., "tilt": ..} and
        ``cap_hz``: the lowest zero the plant has on each axis (tip: about x, tilt: about y), nan if none,
        whatever the closed form says (on a structure the formula does not describe they differ).
    """
    chan = (("v0", "v1", "v2"), ("tip_rad", "tilt_rad", "piston_m"))
    z = transmission_zeros(member, *chan)
    z = z[(z.imag >= 0) & (np.abs(z) < 2 * np.pi * 1e4)]
    axis_of = [("tip", "tilt", "piston")[int(np.argmax(y))] for y in zero_output_directions(member, *chan, z)]
    ratio = np.sqrt(1.0 + fsm.inertia_kg_m2 / fsm.housing_inertia_kg_m2)
    closed = {"tip": fsm.rocking_freq_x_hz * ratio, "tilt": fsm.rocking_freq_y_hz * ratio}
    zhz = np.abs(z) / (2 * np.pi)
    cap = {ax: float(min((f for f, a in zip(zhz, axis_of) if a == ax), default=np.nan)) for ax in closed}
    return {"zeros_hz": zhz, "zeros_zeta": -z.real / np.abs(z), "zeros_axis": axis_of, "closed_form_hz": closed,
            "cap_hz": cap}


def limit_markdown(fsm, limit, notch_mirror_bw_hz=None, ratio=2.0):
    """The :func:`mirror_angle_limit` table; with the notch-only design's mirror-angle bandwidths, the 2x verdict."""
    lines = [f"J = {fsm.inertia_kg_m2:g} kg m^2 (mirror), I_h = {fsm.housing_inertia_kg_m2:g} kg m^2 (housing), "
             f"sqrt(1 + J/I_h) = {np.sqrt(1 + fsm.inertia_kg_m2 / fsm.housing_inertia_kg_m2):.5f}", "",
             "| axis | f_rock (mirror locked) Hz | closed form f_rock sqrt(1 + J/I_h) Hz | plant zero Hz (damping) |"
             + (" notch-only mirror-angle BW Hz | 2x needs Hz | 2x feasible |" if notch_mirror_bw_hz is not None else ""),
             "|---|---|---|---|" + ("---|---|---|" if notch_mirror_bw_hz is not None else "")]
    for a, (ax, f_rock) in enumerate((("tip", fsm.rocking_freq_x_hz), ("tilt", fsm.rocking_freq_y_hz))):
        cap = limit["cap_hz"][ax]
        if np.isfinite(cap):
            k = int(np.argmin(np.abs(limit["zeros_hz"] - cap)))
            cell = f"{cap:.2f} ({100 * limit['zeros_zeta'][k]:.2f} %)"
        else:
            cell = "none below 10 kHz"
        row = f"| {ax} | {f_rock:g} | {limit['closed_form_hz'][ax]:.2f} | {cell} |"
        if notch_mirror_bw_hz is not None:
            need = ratio * notch_mirror_bw_hz[a]
            row += f" {notch_mirror_bw_hz[a]:.0f} | {need:.0f} | {'no' if need >= cap else 'yes'} |"
        lines.append(row)
    other = [f"{f:.1f}" for f in limit["zeros_hz"]
             if all(not abs(f - c) <= 1e-6 * f for c in limit["cap_hz"].values())]
    lines += ["", "other transmission zeros below 10 kHz: " + (", ".join(other) + " Hz" if other else "none")]
    return "\n".join(lines)


def main(argv=None):
    """``python -m workbench.design.mimo_sweep [PLANT] [--limit | --rates [--bridge] | --hinf]``; bad input exits 2."""
    from ..errors import WorkbenchError
    from ..plant.mirror import load_mirror
    from ..arguments import OneLineErrorParser     # one-line usage errors, as the workbench command's
    ap = OneLineErrorParser(prog="python -m workbench.design.mimo_sweep",
                            description="The mirror's damping sweep (default), --limit table or --rates sweep.")
    ap.add_argument("plant", nargs="?", default="plants/fsm_p888_51.toml", help="mirror plant file (TOML)")
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--limit", action="store_true", help="the mirror-angle zeros against their closed form")
    mode.add_argument("--rates", action="store_true", help="the servo-rate sweep")
    ap.add_argument("--bridge", action="store_true", help="with --rates: IFF from the charge bridge")
    ap.add_argument("--hinf", action="store_true", help="add the H-infinity design to the damping sweep")
    ns = ap.parse_args(sys.argv[1:] if argv is None else list(argv))
    hinf = ns.hinf
    args = [f"--{k}" for k in ("limit", "rates", "bridge") if getattr(ns, k)]
    try:
        fsm = load_mirror(ns.plant)
    except (OSError, WorkbenchError, ValueError) as err:
        print(f"error: {err}" if ns.plant in str(err) else f"error: {ns.plant}: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    if "--limit" in args:
        fam = mirror_family(fsm, branches=("ascending", "reversal"))
        lim = mirror_angle_limit(fsm, fam[nominal_name()])
        nd = design_mimo(fsm, fam, damping=False)
        bw, _ = mirror_bandwidth_hz(fsm, fam, nd, MIMO_SPEC.dt_s, MIMO_SPEC.delay_samples)
        print(limit_markdown(fsm, lim, bw))
        return lim
    if "--rates" in args:
        from ..report.output import write_json
        src = "bridge" if "--bridge" in args else "charge+gauge"
        rows = rate_sweep(fsm, progress=lambda i, n: print(f"rate {i}/{n}", file=sys.stderr, flush=True),
                          iff_source=src)
        for ax in AXIS_NAMES:
            print(f"\n{ax}:\n")
            print(rate_markdown(rows, ax))
        write_json("out/mimo_rate_sweep.json" if src == "charge+gauge" else "out/mimo_rate_sweep_bridge.json", rows)
        return rows
    rows = damping_sweep(fsm, hinf=hinf, progress=lambda i, n: print(f"point {i}/{n}", file=sys.stderr, flush=True),
                         hinf_kwargs={"bisections": 4})
    print(f"delay-limited crossover f_d = {rows[0]['delay_limited_crossover_hz']:.0f} Hz (notch-only tip crossover, "
          f"modes at {max(r['tip_mode_hz'] for r in rows):.0f} Hz)\n")
    print(sweep_markdown(rows))
    from ..report.output import write_json
    write_json("out/mimo_sweep.json", rows)
    plot_sweep(rows, "out/mimo_sweep.png")
    return rows


if __name__ == "__main__":
    from ..arguments import run_script                   # Ctrl-C / SIGTERM: one line, no traceback
    raise SystemExit(run_script("python -m workbench.design.mimo_sweep", main))
