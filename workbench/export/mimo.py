"""The mirror's MIMO controller as firmware runs it: two matrices around three SISO cascades (issue 15, item 5).

A :class:`MimoController` is composed of three :class:`~workbench.controller.Controller` s (tip,
tilt, piston: each the SISO 32-bit cascade with its own words, header and validation; no second
copy of the cascade code) and the kinematic decoupler of :mod:`workbench.design.mimo` in words.

**Axis volts.** The design's axis loops map an axis error (rad, rad, m) to an axis command in the
same unit. Firmware runs them on "axis volts": axis a in units of ``axis_scale[a]`` (rad or m per
axis volt), chosen so that one axis volt moves the stack that axis moves most by one volt
(``axis_scale[a] = 1 / max_j |In[j, a]|``). A per-axis (diagonal) controller is unchanged by this
scaling (S^-1 K S = K), so the cascades are the design's, and the output range of each cascade
is in volts of its stacks' range. The matrices become

    gauge_to_axes = S^-1 Out   (axis V per firmware V of gauge reading),
    axes_to_stacks = In S      (stack V per axis V).

**Fixed-point step** (:meth:`MimoController.step_words`, bit for bit NAME_fixed_step of the
header :meth:`MimoController.write` generates; the gcc test runs both):

1. gauge words g_j (firmware V x 2^GF) -> acc_a = sum_j OUT_Q[a][j] g_j (int64; OUT_Q row a in
   Q(FO_a), every |word| < 2^30 so three products cannot overflow), q_a = (acc_a + 2^(sh_a - 1))
   >> sh_a with sh_a = FO_a + GF - FI_a, FI_a the axis cascade's input fraction bits;
2. e_a = sat32(r_a - q_a), r_a the reference in the same format; the axis cascade's own step
   (input clamp, sections, output clamp to its range, anti-windup) gives u_a (Q(FU_a));
3. stack j: acc_j = sum_a (IN_Q[j][a] u_a) >> (FN_a + FU_a - FA) (IN_Q column a in Q(FN_a),
   FA = min_a (FN_a + FU_a)), v_j = (acc_j + 2^(FA - FV - 1)) >> (FA - FV), clamped to the stack's
   amplifier range in Q(FV): the stack command in volts x 2^FV.

Right shifts are arithmetic (floor), as in the SISO header.

**Active damping (optional), per stack** (:func:`iff_step`, an exported IFF-damped design whose force
estimate is the stack's charge bridge, ``design_mimo(..., damping=True, iff_source="bridge")``). Each
stack's charge amplifier with its reference capacitor C_R (:mod:`workbench.selfsense.charge_amp`) reads
b_j = -(q_j - C_R,j V_t,j) / C_int = C_R,j V_p,j / C_int (V): the force on the structure,
F_hat_j = T_j C_int b_j / C_R,j, without the gauge in it. A fourth kind of cascade per stack (again a
SISO :class:`~workbench.controller.Controller`: words, header, validation) maps b_j (its input words,
``bridge_words``) to d_j = -g s / (s + w_l) F_hat_j in its output format FD_j, which step 3 adds to the
stack's accumulator before the clamp: v_j = clamp(((acc_j + 2^(FA - FV - 1)) >> (FA - FV)) + D_j) with
D_j = (d_j + 2^(FD_j - FV - 1)) >> (FD_j - FV) (or d_j << (FV - FD_j) when FD_j <= FV). Without it the
step and the header are the notch-only ones, unchanged.

**Current-limit window, per stack (with IFF).** The IFF's correction is added after the axis windows,
which bound only the outer loops' share of each stack's command; so with IFF the stack's whole command
is held within the same window the notch-only design keeps: v_j within M_j +/- h_j, M_j += alpha_j (v_j -
M_j) the stack's own RC model (alpha_j = 1 - exp(-T / (R_j C_j)), C_j its largest capacitance) of the
command it was sent, h_j = R_j min(I_source,j, I_sink,j) (:func:`stack_windows`). In words: before the
amplifier clamp, v_j = min(max(v_j, M_j - H_j), M_j + H_j) (H_j = floor(h_j 2^FV)), then M_j += ((v_j -
M_j) ALPHA_Q_j + 2^29) >> 30 (alpha in Q1.30, as the cascades' windows); M_j starts at the stack word of
the reset's axis outputs. The stack clamp is fed back to nothing: the axis cascades are conditioned on
their own box only, not on what this clamp removes. When the stacks' alphas are equal (as on the P-888.51
serials) M_j is In' m (the axis models) plus a model of the IFF part (the models are linear, until the
stack clamp cuts), and the axis box keeps the axes' share inside h_j, so what the clamp removes is mostly
the IFF's high-pass correction, which has no integrator to wind up; with unequal alphas M_j and In' m differ and the clamp may also cut the axes' share. On the large
tip step all three stack windows reach h_j and the clamp binds on the axes' share too; the verification shows
no windup there (README, mirror section), but nothing in the step prevents it. Without IFF none of this is in
the step.

**Current-limit window, per axis.** Each axis cascade carries the SISO cascade's own window
(:mod:`workbench.export.fixed_point`): a model m_a += alpha (u_a - m_a) of its output and the
output kept within m_a +/- h_a. With alpha the slowest stack's (1 - exp(-T / (R C)), C its
largest capacitance) and h_a = min_j R_j min(I_source,j, I_sink,j) / max_j sum_a |In'[j, a]|, every
stack's command stays within its current headroom of In' m (the stacks' voltage model when
their alphas are equal; the slowest alpha is the conservative choice otherwise), so the axis
integrators are conditioned on what the current-limited stacks can follow. The box is
conservative: a single-axis move slews at ~1 / max row sum (~40 %) of the fastest rate, and the
sink's larger limit is not used.

Loading (:meth:`MimoController.load`) validates: schema, three axes, finite 3 x 3 matrices of
full rank, each axis controller as :meth:`Controller.from_dict` does (finite, stable poles,
words), one sample rate, ordered stack ranges, and matrix words that are the float matrices
quantized (within half an LSB). :class:`MimoControllerError` names the file and the key.
"""

import hashlib
import json
import math
import re
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
from numba import njit

from ..controller import Controller, _array, plant_window
from ..errors import ControllerError, MimoControllerError
from ..report.output import write_text
from .fixed_point import ALPHA_FRAC_BITS, fixed_step, initial_state, quantize
from .sos import ExportError

__all__ = ["MimoController", "MimoControllerError", "MIMO_SCHEMA", "AXIS_KEYS", "is_mimo_controller_file", "mimo_step",
           "iff_step", "IFF_KEYS", "stack_windows"]

MIMO_SCHEMA = "workbench.mimo_controller/1"
AXIS_KEYS = ("tip", "tilt", "piston")
AXIS_UNITS = ("rad", "rad", "m")
IFF_KEYS = ("stack0", "stack1", "stack2")
_COEF_TOP_BITS = 30          # matrix words: |word| < 2^30
_AF = ALPHA_FRAC_BITS
_NO_WINDOW = 2 ** 40         # an unreachable stack window, in stack words (|v| < 2^31)


def _frac_for(max_abs, top_bits=_COEF_TOP_BITS):
    """Most fraction bits keeping |value| * 2^F < 2^top_bits (F may be > 31 for tiny values; capped at 62)."""
    if not max_abs > 0:
        return 0
    return int(min(62, top_bits - int(np.floor(np.log2(max_abs))) - 1))


def _words_rows(mat, frac):
    """int64 words of ``mat``, row i in Q(frac[i])."""
    return np.rint(mat * 2.0 ** np.asarray(frac, float)[:, None]).astype(np.int64)


@njit(cache=True)
def _cascade(s, e, in_lim, B, A, BSH, n, frac, lim, vm, no_peak):
    """One cascade's sample: the input word clamped to ``in_lim``, then
    :func:`~workbench.export.fixed_point.fixed_step` (anti-windup on, no peak bookkeeping)."""
    e = min(max(e, -in_lim), in_lim)
    return fixed_step(s[:n], e, B[:n], A[:n], BSH[:n], frac, lim, vm, True, no_peak)


@njit(cache=True)
def iff_step(b, s, vm, dv, B, A, BSH, nsec, frac, lim, in_lim, dsh):
    """The per-stack IFF cascades (module docstring): bridge words ``b`` in, stack-word corrections ``dv`` out.

    ``s`` (3, n_max, 2) and ``vm`` (3,) the cascades' states, updated in place; the rest is
    :attr:`MimoController.iff_plan` (``dsh``: FD_j - FV).
    """
    one = np.int64(1)
    no_peak = np.zeros((0, 3), np.int64)
    for j in range(3):
        d = _cascade(s[j], b[j], in_lim[j], B[j], A[j], BSH[j], nsec[j], frac[j], lim[j], vm[j:j + 1], no_peak)
        dv[j] = (d + (one << (dsh[j] - 1))) >> dsh[j] if dsh[j] >= 1 else d << (-dsh[j])


@njit(cache=True)
def mimo_step(g, r, s, vm, out, dv, sm, oq, osh, iq, ish, vsh, lw, B, A, BSH, nsec, frac, lim, in_lim, sw):
    """One sample of the MIMO fixed-point step (module docstring), bit for bit the header's NAME_fixed_step.

    ``g``, ``r``: gauge and reference words (int64, 3); ``s`` (3, n_max, 2) and ``vm`` (3,) the
    axis cascades' states and window models, updated in place; ``out`` receives the stack words;
    ``dv`` (int64, 3): the IFF's corrections in stack words (:func:`iff_step`; zeros without IFF);
    ``sm`` (int64, 3): the stacks' window models M_j, updated in place. The rest is
    :attr:`MimoController.plan` (its last, ``sw`` (3, 3): per stack [alpha Q1.30, H up, H down] of the
    stack window; without IFF an unreachable window). Each axis runs
    :func:`~workbench.export.fixed_point.fixed_step`.
    """
    top, bottom = np.int64(2 ** 31 - 1), np.int64(-2 ** 31)
    one = np.int64(1)
    u = np.empty(3, np.int64)
    no_peak = np.zeros((0, 3), np.int64)
    for a in range(3):
        acc = oq[a, 0] * g[0] + oq[a, 1] * g[1] + oq[a, 2] * g[2]
        q = (acc + (one << (osh[a] - 1))) >> osh[a]
        e = min(max(r[a] - q, bottom), top)
        u[a] = _cascade(s[a], e, in_lim[a], B[a], A[a], BSH[a], nsec[a], frac[a], lim[a], vm[a:a + 1], no_peak)
    for j in range(3):
        acc = np.int64(0)
        for a in range(3):
            acc += (iq[j, a] * u[a]) >> ish[a]
        v = ((acc + (one << (vsh - 1))) >> vsh) + dv[j]
        v = min(max(v, sm[j] - sw[j, 2]), sm[j] + sw[j, 1])
        out[j] = min(max(v, lw[j, 0]), lw[j, 1])
        sm[j] += ((out[j] - sm[j]) * sw[j, 0] + (one << (_AF - 1))) >> _AF


@dataclass(frozen=True, eq=False)
class MimoController:
    """Gauges -> axes matrix, three axis cascades, axes -> stacks matrix, in 32-bit words.

    Attributes
    ----------
    name : str
        File stem and C prefix.
    axes : dict
        ``{"tip": Controller, "tilt": Controller, "piston": Controller}``: axis volts of error in,
        axis volts out (each with fixed-point words).
    axis_scale : ndarray, shape (3,)
        rad (tip, tilt) or m (piston) per axis volt.
    gauge_to_axes : ndarray, shape (3, 3)
        Axis volts per firmware volt of each gauge reading (S^-1 Out).
    axes_to_stacks : ndarray, shape (3, 3)
        Stack volts per axis volt (In S).
    stack_limits_v : ndarray, shape (3, 2)
        Each stack's amplifier range, V.
    gauge_frac_bits, stack_frac_bits : int
        Fraction bits of the gauge reading words and of the stack command words.
    record : dict
        Everything else of the JSON (provenance, design summary, notes).
    source : str
    iff : dict, optional
        The active-damping path: ``{"stack0": Controller, "stack1": ..., "stack2": ...}`` (bridge
        reading V in, stack V out) and ``"bridge"``: a dict of the analog bridge it was designed for
        (``reference_capacitance_f``, ``integrator_capacitance_f``, ``transducer_n_per_v``, ``gain_v_per_n``,
        ``corner_hz``, ``adc_range_v``, ``adc_bits``, ``out_noise_v_rms``; checked on load against the cascades'
        gains). None: no IFF.
    """

    name: str
    axes: dict
    axis_scale: np.ndarray
    gauge_to_axes: np.ndarray
    axes_to_stacks: np.ndarray
    stack_limits_v: np.ndarray
    gauge_frac_bits: int
    stack_frac_bits: int
    record: dict = field(default_factory=dict)
    source: str = ""
    iff: dict = None

    # ------------------------------------------------------------------ words
    @property
    def sample_rate_hz(self):
        return self.axes["tip"].sample_rate_hz

    @property
    def dt_s(self):
        return 1.0 / self.sample_rate_hz

    @property
    def out_frac_bits(self):
        """FO_a: fraction bits of row a of the gauge -> axes words."""
        return np.array([_frac_for(np.abs(r).max()) for r in self.gauge_to_axes], dtype=np.int64)

    @property
    def in_frac_bits(self):
        """FN_a: fraction bits of column a of the axes -> stacks words."""
        return np.array([_frac_for(np.abs(c).max()) for c in self.axes_to_stacks.T], dtype=np.int64)

    @property
    def out_q(self):
        return _words_rows(self.gauge_to_axes, self.out_frac_bits)

    @property
    def in_q(self):
        return _words_rows(self.axes_to_stacks.T, self.in_frac_bits).T

    def _fixed(self):
        return [self.axes[k].fixed for k in AXIS_KEYS]

    @property
    def out_shift(self):
        """sh_a = FO_a + GF - FI_a (right shift from the gauge products to the axis input word)."""
        return np.array([fo + self.gauge_frac_bits - f.input_frac_bits
                         for fo, f in zip(self.out_frac_bits, self._fixed())], dtype=np.int64)

    @property
    def acc_frac_bits(self):
        """FA = min_a (FN_a + FU_a)."""
        return int(min(fn + f.output_frac_bits for fn, f in zip(self.in_frac_bits, self._fixed())))

    @property
    def in_shift(self):
        """Per axis: right shift of its products to FA."""
        return np.array([fn + f.output_frac_bits - self.acc_frac_bits
                         for fn, f in zip(self.in_frac_bits, self._fixed())], dtype=np.int64)

    @property
    def stack_limit_words(self):
        sc = 2.0 ** self.stack_frac_bits
        return np.column_stack([np.ceil(self.stack_limits_v[:, 0] * sc), np.floor(self.stack_limits_v[:, 1] * sc)]
                               ).astype(np.int64)

    def gauge_words(self, g_v):
        """Gauge readings (firmware V) as words, rounded to nearest, saturated to int32."""
        return np.clip(np.rint(np.asarray(g_v, float) * 2.0 ** self.gauge_frac_bits), -2 ** 31, 2 ** 31 - 1
                       ).astype(np.int64)

    def reference_words(self, r_axes):
        """References in axis units (rad, rad, m) as each cascade's input words (saturated to int32)."""
        r = np.asarray(r_axes, float) / self.axis_scale
        fi = np.array([f.input_frac_bits for f in self._fixed()], float)
        return np.clip(np.rint(r * 2.0 ** fi), -2 ** 31, 2 ** 31 - 1).astype(np.int64)

    # ------------------------------------------------------------------ firmware step
    @cached_property
    def plan(self):
        """The step's words as int64 arrays (:func:`mimo_step`'s arguments after the inputs and state), once."""
        fx = self._fixed()
        nmax = max(len(f.b) for f in fx)
        B = np.zeros((3, nmax, 3), np.int64)
        A = np.zeros((3, nmax, 2), np.int64)
        BSH = np.zeros((3, nmax), np.int64)
        for a, f in enumerate(fx):
            n = len(f.b)
            B[a, :n], A[a, :n], BSH[a, :n] = f.b, f.a, f.b_shift
        nsec = np.array([len(f.b) for f in fx], np.int64)
        frac = np.array([f.a_frac_bits for f in fx], np.int64)
        lim = np.array([f.limit_words for f in fx], np.int64)
        in_lim = np.array([f.input_limit for f in fx], np.int64)
        return (self.out_q, self.out_shift, self.in_q, self.in_shift,
                np.int64(self.acc_frac_bits - self.stack_frac_bits), self.stack_limit_words,
                B, A, BSH, nsec, frac, lim, in_lim, self.stack_window_words)

    @property
    def stack_window_words(self):
        """int64 (3, 3): per stack [alpha in Q1.30, H up, H down in stack words] of the stack window (module
        docstring); without IFF alpha = 1 and an unreachable window (the step is the notch-only one)."""
        if self.iff is None:
            return np.tile(np.array([1 << _AF, _NO_WINDOW, _NO_WINDOW], np.int64), (3, 1))
        w = self.iff["stack_window"]
        sc = 2.0 ** self.stack_frac_bits
        return np.column_stack([np.rint(np.asarray(w["alpha"], float) * 2.0 ** _AF),
                                np.floor(np.asarray(w["headroom_v"], float) * sc),
                                np.floor(np.asarray(w["headroom_v"], float) * sc)]).astype(np.int64)

    def stack_words_at(self, u_words):
        """The step's stack words (before IFF and the stack window) of axis output words ``u_words``."""
        iq, ish, vsh, lw = self.in_q, self.in_shift, self.acc_frac_bits - self.stack_frac_bits, self.stack_limit_words
        out = np.empty(3, np.int64)
        for j in range(3):
            acc = sum((int(iq[j, a]) * int(u_words[a])) >> int(ish[a]) for a in range(3))
            out[j] = min(max((acc + (1 << (vsh - 1))) >> vsh, int(lw[j, 0])), int(lw[j, 1]))
        return out

    @cached_property
    def iff_plan(self):
        """:func:`iff_step`'s arguments after its inputs and state (None without IFF)."""
        if self.iff is None:
            return None
        fx = [self.iff[k].fixed for k in IFF_KEYS]
        nmax = max(len(f.b) for f in fx)
        B = np.zeros((3, nmax, 3), np.int64)
        A = np.zeros((3, nmax, 2), np.int64)
        BSH = np.zeros((3, nmax), np.int64)
        for j, f in enumerate(fx):
            n = len(f.b)
            B[j, :n], A[j, :n], BSH[j, :n] = f.b, f.a, f.b_shift
        return (B, A, BSH, np.array([len(f.b) for f in fx], np.int64), np.array([f.a_frac_bits for f in fx], np.int64),
                np.array([f.limit_words for f in fx], np.int64), np.array([f.input_limit for f in fx], np.int64),
                self.iff_shift)

    @property
    def iff_shift(self):
        """FD_j - FV per stack (int64, 3)."""
        return np.array([self.iff[k].fixed.output_frac_bits - self.stack_frac_bits for k in IFF_KEYS], np.int64)

    def bridge_words(self, b_v):
        """Bridge readings (V, per stack) as each IFF cascade's input words, rounded, saturated to int32."""
        fi = np.array([self.iff[k].fixed.input_frac_bits for k in IFF_KEYS], float)
        return np.clip(np.rint(np.asarray(b_v, float) * 2.0 ** fi), -2 ** 31, 2 ** 31 - 1).astype(np.int64)

    def reset_iff(self, u0_axes_v=(0.0, 0.0, 0.0)):
        """IFF state at rest with the axis cascades at ``u0_axes_v`` (as :meth:`reset`): the cascades' states
        (3, n_max, 2), their models (3,) and the stack windows' models M_j (3,: the stack words of the axis
        outputs), int64; None without IFF."""
        if self.iff is None:
            return None
        nmax = max(len(self.iff[k].fixed.b) for k in IFF_KEYS)
        return np.zeros((3, nmax, 2), np.int64), np.zeros(3, np.int64), self.stack_words_at(self.reset(u0_axes_v)[1])

    def reset(self, u0_axes_v=(0.0, 0.0, 0.0)):
        """State (cascade states (3, n_max, 2), window models (3,), int64) at rest at ``u0_axes_v`` (axis V), zero error."""
        fx = self._fixed()
        nmax = max(len(f.b) for f in fx)
        s = np.zeros((3, nmax, 2), np.int64)
        vm = np.zeros(3, np.int64)
        for a, (f, u0) in enumerate(zip(fx, u0_axes_v)):
            sa, w = initial_state(f, float(u0))
            s[a, :len(f.b)] = sa
            vm[a] = w
        return s, vm

    def step_words(self, state, g_w, r_w, b_w=None, iff_state=None):
        """One sample: gauge words and reference words in, stack command words out (``state`` updated).

        With IFF: ``b_w`` the bridge words and ``iff_state`` (:meth:`reset_iff`, updated).
        :func:`mimo_step` (after :func:`iff_step`): bit for bit NAME_fixed_step of the header (module docstring).
        """
        s, vm = state
        out = np.empty(3, np.int64)
        dv = np.zeros(3, np.int64)
        if self.iff is not None:
            iff_step(np.asarray(b_w, np.int64), iff_state[0], iff_state[1], dv, *self.iff_plan)
            sm = iff_state[2]
        else:
            sm = np.zeros(3, np.int64)
        mimo_step(np.asarray(g_w, np.int64), np.asarray(r_w, np.int64), s, vm, out, dv, sm, *self.plan)
        return out

    def stack_volts(self, words):
        return np.asarray(words, float) * 2.0 ** -self.stack_frac_bits

    def axis_to_stack_volts(self, u_axes_v):
        """Float: stack volts of axis commands (axis V)."""
        return self.axes_to_stacks @ np.asarray(u_axes_v, float)

    def run(self, g_v, r_axes, u0_axes_v=(0.0, 0.0, 0.0), b_v=None):
        """The fixed-point step over records: gauges (samples, 3) firmware V, references (samples, 3) axis units.

        ``b_v`` (samples, 3): the bridge readings, V (needed with IFF).

        Returns
        -------
        ndarray, shape (samples, 3)
            Stack commands, V (words times 2^-FV, exact).
        """
        gw = self.gauge_words(g_v)
        rw = self.reference_words(r_axes)
        if self.iff is not None and b_v is None:
            raise ValueError("this controller damps with IFF: give the bridge readings b_v (samples, 3), V")
        bw = None if self.iff is None else self.bridge_words(b_v)
        st, ist = self.reset(u0_axes_v), self.reset_iff(u0_axes_v)
        out = np.empty(gw.shape, np.int64)
        for k in range(gw.shape[0]):
            out[k] = self.step_words(st, gw[k], rw[k], None if bw is None else bw[k], ist)
        return self.stack_volts(out)

    # ------------------------------------------------------------------ build
    @classmethod
    def from_design(cls, design, fsm, *, name="fsm_controller", record=None, coeff_bits=32):
        """Export a :class:`~workbench.design.mimo.MimoDesign` for the mirror ``fsm``.

        An IFF-damped design exports when its force estimate is the charge bridge (``iff_source="bridge"``) and its
        force-estimate noise fits each stack's current-window budget (:func:`~workbench.design.mimo.check_iff_noise`;
        else :class:`ExportError`); its stacks' whole commands are held in their windows (:func:`stack_windows`).
        each stack's IFF becomes a cascade from the bridge reading (module docstring), designed for the
        charge amplifier :class:`~workbench.selfsense.charge_amp.ChargeAmpParams` (C_int, its ADC range)
        with C_R = the design's reference capacitance. The gauge-fed estimate (``"charge+gauge"``) does not
        export: it puts the gauges' noise into the drive (~8 N of force estimate per 7 mV of reading).

        Each axis cascade: :meth:`Controller.from_lti` of the axis' discrete controller, input range
        the largest |axis volts| the gauges' DAC ranges can produce, output range the axis volts that
        keep every stack within its amplifier range with the other axes at their centre (piston: the
        whole range), the axis current-limit window of the module docstring.
        """
        if design.iff is not None and design.iff.source != "bridge":
            raise ExportError(f"the IFF-damped design's force estimate is {design.iff.source!r}: only the charge "
                              f"bridge (design_mimo(..., damping=True, iff_source=\"bridge\")) exports; or export "
                              f"the notch-only design (damping=False)")
        dec = design.decoupler
        dt = float(design.axes["tip"].controller_d.dt)
        if design.iff is not None:
            # the same current-window budget the design searched under (design.mimo.check_iff_noise)
            from ..design.mimo import check_iff_noise
            from ..errors import DesignError
            try:
                check_iff_noise(fsm, design.iff, dt)
            except DesignError as err:
                raise ExportError(f"{err}; re-design with design_mimo's noise budget on") from err
        inv = np.asarray(dec.in_v_per_q, float)
        scale = 1.0 / np.abs(inv).max(axis=0)
        g2a = np.asarray(dec.out_q_per_v, float) / scale[:, None]
        a2s = inv * scale[None, :]
        stacks = fsm.stacks
        lim = np.array([[pz.voltage_min_v, pz.voltage_max_v] for pz in stacks], float)
        dac = np.array([pl.gauge.dac_range_v for pl in fsm.plants], float)
        in_range = np.abs(g2a) @ dac
        # the axis window (module docstring): the slowest stack RC model, the smallest current headroom,
        # shared so that the box of axis deviations maps inside every stack's window
        windows = [plant_window(pl, dt) for pl in fsm.plants]
        if any(w is None or not pl.pzt.series_resistance_ohm > 0 for w, pl in zip(windows, fsm.plants)):
            # R out gives a per-stack slew window (alpha 1), not the RC window the shared axis window is built from
            raise ExportError("a stack has no series resistor (R = 0): no RC current-limit window to build the axis "
                              "window from")
        alpha = float(min(w[0] for w in windows))
        h = float(min(min(w[1], w[2]) for w in windows))
        head = np.full(3, h / np.abs(a2s).sum(axis=1).max())
        axes = {}
        for a, key in enumerate(AXIS_KEYS):
            col = a2s[:, a]
            if key == "piston":
                lo = np.max(np.where(col > 0, lim[:, 0] / col, lim[:, 1] / col))
                hi = np.min(np.where(col > 0, lim[:, 1] / col, lim[:, 0] / col))
            else:
                half = 0.5 * (lim[:, 1] - lim[:, 0])
                nz = np.abs(col) > 1e-12 * np.abs(col).max()
                hi = float(np.min(half[nz] / np.abs(col[nz])))
                lo = -hi
            k_d = design.axes[key].controller_d
            c = Controller.from_lti(k_d, dt_s=float(k_d.dt), output_limits_v=(float(lo), float(hi)),
                                    input_range_v=float(in_range[a]), coeff_bits=coeff_bits, window=False,
                                    name=f"{name}_{key}", method="mirror axis loop (design.mimo)",
                                    record={"axis": key, "axis_unit": AXIS_UNITS[a],
                                            "notch": design.notches.get(key)})
            model = (alpha, float(head[a]), float(head[a]))
            fxp = quantize(c.gain, np.array(c.sos), c.dt_s, input_range_v=float(in_range[a]),
                           output_limits_v=c.output_limits_v, f_max_hz=c.fixed.f_max_hz, coeff_bits=coeff_bits,
                           voltage_model=model)
            aw = {"method": "conditioned_cascade", "output_limits_v": list(c.output_limits_v),
                  "voltage_model": {"alpha": model[0], "headroom_v": [model[1], model[2]]},
                  "description": "axis window: the axis output stays within +/- headroom of its model "
                                 "m += alpha (u - m), so every stack's command stays within R min(I_source, "
                                 "I_sink) of In m (workbench/export/mimo.py)"}
            axes[key] = replace(c, fixed=fxp, voltage_model=model, window_source="file", series_resistor_out=False,
                                record={**c.record, "anti_windup": aw}, max_pole_radius=fxp.max_pole_radius)
        dv = max(np.abs(lim).max(), 1e-9)
        rec = {"provenance": _mirror_provenance(fsm), **(record or {})}
        iff = None
        if design.iff is not None:
            iff = _iff_cascades(design.iff, fsm, dt, name, coeff_bits)
            iff["stack_window"] = stack_windows(fsm, dt)
        return cls(name=name, axes=axes, axis_scale=scale, gauge_to_axes=g2a, axes_to_stacks=a2s,
                   stack_limits_v=lim, gauge_frac_bits=_frac_for(dac.max(), 31),
                   stack_frac_bits=_frac_for(dv, 31), record=rec, iff=iff)

    # ------------------------------------------------------------------ JSON
    def to_dict(self):
        """The JSON form: schema, matrices (float and words), the three axis controllers' JSON."""
        return {"schema": MIMO_SCHEMA, "name": self.name, "sample_rate_hz": self.sample_rate_hz,
                **{k: v for k, v in self.record.items() if k not in _TOP_KEYS},
                "axes": list(AXIS_KEYS), "axis_units": list(AXIS_UNITS),
                "axis_scale": self.axis_scale.tolist(),
                "gauge_to_axes": self.gauge_to_axes.tolist(), "axes_to_stacks": self.axes_to_stacks.tolist(),
                "stack_limits_v": self.stack_limits_v.tolist(),
                "fixed_point": {"gauge_frac_bits": self.gauge_frac_bits, "stack_frac_bits": self.stack_frac_bits,
                                "gauge_to_axes_q": self.out_q.tolist(),
                                "gauge_to_axes_frac_bits": self.out_frac_bits.tolist(),
                                "axes_to_stacks_q": self.in_q.tolist(),
                                "axes_to_stacks_frac_bits": self.in_frac_bits.tolist(),
                                "note": "step: module docstring of workbench/export/mimo.py; the per-axis "
                                        "cascades are controllers[axis], each with its axis current-limit window"},
                "controllers": {k: c.to_dict() for k, c in self.axes.items()},
                **({} if self.iff is None else {"iff": {"bridge": dict(self.iff["bridge"]),
                                                        "stack_window": dict(self.iff["stack_window"]),
                                                        "controllers": {k: self.iff[k].to_dict() for k in IFF_KEYS},
                                                        "note": "stack j's command += this cascade's output; its input "
                                                                "is the charge bridge's reading b_j = -(q_j - C_R V_t,j) "
                                                                "/ C_int, V (workbench/export/mimo.py)"}})}

    def write(self, out_dir, name=None):
        """Write NAME.json, NAME.h and each axis' NAME_AXIS.{json,h,csv,mat} (atomic writes).

        Returns
        -------
        dict of Path
            ``"json"``, ``"h"`` and ``"<axis>_h"`` etc.
        """
        name = name or self.name
        out_dir = Path(out_dir)
        paths = {}
        for k, c in self.axes.items():
            for ext, p in c.write(out_dir, f"{name}_{k}").items():
                paths[f"{k}_{ext}"] = p
        for k in (IFF_KEYS if self.iff is not None else ()):
            for ext, p in self.iff[k].write(out_dir, f"{name}_iff_{k}").items():
                paths[f"iff_{k}_{ext}"] = p
        d = self.to_dict()
        d["name"] = name
        paths["json"] = write_text(out_dir / f"{name}.json", json.dumps(d, indent=1) + "\n")
        paths["h"] = write_text(out_dir / f"{name}.h", self.header(name))
        return paths

    @classmethod
    def from_dict(cls, data, *, source="", allow_unstable=False):
        """Validate and build from the JSON form (see the module docstring for what is checked)."""
        src = source or "<mimo controller>"
        if not isinstance(data, dict):
            raise MimoControllerError(src, "", "a MIMO controller JSON is an object; re-export it")
        if data.get("schema") != MIMO_SCHEMA:
            got = data.get("schema")
            hint = (" (a SISO controller: it drives one stack; the mirror needs the MIMO controller "
                    "`workbench study studies/fsm_servo.toml` exports)" if got is None and "sos" in data else "")
            raise MimoControllerError(src, "schema", f"got {got!r}; expected {MIMO_SCHEMA!r}{hint}")
        name = data.get("name", "fsm_controller")
        if not (isinstance(name, str) and _C_NAME.match(name)):
            raise MimoControllerError(src, "name", f"got {name!r}; a C identifier (letters, digits, '_', not starting "
                                                   f"with a digit): it names the header's functions and files")
        axes_list = data.get("axes")
        if axes_list != list(AXIS_KEYS):
            raise MimoControllerError(src, "axes", f"got {axes_list!r}; expected {list(AXIS_KEYS)}")

        def mat(key, shape):
            if key not in data:
                raise MimoControllerError(src, key, "is missing; re-export the controller")
            m = _array(src, key, data[key], f"an array of shape {shape}", len(shape), MimoControllerError)
            if m.shape != shape:
                raise MimoControllerError(src, key, f"must have shape {shape}; got {m.shape}")
            return m
        scale = mat("axis_scale", (3,))
        if np.any(scale <= 0):
            raise MimoControllerError(src, "axis_scale", f"must be positive (rad or m per axis volt); got {scale}")
        g2a, a2s = mat("gauge_to_axes", (3, 3)), mat("axes_to_stacks", (3, 3))
        for key, m in (("gauge_to_axes", g2a), ("axes_to_stacks", a2s)):
            if np.linalg.cond(m) > 1e8:
                raise MimoControllerError(src, key, f"is singular (condition {np.linalg.cond(m):.3g}): the axes "
                                                    f"cannot be told apart; re-export from the mirror's kinematics")
        lim = mat("stack_limits_v", (3, 2))
        if np.any(lim[:, 0] >= lim[:, 1]):
            raise MimoControllerError(src, "stack_limits_v", f"each row must be ordered [lo, hi] V; got {lim.tolist()}")
        ctr = data.get("controllers")
        if not isinstance(ctr, dict):
            raise MimoControllerError(src, "controllers", "must be a table {tip, tilt, piston} of exported "
                                                          "controllers")
        axes = {}
        for k in AXIS_KEYS:
            axes[k] = _load_cascade(src, ctr, k, "controllers", allow_unstable)
        rates = {k: c.sample_rate_hz for k, c in axes.items()}
        fs = data.get("sample_rate_hz")
        if not isinstance(fs, (int, float)) or any(abs(r - fs) > 1e-9 * fs for r in rates.values()):
            raise MimoControllerError(src, "sample_rate_hz", f"{fs!r} must equal every axis controller's rate "
                                                             f"{rates}")
        fp = data.get("fixed_point")
        if not isinstance(fp, dict):
            raise MimoControllerError(src, "fixed_point", "is missing; re-export the controller")
        try:
            gf, vf = int(fp["gauge_frac_bits"]), int(fp["stack_frac_bits"])
        except (KeyError, TypeError, ValueError) as exc:
            raise MimoControllerError(src, "fixed_point", f"needs integer gauge_frac_bits and stack_frac_bits "
                                                          f"({exc})") from None
        if not (0 <= gf <= 31 and 0 <= vf <= 31):
            raise MimoControllerError(src, "fixed_point", f"fraction bits must lie in 0..31; got {gf}, {vf}")
        rec = {k: v for k, v in data.items() if k not in _TOP_KEYS}
        iff = _load_iff(src, data.get("iff"), fs, allow_unstable, lim) if "iff" in data else None
        out = cls(name=str(data.get("name") or "fsm_controller"), axes=axes, axis_scale=scale, gauge_to_axes=g2a,
                  axes_to_stacks=a2s, stack_limits_v=lim, gauge_frac_bits=gf, stack_frac_bits=vf, record=rec,
                  source=str(source), iff=iff)
        for key, words, want in (("gauge_to_axes_q", fp.get("gauge_to_axes_q"), out.out_q),
                                 ("axes_to_stacks_q", fp.get("axes_to_stacks_q"), out.in_q)):
            try:
                w = np.asarray(words, dtype=np.int64)
            except (TypeError, ValueError):
                w = None
            if w is None or w.shape != (3, 3) or not np.array_equal(w, want):
                raise MimoControllerError(src, f"fixed_point.{key}", "are not the float matrix quantized as the "
                                                                     "exporter does; re-export the controller")
        if np.any(out.out_shift < 1) or out.acc_frac_bits - vf < 1:
            raise MimoControllerError(src, "fixed_point", "word formats leave no rounding shift; re-export")
        return out

    @classmethod
    def load(cls, path, *, allow_unstable=False):
        """Load and validate NAME.json (:class:`MimoControllerError` naming the file and key)."""
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise MimoControllerError(path, "", f"cannot be read ({exc.strerror or exc}); give the exported "
                                                f"MIMO controller NAME.json") from None
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise MimoControllerError(path, "", f"is not JSON ({exc}); give the exported MIMO controller .json") \
                from None
        return cls.from_dict(data, source=str(path), allow_unstable=allow_unstable)

    def check_mirror(self, fsm):
        """Refuse a damped export whose numbers are not those of ``fsm``'s stacks (:class:`MimoControllerError`).

        The exporter writes ``iff.stack_window`` as :func:`stack_windows` of the mirror's serial files and the
        IFF cascades as the Tustin high-pass prewarped at ``iff.bridge.corner_hz``, whose pole is
        z_p = (1 - c) / (1 + c), c = tan(pi f_l T). A window off the stacks' (relative 1e-6: the exporter's
        own numbers) would hold each command in a current window the stack does not have (alpha 0.5 for the
        stacks' 0.10 lets the command lead the stack's RC response five times faster; headroom 1e300 V
        holds nothing); a corner that is not the cascades' is a bridge the file does not describe.
        Without IFF, or for a controller whose provenance names another mirror file (by SHA-256: verify warns
        that it was exported for another mirror), nothing to check.
        """
        if self.iff is None:
            return
        sha = (self.record.get("provenance") or {}).get("plant_sha256")
        if sha and fsm.source and Path(fsm.source).is_file() and \
                sha != hashlib.sha256(Path(fsm.source).read_bytes()).hexdigest():
            return
        want = stack_windows(fsm, self.dt_s)
        for k in ("alpha", "headroom_v"):
            got = np.asarray(self.iff["stack_window"][k], float)
            if not np.allclose(got, want[k], rtol=1e-6, atol=0):
                raise MimoControllerError(self.source or self.name, f"iff.stack_window.{k}",
                                          f"{got.tolist()} is not the current-limit window of the stacks of "
                                          f"{fsm.source} ({[float(f'{v:.6g}') for v in want[k]]}: R, the largest "
                                          f"capacitance and min(I_source, I_sink) of each serial file); re-export "
                                          f"the controller for this mirror")
        f_l = float(self.iff["bridge"]["corner_hz"])
        if not f_l < 0.5 / self.dt_s:
            raise MimoControllerError(self.source or self.name, "iff.bridge.corner_hz",
                                      f"{f_l:g} Hz is not below the Nyquist frequency {0.5 / self.dt_s:g} Hz of the "
                                      f"cascades; re-export the controller")
        c = math.tan(math.pi * f_l * self.dt_s)
        z_want = (1.0 - c) / (1.0 + c)
        for k in IFF_KEYS:
            poles = np.concatenate([np.roots(row[3:]) for row in np.asarray(self.iff[k].sos, float)])
            if not np.any(np.abs(poles - z_want) <= 1e-6):
                raise MimoControllerError(self.source or self.name, "iff.bridge.corner_hz",
                                          f"{f_l:g} Hz puts the high-pass pole at z = {z_want:.6g}; the cascade "
                                          f"iff.controllers.{k} has its poles at {np.round(poles, 6).tolist()}: the "
                                          f"bridge numbers are not the cascades'; re-export the controller")

    # ------------------------------------------------------------------ C
    def header(self, name=None):
        """NAME.h: includes the three axis headers and runs the step of the module docstring."""
        name = name or self.name
        if not _C_NAME.match(name):
            raise MimoControllerError(self.name, "name", f"got {name!r}; the header needs a C identifier")
        up = name.upper()
        ax = [f"{name}_{k}" for k in AXIS_KEYS]

        def arr(m):
            return ",\n".join("    {" + ", ".join(f"INT64_C({int(v)})" for v in row) + "}" for row in m)
        lw = self.stack_limit_words
        has = self.iff is not None
        fi = [f"{name}_iff_{k}" for k in IFF_KEYS]
        i_inc = "".join(f'#include "{h}.h"\n' for h in fi) if has else ""
        sw = self.stack_window_words
        i_def = (f"static const int {up}_IFF_SHIFT[3] = {{{', '.join(str(int(v)) for v in self.iff_shift)}}};\n"
                 f"static const int64_t {up}_STACK_WINDOW_Q[3][3] = {{\n{arr(sw)}\n}};\n"
                 if has else "")
        i_st = (f" {fi[0]}_fixed_state i0; {fi[1]}_fixed_state i1; {fi[2]}_fixed_state i2; int64_t m[3];"
                if has else "")
        i_reset = (("".join(f"    {h}_fixed_reset(&st->i{j}, 0);\n" for j, h in enumerate(fi))
                    + f"    for (int j = 0; j < 3; j++) {{\n"
                      f"        int64_t acc = 0;\n"
                      f"        for (int a = 0; a < 3; a++) acc += ({up}_IN_Q[j][a] * (int64_t)u0_q[a]) >> {up}_IN_SHIFT[a];\n"
                      f"        int64_t v = (acc + ((int64_t)1 << ({up}_V_SHIFT - 1))) >> {up}_V_SHIFT;\n"
                      f"        st->m[j] = v < {up}_STACK_LIMITS_Q[j][0] ? {up}_STACK_LIMITS_Q[j][0] : "
                      f"v > {up}_STACK_LIMITS_Q[j][1] ? {up}_STACK_LIMITS_Q[j][1] : v;\n    }}\n") if has else "")
        i_arg = ", const int32_t b_q[3]" if has else ""
        i_step = (("    int64_t d[3];\n" + "".join(f"    d[{j}] = {h}_fixed_step(&st->i{j}, b_q[{j}]);\n"
                                                  for j, h in enumerate(fi))
                   + f"    for (int j = 0; j < 3; j++) d[j] = {up}_IFF_SHIFT[j] >= 1 ? (d[j] + ((int64_t)1 << "
                     f"({up}_IFF_SHIFT[j] - 1))) >> {up}_IFF_SHIFT[j] : d[j] * ((int64_t)1 << -{up}_IFF_SHIFT[j]);\n")
                  if has else "")
        i_add = " + d[j]" if has else ""
        i_win = (f"        v = v < st->m[j] - {up}_STACK_WINDOW_Q[j][2] ? st->m[j] - {up}_STACK_WINDOW_Q[j][2] : "
                 f"v > st->m[j] + {up}_STACK_WINDOW_Q[j][1] ? st->m[j] + {up}_STACK_WINDOW_Q[j][1] : v;\n" if has else "")
        i_upd = (f"        st->m[j] += ((v - st->m[j]) * {up}_STACK_WINDOW_Q[j][0] + ((int64_t)1 << {ALPHA_FRAC_BITS - 1})) "
                 f">> {ALPHA_FRAC_BITS};\n" if has else "")
        i_doc = ("\n * IFF (active damping): bridge words b_q[3] (each stack's charge bridge, V, in its IFF cascade's "
                 "input format)\n * in; d[j] = STACK_iff_fixed_step(b_q[j]) shifted to stack words is added before "
                 "the clamp,\n * and the sum is held within the stack's current-limit window: v[j] within m[j] +/- "
                 "STACK_WINDOW_Q[j][1..2],\n * m[j] += ((v[j] - m[j]) STACK_WINDOW_Q[j][0] + 2^29) >> 30 (alpha Q1.30) "
                 "after the amplifier clamp." if has else "")
        return f"""\
/* {name}.h: the mirror's MIMO controller "{name}", exported by workbench.export.mimo. Re-export rather than edit.
 *
 * Per sample: gauge words g[3] (firmware V x 2^{up}_GAUGE_FRAC_BITS) and reference words r[3] (each
 * axis cascade's input format, axis volts; axis volt = {self.axis_scale[0]:.6g} rad tip, {self.axis_scale[1]:.6g} rad tilt,
 * {self.axis_scale[2]:.6g} m piston) in; stack command words v[3] (V x 2^{up}_STACK_FRAC_BITS) out:
 *   q[a] = (sum_j OUT_Q[a][j] g[j] + 2^(OUT_SHIFT[a]-1)) >> OUT_SHIFT[a]   (gauges -> axes)
 *   u[a] = AXIS_fixed_step(r[a] - q[a])                                    (the axis cascades)
 *   v[j] = clamp((sum_a (IN_Q[j][a] u[a]) >> IN_SHIFT[a] + 2^(V_SHIFT-1)) >> V_SHIFT)   (axes -> stacks)
 * int64 accumulators, arithmetic right shifts. Each axis cascade clamps its output to its axis range and to
 * its current-limit window (a model of its output; the box maps inside every stack's current headroom), and
 * the clamped value drives its integrator (anti-windup).{i_doc}
 */
#ifndef {up}_H
#define {up}_H

#include <stdint.h>
#include "{ax[0]}.h"
#include "{ax[1]}.h"
#include "{ax[2]}.h"
{i_inc}
#define {up}_GAUGE_FRAC_BITS {self.gauge_frac_bits}
#define {up}_STACK_FRAC_BITS {self.stack_frac_bits}
#define {up}_V_SHIFT {self.acc_frac_bits - self.stack_frac_bits}

static const int64_t {up}_OUT_Q[3][3] = {{
{arr(self.out_q)}
}};
static const int {up}_OUT_SHIFT[3] = {{{", ".join(str(int(v)) for v in self.out_shift)}}};
static const int64_t {up}_IN_Q[3][3] = {{
{arr(self.in_q)}
}};
static const int {up}_IN_SHIFT[3] = {{{", ".join(str(int(v)) for v in self.in_shift)}}};
{i_def}static const int64_t {up}_STACK_LIMITS_Q[3][2] = {{
{arr(lw)}
}};

typedef struct {{ {ax[0]}_fixed_state a0; {ax[1]}_fixed_state a1; {ax[2]}_fixed_state a2;{i_st} }} {name}_fixed_state;

/* At rest with the axis cascades' outputs at u0_q (each in its output format) and zero error. */
static inline void {name}_fixed_reset({name}_fixed_state *st, const int32_t u0_q[3])
{{
    {ax[0]}_fixed_reset(&st->a0, u0_q[0]);
    {ax[1]}_fixed_reset(&st->a1, u0_q[1]);
    {ax[2]}_fixed_reset(&st->a2, u0_q[2]);
{i_reset}}}

static inline int32_t {name}_sat32_(int64_t v)
{{
    return v > INT32_MAX ? INT32_MAX : v < INT32_MIN ? INT32_MIN : (int32_t)v;
}}

static inline void {name}_fixed_step({name}_fixed_state *st, const int32_t g_q[3], const int32_t r_q[3]{i_arg},
                                     int32_t v_q[3])
{{
{i_step}    int64_t u[3];
    int32_t e[3];
    for (int a = 0; a < 3; a++) {{
        int64_t acc = 0;
        for (int j = 0; j < 3; j++) acc += {up}_OUT_Q[a][j] * (int64_t)g_q[j];
        const int64_t q = (acc + ((int64_t)1 << ({up}_OUT_SHIFT[a] - 1))) >> {up}_OUT_SHIFT[a];
        e[a] = {name}_sat32_((int64_t)r_q[a] - q);
    }}
    u[0] = {ax[0]}_fixed_step(&st->a0, e[0]);
    u[1] = {ax[1]}_fixed_step(&st->a1, e[1]);
    u[2] = {ax[2]}_fixed_step(&st->a2, e[2]);
    for (int j = 0; j < 3; j++) {{
        int64_t acc = 0;
        for (int a = 0; a < 3; a++) acc += ({up}_IN_Q[j][a] * u[a]) >> {up}_IN_SHIFT[a];
        int64_t v = ((acc + ((int64_t)1 << ({up}_V_SHIFT - 1))) >> {up}_V_SHIFT){i_add};
{i_win}        v = v < {up}_STACK_LIMITS_Q[j][0] ? {up}_STACK_LIMITS_Q[j][0] : v > {up}_STACK_LIMITS_Q[j][1] ? {up}_STACK_LIMITS_Q[j][1] : v;
{i_upd}        v_q[j] = (int32_t)v;
    }}
}}

#endif /* {up}_H */
"""


_C_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_TOP_KEYS = ("schema", "name", "sample_rate_hz", "axes", "axis_units", "axis_scale", "gauge_to_axes",
             "axes_to_stacks", "stack_limits_v", "fixed_point", "controllers", "iff")
_BRIDGE_KEYS = ("reference_capacitance_f", "integrator_capacitance_f", "transducer_n_per_v", "gain_v_per_n",
                "corner_hz", "adc_range_v", "adc_bits", "out_noise_v_rms")


def stack_windows(fsm, dt_s):
    """Each stack's current-limit window for the damped step (module docstring): ``{"alpha": [3], "headroom_v": [3]}``.

    alpha_j = 1 - exp(-T / (R_j C_j)) (C_j the stack's largest terminal capacitance) and h_j = R_j
    min(I_source,j, I_sink,j), V: the symmetric window each stack keeps in the notch-only design (its
    axes' box maps inside it), from :func:`workbench.controller.plant_window` of each serial file.
    """
    windows = [plant_window(pl, dt_s) for pl in fsm.plants]
    if any(w is None or not pl.pzt.series_resistance_ohm > 0 for w, pl in zip(windows, fsm.plants)):
        # the mirror's stacks carry R (workbench.plant.mirror refuses R = 0): an R-out slew window is not built here
        raise ExportError("a stack has no series resistor (R = 0): no current-limit window to build")
    return {"alpha": [float(w[0]) for w in windows], "headroom_v": [float(min(w[1], w[2])) for w in windows]}


def _iff_cascades(iff, fsm, dt_s, name, coeff_bits):
    """The three IFF cascades of an exported design (bridge reading V -> stack V) and the bridge they assume."""
    import control
    from ..design.antiwindup import discretize
    from ..design.mimo import stack_charge_amps
    amps = stack_charge_amps(fsm)      # each stack's channel; the bridge's circuit (C_int, ADC, noise) is shared
    amp = amps[0]
    if any((a.c_int_f, a.adc_range_v, a.adc_bits, a.out_noise_v_rms)
           != (amp.c_int_f, amp.adc_range_v, amp.adc_bits, amp.out_noise_v_rms) for a in amps):
        raise ExportError("the stacks' charge amplifiers differ in C_int, ADC or noise; the exported bridge "
                          "table holds one of each")
    t = np.array([pz.transducer_constant_n_per_v for pz in fsm.stacks])
    cr = np.asarray(iff.bridge_capacitance_f, float)
    base = discretize(iff.tf(), dt_s, iff.corner_hz)          # V per N, as design.mimo.iff_response
    span = float(max(pz.voltage_max_v - pz.voltage_min_v for pz in fsm.stacks))
    out = {"bridge": {"reference_capacitance_f": cr.tolist(), "integrator_capacitance_f": float(amp.c_int_f),
                      "transducer_n_per_v": t.tolist(), "gain_v_per_n": float(iff.gain_v_per_n),
                      "corner_hz": float(iff.corner_hz), "adc_range_v": float(amp.adc_range_v),
                      "adc_bits": int(amp.adc_bits), "out_noise_v_rms": float(amp.out_noise_v_rms)}}
    for j, key in enumerate(IFF_KEYS):
        k = control.ss(base) * (-t[j] * amp.c_int_f / cr[j])  # d_j = -g s/(s + w_l) T C_int b_j / C_R
        out[key] = Controller.from_lti(k, dt_s=dt_s, output_limits_v=(-span, span), input_range_v=float(amp.adc_range_v),
                                       coeff_bits=coeff_bits, window=False, name=f"{name}_iff_{key}",
                                       method="integral force feedback from the charge bridge (design.mimo)",
                                       record={"stack": j, "input": {"signal": "charge_bridge", "units": "V"},
                                               "output": {"signal": "stack_voltage_correction", "units": "V"}})
    return out


def _load_iff(src, data, fs, allow_unstable, stack_limits_v):
    """Validate the JSON's ``iff`` table (three stack cascades at the servo rate, the bridge's numbers, the
    stack windows: alpha in (0, 1], headroom in (0, hi - lo] of each stack's range ``stack_limits_v`` (3, 2) V,
    a lead no command can exceed, which also keeps the headroom's words inside int64)."""
    if not isinstance(data, dict):
        raise MimoControllerError(src, "iff", "must be a table {bridge, controllers}; re-export the controller")
    for key, table, known in (("iff", data, ("bridge", "stack_window", "controllers", "note")),
                              ("iff.bridge", data.get("bridge"), _BRIDGE_KEYS),
                              ("iff.stack_window", data.get("stack_window"), ("alpha", "headroom_v"))):
        unknown = [k for k in table if k not in known] if isinstance(table, dict) else []
        if unknown:                 # a misspelt key would be dropped without a word
            raise MimoControllerError(src, f"{key}.{unknown[0]}", f"unknown key; {key}'s keys are {', '.join(known)}")
    br = data.get("bridge")
    if not isinstance(br, dict) or any(k not in br for k in _BRIDGE_KEYS):
        raise MimoControllerError(src, "iff.bridge", f"needs {', '.join(_BRIDGE_KEYS)}; re-export the controller")
    for k in ("reference_capacitance_f", "transducer_n_per_v"):
        v = _array(src, f"iff.bridge.{k}", br[k], "three positive numbers", 1, MimoControllerError)
        if v.shape != (3,) or np.any(v <= 0):
            raise MimoControllerError(src, f"iff.bridge.{k}", f"must be three positive numbers; got {br[k]!r}")
    for k in ("integrator_capacitance_f", "corner_hz", "adc_range_v", "out_noise_v_rms", "gain_v_per_n"):
        v = br[k]
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and (v >= 0 if k == "out_noise_v_rms" else v > 0)):
            kind = "non-negative" if k == "out_noise_v_rms" else "positive"
            raise MimoControllerError(src, f"iff.bridge.{k}", f"must be a finite {kind} number; got {v!r}")
    if not (isinstance(br["adc_bits"], int) and not isinstance(br["adc_bits"], bool) and 1 <= br["adc_bits"] <= 64):
        raise MimoControllerError(src, "iff.bridge.adc_bits", f"must be an integer 1..64; got {br['adc_bits']!r}")
    if not br["out_noise_v_rms"] < br["adc_range_v"]:
        # the bridge's output noise alone would fill the ADC's range: its reading would be noise
        raise MimoControllerError(src, "iff.bridge.out_noise_v_rms", f"{br['out_noise_v_rms']:g} V RMS is not below the "
                                                                     f"ADC range {br['adc_range_v']:g} V: the reading "
                                                                     f"would be noise; re-export the controller")
    span = np.asarray(stack_limits_v, float) @ np.array([-1.0, 1.0])
    # the largest reading the bridge can give: a stack's blocked force over its whole range, T_j (hi - lo), read
    # at C_R,j / (T_j C_int) V per N (force_noise_n's scale), i.e. C_R,j (hi - lo) / C_int; an ADC whose one step
    # is above that resolves the bridge's whole reading in at most two codes (the IFF acts on a sign at best;
    # rounding to nearest reads below half a step as 0). 18 bits over 10 V: 7.6e-5 V a step
    s_max = float(np.min(np.asarray(br["reference_capacitance_f"], float) * span) / br["integrator_capacitance_f"])
    from ..selfsense.charge_amp import adc_lsb_v
    lsb = adc_lsb_v(br["adc_bits"], br["adc_range_v"])
    if not lsb <= s_max:
        hi = s_max * 2.0 ** (int(br["adc_bits"]) - 1)
        raise MimoControllerError(src, "iff.bridge.adc_range_v", f"{br['adc_range_v']:g} V over {br['adc_bits']} bits "
                                                                 f"is a step of {lsb:.3g} V, above the largest reading "
                                                                 f"the bridge gives ({s_max:.3g} V: C_R (hi - lo) / "
                                                                 f"C_int, a stack's blocked force over its range): "
                                                                 f"the whole reading spans at most one step; give "
                                                                 f"the ADC's full "
                                                                 f"scale, at most {hi:.3g} V, or re-export the "
                                                                 f"controller")
    sw = data.get("stack_window")
    if not isinstance(sw, dict) or any(k not in sw for k in ("alpha", "headroom_v")):
        raise MimoControllerError(src, "iff.stack_window", "needs alpha and headroom_v (each stack's current-limit "
                                                           "window); re-export the controller")
    for k, hi in (("alpha", np.ones(3)), ("headroom_v", span)):
        v = _array(src, f"iff.stack_window.{k}", sw[k], "three positive numbers", 1, MimoControllerError)
        if v.shape != (3,) or np.any(v <= 0) or np.any(v > hi):
            what = "1" if k == "alpha" else f"each stack's range hi - lo = {', '.join(f'{x:g}' for x in hi)} V"
            raise MimoControllerError(src, f"iff.stack_window.{k}", f"must be three numbers in (0, {what}]; "
                                                                    f"got {sw[k]!r}; re-export the controller")
    ctr = data.get("controllers")
    if not isinstance(ctr, dict):
        raise MimoControllerError(src, "iff.controllers", "must be a table {stack0, stack1, stack2}")
    out = {"bridge": dict(br), "stack_window": {k: [float(x) for x in sw[k]] for k in ("alpha", "headroom_v")}}
    for k in IFF_KEYS:
        c = _load_cascade(src, ctr, k, "iff.controllers", allow_unstable)
        if abs(c.sample_rate_hz - fs) > 1e-9 * fs:
            raise MimoControllerError(src, f"iff.controllers.{k}.sample_rate_hz",
                                      f"{c.sample_rate_hz!r} must equal the controller's {fs!r}")
        out[k] = c
    _check_iff_gains(src, out)
    return out


def _load_cascade(src, table, key, where, allow_unstable):
    """One exported single-channel controller of a MIMO file (``where.key``), loaded by the one
    Controller loader and required to carry its fixed-point words (the MIMO step runs them)."""
    if key not in table:
        raise MimoControllerError(src, f"{where}.{key}", "is missing; re-export the controller")
    try:
        c = Controller.from_dict(table[key], source=f"{src} {where}.{key}", allow_unstable=allow_unstable)
    except ControllerError as err:
        raise MimoControllerError(src, f"{where}.{key}", str(err)) from None
    if c.fixed is None:
        raise MimoControllerError(src, f"{where}.{key}.fixed_point", "is missing: the MIMO step runs the words; "
                                                                     "re-export")
    return c


def _check_iff_gains(src, iff):
    """Each cascade's gain at Nyquist (z = -1: s -> infinity of the Tustin-sampled g s / (s + w_l)) must be the
    bridge's -g T_j C_int / C_R,j (relative 1e-6), else the bridge numbers are not the ones it was designed for."""
    br = iff["bridge"]
    for j, k in enumerate(IFF_KEYS):
        sos = np.asarray(iff[k].sos, float)
        h = iff[k].gain * float(np.prod((sos[:, 0] - sos[:, 1] + sos[:, 2]) / (sos[:, 3] - sos[:, 4] + sos[:, 5])))
        want = -br["gain_v_per_n"] * br["transducer_n_per_v"][j] * br["integrator_capacitance_f"] \
            / br["reference_capacitance_f"][j]
        if not abs(h - want) <= 1e-6 * abs(want):
            raise MimoControllerError(src, f"iff.controllers.{k}",
                                      f"its high-frequency gain {h:.6g} V/V is not the bridge's -g T C_int / C_R = "
                                      f"{want:.6g} V/V: the iff.bridge numbers do not match the cascades; re-export")


def _mirror_provenance(fsm):
    out = {"plant_file": str(fsm.source), "stack_files": [str(p.source) for p in fsm.plants],
           "serials": [p.serial for p in fsm.plants]}
    if fsm.source and Path(fsm.source).is_file():
        out["plant_sha256"] = hashlib.sha256(Path(fsm.source).read_bytes()).hexdigest()
    return out


def is_mimo_controller_file(path):
    """True when ``path`` is a JSON object whose ``schema`` is the MIMO controller's (False on anything else)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(data, dict) and data.get("schema") == MIMO_SCHEMA
