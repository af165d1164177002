"""Firmware files of a quantized controller: NAME.json, NAME.h, NAME.csv and NAME.mat.

Every file is rendered in memory first and then written atomically, so a
failure leaves either the previous files or none, never a half-written one.
The C header holds both cascades: ``NAME_float_step`` (double, equal to
:func:`.run_float` with the output limits) and ``NAME_fixed_step`` (int32/int64,
bit for bit :func:`.run_fixed`).
"""

import io
import json
import re
from pathlib import Path

import numpy as np
from scipy import io as sio

from ..report.output import to_jsonable, write_bytes, write_text
from .fixed_point import ALPHA_FRAC_BITS
from .sos import ExportError

__all__ = ["write_controller", "controller_json"]

_ASSUMPTIONS = (
    "The output is clamped to output_limits_v (and, if given, to the current-limit window around the model of "
    "the stack voltage) and the clamped value drives the last section's recursion (anti-windup). That clamp, "
    "not an L1 norm, bounds the last section's states, which hold the integrator.",
    "The input word is clamped to +/- input_range_v; no other state can overflow for any input (L1 scaling).",
    "Right shifts of negative integers are arithmetic (gcc, clang, arm-none-eabi-gcc, IAR and Keil do this).",
)
_RESERVED = ("gain", "sos", "fixed_point")


def _fixed_point_block(fxp):
    q = fxp.q_formats
    return {
        "form": "cascade of second-order sections, transposed direct form II",
        "word_bits": fxp.word_bits, "accumulator_bits": fxp.acc_bits, "coeff_bits": fxp.coeff_bits,
        "rounding": "round half up: (acc + 2^(F-1)) >> F, F = a_frac_bits",
        "overflow": "saturate to int32; the last section's output is clamped to the output limits",
        "input": {"q": q["input"], "frac_bits": fxp.input_frac_bits, "range_v": fxp.input_range_v,
                  "limit_q": fxp.input_limit},
        "output": {"q": q["output"], "frac_bits": fxp.output_frac_bits, "limits_v": list(fxp.output_limits_v),
                   "limits_q": list(fxp.output_limits),
                   "voltage_model": None if fxp.voltage_model is None else {
                       "alpha": fxp.voltage_model[0], "alpha_q": int(fxp.limit_words[2]),
                       "alpha_frac_bits": ALPHA_FRAC_BITS, "headroom_v": list(fxp.voltage_model[1:]),
                       "headroom_q": fxp.limit_words[3:].tolist(), "slew_v_per_s": list(fxp.slew_limits_v_per_s)}},
        "a_q": q["a"], "a_frac_bits": fxp.a_frac_bits,
        "sections": [{"b": fxp.b[k], "a": fxp.a[k], "b_q": q["b"][k], "b_frac_bits": fxp.b_frac_bits[k],
                      "b_shift": fxp.b_shift[k], "signal_q": q["signals"][k],
                      "signal_frac_bits": fxp.signal_frac_bits[k], "integrator": fxp.integrator[k]}
                     for k in range(len(fxp.b))],
        "max_pole_radius": fxp.max_pole_radius, "f_max_hz": fxp.f_max_hz,
        "error_db": fxp.error_db, "error_deg": fxp.error_deg,
        "assumptions": list(_ASSUMPTIONS),
    }


def controller_json(record, fxp):
    """The text of NAME.json: ``record`` plus ``sample_rate_hz``, ``gain``, ``sos`` and the ``fixed_point`` block."""
    fs_hz = 1.0 / fxp.dt_s
    if "sample_rate_hz" in record and not np.isclose(record["sample_rate_hz"], fs_hz, rtol=1e-12, atol=0.0):
        raise ExportError(f"record['sample_rate_hz'] = {record['sample_rate_hz']} but the controller was quantized "
                          f"for {fs_hz:g} Hz; drop the key or quantize at that rate")
    data = {**record, "sample_rate_hz": record.get("sample_rate_hz", fs_hz), "gain": fxp.gain, "sos": fxp.sos,
            "fixed_point": _fixed_point_block(fxp)}
    return json.dumps(to_jsonable(data), indent=2, allow_nan=False) + "\n"


def _csv(fxp):
    rows = "".join(",".join(_double(v) for v in row) + "\n" for row in fxp.sos)
    return f"# gain = {_double(fxp.gain)}\nb0,b1,b2,a0,a1,a2\n{rows}"


def _mat(record, fxp):
    buf = io.BytesIO()
    # the window (alpha, h_up, h_down; empty without one), the checked band and the JSON record
    # (provenance, anti-windup, margins) travel with the arrays, so Controller.load reads a .mat whole
    rest = {k: v for k, v in record.items() if k not in _RESERVED}
    sio.savemat(buf, {
        "voltage_model": np.array([] if fxp.voltage_model is None else list(fxp.voltage_model), dtype=float),
        "f_max_hz": fxp.f_max_hz,
        "record_json": json.dumps(to_jsonable(rest), allow_nan=False),
        "sos": fxp.sos, "gain": fxp.gain, "fs": 1.0 / fxp.dt_s,
        "b_q": fxp.b.astype(np.int32), "a_q": fxp.a.astype(np.int32),
        "b_frac_bits": fxp.b_frac_bits.astype(np.int32), "b_shift": fxp.b_shift.astype(np.int32),
        "signal_frac_bits": fxp.signal_frac_bits.astype(np.int32), "a_frac_bits": np.int32(fxp.a_frac_bits),
        "input_frac_bits": np.int32(fxp.input_frac_bits), "output_frac_bits": np.int32(fxp.output_frac_bits),
        "input_limit_q": np.int32(fxp.input_limit), "output_limits_q": np.array(fxp.output_limits, dtype=np.int32),
        "input_range_v": fxp.input_range_v, "output_limits_v": np.array(fxp.output_limits_v),
        "integrator": fxp.integrator.astype(np.uint8), "coeff_bits": np.int32(fxp.coeff_bits),
        "error_db": fxp.error_db, "error_deg": fxp.error_deg, "max_pole_radius": fxp.max_pole_radius,
    }, appendmat=False, oned_as="row")
    return buf.getvalue()


def _double(v):
    """The shortest text that reads back as the same double (C and Python alike)."""
    return repr(float(v))


def _int32(v):
    return f"INT32_C({int(v)})"


def _c_array(rows, fmt):
    return ",\n".join("    {" + ", ".join(fmt(v) for v in row) + "}" for row in rows)


def _header(name, fxp, sensor=None, resistor_out=None):
    up = name.upper()
    q = fxp.q_formats
    lo_v, hi_v = fxp.output_limits_v
    lo_q, hi_q = fxp.output_limits
    n = len(fxp.b)
    _, _, alpha_q, hup_q, hdown_q = fxp.limit_words.tolist()
    if fxp.voltage_model is None:
        window_text = ""
        alpha_v, hup_v, hdown_v = "1.0", "INFINITY", "INFINITY"
    else:
        alpha, h_up, h_down = fxp.voltage_model
        s_up, s_down = fxp.slew_limits_v_per_s
        # series resistor out (the plant's R = 0, as the record says; never alpha == 1.0, which an R of ~0.2 ohm or
        # less gives too): v is the last output, the window a slew limit
        if resistor_out:
            window_text = (f"\n *         and to [v - {h_down:g}, v + {h_up:g}] V, v the last output (alpha = 1: "
                           f"series resistor out):\n *         the charge C (u - v) a sample asks for stays within "
                           f"I T, the command slews at most +{s_up:.4g} / -{s_down:.4g} V/s")
        elif resistor_out is None and alpha == 1.0:     # not recorded: claim neither
            window_text = (f"\n *         and to [v - {h_down:g}, v + {h_up:g}] V, v the model of the stack voltage "
                           f"(v += alpha (u - v), alpha = {alpha:.6g}):\n *         the command slews at most "
                           f"+{s_up:.4g} / -{s_down:.4g} V/s")
        else:
            window_text = (f"\n *         and to [v - {h_down:g}, v + {h_up:g}] V, v the model of the stack voltage "
                           f"(v += alpha (u - v), alpha = {alpha:.6g}):\n *         the current (u - v) / R stays "
                           f"within the amplifier's limits, the command slews at most +{s_up:.4g} / -{s_down:.4g} V/s")
        alpha_v, hup_v, hdown_v = _double(alpha), _double(h_up), _double(h_down)
    sections = "\n".join(f" *   section {k}: signals {q['signals'][k]}, b {q['b'][k]}, b shift {fxp.b_shift[k]}"
                         f"{' (integrator, exact at z = 1)' if fxp.integrator[k] else ''}" for k in range(n))
    return f"""\
/* {name}.h: controller "{name}", exported by workbench.export. Re-export rather than edit.
 *
 * Form: cascade of {n} second-order sections, transposed direct form II (TDF-II). Each section,
 * input x, output y, states s1, s2:  y = b0 x + s1;  s1 = b1 x - a1 y + s2;  s2 = b2 x - a2 y.
 * Sample rate {1.0 / fxp.dt_s:g} Hz: call one step per sample. The reset puts the controller at rest at
 * an output u0 with zero error (bumpless start at a bias; u0 = 0 zeroes every state).
 * Input:  gauge error (reference minus demodulated gauge reading), firmware volts, +/-{fxp.input_range_v:g} V.
 * Output: commanded PZT voltage, volts, clamped to [{lo_v:g}, {hi_v:g}] V{window_text}. The clamped value
 *         drives the last section (anti-windup): the integrator is conditioned on what was applied.
 *
 * {name}_float_step: double precision, {up}_GAIN times the input, then the rows of {up}_SOS.
 * {name}_fixed_step: int32 words, int64 accumulators, F = {up}_A_FRAC_BITS = {fxp.a_frac_bits}:
 *   input word  {q['input']} (volts * 2^{fxp.input_frac_bits}), clamped to +/-{up}_INPUT_LIMIT_Q
 *   output word {q['output']} (volts * 2^{fxp.output_frac_bits}), clamped to [{up}_OUTPUT_MIN_Q, {up}_OUTPUT_MAX_Q]
 *   a1, a2 in {q['a']}; per section (y, s1 and s2 share the signal format):
{sections}
 *   acc = align(b x) + s * 2^F - a y  (64 bit);  word = (acc + 2^(F-1)) >> F, round half up,
 *   saturated to int32;  align(p) = p >> shift, or p * 2^-shift for a negative shift.
 *   Scaling: L1 norms from the input bound every state but the last section's; the output clamp
 *   bounds those. No state can overflow for any input word. Right shifts of negative integers
 *   must be arithmetic (gcc, clang, arm-none-eabi-gcc, IAR and Keil are).
 * Quantized response against the design up to {fxp.f_max_hz:g} Hz: {fxp.error_db:.2g} dB, {fxp.error_deg:.2g} deg;
 * largest pole radius {fxp.max_pole_radius:.9f} (integrators excluded: they stay exactly at z = 1).
 */
#ifndef {up}_H
#define {up}_H

#include <math.h>   /* INFINITY */
#include <stdint.h>

#define {up}_N_SECTIONS {n}
#define {up}_SAMPLE_RATE_HZ {_double(1.0 / fxp.dt_s)}
#define {up}_INPUT_RANGE_V {_double(fxp.input_range_v)}
#define {up}_OUTPUT_MIN_V ({_double(lo_v)})
#define {up}_OUTPUT_MAX_V ({_double(hi_v)})
#define {up}_INPUT_FRAC_BITS {fxp.input_frac_bits}
#define {up}_OUTPUT_FRAC_BITS {fxp.output_frac_bits}
#define {up}_A_FRAC_BITS {fxp.a_frac_bits}
#define {up}_INPUT_LIMIT_Q INT32_C({fxp.input_limit})
#define {up}_OUTPUT_MIN_Q INT32_C({lo_q})
#define {up}_OUTPUT_MAX_Q INT32_C({hi_q})
/* current-limit window: model v of the stack voltage, v += alpha (u - v); u within [v - h_down, v + h_up] */
#define {up}_ALPHA ({alpha_v})
#define {up}_ALPHA_Q INT64_C({alpha_q})
#define {up}_ALPHA_FRAC_BITS {ALPHA_FRAC_BITS}
#define {up}_HEADROOM_UP_V ({hup_v})
#define {up}_HEADROOM_DOWN_V ({hdown_v})
#define {up}_HEADROOM_UP_Q INT64_C({hup_q})
#define {up}_HEADROOM_DOWN_Q INT64_C({hdown_q})

static const double {up}_GAIN = {_double(fxp.gain)};
/* rows b0, b1, b2, a0 = 1, a1, a2 */
static const double {up}_SOS[{up}_N_SECTIONS][6] = {{
{_c_array(fxp.sos, _double)}
}};
static const int32_t {up}_B_Q[{up}_N_SECTIONS][3] = {{
{_c_array(fxp.b, _int32)}
}};
static const int32_t {up}_A_Q[{up}_N_SECTIONS][2] = {{
{_c_array(fxp.a, _int32)}
}};
static const int {up}_B_SHIFT[{up}_N_SECTIONS] = {{{", ".join(str(int(v)) for v in fxp.b_shift)}}};

/* s: section states; v: the model of the stack voltage (the current-limit window's centre) */
typedef struct {{ double s[{up}_N_SECTIONS][2]; double v; }} {name}_float_state;
typedef struct {{ int32_t s[{up}_N_SECTIONS][2]; int32_t v; }} {name}_fixed_state;

/* At rest at output u0_v (V) with zero error: the last (integrator) section holds it. */
static inline void {name}_float_reset({name}_float_state *st, double u0_v)
{{
    for (int k = 0; k < {up}_N_SECTIONS; k++) st->s[k][0] = st->s[k][1] = 0.0;
    st->s[{up}_N_SECTIONS - 1][0] = u0_v;
    st->s[{up}_N_SECTIONS - 1][1] = -{up}_SOS[{up}_N_SECTIONS - 1][5] * u0_v;
    st->v = u0_v;
}}

/* One sample: gauge error e_v (V) in, PZT command (V) out. */
static inline double {name}_float_step({name}_float_state *st, double e_v)
{{
    double v = {up}_GAIN * e_v;
    for (int k = 0; k < {up}_N_SECTIONS; k++) {{
        const double *c = {up}_SOS[k];
        double y = c[0] * v + st->s[k][0];
        if (k == {up}_N_SECTIONS - 1) {{
            double lo = st->v - {up}_HEADROOM_DOWN_V, hi = st->v + {up}_HEADROOM_UP_V;
            if (lo < {up}_OUTPUT_MIN_V) lo = {up}_OUTPUT_MIN_V;
            if (hi > {up}_OUTPUT_MAX_V) hi = {up}_OUTPUT_MAX_V;
            y = y < lo ? lo : y > hi ? hi : y;
        }}
        st->s[k][0] = c[1] * v - c[4] * y + st->s[k][1];
        st->s[k][1] = c[2] * v - c[5] * y;
        v = y;
    }}
    st->v += {up}_ALPHA * (v - st->v);
    return v;
}}

static inline int64_t {name}_align_(int64_t p, int shift)
{{
    return shift >= 0 ? p >> shift : p * ((int64_t)1 << -shift);
}}

static inline int32_t {name}_sat32_(int64_t v)
{{
    return v > INT32_MAX ? INT32_MAX : v < INT32_MIN ? INT32_MIN : (int32_t)v;
}}

/* At rest at output word u0_q with zero error: y = s1 = u0, s2 = round(-a2 u0) in the last section. */
static inline void {name}_fixed_reset({name}_fixed_state *st, int32_t u0_q)
{{
    const int64_t half = (int64_t)1 << ({up}_A_FRAC_BITS - 1);
    int64_t u0 = u0_q > {up}_OUTPUT_MAX_Q ? {up}_OUTPUT_MAX_Q : u0_q < {up}_OUTPUT_MIN_Q ? {up}_OUTPUT_MIN_Q : u0_q;
    for (int k = 0; k < {up}_N_SECTIONS; k++) st->s[k][0] = st->s[k][1] = 0;
    st->s[{up}_N_SECTIONS - 1][0] = (int32_t)u0;
    st->s[{up}_N_SECTIONS - 1][1] = (int32_t)((-(int64_t){up}_A_Q[{up}_N_SECTIONS - 1][1] * u0 + half) >> {up}_A_FRAC_BITS);
    st->v = (int32_t)u0;
}}

/* One sample: input word e_q ({q['input']}) in, output word ({q['output']}) out. */
static inline int32_t {name}_fixed_step({name}_fixed_state *st, int32_t e_q)
{{
    const int64_t one = (int64_t)1 << {up}_A_FRAC_BITS, half = one >> 1;
    int64_t v = e_q > {up}_INPUT_LIMIT_Q ? {up}_INPUT_LIMIT_Q : e_q < -{up}_INPUT_LIMIT_Q ? -{up}_INPUT_LIMIT_Q : e_q;
    for (int k = 0; k < {up}_N_SECTIONS; k++) {{
        const int32_t *b = {up}_B_Q[k], *a = {up}_A_Q[k];
        const int shift = {up}_B_SHIFT[k];
        const int last = k == {up}_N_SECTIONS - 1;
        int64_t lo = INT32_MIN, hi = INT32_MAX;
        if (last) {{
            lo = (int64_t)st->v - {up}_HEADROOM_DOWN_Q;
            hi = (int64_t)st->v + {up}_HEADROOM_UP_Q;
            if (lo < {up}_OUTPUT_MIN_Q) lo = {up}_OUTPUT_MIN_Q;
            if (hi > {up}_OUTPUT_MAX_Q) hi = {up}_OUTPUT_MAX_Q;
        }}
        int64_t y = ({name}_align_(b[0] * v, shift) + st->s[k][0] * one + half) >> {up}_A_FRAC_BITS;
        y = y > hi ? hi : y < lo ? lo : y;
        const int64_t s1 = ({name}_align_(b[1] * v, shift) - a[0] * y + st->s[k][1] * one + half) >> {up}_A_FRAC_BITS;
        const int64_t s2 = ({name}_align_(b[2] * v, shift) - a[1] * y + half) >> {up}_A_FRAC_BITS;
        st->s[k][0] = {name}_sat32_(s1);
        st->s[k][1] = {name}_sat32_(s2);
        v = y;
    }}
    st->v = (int32_t)((int64_t)st->v + (((v - (int64_t)st->v) * {up}_ALPHA_Q
                                         + ((int64_t)1 << ({up}_ALPHA_FRAC_BITS - 1))) >> {up}_ALPHA_FRAC_BITS));
    return (int32_t)v;
}}
{"" if sensor is None else _sensor_c(name, fxp, sensor)}
#endif /* {up}_H */
"""


def _startup_c(name, sensor):
    """Macros of firmware's startup and conversion settings the sensor block carries ("" when it carries none)."""
    from ..plant.gauge import TRIM_CENTER_M
    up = name.upper()
    out = []
    if sensor.startup_wait_s is not None:
        if sensor.kind == "gauge":      # no charge integrator: the gauge reading's own settle (its first period)
            what = (f"/* open loop this long before {name}_sensor_reset, s: the gauge reading's settle (no state "
                    f"across periods: its first reading) */\n")
        else:
            what = f"/* open loop this long after the charge integrator's reset before {name}_sensor_reset, s */\n"
        out.append(f"{what}#define {up}_STARTUP_WAIT_S {_double(sensor.startup_wait_s)}\n")
    if sensor.ref_lead_s is not None:
        out.append(f"/* reference lead 1/K_v, s: velocity feedforward on the trajectory generator's planned slope v "
                   f"(ramps):\n   feed r + v * {up}_REF_LEAD_S (a type-1 loop's ramp error v/K_v); not on steps or "
                   f"tones */\n#define {up}_REF_LEAD_S {_double(sensor.ref_lead_s)}\n")
    if sensor.gauge_curvature_per_m is not None:
        out.append(f"/* gauge metres: x = x_lin - beta (x_lin - x_c)^2, beta in 1/m, x_c in m (eq. 27's curvature) */\n"
                   f"#define {up}_GAUGE_CURVATURE_PER_M {_double(sensor.gauge_curvature_per_m)}\n"
                   f"#define {up}_GAUGE_CENTER_M {_double(TRIM_CENTER_M)}\n"
                   f"static inline double {name}_gauge_metres(double x_lin_m)\n{{\n"
                   f"    double u = x_lin_m - {up}_GAUGE_CENTER_M;\n"
                   f"    return x_lin_m - {up}_GAUGE_CURVATURE_PER_M * u * u;\n}}\n")
    return "".join(out)


def _sensor_c(name, fxp, sensor):
    """The header's sensor step: blend (for "fused"), error scale, then {name}_fixed_step (module sensor)."""
    from .sensor import MAX_DIFF_COUNTS, blend_c
    up = name.upper()
    s_q, s_bits = sensor.error_scale(fxp.input_frac_bits)
    kind = sensor.kind
    what = {"gauge": "the gauge reading g", "charge": "the charge estimate c"}.get(kind) or (
        f"the complementary blend c + lowpass(g - c), crossover {sensor.crossover_hz:.6g} Hz "
        f"(a = exp(-w_c T) = {sensor.pole:.12g})")
    blend_defs = ""
    if kind == "fused":
        blend_defs = (f"#define {up}_BLEND_K INT64_C({sensor.k})\n#define {up}_BLEND_K_BITS {sensor.coef_bits}\n"
                      f"#define {up}_BLEND_FRAC_BITS {sensor.frac_bits}\n"
                      f"#define {up}_BLEND_MAX_DIFF INT64_C({MAX_DIFF_COUNTS - 1})\n")
        reading = blend_c(f"{name}_blend", "st->y", "g", "c") + f"    int64_t f = {name}_blend_fused;\n"
    else:
        used, unused = ("g", "c") if kind == "gauge" else ("c", "g")
        reading = f"    (void){unused};\n    int64_t f = {used};\n"
    return f"""
/* Sensor block: the loop closes on {what}.
 * Inputs: int32 counts of {sensor.lsb_m:.6g} m (reference r, gauge reading g, charge estimate c).
 * e = r - reading (counts); cascade input word = (e * {up}_ERROR_SCALE_Q + 2^(B-1)) >> B, B = {s_bits},
 * clamped to +/-{up}_INPUT_LIMIT_Q ({sensor.v_per_m:.9g} firmware V per m); then {name}_fixed_step. */
#define {up}_SENSOR_KIND "{kind}"
#define {up}_ERROR_SCALE_Q INT64_C({s_q})
#define {up}_ERROR_SCALE_BITS {s_bits}
{blend_defs}{_startup_c(name, sensor)}
typedef struct {{ {name}_fixed_state c; int64_t y; }} {name}_sensor_state;

/* At rest at output word u0_q; the blend state starts at the first gauge - charge difference (g0 - c0). */
static inline void {name}_sensor_reset({name}_sensor_state *st, int32_t u0_q, int32_t g0, int32_t c0)
{{
    {name}_fixed_reset(&st->c, u0_q);
    st->y = ((int64_t)g0 - (int64_t)c0) * (INT64_C(1) << {sensor.frac_bits});
}}

/* One sample: counts r, g, c in; output word ({fxp.q_formats['output']}) out. *fused_out (if not NULL): the reading. */
static inline int32_t {name}_sensor_step({name}_sensor_state *st, int32_t r, int32_t g, int32_t c, int64_t *fused_out)
{{
{reading}    if (fused_out) *fused_out = f;
    int64_t e = (((int64_t)r - f) * {up}_ERROR_SCALE_Q + (INT64_C(1) << ({up}_ERROR_SCALE_BITS - 1))) >> {up}_ERROR_SCALE_BITS;
    e = e > {up}_INPUT_LIMIT_Q ? {up}_INPUT_LIMIT_Q : e < -{up}_INPUT_LIMIT_Q ? -{up}_INPUT_LIMIT_Q : e;
    return {name}_fixed_step(&st->c, (int32_t)e);
}}
"""


def write_controller(out_dir, name, record, fxp, sensor=None):
    """Write a quantized controller as NAME.json, NAME.h, NAME.csv and NAME.mat.

    Parameters
    ----------
    out_dir : str or Path
        Folder, created if missing.
    name : str
        File stem and C prefix: a C identifier (letters, digits, underscores).
    record : dict
        Design record (method, notes, input/output signals...), written as
        given into NAME.json; it must not hold ``gain``, ``sos`` or
        ``fixed_point``. ``sample_rate_hz`` is added if missing.
    fxp : FixedPointController
        From :func:`.quantize`.
    sensor : workbench.export.sensor.SensorBlend, optional
        The sensor block: NAME.h then also holds ``NAME_sensor_step`` (blend, error scale,
        cascade; :func:`.sensor.run_sensor` bit for bit). The JSON block is the record's ``sensor``.

    Returns
    -------
    dict of Path
        Keys ``"json"``, ``"h"``, ``"csv"``, ``"mat"``.

    Raises
    ------
    ExportError
        If ``name`` is not a C identifier, ``record`` holds a reserved key or
        a ``sample_rate_hz`` other than the controller's.

    Notes
    -----
    NAME.json: ``record`` plus ``gain``, ``sos`` (rows [b0, b1, b2, 1, a1, a2])
    and a ``fixed_point`` block (Q formats, integer coefficients, shifts,
    error figures, assumptions). NAME.csv: ``# gain = ...``, then the header
    ``b0,b1,b2,a0,a1,a2`` and one row per section. NAME.mat: ``sos``, ``gain``,
    ``fs``, the fixed-point arrays, ``voltage_model`` ([alpha, h_up_v, h_down_v],
    empty without a window), ``f_max_hz`` and ``record_json`` (the record as JSON
    text): :meth:`workbench.Controller.load` reads it back whole. Floats are written with 17 significant
    digits where text is involved, so they read back exactly.
    """
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ExportError(f"name {name!r} must be a C identifier (letters, digits and underscores, not starting "
                          f"with a digit): it prefixes the C functions and names the files")
    clash = [key for key in _RESERVED if key in record]
    if clash:
        raise ExportError(f"record holds {clash}, which write_controller fills from the quantized controller; "
                          f"drop them from the record")
    out_dir = Path(out_dir)
    from ..controller import recorded_resistor_out
    resistor_out = recorded_resistor_out(record.get("anti_windup"))
    payloads = {"json": controller_json(record, fxp), "h": _header(name, fxp, sensor, resistor_out), "csv": _csv(fxp),
                "mat": _mat(record, fxp)}
    return {ext: (write_bytes if isinstance(data, bytes) else write_text)(out_dir / f"{name}.{ext}", data)
            for ext, data in payloads.items()}
