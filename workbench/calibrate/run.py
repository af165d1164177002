"""``workbench calibrate``: fit the declared plant, trace the residual, add the effect, report.

Flow: read the record (``record.read_record``) and the plant (a full PZT file or a generic
stack, told apart by ``plant.generic.plant_kind``); the record's ``series_resistor_ohm`` and
``serial`` override the plant's; split the rows into training and held-out parts; fit the base
model of every recorded channel (``base_fit``); fit every candidate effect and name the one
the plant lacks (``tracing``); fit seed 001's creep law per hold (``creep_holds``); write the
figures, the report, the JSON and the updated plant file (the input files are never touched;
every output is written whole or not at all). The updated plant is loaded back and the record's drive
replayed through it (``plant_update.updated_plant_error``, issue 13 item 6): its test error is in the
JSON and the file's header beside the fitted model's, with a warning beyond 10 %. The JSON's
``error_after`` is the error of what the user gets (session 15): the file's replay on the test rows
when one was replayed (``error_after_source`` "updated plant"), else the tracing model's ("tracing
model"); the tracing model's own is ``error_after_model`` in both cases.
"""

import dataclasses
import time
from pathlib import Path

import numpy as np

from ..errors import DataFileError, PlantDefinitionError, WorkbenchError
from ..plant.files import load_plant
from ..plant.generic import load_generic_stack, plant_kind, to_toml
from ..report.output import write_text
from .stacking import column_stack
from .base_fit import fit_base
from .creep_holds import fit_holds
from .plant_update import (_sensor_terms, carried_stages, written_stages, choose_core, plant_file_gaps,
                           replay_above_before_warning, replay_key, reported_error_after, round_trip_note,
                           round_trip_warning, updated_plant_error, updated_plant_error_reason, updated_plant_text)
from .record import read_record
from .residual import charge_from_current
from .splits import default_split, make_split, settled_row
from .tracing import candidate_plan, trace_effect

__all__ = ["run_calibrate", "agreement_counts"]


def _json_candidates(cands):
    return [{"name": c["name"], "channel": c["channel"], "variant": c.get("variant"), "score": c["score"],
             "n_params": c["n_params"], "passes": c["passes"], "ratios": c["ratios"],
             "error_before": c["error_before"], **({"error_after": c["error_after"]} if "error_after" in c else {}),
             **({"periodic": c["periodic"]} if "periodic" in c else {})}
            for c in cands]


def agreement_counts(effect, channel, fold_winners, stages):
    """How the folds counted for the named effect, per channel (s22_outsider C2).

    ``agreement`` is the named view's own fold wins: a stack effect (creep, a mode) read by the gauge and the
    displacement alike is one motion, and the stages rule names it once when the two views together win the
    folds (:func:`~workbench.calibrate.stages.stack_effect_on_both_sensors`); "1 of 5" on the gauge then read as
    a minority while 4 of 5 folds found it. Returns None for no named effect, else ``{"named_view": "k of n"
    (the effect on the named channel), "by_channel": {channel: folds won}, "any_channel": "k of n" (the effect on
    any channel), "compatible": "k of n" or None (the stage's ``agreement_compatible``: the folds compatible with
    the name, as the tracing counted them)}``.
    """
    if effect in (None, "none", "inconclusive"):
        return None
    n = len(fold_winners or ())
    by = {}
    for w in fold_winners or ():
        if isinstance(w, str) and w.startswith(f"{effect} on the "):
            ch = w[len(f"{effect} on the "):]
            by[ch] = by.get(ch, 0) + 1
    comp = (stages[0].get("agreement_compatible") if stages else None)
    return {"named_view": f"{by.get(channel, 0)} of {n}", "by_channel": by,
            "any_channel": f"{sum(by.values())} of {n}",
            "compatible": None if comp is None else f"{int(comp)} of {n}"}


#: BLAS threads of a calibration: its solves are many and small (Gram matrices of a few dozen
#: columns, projections onto them), where a threaded BLAS spends more on waking its threads than
#: it saves -- several times slower on a loaded 2-core machine (``benchmarks/calibrate_speed.py``).
BLAS_THREADS = 1


def run_calibrate(data_path, plant_path, out_dir=None, split=None, train_cycles=3, max_ratio=0.8,
                  penalty=0.02, figures=True, progress=None, blas_threads=BLAS_THREADS):
    """Calibrate ``plant_path`` on the record ``data_path``; returns the JSON-ready dict.

    ``blas_threads``: the BLAS thread pool is limited to this many threads for the run
    (``threadpoolctl``; ``None``: left as it is). The other options: :func:`_run_calibrate`.
    """
    if blas_threads is None:
        return _run_calibrate(data_path, plant_path, out_dir, split, train_cycles, max_ratio, penalty, figures,
                              progress)
    from threadpoolctl import threadpool_limits
    with threadpool_limits(limits=int(blas_threads), user_api="blas"):
        return _run_calibrate(data_path, plant_path, out_dir, split, train_cycles, max_ratio, penalty, figures,
                              progress)


def _run_calibrate(data_path, plant_path, out_dir=None, split=None, train_cycles=3, max_ratio=0.8,
                   penalty=0.02, figures=True, progress=None):
    """Calibrate ``plant_path`` on the record ``data_path``; returns the JSON-ready dict.

    ``split``: ``"blocks"`` (default for a full PZT plant), ``"forward"`` or ``"cycles"``
    (default for a generic stack: the first ``train_cycles`` input cycles are the development
    rows, the rest is predicted); see :mod:`.splits` (:func:`~.splits.default_split`). The
    split used and why are in the JSON (``split``, ``split_reason``) and the report's notes.
    ``max_ratio`` is ignored (kept for
    callers of the earlier interface: the decision is against the noise floor and a null
    reference over validation folds, :mod:`.tracing`).
    """
    t0 = time.perf_counter()
    data_path, plant_path = Path(data_path), Path(plant_path)
    kind = plant_kind(plant_path)
    plant = load_plant(plant_path) if kind == "pzt" else load_generic_stack(plant_path)
    record = read_record(data_path)
    notes = list(record.notices)
    ch = record.channels
    input_kind = _input_kind(record, plant, kind, notes)
    # the record's readings the run reinterprets are warnings too (console and JSON ``warnings``, issue 17:
    # they were only in report.md's notes), not only notes
    said = []
    if input_kind == "command" and not record.metadata.get("input"):
        said.append(notes[-1] + "; the unit checks of a terminal voltage did not run: if the column holds the "
                    "stack's volts under another unit (e.g. voltage[mV]), fix its header")
    n_notes = len(notes)
    _note_sample_rate(record, notes)
    said += notes[n_notes:]
    if kind == "generic_stack":
        if "displacement_m" not in ch:
            raise DataFileError(f"{data_path}: a generic stack is calibrated from voltage to displacement; "
                                f"the record has no displacement column (add e.g. displacement[um])")
        v = ch["voltage_v"]
        if plant.min_v is None:
            plant = dataclasses.replace(plant, min_v=float(v.min()), max_v=float(v.max()))
            notes.append(f"the plant file gives no [voltage] range: the record's {plant.min_v:.4g} .. "
                         f"{plant.max_v:.4g} V{' (command volts)' if input_kind == 'command' else ''} is used")
        elif input_kind == "command":
            # the model runs in command volts: the calibrated file's range is the command's
            plant = dataclasses.replace(plant, min_v=float(v.min()), max_v=float(v.max()))
        else:
            _check_range(data_path, v, plant.min_v, plant.max_v, f"[voltage] min_v/max_v in {plant_path}")
        record = type(record)(record.path, record.metadata, record.t_s, {"voltage_v": v, "displacement_m":
                                                                        ch["displacement_m"]},
                              record.sample_period_s, record.notices)
        resistance, pzt, dac, n_plays, grid = 0.0, None, None, plant.n_plays, plant.threshold_grid
    else:
        resistance = plant.pzt.series_resistance_ohm
        if "series_resistor_ohm" in record.metadata:
            resistance = float(record.metadata["series_resistor_ohm"])
            notes.append(f"series resistor {resistance:g} ohm from the record's metadata (plant: "
                         f"{plant.pzt.series_resistance_ohm:g} ohm)" + (": the resistor is out, the recorded "
                                                                        "voltage is the terminal voltage"
                                                                        if resistance == 0 else ""))
        if input_kind == "terminal":
            _check_range(data_path, ch["voltage_v"], plant.pzt.voltage_min_v, plant.pzt.voltage_max_v,
                         f"[electrical] voltage_min_v/voltage_max_v in {plant_path}")
            _check_displacement_scale(data_path, record, plant.pzt, plant_path)
            n_notes = len(notes)
            _check_time_scale(data_path, record, plant.pzt, plant_path, resistance, notes)
            said += notes[n_notes:]
        pzt, dac, n_plays, grid = plant.pzt, plant.gauge.dac_range_v, 24, "quadratic"
    if split is None:
        names = {"displacement_m": "displacement", "current_a": "charge", "gauge_v": "gauge"}
        present = {names[c] for c in record.channels if c in names}
        split, split_reason = default_split(kind, [e.name for _, e, _ in candidate_plan(present)])
    else:
        split_reason = "asked for (--split)"
    notes.append(f"{split} split: {split_reason}")
    serial_warning = _serial_warning(record, plant, plant_path, kind)
    if serial_warning:
        said.append(serial_warning)
        notes.append(serial_warning)
    t, v = record.t_s, record.channels["voltage_v"]
    try:
        sp = make_split(t, v, kind=split, train_cycles=train_cycles)
    except ValueError as err:
        raise DataFileError(f"{data_path}: cannot split the record into training and held-out parts: {err}") from err
    left_out_s, settle_warnings = 0.0, []
    if input_kind == "command":
        # the plays start at the first command value, but where the stack stood (the amplifier's offset, the
        # stack's past) the record does not say: the rows before the command has settled every play it can
        # are predicted from an unknown state; they take no part in any fit or score, and the split is made
        # on the rows after them, whatever its kind (splits.settled_row)
        k0 = settled_row(v, n_plays, grid)
        if k0 > 0:
            try:
                sp = make_split(t, v, kind=split, train_cycles=train_cycles, start_row=k0)
                left_out_s = float(t[k0] - t[0])
                notes.append(f"the first {left_out_s:.4g} s are left out and the split made on the rows after them: "
                             f"until then the command has not swept twice the largest threshold it can settle, and "
                             f"the stack's state before a command record is unknown")
                if 2 * k0 > t.size:
                    # more of the record unused than used: said at the top, not only among the notes (review of
                    # s24_command: a command whose range grows to the end lost 92 % of its rows)
                    settle_warnings.append(f"the command settles its plays (sweeps its range) only at {left_out_s:.4g} s "
                                           f"of {t[-1] - t[0]:.4g} s: the rows before are left out (the stack's state "
                                           f"there is unknown); a record that sweeps its whole range early keeps "
                                           f"more")
            except ValueError as err:
                notes.append(f"the command settles its plays only at {t[k0] - t[0]:.4g} s, after which the record "
                             f"cannot be split ({err}): its first rows are used though its plays' states there "
                             f"are guesses")
                settle_warnings.append(f"the command settles its plays only at {t[k0] - t[0]:.4g} s, too late to "
                                       f"split the rest; the rows before are used though the stack's state there is "
                                       f"unknown (a record that sweeps its whole range early avoids this)")
    train, test = sp.train, sp.test
    # a generic stack's grid reaches max |V - V0|, the excursion from the record's start: right for a record that
    # starts mid-range (the real +/-150 V sine), twice too far for one from rest at an end of its range, whose plays
    # above half its span never move once the start's rise is out of the development rows (the cycles split trains
    # from the input's second reversal): a clean SN637 0-110 V sine moved 10 of its 20 plays there, the
    # displacement's held-out base error 7.8e-9 m against 3.0e-9 m with all 20 (noise 1.0e-9 m), and the creep
    # took the difference (s22_outsider A4). The file declares n_plays: they are spread over the thresholds that
    # move in the development rows (base_fit spread_plays)
    if progress:
        progress("base fit", 0, 1)
    base = fit_base(record, resistance, train=train, n_plays=n_plays, grid=grid, pzt=pzt, dac_range_v=dac, test=test,
                    input_kind=input_kind, spread_plays=kind == "generic_stack")
    base.notes = notes + base.notes
    if progress:
        progress("base fit", 1, 1)
    result = trace_effect(base, split=sp, penalty=penalty, progress=progress)
    holds = []
    y_hold = base.channels.get("displacement") or base.channels.get("gauge")
    if y_hold is not None:
        try:
            holds = fit_holds(t, base.v_drive, y_hold.y)
        except ValueError:
            holds = []
    data = {
        "record": str(data_path), "plant": str(plant_path), "plant_kind": kind,
        "effect": result["effect"], "channel": result["channel"],
        "error_before": result["error_before"], "error_after": result["error_after"],
        "parameters": result["parameters"], "agreement": result["agreement"],
        # the named effect's folds per channel (s22_outsider C2: a stack effect's "1 of 5" on the gauge, 3 more on
        # the displacement's view of the same motion)
        "agreement_counts": agreement_counts(result["effect"], result["channel"], result["fold_winners"],
                                             result["stages"]),
        "fold_winners": result["fold_winners"], "leading": result["leading"], "stages": result["stages"],
        "stage_notes": result.get("stage_notes", []),
        "candidates": _json_candidates(result["candidates"]),
        "reason": result["reason"], "penalty": penalty,
        "split": split, "split_reason": split_reason, "block_s": sp.block_s, "n_folds": len(sp.folds),
        "train_fraction": float(np.mean(train)), "held_out_fraction": float(np.mean(test)),
        "base_fit": {
            "voltage_source": base.voltage_source, "starts_from_rest": base.starts_from_rest,
            "series_resistor_ohm": resistance,
            # the channels' error_after is the tracing model's (the file's replay is the top-level error_after
            # when error_after_source is "updated plant"): each says so (review of s15_rt)
            "channels": {name: ({**err, "error_after_source": ("straight line of the drive (the tracing model is no "
                                                                "better on the validation folds)" if err.get("line")
                                                                else "tracing model")}
                                 if "error_after" in err else err)
                         for name, err in (result["channels"] or {}).items()},
            "k_q2x_m_per_c": base.k_q2x_m_per_c, "working_capacitance_f": base.working_capacitance_f,
            "gauge_gain_v_per_m": base.gauge_gain_v_per_m, "gauge_offset_v": base.gauge_offset_v,
            "n_plays": int(base.channels[next(iter(base.channels))].thresholds_v.size),
            "notes": base.notes,
            "warnings": base.warnings, "input": base.input_kind, "command_map": base.command_map,
            "current": base.current_kind, "gauge": base.gauge_kind,
            "train_range_v": list(base.train_range_v),
            "held_out_beyond_training_fraction": float(base.beyond_train.sum() / max(int(base.test.sum()), 1)),
            "dropped_thresholds_v": base.dropped_thresholds_v.tolist(),
            "left_out_s": left_out_s,
            "line": {name: {"rms": m.line_rms_test, "base_rms": m.rms_test, "slope": m.line_slope,
                            "offset": m.line_offset, "ridge": m.ridge if np.isfinite(m.ridge) else "line",
                            "units": m.units,
                            "base_clearly_better": m.clearly_better_than_line}
                     for name, m in base.channels.items()},
        },
        "creep_holds": [{k: (None if isinstance(x, float) and not np.isfinite(x) else x) for k, x in h.items()}
                        for h in holds],
    }
    text, data["updated_plant_error"] = None, None
    # session 15 (the lead's decision): ``error_after`` is the error of what the user gets. With an updated plant
    # file replayed, it is that file's replay on the test rows (rows no choice and no fit saw: every fit behind
    # the file, the core refit, the joint core and branches, the delay re-search, choose_core's choice, reads the
    # development rows alone); the tracing model's own test error is ``error_after_model``, always
    data["error_after_model"] = result["error_after"]
    data["error_after_source"] = "tracing model"
    data["updated_plant_error_reason"] = updated_plant_error_reason(kind, result, base, result["channel"])
    data["updated_plant_gaps"] = []
    data["updated_plant_core"] = None          # pzt: which core the file carries (choose_core)
    # the stages the file carries and those it does not, and why (plant_update.carried_stages)
    data["updated_plant_stages"] = []
    # said at the top of the printed summary and of the report (s22_outsider C1: the file's replay above the
    # error before was said only in base_fit.warnings)
    data["warnings"] = said + list(settle_warnings)
    if kind == "pzt":
        # issue 13 item 6: the updated plant loaded back and the record's drive simulated through it
        # the refitted core or the declared one, by the replay on the development rows (choose_core)
        # every file replayed once: choose_core's, carried_stages' and the test error's replays share one memo
        replays = {}
        core, dev, err = choose_core(plant_path, plant, base, result, data_path, train, test=test, replays=replays)
        # each stage written only where its form replays the development rows closer than the file without it
        omit, data["updated_plant_stages"] = carried_stages(plant_path, plant, base, result, data_path, core, train,
                                                            replays=replays)
        if omit:
            err = None                 # choose_core's test replay was of the file with every stage
        named = (result["effect"], result["channel"])
        if named in omit:              # the answer names an effect the file does not carry: said beside it
            data["warnings"].append(f"the {named[0]} named on the {named[1]} is not in the updated plant file: "
                                    f"{omit[named]}; the file's error_after is not the {named[0]}'s")
        kept = [st for st in written_stages(result["stages"], result, core)
                if (st["effect"], st["channel"]) not in omit]
        data["updated_plant_core"] = {
            "core": "refitted" if core["hysteresis"] is not None else "declared", "channel": core["channel"],
            "range_v": list(core["range_v"]) if core["range_v"] else None, "reason": core.get("reason"),
            "capped": float(core.get("capped", 0.0)), "development_rms": dev,
            # which write-out ran: C_h and branches fitted together (plant_update._core_with_branches) or not
            "joint": bool(core.get("joint", False)),
            # the file's displacement-sensor delay, s, and the offset the joint fit took off the record, m
            "sensor_delay_s": _sensor_terms(kept, base)[0],
            "offset_m": core.get("offset_m"),
            # the joint fit's fastest branch when the resistor is in and the drive is the recorded V (R C lag), s
            "fastest_branch_s": core.get("fastest_branch_s"),
            # the found mode's frequency and damping refitted through the file (_refit_mode): (f Hz, zeta, the
            # tracing's f Hz, zeta), None when not refitted; why the refit did not run, when it could not
            "mode_refit": list(core["mode"]) if core.get("mode") else None,
            "mode_refit_skipped": core.get("mode_refit_skipped")}
        text = updated_plant_text(plant_path, plant, base, result, data_path, core=core, omit=omit)
        if data["updated_plant_error_reason"] is None:
            again = _check_plant_text(text, Path(plant_path.stem + "_calibrated.toml"), kind)
            if err is None:
                err = updated_plant_error(again, base, result["channel"], test, train=train,
                                          current=base.current_kind or "averaged",
                                          replay=replays.get(replay_key(text, result["channel"])))
        else:
            err = None
        data["updated_plant_error"] = err
        file_gaps = plant_file_gaps(kept, base, plant, core=core)
        gaps = file_gaps + [f"the {e} on the {c} is not written: {why}" for (e, c), why in omit.items()]
        data["updated_plant_gaps"] = gaps
        warn = round_trip_warning(result["error_after"], err, result["stages"], gaps=gaps,
                                  core_written=core["hysteresis"] is not None)
        if warn:
            data["base_fit"]["warnings"].append(warn)
        note = round_trip_note(result["error_after"], err)
        if note:
            data["base_fit"]["notes"].append(note)
        text = updated_plant_text(plant_path, plant, base, result, data_path, plant_error=err, core=core, omit=omit)
        data["error_after"], data["error_after_source"] = reported_error_after(result["error_after"], err)
    if result["effect"] not in ("none", "inconclusive"):
        above = replay_above_before_warning(result["error_before"], data["error_after"], data["error_after_source"],
                                            data["updated_plant_stages"], file_gaps if kind == "pzt" else (),
                                            no_replay=data["updated_plant_error_reason"])
        if above:
            data["warnings"].append(above)
    # every warning in ``warnings`` (a script reading that key saw none of the base fit's); base_fit.warnings stays
    # (the same texts, where the base fit put them)
    data["warnings"] += [w for w in data["base_fit"]["warnings"] if w not in data["warnings"]]
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        stem = plant_path.stem + "_calibrated.toml"
        if kind != "pzt":
            m = base.channels["displacement"]
            stack = plant.with_calibration(thresholds_v=tuple(m.thresholds_v), weights_m_per_v=tuple(m.weights),
                                           offset_m=m.offset, initial_states_v=tuple(m.initial_states_v))
            cmd = base.command_map
            text = to_toml(stack, f"workbench calibrate on {data_path.name}, {split} split" + (
                "" if cmd is None else f", in command volts (the command reached the stack through a "
                f"{cmd['lag_s']:.4g} s lag and a {cmd['delay_s']:.4g} s delay, not in this file)"))
        plant_out = out / stem
        _check_plant_text(text, plant_out, kind)
        write_text(plant_out, text)
        data["updated_plant"] = str(plant_out)
        figs = []
        if figures:
            from ..report.calibrate_figures import calibration_figures
            if progress:
                progress("figures", 0, 1)
            figs = calibration_figures(out, base, {**result, "error_after": data["error_after"],
                                                   "error_after_model": data["error_after_model"],
                                                   "error_after_source": data["error_after_source"]},
                                       holds=holds or None)
        data["figures"] = [str(f) for f in figs]
        data["elapsed_s"] = time.perf_counter() - t0
        from ..report.calibrate_report import calibration_markdown
        md = calibration_markdown(data_path, plant_path, base, {**result, "error_after": data["error_after"],
                                                                "error_after_model": data["error_after_model"],
                                                                "error_after_source": data["error_after_source"],
                                                                "warnings": data["warnings"],
                                                                "agreement_counts": data["agreement_counts"],
                                                                "updated_plant_stages": data["updated_plant_stages"],
                                                                "max_ratio": max_ratio,
                                                                "penalty": penalty, "split": split,
                                                                "block_s": sp.block_s, "n_folds": len(sp.folds)},
                                  holds, figs, plant_out, data["elapsed_s"], report_dir=out)
        write_text(out / "report.md", md)
        data["report"] = str(out / "report.md")
        from ..report.html import write_html_report
        data["report_html"] = str(write_html_report(out / "report.md"))
    data["elapsed_s"] = time.perf_counter() - t0
    return data


#: Slack of the range check: a monitor's noise and the amplifier's own overshoot, 1 % of the range.
RANGE_SLACK = 0.01
#: A voltage column whose peak stays under this fraction of the plant's peak |range| is taken for an
#: amplifier command (0-10 V DAC ranges against stacks of 100 V and more) when the record does not say.
COMMAND_FRACTION = 0.1


def _serial_warning(record, plant, plant_path, kind):
    """The warning when the record's ``# serial:`` is not the plant's (None when they agree or either is absent).

    The serial is not used for anything else: the record is fitted to the plant file given, and the updated
    plant keeps that file's serial."""
    serial = record.metadata.get("serial")
    if not serial or kind != "pzt" or serial == plant.serial:
        return None
    return (f"the record's serial {serial} differs from the plant's {plant.serial} ({plant_path}): the record is "
            f"fitted to that plant file and the updated plant keeps serial {plant.serial}; if the record is of "
            f"{serial}, give {serial}'s plant file as --plant")


def _input_kind(record, plant, kind, notes):
    """``"terminal"`` or ``"command"``: the record's ``# input:``, else detected from the ranges and said."""
    said = record.metadata.get("input")
    if said:
        return said
    lo, hi = (plant.min_v, plant.max_v) if kind == "generic_stack" else (plant.pzt.voltage_min_v,
                                                                          plant.pzt.voltage_max_v)
    if lo is None:
        return "terminal"
    v = record.channels["voltage_v"]
    peak, top = float(np.max(np.abs(v))), max(abs(lo), abs(hi))
    if peak < COMMAND_FRACTION * top:
        notes.append(f"the voltage column peaks at {peak:.3g} V, under {COMMAND_FRACTION:g} of the plant's "
                     f"{lo:g} .. {hi:g} V: taken for the amplifier's command (unknown gain, offset and lag, "
                     f"fitted); write '# input: terminal' in the record if it is the stack's voltage")
        return "command"
    return "terminal"


def _check_range(data_path, v, lo, hi, where):
    """The recorded terminal voltage must stay within the declared range (``RANGE_SLACK`` of it)."""
    slack = RANGE_SLACK * (hi - lo)
    if v.min() < lo - slack or v.max() > hi + slack:
        i = int(np.argmax((v < lo - slack) | (v > hi + slack)))
        raise DataFileError(f"{data_path}: the voltage spans {v.min():.4g} .. {v.max():.4g} V (first outside at "
                            f"data row {i + 1}), outside the plant's range {lo:g} .. {hi:g} V ({where}); "
                            f"calibrate against the plant of the stack that was driven, check the voltage "
                            f"column's unit, or write '# input: command' if the column is the amplifier's command")


#: A recorded stroke this many times larger or smaller than the plant's is taken for a unit slip: the geometric
#: middle between the same unit (ratio 1; a stack differs from its model by tens of %) and the next SI prefix
#: (x 1000, e.g. metres written under displacement[um]).
UNIT_SLIP_RATIO = 1000.0 ** 0.5


def _check_displacement_scale(data_path, record, pzt, plant_path):
    """The recorded displacement's span must be the plant's quasi-static stroke over the recorded voltage span
    within :data:`UNIT_SLIP_RATIO` (a record in m under displacement[um] was calibrated, 'no effect', before)."""
    x = record.channels.get("displacement_m")
    if x is None:
        return
    v = record.channels["voltage_v"]
    model = float(pzt.quasi_static_x_m([0.0, v.max()])[-1] - pzt.quasi_static_x_m([0.0, v.min()])[-1])
    recorded = float(np.ptp(x))
    if not model > 0:
        return
    ratio = recorded / model
    if not 1.0 / UNIT_SLIP_RATIO <= ratio <= UNIT_SLIP_RATIO:
        raise DataFileError(f"{data_path}: the displacement spans {recorded:.4g} m over the recorded "
                            f"{v.min():.4g} .. {v.max():.4g} V, {ratio:.3g} times the {model:.4g} m the plant "
                            f"{plant_path} strokes over that range (quasi-static); more than {UNIT_SLIP_RATIO:.3g} "
                            f"times off is a unit slip, not a stack: check the displacement column's unit "
                            f"(e.g. displacement[um] over values in m) or calibrate against the stack's plant")


#: The sample rates records come at (issue 17: rigs from 100 Hz to 1 MHz), Hz. A time column implying a rate
#: outside is suspicious (a notice naming the likely slip), never refused on its own: the physics decides.
RECORD_RATES_HZ = (100.0, 1.0e6)


def _note_sample_rate(record, notes):
    """A notice when the time column implies a sample rate outside :data:`RECORD_RATES_HZ`."""
    rate = 1.0 / record.sample_period_s
    lo, hi = RECORD_RATES_HZ
    if rate < lo:
        notes.append(f"the time column implies {rate:.4g} Hz sampling, under the {lo:g} Hz of the slowest rig: "
                     f"if the times are in ms, write time[ms] in the header")
    elif rate > hi:
        notes.append(f"the time column implies {rate:.4g} Hz sampling, over the {hi:g} Hz of the fastest rig: "
                     f"if the times are in s, write time[s] in the header")


def fastest_slew_v_per_s(pzt):
    """The fastest terminal-voltage slew the plant's amplifier can drive, V/s.

    The charge reaches the stack at most at the amplifier's current limit, ``max(source, sink)``, and the
    terminal voltage is the PI operator ``G`` of that charge (:meth:`~workbench.plant.pzt.PZTParams.
    terminal_operator`), whose steepest slope (V/C) is its largest partial sum of weights (the plays
    switched on one by one): ``dV_t/dt <= I_max max_k sum_{j<=k} w_j``. Creep, leakage and absorption
    branches only take current away.
    """
    g = pzt.terminal_operator()
    slope_v_per_c = float(np.max(np.cumsum(g.weights)))
    return max(pzt.current_limit_source_a, pzt.current_limit_sink_a) * slope_v_per_c


def recorded_slew_v_per_s(record, resistance_ohm, pzt):
    """The fastest voltage change of a record, V/s, over lags of 1, 4, 16, ... samples.

    The monitor reads ``V_t + R i``: each lag's largest change is taken less ``2 R I_max`` (the resistor's
    drop swinging from the plant amplifier's sink to its source limit) and 6 sigmas of the voltage noise
    (from the median absolute deviation of the sample-to-sample change), so a step of the drop or of the
    noise is no slew.
    """
    v, dt_s = record.channels["voltage_v"], record.sample_period_s
    i_max = max(pzt.current_limit_source_a, pzt.current_limit_sink_a)
    dv = np.diff(v)
    noise_v = 1.4826 * float(np.median(np.abs(dv - np.median(dv)))) / np.sqrt(2.0)
    allowance_v = 2.0 * resistance_ohm * i_max + 6.0 * noise_v
    best, k = 0.0, 1
    while k <= max(1, v.size // 4):
        dv = float(np.max(np.abs(v[k:] - v[:-k]))) - allowance_v
        best = max(best, dv / (k * dt_s))
        k *= 4
    return best


def charge_scale(record, pzt, resistance_ohm, rate_test=False):
    """The recorded charge over the plant's, by least squares with the best constant current taken out.

    The charge ``q`` (the current integrated by :func:`~workbench.calibrate.residual.charge_from_current`
    under the record's ``# current:`` convention) is fitted as ``a q_model + b + c t + g int V_t dt``, ``q_model =
    G^-1(V_t - V_t[0])`` the plant's quasi-static charge over the terminal voltage ``V_t = V - R i``: the
    ``b + c t`` term takes the current monitor's offset out and ``g int V_t dt`` a leakage resistor's charge
    (``g = 1/R_leak``), the way the base fit treats offset and leakage, so neither grows with the record's
    length. ``a`` scales with the time unit:
    1 as recorded, 1000 for ms under time[s], 1/1000 for s under time[ms].

    A record with a ``charge[C]`` column and no current: ``q`` is that column (``a`` does not scale with the
    time unit then, but with the column's unit and quantity).

    ``rate_test``: also the RMS left by ``q_model`` and by ``dq_model/dt`` (the plant's current), each scaled and with a
    constant and a line: ``(a, as_charge, as_current)``; a column the current explains better holds a current.

    Returns
    -------
    float or None
        ``a`` (dimensionless, signed: a stack's charge rises with its terminal voltage, ``a > 0``), or None when
        less than 5 % of the plant's charge span is left once a constant
        current and a leakage are taken out (e.g. a ramp): then the time unit cannot be told.
    """
    v, t = record.channels["voltage_v"], record.t_s
    dt = record.sample_period_s
    stride = max(1, v.size // 200_000)            # the quasi-static charge needs no more points than its shape
    if "current_a" in record.channels:
        i = record.channels["current_a"]
        q = charge_from_current(t, i, current=record.current_kind)[::stride]
    else:                                         # a charge column: its current for V_t = V - R i
        q_full = record.channels["charge_c"]
        i = np.gradient(q_full, t)
        q = q_full[::stride]
    v_t = (v - resistance_ohm * i)[::stride]
    q_model = pzt.terminal_operator().inverse()(np.ascontiguousarray(v_t - v_t[0]))
    ts = (t[::stride] - t[0]) / max(float(t[-1] - t[0]), dt)      # 0..1: a well-conditioned basis
    leak = np.cumsum(v - resistance_ohm * i)[::stride]            # a leakage resistor's charge, ~ int V_t dt
    leak_span = float(np.ptp(leak))
    basis = column_stack([np.ones_like(ts), ts] + ([leak / leak_span] if leak_span > 0 else []))
    proj = basis @ np.linalg.lstsq(basis, q_model, rcond=None)[0]
    shape = q_model - proj                        # the plant's charge no offset or leakage can mimic
    span = float(np.ptp(q_model))
    if not span > 0 or float(np.ptp(shape)) < 0.05 * span:
        return None
    q_d = q - basis @ np.linalg.lstsq(basis, q, rcond=None)[0]
    a = float(np.dot(q_d, shape) / np.dot(shape, shape))
    if rate_test:
        # the column as a charge (the plant's q_model) or as a current (its rate), each with a constant and a
        # line free; without the leakage column, which over a periodic drive holds the current's own shape
        lin = basis[:, :2]

        def left(col):
            m = column_stack([col, lin])
            return float(np.sqrt(np.mean((q - m @ np.linalg.lstsq(m, q, rcond=None)[0]) ** 2)))
        # as a current its own drop sets V_t (the charge's derivative, taken above, is then meaningless)
        v_i = (v - resistance_ohm * q_full)[::stride]
        q_i = pzt.terminal_operator().inverse()(np.ascontiguousarray(v_i - v_i[0]))
        return a, left(q_model), left(np.gradient(q_i, t[::stride]))
    return a


def _check_time_scale(data_path, record, pzt, plant_path, resistance_ohm, notes=None):
    """A time column off by 1000 (ms under time[s], s under time[ms]) is refused where the physics says so.

    * With a current column: the charge ``sum(i) dt``, with the best constant current taken out, must scale
      to the plant's quasi-static charge ``G^-1(V_t)`` (:func:`charge_scale`) within :data:`UNIT_SLIP_RATIO`
      either way. The charge scales with the time unit and does not depend on the amplifier: 1000 times too
      much is likely ms under time[s] (or a current in mA under current[A]), 1000 times too little s under
      time[ms]. A current offset or leakage is the constant current taken out.
    * Without one, the voltage alone refutes no time unit: through a series resistor R > 0 a lab amplifier
      can pass up to ``max(I_max, (V_max - V_min) / R)`` and its output steps by the whole range at once
      (the drop across R), and with R = 0 nothing bounds the current. A record slewing
      (:func:`recorded_slew_v_per_s`) more than :data:`UNIT_SLIP_RATIO` times faster than the plant file's
      amplifier can drive (:func:`fastest_slew_v_per_s`) gets a notice naming the likely slip, appended to
      ``notes``.
    * The charge's sign (s22_outsider A5): a stack's charge rises with its terminal voltage (``a > 0``); a
      current (or charge) column whose charge falls as the voltage rises is reversed and refused, whatever
      ``|a|``.
    * A ``charge[C]`` column (no current): refused when the plant's current (the rate of its charge) explains
      it closer than the plant's charge (a current logged under charge[C]), or when it is more than
      :data:`UNIT_SLIP_RATIO` times off the plant's charge either way (its unit).
    """
    v, dt = record.channels["voltage_v"], record.sample_period_s
    i = record.channels.get("current_a")
    q_col = i is None and "charge_c" in record.channels
    if i is None and not q_col:
        i_max = max(pzt.current_limit_source_a, pzt.current_limit_sink_a)
        recorded = recorded_slew_v_per_s(record, resistance_ohm, pzt)
        fastest = fastest_slew_v_per_s(pzt)
        if notes is not None and fastest > 0 and recorded > UNIT_SLIP_RATIO * fastest:
            lab_a = max(i_max, (pzt.voltage_max_v - pzt.voltage_min_v) / resistance_ohm) if resistance_ohm > 0 else 0.0
            through = (f"a lab amplifier can pass up to {lab_a * 1e3:.4g}"
                       f" mA through the {resistance_ohm:g} ohm resistor" if resistance_ohm > 0 else
                       "with no series resistor nothing bounds a lab amplifier's current")
            notes.append(f"the voltage slews at {recorded:.4g} V/s, {recorded / fastest:.3g} times the {fastest:.4g} "
                         f"V/s the plant's {i_max * 1e3:.4g} mA amplifier can drive: if that amplifier drove the "
                         f"record, the time column is likely 1000 times too small (seconds under time[ms], "
                         f"{1.0 / dt:.4g} Hz implied); not refused, {through}")
        return
    a = charge_scale(record, pzt, resistance_ohm, rate_test=q_col)
    if a is None:
        return
    if q_col:
        a, as_charge, as_current = a
        if as_current < as_charge:
            # s22_outsider A5: a current logged under charge[C] was taken for the charge (a 6.6 Hz resonance named)
            raise DataFileError(f"{data_path}: the charge column follows the plant's current (the rate of its charge "
                                f"over the terminal voltage) closer than its charge: {as_current:.3g} against "
                                f"{as_charge:.3g} C RMS left (each scaled, with a constant and a line free); it holds a "
                                f"current: write current[A] (or current[mA], ...) in the header")
        i = np.gradient(record.channels["charge_c"], record.t_s)
    v_t = v - resistance_ohm * i
    over = f"the terminal voltage {v_t.min():.4g} .. {v_t.max():.4g} V"
    if a < 0:
        # s22_outsider A5: |a| was tested, so a reversed current passed and the drive fell back to the raw V;
        # first, whatever |a|: no stack's charge falls as its voltage rises, while a scale may also be off
        name = "charge" if q_col else "current"
        raise DataFileError(f"{data_path}: the {name} column {'' if q_col else 'integrates to a charge that '}falls as "
                            f"the terminal voltage rises ({a:.3g} times the charge the plant {plant_path} holds over "
                            f"{over}): no stack does that; the {name}'s sign is reversed (a probe or a shunt turned "
                            f"round): negate the {name} column")
    if q_col and not (1.0 / UNIT_SLIP_RATIO <= abs(a) <= UNIT_SLIP_RATIO):
        # s22_outsider A5: a current logged under charge[C] was taken for the charge (a 6.6 Hz resonance named)
        raise DataFileError(f"{data_path}: the charge column (best constant and leakage taken out) is {abs(a):.3g} "
                            f"times the charge the plant {plant_path} holds over {over}: more than "
                            f"{UNIT_SLIP_RATIO:.3g} times off; check the charge column's unit, and whether it holds a "
                            f"current (then write current[A] in the header)")
    if 1.0 / UNIT_SLIP_RATIO <= abs(a) <= UNIT_SLIP_RATIO:
        return
    slip = "1000 times too large (ms under time[s])" if abs(a) > 1 else "1000 times too small (s under time[ms])"
    raise DataFileError(f"{data_path}: the current integrates (best constant current taken out) to {abs(a):.3g} "
                        f"times the charge the plant {plant_path} holds over the terminal voltage {v_t.min():.4g} .. "
                        f"{v_t.max():.4g} V: more than {UNIT_SLIP_RATIO:.3g} times off, the time column is likely "
                        f"{slip}, {1.0 / dt:.4g} Hz implied; check the time column's unit (and the current's)")


def _check_plant_text(text, path, kind):
    """Load the updated plant from a scratch copy before it is written: never hand back a file
    the workbench itself would reject. Returns the plant loaded back."""
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / path.name
        p.write_text(text, encoding="utf-8")
        try:
            return load_plant(p) if kind == "pzt" else load_generic_stack(p)
        except PlantDefinitionError as err:       # a bug here, not the user's
            raise WorkbenchError(f"internal: the updated plant would not load ({err})") from err
