"""A sensor drift must show where nothing else moves: in the input's holds.

A drift of the sensor's zero (``drift``: a polynomial in time, optionally with one slow periodic
term) runs on whatever the input does. While the input holds still, the stack's model predicts a
constant, so the residual there moves with the drift and nothing else of the model: the drift
term's motion *within* each hold must be found in the residual's motion within that hold. A
drift candidate fitted to the base model's misfit during motion (an effect-free record whose
chirp the base misses, fitted by a slow polynomial that happens to lower the validation error)
predicts within-hold slopes the record does not show.

The check, on the development rows only (the test part takes no part in a choice):

* **Holds**: maximal runs where the drive's spread stays within 1e-3 of its range
  (:func:`~workbench.calibrate.residual._hold_spans`, as seed 001's creep per hold), lasting at
  least ``min_hold_s``; the first fifth of each hold is skipped (the step's settling: the RC
  charge, a mode's ringing, the fastest creep).
* In every hold the drift term ``d`` and the residual ``e`` (what the drift is fitted to) are
  taken less their means over the hold's rows, and the residual's gain on the term is
  ``k = sum(e_c d_c) / sum(d_c^2)``, with standard error ``sigma / sqrt(sum(d_c^2))`` for white
  noise of RMS ``sigma`` (the channel's noise floor).
* **Verdict**: ``None`` (the holds cannot tell: no holds, or the term moves so little within
  them that ``k``'s standard error exceeds ``1 / 6``, a drift and none not 3 standard errors
  either side of ``1 / 2``); else ``True`` when ``k >= 1 / 2`` (the holds move as the drift
  says, within half of it), ``False`` otherwise. Creep of the stack after a step also moves a
  hold, with the step's sign; the holds of a protocol step both ways, so it does not line up
  with one slow drift.
"""

import numpy as np

from .residual import _hold_spans

__all__ = ["hold_spans", "drift_in_holds", "SETTLE_FRACTION", "MAX_SE", "MIN_GAIN"]

#: Share of each hold skipped at its start (the step's settling).
SETTLE_FRACTION = 0.2
#: The holds inform when the gain's standard error is at most this (3 of them either side of MIN_GAIN).
MAX_SE = 1.0 / 6.0
#: The residual must follow at least this share of the drift's within-hold motion.
MIN_GAIN = 0.5


def hold_spans(t_s, v, min_hold_s):
    """Index spans ``(i, j)`` of the drive's holds, their settling skipped.

    Parameters
    ----------
    t_s : array_like
        Time (s), increasing.
    v : array_like
        The drive (V); a hold keeps its spread within 1e-3 of the drive's peak-to-peak range.
    min_hold_s : float
        Shortest hold kept (s).

    Returns
    -------
    ndarray of int, shape (n_holds, 2)
        Samples ``i .. j-1`` of each hold after its first ``SETTLE_FRACTION``.
    """
    t = np.asarray(t_s, float)
    v = np.asarray(v, float)
    tol = 1e-3 * float(np.ptp(v)) if v.size else 0.0
    if not tol > 0:
        return np.empty((0, 2), dtype=np.int64)
    spans = _hold_spans(t, v, tol, float(min_hold_s))
    out = [(i + int(np.ceil(SETTLE_FRACTION * (j - i))), j) for i, j in spans]
    return np.array([(i, j) for i, j in out if j - i >= 3], dtype=np.int64).reshape(-1, 2)


def drift_in_holds(e, term, rows, spans, noise_rms):
    """Does the residual move within the holds as the drift term does?

    Parameters
    ----------
    e : array_like
        The residual the drift is fitted to (channel units).
    term : array_like
        The fitted drift term (channel units), same length.
    rows : array_like of bool
        Rows that may be used (the development rows of the channel's valid samples).
    spans : ndarray of int, shape (n, 2)
        From :func:`hold_spans`.
    noise_rms : float
        White-noise RMS of the channel (channel units).

    Returns
    -------
    dict
        ``holds`` (holds used), ``gain`` (``k``), ``se`` (its standard error), ``shows``
        (``True``, ``False`` or ``None`` when the holds cannot tell; see the module notes).
    """
    e = np.asarray(e, float)
    d = np.asarray(term, float)
    rows = np.asarray(rows, bool)
    num = den = 0.0
    used = 0
    for i, j in spans:
        sel = np.flatnonzero(rows[i:j]) + i
        if sel.size < 3:
            continue
        dc = d[sel] - d[sel].mean()
        ec = e[sel] - e[sel].mean()
        num += float(dc @ ec)
        den += float(dc @ dc)
        used += 1
    if used == 0 or not den > 0:
        return {"holds": used, "gain": float("nan"), "se": float("inf"), "shows": None}
    k = num / den
    se = float(noise_rms) / np.sqrt(den) if noise_rms > 0 else 0.0
    shows = None if se > MAX_SE else bool(k >= MIN_GAIN)
    return {"holds": used, "gain": float(k), "se": float(se), "shows": shows}
