"""Checks a command's arguments before any work starts, and keeps a failed run from leaving files.

:func:`preflight` is what ``workbench.cli.main`` wraps every command in:

1. every file argument is checked (:mod:`workbench.paths`): inputs exist, are files, are
   readable and decode as UTF-8; outputs are writable, not a folder where a file is wanted
   (or the reverse), and never one of the run's inputs;
2. flags are range-checked with their unit and the sane range in the message, the range
   derived from the plant file where the plant sets it (stroke, amplifier range, sample rate);
3. runs whose size a flag sets (``verify --hold``, ``selfsense --duration``, ``linearize
   --freq-points``, ``freefree --cycles``) state their estimated time and memory first and are
   refused beyond :data:`MAX_SECONDS` or the machine's memory unless ``--force`` is given;
4. during the run, the report writers refuse to replace an input file, and if the run fails
   every file and folder it created under its outputs is removed (a failed run writes nothing).
"""

import contextlib
import itertools
import math
import os
import re
import shutil
import sys
from pathlib import Path

from .errors import FlagRangeError, StudyDefinitionError, WorkbenchError
from .fields import check_seed
from .paths import FileArgumentError, check_input_file, check_output_dir, check_output_file, is_inside, same_path

__all__ = ["preflight", "add_force_flags", "estimate_run", "FlagRangeError", "MAX_SECONDS", "RUN_COSTS"]

# A run estimated longer than this is refused unless --force (an accident, such as --hold 1e12s,
# should not start a job of days; a deliberate long run says so).
MAX_SECONDS = 3600.0

# Cost of one unit of work of each long-running command: (seconds, bytes) per unit, measured with
# benchmarks/preflight_estimates.py (two sizes of each library entry point in one process after a
# warm-up, the difference taken so start-up and compile cancel) on the 2-core machine of the README
# ("Bad input"), rounded up. The estimate is an order of magnitude (the machine may be faster or
# loaded): it only has to tell a 10-second run from a 10-day one.
RUN_COSTS = {
    # verify: one servo period of the closed-loop hold (traces decimated to 20000 points: no memory
    # per period; the other scenarios are fixed-size)
    "verify_period": (2.5e-7, 0.0),
    # verify --sensor: one servo period of a sensor loop (the charge channel and the sensor step beside the
    # plant; its traces keep 5 floats per 10 periods): 6.1e-7 s measured between a 3 s and a 60 s hold of
    # the fused loop at load ~5 (benchmarks/preflight_estimates.py), rounded up
    "verify_sensor_period": (1.0e-6, 4.0),
    # selfsense: one second of the 10 kHz staircase record through the stages (peak RSS 675 MB at
    # 400 s, 1356 MB at 3000 s: /usr/bin/time)
    "selfsense_second": (1.2e-2, 2.6e5),
    # linearize: one describing-function point (an amplitude at a frequency) of one serial, with its
    # C_p and imbalance members in the uncertainty family
    "linearize_point": (0.2, 1.0e4),
    # freefree: one gauge-rate sample of the simulated sine and its gauge reading
    "freefree_sample": (1.2e-6, 120.0),
    # bench (time only; its memory hold measures the memory): one compiled step (timed 3 times), one
    # python-control reference step, one closed-loop period (compiled, 3 times; the memory hold once), one
    # python-control closed-loop period. One run of `bench --steps 100000 --reference-steps 300 --periods
    # 100000 --reference-periods 300 --memory-periods 0` on the loaded 2-core machine (load ~6) measured
    # 1.4e-7, 1.8e-4, 2.7e-7 and 3.7e-4 s, rounded up
    "bench_step": (1.5e-7 * 3, 0.0),
    "bench_reference_step": (2.0e-4, 0.0),
    "bench_period": (3.0e-7 * 3, 0.0),
    "bench_memory_period": (3.0e-7, 0.0),
    "bench_reference_period": (4.0e-4, 0.0),
}


# ---------------------------------------------------------------------------------------------
# which argument of which command is an input or an output

def _files(args):
    """(inputs, output_files, output_dirs) of parsed ``args``: lists of (argument name, path)."""
    cmd = args.command
    ins, out_files, out_dirs = [], [], []

    def add(lst, name, flag):
        value = getattr(args, name, None)
        if value is None:
            return
        for v in (value if isinstance(value, (list, tuple)) else [value]):
            lst.append((flag, Path(v)))

    if cmd == "identify":
        add(ins, "table", "table")
    elif cmd in ("study", "sweep"):
        add(ins, "study", "study")
    elif cmd == "calibrate":
        add(ins, "data", "record")
    if cmd not in ("demo", "identify", "study", "sweep") and cmd != "bench":
        add(ins, "plant", "plant" if cmd != "calibrate" else "--plant")
    if cmd == "bench":
        add(ins, "plant", "--plant")
    add(ins, "serials", "--serials")
    add(ins, "controller", "--controller")
    if getattr(args, "fused", False):
        add(ins, "fused_controller", "--fused-controller")      # selfsense --fused runs it in closed loop
    add(ins, "targets_from", "--targets-from")
    if cmd == "synth":
        add(out_files, "out", "--out")
    else:
        add(out_dirs, "out", "--out")
    if cmd == "sweep":
        add(out_files, "table", "--table")
    add(out_files, "json", "--json")
    return ins, out_files, out_dirs


def _implicit_inputs(args):
    """Files a command reads without an argument naming them (its defaults): (name, path) pairs.

    They are not checked here (their command reports a missing one in its own words), but no output
    may be one of them: ``demo --json plants/p888_51_sn637.toml``, ``sweep --table`` onto the
    controller it runs, ``selfsense --json`` onto its default controller."""
    cmd = args.command
    found = []
    if cmd == "demo":
        from .demo import CREEP_PLANT, PLANTS, TABLE1
        found += [("file the demo reads", Path(p)) for p in (*PLANTS, CREEP_PLANT, TABLE1)]
    elif cmd == "sweep" and getattr(args, "controller", None) is None:
        import tomllib
        try:
            data = tomllib.loads(Path(args.study).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            data = {}
        name = data.get("export", {}).get("name") if isinstance(data.get("export"), dict) else None
        if isinstance(name, str):
            from .verify.sweep_job import default_controller_path
            found.append(("controller (the sweep's default)", default_controller_path(args.study, name)))
    elif cmd == "selfsense":
        from .selfsense.fused_loop import FUSED_CONTROLLER
        from .selfsense.defaults import DEFAULT_CONTROLLER
        if getattr(args, "controller", None) is None:
            found.append(("--controller (default)", DEFAULT_CONTROLLER))
        if getattr(args, "fused_controller", None) is None:
            found.append(("--fused-controller (default)", FUSED_CONTROLLER))
        if getattr(args, "force", False):
            from .identify.transducer import DEFAULT_TABLE1_PATH
            found.append(("Table 1 the --force study reads", DEFAULT_TABLE1_PATH))
    # a mirror file's stack files (verify reads them, and its creep file beside them; a mirror study too)
    from .plant.mirror import mirror_stack_files
    mirrors = [Path(args.plant)] if cmd == "verify" and getattr(args, "plant", None) else []
    if cmd == "study":
        import tomllib
        try:
            mirrors += [p for _, p in _study_inputs(args)]
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            pass                                # the study's own check names the problem
    for m in map(lambda p: Path(os.path.normpath(p)), mirrors):
        stacks = mirror_stack_files(m)
        found += stacks
        if stacks and cmd == "verify":
            from .verify.mirror import VERIFY_CREEP_FILE
            found.append((f"{m}: the creep plant beside it", m.parent / VERIFY_CREEP_FILE))
    return found


def _check_files(args):
    ins, out_files, out_dirs = _files(args)
    for name, path in ins:
        check_input_file(path, name)
        if path.suffix.lower() == ".json":
            _check_json(path, name)
        if path.suffix.lower() == ".csv":
            _check_csv_delimiter(path, name)
    ins = ins + _implicit_inputs(args)
    for name, path in ins:
        if name in ("--controller", "--fused-controller") and path.suffix.lower() in (".json", ".mat"):
            if args.command == "verify" and _mirror_pairing(args, path):
                continue          # a three-stack mirror and its MIMO controller (validated there)
            # the one controller loader validates it now, not after minutes of linearization
            from .controller import Controller, ControllerMismatchError
            ctrl = Controller.load(path, allow_unstable=getattr(args, "allow_unstable", False))
            if args.command in ("verify", "selfsense") and getattr(args, "plant", None):
                fs = _plant(args.plant).gauge.modulation_hz        # the servo runs once per modulation period
                if abs(ctrl.sample_rate_hz - fs) > 1e-9 * fs:
                    raise ControllerMismatchError(
                        f"--controller {path}: [sample_rate_hz] {ctrl.sample_rate_hz:g} Hz differs from the servo "
                        f"rate {fs:g} Hz of {args.plant} (its gauge modulation): it cannot run on this plant; "
                        f"export the controller at {fs:g} Hz")
            plant_arg = getattr(args, "plant", None)
            if args.command in ("verify", "selfsense", "bench") and plant_arg is not None:
                # the sensor block's gauge curvature and reference lead, on the plant the loop closes on
                ctrl.check_firmware_settings(_plant(plant_arg))
            if args.command == "sweep" and ctrl.sensor is not None:
                import tomllib
                try:
                    plants = [p for _, p in _study_inputs(args)]
                except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
                    plants = []                       # the study's own check names the problem
                for p in plants:                      # the sweep closes the loop on every serial of the study
                    if p.is_file():
                        ctrl.check_firmware_settings(_plant(p))
    for name, path in out_files:
        # the suffix of the file the flag writes, for the message's example (synth writes a CSV record)
        csv = (args.command, name) in (("synth", "--out"), ("sweep", "--table"))
        check_output_file(path, name, inputs=ins, suffix=".csv" if csv else ".json")
    for name, path in out_dirs:
        check_output_dir(path, name, inputs=ins)
    if getattr(args, "cache_dir", None):
        # a folder the run writes into but does not own (kept after a failure, so not an output to clean)
        check_output_dir(Path(args.cache_dir), "--cache-dir", inputs=ins)
    outs = out_files + out_dirs
    for i, (name, path) in enumerate(outs):
        for other, p2 in outs[i + 1:]:
            if same_path(path, p2):
                raise FileArgumentError(f"{name} {path}: is also {other}; two outputs cannot share a path")
    for name, path in out_files:
        for dname, d in out_dirs:
            if same_path(path.parent, d) and path.name in _RESERVED.get(args.command, ()):
                raise FileArgumentError(f"{name} {path}: the command writes its own {path.name} into {dname} {d}; "
                                        f"give another file name")
    return ins, out_files, out_dirs


def _mirror_pairing(args, path):
    """A mirror file (workbench.fsm/1) with a MIMO controller: validate the controller, True; a mismatch
    (SISO controller on the mirror or the reverse) raises naming the file; a single stack with a SISO one: False."""
    from .verify.mirror import check_pairing
    if not check_pairing(args.plant, path):
        return False
    from .export.mimo import MimoController
    from .plant.mirror import load_mirror
    ctrl = MimoController.load(path, allow_unstable=getattr(args, "allow_unstable", False))
    ctrl.check_mirror(load_mirror(args.plant))          # a damped export's windows and corner are the stacks'
    return True


def _is_mirror_file(path):
    from .plant.mirror import FSM_SCHEMA_VERSION
    import tomllib
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8")).get("schema") == FSM_SCHEMA_VERSION
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False


def _check_json(path, name):
    import json
    text = path.read_text(encoding="utf-8")
    try:
        json.loads(text)
    except json.JSONDecodeError as err:
        raise FileArgumentError(f"{name} {path}: line {err.lineno}, column {err.colno}: not valid JSON ({err.msg}); "
                                f"give a controller JSON exported by `workbench study`") from None


def _check_csv_delimiter(path, name):
    """The header (first line not a '#' comment) of a CSV must be comma-separated."""
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, 1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            if "," not in text:
                for sep, what in ((";", "semicolons"), ("\t", "tabs")):
                    if sep in text:
                        raise FileArgumentError(f"{name} {path}: line {lineno}: columns separated by {what}; the "
                                                f"workbench reads comma-separated CSV (e.g. time[s],voltage[V],...): "
                                                f"export it with ',' as the separator and '.' as the decimal point")
            return


# the report a command writes into its --out folder: a --json of the same path would replace it
# (summary.json / verify.json there hold the same data as --json, so those names are allowed)
_RESERVED = {"study": ("report.md",), "verify": ("report.md",), "selfsense": ("report.md",),
             "calibrate": ("report.md",)}


# ---------------------------------------------------------------------------------------------
# study files: the parts whose mistakes are otherwise found late

_STEM = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")
_C_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _check_study_sections(path, data):
    from .study.spec import STUDY_FIELDS
    for section in STUDY_FIELDS:
        if not section or section not in data:
            continue
        value = data[section]
        if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            raise StudyDefinitionError(path, section, f"written as an array of tables [[{section}]]; write it "
                                                      f"once as [{section}]")
        if not isinstance(value, dict):
            raise StudyDefinitionError(path, section, f"is a value ({section} = {value!r}), not a section; "
                                                      f"write [{section}] with its keys on the lines below")
    from .study.spec import STUDY_FIELDS as schema
    from .study.spec import OTHER_SECTIONS
    for key, value in data.items():
        if isinstance(value, dict) and key not in schema and key not in OTHER_SECTIONS:
            raise StudyDefinitionError(path, key, f"unknown section [{key}]; known sections: "
                                                  f"{', '.join(f'[{s}]' for s in schema if s)}")


def _refuse_plant_file_as_study(path, data, command):
    """A plant file (single stack, mirror or generic stack) given where a study file is wanted: said so, not
    "[electrical] unknown section" (issue 17, session 32)."""
    from .plant.files import SCHEMA_VERSION
    from .plant.mirror import FSM_SCHEMA_VERSION
    from .plant.generic import GENERIC_SCHEMA
    what = {SCHEMA_VERSION: "a plant file", FSM_SCHEMA_VERSION: "a three-stack mirror file",
            GENERIC_SCHEMA: "a generic stack file"}.get(data.get("schema"))
    if what:
        example = "studies/fsm_servo.toml" if data.get("schema") == FSM_SCHEMA_VERSION else "studies/sn637_servo.toml"
        raise StudyDefinitionError(path, "schema", f"this is {what} ({data['schema']}); `workbench {command}` takes a "
                                                   f"study file, e.g. {example} (which names its plant files)")


def _check_study_file(args):
    import tomllib
    path = Path(args.study)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise StudyDefinitionError(path, "syntax", f"is not valid TOML: {exc}") from None
    from .study.mirror import FSM_STUDY_SCHEMA
    _refuse_plant_file_as_study(path, data, args.command)
    mirror = data.get("schema") == FSM_STUDY_SCHEMA      # its loader checks its own sections (study/mirror.py)
    if not mirror:
        _check_study_sections(path, data)
    if getattr(args, "set", None) and not mirror:
        # a study value given by --set is checked as if written in the file (study --set export.name=../x
        # was found by the exporter after the design work)
        from .study.overrides import parse_overrides, split_overrides
        for key, value in split_overrides(parse_overrides(args.set))[1].items():
            section, _, name = key.partition(".")
            if isinstance(data.get(section, {}), dict):
                data[section] = {**data.get(section, {}), name: value}
    export = data.get("export", {})
    if not isinstance(export, dict):
        return
    name = export.get("name")
    if mirror and isinstance(name, str) and not _C_NAME.match(name):
        raise StudyDefinitionError(path, "export.name", f"got {name!r}; the mirror's C header needs a C identifier "
                                                        f"(letters, digits, '_', not starting with a digit), "
                                                        f"e.g. \"fsm_servo\"")
    if isinstance(name, str) and not _STEM.match(name):
        raise StudyDefinitionError(path, "export.name", f"got {name!r}; a file stem of letters, digits, '_', '-' "
                                                        f"and '.', e.g. \"sn637_loopshape\"")
    directory = export.get("directory")
    if args.command == "study" and isinstance(directory, str):
        out = Path(args.out)
        target = out / directory
        if Path(directory).is_absolute() or not is_inside(target, out):
            raise StudyDefinitionError(path, "export.directory", f"got {directory!r}, which is outside the output "
                                                                 f"folder {out}; give a folder relative to --out, "
                                                                 f"e.g. \"controllers\"")


def _study_inputs(args):
    """The plant files a study names (its inputs too), resolved against the study file's folder."""
    import tomllib
    path = Path(args.study)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    serials = data.get("serials") if isinstance(data.get("serials"), list) else []
    names = [("plant", data.get("plant"))] + [(f"serials[{i}]", s) for i, s in enumerate(serials)]
    return [(f"{path}: {key}", path.parent / value) for key, value in names if isinstance(value, str)]


# ---------------------------------------------------------------------------------------------
# flags

def _finite(flag, value, unit):
    if not math.isfinite(value):
        raise FlagRangeError(f"{flag} {value:g} {unit}: must be a finite number")


def _in_range(flag, value, unit, lo, hi, why, lo_open=False, hi_open=False):
    _finite(flag, value, unit)
    low_ok = value > lo if lo_open else value >= lo
    high_ok = value < hi if hi_open else value <= hi
    if not (low_ok and high_ok):
        rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'} {unit}"
        raise FlagRangeError(f"{flag} {value:g} {unit}: out of range {rng} ({why})")


def _plant(path):
    from .plant import load_plant
    return load_plant(path)


def _stroke_from_rest_m(pzt, v):
    """Quasi-static displacement from rest at the terminal voltage ``v`` (V), m."""
    return float(pzt.quasi_static_x_m([0.0, v])[-1])


def _stroke_range_m(pzt):
    """Quasi-static displacement from rest at the amplifier's lowest and highest voltage, m."""
    lo = _stroke_from_rest_m(pzt, pzt.voltage_min_v) if pzt.voltage_min_v < 0 else 0.0
    hi = _stroke_from_rest_m(pzt, pzt.voltage_max_v)
    return min(lo, 0.0), hi


def _v_for_stroke(pzt, x_m):
    """The lowest positive voltage whose quasi-static stroke from rest reaches ``x_m``, V (the library's)."""
    from .identify.freefree import v_peak_floor_v
    return v_peak_floor_v(pzt, x_m)


def _check_flags(args):
    cmd = args.command
    if cmd == "gauge":
        pzt = _plant(args.plant).pzt
        lo, hi = _stroke_range_m(pzt)
        _finite("--x0", args.x0, "m")
        if not lo <= args.x0 <= hi:
            raise FlagRangeError(f"--x0 {args.x0 * 1e6:g} um: out of range [{lo * 1e6:.2f}, {hi * 1e6:.2f}] um, the "
                                 f"stack's quasi-static stroke over the amplifier's {pzt.voltage_min_v:g}.."
                                 f"{pzt.voltage_max_v:g} V in {args.plant}")
    elif cmd == "identify":
        from .plant.files import PLANT_FIELDS as plant_fields      # the plant file's range for k_p: one home
        k_max = plant_fields["mechanics"]["stiffness_n_per_m"].hi
        _in_range("--stiffness", args.stiffness, "N/m", 0.0, k_max, "a stiffness is positive, at most the plant "
                  "file's stiffness_n_per_m range; e.g. 2e8 (200 N/um)", lo_open=True)
    elif cmd == "freefree":
        plant = _plant(args.plant)
        fs = plant.gauge.modulation_hz
        from .identify.freefree import check_v_peak      # the library's check (one home)
        _finite("--v-peak", args.v_peak, "V")
        check_v_peak(plant, args.v_peak, name="--v-peak", where=str(args.plant))
        _in_range("--freq", args.freq, "Hz", 0.0, fs / 20, f"at least 20 gauge samples a period at the "
                  f"{fs:g} Hz gauge rate of {args.plant}", lo_open=True)
    elif cmd == "linearize":
        pzt = _plant(args.plant).pzt
        from .linearize.run import check_amplitudes          # the library's check (one home)
        check_amplitudes(pzt, args.amplitudes, name="--amplitudes", where=str(args.plant))
        _in_range("--bias", args.bias, "V", pzt.voltage_min_v, pzt.voltage_max_v, f"the amplifier range of {args.plant}")
        _in_range("--freq-min", args.freq_min, "Hz", 0.0, 1e5, "positive, at most the study schema's 100 kHz",
                  lo_open=True)
        _in_range("--freq-max", args.freq_max, "Hz", 0.0, 1e5, "positive, at most the study schema's 100 kHz",
                  lo_open=True)
        if not args.freq_min < args.freq_max:
            raise FlagRangeError(f"--freq-min ({args.freq_min:g} Hz) must be below --freq-max ({args.freq_max:g} Hz)")
        from .linearize.weight import MIN_GRID_POINTS
        _in_range("--freq-points", args.freq_points, "points", MIN_GRID_POINTS, 100_000,
                  f"the uncertainty weight W_m is fitted over at least {MIN_GRID_POINTS} frequencies")
        _in_range("--cp-tolerance", args.cp_tolerance, "(fraction of C_p)", 0.0, 1.0, "e.g. 0.2 for +/-20 %",
                  hi_open=True)
        _in_range("--imbalance-tolerance", args.imbalance_tolerance, "ohm", 0.0, 10.0,
                  "per-arm bridge imbalance, the study schema's range; e.g. 0.4ohm")
    elif cmd == "verify":
        check_seed(args.seed, "--seed")
        # the hold scores the settled loop after its first second: at least one more second
        _in_range("--hold", args.hold, "s", 2.0, math.inf, "the first second of the hold settles the loop and "
                  "is not scored; give at least 2s, e.g. 1000s")
        if getattr(args, "sensor", None):
            # the sensor loops' hold: 1 s settling and two 1 s windows for the drift (verify/sensors.py)
            _in_range("--hold", args.hold, "s", 3.0, math.inf, "with --sensor the hold settles 1 s and measures "
                      "its drift between two 1 s windows; give at least 3s, e.g. 1000s")
    elif cmd == "sweep" and args.amplitudes:
        from .linearize.run import check_amplitudes          # the library's check (one home)
        import tomllib
        try:
            plants = [(n, p) for n, p in _study_inputs(args) if p.is_file()]
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            plants = []                                       # the study's own check names the problem
        for where, p in plants:                               # every serial of the study is driven at them
            check_amplitudes(_plant(p).pzt, args.amplitudes, name="--amplitudes", where=f"{p} ({where})")
    elif cmd == "calibrate":
        # --max-ratio is ignored (kept for scripts, as its help says): the range its scripts gave is still checked,
        # and the message says it has no effect
        _in_range("--max-ratio", args.max_ratio, "(held-out RMS after / before)", 0.0, 1.0,
                  "the range it had; the option is ignored (kept for scripts): the decision is against the noise "
                  "floor and a null reference over validation folds; drop it or give e.g. 0.8",
                  lo_open=True, hi_open=True)
        _in_range("--train-cycles", args.train_cycles, "cycles", 0.0, 1e6, "input cycles that train, e.g. 3",
                  lo_open=True)
    elif cmd == "synth":
        check_seed(args.seed, "--seed")
    elif cmd == "selfsense":
        if getattr(args, "force", False) and getattr(args, "step_force", None) is not None:
            # the library's check (--step-force 1e9N ran and reported errors of a 5 m compression)
            from .selfsense.force import check_step_force
            check_step_force(_plant(args.plant).pzt, args.step_force, name="--step-force", where=str(args.plant))
        _in_range("--duration", args.duration, "s", 100.0, math.inf, "a few steps of 20-60 s; e.g. 1000s")
        if args.seed is not None:
            check_seed(args.seed, "--seed")
    elif cmd == "bench":
        if args.memory_periods < 0:
            raise FlagRangeError(f"--memory-periods {args.memory_periods}: must be >= 0 (0 skips the memory check)")


# ---------------------------------------------------------------------------------------------
# long runs

def _human_s(s):
    for unit, size in (("years", 365.25 * 86400.0), ("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if s >= size:
            return f"{s / size:.3g} {unit}"
    return f"{s:.3g} s"


def _human_b(b):
    if b < 1e6:
        return "under 1 MB"
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if b >= size:
            return f"{b / size:.3g} {unit}"
    return f"{b / 1e3:.3g} kB"


def _memory_bytes():
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8e9


def _controller_rate_hz(path, default):
    import json
    try:
        rate = float(json.loads(Path(path).read_text(encoding="utf-8")).get("sample_rate_hz", default))
    except (OSError, ValueError, TypeError, AttributeError):
        return default       # the controller loader reports what is wrong with the file itself
    return rate if math.isfinite(rate) and rate > 0 else default


def _default_scenarios():
    from .cli import _DEFAULT_SCENARIOS
    return _DEFAULT_SCENARIOS


def _verify_sensor_loops(args):
    """The sensor loops verify will run (kinds) and the startup wait each takes from the controller, s."""
    sensor = getattr(args, "sensor", None)
    if sensor is None and getattr(args, "targets_from", None):
        from .verify.run import load_verify_sensor
        sensor = load_verify_sensor(args.targets_from)
    if not sensor:
        return [], {}
    from .export.sensor import SENSOR_KINDS
    kinds = list(SENSOR_KINDS) if sensor == "all" else [sensor]
    wait = {}
    try:
        from .controller import Controller
        sb = Controller.load(args.controller).sensor
    except (WorkbenchError, ValueError, OSError):
        sb = None                                     # the controller's own check names the problem
    if sb is not None and sb.startup_wait_s is not None and sb.kind in kinds:
        wait[sb.kind] = sb.startup_wait_s
    return kinds, wait


def estimate_run(args):
    """(what, seconds, bytes) of the part of the run a flag sizes, or None for fixed-size runs (bytes None:
    not estimated, as bench measures its own memory)."""
    cmd = args.command
    if cmd == "verify" and _is_mirror_file(args.plant):
        return None                 # the mirror's scenarios have a fixed size (tens of seconds of mirror time)
    if cmd == "verify":
        fs = _controller_rate_hz(args.controller, _plant(args.plant).gauge.modulation_hz)
        scenarios = [args.scenario] if isinstance(args.scenario, str) else args.scenario   # --scenario takes several
        sensors, wait_s = _verify_sensor_loops(args)
        if sensors and args.scenario is _default_scenarios():
            scenarios = []                      # --sensor alone: the sensor loops only (cli.cmd_verify)
        periods = args.hold * fs if {"all", "hold"} & set(scenarios) else 0
        s, b = RUN_COSTS["verify_period"]
        parts = [f"--hold {args.hold:g} s ({periods:.3g} servo periods at {fs:g} Hz)"] if periods else []
        seconds, nbytes = periods * s, periods * b
        if sensors:
            # each sensor loop: open loop for the controller's startup_wait_s (when its block carries one for
            # that sensor), the two-period 0.1 Hz triangle, then the --hold (verify/sensors.py run_sensor_loop)
            s_p, b_p = RUN_COSTS["verify_sensor_period"]
            from .verify.sensors import closing_time_s       # one home for when the sensor loop closes
            n = sum((closing_time_s(wait_s.get(k)) + 20.0 + args.hold) * fs for k in sensors)
            parts.append(f"--sensor {' '.join(sensors)} with --hold {args.hold:g} s ({n:.3g} servo periods"
                         + "".join(f"; {args.controller}: [sensor.startup_wait_s] {w:g} s of open loop"
                                   for w in wait_s.values()) + ")")
            seconds, nbytes = seconds + n * s_p, nbytes + n * b_p
        what = " and ".join(parts) or f"--hold {args.hold:g} s (no hold scenario)"
        return what, seconds, nbytes
    if cmd == "selfsense":
        s, b = RUN_COSTS["selfsense_second"]
        return f"--duration {args.duration:g} s", args.duration * s, args.duration * b
    if cmd == "linearize":
        serials = 1 + len(args.serials)
        points = len(args.amplitudes) * args.freq_points * serials
        s, b = RUN_COSTS["linearize_point"]
        return (f"--freq-points {args.freq_points} x {len(args.amplitudes)} amplitudes x {serials} serial(s)",
                points * s, points * b)
    if cmd == "bench":
        periods = args.steps if args.periods is None else args.periods
        ref_periods = args.reference_steps if args.reference_periods is None else args.reference_periods
        parts = [(args.steps, "bench_step"), (args.reference_steps, "bench_reference_step"), (periods, "bench_period"),
                 (ref_periods, "bench_reference_period"), (max(args.memory_periods, 0), "bench_memory_period")]
        seconds = sum(n * RUN_COSTS[key][0] for n, key in parts)
        return (f"--steps {args.steps} / --reference-steps {args.reference_steps} / --periods {periods} / "
                f"--reference-periods {ref_periods} / --memory-periods {args.memory_periods}", seconds, None)
    if cmd == "freefree":
        fs = _plant(args.plant).gauge.modulation_hz
        n = args.cycles * fs / args.freq
        s, b = RUN_COSTS["freefree_sample"]
        return f"--cycles {args.cycles} at {args.freq:g} Hz ({n:.3g} samples at {fs:g} Hz)", n * s, n * b
    return None


def _check_size(args):
    est = estimate_run(args)
    if est is None:
        return
    what, seconds, nbytes = est
    force = getattr(args, "force_size", False)
    ram = _memory_bytes()
    memory = "" if nbytes is None else f" and {_human_b(nbytes)} of memory"
    nbytes = nbytes or 0.0
    if nbytes > ram:
        raise FlagRangeError(f"{what}: estimated {_human_s(seconds)} and {_human_b(nbytes)} of memory, more than "
                             f"this machine's {_human_b(ram)}; shorten the run")
    if seconds > MAX_SECONDS and not force:
        raise FlagRangeError(f"{what}: estimated {_human_s(seconds)}{memory}, beyond the "
                             f"{_human_s(MAX_SECONDS)} bound; shorten the run or give {size_flag(args.command)} to "
                             f"run it anyway")
    if seconds > 30.0:
        print(f"workbench {args.command}: {what}: estimated {_human_s(seconds)}{memory}",
              file=sys.stderr, flush=True)


def size_flag(command):
    """The flag that lifts the run-size bound of ``command``: ``--force``, except on selfsense,
    where ``--force`` runs the force self-sensing study (issue 16 names it so)."""
    return "--allow-long-run" if command == "selfsense" else "--force"


def add_force_flags(sub):
    """Give the commands whose size a flag sets the run-size bound's override (:func:`size_flag`)."""
    for name in ("verify", "selfsense", "linearize", "freefree", "bench"):
        p = sub.choices.get(name)
        if p is not None:
            p.add_argument(size_flag(name), dest="force_size", action="store_true",
                           help=f"run even if the estimated time exceeds {MAX_SECONDS / 3600:g} h")


# ---------------------------------------------------------------------------------------------
# no partial outputs

_SNAPSHOT_MAX = 100_000      # entries; an --out folder larger than this (e.g. '.') is not cleaned


def _snapshot(path):
    if not path.exists():
        return None
    if path.is_file():
        return {path}
    entries = set(itertools.islice(path.rglob("*"), _SNAPSHOT_MAX + 1))
    return "skip" if len(entries) > _SNAPSHOT_MAX else {path, *entries}


def _remove_new(path, before):
    if before == "skip":
        return
    if before is None:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        elif path.exists():
            path.unlink()
        return
    if path.is_dir():
        new = sorted((p for p in path.rglob("*") if p not in before), key=lambda p: len(p.parts), reverse=True)
        for p in new:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            elif p.exists() or p.is_symlink():
                p.unlink()


@contextlib.contextmanager
def preflight(args):
    """Check ``args`` before the command runs; protect its inputs and clean up after a failure.

    Raises
    ------
    WorkbenchError
        From the checks, before the block runs.
    """
    from .report.output import protect_inputs
    ins, out_files, out_dirs = _check_files(args)
    if args.command in ("study", "sweep"):
        from .study.overrides import naming_set, parse_overrides
        given = getattr(args, "set", None) or []
        with naming_set(parse_overrides(given) if given else {}, given):    # a --set value's error names --set
            _check_study_file(args)
        extra = _study_inputs(args)
        for name, path in out_files:
            check_output_file(path, name, inputs=extra)
        ins = ins + extra
        if args.command == "sweep" and getattr(args, "table", None) is not None:
            from .verify.sweep import check_table_path      # the library's check (one home)
            check_table_path(args.table, name="--table")
    if args.command == "synth":
        from .calibrate.synthetic import RECORD_SUFFIXES as suffixes    # the record writer's (one home)
        if Path(args.out).suffix.lower() not in suffixes:
            raise FileArgumentError(f"--out {args.out}: the suffix must be one of {', '.join(suffixes)} (synth writes "
                                    f"a CSV record); e.g. {Path(args.out).with_suffix('.csv')}")
    _check_flags(args)
    _check_size(args)
    outs = [p for _, p in out_files + out_dirs]
    before = {p: _snapshot(p) for p in outs}
    ok = False
    try:
        with protect_inputs(ins):
            yield
        ok = True
    except WorkbenchError as err:
        # a run that completed with a negative answer (a study whose best design misses a target)
        # keeps the report that says why; any other failure leaves nothing behind
        ok = getattr(err, "outputs_are_the_result", False)
        raise
    finally:
        if not ok:
            for p in outs:
                _remove_new(p, before[p])
