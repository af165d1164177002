"""Second-order sections: a discrete controller as a cascade of biquads and a scalar gain.

Rows follow scipy: ``[b0, b1, b2, 1, a1, a2]``, each the section

    H_k(z) = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2),

and the controller is ``gain * prod_k H_k(z)``.

Conventions chosen here (the firmware export relies on them):

- Pairing is scipy's ``"nearest"`` rule, written out here because scipy's
  ``zpk2sos`` pads missing zeros at the origin (a one-sample advance per
  missing zero unless undone) and its ``"keep_odd"`` variant fails on some
  zero sets. Repeatedly: take the pole nearest the unit circle, its conjugate
  or else the next real pole nearest the unit circle, and the zeros nearest
  the first pole (a conjugate pair, or up to two real zeros), as long as the
  zeros left over still fit the sections left over. An odd order ends with one
  first-order section (b2 = a2 = 0); a section with fewer zeros than poles
  carries the controller's delay (its numerator starts with zeros).
- Sections run from the poles farthest from the unit circle to the nearest:
  the integrator (a pole at z = 1) always sits in the last section, where the
  output limits bound it (see :mod:`.fixed_point`).
- Poles within ``1e-8`` of z = 1 are set to exactly 1: an integrator computed
  from polynomial roots lands a few ulp off, and the fixed-point export keeps an
  integrator exact only if it is one.
- Each numerator is divided by its largest-magnitude coefficient (that
  coefficient becomes exactly 1) and the product of the divisors goes into
  ``gain``: every coefficient lies in [-1, 1] and the controller's scale is one
  visible number. No per-section gain normalization is attempted because the
  fixed-point export picks its own signal ranges from L1 norms.
"""

import control
import numpy as np

from ..errors import ExportError

__all__ = ["ExportError", "to_sos", "from_sos"]

# Poles this close to z = 1 are integrators (a real pole at 1 - 1e-8 is a
# 16 uHz corner at 10 kHz); np.roots places a simple root at 1 within ~1e-15.
_INTEGRATOR_TOL = 1e-8


def _check_controller(ctrl):
    if not isinstance(ctrl, (control.TransferFunction, control.StateSpace)):
        raise TypeError(f"expected a python-control TransferFunction or StateSpace, got {type(ctrl).__name__}")
    if not control.isdtime(ctrl, strict=True):
        raise ExportError("the controller is continuous-time; discretize it first, e.g. "
                          "control.sample_system(ctrl, 1e-4, method='tustin')")
    if ctrl.ninputs != 1 or ctrl.noutputs != 1:
        raise ExportError(f"the controller must be SISO; it has {ctrl.ninputs} inputs and "
                          f"{ctrl.noutputs} outputs: export each channel separately")


def _zpk(ctrl):
    """Zeros, poles and gain with H(z) = k prod(z - z_i) / prod(z - p_i)."""
    # A state-space model goes through its transfer function: the transmission zeros of a
    # realization with clustered poles come back with spurious huge zeros (seen: 1e14),
    # while roots of the polynomials are backward stable.
    tf = control.tf(ctrl) if isinstance(ctrl, control.StateSpace) else ctrl
    num = np.trim_zeros(np.atleast_1d(tf.num[0][0]).astype(float), "f")
    den = np.trim_zeros(np.atleast_1d(tf.den[0][0]).astype(float), "f")
    if num.size == 0:
        raise ExportError("the controller is identically zero; there is nothing to export")
    return np.roots(num), np.roots(den), num[0] / den[0]


def _split(roots, what):
    """Real roots and one of each conjugate pair (imaginary part > 0)."""
    roots = np.asarray(roots, dtype=complex)
    tol = 100 * np.finfo(float).eps * np.maximum(np.abs(roots), 1.0)
    real = np.abs(roots.imag) <= tol
    upper, lower = roots[~real & (roots.imag > 0)], roots[~real & (roots.imag < 0)]
    if upper.size != lower.size:
        raise ExportError(f"the controller's {what} are not in conjugate pairs: it has complex coefficients")
    return list(roots[real].real), list(upper)


def _take(z_real, z_pairs, kind, target, slots):
    """Remove the zeros of ``kind`` nearest ``target``: (real left, pairs left, zeros taken), or None."""
    real, pairs, zeros = list(z_real), list(z_pairs), []
    if 2 * kind.count("pair") + kind.count("real") > slots:
        return None
    for part in kind:
        pool = pairs if part == "pair" else real
        if not pool:
            return None
        v = pool.pop(min(range(len(pool)), key=lambda i: abs(pool[i] - target)))
        zeros += [v, np.conj(v)] if part == "pair" else [v]
    return real, pairs, zeros


def _fits(real, pairs, n_real_poles, n_pair_poles):
    """Whether these zeros fit into the sections these poles will form."""
    second = n_pair_poles + n_real_poles // 2
    return len(pairs) <= second and len(real) <= 2 * (second - len(pairs)) + n_real_poles % 2


def _pair(z, p):
    """Sections (zeros, poles) by the nearest rule, poles nearest the unit circle last."""
    z_real, z_pairs = _split(z, "zeros")
    p_real, p_pairs = _split(p, "poles")
    sections = []
    while p_real or p_pairs:
        worst = min(p_real + p_pairs, key=lambda v: abs(1.0 - abs(v)))
        if worst in p_pairs:
            p_pairs.remove(worst)
            poles = [worst, np.conj(worst)]
        else:
            p_real.remove(worst)
            poles = [worst]
            if p_real:
                poles.append(p_real.pop(min(range(len(p_real)), key=lambda i: abs(1.0 - abs(p_real[i])))))
        # The nearest zero's kind first, then fallbacks; the first whose leftovers still fit wins.
        nearest = min(z_real + z_pairs, key=lambda v: abs(v - worst), default=None)
        first = ("pair",) if nearest in z_pairs else ("real", "real")
        for kind in (first, ("pair",), ("real", "real"), ("real",), ()):
            taken = _take(z_real, z_pairs, kind, worst, len(poles))
            if taken and _fits(taken[0], taken[1], len(p_real), len(p_pairs)):
                z_real, z_pairs, zeros = taken
                break
        sections.append((zeros, poles))
    return sections[::-1]


def _row(zeros, poles):
    """[b0, b1, b2, 1, a1, a2] of prod(z - zeros) / prod(z - poles); missing zeros are delays."""
    a = np.real(np.poly(poles))
    b = np.concatenate((np.zeros(len(poles) - len(zeros)), np.atleast_1d(np.real(np.poly(zeros)))))
    return np.concatenate((b, np.zeros(3 - b.size), a, np.zeros(3 - a.size)))


def to_sos(ctrl):
    """Second-order sections and a scalar gain of a discrete SISO controller.

    Parameters
    ----------
    ctrl : control.TransferFunction or control.StateSpace
        Discrete-time SISO controller, input and output in any units (the
        workbench uses firmware volts of gauge error in, PZT volts out).

    Returns
    -------
    gain : float
        Scalar gain, units of the controller (V/V).
    sos : ndarray of float, shape (n_sections, 6)
        Rows ``[b0, b1, b2, 1, a1, a2]``; sections ordered with the poles
        nearest the unit circle last; each numerator's largest-magnitude
        coefficient is exactly 1.

    Raises
    ------
    TypeError
        If ``ctrl`` is not a python-control TransferFunction or StateSpace.
    ExportError
        If it is continuous-time, not SISO, improper or identically zero.

    Examples
    --------
    >>> import control
    >>> pi = control.tf([1.2, -1.0], [1.0, -1.0], 1e-4)   # PI: integrator and a zero at 5/6
    >>> gain, sos = to_sos(pi)
    >>> float(gain), sos.tolist()
    (1.2, [[1.0, -0.8333333333333334, 0.0, 1.0, -1.0, 0.0]])
    """
    _check_controller(ctrl)
    z, p, k = _zpk(ctrl)
    if z.size > p.size:
        raise ExportError(f"the controller is improper ({z.size} zeros, {p.size} poles): a causal "
                          f"filter needs at least as many poles as zeros; add {z.size - p.size} roll-off pole(s)")
    p = np.where(np.abs(p - 1.0) < _INTEGRATOR_TOL, 1.0, p)
    sos = np.array([_row(zeros, poles) for zeros, poles in _pair(z, p)]).reshape(-1, 6)
    if sos.shape[0] == 0:    # a static gain
        sos = np.array([[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
    gain = k
    for row in sos:
        lead = row[np.argmax(np.abs(row[:3]))]
        row[:3] /= lead
        gain *= lead
    return float(gain), sos


def from_sos(gain, sos, dt):
    """The transfer function ``gain * prod_k H_k(z)`` of second-order sections.

    Parameters
    ----------
    gain : float
        Scalar gain.
    sos : array_like of float, shape (n_sections, 6)
        Rows ``[b0, b1, b2, a0, a1, a2]`` (rows with a0 != 1 are normalized).
    dt : float
        Sample time, s.

    Returns
    -------
    control.TransferFunction
        Discrete SISO transfer function with sample time ``dt``; factors z that
        the numerator and denominator share (first-order sections) are removed.

    Raises
    ------
    ExportError
        If ``sos`` is not an (n, 6) array of finite numbers with a0 != 0, or
        ``dt`` is not positive.
    """
    sos = np.atleast_2d(np.asarray(sos, dtype=float))
    if sos.ndim != 2 or sos.shape[1] != 6 or not np.all(np.isfinite(sos)) or np.any(sos[:, 3] == 0):
        raise ExportError(f"sos must be rows [b0, b1, b2, a0, a1, a2] of finite numbers with a0 != 0; "
                          f"got shape {sos.shape}")
    if not dt > 0:
        raise ExportError(f"dt must be a positive sample time in seconds; got {dt}")
    num, den = np.array([float(gain)]), np.array([1.0])
    for row in sos:
        num = np.convolve(num, row[:3] / row[3])
        den = np.convolve(den, row[3:] / row[3])
    # Equal lengths: the z^-1 polynomials are also the z polynomials (times z^2n).
    while num.size > 1 and num[-1] == 0.0 and den[-1] == 0.0:
        num, den = num[:-1], den[:-1]
    return control.tf(num, den, dt)
