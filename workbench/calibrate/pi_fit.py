"""Fit a Prandtl-Ishlinskii (PI) hysteresis model to a voltage -> displacement record.

Model: x(t) = sum_i w_i F_{r_i}[V](t) + c, a weighted sum of play operators
(:mod:`workbench.plant.hysteresis`, seed 002 eqs. 2.35-2.36) plus a signed offset ``c``.
There is no separate gain: the weights carry the unit m/V and the r = 0 play (the identity)
is the slope right after a reversal.

Choices, and why
----------------
* **Thresholds**: uniform grid ``r_i = i / n * R`` for i = 0 .. n-1, with
  R = max |V - V0| over the input up to the last training sample (``grid="uniform"``, the
  default): the held-out part's range does not set the grid. A play that still does not move in
  the training rows gets weight 0 (its column would copy the offset's and let the two trade
  unbounded values). A play with r >= R never leaves its
  initial state V0 over this record, so it would only be a copy of the offset column; the
  uniform grid spans the whole range of reachable thresholds evenly, which is what the
  symmetric, near-sinusoidal loops of a stack under a periodic drive need (the loop width
  is set by the large thresholds as much as by the small ones). ``grid="quadratic"``,
  ``r_i = (i / n)**2 * R``, packs thresholds near 0 for records with many small minor loops,
  where the curvature right after a reversal matters most. Explicit ``thresholds`` override
  both.
* **Initial states**: every play starts at the record's first voltage V0 (the stack starts
  from rest at V0, so the first branch is the virgin curve). Bipolar inputs are fine: the
  plays are symmetric and V may go negative.
* **Regression**: each play is run over the WHOLE record from the start (its memory then is
  right at every sample), and only then are the training rows taken. Weights are
  non-negative (bounded least squares, ``scipy.optimize.lsq_linear`` with BVLS, an exact
  active-set method); the offset is a free, signed column (bounds -inf .. inf). Columns are
  scaled to unit RMS before solving so that volts and metres do not ruin the conditioning.
* **Cycles** (:func:`split_by_cycles`): counted by the input's turning points (reversals),
  which is where a PI operator's memory is written. A cycle is two reversals; training
  ends at the 2N-th reversal, so the held-out part starts on a fresh branch.
"""

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy.optimize import lsq_linear

from .._kernel_args import readonly
from ..plant.hysteresis import PrandtlIshlinskii, play
from .stacking import column_stack

__all__ = ["PIFit", "LineFit", "fit_pi", "pi_thresholds", "play_matrix", "turning_points",
           "split_by_cycles", "straight_line_rms", "rms"]

GRIDS = ("uniform", "quadratic")
#: A play moving less than this fraction of the training input's span over the training rows is
#: not excited there (below a 10-bit monitor's step); its weight is 0 (``base_fit`` drops it).
MOVE_REL = 1e-3


def rms(a):
    """Root mean square of ``a`` (NaN for an empty array, without a warning)."""
    a = np.asarray(a, dtype=float)
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


@dataclass(frozen=True, eq=False)        # eq=False: == on arrays is elementwise
class PIFit:
    """A fitted model x = sum_i w_i F_{r_i}[V] + offset.

    Attributes
    ----------
    thresholds_v : ndarray
        r_i in V, strictly increasing, starting at 0 on the built-in grids.
    weights : ndarray
        w_i in m/V, all >= 0.
    offset_m : float
        Signed constant in m.
    initial_states_v : ndarray
        Play states before the first sample (the record's first voltage).
    rms_train_m : float
        RMS residual over the training samples, m.
    """

    thresholds_v: np.ndarray
    weights: np.ndarray
    offset_m: float
    initial_states_v: np.ndarray
    rms_train_m: float

    @property
    def operator(self):
        """The PI operator (without the offset); invertibility is not checked since
        non-negative weights may leave the r = 0 weight at zero."""
        return PrandtlIshlinskii(self.thresholds_v, self.weights, self.initial_states_v,
                                 check_invertible=False)

    def predict(self, v):
        """Displacement in m for the voltage record ``v``, run from the initial states."""
        return self.operator(np.asarray(v, dtype=float)) + self.offset_m


class LineFit(NamedTuple):
    """Straight line x = slope * V + offset fitted on the training part."""

    slope_m_per_v: float
    offset_m: float
    rms_train_m: float
    rms_test_m: float        # NaN when nothing is held out


def _mask(train, n):
    """``train`` (None, slice, boolean mask or index array) as a boolean mask of length n."""
    if train is None:
        return np.ones(n, dtype=bool)
    if isinstance(train, slice):
        mask = np.zeros(n, dtype=bool)
        mask[train] = True
        return mask
    train = np.asarray(train)
    if train.dtype == bool:
        if train.shape != (n,):
            raise ValueError(f"train mask must have shape ({n},), got {train.shape}")
        return train.copy()
    if np.issubdtype(train.dtype, np.integer):
        mask = np.zeros(n, dtype=bool)
        mask[train] = True
        return mask
    raise TypeError(f"train must be None, a slice, a boolean mask or integer indices, got {train.dtype}")


def _inputs(v, x):
    v = np.ascontiguousarray(v, dtype=float)
    x = np.ascontiguousarray(x, dtype=float)
    if v.ndim != 1 or v.shape != x.shape or v.size < 2:
        raise ValueError(f"v and x must be 1-D of one length >= 2, got {v.shape} and {x.shape}")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(x))):
        raise ValueError("v and x must be finite")
    return v, x


def pi_thresholds(v, n_plays, grid="uniform"):
    """Thresholds r_i, i = 0 .. n-1, on ``grid`` over R = max |V - V0| (see module notes)."""
    if isinstance(n_plays, bool) or not isinstance(n_plays, (int, np.integer)) or n_plays < 1:
        raise ValueError(f"n_plays must be an integer >= 1, got {n_plays!r}")
    if grid not in GRIDS:
        raise ValueError(f"grid must be one of {GRIDS}, got {grid!r}")
    v = np.asarray(v, dtype=float)
    span = float(np.max(np.abs(v - v[0])))
    if not span > 0:
        raise ValueError("the input never leaves its first value; nothing to fit")
    s = np.arange(n_plays) / n_plays
    return span * (s if grid == "uniform" else s * s)


def play_matrix(v, thresholds, initial_states):
    """Play outputs over the whole record, one column per threshold (shape n x n_plays)."""
    v = np.ascontiguousarray(v, dtype=float)
    return column_stack([play(v, r, z) for r, z in zip(thresholds, initial_states)])


def fit_pi(v, x, n_plays=20, thresholds=None, train=None, grid="uniform"):
    """Fit x = PI(V) + offset by non-negative least squares.

    Parameters
    ----------
    v, x : array_like
        Voltage (V) and displacement (m) samples of one record, from its start.
    n_plays : int
        Number of plays on the built-in grid (ignored when ``thresholds`` is given).
    thresholds : array_like, optional
        Explicit thresholds in V, >= 0 and strictly increasing.
    train : slice, boolean mask or index array, optional
        Samples that enter the fit (default: all). The plays run over the whole record.
    grid : {"uniform", "quadratic"}
        Threshold grid when ``thresholds`` is None.
    """
    v, x = _inputs(v, x)
    mask = _mask(train, v.size)
    if not mask.any():
        raise ValueError("no training samples")
    last = int(np.flatnonzero(mask)[-1])
    # the grid spans the input as far as the training rows reach, not the held-out part's range
    r = pi_thresholds(v[: last + 1], n_plays, grid) if thresholds is None else np.asarray(thresholds, float)
    if r.ndim != 1 or r.size < 1 or np.any(r < 0) or np.any(np.diff(r) <= 0) or not np.all(np.isfinite(r)):
        raise ValueError(f"thresholds must be finite, >= 0 and strictly increasing; got {r}")
    z0 = np.full(r.size, v[0])
    if mask.sum() < r.size + 1:
        raise ValueError(f"{int(mask.sum())} training samples for {r.size + 1} unknowns")
    P = play_matrix(v, r, z0)[mask]
    # a play that does not move in the training rows would only copy the offset's column: weight 0
    moves = np.ptp(P, axis=0) > MOVE_REL * float(np.ptp(v[mask]))
    a = column_stack([P[:, moves], np.ones(int(mask.sum()))])
    b = x[mask]
    col = np.sqrt(np.mean(a * a, axis=0))
    col[col == 0] = 1.0
    bscale = rms(b) or 1.0
    k = int(moves.sum())
    lb = np.r_[np.zeros(k), -np.inf]
    ub = np.full(k + 1, np.inf)
    sol = lsq_linear(a / col, b / bscale, bounds=(lb, ub), method="bvls", tol=1e-12)
    p = sol.x / col * bscale
    w = np.zeros(r.size)
    w[moves] = np.maximum(p[:-1], 0.0)      # BVLS keeps the bound; clip -0.0 and round-off
    offset = float(p[-1])
    resid = P @ w + offset - b
    return PIFit(r.copy(), w, offset, z0, rms(resid))


def turning_points(v, band=0.01):
    """Indices of the input's reversals (local extrema), ignoring wiggles below ``band``.

    A reversal is recorded at a running extremum once the input has moved back from it by
    more than ``band`` times the input's peak-to-peak range, so noise or a flat stretch
    (the stack at rest) makes no reversals; a step counts as motion.
    """
    v = np.asarray(v, dtype=float).reshape(-1)
    tol = band * float(np.ptp(v))
    out = np.empty(max(v.size, 1), dtype=np.int64)
    n = _turning_points(readonly(v), tol, out)
    return out[:n].astype(int)


@njit(cache=True)
def _turning_points(v, tol, out):
    """:func:`turning_points`' walk over ``v`` (compiled: ~0.3 s of Python for 355,000 rows), the
    reversals written into ``out``; returns their count. The same comparisons in the same order
    (a difference times +-1 is exact), so the same indices."""
    n, direction, k_ext = 0, 0, 0
    for k in range(1, v.size):
        if direction == 0:
            if abs(v[k] - v[0]) > tol:
                direction = 1 if v[k] > v[0] else -1
                k_ext = k
            continue
        if (v[k] - v[k_ext]) * direction > 0:
            k_ext = k
        elif (v[k_ext] - v[k]) * direction > tol:
            out[n] = k_ext
            n += 1
            direction = -direction
            k_ext = k
    return n


def split_by_cycles(v, n_train_cycles, band=0.01):
    """Boolean mask of the first ``n_train_cycles`` input cycles (True = train).

    A cycle is two reversals of the input (:func:`turning_points`); the mask covers the
    samples from the start up to and including the 2N-th reversal, so the held-out part
    begins on a fresh branch. Half cycles are allowed (N = 2.5 ends at the 5th reversal).
    The stretch before the first motion is part of the first cycle.
    """
    n_rev = int(round(2 * float(n_train_cycles)))
    if n_rev < 1 or abs(n_rev - 2 * float(n_train_cycles)) > 1e-9:
        raise ValueError(f"n_train_cycles must be a positive multiple of 0.5, got {n_train_cycles!r}")
    tp = turning_points(v, band)
    if tp.size < n_rev:
        raise ValueError(f"the input has {tp.size} reversals ({tp.size / 2:g} cycles), fewer than "
                         f"the {n_rev} that {n_train_cycles} training cycles need")
    mask = np.zeros(np.asarray(v).size, dtype=bool)
    mask[: tp[n_rev - 1] + 1] = True
    return mask


def straight_line_rms(v, x, train=None):
    """Least-squares line x = a V + b on ``train``; RMS in-sample and on the rest."""
    v, x = _inputs(v, x)
    mask = _mask(train, v.size)
    if mask.sum() < 2:
        raise ValueError("need at least 2 training samples for a line")
    a = column_stack([v[mask], np.ones(int(mask.sum()))])
    (slope, offset), *_ = np.linalg.lstsq(a, x[mask], rcond=None)
    resid = slope * v + offset - x
    return LineFit(float(slope), float(offset), rms(resid[mask]), rms(resid[~mask]))
