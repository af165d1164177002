"""Synthetic records of rigs other than the project's protocol (issue 13): a stack known only by
its voltage -> displacement hysteresis, driven through an amplifier of unknown gain, offset and lag
from a logged 0-3.6 V command.

The stack is a Prandtl-Ishlinskii operator (seed 002 eqs. 2.35-2.36) on thresholds and weights
drawn at random (not the fit's grid, so the base has an approximation error of its own); the
displacement sensor adds white noise. Everything is drawn from wide ranges by ``rng``.
"""

import numpy as np
from scipy.signal import lfilter

from workbench.plant.hysteresis import PrandtlIshlinskii

COMMAND_V = 3.6        # V: the logged command spans 0 .. 3.6 V (a DAC's unipolar range)


def command_rig(rng, rate_hz, amplitudes, max_rows=100_000):
    """A record of an amplifier-driven stack whose logged input is the command.

    The command is one raised-cosine cycle from 0 V per entry of ``amplitudes`` (fractions of
    3.6 V), at a frequency drawn from 0.05-2 Hz (at least ``rate_hz * cycles / max_rows``, to keep
    the record short). Returns ``(t_s, command_v, x_m, truth)``.
    """
    f_lo = max(0.05, rate_hz * len(amplitudes) / max_rows)
    f0 = float(np.exp(rng.uniform(np.log(f_lo), np.log(max(2.0, f_lo)))))    # excitation, Hz
    period = 1.0 / f0
    n_cycles = len(amplitudes)
    duration = n_cycles * period
    t = np.arange(int(round(duration * rate_hz))) / rate_hz
    env = np.asarray(amplitudes, float)[np.minimum((t * f0).astype(int), n_cycles - 1)]
    u = COMMAND_V * env * 0.5 * (1.0 - np.cos(2 * np.pi * f0 * t))
    gain = rng.uniform(20.0, 40.0)                                       # V/V, amplifier
    offset = rng.uniform(-5.0, 5.0)                                      # V, amplifier output offset
    lag = rng.uniform(0.002, 0.03) * period                              # s, amplifier bandwidth
    a = 1.0 - np.exp(-1.0 / (rate_hz * lag))
    v_t = gain * lfilter([a], [1.0, a - 1.0], u, zi=[(1.0 - a) * u[0]])[0] + offset
    span = gain * COMMAND_V
    n = int(rng.integers(6, 40))
    r = np.sort(rng.uniform(0.0, 0.9 * span, n))
    r[0] = 0.0
    w = rng.uniform(0.2, 1.0, n) * np.exp(-r / (rng.uniform(0.1, 1.0) * span))
    stroke = rng.uniform(5e-6, 100e-6)                                   # m over the full range
    op = PrandtlIshlinskii(r, w, np.full(n, v_t[0]), check_invertible=False)
    x_clean = op(v_t)
    x_clean = stroke * (x_clean - x_clean.min()) / np.ptp(x_clean) + rng.uniform(-20e-6, 20e-6)
    noise = rng.uniform(1e-4, 3e-3) * stroke
    x = x_clean + noise * rng.standard_normal(t.size)
    truth = {"f0_hz": f0, "gain": gain, "offset_v": offset, "lag_s": lag, "noise_m": noise, "stroke_m": stroke}
    return t, u, x, truth
