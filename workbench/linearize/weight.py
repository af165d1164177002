"""Multiplicative uncertainty weight: a low-order W(s) whose magnitude covers a relative-deviation envelope.

Given the envelope ell(w) = max over a plant family of |P(jw)/P_nom(jw) - 1| on a frequency grid,
:func:`fit_weight` returns a stable, minimum-phase, biproper weight

    W(s) = gain * prod(1 + s/(2 pi z_i)) / prod(1 + s/(2 pi p_i)),   z_i, p_i > 0 (Hz),

with |W(j w_k)| >= ell_k at every grid frequency. Only real zeros and poles are fitted: a
resonant envelope is covered by its real-pole hull, which is looser but never unsafe.

The shape (the corners) is found by minimizing the mean excess minus the smallest excess in dB,
which does not depend on the gain; the gain is then set so that the smallest excess is exactly
``guard_db``. Coverage on the grid therefore holds whatever the optimizer did. Between grid
points it is not guaranteed: the grid must resolve the envelope's peaks.
"""

from dataclasses import dataclass

import control
import numpy as np
from scipy.optimize import minimize
from scipy.special import expit

__all__ = ["WeightFit", "Coverage", "fit_weight", "coverage", "envelope"]

_DB = 20.0 / np.log(10.0)            # natural log of a magnitude -> dB
_BETAS = (1.0, 5.0, 30.0)            # soft-min sharpness, 1/dB: smooth first, then close to the true min
_N_RANDOM = 3                        # random starts per order, on top of the slope-change and warm starts


@dataclass(frozen=True)
class WeightFit:
    """A fitted weight; margins in dB over the grid points where the envelope is positive."""
    weight: control.TransferFunction
    order: int
    zeros_hz: tuple
    poles_hz: tuple
    gain: float
    coverage_margin_db: float
    tightness_db: float
    worst_freq_hz: float


@dataclass(frozen=True)
class Coverage:
    """The smallest 20 log10(|W| / |Delta|) over members and frequencies, and where it occurs."""
    margin_db: float
    member: str
    freq_hz: float
    covered: bool


# the fewest frequencies the weight W_m is fitted over (the grid check below; linearize --freq-points too)
MIN_GRID_POINTS = 3


def _check_grid(freq_hz):
    f = np.asarray(freq_hz, dtype=float)
    if f.ndim != 1 or f.size < MIN_GRID_POINTS:
        raise ValueError(f"freq_hz must be a 1-D array of at least {MIN_GRID_POINTS} points, got shape {f.shape}")
    if not np.all(np.isfinite(f)) or np.any(f <= 0) or np.any(np.diff(f) <= 0):
        raise ValueError("freq_hz must be finite, positive and strictly increasing")
    return f


def _shape_db(lf, lz, lp):
    """20 log10 |prod(1 + jf/z) / prod(1 + jf/p)| and its gradient in (ln z, ln p); lf, lz, lp natural logs."""
    uz = 2.0 * (lf[:, None] - lz[None, :])     # ln (f/z)^2, kept in logs so extreme ratios cannot overflow
    up = 2.0 * (lf[:, None] - lp[None, :])
    h = 0.5 * _DB * (np.logaddexp(0.0, uz).sum(axis=1) - np.logaddexp(0.0, up).sum(axis=1))
    return h, np.hstack([-_DB * expit(uz), _DB * expit(up)])


def _objective(x, lf, target_db, beta):
    """Mean excess minus soft-min excess (an upper bound on mean - min): the tightness after rescaling."""
    n = x.size // 2
    h, dh = _shape_db(lf, x[:n], x[n:])
    r = h - target_db
    e = np.exp(-beta * (r - r.min()))                # shifted so the largest term is 1: no overflow
    return r.mean() - r.min() + np.log(e.sum()) / beta, dh.mean(axis=0) - (e / e.sum()) @ dh


def _excess(x, lf, target_db):
    n = x.size // 2
    r = _shape_db(lf, x[:n], x[n:])[0] - target_db
    return r.mean() - r.min()


def _slope_corners(lf, target_db, n):
    """Start: zeros where the smoothed log-log slope rises most, poles where it falls most; spares at the top."""
    k = max(3, lf.size // 10)
    y = np.convolve(np.pad(target_db, k, mode="edge"), np.ones(2 * k + 1) / (2 * k + 1), mode="valid")
    curv = np.gradient(np.gradient(y, lf), lf)
    gap = 2 * k * (lf[-1] - lf[0]) / (lf.size - 1)    # one smoothing window: closer peaks are the same corner
    zeros, poles = [], []
    for i in np.argsort(-np.abs(curv)):
        side = zeros if curv[i] > 0 else poles
        if len(side) < n and all(abs(lf[i] - lf[j]) > gap for j in zeros + poles):
            side.append(i)
    return np.array([lf[i] for i in zeros] + [lf[-1]] * (n - len(zeros))
                    + [lf[i] for i in poles] + [lf[-1]] * (n - len(poles)))


def _fit_shape(lf, target_db, warm, bounds, rng):
    """Best corners (ln z..., ln p...) one order above ``warm``, the previous order's best, over several starts."""
    n = warm.size // 2 + 1
    starts = [_slope_corners(lf, target_db, n),
              np.concatenate([warm[:n - 1], [lf[-1]], warm[n - 1:], [lf[-1]]])]   # plus a cancelling pair
    starts += [rng.uniform(lf[0], lf[-1], 2 * n) for _ in range(_N_RANDOM)]
    best, best_j = None, np.inf
    for x in starts:
        x = np.clip(x, *bounds)
        for beta in _BETAS:
            # TNC, not L-BFGS-B: same optima here, and no multithreaded-OpenBLAS slowdown (scipy#22438).
            x = minimize(_objective, x, args=(lf, target_db, beta), jac=True, method="TNC",
                         bounds=[bounds] * (2 * n)).x
        j = _excess(x, lf, target_db)
        if j < best_j:
            best, best_j = x, j
    return best


def _build(f, ell, x, guard_db):
    """The weight of corners x with the gain that puts the smallest excess over ell at guard_db."""
    n = x.size // 2
    h = _shape_db(np.log(f), x[:n], x[n:])[0]
    gain = 10.0 ** ((guard_db - np.min(h - 20.0 * np.log10(ell))) / 20.0)
    wz, wp = 2 * np.pi * np.exp(x[:n]), 2 * np.pi * np.exp(x[n:])
    # Monic denominator, numerator scaled so the DC gain is `gain`; dt=0 so that order 0 is continuous too.
    weight = control.tf(np.atleast_1d(gain * np.prod(wp) / np.prod(wz) * np.poly(-wz)),
                        np.atleast_1d(np.poly(-wp)), dt=0)
    margin = 20.0 * np.log10(np.abs(weight(2j * np.pi * f)) / ell)
    k = int(np.argmin(margin))
    return WeightFit(weight, n, tuple(sorted(np.exp(x[:n]).tolist())), tuple(sorted(np.exp(x[n:]).tolist())),
                     float(gain), float(margin[k]), float(margin.mean()), float(f[k]))


def _validate(f, ell, max_order, guard_db):
    if ell.shape != f.shape:
        raise ValueError(f"envelope shape {ell.shape} does not match freq_hz shape {f.shape}")
    if not np.all(np.isfinite(ell)):
        raise ValueError("envelope must be finite")
    if np.any(ell < 0):
        raise ValueError("envelope must be >= 0 (it is a magnitude)")
    if not np.any(ell > 0):
        raise ValueError("envelope is zero everywhere: there is no uncertainty to cover")
    if int(max_order) != max_order or max_order < 0:
        raise ValueError(f"max_order must be a non-negative integer, got {max_order}")
    if not np.isfinite(guard_db) or guard_db < 0:
        raise ValueError(f"guard_db must be finite and >= 0, got {guard_db}")


def fit_weight(freq_hz, envelope, max_order=3, guard_db=0.5):
    """Fit W(s) of order <= max_order with |W(j 2 pi f_k)| >= envelope_k * 10^(guard_db/20) on the grid.

    Every order 0..max_order is fitted; the lowest one whose mean excess is within 1 dB of the best
    order's is returned. Grid points where the envelope is zero impose nothing. Corners are kept
    within 1e-3 x the lowest and 1e3 x the highest grid frequency.
    """
    f = _check_grid(freq_hz)
    ell = np.asarray(envelope, dtype=float)
    _validate(f, ell, max_order, guard_db)
    f, ell = f[ell > 0], ell[ell > 0]
    lf, target_db = np.log(f), 20.0 * np.log10(ell)
    bounds = (np.log(1e-3 * f[0]), np.log(1e3 * f[-1]))
    rng = np.random.default_rng(0)                    # fixed seed: the same data always gives the same weight
    x = np.empty(0)
    fits = [_build(f, ell, x, guard_db)]
    for _ in range(int(max_order)):
        x = _fit_shape(lf, target_db, x, bounds, rng)
        fits.append(_build(f, ell, x, guard_db))
    best = min(fit.tightness_db for fit in fits)
    return next(fit for fit in fits if fit.tightness_db <= best + 1.0)


def _magnitudes(members, shape):
    if not members:
        raise ValueError("members is empty")
    out = {}
    for name, delta in members.items():
        d = np.abs(np.asarray(delta, dtype=complex))
        if d.shape != shape:
            raise ValueError(f"member {name!r} has shape {d.shape}, expected {shape}")
        if not np.all(np.isfinite(d)):
            raise ValueError(f"member {name!r} has non-finite values")
        out[name] = d
    return out


def coverage(weight, freq_hz, members):
    """Worst 20 log10(|W| / |Delta|) over members (name -> complex Delta(j w) on freq_hz); Delta = 0 ignored."""
    f = _check_grid(freq_hz)
    if not (weight.issiso() and weight.isctime()):
        raise ValueError("weight must be a continuous-time SISO system")
    mag_w = np.abs(weight(2j * np.pi * f))
    worst = None
    for name, d in _magnitudes(members, f.shape).items():
        with np.errstate(divide="ignore", invalid="ignore"):
            m = np.where(d > 0, 20.0 * np.log10(mag_w / d), np.inf)
        k = int(np.argmin(m))
        if worst is None or m[k] < worst[0]:
            worst = (float(m[k]), name, float(f[k]))
    if not np.isfinite(worst[0]):
        raise ValueError("every deviation is zero: there is nothing to cover")
    return Coverage(*worst, covered=worst[0] >= 0)


def envelope(members):
    """Largest |Delta| per frequency over members (name -> complex array, all the same shape)."""
    mags = list(_magnitudes(members, np.shape(next(iter(members.values()), ()))).values())
    return np.max(mags, axis=0)
