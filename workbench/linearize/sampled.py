"""Sampled-data model of the servo loop: DAC hold, plant, period-averaging gauge, compute delay.

The servo runs at the gauge modulation rate, T = ``g.period_s`` (10 kHz), with
sample instants t_k = k T. Timing convention:

- the reading r_k, available at t_k, is the MEAN of the displacement over
  (t_{k-1}, t_k]: the 40 + 40 ADC samples average the bridge over the whole
  modulation period (:func:`workbench.plant.gauge.gauge_run`), which delays the
  reading by T/2 on average;
- the controller output c_k computed from reading r_k is applied at
  t_{k + delay_samples} and held by the DAC (zero-order hold) until the next
  sample instant, which delays the drive by another T/2 on average.

So the DAC value u_k = c_{k - delay_samples} is held over [t_k, t_{k+1}), and r_k
depends on u_{k-1} and the plant state at t_{k-1}: even with ``delay_samples = 0``
the model from c to r is strictly proper, and at low frequency its phase is the
plant's minus omega T (1 + delay_samples).

The exact discrete model (no approximation of the hold or the average) comes from
one matrix exponential of a block matrix (Van Loan), which needs no inverse of A
and so handles integrators and other singular A.
"""

import operator

import control
import numpy as np
from scipy.linalg import expm

from ..plant.gauge import arm_resistances

__all__ = ["gauge_gain_v_per_m", "period_average", "compute_delay", "firmware_plant", "sampled_elements"]


def _check_dt(dt_s):
    try:
        t = float(dt_s)
    except (TypeError, ValueError):
        raise ValueError(f"dt_s must be a positive finite number of seconds; got {dt_s!r}") from None
    if not np.isfinite(t) or t <= 0:
        raise ValueError(f"dt_s must be a positive finite number of seconds; got {dt_s!r}")
    return t


def _check_samples(samples):
    try:
        n = operator.index(samples)
    except TypeError:
        raise ValueError(f"delay must be a non-negative integer number of samples; got {samples!r}") from None
    if isinstance(samples, bool) or n < 0:
        raise ValueError(f"delay must be a non-negative integer number of samples; got {samples!r}")
    return n


def _continuous_siso(sys_c):
    """sys_c as a continuous SISO StateSpace with finite matrices, or ValueError saying why not."""
    if not isinstance(sys_c, (control.StateSpace, control.TransferFunction)):
        raise ValueError(f"sys_c must be a control.StateSpace or TransferFunction; got {type(sys_c).__name__}")
    if sys_c.isdtime(strict=True):
        raise ValueError(f"sys_c must be continuous-time; it is already discrete (dt = {sys_c.dt})")
    if (sys_c.ninputs, sys_c.noutputs) != (1, 1):
        raise ValueError(f"sys_c must be SISO; it has {sys_c.ninputs} inputs and {sys_c.noutputs} outputs")
    if isinstance(sys_c, control.TransferFunction):
        num, den = np.asarray(sys_c.num[0][0], float), np.asarray(sys_c.den[0][0], float)
        if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))):
            raise ValueError("sys_c has non-finite coefficients")
        if len(np.trim_zeros(num, "f")) > len(np.trim_zeros(den, "f")):
            raise ValueError("sys_c is improper (numerator degree above denominator degree); "
                             "a held input cannot drive it")
    ss = control.ss(sys_c)
    if not all(np.all(np.isfinite(m)) for m in (ss.A, ss.B, ss.C, ss.D)):
        raise ValueError("sys_c has non-finite matrices")
    return ss


def gauge_gain_v_per_m(x0_m, g):
    """Small-signal firmware volts per metre at x0, from eq. 26 WITH the arm imbalance.

    :func:`workbench.plant.gauge.chain_gain` uses eq. 27 (no imbalance); the loop gain
    the controller sees is the slope of the real bridge, so this differentiates eq. 26
    analytically: each ratio (a - b)/(a + b) has slope 2 (a' b - a b') / (a + b)^2.
    """
    x0 = float(x0_m)
    if not np.isfinite(x0):
        raise ValueError(f"x0_m must be finite; got {x0_m!r}")
    L, W, k = g.rest_length_m, g.rest_width_m, g.gauge_factor
    r0 = [g.arm_nominal_ohm + d for d in g.imbalance_ohm]
    r_wy, r_gb, r_yg, r_wb = arm_resistances(x0, g)
    d_wy, d_gb = -r0[0] * k * W / L ** 2, -r0[1] * k * W / L ** 2   # widthwise arms fall
    d_yg, d_wb = r0[2] * k / L, r0[3] * k / L                       # lengthwise arms rise

    def ratio_slope(a, da, b, db):
        return 2 * (da * b - a * db) / (a + b) ** 2

    bridge = g.modulation_v * (ratio_slope(r_wb, d_wb, r_wy, d_wy) - ratio_slope(r_gb, d_gb, r_yg, d_yg))
    return float(bridge) * g.amplifier_gain * g.demodulation_gain * g.trim_scale


def period_average(sys_c, dt_s):
    """Exact discrete model: input held over [kT, (k+1)T), output the mean of y over ((k-1)T, kT].

    With Phi = e^{AT}, M1 = (1/T) int_0^T e^{A t} dt and M2 = (1/T) int_0^T int_0^t e^{A s} ds dt,
    the mean over a period that starts at state x with held input u is C (M1 x + M2 B u) + D u.
    The state is [x((k-1)T); u_{k-1}], so the model is strictly proper and its poles are
    e^{pT} for the poles p of sys_c plus one at z = 0 (no spurious pole at z = 1). It is
    minimal when sys_c is, barring pathological sampling (pole pairs 2 pi j / T apart).
    """
    t = _check_dt(dt_s)
    ss = _continuous_siso(sys_c)
    a, b, c, d = (np.asarray(m, float) for m in (ss.A, ss.B, ss.C, ss.D))
    n = a.shape[0]
    # expm([[A T, I, 0], [0, 0, I], [0, 0, 0]]) = [[Phi, M1, M2 / T], ...]: dimensionless, no A^-1
    blk = np.zeros((3 * n, 3 * n))
    blk[:n, :n] = a * t
    blk[:n, n:2 * n] = np.eye(n)
    blk[n:2 * n, 2 * n:] = np.eye(n)
    e = expm(blk)
    phi, m1, m2 = e[:n, :n], e[:n, n:2 * n], t * e[:n, 2 * n:]
    ad = np.block([[phi, t * m1 @ b], [np.zeros((1, n)), np.zeros((1, 1))]])
    bd = np.vstack([np.zeros((n, 1)), np.ones((1, 1))])
    cd = np.hstack([c @ m1, c @ m2 @ b + d])
    return control.ss(ad, bd, cd, np.zeros((1, 1)), t)


def compute_delay(dt_s, samples=1):
    """z^-samples as a discrete StateSpace (a shift register); samples = 0 is the unit gain."""
    t = _check_dt(dt_s)
    n = _check_samples(samples)
    if n == 0:
        return control.ss(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1)), t)
    b = np.zeros((n, 1))
    b[0, 0] = 1.0
    c = np.zeros((1, n))
    c[0, -1] = 1.0
    return control.ss(np.eye(n, k=-1), b, c, np.zeros((1, 1)), t)


def sampled_elements(sys_v_to_x, g, x0_m, delay_samples=1):
    """The pieces of :func:`firmware_plant`, named so a report can show each.

    ``sys_v_to_x`` is the continuous small-signal model from PZT voltage (V) to
    displacement (m); the gauge gain is taken at the operating point x0_m.
    """
    t = g.period_s
    return {"zoh_and_average": period_average(sys_v_to_x, t),
            "gauge_gain_v_per_m": gauge_gain_v_per_m(x0_m, g),
            "compute_delay": compute_delay(t, delay_samples)}


def firmware_plant(sys_v_to_x, g, x0_m, delay_samples=1):
    """Discrete model at T = g.period_s from the controller output (V) to the firmware reading (V).

    The chain, in signal order: compute delay, DAC hold + plant + period average, gauge gain.
    """
    e = sampled_elements(sys_v_to_x, g, x0_m, delay_samples)
    return e["gauge_gain_v_per_m"] * (e["zoh_and_average"] * e["compute_delay"])
