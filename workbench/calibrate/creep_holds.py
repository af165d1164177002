"""Seed 001's creep law fitted hold by hold on a record with constant-input holds.

Jung & Gweon (seed 001) drive a stack with a ladder of voltage steps and fit, for every step,
``L(t) = L0 (1 + gamma log10(t / 0.1 s))`` by least squares (eqs. 2-6), with the uncertainty of
gamma = (L0 gamma) / L0 by error propagation (eq. 7). :func:`fit_holds` does the same on any
record whose input has holds (a staircase, a square wave, a ramp-hold profile).

What L means in a staircase
---------------------------
For one step from rest, L(t) is the displacement itself. In a staircase the stack already
sits at the previous level's displacement, so L is taken as **the displacement change caused
by the step**:

* **time origin** ``t0``: the instant the input finished moving, i.e. the first sample of the
  hold (an ideal step moves between the previous sample and this one; a ramp ends here). The
  resolution is one sample: with coarse sampling (seed 001 stores every 0.2 s) the log law is
  sensitive to this choice at small t.
* ``L(t) = y(t) - y_ref`` for ``t - t0 >= fit_from_s`` (default 0.1 s: seed 001's reference
  time; the dynamic response before it -- the slew through the amplifier's current limit, the
  RC settling, the first creep branch -- is excluded, as the seed excludes its Fig. 7 peak), so
  **L0 is the change of displacement 0.1 s after the step** and gamma its creep per decade
  relative to that change. A step down gives L0 < 0; gamma > 0 then still means creep in the
  direction of the step.
* ``y_ref``, the displacement before the step: the mean of the measured output over the last
  ``ref_window_s`` of the preceding hold (averaging keeps its noise out of L0; the drift over
  that window is negligible late in a hold). Its standard error ``s / sqrt(m)`` shifts every L
  by one constant, so it is added to ``sigma_l0`` in quadrature and propagated to
  ``sigma_gamma`` (``+ gamma^2 sigma_ref^2 / L0^2``); ``log_creep_fit``'s own sigmas assume
  independent samples only.
* **Caveat**: the creep of earlier steps does not stop at the next step. L includes the part of
  their creep still running during this hold, which the log law of this step absorbs: gamma
  per hold is that of the *staircase* (hold length and history matter), not of an isolated
  step. On the creep plant with 20 s holds of 10 V, gamma rises from the single-step value
  (~0.012-0.015 over long holds) to ~0.018-0.029. Extrapolating the preceding hold's fitted
  law as a baseline (superposition) was tried and is not better: the log law extrapolated
  hold after hold drifts (gamma 0.011-0.037 on the same staircase), so it is not offered.

The preceding hold is the last constant stretch (same ``tol_v``, lasting at least
``ref_window_s`` and 2 samples) ending before the hold; ``step_v`` is the difference of the two
stretches' mean inputs. A hold is skipped (fit fields NaN, ``skip_reason`` says why) when no
constant stretch precedes it, when ``|step_v| <= tol_v`` (the input did not step), when fewer
than 3 samples lie after ``fit_from_s``, or when ``|L0|`` is below ``min_l0_snr`` times the
noise of one sample (the measured ``noise_rms`` when given, else the fit's residual standard
deviation): gamma is a ratio over L0 and means nothing there.

With ``noise_rms`` given, it is passed to ``log_creep_fit`` as sigma, so ``chi2_reduced`` is
the seed's reduced chi-square test (Fig. 9: 0.8-2.8 on their stack): ~1 when the log law
describes the hold to within the noise, larger when it does not. Without it, sigma is
estimated from the residual and ``chi2_reduced`` is 1 by construction.
"""

import numpy as np

from ..plant.creep import T_REF_S, log_creep_fit
from .residual import _hold_spans, _is_real, _series

__all__ = ["hold_segments", "fit_holds"]


def _check_nonneg(name, value, positive=False):
    if not _is_real(value) or not np.isfinite(value) or value < 0 or (positive and value == 0):
        kind = "> 0" if positive else ">= 0"
        raise ValueError(f"{name} must be a finite number {kind}, got {value!r}")
    return float(value)


def hold_segments(t_s, u, tol_v, min_s):
    """Constant-input holds: index spans ``(start, stop)`` (samples start .. stop-1).

    The holds of :func:`workbench.calibrate.residual.analyze_residual` (the same search):
    maximal runs whose input spread ``max(u) - min(u)`` stays within ``tol_v``, grown left to
    right, kept when they last at least ``min_s`` (and hold at least 2 samples).

    Parameters
    ----------
    t_s : array_like of float
        Sample times, s, strictly increasing (need not be even).
    u : array_like of float
        Input, V, same length.
    tol_v : float
        Largest input spread inside a hold, V (>= 0).
    min_s : float
        Shortest hold, s (>= 0; 0 returns every constant stretch of 2 samples or more).

    Returns
    -------
    ndarray of int, shape (n_holds, 2)

    Raises
    ------
    ValueError
        Non-finite or mismatched arrays, time not increasing, a negative tolerance or duration.

    Examples
    --------
    >>> t = np.arange(10) * 0.5
    >>> hold_segments(t, [0, 0, 0, 0, 1, 1, 1, 1, 1, 2], tol_v=0.01, min_s=1.0).tolist()
    [[0, 4], [4, 9]]
    """
    tol = _check_nonneg("tol_v", tol_v)
    min_s = _check_nonneg("min_s", min_s)
    t, (u,) = _series(t_s, (u,), ("u",), 2, uniform=False)
    return _hold_spans(t, u, tol, min_s)


def fit_holds(t_s, u, y, *, tol_v=None, min_s=1.0, fit_from_s=T_REF_S, noise_rms=None,
              ref_window_s=0.1, min_l0_snr=10.0):
    """Seed 001's L0 and gamma (eqs. 2-7) for every hold of a record; see the module notes.

    Parameters
    ----------
    t_s : array_like of float
        Sample times, s, strictly increasing.
    u : array_like of float
        Input voltage, V.
    y : array_like of float
        Measured displacement, m.
    tol_v : float, optional
        Largest input spread inside a hold, V (default 1e-3 of the input's peak-to-peak range,
        as ``analyze_residual``).
    min_s : float
        Shortest hold fitted, s (default 1 s).
    fit_from_s : float
        Fit samples at ``t - t0 >= fit_from_s``, s (> 0; default 0.1 s, seed 001's reference).
    noise_rms : float, optional
        Standard deviation of one displacement sample, m (> 0). Makes ``chi2_reduced`` a test.
    ref_window_s : float
        Length of the end of the preceding hold averaged into ``y_ref``, s (>= 0; at least one
        sample is used).
    min_l0_snr : float
        Skip holds with ``|L0| < min_l0_snr * noise`` (>= 0; default 10).

    Returns
    -------
    list of dict
        One per hold of at least ``min_s``, in time order: ``start_s`` (t0), ``duration_s``,
        ``voltage_v`` (mean input), ``step_v`` (input step into the hold), ``l0`` (m),
        ``gamma``, ``sigma_l0`` (m), ``sigma_gamma``, ``chi2_reduced``, ``n`` (samples
        fitted) and ``skip_reason`` ("" when fitted; the fit fields are NaN and ``n`` 0
        otherwise).

    Raises
    ------
    ValueError
        Bad arrays (mismatched, non-finite, time not increasing) or an out-of-range option.
    """
    min_s = _check_nonneg("min_s", min_s)
    fit_from_s = _check_nonneg("fit_from_s", fit_from_s, positive=True)
    ref_window_s = _check_nonneg("ref_window_s", ref_window_s)
    min_l0_snr = _check_nonneg("min_l0_snr", min_l0_snr)
    if noise_rms is not None:
        noise_rms = _check_nonneg("noise_rms", noise_rms, positive=True)
    t, (u, y) = _series(t_s, (u, y), ("u", "y"), 3, uniform=False)
    tol = 1e-3 * float(np.ptp(u)) if tol_v is None else _check_nonneg("tol_v", tol_v)

    # every constant stretch (>= 2 samples); a preceding one must last ref_window_s
    stretches = _hold_spans(t, u, tol, 0.0)
    out = []
    last_ref = -1         # index of the last stretch that can serve as "before the step"
    for k, (i, j) in enumerate(stretches):
        pred, dur = last_ref, float(t[j - 1] - t[i])
        if dur >= ref_window_s:
            last_ref = k
        if dur < min_s:
            continue
        t0 = float(t[i])
        entry = {"start_s": t0, "duration_s": dur,
                 "voltage_v": float(np.mean(u[i:j])), "step_v": float("nan")}
        nan = float("nan")
        entry.update(l0=nan, gamma=nan, sigma_l0=nan, sigma_gamma=nan, chi2_reduced=nan, n=0,
                     skip_reason="")
        out.append(entry)
        if pred < 0:
            entry["skip_reason"] = "no constant input before the hold: the step is unknown"
            continue
        pi, pj = stretches[pred]
        step = entry["voltage_v"] - float(np.mean(u[pi:pj]))
        entry["step_v"] = step
        if abs(step) <= tol:
            entry["skip_reason"] = f"no step: |step_v| {abs(step):.3g} V <= tol_v {tol:.3g} V"
            continue
        after = np.flatnonzero(t[i:j] - t0 >= fit_from_s) + i
        if after.size < 3:
            entry["skip_reason"] = f"fewer than 3 samples after fit_from_s = {fit_from_s:g} s"
            continue
        ref = np.flatnonzero(t[pi:pj] >= t[pj - 1] - ref_window_s) + pi
        y_ref = float(np.mean(y[ref]))
        fit = log_creep_fit(t[after] - t0, y[after] - y_ref, sigma=noise_rms)
        if noise_rms is None:
            noise = _resid_sd(fit, t[after] - t0, y[after] - y_ref)
        else:
            noise = noise_rms
        if not abs(fit.l0) >= min_l0_snr * noise:
            entry["skip_reason"] = (f"|L0| {abs(fit.l0):.3g} m is below min_l0_snr "
                                    f"{min_l0_snr:g} x the noise {noise:.3g} m: step too small")
            continue
        sigma_ref = noise / np.sqrt(ref.size)          # y_ref's error: one offset on every L
        sigma_l0 = float(np.hypot(fit.sigma_l0, sigma_ref))
        sigma_gamma = float(np.hypot(fit.sigma_gamma, fit.gamma * sigma_ref / fit.l0))
        entry.update(l0=fit.l0, gamma=fit.gamma, sigma_l0=sigma_l0, sigma_gamma=sigma_gamma,
                     chi2_reduced=fit.chi2_reduced, n=fit.n)
    return out


def _resid_sd(fit, t, length):
    """Residual standard deviation of a log-law fit (n - 2 degrees of freedom), m."""
    r = length - fit.l0 * (1.0 + fit.gamma * np.log10(t / T_REF_S))
    return float(np.sqrt(r @ r / (t.size - 2)))
