"""Mixed-sensitivity H-infinity synthesis (python-control ``mixsyn``, slycot SB10AD) under a time limit.

The loop is the usual one-degree-of-freedom servo: the controller K reads the error
e = r - y (firmware volts of gauge reading) and drives the plant G with u = K e (volts
on the PZT). With L = G K,

    S = 1 / (1 + L),    T = L / (1 + L),    K S (error -> drive),

and the synthesis minimizes gamma = || [W_s S; W_ks K S; W_t T] ||_inf over stabilizing
K. The stacked norm bounds each entry: |W_s S|, |W_ks K S|, |W_t T| <= gamma at every
frequency. A weight is a spec when its inverse is the allowed magnitude: the weighted
specs are met when all three weighted functions stay below 1.

SB10AD can run for a very long time when no stabilizing controller exists or the
problem is badly conditioned (python-control issues #152, #596, #973: python-control
starts its gamma iteration at 1e100), and a Fortran routine cannot be interrupted from
Python. :func:`mixed_sensitivity` therefore runs ``mixsyn`` in a child process and kills
it at the time limit. Before synthesis the plant and the weights are balanced (slycot
TB01ID, a diagonal state scaling): the piezo model's raw realization spans 1e-1 to 1e13
in its entries, which SB10AD otherwise takes for a rank-deficient problem (info = 1).
"""

import contextlib
import math
import multiprocessing
import os
import time
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import control
import numpy as np

from ..errors import DesignError

__all__ = ["HinfResult", "MixedSensitivityWeights", "default_weights", "mixed_sensitivity",
           "weighted_responses", "weighted_norms", "gain_crossover_hz"]

_START_METHODS = ("spawn", "fork")
# SB10AD works on matrices of order ~10-30, where a multithreaded OpenBLAS only adds contention:
# single-threaded, a synthesis on the piezo plant takes ~0.5 s instead of 2-4 s on two busy cores.
_CHILD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
_WEIGHT_NAMES = ("w_s", "w_ks", "w_t")
_NORM_KEYS = ("S", "KS", "T")

# SB10AD's info codes (slycot's docstring), each with what to change in mixed-sensitivity terms.
_SB10AD_ADVICE = {
    1: "[A - jwI, B2; C1, D12] lost column rank: the drive reaches the weighted outputs through a zero "
       "on the imaginary axis; give the plant and every weight their poles and zeros strictly in the "
       "left half-plane (no pure integrators or differentiators in w_s, w_ks, w_t)",
    2: "[A - jwI, B1; C2, D21] lost row rank: a pole of w_s (or of the plant) lies on the imaginary axis; "
       "move it to a small negative frequency (default_weights puts the w_s pole at 1e-4 x the crossover)",
    3: "D12 lost column rank: w_ks needs a nonzero high-frequency gain; make w_ks biproper (as many zeros "
       "as poles), as default_weights does",
    4: "D21 lost row rank, which mixed sensitivity (D21 = I) should never produce; check the plant for "
       "non-finite or huge entries",
    5: "an SVD did not converge; rescale the plant (frequencies near 1 rad/s, gains near 1)",
    6: "no admissible controller at the current gamma: the weights demand more than any controller can "
       "give; lower the w_s bandwidth or relax w_t / w_ks near the crossover",
    7: "the X-Riccati equation could not be solved: the weights are too demanding or badly scaled; lower "
       "the w_s bandwidth or its low-frequency gain (move its pole up)",
    8: "the Y-Riccati equation could not be solved: the weights are too demanding or badly scaled; lower "
       "the w_s bandwidth or its low-frequency gain (move its pole up)",
    9: "a determinant in the controller formulas is zero; perturb the weights slightly",
    10: "singular values of the D11 blocks could not be estimated; check the weights' high-frequency gains",
    11: "the controller feedthrough is singular against the plant feedthrough; give the plant a zero "
        "feedthrough or w_ks a larger high-frequency gain",
    12: "no stabilizing controller can be found: the plant is not stabilizable/detectable with these "
        "weights; check for unstable plant modes the drive cannot reach and relax w_s",
}


class MixedSensitivityWeights(NamedTuple):
    """The three weights of :func:`mixed_sensitivity`, continuous transfer functions."""
    w_s: control.TransferFunction
    w_ks: control.TransferFunction
    w_t: control.TransferFunction


@dataclass(frozen=True)
class HinfResult:
    """A mixed-sensitivity H-infinity design.

    Attributes
    ----------
    controller : control.StateSpace
        Continuous controller, u = K e with e = r - y (negative feedback).
    gamma : float
        SB10AD's gamma: its bound on the stacked norm || [W_s S; W_ks K S; W_t T] ||_inf.
    closed_loop_norms : dict of str to float
        Achieved peaks on the evaluation grid: ``"S"`` max |W_s S|, ``"KS"`` max |W_ks K S|,
        ``"T"`` max |W_t T|, ``"stacked"`` max of sqrt(|W_s S|^2 + |W_ks K S|^2 + |W_t T|^2).
        A weight given as None contributes 0.
    meets_specs : bool
        True when ``S``, ``KS`` and ``T`` above are all below 1: every weighted spec holds.
    crossover_hz : float
        Lowest frequency where |G K| falls through 1, Hz (nan if it never does on the grid).
    rcond : tuple of float
        SB10AD's reciprocal condition estimates (control and measurement transformations,
        X- and Y-Riccati equations); values near 1e-16 and below mean a fragile design.
    seconds : float
        Wall time of the synthesis, process start-up included, s.
    """
    controller: control.StateSpace
    gamma: float
    closed_loop_norms: dict
    meets_specs: bool
    crossover_hz: float
    rcond: tuple
    seconds: float


# ---------------------------------------------------------------------------------------------------------
# Checks and frequency responses shared with the convex route


def _as_siso(sys, name, *, allow_none=False):
    """``sys`` as a SISO LTI (a number becomes a static gain); None passes when allowed."""
    if sys is None:
        if allow_none:
            return None
        raise TypeError(f"{name} must be a SISO control.StateSpace or TransferFunction; got None")
    if isinstance(sys, (int, float, np.integer, np.floating)) and not isinstance(sys, bool):
        if not np.isfinite(sys):
            raise ValueError(f"{name} must be finite; got {sys!r}")
        return control.ss([], [], [], [[float(sys)]])
    if not isinstance(sys, (control.StateSpace, control.TransferFunction)):
        raise TypeError(f"{name} must be a SISO control.StateSpace, TransferFunction or a number; "
                        f"got {type(sys).__name__}")
    if (sys.ninputs, sys.noutputs) != (1, 1):
        raise ValueError(f"{name} must be SISO; it has {sys.ninputs} inputs and {sys.noutputs} outputs")
    return sys


def _response(sys, freq_hz, dt):
    """Frequency response of ``sys`` at freq_hz: at s = j w if continuous, at z = e^{j w dt} if discrete.

    ``dt`` is the loop's sample time (0 for a continuous loop). A continuous weight in a discrete
    loop is read at the same physical frequency; a discrete one must share the loop's sample time.
    """
    if sys is None:
        return np.zeros(len(freq_hz), dtype=complex)
    w = 2 * np.pi * np.asarray(freq_hz, dtype=float)
    if sys.isdtime(strict=True):
        if dt == 0 or not math.isclose(float(sys.dt), dt, rel_tol=1e-9):
            raise ValueError(f"a discrete system with dt = {sys.dt} s cannot be used in a loop sampled "
                             f"at dt = {dt} s; give it as a continuous system or resample it")
        x = np.exp(1j * w * dt)
    else:
        x = 1j * w
    return np.atleast_1d(np.asarray(sys(x), dtype=complex)).reshape(-1)


def weighted_responses(plant, controller, w_s, w_ks, w_t, freq_hz):
    """W_s S, W_ks K S, W_t T and L = G K on a grid, for a continuous or a discrete loop.

    Parameters
    ----------
    plant, controller : control.StateSpace or TransferFunction
        SISO; both continuous, or both discrete with the same sample time.
    w_s, w_ks, w_t : SISO LTI, number or None
        Weights; continuous ones are read at s = j 2 pi f also in a discrete loop. None gives zeros.
    freq_hz : array_like of float
        Frequencies, Hz (below the Nyquist frequency for a discrete loop).

    Returns
    -------
    dict of str to ndarray of complex
        ``"S"``, ``"KS"``, ``"T"`` (weighted) and ``"L"``.
    """
    g = _as_siso(plant, "plant")
    k = _as_siso(controller, "controller")
    dt = float(g.dt) if g.isdtime(strict=True) else 0.0
    if k.isdtime(strict=True) != (dt > 0):
        raise ValueError("plant and controller must both be continuous or both be discrete")
    gw, kw = _response(g, freq_hz, dt), _response(k, freq_hz, dt)
    loop = gw * kw
    s = 1.0 / (1.0 + loop)
    ws, wks, wt = (_response(_as_siso(w, n, allow_none=True), freq_hz, dt)
                   for w, n in zip((w_s, w_ks, w_t), _WEIGHT_NAMES))
    return {"S": ws * s, "KS": wks * kw * s, "T": wt * loop * s, "L": loop}


def weighted_norms(plant, controller, w_s, w_ks, w_t, freq_hz):
    """Peaks over ``freq_hz`` of |W_s S|, |W_ks K S|, |W_t T| and of their stacked 2-norm.

    Same arguments as :func:`weighted_responses`; returns a dict with keys ``"S"``, ``"KS"``,
    ``"T"`` and ``"stacked"``.
    """
    r = weighted_responses(plant, controller, w_s, w_ks, w_t, freq_hz)
    mags = [np.abs(r[key]) for key in _NORM_KEYS]
    norms = {key: float(np.max(m)) for key, m in zip(_NORM_KEYS, mags)}
    norms["stacked"] = float(np.max(np.sqrt(sum(m ** 2 for m in mags))))
    return norms


def gain_crossover_hz(freq_hz, loop):
    """Lowest frequency where |loop| falls through 1, interpolated in log-log, Hz; nan if none."""
    f = np.asarray(freq_hz, dtype=float)
    mag = np.log(np.abs(np.asarray(loop)))
    idx = np.flatnonzero((mag[:-1] > 0) & (mag[1:] <= 0))
    if idx.size == 0:
        return float("nan")
    i = idx[0]
    lf = np.log(f[i:i + 2])
    return float(np.exp(lf[0] + (lf[1] - lf[0]) * mag[i] / (mag[i] - mag[i + 1])))


# ---------------------------------------------------------------------------------------------------------
# Weights


def default_weights(G, crossover_hz, w_m, output_range_v, *, error_range_v=2.6, peak_s=2.0,
                    low_freq_s=1e-4, rolloff_ratio=5.0):
    """Mixed-sensitivity weights for a crossover target, an uncertainty weight and the drive range.

    Parameters
    ----------
    G : SISO LTI
        The plant, firmware volts per PZT volt; only its DC gain is used (to check the drive bound).
    crossover_hz : float
        Target loop crossover, Hz (the servo aims at 100 to 500 Hz).
    w_m : SISO LTI, continuous
        Multiplicative uncertainty weight of the plant family, |W_m| >= |P/P_nom - 1|.
    output_range_v : (float, float)
        Controller output (PZT drive) range (lo, hi), V; e.g. (-20, 120).
    error_range_v : float, optional
        Full-scale amplitude of the error the controller reads, firmware V. Default 2.6.
    peak_s : float, optional
        Bound on the sensitivity peak |S|, default 2 (6 dB).
    low_freq_s : float, optional
        |S| bound at DC relative to 1 (the integral-like depth), default 1e-4 (-80 dB).
    rolloff_ratio : float, optional
        Corner of the high-frequency roll-off of w_ks and w_t, in multiples of the crossover.
        Default 5.

    Returns
    -------
    MixedSensitivityWeights
        ``(w_s, w_ks, w_t)``, continuous transfer functions, unpackable as a tuple.

    Raises
    ------
    DesignError
        If the drive bound cannot hold even at DC: integral action forces K S(0) = 1/G(0).

    Notes
    -----
    With w_b = 2 pi crossover_hz, M = peak_s, A = low_freq_s, r = rolloff_ratio,
    k_max = (hi - lo) / error_range_v:

    - w_s = (s / M + w_b) / (s + A w_b). Its pole sits at A w_b, a tiny but nonzero
      frequency (a pole at 0 would leave the generalized plant unstabilizable, SB10AD
      info 2), so |S| <= gamma A at DC (integral-like), |S| <= gamma s / w_b below the
      crossover (the sensitivity bandwidth is w_b) and |S| <= gamma M above it.
    - w_ks = (1 + s / (r w_b)) / (1 + s / (100 r w_b)) / k_max. An error of full-scale
      amplitude may ask for at most the whole drive span (140 V / 2.6 V = 54 V/V), and above
      r times the crossover the allowed controller gain falls at 20 dB/decade (roll-off).
      The far pole keeps w_ks biproper: SB10AD needs its nonzero high-frequency gain (D12
      full rank).
    - w_t = W_m ((1 + s / (r w_b)) / (1 + s / (100 r w_b)))^2: robust stability against the
      family (|T| < 1/|W_m|), and |T| falling at 40 dB/decade above r times the crossover,
      where the continuous model of the sampled loop (Pade delay, Tustin) stops being
      trustworthy and the 70 kHz stack mode lives.

    Examples
    --------
    >>> import control
    >>> G = control.tf([0.04 * 1460.0], [1.0, 1460.0])
    >>> w_m = control.tf([0.407 / 1004, 0.407], [1 / 300, 1.0])
    >>> w_s, w_ks, w_t = default_weights(G, 200.0, w_m, (-20.0, 120.0))
    >>> print(f"|W_s(0)| = {abs(w_s(0)):.0f}, 1/|W_ks(0)| = {1 / abs(w_ks(0)):.1f} V/V")
    |W_s(0)| = 10000, 1/|W_ks(0)| = 53.8 V/V
    """
    g = _as_siso(G, "G")
    wm = _as_siso(w_m, "w_m")
    if wm.isdtime(strict=True) or g.isdtime(strict=True):
        raise ValueError("default_weights builds continuous weights: give a continuous G and w_m")
    fc = float(crossover_hz)
    if not np.isfinite(fc) or fc <= 0:
        raise ValueError(f"crossover_hz must be a positive frequency in Hz; got {crossover_hz!r}")
    try:
        lo, hi = (float(v) for v in output_range_v)
    except (TypeError, ValueError):
        raise ValueError(f"output_range_v must be a pair (lo, hi) of volts; got {output_range_v!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise ValueError(f"output_range_v must be (lo, hi) with lo < hi, in V; got {output_range_v!r}")
    for name, value, ok in (("error_range_v", error_range_v, error_range_v > 0),
                            ("peak_s", peak_s, peak_s > 1),
                            ("low_freq_s", low_freq_s, 0 < low_freq_s < 1),
                            ("rolloff_ratio", rolloff_ratio, rolloff_ratio > 1)):
        if not (np.isfinite(value) and ok):
            raise ValueError(f"{name} = {value!r} is out of range: error_range_v > 0, peak_s > 1, "
                             f"0 < low_freq_s < 1, rolloff_ratio > 1")
    wb = 2 * np.pi * fc
    k_max = (hi - lo) / float(error_range_v)
    g0 = abs(complex(np.squeeze(g(0))))
    if g0 > 0 and 1.0 / g0 >= k_max:
        raise DesignError(f"the drive bound cannot hold: integral action makes K S = 1/G = {1 / g0:.3g} V/V at "
                          f"DC, above the allowed {k_max:.3g} V/V ({hi - lo:g} V of drive span per "
                          f"{error_range_v:g} V of error); widen output_range_v or raise error_range_v")
    s = control.tf("s")
    wr = rolloff_ratio * wb
    rolloff = (1 + s / wr) / (1 + s / (100 * wr))
    w_s = (s / peak_s + wb) / (s + low_freq_s * wb)
    w_ks = rolloff / k_max
    w_t = control.tf(wm) * rolloff * rolloff
    return MixedSensitivityWeights(w_s, w_ks, w_t)


# ---------------------------------------------------------------------------------------------------------
# Synthesis


def _balanced_matrices(sys):
    """(A, B, C, D) of ``sys`` after slycot TB01ID diagonal balancing (no change for a static gain)."""
    ss = control.ss(sys)
    a, b, c, d = (np.array(m, dtype=float) for m in (ss.A, ss.B, ss.C, ss.D))
    if a.shape[0] == 0:
        return a, b, c, d
    from slycot import tb01id
    _, a, b, c, _ = tb01id(a.shape[0], b.shape[1], c.shape[0], 10.0, a, b, c, job="A")
    return a, b, c, d


def _mixsyn_worker(conn, plant_abcd, weights_abcd):
    """Child process: mixsyn on the given matrices; sends ("ok", K matrices, gamma, rcond) or the failure."""
    try:
        with warnings.catch_warnings():
            # augw still builds its interconnection with connect(), deprecated in python-control 0.10.
            warnings.filterwarnings("ignore", message=r"connect\(\) is deprecated", category=FutureWarning)
            warnings.filterwarnings("ignore", message="`connect`", category=DeprecationWarning)
            g = control.ss(*plant_abcd)
            ws = [None if m is None else control.ss(*m) for m in weights_abcd]
            k, _, (gamma, rcond) = control.mixsyn(g, *ws)
        conn.send(("ok", tuple(np.asarray(m, dtype=float) for m in (k.A, k.B, k.C, k.D)), float(gamma),
                   tuple(float(r) for r in np.ravel(rcond))))
    except Exception as err:                      # report everything: the parent turns it into DesignError
        conn.send(("error", type(err).__name__, getattr(err, "info", None), str(err).strip()))
    finally:
        conn.close()


def _check_d12(g, weights):
    """D12 = [-W_s(inf) G(inf); W_ks(inf); W_t(inf) G(inf)] must be nonzero (full column rank, SISO).

    SB10AD should report this as info = 3, but with python-control's initial gamma of 1e100 it
    was seen to run for over a minute instead; checking first answers at once.
    """
    dg = float(np.squeeze(control.ss(g).D))
    d = [0.0 if w is None else float(np.squeeze(control.ss(w).D)) for w in weights]
    d12 = np.array([-d[0] * dg, d[1], d[2] * dg])
    if not np.any(np.abs(d12) > 1e-12 * max(1.0, abs(dg))):
        raise DesignError("D12 = [-W_s G; W_ks; W_t G] at infinite frequency is zero, so the H-infinity problem is "
                          "singular (SB10AD info 3): w_ks needs a nonzero high-frequency gain; make it biproper "
                          "(as many zeros as poles), as default_weights does")


def _check_weight_poles(weights):
    for name, w in zip(_WEIGHT_NAMES, weights):
        if w is None:
            continue
        poles = control.poles(w)
        bad = poles[poles.real >= 0]
        if bad.size:
            raise DesignError(f"{name} has a pole at s = {complex(bad[0]):.3g} rad/s, on or right of the imaginary "
                              f"axis: the generalized plant is then not stabilizable; move it to a small "
                              f"negative frequency (an integral-like w_s uses a pole at 1e-4 x the crossover)")


def _grid_hz(systems):
    """Dense log grid from a decade below the slowest to a decade above the fastest dynamics, plus
    the natural frequencies themselves (where lightly damped peaks sit)."""
    mags = np.concatenate([np.abs(control.poles(s)) for s in systems if s is not None] + [np.zeros(0)])
    mags = mags[mags > 0] / (2 * np.pi)
    lo, hi = (mags.min() / 10, mags.max() * 10) if mags.size else (1e-2, 1e6)
    n = int(np.clip(400 * np.log10(hi / lo), 400, 8000))
    return np.unique(np.concatenate([np.geomspace(lo, hi, n), mags]))


def mixed_sensitivity(G, w_s, w_ks, w_t, time_limit_s=60.0, *, gamma_max=None, freq_hz=None,
                      start_method="spawn"):
    """Mixed-sensitivity H-infinity controller for the continuous plant ``G``, with a time limit.

    Parameters
    ----------
    G : SISO LTI, continuous
        Plant from controller output (V) to the reading (firmware V); include the loop's delay
        (e.g. ``G * control.tf(*control.pade(2e-4, 2))``) for a design meant for sampling.
    w_s, w_ks, w_t : SISO LTI, number or None
        Weights on S, K S and T, continuous, stable; w_ks must have a nonzero high-frequency gain.
        See :func:`default_weights`.
    time_limit_s : float, optional
        Wall-time limit of the synthesis, process start-up (about 1 to 2 s with "spawn")
        included, s. Default 60.
    gamma_max : float or None, optional
        If given, a gamma above it raises DesignError (e.g. 1.0 to demand the weighted specs).
        Default None: any gamma is returned, and ``meets_specs`` tells whether the specs hold.
    freq_hz : array_like of float or None, optional
        Grid for the achieved norms and the crossover, Hz. Default: a dense log grid spanning
        the plant's, the weights' and the controller's dynamics.
    start_method : {"spawn", "fork"}, optional
        How the child process starts. "spawn" (default) is safe with multithreaded BLAS but
        re-imports the calling script, which therefore needs ``if __name__ == "__main__":``;
        "fork" starts faster and needs no guard, but may deadlock if threads are running.

    Returns
    -------
    HinfResult

    Raises
    ------
    DesignError
        If synthesis does not finish within ``time_limit_s``; if SB10AD fails (its reason and
        which weight to change); if a weight has a pole on or right of the imaginary axis; if
        the returned controller does not stabilize G; if gamma exceeds ``gamma_max``.
    TypeError, ValueError
        For a plant or weight of the wrong kind (not SISO, discrete, no weight at all).

    Notes
    -----
    Infeasibility has a precise meaning here. SB10AD always returns the smallest gamma it
    finds; gamma >= 1 says the weighted specs cannot all hold at once in the stacked sense,
    and the achieved separate peaks (``closed_loop_norms``) say which ones fail. That is a
    result, not an error (``meets_specs`` is False), unless ``gamma_max`` asks for an error.
    Errors are reserved for a synthesis that cannot answer: time-out, or a SLICOT failure.

    The synthesis sees the plant and the weights after a diagonal state scaling (TB01ID) that
    leaves their transfer functions unchanged; the controller is returned in the caller's
    units. ``mixsyn`` starts the gamma search at 1e100 (python-control issue #152), so a
    badly posed problem may run until the time limit.
    """
    t0 = time.perf_counter()
    g = _as_siso(G, "G")
    if g.isdtime(strict=True):
        raise ValueError(f"G must be continuous-time (H-infinity synthesis here is continuous); it has "
                         f"dt = {g.dt}; use workbench.design.convex for a discrete plant")
    weights = [_as_siso(w, n, allow_none=True) for w, n in zip((w_s, w_ks, w_t), _WEIGHT_NAMES)]
    if all(w is None for w in weights):
        raise ValueError("at least one of w_s, w_ks, w_t must be given")
    for name, w in zip(_WEIGHT_NAMES, weights):
        if w is not None and w.isdtime(strict=True):
            raise ValueError(f"{name} must be continuous-time for H-infinity synthesis; it has dt = {w.dt}")
    limit = float(time_limit_s)
    if not (np.isfinite(limit) and limit > 0):
        raise ValueError(f"time_limit_s must be a positive number of seconds; got {time_limit_s!r}")
    if start_method not in _START_METHODS:
        raise ValueError(f"start_method must be one of {', '.join(_START_METHODS)}; got {start_method!r}")
    if gamma_max is not None and not (np.isfinite(gamma_max) and gamma_max > 0):
        raise ValueError(f"gamma_max must be a positive number or None; got {gamma_max!r}")
    _check_weight_poles(weights)
    _check_d12(g, weights)

    message = _run_with_limit(_balanced_matrices(g), [None if w is None else _balanced_matrices(w)
                                                      for w in weights], limit, start_method, t0)
    if message[0] != "ok":
        _, kind, info, text = message
        if info is not None and int(np.atleast_1d(info)[0]) in _SB10AD_ADVICE:
            code = int(np.atleast_1d(info)[0])
            raise DesignError(f"H-infinity synthesis failed: slycot SB10AD info = {code}: "
                              f"{_SB10AD_ADVICE[code]}")
        last = text.splitlines()[-1] if text else ""
        raise DesignError(f"H-infinity synthesis failed ({kind}: {last}); check that G and the weights "
                          f"are finite, proper and stable, or use the convex route")
    _, (ak, bk, ck, dk), gamma, rcond = message
    seconds = time.perf_counter() - t0
    k = control.ss(ak, bk, ck, dk)

    cl_poles = control.poles(control.feedback(control.ss(g), k))
    if cl_poles.size and np.max(cl_poles.real) >= 0:
        raise DesignError(f"H-infinity synthesis returned a controller that does not stabilize G (closed-loop "
                          f"pole at {complex(cl_poles[np.argmax(cl_poles.real)]):.3g} rad/s): a numerical "
                          f"failure (rcond = {', '.join(f'{r:.1e}' for r in rcond)}); move the w_s pole up, "
                          f"lower its bandwidth, or use the convex route")
    f = _grid_hz([g, *weights, k]) if freq_hz is None else np.asarray(freq_hz, dtype=float)
    resp = weighted_responses(g, k, *weights, f)
    norms = weighted_norms(g, k, *weights, f)
    if gamma_max is not None and gamma > gamma_max:
        worst = max(_NORM_KEYS, key=norms.get)
        raise DesignError(f"the weighted specs cannot be met: H-infinity gamma = {gamma:.3g} exceeds gamma_max = "
                          f"{gamma_max:g} (peaks |W_s S| = {norms['S']:.3g}, |W_ks K S| = {norms['KS']:.3g}, "
                          f"|W_t T| = {norms['T']:.3g}; the largest is {worst}); relax that weight, lower the "
                          f"crossover, or raise gamma_max")
    return HinfResult(controller=k, gamma=float(gamma), closed_loop_norms=norms,
                      meets_specs=bool(max(norms[key] for key in _NORM_KEYS) < 1.0),
                      crossover_hz=gain_crossover_hz(f, resp["L"]), rcond=tuple(rcond), seconds=seconds)


@contextlib.contextmanager
def _environment(overrides):
    """Set environment variables while a spawned child starts (it copies os.environ), then restore them."""
    saved = {key: os.environ.get(key) for key in overrides}
    os.environ.update(overrides)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _run_with_limit(plant_abcd, weights_abcd, limit, start_method, t0):
    """Run :func:`_mixsyn_worker` in a child process; kill it and raise DesignError after ``limit`` s."""
    ctx = multiprocessing.get_context(start_method)
    receiver, sender = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_mixsyn_worker, args=(sender, plant_abcd, weights_abcd), daemon=True,
                       name="workbench-mixsyn")
    # A spawned child loads its BLAS afresh and reads these; a forked one inherits the parent's threads.
    with _environment(_CHILD_ENV if start_method == "spawn" else {}):
        proc.start()
    sender.close()                                 # the child holds the only writer: EOF if it dies
    try:
        ready = receiver.poll(max(0.0, limit - (time.perf_counter() - t0)))
        if not ready:
            raise DesignError(f"H-infinity synthesis did not finish in {limit:g} s (time_limit_s, process start-up "
                              f"included) and was stopped; relax the weights (lower the w_s bandwidth or its "
                              f"low-frequency gain, soften the w_ks and w_t roll-offs), raise time_limit_s, or "
                              f"use the convex route (workbench.design.convex)")
        try:
            return receiver.recv()
        except EOFError:
            proc.join(timeout=5.0)
            raise DesignError(f"the H-infinity synthesis process died (exit code {proc.exitcode}) without an "
                              f"answer; with start_method='spawn' the calling script needs an "
                              f"`if __name__ == '__main__':` guard; otherwise check the plant and weights for "
                              f"non-finite or extreme values, or use the convex route") from None
    finally:
        receiver.close()
        if proc.is_alive():
            proc.kill()
        proc.join(timeout=5.0)
