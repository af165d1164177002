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
"""

import dataclasses
import sys
import time

import numpy as np

from ..errors import DesignError
from ..linearize.mimo import mirror_family
from .mimo import axis_resonances_hz, design_mimo, nominal_name

__all__ = ["scaled_mirror", "damping_sweep", "sweep_markdown", "DEFAULT_MODES_HZ"]

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


def main(argv=None):
    from ..plant.mirror import load_mirror
    args = sys.argv[1:] if argv is None else list(argv)
    hinf = "--hinf" in args
    paths = [a for a in args if not a.startswith("--")] or ["plants/fsm_p888_51.toml"]
    fsm = load_mirror(paths[0])
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
    main()
