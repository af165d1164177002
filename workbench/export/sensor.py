"""The controller's sensor block: which reading the loop closes on, and the complementary blend's words.

A :class:`SensorBlend` says what the firmware step feeds the cascade with:

- ``"gauge"``: the strain-gauge reading (the classic loop);
- ``"charge"``: the compensated charge estimate (self-sensing, :mod:`workbench.selfsense`);
- ``"fused"``: the complementary blend of the two (:class:`workbench.selfsense.fusion.Blend`),
  the gauge below ``crossover_hz``, the charge estimate above.

The firmware step with a sensor block (``NAME_sensor_step`` of the header, :func:`run_sensor`
here, bit for bit) takes three int32 counts of ``lsb_m`` (the reference, the gauge reading and
the charge estimate, both converted to metres by firmware), per sample::

    fused = blend(g, c)              (the sensor kind: g, c, or the blend below)
    e     = r - fused                (int64 counts)
    e_q   = (e * S + 2^(B-1)) >> B   (input word of the cascade, rounded half up, clamped to its range)
    u     = cascade(e_q)             (NAME_fixed_step: the controller's fixed-point cascade)

with S = round(v_per_m lsb_m 2^(input_frac_bits + B)) the error scale word (firmware V per m, the
gauge gain the loop was designed with, :data:`workbench.controller.X_GAUGE_M`), B chosen so that
2^30 <= S < 2^31. |e| < 2^32 and S < 2^31 keep the product in int64.

The blend (one home: :func:`blend_step`, used by :class:`workbench.selfsense.blend_fixed.FixedBlend`
and by the controller's step; :func:`blend_c` writes its C)::

    d    = g - c, saturated to +/-(2^26 - 1) counts         (int64)
    y   += (k * ((d << F) - y)) >> K                       k = round((1 - a) 2^K), a = exp(-w_c T)
    out  = c + ((y + 2^(F-1)) >> F)

y in Q``frac_bits`` counts, k with ``coef_bits`` = K fraction bits (see
:mod:`workbench.selfsense.blend_fixed` for the bounds: |d| < 2^26, F = 12, k < 2^24 keep every
product below 2^63).
"""

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .fixed_point import fixed_step

__all__ = ["SENSOR_KINDS", "KIND_CODE", "SensorBlend", "blend_step", "sensor_reading", "error_word", "blend_c",
           "run_sensor", "MAX_DIFF_COUNTS"]

SENSOR_KINDS = ("gauge", "charge", "fused")
MAX_DIFF_COUNTS = 2 ** 26          # |gauge - charge| bound of the blend's int64 arithmetic, counts
KIND_CODE = {"gauge": 0, "charge": 1, "fused": 2}       # the sensor kinds as the compiled steps take them


@njit(cache=True, inline="always")
def blend_step(y, g, c, k, frac_bits, coef_bits):
    """One sample of the fixed-point blend: (new state, fused count) from state ``y`` (Q F counts), counts g, c.

    int64 throughout; ``>>`` is the arithmetic (floor) shift, as gcc's on signed integers.
    """
    d = g - c
    lim = np.int64(MAX_DIFF_COUNTS - 1)
    d = min(max(d, -lim), lim)
    y += (k * ((d << frac_bits) - y)) >> coef_bits
    return y, c + ((y + (np.int64(1) << (frac_bits - 1))) >> frac_bits)


@njit(cache=True, inline="always")
def sensor_reading(kind, y, g, c, k, frac_bits, coef_bits):
    """(new blend state, reading count) of the sensor step: ``kind`` 0 gauge, 1 charge, 2 fused (blend)."""
    if kind == 0:
        return y, g
    if kind == 1:
        return y, c
    return blend_step(y, g, c, k, frac_bits, coef_bits)


@njit(cache=True, inline="always")
def error_word(r, f, scale, scale_bits, in_lim):
    """The cascade's input word of reference ``r`` and reading ``f`` (counts): (e S + 2^(B-1)) >> B, clamped."""
    e = ((r - f) * scale + (np.int64(1) << (scale_bits - 1))) >> scale_bits
    return min(max(e, -in_lim), in_lim)


def blend_c(prefix, state_expr, g, c):
    """C99 statements of :func:`blend_step`: update ``state_expr`` (int64_t) and leave the fused count in
    ``int64_t {prefix}_fused``. ``prefix`` names the macros {PREFIX}_K, _K_BITS, _FRAC_BITS, _MAX_DIFF."""
    up = prefix.upper()
    return (f"    int64_t {prefix}_d = (int64_t){g} - (int64_t){c};\n"
            f"    {prefix}_d = {prefix}_d > {up}_MAX_DIFF ? {up}_MAX_DIFF : {prefix}_d < -{up}_MAX_DIFF ? -{up}_MAX_DIFF "
            f": {prefix}_d;\n"
            f"    {state_expr} += ({up}_K * ({prefix}_d * (INT64_C(1) << {up}_FRAC_BITS) - {state_expr})) "
            f">> {up}_K_BITS;\n"
            f"    int64_t {prefix}_fused = (int64_t){c} + (({state_expr} + (INT64_C(1) << ({up}_FRAC_BITS - 1))) "
            f">> {up}_FRAC_BITS);\n")


# firmware's startup and conversion settings the block may carry (SensorBlend attributes, JSON keys)
STARTUP_FIELDS = ("startup_wait_s", "ref_lead_s", "gauge_curvature_per_m")
# every key SensorBlend.as_dict may write (the loader refuses any other), and those of its blend table
SENSOR_BLOCK_KEYS = ("kind", "description", "inputs", "v_per_m", "lsb_m", "error_scale", "crossover_hz", "blend",
                     *STARTUP_FIELDS)
BLEND_KEYS = ("k", "coef_bits", "frac_bits", "pole")


@dataclass(frozen=True)
class SensorBlend:
    """The sensor block of a :class:`workbench.controller.Controller` (see the module notes).

    Attributes
    ----------
    kind : {"gauge", "charge", "fused"}
        The reading the loop closes on.
    crossover_hz : float or None
        Blend crossover f_c, Hz ("fused" only; None otherwise). Below the Nyquist frequency.
    dt_s : float
        Sample time, s (the controller's).
    v_per_m : float
        Firmware volts of error per metre (the gauge gain the cascade was designed with), V/m.
    lsb_m : float, default 1e-12
        Metres per count of the three int32 inputs (1 pm: +/-2.1 mm of range).
    frac_bits : int, default 12
        Fraction bits F of the blend state.
    coef_bits : int, default 24
        Fraction bits K of the blend coefficient word.
    k : int or None
        The blend coefficient word round((1 - a) 2^K); None: computed from ``crossover_hz``. A given
        word must be that rounding (within one LSB).
    startup_wait_s : float or None
        Firmware's startup: open loop this long after the charge integrator's reset (for "gauge": after the
        start) before the loop closes, s: the reading's own settle (:func:`workbench.verify.sensors.startup_settle_s`;
        the gauge's is its first period). The harnesses' scenario floors (the plant's creep after the bias step,
        :data:`workbench.verify.sensors.MIN_OPEN_LOOP_S`) are not part of it. None: not carried (the harness
        computes it).
    ref_lead_s : float or None
        Velocity feedforward 1/K_v, s, on the trajectory generator's planned slope: on a ramp of planned slope v
        the sensor step is fed r + v ref_lead_s, which takes out a type-1 loop's ramp error v / K_v
        (:func:`workbench.verify.sensors.velocity_constant_per_s`). Not a derivative of arbitrary references:
        steps, holds and tones are fed as they are (a step's discrete dr/dt would be a one-sample pulse of
        ref_lead_s / dt_s times its height). Neither the header's step nor
        :meth:`workbench.Controller.run_sensors` applies it: the
        reference generator does. None: not carried; 0: no lead.
    gauge_curvature_per_m : float or None
        beta of firmware's gauge conversion x = x_lin - beta (x_lin - x_c)^2, 1/m
        (:func:`workbench.plant.gauge.bridge_curvature_per_m`). None: not carried; 0: linear calibration.
    """

    kind: str
    crossover_hz: float | None = None
    dt_s: float = 1e-4
    v_per_m: float = 0.0
    lsb_m: float = 1e-12
    frac_bits: int = 12
    coef_bits: int = 24
    k: int | None = None
    startup_wait_s: float | None = None
    ref_lead_s: float | None = None
    gauge_curvature_per_m: float | None = None

    def __post_init__(self):
        if self.kind not in SENSOR_KINDS:
            raise ValueError(f"sensor kind must be one of {', '.join(SENSOR_KINDS)}; got {self.kind!r}")
        for name in ("dt_s", "v_per_m", "lsb_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not (math.isfinite(v) and v > 0):
                raise ValueError(f"sensor {name} must be a positive finite number; got {v!r}")
        for name, lo in (("startup_wait_s", 0.0), ("ref_lead_s", 0.0), ("gauge_curvature_per_m", None)):
            v = getattr(self, name)
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(v) or (lo is not None and v < lo):
                raise ValueError(f"sensor {name} must be a finite number{'' if lo is None else ' >= 0'}; got {v!r}")
            object.__setattr__(self, name, float(v))
        if not (isinstance(self.frac_bits, (int, np.integer)) and 1 <= self.frac_bits <= 16):
            raise ValueError(f"sensor frac_bits must be an integer in 1..16; got {self.frac_bits!r}")
        if not (isinstance(self.coef_bits, (int, np.integer)) and 8 <= self.coef_bits <= 30):
            raise ValueError(f"sensor coef_bits must be an integer in 8..30; got {self.coef_bits!r}")
        if self.kind != "fused":
            if self.crossover_hz is not None or self.k is not None:
                raise ValueError(f"a {self.kind!r} sensor has no blend: drop crossover_hz and k (or use kind 'fused')")
            return
        fc = self.crossover_hz
        if isinstance(fc, bool) or not isinstance(fc, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(fc) and fc > 0):
            raise ValueError(f"the blend crossover must be a positive finite frequency in Hz; got {fc!r}")
        if not fc < 0.5 / self.dt_s:
            raise ValueError(f"the blend crossover {fc:g} Hz must lie below the Nyquist frequency "
                             f"{0.5 / self.dt_s:g} Hz of the {self.dt_s:g} s sample period")
        exact = self.k_exact
        if self.k is None:
            object.__setattr__(self, "k", int(round(exact)))
        elif isinstance(self.k, bool) or not isinstance(self.k, (int, np.integer)):
            raise ValueError(f"the blend word k must be an integer; got {self.k!r}")
        elif abs(int(self.k) - exact) > 1.0:
            raise ValueError(f"the blend word k = {int(self.k)} is not the crossover {fc:g} Hz quantized: "
                             f"(1 - exp(-2 pi f_c T)) 2^{self.coef_bits} = {exact:.3f}; re-export the controller")
        object.__setattr__(self, "k", int(self.k))
        if not 64 <= self.k < 2 ** self.coef_bits:
            raise ValueError(f"the blend crossover {fc:g} Hz gives k = {self.k}: outside 64..2^{self.coef_bits} "
                             f"(too low a crossover for {self.coef_bits} coefficient bits)")

    @property
    def pole(self):
        """a = exp(-2 pi f_c T) of the float blend (None unless fused)."""
        return None if self.crossover_hz is None else math.exp(-2 * math.pi * self.crossover_hz * self.dt_s)

    @property
    def k_exact(self):
        """(1 - a) 2^K, the word before rounding (None unless fused)."""
        return None if self.crossover_hz is None else (1.0 - self.pole) * 2.0 ** self.coef_bits

    def error_scale(self, input_frac_bits):
        """(S, B): the error scale word and its fraction bits for a cascade whose input word has
        ``input_frac_bits`` (2^30 <= S < 2^31; module notes)."""
        x = self.v_per_m * self.lsb_m * 2.0 ** int(input_frac_bits)
        b = 30 - math.floor(math.log2(x))
        s = int(round(x * 2.0 ** b))
        if s >= 2 ** 31:
            b -= 1
            s = int(round(x * 2.0 ** b))
        if not (1 <= b <= 62):
            raise ValueError(f"the error scale {x:.3g} words per count needs {b} fraction bits (1..62): choose "
                             f"another lsb_m")
        return s, b

    def counts(self, x_m):
        """Metres to int64 counts of ``lsb_m`` (rounded to nearest)."""
        return np.round(np.asarray(x_m, float) / self.lsb_m).astype(np.int64)

    def as_dict(self, input_frac_bits):
        """The JSON ``sensor`` block (words included) for a cascade with ``input_frac_bits``."""
        s, b = self.error_scale(input_frac_bits)
        out = {"kind": self.kind,
               "description": {"gauge": "the cascade closes on the strain-gauge reading",
                               "charge": "the cascade closes on the compensated charge estimate",
                               "fused": "the cascade closes on charge + lowpass(gauge - charge): the gauge below "
                                        "the crossover, the charge estimate above"}[self.kind],
               "inputs": "int32 counts of lsb_m: reference, gauge reading, charge estimate (metres)",
               "v_per_m": self.v_per_m, "lsb_m": self.lsb_m,
               "error_scale": {"q": s, "frac_bits": b}}
        if self.kind == "fused":
            out["crossover_hz"] = self.crossover_hz
            out["blend"] = {key: getattr(self, key) for key in BLEND_KEYS}
        for name in STARTUP_FIELDS:                 # only when carried: older exports stay byte for byte
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return out

    @classmethod
    def from_dict(cls, block, dt_s, input_frac_bits=None):
        """A SensorBlend from its JSON block; raises ValueError/KeyError/TypeError (the caller names the file).

        With ``input_frac_bits``, a written ``error_scale`` must equal the one derived here.
        """
        if not isinstance(block, dict):
            raise TypeError(f"must be a table {{kind, crossover_hz, ...}}; got {block!r}")
        kind = block["kind"]
        bl = block.get("blend") or {}
        if kind == "fused" and not isinstance(bl, dict):
            raise TypeError(f"blend must be a table {{k, coef_bits, frac_bits}}; got {bl!r}")
        sb = cls(kind=kind, crossover_hz=block.get("crossover_hz"), dt_s=dt_s, v_per_m=block["v_per_m"],
                 lsb_m=block.get("lsb_m", 1e-12), frac_bits=bl.get("frac_bits", 12) if kind == "fused" else 12,
                 coef_bits=bl.get("coef_bits", 24) if kind == "fused" else 24,
                 k=bl.get("k") if kind == "fused" else None,
                 **{name: block.get(name) for name in STARTUP_FIELDS})
        es = block.get("error_scale")
        if input_frac_bits is not None and es is not None:
            want = sb.error_scale(input_frac_bits)
            if not isinstance(es, dict) or (es.get("q"), es.get("frac_bits")) != want:
                raise ValueError(f"error_scale {es!r} is not v_per_m lsb_m 2^(input_frac_bits + B) quantized "
                                 f"(expected q = {want[0]}, frac_bits = {want[1]}); re-export the controller")
        return sb


@njit(cache=True)
def _sensor_kernel(r, g, c, kind, k, frac, kbits, scale, scale_bits, in_lim, b, a, b_shift, afrac, lim, s, vm, y,
                   fused):
    peak = np.zeros((b.shape[0], 3), np.int64)
    out = np.empty(r.size, np.int64)
    for i in range(r.size):
        y[0], f = sensor_reading(kind, y[0], g[i], c[i], k, frac, kbits)
        fused[i] = f
        out[i] = fixed_step(s, error_word(r[i], f, scale, scale_bits, in_lim), b, a, b_shift, afrac, lim, vm, True,
                            peak)
    return out


def run_sensor(sensor, fxp, ref_counts, gauge_counts, charge_counts, u0_v=0.0, y0=None):
    """The firmware step with its sensor block over records of counts: NAME_sensor_step bit for bit.

    Parameters
    ----------
    sensor : SensorBlend
    fxp : workbench.export.FixedPointController
        The cascade's words.
    ref_counts, gauge_counts, charge_counts : array_like of int
        Reference, gauge reading and charge estimate per sample, counts of ``sensor.lsb_m`` (int32).
    u0_v : float, default 0
        Output at rest before the first sample, V (:func:`workbench.export.fixed_point.initial_state`).
    y0 : int, optional
        Blend state before the first sample (Q F counts); default (g_0 - c_0) << F, as NAME_sensor_reset.

    Returns
    -------
    u_v : ndarray of float
        Commanded PZT voltage per sample, V (output words times 2^-output_frac_bits, exact).
    fused_counts : ndarray of int64
        The reading the cascade closed on, per sample (counts).
    y_end : int
        Final blend state.
    """
    from .fixed_point import initial_state
    r, g, c = (np.ascontiguousarray(v, dtype=np.int64) for v in (ref_counts, gauge_counts, charge_counts))
    if not (r.shape == g.shape == c.shape and r.ndim == 1):
        raise ValueError("reference, gauge and charge must be 1-D sequences of one length")
    for name, v in (("reference", r), ("gauge", g), ("charge", c)):
        if v.size and int(np.max(np.abs(v))) >= 2 ** 31:
            raise ValueError(f"the {name} counts must fit in int32 (|x| < 2^31 counts of {sensor.lsb_m:g} m)")
    scale, scale_bits = sensor.error_scale(fxp.input_frac_bits)
    s, u0 = initial_state(fxp, u0_v)
    frac = int(sensor.frac_bits)
    y = np.array([(int(g[0] - c[0]) << frac) if (y0 is None and g.size) else int(y0 or 0)], np.int64)
    fused = np.empty(r.size, np.int64)
    out = _sensor_kernel(r, g, c, KIND_CODE[sensor.kind], np.int64(sensor.k or 0), frac, int(sensor.coef_bits),
                         np.int64(scale), int(scale_bits), np.int64(fxp.input_limit), fxp.b, fxp.a,
                         fxp.b_shift.astype(np.int64), fxp.a_frac_bits, fxp.limit_words, s, np.array([u0]), y, fused)
    return out * 2.0 ** -fxp.output_frac_bits, fused, int(y[0])
