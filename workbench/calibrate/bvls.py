"""Bounded least squares on the calibration's small square-root systems, compiled (numba).

The calibration's Gram solves (``base_fit._gram_solve``, ``tracing._Problem.solve``) each minimize
``w'G w - 2 h'w`` over ``w >= lower`` for a Gram matrix of tens of columns, thousands of times a record:
``scipy.optimize.lsq_linear(R, c, bounds, method="bvls", tol=1e-12)`` on the square root ``R'R = G``
spent nearly all its time in the interpreter (a cProfile of one creep test: 8.2 s of 21.4 s of tracing
in 5,664 calls, ~28,500 ``numpy.linalg.lstsq`` calls). :func:`bvls` is the same algorithm compiled:
``lsq_linear``'s first step (the unconstrained ``lstsq`` solution, ``rcond=-1``, returned as is when it
lies within the bounds) and then scipy's BVLS (Stark and Parker 1995), its initialization loop, its
loops A and B, its tie-breaks (the first maximum, the first minimum), its ``rcond=None`` inner solves and
its termination (KKT optimality below ``tol``, or a relative cost change below ``tol``, or ``n``
iterations after the initialization), so the iterates are the reference's. Ported from SciPy's
``scipy/optimize/_lsq/bvls.py`` and ``lsq_linear.py`` (SciPy 1.17, BSD-3-Clause license, copyright
2001-2002 Enthought, Inc. and 2003-2024 SciPy Developers).

The LAPACK (``gelsd``) and BLAS routines are those numba binds (SciPy's build) rather than numpy's: on the
machines measured the results equal ``lsq_linear``'s to the bit, but nothing guarantees it, and they can
differ in the last bits (``tests/calibrate/test_bvls.py`` states the
agreement as bounds on the objective, the fitted values and, for well-conditioned problems, ``x``).
"""

import numpy as np
from numba import njit

__all__ = ["bvls"]


@njit(cache=True)
def _kkt_optimality(g, on_bound):
    out = 0.0
    for i in range(g.size):
        v = abs(g[i]) if on_bound[i] == 0.0 else g[i] * on_bound[i]
        if i == 0 or v > out:
            out = v
    return out


@njit(cache=True)
def _free_solve(A, b, x, free_set, active):
    """``lstsq(A[:, free], b - A (x * active), rcond=None)``: numpy's default cutoff ``eps max(m, n)``."""
    xa = x * active
    b_free = b - np.dot(A, xa)
    if free_set.size == 0:
        return np.empty(0)
    A_free = A[:, free_set]
    rcond = np.finfo(np.float64).eps * max(A.shape[0], free_set.size)
    return np.linalg.lstsq(A_free, b_free, rcond)[0]


@njit(cache=True, error_model="numpy")      # a step's 0 / 0 is NaN as in numpy, not a ZeroDivisionError
def _bvls(A, b, lb, ub, tol):
    m, n = A.shape
    # lsq_linear's first step: the unconstrained solution (rcond=-1: LAPACK's machine-precision cutoff)
    x_lsq = np.linalg.lstsq(A, b, -1.0)[0]
    inside = True
    for i in range(n):
        if not (x_lsq[i] >= lb[i] and x_lsq[i] <= ub[i]):
            inside = False
    if inside:
        return x_lsq, 3, 0

    x = x_lsq.copy()
    on_bound = np.zeros(n)
    for i in range(n):
        if x[i] <= lb[i]:
            x[i] = lb[i]
            on_bound[i] = -1.0
    for i in range(n):
        if x[i] >= ub[i]:
            x[i] = ub[i]
            on_bound[i] = 1.0
    active = np.zeros(n)
    for i in range(n):
        if on_bound[i] != 0.0:
            active[i] = 1.0
    free_set = np.nonzero(on_bound == 0.0)[0]

    r = np.dot(A, x) - b
    cost = 0.5 * np.dot(r, r)
    g = np.dot(A.T, r)
    iteration = 0

    # initialization loop: the least-squares solution on the free variables, violators to their bounds
    while free_set.size > 0:
        iteration += 1
        z = _free_solve(A, b, x, free_set, active)
        nf = free_set.size
        viol = np.zeros(nf, np.bool_)
        for j in range(nf):
            i = free_set[j]
            if z[j] < lb[i]:
                viol[j] = True
                x[i] = lb[i]
                active[i] = 1.0
                on_bound[i] = -1.0
        for j in range(nf):
            i = free_set[j]
            if z[j] > ub[i]:
                viol[j] = True
                x[i] = ub[i]
                active[i] = 1.0
                on_bound[i] = 1.0
        for j in range(nf):
            if not viol[j]:
                x[free_set[j]] = z[j]
        r = np.dot(A, x) - b
        cost = 0.5 * np.dot(r, r)
        g = np.dot(A.T, r)
        if viol.any():
            free_set = free_set[~viol]
        else:
            break

    max_iter = n + iteration
    status = -1
    optimality = _kkt_optimality(g, on_bound)
    it = iteration
    while it < max_iter:                       # loop A
        if optimality < tol:
            status = 1
        if status != -1:
            break
        move_to_free = np.argmax(g * on_bound)
        on_bound[move_to_free] = 0.0

        while True:                            # loop B
            free_set = np.nonzero(on_bound == 0.0)[0]
            for i in range(n):
                active[i] = 0.0 if on_bound[i] == 0.0 else 1.0
            nf = free_set.size
            x_free = np.empty(nf)
            for j in range(nf):
                x_free[j] = x[free_set[j]]
            z = _free_solve(A, b, x, free_set, active)
            # violators, those below their lower bound first (scipy's hstack((lbv, ubv)))
            nv = 0
            v = np.empty(2 * nf, np.int64)
            for j in range(nf):
                if z[j] < lb[free_set[j]]:
                    v[nv] = j
                    nv += 1
            n_low = nv
            for j in range(nf):
                if z[j] > ub[free_set[j]]:
                    v[nv] = j
                    nv += 1
            if nv > 0:
                alphas = np.empty(nv)
                for q in range(nv):
                    j = v[q]
                    bound = lb[free_set[j]] if q < n_low else ub[free_set[j]]
                    alphas[q] = (bound - x_free[j]) / (z[j] - x_free[j])
                q = np.argmin(alphas)
                alpha = alphas[q]
                for j in range(nf):
                    xf = x_free[j] * (1 - alpha)
                    xf += alpha * z[j]
                    x[free_set[j]] = xf
                on_bound[free_set[v[q]]] = -1.0 if q < n_low else 1.0
            else:
                for j in range(nf):
                    x[free_set[j]] = z[j]
                break

        r = np.dot(A, x) - b
        cost_new = 0.5 * np.dot(r, r)
        cost_change = cost - cost_new
        if cost_change < tol * cost:
            status = 2
        cost = cost_new
        g = np.dot(A.T, r)
        optimality = _kkt_optimality(g, on_bound)
        it += 1

    if status == -1:
        status = 0
    return x, status, it


def bvls(R, c, lower, upper=None, tol=1e-12):
    """``scipy.optimize.lsq_linear(R, c, bounds=(lower, upper), method="bvls", tol=tol).x``, compiled.

    Parameters
    ----------
    R : (m, n) array_like
        The system's matrix (here the square root of a Gram matrix, ``R'R = G``; dimensionless or in the
        scaled units of the caller's columns).
    c : (m,) array_like
        Its right-hand side (``R'c = h``).
    lower, upper : (n,) array_like
        Bounds on ``x``, ``-inf``/``inf`` for none (``upper`` None: no upper bounds); ``lower < upper``.
    tol : float
        lsq_linear's ``tol``: the KKT optimality and relative cost change at which BVLS stops.

    Returns
    -------
    (n,) ndarray
        The minimizer of ``||R x - c||`` over the box, by the same iterations as scipy's BVLS. Non-finite
        ``R`` or ``c`` go to scipy itself (its own error or answer).
    """
    R = np.asarray(R, float)
    c = np.asarray(c, float)
    lower = np.asarray(lower, float)
    upper = np.full(lower.size, np.inf) if upper is None else np.asarray(upper, float)
    shapes = R.ndim == 2 and c.shape == R.shape[:1] and lower.shape == upper.shape == R.shape[1:]
    if not shapes or R.size == 0 or not (np.all(np.isfinite(R)) and np.all(np.isfinite(c))) \
            or np.any(lower >= upper) or np.isnan(lower).any() or np.isnan(upper).any():
        from scipy.optimize import lsq_linear
        return lsq_linear(R, c, bounds=(lower, upper), method="bvls", tol=tol).x
    # R keeps its layout (C or F: two compilations): numpy's and numba's products with it then make the
    # same BLAS call (gemv, transposed or not), and round alike
    order = "F" if R.flags.f_contiguous and not R.flags.c_contiguous else "C"
    return _bvls(_writable(R, order), _writable(c), _writable(lower), _writable(upper), float(tol))[0]


def _writable(a, order="C"):
    # a writable float64 copy: numba's ``np.dot`` on read-only arrays (``_kernel_args.readonly``, the other
    # kernels' convention) does not make the BLAS call numpy makes, and its products then differ from
    # numpy's in the last bits (measured, numba 0.68)
    return np.array(a, dtype=np.float64, order=order, copy=True)
