"""Compiled inner loops of the calibration's searches (numba), equal to their numpy/scipy forms.

The nonlinear searches of :mod:`.effects` evaluate one column per grid point over the whole
record (a filter needs its memory from the start) and then keep only the search rows. These
kernels run the same recursion and write only the rows asked for, skipping the full-length
temporaries and the boolean gather. The arithmetic is the one of ``scipy.signal.lfilter``'s
direct form II transposed (``y = z_0 + b_0 x``, ``z_0 = z_1 + b_1 x - a_1 y``,
``z_1 = b_2 x - a_2 y``, in that order, no fused multiply-add), so the values are those of
the reference forms to the last bit on the machines we measured; the tests compare them
bit for bit (``tests/calibrate/test_speed_equivalence.py``). ``rows`` must be strictly increasing
(``numpy.flatnonzero`` of a mask, as every caller passes): other rows leave output unwritten.
The arrays are handed over read-only (:func:`workbench._kernel_args.readonly`), so each kernel compiles
once whether the caller's arrays are writable or not.
"""

import numpy as np
from numba import njit

from .._kernel_args import readonly

__all__ = ["mode_column_rows", "mode_columns_rows", "lowpass_rows", "plays_rows", "filtered_rows_scaled",
           "shifted_rows_into", "held_mode_column_compiled"]


@njit(cache=True)
def _biquad_minus_input(u, b0, b1, b2, a1, a2, rows):
    out = np.empty(rows.size)
    u0 = u[0]
    z0 = 0.0
    z1 = 0.0
    k = 0
    n_rows = rows.size
    last = rows[n_rows - 1] if n_rows else -1
    for i in range(last + 1):
        x = u[i] - u0
        y = z0 + b0 * x
        z0 = z1 + x * b1 - y * a1
        z1 = x * b2 - y * a2
        if k < n_rows and rows[k] == i:
            out[k] = y - x
            k += 1
    return out


def mode_column_rows(u, b, a, rows):
    """``(lfilter(b, a, v) - v)[rows]`` with ``v = u - u[0]``, for a second-order ``b``, ``a``
    (``a[0] = 1``); ``rows`` strictly increasing row indices within ``u`` (int64; anything else
    raises ``ValueError``: the kernel's one pass would return unset values)."""
    b = np.asarray(b, float)
    a = np.asarray(a, float)
    rows = np.asarray(rows, np.int64)
    if rows.size and (rows[0] < 0 or rows[-1] >= np.size(u) or np.any(np.diff(rows) <= 0)):
        raise ValueError("mode_column_rows: rows must be strictly increasing indices within the record")
    return _biquad_minus_input(readonly(u), float(b[0]), float(b[1]), float(b[2]),
                               float(a[1]), float(a[2]), readonly(rows, np.int64))


@njit(cache=True)
def _biquads_minus_input(u, coef, rows):
    # the recursion of _biquad_minus_input for several filters in one pass over the record: the
    # same operations in the same order per filter (bit-equal), but independent filters' steps
    # overlap instead of each waiting for its own previous sample (the loop is latency-bound)
    n_f = coef.shape[0]
    n_rows = rows.size
    out = np.empty((n_f, n_rows))
    b0 = coef[:, 0].copy()
    b1 = coef[:, 1].copy()
    b2 = coef[:, 2].copy()
    a1 = coef[:, 3].copy()
    a2 = coef[:, 4].copy()
    z0 = np.zeros(n_f)
    z1 = np.zeros(n_f)
    u0 = u[0]
    k = 0
    last = rows[n_rows - 1] if n_rows else -1
    for i in range(last + 1):
        x = u[i] - u0
        hit = k < n_rows and rows[k] == i
        for j in range(n_f):
            y = z0[j] + b0[j] * x
            z0[j] = z1[j] + x * b1[j] - y * a1[j]
            z1[j] = x * b2[j] - y * a2[j]
            if hit:
                out[j, k] = y - x
        if hit:
            k += 1
    return out


@njit(cache=True)
def _biquad_pair_minus_input(u, c, d, rows):
    # two filters (coefficients c, d: b0 b1 b2 a1 a2) with their state in registers: the
    # least-squares Jacobian's two columns in the time of about one
    out = np.empty((2, rows.size))
    u0 = u[0]
    p0 = p1 = q0 = q1 = 0.0
    k = 0
    n_rows = rows.size
    last = rows[n_rows - 1] if n_rows else -1
    for i in range(last + 1):
        x = u[i] - u0
        y = p0 + c[0] * x
        p0 = p1 + x * c[1] - y * c[3]
        p1 = x * c[2] - y * c[4]
        w = q0 + d[0] * x
        q0 = q1 + x * d[1] - w * d[3]
        q1 = x * d[2] - w * d[4]
        if k < n_rows and rows[k] == i:
            out[0, k] = y - x
            out[1, k] = w - x
            k += 1
    return out


@njit(cache=True)
def _biquad_triple_minus_input(u, c, d, e, rows):
    # three filters with their state in registers (as the pair): a point's column and its 2-point
    # Jacobian's two in about the time of one (:func:`~workbench.calibrate.effects._varpro`)
    out = np.empty((3, rows.size))
    u0 = u[0]
    p0 = p1 = q0 = q1 = r0 = r1 = 0.0
    k = 0
    n_rows = rows.size
    last = rows[n_rows - 1] if n_rows else -1
    for i in range(last + 1):
        x = u[i] - u0
        y = p0 + c[0] * x
        p0 = p1 + x * c[1] - y * c[3]
        p1 = x * c[2] - y * c[4]
        w = q0 + d[0] * x
        q0 = q1 + x * d[1] - w * d[3]
        q1 = x * d[2] - w * d[4]
        v = r0 + e[0] * x
        r0 = r1 + x * e[1] - v * e[3]
        r1 = x * e[2] - v * e[4]
        if k < n_rows and rows[k] == i:
            out[0, k] = y - x
            out[1, k] = w - x
            out[2, k] = v - x
            k += 1
    return out


def mode_columns_rows(u, filters, rows):
    """:func:`mode_column_rows` for several filters at once: row ``j`` of the ``(len(filters),
    rows.size)`` result is ``mode_column_rows(u, *filters[j], rows)``, equal to the last bit.

    Parameters
    ----------
    u : ndarray
        The drive (any unit), one value per sample.
    filters : sequence of (b, a)
        Second-order sections (``a[0] = 1``), as :func:`~workbench.calibrate.effects._foh_mode` gives.
    rows : ndarray of int
        Sorted row indices.
    """
    coef = np.array([[float(b[0]), float(b[1]), float(b[2]), float(a[1]), float(a[2])] for b, a in filters],
                    dtype=float).reshape(-1, 5)
    u = readonly(u)
    rows = readonly(rows, np.int64)
    if coef.shape[0] == 1:
        return _biquad_minus_input(u, *coef[0], rows)[None, :]
    if coef.shape[0] == 2:
        return _biquad_pair_minus_input(u, coef[0], coef[1], rows)
    if coef.shape[0] == 3:
        return _biquad_triple_minus_input(u, coef[0], coef[1], coef[2], rows)
    return _biquads_minus_input(u, coef, rows)


@njit(cache=True)
def _lowpass(u, a, minus_input, rows):
    out = np.empty(rows.size)
    b0 = 1.0 - a
    na = -a
    z = a * u[0]
    k = 0
    n_rows = rows.size
    last = rows[n_rows - 1] if n_rows else -1
    for i in range(last + 1):
        x = u[i]
        y = z + b0 * x
        z = x * 0.0 - y * na
        if k < n_rows and rows[k] == i:
            out[k] = y - x if minus_input else y
            k += 1
    return out


def lowpass_rows(u, tau, dt, rows, minus_input=False):
    """``lowpass(u, tau, dt)[rows]`` (``- u[rows]`` with ``minus_input``), see :func:`.effects.lowpass`."""
    a = float(np.exp(-dt / tau))
    return _lowpass(readonly(u), a, bool(minus_input), readonly(rows, np.int64))


@njit(cache=True)
def _plays_rows(v, r, z0, rows):
    n_p = r.size
    out = np.empty((rows.size, n_p))
    z = z0.copy()
    k = 0
    n_rows = rows.size
    last = rows[n_rows - 1] if n_rows else -1
    for i in range(last + 1):
        x = v[i]
        for j in range(n_p):
            lo = x - r[j]
            hi = x + r[j]
            if z[j] < lo:
                z[j] = lo
            elif z[j] > hi:
                z[j] = hi
        if k < n_rows and rows[k] == i:
            for j in range(n_p):
                out[k, j] = z[j]
            k += 1
    return out


def plays_rows(v, thresholds, initial_states, rows):
    """``pi_fit.play_matrix(v, thresholds, initial_states)[rows]`` without the full-length matrix.

    Each play's update is ``plant.hysteresis.play_step``'s (clamp to ``[v - r, v + r]``): the same values.
    ``rows`` strictly increasing (``numpy.flatnonzero`` of a mask).
    """
    return _plays_rows(readonly(v), readonly(thresholds), readonly(initial_states), readonly(rows, np.int64))


@njit(cache=True)
def _biquad_rows_scaled(V, z0, inv, b0, b1, b2, a1, a2, rows):
    # each row of V filtered from rest (lfilter's recursion, in its order), at the asked columns
    # ``(y + z0[j]) * inv[j]``; the rows' steps interleaved (independent recursions overlap). Written
    # into the transpose of a C-ordered (rows, filters) array: the reference's Fortran layout (a
    # column gather of a C-ordered array), so later products read it in the same order
    n_f = V.shape[0]
    n_rows = rows.size
    out = np.empty((n_rows, n_f))
    s0 = np.zeros(n_f)
    s1 = np.zeros(n_f)
    k = 0
    last = rows[n_rows - 1] if n_rows else -1
    for i in range(last + 1):
        hit = k < n_rows and rows[k] == i
        for j in range(n_f):
            x = V[j, i]
            y = s0[j] + b0 * x
            s0[j] = s1[j] + x * b1 - y * a1
            s1[j] = x * b2 - y * a2
            if hit:
                out[k, j] = (y + z0[j]) * inv[j]
        if hit:
            k += 1
    return out.T


def filtered_rows_scaled(V, b, a, z0, inv, rows):
    """``((lfilter(b, a, V, axis=-1) + z0[:, None])[:, rows] * inv[:, None]`` for a second-order
    ``b``, ``a`` (``a[0] = 1``), each row of ``V`` filtered from rest, without the full-length
    temporaries: the refitted mode's trial columns (:meth:`.effects.Resonance._fit_refit`). The result
    has the reference's values and its layout (Fortran order: the products of it, e.g. BLAS's
    ``c @ X``, then sum in the same order).

    Parameters
    ----------
    V : ndarray
        ``(m, n)`` signals, one a row (any unit).
    b, a : array_like
        Second-order section, as :func:`~workbench.calibrate.effects._foh_mode` gives.
    z0 : ndarray
        ``(m,)`` offsets added after filtering (the unit of ``V``).
    inv : ndarray
        ``(m,)`` scales applied last (1 / the unit of ``V``).
    rows : ndarray of int
        Strictly increasing column indices within ``V`` (anything else raises ``ValueError``).
    """
    rows = np.asarray(rows, np.int64)
    if rows.size and (rows[0] < 0 or rows[-1] >= np.shape(V)[1] or np.any(np.diff(rows) <= 0)):
        raise ValueError("filtered_rows_scaled: rows must be strictly increasing indices within the signals")
    b = np.asarray(b, float)
    a = np.asarray(a, float)
    return _biquad_rows_scaled(readonly(V), readonly(np.ravel(z0)), readonly(np.ravel(inv)),
                               float(b[0]), float(b[1]), float(b[2]), float(a[1]), float(a[2]),
                               readonly(rows, np.int64))


@njit(cache=True)
def _shifted_into(Z, rows, d, scale, out, col0):
    # Z(t - d dt) at rows, linear interpolation on the uniform grid with the ends held, each value
    # ``(Z[i0] * (1 - f) + Z[i1] * f) * scale[j]`` written to out[:, col0 + j]
    n = Z.shape[0]
    k = Z.shape[1]
    top = n - 1.0
    for r in range(rows.size):
        s = rows[r] - d
        if s < 0.0:
            s = 0.0
        if s > top:
            s = top
        i0 = np.int64(np.floor(s))
        f = s - i0
        g = 1.0 - f
        i1 = min(i0 + 1, n - 1)
        for j in range(k):
            out[r, col0 + j] = (Z[i0, j] * g + Z[i1, j] * f) * scale[col0 + j]


def shifted_rows_into(Z, rows, d, out, col0=0, scale=None):
    """Write ``Z(t - d dt)`` at ``rows`` (``(n, k)`` columns, linear interpolation on the uniform
    grid, ends held: :meth:`.effects.Delay._rows_shifted`'s values to the last bit), times ``scale``
    (one factor a column of ``out``, default 1), into ``out[:, col0:col0 + k]`` in one pass.

    ``Z`` C-ordered float64 and ``out`` a writable C-ordered float64 ``(rows.size, >= col0 + k)``
    array (checked: a copy of a record's columns per call would cost more than it saves); ``rows``
    int64 row indices, any order; ``d`` in samples."""
    if not (isinstance(Z, np.ndarray) and Z.ndim == 2 and Z.dtype == np.float64 and Z.flags.c_contiguous):
        raise ValueError("shifted_rows_into: Z must be a C-ordered float64 (n, k) array")
    if not (out.ndim == 2 and out.dtype == np.float64 and out.flags.c_contiguous and out.flags.writeable
            and out.shape[0] == np.size(rows) and out.shape[1] >= col0 + Z.shape[1]):
        raise ValueError("shifted_rows_into: out must be a writable C-ordered (rows, >= col0 + k) float64 array")
    scale = np.ones(out.shape[1]) if scale is None else scale
    _shifted_into(readonly(Z), readonly(rows, np.int64), float(d), readonly(scale), out, int(col0))
    return out


@njit(cache=True)
def _held_mode(v, t_ramp, slope, q_ramp, left, settled, dt, rc, lam, r):
    out = np.empty(v.size)
    e_dt = np.exp(lam * dt)
    inv_lam = 1.0 / lam
    inv_lam2 = inv_lam * inv_lam
    zoh = (e_dt - 1.0) * inv_lam
    state = 0.0 + 0.0j
    v_prev = 0.0
    e_mdt = np.exp(-lam * dt)
    for k in range(v.size):
        T = t_ramp[k]
        lt = lam * T
        # (no ramp, and a ramp over the whole interval, are most rows: their exponentials are e_dt's)
        e_mt = 1.0 + 0.0j if T == 0.0 else (e_mdt if T == dt else np.exp(-lt))
        e_rest = e_dt * e_mt
        if abs(lt) < 1e-2:
            J = T * T * (0.5 - lt / 3.0 + lt * lt / 8.0)
        else:
            J = (1.0 - e_mt * (1.0 + lt)) * inv_lam2
        inv_a = 1.0 / (lam + 1.0 / rc[k])
        K = slope[k] * e_dt * J + q_ramp[k] * ((e_rest - 1.0) * inv_lam) \
            + left[k] * ((e_rest - 1.0) * inv_lam - (e_rest - settled[k]) * inv_a)
        dv = v[k] - v_prev
        state = e_dt * state + r * (v_prev * zoh + dv * K)
        out[k] = 2.0 * state.real - v[k]
        v_prev = v[k]
    return out


def held_mode_column_compiled(v, held, lam, r):
    """:func:`~.effects.held_mode_column`'s recursion in one compiled pass (``v``: the input less its first
    value; ``held``: the :class:`~.effects.HeldDrive`; ``lam``, ``r``: one pole and its residue)."""
    arrays = (v, held.t_ramp, held.slope, held.q_ramp, held._left, held._settled)
    return _held_mode(*(readonly(x) for x in arrays), float(held.dt), readonly(held.rc_k), complex(lam), complex(r))
