"""Effect library: candidate effects the declared plant may lack, as additive corrections.

Each effect models the residual ``e = y_meas - y_model`` of ONE output channel as an additive
term driven by the input ``u`` (and time ``t``; some effects by the base model's prediction
``y_model`` too)::

    y_meas ~ y_model + effect.term(t, u, params, y_model=y_model)

An :class:`Effect` has

* ``name``, ``n_params`` (the count used in the parsimony penalty), ``channels`` (the channel
  keys it is a candidate for, or ``None`` for any channel);
* ``signature(report, t, u, residual) -> float`` in [0, 1]: how strongly the residual shows this
  effect's fingerprint. It is the fraction of the residual's variance the effect explains when
  fitted on the whole record (an R^2), multiplied by an effect-specific factor read from the
  :class:`~workbench.calibrate.residual.ResidualReport` (e.g. drift is scored down when the
  residual is correlated with the input). It is a diagnostic; :func:`choose_effect` decides by
  held-out error, not by the signature;
* ``fit(t, u, residual, train_mask, y_model=None) -> dict``: least squares on the training
  rows. Every effect's term is computed over the WHOLE record first (filters and integrals
  need their memory from the start) and only then are training rows taken. Parameters that
  enter linearly are solved exactly; a nonlinear one (a time constant, a natural frequency and
  damping, a delay) is found on a small grid (variable projection: the linear gain is solved at
  each grid point) and refined with ``scipy.optimize.least_squares`` within bounds;
* ``term(t, u, params, y_model=None) -> ndarray``: the correction.

``y_model`` is an optional keyword of ``fit`` / ``term``; only :class:`Delay` needs it (a
latency shifts the model's own output) and raises ``ValueError`` without it.

Effects implemented (``dt`` the sampling step, ``lowpass_tau(u)`` the discrete first-order
lowpass ``y_k = a y_{k-1} + (1 - a) u_k``, ``a = exp(-dt / tau)``, started at rest at ``u_0``):

* ``drift``: ``sum_i p_i s^i``, ``s = (t - t_0) / (t_end - t_0)``; degree + 1 params (3 by
  default); any channel.
* ``delay``: ``y_model(t - d dt) - y_model(t)`` (linear interpolation, ends held); 1 param
  (``d`` in samples); any channel.
* ``creep``: ``c (lowpass_tau(u) - u)``; 2 params (``c``, ``tau``); displacement and gauge.
* ``dielectric_absorption``: ``k lowpass_tau(u)``; 2 params (``k``, ``tau``); charge.
* ``leakage``: ``k int_{t_0}^t u dt`` (trapezoid); 1 param; charge.
* ``resonance``: ``g (H(s) - 1) u``, ``H = w^2 / (s^2 + 2 zeta w s + w^2)``, first-order hold
  (the drive linear between samples), started at rest at ``u_0``; 3 params (``g``, ``f_n``, ``zeta``); any channel.

* **creep** -- one first-order relaxation with zero static gain: after a step ``Du`` the
  correction is ``-c Du exp(-t / tau)``, so with ``c > 0`` the output keeps creeping towards
  the static value set by the base model (which is matched in steady state). The log-creep of
  a stack is approximated by the best single ``tau`` of a log grid (``tau >= tau_min``, 50
  samples by default, so that it does not mimic a latency).
* **dielectric_absorption** -- seed 002 (Ivan et al., self-sensing), eq. 2.9:
  ``Q_DA(V_in, s) / alpha = k_s / (tau s + 1) V_in``, an internal charge that relaxes to
  ``k_s V_in`` with time constant ``tau``: the term is ``k lowpass_tau(u)`` on the charge
  channel (static gain ``k``, no instantaneous part). Creep is the same relaxation written with
  the opposite convention (instantaneous part ``-c``, static gain 0) on the mechanical
  channels; the channel decides which one is a candidate.
* **leakage** -- seed 002 eq. 2.7: the charge lost through the finite leaking resistance is
  ``(1 / R_FP) int V_in dt``; ``k = 1 / R_FP`` (free sign in ``fit``, >= 0 in the joint fit).
* **resonance** -- a lightly damped mode (``zeta <= 0.3``) the base model lacks, with unit DC
  gain so the correction has no static part: ``g (H - 1) u``; ``g = 1`` for a plant whose
  output is the base model's filtered by the mode.
* **delay** -- a sensor or actuator latency of ``d`` samples (fractional allowed, either sign,
  ``|d| <= max_delay``).
* **drift** -- a slow sensor drift uncorrelated with the input, a polynomial in time (degree 2
  by default).

Not done yet: ``gauge_nonlinearity`` (seed eq. 27 against the linear gain).

Known limitation: on the charge channel ``leakage`` (``k int u dt``) and ``drift`` are nearly
collinear when the input is unipolar and roughly steady on average (``int u dt ~ mean(u) t``);
the parsimony penalty then favours ``leakage`` (1 parameter against 3) for a linear drift in
a noisy record. An input whose mean changes across the record (holds at very different
levels, a bipolar segment) separates them.

:func:`choose_effect` fits every candidate on the training rows and scores it on the held-out
rows by ``rms_after (1 + penalty n_params)``; see its docstring for the ``none`` rule.
"""

import copy
import functools
import inspect
import hashlib
import weakref

import numpy as np
from scipy import linalg, signal
from scipy.integrate import cumulative_trapezoid
from scipy.optimize import least_squares

from .stacking import column_stack
from .kernels import (filtered_rows_scaled, held_mode_column_compiled, lowpass_rows, mode_column_rows, mode_columns_rows,
                      shifted_rows_into)
from .pi_fit import rms
from .residual import analyze_residual

__all__ = ["Effect", "Drift", "Delay", "Creep", "CreepSpectrum", "DielectricAbsorption", "Leakage", "Resonance",
           "GaugeNonlinearity",
           "default_effects", "choose_effect", "lowpass"]

CHARGE = ("charge_c",)
MECHANICAL = ("displacement_m", "gauge_v")


def _dt(t):
    t = np.asarray(t, dtype=float)
    return float((t[-1] - t[0]) / (t.size - 1))


def lowpass(u, tau, dt):
    """First-order lowpass ``y_k = a y_{k-1} + (1 - a) u_k``, ``a = exp(-dt / tau)``, at rest at u_0."""
    u = np.asarray(u, dtype=float)
    a = float(np.exp(-dt / tau))
    y, _ = signal.lfilter([1.0 - a], [1.0, -a], u, zi=[a * u[0]])
    return y


def _lstsq(X, y):
    """Least squares with columns scaled to unit RMS; returns (beta, residual)."""
    # Normal equations with einsum (no BLAS call on the long vectors: a threaded BLAS on a
    # loaded machine costs milliseconds per call); columns scaled to unit RMS, a few columns.
    X = np.atleast_2d(np.asarray(X, dtype=float).T).T
    scale = np.sqrt(np.einsum("ij,ij->j", X, X) / X.shape[0])
    scale[scale == 0] = 1.0
    Xs = X / scale
    gram = np.einsum("ij,ik->jk", Xs, Xs)
    rhs = np.einsum("ij,i->j", Xs, y)
    beta = np.linalg.lstsq(gram, rhs, rcond=1e-12)[0] / scale
    return beta, y - np.einsum("ij,j->i", X, beta)


_GELSY_LWORK = {}     # (m, n, cond) -> the workspace size scipy's lstsq asks gelsy's query for


def _gelsy(A, y, cond=1e-10):
    """``scipy.linalg.lstsq(A, y, cond=cond, lapack_driver="gelsy", check_finite=False)[0]``, the same
    LAPACK call with the same arguments (workspace size included), made directly: the wrapper's
    checks and its workspace query cost ~0.3 ms a call beside gelsy's ~2 ms on the refitted searches'
    ~1,600 x 27 columns, called ~130 times a search. A float64 ``(m, n)`` ``A`` with ``m >= n > 0``
    and a float64 vector ``y``; anything else goes to ``lstsq`` itself."""
    A = np.asarray(A)
    y = np.asarray(y)
    if not (A.ndim == 2 and y.ndim == 1 and A.dtype == np.float64 and y.dtype == np.float64
            and A.shape[0] == y.size and A.shape[0] >= A.shape[1] > 0):
        return linalg.lstsq(A, y, cond=cond, lapack_driver="gelsy", check_finite=False)[0]
    m, n = A.shape
    gelsy, gelsy_lwork = linalg.get_lapack_funcs(("gelsy", "gelsy_lwork"), (A, y))
    key = (m, n, float(cond))
    lwork = _GELSY_LWORK.get(key)
    if lwork is None:
        work, info = gelsy_lwork(m, n, 1, cond)
        if info != 0:
            return linalg.lstsq(A, y, cond=cond, lapack_driver="gelsy", check_finite=False)[0]
        lwork = _GELSY_LWORK[key] = int(work.real)
    _, x, _, _, info = gelsy(A, y, np.zeros((n, 1), dtype=np.int32), cond, lwork, False, False)
    if info < 0:
        raise ValueError(f"illegal value in {-info}-th argument of internal gelsy")
    return x[:n]


def _rows(X, mask, project=None):
    """Training rows of ``X`` (a vector or columns), minus their projection on the base model's
    columns when ``project`` is given: the effect is then fitted jointly with the base model
    (variable projection), so what the base model could absorb is not credited to the effect."""
    X = np.asarray(X, dtype=float)[mask]
    return X if project is None else project(X)


def _r2(residual, explained):
    """Fraction of the residual's variance (about zero) removed by subtracting ``explained``."""
    e = np.asarray(residual, dtype=float)
    den = float(np.sum(e * e))
    if not den > 0:
        return 0.0
    r = e - explained
    return float(np.clip(1.0 - np.sum(r * r) / den, 0.0, 1.0))


def _data_key(*arrays):
    """A digest of arrays' contents (to tell whether a later search runs on the same data).

    SHA-256 of the arrays' bytes read in place (no copy): on a CPU with SHA instructions about twice
    BLAKE2b's speed (2.4 against 4.3 ms per 355,000-row column; ~65 keys of four arrays per protocol
    record). The digest is only compared with digests of this function, within one run."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype, a.shape)).encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def _row_groups(rows_list, n):
    """The row sets of ``rows_list`` grouped by the sets each row belongs to: ``(union, groups)``, the
    sets' union (sorted rows) and per group ``(idx, sets)``, its rows' positions in ``union`` and the
    numbers of the sets that hold them (:func:`_row_set_normals`). Each set strictly increasing
    row indices (``numpy.flatnonzero`` of a mask, as every caller passes), else each set is a group
    of its own (its rows concatenated into ``union``)."""
    sets = [np.asarray(r, np.int64) for r in rows_list]
    if len(sets) < 63 and all(r.size < 2 or bool(np.all(np.diff(r) > 0)) for r in sets):
        code = np.zeros(n, np.int64)
        for k, r in enumerate(sets):
            code[r] |= np.int64(1) << k
        union = np.flatnonzero(code)
        keys, inv = np.unique(code[union], return_inverse=True)
        return union, [(np.flatnonzero(inv == g), [k for k in range(len(sets)) if (int(c) >> k) & 1])
                       for g, c in enumerate(keys)]
    union = np.concatenate(sets) if sets else np.zeros(0, np.int64)
    ends = np.cumsum([0] + [r.size for r in sets])
    return union, [(np.arange(ends[k], ends[k + 1]), [k]) for k in range(len(sets))]


def _row_set_normals(X_rows, r_rows, groups, n_sets, union=None):
    """``[(G, h, m)]`` per row set: ``X[rows].T X[rows]``, ``X[rows].T r[rows]`` and the row count,
    ``X_rows`` and ``r_rows`` holding ``X`` and ``r`` at the sets' union (:func:`_row_groups`), or at
    every row with ``union`` given (each group's rows then taken from them directly).

    The folds' training row sets overlap (each holds ~4/5 of the development rows, which hold
    them all): each group's Gram is formed once and each set's summed from its groups, one pass
    over the rows in place of one per set (the refitted mode's and delay's per-fold weights, six
    Grams of ~280,000 x 26 on a 355,000-row protocol record). Equal to the per-set products up to
    rounding."""
    k_cols = X_rows.shape[1]
    out = [[np.zeros((k_cols, k_cols)), np.zeros(k_cols), 0] for _ in range(n_sets)]
    for idx, ks in groups:
        at = idx if union is None else union[idx]
        Xg = X_rows[at]
        G, h = Xg.T @ Xg, Xg.T @ r_rows[at]
        for k in ks:
            out[k][0] = out[k][0] + G
            out[k][1] = out[k][1] + h
            out[k][2] += idx.size
    return [tuple(o) for o in out]


def _bounded_delta(G, h, m, lower):
    """The drive model's corrections from a row set's normal equations (:func:`_row_set_normals`):
    its columns scaled to unit RMS on the rows, bounded least squares
    (:func:`~workbench.calibrate.base_fit._gram_solve`, ``delta >= lower``)."""
    from .base_fit import _gram_solve
    nrm = np.sqrt(np.maximum(np.diag(G), 0.0) / m) if m else np.ones(G.shape[0])
    nrm = np.where(nrm > 0, nrm, 1.0)
    return _gram_solve(G / np.outer(nrm, nrm), h / nrm, lower * nrm) / nrm


def _forward_points(x0, lb, ub):
    """The points ``least_squares``' 2-point finite-difference Jacobian at ``x0`` evaluates (default
    relative step, within the bounds ``lb``, ``ub``), by scipy's own step rules
    (``scipy.optimize._numdiff``); None where those are not importable. :func:`_varpro` filters their
    columns with ``x0``'s: a point that turns out not to be asked is a column filtered for nothing, a
    point asked that is not among them is filtered when asked (the same columns either way)."""
    try:
        from scipy.optimize._numdiff import _adjust_scheme_to_bounds, _compute_absolute_step
        x0 = np.asarray(x0, dtype=float)
        h = _compute_absolute_step(None, x0, x0, "2-point")
        h, _ = _adjust_scheme_to_bounds(x0, h, 1, "1-sided", np.broadcast_to(lb, x0.shape),
                                        np.broadcast_to(ub, x0.shape))
    except (ImportError, TypeError, ValueError):
        return None
    out = []
    for i in range(x0.size):
        x1 = np.copy(x0)
        x1[i] = x0[i] + h[i]
        out.append(x1)
    return out


def _varpro(columns, e, mask, grid, lower, upper, project=None, starts=1, row_columns=None, plain_costs=None,
            row_columns_many=None, jac="2-point", added_from=None):
    """Nonlinear parameters theta by grid + least_squares; the linear gains solved inside.

    ``columns(theta) -> (N, m)`` array over the whole record; returns ``(theta, beta)``.
    ``row_columns(theta, rows)``, optional, gives the same values at the sorted row indices
    ``rows`` (the mask's) only: a fast form used by the search (see :mod:`.kernels`).
    ``plain_costs``, optional dict (with ``row_columns``): a search with ``project`` also
    evaluates the grid's costs without it from the same columns and leaves them there; a later
    search on the same data and grid without ``project`` takes them instead of computing every
    grid column again (the caller clears the dict when the data change).
    ``row_columns_many(thetas, rows)``, optional (with ``row_columns``, one column per theta):
    the columns of several grid points at once, row ``j`` equal to ``row_columns(thetas[j], rows)``
    to the last bit (a compiled filter runs :data:`GRID_BATCH` of them in one pass).
    ``jac``: ``least_squares``' finite-difference scheme (see :meth:`_Relaxation.fit` for why a
    relaxation's search takes ``"3-point"``).
    ``added_from``, optional: the grid's points from this index on are an added part (:meth:`Resonance.fit`'s
    long-segment peaks): the ``starts`` refinements start from the best points before it, as without the
    added part, and one more from the added part's best. The answer is the least cost of every grid point
    and refinement, so it leaves no more than the search without the added part would (the added
    points, ~77 about each peak, cannot crowd the others' valleys out of the starts).
    """
    y = _rows(e, mask, project)
    # the target at unit RMS: least_squares' tolerances are absolute on the gradient, and a
    # residual in metres (1e-8) would stop it at its first step
    y_scale = float(np.sqrt(np.mean(y * y))) or 1.0
    y = y / y_scale
    rows = None if row_columns is None else np.flatnonzero(mask)

    ready = {}              # columns filtered ahead, by theta's bytes (the Jacobian's points)
    ahead = {}              # the next Jacobian's points' columns, filtered with the point they are taken at
    # (a 2-point Jacobian follows nearly every new point least_squares evaluates: its points' columns are
    # filtered in the same pass as the point's own, :func:`_forward_points`)
    guess = row_columns_many is not None and rows is not None and jac == "2-point"

    def res(theta):
        if rows is None:
            X = _rows(np.atleast_2d(columns(theta).T).T, mask, project)
        else:
            th = np.atleast_1d(np.asarray(theta, dtype=float))
            col = ready.pop(th.tobytes(), None)
            if col is None and guess:
                nxt = _forward_points(th, lo, hi)
                if nxt is not None:
                    cols = row_columns_many([th] + nxt, rows)
                    col = cols[0]
                    ahead.clear()
                    ahead.update((x.tobytes(), c) for x, c in zip(nxt, cols[1:]))
            X = np.atleast_2d(np.asarray(row_columns(theta, rows) if col is None else col, dtype=float).T).T
            X = X if project is None else project(X)
        return _lstsq(X, y)[1]

    def jacobian_map(fun, points):
        """least_squares' map over its finite-difference points: their columns filtered in one
        pass (``row_columns_many``), or with the point they are taken at (``ahead``), then ``fun`` at
        each point as before, in order."""
        points = list(points)
        if row_columns_many is not None and rows is not None and points:
            thetas = [np.atleast_1d(np.asarray(x, dtype=float)) for x in points]
            ready.clear()
            keys = [th.tobytes() for th in thetas]
            if all(k in ahead for k in keys):
                ready.update((k, ahead[k]) for k in keys)
            else:
                ready.update(zip(keys, row_columns_many(thetas, rows)))
        ahead.clear()
        out = [fun(x) for x in points]
        ready.clear()
        return out

    def grid_columns():
        """Each grid point's columns at ``rows``, as ``res`` shapes them (before any projection)."""
        if row_columns_many is None:
            for g in grid:
                yield np.atleast_2d(np.asarray(row_columns(np.atleast_1d(g), rows), dtype=float).T).T
            return
        step = _grid_batch(rows.size)
        for i in range(0, len(grid), step):
            block = row_columns_many([np.atleast_1d(np.asarray(g, dtype=float)) for g in grid[i:i + step]], rows)
            for col in block:
                yield np.atleast_2d(np.asarray(col, dtype=float).T).T

    share = plain_costs is not None and rows is not None
    grid_key = _data_key(np.asarray(grid, dtype=float)) if share else None
    if share and project is None and plain_costs.get("grid") == grid_key:
        costs = plain_costs.pop("costs")
        del plain_costs["grid"]
    elif share and project is not None:
        # the plain search's target, as that search computes it
        y_plain = _rows(e, mask, None)
        y_plain = y_plain / (float(np.sqrt(np.mean(y_plain * y_plain))) or 1.0)
        costs, plain = [], []
        for widths, XB, PB in _grid_blocks(grid_columns(), project, rows.size):
            plain += _grid_costs(widths, XB, y_plain)
            costs += _grid_costs(widths, PB, y)
        plain_costs.update(grid=grid_key, costs=plain)
    elif rows is not None:
        # res(g) for every grid point, the columns filtered GRID_BATCH at a time (and projected a
        # block at a time)
        costs = []
        for widths, _, PB in _grid_blocks(grid_columns(), project, rows.size):
            costs += _grid_costs(widths, PB, y)
    else:
        costs = [float(np.sum(res(np.atleast_1d(g)) ** 2)) for g in grid]
    lo, hi = np.atleast_1d(lower).astype(float), np.atleast_1d(upper).astype(float)
    theta, best_cost = np.atleast_1d(np.asarray(grid[int(np.argmin(costs))], dtype=float)), min(costs)
    # refine from the best few grid points: a light mode's valleys are narrow and several
    if added_from is None or added_from >= len(costs):
        picks = np.argsort(costs)[:starts]
    else:
        c = np.asarray(costs, dtype=float)
        picks = list(np.argsort(c[:added_from])[:starts]) + [added_from + int(np.argmin(c[added_from:]))]
    for k in picks:
        x0 = np.clip(np.atleast_1d(np.asarray(grid[int(k)], dtype=float)), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        sol = least_squares(res, x0, bounds=(lo, hi), x_scale="jac", max_nfev=60, jac=jac, **_MAP_KW(jacobian_map))
        if 2 * sol.cost < best_cost:
            theta, best_cost = sol.x, 2 * sol.cost
    beta, _ = _lstsq(_rows(np.atleast_2d(columns(theta).T).T, mask, project), y)
    return theta, beta * y_scale


class Effect:
    """Base class: an additive correction to one channel's model output (see the module notes)."""

    name = "effect"
    n_params = 0
    channels = None          # None: a candidate on any channel

    def applies_to(self, channel):
        return self.channels is None or channel is None or channel in self.channels

    def fit(self, t, u, residual, train_mask, y_model=None, project=None):
        raise NotImplementedError

    def term(self, t, u, params, y_model=None):
        raise NotImplementedError

    def _fingerprint(self, report, t, u, residual):
        """Effect-specific factor in [0, 1] applied to the explained-variance score."""
        return 1.0

    def signature(self, report, t, u, residual, y_model=None):
        """Score in [0, 1]: explained variance of a whole-record fit times the fingerprint factor."""
        e = np.asarray(residual, dtype=float)
        try:
            p = self.fit(t, u, e, np.ones(e.size, bool), y_model=y_model)
            r2 = _r2(e, self.term(t, u, p, y_model=y_model))
        except ValueError:
            return 0.0
        return float(np.clip(r2 * self._fingerprint(report, t, u, e), 0.0, 1.0))

    def __repr__(self):
        return f"{type(self).__name__}()"


class Drift(Effect):
    """Slow sensor drift: a polynomial of ``degree`` in normalized time, optionally plus one slow
    periodic term (a temperature cycle) whose frequency is searched in ``periodic_hz``
    (``(f_lo, f_hi)``, Hz). Time only: independent of the input's history (that is creep)."""

    name = "drift"

    def __init__(self, degree=2, periodic_hz=None):
        self.degree = int(degree)
        self.periodic_hz = None if periodic_hz is None else (float(min(periodic_hz)), float(max(periodic_hz)))
        self.nonlinear = self.periodic_hz is not None
        self.n_params = self.degree + 1 + (3 if self.periodic_hz else 0)

    def _X(self, t, f_hz=None):
        t = np.asarray(t, dtype=float)
        s = (t - t[0]) / (t[-1] - t[0])
        X = np.vander(s, self.degree + 1, increasing=True)
        if f_hz:
            ph = 2 * np.pi * f_hz * (t - t[0])
            X = column_stack([X, np.sin(ph), np.cos(ph)])
        return X

    def fit(self, t, u, residual, train_mask, y_model=None, project=None):
        mask = np.asarray(train_mask, bool)
        t = np.asarray(t, float)
        f_hz = None
        if self.periodic_hz:
            lo, hi = np.log(self.periodic_hz[0]), np.log(max(self.periodic_hz[1], 1.01 * self.periodic_hz[0]))
            cols = (lambda th: self._X(t, np.exp(th[0]))[:, 1:]) if project is not None else \
                (lambda th: self._X(t, np.exp(th[0])))
            # the search's rows only: the powers once, the periodic pair per frequency (equal values)
            t_rows = t[mask]
            powers = np.vander((t_rows - t[0]) / (t[-1] - t[0]), self.degree + 1, increasing=True)
            powers = powers[:, 1:] if project is not None else powers

            def row_cols(th, rows):
                ph = 2 * np.pi * np.exp(th[0]) * (t_rows - t[0])
                return column_stack([powers, np.sin(ph), np.cos(ph)])

            theta, _ = _varpro(cols, np.asarray(residual, float), mask, [[g] for g in np.linspace(lo, hi, 16)],
                               [lo], [hi], project, row_columns=row_cols)
            f_hz = float(np.exp(theta[0]))
        X = self._X(t, f_hz)
        if project is not None:
            # the base model has its own offset: the constant column projects to zero
            X = X[:, 1:]
        beta, _ = _lstsq(_rows(X, mask, project), _rows(residual, mask, project))
        if project is not None:
            beta = np.r_[0.0, beta]
        out = {"coefficients": beta[: self.degree + 1], "t0_s": float(t[0]), "t_end_s": float(t[-1])}
        if f_hz:
            out.update(period_s=1.0 / f_hz, sin_cos=beta[self.degree + 1:])
        return out

    def term(self, t, u, params, y_model=None):
        t = np.asarray(t, dtype=float)
        s = (t - params["t0_s"]) / (params["t_end_s"] - params["t0_s"])
        y = np.vander(s, self.degree + 1, increasing=True) @ np.asarray(params["coefficients"], float)
        if params.get("period_s"):
            ph = 2 * np.pi * (t - params["t0_s"]) / params["period_s"]
            a, b = params["sin_cos"]
            y = y + a * np.sin(ph) + b * np.cos(ph)
        return y

    def columns(self, t, u, params, y_model=None):
        """Powers 1 .. degree of normalized time (the base model has the constant) and the periodic
        pair when fitted, free signs."""
        X = self._X(t, 1.0 / params["period_s"] if params.get("period_s") else None)[:, 1:]
        return X, np.full(X.shape[1], -np.inf)

    def with_gains(self, params, gains):
        g = np.asarray(gains, float)
        out = {**params, "coefficients": np.r_[0.0, g[: self.degree]]}
        if params.get("period_s"):
            out["sin_cos"] = g[self.degree: self.degree + 2]
        return out

    def _fingerprint(self, report, t, u, residual):
        return 1.0 if report.independent else 0.5


# least_squares takes a map for its finite-difference points from scipy 1.16 (``workers``)
_MAP_KW = ((lambda m: {"workers": m}) if "workers" in inspect.signature(least_squares).parameters
           else (lambda m: {}))
GRID_BATCH = 32    # grid points whose columns one pass of a compiled filter computes (_varpro)
GRID_BATCH_BYTES = 1 << 25    # at most 32 MB of columns per pass (a full 1M-row record: 4 columns a pass)


def _grid_blocks(columns, project, n_rows):
    """A grid's columns side by side, a block at a time, and the block projected.

    ``columns``: an iterable of ``(n_rows, m)`` arrays (one per grid point, in order). Yields
    ``(widths, XB, PB)``: the block's grid points' column counts ``m``, their columns side by side
    (``n_rows x sum(widths)``, column order) and ``project(XB)`` (``XB`` itself when ``project`` is
    None), at most :func:`_grid_batch` columns a block (one grid point's wider columns alone).

    A projection off ``k`` base columns, ``X - E (G^+ (E' X))``, reads all of ``E`` (``n_rows x k``)
    twice whatever the width of ``X``: a resonance search's ~550 grid points projected one at a
    time read it ~550 times (~1.5 ms each at 50,000 rows and ``k = 25``), a block of 32 once. The
    projection is linear column by column: each column of ``PB`` is that column's projection, to the
    rounding of a matrix-matrix against a matrix-vector product (the grid's costs only rank its
    points; the refinement's ``res`` projects each point alone, as before).
    """
    width = _grid_batch(n_rows)
    block = []

    def flush():
        # the columns copied one by one into rows of a C-ordered array: its transpose (each column
        # contiguous) without the strided writes of a column stack
        XT = np.empty((sum(b.shape[1] for b in block), block[0].shape[0]))
        j = 0
        for b in block:
            XT[j:j + b.shape[1]] = b.T
            j += b.shape[1]
        XB = XT.T
        out = ([b.shape[1] for b in block], XB, XB if project is None else project(XB))
        block.clear()
        return out

    for X in columns:
        if block and sum(b.shape[1] for b in block) + X.shape[1] > width:
            yield flush()
        block.append(X)
    if block:
        yield flush()


def _grid_costs(widths, XB, y):
    """Each grid point's least-squares cost ``||y - X b||^2`` (``b`` its best gains), its columns
    ``X`` the next ``widths[j]`` columns of ``XB`` (:func:`_grid_blocks`).

    One column a point (a mode's, a relaxation's): the block at once, ``b = x'y / x'x`` (0 for a
    zero column, as :func:`_lstsq`'s pseudo-inverse gives) -- :func:`_lstsq`'s cost to rounding
    (checked in ``tests/calibrate/test_speed_equivalence.py``), in four passes over the block instead
    of seven calls per point. Several columns a point: :func:`_lstsq` on each point's.
    """
    if all(w == 1 for w in widths):
        xx = np.einsum("ij,ij->j", XB, XB)
        xy = XB.T @ y
        beta = np.divide(xy, xx, out=np.zeros_like(xy), where=xx > 0)
        R = y[:, None] - XB * beta
        return [float(c) for c in np.einsum("ij,ij->j", R, R)]
    out, j = [], 0
    for w in widths:
        out.append(float(np.sum(_lstsq(XB[:, j:j + w], y)[1] ** 2)))
        j += w
    return out


def _grid_batch(n_rows):
    """Grid points per compiled pass: :data:`GRID_BATCH`, fewer when their columns would pass 32 MB."""
    return int(min(GRID_BATCH, max(1, GRID_BATCH_BYTES // (8 * max(int(n_rows), 1)))))
_C_BASIS = {}     # id(basis) -> (weak reference to it, its C-ordered copy): one entry


def _c_ordered(basis):
    """``basis`` in C order, the last basis's copy kept while that basis lives (one entry: the
    record's columns are tens of MB, and a copy held past its record would pin them after the
    calibration returns)."""
    if basis.flags.c_contiguous:
        return basis
    key = id(basis)
    hit = _C_BASIS.get(key)
    if hit is None or hit[0]() is not basis:
        _C_BASIS.clear()
        hit = _C_BASIS[key] = (weakref.ref(basis, lambda _r, k=key: _C_BASIS.pop(k, None)),
                               np.ascontiguousarray(basis))
    return hit[1]


class Delay(Effect):
    """Latency of ``d`` samples: ``y_model(t - d dt) - y_model(t)``; needs ``y_model``.

    Parameters
    ----------
    max_delay : float
        Bound on a lag ``d > 0`` (samples).
    max_lead : float, optional
        Bound on a lead ``-d`` (samples; default ``max_delay``). A channel logged ahead of
        the drive is a logging skew, small; the caller bounds it tighter than a lag.
    basis : ndarray, optional
        ``(n, k)`` columns of the channel's model of the drive (the base's plays and offset).
        With it, the delayed model is the drive model **refitted** to the record at each trial
        delay (``basis(t - d dt)`` and ``y_model(t - d dt)``, least squares on the search
        rows): a model fitted to a record whose sensor lags by more than a few samples is
        itself wrong (fitted to the lagged output as if it were not lagged), and its shifted
        copy is then not the lagged motion; the refit removes that bias. The term is then the
        refitted model shifted, ``m_d(t - d dt) - m_d(t)`` (``params["refit"]`` True; kept on
        the instance); the change of its weights from the base is left to the base's columns.
    period : float, optional
        The drive's period (samples) when the drive repeats (:func:`~workbench.calibrate.tracing.
        periodic_drive_period`; None otherwise). On a periodic drive a lag ``d`` and ``d + k P``
        are nearly the same phase, so the refitted cost's valley at a lag longer than the period
        is narrow (the drive's decay alone tells the cycles apart) and its copies one period
        earlier are broad: the refitted search also scores each of the grid's local minima below
        one period shifted by whole periods (:meth:`_search_refit`).
    """

    name = "delay"
    n_params = 1
    nonlinear = True

    def __init__(self, max_delay=20, basis=None, max_lead=None, period=None):
        self.max_delay = float(max_delay)
        self.period = None if period is None or not period > 0 else float(period)
        self.max_lead = self.max_delay if max_lead is None else min(float(max_lead), self.max_delay)
        self.basis = None if basis is None else np.asarray(basis, float)
        self._models = {}
        self._memo = {}

    def __deepcopy__(self, memo):
        # the drive's columns and the search's memo are shared (read-only; the stages copy an
        # effect per search variant, and a copy of the record's columns each time cost seconds)
        new = copy.copy(self)
        new._models = dict(self._models)
        return new

    @staticmethod
    def _shifted(t, y_model, d):
        t = np.asarray(t, dtype=float)
        y = np.asarray(y_model, dtype=float)
        return np.interp(t - d * _dt(t), t, y) - y

    @staticmethod
    def _residual_fn(t, e, y_model, mask, project):
        """``d -> _rows(e - _shifted(t, y_model, d), mask, project)``, shifting only the mask's rows
        (equal values: the interpolation is pointwise)."""
        t = np.asarray(t, dtype=float)
        y = np.asarray(y_model, dtype=float)
        dt = _dt(t)
        rows = np.flatnonzero(mask)
        t_r, e_r, y_r = t[rows], e[rows], y[rows]

        def res(d):
            x = e_r - (np.interp(t_r - d * dt, t, y) - y_r)
            return x if project is None else project(x)
        return res

    @staticmethod
    def _residual_fn_reference(t, e, y_model, mask, project):
        """The slow reference of :meth:`_residual_fn` (the whole record shifted, then the rows)."""
        return lambda d: _rows(e - Delay._shifted(t, y_model, d), mask, project)

    def _grid(self):
        """Delays of either sign, log-spaced from half a sample to the bounds (at most 27 % apart;
        leads up to ``max_lead``, lags up to ``max_delay``)."""
        top = max(self.max_delay, 1.0)
        n = max(36, int(np.ceil(np.log(top / 0.5) / np.log(1.27))) + 1)
        mags = np.geomspace(0.5, top, n)
        # the same points on both sides up to the lead's bound (and the bound itself)
        lead = mags[mags < max(self.max_lead, 1.0)]
        lead = np.r_[lead, max(self.max_lead, 1.0)] if self.max_lead < top else mags
        return np.r_[-lead[::-1], mags]

    @staticmethod
    def _rows_shifted(Z, rows, d):
        """``Z(t - d dt)`` at ``rows`` (linear interpolation on the uniform grid, ends held).

        A C-ordered float64 ``Z`` with int64 ``rows`` (every caller's) in one compiled pass
        (:func:`~workbench.calibrate.kernels.shifted_rows_into`, the values of
        :meth:`_rows_shifted_reference` to the last bit); anything else by that reference."""
        if (isinstance(Z, np.ndarray) and Z.ndim == 2 and Z.dtype == np.float64 and Z.flags.c_contiguous
                and isinstance(rows, np.ndarray) and rows.ndim == 1 and rows.dtype == np.int64):
            return shifted_rows_into(Z, rows, d, np.empty((rows.size, Z.shape[1])))
        return Delay._rows_shifted_reference(Z, rows, d)

    @staticmethod
    def _rows_shifted_reference(Z, rows, d):
        """:meth:`_rows_shifted` in numpy (gathers and products over whole arrays)."""
        n = Z.shape[0]
        s = np.clip(rows - d, 0.0, n - 1.0)
        i0 = np.floor(s).astype(np.int64)
        f = (s - i0)[:, None]
        i1 = np.minimum(i0 + 1, n - 1)
        # (in-place products: the same arithmetic as Z[i0] * (1 - f) + Z[i1] * f,
        # bit for bit, in half the time)
        a = Z[i0]
        b = Z[i1]
        a *= 1.0 - f
        b *= f
        a += b
        return a

    @classmethod
    def _grid_cost_batch(cls, Z, y, rows, grid, chunk=16):
        """cost(d) of :meth:`_fit_refit` at every delay of ``grid`` on ``rows``, batched.

        Each delay's least squares by the normal equations of unit-RMS columns, solved by a
        batched eigendecomposition (directions with eigenvalues under 1e-13 of the largest
        dropped: the delayed ``y_model`` is exactly a combination of the delayed basis when
        it is the base's own model), the residual formed explicitly (no cancellation). The
        columns' condition number after the scaling is ~1e4 on protocol records, so the
        costs equal the QR solve's to ~1e-8 relative: the grid's minimum is the same. One
        pass over all delays instead of one LAPACK call each (issue 13: the grid's ~100
        ``lstsq`` calls were ~3/4 of the delay's search). ``Z``: the ``(n, k)`` columns, or a
        tuple of such blocks side by side.
        """
        blocks = Z if isinstance(Z, tuple) else (Z,)
        n = np.sqrt(np.mean(np.hstack([b[rows] for b in blocks]) ** 2, axis=0))
        inv = 1.0 / np.where(n > 0, n, 1.0)
        yr = y[rows]
        out = np.empty(len(grid))
        # each delay's shifted, scaled columns written in place (:func:`~workbench.calibrate.kernels.
        # shifted_rows_into`: the values of ``np.stack([np.hstack([_rows_shifted(b, rows, d) ...])]) * inv``
        # to the last bit) where the blocks and rows allow, else by that expression
        fast = rows.dtype == np.int64 and all(b.dtype == np.float64 and b.ndim == 2 and b.flags.c_contiguous
                                              for b in blocks)
        offsets = np.cumsum([0] + [b.shape[1] for b in blocks])
        for i in range(0, len(grid), chunk):
            ds = np.asarray(grid[i: i + chunk], float)
            if fast:
                X = np.empty((ds.size, rows.size, int(offsets[-1])))
                for m, d in enumerate(ds):
                    for b, j0 in zip(blocks, offsets):
                        shifted_rows_into(b, rows, d, X[m], int(j0), inv)
            else:
                X = np.stack([np.hstack([cls._rows_shifted(b, rows, d) for b in blocks]) for d in ds]) * inv
            G = np.matmul(X.transpose(0, 2, 1), X)
            b = np.matmul(X.transpose(0, 2, 1), yr)                           # (m, k)
            w, V = np.linalg.eigh(G)
            keep = w > 1e-13 * w[:, -1:]
            a = np.einsum("mkj,mk->mj", V, b)
            a = np.where(keep, a / np.where(keep, w, 1.0), 0.0)
            c = np.einsum("mkj,mj->mk", V, a)
            r = yr[None, :] - np.einsum("mrk,mk->mr", X, c)
            out[i: i + len(ds)] = np.sum(r * r, axis=1)
        return out

    def _search_refit(self, blocks, y, rows, near=None):
        """The refitted search's delay (samples): cost(d) = least squares of ``y`` on the ``blocks``
        (C-ordered ``(n, k)`` column blocks, side by side), all delayed by ``d``, on ``rows``: a log
        grid (:meth:`_grid`) on at most 2,000 of the rows (every k-th), then a bounded refinement on
        at most 10,000. With ``near`` (a delay known from a nested search, samples), the refinement
        is also made between the grid points around it and the lower cost kept: a wider model's
        coarse grid can prefer another bracket (27 #94: a 2125.4-sample lag, the joint creep + delay
        search's grid chose 1516 and returned 1461.5 at 600x its cost at 2125; review of
        s14_creepdelay). With :attr:`period` ``P`` (a periodic drive), each local minimum of the
        grid's costs below one period (either sign) is also scored shifted by whole periods
        (``d + k P``, lags up to the bound, one batch, its bracket the grid neighbours' shifted), and
        the best of these, when it beats the grid's best, is refined too and the lower refined cost
        kept (the grid's own refinement is made as without a period): a lag longer than
        the period has a valley narrower than the grid's steps (82 #152 at 1 MHz: 0.0037 of the
        no-delay cost at the true 18,000 samples, 0.147 at 19,000, aliases 0.17-0.26 elsewhere; the
        grid stepped from 15,618 to 19,760 and the fit settled at 8,042), while the same phase one
        period earlier sits in a broad one the grid sees."""
        coarse = rows[:: max(1, int(np.ceil(rows.size / 2_000)))]
        fine = rows[:: max(1, int(np.ceil(rows.size / 10_000)))]

        def cost(d, r):
            Zd = np.hstack([self._rows_shifted(b, r, d) for b in blocks])
            c = _gelsy(Zd, y[r], 1e-10)
            return float(np.sum((y[r] - Zd @ c) ** 2))

        grid = self._grid()
        costs = self._grid_cost_batch(tuple(blocks), y, coarse, grid)
        from scipy.optimize import minimize_scalar

        def bracket(k):
            lo = float(grid[k - 1]) if k > 0 else -self.max_lead
            hi = float(grid[k + 1]) if k + 1 < grid.size else self.max_delay
            if lo < 0 < hi:
                lo, hi = (lo, -0.25) if grid[k] < 0 else (0.25, hi)
            return lo, hi

        def refine(k, shift=0.0):
            lo, hi = bracket(k)
            lo, hi = lo + shift, min(hi + shift, self.max_delay)
            d_k = float(grid[k]) + shift
            sol = minimize_scalar(lambda d: cost(d, fine), bounds=(lo, hi), method="bounded",
                                  options={"xatol": 0.05, "maxiter": 40})
            c_k = cost(d_k, fine)
            return (float(sol.x), float(sol.fun)) if sol.fun <= c_k else (d_k, c_k)
        k = int(np.argmin(costs))
        best = refine(k)
        tries = [best]
        shifted = self._period_shifts(grid, costs)
        if shifted:
            # the shifted candidates scored with the grid; the best of them, if better than the grid's,
            # refined too and the lower refined cost kept (refined alone, a shifted lead bound beat a
            # grid point beside the true lag: 73 #152 at 1 MHz, 11,312.6 -> 11,953.8, true 11,274.2)
            c_s = self._grid_cost_batch(tuple(blocks), y, coarse, [grid[j] + s for j, s in shifted])
            j = int(np.argmin(c_s))
            if c_s[j] < costs[k]:
                tries.append(refine(*shifted[j]))
        if near is not None:
            k2 = int(np.argmin(np.abs(grid - float(near))))
            tries += [(float(near), cost(float(near), fine))] + ([refine(k2)] if k2 != k else [])
        return min(tries, key=lambda dc: dc[1])[0]

    def _period_shifts(self, grid, costs):
        """``(k, s)`` pairs: the grid's local minima ``k`` below one period (either sign), each with
        the whole-period shifts ``s = j P`` (``j >= 1``) that keep ``grid[k] + s`` a lag within the
        bound, the nearest first, at most as many as the grid has points (the batch at most doubles:
        on a drive of many cycles every shift up to the bound made 622 candidates against a 78-point
        grid, 3.6x the search's time, review finding 1; a far shift can hardly win, the record's
        first ``j P`` rows lying before the drive's start); empty without :attr:`period`."""
        P = self.period
        if P is None:
            return []
        c = np.asarray(costs, float)
        out = []
        for k in range(grid.size):
            if abs(grid[k]) >= P or (k > 0 and c[k] > c[k - 1]) or (k + 1 < grid.size and c[k] > c[k + 1]):
                continue
            j = 1
            while grid[k] + j * P <= self.max_delay:
                if grid[k] + j * P > 0.25:
                    out.append((k, j * P))
                j += 1
        out.sort(key=lambda ks: (ks[1], c[ks[0]]))
        return out[:grid.size]

    def _fit_refit(self, t, y, y_model, mask):
        """The refitted search: cost(d) = least squares of ``y`` on the drive model's columns and
        ``y_model``, all delayed by ``d``, on the mask's rows."""
        Z0 = column_stack([self.basis, y_model])
        # a C-ordered copy for the search, which gathers rows (a row gather from the base's
        # Fortran-ordered columns costs ~5x more); the same values. The basis's copy is made
        # once per basis (~0.15 s at 355,000 rows; both channels' delays and both stages share it)
        Bc = _c_ordered(self.basis)
        ym = np.asarray(y_model, float)[:, None]
        rows = np.flatnonzero(mask)
        d = self._search_refit((Bc, ym), y, rows)
        all_rows = np.arange(Z0.shape[0], dtype=float)
        Zr = np.hstack([self._rows_shifted(Bc, rows, d), self._rows_shifted(ym, rows, d)])
        c = np.linalg.lstsq(Zr, y[rows], rcond=1e-10)[0]
        # the refitted model, shifted: its weights' change from the base is left to the base's
        # own columns (refitted per fold), the column is the latency alone
        model = Z0 @ c                  # (Z0: the product's summation order as before the copy)
        return d, self._rows_shifted(model[:, None], all_rows, d)[:, 0] - model

    def fit(self, t, u, residual, train_mask, y_model=None, project=None):
        if y_model is None:
            raise ValueError("delay needs y_model (the base model's prediction)")
        mask = np.asarray(train_mask, bool)
        e = np.asarray(residual, float)
        if self.basis is not None and self.basis.shape[0] == e.size:
            ym = np.asarray(y_model, float)
            # the same search with and without the base's projection (the refit contains the
            # base's columns): searched once per data
            key = _data_key(e, ym, mask)
            memo = self._memo                                  # shared by the copies
            if memo.get("key") != key:
                d, col = self._fit_refit(t, e + ym, ym, mask)
                memo.clear()
                memo.update(key=key, d=d, col=col)
            d = memo["d"]
            # the column is the model fitted to this y_model: kept under the delay and y_model
            # (a term asked for another model is that model shifted, not this column)
            self._models[(d, _data_key(ym))] = memo["col"]
            return {"delay_samples": d, "delay_s": d * _dt(t), "refit": True}
        # a log grid of delays of either sign from half a sample to the bound (the bound is in
        # samples of this record, set from seconds by the caller), then a bounded refinement
        grid = self._grid()
        res = self._residual_fn(t, e, y_model, mask, project)
        cost = lambda d: float(np.sum(res(d) ** 2))  # noqa: E731
        costs = [cost(d) for d in grid]
        k = int(np.argmin(costs))
        d0 = float(grid[k])
        lo = float(grid[k - 1]) if k > 0 else -self.max_lead
        hi = float(grid[k + 1]) if k + 1 < grid.size else self.max_delay
        if lo < 0 < hi:
            lo, hi = (lo, -0.25) if d0 < 0 else (0.25, hi)
        sol = least_squares(lambda x: res(x[0]), [d0], bounds=([lo], [hi]), max_nfev=40)
        d = float(sol.x[0]) if 2 * sol.cost <= min(costs) else d0
        return {"delay_samples": d, "delay_s": d * _dt(t)}

    def fold_columns(self, t, y, y_model, params, rows_list, lower):
        """The refitted delay's column with the model's weights fitted on each of ``rows_list``.

        The delay ``d`` is searched on the development rows (as a relaxation's time constant);
        the model it shifts has ~``k`` weights, which a fold may fit only on its own training
        rows (issue 13: fitted on all development rows, they had seen every fold's validation
        rows, and the fold's score counted one parameter). Per row set: ``m = y_model + basis
        delta`` with ``delta`` fitted to ``y(t) - y_model(t - d dt)`` on ``basis(t - d dt)`` at
        those rows, bounded like the base's own corrections (``delta >= lower``: the plays'
        weights stay >= 0; :func:`~workbench.calibrate.base_fit._gram_solve`, the base's bounded
        least squares); the column is ``m(t - d dt) - m(t)``.

        Parameters
        ----------
        t : ndarray
            Times (s), uniform.
        y : ndarray
            The channel's record (channel units).
        y_model : ndarray
            The model the delay shifts (channel units).
        params : dict
            :meth:`fit`'s result (``delay_samples``).
        rows_list : list of ndarray
            Row indices per fit (e.g. each fold's training search rows).
        lower : ndarray
            ``(k,)`` lower bounds of the basis weights' corrections (``-w0`` for the plays,
            ``-inf`` for the offset; channel units per column unit).

        Returns
        -------
        list of ndarray
            One ``(n,)`` column per row set (channel units).
        """
        if self.basis is None or self.basis.shape[0] != np.size(y_model):
            col = self._shifted(t, y_model, params["delay_samples"])
            return [col for _ in rows_list]
        d = float(params["delay_samples"])
        Bc = _c_ordered(self.basis)
        ym = np.asarray(y_model, float)
        y = np.asarray(y, float)
        lower = np.asarray(lower, float)
        all_rows = np.arange(ym.size, dtype=float)
        # the shifted columns at the row sets' union once, each set's normal equations from its groups
        union, groups = _row_groups(rows_list, ym.size)
        X = self._rows_shifted(Bc, union, d)
        r = y[union] - self._rows_shifted(ym[:, None], union, d)[:, 0]
        out = []
        for G, h, m_rows in _row_set_normals(X, r, groups, len(rows_list)):
            delta = _bounded_delta(G, h, m_rows, lower)
            m = ym + self.basis @ delta
            out.append(self._rows_shifted(m[:, None], all_rows, d)[:, 0] - m)
        return out

    def term(self, t, u, params, y_model=None):
        if y_model is None:
            raise ValueError("delay needs y_model (the base model's prediction)")
        col = None
        if params.get("refit") and self._models:
            col = self._models.get((params["delay_samples"], _data_key(np.asarray(y_model, float))))
        if col is not None:
            return col
        return self._shifted(t, y_model, params["delay_samples"])

    def _fingerprint(self, report, t, u, residual):
        return 1.0 if not report.independent else 0.5


class _Relaxation(Effect):
    """Shared machinery: one linear gain times a column depending on a time constant tau."""

    n_params = 2
    nonlinear = True

    def __init__(self, tau_min_samples=50, tau_max_fraction=1.0 / 3.0, n_grid=24):
        self.tau_min_samples = float(tau_min_samples)
        self.tau_max_fraction = float(tau_max_fraction)
        self.n_grid = int(n_grid)

    def _column(self, u, tau, dt):
        raise NotImplementedError

    def _column_rows(self, u, tau, dt, rows):
        """``_column(u, tau, dt)[rows]`` (compiled, equal values)."""
        raise NotImplementedError

    def fit(self, t, u, residual, train_mask, y_model=None, project=None):
        dt = _dt(t)
        u = np.asarray(u, float)
        lo = np.log(self.tau_min_samples * dt)
        hi = np.log(max(self.tau_max_fraction * (t[-1] - t[0]), 2 * self.tau_min_samples * dt))
        grid = [[g] for g in np.linspace(lo, hi, self.n_grid)]
        # central differences: the column less its part in the base's span (``project``: an
        # absorption's lowpass of V is mostly V, which the plays hold) is a small difference of
        # large columns, and the forward difference's step (1.5e-8 in log tau) sits in its rounding.
        # Measured on a 1 kHz steps record (absorption 702x its floor, tau 1.098 s): the forward
        # slope came out 356 against 37-39 from steps 1e-6-1e-4, the search stopped at its 60
        # evaluations at 1.060 s (cost 32x the truth's), and the 5x misfit that left was read as a
        # leakage beside it; with central differences (step 6e-6) it converges in 6 to 1.097 s.
        # (A forward difference at a step above the rounding, 1e-5, one evaluation per Jacobian instead
        # of two, ~1 s CPU less a protocol record, passed the same tests but named a leakage beside a
        # 239x absorption on the confusion benchmark's seed 41 #3, which central differences answer
        # right: tried in the final review, not kept)
        theta, beta = _varpro(lambda th: self._column(u, np.exp(th[0]), dt),
                              np.asarray(residual, float), np.asarray(train_mask, bool),
                              grid, [lo], [hi], project,
                              row_columns=lambda th, rows: self._column_rows(u, np.exp(th[0]), dt, rows),
                              jac="3-point")
        return {"gain": float(beta[0]), "tau_s": float(np.exp(theta[0]))}

    def term(self, t, u, params, y_model=None):
        return params["gain"] * self._column(np.asarray(u, float), params["tau_s"], _dt(t))

    def columns(self, t, u, params, y_model=None):
        # absorbed charge follows the voltage (k_s > 0); creep's single-tau form keeps a free sign
        lower = 0.0 if self.name == "dielectric_absorption" else -np.inf
        return self._column(np.asarray(u, float), params["tau_s"], _dt(t)), [lower]

    def with_gains(self, params, gains):
        return {**params, "gain": float(gains[0])}


class Creep(_Relaxation):
    """Creep: ``c (lowpass_tau(u) - u)`` (zero static gain), displacement or gauge channel."""

    name = "creep"
    channels = MECHANICAL

    def _column(self, u, tau, dt):
        return lowpass(u, tau, dt) - u

    def _column_rows(self, u, tau, dt, rows):
        return lowpass_rows(u, tau, dt, rows, minus_input=True)

    def _fingerprint(self, report, t, u, residual):
        # creep drifts during holds, with a rate whose sign follows the step into the hold
        if len(report.holds) < 2:
            return 0.5
        steps, rates = [], []
        prev = None
        for h in report.holds:
            if prev is not None:
                steps.append(h["input_value"] - prev)
                rates.append(h["drift_rate_per_s"])
            prev = h["input_value"]
        steps, rates = np.asarray(steps), np.asarray(rates)
        if not (np.any(steps) and np.any(rates)):
            return 0.5
        c = abs(float(np.corrcoef(steps, rates)[0, 1])) if steps.size > 1 else 0.5
        return 0.5 + 0.5 * (c if np.isfinite(c) else 0.0)


class CreepSpectrum(Effect):
    """Creep as a spectrum of relaxations: ``sum_j c_j (lowpass_tau_j(u) - u)``, ``c_j >= 0``.

    One branch per ``taus_s`` entry (default: half a decade apart from 10 samples to ten record
    lengths), the gains by non-negative least squares: the discrete form of the Kelvin-Voigt
    branches of ``workbench.plant.creep``, whose sum approximates seed 001's logarithmic law over
    the decades covered. ``c_j >= 0`` because creep continues in the direction of the step;
    this sign constraint is what keeps the spectrum from fitting arbitrary slow residuals.
    Same name as :class:`Creep` (it is the same effect); ``n_params`` counts the branches that
    came out non-zero.

    With ``loop`` (a :class:`~workbench.calibrate.creep_across.CreepLoop`: the base's terminal voltage,
    the channel's ``a`` and plays) the branches are driven as the plant's are, by the voltage across
    C_h with the creep's own pull-back (:func:`~workbench.calibrate.creep_across.creep_drive`, solved
    in :meth:`fit` on the rows given), ``u = V_h`` (``params["driver"] = "v_h"``). The drive is kept on the
    instance: :meth:`columns` returns the same columns whatever ``u`` (another channel reading the same
    stack scales them by its own gains). ``V_h`` enters scaled to the base model's units (its least-squares
    multiple on the rows fitted), so the gains keep the plain spectrum's meaning, fractions of the
    driver, which the written plant's branches are sized from (:mod:`.plant_update` rebuilds the fitted
    model with this drive, ``plant_update.creep_driver``, and the instant core takes the branches' held
    part as the plays' fit of it, ``core_refit.refitted_core``; a creep refitted jointly beside a delay,
    ``creep_beside_delay.delay_beside_creep``, keeps this drive and ``driver``; a creep found beside a delay,
    ``creep_beside_delay.creep_beside_delay``, is driven by the drive model refitted at the found delay, kept
    on its instance as this drive, ``driver: refit``, and rebuilt on it the same way).
    """

    name = "creep"
    channels = MECHANICAL + CHARGE
    n_params = 2

    def __init__(self, taus_s=None, per_decade=2, loop=None):
        self.taus_s = None if taus_s is None else np.asarray(taus_s, float)
        self.per_decade = int(per_decade)
        self.loop = loop
        self._drive = None            # V_h (scaled) of the last fit with ``loop``

    def _taus(self, t):
        if self.taus_s is not None:
            return self.taus_s
        dt = _dt(t)
        # up to ten record lengths: slower branches still charge during the record (a ramp)
        lo, hi = np.log10(10 * dt), np.log10(max(10.0 * (t[-1] - t[0]), 100 * dt))
        return 10.0 ** np.arange(lo, hi + 1e-9, 1.0 / self.per_decade)

    @staticmethod
    def _columns(u, taus, dt):
        return column_stack([lowpass(u, tau, dt) - u for tau in taus])

    def _nnls(self, X, residual, mask, project):
        from scipy.optimize import nnls
        X = _rows(X, mask, project)
        scale = np.sqrt(np.mean(X * X, axis=0))
        scale[scale == 0] = 1.0
        gains, _ = nnls(X / scale, _rows(residual, mask, project))
        return gains / scale

    def fit(self, t, u, residual, train_mask, y_model=None, project=None):
        t = np.asarray(t, float)
        taus = self._taus(t)
        mask = np.asarray(train_mask, bool)
        if self.loop is None or y_model is None:
            self._drive = None
            gains = self._nnls(self._columns(np.asarray(u, float), taus, _dt(t)), residual, mask, project)
            self.n_params = max(1, int(np.count_nonzero(gains)))
            return {"gains": gains.tolist(), "taus_s": taus.tolist()}
        from .creep_across import creep_drive
        y_model = np.asarray(y_model, float)
        v_h = creep_drive(self.loop, np.asarray(residual, float) + y_model, taus, _dt(t), mask)
        # V_h in the base model's units (its least-squares multiple on the rows): gains as the plain spectrum's
        vm = v_h[mask] - v_h[mask].mean()
        s = float(vm @ (y_model[mask] - y_model[mask].mean()) / (vm @ vm)) if vm @ vm > 0 else 1.0
        self._drive = s * v_h
        gains = self._nnls(self._columns(self._drive, taus, _dt(t)), residual, mask, project)
        self.n_params = max(1, int(np.count_nonzero(gains)))
        return {"gains": gains.tolist(), "taus_s": taus.tolist(), "driver": "v_h"}

    def _uses_drive(self, params):
        return params.get("driver") == "v_h" and self._drive is not None

    def term(self, t, u, params, y_model=None):
        X, _ = self.columns(t, u, params, y_model)
        return X @ np.asarray(params["gains"], float)

    def columns(self, t, u, params, y_model=None):
        """The branches as columns and their lower bounds (0: creep follows the step)."""
        taus = np.asarray(params["taus_s"], float)
        if self._uses_drive(params):
            u = self._drive
        return self._columns(np.asarray(u, float), taus, _dt(t)), np.zeros(taus.size)

    def with_gains(self, params, gains):
        return {**params, "gains": np.maximum(np.asarray(gains, float), 0.0).tolist()}


class GaugeNonlinearity(Effect):
    """The bridge's bow, seed 000 eq. 27, against a linear gauge gain.

    For the gauge channel modelled as ``a + b x`` from the recorded displacement ``x`` (passed
    as ``u``), eq. 27 reads ``V = G d / (1 + beta d)`` about a reference ``d = x - x_ref``; to
    first order in ``beta d`` the residual from the line is ``c0 + c1 d + c2 d^2`` with
    ``c2 = -G beta``. The fit solves the three gains (the line is refitted with the bow, so
    only ``beta`` is new: one parameter) and reports ``coefficient_per_m = -c2 / b`` with ``b``
    the base model's slope (from ``y_model``; 1 when it is not given).
    """

    name = "gauge_nonlinearity"
    n_params = 1
    channels = ("gauge_v",)

    @staticmethod
    def _columns(u, x_ref):
        d = np.asarray(u, float) - x_ref
        return column_stack([np.ones_like(d), d, d * d])

    def fit(self, t, u, residual, train_mask, y_model=None, project=None):
        u = np.asarray(u, float)
        mask = np.asarray(train_mask, bool)
        x_ref = float(np.mean(u[mask]))
        X = self._columns(u, x_ref)
        if project is None:
            beta, _ = _lstsq(X[mask], np.asarray(residual, float)[mask])
        else:
            # fitted jointly with the base line a + b x: only the bow is new
            c2, _ = _lstsq(_rows(X[:, 2:], mask, project), _rows(residual, mask, project))
            beta = np.r_[0.0, 0.0, c2]
        slope = 1.0
        if y_model is not None:
            slope = float(np.polyfit(u[mask], np.asarray(y_model, float)[mask], 1)[0]) or 1.0
        return {"c0": float(beta[0]), "c1": float(beta[1]), "c2": float(beta[2]), "x_ref": x_ref,
                "coefficient_per_m": float(-beta[2] / (slope + beta[1]))}

    def term(self, t, u, params, y_model=None):
        return self._columns(u, params["x_ref"]) @ np.array([params["c0"], params["c1"], params["c2"]])

    def columns(self, t, u, params, y_model=None):
        d = np.asarray(u, float) - params["x_ref"]
        return d * d, [-np.inf]

    def with_gains(self, params, gains):
        # the joint fit refits the line; the bow's coefficient keeps the base slope's scale
        c2 = float(gains[0])
        scale = c2 / params["c2"] if params["c2"] else 1.0
        return {**params, "c0": 0.0, "c1": 0.0, "c2": c2, "coefficient_per_m": params["coefficient_per_m"] * scale}


class DielectricAbsorption(_Relaxation):
    """Dielectric absorption, seed 002 eq. 2.9: ``k lowpass_tau(u)``, charge channel."""

    name = "dielectric_absorption"
    channels = CHARGE

    def _column(self, u, tau, dt):
        return lowpass(u, tau, dt)

    def _column_rows(self, u, tau, dt, rows):
        return lowpass_rows(u, tau, dt, rows)


class Leakage(Effect):
    """Leakage through a finite resistance: ``k int u dt`` (seed 002 eq. 2.7), charge channel."""

    name = "leakage"
    n_params = 1
    channels = CHARGE

    @staticmethod
    def _column(t, u):
        return cumulative_trapezoid(np.asarray(u, float), np.asarray(t, float), initial=0.0)

    def fit(self, t, u, residual, train_mask, y_model=None, project=None):
        mask = np.asarray(train_mask, bool)
        beta, _ = _lstsq(_rows(self._column(t, u), mask, project), _rows(residual, mask, project))
        return {"gain_per_s": float(beta[0])}

    def term(self, t, u, params, y_model=None):
        return params["gain_per_s"] * self._column(t, u)

    def columns(self, t, u, params, y_model=None):
        # a resistance draws charge with the voltage's sign: gain 1 / R_FP >= 0
        return self._column(t, u), [0.0]

    def with_gains(self, params, gains):
        return {**params, "gain_per_s": float(gains[0])}


def _foh_mode(f_hz, zeta, dt):
    """First-order-hold discretization of ``w^2 / (s^2 + 2 zeta w s + w^2)`` (0 < zeta < 1).

    The drive is taken as linear between samples (the triangle hold of
    ``scipy.signal.cont2discrete(..., method="foh")``, same coefficients), as the record's drive
    is (a sampled smooth voltage, and the base model driven by it), not a staircase. A zero-order
    hold would excite the mode with steps the record never had and put a half-sample lag into
    the column. Computed from one 4 x 4 matrix exponential of the augmented system (state,
    input, input slope), whose products stay accurate for a mode far below the sample rate
    (``w dt`` down to 1e-5), where a closed form in ``1 / (w dt)`` cancels.

    The searches ask for the same ``(f_hz, zeta, dt)`` many times (every fold's grid, the searches with
    and without the base's projection, the refinement's returns): the last 4,096 answers are kept
    (:func:`_foh_mode_of`, keyed by the three floats; the same values, fresh arrays each call).

    Parameters
    ----------
    f_hz : float
        Natural frequency (Hz).
    zeta : float
        Damping ratio (dimensionless).
    dt : float
        Sample period (s).

    Returns
    -------
    b, a : ndarray
        Numerator and denominator in ``z^-1`` (``a[0] = 1``), unit DC gain.
    """
    b, a = _foh_mode_of(float(f_hz), float(zeta), float(dt))
    return b.copy(), a.copy()


@functools.lru_cache(maxsize=4096)
def _foh_mode_of(f_hz, zeta, dt):
    """:func:`_foh_mode`'s computation (floats in, read-only arrays out: the cache's entries)."""
    w = 2 * np.pi * float(f_hz)
    M = np.zeros((4, 4))
    M[0, 1] = dt
    M[1, 0] = -w * w * dt
    M[1, 1] = -2.0 * float(zeta) * w * dt
    M[1, 2] = w * w * dt
    M[2, 3] = 1.0
    E = linalg.expm(M)
    phi, g0, g1 = E[:2, :2], E[:2, 2], E[:2, 3]
    gd = g0 - g1
    # y = C adj(zI - Phi) (g1 z + g0 - g1) / det(zI - Phi), C = [1, 0]
    b = np.array([g1[0], gd[0] - phi[1, 1] * g1[0] + phi[0, 1] * g1[1], -phi[1, 1] * gd[0] + phi[0, 1] * gd[1]])
    a = np.array([1.0, -(phi[0, 0] + phi[1, 1]), phi[0, 0] * phi[1, 1] - phi[0, 1] * phi[1, 0]])
    # unit DC gain in the stored floats: for a mode far below the rate, sum(a) ~ (w dt)^2 is
    # resolved only to ~1e-16 / (w dt)^2 by a's rounding; b follows it, so a held input adds nothing
    b = b * (a.sum() / b.sum())
    b.flags.writeable = a.flags.writeable = False
    return b, a


#: a mode's frequency floor, in cycles over the record: the slow periodic term of a drift (a
#: temperature cycle, :func:`~workbench.calibrate.tracing.candidate_plan`) reaches up to this many
#: cycles, a mode starts there (below it, a heavily damped slow "mode" mimics a creep branch: a
#: 3.8 Hz, zeta 0.3 mode split the folds of a 2 s creep record with creep at 4 cycles per record)
SLOW_CYCLES_PER_RECORD = 10.0
#: below SLOW_CYCLES_PER_RECORD a mode is searched down to this many cycles over the record (a cycle is told
#: from a one-off bend only when it repeats), and only as a ringing one: its damping at most
#: RING_ZETA_MAX, so its ringing outlasts a cycle (the envelope ``exp(-2 pi zeta)`` per cycle above 1/e).
#: A heavier slow "mode" is a relaxation, creep's form, and stays out (the 3.8 Hz, zeta 0.3 mode of a
#: 2 s creep record). A 0.1 s record at 1 MHz rings 2.7-7.3 cycles of the benchmark's 27-73 Hz modes
#: (57 #143: 74 Hz, 7.4 cycles, was answered `none`)
RING_CYCLES_PER_RECORD = 2.0
RING_ZETA_MAX = 1.0 / (2.0 * np.pi)


#: the refitted mode's search (:meth:`Resonance._fit_refit`) filters the drive model's ~26 columns per
#: trial: on the record taken every k-th sample, at most this many samples (a cost bound, as the
#: delay's refitted search's 2,000 / 10,000 rows); its trials reach a tenth of that rate. Why the bound
#: is safe: a trial at a tenth of the thinned rate is sampled ten times a cycle, where the first-order
#: hold's discretisation of the mode (:func:`_foh_mode`, exact for a piecewise-linear input) keeps its
#: frequency and damping. The variant is searched over its whole reach on every record: a gate that
#: skipped it where no trial mode could turn the motion (session 21, ``refit_reach``) lost modes its
#: review found in that reach (a 10 Hz mode on 1 kHz steps: ratio 0.003 with the refit, 0.050
#: without; 4 of 19 constructed 1.5-16 Hz modes at 100 Hz / 1 kHz not named) and was taken out. The
#: thinning takes every k-th sample without an anti-alias filter: the record's noise above the thinned
#: Nyquist folds into the search's band (a level under every trial's cost); block means in its place
#: are not measured (open, issue 13 review finding 3)
REFIT_SEARCH_SAMPLES = 2_000
#: the refitted mode's search reuses what it evaluated (:meth:`Resonance._fit_refit`: the starting grid
#: points' residuals, the answer's weights); False evaluates each afresh (the reference the tests compare with)
_REFIT_REUSE = True

#: the fine frequency grid about a residual spectrum's peak spans +- this in log f (+-12 %)
FINE_HALF_LOG = 0.12
#: the residual spectrum's peaks are sought above this frequency (Hz): below it the base model's own slow
#: errors dominate the spectrum (and the search's floor, RING_CYCLES_PER_RECORD cycles over the record, is
#: at or below it on the benchmark's records: 20 Hz on a 0.1 s record)
PEAK_FLOOR_HZ = 20.0
#: Welch's segment of the residual spectrum whose peaks seed the fine grid, in samples: 2.4 Hz bins at
#: 10 kHz. Where it cannot resolve the fine grid's half-width (its bin above ``expm1(FINE_HALF_LOG) f``:
#: below ~190 Hz at 100 kHz, ~960 Hz at the thinned 1 MHz) a longer segment's peaks are added
#: (:meth:`Resonance._spectral_peaks`)
PEAK_SEGMENT = 4096


#: the held drive's path (:class:`HeldDrive`) takes each sample's step as settled within the sample: the
#: series resistor's RC tail left at the sample's end, ``exp(-dt / RC)``, at most this share of the step (a
#: record sampled at least ``ln(100) = 4.6`` RC apart; the P-888.51's 80 ohm and ~6 uF: 100 Hz, not 1 kHz)
HELD_SETTLED = 0.01


class HeldDrive:
    """The stack's drive between samples under an amplifier command held from sample to sample.

    A command updated at the samples and held between them (a DAC at the record's rate) is a staircase; the
    amplifier moves the stack's charge at most at its current limit (``limits``: source, sink, A) and settles
    through the series resistor with the time constant ``rc = R C`` (s). Where a step settles within a sample
    (:data:`HELD_SETTLED`) each interval's path is fixed by its charge step ``dq`` (C; the record's integrated
    current, its mean over the interval times ``dt``): the charge ramps at the limit from the interval's start
    while the resistor's current exceeds it, then settles exponentially, the two moving ``dq`` together; a step
    too small to reach the limit settles from the start, and an interval that moves ``limit * dt`` ramps at the
    limit throughout (a slew that runs on; its settle, spilling into the next interval, is that one's). The
    motion follows the charge (its model interpolated in proportion to the charge moved): a mode of the stack
    is driven through that path (:func:`held_mode_column`), not through a first-order hold's straight line
    between samples (:func:`_foh_mode`). At 100 Hz a 38.4 Hz mode under the 0.15 Hz sine (93 #115, n_sub 64
    simulation): the first-order hold leaves 7.96e-9 m of its 1.15e-8 m effect (gain -23), this path 2.2e-10 m
    (gain 0.96). Above the record's Nyquist frequency the path tells a mode from its alias: the same poles,
    different responses to the path's ramps and settles.

    Parameters
    ----------
    dq : ndarray
        The charge moved in each sample's interval (C), ``dq[0]`` 0 (the record's start).
    dt : float
        Sample period (s).
    rc : float
        The fastest settle's time constant (s): the series resistor times the stack's smallest capacitance (the
        held search's ceiling, :meth:`Resonance._held_ceiling`, and the replay's resolution read it).
    limits : (float, float)
        The amplifier's current limits, source and sink, both positive (A).
    rc_k : ndarray, optional
        Each interval's settle time constant (s; default ``rc`` for all): the series resistor times the stack's
        capacitance over that step, which a hysteretic stack changes along its loop (the P-888.51's 6.0 uF at a
        reversal, ~11.6 uF on a continuing step: :func:`~.tracing.held_drive` reads it from the record, ``dq / dv``).
    """

    def __init__(self, dq, dt, rc, limits, rc_k=None):
        dq = np.asarray(dq, float)
        self.dt, self.rc = float(dt), float(rc)
        self.rc_k = np.full(dq.shape, self.rc) if rc_k is None else np.asarray(rc_k, float).copy()
        if self.rc_k.shape != dq.shape:
            raise ValueError("rc_k: one settle time constant per interval")
        dt, rc = self.dt, self.rc_k
        lim = np.where(dq >= 0.0, float(limits[0]), float(limits[1]))
        x = np.abs(dq) / lim                       # the time at the limit that would move the step (s)
        # each interval: at the limit until t_e, then the settle from there, lim rc (1 - exp(-s / rc)) of charge
        # by the time s after: x = t_e + rc (1 - exp(-(dt - t_e) / rc)), solved for t_e (increasing in t_e);
        # a step the settle alone moves (x <= rc (1 - exp(-dt / rc)): its current never reaches the limit) has
        # t_e = 0, and one the limit moves the whole interval (x >= dt) t_e = dt
        settle_only = x <= rc * -np.expm1(-dt / rc)
        runs_on = x >= dt
        lo, hi = np.zeros_like(x), np.full_like(x, dt)
        for _ in range(60):                         # bisection to ~dt 2^-60
            mid = 0.5 * (lo + hi)
            above = mid + rc * -np.expm1(-(dt - mid) / rc) > x
            hi = np.where(above, mid, hi)
            lo = np.where(above, lo, mid)
        t_e = np.where(settle_only, 0.0, np.where(runs_on, dt, 0.5 * (lo + hi)))
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(x > 0.0, 1.0 / x, 0.0)   # per second: the ramp's slope as a fraction of the step
        self.t_ramp = t_e
        self.slope = inv
        # the fraction of the step the ramp moved, and the settle's amplitude as a fraction of the step
        self.q_ramp = np.where(runs_on, 1.0, t_e * inv)
        self._left = np.where(runs_on, 0.0, np.where(settle_only, 1.0 / -np.expm1(-dt / rc), rc * inv))
        self.slope = np.where(settle_only, 0.0, inv)
        self.q_ramp = np.where(settle_only, 0.0, self.q_ramp)
        # the settle's decay over the interval's rest, exp(-(dt - t_e) / rc) (trial-free)
        self._settled = np.exp(-(dt - t_e) / rc)
        self._runs_on = runs_on
        self._key = _data_key(dq, rc, np.array([dt, self.rc, float(limits[0]), float(limits[1])]))

    #: a step of :meth:`direct` (``ramp_fraction`` 0) settles with this fraction of the sample as its time constant
    #: (the kernel's settle term then differs from an instant step's by this fraction of a sample's kernel)
    STEP_SETTLE_FRACTION = 1e-12

    @classmethod
    def direct(cls, n, dt, ramp_fraction):
        """The path between samples of a drive with no series resistor: the stack's terminal is the logged voltage
        itself, which the amplifier moved from one sample's value to the next along a straight line over the first
        ``ramp_fraction`` of the interval and then held: 1, a straight line over the whole sample (a first-order
        hold, a sampled smooth voltage; :func:`_foh_mode`'s drive); 0, a step at the interval's start (a command
        held from sample to sample that nothing slows); between, a slew over part of the sample (the amplifier's
        current limit: a step of ``dv`` slews at ``I / C`` for ``C dv / (I dt)`` of the sample; the simulator's own
        record without a resistor at :data:`~.synthetic.N_SUB` sub-steps a sample moves a step its limit allows
        within a sub-step linearly over the first sub-step, ``1 / N_SUB``, a longer one at the limit over as many
        sub-steps as it takes).

        No current limit and no settle are read from the record (there is no resistor to settle through). ``rc``,
        the fastest settle the held search's ceiling reads (:meth:`Resonance._held_ceiling`), is the sample period:
        the ceiling is the Nyquist frequency, which no settle's corner raises.

        Parameters
        ----------
        n : int
            Samples (intervals) of the record.
        dt : float
            Sample period (s).
        ramp_fraction : float
            The part of the sample the ramp lasts, 0 to 1 (dimensionless).
        """
        a = float(ramp_fraction)
        if not 0.0 <= a <= 1.0:
            raise ValueError(f"ramp_fraction must be within 0..1, got {ramp_fraction!r}")
        self = cls.__new__(cls)
        n, dt = int(n), float(dt)
        self.dt, self.rc = dt, dt
        self.ramp_fraction = a
        step = a == 0.0
        self.t_ramp = np.full(n, a * dt)
        self.slope = np.full(n, 0.0 if step else 1.0 / (a * dt))
        self.q_ramp = np.full(n, 0.0 if step else 1.0)
        self._left = np.full(n, 1.0 if step else 0.0)
        self._settled = np.full(n, 0.0 if step else 1.0)
        self._runs_on = np.full(n, a == 1.0)
        self.rc_k = np.full(n, cls.STEP_SETTLE_FRACTION * dt if step else dt)
        self._key = _data_key(np.array([n, dt, a]))
        return self

    def path(self, s, rows=slice(None)):
        """``rho_k(s)``, the share of interval ``k``'s step moved by the time ``s`` after its start (0 to 1).

        The ramp at the limit ``s / x_k`` up to ``t_ramp``, then the settle ``q_ramp + left (1 - exp(-(s - t_ramp) /
        RC))``, reaching 1 at ``dt``; an interval the limit moves throughout (a slew that runs on) ramps as ``s / dt``
        (its recorded step over the interval: the kernel's slope, ``1 / x_k``, equals it but for the record's noise).
        The plant file's replay drives the stack along it between samples
        (:func:`~workbench.calibrate.plant_update.updated_plant_error`).

        Parameters
        ----------
        s : ndarray
            Times after an interval's start, s (``0 <= s <= dt``).
        rows : slice, optional
            The intervals (samples ``k``; interval ``k`` ends at sample ``k``).

        Returns
        -------
        ndarray
            ``(intervals, s.size)`` shares of each interval's step (dimensionless).
        """
        s = np.asarray(s, float)[None, :]
        T = self.t_ramp[rows][:, None]
        ramp = np.where(self._runs_on[rows][:, None], s / self.dt, self.slope[rows][:, None] * s)
        settle = self.q_ramp[rows][:, None] + self._left[rows][:, None] * -np.expm1(-np.maximum(s - T, 0.0)
                                                                                  / self.rc_k[rows][:, None])
        return np.where(s < T, ramp, settle)

    def kernel(self, lam):
        """``K_k = int_0^dt exp(lam (dt - s)) rho_k(s) ds`` per interval (complex), ``rho_k`` the interval's path
        from 0 to 1 (:class:`HeldDrive`), for a pole ``lam`` (1/s). One complex exponential per interval: the
        ramp's ``exp(-lam T)``; the rest from it and the settle's ``exp(-(dt - T) / RC)``, computed once."""
        dt, T = self.dt, self.t_ramp
        e_dt = complex(np.exp(lam * dt))
        lt = lam * T
        e_mt = np.exp(-lt)                                   # exp(-lam T)
        e_rest = e_dt * e_mt                                 # exp(lam (dt - T))
        # the ramp: slope * exp(lam dt) * int_0^T s exp(-lam s) ds, by its series where lam T is small
        J = np.empty(T.size, complex)
        small = np.abs(lt) < 1e-2
        ls = lt[small]
        J[small] = T[small] ** 2 * (0.5 - ls / 3.0 + ls * ls / 8.0)
        big = ~small
        J[big] = (1.0 - e_mt[big] * (1.0 + lt[big])) / (lam * lam)
        K = (self.slope * e_dt) * J
        # the level the ramp reached, held (a ramp that runs on: q_ramp 1, nothing left to settle)
        K += self.q_ramp * ((e_rest - 1.0) / lam)
        # the settle: (1 - q_ramp) int_0^rest exp(lam (rest - s)) (1 - exp(-s / RC)) ds
        a = lam + 1.0 / self.rc_k
        K += self._left * ((e_rest - 1.0) / lam - (e_rest - self._settled) / a)
        return K


def held_mode_column(u, held, f_hz, zeta):
    """``(H - 1) u`` at the samples of a mode ``H`` (unit DC gain, ``f_hz``, ``zeta`` < 1) driven by ``u``
    along the held drive's path between samples (:class:`HeldDrive`), started at rest at ``u[0]``.

    Exact for that path: per pole ``lam`` the mode's state moves over an interval by ``exp(lam dt)`` and
    takes the interval's input ``u_{k-1} + (u_k - u_{k-1}) rho_k``, whose integral against ``exp(lam (dt -
    s))`` is :meth:`HeldDrive.kernel`'s; the two poles are conjugate, so the response is twice the real part
    of one's."""
    u = np.asarray(u, float)
    dt = held.dt
    w = 2.0 * np.pi * float(f_hz)
    z = float(zeta)
    beta = w * np.sqrt(max(1.0 - z * z, 1e-12))
    lam = complex(-z * w, beta)
    r = w * w / (2j * beta)                      # the residue of w^2 / ((s - lam)(s - conj(lam))) at lam
    v = u - u[0]
    if _HELD_COMPILED:
        return held_mode_column_compiled(v, held, lam, r)
    e_dt = np.exp(lam * dt)
    dv = np.diff(v, prepend=0.0)
    v_prev = np.r_[0.0, v[:-1]]
    F = r * (v_prev * ((e_dt - 1.0) / lam) + dv * held.kernel(lam))
    state = signal.lfilter([1.0], [1.0, -e_dt], F)
    return 2.0 * state.real - v


#: :func:`held_mode_column` by its compiled recursion (:func:`.kernels.held_mode_column_compiled`); False: the
#: numpy form (:meth:`HeldDrive.kernel` and ``lfilter``), the reference the tests compare with
_HELD_COMPILED = True


class Resonance(Effect):
    """A lightly damped mode with unit DC gain the base model lacks: ``g (H(s) - 1) u``.

    basis : ndarray, optional
        ``(n, k)`` columns of the channel's model of the drive (the base's plays and offset), as
        :class:`Delay`'s. With it, :meth:`fit` has a third variant (``refit=True``): the mode acting
        on the drive model **refitted** per trial mode (least squares of the record on the trial
        mode's filtered columns ``H(basis)`` and ``H(y_model)``), the term the refitted model's
        ``(H - 1) m`` (``params["refit"]`` True; its per-fold weights :meth:`fold_columns`). A mode
        below the drive's frequency turns the motion's sign (``H ~ -0.7`` at 1.55x the mode), a
        motion the base's plays (weights >= 0) cannot follow: the base's prediction is then a
        distorted drive for the mode, and the mode filtering it explains little (issue 13: 78 #148
        at 1 MHz, a 130x 39.8 Hz mode under a 62 Hz sine, found at 44.1 Hz and answered
        ``inconclusive``; the true mode on the refitted columns reaches the noise floor). The
        tracing keeps the variant whose joint fit leaves less on the development rows.
    held : HeldDrive, optional
        The drive's path between samples of a held command (:class:`HeldDrive`, built by
        :func:`~.tracing.held_drive` only where each step settles within a sample: 100 Hz on the P-888.51). With
        it, :meth:`fit` has a fourth variant (``held=True``): the mode driven through that path
        (:func:`held_mode_column`), searched past the Nyquist frequency (:meth:`_fit_held`; ``params["held"]``
        True), which tells a mode above Nyquist from its alias. The first-order hold's column is the wrong
        discretization there: on 93 #115's 38.4 Hz mode at 100 Hz it leaves 7.4e-9 of a 1.05e-8 m effect, the
        held path 4.4e-10 (README, "Session 31, modes above the record's Nyquist frequency").
    """

    name = "resonance"
    n_params = 3
    nonlinear = True

    def __init__(self, f_min_hz=None, f_max_fraction=0.5, zeta_min=0.002, zeta_max=0.3,
                 n_freq=30, basis=None, held=None):
        # the search's ceiling, f_max_fraction / dt: the Nyquist frequency, the highest at which a sampled
        # record shows a mode's ringing (a faster mode rings at its alias fs - f, below it). It was 0.4 of the
        # rate, a constant of the first library: a 410 Hz mode beside a drift at 1 kHz (seed 73 #33) was
        # searched at the 400 Hz ceiling and missed (tests/calibrate/test_mode_ceiling.py)
        self.f_min_hz = f_min_hz
        self.f_max_fraction = float(f_max_fraction)
        self.zeta_min, self.zeta_max = float(zeta_min), float(zeta_max)
        self.n_freq = int(n_freq)
        self.basis = None if basis is None else np.asarray(basis, float)
        # the drive's path between samples of a held command (:class:`HeldDrive`): with it, :meth:`fit` has a
        # fourth variant (``held=True``), the mode driven through that path, searched above Nyquist too
        self.held = held
        self._models = {}
        self._refit_memo = {}
        self._fold_memo = {}

    @property
    def refits(self):
        """Has :meth:`fit` the refitted variant (``refit=True``)?"""
        return self.basis is not None

    @property
    def holds(self):
        """Has :meth:`fit` the held drive's variant (``held=True``, :class:`HeldDrive`)?"""
        return self.held is not None

    def __deepcopy__(self, memo):
        # the drive's columns and the refitted search's memo are shared (read-only; the stages copy
        # an effect per search variant), the rest copied as before
        new = copy.copy(self)
        for k, v in self.__dict__.items():
            if k not in ("basis", "held", "_refit_memo", "_fold_memo"):
                new.__dict__[k] = copy.deepcopy(v, memo)
        return new

    @staticmethod
    def _filtered(b, a, Z):
        """``(H - 1)`` of each column of ``Z`` (``(n, m)``), each started at rest at its first value."""
        V = np.ascontiguousarray((Z - Z[:1]).T)
        return (signal.lfilter(b, a, V, axis=-1) - V).T

    def _fit_refit(self, t, y, y_model, mask):
        """The refitted mode's search: cost(f, zeta) = least squares of the record ``y`` on the trial
        mode's ``H(Z)``, ``Z = [basis, y_model]``, on the mask's rows.

        The search runs on the record taken every ``s``-th sample (at most
        :data:`REFIT_SEARCH_SAMPLES`; the first-order hold at ``s dt``, the mask's rows where any of the
        ``s`` samples is one; trials up to a tenth of that rate when ``s > 1``, to the record's own
        ceiling otherwise): a log grid of frequencies x dampings, then a bounded refinement from the
        best two. Each trial's least squares by a QR of its unit-RMS columns (the normal equations
        square the columns' ~1e4 condition, and the cost's valley lies ~1e-8 below its level at a 1e-9 m
        floor under a 1e-5 m motion: they moved the found mode 39.8 -> 40.8 Hz on 78 #148). Returns ``(f_hz, zeta, column)``, the
        column ``(H - 1) m`` at the full rate of the model ``m = Z c`` as the search refitted it."""
        dt = _dt(t)
        Z = column_stack([self.basis, np.asarray(y_model, float)])
        n = Z.shape[0]
        s = max(1, int(np.ceil(n / REFIT_SEARCH_SAMPLES)))
        m_s = np.add.reduceat(np.asarray(mask, bool).astype(np.int64), np.arange(0, n, s)) > 0
        rows = np.flatnonzero(m_s)
        ZT = np.ascontiguousarray(Z[::s].T)                      # (m, n_s): each column a row
        nrm = np.sqrt(np.mean(ZT[:, rows] ** 2, axis=1))
        inv = 1.0 / np.where(nrm > 0, nrm, 1.0)
        z0 = ZT[:, :1]
        V = ZT - z0
        y_r = y[::s][rows]
        y_sc = float(np.sqrt(np.mean(y_r * y_r))) or 1.0
        y_r = y_r / y_sc
        lf_lo, lf_hi = self._range(t)
        if s > 1:
            lf_hi = min(lf_hi, np.log(0.1 / (s * dt)))
        lz_lo, lz_hi = np.log(self.zeta_min), np.log(self.zeta_max)
        zeta = self._ring_cap(t)
        if not lf_hi > lf_lo or rows.size < 4 * Z.shape[1]:
            raise ValueError("record too short for the refitted mode's search")

        def weights(th):
            f = float(np.exp(th[0]))
            b, a = _foh_mode(f, zeta(f, float(np.exp(th[1]))), s * dt)
            # ``(lfilter(b, a, V, axis=-1) + z0)[:, rows] * inv[:, None]`` in one compiled pass, to the last bit
            XT = filtered_rows_scaled(V, b, a, z0, inv, rows)
            return XT, _gelsy(XT.T, y_r, 1e-10)

        # every trial's weights, and the two starting grid points' residuals, kept by the trial's bytes: the
        # refinement's first evaluation is its start's grid point and the model below is the answer's,
        # both evaluated already (the same function of the same floats: the same numbers)
        coef, start_res = {}, {}

        def res(th):
            key = np.asarray(th, float).tobytes()
            if _REFIT_REUSE and key in start_res:
                return start_res[key].copy()
            XT, c = weights(th)
            coef[key] = c
            return y_r - c @ XT
        grid = [[lf, lz] for lf in np.linspace(lf_lo, lf_hi, self.n_freq) for lz in np.linspace(lz_lo, lz_hi, 3)]
        grid_res = [res(g) for g in grid]
        costs = [float(np.sum(r ** 2)) for r in grid_res]
        start_res.update((np.asarray(grid[int(k)], float).tobytes(), grid_res[int(k)]) for k in np.argsort(costs)[:2])
        del grid_res
        lo, hi = np.array([lf_lo, lz_lo]), np.array([lf_hi, lz_hi])
        theta, best = np.asarray(grid[int(np.argmin(costs))], float), min(costs)
        for k in np.argsort(costs)[:2]:
            x0 = np.clip(np.asarray(grid[int(k)], float), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
            sol = least_squares(res, x0, bounds=(lo, hi), x_scale="jac", max_nfev=30)
            if 2 * sol.cost < best:
                theta, best = sol.x, 2 * sol.cost
        f = float(np.exp(theta[0]))
        z = float(zeta(f, float(np.exp(theta[1]))))
        # the model as the search refitted it (its weights on the search's samples), its mode's column at
        # the full rate (one column filtered: the ~26 at 355,000 rows cost 0.8 s)
        c = coef.get(np.asarray(theta, float).tobytes()) if _REFIT_REUSE else None
        m = Z @ ((weights(theta)[1] if c is None else c) * inv * y_sc)
        b, a = _foh_mode(f, z, dt)
        return f, z, self._filtered(b, a, m[:, None])[:, 0]

    def fold_columns(self, t, y, y_model, params, rows_list, lower):
        """The refitted mode's column with the drive model's weights fitted on each of ``rows_list``.

        As :meth:`Delay.fold_columns`: per row set, ``m = y_model + basis delta`` with ``delta`` fitted
        to ``y - H(y_model)`` on ``H(basis)`` at those rows, bounded like the base's own corrections
        (``delta >= lower``); the column is ``(H - 1) m``. ``params``: :meth:`fit`'s (``f_n_hz``,
        ``zeta``)."""
        ym = np.asarray(y_model, float)
        if self.basis is None or self.basis.shape[0] != ym.size:
            col = self._column(ym, params["f_n_hz"], params["zeta"], _dt(t))
            return [col for _ in rows_list]
        y = np.asarray(y, float)
        lower = np.asarray(lower, float)
        # the same construction asked twice (the variant's selection, then its scoring: issue 13 review
        # finding 1) is built once: the last answer kept, keyed by everything it reads
        memo = self.__dict__.setdefault("_fold_memo", {})
        key = (float(params["f_n_hz"]), float(params["zeta"]), _dt(t),
               _data_key(y, ym, lower, *[np.asarray(r) for r in rows_list]))
        if memo.get("key") == key:
            return list(memo["out"])
        b, a = _foh_mode(params["f_n_hz"], params["zeta"], _dt(t))
        # each row set's normal equations from the groups of rows the sets share (one pass), the filtered
        # columns H(basis), H(y_model) built at the sets' rows only (:func:`mode_column_rows`, the values
        # of ``_filtered``'s lfilter to the last bit, without its full-length temporaries)
        union, groups = _row_groups(rows_list, ym.size)
        at, pos = (union, None) if union.size < 2 or bool(np.all(np.diff(union) > 0)) \
            else np.unique(union, return_inverse=True)
        HB = np.empty((at.size, self.basis.shape[1]), order="F")     # (a column written at a time)
        for j in range(self.basis.shape[1]):
            HB[:, j] = mode_column_rows(self.basis[:, j], b, a, at)
        HB += self.basis[at]
        r = y[at] - (ym[at] + mode_column_rows(ym, b, a, at))
        if pos is not None:
            HB, r = HB[pos], r[pos]
        out = []
        for G, h, m_rows in _row_set_normals(HB, r, groups, len(rows_list)):
            delta = _bounded_delta(G, h, m_rows, lower)
            m = ym + self.basis @ delta
            out.append(self._filtered(b, a, m[:, None])[:, 0])
        memo.clear()
        memo.update(key=key, out=list(out))
        return out

    @staticmethod
    def _column(u, f_hz, zeta, dt):
        b, a = _foh_mode(f_hz, zeta, dt)
        v = u - u[0]
        return signal.lfilter(b, a, v) - v

    def _range(self, t):
        dt = _dt(t)
        # a mode rings at least RING_CYCLES_PER_RECORD cycles over the record, lightly damped below
        # SLOW_CYCLES_PER_RECORD (:meth:`_ring_cap`; the floor was ten cycles, before that twenty: 50 Hz on
        # a 0.4 s record, above the 27-50 Hz modes of a heavily loaded stack, then unseen)
        f_lo = self.f_min_hz if self.f_min_hz is not None else max(1.0, RING_CYCLES_PER_RECORD / (t[-1] - t[0]))
        return np.log(f_lo), np.log(self.f_max_fraction / dt)

    def _ring_cap(self, t):
        """``zeta(f, z)``: the damping a trial ``(f, z)`` takes, at most RING_ZETA_MAX below
        SLOW_CYCLES_PER_RECORD cycles over the record (a slower mode must ring, not relax), and at most
        ``f_N / f - 1`` near the Nyquist frequency ``f_N`` (not below ``zeta_min``): the mode's half-power
        band, ``f (1 +/- zeta)``, lies below ``f_N``, where the record can show its peak. A heavily damped
        trial at ``f_N`` has no peak in the record, only its low-frequency phase, a sub-sample delay's
        (seed 26 #31: a 0.14 ms delay after creep at 1 kHz, one fold taken by a 500 Hz, zeta 0.3 trial)."""
        f_slow = SLOW_CYCLES_PER_RECORD / (t[-1] - t[0])
        f_nyq = 0.5 / _dt(t)
        cap = max(RING_ZETA_MAX, self.zeta_min)

        def zeta(f, z):
            z = min(z, max(f_nyq / f - 1.0, self.zeta_min))
            return min(z, cap) if f < f_slow else z
        return zeta

    def _spectral_peaks(self, e, fs, lf_lo, lf_hi, floor_hz=PEAK_FLOOR_HZ):
        """The residual spectrum's peaks (Hz) about which :meth:`fit` lays its fine grid.

        Peaks of a Welch estimate of ``e`` (the search rows' residual, rate ``fs`` in Hz) with
        :data:`PEAK_SEGMENT`-sample segments above :data:`PEAK_FLOOR_HZ` (and the search's floor
        ``exp(lf_lo)``), up to ``exp(lf_hi)``, ranked by prominence over a running median of 31 bins: two by
        power (a broad, damped mode), then two more by prominence (a sharp, weak one), each more than 0.1 in
        log f from those taken.

        Where that segment's bin, ``fs / PEAK_SEGMENT``, is wider than the fine grid's half-width
        ``expm1(FINE_HALF_LOG) f`` (below the cutoff ``f_c = fs / (PEAK_SEGMENT expm1(FINE_HALF_LOG))``:
        ~190 Hz at 100 kHz, ~960 Hz at the 500 kHz search rows of a 1 MHz record, 19 Hz at 10 kHz, under the
        floor) a mode there has no peak of its own (244 Hz bins at 1 MHz above the benchmark's 27-110 Hz
        modes: 106 #159's 34 Hz mode was searched from a factor of two away and ended at the damping cap).
        There, and only there, the peaks of a longer segment are **added**: the segment that resolves the
        fine grid's half-width at the floor, at most every row (one periodogram at the benchmark's lengths),
        by the same rule (two by power, two more by prominence), the running median's width the coarse
        grid's step in log f (its bins are not the short segment's). Above ``f_c`` the averaged short segments
        alone seed the grid: a single long periodogram loses a weak mode there to noise peaks (session 27's
        review: seed 20 #88's 1129 Hz mode at 100 kHz).

        Parameters
        ----------
        e : ndarray
            The residual on the search rows (channel units).
        fs : float
            The rows' sampling rate (Hz).
        lf_lo, lf_hi : float
            The search's band, ``log`` of Hz.

        Returns
        -------
        peaks, added : list of float
            The short segment's peaks and the long segment's added ones (Hz; ``added`` empty where the
            short segment resolves the fine grid at the floor).
        """
        from scipy.ndimage import median_filter
        e = np.asarray(e, float) - float(np.mean(e))
        f_pk = max(np.exp(lf_lo), floor_hz)
        nseg = min(PEAK_SEGMENT, e.size)
        f_psd, pxx = signal.welch(e, fs=fs, nperseg=nseg)
        band = (f_psd >= f_pk) & (f_psd <= np.exp(lf_hi))
        peaks = []

        def take(f_b, order, quota):
            for k in order:
                if len(peaks) >= quota:
                    break
                if all(abs(np.log(f_b[k] / q)) > 0.1 for q in peaks):
                    peaks.append(float(f_b[k]))
        if band.sum() > 31:
            p_b, f_b = pxx[band], f_psd[band]
            prominence = p_b / (median_filter(p_b, size=31, mode="nearest") + 1e-300)
            take(f_b, np.argsort(p_b)[::-1], 2)
            take(f_b, np.argsort(prominence)[::-1], 4)
        # below the cutoff: a longer segment's peaks added (none where the short segment resolves the
        # fine grid at the floor, 10 kHz and below, or where it already takes every row)
        f_c = min(fs / (nseg * np.expm1(FINE_HALF_LOG)), np.exp(lf_hi))
        if f_c <= f_pk or e.size <= nseg:
            return peaks, []
        need = fs / (np.expm1(FINE_HALF_LOG) * f_pk)
        nlong = int(min(2 ** int(np.ceil(np.log2(need))), e.size))
        f_l, p_l = signal.welch(e, fs=fs, nperseg=nlong)
        low = (f_l >= f_pk) & (f_l < f_c)
        if low.sum() < 3:
            return peaks, []
        p_b, f_b = p_l[low], f_l[low]
        lf_b = np.log(f_b)
        half = 0.5 * (lf_hi - lf_lo) / max(self.n_freq // 2 - 1, 1)
        lo_i = np.searchsorted(lf_b, lf_b - half, side="left")
        hi_i = np.searchsorted(lf_b, lf_b + half, side="right")
        med = np.array([np.median(p_b[i:j]) for i, j in zip(lo_i, hi_i)])
        prominence = p_b / (med + 1e-300)
        n0 = len(peaks)
        take(f_b, np.argsort(p_b)[::-1], n0 + 2)
        take(f_b, np.argsort(prominence)[::-1], n0 + 4)
        return peaks[:n0], peaks[n0:]

    def fit(self, t, u, residual, train_mask, y_model=None, project=None, refit=False, held=False):
        dt = _dt(t)
        u = np.asarray(u, float)
        if held:
            return self._fit_held(t, u, residual, train_mask, project)
        if refit:
            # the mode on the drive model refitted per trial (see the class notes): searched once per data
            ym = np.asarray(y_model, float) if y_model is not None else None
            if self.basis is None or ym is None or self.basis.shape[0] != ym.size:
                raise ValueError("the refitted mode needs the drive model's basis and y_model")
            mask = np.asarray(train_mask, bool)
            e = np.asarray(residual, float)
            key = _data_key(e, ym, mask)
            memo = self._refit_memo
            if memo.get("key") != key:
                f, z, col = self._fit_refit(t, e + ym, ym, mask)
                memo.clear()
                memo.update(key=key, f=f, z=z, col=col)
            self._models[(memo["f"], memo["z"], _data_key(ym))] = memo["col"]
            return {"gain": 1.0, "f_n_hz": memo["f"], "zeta": memo["z"], "refit": True}
        lf_lo, lf_hi = self._range(t)
        lz_lo, lz_hi = np.log(self.zeta_min), np.log(self.zeta_max)
        zeta = self._ring_cap(t)
        # a coarse log grid plus a fine one about the residual spectrum's strongest peak: a light
        # mode's cost valley is narrower than any affordable global grid
        rows = np.flatnonzero(np.asarray(train_mask, bool))
        e_fit = np.asarray(residual, float)[rows]
        # the training rows may be thinned (every k-th row): the spectrum's rate is the rows' own
        step = float(np.median(np.diff(rows))) if rows.size > 1 else 1.0
        lfs = list(np.linspace(lf_lo, lf_hi, self.n_freq // 2))
        peaks, added = self._spectral_peaks(e_fit, 1.0 / (dt * step), lf_lo, lf_hi)
        lfs = np.clip(lfs, lf_lo, lf_hi)

        def fine(pks):
            return [[lf, lz] for f_peak in pks for lf in np.log(f_peak) + np.linspace(-FINE_HALF_LOG, FINE_HALF_LOG, 11)
                    for lz in np.linspace(lz_lo, lz_hi, 7) if lf_lo <= lf <= lf_hi]
        grid = [[lf, lz] for lf in lfs for lz in np.linspace(lz_lo, lz_hi, 6)] + fine(peaks)
        # a slow trial's damping capped (:meth:`_ring_cap`): the grid's capped points once each; the long
        # segment's peaks' points after the others, their own start (_varpro's added_from)
        seen, capped = set(), []
        for part in (grid, fine(added)):
            n_before = len(capped)
            for lf, lz in part:
                g = (float(lf), float(np.log(zeta(np.exp(lf), np.exp(lz)))))
                if g not in seen:
                    seen.add(g)
                    capped.append(list(g))
        added_from = n_before if len(capped) > n_before else None
        grid = capped

        def mode(th):
            f = float(np.exp(th[0]))
            return _foh_mode(f, zeta(f, float(np.exp(th[1]))), dt)
        # the searches with and without the base's projection (tracing runs both on the same
        # data) share the grid's columns: see _varpro's plain_costs
        memo = self.__dict__.setdefault("_grid_costs", {})
        key = _data_key(u, residual, train_mask, np.array([dt]))
        if memo.get("key") != key:
            memo.clear()
            memo["key"] = key
        theta, beta = _varpro(lambda th: self._column(u, np.exp(th[0]), zeta(np.exp(th[0]), np.exp(th[1])), dt),
                              np.asarray(residual, float), np.asarray(train_mask, bool),
                              grid, [lf_lo, lz_lo], [lf_hi, lz_hi], project, starts=3,
                              row_columns=lambda th, rows: mode_column_rows(u, *mode(th), rows),
                              plain_costs=memo, added_from=added_from,
                              row_columns_many=lambda ths, rows: mode_columns_rows(
                                  u, [mode(th) for th in ths], rows))
        f = float(np.exp(theta[0]))
        return {"gain": float(beta[0]), "f_n_hz": f, "zeta": float(zeta(f, float(np.exp(theta[1]))))}

    def _held_ceiling(self, t):
        """The held variant's highest trial frequency (Hz): the settle's corner ``1 / (2 pi RC)`` (343 Hz on the
        P-888.51's 80 ohm and ~6 uF), above which the settle's edge is slower than the mode and the ring it
        excites falls as ``1 / (w RC)``; at least the Nyquist frequency."""
        return max(self.f_max_fraction / _dt(t), 1.0 / (2.0 * np.pi * self.held.rc))

    def _fit_held(self, t, u, residual, train_mask, project):
        """The mode driven through the held drive's path (:class:`HeldDrive`, :func:`held_mode_column`).

        Its trials run from the search's floor (:meth:`_range`) past the Nyquist frequency to
        :meth:`_held_ceiling`, their damping at most RING_ZETA_MAX (a mode this variant reads rings: a heavier
        one is the phase a delay reads, :func:`~.tracing._phase_only_mode`): a coarse log grid, and a fine one
        about every image ``k fs +- f_p`` of the residual spectrum's peaks ``f_p`` (:meth:`_spectral_peaks`, down
        to the search's floor; a mode above Nyquist rings at its alias in the samples), then :func:`_varpro`'s
        refinement."""
        if self.held is None or self.held.t_ramp.size != np.asarray(u).size:
            raise ValueError("the held drive's mode needs the record's held drive")
        dt = _dt(t)
        fs = 1.0 / dt
        lf_lo = self._range(t)[0]
        lf_hi = np.log(self._held_ceiling(t))
        z_hi = max(min(self.zeta_max, RING_ZETA_MAX), self.zeta_min)
        lz_lo, lz_hi = np.log(self.zeta_min), np.log(z_hi)
        rows = np.flatnonzero(np.asarray(train_mask, bool))
        step = float(np.median(np.diff(rows))) if rows.size > 1 else 1.0
        # (every alias, down to the search's floor: a mode just above a multiple of the rate rings at a few Hz in
        # the samples, under PEAK_FLOOR_HZ, 109 #126's 92.9 Hz at 7.1 Hz)
        peaks, _ = self._spectral_peaks(np.asarray(residual, float)[rows], fs / step, lf_lo,
                                        min(self._range(t)[1], lf_hi), floor_hz=0.0)
        grid = [[lf, lz] for lf in np.linspace(lf_lo, lf_hi, self.n_freq) for lz in np.linspace(lz_lo, lz_hi, 4)]
        f_hi = float(np.exp(lf_hi))
        # (each image's points span the alias's fine grid in Hz: a mode above Nyquist rings at its alias)
        for f_p in peaks:
            offs = f_p * np.exp(np.linspace(-FINE_HALF_LOG, FINE_HALF_LOG, 5))
            for k in range(int(f_hi // fs) + 2):
                for f in np.r_[k * fs - offs, k * fs + offs]:
                    if np.exp(lf_lo) <= f <= f_hi:
                        grid += [[np.log(f), lz] for lz in np.linspace(lz_lo, lz_hi, 3)]

        def col(th):
            return held_mode_column(u, self.held, np.exp(th[0]), np.exp(th[1]))
        theta, beta = _varpro(col, np.asarray(residual, float), np.asarray(train_mask, bool), grid,
                              [lf_lo, lz_lo], [lf_hi, lz_hi], project, starts=3)
        if theta[1] >= lz_hi - 1e-9:
            # the fit ran to its damping cap: no ring (a mode this variant reads rings within RING_ZETA_MAX), the
            # lag of the drive's phase at its harmonics read by the most damped trial, a sub-sample delay's reading
            # (107 #127 at 100 Hz steps: a 0.28 ms displacement latency, 0.028 samples, fitted 301.9 Hz at zeta
            # 0.159 and named a mode on 2 of 5 folds). Not this variant's answer (as _phase_only_mode, beside a delay)
            raise ValueError("the held mode's fit runs to its damping cap: a phase, not a ring")
        return {"gain": float(beta[0]), "f_n_hz": float(np.exp(theta[0])), "zeta": float(np.exp(theta[1])),
                "held": True}

    def _refit_column(self, params, y_model):
        """The refitted model's column :meth:`fit` found for ``y_model`` (None for another model)."""
        if not params.get("refit") or y_model is None or not self._models:
            return None
        return self._models.get((params["f_n_hz"], params["zeta"], _data_key(np.asarray(y_model, float))))

    def _held_only(self, params):
        """A held drive's mode (``params["held"]``) is a column of that path alone: without it, an error (the
        first-order hold's column is another model, and was once returned in its place without a word)."""
        if params.get("held") and self.held is None:
            raise ValueError("a held drive's mode needs the record's held drive (HeldDrive); this Resonance has none")

    def term(self, t, u, params, y_model=None):
        self._held_only(params)
        if params.get("held"):
            return params["gain"] * held_mode_column(u, self.held, params["f_n_hz"], params["zeta"])
        col = self._refit_column(params, y_model)
        if col is not None:
            return params["gain"] * col
        return params["gain"] * self._column(np.asarray(u, float), params["f_n_hz"],
                                             params["zeta"], _dt(t))

    def columns(self, t, u, params, y_model=None):
        # the refitted model's column where fitted to this y_model (its gain ~1, >= 0: the mode's
        # sign is in the column); a model it was not fitted to (a channel the found mode is carried
        # to) takes the mode on its own prediction
        self._held_only(params)
        if params.get("held"):
            return held_mode_column(u, self.held, params["f_n_hz"], params["zeta"]), [-np.inf]
        col = self._refit_column(params, y_model)
        if col is not None:
            return col, [0.0]
        return self._column(np.asarray(u, float), params["f_n_hz"], params["zeta"], _dt(t)), [-np.inf]

    def with_gains(self, params, gains):
        return {**params, "gain": float(gains[0])}


def default_effects():
    """One instance of every implemented effect, default settings."""
    return [Drift(), Delay(), Creep(), DielectricAbsorption(), Leakage(), Resonance()]


def _errors(e):
    return {"rms": rms(e), "max": float(np.max(np.abs(e))) if e.size else float("nan")}


def choose_effect(t, u, y_meas, y_model, channel=None, effects=None, train_mask=None,
                  noise_rms=None, penalty=0.02, improvement=0.05, report=None,
                  signatures=False):
    """Pick the effect that best explains the residual ``y_meas - y_model`` of one channel.

    Every effect that applies to ``channel`` (all of :func:`default_effects` when ``effects``
    is None) is fitted on the rows where ``train_mask`` is True and scored on the others
    (held out) by ``score = rms_after (1 + penalty n_params)``. The answer is ``"none"`` when

    * the residual is white and independent of the input (:func:`analyze_residual`) and, when
      ``noise_rms`` is given, its RMS is within 1.2 ``noise_rms``; or
    * the best score does not beat the held-out RMS before by more than ``improvement``
      (5 %): ``score > (1 - improvement) rms_before``.

    ``train_mask`` defaults to the first 70 % of the samples. Returns a dict with ``effect``
    (name or ``"none"``), ``error_before`` and ``error_after`` (``{rms, max}`` on the held-out
    rows; equal for ``"none"``), ``parameters`` (of the chosen effect, ``{}`` for ``"none"``),
    ``candidates`` (``{name, score, error_after, signature}`` per effect, best first),
    ``report`` (the :class:`ResidualReport`) and ``reason``. ``signature`` is each effect's
    :meth:`Effect.signature` when ``signatures`` is True (it refits on the whole record, so it
    doubles the cost), else None. A ``report`` from :func:`analyze_residual` may be passed to
    avoid recomputing it.
    """
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    y = np.asarray(y_meas, float)
    yhat = np.asarray(y_model, float)
    if not (t.shape == u.shape == y.shape == yhat.shape) or t.ndim != 1:
        raise ValueError("t, u, y_meas and y_model must be 1-D arrays of one length")
    n = t.size
    if train_mask is None:
        train_mask = np.arange(n) < int(0.7 * n)
    train = np.asarray(train_mask, bool)
    if train.shape != t.shape or not train.any() or train.all():
        raise ValueError("train_mask must be a boolean array of the record's length with both "
                         "training (True) and held-out (False) rows")
    test = ~train
    e = y - yhat
    if report is None:
        report = analyze_residual(t, u, y, yhat)
    before = _errors(e[test])
    effects = default_effects() if effects is None else list(effects)
    candidates, fitted = [], {}
    for eff in effects:
        if not eff.applies_to(channel):
            continue
        try:
            p = eff.fit(t, u, e, train, y_model=yhat)
            after = _errors((e - eff.term(t, u, p, y_model=yhat))[test])
        except ValueError:
            continue
        sig = eff.signature(report, t, u, e, y_model=yhat) if signatures else None
        candidates.append({"name": eff.name, "score": after["rms"] * (1 + penalty * eff.n_params),
                           "error_after": after, "signature": sig})
        fitted[eff.name] = (eff, p, after)
    candidates.sort(key=lambda c: c["score"])
    out = {"effect": "none", "error_before": before, "error_after": before, "parameters": {},
           "candidates": candidates, "report": report}
    noise_ok = noise_rms is None or report.rms <= 1.2 * float(noise_rms)
    if report.white and report.independent and noise_ok:
        out["reason"] = "residual white and independent of the input" + (
            "" if noise_rms is None else ", RMS within 1.2 x noise_rms")
        return out
    if not candidates or candidates[0]["score"] > (1 - improvement) * before["rms"]:
        out["reason"] = "no candidate reduces the held-out RMS enough"
        return out
    best = candidates[0]
    eff, p, after = fitted[best["name"]]
    out.update(effect=best["name"], error_after=after, parameters=p,
               reason="lowest penalized held-out RMS")
    return out
