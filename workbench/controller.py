"""The controller: one artifact from design to firmware, read and written in one place.

A :class:`Controller` is what firmware runs: a discrete SISO filter as a scalar gain and
second-order sections (rows ``[b0, b1, b2, 1, a1, a2]``, scipy's convention, see
:mod:`workbench.export.sos`), the output range, the current-limit window (a model of the
stack voltage, v <- v + alpha (u - v), and the command kept within [v - h_down, v + h_up],
see :mod:`workbench.export.fixed_point`), its 32-bit fixed-point words, and where it came
from (the plant file's SHA-256, the serial, the gauge trim and gain it was designed with).

Build one from a python-control model (:meth:`Controller.from_lti`) or load an exported
one (:meth:`Controller.load`, ``.json`` or ``.mat``); write it as NAME.json/.h/.csv/.mat
(:meth:`Controller.write`); run its firmware step (:meth:`Controller.run`, the fixed-point
step bit for bit with the C header); look at it as python-control sees it
(:meth:`Controller.as_lti`). Every command that reads or writes a controller (study,
export, verify, linearize's limit-cycle analysis, selfsense) goes through this module.

Loading validates (:class:`ControllerError` names the file and the key): finite numbers,
six coefficients per section with a0 = 1, a positive sample rate, ordered output limits,
a window with 0 < alpha < 1 and non-negative headroom, every pole of the float and of the
quantized sections strictly inside the unit circle (integrators, poles exactly at z = 1 in
the last section where the output clamp bounds them, excepted) unless ``allow_unstable``,
and fixed-point words that are the float sections quantized (within one LSB).
"""

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import control
import numpy as np

from .errors import ControllerError, ControllerMismatchError
from .export.fixed_point import FixedPointController, quantize, run_fixed, run_float
from .export.sensor import BLEND_KEYS, SENSOR_BLOCK_KEYS, SENSOR_KINDS, STARTUP_FIELDS, SensorBlend, run_sensor
from .export.sos import ExportError, from_sos, to_sos

__all__ = ["Controller", "ControllerError", "ControllerMismatchError", "NO_WINDOW_TEXT", "window_text", "recorded_resistor_out", "X_GAUGE_M", "SensorBlend",
           "SENSOR_KINDS"]

NO_WINDOW_TEXT = "no current-limit window (anti-windup off)"
X_GAUGE_M = 7.5e-6            # the operating point the gauge gain is quoted at (mid-stroke, the seed's x0)
_INTEGRATOR_TOL = 1e-12       # |1 + a1 + a2| of a section built with a pole at z = 1 (fixed_point's rule)
_A0_TOL = 1e-12
_RESERVED = ("gain", "sos", "fixed_point", "sensor")
# Preflight tolerances (relative): the same plant file gives the same numbers to ~1e-15; a
# different serial differs by percents (C_p, calibration), so these separate the two cases.
_RTOL_GAUGE = 1e-3
_RTOL_TRIM = 1e-6
_RTOL_WINDOW = 1e-3


def _sha256(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def plant_provenance(plant):
    """Provenance of a plant as a controller records it: file, SHA-256, serial, trim, gauge gain.

    Parameters
    ----------
    plant : workbench.plant.Plant

    Returns
    -------
    dict
        ``plant_file``, ``plant_sha256`` (of the file's bytes; absent for a plant not read from a file),
        ``serial``, ``trim_scale`` (V/V), ``trim_bias_v`` (V), ``gauge_v_per_m`` (firmware V per m at
        :data:`X_GAUGE_M`, the imbalanced bridge of :func:`workbench.linearize.sampled.gauge_gain_v_per_m`).
    """
    from .linearize.sampled import gauge_gain_v_per_m
    g = plant.gauge
    out = {"plant_file": str(plant.source), "serial": plant.serial, "trim_scale": float(g.trim_scale),
           "trim_bias_v": float(g.trim_bias_v), "gauge_v_per_m": float(gauge_gain_v_per_m(X_GAUGE_M, g))}
    if plant.source and Path(plant.source).is_file():
        out["plant_sha256"] = _sha256(plant.source)
    return out


def plant_window(plant, dt_s):
    """(alpha, h_up, h_down) of the current-limit window for ``plant`` at sample time ``dt_s``.

    With the series resistor in: alpha = 1 - exp(-T / (R C)) with R the series resistor and C
    the largest terminal capacitance, h_up = R I_source, h_down = R I_sink (V). With it out
    (R = 0): alpha = 1 (the model follows the command), h_up = I_source T / C, h_down =
    I_sink T / C, the slew the amplifier can follow in a sample (see
    :func:`workbench.design.antiwindup.current_limit_model`).
    """
    from .design.antiwindup import current_limit_model
    return current_limit_model(plant.pzt, dt_s)


def window_text(model, resistor_out=None):
    """The words for a current-limit window (alpha, h_up, h_down) in a description line.

    ``resistor_out``: whether the window was derived with the series resistor out (R = 0, a slew window of
    I T / C a sample) or in (an RC model, headroom R I); None when not recorded. Decided from the plant's R,
    never from alpha: with R in, alpha = 1 - exp(-T / (R C)) rounds to 1.0 once R C < T / 37 (~0.2 ohm).
    """
    if resistor_out:
        return ("current-limit window +{1:.4g}/-{2:.4g} V a sample around the last output (alpha 1: a slew window, "
                "series resistor out)").format(*model)
    return "current-limit window +{1:g}/-{2:g} V around a stack-voltage model (alpha {0:.4g})".format(*model)


def recorded_resistor_out(anti_windup):
    """Whether an ``anti_windup`` block's window was derived with the series resistor out: True, False, or None.

    :func:`_anti_windup_block` records it with the plant's R: ``voltage_model.slew_v_per_s`` (resistor out:
    the slew I / C the window allows) or ``voltage_model.time_constant_s`` (resistor in: R C). None when the
    block records neither (a window given without a plant, or a file exported before session 38).
    """
    vm = anti_windup.get("voltage_model") if isinstance(anti_windup, dict) else None
    if isinstance(vm, dict):
        if "slew_v_per_s" in vm:
            return True
        if "time_constant_s" in vm:
            return False
    return None


def _anti_windup_block(model, limits, plant=None, resistor_out=None, dt_s=None):
    """The ``anti_windup`` block of the JSON (the conditioned cascade the fixed-point step runs).

    Whether the series resistor is out is the plant's R = 0 (``plant``), else ``resistor_out`` (a controller
    that knows it, with its sample time ``dt_s``); never alpha == 1 (see :func:`window_text`). The block then
    records it (:func:`recorded_resistor_out`).
    """
    if plant is not None and model is not None:
        resistor_out = not plant.pzt.series_resistance_ohm > 0
    block = {"method": "conditioned_cascade",
             "description": "the last (integrator) section's output is clamped to the output limits and to "
                            "[v - headroom_v[1], v + headroom_v[0]], v a model of the stack voltage "
                            "(v += alpha (u - v), the series R and the largest stack capacitance); the clamped "
                            "value drives that section's recursion",
             "output_limits_v": list(limits)}
    if model is not None and resistor_out:
        # the series resistor out (R = 0): alpha = 1, a slew window
        block["description"] = ("the last (integrator) section's output is clamped to the output limits and to "
                                "[v - headroom_v[1], v + headroom_v[0]], v the last clamped output (alpha = 1: "
                                "series resistor out, headroom I T / C with C the largest stack capacitance, the "
                                "slew the current limits allow in a sample); the clamped value drives that "
                                "section's recursion")
    if model is not None:
        block["voltage_model"] = {"alpha": model[0], "headroom_v": list(model[1:])}
        if plant is not None:
            from .design.antiwindup import rate_limits_v_per_s
            pz = plant.pzt
            if pz.series_resistance_ohm > 0:
                block["voltage_model"]["time_constant_s"] = (pz.series_resistance_ohm * pz.current_limit_source_a
                                                             / rate_limits_v_per_s(pz)[0])
            else:
                block["voltage_model"]["slew_v_per_s"] = list(rate_limits_v_per_s(pz))
        elif resistor_out and dt_s is not None:
            block["voltage_model"]["slew_v_per_s"] = [model[1] / dt_s, model[2] / dt_s]
    return block


# ----------------------------------------------------------------------------- validation helpers

def _number(src, key, value, *, positive=False, nonzero=False):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ControllerError(src, key, f"must be a number; got {value!r}")
    v = float(value)
    if not np.isfinite(v):
        raise ControllerError(src, key, f"must be a finite number; got {value!r}")
    if positive and not v > 0:
        raise ControllerError(src, key, f"must be positive; got {v:g}")
    if nonzero and v == 0:
        raise ControllerError(src, key, "must be nonzero (a zero gain is no controller)")
    return v


def _cells(value):
    """The leaves of nested lists/tuples."""
    if isinstance(value, (list, tuple)):
        for v in value:
            yield from _cells(v)
    else:
        yield value


def _array(src, key, value, shape_text, ndim, error=ControllerError):
    """``value`` as a finite float array of ``ndim`` dimensions, else ``error(src, key, message)``."""
    # numbers only: numpy would read the text "0.5" (and true) as a number, while a text gain is refused
    cells = value.ravel().tolist() if isinstance(value, np.ndarray) and value.dtype.kind not in "iuf" else (
        [] if isinstance(value, np.ndarray) else _cells(value))
    for cell in cells:
        if isinstance(cell, bool) or not isinstance(cell, (int, float, np.integer, np.floating)):
            fix = ("save it as a double array in MATLAB, not logical, complex or cell"
                   if isinstance(value, np.ndarray) or str(src).lower().endswith(".mat")
                   else "write the number without quotes")
            raise error(src, key, f"must be {shape_text} of numbers; got {cell!r} in it ({fix})")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise error(src, key, f"must be {shape_text} of numbers; got {str(value)[:80]}") from None
    if arr.ndim != ndim:
        raise error(src, key, f"must be {shape_text}; got an array of shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise error(src, key, f"must hold finite numbers only; got {arr.tolist()}")
    return arr


def _limits(src, key, value):
    lim = _array(src, key, value, "[lo, hi] in V", 1)
    if lim.size != 2:
        raise ControllerError(src, key, f"must be two numbers [lo, hi] in V; got {lim.tolist()}")
    if not lim[0] < lim[1]:
        raise ControllerError(src, key, f"must be ordered lo < hi; got {lim.tolist()} (swap them)")
    return float(lim[0]), float(lim[1])


def _window(src, key, block):
    if not isinstance(block, dict):
        raise ControllerError(src, key, f"must be a table {{alpha, headroom_v: [up, down]}}; got {block!r}")
    alpha = _number(src, f"{key}.alpha", block.get("alpha"))
    if not 0 < alpha <= 1:
        raise ControllerError(src, f"{key}.alpha", f"must lie in (0, 1]: alpha = 1 - exp(-T / (R C)), or 1 with the "
                                                   f"series resistor out; got {alpha:g}")
    head = _array(src, f"{key}.headroom_v", block.get("headroom_v"), "[up, down] in V", 1)
    if head.size != 2 or np.any(head < 0):
        raise ControllerError(src, f"{key}.headroom_v", f"must be two non-negative volts [R I_source, R I_sink] "
                                                        f"(I_source T / C, I_sink T / C with R out); got {head.tolist()}")
    return alpha, float(head[0]), float(head[1])


def _is_integrator(row):
    return abs(1.0 + row[4] + row[5]) <= _INTEGRATOR_TOL


def _section_poles(sos, k):
    """Poles of section k, an exact integrator of the last section left out."""
    row = sos[k]
    poles = np.roots(row[3:]) if np.any(row[4:]) else np.zeros(0)
    if _is_integrator(row) and k == len(sos) - 1:
        poles = poles[np.abs(poles - 1.0) > 1e-6]
    return poles


def _float_radius(sos):
    return max(float(np.max(np.abs(_section_poles(sos, k)), initial=0.0)) for k in range(len(sos)))


def _check_float_poles(src, sos, allow_unstable):
    """Every pole strictly inside the unit circle, integrators (z = 1) in the last section excepted."""
    for k, row in enumerate(sos):
        poles = _section_poles(sos, k)      # the last section's exact integrator is bounded by the clamp
        r = float(np.max(np.abs(poles), initial=0.0))
        if r >= 1.0 and not allow_unstable:
            what = ("an integrator outside the last section (only there do the output limits bound it)"
                    if _is_integrator(row) else f"a pole at |z| = {r:.6g}, on or outside the unit circle")
            raise ControllerError(src, f"sos[{k}]", f"section {k} has {what}; a controller must be stable apart "
                                                    f"from integrators in the last section (for an analysis run "
                                                    f"of an unstable controller give --allow-unstable)")


def _fixed_from_block(src, data, gain, sos, dt):
    """FixedPointController of a JSON ``fixed_point`` block, every word checked."""
    fp = data["fixed_point"]
    key = "fixed_point"
    if not isinstance(fp, dict):
        raise ControllerError(src, key, "must be a table (as write_controller writes it)")
    try:
        secs = fp["sections"]
        if not isinstance(secs, list) or len(secs) != len(sos):
            raise ControllerError(src, f"{key}.sections", f"must list {len(sos)} sections (one per sos row); got "
                                                          f"{len(secs) if isinstance(secs, list) else secs!r}")

        def ints(name, values, n):
            arr = np.asarray(values)
            if arr.shape != (n,) or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                            for v in arr.tolist()):
                raise ControllerError(src, name, f"must be {n} integers; got {values!r}")
            if np.any(np.abs(arr) >= 2 ** 31):
                raise ControllerError(src, name, f"must fit in int32; got {values!r}")
            return arr.astype(np.int64)

        b = np.array([ints(f"{key}.sections[{k}].b", s["b"], 3) for k, s in enumerate(secs)]).reshape(-1, 3)
        a = np.array([ints(f"{key}.sections[{k}].a", s["a"], 2) for k, s in enumerate(secs)]).reshape(-1, 2)
        b_frac = np.array([ints(f"{key}.sections[{k}].b_frac_bits", [s["b_frac_bits"]], 1)[0]
                           for k, s in enumerate(secs)], dtype=np.int64)
        sig = np.array([ints(f"{key}.sections[{k}].signal_frac_bits", [s["signal_frac_bits"]], 1)[0]
                        for k, s in enumerate(secs)], dtype=np.int64)
        integ = np.array([bool(s["integrator"]) for s in secs])
        coeff_bits = int(ints(f"{key}.coeff_bits", [fp["coeff_bits"]], 1)[0])
        if not 8 <= coeff_bits <= 32:
            raise ControllerError(src, f"{key}.coeff_bits", f"must be 8 to 32; got {coeff_bits}")
        if np.any((sig < 0) | (sig > 31)):
            raise ControllerError(src, f"{key}.sections[].signal_frac_bits", f"must lie in 0..31; got {sig.tolist()}")
        inp = fp["input"]
        in_frac = int(ints(f"{key}.input.frac_bits", [inp["frac_bits"]], 1)[0])
        range_v = _number(src, f"{key}.input.range_v", inp["range_v"], positive=True)
        out = fp["output"]
        lim = _limits(src, f"{key}.output.limits_v", out["limits_v"])
        vm = out.get("voltage_model")
        model = None if vm is None else _window(src, f"{key}.output.voltage_model", vm)
        f_max = _number(src, f"{key}.f_max_hz", fp["f_max_hz"], positive=True)
        err_db = _number(src, f"{key}.error_db", fp.get("error_db", 0.0))
        err_deg = _number(src, f"{key}.error_deg", fp.get("error_deg", 0.0))
    except KeyError as exc:
        raise ControllerError(src, f"{key}.{exc.args[0]}", "is missing; re-export the controller "
                                                           "(Controller.write or `workbench study`)") from None
    except TypeError as exc:
        raise ControllerError(src, key, f"is malformed ({exc}); re-export the controller") from None
    try:
        fxp = FixedPointController(gain=gain, sos=sos, dt_s=dt, input_range_v=range_v, output_limits_v=lim,
                                   f_max_hz=f_max, coeff_bits=coeff_bits, b=b, a=a, b_frac_bits=b_frac,
                                   signal_frac_bits=sig, input_frac_bits=in_frac, integrator=integ,
                                   max_pole_radius=0.0, error_db=err_db, error_deg=err_deg, voltage_model=model)
    except ControllerError as exc:     # the object's own checks (the clamp words): the field it names, this file
        raise ControllerError(src, exc.key, exc.detail) from None
    except ValueError as exc:
        raise ControllerError(src, key, str(exc)) from None
    return fxp


def _check_words(src, fxp, allow_unstable):
    """Quantized poles inside the unit circle and words equal to the float sections within one LSB.

    Returns the largest quantized pole radius (integrators excluded), as ``quantize`` reports it.
    """
    f = fxp.a_frac_bits
    lsb_a = 2.0 ** -f
    sos = fxp.sos
    radius = 0.0
    for k in range(len(sos)):
        a1, a2 = fxp.a[k] * lsb_a
        if fxp.integrator[k]:
            if k != len(sos) - 1 or int(fxp.a[k, 0]) != -((1 << f) + int(fxp.a[k, 1])):
                raise ControllerError(src, f"fixed_point.sections[{k}]",
                                      "is flagged as an integrator but its words do not put a pole exactly at "
                                      "z = 1 in the last section (a1 = -(2^F + a2)); re-export the controller")
            poles = [a2] if abs(sos[k, 5] - 1.0) > _INTEGRATOR_TOL else []
        else:
            poles = np.roots([1.0, a1, a2])
        r = float(np.max(np.abs(poles), initial=0.0))
        if r >= 1.0 and not allow_unstable:
            raise ControllerError(src, f"fixed_point.sections[{k}].a",
                                  f"the quantized words put a pole at |z| = {r:.9g}, on or outside the unit circle; "
                                  f"re-export with more coefficient bits or move that pole inward")
        radius = max(radius, r)
    # words against the float design: a within half an LSB, b within one LSB of its own format
    # (a zero kept exactly at z = -1 moves b1 by up to one LSB)
    da = np.abs(fxp.a * lsb_a - sos[:, 4:])
    bad = np.argwhere(da > 0.5 * lsb_a * (1 + 1e-9) + 4 * np.finfo(float).eps)
    if bad.size:
        k, i = bad[0]
        raise ControllerError(src, f"fixed_point.sections[{k}].a",
                              f"a{i + 1} word {int(fxp.a[k, i])} is {da[k, i] / lsb_a:.3g} LSB from the float "
                              f"section's a{i + 1} = {float(sos[k, 4 + i])!r}: the words are not these sections quantized; "
                              f"re-export the controller")
    _, q = fxp.quantized_sos()
    b_real = sos[:, :3].copy()
    b_real[0] *= fxp.gain
    f_prev = np.concatenate(([fxp.input_frac_bits], fxp.signal_frac_bits[:-1]))
    lsb_b = 2.0 ** (f_prev - fxp.signal_frac_bits - fxp.b_frac_bits)
    db = np.abs(q[:, :3] - b_real)
    bad = np.argwhere(db > lsb_b[:, None] * (1 + 1e-9) + 4 * np.finfo(float).eps * np.abs(b_real))
    if bad.size:
        k, i = bad[0]
        with np.errstate(over="ignore", divide="ignore"):
            away = db[k, i] / lsb_b[k]
        raise ControllerError(src, f"fixed_point.sections[{k}].b",
                              f"b{i} word {int(fxp.b[k, i])} implements {float(q[k, i])!r} but the float section (gain "
                              f"folded into section 0) has {float(b_real[k, i])!r}, {away:.3g} LSB away: the "
                              f"words are not these sections quantized; re-export the controller")
    return radius


# ----------------------------------------------------------------------------- the controller

@dataclass(frozen=True, eq=False)
class Controller:
    """A discrete SISO controller as firmware runs it.

    Input: gauge error (reference minus the demodulated reading), firmware volts. Output:
    the commanded PZT voltage, V.

    Attributes
    ----------
    sample_rate_hz : float
        Servo rate, Hz (the gauge modulation rate, 10 kHz for the seed's chain).
    gain : float
        Scalar gain, V/V; the controller is ``gain * prod_k H_k(z)``.
    sos : ndarray of float, shape (n_sections, 6)
        Rows ``[b0, b1, b2, 1, a1, a2]``; poles nearest the unit circle (an integrator) last.
    output_limits_v : (float, float) or None
        Output clamp (lo, hi), V; None: not given (a bare controller without a plant).
    voltage_model : (float, float, float) or None
        Current-limit window (alpha, h_up_v, h_down_v): v <- v + alpha (u - v) models the stack
        voltage (alpha = 1 - exp(-T / (R C)), C the largest stack capacitance) and u is kept within
        [v - h_down, v + h_up] (h = R I_source, R I_sink); with the series resistor out, alpha = 1
        and h = I_source T / C, I_sink T / C (a slew window). None: no window (anti-windup off).
    window_source : str
        ``"file"`` (the window was in the file or given), ``"plant"`` (derived from the plant on
        load: a bare controller) or ``"none"``.
    series_resistor_out : bool or None
        Whether the window was derived with the series resistor out (R = 0: a slew window) or in;
        from the plant's R, or what the file records (:func:`recorded_resistor_out`); None when not
        known. Never read from alpha (with R in, alpha rounds to 1.0 below ~0.2 ohm).
    fixed : FixedPointController or None
        The 32-bit words of the C header (None: a float-only controller).
    provenance : dict
        ``plant_file``, ``plant_sha256``, ``serial``, ``trim_scale``, ``trim_bias_v`` and
        ``gauge_v_per_m`` of the plant it was designed for (keys absent when unknown).
    record : dict
        Everything else of the JSON (name, method, margins, notes...), written back as given.
    hanus : HanusController or None
        A Hanus realization declared in the ``anti_windup`` block (``--form hanus``), else None.
    source : str
        The file it was loaded from ("" when built in memory).
    max_pole_radius : float
        Largest |z| of the poles (quantized ones when there are words), integrators excluded.
    sensor : SensorBlend or None
        The sensor block (:mod:`workbench.export.sensor`): which reading the loop closes on
        (gauge, charge estimate or their complementary blend) and the blend's words. None: a
        gauge controller as before (input: the gauge error in firmware V).
    """

    sample_rate_hz: float
    gain: float
    sos: np.ndarray
    output_limits_v: tuple | None = None
    voltage_model: tuple | None = None
    window_source: str = "none"
    fixed: FixedPointController | None = None
    provenance: dict = field(default_factory=dict)
    record: dict = field(default_factory=dict)
    hanus: object = None
    source: str = ""
    max_pole_radius: float = 0.0
    sensor: SensorBlend | None = None
    series_resistor_out: bool | None = None

    def __post_init__(self):
        self.sos.flags.writeable = False

    def __repr__(self):
        where = f" from {self.source}" if self.source else ""
        return f"Controller({self.name!r}{where}: {self.describe()})"

    # ------------------------------------------------------------------ views
    @property
    def dt_s(self):
        """Sample time, s."""
        return 1.0 / self.sample_rate_hz

    @property
    def name(self):
        """The record's ``name`` (file stem and C prefix), or "controller"."""
        return str(self.record.get("name") or "controller")

    @property
    def has_window(self):
        """Whether the current-limit window (anti-windup on the current limits) is part of the controller."""
        return self.voltage_model is not None

    def describe(self):
        """One line: form, output range and window (says "no current-limit window (anti-windup off)")."""
        form = "32-bit fixed-point cascade" if self.fixed is not None else "float cascade"
        lim = ("no output limits" if self.output_limits_v is None
               else f"output {self.output_limits_v[0]:g}..{self.output_limits_v[1]:g} V")
        if self.voltage_model is None:
            win = NO_WINDOW_TEXT
        else:
            win = window_text(self.voltage_model, self.series_resistor_out)
            if self.window_source == "plant":
                win += ", derived from the plant (the file has none)"
        n = len(self.sos)
        sens = ""
        if self.sensor is not None:
            sens = {"gauge": ", closes on the gauge", "charge": ", closes on the charge estimate"}.get(
                self.sensor.kind) or f", closes on the gauge + charge blend at {self.sensor.crossover_hz:.4g} Hz"
        return f"{form}, {n} section{'s' if n > 1 else ''} at {self.sample_rate_hz:g} Hz, {lim}, {win}{sens}"

    @property
    def sensor_kind(self):
        """"gauge", "charge" or "fused": the reading the loop closes on ("gauge" without a sensor block)."""
        return "gauge" if self.sensor is None else self.sensor.kind

    def with_sensor(self, kind, crossover_hz=None, *, v_per_m=None, lsb_m=1e-12):
        """This controller with a sensor block: the loop closes on ``kind``'s reading.

        Parameters
        ----------
        kind : {"gauge", "charge", "fused"}
            The gauge reading, the compensated charge estimate, or their complementary blend
            (:class:`workbench.selfsense.fusion.Blend`: the gauge below ``crossover_hz``).
        crossover_hz : float, optional
            Blend crossover, Hz ("fused" only; positive, below the Nyquist frequency).
        v_per_m : float, optional
            Firmware V of error per metre (default: the gauge gain of the provenance, ``gauge_v_per_m``,
            the gain the cascade was designed with).
        lsb_m : float, default 1e-12
            Metres per count of the firmware step's int32 inputs.

        Returns
        -------
        Controller
            A new controller; the cascade and its words are unchanged.

        Raises
        ------
        ControllerError
            A bad kind or crossover, no words (a float-only controller), or no gain to scale the error.
        """
        if v_per_m is None:
            v_per_m = self.provenance.get("gauge_v_per_m")
            if v_per_m is None:
                raise ControllerError(self.source, "sensor.v_per_m", "is needed: the controller records no gauge "
                                                                     "gain (gauge_chain.volts_per_meter); pass v_per_m=")
        if self.fixed is None:
            raise ControllerError(self.source, "sensor", "needs the fixed-point words (the sensor step runs the "
                                                         "fixed-point cascade); build it with Controller.from_lti")
        try:
            sb = SensorBlend(kind=kind, crossover_hz=None if crossover_hz is None else float(crossover_hz),
                             dt_s=self.dt_s, v_per_m=float(v_per_m), lsb_m=float(lsb_m))
            sb.error_scale(self.fixed.input_frac_bits)
        except (TypeError, ValueError) as exc:
            raise ControllerError(self.source, "sensor", str(exc)) from None
        return replace(self, sensor=sb)

    def run_sensors(self, ref_m, gauge_m, charge_m=None, u0_v=0.0, y0=None):
        """The firmware step with its sensor block over records in metres: NAME_sensor_step bit for bit.

        Each input is rounded to counts of ``sensor.lsb_m`` as firmware receives them; a controller
        without a sensor block runs as a gauge controller (the error scaled by its gauge gain).

        Parameters
        ----------
        ref_m, gauge_m, charge_m : array_like of float
            Reference, gauge reading and charge estimate per sample, m (``charge_m`` may be omitted
            for a gauge controller).
        u0_v : float, default 0
            Output at rest before the first sample, V.
        y0 : int, optional
            Blend state before the first sample (default: the first gauge - charge difference).

        Returns
        -------
        u_v : ndarray of float
            Commanded PZT voltage per sample, V.
        fused_m : ndarray of float
            The reading the cascade closed on, m (counts times lsb_m).
        """
        sb = self.sensor if self.sensor is not None else self.with_sensor("gauge").sensor
        g = sb.counts(gauge_m)
        c = np.zeros_like(g) if charge_m is None else sb.counts(charge_m)
        if charge_m is None and sb.kind != "gauge":
            raise ValueError(f"a {sb.kind!r} controller needs the charge estimate (charge_m)")
        u, f, _ = run_sensor(sb, self._words(), sb.counts(ref_m), g, c, u0_v=u0_v, y0=y0)
        return u, f * sb.lsb_m

    def as_lti(self, quantized=False):
        """The linear controller (no limits, no window) as a python-control StateSpace.

        A StateSpace, not a TransferFunction: products with the plant's state-space models
        stay well conditioned (a TransferFunction times the SN637 plant loses the loop's
        margins to polynomial rounding near z = 1).

        Parameters
        ----------
        quantized : bool, default False
            True: the transfer function the fixed-point words implement (rounding aside).

        Returns
        -------
        control.StateSpace
            Discrete, sample time :attr:`dt_s`; firmware volts of error in, V out.
        """
        if quantized:
            if self.fixed is None:
                raise ExportError("this controller has no fixed-point words; quantize it with Controller.from_lti "
                                  "or load an exported JSON")
            return control.ss(from_sos(*self.fixed.quantized_sos(), self.dt_s))
        return control.ss(from_sos(self.gain, self.sos, self.dt_s))

    def run(self, e_v, form=None, u0_v=0.0):
        """The firmware step over a record of errors: what NAME.h computes, sample by sample.

        Parameters
        ----------
        e_v : array_like of float
            Gauge error per sample, firmware V.
        form : {"fixed", "float"}, optional
            Default: "fixed" when there are words (bit for bit NAME_fixed_step), else "float"
            (NAME_float_step: double precision, output limits and window).
        u0_v : float, default 0
            Output at rest before the first sample, V.

        Returns
        -------
        ndarray of float
            Commanded PZT voltage per sample, V.
        """
        form = form or ("fixed" if self.fixed is not None else "float")
        if form == "fixed":
            if self.fixed is None:
                raise ExportError("no fixed-point words to run; use form='float'")
            return run_fixed(self.fixed, e_v, u0_v)
        if form != "float":
            raise ValueError(f"form must be 'fixed' or 'float'; got {form!r}")
        return run_float(self.gain, self.sos, e_v, output_limits_v=self.output_limits_v,
                         voltage_model=self.voltage_model, u0_v=u0_v)

    def firmware(self, form=None):
        """The kernel-ready form the closed-loop simulation runs (:class:`workbench.verify.closed_loop.FirmwareController`).

        ``form`` None: "fixed" with words, else "hanus" when a Hanus realization is declared,
        else "float".
        """
        from .verify.closed_loop import FirmwareController
        if self.output_limits_v is None:
            raise ControllerError(self.source, "output_limits_v", "is missing: a controller run in closed loop "
                                                                 "needs its output range; load it with the plant "
                                                                 "(the amplifier's range is taken) or add the key")
        if form is None:
            form = "fixed" if self.fixed is not None else "hanus" if self.hanus is not None else "float"
        sb = self.sensor            # firmware's reference lead and gauge linearization, when its block carries them
        fw = {"ref_lead_s": 0.0 if sb is None or sb.ref_lead_s is None else sb.ref_lead_s,
              "gauge_curvature_per_m": 0.0 if sb is None or sb.gauge_curvature_per_m is None
              else sb.gauge_curvature_per_m, "series_resistor_out": self.series_resistor_out}
        if form == "fixed":
            if self.fixed is None:
                raise ControllerError(self.source, "fixed_point", "is missing: there are no words to run; drop "
                                                                  "--form fixed or export the controller")
            return FirmwareController("fixed", self.dt_s, self.fixed.output_limits_v, self.fixed.voltage_model,
                                      gain=self.gain, sos=np.array(self.sos), fixed=self.fixed, **fw)
        if form == "hanus":
            if self.hanus is None:
                raise ControllerError(self.source, "anti_windup", "has no Hanus realization (method 'hanus'); "
                                                                  "drop --form hanus")
            h = replace(self.hanus, output_limits_v=self.output_limits_v)
            return FirmwareController("hanus", self.dt_s, self.output_limits_v, self.voltage_model, hanus=h, **fw)
        if form != "float":
            raise ValueError(f"unknown controller form {form!r}; known: fixed, float, hanus")
        return FirmwareController("float", self.dt_s, self.output_limits_v, self.voltage_model, gain=self.gain,
                                  sos=np.array(self.sos), **fw)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_lti(cls, K, plant=None, *, dt_s=None, output_limits_v=None, input_range_v=None, f_max_hz=None,
                 coeff_bits=32, window=True, name="controller", method="python-control model", record=None):
        """A firmware controller from a python-control LTI model, the window derived from the plant.

        Parameters
        ----------
        K : control.TransferFunction or control.StateSpace
            SISO controller, firmware V of gauge error in, V out. Continuous-time models are
            discretized by Tustin at the sample time.
        plant : workbench.plant.Plant, optional
            Supplies the sample time (the gauge period), the output limits (the amplifier's
            voltage range), the input range (the gauge DAC range), the current-limit window
            (R, the largest stack capacitance, I_source and I_sink) and the provenance.
        dt_s : float, optional
            Sample time, s (default: the plant's gauge period, or K's own for a discrete K).
        output_limits_v : (float, float), optional
            Output clamp, V (default: the plant's voltage range).
        input_range_v : float, optional
            Input clamp of the fixed-point words, +/- V (default: the plant's gauge DAC range).
        f_max_hz : float, optional
            Band where the quantized response is checked (default 0.4 x the sample rate).
        coeff_bits : int, default 32
        window : bool, default True
            Derive the current-limit window from the plant (False, or no plant: none).
        name, method : str
            Recorded in the JSON (``name`` is also the file stem and C prefix on write).
        record : dict, optional
            More keys for the JSON (notes, margins...).

        Returns
        -------
        Controller
            With fixed-point words (:func:`workbench.export.quantize`).

        Raises
        ------
        ExportError
            Not SISO, improper, a sample time that differs from the plant's, or a quantization
            that misses its error bounds (the message says what to change).
        """
        if not isinstance(K, (control.TransferFunction, control.StateSpace)):
            raise TypeError(f"expected a python-control TransferFunction or StateSpace, got {type(K).__name__}")
        plant_dt = None if plant is None else float(plant.gauge.period_s)
        if control.isdtime(K, strict=True):
            dt = float(K.dt) if K.dt is not True else (dt_s or plant_dt)
        else:
            dt = dt_s or plant_dt
            if dt is None:
                raise ExportError("a continuous-time controller needs a sample time: pass plant= or dt_s=")
            K = control.sample_system(K, dt, method="tustin")
        if dt is None or not dt > 0:
            raise ExportError(f"the sample time must be positive; got {dt}")
        if plant_dt is not None and abs(dt - plant_dt) > 1e-9 * plant_dt:
            raise ExportError(f"the controller samples at {1 / dt:g} Hz but the plant's servo rate is "
                              f"{1 / plant_dt:g} Hz ({plant.source}); discretize at dt = {plant_dt:g} s")
        gain, sos = to_sos(K)
        if output_limits_v is None:
            if plant is None:
                raise ExportError("output_limits_v is needed without a plant (the amplifier's range, V)")
            output_limits_v = (plant.pzt.voltage_min_v, plant.pzt.voltage_max_v)
        lim = (float(output_limits_v[0]), float(output_limits_v[1]))
        if input_range_v is None:
            if plant is None:
                raise ExportError("input_range_v is needed without a plant (the gauge DAC range, firmware V)")
            input_range_v = float(plant.gauge.dac_range_v)
        model = plant_window(plant, dt) if (window and plant is not None) else None
        fxp = quantize(gain, sos, dt, input_range_v=input_range_v, output_limits_v=lim,
                       f_max_hz=f_max_hz or 0.4 / dt, coeff_bits=coeff_bits, voltage_model=model)
        prov = plant_provenance(plant) if plant is not None else {}
        rec = {"name": name, "method": method, "sample_rate_hz": 1.0 / dt,
               "input": {"signal": "gauge_error", "units": "V"}, "output": {"signal": "pzt_voltage", "units": "V"},
               "output_limits_v": list(lim), **(record or {})}
        if prov:
            rec["gauge_chain"] = {"volts_per_meter": prov["gauge_v_per_m"],
                                  "trim": {"scale": prov["trim_scale"], "bias_v": prov["trim_bias_v"]}}
            rec["provenance"] = {k: prov[k] for k in ("plant_file", "plant_sha256", "serial") if k in prov}
        rec["anti_windup"] = _anti_windup_block(model, lim, plant)
        return cls(sample_rate_hz=1.0 / dt, gain=fxp.gain, sos=np.array(fxp.sos), output_limits_v=lim,
                   voltage_model=model, window_source="file" if model else "none", fixed=fxp, provenance=prov,
                   record=rec, max_pole_radius=fxp.max_pole_radius,
                   series_resistor_out=None if model is None else not plant.pzt.series_resistance_ohm > 0)

    @classmethod
    def from_dict(cls, data, *, source="", plant=None, allow_unstable=False):
        """A controller from its JSON form (an exported controller, or a bare ``{sample_rate_hz, gain, sos}``).

        Parameters
        ----------
        data : dict
            The JSON object.
        source : str
            File name for messages.
        plant : workbench.plant.Plant, optional
            For a controller that names no output limits or window: the amplifier's range is
            taken and the window derived from the plant (:attr:`window_source` = "plant").
        allow_unstable : bool, default False
            Accept poles on or outside the unit circle (analysis runs only).

        Returns
        -------
        Controller

        Raises
        ------
        ControllerError
            Naming ``source`` and the key: see the module docstring for what is checked.
        """
        src = source or "<controller>"
        if not isinstance(data, dict):
            raise ControllerError(src, "", f"a controller JSON is an object {{sample_rate_hz, gain, sos, ...}}; "
                                           f"got {type(data).__name__}")
        from .export.mimo import MIMO_SCHEMA
        if data.get("schema") == MIMO_SCHEMA:
            raise ControllerError(src, "schema", f"is a MIMO mirror controller ({MIMO_SCHEMA!r}: three axes, three "
                                                 f"stacks); this needs a single-stack controller (sample_rate_hz, gain, "
                                                 f"sos), e.g. controllers/sn637_loopshape.json; run the mirror with "
                                                 f"`workbench verify plants/fsm_p888_51.toml --controller {src}`")
        if "sample_rate_hz" not in data:
            raise ControllerError(src, "sample_rate_hz", "is missing: the servo rate in Hz (e.g. 10000.0)")
        fs = _number(src, "sample_rate_hz", data["sample_rate_hz"], positive=True)
        if "sos" not in data:
            raise ControllerError(src, "sos", "is missing: rows [b0, b1, b2, 1, a1, a2] (scipy's convention)")
        gain = _number(src, "gain", data.get("gain", 1.0), nonzero=True)
        sos = _array(src, "sos", data["sos"], "rows [b0, b1, b2, 1, a1, a2]", 2)
        if sos.shape[1] != 6 or sos.shape[0] == 0:
            raise ControllerError(src, "sos", f"must be rows of six coefficients [b0, b1, b2, 1, a1, a2]; got shape "
                                              f"{sos.shape}")
        off = np.flatnonzero(np.abs(sos[:, 3] - 1.0) > _A0_TOL)
        if off.size:
            k = off[0]
            raise ControllerError(src, f"sos[{k}]", f"a0 = {float(sos[k, 3])!r}, must be 1: divide the row by a0 (scipy's "
                                                    f"sos rows are normalized)")
        zero = np.flatnonzero(np.all(sos[:, :3] == 0, axis=1))
        if zero.size:
            raise ControllerError(src, f"sos[{zero[0]}]", "has an all-zero numerator: the controller is zero")
        _check_float_poles(src, sos, allow_unstable)
        aw = data.get("anti_windup") or {}
        if not isinstance(aw, dict):
            raise ControllerError(src, "anti_windup", f"must be a table; got {aw!r}")
        limits = None
        for key, value in (("output_limits_v", data.get("output_limits_v")),
                           ("anti_windup.output_limits_v", aw.get("output_limits_v"))):
            if value is not None:
                got = _limits(src, key, value)
                if limits is not None and got != limits:
                    raise ControllerError(src, key, f"{list(got)} differs from output_limits_v {list(limits)}")
                limits = got
        model = None if aw.get("voltage_model") is None else _window(src, "anti_windup.voltage_model",
                                                                     aw["voltage_model"])
        fxp, radius = None, None
        if "fixed_point" in data:
            fxp = _fixed_from_block(src, data, gain, sos, 1.0 / fs)
            if limits is not None and fxp.output_limits_v != limits:
                raise ControllerError(src, "fixed_point.output.limits_v", f"{list(fxp.output_limits_v)} differs "
                                                                          f"from output_limits_v {list(limits)}")
            limits = fxp.output_limits_v
            if model is not None and fxp.voltage_model is not None and not np.allclose(model, fxp.voltage_model):
                raise ControllerError(src, "fixed_point.output.voltage_model",
                                      f"{fxp.voltage_model} differs from anti_windup.voltage_model {model}")
            if model is not None and fxp.voltage_model is None:
                raise ControllerError(src, "fixed_point.output.voltage_model",
                                      "is missing while anti_windup declares a window: the words would run "
                                      "without it; re-export the controller")
            model = fxp.voltage_model
            radius = _check_words(src, fxp, allow_unstable)
            fxp = replace(fxp, max_pole_radius=radius)
        hanus = None
        if aw.get("method") == "hanus":
            hanus = _hanus(src, aw, 1.0 / fs, limits)
        window_source = "file" if model is not None else "none"
        resistor_out = recorded_resistor_out(aw) if model is not None else None
        if plant is not None:
            if limits is None:
                limits = (float(plant.pzt.voltage_min_v), float(plant.pzt.voltage_max_v))
            if model is None and fxp is None:
                model = plant_window(plant, 1.0 / fs)
                window_source = "plant" if model is not None else "none"
                resistor_out = None if model is None else not plant.pzt.series_resistance_ohm > 0
            elif model is None:
                # words without a window: the limit words derive from the float window, so the
                # plant's can be attached; the run says so
                model = plant_window(plant, 1.0 / fs)
                if model is not None:
                    window_source = "plant"
                    resistor_out = not plant.pzt.series_resistance_ohm > 0
                    fxp = replace(fxp, voltage_model=model)
        if radius is None:
            radius = _float_radius(sos)
        if plant is not None and limits is not None:
            _check_not_bang_bang(src, gain, sos, fs, limits, plant)
        prov = _provenance_of(data)
        record = {k: v for k, v in data.items() if k not in _RESERVED}
        sensor = _sensor_from_block(src, data, fs, fxp)
        return cls(sample_rate_hz=fs, gain=gain, sos=sos, output_limits_v=limits, voltage_model=model,
                   window_source=window_source, fixed=fxp, provenance=prov, record=record, hanus=hanus,
                   source=str(source), max_pole_radius=float(radius), sensor=sensor,
                   series_resistor_out=resistor_out)

    @classmethod
    def load(cls, path, *, plant=None, allow_unstable=False):
        """Load and validate an exported controller (``.json`` or ``.mat``).

        Parameters
        ----------
        path : str or Path
        plant : workbench.plant.Plant, optional
            See :meth:`from_dict` (fills the output range and window of a bare controller).
        allow_unstable : bool, default False

        Returns
        -------
        Controller

        Raises
        ------
        ControllerError
            The file cannot be read, is not JSON/MAT, or is not a valid controller; the
            message names the file and the key.
        """
        path = Path(path)
        if path.suffix.lower() == ".mat":
            data = _read_mat(path)
        else:
            try:
                text = path.read_bytes().decode("utf-8")
            except OSError as exc:
                raise ControllerError(path, "", f"cannot be read ({exc.strerror or exc}); give an exported "
                                                f"controller, e.g. controllers/sn637_loopshape.json") from None
            except UnicodeDecodeError:
                raise ControllerError(path, "", "is not UTF-8 text; give an exported controller .json or .mat") \
                    from None
            try:
                data = json.loads(text)
            except json.JSONDecodeError as exc:
                raise ControllerError(path, "", f"line {exc.lineno}: not JSON ({exc.msg}); give an exported "
                                                                  f"controller .json or .mat") from None
        return cls.from_dict(data, source=str(path), plant=plant, allow_unstable=allow_unstable)

    # ------------------------------------------------------------------ writers
    def to_dict(self):
        """The JSON form (what NAME.json holds): the record, ``gain``, ``sos`` and the ``fixed_point`` block."""
        from .export.writers import controller_json
        return json.loads(controller_json(self._record_out(), self._words()))

    def _words(self):
        if self.fixed is None:
            raise ExportError(f"{self.source or self.name}: a float-only controller has no fixed-point words to "
                              f"write; build it with Controller.from_lti(K, plant) to quantize it")
        return self.fixed

    def _record_out(self):
        rec = dict(self.record)
        if self.window_source == "plant" and self.voltage_model is not None:
            lim = self.output_limits_v
            rec["anti_windup"] = {**_anti_windup_block(self.voltage_model, lim, resistor_out=self.series_resistor_out,
                                                       dt_s=self.dt_s),
                                  "window_source": "derived from the plant on load"}
        if self.sensor is not None:
            rec["sensor"] = self.sensor.as_dict(self._words().input_frac_bits)
        return rec

    def write(self, out_dir, name=None):
        """Write NAME.json, NAME.h, NAME.csv and NAME.mat (each atomically; the .mat carries the window).

        Parameters
        ----------
        out_dir : str or Path
        name : str, optional
            File stem and C prefix (default: the record's ``name``).

        Returns
        -------
        dict of Path
            Keys ``"json"``, ``"h"``, ``"csv"``, ``"mat"``.
        """
        from .export.writers import write_controller
        name = name or self.name
        rec = {**self._record_out(), "name": name}
        return write_controller(out_dir, name, rec, self._words(), sensor=self.sensor)

    # ------------------------------------------------------------------ against a plant
    def check_firmware_settings(self, plant):
        """Refuse sensor-block settings that would serve ``plant`` worse than carrying none.

        The sensor block may carry firmware's gauge curvature beta and reference lead 1/K_v
        (:class:`~workbench.export.sensor.SensorBlend`). On ``plant``:

        - a reading x = x_c + u read linearly is off by beta_p u^2 (beta_p of eq. 27,
          :func:`workbench.plant.gauge.bridge_curvature_per_m`); taking out beta leaves
          (beta_p - beta) u^2, worse than the linear calibration when |beta_p - beta| > |beta_p|;
        - a type-1 loop follows a ramp of slope v with the lag v / K_v (K_v of this controller on
          this plant, :func:`workbench.verify.sensors.velocity_constant_per_s`); a lead lambda / K_v
          leaves v (1 - lambda) / K_v, worse than no lead when lambda > 2.

        A value within these bounds but not the plant's own (another serial) is a mismatch of
        :meth:`compare_plant`, not an error.

        Raises
        ------
        ControllerMismatchError
            Naming the controller file, the key, the plant's value and the fix.
        """
        sb = self.sensor
        if sb is None:
            return
        from .plant.gauge import bridge_curvature_per_m
        beta = sb.gauge_curvature_per_m
        if beta is not None and beta != 0.0:
            bp = float(bridge_curvature_per_m(plant.gauge))
            if not abs(bp - beta) <= abs(bp):
                raise ControllerMismatchError(
                    f"{self.source}: [sensor.gauge_curvature_per_m] {beta:.6g} 1/m: the bridge of {plant.source} "
                    f"curves by {bp:.6g} 1/m (eq. 27); taking out {beta:.6g} leaves {bp - beta:.3g} 1/m, more than "
                    f"the linear calibration's {bp:.3g} 1/m: give a value in [{min(0.0, 2 * bp):.4g}, "
                    f"{max(0.0, 2 * bp):.4g}] 1/m ({bp:.6g} for this plant), 0 or drop the key")
        lead = sb.ref_lead_s
        if lead is not None and lead > 0.0 and self.fixed is not None:
            from .verify.sensors import velocity_constant_per_s
            kv = velocity_constant_per_s(self, sb, plant)
            if kv is not None and lead * kv > 2.0:
                raise ControllerMismatchError(
                    f"{self.source}: [sensor.ref_lead_s] {lead:.6g} s is {lead * kv:.3g} times 1/K_v = {1 / kv:.6g} s "
                    f"of this loop on {plant.source}: a lead over 2/K_v = {2 / kv:.6g} s leaves a larger ramp error "
                    f"than no lead; give {1 / kv:.6g} s, 0 or drop the key")

    def compare_plant(self, plant):
        """Where this controller and ``plant`` disagree (the verify preflight).

        Compared: the plant file's SHA-256 with the provenance, the serial, the gauge trim
        (relative 1e-6), the gauge gain at 7.5 um (relative 1e-3), the output limits with the
        amplifier's voltage range, and the current-limit window with the one the plant's R,
        largest capacitance and current limits give (relative 1e-3). Fixed-point words without a
        window on a plant with the series resistor out are a mismatch although a window derived
        from the plant is attached (:attr:`window_source` "plant"): the firmware built from the
        header has none and winds up while the amplifier slews.

        Parameters
        ----------
        plant : workbench.plant.Plant

        Returns
        -------
        list of dict
            ``{"check", "message"}`` per mismatch; items that the controller does not record
            are listed with ``"check": "not recorded"`` (information, not mismatches).
        """
        here = plant_provenance(plant)
        prov = self.provenance
        out, unknown = [], []

        def bad(check, message):
            out.append({"check": check, "message": message})

        if "plant_sha256" in prov and "plant_sha256" in here:
            if prov["plant_sha256"] != here["plant_sha256"]:
                bad("plant_sha256", f"exported for {prov.get('plant_file', 'another plant file')} (SHA-256 "
                                    f"{prov['plant_sha256'][:12]}...), running on {plant.source} "
                                    f"({here['plant_sha256'][:12]}...)")
        else:
            unknown.append("plant SHA-256")
        if "serial" in prov:
            if str(prov["serial"]) != plant.serial:
                bad("serial", f"designed for serial {prov['serial']}, the plant is {plant.serial}")
        else:
            unknown.append("serial")
        for key, label in (("trim_scale", "trim scale"), ("trim_bias_v", "trim bias (V)")):
            if key in prov:
                if not np.isclose(prov[key], here[key], rtol=_RTOL_TRIM, atol=1e-12):
                    bad(key, f"{label} {prov[key]:.7g} in the controller, {here[key]:.7g} in {plant.source}: "
                             f"firmware would scale the reading differently")
            else:
                unknown.append(label)
        if "gauge_v_per_m" in prov:
            ratio = here["gauge_v_per_m"] / prov["gauge_v_per_m"]
            if abs(ratio - 1) > _RTOL_GAUGE:
                bad("gauge_v_per_m", f"gauge gain {prov['gauge_v_per_m']:.6g} V/m at design, {here['gauge_v_per_m']:.6g} "
                                     f"V/m on this plant ({(ratio - 1) * 100:+.2f} % loop gain)")
        else:
            unknown.append("gauge gain")
        amp = (float(plant.pzt.voltage_min_v), float(plant.pzt.voltage_max_v))
        if self.output_limits_v is not None and not np.allclose(self.output_limits_v, amp, rtol=1e-9, atol=1e-9):
            lo, hi = self.output_limits_v
            beyond = lo < amp[0] or hi > amp[1]
            bad("output_limits_v", f"output limits {lo:g}..{hi:g} V, the amplifier's range {amp[0]:g}..{amp[1]:g} V"
                                   + (" (the controller asks for more than the amplifier gives)" if beyond else ""))
        want = plant_window(plant, self.dt_s)
        pz = plant.pzt
        via = (f"through {pz.series_resistance_ohm:g} ohm" if pz.series_resistance_ohm > 0 else
               "with the series resistor out, a slew of I T / C a sample")
        if want is None:
            if self.voltage_model is not None:
                bad("window", "a current-limit window in the controller, but the plant's amplifier has no current "
                              "limit: export without a window for this plant")
        elif self.voltage_model is None:
            bad("window", f"{NO_WINDOW_TEXT}; the plant's current limits ({pz.current_limit_source_a * 1e3:g}"
                          f"/-{pz.current_limit_sink_a * 1e3:g} mA {via}) give a window of +{want[1]:.4g}/-{want[2]:.4g} "
                          f"V, alpha {want[0]:.4g}" + ("" if pz.series_resistance_ohm > 0 else
                                                       "; re-export the controller with this plant"))
        elif self.window_source == "plant" and self.fixed is not None and not pz.series_resistance_ohm > 0:
            # words without a window (an R-out export before session 38): verify attaches the plant's window, but
            # the C header's step has none (headroom 2^40 words) and winds up while the amplifier slews
            bad("window", f"this controller's firmware has no current-limit window; verify runs it with the plant's "
                          f"window (+{want[1]:.4g}/-{want[2]:.4g} V a sample, series resistor out), the firmware "
                          f"built from its header would wind up: re-export it with this plant")
        elif self.window_source != "plant" and not np.allclose(self.voltage_model, want, rtol=_RTOL_WINDOW, atol=0):
            a, hu, hd = self.voltage_model
            bad("window", f"current-limit window +{hu:.4g}/-{hd:.4g} V, alpha {a:.4g} in the controller; the plant's "
                          f"R = {pz.series_resistance_ohm:g} ohm, I = +{pz.current_limit_source_a * 1e3:g}"
                          f"/-{pz.current_limit_sink_a * 1e3:g} mA and largest capacitance give "
                          f"+{want[1]:.4g}/-{want[2]:.4g} V, alpha {want[0]:.4g}")
        if unknown:
            out.append({"check": "not recorded", "message": "the controller does not record its "
                                                            + ", ".join(unknown) + ": not compared"})
        return out


def _sensor_from_block(src, data, fs, fxp):
    """The SensorBlend of a JSON ``sensor`` block (None without one), every value and word checked."""
    if data.get("sensor") is None:
        return None
    block = data["sensor"]
    if fxp is None:
        raise ControllerError(src, "sensor", "needs the fixed_point block: the sensor step runs the fixed-point "
                                             "cascade; re-export the controller")
    if not isinstance(block, dict):
        raise ControllerError(src, "sensor", f"must be a table {{kind, crossover_hz, v_per_m, ...}}; got {block!r}")
    if block.get("kind") not in SENSOR_KINDS:
        raise ControllerError(src, "sensor.kind", f"must be one of {', '.join(SENSOR_KINDS)}; got "
                                                  f"{block.get('kind')!r}")
    # a misspelt key (startup_wait_ms) would drop firmware's setting without a word: every key is known
    unknown = [k for k in block if k not in SENSOR_BLOCK_KEYS]
    if unknown:
        raise ControllerError(src, f"sensor.{unknown[0]}", f"unknown key; the sensor block's keys are "
                                                           f"{', '.join(SENSOR_BLOCK_KEYS)}")
    if isinstance(block.get("blend"), dict):
        unknown = [k for k in block["blend"] if k not in BLEND_KEYS]
        if unknown:
            raise ControllerError(src, f"sensor.blend.{unknown[0]}", f"unknown key; the blend's keys are "
                                                                     f"{', '.join(BLEND_KEYS)}")
    for key in ("crossover_hz", "v_per_m", "lsb_m"):
        if block.get(key) is not None:
            _number(src, f"sensor.{key}", block[key], positive=True)
    for key in STARTUP_FIELDS:                  # named at their key (SensorBlend checks the range)
        if block.get(key) is not None:
            v = _number(src, f"sensor.{key}", block[key])
            if key != "gauge_curvature_per_m" and v < 0:
                raise ControllerError(src, f"sensor.{key}", f"must be >= 0 s; got {v:g}")
    try:
        return SensorBlend.from_dict(block, 1.0 / fs, fxp.input_frac_bits)
    except KeyError as exc:
        raise ControllerError(src, f"sensor.{exc.args[0]}", "is missing; re-export the controller "
                                                            "(Controller.with_sensor(...).write)") from None
    except (TypeError, ValueError) as exc:
        raise ControllerError(src, "sensor", str(exc)) from None


def _check_not_bang_bang(src, gain, sos, fs, limits, plant):
    """Refuse a controller for which one LSB of the reading commands more than the whole output
    range at every frequency (e.g. a gain of 1e300): it can only switch between its limits."""
    g = plant.gauge
    lsb_v = 2.0 * g.dac_range_v / 2 ** int(g.dac_bits)          # one step of the servo DAC's reading
    w = np.geomspace(1e-4, 0.5, 200) * 2 * np.pi                 # rad/sample, 1e-4 of fs to Nyquist
    from scipy import signal
    with np.errstate(all="ignore"):
        k = np.abs(gain * signal.sosfreqz(sos, worN=w)[1])
    smallest = float(np.nanmin(k)) if np.any(np.isfinite(k)) else float("inf")
    if smallest * lsb_v > limits[1] - limits[0]:
        raise ControllerError(src, "gain", f"|K| >= {smallest:.3g} V/V at every frequency: one LSB of the reading "
                                           f"({lsb_v * 1e6:.3g} uV) commands more than the whole output range "
                                           f"{limits[0]:g}..{limits[1]:g} V, so the controller can only switch "
                                           f"between its limits; check the gain's units (V of PZT per firmware V)")


def _provenance_of(data):
    """Provenance fields of an exported JSON (``provenance`` and ``gauge_chain`` blocks)."""
    prov = {}
    p = data.get("provenance") or {}
    g = data.get("gauge_chain") or {}
    if isinstance(p, dict):
        for key in ("plant_file", "plant_sha256", "serial"):
            if isinstance(p.get(key), str):
                prov[key] = p[key]
    if isinstance(g, dict):
        trim = g.get("trim") or {}
        for key, value in (("gauge_v_per_m", g.get("volts_per_meter")), ("trim_scale", trim.get("scale")),
                           ("trim_bias_v", trim.get("bias_v"))):
            if isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value):
                prov[key] = float(value)
    return prov


def _hanus(src, aw, dt, limits):
    from .design.antiwindup import HanusController
    try:
        a = np.asarray(aw["a"], dtype=float)
        b = np.asarray(aw["b"], dtype=float).ravel()
        c = np.asarray(aw["c"], dtype=float).ravel()
        d = float(aw["d"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ControllerError(src, "anti_windup", f"a Hanus realization needs a, b, c, d ({exc})") from None
    n = b.size
    if a.size != n * n or c.size != n or not all(np.all(np.isfinite(x)) for x in (a, b, c, [d])) or d == 0:
        raise ControllerError(src, "anti_windup", f"Hanus a must be {n}x{n}, b and c {n} finite numbers, d finite "
                                                  f"and nonzero")
    return HanusController(a=a.reshape(n, n), b=b.reshape(n, 1), c=c.reshape(1, n), d=d, dt_s=dt,
                           output_limits_v=limits, rate_limits_v_per_s=(np.inf, np.inf))


def _read_mat(path):
    """The JSON form of an exported NAME.mat (arrays of :func:`workbench.export.writers.write_controller`)."""
    from scipy import io as sio
    try:
        m = sio.loadmat(path, squeeze_me=False)
    except Exception as exc:      # scipy raises MatReadError, ValueError, OSError... on a bad file
        raise ControllerError(path, "", f"cannot be read as a MATLAB file ({exc}); give an exported "
                                        f"controller .mat or .json") from None

    def get(key, kind=float):
        if key not in m:
            raise ControllerError(path, key, "is missing: re-export the controller (Controller.write writes it)")
        arr = np.asarray(m[key])
        return arr if kind is None else kind(arr.ravel()[0])

    try:
        sos = np.atleast_2d(get("sos", None).astype(float))
        n = sos.shape[0]
        b = np.asarray(get("b_q", None), dtype=np.int64).reshape(n, 3)
        a = np.asarray(get("a_q", None), dtype=np.int64).reshape(n, 2)
        b_frac = np.asarray(get("b_frac_bits", None), dtype=np.int64).reshape(n)
        sig = np.asarray(get("signal_frac_bits", None), dtype=np.int64).reshape(n)
        integ = np.asarray(get("integrator", None)).reshape(n)
        lim = np.asarray(get("output_limits_v", None), dtype=float).ravel().tolist()
        data = {}
        if "record_json" in m:
            data = json.loads(str(np.asarray(m["record_json"]).ravel()[0]))
        vm = np.asarray(m.get("voltage_model", np.zeros(0)), dtype=float).ravel()
        f_max = float(np.asarray(m["f_max_hz"]).ravel()[0]) if "f_max_hz" in m else 0.4 * get("fs")
    except (ValueError, TypeError, IndexError) as exc:
        raise ControllerError(path, "", f"is not an exported controller ({exc}); re-export it") from None
    data.update({
        "sample_rate_hz": get("fs"), "gain": get("gain"), "sos": sos.tolist(), "output_limits_v": lim,
        "fixed_point": {
            "coeff_bits": int(get("coeff_bits")), "f_max_hz": f_max,
            "error_db": get("error_db"), "error_deg": get("error_deg"),
            "input": {"frac_bits": int(get("input_frac_bits")), "range_v": get("input_range_v")},
            "output": {"limits_v": lim, "voltage_model": None if vm.size != 3 else
                       {"alpha": float(vm[0]), "headroom_v": [float(vm[1]), float(vm[2])]}},
            "sections": [{"b": b[k].tolist(), "a": a[k].tolist(), "b_frac_bits": int(b_frac[k]),
                          "signal_frac_bits": int(sig[k]), "integrator": bool(integ[k])} for k in range(n)]}})
    if vm.size == 3:
        aw = data.get("anti_windup") if isinstance(data.get("anti_windup"), dict) else {}
        old = aw.get("voltage_model") if isinstance(aw.get("voltage_model"), dict) else {}
        # the arrays' window, the record's other keys kept (slew_v_per_s / time_constant_s: resistor out or in)
        data["anti_windup"] = {**aw, "voltage_model": {**old, "alpha": float(vm[0]),
                                                       "headroom_v": [float(vm[1]), float(vm[2])]}}
    return data

