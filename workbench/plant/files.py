"""Read and validate plant definitions (``plants/*.toml``).

A plant file is data only: every value in SI, every key named with its unit, every
line commented with its source. This module checks each field against a schema and
builds the frozen parameter objects the models use. Any problem is a
:class:`~workbench.errors.PlantDefinitionError` naming the file, the key, the value
and what was expected; a file is never written back.
"""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import PlantDefinitionError
from ..fields import Field as _Field, check_value, read_toml
from .additions import Additions
from .creep import CreepParams
from .gauge import GaugeParams
from .hysteresis import PrandtlIshlinskii
from .pzt import Mode, PZTParams
from .structure import STRUCTURE_SCHEMA, structure_from_section

__all__ = ["Plant", "load_plant", "SCHEMA_VERSION", "PLANT_FIELDS"]

SCHEMA_VERSION = "workbench.plant/1"


def _pos(expect, hi=math.inf):
    return _Field("float", 0.0, hi, lo_open=True, expect=expect)


_SCHEMA = {
    "": {
        "schema": _Field("str", expect=f'the string "{SCHEMA_VERSION}"'),
        "name": _Field("str", expect="a descriptive name"),
        "serial": _Field("str", expect="the stack's serial, e.g. \"SN637\""),
    },
    "electrical": {
        "series_resistor_ohm": _Field("float", 0.0, 1e6, expect="a resistance >= 0 ohm (0 = quasi-static form)"),
        "series_resistor_in": _Field("bool", expect="true or false (seed 000 Fig. 2 switch)"),
        "current_limit_source_a": _pos("a positive source current limit in A, e.g. 2.0e-3", 10.0),
        "current_limit_sink_a": _pos("a positive sink current magnitude in A, e.g. 14.0e-3", 10.0),
        "voltage_min_v": _Field("float", -1000.0, 0.0, expect="the amplifier's lowest output in V, <= 0"),
        "voltage_max_v": _Field("float", 0.0, 1000.0, lo_open=True, expect="the amplifier's highest output in V, > 0"),
        "working_capacitance_f": _pos("C_p in farads, e.g. 5.802e-6", 1e-3),
        "transducer_constant_n_per_v": _pos("T_em in N/V (= C/m), e.g. 46.71", 1e4),
    },
    "hysteresis": {
        "thresholds_v": _Field("floats", 0.0, 1000.0, expect="increasing thresholds in V starting at 0"),
        "weights_f": _Field("floats", expect="weights in F, first one > 0, partial sums > 0"),
        "initial_states_v": _Field("floats", -1000.0, 1000.0, expect="one initial play state in V per threshold"),
    },
    "mechanics": {
        "stiffness_n_per_m": _pos("k_p in N/m, e.g. 2.0e8 (200 N/um)", 1e12),
    },
    "mechanics.modes": {
        "freq_hz": _pos("a modal frequency in Hz", 1e8),
        "damping_ratio": _Field("float", 0.0, 1.0, lo_open=True, expect="a damping ratio in (0, 1]"),
    },
    "creep": {
        "time_constants_s": _Field("floats", 0.0, 1e7, lo_open=True, expect="positive, increasing time constants in s"),
        "capacitances_f": _Field("floats", 0.0, 1e-3, lo_open=True, expect="one positive capacitance in F per time constant"),
    },
    "leakage": {
        "resistance_ohm": _pos("the insulation resistance R_FP in ohm, e.g. 1e9", 1e18),
    },
    "dielectric_absorption": {
        "gain_f": _pos("k_s, the absorbed charge per volt at equilibrium in F, e.g. 1e-6", 1e-2),
        "time_constant_s": _pos("tau, the absorption time constant in s, e.g. 2.0", 1e7),
    },
    "displacement_sensor": {
        "delay_s": _Field("float", -10.0, 10.0,
                          expect="the sensor latency in s within +/-10 s: > 0 lags the drive, < 0 leads it "
                                 "(an acquisition timing offset), 0 = none"),
        "drift_rate_m_per_s": _Field("float", -1e-3, 1e-3, expect="the sensor drift rate in m/s (0 = none)"),
        "drift_curvature_m_per_s2": _Field("float", -1e-3, 1e-3,
                                           expect="the drift's quadratic coefficient in m/s^2 (0 = none)"),
    },
    "gauge_nonlinearity": {
        "coefficient_per_m": _Field("float", -1e5, 1e5, expect="b of the bow x / (1 + b x) in 1/m, e.g. 2000"),
    },
    "gauge": {
        "rest_length_m": _pos("L_rest in m, e.g. 0.018", 1.0),
        "rest_width_m": _pos("W_rest in m, e.g. 0.010", 1.0),
        "gauge_factor": _pos("the gauge factor, e.g. 2.05", 10.0),
        "arm_nominal_ohm": _pos("the nominal arm resistance in ohm, e.g. 350", 1e6),
        "imbalance_w_y_ohm": _Field("float", -10.0, 10.0, expect="the W-Y arm's deviation in ohm (seed: within +/-0.4)"),
        "imbalance_g_b_ohm": _Field("float", -10.0, 10.0, expect="the G-B arm's deviation in ohm (seed: within +/-0.4)"),
        "imbalance_y_g_ohm": _Field("float", -10.0, 10.0, expect="the Y-G arm's deviation in ohm (seed: within +/-0.4)"),
        "imbalance_w_b_ohm": _Field("float", -10.0, 10.0, expect="the W-B arm's deviation in ohm (seed: within +/-0.4)"),
        "modulation_v": _pos("the square-wave amplitude in V, e.g. 2.0", 100.0),
        "modulation_hz": _pos("the modulation frequency in Hz, e.g. 10000", 1e7),
        "amplifier_gain": _pos("the differential amplifier gain, e.g. 300", 1e6),
        "adc_bits": _Field("int", 1, 32, expect="an ADC word length between 1 and 32 bits"),
        "adc_range_v": _pos("the ADC full scale +/- in V, e.g. 2.5", 100.0),
        "adc_rate_hz": _pos("the ADC sample rate in Hz, e.g. 800000", 1e10),
        "samples_per_half_period": _Field("int", 1, 100000, expect="ADC samples averaged per half period, e.g. 40"),
        "demodulation_gain": _pos("the demodulation gain, 2 for a firmware difference of the halves", 10.0),
        "trim_scale": _Field("float", -1e6, 1e6, expect="the firmware scale factor (dimensionless), non-zero"),
        "trim_bias_v": _Field("float", -100.0, 100.0, expect="the firmware bias in V"),
        "dac_range_v": _pos("the DAC full scale +/- in V, e.g. 2.6", 100.0),
        "dac_bits": _Field("int", 1, 32, expect="a DAC word length between 1 and 32 bits"),
        "noise_rms_m": _Field("float", 0.0, 1e-3, expect="the gauge noise referred to displacement, m RMS, >= 0"),
        "calibration_m_per_v": _pos("the serial's calibration in m/V, e.g. 3.077e-6", 1.0),
    },
    # [structure]: M(.) as a modal model or a state-space file (plant/structure.py owns the keys)
    "structure": {k: _Field(kind, lo if lo is not None else -math.inf, hi if hi is not None else math.inf,
                            lo_open=lo_open, expect=expect, required=False)
                  for k, (kind, lo, hi, lo_open, expect) in STRUCTURE_SCHEMA.items()},
}
_SECTIONS_OPTIONAL = {"structure", "creep", "leakage", "dielectric_absorption", "displacement_sensor",
                      "gauge_nonlinearity"}
_TABLE_ARRAYS = {"mechanics": "modes"}


@dataclass(frozen=True)
class Plant:
    """A validated plant: the PZT, its optional creep, and its gauge chain."""

    name: str
    serial: str
    pzt: PZTParams
    gauge: GaugeParams
    source: str = ""
    additions: Additions = Additions()
    structure: object = None   # plant.structure.Structure from [structure], or None (M = k_p with modes)

    @property
    def creep(self):
        return self.pzt.creep


def _check(path, key, field, value):
    return check_value(path, key, field, value, PlantDefinitionError)


def _read_table(path, section, table):
    schema = _SCHEMA[section]
    out = {}
    nested = _TABLE_ARRAYS.get(section)
    for key, value in table.items():
        where = f"{section}.{key}" if section else key
        if section == "" and key in _SCHEMA and isinstance(value, dict):
            continue
        if key == nested:
            continue
        if key not in schema:
            known = ", ".join(sorted(schema))
            raise PlantDefinitionError(path, where, f"unknown key (value {value!r}); known keys here: {known}")
        out[key] = _check(path, where, schema[key], value)
    for key, field in schema.items():
        if field.required and key not in out:
            where = f"{section}.{key}" if section else key
            raise PlantDefinitionError(path, where, f"missing; expected {field.expect}")
    return out


def as_plant(plant, name="plant"):
    """A :class:`Plant` from a Plant or a plant file's path (the library's entry points take either).

    Parameters
    ----------
    plant : Plant or str or path-like
        A loaded plant, or a ``plants/*.toml`` file (loaded with :func:`load_plant`).
    name : str
        The parameter named in the error.

    Raises
    ------
    ArgumentKindError
        If ``plant`` is neither (e.g. a ``PZTParams``, whose Plant carries the gauge too).
    """
    import os
    if isinstance(plant, Plant):
        return plant
    if isinstance(plant, (str, os.PathLike)):
        return load_plant(plant)
    from ..errors import ArgumentKindError
    raise ArgumentKindError(f"{name}: got {type(plant).__name__}; give a Plant (workbench.load_plant(path)) or a "
                            f"plant file's path, e.g. \"plants/p888_51_sn637_creep.toml\"")


def load_plant(path, overrides=None):
    """Load and validate a plant file.

    Parameters
    ----------
    path : str or Path
        A ``plants/*.toml`` file.
    overrides : dict, optional
        ``{"section.key": value}`` (SI) set into the file's values before they are
        validated (``workbench study --set``); the file itself is not modified.

    Returns
    -------
    Plant

    Raises
    ------
    PlantDefinitionError
        On a syntax error, an unknown or missing key, a wrong type or sign, or an
        out-of-range value; the message names the file, key, value and expectation.
    """
    path = Path(path)
    doc = read_toml(path, PlantDefinitionError)
    from .generic import GENERIC_SCHEMA
    from .mirror import FSM_SCHEMA_VERSION
    other = {FSM_SCHEMA_VERSION: "a three-stack mirror file (its stacks are the plant files it names; `workbench "
                                "verify` and `workbench study` take it)",
             GENERIC_SCHEMA: "a generic stack known only by V -> x (`workbench calibrate --plant` takes "
                                          "it)"}.get(doc.get("schema"))
    if other:
        # not "[stacks] unknown section": say what the file is and which file this needs
        raise PlantDefinitionError(path, "schema", f"is {other}; this needs a single-stack PZT plant file, e.g. "
                                                   f"plants/p888_51_sn637.toml")
    for where, value in (overrides or {}).items():
        section, _, key = where.partition(".")
        if not isinstance(doc.get(section), dict):
            raise PlantDefinitionError(path, where, f"--set names section [{section}], which this file lacks")
        doc[section][key] = value

    for key, value in doc.items():
        if isinstance(value, dict) and key not in _SCHEMA:
            known = ", ".join(s for s in _SCHEMA if s and "." not in s)
            raise PlantDefinitionError(path, key, f"unknown section; known sections: {known}")
    top = _read_table(path, "", doc)
    if top["schema"] != SCHEMA_VERSION:
        raise PlantDefinitionError(path, "schema", f"got {top['schema']!r}; expected {SCHEMA_VERSION!r}")
    sections = {}
    for name in ("electrical", "hysteresis", "mechanics", "gauge", "creep", "leakage", "dielectric_absorption",
                 "displacement_sensor", "gauge_nonlinearity", "structure"):
        if name not in doc:
            if name in _SECTIONS_OPTIONAL:
                continue
            raise PlantDefinitionError(path, name, "section missing; see plants/p888_51_sn637.toml for its keys")
        if not isinstance(doc[name], dict):
            raise PlantDefinitionError(path, name, f"must be a table, got {doc[name]!r}")
        sections[name] = _read_table(path, name, doc[name])

    modes_raw = doc["mechanics"].get("modes", [])
    if not isinstance(modes_raw, list):
        raise PlantDefinitionError(path, "mechanics.modes", "must be an array of tables [[mechanics.modes]]")
    modes = tuple(Mode(**_read_table(path, "mechanics.modes", m)) if isinstance(m, dict) else
                  _raise(path, "mechanics.modes", f"entry {m!r} is not a table") for m in modes_raw)

    hy = sections["hysteresis"]
    n = hy["thresholds_v"].size
    for key in ("weights_f", "initial_states_v"):
        if hy[key].size != n:
            raise PlantDefinitionError(path, f"hysteresis.{key}",
                                       f"has {hy[key].size} entries; expected {n}, one per threshold")
    try:
        ch = PrandtlIshlinskii(hy["thresholds_v"], hy["weights_f"], hy["initial_states_v"])
    except ValueError as err:
        raise PlantDefinitionError(path, "hysteresis", f"{err}") from err
    if not ch.states_admissible():
        raise PlantDefinitionError(path, "hysteresis.initial_states_v",
                                   f"got {hy['initial_states_v'].tolist()}; no input history leaves the plays "
                                   f"there (need |z_i - z_j| <= |r_i - r_j|); use zeros for a stack at rest")

    creep = None
    if "creep" in sections:
        cr = sections["creep"]
        if cr["capacitances_f"].size != cr["time_constants_s"].size:
            raise PlantDefinitionError(path, "creep.capacitances_f",
                                       f"has {cr['capacitances_f'].size} entries; expected "
                                       f"{cr['time_constants_s'].size}, one per time constant")
        if np.any(np.diff(cr["time_constants_s"]) <= 0):
            raise PlantDefinitionError(path, "creep.time_constants_s",
                                       f"got {cr['time_constants_s'].tolist()}; expected strictly increasing values")
        creep = CreepParams(cr["time_constants_s"], cr["capacitances_f"])

    el = sections["electrical"]
    if el["voltage_min_v"] >= el["voltage_max_v"]:
        raise PlantDefinitionError(path, "electrical.voltage_min_v", "must be below voltage_max_v")
    pzt = PZTParams(
        series_resistance_ohm=el["series_resistor_ohm"] if el["series_resistor_in"] else 0.0,
        current_limit_source_a=el["current_limit_source_a"],
        current_limit_sink_a=el["current_limit_sink_a"],
        voltage_min_v=el["voltage_min_v"], voltage_max_v=el["voltage_max_v"],
        working_capacitance_f=el["working_capacitance_f"],
        transducer_constant_n_per_v=el["transducer_constant_n_per_v"],
        stiffness_n_per_m=sections["mechanics"]["stiffness_n_per_m"],
        hysteresis=ch, modes=modes, creep=creep)
    g = sections["gauge"]
    if g["trim_scale"] == 0.0:
        raise PlantDefinitionError(path, "gauge.trim_scale", "got 0; expected a non-zero scale factor")
    gauge = GaugeParams(
        rest_length_m=g["rest_length_m"], rest_width_m=g["rest_width_m"], gauge_factor=g["gauge_factor"],
        arm_nominal_ohm=g["arm_nominal_ohm"],
        imbalance_ohm=(g["imbalance_w_y_ohm"], g["imbalance_g_b_ohm"], g["imbalance_y_g_ohm"],
                       g["imbalance_w_b_ohm"]),
        modulation_v=g["modulation_v"], modulation_hz=g["modulation_hz"], amplifier_gain=g["amplifier_gain"],
        adc_bits=g["adc_bits"], adc_range_v=g["adc_range_v"], adc_rate_hz=g["adc_rate_hz"],
        samples_per_half_period=g["samples_per_half_period"], demodulation_gain=g["demodulation_gain"],
        trim_scale=g["trim_scale"], trim_bias_v=g["trim_bias_v"], dac_range_v=g["dac_range_v"],
        dac_bits=g["dac_bits"], noise_rms_m=g["noise_rms_m"], calibration_m_per_v=g["calibration_m_per_v"])
    try:
        gauge.check()
    except ValueError as err:
        raise PlantDefinitionError(path, "gauge", str(err)) from err
    leak = sections.get("leakage", {})
    da = sections.get("dielectric_absorption", {})
    sens = sections.get("displacement_sensor", {})
    additions = Additions(
        leakage_resistance_ohm=leak.get("resistance_ohm"),
        absorption_gain_f=da.get("gain_f"), absorption_time_constant_s=da.get("time_constant_s"),
        sensor_delay_s=sens.get("delay_s", 0.0), sensor_drift_rate_m_per_s=sens.get("drift_rate_m_per_s", 0.0),
        sensor_drift_curvature_m_per_s2=sens.get("drift_curvature_m_per_s2", 0.0),
        gauge_nonlinearity_per_m=sections.get("gauge_nonlinearity", {}).get("coefficient_per_m", 0.0))
    structure = None
    if "structure" in sections:
        if modes:
            raise PlantDefinitionError(path, "structure", "give either [structure] or [[mechanics.modes]]: "
                                       "the structure is the whole M(.), the stack's own modes included")
        structure = structure_from_section(path, sections["structure"], pzt.stiffness_n_per_m)
    return Plant(name=top["name"], serial=top["serial"], pzt=pzt, gauge=gauge, source=str(path),
                 additions=additions, structure=structure)


def _raise(path, key, message):
    raise PlantDefinitionError(path, key, message)


#: The file's sections and their typed, range-checked fields (public name of the one schema).
PLANT_FIELDS = _SCHEMA
