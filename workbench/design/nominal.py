"""One definition of the nominal plant, its crossover and margins, used by study, sweep, verify and selfsense.

**Nominal plant**: the serial's small-signal model on the *ascending* branch at the bias
(mid-range, 50 V by default: where a small step up runs), i.e. with C_h the incremental
capacitance of that operating point, seen through the gauge chain at mid-stroke
(x0 = 7.5 um, the firmware trim's centre) and the sampled chain firmware runs (DAC
hold, period-averaging gauge, one sample of compute delay:
:func:`~workbench.linearize.sampled.firmware_plant`). ``verify`` and ``selfsense``
already took this plant; the study used to place its crossover on the centre of its
uncertainty weight instead (another capacitance: 121 Hz there against 141 Hz here for
the same controller). The weight's centre remains only the centre of W_m.

**Crossover**: the highest frequency where |L| = 1 on the nominal loop
(:attr:`~.margins.Margins.crossover_hz`); over a family, the lowest and highest of the
members' crossovers.

**Worst member**: for each margin, the member with the smallest margin in magnitude
(largest |S|, |T| peaks): :func:`~.margins.family_margins`.

The model is a minimal StateSpace: the creep branches' pole/zero pairs (time constants
of 0.1-1000 s, a few per cent apart; at 10 kHz the discrete poles sit within 1e-7 of
z = 1) are truncated in modal form. They act below 2 Hz, a decade and more below any
crossover: the servo-band response changes by < 1 % above 5 Hz, the DC gain loses the
creep's ~5 % (integral action owns that drift). Left in, they make transfer-function
arithmetic (``control.feedback`` of a tf controller with the plant) misplace closed-loop
poles outside the unit circle.
"""

from dataclasses import dataclass

import control
import numpy as np

__all__ = ["NOMINAL_BIAS_V", "NOMINAL_BRANCH", "NOMINAL_X0_M", "SLOW_HZ", "NominalPlant", "nominal_plant",
           "minimal", "nominal_loop", "nominal_margins"]

NOMINAL_BIAS_V = 50.0          # V, mid-range of 0-100 V
NOMINAL_BRANCH = "ascending"
NOMINAL_X0_M = 7.5e-6          # m, mid-stroke (the firmware trim's centre)
SLOW_HZ = 5.0                  # Hz: modes slower than this are truncated (creep: <= 1.6 Hz)
METHOD = "truncate"


@dataclass(frozen=True)
class NominalPlant:
    """The nominal plant (module docstring).

    Attributes
    ----------
    continuous : control.StateSpace
        K_g P(s), V_pea -> firmware volts (V/V), minimal, slow creep modes truncated.
    firmware : control.StateSpace
        The sampled chain (hold, plant, average, delay), firmware V per commanded V, dt = T.
    capacitance_f : float
        Incremental C_h of the operating point, F.
    gauge_v_per_m : float
        Firmware volts per metre at ``x0_m``.
    bias_v, x0_m : float
        Operating point, V and m.
    branch : str
    truncated : int
        States removed (the slow creep branches).
    """

    continuous: control.StateSpace
    firmware: control.StateSpace
    capacitance_f: float
    gauge_v_per_m: float
    bias_v: float
    x0_m: float
    branch: str
    truncated: int

    def frd(self, freq_hz):
        """The continuous nominal as a python-control FRD on ``freq_hz`` (Hz)."""
        return control.FRD(self.continuous, 2 * np.pi * np.asarray(freq_hz, dtype=float))


def minimal(sys, slow_hz=SLOW_HZ):
    """``sys`` (continuous SISO) with its real modes slower than ``slow_hz`` truncated.

    Returns ``(reduced, removed)``. The states are taken to a block-modal form first, so
    a slow mode is removed whole and the fast dynamics are kept exactly.
    """
    s = control.ss(sys)
    if s.nstates == 0:
        return s, 0
    lam, vec = np.linalg.eig(np.asarray(s.A))
    slow = np.abs(lam) < 2 * np.pi * slow_hz
    if not slow.any() or np.any(np.abs(lam[slow].imag) > 0):
        return s, 0
    # real block-diagonalizing basis: the slow (real) eigenvectors, then a basis of the rest
    fast_vecs = vec[:, ~slow]
    basis_fast = np.linalg.qr(np.column_stack([fast_vecs.real, fast_vecs.imag]))[0][:, :int((~slow).sum())]
    t = np.column_stack([vec[:, slow].real, basis_fast])
    ti = np.linalg.inv(t)
    a, b, c = ti @ np.asarray(s.A) @ t, ti @ np.asarray(s.B), np.asarray(s.C) @ t
    k = int(slow.sum())
    t_sys = control.ss(a, b, c, np.asarray(s.D))
    red = control.modred(t_sys, list(range(k)), method=METHOD)
    return control.ss(red.A, red.B, red.C, red.D), k


def nominal_plant(plant, bias_v=NOMINAL_BIAS_V, delay_samples=1, slow_hz=SLOW_HZ, branch=NOMINAL_BRANCH):
    """The nominal plant of ``plant`` (a loaded Plant), module docstring's definition.

    Parameters
    ----------
    plant : Plant
    bias_v : float
        Operating point, V (the study's ``family.bias_v``).
    delay_samples : int
        Compute delay, samples.
    slow_hz : float
        Modes slower than this are truncated (:func:`minimal`); 0 keeps every state.
    branch : str, default "ascending"
        Hysteresis branch of the operating point. The nominal is the ascending branch; verify's
        small-tone prediction asks for the same plant on the "reversal" branch (minor loops).
    """
    from ..linearize.sampled import firmware_plant, gauge_gain_v_per_m
    from ..linearize.small_signal import operating_point, small_signal_model
    g = plant.gauge
    c_h = operating_point(plant.pzt, bias_v, branch).capacitance_f
    x_per_v, removed = minimal(small_signal_model(plant.pzt, c_h)[0, 0], slow_hz)
    k_g = gauge_gain_v_per_m(NOMINAL_X0_M, g)
    fw = firmware_plant(x_per_v, g, NOMINAL_X0_M, delay_samples)
    return NominalPlant(k_g * x_per_v, control.ss(fw), c_h, k_g, float(bias_v), NOMINAL_X0_M, branch, removed)


def nominal_loop(controller_d, nominal):
    """L(z) = C(z) G_fw(z) as a StateSpace (never via transfer functions)."""
    return control.ss(controller_d) * nominal.firmware


def nominal_margins(controller_d, nominal, freq_hz=None):
    """:class:`~.margins.Margins` of the nominal loop (crossover, PM, GM, ...)."""
    from .margins import margins_of
    loop = nominal_loop(controller_d, nominal)
    if freq_hz is None:
        freq_hz = np.geomspace(0.1, 0.4999 / loop.dt, 4000)
    return margins_of(loop, freq_hz)
