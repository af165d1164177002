"""`workbench selfsense PLANT.toml --json OUT --out DIR`: the staged self-sensing study.

Wiring into :mod:`workbench.cli`: ``from .selfsense.command import add_parser`` and call
``add_parser(sub)`` next to the other sub-commands; ``main`` then runs ``args.func(args)``
and turns a :class:`~workbench.errors.WorkbenchError` (or ValueError) into exit status 2.
"""

import argparse
from pathlib import Path

from ..errors import DataFileError, WorkbenchError
from ..arguments import emit, quantity

__all__ = ["add_parser", "run", "run_force", "run_dynamics", "run_fused", "main"]


def add_parser(sub):
    """Register `selfsense` on an argparse sub-parsers object."""
    from .defaults import DEFAULT_CONTROLLER
    p = sub.add_parser("selfsense", help="displacement from the stack's own charge (seed 002), staged errors",
                       description="Self-sensing as seed 002 builds it, for a stack: a charge amplifier "
                                   "(integrator, reference capacitor, bias current, leakage resistance, "
                                   "dielectric absorption) on the PZT model; i_bias, R_FP, alpha, the "
                                   "absorption and a stage-4 creep/PI operator identified on a separate "
                                   "simulated record; the estimate's peak-to-peak and RMS error at each "
                                   "stage on a staircase record, its noise beside the gauge chain's, and "
                                   "the committed controller's margins with the dynamic estimator in place "
                                   "of the gauge.")
    p.add_argument("plant", type=Path, help="plant file, e.g. plants/p888_51_sn637_creep.toml")
    p.add_argument("--duration", type=_quantity("s"), default=1000.0,
                   help="evaluation staircase length (default 1000s, at least 100s)")
    p.add_argument("--controller", type=Path, default=DEFAULT_CONTROLLER,
                   help="controller JSON for the loop analysis (default controllers/sn637_loopshape.json)")
    p.add_argument("--no-loop", action="store_true", help="skip the loop analysis")
    p.add_argument("--strict", action="store_true",
                   help="a --controller exported for another plant (SHA-256, serial, trim, gauge gain, limits, "
                        "current-limit window) is an error, not a warning (as verify --strict)")
    p.add_argument("--seed", type=int, default=2, help="noise and staircase seed (default 2)")
    p.add_argument("--out", type=Path, help="folder for the stage figures, noise.png, loop.png, report.md")
    p.add_argument("--json", type=Path, help="write the results as JSON here")
    p.add_argument("--force", action="store_true",
                   help="force self-sensing instead of the displacement stages: a simulated force step "
                        "(--step-force, default -100N, at 50 V) and the Table 1 Instron runs; writes force.png, "
                        "force_report.md and force.json with --out")
    p.add_argument("--dynamics", action="store_true",
                   help="the estimator's K D(s) and H(s) identified from a step record instead of the displacement "
                        "stages; both dynamic estimators scored on a staircase; writes dynamics.png, "
                        "dynamics_report.md and dynamics.json with --out")
    p.add_argument("--fused", action="store_true",
                   help="fused gauge + charge feedback instead of the displacement stages: the blend's crossover "
                        "from the two sensors' error spectra, the gauge, charge and fused closed loops on the "
                        "nonlinear plant side by side (0.1 Hz triangle, then a --hold); writes fused.png, "
                        "fused_report.md and fused.json with --out")
    p.add_argument("--fused-controller", type=Path, default=None,
                   help="controller JSON designed on the fused signal (default controllers/sn637_fused_loopshape.json)")
    p.add_argument("--hold", type=_quantity("s"), default=100.0,
                   help="hold after the triangle in the --fused closed loops (default 100s; the target is set "
                        "for 1000s, ~25 min per sensor)")
    p.add_argument("--step-force", type=_quantity("N"), default=-100.0,
                   help="force step of the --force study (default -100N: compression is negative)")
    p.set_defaults(func=run)
    return p


_quantity = quantity
_emit = emit


def run(args):
    """Run the study for parsed ``args`` and print/write the results."""
    from .run import run_selfsense
    if not Path(args.plant).is_file():
        raise DataFileError(f"{args.plant}: no such plant file; give one of plants/*.toml, "
                            f"e.g. plants/p888_51_sn637_creep.toml")
    if args.out is not None and Path(args.out).exists() and not Path(args.out).is_dir():
        raise DataFileError(f"--out {args.out}: exists and is not a folder; give a folder path")
    if sum(bool(getattr(args, k, False)) for k in ("force", "dynamics", "fused")) > 1:
        raise DataFileError("--force, --dynamics and --fused are separate studies; give one of them")
    if getattr(args, "fused", False):
        return run_fused(args)
    if getattr(args, "force", False):
        return run_force(args)
    if getattr(args, "dynamics", False):
        return run_dynamics(args)
    data = run_selfsense(args.plant, duration_s=args.duration, out_dir=args.out, seed=args.seed,
                         controller_path=args.controller, loop=not args.no_loop, strict=args.strict)
    stroke = data["stroke_m"]
    lines = [f"{args.plant}: self-sensing over a {data['duration_s']:.0f} s staircase, stroke {stroke * 1e6:.2f} um"]
    lines += [f"  WARNING {w} (--strict refuses it)" for w in data.get("warnings") or ()]
    for s in data["stages"]:
        lines.append(f"  {s['title']}: {s['error_pp_m'] * 1e9:.1f} nm p-p ({s['error_pp_percent_stroke']:.2f} % "
                     f"of stroke), {s['error_rms_m'] * 1e9:.1f} nm RMS")
    g, n = data["gauge_on_same_record"], data["noise_per_10khz_sample"]
    lines.append(f"  gauge chain on the same record: {g['error_pp_m'] * 1e9:.1f} nm p-p, {g['error_rms_m'] * 1e9:.1f} nm RMS")
    lines.append(f"  noise per 10 kHz sample: self-sensed {n['self_sensed_rms_m'] * 1e9:.2f} nm RMS, "
                 f"gauge {n['gauge_rms_m'] * 1e9:.1f} nm RMS")
    if "loop" in data:
        mg, ms = data["loop"]["margins_gauge"], data["loop"]["margins_self_sensed"]
        lines.append(f"  loop: gauge PM {mg['phase_margin_deg']:.1f} deg GM {mg['gain_margin_db']:.1f} dB; "
                     f"self-sensed PM {ms['phase_margin_deg']:.1f} deg GM {ms['gain_margin_db']:.1f} dB")
    lines.append(f"  target (last stage <= 1 % of stroke p-p): {'met' if data['target_met'] else 'MISSED'}")
    if args.out is not None:
        lines.append(f"  report {Path(args.out) / 'report.md'}")
    _emit(args, data, lines)


def run_force(args):
    """`workbench selfsense --force`: the force study, printed; figures/report with --out, JSON with --json."""
    from .force import run_force_study
    if not args.step_force != 0.0:
        raise DataFileError("--step-force must be nonzero, e.g. -100N (compression) or 50N")
    data = run_force_study(args.plant, seed=args.seed, step_n=args.step_force)
    if args.out is not None:
        from ..report.selfsense_figures import write_force_outputs
        data["figures"] = write_force_outputs(Path(args.out), data)
    data.pop("_arrays")
    st, ins = data["force_step"], data["instron"]
    tol = st["target_fraction"] * abs(st["force_n"])
    lines = [f"{args.plant}: force self-sensing, {st['force_n']:+.0f} N step at {st['bias_v']:.0f} V "
             f"(error max from 1 s after the step to the end, N)"]
    for s in st["stages"]:
        lines.append(f"  {s['title']}: {s['abs_error_max_n']['1s_end']:.2f} N from reset, "
                     f"{s['tared_error_max_n']['1s_end']:.2f} N tared ({s['tared_error_max_n']['1_5s']:.2f} N over 1-5 s); "
                     f"x {s['x_error_max_m'] * 1e9:.1f} nm (x = k_q2x q: {s['x_from_charge_only_error_max_m'] * 1e9:.1f} nm)")
    met = lambda b: "met" if b else "MISSED"    # noqa: E731
    lines.append(f"  target {tol:.1f} N after 1 s: tared 1-5 s {met(st['target_met_tared_1_5s'])}, tared to the end "
                 f"{met(st['target_met_tared_1s_end'])}, from reset {met(st['target_met_absolute_1s_end'])}")
    lines.append(f"  Table 1, {len(ins['runs'])} runs simulated: peak force max error "
                 f"{100 * ins['simulated_max_error_fraction']:.2f} % ({met(ins['target_met_simulated'])})")
    lines.append(f"  Table 1 R out from the measured back EMF: model gain {ins['force_per_back_emf_model_n_per_v']:.2f} N/V "
                 f"max error {100 * ins['measured_r_out_max_error_fraction']:.1f} % ({met(ins['target_met_measured_r_out'])}); "
                 f"gain of the other runs max {100 * ins['measured_r_out_calibrated_max_error_fraction']:.1f} % "
                 f"({met(ins['target_met_measured_r_out_calibrated'])})")
    h, hd = ins["held_out"], ins["held_out_displacement_column"]
    rep, pure, mixed = h["reported"], h["nested_pure_back_emf"], h["nested_back_emf_with_gauge"]
    lines.append(f"  Table 1 R out held out, form chosen without the run (nested loo): self-sensing from the run's own "
                 f"back EMF (pure back EMF) max {100 * pure['max_error_fraction']:.2f} % "
                 f"({met(h['target_met_nested_pure_back_emf'])}); back EMF with the gauge "
                 f"{100 * mixed['max_error_fraction']:.2f} % ({met(h['target_met_nested_back_emf_with_gauge'])}); "
                 f"any form incl. gauge only {100 * h['nested']['max_error_fraction']:.2f} % "
                 f"({met(h['target_met_nested'])}), loso {100 * h['nested_loso']['max_error_fraction']:.2f} % "
                 f"({met(h['target_met_nested_loso'])})")
    if "nested_pure_back_emf_hysteresis_inverse" in h:
        hi, sq = h["nested_pure_back_emf_hysteresis_inverse"], ins["sequence"]
        hl = h["forms"]["back_emf_hysteresis_inverse"]["loo"]
        order = ", ".join(f"{sn} {100 * c['measured']:+.1f} % (model {100 * c['model']:+.2f} %)"
                          for sn, c in sq["run_order_v_per_f_change_1_to_2"].items())
        gl = h["forms"]["back_emf"]["loo"]
        lines.append(f"  Table 1 R out, back EMF through the hysteresis inverse, each serial's state carried (drain "
                     f"{sq['drain_s']:g} s assumed, R in runs first): loo max {100 * hl['max_error_fraction']:.2f} % "
                     f"(F = G V: {100 * gl['max_error_fraction']:.2f} %), "
                     f"nested among the pure back-EMF forms max {100 * hi['max_error_fraction']:.2f} % RMS "
                     f"{100 * hi['rms_error_fraction']:.2f} % (without it {100 * pure['max_error_fraction']:.2f} % RMS "
                     f"{100 * pure['rms_error_fraction']:.2f} %) "
                     f"({met(h['target_met_nested_pure_back_emf_hysteresis_inverse'])}); "
                     f"V/F run 1 -> 2: {order}")
    lines.append(f"  Table 1 R out held out, {h['reported_form_title']}, form chosen on the same runs, reads no back "
                 f"EMF of the run: max {100 * rep['loo']['max_error_fraction']:.1f} % loo ({met(h['target_met_loo'])}), "
                 f"{100 * rep['loso']['max_error_fraction']:.1f} % loso ({met(h['target_met_loso'])}); x from the "
                 f"displacement column: {100 * hd['reported']['loso']['max_error_fraction']:.1f} % loso")
    if args.out is not None:
        lines.append(f"  report {Path(args.out) / 'force_report.md'}, figure {Path(args.out) / 'force.png'}")
    _emit(args, data, lines)


def run_dynamics(args):
    """`workbench selfsense --dynamics`: identified K D(s), H(s) and the two dynamic estimators, printed."""
    from .sysid import run_dynamics_study
    data = run_dynamics_study(args.plant, seed=args.seed)
    if args.out is not None:
        from ..report.selfsense_figures import write_dynamics_outputs
        data["figures"] = write_dynamics_outputs(Path(args.out), data)
    data.pop("_arrays")
    dyn, c = data["dynamics"], data["comparison"]
    kd = dyn["kd"]
    lines = [f"{args.plant}: estimator dynamics identified from a 20 V step (orders by BIC: K D {dyn['order_kd']}, "
             f"H {dyn['order_h']})",
             f"  K = {kd['dc_gain'] * 1e6:.5f} +/- {kd['sigma_dc_gain'] * 1e6:.1g} um/V (model, small signal at 50 V: "
             f"{data['model']['k_m_per_v'] * 1e6:.5f} um/V); creep time constants "
             + ", ".join(f"{t:.3g} s" for t in kd["time_constants_s"])]
    for key, label in (("static", "static estimate (stage 3)"), ("model", "dynamic, model-derived E"),
                       ("identified", "dynamic, identified E")):
        lines.append(f"  {label}: {c[key]['error_rms_m'] * 1e9:.1f} nm RMS, {c[key]['error_pp_m'] * 1e9:.1f} nm p-p "
                     f"over {data['evaluation_duration_s']:.0f} s")
    lines.append(f"  target (identified <= {data['target_ratio']:.1f}x model, RMS): ratio "
                 f"{c['ratio_rms_identified_over_model']:.2f}, {'met' if data['target_met'] else 'MISSED'}")
    if args.out is not None:
        lines.append(f"  report {Path(args.out) / 'dynamics_report.md'}, figure {Path(args.out) / 'dynamics.png'}")
    _emit(args, data, lines)


def run_fused(args):
    """`workbench selfsense --fused`: the blend and the three sensors' closed loops, printed."""
    import sys

    from .fused_loop import run_fused_study
    if not args.hold >= 3.0:
        raise DataFileError(f"--hold must be at least 3s (1 s settling and two 1 s windows); got {args.hold:g} s")
    for pth in (args.controller, args.fused_controller):
        if pth is not None and not Path(pth).is_file():
            raise DataFileError(f"{pth}: no such controller JSON; give e.g. controllers/sn637_loopshape.json "
                                f"(--controller) and controllers/sn637_fused_loopshape.json (--fused-controller)")
    data = run_fused_study(args.plant, gauge_controller=args.controller, fused_controller=args.fused_controller,
                           seed=args.seed, hold_s=args.hold,
                           progress=lambda stage: print(f"  ... {stage}", file=sys.stderr, flush=True))
    if args.out is not None:
        from ..report.fusion_figures import write_fused_outputs
        data["figures"] = write_fused_outputs(Path(args.out), data)
    data.pop("_arrays")
    b = data["blend"]
    lines = [f"{args.plant}: fused feedback, blend crossover {b['crossover_hz']:.3g} Hz (error RMS gauge "
             f"{b['gauge_error_rms_m'] * 1e9:.2f} nm, charge {b['charge_error_rms_m'] * 1e9:.2f} nm, fused "
             f"{b['fused_error_rms_m'] * 1e9:.2f} nm)"]
    for r in data["closed_loops"]:
        m = r["margins"]
        lines.append(f"  {r['sensor']}: crossover {m['crossover_hz']:.0f} Hz, PM {m['phase_margin_deg']:.1f} deg, "
                     f"GM {m['gain_margin_db']:.1f} dB; triangle {r['triangle_rms_percent_stroke']:.4f} % of stroke "
                     f"RMS; "
                     f"hold drift {r['hold_drift_m'] * 1e9:+.2f} nm over {r['hold_s']:.0f} s; noise "
                     f"{r['hold_noise_rms_m'] * 1e9:.2f} nm RMS")
    if "targets_met" in data:
        met = lambda b_: "met" if b_ else "MISSED"    # noqa: E731
        tm = data["targets_met"]
        lines.append(f"  targets (fused): triangle <= 0.01 % {met(tm['triangle'])}, hold drift <= 1 nm "
                     f"{met(tm['hold_drift'])}, PM >= 45 / GM >= 6 dB {met(tm['margins'])}")
    if args.out is not None:
        lines.append(f"  report {Path(args.out) / 'fused_report.md'}, figure {Path(args.out) / 'fused.png'}")
    _emit(args, data, lines)


def main(argv=None):
    """Stand-alone entry (`python -m workbench.selfsense.command ...`) with the CLI's error convention:
    a user error prints one message on stderr and returns 2."""
    import sys
    parser = argparse.ArgumentParser(prog="workbench")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    args = parser.parse_args(["selfsense", *(sys.argv[1:] if argv is None else argv)])
    try:
        args.func(args)
    except (WorkbenchError, ValueError) as err:
        print(f"workbench selfsense: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
