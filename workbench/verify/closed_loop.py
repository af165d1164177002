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
   quantization of the 80 conversions, then the firmware trim. The 80 conversions are not
   simulated one by one here (``gauge_run`` does that, and the tests tie the two together);
3. the controller computes its output from the reading **sample by sample** as firmware
   does: the Hanus form of the exported JSON (rate limit from the last output, the output
   range, the state conditioned on the limited output; see
   :mod:`workbench.design.antiwindup`), or, with ``anti_windup=False``, the plain linear
   realization with only the range clip;
4. that output is applied at the next period (the one-sample compute delay).

Nothing in the loop allocates or calls Python: a 10^7-period run is a single call.
Traces are decimated inside the loop; streaming statistics (current peaks, time at the
current limit or the rate limit) are accumulated there too, so long runs need no
full-rate arrays.
"""

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..design.antiwindup import HanusController
from ..plant import kernels as K
from ..plant.gauge import _bridge, demod_noise_sigma_v
from ..plant.simulator import PZTSimulator

__all__ = ["controller_from_json", "ClosedLoopRun", "ClosedLoop"]

TRACE_NAMES = ("x_m", "reading_v", "u_v", "error_v", "force_n", "i_a")


def controller_from_json(data):
    """The ``anti_windup`` block of an exported controller JSON as a HanusController."""
    aw = data["anti_windup"]
    n = len(aw["b"])
    return HanusController(a=np.asarray(aw["a"], dtype=float).reshape(n, n),
                           b=np.asarray(aw["b"], dtype=float).reshape(n, 1),
                           c=np.asarray(aw["c"], dtype=float).reshape(1, n), d=float(aw["d"]),
                           dt_s=1.0 / float(data["sample_rate_hz"]),
                           output_limits_v=tuple(float(v) for v in aw.get("output_limits_v", data["output_limits_v"])),
                           rate_limits_v_per_s=tuple(float(v) for v in aw["output_rate_limit_v_per_s"]))


@njit(cache=True, error_model="numpy")
def _loop(m, st, n_sub, ref, force, gp, r0, a, b, c, d, lim, xk, u0, x0, anti_windup, seed, decimate, rec, stats):
    """Closed loop over len(ref) servo periods from output ``u0`` and displacement ``x0``.

    ``stats``: [i_max, i_min, n_at_current_limit, n_rate_limited, n_range_limited]. The
    controller state ``xk`` is updated in place; returns (next output, last displacement).
    """
    np.random.seed(seed)
    out = np.empty(K.N_OUT)
    n = xk.shape[0]
    xn = np.empty(n)
    L, W, kgf, vm, amp, adc_fs, demod, trim_s, trim_b, sigma = (gp[0], gp[1], gp[2], gp[3], gp[4], gp[5],
                                                                gp[6], gp[7], gp[8], gp[9])
    lo, hi, up, down = lim[0], lim[1], lim[2], lim[3]
    i_src, i_snk = m[K.I_SRC], m[K.I_SNK]
    u = u0
    pending = u0
    x_prev = x0
    xprev_sub = x0
    row = 0
    count = 0
    for k in range(ref.shape[0]):
        u = pending
        fk = force[k]
        x_start = x_prev
        xq = 0.0
        xt = 0.0
        xsum = 0.0
        i_peak = 0.0
        for j in range(n_sub):
            K.pzt_step(m, st, u, fk, out)
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
        dem = 0.5 * demod * (vp - vn)
        if sigma > 0.0:
            dem += sigma * np.random.standard_normal()
        reading = trim_s * dem + trim_b
        e = ref[k] - reading
        # controller, sample by sample
        u_raw = d * e
        for i in range(n):
            u_raw += c[i] * xk[i]
        if anti_windup:
            un = min(max(u_raw, u - down), u + up)
            if un != u_raw:
                stats[3] += 1
            u_lim = min(max(un, lo), hi)
            if u_lim != un:
                stats[4] += 1
            # conditioned on the limited output: x <- a x + b e_equiv, e_equiv = (u_lim - c x) / d
            e_eq = (u_lim - (u_raw - d * e)) / d
        else:
            u_lim = min(max(u_raw, lo), hi)
            if u_lim != u_raw:
                stats[4] += 1
            e_eq = e
        for i in range(n):
            acc = b[i] * e_eq
            for jj in range(n):
                acc += a[i, jj] * xk[jj]
            xn[i] = acc
        for i in range(n):
            xk[i] = xn[i]
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
    return pending, x_prev


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
    samples_rate_limited: int
    samples_range_limited: int
    periods: int


class ClosedLoop:
    """The plant file's PZT and gauge with an exported controller, stepped at the servo rate.

    Parameters
    ----------
    plant : Plant
    controller : HanusController (see :func:`controller_from_json`)
    n_sub : int
        Plant steps per servo period (1: the plant's exact RC step over the whole period).
    noise : bool
        Gauge noise and ADC quantization (one Gaussian term per reading).
    anti_windup : bool
        Run the declared anti-windup (rate limit + Hanus); False: the plain controller.
    seed : int
    """

    def __init__(self, plant, controller, n_sub=1, noise=True, anti_windup=True, seed=0):
        g = plant.gauge
        if abs(controller.dt_s - g.period_s) > 1e-9 * g.period_s:
            raise ValueError(f"controller sample time {controller.dt_s:g} s differs from the servo period "
                             f"{g.period_s:g} s of {plant.source}")
        self.plant, self.controller = plant, controller
        self.n_sub, self.anti_windup, self.seed = int(n_sub), bool(anti_windup), int(seed)
        self.sim = PZTSimulator(plant.pzt, g.period_s / self.n_sub)
        self._gp = np.array([g.rest_length_m, g.rest_width_m, g.gauge_factor, g.modulation_v, g.amplifier_gain,
                             g.adc_range_v, g.demodulation_gain, g.trim_scale, g.trim_bias_v,
                             demod_noise_sigma_v(g) if noise else 0.0])
        self._r0 = np.array([g.arm_nominal_ohm + dr for dr in g.imbalance_ohm])
        c = controller
        self._lim = np.array([c.output_limits_v[0], c.output_limits_v[1], c.rate_limits_v_per_s[0] * c.dt_s,
                              c.rate_limits_v_per_s[1] * c.dt_s])
        self._b, self._c = np.ascontiguousarray(c.b[:, 0]), np.ascontiguousarray(c.c[0])
        self.reset()

    def reset(self, u0=0.0):
        """Plant at rest; controller state at rest with output ``u0`` and zero error."""
        self.sim.reset()
        c = self.controller
        from ..design.antiwindup import hanus_initial_state
        self.xk = hanus_initial_state(c, u0)
        self.u = float(u0)
        self.x = self.plant.pzt.k_q2x_m_per_c * self.plant.pzt.hysteresis.output_at_rest()
        self._k = 0

    def run(self, ref_v, force_n=None, decimate=1):
        """Run len(ref_v) servo periods with the reference (firmware volts) and force (N) per period."""
        ref = np.ascontiguousarray(ref_v, dtype=float)
        f = np.zeros_like(ref) if force_n is None else np.ascontiguousarray(force_n, dtype=float)
        if ref.ndim != 1 or f.shape != ref.shape or not (np.all(np.isfinite(ref)) and np.all(np.isfinite(f))):
            raise ValueError("reference and force must be finite 1-D arrays of one length")
        decimate = max(1, int(decimate))
        rec = np.zeros((ref.size // decimate, len(TRACE_NAMES)))
        stats = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
        c = self.controller
        self.u, self.x = _loop(self.sim.m, self.sim.st, self.n_sub, ref, f, self._gp, self._r0, c.a, self._b, self._c, c.d,
                               self._lim, self.xk, self.u, self.x, self.anti_windup, self.seed + self._k, decimate,
                               rec, stats)
        dt = c.dt_s
        t = (self._k + (np.arange(rec.shape[0]) + 1) * decimate) * dt
        self._k += ref.size
        return ClosedLoopRun(t, *(rec[:, i] for i in range(rec.shape[1])), peak_current_a=(stats[0], stats[1]),
                             periods_at_current_limit=stats[2] / self.n_sub, samples_rate_limited=int(stats[3]),
                             samples_range_limited=int(stats[4]), periods=int(ref.size))
