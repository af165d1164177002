"""Convex mixed-sensitivity design: FIR Youla parameter, second-order cones on a frequency grid.

For a STABLE discrete plant G(z) every stabilizing controller is K = Q / (1 - G Q) with Q
stable (Youla, for stable plants the "internal model" form), and then

    S = 1 - G Q,    T = G Q,    K S = Q

are affine in Q. With Q an FIR filter, Q(z) = sum_{k<N} q_k z^-k, the mixed-sensitivity
problem becomes a second-order cone program in the taps q:

    minimize gamma  subject to, at every grid frequency w,
        |W_s S| <= gamma,  |W_ks Q| <= gamma,  |W_t T| <= gamma       ("separate")
    or  || [W_s S, W_ks Q, W_t T] ||_2 <= gamma                         ("stacked", as mixsyn)
    and G(1) Q(1) = 1                                                   (S(1) = 0: integral action)

each complex modulus being the 2-norm of its real and imaginary parts. The route needs no
Riccati equations, so it still answers where slycot's SB10AD fails or hangs, and it works on
the exact sampled plant (hold, period average, compute delay) instead of a Pade
approximation. It is only as good as its grid and its N taps: the peaks between grid
points are checked afterwards on a denser grid.

The controller K = Q / (1 - G Q) has order N - 1 + order(G) and a pole at z = 1 (integral
action). It is reduced by balanced truncation (python-control ``balred``, slycot AB09AD/MD)
of its part without that pole, through the bilinear map z = (1 + s) / (1 - s), which keeps
the Hankel singular values; the integrator is put back exactly.
"""

import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import control
import cvxpy as cp
import numpy as np

from ..errors import DesignError
from .hinf import _as_siso, _response, gain_crossover_hz, weighted_norms, weighted_responses

__all__ = ["ConvexResult", "youla_mixed_sensitivity"]

_CRITERIA = ("separate", "stacked")
_NAMES = {"S": "|W_s S|", "KS": "|W_ks K S|", "T": "|W_t T|"}


@dataclass(frozen=True)
class ConvexResult:
    """A convex (FIR Youla) mixed-sensitivity design.

    Attributes
    ----------
    controller : control.StateSpace
        The delivered discrete controller (reduced), u = K e with e = r - y; it has a pole at z = 1.
    order, full_order : int
        States of the delivered controller and of K = Q / (1 - G Q) before reduction.
    reduction_error : float
        max over the check grid of |K - K_reduced|, V/V.
    reduction_error_rel : float
        max over the check grid of |K - K_reduced| / |K|.
    gamma : float
        Optimal value of the cone program (peaks on the design grid).
    closed_loop_norms : dict of str to float
        Peaks on the check grid with the delivered controller: ``"S"`` |W_s S|, ``"KS"``
        |W_ks K S|, ``"T"`` |W_t T| and ``"stacked"`` (their 2-norm).
    youla_norms : dict of str to float
        The same peaks for the full-order K (what the optimizer achieved).
    meets_specs : bool
        ``closed_loop_norms`` ``S``, ``KS`` and ``T`` all below 1.
    crossover_hz : float
        Lowest frequency where |G K| falls through 1 with the delivered controller, Hz.
    taps : ndarray of float
        q_0 ... q_{N-1}, V/V, adjusted so that G(1) sum(q) = 1 to rounding.
    integral_residual : float
        |S(1)| = |1 - G(1) sum(q)|.
    criterion : str
        "separate" or "stacked".
    solver, status : str
        The cvxpy solver and its status ("optimal" or "optimal_inaccurate").
    seconds : float
        Wall time, s.
    """
    controller: control.StateSpace
    order: int
    full_order: int
    reduction_error: float
    reduction_error_rel: float
    gamma: float
    closed_loop_norms: dict
    youla_norms: dict
    meets_specs: bool
    crossover_hz: float
    taps: np.ndarray
    integral_residual: float
    criterion: str
    solver: str
    status: str
    seconds: float


def _stable_discrete_plant(Gz):
    g = _as_siso(Gz, "Gz")
    if not g.isdtime(strict=True):
        raise ValueError("Gz must be discrete-time (e.g. workbench.linearize.sampled.firmware_plant); "
                         "use workbench.design.hinf for a continuous plant")
    g = control.ss(g)
    a, b, c, d = (np.asarray(m, dtype=float) for m in (g.A, g.B, g.C, g.D))
    if not all(np.all(np.isfinite(m)) for m in (a, b, c, d)):
        raise ValueError("Gz has non-finite matrices")
    radius = np.max(np.abs(np.linalg.eigvals(a))) if a.size else 0.0
    if radius >= 1.0 - 1e-9:
        raise ValueError(f"Gz has a pole of modulus {radius:.6g}; the FIR Youla parametrization needs a stable "
                         f"plant (all poles strictly inside the unit circle); stabilize it first or use "
                         f"workbench.design.hinf")
    return g


def _grid(freq_hz, nyquist_hz, taps):
    """The design grid: log-spaced where the weights change, and uniform where the FIR taps can ripple.

    Q is a trigonometric polynomial of degree N - 1 in w dt; sampled uniformly at 4 N points of
    (0, Nyquist) its modulus between the points exceeds the sampled peak by a few per cent at
    most, whereas a log grid alone leaves the top octave so sparse that the taps ripple freely.
    """
    if freq_hz is None:
        log_part = np.geomspace(nyquist_hz * 1e-5, nyquist_hz * (1 - 1e-3), 150)
        uniform = np.linspace(0.0, nyquist_hz, 4 * taps + 1)[1:]
        uniform[-1] = nyquist_hz * (1 - 1e-3)
        return np.unique(np.concatenate([log_part, uniform]))
    f = np.asarray(freq_hz, dtype=float)
    if f.ndim != 1 or f.size < 3 or not np.all(np.isfinite(f)):
        raise ValueError(f"freq_hz must be a 1-D array of at least 3 finite frequencies; got shape {f.shape}")
    if np.any(f <= 0) or np.any(f >= nyquist_hz):
        raise ValueError(f"freq_hz must lie strictly between 0 and the Nyquist frequency {nyquist_hz:g} Hz")
    return np.unique(f)


def _fir(taps, dt):
    """Q(z) = sum q_k z^-k as a StateSpace (a shift register of the past inputs)."""
    n = taps.size
    if n == 1:
        return control.ss([], [], [], [[taps[0]]], dt)
    a = np.eye(n - 1, k=-1)
    b = np.zeros((n - 1, 1))
    b[0, 0] = 1.0
    return control.ss(a, b, taps[1:].reshape(1, -1), [[taps[0]]], dt)


def _split_integrator(k):
    """K(z) = r / (z - 1) + K_s(z): the residue r at the pole nearest 1 and the rest (spectral projector)."""
    a, b, c, d = (np.asarray(m, dtype=float) for m in (k.A, k.B, k.C, k.D))
    lam, right = np.linalg.eig(a)
    i = int(np.argmin(np.abs(lam - 1.0)))
    if abs(lam[i] - 1.0) > 1e-6:
        raise DesignError(f"the Youla controller lost its integrator (nearest pole at z = {complex(lam[i]):.8g}); "
                          f"the solver's answer is too inaccurate: use more taps or another solver")
    lam_l, left = np.linalg.eig(a.T)
    j = int(np.argmin(np.abs(lam_l - lam[i])))
    v, w = np.real(right[:, i]), np.real(left[:, j])
    p = np.outer(v, w) / (w @ v)                       # spectral projector onto the z = 1 mode
    residue = float((c @ v)[0] * (w @ b)[0] / (w @ v))
    q = np.eye(a.shape[0]) - p
    rest = control.ss(a - float(np.real(lam[i])) * p, q @ b, c @ q, d, k.dt)
    return residue, rest


def _to_continuous(sys):
    """Bilinear map s = (z - 1) / (z + 1): same Hankel singular values, continuous."""
    a, b, c, d = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
    n = a.shape[0]
    m = np.linalg.inv(a + np.eye(n))
    return control.ss(m @ (a - np.eye(n)), np.sqrt(2) * m @ b, np.sqrt(2) * c @ m, d - c @ m @ b)


def _to_discrete(sys, dt):
    """Inverse of :func:`_to_continuous`: z = (1 + s) / (1 - s)."""
    a, b, c, d = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
    n = a.shape[0]
    if n == 0:
        return control.ss([], [], [], d, dt)
    m = np.linalg.inv(np.eye(n) - a)
    return control.ss((np.eye(n) + a) @ m, np.sqrt(2) * m @ b, np.sqrt(2) * c @ m, d + c @ m @ b, dt)


def _with_integrator(residue, rest, dt):
    integ = control.ss([[1.0]], [[1.0]], [[residue]], [[0.0]], dt)
    return control.parallel(integ, rest)


def _worst(norms, criterion):
    return norms["stacked"] if criterion == "stacked" else max(norms[key] for key in ("S", "KS", "T"))


def _closed_loop_stable(g, k):
    poles = control.poles(control.feedback(g, k))
    return bool(poles.size == 0 or np.max(np.abs(poles)) < 1.0)


def _reduce(k_full, g, weights, f_check, full, criterion, order, reduction_tol):
    """Balanced truncation of K's non-integrating part; the smallest order within the tolerance of ``full``."""
    dt = k_full.dt
    residue, rest = _split_integrator(k_full)
    if np.min(np.abs(np.linalg.eigvals(rest.A) + 1.0)) < 1e-9:
        raise DesignError("the Youla controller has a pole at z = -1, which the bilinear map used for the "
                          "reduction cannot take; change the number of taps")
    rest_c = _to_continuous(rest)
    n_unstable = int(np.sum(np.linalg.eigvals(rest_c.A).real >= 0.0))
    target = _worst(full, criterion) * (1.0 + reduction_tol)
    # ``rest`` carries one dead mode (the projected-out integrator, at z = 0), so its full useful
    # order is rest.nstates - 1 and truncating to it is exact.
    top = rest.nstates - 1
    candidates = [min(order - 1, top)] if order is not None else range(max(n_unstable, 1), top + 1)
    for r in candidates:
        if r < n_unstable:
            raise DesignError(f"order = {order} is below the {n_unstable + 1} states the controller cannot lose "
                              f"(its integrator and unstable modes); ask for order >= {n_unstable + 1}")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            red_c = control.balred(rest_c, r) if r > 0 else control.ss([], [], [], rest_c.D)
        if caught or red_c.nstates != r:         # AB09MD kept more (marginal) modes than asked
            if order is not None:
                raise DesignError(f"balanced truncation cannot reach order = {order}: it keeps {red_c.nstates + 1} "
                                  f"states (marginal modes); ask for a higher order or leave order=None")
            continue
        red = _to_discrete(red_c, dt)
        k_r = _with_integrator(residue, red, dt)
        if not _closed_loop_stable(g, k_r):
            if order is not None:
                raise DesignError(f"the order-{order} reduction of the Youla controller destabilizes the loop; "
                                  f"ask for a higher order or leave order=None")
            continue
        norms = weighted_norms(g, k_r, *weights, f_check)
        if order is not None or _worst(norms, criterion) <= target:
            return k_r, norms
    # the full-order split is exact up to rounding, so this only happens if the split itself failed
    raise DesignError("no reduction of the Youla controller keeps the closed loop stable within reduction_tol; "
                      "raise reduction_tol or check the solver status")


def _youla_maps(g, freq_hz, taps, g1):
    """Affine maps (c0, A), complex, one row per frequency, with S, Q, T = c0 + A q for taps q.

    S = 1 - G Q is written without cancellation, given sum(q) = 1/G(1):
    S = -(1 - z) Gd(z) / G(1) - G(z) sum q_k (z^-k - 1), with Gd = (G(z) - G(1)) / (1 - z)
    = C (zI - A)^-1 (I - A)^-1 B; z^-k - 1 and 1 - z come from expm1, exact at low frequency.
    """
    dt = float(g.dt)
    a, b, c = (np.asarray(m, dtype=float) for m in (g.A, g.B, g.C))
    n = a.shape[0]
    wdt = 2 * np.pi * np.asarray(freq_hz, dtype=float) * dt
    z_minus_one_powers = np.expm1(-1j * np.outer(wdt, np.arange(taps)))
    z_inv_powers = z_minus_one_powers + 1.0
    one_minus_z = -np.expm1(1j * wdt)
    if n:
        v = np.linalg.solve(np.eye(n) - a, b)[:, 0]
        gdiff = np.array([c[0] @ np.linalg.solve(zz * np.eye(n) - a, v) for zz in np.exp(1j * wdt)])
    else:
        gdiff = np.zeros(wdt.size, dtype=complex)
    g_resp = _response(g, freq_hz, dt)
    zeros = np.zeros(wdt.size, dtype=complex)
    return {"S": (-one_minus_z * gdiff / g1, -g_resp[:, None] * z_minus_one_powers),
            "KS": (zeros, z_inv_powers),
            "T": (zeros, g_resp[:, None] * z_inv_powers)}


def _cone_data(maps, weights_resp):
    """The maps weighted: weighted response = c0 + A q; a weight given as None drops its block."""
    return {key: (w * c0, w[:, None] * a) for (key, (c0, a)), w in zip(maps.items(), weights_resp)
            if w is not None}


def _solve(blocks, n_taps, q1, criterion, gamma_max, solver, solver_options):
    q = cp.Variable(n_taps)
    gamma = cp.Variable()
    rows = {key: (np.real(c0) + np.real(a) @ q, np.imag(c0) + np.imag(a) @ q) for key, (c0, a) in blocks.items()}
    nf = next(iter(blocks.values()))[0].size
    ones = np.ones(nf)
    if criterion == "separate":
        cons = [cp.SOC(gamma * ones, cp.vstack(list(parts)), axis=0) for parts in rows.values()]
    else:
        cons = [cp.SOC(gamma * ones, cp.vstack([x for parts in rows.values() for x in parts]), axis=0)]
    cons.append(cp.sum(q) == q1)
    if gamma_max is not None:
        cons.append(gamma <= gamma_max)
    prob = cp.Problem(cp.Minimize(gamma), cons)
    with warnings.catch_warnings():
        # the status carries the same news; callers read ConvexResult.status
        warnings.filterwarnings("ignore", message="Solution may be inaccurate", category=UserWarning)
        try:
            prob.solve(solver=solver, **dict(solver_options or {}))
        except cp.error.SolverError as err:
            raise DesignError(f"the cone program failed in solver {solver} ({err}); try another solver "
                              f"(installed: {', '.join(cp.installed_solvers())}), fewer taps or a coarser "
                              f"grid") from err
    return prob.status, (None if q.value is None else np.asarray(q.value, dtype=float)), gamma.value


def _binding(blocks, taps, nf_hz, criterion):
    """Peaks of each weighted function at the taps, and where they sit: the constraints to relax."""
    parts = []
    for key, (c0, a) in blocks.items():
        mag = np.abs(c0 + a @ taps)
        i = int(np.argmax(mag))
        parts.append((float(mag[i]), key, float(nf_hz[i])))
    parts.sort(reverse=True)
    top = parts[0][0]
    active = [p for p in parts if p[0] >= 0.95 * top] if criterion == "separate" else parts
    return ", ".join(f"{_NAMES[key]} = {m:.3g} near {f:.4g} Hz" for m, key, f in active)


def youla_mixed_sensitivity(Gz, w_s, w_ks, w_t, *, taps=80, freq_hz=None, criterion="separate",
                            gamma_max=None, order=None, reduction_tol=0.05, solver="CLARABEL",
                            solver_options=None):
    """Mixed-sensitivity design for a stable discrete plant by convex optimization over an FIR Youla parameter.

    Parameters
    ----------
    Gz : SISO LTI, discrete, stable
        Plant from controller output (V) to reading (firmware V), as the firmware sees it
        (e.g. :func:`workbench.linearize.sampled.firmware_plant`).
    w_s, w_ks, w_t : SISO LTI, number or None
        Weights on S, K S and T. A continuous weight is read at s = j 2 pi f, a discrete one
        (same sample time as Gz) at z = e^{j 2 pi f dt}. None drops that constraint.
    taps : int, optional
        N, the length of the FIR Youla parameter Q. Default 80 (8 ms at 10 kHz).
    freq_hz : array_like of float or None, optional
        Design grid, Hz, strictly between 0 and Nyquist. Default: 150 log-spaced points from
        1e-5 x Nyquist up, plus 4 N uniformly spaced ones up to just below Nyquist (a log grid
        alone leaves the FIR free to ripple between its sparse top-octave points).
    criterion : {"separate", "stacked"}, optional
        Bound each weighted function by gamma ("separate", default), or their stacked 2-norm
        (the H-infinity norm mixsyn minimizes).
    gamma_max : float or None, optional
        If given, gamma <= gamma_max is a hard constraint (1.0 demands the weighted specs);
        an infeasible program then raises DesignError naming the binding constraints.
    order : int or None, optional
        States of the delivered controller, integrator included. Default None: the smallest
        order whose worst weighted peak is within ``reduction_tol`` of the full-order design's.
    reduction_tol : float, optional
        Relative growth of the worst weighted peak allowed by the reduction. Default 0.05.
    solver : str, optional
        cvxpy solver name. Default "CLARABEL" (interior point; "SCS" is faster but looser).
    solver_options : mapping or None, optional
        Keyword options passed to the solver through ``Problem.solve``.

    Returns
    -------
    ConvexResult

    Raises
    ------
    DesignError
        If the cone program is infeasible (only possible with ``gamma_max``) or unbounded, the
        solver fails, integral action is impossible (G(1) = 0), or no reduced controller
        stabilizes the loop.
    TypeError, ValueError
        For a plant or weight of the wrong kind, an unstable or continuous Gz, bad options.

    Notes
    -----
    The equality G(1) sum(q) = 1 puts a zero of S at z = 1; after the solve the taps are
    shifted uniformly by the (tiny) residual, so |S(1)| is at rounding level. S is formed
    as -(1 - z) Gd(z)/G(1) - G(z) sum q_k (z^-k - 1) with Gd = (G(z) - G(1))/(1 - z) =
    C (zI - A)^-1 (I - A)^-1 B, so no two large numbers cancel at low frequency where W_s is
    large. Weighted peaks are then re-evaluated on a check grid ten times denser that
    reaches a decade lower, with the delivered (reduced) and the full-order controller.
    """
    t0 = time.perf_counter()
    g = _stable_discrete_plant(Gz)
    dt = float(g.dt)
    weights = [_as_siso(w, n, allow_none=True) for w, n in zip((w_s, w_ks, w_t), ("w_s", "w_ks", "w_t"))]
    if all(w is None for w in weights):
        raise ValueError("at least one of w_s, w_ks, w_t must be given")
    if isinstance(taps, bool) or not isinstance(taps, (int, np.integer)) or not 2 <= taps <= 4000:
        raise ValueError(f"taps must be an integer between 2 and 4000; got {taps!r}")
    if criterion not in _CRITERIA:
        raise ValueError(f"criterion must be one of {', '.join(_CRITERIA)}; got {criterion!r}")
    if gamma_max is not None and not (np.isfinite(gamma_max) and gamma_max > 0):
        raise ValueError(f"gamma_max must be a positive number or None; got {gamma_max!r}")
    if order is not None and (isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1):
        raise ValueError(f"order must be a positive integer or None; got {order!r}")
    if not (np.isfinite(reduction_tol) and reduction_tol >= 0):
        raise ValueError(f"reduction_tol must be a non-negative number; got {reduction_tol!r}")
    if solver not in cp.installed_solvers():
        raise ValueError(f"solver {solver!r} is not installed; installed: {', '.join(cp.installed_solvers())}")
    if solver_options is not None and not isinstance(solver_options, Mapping):
        raise TypeError(f"solver_options must be a mapping or None; got {type(solver_options).__name__}")

    nyquist = 0.5 / dt
    f = _grid(freq_hz, nyquist, taps)
    f_check = np.unique(np.concatenate([f, np.geomspace(f[0] / 10, f[-1], 10 * f.size)]))
    g1 = float(np.real(complex(np.squeeze(g(1.0)))))
    if abs(g1) < 1e-12 * max(1.0, float(np.max(np.abs(_response(g, f, dt))))):
        raise DesignError("Gz has (nearly) zero DC gain, so no controller can give integral action (S(1) = 0 "
                          "needs G(1) Q(1) = 1); remove the DC zero from the plant model")

    blocks = _cone_data(_youla_maps(g, f, taps, g1), [None if w is None else _response(w, f, dt) for w in weights])

    status, q, gamma = _solve(blocks, taps, 1.0 / g1, criterion, gamma_max, solver, solver_options)
    if status in ("infeasible", "infeasible_inaccurate") and gamma_max is not None:
        _, q2, gamma2 = _solve(blocks, taps, 1.0 / g1, criterion, None, solver, solver_options)
        where = _binding(blocks, q2, f, criterion) if q2 is not None else "unknown"
        best = f"{gamma2:.3g}" if gamma2 is not None else "unknown"
        raise DesignError(f"the weighted specs cannot be met with gamma <= gamma_max = {gamma_max:g}: the best this "
                          f"{taps}-tap Youla design reaches is gamma = {best}, limited by {where}; relax those "
                          f"weights there (S + T = 1: |S| and |T| cannot both be small at one frequency) or "
                          f"raise gamma_max")
    if status not in ("optimal", "optimal_inaccurate") or q is None:
        hint = "check that every weight is finite; " if "unbounded" in str(status) else ""
        raise DesignError(f"the cone program ended with status {status!r} in solver {solver}; {hint}try another "
                          f"solver (installed: {', '.join(cp.installed_solvers())}), fewer taps or a coarser grid")
    q = q + (1.0 / g1 - q.sum()) / taps                                 # exact integral action
    integral_residual = abs(1.0 - g1 * q.sum())

    # The full-order design on the check grid, from the taps (a state-space evaluation of K near its
    # pole at z = 1 would lose several digits where |K| is huge).
    full_resp = {key: c0 + a @ q for key, (c0, a) in _youla_maps(g, f_check, taps, g1).items()}
    weighted = [_response(_as_siso(w, "w", allow_none=True), f_check, dt) * full_resp[key]
                for w, key in zip(weights, ("S", "KS", "T"))]
    full = {key: float(np.max(np.abs(x))) for key, x in zip(("S", "KS", "T"), weighted)}
    full["stacked"] = float(np.max(np.sqrt(sum(np.abs(x) ** 2 for x in weighted))))
    kf = full_resp["KS"] / full_resp["S"]                               # K = Q / S

    k_full = control.feedback(_fir(q, dt), g, sign=1)                  # K = Q / (1 - G Q)
    k_r, norms = _reduce(k_full, g, weights, f_check, full, criterion, order, reduction_tol)
    err = np.abs(kf - _response(k_r, f_check, dt))
    loop = weighted_responses(g, k_r, *weights, f_check)["L"]
    return ConvexResult(controller=k_r, order=int(k_r.nstates), full_order=int(k_full.nstates),
                        reduction_error=float(np.max(err)), reduction_error_rel=float(np.max(err / np.abs(kf))),
                        gamma=float(gamma), closed_loop_norms=norms, youla_norms=full,
                        meets_specs=bool(max(norms[key] for key in ("S", "KS", "T")) < 1.0),
                        crossover_hz=gain_crossover_hz(f_check, loop), taps=q,
                        integral_residual=float(integral_residual), criterion=criterion, solver=solver,
                        status=str(status), seconds=time.perf_counter() - t0)
