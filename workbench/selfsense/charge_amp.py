"""Charge amplifier on the stack: what a self-sensing circuit (seed 002, Fig. 2.6) reads.

The stack's return electrode goes to the virtual ground of an integrator with capacitor
C_int (the seed's C, eq. 2.1); a reference capacitor C_R, driven with the stack's
terminal voltage inverted (the seed's C_R "in anti-parallel", eq. 2.5), takes
C_R V_in out of the integrated charge so that the output only carries what differs
from a linear capacitor, which keeps it inside the ADC range with a modest C_int:

    V_out = -(Q - C_R V_in) / C_int,
    Q     = q + int V_in / R_FP dt + i_bias t + Q_DA,      Q_DA = sum_j k_j / (tau_j s + 1) V_in

with q the terminal charge of the seed 000 model (:mod:`workbench.plant.pzt`; for a free
stack x = k_q2x q, eq. 10, creep included because the creep branches pass their charge
through the terminals), the leakage current through R_FP, the op-amp bias current, and
dielectric absorption (charge without displacement, seed 002 eq. 2.9). The seed's
inverting integrator gives the sign; everything starts at rest with the integrator reset
at t = 0 (seed 002 sec. 2.4.1: "external resetting before each measurement").

V_in here is the stack's terminal voltage V_t (the seed's V_in: there the HV amplifier
drives the cantilever directly, here the 80 ohm of seed 000 sits between them). The
estimator reads it through an HV monitor ADC.

Defaults (assumed; the seeds give none of them for a stack; a plant file's ``[leakage]`` and
``[dielectric_absorption]`` sections replace the leakage and absorption ones, :func:`charge_amp_params`):

- C_R = 10 uF: about the stack's secant capacitance (1.1 mC at 100 V in the SN637 model),
  so Q - C_R V_in is the hysteresis (~0.1 mC), creep and drift; C_int = 47 uF keeps that
  within +/-5 V of a +/-10 V ADC (a polypropylene film capacitor; its own absorption is
  not modelled).
- R_FP = 1 GOhm: PZT bulk resistivity ~1e11 Ohm m over the ~180 layers of 100 um and
  1 cm^2 of a 10 x 10 x 18 mm stack gives ~5e8 Ohm; seed 002 quotes > 1e10 Ohm for a
  single-layer cantilever, a stack has 100x the electrode area over 1/5 the thickness.
  100 nA at 100 V: 100 uC = 1.4 um of apparent displacement per 1000 s.
- i_bias = 200 pA: a JFET op-amp at the top of its room-temperature spec (TL07x: 65 pA
  typ., 200 pA max); seed 002 says < 1 pA for a good one. 2.8 nm per 1000 s.
- Dielectric absorption: two relaxations, 0.25 uF at 5 s and 0.12 uF at 80 s (2.3 % and
  1.1 % of the secant capacitance). Real absorption is a spread of time constants
  (capacitor models use 3-5 RC branches); seed 002 fits one (eq. 2.9), which is what the
  identification does, so the second branch is what its one-branch model misses.
- Output noise 50 uV RMS per 10 kHz sample (op-amp noise times the noise gain, ADC noise),
  18-bit ADC over +/-10 V; HV monitor 16 bits over +/-150 V with 1 mV RMS noise.

Records can be decimated: then each kept sample stands for the mean of ``average``
ADC conversions, noise falls by sqrt(average) and the quantization is one Gaussian
term (LSB^2/12 per conversion), as :func:`workbench.plant.gauge.gauge_run_equivalent`
treats the gauge.
"""

from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit
from scipy import signal

__all__ = ["ChargeAmpParams", "charge_amp_params", "ChargeRecord", "ChargeAmpStream", "measure", "relax_foh", "cumulative_integral",
           "adc_convert", "adc_lsb_v", "charge_amp_arrays", "charge_amp_step"]


@dataclass(frozen=True)
class ChargeAmpParams:
    """Charge amplifier and the stack's non-displacement charges (SI; see the module notes)."""

    c_int_f: float = 47e-6
    c_ref_f: float = 10e-6
    r_leak_ohm: float = 1e9
    i_bias_a: float = 200e-12
    da_gains_f: tuple = field(default=(0.25e-6, 0.12e-6))
    da_time_constants_s: tuple = field(default=(5.0, 80.0))
    out_noise_v_rms: float = 50e-6
    adc_bits: int = 18
    adc_range_v: float = 10.0
    vin_noise_v_rms: float = 1e-3
    vin_adc_bits: int = 16
    vin_range_v: float = 150.0

    def __post_init__(self):
        for name in ("c_int_f", "r_leak_ohm", "adc_range_v", "vin_range_v"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ChargeAmpParams.{name} must be positive; got {getattr(self, name)!r}")
        for name in ("c_ref_f", "out_noise_v_rms", "vin_noise_v_rms"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"ChargeAmpParams.{name} must be >= 0; got {getattr(self, name)!r}")
        if len(self.da_gains_f) != len(self.da_time_constants_s):
            raise ValueError("da_gains_f and da_time_constants_s must have one entry per relaxation")
        if any(t <= 0 for t in self.da_time_constants_s) or any(k < 0 for k in self.da_gains_f):
            raise ValueError("dielectric absorption needs gains >= 0 and time constants > 0")
        if int(self.adc_bits) < 1 or int(self.vin_adc_bits) < 1:
            raise ValueError("ADC word lengths must be >= 1 bit")

    def ideal(self):
        """The same circuit with no noise and no quantization (for exactness checks)."""
        return replace(self, out_noise_v_rms=0.0, vin_noise_v_rms=0.0, adc_bits=64, vin_adc_bits=64)


def charge_amp_params(plant, base=None):
    """The charge channel of ``plant``: the assumed circuit with the stack's own leakage and absorption when the
    plant file gives them.

    Parameters
    ----------
    plant : workbench.plant.Plant
        Its ``additions`` carry the file's optional ``[leakage] resistance_ohm`` (R_FP, ohm) and
        ``[dielectric_absorption] gain_f`` / ``time_constant_s`` (k_s in F, tau in s: seed 002 eq. 2.9, one
        relaxation), the sections :mod:`workbench.calibrate` fits.
    base : ChargeAmpParams, optional
        The rest of the circuit (default :class:`ChargeAmpParams`: C_int, C_R, bias current, noise and ADCs,
        and the leakage and absorption used when the file has no such section).

    Returns
    -------
    ChargeAmpParams
        ``base`` with ``r_leak_ohm`` = the file's R_FP, and ``da_gains_f`` / ``da_time_constants_s`` = the
        file's single relaxation (k_s,), (tau,) in place of the assumed two, each only when given. Without
        the sections, ``base`` unchanged.
    """
    amp = ChargeAmpParams() if base is None else base
    add = getattr(plant, "additions", None)
    if add is None:
        return amp
    changes = {}
    if add.leakage_resistance_ohm:
        changes["r_leak_ohm"] = float(add.leakage_resistance_ohm)
    if add.absorption_gain_f:
        tau = add.absorption_time_constant_s
        if not tau:
            raise ValueError(f"{plant.source}: [dielectric_absorption] gives gain_f = {add.absorption_gain_f:g} F "
                             f"without time_constant_s; add the absorption time constant in s, e.g. 2.0")
        changes["da_gains_f"] = (float(add.absorption_gain_f),)
        changes["da_time_constants_s"] = (float(tau),)
    return replace(amp, **changes) if changes else amp


@dataclass(frozen=True)
class ChargeRecord:
    """A self-sensing record: what the estimator reads, and the truth beside it.

    ``v_in_v`` and ``v_out_v`` are the measured (noisy, quantized) signals; ``x_m``
    and the charge components are the simulation's truth, for identification
    references and error figures.
    """

    t_s: np.ndarray
    v_in_v: np.ndarray
    v_out_v: np.ndarray
    x_m: np.ndarray
    v_in_true_v: np.ndarray
    q_stack_c: np.ndarray
    q_leak_c: np.ndarray
    q_bias_c: np.ndarray
    q_da_c: np.ndarray
    clipped_fraction: float


def cumulative_integral(t_s, y):
    """int_0^t y dt by trapezoids, from rest (t = 0, y = 0) to each sample."""
    t = np.concatenate([[0.0], np.asarray(t_s, float)])
    yy = np.concatenate([[0.0], np.asarray(y, float)])
    return np.cumsum(0.5 * (yy[1:] + yy[:-1]) * np.diff(t))


def relax_foh(u, tau_s, dt_s):
    """Exact response of tau y' = u - y, y(0) = 0, to u linear between samples (from u = 0 at t = 0).

    y_k = a y_{k-1} + b0 u_{k-1} + b1 u_k with a = exp(-dt/tau),
    b1 = 1 - (tau/dt)(1 - a), b0 = (tau/dt)(1 - a) - a.
    """
    u = np.asarray(u, dtype=float)
    a = float(np.exp(-dt_s / tau_s))
    g = tau_s / dt_s * (1.0 - a)
    b1, b0 = 1.0 - g, g - a
    uu = np.concatenate([[0.0], u])
    y = signal.lfilter([b1, b0], [1.0, -a], uu)
    return y[1:]


def adc_lsb_v(bits, full_scale_v):
    """The LSB of a bipolar ADC of ``bits`` over +/-``full_scale_v``, V; 0.0 for ``bits`` >= 60 (no quantization)."""
    return 2.0 * full_scale_v / 2.0 ** int(bits) if int(bits) < 60 else 0.0


@njit(cache=True)
def adc_convert(v, lsb_v, full_scale_v):
    """One ADC conversion of ``v`` (V): rounded to the LSB, ties to even (as an IEEE rint), then clipped to
    +/-``full_scale_v``; ``lsb_v`` <= 0 leaves it unquantized. The one ADC of the charge channel: the
    record (:func:`measure`), the stream (:class:`ChargeAmpStream`) and verify's compiled loop call it."""
    if lsb_v > 0.0:
        v = np.rint(v / lsb_v) * lsb_v
    return min(max(v, -full_scale_v), full_scale_v)


@njit(cache=True)
def _adc_array(v, lsb_v, full_scale_v):
    out = np.empty(v.size)
    for i in range(v.size):
        out[i] = adc_convert(v[i], lsb_v, full_scale_v)
    return out


def _measured(v, noise_rms, bits, full_scale, average, rng):
    lsb = adc_lsb_v(bits, full_scale)
    if average > 1:
        sig = np.sqrt(noise_rms ** 2 + lsb ** 2 / 12.0) / np.sqrt(average)
        out = v + (rng.standard_normal(v.size) * sig if sig > 0 else 0.0)
        lsb = 0.0                                   # one Gaussian term stands for the quantization
    else:
        out = v + (rng.standard_normal(v.size) * noise_rms if noise_rms > 0 else 0.0)
    clipped = np.abs(out) > full_scale
    return _adc_array(np.asarray(out, float), lsb, float(full_scale)), float(np.mean(clipped))


def charge_amp_arrays(amp, dt_s):
    """The streamed charge amplifier's constants for :func:`charge_amp_step` at sample period ``dt_s``.

    Returns (``cp`` = [dt, R_FP, i_bias, C_R, C_int], ``k`` absorption gains (F), ``a``, ``b0``, ``b1``: the
    first-order-hold recursion of each absorption branch, :func:`relax_foh`'s)."""
    taus = np.asarray(amp.da_time_constants_s, float)
    a = np.exp(-dt_s / taus)
    g = taus / dt_s * (1.0 - a)
    cp = np.array([dt_s, amp.r_leak_ohm, amp.i_bias_a, amp.c_ref_f, amp.c_int_f], float)
    return cp, np.asarray(amp.da_gains_f, float), a, g - a, 1.0 - g


@njit(cache=True, error_model="numpy")
def charge_amp_step(state, q_c, v_t_v, cp, k, a, b0, b1):
    """One sample of the charge amplifier (module notes), its true output V_out before noise and ADC, V.

    ``state`` = [t (s), V_in at the previous sample (V), leakage charge (C), one absorption state (V) per
    branch], updated in place, zeros at rest; ``q_c`` and ``v_t_v``: the stack's terminal charge (C) and
    voltage (V) at this sample; ``cp, k, a, b0, b1`` from :func:`charge_amp_arrays`. The one compiled home
    of the circuit's recursion (:class:`ChargeAmpStream` and verify's sensor loop both step it)."""
    dt = cp[0]
    state[0] += dt
    state[2] += 0.5 * (v_t_v + state[1]) / cp[1] * dt
    q_da = 0.0
    for j in range(k.shape[0]):
        state[3 + j] = a[j] * state[3 + j] + b0[j] * state[1] + b1[j] * v_t_v
        q_da += k[j] * state[3 + j]
    state[1] = v_t_v
    q_tot = q_c + state[2] + cp[2] * state[0] + q_da
    return -(q_tot - cp[3] * v_t_v) / cp[4]


def measure(traj, amp=ChargeAmpParams(), seed=0, average=1):
    """The charge amplifier's record of a :class:`~workbench.plant.simulator.Trajectory`.

    Parameters
    ----------
    traj : Trajectory
        A run of :class:`~workbench.plant.simulator.PZTSimulator` from rest (uniform samples).
    amp : ChargeAmpParams
    seed : int
        Seed of the noise generator.
    average : int
        ADC conversions each kept sample averages (the simulator's ``decimate``).
    """
    t = np.asarray(traj.t_s, float)
    if t.size < 2:
        raise ValueError("the trajectory needs at least two samples")
    dt = float(t[1] - t[0])
    v = np.asarray(traj.v_t_v, float)
    q_leak = cumulative_integral(t, v / amp.r_leak_ohm)
    q_bias = amp.i_bias_a * t
    q_da = np.zeros_like(v)
    for k, tau in zip(amp.da_gains_f, amp.da_time_constants_s):
        q_da += k * relax_foh(v, tau, dt)
    q_stack = np.asarray(traj.q_c, float)
    q_total = q_stack + q_leak + q_bias + q_da
    v_out_true = -(q_total - amp.c_ref_f * v) / amp.c_int_f
    rng = np.random.default_rng(seed)
    v_out, clip_o = _measured(v_out_true, amp.out_noise_v_rms, amp.adc_bits, amp.adc_range_v, int(average), rng)
    v_in, clip_i = _measured(v, amp.vin_noise_v_rms, amp.vin_adc_bits, amp.vin_range_v, int(average), rng)
    return ChargeRecord(t_s=t, v_in_v=v_in, v_out_v=v_out, x_m=np.asarray(traj.x_m, float), v_in_true_v=v,
                        q_stack_c=q_stack, q_leak_c=q_leak, q_bias_c=q_bias, q_da_c=q_da,
                        clipped_fraction=max(clip_o, clip_i))


class ChargeAmpStream:
    """:func:`measure` one sample at a time (for closed loops); the same recursions, from rest.

    ``update(q_c, v_t_v)`` takes the stack's terminal charge and voltage at the next sample
    instant and returns (v_in measured, v_out measured); samples are ``dt_s`` apart.
    """

    def __init__(self, amp, dt_s, seed=0):
        self.amp, self.dt = amp, float(dt_s)
        self.arrays = charge_amp_arrays(amp, self.dt)
        self.state = np.zeros(3 + len(amp.da_gains_f))
        self.out_lsb_v = adc_lsb_v(amp.adc_bits, amp.adc_range_v)
        self.in_lsb_v = adc_lsb_v(amp.vin_adc_bits, amp.vin_range_v)
        self.rng = np.random.default_rng(seed)

    def update(self, q_c, v_t_v):
        amp = self.amp
        v = float(v_t_v)
        v_out = charge_amp_step(self.state, float(q_c), v, *self.arrays)
        if amp.out_noise_v_rms > 0:
            v_out += self.rng.standard_normal() * amp.out_noise_v_rms
        v_in = v + (self.rng.standard_normal() * amp.vin_noise_v_rms if amp.vin_noise_v_rms > 0 else 0.0)
        return (adc_convert(v_in, self.in_lsb_v, amp.vin_range_v),
                adc_convert(v_out, self.out_lsb_v, amp.adc_range_v))
