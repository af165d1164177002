"""Balanced truncation of a controller, with the error bound of the part that is truncated.

python-control's ``balred`` (slycot ab09md) keeps the unstable and marginal modes (an
integrator) and balances the stable part. The truncation error is then bounded by
twice the sum of the discarded Hankel singular values of that stable part; this
module separates the stable part itself (ordered Schur form and a Sylvester
equation) to compute those values, and also measures the error on a grid.
"""

import warnings
from dataclasses import dataclass

import control
import numpy as np
import scipy.linalg

__all__ = ["Reduction", "hankel_singular_values", "marginal_tolerance", "reduce_controller", "stable_part"]


@dataclass(frozen=True)
class Reduction:
    controller: control.StateSpace
    order_before: int
    order_after: int
    error_bound: float          # 2 x the discarded Hankel singular values (absolute, H-inf)
    error_measured: float       # max |K - K_r| on the grid
    hankel_singular_values: tuple


def marginal_tolerance(sys):
    """Real part (rad/s) above which a pole counts as marginal: 1e-9 of the fastest pole, at least 1e-9.

    A pole that slow is an integrator for a controller (1e-9 of a 1e5 rad/s pole is a 16 uHz
    corner); balancing it with the stable part makes the Gramians singular (its eigenvalue pair
    with itself sums to ~0), so it is kept with the integrators instead.
    """
    a = np.asarray(sys.A, dtype=float)
    return 1e-9 * max(1.0, float(np.max(np.abs(np.linalg.eigvals(a))))) if a.size else 1e-9


def stable_part(sys, tol=None):
    """(stable StateSpace, number of marginal/unstable modes) of a continuous system.

    A pole is stable when Re p < -tol (default :func:`marginal_tolerance`).
    """
    tol = marginal_tolerance(sys) if tol is None else tol
    a, b, c, d = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
    t, u, n_s = scipy.linalg.schur(a, output="real", sort=lambda re, im: re < -tol)
    a11, a12, a22 = t[:n_s, :n_s], t[:n_s, n_s:], t[n_s:, n_s:]
    bt, ct = u.T @ b, c @ u
    # decouple: x1' = x1 + X x2 with A11 X - X A22 = -A12
    xx = scipy.linalg.solve_sylvester(a11, -a22, -a12)
    bs = bt[:n_s] - xx @ bt[n_s:]
    cs = ct[:, :n_s]
    return control.ss(a11, bs, cs, d), a.shape[0] - n_s


def reduce_controller(ctrl, order, freq_hz=None):
    """Balanced truncation of the continuous controller ``ctrl`` to ``order`` states."""
    ctrl = control.ss(ctrl)
    n = ctrl.nstates
    if order >= n:
        return Reduction(ctrl, n, n, 0.0, 0.0, ())
    tol = marginal_tolerance(ctrl)
    stable, n_unstable = stable_part(ctrl, tol)
    if order < n_unstable:
        raise ValueError(f"cannot reduce below the {n_unstable} marginal/unstable modes (integrators) it keeps")
    hsv = hankel_singular_values(stable)
    with warnings.catch_warnings():
        # slycot warns when the minimal realization is already smaller than ``order``: it then
        # returns that minimal realization, which is what we want
        warnings.simplefilter("ignore")
        red = control.balred(ctrl, order, method="truncate", alpha=-tol)
    # the bound of what was actually truncated: slycot may return fewer states than asked
    k_stable = max(int(red.nstates) - n_unstable, 0)
    bound = float(2 * np.sum(hsv[k_stable:])) if np.all(np.isfinite(hsv)) else float("nan")
    f = np.geomspace(1e-2, 1e5, 800) if freq_hz is None else np.asarray(freq_hz, dtype=float)
    w = 2j * np.pi * f
    # balred keeps the marginal/unstable part exactly, so K - K_r is the difference of the stable
    # parts; measured there, the error is not buried under the rounding of an integrator's gain at
    # low frequency (4e-10 of |K| = 1600 at 10 mHz exceeds a 1e-7 bound otherwise)
    red_stable, red_unstable = stable_part(control.ss(red), tol)
    if red_unstable == n_unstable:
        err = max(abs(complex(np.squeeze(stable(s))) - complex(np.squeeze(red_stable(s)))) for s in w)
    else:
        err = max(abs(complex(np.squeeze(ctrl(s))) - complex(np.squeeze(red(s)))) for s in w)
    return Reduction(red, n, int(red.nstates), bound, float(err), tuple(float(h) for h in hsv))


def hankel_singular_values(stable):
    """Hankel singular values of a stable continuous StateSpace, largest first (real, >= 0).

    slycot (``control.hsvd``) first; where its Lyapunov solver gives up on an ill-conditioned part
    (very slow and fast poles together), the Gramians from scipy's Bartels-Stewart solver. The
    values are sqrt(eig(W_c W_o)): rounding makes the smallest ones slightly complex or negative,
    which is taken as their modulus (they sit at the rounding floor, ~1e-8 of the largest).
    NaN when neither solver gives finite Gramians.
    """
    n = stable.nstates
    if n == 0:
        return np.zeros(0)
    try:
        with np.errstate(invalid="ignore"):
            hsv = np.asarray(control.hsvd(stable))
        if np.all(np.isfinite(hsv)):            # a NaN is no value at the rounding floor: ask scipy instead
            return np.sort(np.abs(hsv))[::-1]
    except Exception:                           # slycot's Lyapunov solver gives up on ill-conditioned parts
        pass
    a, b, c = (np.asarray(m, dtype=float) for m in (stable.A, stable.B, stable.C))
    try:
        with warnings.catch_warnings():
            # scipy warns when it perturbs a near-singular equation: that solution bounds nothing
            warnings.simplefilter("error", RuntimeWarning)
            wc = scipy.linalg.solve_continuous_lyapunov(a, -b @ b.T)
            wo = scipy.linalg.solve_continuous_lyapunov(a.T, -c.T @ c)
        ev = np.linalg.eigvals(wc @ wo)
    except (np.linalg.LinAlgError, ValueError, RuntimeWarning):
        return np.full(n, np.nan)
    if not np.all(np.isfinite(ev)):
        return np.full(n, np.nan)
    return np.sort(np.sqrt(np.abs(ev)))[::-1]
