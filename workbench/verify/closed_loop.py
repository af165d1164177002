"""The exported controller in closed loop with the full nonlinear plant, one compiled loop.

Per servo period T (the gauge modulation period, 10 kHz), in this order:

1. the PZT runs ``n_sub`` steps of the compiled plant (:func:`workbench.plant.kernels.pzt_step`:
   R, current and voltage limits, hysteresis, creep, modes, the environmental force) with
   the command held (the DAC's zero-order hold);
2. the gauge chain reads the period: **equivalent discrete model**, as
   :func:`workbench.plant.gauge.gauge_run_equivalent`: the bridge of eq. 26 (imbalance
   included) at the displacement a quarter and three quarters into the period
   (interpolated between sub-steps), the x300 amplifier with the ADC range as a clip, the
   difference of the halves (x2), one Gaussian term for the gauge noise and the ADC
   quantization of the 80 conversions, then the firmware trim and the servo DAC's
   quantization (16 bits over +/-2.6 V). The 80 conversions are not simulated one by
   one here (``gauge_run`` does that, and the tests tie the two together). A controller whose
   sensor block carries the bridge curvature (``gauge_curvature_per_m``) has each reading
   linearized as firmware does (:func:`workbench.plant.gauge.linearized_displacement`, the
   sensor loop's conversion of :mod:`workbench.verify.sensors`);
3. the controller computes its output from the reading **sample by sample** as firmware
   does, in the form the JSON declares (:class:`FirmwareController`): the 32-bit
   fixed-point cascade bit for bit (:func:`workbench.export.fixed_point.fixed_step`, the
   C header's step) when the JSON has a ``fixed_point`` block, else the float cascade,
   or the Hanus realization when the ``anti_windup`` block says ``hanus``; each with the
   output range, the current-limit window (a model of the stack voltage; the command
   never asks for more current than the amplifier gives with the series resistor in, for
   more charge in a sample than it moves with the resistor out, where the stack reaches
   the command within the sample while the amplifier slews at its limit inside it) and
   the anti-windup it declares.
   With ``anti_windup=False`` the same controller runs with the range clip only: no
   window, the states driven by the unclipped output (what firmware without anti-windup
   does);
4. that output is applied at the next period (the one-sample compute delay).

Nothing in the loop calls Python per period. The gauge noise is drawn inside the loop,
one standard normal a period from the run's ``numpy.random.Generator`` (numba's
implementation of numpy's PCG64/ziggurat draw: the same numbers as
``standard_normal(n) * sigma``, with no noise block in memory). The run is cut in chunks of
:data:`CHUNK` periods (for a constant reference and force, one chunk's buffer); traces are decimated inside
the loop and streaming statistics (current peaks, time at the current limit, rate- and
range-limited samples) accumulated there, so memory does not grow with the run.
"""

import math
from dataclasses import dataclass

import control
import numpy as np
from numba import njit

from ..design.antiwindup import HanusController, hanus_initial_state
from ..export.fixed_point import FixedPointController, fixed_step, float_step, initial_state
from .._kernel_args import readonly
from ..export.sos import from_sos
from ..plant import kernels as K
from ..plant.gauge import TRIM_CENTER_M, _bridge, _quantize, demod_noise_sigma_v, linearized_displacement
from ..plant.simulator import PZTSimulator

__all__ = ["FirmwareController", "controller_from_json", "ClosedLoopRun", "ClosedLoop", "CHUNK"]

TRACE_NAMES = ("x_m", "reading_v", "u_v", "error_v", "force_n", "i_a")
CHUNK = 1 << 17               # periods per compiled call (13 s at 10 kHz)
FORMS = ("hanus", "float", "fixed")


@dataclass(frozen=True)
class FirmwareController:
    """What firmware runs, read from an exported JSON.

    ``form``: "fixed" (the JSON's fixed-point cascade, bit for bit), "float" (the float
    cascade ``gain``, ``sos``) or "hanus" (a state-space realization conditioned on its
    limited output). ``voltage_model``: (alpha, h_up, h_down) of the current-limit window
    (:mod:`workbench.export.fixed_point`), or None. ``ref_lead_s`` (s) and ``gauge_curvature_per_m``
    (beta, 1/m): firmware's reference lead 1/K_v and the bridge curvature its gauge conversion takes out, from
    the controller's sensor block (:func:`workbench.verify.sensors.firmware_startup`); 0 when it carries none
    (the linear calibration and the reference as given, bit for bit as before). The ramp scenarios (the
    triangles, and ``workbench sweep``'s triangle) feed r + v ``ref_lead_s`` with v the planned slope
    (:func:`workbench.verify.scenarios.planned_slope_lead`); steps, holds and tones are fed as given. Every
    reading is linearized with ``gauge_curvature_per_m`` (:func:`workbench.plant.gauge.linearized_displacement`).
    ``series_resistor_out``: whether the window was derived with the series resistor out (a slew window; the
    controller's :attr:`~workbench.controller.Controller.series_resistor_out`), for the description only.
    """

    form: str
    dt_s: float
    output_limits_v: tuple
    voltage_model: tuple | None
    gain: float = 1.0
    sos: np.ndarray | None = None
    fixed: FixedPointController | None = None
    hanus: HanusController | None = None
    ref_lead_s: float = 0.0
    gauge_curvature_per_m: float = 0.0
    series_resistor_out: bool | None = None

    def linear(self):
        """The discrete linear controller (no limits) as a python-control StateSpace."""
        if self.form == "hanus":
            h = self.hanus
            return control.ss(h.a, h.b, h.c, [[h.d]], h.dt_s)
        if self.form == "fixed":
            gain, sos = self.fixed.quantized_sos()
            return control.ss(from_sos(gain, sos, self.dt_s))
        return control.ss(from_sos(self.gain, self.sos, self.dt_s))

    def describe(self):
        from ..controller import window_text
        rate = "no current-limit window" if self.voltage_model is None else window_text(self.voltage_model, self.series_resistor_out)
        form = {"fixed": "32-bit fixed-point cascade", "float": "float cascade", "hanus": "Hanus float form"}[self.form]
        return f"{form}, output {self.output_limits_v[0]:g}..{self.output_limits_v[1]:g} V, {rate}"


def controller_from_json(data, form=None, default_limits_v=None, plant=None, source="", allow_unstable=False):
    """The controller an exported JSON declares, in the form firmware runs.

    Validation and the choice of form are :class:`workbench.controller.Controller`'s
    (``Controller.from_dict(...).firmware(form)``): ``form`` None is "fixed" when the JSON
    has a ``fixed_point`` block, else "hanus" when its ``anti_windup`` block is a Hanus
    realization, else "float". ``default_limits_v``: output limits for a JSON that names
    none (the amplifier's range); ``plant``: the same and the current-limit window of a bare
    controller. Raises :class:`workbench.controller.ControllerError` (a ValueError) naming the key.
    """
    from ..controller import Controller
    c = Controller.from_dict(data, source=source, plant=plant, allow_unstable=allow_unstable)
    if c.output_limits_v is None and default_limits_v is not None:
        from dataclasses import replace
        c = replace(c, output_limits_v=tuple(float(v) for v in default_limits_v))
    return c.firmware(form)


@njit(cache=True, error_model="numpy")
def _loop(m, st, n_sub, ref, force, rng, sigma, gp, r0, form, ha, hb, hc, hd, hx, gain, sos, fb, fa, fshift, ffrac,
          f_in, in_scale, out_scale, cs_f, cs_i, vm_f, vm_i, lim, limw, aw, decimate, io, rec, stats):
    """Closed loop over len(ref) servo periods.

    ``rng``: the numpy Generator the gauge noise is drawn from, one ``standard_normal()`` times
    ``sigma`` (V, the demodulated reading's noise) a period; none drawn when ``sigma`` is 0.
    ``form``: 0 Hanus (``ha, hb, hc, hd``, state ``hx``), 1 float cascade (``gain, sos``),
    2 fixed-point cascade (``fb, fa, fshift, ffrac``, input clamp ``f_in`` words, scales);
    cascade states ``cs_f`` (float form) and ``cs_i`` (fixed, int64); the window's
    voltage model ``vm_f`` / ``vm_i`` (1-element). ``lim`` = [lo, hi, alpha, h_up, h_down]
    in V, ``limw`` the same in output words (alpha in Q1.30). ``io`` =
    [pending output, last x, decimation counter, trace row] carries the loop between chunks.
    ``stats`` = [i_max, i_min, sub-steps at a current limit, samples held by the
    current-limit window, range-limited samples].

    The physics of :func:`_loop_reference` with the arithmetic arranged for a short
    dependency chain per period (the tests hold the two equal to 1e-12 relative on the
    position, and the controller words identical, over runs that reach the output limits,
    the current limit and the window): the plant step of
    :func:`workbench.plant.kernels.pzt_advance` (capacitance and exp per capacitance
    segment, the semi-implicit creep step and exact mode steps, no division but the creep step's) with its scalars and offsets read
    once (:func:`workbench.plant.kernels.plant_params`), the gauge constants (bridge
    factors, 1/L, the DAC step and its reciprocal: the period's only divisions are the
    bridge's ratios) and the sub-steps that hold the quarter and three-quarter points
    worked out before the loop, the statistics kept in locals, nothing allocated per period, and no
    reference count per period (the arrays the inlined steps take are :func:`workbench.plant.kernels._borrowed`
    views, taken once).
    ``benchmarks/closed_loop_vs_c.c`` is this loop in C, bit for bit.
    """
    # borrowed views of the arrays handed to the inlined plant and controller steps: no atomic reference count
    # per period (K._borrowed; the arrays themselves, a plain view or a copy here put 10 reference counts in the
    # loop on numba 0.68.1, benchmarks/borrowed_codegen.py; tested on the compiled loop)
    m, st, cs_i, vm_i = K._borrowed(m), K._borrowed(st), K._borrowed(cs_i), K._borrowed(vm_i)
    fb, fa, fshift, limw = K._borrowed(fb), K._borrowed(fa), K._borrowed(fshift), K._borrowed(limw)
    cs_f, sos, lim, vm_f = K._borrowed(cs_f), K._borrowed(sos), K._borrowed(lim), K._borrowed(vm_f)
    p = K.plant_params(m)
    n = hx.shape[0]
    xn = np.empty(n)
    peak = np.zeros((0, 3), np.int64)          # fixed_step skips its peak bookkeeping (not read here)
    draw = sigma > 0.0
    L, W, kgf, vm, amp, adc_fs = gp[0], gp[1], gp[2], gp[3], gp[4], gp[5]
    demod, trim_s, trim_b, dac_fs, dac_bits = gp[6], gp[7], gp[8], gp[9], int(gp[10])
    cal, beta = gp[11], gp[12]          # firmware's metres per firmware V and the curvature it takes out (0: none)
    # the bridge (eq. 26): each half's arms are linear in x, so each ratio is (n0 + n1 x) / (d0 + d1 x)
    kw = kgf * (W / L)
    r0a, r0b, r0c, r0d = r0[0], r0[1], r0[2], r0[3]
    n10, n11 = r0d - r0a, (r0d * kgf + r0a * kw) / L
    d10, d11 = r0d + r0a, (r0d * kgf - r0a * kw) / L
    n20, n21 = r0b - r0c, -(r0b * kw + r0c * kgf) / L
    d20, d21 = r0b + r0c, (r0c * kgf - r0b * kw) / L
    k_br = amp * vm
    k_dem = trim_s * (0.5 * demod)
    # _quantize's step and its top code
    dac_lsb = 2.0 * dac_fs / (2.0 ** dac_bits)
    dac_top = dac_fs - dac_lsb
    inv_lsb = 1.0 / dac_lsb
    i_src_lim, i_snk_lim = p[1] * (1 - 1e-9), p[2] * (1 - 1e-9)
    # the sub-steps whose interval holds t = 1/4 and t = 3/4 of the period, and their offsets
    jq = jt = -1
    fq = ft = 0.0
    for j in range(n_sub):
        t_end = (j + 1) / n_sub
        t_beg = j / n_sub
        if t_beg < 0.25 <= t_end:
            jq, fq = j, 0.25 - t_beg
        if t_beg < 0.75 <= t_end:
            jt, ft = j, 0.75 - t_beg
    fqn, ftn = fq * n_sub, ft * n_sub            # the interpolation weights (n_sub 1: fq and ft exactly)
    # the error word in input units at once: in_scale is a power of two, so ref*s - code*(lsb*s) rounds as
    # (ref - code*lsb)*s does, bit for bit, one multiplication fewer on the period's dependency chain
    lsb_in = dac_lsb * in_scale
    i_max, i_min, n_lim, n_win, n_range = stats[0], stats[1], stats[2], stats[3], stats[4]
    lo_v, hi_v, h_up_v, h_dn_v = lim[0], lim[1], lim[3], lim[4]
    lo_w, hi_w, h_up_w, h_dn_w = limw[0], limw[1], limw[3], limw[4]
    pending = io[0]
    x_prev = io[1]
    count = int(io[2])
    row = int(io[3])
    n_rows = rec.shape[0]
    for k in range(ref.shape[0]):
        u = pending
        fk = force[k]
        xb = x_prev
        xq = 0.0
        xt = 0.0
        xsum = 0.0
        i_peak = 0.0
        for j in range(n_sub):
            xj, _, ij, _, _ = K.pzt_advance(p, m, st, u, fk)
            # positions a quarter and three quarters into the period, linear between sub-steps
            if j == jq:
                xq = xb + (xj - xb) * fqn
            if j == jt:
                xt = xb + (xj - xb) * ftn
            xb = xj
            xsum += xj
            if abs(ij) > abs(i_peak):
                i_peak = ij
            i_max = max(i_max, ij)
            i_min = min(i_min, ij)
            if ij >= i_src_lim or -ij >= i_snk_lim:
                n_lim += 1
        x_prev = xb
        # the bridge (eq. 26) at the two points, as _bridge; the amplifier, the ADC range as a clip
        vp = min(max((((n10 + n11 * xq) / (d10 + d11 * xq)) - ((n20 + n21 * xq) / (d20 + d21 * xq))) * k_br,
                     -adc_fs), adc_fs)
        vn = min(max((((n10 + n11 * xt) / (d10 + d11 * xt)) - ((n20 + n21 * xt) / (d20 + d21 * xt))) * -k_br,
                     -adc_fs), adc_fs)
        # demodulation (x2 the difference of the halves) with the noise term, trim, the servo DAC, as _quantize
        w = rng.standard_normal() * sigma if draw else 0.0
        reading = min(max(k_dem * (vp - vn) + (trim_s * w + trim_b), -dac_fs), dac_top)
        code = math.floor(reading * inv_lsb + 0.5)
        reading = code * dac_lsb
        if beta != 0.0:
            # firmware's conversion to metres with eq. 27's curvature taken out, back in firmware V
            reading = (linearized_displacement(reading * cal + TRIM_CENTER_M, beta, TRIM_CENTER_M)
                       - TRIM_CENTER_M) / cal
        e = ref[k] - reading
        if form == 2:
            # the input word as FixedPointController.input_words makes it (round half even, clamp)
            if beta != 0.0:
                v = min(max(np.int64(np.rint(e * in_scale)), -f_in), f_in)
            else:
                v = min(max(np.int64(np.rint(ref[k] * in_scale - code * lsb_in)), -f_in), f_in)
            wlo, whi = vm_i[0] - h_dn_w, vm_i[0] + h_up_w
            u_w = fixed_step(cs_i, v, fb, fa, fshift, ffrac, limw, vm_i, aw, peak)
            # held by the window (no "aw and": without anti-windup limw's headroom is 2^40 words, so wlo > lo_w and
            # whi < hi_w are false; the same count, and the test then compiles ~6 ns a period shorter, as in the C)
            if (u_w == wlo and wlo > lo_w) or (u_w == whi and whi < hi_w):
                n_win += 1
            if u_w == lo_w or u_w == hi_w:
                n_range += 1
            u_lim = u_w * out_scale
        else:
            wlo, whi = vm_f[0] - h_dn_v, vm_f[0] + h_up_v
            if form == 1:
                u_lim = float_step(cs_f, gain * e, sos, lim, vm_f, aw)
            else:
                u_raw = hd * e
                for i in range(n):
                    u_raw += hc[i] * hx[i]
                u_lim = min(max(u_raw, max(lo_v, wlo)), min(hi_v, whi))
                # conditioned on the limited output: x <- a x + b e_equiv, e_equiv = (u_lim - c x) / d
                e_eq = (u_lim - (u_raw - hd * e)) / hd if aw else e
                for i in range(n):
                    acc = hb[i] * e_eq
                    for jj in range(n):
                        acc += ha[i, jj] * hx[jj]
                    xn[i] = acc
                for i in range(n):
                    hx[i] = xn[i]
                vm_f[0] += lim[2] * (u_lim - vm_f[0])
            if aw and ((u_lim == wlo and wlo > lo_v) or (u_lim == whi and whi < hi_v)):
                n_win += 1
            if u_lim == lo_v or u_lim == hi_v:
                n_range += 1
        pending = u_lim
        count += 1
        if count == decimate:
            count = 0
            if row < n_rows:
                rec[row, 0] = xsum / n_sub
                rec[row, 1] = reading
                rec[row, 2] = u
                rec[row, 3] = e
                rec[row, 4] = fk
                rec[row, 5] = i_peak
                row += 1
    stats[0], stats[1], stats[2], stats[3], stats[4] = i_max, i_min, n_lim, n_win, n_range
    io[0] = pending
    io[1] = x_prev
    io[2] = count
    io[3] = row


def _loop_reference(m, st, n_sub, ref, force, rng, sigma, gp, r0, form, ha, hb, hc, hd, hx, gain, sos, fb, fa, fshift,
                    ffrac, f_in, in_scale, out_scale, cs_f, cs_i, vm_f, vm_i, lim, limw, aw, decimate, io, rec, stats):
    """The closed loop as first written, run by the interpreter: the slow reference of :func:`_loop`.

    The plant step as first written (:func:`workbench.plant.kernels.pzt_step_reference`:
    per-step divisions, exp and formulae) through its packed arrays and an output array,
    the gauge and controller helpers called as they are (those run compiled). The tests
    hold :func:`_loop` to it (1e-12 relative on the position, controller words identical);
    ~50 us a period, for short runs only. Same arguments, same effect as :func:`_loop`
    up to rounding.

    ``rng``: the numpy Generator the gauge noise is drawn from, one ``standard_normal()`` times
    ``sigma`` (V, the demodulated reading's noise) a period; none drawn when ``sigma`` is 0.
    ``form``: 0 Hanus (``ha, hb, hc, hd``, state ``hx``), 1 float cascade (``gain, sos``),
    2 fixed-point cascade (``fb, fa, fshift, ffrac``, input clamp ``f_in`` words, scales);
    cascade states ``cs_f`` (float form) and ``cs_i`` (fixed, int64); the window's
    voltage model ``vm_f`` / ``vm_i`` (1-element). ``lim`` = [lo, hi, alpha, h_up, h_down]
    in V, ``limw`` the same in output words (alpha in Q1.30). ``io`` =
    [pending output, last x, decimation counter, trace row] carries the loop between chunks.
    ``stats`` = [i_max, i_min, sub-steps at a current limit, samples held by the
    current-limit window, range-limited samples].
    """
    out = np.empty(K.N_OUT)
    n = hx.shape[0]
    xn = np.empty(n)
    peak = np.zeros((fb.shape[0], 3), np.int64)
    L, W, kgf, vm, amp, adc_fs = gp[0], gp[1], gp[2], gp[3], gp[4], gp[5]
    demod, trim_s, trim_b, dac_fs, dac_bits = gp[6], gp[7], gp[8], gp[9], int(gp[10])
    cal, beta = gp[11], gp[12]
    i_src, i_snk = m[K.I_SRC], m[K.I_SNK]
    pending = io[0]
    x_prev = io[1]
    count = int(io[2])
    row = int(io[3])
    xprev_sub = x_prev
    for k in range(ref.shape[0]):
        u = pending
        fk = force[k]
        x_start = x_prev
        xq = 0.0
        xt = 0.0
        xsum = 0.0
        i_peak = 0.0
        for j in range(n_sub):
            K.pzt_step_reference(m, st, u, fk, out)
            xj = out[0]
            # positions a quarter and three quarters into the period, linear between sub-steps
            t_end = (j + 1) / n_sub
            t_beg = j / n_sub
            if t_beg < 0.25 <= t_end:
                xb = x_start if j == 0 else xprev_sub
                xq = xb + (xj - xb) * (0.25 - t_beg) * n_sub
            if t_beg < 0.75 <= t_end:
                xb = x_start if j == 0 else xprev_sub
                xt = xb + (xj - xb) * (0.75 - t_beg) * n_sub
            xprev_sub = xj
            xsum += xj
            ij = out[2]
            if abs(ij) > abs(i_peak):
                i_peak = ij
            if ij > stats[0]:
                stats[0] = ij
            if ij < stats[1]:
                stats[1] = ij
            if ij >= i_src * (1 - 1e-9) or -ij >= i_snk * (1 - 1e-9):
                stats[2] += 1
        x_prev = xprev_sub
        vp = min(max(amp * _bridge(xq, L, W, kgf, r0, vm), -adc_fs), adc_fs)
        vn = min(max(amp * _bridge(xt, L, W, kgf, r0, -vm), -adc_fs), adc_fs)
        dem = 0.5 * demod * (vp - vn) + (rng.standard_normal() * sigma if sigma > 0.0 else 0.0)
        reading = _quantize(trim_s * dem + trim_b, dac_fs, dac_bits)
        if beta != 0.0:
            reading = (linearized_displacement(reading * cal + TRIM_CENTER_M, beta, TRIM_CENTER_M)
                       - TRIM_CENTER_M) / cal
        e = ref[k] - reading
        if form == 2:
            # the input word as FixedPointController.input_words makes it (round half even, clamp)
            v = np.int64(np.rint(e * in_scale))
            v = min(max(v, -f_in), f_in)
            wlo, whi = vm_i[0] - limw[4], vm_i[0] + limw[3]
            u_w = fixed_step(cs_i, v, fb, fa, fshift, ffrac, limw, vm_i, aw, peak)
            if aw and ((u_w == wlo and wlo > limw[0]) or (u_w == whi and whi < limw[1])):
                stats[3] += 1
            if u_w == limw[0] or u_w == limw[1]:
                stats[4] += 1
            u_lim = u_w * out_scale
        else:
            wlo, whi = vm_f[0] - lim[4], vm_f[0] + lim[3]
            if form == 1:
                u_lim = float_step(cs_f, gain * e, sos, lim, vm_f, aw)
            else:
                u_raw = hd * e
                for i in range(n):
                    u_raw += hc[i] * hx[i]
                u_lim = min(max(u_raw, max(lim[0], wlo)), min(lim[1], whi))
                # conditioned on the limited output: x <- a x + b e_equiv, e_equiv = (u_lim - c x) / d
                e_eq = (u_lim - (u_raw - hd * e)) / hd if aw else e
                for i in range(n):
                    acc = hb[i] * e_eq
                    for jj in range(n):
                        acc += ha[i, jj] * hx[jj]
                    xn[i] = acc
                for i in range(n):
                    hx[i] = xn[i]
                vm_f[0] += lim[2] * (u_lim - vm_f[0])
            if aw and ((u_lim == wlo and wlo > lim[0]) or (u_lim == whi and whi < lim[1])):
                stats[3] += 1
            if u_lim == lim[0] or u_lim == lim[1]:
                stats[4] += 1
        pending = u_lim
        count += 1
        if count == decimate:
            count = 0
            if row < rec.shape[0]:
                rec[row, 0] = xsum / n_sub
                rec[row, 1] = reading
                rec[row, 2] = u
                rec[row, 3] = e
                rec[row, 4] = fk
                rec[row, 5] = i_peak
                row += 1
    io[0] = pending
    io[1] = x_prev
    io[2] = count
    io[3] = row


@dataclass(frozen=True)
class ClosedLoopRun:
    """Decimated traces (one row per ``decimate`` servo periods) and streaming statistics."""

    t_s: np.ndarray
    x_m: np.ndarray
    reading_v: np.ndarray
    u_v: np.ndarray
    error_v: np.ndarray
    force_n: np.ndarray
    i_a: np.ndarray
    peak_current_a: tuple
    periods_at_current_limit: float     # sub-steps at a current limit / n_sub
    samples_rate_limited: int           # held by the current-limit window (or a Hanus rate limit)
    samples_range_limited: int
    periods: int


class ClosedLoop:
    """The plant file's PZT and gauge with an exported controller, stepped at the servo rate.

    Parameters
    ----------
    plant : Plant
    controller : FirmwareController (see :func:`controller_from_json`)
    n_sub : int
        Plant steps per servo period (1: the plant's exact RC step over the whole period).
    noise : bool
        Gauge noise and ADC quantization (one Gaussian term per reading).
    anti_windup : bool
        Run the declared anti-windup (current-limit window, conditioning on the limited output);
        False: the same controller with the range clip only.
    seed : int
    """

    def __init__(self, plant, controller, n_sub=1, noise=True, anti_windup=True, seed=0):
        g = plant.gauge
        if abs(controller.dt_s - g.period_s) > 1e-9 * g.period_s:
            from ..controller import ControllerMismatchError
            raise ControllerMismatchError(
                f"controller sample rate {1.0 / controller.dt_s:g} Hz differs from the servo rate "
                f"{1.0 / g.period_s:g} Hz of {plant.source} (its gauge modulation): it cannot run on this "
                f"plant; export the controller at {1.0 / g.period_s:g} Hz")
        self.plant, self.controller = plant, controller
        self.n_sub, self.anti_windup = int(n_sub), bool(anti_windup)
        self.sim = PZTSimulator(plant.pzt, g.period_s / self.n_sub)
        self.sigma_v = float(demod_noise_sigma_v(g)) if noise else 0.0
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._gp = np.array([g.rest_length_m, g.rest_width_m, g.gauge_factor, g.modulation_v, g.amplifier_gain,
                             g.adc_range_v, g.demodulation_gain, g.trim_scale, g.trim_bias_v, g.dac_range_v,
                             g.dac_bits, g.calibration_m_per_v, controller.gauge_curvature_per_m])
        self._r0 = np.array([g.arm_nominal_ohm + dr for dr in g.imbalance_ohm])
        c = controller
        model = c.voltage_model if (anti_windup and c.voltage_model is not None) else (1.0, np.inf, np.inf)
        self._lim = np.array([c.output_limits_v[0], c.output_limits_v[1], *model])
        self._form = {"hanus": 0, "float": 1, "fixed": 2}[c.form]
        # arrays of the forms not in use are small dummies (numba compiles one signature)
        h = c.hanus
        self._ha = np.zeros((1, 1)) if h is None else np.ascontiguousarray(h.a)
        self._hb = np.zeros(1) if h is None else np.ascontiguousarray(h.b[:, 0])
        self._hc = np.zeros(1) if h is None else np.ascontiguousarray(h.c[0])
        self._hd = 1.0 if h is None else float(h.d)
        f = c.fixed
        if f is not None:
            self._fb, self._fa = readonly(f.b, np.int64), readonly(f.a, np.int64)    # read-only: one _loop signature
            self._fshift = f.b_shift.astype(np.int64)
            self._ffrac, self._fin = int(f.a_frac_bits), int(f.input_limit)
            self._in_scale, self._out_scale = 2.0 ** f.input_frac_bits, 2.0 ** -f.output_frac_bits
            # _loop forms the error word as rint(ref*s - code*(lsb*s)), and the C of benchmarks/closed_loop_vs_c.c
            # the same: equal bit for bit to rint((ref - code*lsb)*s) only when s is a power of two (exact scaling)
            assert math.frexp(self._in_scale)[0] == 0.5, f"in_scale {self._in_scale!r} is not a power of two"
            self._limw = f.limit_words.copy()
            if not anti_windup:
                self._limw[2:] = (1 << 30, 1 << 40, 1 << 40)
        else:
            self._fb, self._fa = readonly(np.zeros((1, 3)), np.int64), readonly(np.zeros((1, 2)), np.int64)
            self._fshift = np.zeros(1, np.int64)
            self._ffrac, self._fin, self._in_scale, self._out_scale = 29, 1, 1.0, 1.0
            self._limw = np.zeros(5, np.int64)
        self._sos = np.zeros((1, 6)) if c.sos is None else np.ascontiguousarray(c.sos, dtype=float)
        self.reset()

    def reset(self, u0=0.0):
        """Plant at rest; controller state at rest with output ``u0`` and zero error."""
        self.sim.reset()
        c = self.controller
        self._hx = hanus_initial_state(c.hanus, u0) if c.hanus is not None else np.zeros(1)
        self._csf, self._csi, u_w = np.zeros((1, 2)), np.zeros((1, 2), np.int64), 0
        if c.form == "fixed":
            self._csi, u_w = initial_state(c.fixed, u0)
            u0 = float(u_w) * self._out_scale
        elif c.form == "float":
            self._csf = np.zeros((len(self._sos), 2))
            self._csf[-1] = u0, -self._sos[-1, 5] * u0
        self._vmf, self._vmi = np.array([float(u0)]), np.array([u_w], dtype=np.int64)
        x0 = self.plant.pzt.k_q2x_m_per_c * self.plant.pzt.hysteresis.output_at_rest()
        self._io = np.array([float(u0), x0, 0.0, 0.0])
        self._k = 0

    @property
    def u(self):
        """The output that the next period applies, V."""
        return float(self._io[0])

    def run(self, ref_v, force_n=None, decimate=1, periods=None):
        """Run servo periods with the reference (firmware V) and force (N) per period.

        ``ref_v`` and ``force_n`` are arrays of one length, or scalars held for
        ``periods``. Traces keep one row per ``decimate`` periods.
        """
        scalar = np.ndim(ref_v) == 0 and (force_n is None or np.ndim(force_n) == 0)
        if scalar:
            if periods is None:
                raise ValueError("a constant reference needs periods=")
            n = int(periods)
            ref = float(ref_v)
            force = 0.0 if force_n is None else float(force_n)
            if not (np.isfinite(ref) and np.isfinite(force)):
                raise ValueError("reference and force must be finite")
        else:
            # read-only views (a broadcast is one; an array of the caller's is viewed so): _loop compiles once
            ref = readonly(np.broadcast_to(ref_v, np.shape(ref_v) if np.ndim(ref_v) else np.shape(force_n)))
            force = readonly(np.zeros(ref.shape) if force_n is None else np.broadcast_to(force_n, ref.shape))
            if ref.ndim != 1 or not (np.all(np.isfinite(ref)) and np.all(np.isfinite(force))):
                raise ValueError("reference and force must be finite 1-D arrays of one length")
            n = ref.size
        decimate = max(1, int(decimate))
        rec = np.zeros((n // decimate, len(TRACE_NAMES)))
        stats = np.zeros(5)
        self._io[2:] = 0.0
        c = self.controller
        # a constant reference and force held in one chunk's buffer, made once per run; the gauge noise is
        # drawn inside the loop, one standard normal a period from self._rng (the draw of
        # standard_normal(n) * sigma, in the same order: the stream does not depend on the chunking)
        size = min(n, CHUNK)
        if scalar:
            r_const, f_const = readonly(np.full(size, ref)), readonly(np.full(size, force))
        for start in range(0, n, CHUNK):
            stop = min(n, start + CHUNK)
            if scalar:
                r_chunk, f_chunk = r_const[:stop - start], f_const[:stop - start]
            else:
                r_chunk, f_chunk = ref[start:stop], force[start:stop]
            _loop(self.sim.m, self.sim.st, self.n_sub, r_chunk, f_chunk, self._rng, self.sigma_v, self._gp, self._r0, self._form,
                  self._ha, self._hb, self._hc, self._hd, self._hx, float(c.gain), self._sos, self._fb, self._fa,
                  self._fshift, self._ffrac, self._fin, self._in_scale, self._out_scale, self._csf, self._csi, self._vmf, self._vmi, self._lim,
                  self._limw, self.anti_windup, decimate, self._io, rec, stats)
        dt = c.dt_s
        t = (self._k + (np.arange(rec.shape[0]) + 1) * decimate) * dt
        self._k += n
        return ClosedLoopRun(t, *(rec[:, i] for i in range(rec.shape[1])), peak_current_a=(stats[0], stats[1]),
                             periods_at_current_limit=stats[2] / self.n_sub, samples_rate_limited=int(stats[3]),
                             samples_range_limited=int(stats[4]), periods=int(n))
