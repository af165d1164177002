"""Fused feedback: a complementary blend of the gauge (low frequencies) and the charge estimate (high).

The gauge chain has white noise (22 nm RMS per 10 kHz sample on SN637, seed 000 sec. 3.1)
and no drift; the compensated charge estimate (:mod:`.estimator`, stage 4) has 0.27 nm of
noise per sample and a slow residual drift (the absorption its one-relaxation model misses,
identification errors: ~31 nm p-p over a 1000 s staircase). A first-order complementary pair

    F_low(s) = w_c / (s + w_c)      (applied to the gauge reading)
    F_high(s) = s / (s + w_c)       (applied to the charge estimate),   F_low + F_high = 1

passes each sensor where it is good. Firmware runs it as one state (the complementary form)::

    fused = charge + F_low(z) (gauge - charge),   F_low(z) = (1 - a) / (1 - a z^-1),  a = exp(-w_c T)

so that F_low(z) + (1 - F_low(z)) = 1 holds exactly in the discrete filter too: a constant
offset between the two sensors (the charge integrator is reset at an arbitrary moment) goes
to the gauge, which owns DC.

The crossover is chosen from the two error spectra (:func:`sensor_spectra`): the fused error
PSD is |F_low|^2 S_gauge + |F_high|^2 S_charge (the two sensors' errors are independent) and
:func:`choose_crossover` minimizes its integral over the band the record resolves (from 1 /
record length to the Nyquist frequency of the servo).
"""

from dataclasses import dataclass

import control
import numpy as np
from scipy import optimize, signal

__all__ = ["Blend", "SensorSpectra", "sensor_spectra", "fused_psd", "fused_error_variance", "choose_crossover",
           "fused_noise_rms_per_sample", "drift_record"]


@dataclass(frozen=True)
class Blend:
    """The first-order complementary pair at ``crossover_hz`` (Hz), run at ``dt_s`` (s)."""

    crossover_hz: float
    dt_s: float = 1e-4

    def __post_init__(self):
        if not (np.isfinite(self.crossover_hz) and self.crossover_hz > 0):
            raise ValueError(f"the blend crossover must be a positive frequency in Hz; got {self.crossover_hz!r}")
        if not (self.dt_s > 0 and self.crossover_hz < 0.5 / self.dt_s):
            raise ValueError(f"the blend crossover {self.crossover_hz} Hz must lie below the Nyquist frequency "
                             f"{0.5 / self.dt_s:g} Hz of the {self.dt_s:g} s sample period")

    @property
    def omega_rad_s(self):
        """w_c = 2 pi f_c, rad/s."""
        return 2 * np.pi * self.crossover_hz

    def low(self):
        """F_low(s) = w_c / (s + w_c), the gauge's path, TransferFunction."""
        return control.tf([self.omega_rad_s], [1.0, self.omega_rad_s])

    def high(self):
        """F_high(s) = s / (s + w_c), the charge estimate's path, TransferFunction."""
        return control.tf([1.0, 0.0], [1.0, self.omega_rad_s])

    @property
    def pole(self):
        """a = exp(-w_c T) of the discrete low-pass (matched pole, unit DC gain)."""
        return float(np.exp(-self.omega_rad_s * self.dt_s))

    def low_d(self):
        """F_low(z) = (1 - a) z / (z - a), discrete TransferFunction at ``dt_s``."""
        a = self.pole
        return control.tf([1.0 - a, 0.0], [1.0, -a], self.dt_s)

    def high_d(self):
        """F_high(z) = 1 - F_low(z) = a (z - 1) / (z - a), discrete TransferFunction (exactly complementary)."""
        a = self.pole
        return control.tf([a, -a], [1.0, -a], self.dt_s)

    def low_response(self, freq_hz):
        """|F_low(j w)|^2 evaluated analytically (continuous pair), per frequency."""
        f = np.asarray(freq_hz, float)
        return 1.0 / (1.0 + (f / self.crossover_hz) ** 2)

    def run(self, gauge_m, charge_m, state=None):
        """The firmware blend over arrays: fused_k = c_k + y_k, y_k = a y_{k-1} + (1 - a)(g_k - c_k).

        ``state`` (y before the first sample) defaults to g_0 - c_0 (starts with the gauge's offset).
        Returns (fused, last state).
        """
        g, c = np.asarray(gauge_m, float), np.asarray(charge_m, float)
        a = self.pole
        d = g - c
        y0 = d[0] if state is None else float(state)
        y, _ = signal.lfilter([1.0 - a], [1.0, -a], d, zi=[a * y0])
        return c + y, float(y[-1])


@dataclass(frozen=True)
class SensorSpectra:
    """One-sided error PSDs of the two sensors on ``freq_hz``, m^2/Hz (see :func:`sensor_spectra`)."""

    freq_hz: np.ndarray
    gauge_m2_per_hz: np.ndarray
    charge_m2_per_hz: np.ndarray
    charge_noise_m2_per_hz: float
    gauge_noise_rms_m: float
    charge_noise_rms_m: float
    dt_s: float


def sensor_spectra(gauge_noise_rms_m, charge_noise_rms_m, dt_s, drift_t_s, drift_m, n_freq=400):
    """Error PSDs of the gauge (white) and the charge estimate (white noise + drift), m^2/Hz.

    Parameters
    ----------
    gauge_noise_rms_m, charge_noise_rms_m : float
        RMS noise per sample at ``dt_s``, m (white: one-sided PSD 2 sigma^2 dt).
    dt_s : float
        Servo sample period, s.
    drift_t_s, drift_m : ndarray
        A record of the charge estimate's error (estimate - true x), uniformly sampled
        (may be decimated; its own averaged noise is small beside the drift). Its Welch PSD
        (Hann, segments of a quarter of the record) is the drift spectrum below its Nyquist
        frequency; above, the charge has only its white noise.
    n_freq : int
        Points of the log-spaced grid, from 1 / record length to 0.5 / dt_s.
    """
    t = np.asarray(drift_t_s, float)
    e = np.asarray(drift_m, float)
    if t.size < 64 or e.shape != t.shape:
        raise ValueError("the drift record needs at least 64 samples and one time per sample")
    fs = 1.0 / float(t[1] - t[0])
    nper = max(64, e.size // 4)
    fw, pw = signal.welch(e - np.mean(e), fs=fs, nperseg=nper, window="hann", detrend="linear")
    f = np.geomspace(fw[1], 0.5 / dt_s * 0.999, int(n_freq))
    s_drift = np.interp(np.log(f), np.log(fw[1:]), pw[1:], right=0.0)
    s_c_white = 2.0 * charge_noise_rms_m ** 2 * dt_s
    s_g_white = 2.0 * gauge_noise_rms_m ** 2 * dt_s
    return SensorSpectra(freq_hz=f, gauge_m2_per_hz=np.full_like(f, s_g_white), charge_m2_per_hz=s_drift + s_c_white,
                         charge_noise_m2_per_hz=s_c_white, gauge_noise_rms_m=float(gauge_noise_rms_m),
                         charge_noise_rms_m=float(charge_noise_rms_m), dt_s=float(dt_s))


def fused_psd(spectra, crossover_hz):
    """|F_low|^2 S_gauge + |F_high|^2 S_charge on ``spectra.freq_hz``, m^2/Hz (independent errors)."""
    lo = Blend(crossover_hz, spectra.dt_s).low_response(spectra.freq_hz)
    return lo * spectra.gauge_m2_per_hz + (1.0 - lo) * spectra.charge_m2_per_hz


def fused_error_variance(spectra, crossover_hz):
    """Integral of :func:`fused_psd` over the grid (trapezoids in f), m^2."""
    return float(np.trapezoid(fused_psd(spectra, crossover_hz), spectra.freq_hz))


def choose_crossover(spectra, lo_hz=None, hi_hz=None):
    """The crossover (Hz) that minimizes :func:`fused_error_variance`, searched on log f.

    A coarse log grid (200 points over [lo_hz, hi_hz], default the spectra's band / 10 of
    Nyquist) brackets the minimum, then a bounded scalar search refines it.
    """
    f = spectra.freq_hz
    lo = f[0] if lo_hz is None else float(lo_hz)
    hi = 0.1 * 0.5 / spectra.dt_s if hi_hz is None else float(hi_hz)
    grid = np.geomspace(lo, hi, 200)
    j = np.array([fused_error_variance(spectra, fc) for fc in grid])
    i = int(np.argmin(j))
    a, b = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, grid.size - 1)])
    res = optimize.minimize_scalar(lambda lf: fused_error_variance(spectra, float(np.exp(lf))), bounds=(a, b),
                                   method="bounded", options={"xatol": 1e-6})
    fc = float(np.exp(res.x)) if res.fun <= j[i] else float(grid[i])
    return fc


def fused_noise_rms_per_sample(spectra, crossover_hz):
    """RMS of the fused signal's white-noise part per sample, m: sqrt(sigma_c^2 + sigma_g^2 (fraction of the
    gauge's white noise the discrete low-pass passes)).

    The discrete F_low(z) = (1 - a)/(1 - a z^-1) passes a fraction (1 - a)/(1 + a) of white noise's variance;
    F_high = 1 - F_low passes 2a^2/(1 + a) of the charge's (close to 1). This is the noise the loop's
    noise budget sees; it is spread over all frequencies here, which overstates the command noise
    (the low-passed gauge noise really sits below the crossover, where K S is small): conservative.
    """
    a = Blend(crossover_hz, spectra.dt_s).pole
    var = spectra.gauge_noise_rms_m ** 2 * (1 - a) / (1 + a) + spectra.charge_noise_rms_m ** 2 * 2 * a * a / (1 + a)
    return float(np.sqrt(var))


def drift_record(plant, amp, ident, duration_s=1000.0, dt_s=1e-4, eval_hz=1000.0, seed=2):
    """(t_s, error_m, stroke_m): the stage-4 charge estimate's error on the staircase of
    :func:`.run.staircase_voltage` (0-100 V, holds of 20-60 s), and the stroke it spans (p-p true x)."""
    from ..plant.simulator import PZTSimulator
    from .charge_amp import measure
    from .run import STAGES, stage_errors, staircase_voltage
    dec = max(1, int(round(1.0 / (eval_hz * dt_s))))
    v = staircase_voltage(duration_s, dt_s, seed)
    n = (v.size // dec) * dec
    traj = PZTSimulator(plant.pzt, dt_s).run(v[:n], decimate=dec)
    rec = measure(traj, amp, seed=seed, average=dec)
    e = stage_errors(rec, ident, (STAGES[-1],))[STAGES[-1]][1]
    return rec.t_s, e, float(np.ptp(rec.x_m))
