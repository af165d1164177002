"""The loop with a controller: describing-function Nyquist analysis and predicted limit cycles.

The firmware loop is C(z) after the sampled gauge chain (:mod:`.sampled`). For the
harmonic balance the sampled elements are taken at their fundamental, without
aliases (the period average suppresses them): hold and average each contribute
(1 - e^{-jwT}) / (jwT), the compute delay e^{-jwTd}. With P(jw; A) the PZT's
describing function at amplitude A of V_pea (current saturation included: slewing
is exactly what limits an oscillation's amplitude),

    L_A(jw) = C(e^{jwT}) e^{-jwTd} [(1 - e^{-jwT}) / (jwT)]^2 K_g P(jw; A),

and a limit cycle sits where L_A(jw) = -1. Written against the nominal loop,
L_A = L_nom N(A, w) with N = P(jw; A) / P_nom(jw), the classic picture: the Nyquist
curve of L_nom meeting the locus -1/N(A). For each amplitude the phase crossover
w_pc(A) of L_A is found; where |L_A(w_pc)| crosses 1 between amplitudes, a limit
cycle is predicted there, stable when the loop gain falls through 1 as A grows
(Loeb's criterion).
"""

from dataclasses import dataclass

import numpy as np

__all__ = ["load_controller", "sampled_factor", "loop_responses", "predict_limit_cycles", "LimitCycle"]


def load_controller(path, allow_unstable=False):
    """The linear part of a controller file (.json or .mat) as a discrete python-control TransferFunction.

    Read and validated by :meth:`workbench.controller.Controller.load` (a bare
    ``{sample_rate_hz, gain, sos}`` JSON is enough; rows [b0, b1, b2, 1, a1, a2]; input
    firmware volts of error, output PZT volts). Limits and the current-limit window are not
    part of this linear view. ``allow_unstable``: accept poles outside the unit circle
    (an analysis of an unstable controller). Raises ControllerError (a DataFileError)
    naming the file and the key.
    """
    from ..controller import Controller
    from ..export.sos import from_sos
    c = Controller.load(path, allow_unstable=allow_unstable)
    return from_sos(c.gain, c.sos, c.dt_s)


def sampled_factor(freq_hz, dt_s, delay_samples=1):
    """Hold x period average x compute delay at the fundamental: e^{-jwTd} ((1 - e^{-jwT}) / (jwT))^2."""
    wt = 2 * np.pi * np.asarray(freq_hz, dtype=float) * dt_s
    avg = np.where(wt > 0, (1 - np.exp(-1j * wt)) / (1j * np.where(wt > 0, wt, 1.0)), 1.0)
    return np.exp(-1j * wt * delay_samples) * avg * avg


def loop_responses(controller, gauge_v_per_m, df_family, bias_index=0, delay_samples=1):
    """L_A(jw) for every amplitude of ``df_family`` (rows: amplitudes; NaN where not periodic)."""
    f = df_family.freq_hz
    c = np.array([complex(controller(np.exp(2j * np.pi * fi * controller.dt))) for fi in f])
    common = c * sampled_factor(f, controller.dt, delay_samples) * gauge_v_per_m
    p = np.where(df_family.periodic[bias_index], df_family.x_m_per_v[bias_index], np.nan)
    return common[None, :] * p


@dataclass(frozen=True)
class LimitCycle:
    """A predicted oscillation: amplitude of V_pea, frequency, and whether it is stable."""

    amplitude_v: float
    freq_hz: float
    stable: bool


def _phase_crossover(freq_hz, l):
    """First frequency where L crosses the negative real axis, and |L| there (log-linear interpolation)."""
    for k in range(l.size - 1):
        a, b = l[k], l[k + 1]
        if not (np.isfinite(a) and np.isfinite(b)):
            continue
        if np.sign(a.imag) != np.sign(b.imag) and (a.real < 0 or b.real < 0):
            t = a.imag / (a.imag - b.imag)
            lf = np.log(freq_hz[k]) + t * (np.log(freq_hz[k + 1]) - np.log(freq_hz[k]))
            mag = np.exp(np.log(abs(a)) + t * (np.log(abs(b)) - np.log(abs(a))))
            if (a + t * (b - a)).real < 0:
                return float(np.exp(lf)), float(mag)
    return None, None


def predict_limit_cycles(amplitudes_v, freq_hz, loops):
    """Limit cycles from the loop responses ``loops`` [amplitude, frequency] (see module docstring).

    Returns the list of :class:`LimitCycle` and, per amplitude, (w_pc in Hz, |L_A| there).
    """
    crossings = [_phase_crossover(freq_hz, l) for l in loops]
    cycles = []
    for k in range(len(amplitudes_v) - 1):
        (f0, m0), (f1, m1) = crossings[k], crossings[k + 1]
        if m0 is None or m1 is None or (m0 - 1) * (m1 - 1) > 0:
            continue
        t = np.log(m0) / (np.log(m0) - np.log(m1))
        amp = np.exp(np.log(amplitudes_v[k]) + t * (np.log(amplitudes_v[k + 1]) - np.log(amplitudes_v[k])))
        freq = np.exp(np.log(f0) + t * (np.log(f1) - np.log(f0)))
        cycles.append(LimitCycle(float(amp), float(freq), stable=bool(m1 < m0)))
    return cycles, crossings
