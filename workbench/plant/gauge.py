"""The strain-gauge chain of seed 000 section 5.

Arms (eqs. 18-21): the two lengthwise arms (Y-G, W-B) rise by k_gf R x / L_rest, the
two widthwise arms (W-Y, G-B) fall by k_gf R (W_rest/L_rest) x / L_rest, each from
its own rest value R_nom + dR (the intrinsic imbalance).

Bridge (eq. 26) with V+ = V_mod and V- = -V_mod. The printed eqs. 22-25 repeat
R_(Y-G); eq. 26 follows from the bridge of Fig. 1 with R_(W-B) in the right branch,
so it is derived from eq. 26 here (seeds README). Without imbalance eq. 26 reduces
to eq. 27, and its derivative is

    dV/dx = 4 L^2 V_mod k_gf (L + W) / (2 L^2 + k_gf (L - W) x)^2,

which has no x in the numerator: the printed eq. 28 carries a stray x_pzt, and only
the form above gives the quoted 354.18 V/m at x0 = 7.5 um (tests check both).

Sampled chain (Fig. 11): the bridge is excited by a square wave at f_mod; the x300
amplifier output is sampled by a 14-bit +/-2.5 V ADC at 800 kHz, 40 samples are
averaged in each half period and the firmware differences the halves (gain 2,
since the halves carry the same signal with opposite sign), applies the trim
(scale, bias) and writes a +/-2.6 V DAC. :func:`gauge_run` models this sample by
sample (80 ADC conversions per period, displacement interpolated linearly within
the period); :func:`gauge_run_equivalent` is the per-period equivalent used in long
runs (the half-period means of the interpolated displacement, the ADC noise and
quantization folded into one Gaussian term). Averaging over the two halves delays
the reading by half a modulation period on average.
"""

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.optimize import brentq

__all__ = ["GaugeParams", "arm_resistances", "bridge_output", "bridge_output_eq27", "bridge_gain",
           "bridge_gain_eq28_printed", "four_probe_measure", "four_probe_solve", "chain_gain",
           "gauge_run", "gauge_run_equivalent", "GaugeReading", "design_trim", "gauge_summary",
           "displacement_from_reading", "TRIM_CENTER_M", "demod_noise_sigma_v", "bridge_curvature_per_m",
           "linearized_displacement"]

@dataclass(frozen=True)
class GaugeParams:
    """The gauge chain, SI. ``imbalance_ohm`` is (W-Y, G-B, Y-G, W-B)."""

    rest_length_m: float
    rest_width_m: float
    gauge_factor: float
    arm_nominal_ohm: float
    imbalance_ohm: tuple
    modulation_v: float
    modulation_hz: float
    amplifier_gain: float
    adc_bits: int
    adc_range_v: float
    adc_rate_hz: float
    samples_per_half_period: int
    demodulation_gain: float
    trim_scale: float
    trim_bias_v: float
    dac_range_v: float
    dac_bits: int
    noise_rms_m: float
    calibration_m_per_v: float

    def check(self):
        """Cross-field consistency: the ADC rate must fit the averaged samples."""
        need = 2 * self.samples_per_half_period * self.modulation_hz
        if abs(need - self.adc_rate_hz) > 1e-6 * self.adc_rate_hz:
            raise ValueError(f"adc_rate_hz = {self.adc_rate_hz:g} but 2 x samples_per_half_period x "
                             f"modulation_hz = {need:g}; the ADC must take exactly the averaged samples "
                             f"in each period")

    @property
    def period_s(self):
        return 1.0 / self.modulation_hz

    def replace(self, **changes):
        from dataclasses import replace
        return replace(self, **changes)


def arm_resistances(x_m, g):
    """Eqs. 18-21: the four arm resistances (W-Y, G-B, Y-G, W-B), ohm, at displacement x."""
    x = np.asarray(x_m, float)
    L, W, k = g.rest_length_m, g.rest_width_m, g.gauge_factor
    r0 = [g.arm_nominal_ohm + d for d in g.imbalance_ohm]
    strain = x / L
    return (r0[0] * (1 - k * (W / L) * strain), r0[1] * (1 - k * (W / L) * strain),
            r0[2] * (1 + k * strain), r0[3] * (1 + k * strain))


def bridge_output(x_m, g, v_mod=None):
    """Eq. 26 with V+ = V_mod, V- = -V_mod: bridge differential output, V."""
    vm = g.modulation_v if v_mod is None else v_mod
    r_wy, r_gb, r_yg, r_wb = arm_resistances(x_m, g)
    return ((r_wb - r_wy) / (r_wb + r_wy) - (r_gb - r_yg) / (r_gb + r_yg)) * vm


def bridge_output_eq27(x_m, g):
    """Eq. 27: the bridge output without imbalance, V."""
    x = np.asarray(x_m, float)
    L, W, k, vm = g.rest_length_m, g.rest_width_m, g.gauge_factor, g.modulation_v
    return 2 * vm * k * (L + W) * x / (2 * L * L + k * L * x - W * k * x)


def bridge_gain(x0_m, g):
    """Derivative of eq. 27 at x0, V/m (the corrected eq. 28, no x in the numerator)."""
    L, W, k, vm = g.rest_length_m, g.rest_width_m, g.gauge_factor, g.modulation_v
    return 4 * L * L * vm * k * (L + W) / (2 * L * L + k * (L - W) * x0_m) ** 2


def bridge_gain_eq28_printed(x0_m, g):
    """Eq. 28 as printed (with the stray x_pzt in the numerator), V/m; kept to show the slip."""
    L, W, k, vm = g.rest_length_m, g.rest_width_m, g.gauge_factor, g.modulation_v
    return 4 * L * L * vm * k * x0_m * (L + W) / (2 * L * L + k * (L - W) * x0_m) ** 2


def four_probe_measure(arms):
    """Eqs. 14-17: the resistance across each arm with the other three in parallel.

    ``arms`` is (W-Y, G-B, Y-G, W-B); the ring is W-Y, Y-G, G-B, W-B, so each probe
    reads R_i || (S - R_i) = R_i (S - R_i) / S with S the sum of the four.
    """
    a = np.asarray(arms, float)
    s = a.sum()
    return a * (s - a) / s


def four_probe_solve(measured):
    """Invert eqs. 14-17: the arm resistances from the four probe readings.

    Each reading m_i = R_i (S - R_i)/S gives R_i = (S - sqrt(S^2 - 4 m_i S))/2 on the
    branch R_i < S/2 (an arm is less than half the ring), and S is the root of
    sum_i R_i(S) = S, found by bracketing. This is the one real solution the seed
    reports among the four of its polynomial system.
    """
    m = np.asarray(measured, float)
    if m.shape != (4,) or np.any(~np.isfinite(m)) or np.any(m <= 0):
        raise ValueError(f"need four positive finite readings; got {measured!r}")

    def arms(s):
        return (s - np.sqrt(np.maximum(s * s - 4 * m * s, 0.0))) / 2

    def resid(s):
        return arms(s).sum() - s

    lo = 4 * m.max() * (1 + 1e-12)
    hi = 16 * m.sum()
    if resid(lo) * resid(hi) > 0:
        raise ValueError(f"readings {m.tolist()} are not those of a four-arm ring")
    s = brentq(resid, lo, hi, xtol=1e-14, rtol=1e-15)
    return arms(s)


def chain_gain(x0_m, g):
    """Small-signal firmware volts per metre at x0: bridge x amplifier x demodulation x trim."""
    return bridge_gain(x0_m, g) * g.amplifier_gain * g.demodulation_gain * g.trim_scale


@njit(cache=True, inline="always")
def _bridge(x, L, W, kgf, r0, vm):
    s = x / L
    r_wy = r0[0] * (1 - kgf * (W / L) * s)
    r_gb = r0[1] * (1 - kgf * (W / L) * s)
    r_yg = r0[2] * (1 + kgf * s)
    r_wb = r0[3] * (1 + kgf * s)
    return ((r_wb - r_wy) / (r_wb + r_wy) - (r_gb - r_yg) / (r_gb + r_yg)) * vm


@njit(cache=True, inline="always")
def _quantize(v, full_scale, bits):
    lsb = 2.0 * full_scale / (2.0 ** bits)
    if v > full_scale - lsb:
        v = full_scale - lsb
    if v < -full_scale:
        v = -full_scale
    return math.floor(v / lsb + 0.5) * lsb


@njit(cache=True)
def _gauge_kernel(x, x_prev0, L, W, kgf, r0, vm, amp, adc_fs, adc_bits, n_half, sigma_adc, demod,
                  trim_s, trim_b, dac_fs, dac_bits, seed, demod_out, dac_out):
    np.random.seed(seed)
    x_prev = x_prev0
    n2 = 2 * n_half
    for k in range(x.shape[0]):
        dx = x[k] - x_prev
        acc_p = 0.0
        acc_m = 0.0
        for j in range(n2):
            xs = x_prev + dx * (j + 0.5) / n2
            sign = 1.0 if j < n_half else -1.0
            v = amp * _bridge(xs, L, W, kgf, r0, sign * vm)
            if sigma_adc > 0.0:
                v += sigma_adc * np.random.standard_normal()
            v = _quantize(v, adc_fs, adc_bits)
            if j < n_half:
                acc_p += v
            else:
                acc_m += v
        d = 0.5 * demod * (acc_p - acc_m) / n_half
        demod_out[k] = d
        dac_out[k] = _quantize(trim_s * d + trim_b, dac_fs, dac_bits)
        x_prev = x[k]


@njit(cache=True)
def _gauge_kernel_eq(x, x_prev0, L, W, kgf, r0, vm, amp, adc_fs, sigma_dem, demod, trim_s, trim_b,
                     dac_fs, dac_bits, seed, demod_out, dac_out):
    np.random.seed(seed)
    x_prev = x_prev0
    for k in range(x.shape[0]):
        dx = x[k] - x_prev
        vp = min(max(amp * _bridge(x_prev + 0.25 * dx, L, W, kgf, r0, vm), -adc_fs), adc_fs)
        vn = min(max(amp * _bridge(x_prev + 0.75 * dx, L, W, kgf, r0, -vm), -adc_fs), adc_fs)
        d = 0.5 * demod * (vp - vn)
        if sigma_dem > 0.0:
            d += sigma_dem * np.random.standard_normal()
        demod_out[k] = d
        dac_out[k] = _quantize(trim_s * d + trim_b, dac_fs, dac_bits)
        x_prev = x[k]


@dataclass(frozen=True)
class GaugeReading:
    """Per modulation period: demodulated volts (before trim) and the DAC output, V."""

    demod_v: np.ndarray
    dac_v: np.ndarray


def _noise_per_adc_sample(g, x0_m=7.5e-6):
    """ADC-input noise (V RMS per sample) that gives noise_rms_m after averaging and demodulation."""
    n = g.samples_per_half_period
    per_m = bridge_gain(x0_m, g) * g.amplifier_gain * g.demodulation_gain
    return g.noise_rms_m * per_m / (0.5 * g.demodulation_gain * math.sqrt(2.0 / n))


def gauge_run(x_m, g, x_prev_m=0.0, seed=0, noise=True):
    """Sample-by-sample gauge chain over displacement samples at the modulation rate.

    Parameters
    ----------
    x_m : ndarray of float
        Displacement at the end of each modulation period, m.
    g : GaugeParams
    x_prev_m : float
        Displacement at the start of the first period.
    seed : int
        Seed of the noise generator (deterministic runs).
    noise : bool
        Add the gauge noise (``g.noise_rms_m`` referred to displacement).
    """
    x = np.ascontiguousarray(x_m, dtype=float)
    sig = _noise_per_adc_sample(g) if noise else 0.0
    r0 = np.array([g.arm_nominal_ohm + d for d in g.imbalance_ohm])
    dem, dac = np.empty_like(x), np.empty_like(x)
    _gauge_kernel(x, float(x_prev_m), g.rest_length_m, g.rest_width_m, g.gauge_factor, r0, g.modulation_v,
                  g.amplifier_gain, g.adc_range_v, g.adc_bits, g.samples_per_half_period, sig,
                  g.demodulation_gain, g.trim_scale, g.trim_bias_v, g.dac_range_v, g.dac_bits, seed, dem, dac)
    return GaugeReading(dem, dac)


def demod_noise_sigma_v(g):
    """RMS noise of one demodulated reading, V: the gauge noise and the ADC quantization
    (LSB^2/12 per conversion) of the 2 x n averaged conversions, as one Gaussian term."""
    n = g.samples_per_half_period
    lsb = 2 * g.adc_range_v / 2 ** g.adc_bits
    sig_adc = _noise_per_adc_sample(g)
    return 0.5 * g.demodulation_gain * math.sqrt(2.0 / n) * math.sqrt(sig_adc ** 2 + lsb ** 2 / 12)


def gauge_run_equivalent(x_m, g, x_prev_m=0.0, seed=0, noise=True):
    """Per-period equivalent of :func:`gauge_run` (one bridge evaluation per half period).

    The ADC quantization error of the 2 x 40 averaged samples (LSB^2/12 each) is
    added to the Gaussian noise rather than applied sample by sample.
    """
    x = np.ascontiguousarray(x_m, dtype=float)
    sig = demod_noise_sigma_v(g) if noise else 0.0
    r0 = np.array([g.arm_nominal_ohm + d for d in g.imbalance_ohm])
    dem, dac = np.empty_like(x), np.empty_like(x)
    _gauge_kernel_eq(x, float(x_prev_m), g.rest_length_m, g.rest_width_m, g.gauge_factor, r0, g.modulation_v,
                     g.amplifier_gain, g.adc_range_v, sig, g.demodulation_gain, g.trim_scale, g.trim_bias_v,
                     g.dac_range_v, g.dac_bits, seed, dem, dac)
    return GaugeReading(dem, dac)


TRIM_CENTER_M = 7.5e-6  # the seed's x0: mid-stroke, where design_trim puts 0 firmware volts


def displacement_from_reading(demod_v, g, x_center_m=TRIM_CENTER_M):
    """Displacement, m, that firmware infers from demodulated volts: trim, then calibration.

    The inverse of the trim :func:`design_trim` makes: firmware volts times the serial's
    calibration, plus the displacement the trim maps to 0 V.
    """
    return (g.trim_scale * np.asarray(demod_v) + g.trim_bias_v) * g.calibration_m_per_v + x_center_m


def bridge_curvature_per_m(g, x_center_m=TRIM_CENTER_M):
    """beta = V''/(2 V') of eq. 27 at ``x_center_m``, 1/m: the bridge's quadratic term relative to its slope.

    Eq. 27, V = A x / (B + C x) with B = 2 L^2 and C = k (L - W), gives V' = A B / (B + C x)^2 and
    V'' = -2 A B C / (B + C x)^3, so beta = -C / (B + C x_c). A linear calibration at x_c then reads
    x_c + u + beta u^2 for x = x_c + u (SN637: beta = -25 1/m, -1.4 nm at the ends of the 15 um stroke).
    It depends on the gauge's geometry and gauge factor only, which firmware knows as it knows the slope.
    """
    L, W, k = g.rest_length_m, g.rest_width_m, g.gauge_factor
    c = k * (L - W)
    return -c / (2.0 * L * L + c * x_center_m)


@njit(cache=True)
def linearized_displacement(x_lin_m, beta_per_m, x_center_m=TRIM_CENTER_M):
    """The displacement a linear calibration's ``x_lin_m`` stands for, with eq. 27's curvature taken out, m.

    Compiled: firmware's conversion in the compiled sensor loop (:mod:`workbench.verify.sensors`) calls it
    per period, so the loop and this function are one home (scalar or array ``x_lin_m``).

    x = x_lin - beta u^2 with u = x_lin - x_c (:func:`bridge_curvature_per_m`); what is left is of order
    beta^2 u^3 (SN637: 1e-13 m at the ends of the stroke) and the arm imbalance's share of the curvature.
    """
    u = x_lin_m - x_center_m
    return x_lin_m - beta_per_m * u * u


def design_trim(g, x_center_m=TRIM_CENTER_M):
    """Firmware trim (scale, bias_v) that makes the chain read (x - x_center) / calibration.

    The scale matches the serial's calibration slope at x_center (the seed's x0 of
    7.5 um, mid-stroke) and the bias cancels the bridge output there, imbalance
    included, so 0-15 um maps to about +/-2.4 V inside the +/-2.6 V DAC range.
    """
    per_m = bridge_gain(x_center_m, g) * g.amplifier_gain * g.demodulation_gain
    scale = 1.0 / (g.calibration_m_per_v * per_m)
    demod_center = g.demodulation_gain * g.amplifier_gain * float(bridge_output(x_center_m, g))
    return scale, -scale * demod_center


def gauge_summary(plant, x0_m=7.5e-6):
    """The numbers ``workbench gauge`` reports, as a JSON-ready dict (SI, keys name units).

    ``bias_v`` is the bridge output at zero displacement caused by the arm imbalance
    (eq. 26 at x = 0); ``chain_bias_v`` is the same after the amplifier and the
    demodulation, ``firmware_v_at_zero`` after the trim as well.
    """
    g = plant.gauge
    h = 1e-9
    numeric = float((bridge_output(x0_m + h, g) - bridge_output(x0_m - h, g)) / (2 * h))
    bias = float(bridge_output(0.0, g))
    chain_bias = bias * g.amplifier_gain * g.demodulation_gain
    chain = chain_gain(x0_m, g)
    return {
        "plant": plant.source,
        "x0_m": x0_m,
        "bridge_v_per_m": bridge_gain(x0_m, g),
        "bridge_v_per_m_eq26_with_imbalance": numeric,
        "bridge_v_per_m_eq28_as_printed": bridge_gain_eq28_printed(x0_m, g),
        "chain_v_per_m": chain,
        "chain_v_per_m_before_trim": chain / g.trim_scale,
        "trim": {"scale": g.trim_scale, "bias_v": g.trim_bias_v},
        "bias_v": bias,
        "chain_bias_v": chain_bias,
        "firmware_v_at_zero": g.trim_scale * chain_bias + g.trim_bias_v,
        "calibration_um_per_v": g.calibration_m_per_v * 1e6,
        "calibration_implied_um_per_v": 1e6 / chain,
        "delay_s": 0.5 / g.modulation_hz,
        "adc_lsb_v": 2 * g.adc_range_v / 2 ** g.adc_bits,
    }
