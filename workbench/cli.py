"""Command line: parses arguments, calls library functions, writes results. Nothing more.

Every command that computes something takes ``--json PATH``; errors caused by the
user's input print one clear message and exit with status 2, without a traceback.
"""

import argparse
import contextlib
import sys
from pathlib import Path

from .errors import WorkbenchError
from .arguments import emit, quantity, refuse_empty_paths

__all__ = ["main"]


_quantity = quantity          # argparse type of a quantity with its unit (workbench.arguments)


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        # an integer written as a float (1e6, 2.0e7: the helps' own "default 1e7") is that integer
        try:
            number = float(text)
        except ValueError:
            number = None
        if number is None or not number.is_integer():
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        value = int(number)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 1")
    return value


_emit = emit                  # lines on stdout, --json written whole (workbench.arguments)


def cmd_gauge(args):
    from .plant import load_plant
    from .plant.gauge import gauge_summary
    plant = load_plant(args.plant)
    data = gauge_summary(plant, args.x0)
    _emit(args, data, [
        f"{plant.name}: gauge chain at x0 = {args.x0 * 1e6:g} um",
        f"  bridge gain      {data['bridge_v_per_m']:.2f} V/m (seed eq. 28 corrected: 354.18 V/m at 7.5 um)",
        f"  chain gain       {data['chain_v_per_m']:.1f} V/m after x{plant.gauge.amplifier_gain:g}, "
        f"x{plant.gauge.demodulation_gain:g} and trim {plant.gauge.trim_scale:g}",
        f"  implied calibration {data['calibration_implied_um_per_v']:.4f} um/V "
        f"(plant file: {data['calibration_um_per_v']:.3f} um/V)",
        f"  bias at x = 0    {data['bias_v'] * 1e3:.4f} mV at the bridge, {data['chain_bias_v']:.4f} V after "
        f"amplifier and demodulation, {data['firmware_v_at_zero']:.4f} V after trim",
    ])


def cmd_identify_transducer(args):
    from .identify.transducer import identify_transducer
    res = identify_transducer(args.table, stiffness_n_per_m=args.stiffness)
    data = res.to_json()
    lines = [f"T_em = {data['t_em_n_per_v']:.2f} N/V over {len(data['runs_used'])} runs "
             f"(seed: {data.get('seed_t_em_n_per_v', 46.71)} N/V)",
             "stiffness from R-in runs: " + (f"{data['stiffness_from_r_in_n_per_um']:.1f} N/um"
                                              if data["stiffness_from_r_in_n_per_um"] is not None else
                                              "n/a (no R_in run in the table)")
             + f" (k_p used: {args.stiffness / 1e6:g} N/um)"]
    for flag in data["runs_flagged"]:
        lines.append(f"  flagged {flag['serial']} run {flag['run']} {flag['config']}: {flag['reason']}")
    _emit(args, data, lines)


def cmd_freefree(args):
    from .identify.freefree import plot_freefree, run_freefree
    from .plant import load_plant
    from .report import save_figure
    plant = load_plant(args.plant)
    res = run_freefree(plant, v_peak_v=args.v_peak, freq_hz=args.freq, cycles=args.cycles)
    data = {"plant": str(args.plant), **res.summary()}
    if args.out:
        fig_path = Path(args.out) / "freefree.png"
        save_figure(plot_freefree(res, f"{plant.name}: free-free test (seed 000 sec. 3.3)"), fig_path)
        data["figure"] = str(fig_path)
    _emit(args, data, [
        f"{plant.name}: free-free 0-{args.v_peak:g} V at {args.freq:g} Hz",
        f"  stroke at peak   {res.stroke_m * 1e6:.2f} um",
        f"  V_h / V_pea      {res.v_h_over_v_pea:.3f}",
        f"  hysteresis of x  {100 * res.hysteresis_x_fraction:.1f} % of stroke",
        f"  C_h secant       {res.ch_secant_f * 1e6:.1f} uF (rest to peak)",
        f"  C_p by eqs. 10-12 {res.cp_recovered_f * 1e6:.4f} uF (plant {res.cp_true_f * 1e6:.4f} uF, "
        f"{100 * (res.cp_recovered_f / res.cp_true_f - 1):+.3f} %)",
    ] + ([f"  figure           {data['figure']}"] if args.out else []))


def cmd_bench(args):
    from .bench import run_bench
    if args.memory_periods < 0:
        raise ValueError(f"--memory-periods must be >= 0 (0 skips the memory check); got {args.memory_periods}")
    data = run_bench(args.plant, steps=args.steps, reference_steps=args.reference_steps, progress=print,
                     controller_path=args.controller, periods=args.periods,
                     reference_periods=args.reference_periods, memory_periods=args.memory_periods)
    cl = data["closed_loop"]
    ok = cl["meets_target"]
    t = cl["targets"]
    lines = [
        f"{data['steps']} steps of {data['model']}: {data['seconds']:.3f} s, "
        f"{data['steps_per_second']:.3e} steps/s (compile excluded)",
        f"python-control input_output_response: {data['python_control_steps_per_second']:.3e} steps/s "
        f"over {data['python_control_steps']} steps; ratio {data['ratio_vs_python_control']:.0f}x",
        f"closed loop ({cl['controller_form']}), {cl['scenario']}:",
        f"  {cl['periods']} periods: {cl['seconds']:.3f} s, {cl['periods_per_second']:.3e} periods/s "
        f"(compile excluded); {cl['seconds_per_1e7_periods']:.2f} s per 1e7, "
        f"CPU {min(cl['cpu_seconds_all_repeats']) * 1e7 / cl['periods']:.2f} s "
        f"(target < {t['seconds_per_1e7_max']:g} s: {'met' if ok['seconds'] else 'NOT met'} on wall time, "
        f"{'met' if ok['seconds_cpu'] else 'NOT met'} on CPU time)",
        f"  python-control input_output_response: {cl['python_control_periods_per_second']:.3e} periods/s over "
        f"{cl['python_control_periods']} periods; ratio {cl['ratio_vs_python_control']:.0f}x wall, "
        f"{cl['ratio_vs_python_control_cpu']:.0f}x CPU time "
        f"(target >= {t['ratio_min']:g}x: {'met' if ok['ratio_cpu'] else 'NOT met'}); final state vs compiled: "
        f"|dx| {cl['python_control_state_difference']['x_m']:.1e} m, "
        f"|du| {cl['python_control_state_difference']['u_v']:.1e} V",
    ]
    if "c_reference" in cl:
        c = cl["c_reference"]
        lines.append(f"  the same loop in plain C ({' '.join(c['cflags'])}): "
                     f"{c['ns_per_period']['c_kernel']:.1f} ns/period against {c['ns_per_period']['numba']:.1f}; ratio {c['ratio_vs_c_kernel']:.2f} (target <= "
                     f"{t['ratio_vs_c_max']:g}: {'met' if ok['ratio_vs_c'] else 'NOT met'}); output words identical: "
                     f"{c['agreement_decimate_1']['output_words_identical']}/{c['agreement_decimate_1']['rows']}")
    if "memory" in cl:
        m = cl["memory"]
        lines.append(f"  peak RSS of a {m['periods']:.0e}-period hold (decimate {m['decimate']}): "
                     f"{m['peak_rss_mb']:.1f} MB in {m['seconds']:.1f} s "
                     f"(target < {m['limit_mb']:g} MB: {'met' if ok['memory'] else 'NOT met'})")
    _emit(args, data, lines)


_last_bar = {}


def _progress_bar(stage, done, total):
    """A status line on stderr: redrawn in place on a terminal, every 10 % otherwise."""
    width = 30
    fill = int(width * done / max(total, 1))
    tty = sys.stderr.isatty()
    step = fill if tty else int(10 * done / max(total, 1))
    if _last_bar.get(stage) == step and done < total:
        return
    _last_bar[stage] = step
    bar = f"  {stage:<22} [{'#' * fill}{'.' * (width - fill)}] {done}/{total}"
    if tty:
        print("\r" + bar, end="\n" if done >= total else "", file=sys.stderr, flush=True)
    else:
        print(bar, file=sys.stderr, flush=True)


def cmd_linearize(args):
    import numpy as np
    from .linearize.run import run_linearize
    from .linearize.uncertainty import FamilySpec
    if not args.freq_min < args.freq_max:
        raise ValueError(f"--freq-min ({args.freq_min:g} Hz) must be below --freq-max ({args.freq_max:g} Hz)")
    amps = tuple(sorted(args.amplitudes))
    if amps[0] <= 0:
        raise ValueError(f"--amplitudes must be positive; got {amps}")
    if not 0 <= args.cp_tolerance < 1:
        raise ValueError(f"--cp-tolerance is a fraction of C_p in [0, 1), e.g. 0.2; got {args.cp_tolerance}")
    spec = FamilySpec(amplitudes_v=amps, freq_hz=tuple(np.geomspace(args.freq_min, args.freq_max, args.freq_points)),
                      bias_v=args.bias, cp_tolerance=args.cp_tolerance,
                      imbalance_tolerance_ohm=args.imbalance_tolerance)
    data = run_linearize(args.plant, args.serials, args.controller, spec, args.out, progress=_progress_bar,
                         allow_unstable=args.allow_unstable)
    u, c = data["uncertainty"], data["capacitances"]
    lines = [
        f"{data['serial']}: linearized over {len(amps)} amplitudes x {args.freq_points} frequencies at bias "
        f"{args.bias:g} V; family of {len(data['family'])} plant file(s)",
        f"  capacitances: reversal {c['reversal_f'] * 1e6:.2f} uF, on-branch (ascending at {args.bias:g} V) "
        f"{c['ascending_f'] * 1e6:.2f} uF, secant from rest {c['secant_from_rest_f'] * 1e6:.2f} uF",
        f"  describing functions: {data['df_summary']['current_saturated']} of {data['df_summary']['points']} "
        f"points current-limited (slewing), {data['df_summary']['not_periodic']} not periodic",
        f"  gauge: {data['gauge']['volts_per_meter']:.0f} firmware V/m at x0 = {data['gauge']['x0_m'] * 1e6:g} um",
        f"  W_m: order {u['weight']['order']}, gain {u['weight']['gain']:.3f}, zeros {np.round(u['weight']['zeros_hz'], 1)}"
        f" Hz, poles {np.round(u['weight']['poles_hz'], 1)} Hz; coverage margin {u['coverage_margin_db']:.2f} dB "
        f"set by '{u['worst_member']}' at {u['worst_freq_hz']:.3g} Hz",
    ]
    if "controller" in data:
        lc = data["controller"]["limit_cycles"]
        lines.append("  loop: " + ("no limit cycle predicted" if not lc else "; ".join(
            f"limit cycle {c['amplitude_v']:.3g} V at {c['freq_hz']:.0f} Hz ({'stable' if c['stable'] else 'unstable'})"
            for c in lc)))
    if args.out:
        lines.append(f"  figures in {args.out}")
    _emit(args, data, lines)


def cmd_study(args):
    from .study.mirror import is_mirror_study
    if is_mirror_study(args.study):
        return _cmd_mirror_study(args)
    from .study.run import run_study
    if args.workers is not None and args.workers < 1:
        raise WorkbenchError(f"--workers {args.workers}: give 1 or more processes")
    cache = None if args.no_cache else ("default" if args.cache_dir is None else args.cache_dir)
    data = run_study(args.study, args.out, progress=_progress_bar, overrides=args.set, only=args.only,
                     cache_dir=cache, workers=args.workers)
    ls = data["designs"]["loop_shape"]
    q = ls["worst_quantized"]
    b = data["binding"]
    fc = data["family_cache"]
    lines = [
        f"study {data['name']}: {data['members']} family members "
        f"({'cached' if fc['hit'] else 'computed'} in {fc['seconds']:.1f} s"
        + (f", {fc['path']}" if fc["path"] else "") + ")",
        f"  nominal crossover {ls['nominal_quantized']['crossover_hz']:.0f} Hz (PM "
        f"{ls['nominal_quantized']['phase_margin_deg']:.1f} deg); bound by {b['constraint']} "
        f"({b['value']:.4g} against {b['limit']:.4g} {b['unit']})"
        + (f"; with it {b['relaxed']['by']}: lowest crossover {b['relaxed']['crossover_hz_min']:.0f} Hz"
           if "crossover_hz_min" in b.get("relaxed", {}) else ""),
        "  noise budget " + (f"{data['budgets']['noise_command_v']['value']:.3g} V RMS"
                             if data['budgets']['noise_command_v']['value'] is not None else "none")
        + f" (from the {data['budgets']['noise_command_v']['source']})",
        *_study_sensor_lines(data, ls),
        f"  exported {data['exported']['json']}: crossover {ls['crossover_hz']:.0f}-"
        f"{q['crossover_hz_max']['value']:.0f} Hz over the family; quantized worst PM "
        f"{q['phase_margin_deg']['value']:.1f} deg, GM {q['gain_margin_db']['value']:.1f} dB "
        f"({'meets' if ls['meets_targets'] else 'MISSES'} the targets)",
        f"  report {data['report']}",
    ]
    _emit(args, data, lines)


def _study_sensor_lines(data, ls):
    """The study's sensor and triangle-tracking lines (none for a plain gauge study)."""
    sn = data.get("sensor") or {}
    out = []
    if sn.get("kind", "gauge") != "gauge":
        bl = sn.get("blend")
        out.append(f"  sensor {sn['kind']}: reading noise {sn['noise_per_reading_m']['reading'] * 1e9:.3g} nm"
                   + (f", blend crossover {bl['crossover_hz']:.3g} Hz ({bl['source']})" if bl else ""))
    t = ls.get("tracking")
    if t:
        out.append(f"  triangle tracking (nominal loop) {100 * t['rms']:.3g} % of stroke RMS, limit "
                   f"{100 * t['limit']:.3g} %")
    return out


def _fmt_metric(m, key):
    """A metric for the terminal: the number, or why there is none (never a bare nan)."""
    import math
    v = m[key]
    if v is None or not math.isfinite(v):
        return f"{key} n/a ({m.get(key + '_why', 'not measurable in this run')})"
    return f"{key} {v:.4g}"


def _refuse_for_mirror(command, given):
    """A flag the mirror's command does not implement is refused before any work (not silently ignored)."""
    from .errors import UnsupportedError
    from .plant.mirror import FSM_SCHEMA_VERSION
    from .study.mirror import FSM_STUDY_SCHEMA
    flags = [flag for flag, on in given if on]
    if flags:
        what = (f"a mirror study (schema {FSM_STUDY_SCHEMA})" if command == "study" else
                f"{command} of a mirror (schema {FSM_SCHEMA_VERSION})")
        raise UnsupportedError(f"{what} does not take {', '.join(flags)}; "
                               f"run it without {'them' if len(flags) > 1 else 'it'} (the mirror's scenarios and "
                               f"targets are those of workbench/verify/mirror.py and study/mirror.py)")


def _cmd_mirror_study(args):
    _refuse_for_mirror("study", [("--set", bool(args.set)), ("--only", args.only is not None),
                                 ("--cache-dir", args.cache_dir is not None), ("--no-cache", args.no_cache),
                                 ("--workers", args.workers is not None)])
    from .study.mirror import run_mirror_study
    data = run_mirror_study(args.study, args.out, progress=_progress_bar)
    d = data["design"]
    lines = [f"mirror study {data['name']}: {data['members']} family members, {data['seconds']:.0f} s; noise gain "
             f"bound {data['noise_gain_bound']:.3g} ({'used' if data['noise_budget_used'] else 'not used'})"]
    for ax, a in d["axes"].items():
        lines.append(f"  {ax}: bandwidth {a['bandwidth_hz']['value']:.0f} Hz, PM {a['phase_margin_deg']['value']:.1f} "
                     f"deg, GM {a['gain_margin_db']['value']:.2f} dB (worst members)")
    lines += [f"  simultaneous disk margin alpha {d['disk_in']['alpha']:.3f} (stack inputs), "
              f"{d['disk_out']['alpha']:.3f} (axis outputs)",
              f"  exported {data['exported']['json']} and {data['exported']['h']}"]
    if data.get("damped"):
        dd = data["damped"]["design"]
        lines += [f"  IFF-damped (charge bridge, {dd['iff']['gain_v_per_n']:.3g} V/N): bandwidth "
                  + ", ".join(f"{ax} {a['bandwidth_hz']['value']:.0f} Hz" for ax, a in dd["axes"].items())
                  + f"; exported {data['damped']['exported']['json']}"]
    lines.append(f"  report {data['report']}")
    _emit(args, data, lines)


def _cmd_mirror_verify(args):
    _refuse_for_mirror("verify", [("--scenario", args.scenario is not _DEFAULT_SCENARIOS),
                                  ("--sensor", args.sensor is not None), ("--form", args.form not in (None, "fixed")),
                                  ("--hold", args.hold != 1000.0), ("--no-anti-windup", args.no_anti_windup),
                                  ("--strict", args.strict), ("--allow-unstable", args.allow_unstable),
                                  ("--target", bool(args.target)), ("--targets-from", args.targets_from is not None)])
    from .verify.mirror import run_mirror_verify
    data = run_mirror_verify(args.plant, args.controller, out_dir=args.out, noise=not args.no_noise, seed=args.seed,
                             progress=lambda stage, d, t: _progress_bar(stage, d, t))
    lines = [f"{args.plant} with {data['controller_name']} (MIMO fixed-point step), tip range "
             f"{data['tip_range_urad']:.0f} urad:"] + [f"  note: {a}" for a in data["assumptions"]]
    for m in data["metrics"]:
        keys = [k for k in m if k.endswith(("_urad", "_percent", "_nm", "_s", "_ratio")) and k != "tip_range_urad"
                and not isinstance(m[k], list)]
        lines.append(f"  {m['scenario']}: " + ", ".join(
            f"{k} {m[k]:.4g}" if m[k] is not None else f"{k} n/a" for k in keys))
    for name, t in data["targets"].items():
        lines.append(f"  target {name}: {t['value']:.4g} (limit {t['limit']:g} {t['unit']}): "
                     f"{'met' if t['met'] else 'MISSED'}")
    if "report" in data:
        lines.append(f"  report {data['report']}")
    _emit(args, data, lines)


_DEFAULT_SCENARIOS = ["all"]


def cmd_verify(args):
    from .verify.mirror import check_pairing
    if check_pairing(args.plant, args.controller):
        return _cmd_mirror_verify(args)
    from .verify.run import load_verify_sensor, load_verify_targets, parse_target, run_verify
    limits = load_verify_targets(args.targets_from) if args.targets_from else {}
    limits.update(dict(parse_target(t) for t in args.target or ()))
    sensor = args.sensor or (load_verify_sensor(args.targets_from) if args.targets_from else None)
    # --sensor without --scenario: the sensor runs only (argparse hands back the default object itself)
    scenarios = [] if (sensor and args.scenario is _DEFAULT_SCENARIOS) else args.scenario
    data = run_verify(args.plant, args.controller, scenarios, hold_s=args.hold, noise=not args.no_noise,
                      anti_windup=not args.no_anti_windup, form=args.form, out_dir=args.out,
                      progress=lambda stage, d, t: _progress_bar(stage, d, t), seed=args.seed, targets=limits,
                      strict=args.strict, allow_unstable=args.allow_unstable, sensor=sensor)
    lines = [f"{args.plant} with {data['controller_name'] or args.controller} ({data['controller_form']}), "
             f"seed {data['seed']}, gauge noise {'on' if data['noise'] else 'off'}:"]
    for p in data["preflight"]:
        lines.append(("  note: " if p["check"] == "not recorded" else f"  WARNING preflight {p['check']}: ")
                     + p["message"])
    lines += [f"  note: {n}" for n in data["notes"]]
    for m in data["scenarios"]:
        keys = [k for k in m if k.endswith(("_percent", "_m", "_s", "_fraction", "_points", "_db", "_deg", "_ratio"))
                and not isinstance(m[k], (list, tuple)) and k != "stroke_m"]
        lines.append(f"  {m['scenario']}: " + ", ".join(_fmt_metric(m, k) for k in keys))
    cyc = data["predicted_limit_cycles"]
    lines.append("  describing-function limit cycles predicted: " + (", ".join(
        f"{c['amplitude_v']:.3g} V at {c['freq_hz']:.0f} Hz ({'stable' if c['stable'] else 'unstable'})"
        for c in cyc) if cyc else "none"))
    met = sum(t["met"] for t in data["targets"].values())
    lines.append(f"  {met} of {len(data['targets'])} targets met")
    for name, t in data["targets"].items():
        value = f"{t['value']:.4g}" if t["value"] is not None else f"n/a ({t['why']})"
        lines.append(f"  target {name}: {t['metric']} {value} (limit {t['limit']:g} {t['unit']}): "
                     f"{'met' if t['met'] else 'MISSED'}")
    import math
    for r in data.get("sensors") or []:
        bw = r.get("bandwidth_hz")
        bw = f"{bw:.0f} Hz" if bw is not None and math.isfinite(bw) else f"n/a ({r.get('bandwidth_why', 'not measured')})"
        lines.append(f"  sensor {r['sensor']}: bandwidth {bw} (linear "
                     f"{r.get('linear_bandwidth_hz') or float('nan'):.0f} Hz), crossover "
                     f"{r['crossover_hz'] or float('nan'):.0f} Hz, triangle "
                     f"{r['triangle_rms_percent_stroke']:.3f} % of stroke RMS, hold drift {r['hold_drift_m'] * 1e9:+.2f} nm "
                     f"over {r['hold_s']:g} s, hold noise {r['hold_noise_rms_m'] * 1e9:.2f} nm RMS")
    if "report" in data:
        lines.append(f"  report {data['report']}")
    _emit(args, data, lines)


def cmd_sweep(args):
    from .verify.sweep_job import run_sweep
    if args.scheduler is not None and args.workers is not None:
        raise WorkbenchError("--workers sets local processes; a dask cluster (--scheduler) has its own: give one")
    data = run_sweep(args.study, args.controller, out_dir=args.out, table=args.table, scheduler=args.scheduler,
                     workers=args.workers, amplitudes_v=args.amplitudes, noise=args.noise,
                     progress=lambda d, t: _progress_bar("sweep", d, t))
    lines = [f"sweep of {args.study}: {data['cases']} cases ({data['failed']} failed) with {data['controller']}",
             f"  covers: {data['members_covered']}"]
    for metric, w in data["worst"].items():
        lines.append(f"  worst {metric}: {w['value']:.4g} ({w['serial']}, C_p x{w['cp_factor']:.2f}, "
                     f"{w['amplitude_v']:g} V)")
    for metric in ("phase_margin_deg", "gain_margin_db", "crossover_hz"):
        if metric not in data["worst"]:
            slew = sum(bool(r.get("slews_at_crossover")) for r in data["rows"])
            lines.append(f"  no case has a {metric}: {slew} of {data['cases']} slew at crossover (column "
                         f"slews_at_crossover), {data['failed']} failed (column error)")
    for e in data["errors"][:5]:
        lines.append(f"  FAILED {e['serial']} C_p x{e['cp_factor']:.2f} {e['amplitude_v']:g} V: {e['error']}")
    if "table" in data:
        lines.append(f"  table {data['table']}")
    _emit(args, {k: v for k, v in data.items() if k != "rows"}, lines)


def cmd_calibrate(args):
    from ._malloc import keep_freed_memory, small_pages
    from .calibrate.run import run_calibrate
    if getattr(args, "_whole_process", False):
        # the command owns its short-lived process (not an in-process main([...]) call, e.g. a test's):
        # its large temporaries reuse freed memory in 4 kB pages (_malloc); the settings are process-wide and stay
        keep_freed_memory()
        small_pages()
        # the modules' objects (~170,000 after the imports, ~250,000 with matplotlib's) set aside from the
        # cyclic garbage collector: its full passes then traverse only the run's own objects (the speed
        # benchmark's creep record: 2 full passes, 0.22 s of CPU, against 0.01 s). Nothing is computed
        # differently; objects still go when their last reference does. Imported here, before the freeze,
        # what the command imports later for its figures and report
        if args.out is not None:
            from .report import calibrate_figures, calibrate_report, html  # noqa: F401
        import gc
        gc.freeze()
    data = run_calibrate(args.data, args.plant, out_dir=args.out, split=args.split, train_cycles=args.train_cycles,
                         max_ratio=args.max_ratio, progress=lambda stage, d, t: _progress_bar(stage, d, t))
    eb, ea = data["error_before"], data["error_after"]
    stages = data["stages"]
    first = stages[0]["error_after"] if stages else ea
    # an inconclusive answer has no agreement to print (its "k of n" is the leading answer's count, which a
    # later rule may still refuse: s22_outsider D printed "inconclusive ... (5 of 5 validation folds)")
    counts = data.get("agreement_counts") or {}
    others = {c: k for c, k in (counts.get("by_channel") or {}).items() if c != data["channel"]}
    # s22_outsider C2: a stack effect's folds on the other sensor's view of the same motion are said beside it
    also = "".join(f"; the {data['effect']} on the {c} won {k} more" for c, k in others.items())
    folds = (f"{data['agreement']} validation folds on the {data['channel']}{also}" if data["effect"] not in
             ("inconclusive", "none") else f"{data['agreement']} validation folds" if data["effect"] == "none" else
             "fold winners: " + (", ".join(f"{x['answer']} {x['folds']}" for x in data.get("leading") or ())
                                 or "none"))
    lines = [f"{args.data} against {args.plant}: effect {data['effect']} on the {data['channel']} channel "
             f"({folds})",
             f"  test RMS {eb['rms']:.4g} -> {first['rms']:.4g} {eb['units']}, max {eb['max']:.4g} -> "
             f"{first['max']:.4g} {eb['units']}  ({data['reason']})"]
    # s22_outsider C1: the file's replay above the error before, said at the top (not only among the base's warnings)
    lines += [f"  WARNING: {w}" for w in data.get("warnings") or ()]
    for st in stages[1:]:
        lines.append(f"  then {st['effect']} on the {st['channel']} ({st['agreement']}): test RMS "
                     f"{st['error_before']['rms']:.4g} -> {st['error_after']['rms']:.4g} {st['error_before']['units']}")
    em = data.get("error_after_model", ea)
    if len(stages) > 1:
        lines.append(f"  the {data['channel']} after every effect found (the tracing model): test RMS {eb['rms']:.4g} "
                     f"-> {em['rms']:.4g} {eb['units']}, max {eb['max']:.4g} -> {em['max']:.4g} {eb['units']}")
    if data.get("error_after_source") == "updated plant":
        lines.append(f"  error after (the updated plant, the record's drive simulated through it): test RMS "
                     f"{ea['rms']:.4g} {ea['units']}, max {ea['max']:.4g} (the tracing model's {em['rms']:.4g})")
    for c in data["candidates"][:6]:
        lines.append(f"  candidate {c['name']} ({c['channel']}): score {c['score']:.3f}, passes {c['passes']} folds")
    lines += [f"  warning: {w}" for w in data["base_fit"].get("warnings", [])]
    if "updated_plant" in data:
        lines.append(f"  updated plant {data['updated_plant']}; report {data['report']}")
    lines.append(f"  {data['elapsed_s']:.1f} s")
    _emit(args, data, lines)


def cmd_synth(args):
    from .calibrate.protocol import calibration_protocol
    from .calibrate.synthetic import plant_with_effect, simulate_record, write_record
    from .plant import load_plant
    plant = load_plant(args.plant)
    drawn, truth = plant_with_effect(plant, args.effect, args.seed)
    t, v = calibration_protocol()
    path = write_record(args.out, simulate_record(drawn, t, v, seed=args.seed),
                        {"serial": plant.serial, "source": f"workbench synth {args.plant.name} --effect {args.effect} "
                                                          f"--seed {args.seed}"})
    data = {"record": str(path), "effect": args.effect, "truth": truth, "rows": int(t.size)}
    _emit(args, data, [f"wrote {path}: {t.size} rows of the calibration protocol, effect {args.effect} {truth}"])


def cmd_demo(args):
    from .demo import run_demo
    data = run_demo(Path(args.out), progress=print)
    _emit(args, data, [])


class _Parser(argparse.ArgumentParser):
    """argparse's parser whose usage errors are one line on stderr, exit status 2, as every other error of the
    workbench (argparse printed its usage first: 5-11 lines); ``--help`` prints the usage as before.
    The sub-commands' parsers are of this class too (``add_subparsers`` uses the parent's class)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def build_parser():
    parser = _Parser(prog="workbench", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("gauge", help="strain-gauge chain gains and bias at an operating point",
                       description="Bridge gain (eq. 28, corrected), chain gain after amplifier, "
                                   "demodulation and trim, and the bias from the arm imbalance.")
    p.add_argument("plant", type=Path, help="plant file, e.g. plants/p888_51_sn637.toml")
    p.add_argument("--x0", type=_quantity("m"), default=7.5e-6, help="operating displacement, e.g. 7.5um")
    p.add_argument("--json", type=Path, help="write the results as JSON here")
    p.set_defaults(func=cmd_gauge)

    p = sub.add_parser("identify", help="identify model parameters from test data")
    isub = p.add_subparsers(dest="what", required=True, metavar="WHAT")
    q = isub.add_parser("transducer", help="T_em by eq. 6 from the Instron runs (Table 1)",
                        description="T_em by eq. 6 over the runs that pass the consistency checks; "
                                    "every run that disagrees is listed with the reason.")
    q.add_argument("table", type=Path, help="e.g. plants/data/p888_51_instron_table1.csv")
    q.add_argument("--stiffness", type=_quantity("N/m"), default=2.0e8,
                   help="k_p in N/m (default 2e8 = 200 N/um, the spec sheet)")
    q.add_argument("--json", type=Path, help="write the results as JSON here")
    q.set_defaults(func=cmd_identify_transducer)

    p = sub.add_parser("freefree", help="simulated free-free test and eqs. 7-12",
                       description="Simulate seed 000's free-free test (0-V sine from rest, R out) and "
                                   "recover C_p by eqs. 10-12 from the gauge-read displacement.")
    p.add_argument("plant", type=Path)
    p.add_argument("--v-peak", type=_quantity("V"), default=100.0, help="sine peak, default 100V")
    p.add_argument("--freq", type=_quantity("Hz"), default=0.1, help="sine frequency, default 0.1Hz")
    p.add_argument("--cycles", type=_positive_int, default=2, help="periods from rest, default 2")
    p.add_argument("--out", type=Path, help="folder for the figure")
    p.add_argument("--json", type=Path, help="write the results as JSON here")
    p.set_defaults(func=cmd_freefree)

    p = sub.add_parser("bench", help="steps per second of the compiled PZT and closed loop against python-control",
                       description="Time the compiled SN637 model (dynamic form, creep) and the same "
                                   "step function under python-control's input_output_response; then the "
                                   "closed-loop 1000 s hold (exported controller, gauge noise) against the "
                                   "same loop period under input_output_response, and its peak memory.")
    p.add_argument("--plant", type=Path, default=Path("plants/p888_51_sn637_creep.toml"))
    p.add_argument("--steps", type=_positive_int, default=10_000_000, help="compiled steps (default 1e7)")
    p.add_argument("--reference-steps", type=_positive_int, default=2000,
                   help="steps for the python-control reference (default 2000)")
    p.add_argument("--controller", type=Path, default=Path("controllers/sn637_loopshape.json"),
                   help="controller JSON of the closed-loop hold")
    p.add_argument("--periods", type=_positive_int, help="closed-loop servo periods (default: --steps)")
    p.add_argument("--reference-periods", type=_positive_int,
                   help="periods for the closed loop's python-control reference (default: --reference-steps)")
    p.add_argument("--memory-periods", type=int, default=10**8,
                   help="periods of the peak-memory hold in a child process (default 1e8, ~30 s; 0 skips it)")
    p.add_argument("--json", type=Path, help="write the results as JSON here")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("linearize", help="describing functions, small-signal models, sampled gauge chain, W_m",
                       description="Linear models of the plant: the PZT's describing functions over amplitude "
                                   "and frequency, small-signal models on each branch, the gauge chain as the "
                                   "firmware samples it, and a multiplicative uncertainty bound over the family "
                                   "(the serials given, C_p and arm-imbalance tolerances). With --controller, "
                                   "the describing-function Nyquist analysis and predicted limit cycles.")
    p.add_argument("plant", type=Path, help="plant file, e.g. plants/p888_51_sn637_creep.toml (the nominal)")
    p.add_argument("--serials", type=Path, nargs="*", default=[],
                   help="other plant files of the family, e.g. plants/p888_51_sn629.toml plants/p888_51_sn618.toml")
    p.add_argument("--controller", type=Path, help="controller JSON (sample_rate_hz, sos rows, gain)")
    p.add_argument("--amplitudes", type=_quantity("V"), nargs="+",
                   default=[0.1, 0.3, 1.0, 3.0, 10.0, 20.0, 35.0, 50.0], help="sine amplitudes, default 0.1V..50V")
    p.add_argument("--bias", type=_quantity("V"), default=50.0, help="sine bias, default 50V")
    p.add_argument("--freq-min", type=_quantity("Hz"), default=0.1, help="default 0.1Hz")
    p.add_argument("--freq-max", type=_quantity("Hz"), default=5000.0, help="default 5kHz")
    p.add_argument("--freq-points", type=_positive_int, default=26, help="log-spaced frequencies, default 26")
    p.add_argument("--cp-tolerance", type=float, default=0.2, help="relative C_p tolerance, default 0.2")
    p.add_argument("--imbalance-tolerance", type=_quantity("ohm"), default=0.4,
                   help="per-arm bridge imbalance tolerance, default 0.4ohm")
    p.add_argument("--allow-unstable", action="store_true",
                   help="analyse a --controller with poles on or outside the unit circle (refused otherwise)")
    p.add_argument("--out", type=Path, help="folder for the figures")
    p.add_argument("--json", type=Path, help="write the results as JSON here")
    p.set_defaults(func=cmd_linearize)

    p = sub.add_parser("study", help="a design study: linearize, design, margins, export, report",
                       description="Run a study file (studies/*.toml): the plant family, the structured "
                                   "loop-shaping design (exported for firmware), Glover-McFarlane, H-infinity "
                                   "and convex designs for comparison, margins on every member, a Markdown "
                                   "report with figures and summary.json.")
    p.add_argument("study", type=Path, help="e.g. studies/sn637_servo.toml")
    p.add_argument("--out", type=Path, default=Path("out/study"), help="output folder (default out/study)")
    p.add_argument("--json", type=Path, help="write the summary as JSON here (summary.json in --out is always written)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a plant or study value, units allowed (repeatable), e.g. "
                        "--set electrical.current_limit_source_a=20mA --set targets.min_crossover_hz=80Hz (a key "
                        "named in deg, dB, percent takes a plain number or that unit: targets.phase_margin_deg=50deg); "
                        "plant sections apply to every plant of the study; the files are not modified")
    p.add_argument("--only", choices=["loopshape"], help="loopshape: the exported design alone, no comparison "
                                                         "designs (Glover-McFarlane, H-infinity, convex)")
    p.add_argument("--cache-dir", type=Path, help="family cache folder (default $WORKBENCH_CACHE_DIR, else "
                                                  "$XDG_CACHE_HOME/workbench, else ~/.cache/workbench)")
    p.add_argument("--no-cache", action="store_true", help="compute the family, neither read nor write the cache")
    p.add_argument("--workers", type=int, help="processes for the family (default: the machine's cores); not for a "
                                               "mirror study (workbench.fsm_study/1), which runs in one process")
    p.set_defaults(func=cmd_study)

    p = sub.add_parser("verify", help="the exported controller in closed loop with the nonlinear plant",
                       description="Closed-loop runs of an exported controller as firmware runs it (the "
                                   "fixed-point step when the JSON has one, with its current-limit window "
                                   "and anti-windup) with the hysteretic, creeping PZT, the current and "
                                   "voltage limits and the gauge chain with its noise: small and large "
                                   "steps, triangles at 0.1 and 1 Hz, a hold, a force step, a sine sweep; "
                                   "metrics beside the linear prediction, figures and a report. First a "
                                   "preflight compares the controller with the plant (SHA-256, serial, trim, "
                                   "gauge gain, limits, current-limit window): a mismatch warns, or with "
                                   "--strict is an error.")
    p.add_argument("plant", type=Path)
    p.add_argument("--controller", type=Path, required=True,
                   help="an exported .json or .mat, e.g. controllers/sn637_loopshape.json")
    p.add_argument("--scenario", nargs="+", default=_DEFAULT_SCENARIOS, metavar="NAME",
                   choices=["all", "small_step", "large_step", "triangle_0p1hz", "triangle_1hz", "hold",
                            "force_step", "sine_sweep"],
                   help="one or more of: all (default without --sensor), small_step, large_step, triangle_0p1hz, "
                        "triangle_1hz, hold, force_step, sine_sweep")
    p.add_argument("--sensor", choices=["gauge", "charge", "fused", "all"],
                   help="also run the controller's fixed-point sensor step closing on the gauge, the charge "
                        "estimate or their blend (all: the three side by side; 0.1 Hz triangle, then a --hold "
                        "hold, charge amplifier drifts and gauge noise present); alone, only these runs. "
                        "Default: the [verify] table's sensor key of --targets-from")
    p.add_argument("--form", choices=["fixed", "float", "hanus"],
                   help="controller form to run (default: what the JSON declares, fixed point first)")
    p.add_argument("--out", type=Path, help="folder for the figures, report.md and verify.json")
    p.add_argument("--hold", type=_quantity("s"), default=1000.0, help="hold duration, default 1000s")
    p.add_argument("--no-noise", action="store_true", help="gauge noise off")
    p.add_argument("--no-anti-windup", action="store_true", help="plain controller (shows the windup)")
    p.add_argument("--seed", type=int, default=0, help="seed of the gauge noise (default 0)")
    p.add_argument("--strict", action="store_true",
                   help="a controller exported for another plant (SHA-256, serial, trim, gauge gain, limits, "
                        "current-limit window) is an error, not a warning")
    p.add_argument("--allow-unstable", action="store_true",
                   help="accept a controller with poles on or outside the unit circle (analysis runs only)")
    p.add_argument("--target", action="append", metavar="NAME=VALUE",
                   help="override a target limit, e.g. small_step_settling_ratio=3 (repeatable)")
    p.add_argument("--targets-from", type=Path, metavar="TOML",
                   help="read target limits from the [verify] table of a study (or any TOML) file")
    p.add_argument("--json", type=Path, help="write the metrics as JSON here")
    p.set_defaults(func=cmd_verify)

    p = sub.add_parser("sweep", help="verification and margins over serials x tolerances x amplitudes",
                       description="For every serial of a study file x C_p (1 - tol, 1, 1 + tol) x amplitude: "
                                   "the exported controller's margins on the describing function at that "
                                   "amplitude, and a closed-loop triangle and step of that size with the "
                                   "nonlinear plant. Local processes by default, or a dask.distributed "
                                   "cluster with --scheduler; one table with the worst cases named.")
    p.add_argument("study", type=Path)
    p.add_argument("--controller", type=Path,
                   help="exported controller JSON (default: controllers/NAME.json next to the studies folder)")
    p.add_argument("--amplitudes", type=_quantity("V"), nargs="+", help="amplitudes, default the study's")
    p.add_argument("--scheduler", help="dask.distributed scheduler address, e.g. tcp://127.0.0.1:8786")
    p.add_argument("--workers", type=_positive_int, help="local processes (default: all cores)")
    p.add_argument("--noise", action="store_true", help="gauge noise on in the closed-loop runs (default off)")
    p.add_argument("--out", type=Path, default=Path("out/sweep"), help="output folder (default out/sweep)")
    p.add_argument("--table", type=Path, help="table path, .csv or .parquet (default OUT/sweep.csv)")
    p.add_argument("--json", type=Path, help="write the summary as JSON here")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("calibrate", help="fit the declared plant to a record, trace the residual to an effect",
                       description="Fit the plant to a measured record, analyse the residual, name the physical "
                                   "effect the plant lacks, add it, and report the error before and after on "
                                   "held-out data; writes an updated plant file into --out.")
    p.add_argument("data", type=Path, help="record CSV (time[s], voltage[V], and current/charge/displacement/gauge)")
    p.add_argument("--plant", type=Path, required=True, help="declared plant: plants/*.toml or a generic stack")
    p.add_argument("--out", type=Path, default=None, help="folder for the report, figures and updated plant")
    p.add_argument("--json", type=Path, default=None, help="write the result as JSON here")
    p.add_argument("--split", choices=("blocks", "forward", "cycles"), default=None,
                   help="test and validation rows: interleaved blocks (default for a PZT plant), forward (train on "
                        "the past, predict the last quarter) or after the first cycles (default for a generic stack)")
    p.add_argument("--train-cycles", type=float, default=3, help="input cycles that train with --split cycles")
    p.add_argument("--max-ratio", type=float, default=0.8,
                   help="ignored (kept for scripts; a value outside (0, 1) is still refused, as it was): the "
                        "decision is against the noise floor and a null reference over validation folds")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("synth", help="a synthetic calibration record from the simulator, with one effect",
                       description="Simulate the 35.5 s calibration protocol (decaying sines, 3 s holds, a chirp) "
                                   "through the plant with one effect drawn at random; writes the CSV "
                                   "`workbench calibrate` reads.")
    p.add_argument("plant", type=Path, help="plant file, e.g. plants/p888_51_sn637.toml")
    p.add_argument("--effect", default="none", choices=("none", "creep", "dielectric_absorption", "leakage",
                                                         "resonance", "delay", "drift", "gauge_nonlinearity"))
    p.add_argument("--seed", type=int, default=1, help="draws the effect's values and the noise")
    p.add_argument("--out", type=Path, required=True, help="CSV file to write")
    p.add_argument("--json", type=Path, default=None, help="write the drawn values as JSON here")
    p.set_defaults(func=cmd_synth)

    from .selfsense.command import add_parser as add_selfsense
    add_selfsense(sub)

    p = sub.add_parser("demo", help="the default job: seed reproductions with figures",
                       description="Gauge gains, T_em from Table 1, the free-free test on the three "
                                   "serials, creep, and the gauge chain's sampled behaviour, with figures.")
    p.add_argument("--out", type=Path, default=Path("out/demo"))
    p.add_argument("--json", type=Path, help="write the summary as JSON here")
    p.set_defaults(func=cmd_demo)

    from .preflight import add_force_flags
    add_force_flags(sub)
    return refuse_empty_paths(parser)      # an empty path is the current folder: refused (arguments.py)


class Terminated(KeyboardInterrupt):
    """SIGTERM (a plain ``kill``) turned into an exception in the main thread, so that the run's cleanup
    (:func:`workbench.preflight.preflight`: no partial outputs) runs as it does for Ctrl-C."""


@contextlib.contextmanager
def _sigterm_raises():
    """Within the block, SIGTERM raises :class:`Terminated` in the main thread (once: a second SIGTERM during
    the cleanup is ignored; SIGKILL still ends the process). Outside the main thread, nothing changes."""
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated()
    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    args._whole_process = argv is None      # the console script / python -m workbench: the process is the command's
    from .preflight import preflight
    import warnings
    from .errors import ControllerMismatchWarning
    try:
        # file arguments, flag ranges and run size checked before the work; no partial output after a failure
        # (also on Ctrl-C or a plain kill: both raise here, and preflight removes what the run created)
        with _sigterm_raises(), preflight(args), warnings.catch_warnings():
            # the library's warning of a controller exported for another plant: the commands print it as a
            # WARNING line of their own (verify's preflight lines, selfsense's), not twice
            warnings.simplefilter("ignore", ControllerMismatchWarning)
            args.func(args)
    except KeyboardInterrupt as err:
        # one line, no traceback; 128 + the signal's number, as a shell reports a process the signal ended
        terminated = isinstance(err, Terminated)
        print(f"{chr(10) if sys.stderr.isatty() else ''}workbench {args.command}: "
              f"{'terminated' if terminated else 'interrupted'}; nothing written "
              f"(the outputs this run created are removed)", file=sys.stderr)
        return 143 if terminated else 130
    except WorkbenchError as err:
        print(f"workbench {args.command}: error: {err}", file=sys.stderr)
        return 2
    except ValueError as err:
        # library argument checks (plain ValueError) are user errors at this level too
        print(f"workbench {args.command}: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
