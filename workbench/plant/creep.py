"""Creep: Kelvin-Voigt branches on the hysteretic capacitance, and seed 001's log law.

Seed 000 notes that springs and dashpots added to the backlash elements would
capture creep. In the charge/voltage analogy (charge ~ displacement, voltage ~
force) a Kelvin-Voigt element in series with C_h is a capacitor C_j and a resistor
in series, both across C_h: under a held voltage V_h each branch charges toward
C_j V_h with time constant tau_j. That extra charge raises V_p and hence the
displacement, and because it passes through the working capacitance the charge
still tracks the displacement, as seed 002 relies on. Time constants spread one
per decade make the sum close to the logarithmic law of seed 001,
L(t) = L0 (1 + gamma log10(t / 0.1 s)), over the decades they cover.

:func:`log_creep_fit` is the analysis model: least squares for L0 and gamma with
the uncertainties of seed 001 eqs. 2-7.
"""

from dataclasses import dataclass

import numpy as np

__all__ = ["CreepParams", "log_creep", "log_creep_fit", "LogCreepFit", "T_REF_S"]

T_REF_S = 0.1  # seed 001 eq. 1: time origin of the logarithmic law


@dataclass(frozen=True)
class CreepParams:
    """Kelvin-Voigt creep branches across C_h.

    Parameters
    ----------
    time_constants_s : ndarray of float
        tau_j, s, positive and increasing.
    capacitances_f : ndarray of float
        C_j, F: charge per volt each branch takes up at equilibrium.
    """

    time_constants_s: np.ndarray
    capacitances_f: np.ndarray

    def __post_init__(self):
        tau = np.asarray(self.time_constants_s, float)
        cap = np.asarray(self.capacitances_f, float)
        object.__setattr__(self, "time_constants_s", tau)
        object.__setattr__(self, "capacitances_f", cap)
        if tau.shape != cap.shape or tau.ndim != 1:
            raise ValueError("time constants and capacitances must be 1-D of one length")
        if np.any(tau <= 0) or np.any(cap <= 0) or not np.all(np.isfinite(tau * cap)):
            raise ValueError("creep time constants and capacitances must be positive and finite")

    @property
    def size(self):
        return self.time_constants_s.size


def log_creep(t_s, l0, gamma):
    """Seed 001 eq. 1: L(t) = L0 (1 + gamma log10(t / 0.1 s))."""
    return l0 * (1.0 + gamma * np.log10(np.asarray(t_s, float) / T_REF_S))


@dataclass(frozen=True)
class LogCreepFit:
    """Result of :func:`log_creep_fit` (seed 001 eqs. 2-7)."""

    l0: float
    gamma: float
    sigma_l0: float
    sigma_gamma: float
    chi2_reduced: float
    n: int


def log_creep_fit(t_s, length, sigma=None):
    """Least-squares L0 and gamma of seed 001's law with their uncertainties.

    The law is linear in a = L0 and b = L0 gamma with regressor u = log10(t/0.1 s):
    L = a + b u (seed 001 eqs. 2-5). Uncertainties follow from the normal equations
    (eq. 6) and gamma = b / a by error propagation (eq. 7), including the a-b
    covariance. When ``sigma`` (the measurement standard deviation) is None it is
    estimated from the residual, so the reduced chi-square is 1 by construction.

    Parameters
    ----------
    t_s : array_like of float
        Time since the step, s (> 0).
    length : array_like of float
        Displacement, m.
    sigma : float, optional
        Standard deviation of each displacement sample, m.
    """
    t = np.asarray(t_s, float)
    y = np.asarray(length, float)
    if t.shape != y.shape or t.size < 3 or np.any(t <= 0):
        raise ValueError("need at least 3 samples at t > 0 with one length each")
    u = np.log10(t / T_REF_S)
    A = np.column_stack([np.ones_like(u), u])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    a, b = coef
    resid = y - A @ coef
    dof = t.size - 2
    s2 = float(resid @ resid) / dof if sigma is None else float(sigma) ** 2
    cov = s2 * np.linalg.inv(A.T @ A)
    gamma = b / a
    var_g = (cov[1, 1] / a**2 + b**2 * cov[0, 0] / a**4 - 2 * b * cov[0, 1] / a**3)
    chi2 = float(resid @ resid) / (s2 * dof)
    return LogCreepFit(l0=float(a), gamma=float(gamma), sigma_l0=float(np.sqrt(cov[0, 0])),
                       sigma_gamma=float(np.sqrt(max(var_g, 0.0))), chi2_reduced=chi2, n=int(t.size))
