"""Displacement from the charge amplifier: seed 002's static (eqs. 2.5-2.9, 2.30) and dynamic
(eqs. 2.42-2.48) estimators, for a stack.

Static (eq. 2.8 with the sign of the inverting integrator of :mod:`.charge_amp`)::

    delta_s = [C_R V_in - C_int V_out - int V_in / R_FP dt - i_bias t - Q_DA(V_in)] / alpha - F(V_in)

with Q_DA = k_s / (tau s + 1) V_in (eq. 2.9; k_s here in farads, the seed's k_s is k_s / alpha)
and F the optional stage-4 correction (:class:`ResidualCorrection`: a Prandtl-Ishlinskii
operator and an LTI creep operator of V_in, eqs. 2.28-2.29 and 2.36-2.38 as they apply to a
stack). With R_FP = inf, i_bias = 0, k_s = 0 and no F it is eq. 2.30's uncompensated form
alpha delta = C_R V_in - C_int V_out.

What the charge of THIS stack contains. In seed 002 the cantilever's hysteresis and creep
enter V_out - (C_R / C) V_in because that form compares the charge with the voltage (force
sensing, eqs. 2.26-2.29). In the seed 000 model the hysteresis sits in the charge itself
(C_h) and the creep branches pass their charge through the terminals, so the terminal charge
tracks the free stack's displacement exactly (x = k_q2x q, eq. 10) up to the 70 kHz mode:
displacement from charge needs no hysteresis or creep operator for the stack's own
nonlinearity. What remains after leakage, bias and a one-relaxation absorption model is
the absorption those do not describe (here the slower relaxation branch of
:class:`~.charge_amp.ChargeAmpParams`) and the identification errors; the stage-4 operator
is fitted to that residual. Its hysteresis (play) part has nothing physical to find in this
model and comes out small; the run reports each part's size.

Dynamic: with V_out(s) = H(s) V_in(s) (eq. 2.42) the static estimate is
delta_s = [c1 H(s) + c2 - c3/s - k_s/(tau s + 1)] V_in (eq. 2.43), c1 = -C_int/alpha,
c2 = C_R/alpha, c3 = 1/(R_FP alpha) (bias left out, as in the seed). The inverse multiplicative
structure gives delta_d / delta_s = G1 / (G2 + G3) (eq. 2.44) and, with G1 = K D(s),
G2 = c1 H - c3/s - k_s/(tau s + 1), G3 = c2 (eq. 2.48), delta_d / V_in = K D(s) (eq. 2.47).
:func:`dynamic_estimator` builds E = G1 (G2 + G3)^-1 as one proper state-space system.
"""

from dataclasses import dataclass, field

import control
import numpy as np
from numba import njit

from ..plant.hysteresis import play
from .charge_amp import cumulative_integral, relax_foh

__all__ = ["EstimatorParams", "ResidualCorrection", "static_estimate", "charge_estimate",
           "charge_transfer", "output_transfer", "dynamic_gains", "dynamic_estimator", "static_transfer",
           "ss_inverse", "StreamingEstimator", "band_limited", "estimator_arrays", "estimator_step"]


@dataclass(frozen=True)
class ResidualCorrection:
    """Stage-4 operator F(V_in), m: sum_j b_j / (tau_j s + 1) V_in + sum_i w_i play_{r_i}(V_in).

    ``creep_gains_m_per_v`` b_j on ``creep_time_constants_s`` (the LTI creep operator of
    seed 002 eq. 2.38, as a bank of first-order relaxations fitted linearly instead of an
    ARMAX model); ``play_weights_m_per_v`` w_i on ``thresholds_v`` (the PI operator of
    eq. 2.36; r = 0 is the linear term). Signed weights: the residual can be either sign.
    """

    creep_time_constants_s: tuple = ()
    creep_gains_m_per_v: tuple = ()
    thresholds_v: tuple = ()
    play_weights_m_per_v: tuple = ()

    def columns(self, t_s, v_in_v):
        """(creep columns, play columns), each n x k, unit weights."""
        t = np.asarray(t_s, float)
        dt = float(t[1] - t[0])
        v = np.asarray(v_in_v, float)
        cc = [relax_foh(v, tau, dt) for tau in self.creep_time_constants_s]
        pc = [play(v, r, 0.0) for r in self.thresholds_v]
        n = v.size
        return (np.column_stack(cc) if cc else np.zeros((n, 0)), np.column_stack(pc) if pc else np.zeros((n, 0)))

    def parts(self, t_s, v_in_v):
        """(creep term, hysteresis term), m."""
        cc, pc = self.columns(t_s, v_in_v)
        return cc @ np.asarray(self.creep_gains_m_per_v, float), pc @ np.asarray(self.play_weights_m_per_v, float)

    def __call__(self, t_s, v_in_v):
        c, h = self.parts(t_s, v_in_v)
        return c + h


@dataclass(frozen=True)
class EstimatorParams:
    """Parameters of the static estimator (eq. 2.8); defaults switch every compensation off."""

    alpha_c_per_m: float
    c_int_f: float
    c_ref_f: float
    r_leak_ohm: float = float("inf")
    i_bias_a: float = 0.0
    da_gain_f: float = 0.0
    da_time_constant_s: float = 1.0
    correction: ResidualCorrection | None = field(default=None)

    def __post_init__(self):
        if not (self.alpha_c_per_m > 0 and self.c_int_f > 0 and self.c_ref_f >= 0):
            raise ValueError("alpha, C_int must be positive and C_R >= 0")
        if not (self.r_leak_ohm > 0 and self.da_time_constant_s > 0):
            raise ValueError("R_FP and the absorption time constant must be positive")


def charge_estimate(t_s, v_in_v, v_out_v, p):
    """Charge that went into the stack with leakage, bias and absorption taken out, C."""
    t = np.asarray(t_s, float)
    v = np.asarray(v_in_v, float)
    q = p.c_ref_f * v - p.c_int_f * np.asarray(v_out_v, float)
    if np.isfinite(p.r_leak_ohm):
        q = q - cumulative_integral(t, v / p.r_leak_ohm)
    if p.i_bias_a:
        q = q - p.i_bias_a * t
    if p.da_gain_f:
        q = q - p.da_gain_f * relax_foh(v, p.da_time_constant_s, float(t[1] - t[0]))
    return q


def static_estimate(t_s, v_in_v, v_out_v, p):
    """delta_s of eq. 2.8 (plus the stage-4 correction if ``p.correction``), m, per sample.

    Samples must be uniform and start from rest (integrator reset at t = 0).
    """
    d = charge_estimate(t_s, v_in_v, v_out_v, p) / p.alpha_c_per_m
    if p.correction is not None:
        d = d - p.correction(t_s, v_in_v)
    return d


# ---- transfer functions (eqs. 2.42-2.48) -------------------------------------------------------

def _s():
    return control.tf([1.0, 0.0], [1.0])


def _integrator():
    return control.ss([[0.0]], [[1.0]], [[1.0]], [[0.0]])


def _relax(gain, tau):
    return control.ss([[-1.0 / tau]], [[1.0 / tau]], [[gain]], [[0.0]])


def charge_transfer(q_per_v, r_leak_ohm=float("inf"), da_gains_f=(), da_time_constants_s=()):
    """Q(s)/V_in(s) at the integrator: the stack's q/V plus 1/(R_FP s) plus the absorption, C/V."""
    sys = control.ss(q_per_v)
    if np.isfinite(r_leak_ohm):
        sys = sys + _integrator() * (1.0 / r_leak_ohm)
    for k, tau in zip(da_gains_f, da_time_constants_s):
        if k:
            sys = sys + _relax(k, tau)
    return sys


def output_transfer(q_total_per_v, c_int_f, c_ref_f):
    """H(s) = V_out/V_in = -(Q/V_in - C_R)/C_int (eq. 2.42 for the circuit of :mod:`.charge_amp`)."""
    return (control.ss(q_total_per_v) - c_ref_f) * (-1.0 / c_int_f)


def static_transfer(h, p):
    """Eq. 2.43: delta_s / V_in = c1 H(s) + c2 - c3/s - k_s/(tau s + 1), as a StateSpace (bias left out)."""
    c1, c2 = -p.c_int_f / p.alpha_c_per_m, p.c_ref_f / p.alpha_c_per_m
    sys = control.ss(h) * c1 + c2
    if np.isfinite(p.r_leak_ohm):
        sys = sys - _integrator() * (1.0 / (p.r_leak_ohm * p.alpha_c_per_m))
    if p.da_gain_f:
        sys = sys - _relax(p.da_gain_f / p.alpha_c_per_m, p.da_time_constant_s)
    return sys


def dynamic_gains(k_d, h, p):
    """(G1, G2, G3) of eq. 2.48: G1 = K D(s), G2 = c1 H - c3/s - k_s/(tau s + 1), G3 = c2."""
    g3 = p.c_ref_f / p.alpha_c_per_m
    g2 = static_transfer(h, p) - g3
    return control.ss(k_d), g2, g3


def ss_inverse(sys):
    """Inverse of a biproper SISO StateSpace (D != 0): (A - B C/D, B/D, -C/D, 1/D)."""
    sys = control.ss(sys)
    d = float(np.asarray(sys.D)[0, 0])
    if abs(d) < 1e-300:
        raise ValueError("the system is strictly proper (D = 0); its inverse is improper")
    a, b, c = np.asarray(sys.A), np.asarray(sys.B), np.asarray(sys.C)
    return control.ss(a - b @ c / d, b / d, -c / d, [[1.0 / d]])


def dynamic_estimator(g1, g2, g3):
    """E(s) = delta_d / delta_s = G1 (G2 + G3)^-1 (eq. 2.44), one proper StateSpace.

    The inverse multiplicative structure runs u = (delta_s - G2 u) / G3, delta_d = G1 u:
    it is well posed only if G3 + G2(inf) != 0, and then u = (G2 + G3)^-1 delta_s. (G2 + G3
    is biproper here: at high frequency the charge follows V_in through the stack's
    capacitance.) The product is formed in the order (G2 + G3)^-1 G1: SISO, so the same system,
    but python-control's frequency evaluation of the other order's realization loses ~1 % at
    1 mHz (the 70 kHz mode and the millihertz creep poles in one badly scaled matrix).
    """
    return ss_inverse(control.ss(g2) + g3) * control.ss(g1)


def estimator_arrays(p, dt_s):
    """The streamed estimator's constants for :func:`estimator_step` at sample period ``dt_s``.

    Returns (``ep`` = [alpha (C/m), C_int (F), C_R (F), R_FP (Ohm; -1: none), i_bias (A), dt (s)], ``g``
    the relaxation gains (m/V: the absorption's k_s / alpha, then the stage-4 creep gains), ``a``, ``b0``,
    ``b1`` their first-order-hold recursions, ``r`` the play thresholds (V), ``w`` their weights (m/V))."""
    c = p.correction or ResidualCorrection()
    taus = np.array([p.da_time_constant_s, *c.creep_time_constants_s], float)
    gains = np.array([p.da_gain_f / p.alpha_c_per_m, *c.creep_gains_m_per_v], float)
    a = np.exp(-dt_s / taus)
    g = taus / dt_s * (1.0 - a)
    ep = np.array([p.alpha_c_per_m, p.c_int_f, p.c_ref_f, p.r_leak_ohm if np.isfinite(p.r_leak_ohm) else -1.0,
                   p.i_bias_a, dt_s], float)
    return (ep, gains, a, g - a, 1.0 - g, np.asarray(c.thresholds_v, float),
            np.asarray(c.play_weights_m_per_v, float))


@njit(cache=True, error_model="numpy")
def estimator_step(state, z, v_in_v, v_out_v, ep, g, a, b0, b1, r, w):
    """delta_s of :func:`static_estimate` at the next sample, m: one step of the same recursions, from rest.

    ``state`` = [t (s), V_in at the previous sample (V), leakage charge (C), one relaxation state (V) per
    gain], ``z`` the play states (V), both updated in place; the rest from :func:`estimator_arrays`. The
    one compiled home of the streamed estimator (:class:`StreamingEstimator` and verify's sensor loop)."""
    dt = ep[5]
    state[0] += dt
    if ep[3] > 0:
        state[2] += 0.5 * (v_in_v + state[1]) / ep[3] * dt
    corr = 0.0
    for j in range(g.shape[0]):
        state[3 + j] = a[j] * state[3 + j] + b0[j] * state[1] + b1[j] * v_in_v
        corr += g[j] * state[3 + j]
    state[1] = v_in_v
    for j in range(r.shape[0]):
        z[j] = max(v_in_v - r[j], min(v_in_v + r[j], z[j]))
        corr += w[j] * z[j]
    q = ep[2] * v_in_v - ep[1] * v_out_v - state[2] - ep[4] * state[0]
    return q / ep[0] - corr


class StreamingEstimator:
    """:func:`static_estimate` one sample at a time, as firmware would run it (:func:`estimator_step`, from rest)."""

    def __init__(self, p, dt_s):
        self.p, self.dt = p, float(dt_s)
        self.arrays = estimator_arrays(p, self.dt)
        self.state = np.zeros(3 + self.arrays[1].size)
        self.z = np.zeros(self.arrays[5].size)

    def update(self, v_in_v, v_out_v):
        """delta_s at the next sample, m."""
        return estimator_step(self.state, self.z, float(v_in_v), float(v_out_v), *self.arrays)


def band_limited(sys, dt_s):
    """``sys`` with its modes above the Nyquist frequency pi/dt_s residualized (DC gain kept).

    What a firmware filter at 1/dt_s can run: E(s) carries the stack's 70 kHz mode (from
    G1 = K D(s)), which a 10 kHz discretization would alias (a zero-order-hold copy rings
    in the samples, a Tustin copy puts a lightly damped peak near Nyquist). Modal form,
    then :func:`control.modred` with ``matchdc`` on the fast states.
    """
    sys = control.ss(sys)
    if sys.nstates == 0:
        return sys
    em, _ = control.canonical_form(sys, "modal")
    a = np.asarray(em.A)
    lim = np.pi / float(dt_s)
    n = a.shape[0]
    fast = []
    for i in range(n):
        lo, hi = max(i - 1, 0), min(i + 2, n)
        if np.max(np.abs(a[i, lo:hi])) > lim or np.max(np.abs(a[lo:hi, i])) > lim:
            fast.append(i)
    if not fast:
        return em
    if len(fast) == n:
        return control.ss([], [], [], [[float(np.real(sys.dcgain()))]])
    return control.modred(em, fast, method="matchdc")
