"""Fixed point: a 32-bit transposed direct form II cascade that cannot overflow.

Arithmetic (the C code of :mod:`.writers` does exactly this; :func:`run_fixed`
simulates it bit for bit). Words are int32, accumulators int64, F = coeff_bits - 3
(29 for 32-bit coefficients). Section k maps its input word x (the controller
input or the previous section's output) to its output word y; y and the two
states s1, s2 share one format Q(m_k).(31 - m_k)::

    acc0 = B_k(b0 x) + s1 * 2^F         ;  y  = clamp(round(acc0 / 2^F))
    acc1 = B_k(b1 x) - a1 y + s2 * 2^F  ;  s1 = sat32(round(acc1 / 2^F))
    acc2 = B_k(b2 x) - a2 y             ;  s2 = sat32(round(acc2 / 2^F))

- a1, a2: Q2.F (Q2.29). Any pole on or inside the unit circle has |a1| <= 2 and
  |a2| <= 1; Q1.30 cannot hold a1 = +2 and a Q format per section buys
  nothing for a (its range is fixed by stability).
- b0..b2: Q format per section with Fb_k fraction bits, the most that keep the
  largest |b| in the word (a section's numerator can be far larger or smaller
  than 1 once scaled to its words). B_k aligns a product to the accumulator:
  ``p >> (Fb_k - F)`` (arithmetic shift, floor) or ``p * 2^(F - Fb_k)``.
- Exact roots: an integrator keeps its pole at z = 1 (a2 rounded,
  a1 = -(2^F + a2)) and a zero at z = -1, as Tustin leaves one per roll-off
  order, stays there (b1 = b0 + b2).
- round(v / 2^F) = (v + 2^(F-1)) >> F: round half up. sat32 saturates to
  int32 (a safety net: the scaling below keeps every state inside). clamp is
  sat32, except in the last section where it is the output limits.
- The input word, Q(m_in).(31 - m_in), is clamped to +/- ``input_range_v``: the
  no-overflow guarantee holds for any input. The output word is the last
  section's y, in volts times 2^(31 - m_last).

Scaling: m_k (the section's power-of-two scale) is the smallest integer with
2^m_k > 1.01 W_k (1 % covers coefficient and rounding perturbations), where

- for every section but the last, W_k is the largest L1 bound (sum of
  |impulse response| from the controller input, times ``input_range_v``) of y,
  s1 and s2, and of |b_i| X_k with X_k the L1 bound of the section's input;
- the last section holds the integrator, whose L1 norm is unbounded. Its
  output is clamped to ``output_limits_v`` and the clamped value drives its
  recursion (anti-windup: the integrator state cannot wind past the limits).
  With Y = max |output limit|: |s2| <= |b2| X + |a2| Y and
  |s1| <= |b1| X + |a1| Y + max|s2|, and W_last is the largest of Y, these and
  |b_i| X. ASSUMPTION (repeated in the exported JSON and header): the firmware
  runs this step as generated, clamp included. Were the output limited
  elsewhere instead, the integrator state would be unbounded and could
  overflow. A controller whose integrator is not in the last section is refused.
- Current-limit window (optional, ``voltage_model`` = (alpha, h_up, h_down)): firmware
  keeps a model v of the stack's terminal voltage, the RC response of the series
  resistor and the largest stack capacitance to the held output, v <- v + alpha (u - v)
  with alpha = 1 - exp(-T / (R C)); the last section's clamp is narrowed to
  [v - h_down, v + h_up] with h = R I_max, so the command never asks the amplifier
  for more current than its limits give (I = (u - v) / R). A large step therefore
  slews at I_max / C in the controller as in the plant, and the clamped value drives
  the recursion as above (the integrator is conditioned on what the stack can follow),
  while small and noisy moves pass untouched. In words: alpha in Q1.30,
  v <- v + ((u - v) alpha_q + 2^29) >> 30. The range bound on the states is unchanged.
- Start: :func:`initial_state` puts the cascade at rest at an output u0 with zero
  error (the last section's s1 = u0, s2 = round(-a2 u0)), so the loop can be
  closed at a bias without a bump.

The |b_i| X terms keep every accumulator term below 2^(32 + F) even with
saturated words, so no int64 accumulator can overflow.
"""

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
from numba import njit
from scipy import signal

from ..errors import ControllerError
from .sos import ExportError

__all__ = ["FixedPointController", "quantize", "run_float", "run_fixed", "fixed_point_peaks",
           "node_impulse_responses", "initial_state", "fixed_step", "float_step", "ALPHA_FRAC_BITS"]

_WORD_BITS = 32
_ACC_BITS = 64
_HEADROOM = 1.01
_INTEGRATOR_TOL = 1e-12      # |1 + a1 + a2| (relative |b0 - b1 + b2|): rounding of a row built from z = 1 (z = -1)
_L1_TAIL = 1e-10             # truncate impulse responses once r^n / (1 - r) falls below this
_L1_MAX_SAMPLES = 1 << 22    # 7 min at 10 kHz: slower poles belong in the last section
_NO_WINDOW = 1 << 40          # words: wider than any output range
ALPHA_FRAC_BITS = 30          # the voltage model's alpha in Q1.30


def _q(frac_bits, bits=_WORD_BITS):
    return f"Q{bits - 1 - int(frac_bits)}.{int(frac_bits)}"


@dataclass(frozen=True, eq=False)
class FixedPointController:
    """A controller quantized for the fixed-point TDF-II cascade (see the module docstring).

    Attributes
    ----------
    gain, sos : float, ndarray of float (n_sections, 6)
        The float design that was quantized (rows ``[b0, b1, b2, 1, a1, a2]``).
    dt_s : float
        Sample time, s.
    input_range_v, output_limits_v : float, (float, float)
        Input clamp +/- V (gauge error, firmware volts); output clamp (lo, hi), V.
    f_max_hz : float
        Upper end of the band where the response error was checked, Hz.
    coeff_bits : int
        Coefficient word length, bits (stored in int32).
    b, a : ndarray of int64, (n_sections, 3) and (n_sections, 2)
        Integer coefficients: b per section in Q(b_frac_bits), a1, a2 in Q2.(coeff_bits - 3).
    b_frac_bits, signal_frac_bits : ndarray of int64, (n_sections,)
        Fraction bits of each section's b and of its y, s1, s2 words.
    input_frac_bits : int
        Fraction bits of the input word.
    integrator : ndarray of bool, (n_sections,)
        Sections holding a pole kept exactly at z = 1 (1 + a1 + a2 = 0 in integers).
    max_pole_radius : float
        Largest |z| of the quantized poles other than the exact integrators.
    error_db, error_deg : float
        Largest |quantized / design| response error up to ``f_max_hz``: dB and degrees.
    voltage_model : (float, float, float) or None
        (alpha, h_up, h_down): the current-limit window of the module docstring; None: none.
    """

    gain: float
    sos: np.ndarray
    dt_s: float
    input_range_v: float
    output_limits_v: tuple
    f_max_hz: float
    coeff_bits: int
    b: np.ndarray
    a: np.ndarray
    b_frac_bits: np.ndarray
    signal_frac_bits: np.ndarray
    input_frac_bits: int
    integrator: np.ndarray
    max_pole_radius: float
    error_db: float
    error_deg: float
    voltage_model: tuple | None = None
    word_bits: ClassVar[int] = _WORD_BITS
    acc_bits: ClassVar[int] = _ACC_BITS

    def __post_init__(self):
        n = len(self.sos)
        shapes = [arr.shape for arr in (self.sos, self.b, self.a, self.b_frac_bits, self.signal_frac_bits,
                                        self.integrator)]
        if shapes != [(n, 6), (n, 3), (n, 2), (n,), (n,), (n,)]:
            raise ValueError(f"inconsistent section arrays: shapes {shapes} for {n} sections")
        for arr in (self.sos, self.b, self.a, self.b_frac_bits, self.signal_frac_bits, self.integrator):
            arr.flags.writeable = False
        self._check_clamp_words()

    def _check_clamp_words(self):
        """The input and output clamps as words fit the firmware's int32 (the C header's ``INT32_C``).

        The one home of this check: a controller built through the API or read from a file
        (``Controller.load`` calls it through this constructor). Raises :class:`ControllerError`
        naming the file's field (``fixed_point.input.range_v`` / ``fixed_point.output.limits_v``).
        The output words must also lie inside the no-window headroom (2^40) of ``limit_words``.
        """
        fb = self.input_frac_bits
        if isinstance(fb, bool) or not isinstance(fb, (int, np.integer)) or not 0 <= fb <= 31:
            raise ControllerError(None, "fixed_point.input.frac_bits",
                                  f"must be an integer number of fraction bits in 0..31 (an int32 input word); "
                                  f"got {fb!r}")
        in_scale = 2.0 ** fb
        if not (np.isfinite(self.input_range_v) and self.input_range_v > 0):
            raise ControllerError(None, "fixed_point.input.range_v",
                                  f"must be a finite number of volts > 0; got {self.input_range_v}")
        if self.input_range_v * in_scale >= 2 ** 31:
            raise ControllerError(None, "fixed_point.input.range_v",
                                  f"+/-{self.input_range_v!r} V at {fb} fraction bits is a word outside "
                                  f"+/-(2^31 - 1) (int32, the firmware's input clamp); give a range below "
                                  f"{2 ** 31 / in_scale!r} V or re-export the controller")
        lo, hi = self.output_limits_v
        out_scale = 2.0 ** self.output_frac_bits
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
            raise ControllerError(None, "fixed_point.output.limits_v",
                                  f"must be two finite numbers of volts, lo < hi; got {[lo, hi]}")
        if max(abs(lo), abs(hi)) * out_scale >= 2 ** 31:
            raise ControllerError(None, "fixed_point.output.limits_v",
                                  f"{[lo, hi]} V at {self.output_frac_bits} fraction bits are words outside "
                                  f"+/-(2^31 - 1) (int32, the firmware's clamp); give limits of magnitude below "
                                  f"{2 ** 31 / out_scale!r} V or re-export the controller")

    @property
    def a_frac_bits(self):
        """Fraction bits of a1, a2 and of the accumulators relative to a word, F."""
        return self.coeff_bits - 3

    @property
    def b_shift(self):
        """Right shift aligning each section's b products to the accumulator (negative: left)."""
        return self.b_frac_bits - self.a_frac_bits

    @property
    def output_frac_bits(self):
        """Fraction bits of the output word (the last section's format)."""
        return int(self.signal_frac_bits[-1])

    @property
    def input_limit(self):
        """Input clamp as a word: +/- this."""
        return int(np.floor(self.input_range_v * 2.0 ** self.input_frac_bits))

    @property
    def output_limits(self):
        """Output clamp (lo, hi) as words."""
        scale = 2.0 ** self.output_frac_bits
        return int(np.ceil(self.output_limits_v[0] * scale)), int(np.floor(self.output_limits_v[1] * scale))

    @property
    def limit_words(self):
        """int64 [lo, hi, alpha_q, h_up, h_down]: the step's ``lim`` (output words; alpha in Q1.30).

        Without a voltage model: alpha = 1 (v follows u) and an unreachable window.
        """
        if self.voltage_model is None:
            return np.array([*self.output_limits, 1 << ALPHA_FRAC_BITS, _NO_WINDOW, _NO_WINDOW], dtype=np.int64)
        alpha, h_up, h_down = self.voltage_model
        scale = 2.0 ** self.output_frac_bits
        return np.array([*self.output_limits, int(np.rint(alpha * 2.0 ** ALPHA_FRAC_BITS)),
                         int(np.floor(h_up * scale)), int(np.floor(h_down * scale))], dtype=np.int64)

    @property
    def slew_limits_v_per_s(self):
        """Fastest (up, down) slew of the output the window allows (alpha h / T), V/s; None without one."""
        if self.voltage_model is None:
            return None
        alpha, h_up, h_down = self.voltage_model
        return alpha * h_up / self.dt_s, alpha * h_down / self.dt_s

    @property
    def q_formats(self):
        """Q format strings: input, output, a, and per section b and signals."""
        return {"input": _q(self.input_frac_bits), "output": _q(self.output_frac_bits),
                "a": _q(self.a_frac_bits, self.coeff_bits),
                "b": [_q(f, self.coeff_bits) for f in self.b_frac_bits],
                "signals": [_q(f) for f in self.signal_frac_bits]}

    def input_words(self, e_v):
        """Input words of errors ``e_v`` (V): rounded to nearest (ties to even), clamped to the input range."""
        lim = self.input_limit
        return np.clip(np.rint(np.asarray(e_v, dtype=float) * 2.0 ** self.input_frac_bits), -lim, lim).astype(np.int64)

    def quantized_sos(self):
        """(gain, sos) of the linear controller the integers implement (rounding aside), gain folded in."""
        f_prev = np.concatenate(([self.input_frac_bits], self.signal_frac_bits[:-1]))
        b = self.b * 2.0 ** (f_prev - self.signal_frac_bits - self.b_frac_bits)[:, None]
        a = self.a * 2.0 ** -self.a_frac_bits
        return 1.0, np.column_stack([b, np.ones(len(b)), a])


def _check_sos(sos):
    sos = np.atleast_2d(np.asarray(sos, dtype=float))
    if sos.ndim != 2 or sos.shape[1] != 6 or not np.all(np.isfinite(sos)) or np.any(sos[:, 3] == 0):
        raise ExportError(f"sos must be rows [b0, b1, b2, a0, a1, a2] of finite numbers with a0 != 0; "
                          f"got shape {sos.shape}")
    return sos / sos[:, 3:4]


def _is_integrator(row):
    return abs(1.0 + row[4] + row[5]) <= _INTEGRATOR_TOL


def node_impulse_responses(gain, sos, n_samples):
    """Impulse responses from the controller input to each section's y, s1 and s2.

    Parameters
    ----------
    gain : float
        Scalar gain.
    sos : array_like of float, shape (n_sections, 6)
        Second-order sections.
    n_samples : int
        Length of the responses.

    Returns
    -------
    ndarray of float, shape (n_sections, 3, n_samples)
        ``[k, 0]``: y of section k; ``[k, 1]``, ``[k, 2]``: s1, s2 after the
        update of each sample (TDF-II, as :func:`run_float` computes them).

    Notes
    -----
    With H = B/A a section's transfer, the states after the update are
    s1 = [(b1 - a1 b0) + (b2 - a2 b0) z^-1] / A and
    s2 = [(b2 - a2 b0) + (b2 a1 - a2 b1) z^-1] / A times its input.
    """
    sos = _check_sos(sos)
    u = np.zeros(int(n_samples))
    u[0] = gain
    out = np.empty((len(sos), 3, u.size))
    for k, (b0, b1, b2, _, a1, a2) in enumerate(sos):
        a = [1.0, a1, a2]
        out[k, 1] = signal.lfilter([b1 - a1 * b0, b2 - a2 * b0], a, u)
        out[k, 2] = signal.lfilter([b2 - a2 * b0, b2 * a1 - a2 * b1], a, u)
        u = out[k, 0] = signal.lfilter([b0, b1, b2], a, u)
    return out


def _l1_samples(sos):
    """Samples after which the responses of these (stable) sections are negligible.

    The tail of a response with poles of radius <= r is taken as r^n / (1 - r) of its
    start (a simple pole); 64 extra samples and the 1 % headroom cover repeated poles.
    """
    r = max((np.max(np.abs(np.roots(row[3:]))) for row in sos), default=0.0)
    if r == 0.0:
        return 64
    n = int(np.ceil(np.log(_L1_TAIL * (1.0 - r)) / np.log(r))) + 64
    if n > _L1_MAX_SAMPLES:
        raise ExportError(f"a pole at |z| = {r:.9f} outside the last section decays too slowly for an L1 bound "
                          f"({n} samples); pair it with the integrator in the last section or move it away "
                          f"from the unit circle")
    return n


def _check_poles(sos):
    """Only the last section may hold unit-circle poles, and only integrators at z = 1."""
    for k, row in enumerate(sos):
        if _is_integrator(row):
            if k != len(sos) - 1:
                raise ExportError(f"section {k} of {len(sos)} holds an integrator (pole at z = 1) but only the "
                                  f"last section can: the output limits bound it there. Reorder the sections "
                                  f"(to_sos puts the poles nearest the unit circle last)")
            other = abs(row[5])
            if other >= 1.0 and abs(row[5] - 1.0) > _INTEGRATOR_TOL:
                raise ExportError(f"section {k} pairs its integrator with a pole at z = {row[5]:.6g}, on or outside "
                                  f"the unit circle; the controller must be stable apart from integrators")
            continue
        r = np.max(np.abs(np.roots(row[3:])))
        if r >= 1.0:
            raise ExportError(f"section {k} has a pole at |z| = {r:.6g}: the fixed-point export needs every pole "
                              f"inside the unit circle except integrators (z = 1) in the last section")


def _word_bounds(b_real, sos, input_range_v, output_limits_v):
    """W_k: the largest magnitude each section's y, s1, s2 and |b_i| x can reach (see the module docstring)."""
    n_sec = len(sos)
    x_bound = np.empty(n_sec)
    w = np.empty(n_sec)
    x_bound[0] = input_range_v
    if n_sec > 1:
        stable = sos[:-1]
        l1 = np.abs(node_impulse_responses(1.0, np.column_stack([b_real[:-1], stable[:, 3:]]),
                                           _l1_samples(stable))).sum(axis=-1) * input_range_v
        x_bound[1:] = l1[:, 0]
        w[:-1] = np.maximum(l1.max(axis=1), np.abs(b_real[:-1]).max(axis=1) * x_bound[:-1])
    x = x_bound[-1]
    b0, b1, b2 = np.abs(b_real[-1])
    a1, a2 = np.abs(sos[-1, 4:])
    y = max(abs(output_limits_v[0]), abs(output_limits_v[1]))
    s2 = b2 * x + a2 * y
    s1 = b1 * x + a1 * y + s2
    w[-1] = max(y, s1, s2, b0 * x, b1 * x, b2 * x)
    return w


def _int_bits(bound):
    """Smallest m with 2^m > 1.01 bound."""
    return int(np.floor(np.log2(_HEADROOM * bound))) + 1


def _quantize_b(b_w, coeff_bits):
    """Integer numerator and its fraction bits: the most bits that keep max|b| in the word.

    A zero at z = -1 (Tustin puts one there per roll-off order) stays exact, b1 = b0 + b2
    in integers: the response vanishes at the Nyquist frequency, where any shift of that zero
    would be an unbounded relative error.
    """
    top = (1 << (coeff_bits - 1)) - 1
    nyquist_zero = abs(b_w[0] - b_w[1] + b_w[2]) <= _INTEGRATOR_TOL * np.max(np.abs(b_w))
    frac = coeff_bits - 1 - int(np.floor(np.log2(np.max(np.abs(b_w)))))
    while True:
        frac -= 1
        q = np.rint(b_w * 2.0 ** frac)
        if nyquist_zero:
            q[1] = q[0] + q[2]
        if np.max(np.abs(q)) <= top:
            return q.astype(np.int64), frac


def _worst_error(sos, sos_q, dt, f_max_hz, max_error_db, max_error_deg):
    """Largest dB and degree errors of sections ``sos_q`` against ``sos`` (gains folded into both),
    the frequency of the worst one, Hz, and the section contributing most there."""
    f_hz = np.unique(np.concatenate([np.geomspace(f_max_hz * 1e-4, f_max_hz, 1000),
                                     np.linspace(f_max_hz / 1000, f_max_hz, 1000)]))
    w = 2 * np.pi * f_hz * dt
    per_section = np.array([signal.sosfreqz(sos_q[k:k + 1], worN=w)[1] / signal.sosfreqz(sos[k:k + 1], worN=w)[1]
                            for k in range(len(sos))])
    ratio = np.prod(per_section, axis=0)
    err_db, err_deg = np.abs(20 * np.log10(np.abs(ratio))), np.abs(np.angle(ratio, deg=True))
    i = int(np.argmax(np.maximum(err_db / max_error_db, err_deg / max_error_deg)))
    worst_section = int(np.argmax(np.abs(np.log(per_section[:, i]))))
    return float(err_db.max()), float(err_deg.max()), float(f_hz[i]), worst_section


def quantize(gain, sos, dt, *, input_range_v, output_limits_v, f_max_hz, coeff_bits=32,
             max_error_db=0.1, max_error_deg=1.0, voltage_model=None):
    """Quantize second-order sections for the fixed-point TDF-II cascade.

    Parameters
    ----------
    gain : float
        Scalar gain of the design, V/V.
    sos : array_like of float, shape (n_sections, 6)
        Rows ``[b0, b1, b2, a0, a1, a2]``, ordered as :func:`.to_sos` orders them;
        only the last section may hold an integrator (pole at z = 1).
    dt : float
        Sample time, s.
    input_range_v : float
        The input (gauge error, firmware volts) is clamped to +/- this, V.
    output_limits_v : (float, float)
        Output clamp (lo, hi), PZT volts; it also bounds the integrator.
    f_max_hz : float
        The response error is checked from ``f_max_hz / 1e4`` to this, Hz;
        below the Nyquist frequency.
    coeff_bits : int, default 32
        Coefficient word length, 8 to 32 bits (signals stay 32-bit).
    max_error_db, max_error_deg : float, default 0.1 and 1.0
        Largest allowed response error up to ``f_max_hz``: dB and degrees.
    voltage_model : (float, float, float), optional
        (alpha, h_up, h_down): the current-limit window (module docstring), 0 < alpha <= 1,
        h >= 0 V.

    Returns
    -------
    FixedPointController

    Raises
    ------
    ExportError
        If an argument is out of range, a pole outside the last section is on
        or outside the unit circle, a quantized pole reaches the unit circle,
        or the response error exceeds the bounds; the message says what to change.

    Notes
    -----
    The integrator section keeps its pole exactly at 1: a2 is rounded and
    a1 = -(2^F + a2) in integers; likewise zeros at z = -1 stay exact. Formats
    and scaling, and the anti-windup assumption that bounds the integrator:
    see the module docstring.
    """
    sos = _check_sos(sos)
    fs_hz = 1.0 / dt if dt > 0 else float("nan")
    lo, hi = (float(v) for v in output_limits_v)
    if not (np.isfinite(gain) and gain != 0.0):
        raise ExportError(f"gain must be finite and nonzero; got {gain}")
    if not (input_range_v > 0 and lo < hi and dt > 0):
        raise ExportError(f"need input_range_v > 0, output_limits_v = (lo, hi) with lo < hi and dt > 0; "
                          f"got {input_range_v} V, ({lo}, {hi}) V, {dt} s")
    if not 0 < f_max_hz < fs_hz / 2:
        raise ExportError(f"f_max_hz must lie between 0 and the Nyquist frequency {fs_hz / 2:g} Hz; got {f_max_hz}")
    if not (isinstance(coeff_bits, (int, np.integer)) and 8 <= coeff_bits <= 32):
        raise ExportError(f"coeff_bits must be an integer from 8 to 32 (coefficients are stored in int32); "
                          f"got {coeff_bits!r}")
    if voltage_model is not None:
        voltage_model = tuple(float(v) for v in voltage_model)
        if (len(voltage_model) != 3 or not 0 < voltage_model[0] <= 1
                or not all(np.isfinite(h) and h >= 0 for h in voltage_model[1:])):
            raise ExportError(f"voltage_model must be (alpha, h_up, h_down) with 0 < alpha <= 1 and h >= 0 V; "
                              f"got {voltage_model}")
    if np.any(np.all(sos[:, :3] == 0, axis=1)):
        raise ExportError("a section has an all-zero numerator: the controller is zero")
    _check_poles(sos)
    integrator = np.array([_is_integrator(row) for row in sos])

    b_real = sos[:, :3].copy()
    b_real[0] *= gain    # the gain rides in the first numerator: its format absorbs any scale
    w = _word_bounds(b_real, sos, input_range_v, (lo, hi))
    f_sig = np.array([_WORD_BITS - 1 - _int_bits(v) for v in w], dtype=np.int64)
    f_in = _WORD_BITS - 1 - _int_bits(input_range_v)
    f_prev = np.concatenate(([f_in], f_sig[:-1]))
    frac_a = coeff_bits - 3
    b_q, b_frac = zip(*(_quantize_b(b_real[k] * 2.0 ** (f_sig[k] - f_prev[k]), coeff_bits) for k in range(len(sos))))
    b_frac = np.array(b_frac, dtype=np.int64)
    if np.any((b_frac - frac_a > 62) | (b_frac - frac_a < -31)):
        raise ExportError(f"a numerator is out of scale with its signals (b fraction bits {b_frac.tolist()}); "
                          f"rebalance the design's sections")
    a_q = np.rint(sos[:, 4:] * 2.0 ** frac_a).astype(np.int64)
    a_q[integrator, 0] = -((1 << frac_a) + a_q[integrator, 1])

    radius = []
    for k, (a1, a2) in enumerate(a_q / 2.0 ** frac_a):
        poles = [a2] if integrator[k] else np.roots([1.0, a1, a2])
        if integrator[k] and abs(sos[k, 5] - 1.0) <= _INTEGRATOR_TOL:
            poles = []    # a designed double integrator: both poles exact
        r = float(np.max(np.abs(poles), initial=0.0))
        if r >= 1.0:
            r0 = np.max(np.abs(np.roots(sos[k, 3:])))
            raise ExportError(f"with {coeff_bits}-bit coefficients a pole of section {k} moves to |z| = {r:.9f}, "
                              f"on or outside the unit circle (designed at |z| = {r0:.9f}); raise coeff_bits "
                              f"(now {coeff_bits}, at most 32) or move that pole away from the unit circle")
        radius.append(r)

    fxp = FixedPointController(
        gain=float(gain), sos=sos, dt_s=float(dt), input_range_v=float(input_range_v), output_limits_v=(lo, hi),
        f_max_hz=float(f_max_hz), coeff_bits=int(coeff_bits), b=np.array(b_q), a=a_q, b_frac_bits=b_frac,
        signal_frac_bits=f_sig, input_frac_bits=int(f_in), integrator=integrator,
        max_pole_radius=max(radius), error_db=0.0, error_deg=0.0, voltage_model=voltage_model)
    design = np.column_stack([b_real, sos[:, 3:]])
    err_db, err_deg, f_worst, k_worst = _worst_error(design, fxp.quantized_sos()[1], dt, f_max_hz,
                                                     max_error_db, max_error_deg)
    if err_db > max_error_db or err_deg > max_error_deg:
        raise ExportError(f"with {coeff_bits}-bit coefficients the response differs from the design by up to "
                          f"{err_db:.3g} dB / {err_deg:.3g} deg (worst near {f_worst:.4g} Hz, section {k_worst}); "
                          f"allowed {max_error_db} dB / {max_error_deg} deg up to f_max_hz = {f_max_hz:g} Hz. "
                          f"Raise coeff_bits (now {coeff_bits}, at most 32), lower f_max_hz, or move the poles "
                          f"and zeros of section {k_worst} away from the unit circle and from each other")
    return replace(fxp, error_db=err_db, error_deg=err_deg)


@njit(cache=True, inline="always")
def float_step(s, v, sos, lim, vm, condition):
    """One sample of the float cascade (states ``s`` and voltage model ``vm[0]`` updated in place).

    ``v`` is gain x input; ``lim`` = [lo, hi, alpha, h_up, h_down] (V). The last section's
    output is clamped to [lo, hi] and to [vm - h_down, vm + h_up]; with ``condition`` the
    clamped value drives its recursion (anti-windup), else the raw one. Then
    vm <- vm + alpha (u - vm) (module docstring).
    """
    n_sec = sos.shape[0]
    for k in range(n_sec):
        y = sos[k, 0] * v + s[k, 0]
        out = y
        if k == n_sec - 1:
            out = min(max(y, max(lim[0], vm[0] - lim[4])), min(lim[1], vm[0] + lim[3]))
            if condition:
                y = out
        s[k, 0] = sos[k, 1] * v - sos[k, 4] * y + s[k, 1]
        s[k, 1] = sos[k, 2] * v - sos[k, 5] * y
        v = out
    vm[0] += lim[2] * (v - vm[0])
    return v


@njit(cache=True)
def _float_kernel(e, gain, sos, lim, s, u0):
    u = np.empty(e.size)
    vm = np.array([u0])
    for i in range(e.size):
        u[i] = float_step(s, gain * e[i], sos, lim, vm, True)
    return u


def run_float(gain, sos, e, *, output_limits_v=None, voltage_model=None, u0_v=0.0):
    """The float64 TDF-II cascade, as the exported C float step computes it.

    Parameters
    ----------
    gain : float
        Scalar gain; it multiplies the input.
    sos : array_like of float, shape (n_sections, 6)
        Second-order sections.
    e : array_like of float
        Input samples (gauge error, V), zero initial state.
    output_limits_v : (float, float), optional
        If given, the last section's output is clamped to (lo, hi) V and the
        clamped value drives its recursion (the anti-windup of :func:`run_fixed`).
    voltage_model : (float, float, float), optional
        (alpha, h_up, h_down): the current-limit window (module docstring).
    u0_v : float, default 0
        Output at rest before the first sample (the voltage model starts there; the last
        section's states are set to hold it with zero input).

    Returns
    -------
    ndarray of float
        Output samples, V.
    """
    lo, hi = (-np.inf, np.inf) if output_limits_v is None else output_limits_v
    sos = _check_sos(sos)
    s = np.zeros((len(sos), 2))
    s[-1] = u0_v, -sos[-1, 5] * u0_v            # at rest at u0 with zero input (see initial_state)
    lim = np.array([lo, hi, *((1.0, np.inf, np.inf) if voltage_model is None else voltage_model)], dtype=float)
    return _float_kernel(np.ascontiguousarray(e, dtype=float), float(gain), sos, lim, s, float(u0_v))


@njit(cache=True, inline="always")
def fixed_step(s, v, b, a, b_shift, frac, lim, vm, condition, peak):
    """One sample of the fixed-point cascade, line for line NAME_fixed_step of writers.py.

    ``v``: the input word (already clamped to the input range); ``s``: int64 states and
    ``vm[0]``: the voltage model word, updated in place. ``lim``: int64 [lo, hi, alpha_q,
    h_up, h_down] (:attr:`FixedPointController.limit_words`). The last section's output is
    clamped to the range and to the current-limit window around the model; with ``condition`` (anti-windup) the clamped word drives its recursion,
    else the raw one (saturated to int32). ``peak`` (n_sections, 3) collects the largest
    |y|, |s1|, |s2| before saturation; an empty ``peak`` (0 rows) skips that bookkeeping
    (the closed loop's hot path does not read it). int64 never overflows here (module docstring).
    Returns the output word.
    """
    n_sec = b.shape[0]
    track = peak.shape[0] > 0
    top, bottom = np.int64(2**31 - 1), np.int64(-2**31)
    one, half = np.int64(1) << frac, np.int64(1) << (frac - 1)
    for k in range(n_sec):
        sh = b_shift[k]
        p0, p1, p2 = b[k, 0] * v, b[k, 1] * v, b[k, 2] * v
        if sh >= 0:
            p0, p1, p2 = p0 >> sh, p1 >> sh, p2 >> sh
        else:
            m = np.int64(1) << -sh
            p0, p1, p2 = p0 * m, p1 * m, p2 * m
        y = (p0 + s[k, 0] * one + half) >> frac
        if track:
            peak[k, 0] = max(peak[k, 0], abs(y))
        if k == n_sec - 1:
            lo = max(lim[0], vm[0] - lim[4])
            hi = min(lim[1], vm[0] + lim[3])
            out = min(max(y, lo), hi)
            y = out if condition else min(max(y, bottom), top)
        else:
            y = min(max(y, bottom), top)
            out = y
        s1 = (p1 - a[k, 0] * y + s[k, 1] * one + half) >> frac
        s2 = (p2 - a[k, 1] * y + half) >> frac
        if track:
            peak[k, 1] = max(peak[k, 1], abs(s1))
            peak[k, 2] = max(peak[k, 2], abs(s2))
        s[k, 0] = min(max(s1, bottom), top)
        s[k, 1] = min(max(s2, bottom), top)
        v = out
    vm[0] += ((v - vm[0]) * lim[2] + (np.int64(1) << (ALPHA_FRAC_BITS - 1))) >> ALPHA_FRAC_BITS
    return v


@njit(cache=True)
def _fixed_kernel(x, b, a, b_shift, frac, in_lim, lim, s, u0_w):
    peak = np.zeros((b.shape[0], 3), np.int64)
    out = np.empty(x.size, np.int64)
    vm = np.array([u0_w])
    for i in range(x.size):
        v = min(max(x[i], -in_lim), in_lim)
        out[i] = fixed_step(s, v, b, a, b_shift, frac, lim, vm, True, peak)
    return out, peak


def initial_state(fxp, u0_v=0.0):
    """(states, output word) of the cascade at rest at output ``u0_v`` with zero input.

    The earlier sections rest at zero; the last (integrator) section holds u0: y = s1 = u0
    and s2 = round(-a2 u0), which the step maps to themselves (a1 = -(1 + a2) exactly).
    """
    lo, hi = fxp.output_limits
    u0 = int(min(max(np.rint(u0_v * 2.0 ** fxp.output_frac_bits), lo), hi))
    s = np.zeros((len(fxp.b), 2), np.int64)
    f = fxp.a_frac_bits
    s[-1, 0] = u0
    s[-1, 1] = (-int(fxp.a[-1, 1]) * u0 + (1 << (f - 1))) >> f
    return s, np.int64(u0)


def _run(fxp, e, u0_v=0.0):
    s, u0 = initial_state(fxp, u0_v)
    return _fixed_kernel(fxp.input_words(np.atleast_1d(e)), fxp.b, fxp.a, fxp.b_shift.astype(np.int64),
                         fxp.a_frac_bits, fxp.input_limit, fxp.limit_words, s, u0)


def run_fixed(fxp, e, u0_v=0.0):
    """Bit-exact simulation of the exported C fixed-point step over a record.

    Parameters
    ----------
    fxp : FixedPointController
    e : array_like of float
        Input samples (gauge error, V), converted by ``fxp.input_words``.
    u0_v : float, default 0
        Output at rest before the first sample (:func:`initial_state`; 0: zero states).

    Returns
    -------
    ndarray of float
        Output samples, V: the output words times 2^-output_frac_bits (exact).
    """
    return _run(fxp, e, u0_v)[0] * 2.0 ** -fxp.output_frac_bits


def fixed_point_peaks(fxp, e):
    """Largest |y|, |s1|, |s2| of each section over a record, as fractions of the int32 range.

    Values are taken before saturation (for the last section's y, before the
    output clamp): below 1 means nothing saturated.

    Parameters
    ----------
    fxp : FixedPointController
    e : array_like of float
        Input samples (gauge error, V), as for :func:`run_fixed`.

    Returns
    -------
    ndarray of float, shape (n_sections, 3)
    """
    return _run(fxp, e)[1] / 2.0**31
