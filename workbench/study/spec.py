"""Study files (``studies/*.toml``): what a design study runs, validated before anything runs.

Paths inside a study are relative to the study file. Every key is checked: an
unknown or missing key, a wrong type or an out-of-range value is a
:class:`~workbench.errors.StudyDefinitionError` naming the file, the key, the value
and what is expected.
"""

import math
from dataclasses import dataclass
from pathlib import Path

from ..errors import StudyDefinitionError
from ..fields import Field, check_table, check_value, read_toml

__all__ = ["SCHEMA_VERSION", "StudySpec", "load_study", "STUDY_FIELDS"]

SCHEMA_VERSION = "workbench.study/1"

_SCHEMA = {
    "": {
        "schema": Field("str", expect=f'the string "{SCHEMA_VERSION}"'),
        "name": Field("str", expect="a short name for the study, used in file names"),
        "plant": Field("str", expect="the nominal plant file, relative to the study file"),
        "serials": Field("strs", expect="other plant files of the family (a list, may be empty)", required=False),
    },
    "family": {
        "amplitudes_v": Field("floats", 0.0, 200.0, lo_open=True, expect="sine amplitudes in V, e.g. [0.1, 1, 10, 50]"),
        "bias_v": Field("float", -20.0, 120.0, expect="the sine bias in V, inside the amplifier range"),
        "freq_min_hz": Field("float", 0.0, 1e4, lo_open=True, expect="lowest frequency in Hz"),
        "freq_max_hz": Field("float", 0.0, 1e5, lo_open=True, expect="highest frequency in Hz, below Nyquist"),
        "freq_points": Field("int", 8, 400, expect="number of log-spaced frequencies"),
        "cp_tolerance": Field("float", 0.0, 0.9, expect="relative C_p tolerance, e.g. 0.2"),
        "imbalance_tolerance_ohm": Field("float", 0.0, 10.0, expect="per-arm bridge imbalance in ohm, e.g. 0.4"),
    },
    "targets": {
        "phase_margin_deg": Field("float", 0.0, 90.0, lo_open=True, expect="phase margin in degrees, e.g. 45"),
        "gain_margin_db": Field("float", 0.0, 40.0, lo_open=True, expect="gain margin in dB, e.g. 6"),
        "min_crossover_hz": Field("float", 0.0, 5e3, lo_open=True, expect="the lowest acceptable crossover in Hz"),
        "triangle_hz": Field("float", 0.0, 100.0, lo_open=True, required=False,
                             expect="frequency of the triangle the loop must track (10-90 % of stroke), Hz, e.g. 0.1"),
        "triangle_rms_percent_stroke": Field("float", 0.0, 100.0, lo_open=True, required=False,
                                             expect="largest RMS error of that triangle after its first period, % of "
                                                    "stroke, e.g. 0.01"),
    },
    "loop_shape": {
        "fc_min_hz": Field("float", 0.0, 5e3, lo_open=True, expect="lowest crossover searched, Hz"),
        "fc_max_hz": Field("float", 0.0, 5e3, lo_open=True, expect="highest crossover searched, Hz"),
        "integral_ratios": Field("floats", 0.0, 100.0, lo_open=True, required=False,
                                 expect="crossover / PI corner ratios to try, e.g. [0.1, 0.25, 1, 4, 8]"),
        "integral_orders": Field("floats", 1.0, 2.0, required=False,
                                 expect="integrators to try: [1] PI (type-1 loop), [1, 2] also (1 + w_i/s)^2 (type 2)"),
        "lead_ratios": Field("floats", 1.0, 100.0, required=False, expect="lead pole/zero ratios, e.g. [1, 3, 6]"),
        "rolloff_ratios": Field("floats", 1.0, 100.0, lo_open=True, required=False,
                                expect="roll-off frequency / crossover ratios, e.g. [4, 8]"),
        "max_noise_command_v": Field("float", 0.0, 100.0, lo_open=True, required=False,
                                     expect="largest RMS per-sample command change from gauge noise, V, e.g. 0.03"),
        "max_overshoot_percent": Field("float", 0.0, 100.0, required=False,
                                       expect="largest nominal small-step overshoot, %, e.g. 3"),
    },
    "sensor": {
        "kind": Field("str", required=False, expect='the feedback sensor: "gauge", "charge" or "fused"'),
        "blend_crossover_hz": Field("float", 0.0, 5e3, lo_open=True, required=False,
                                    expect="the fused blend's crossover in Hz (default: chosen from the two sensors' "
                                           "noise and drift spectra)"),
        "drift_record_s": Field("float", 60.0, 20000.0, required=False,
                                expect="length of the staircase record that gives the charge's drift spectrum, s, "
                                       "e.g. 1000"),
        "seed": Field("int", 0, 2 ** 31 - 1, required=False, expect="seed of the simulated sensor records, e.g. 2"),
    },
    "hinf": {
        "time_limit_s": Field("float", 0.0, 3600.0, lo_open=True, expect="time limit of the slycot synthesis, s"),
    },
    "export": {
        "name": Field("str", expect="controller name (file stem), e.g. \"sn637_loopshape\""),
        "directory": Field("str", expect="folder for the exported controllers, relative to the output folder"),
        "output_limits_v": Field("floats", -1000.0, 1000.0, expect="[low, high] PZT command limits in V"),
        "input_range_v": Field("float", 0.0, 100.0, lo_open=True, expect="error input range in firmware V, e.g. 2.6"),
    },
}


@dataclass(frozen=True)
class StudySpec:
    path: Path
    name: str
    plant: Path
    serials: tuple
    family: dict
    targets: dict
    loop_shape: dict
    hinf: dict
    export: dict
    sensor: dict = None        # [sensor] (optional; kind "gauge" when absent): see SENSOR_KINDS


SENSOR_KINDS = ("gauge", "charge", "fused")
_OPTIONAL_SECTIONS = ("sensor",)         # may be absent (then every key takes its default)


# Sections a study file may carry for other commands: [verify] holds verify's target limits
# (`workbench verify ... --targets-from STUDY.toml` reads and validates it); the study ignores it.
OTHER_SECTIONS = ("verify",)


def _check(path, key, field, value):
    if field.kind == "strs":
        if not isinstance(value, list) or not all(isinstance(v, str) and v.strip() for v in value):
            raise StudyDefinitionError(path, key, f"got {value!r}; expected {field.expect}")
        return tuple(value)
    return check_value(path, key, field, value, StudyDefinitionError)


def load_study(path, overrides=None):
    """Read and validate a study file; paths come back resolved against its folder.

    ``overrides`` ``{"section.key": value}`` (SI, see :mod:`.overrides`) replace the file's
    values before validation; the file is not modified.
    """
    path = Path(path)
    data = read_toml(path, StudyDefinitionError, "give an existing study file, e.g. studies/sn637_servo.toml")
    for where, value in (overrides or {}).items():
        section, _, key = where.partition(".")
        data.setdefault(section, {})
        if not isinstance(data[section], dict):
            raise StudyDefinitionError(path, where, f"--set names [{section}], which is not a table here")
        data[section][key] = value
    out = {}
    for section, schema in _SCHEMA.items():
        table = data if section == "" else data.get(section)
        if table is None and section in _OPTIONAL_SECTIONS:
            table = {}
        if table is None:
            raise StudyDefinitionError(path, section, f"missing section [{section}]; expected keys {', '.join(schema)}")
        vals = check_table(path, section, table, schema, StudyDefinitionError,
                           sections=[*(k for k in _SCHEMA if k), *OTHER_SECTIONS], check=_check)
        out[section] = vals
    unknown = set(data) - set(_SCHEMA) - set(_SCHEMA[""]) - set(OTHER_SECTIONS)
    if unknown:
        raise StudyDefinitionError(path, sorted(unknown)[0], f"unknown section; known: {', '.join(s for s in _SCHEMA if s)}")
    top = out[""]
    if top["schema"] != SCHEMA_VERSION:
        raise StudyDefinitionError(path, "schema", f"got {top['schema']!r}; expected {SCHEMA_VERSION!r}")
    fam, ls, ex = out["family"], out["loop_shape"], out["export"]
    if not fam["freq_min_hz"] < fam["freq_max_hz"]:
        raise StudyDefinitionError(path, "family.freq_max_hz", f"got {fam['freq_max_hz']:g}; must exceed "
                                                              f"freq_min_hz = {fam['freq_min_hz']:g}")
    if not ls["fc_min_hz"] < ls["fc_max_hz"]:
        raise StudyDefinitionError(path, "loop_shape.fc_max_hz", "must exceed fc_min_hz")
    if "integral_orders" in ls and not all(float(v) in (1.0, 2.0) for v in ls["integral_orders"]):
        raise StudyDefinitionError(path, "loop_shape.integral_orders", f"got {list(ls['integral_orders'])}; "
                                                                       f"expected 1 and/or 2, e.g. [1, 2]")
    lim = ex["output_limits_v"]
    if lim.size != 2 or not lim[0] < lim[1]:
        raise StudyDefinitionError(path, "export.output_limits_v", f"got {lim.tolist()}; expected [low, high], low < high")
    base = path.parent
    files = [base / top["plant"]] + [base / s for s in top.get("serials", ())]
    for i, f in enumerate(files):
        if not f.is_file():
            key = "plant" if i == 0 else f"serials[{i - 1}]"
            raise StudyDefinitionError(path, key, f"{f} does not exist; paths are relative to the study file")
    if not all(math.isfinite(a) for a in fam["amplitudes_v"]):
        raise StudyDefinitionError(path, "family.amplitudes_v", "must be finite")
    sensor = {"kind": "gauge", **out["sensor"]}
    if sensor["kind"] not in SENSOR_KINDS:
        raise StudyDefinitionError(path, "sensor.kind", f"got {sensor['kind']!r}; expected one of "
                                                        f"{', '.join(repr(k) for k in SENSOR_KINDS)}")
    tg = out["targets"]
    if ("triangle_hz" in tg) != ("triangle_rms_percent_stroke" in tg):
        missing = "triangle_rms_percent_stroke" if "triangle_hz" in tg else "triangle_hz"
        raise StudyDefinitionError(path, f"targets.{missing}", "missing; the triangle target takes both "
                                                               "triangle_hz and triangle_rms_percent_stroke")
    return StudySpec(path=path, name=top["name"], plant=files[0], serials=tuple(files[1:]), family=fam,
                     targets=tg, loop_shape=ls, hinf=out["hinf"], export=ex, sensor=sensor)


#: The file's sections and their typed, range-checked fields (public name of the one schema).
STUDY_FIELDS = _SCHEMA
