"""Effects a plant file may add to the seed-000 model, and how a recorded channel shows them.

These are the parametric forms of the calibration effect library (``workbench.calibrate``)
that do not belong to the electromechanical core: calibration writes them into the plant
file it hands back, and the synthetic-record simulator (``workbench.calibrate.synthetic``)
reads them from a plant file to generate a record that has them. Creep and mechanical modes
are not here: they are part of the core model (``[creep]``, ``[[mechanics.modes]]``).

Plant-file sections (all optional, SI, units in the key names):

* ``[leakage] resistance_ohm`` -- seed 002 eq. 2.7: a finite insulation resistance R_FP across
  the stack terminals. It draws ``V_t / R_FP`` through the series resistor and the current
  sensor but moves nothing: the recorded charge gains ``int V_t dt / R_FP``, the displacement
  does not.
* ``[dielectric_absorption] gain_f, time_constant_s`` -- seed 002 eq. 2.9: an internal charge
  ``Q_DA = k_s / (tau s + 1) V_t`` that flows through the terminals without displacement
  (``k_s`` in C/V = F).
* ``[displacement_sensor] delay_s, drift_rate_m_per_s, drift_curvature_m_per_s2`` -- the
  external displacement sensor's latency (signed, |delay_s| <= 10 s: a negative one is a sensor
  that leads the drive, an acquisition timing offset) and its slow drift ``a t + b t^2`` (t from the start
  of the record), uncorrelated with the input.
* ``[gauge_nonlinearity] coefficient_per_m`` -- the strain-gauge bridge read as seed 000
  eq. 27's shape ``x / (1 + b x)`` with a larger ``b`` than the bridge geometry gives
  (``k_gf (L - W) / (2 L^2)`` = 25 /m for the P-888.51, a bow of ~1 nm over the stroke, far
  below the 22 nm gauge noise): a gauge whose nonlinearity a calibration can see.

The electrical additions draw a current of microamps, far below the amplifier's limits, so
they are applied to the recorded current and charge after the core simulation rather than
inside its current-limited step.
"""

from dataclasses import dataclass, fields

import numpy as np
from scipy.signal import lfilter

__all__ = ["Additions", "leakage_charge", "absorption_charge", "delayed", "drift", "gauge_bow"]


@dataclass(frozen=True)
class Additions:
    """Optional effects of a plant file (None or 0 = absent)."""

    leakage_resistance_ohm: float | None = None
    absorption_gain_f: float | None = None
    absorption_time_constant_s: float | None = None
    sensor_delay_s: float = 0.0
    sensor_drift_rate_m_per_s: float = 0.0
    sensor_drift_curvature_m_per_s2: float = 0.0
    gauge_nonlinearity_per_m: float = 0.0

    @property
    def names(self):
        """Effect names (the calibration library's) present in this set."""
        out = []
        if self.leakage_resistance_ohm:
            out.append("leakage")
        if self.absorption_gain_f:
            out.append("dielectric_absorption")
        if self.sensor_delay_s:
            out.append("delay")
        if self.sensor_drift_rate_m_per_s or self.sensor_drift_curvature_m_per_s2:
            out.append("drift")
        if self.gauge_nonlinearity_per_m:
            out.append("gauge_nonlinearity")
        return out

    def as_dict(self):
        return {f.name: getattr(self, f.name) for f in fields(self)}


def leakage_charge(t_s, v_t, resistance_ohm):
    """Charge through R_FP since the start, C: the trapezoid integral of V_t / R_FP."""
    t = np.asarray(t_s, float)
    v = np.asarray(v_t, float)
    q = np.zeros_like(v)
    q[1:] = np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))
    return q / resistance_ohm


def absorption_charge(t_s, v_t, gain_f, time_constant_s):
    """Seed 002 eq. 2.9: k_s / (tau s + 1) V_t, discretized exactly for a held input, C.

    Starts at equilibrium with the first sample (a stack at rest has ``Q_DA = k_s V_t(0)``).
    """
    v = np.asarray(v_t, float)
    dt = float(np.mean(np.diff(t_s)))
    a = np.exp(-dt / time_constant_s)
    y, _ = lfilter([1.0 - a], [1.0, -a], v, zi=[a * v[0]])
    return gain_f * y


def delayed(t_s, y, delay_s):
    """``y(t - delay)`` by linear interpolation (fractional samples), either sign.

    ``delay_s > 0`` lags (the first value held before the start); ``delay_s < 0`` leads: the
    channel is shifted earlier, offline, and its last value held past the end.
    """
    t = np.asarray(t_s, float)
    return np.interp(t - delay_s, t, np.asarray(y, float))


def drift(t_s, rate_m_per_s, curvature_m_per_s2):
    """Sensor drift ``a t + b t^2`` from the start of the record, m."""
    s = np.asarray(t_s, float) - float(t_s[0])
    return rate_m_per_s * s + curvature_m_per_s2 * s * s


def gauge_bow(x_m, coefficient_per_m, x_ref_m=0.0):
    """The displacement a gauge with eq. 27's bow reads: ``x / (1 + b x)`` about ``x_ref``.

    Written about ``x_ref`` so the map keeps unit slope there; ``b > 0`` reads low above it.
    """
    d = np.asarray(x_m, float) - x_ref_m
    return x_ref_m + d / (1.0 + coefficient_per_m * d)
