"""Residual analysis of a calibrated model, one output channel at a time.

The residual is ``e = y_meas - y_model`` (measured minus model, as MATLAB's ``resid``) of one
channel: displacement, charge (from the integrated current, :func:`charge_from_current`) or
gauge. :func:`analyze_residual` reports its size (RMS, max, fit %), the whiteness and
independence tests of MATLAB's ``resid`` (Ljung, *System Identification*, 2nd ed., sec. 16.6),
its spectrum and its drift while the input is held constant (creep shows up there).

Definitions, and why
--------------------
* **Fit** (MATLAB ``compare``, NRMSE): ``100 (1 - ||y - yhat|| / ||y - mean(y)||)``; 100 is a
  perfect model, 0 is no better than the measured mean, negative is worse. NaN when the measured
  channel is constant (the ratio is undefined).
* **Correlations** (Ljung's biased estimates, means removed, divided by N, not N - |k|):
  ``R_e(k) = 1/N sum_t e(t) e(t-k)`` and ``R_eu(tau) = 1/N sum_t e(t) u(t-tau)``. The reported
  ``autocorr`` is ``R_e(k) / R_e(0)`` for k = 0 .. max_lag, ``crosscorr`` is
  ``R_eu(tau) / sqrt(R_e(0) R_u(0))`` for tau = -max_lag .. max_lag. **Sign convention**: a
  positive lag means the input leads the residual: a residual containing ``u(t - 3)`` peaks at
  tau = +3 (unmodelled dynamics or a wrong delay); peaks at tau < 0 (future inputs) point to
  feedback from the output to the input.
  Computed by zero-padded FFT (O(N log N); the zero lags as direct sums); the same numbers as
  the direct sums to round-off.
* **Whiteness band**: for a white residual ``sqrt(N) R_e(k) / R_e(0)`` is asymptotically N(0, 1)
  for k != 0, so ``autocorr_bound = z / sqrt(N)`` with ``z = Phi^-1((1 + confidence) / 2)``
  (2.58 at 99 %, per lag, two-sided).
* **Independence band** (Ljung sec. 16.6; what ``resid`` draws): if the residual is independent
  of the input, ``sqrt(N) R_eu(tau)`` is asymptotically normal with zero mean and variance
  ``P1 = sum_{k=-inf}^{inf} R_e(k) R_u(k)``, valid for a coloured residual and a coloured input
  alike (``P1 = R_e(0) R_u(0)`` when either is white). P1 is estimated by the plain sum over
  ``|k| <= max_lag`` of the estimated covariances, so on the normalized scale
  ``crosscorr_bound = z / sqrt(N) * sqrt(1 + 2 sum_{k=1}^{max_lag} rho_e(k) rho_u(k))``
  (``rho`` the normalized autocorrelations). Truncation can make that sum non-positive in
  contrived cases; then the Bartlett-weighted sum (weights ``1 - |k| / (max_lag + 1)``), which
  cannot be negative, is used, and the white bound ``z / sqrt(N)`` if that is zero too.
* **Decision** (``white``, ``independent``): at the band's confidence about ``1 - confidence`` of
  the lags fall outside by chance, so a count rule is used: the test passes when (a) the number
  of lags outside the band is at most the ``confidence`` quantile of Binomial(n_lags,
  1 - confidence) (the slack: e.g. 3 of 50 lags at 99 %, 5 of 50 at 95 %), and (b) no lag lies
  beyond the family-wise (Bonferroni) bound ``Phi^-1(1 - (1 - confidence) / (2 n_lags))`` in
  units of the per-lag sigma. (b) catches a single strong peak -- a delayed copy of a white
  input is one lag out of 2 max_lag + 1 -- that a fraction rule alone lets through. Whiteness
  uses lags 1 .. max_lag, independence all lags -max_lag .. max_lag. A residual (or input)
  that is constant (up to round-off, 1e-12 of its largest magnitude) has zero correlations
  (``autocorr[0]`` stays 1) and passes.
* **Spectrum**: Welch (``scipy.signal.welch``'s estimate, computed in one batch), Hann segments
  of ``min(256, N)`` samples, mean removed per segment, one-sided density in unit^2/Hz.
* **Holds**: maximal runs of samples whose input spread ``max(u) - min(u)`` stays within
  ``hold_tol`` (so every sample lies within ``hold_tol`` of the hold's mean, ``input_value``),
  found left to right, kept when ``t_end_s - t_start_s >= hold_min_s`` (and >= 2 samples).
  ``hold_tol`` defaults to 1e-3 of the input's peak-to-peak range. ``drift_rate_per_s`` is the
  least-squares slope of the residual over the hold, ``drift_total = drift_rate_per_s *
  (t_end_s - t_start_s)`` (the drift of the fitted line across the hold, robust to noise,
  unlike the difference of the end samples).

Samples must be evenly spaced in time (within 1e-3 of the median step, as
:func:`~workbench.calibrate.record.read_record` checks): lags are counted in samples and the
spectrum needs one sampling rate.
"""

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import fft, signal, stats
from scipy.integrate import cumulative_trapezoid

from .._kernel_args import readonly
from .record import CURRENT_KINDS

__all__ = ["ResidualReport", "analyze_residual", "analyze_record", "charge_from_current",
           "record_charge", "fit_percent", "CHANNEL_UNITS"]

#: Record channel key -> SI unit of the channels a residual is usually analysed for.
CHANNEL_UNITS = {"displacement_m": "m", "charge_c": "C", "gauge_v": "V", "current_a": "A",
                 "force_n": "N"}

_REL_JITTER = 1e-3


@dataclass(frozen=True, eq=False)        # eq=False: == on arrays is elementwise
class ResidualReport:
    """Residual analysis of one channel; see the module notes for every definition.

    Attributes
    ----------
    residual : ndarray
        ``y_meas - y_model``, in the channel's unit.
    rms, max_abs : float
        RMS and largest magnitude of the residual (mean included).
    fit_percent : float
        NRMSE fit as MATLAB ``compare``, percent.
    lags : ndarray
        0 .. max_lag, the lags of ``autocorr`` (samples).
    autocorr : ndarray
        Normalized autocorrelation of the residual, ``autocorr[0] == 1``.
    autocorr_bound : float
        Half-width of the whiteness band, ``z / sqrt(N)``.
    crosscorr_lags : ndarray
        -max_lag .. max_lag, the lags of ``crosscorr`` (positive: the input leads).
    crosscorr : ndarray
        Normalized cross-correlation of residual and input.
    crosscorr_bound : float
        Half-width of the independence band, ``z sqrt(P1 / N)`` on the normalized scale.
    white, independent : bool
        Outcomes of the whiteness and independence tests.
    freq_hz, psd : ndarray
        Welch estimate of the residual's one-sided power spectral density, unit^2/Hz.
    holds : list of dict
        ``{t_start_s, t_end_s, input_value, drift_rate_per_s, drift_total}`` per hold.
    units : dict
        Unit of each quantity above, built from the channel's unit.
    n : int
        Number of samples.
    confidence : float
        Confidence of the bands (per lag, two-sided).
    sample_period_s : float
        Mean sampling step.
    """

    residual: np.ndarray
    rms: float
    max_abs: float
    fit_percent: float
    lags: np.ndarray
    autocorr: np.ndarray
    autocorr_bound: float
    crosscorr_lags: np.ndarray
    crosscorr: np.ndarray
    crosscorr_bound: float
    white: bool
    independent: bool
    freq_hz: np.ndarray
    psd: np.ndarray
    holds: list
    units: dict
    n: int
    confidence: float
    sample_period_s: float


def _is_int(x):
    return not isinstance(x, bool) and isinstance(x, (int, np.integer))


def _is_real(x):
    return not isinstance(x, bool) and isinstance(x, (int, float, np.integer, np.floating))


def _series(t_s, others, names, min_n, uniform):
    """Validate time and same-length signals; return float arrays."""
    t = np.asarray(t_s, dtype=float)
    arrays = [np.asarray(a, dtype=float) for a in others]
    if t.ndim != 1:
        raise ValueError(f"t_s must be 1-D, got shape {t.shape}")
    for name, a in zip(names, arrays):
        if a.shape != t.shape:
            raise ValueError(f"{name} must have the shape of t_s {t.shape}, got {a.shape}")
    if t.size < min_n:
        raise ValueError(f"{t.size} samples, need at least {min_n}")
    for name, a in zip(("t_s",) + tuple(names), [t] + arrays):
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise ValueError(f"{name} must be finite; sample {int(bad[0])} is {float(a[bad[0]])}")
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise ValueError(f"t_s must increase strictly; sample {i} ({t[i]:.9g} s) is not after "
                         f"sample {i - 1} ({t[i - 1]:.9g} s)")
    if uniform:
        step = float(np.median(dt))
        off = np.flatnonzero(np.abs(dt - step) > _REL_JITTER * step)
        if off.size:
            i = int(off[0]) + 1
            raise ValueError(f"t_s must be evenly spaced (within {_REL_JITTER:g} of the median step "
                             f"{step:.6g} s); step {dt[i - 1]:.6g} s before sample {i}; resample "
                             f"on a uniform grid")
    return t, arrays


def fit_percent(y_meas, y_model):
    """NRMSE fit in percent, ``100 (1 - ||y - yhat|| / ||y - mean(y)||)`` (MATLAB ``compare``).

    NaN when ``y_meas`` is constant.
    """
    y = np.asarray(y_meas, dtype=float)
    yhat = np.asarray(y_model, dtype=float)
    den = float(np.linalg.norm(y - y.mean()))
    if not den > 0:
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / den))


def _covariances(a, b, max_lag):
    """Biased cross-covariances ``1/N sum_t a(t) b(t - k)``, k = -max_lag .. max_lag, means removed.

    The direct sums, one dot product of record length per lag: the reference that
    :func:`_covariance_set` (FFT) is tested against.
    """
    a = a - a.mean()
    b = b - b.mean()
    n = a.size
    out = np.empty(2 * max_lag + 1)
    for j, k in enumerate(range(-max_lag, max_lag + 1)):
        out[j] = (a[k:] @ b[: n - k] if k >= 0 else a[: n + k] @ b[-k:]) / n
    return out


def _covariance_set(e, u, max_lag):
    """``R_e(k)``, ``R_u(k)`` for k = 0 .. max_lag and ``R_eu(tau)`` for tau = -max_lag .. max_lag.

    Same definitions as :func:`_covariances` (means removed, biased, divided by N), computed
    from two zero-padded real FFTs: with ``nfft >= N + max_lag`` the circular correlation
    ``irfft(A conj(B))`` holds ``sum_t a(t) b(t - k)`` at index k for k >= 0 and at
    ``nfft + k`` for k < 0, with no wrap-around for ``|k| <= max_lag``. O(N log N) instead of
    the direct sums' O(N max_lag). The zero-lag autocovariances are the direct sums
    ``a @ a / N`` (exactly as before, so the constant-signal test and ``autocorr[0]`` do not
    see FFT round-off); the other lags agree with the direct sums to round-off (~1e-15 of
    ``sqrt(R_a(0) R_b(0))``).
    """
    e = e - e.mean()
    u = u - u.mean()
    n = e.size
    nfft = fft.next_fast_len(n + max_lag, real=True)
    fe = fft.rfft(e, nfft)
    fu = fft.rfft(u, nfft)
    r_e = fft.irfft(fe * fe.conj(), nfft)[: max_lag + 1] / n
    r_u = fft.irfft(fu * fu.conj(), nfft)[: max_lag + 1] / n
    c = fft.irfft(fe * fu.conj(), nfft)
    r_eu = np.r_[c[nfft - max_lag:], c[: max_lag + 1]] / n
    r_e[0] = (e @ e) / n
    r_u[0] = (u @ u) / n
    return r_e, r_u, r_eu


def _welch(x, fs, nperseg):
    """``scipy.signal.welch(x, fs=fs, nperseg=nperseg, detrend="constant", scaling="density")``.

    The same estimate (periodic Hann window, 50 % overlap, trailing samples that fill no
    segment dropped, mean removed per segment, one-sided density, segments averaged), with the
    segments transformed in one batch: recent scipy runs ``welch`` through ``ShortTimeFFT``,
    which detrends and transforms segment by segment in Python (~2,700 calls for 350,000
    samples, most of this function's time). Agrees with scipy to round-off (tested).
    """
    step = nperseg - nperseg // 2
    win = signal.get_window("hann", nperseg)
    segs = np.lib.stride_tricks.sliding_window_view(x, nperseg)[::step]
    segs = segs - segs.mean(axis=1, keepdims=True)
    spec = np.abs(fft.rfft(segs * win, axis=1)) ** 2
    psd = spec.mean(axis=0) / (fs * float(win @ win))
    if nperseg % 2:
        psd[1:] *= 2.0
    else:
        psd[1:-1] *= 2.0
    return fft.rfftfreq(nperseg, 1.0 / fs), psd


def _passes(r, bound, confidence):
    """The count rule and the family-wise rule of the module notes."""
    m = r.size
    alpha = 1.0 - confidence
    allowed = int(stats.binom.ppf(confidence, m, alpha))
    z = stats.norm.ppf(0.5 + confidence / 2.0)
    z_family = stats.norm.ppf(1.0 - alpha / (2.0 * m))
    outside = int(np.count_nonzero(np.abs(r) > bound))
    return bool(outside <= allowed and np.max(np.abs(r)) <= bound * z_family / z)


def _hold_spans(t, u, tol, min_s):
    """Index spans ``(i, j)`` (samples i .. j-1) of the holds of the module notes.

    Maximal runs of spread ``max(u) - min(u) <= tol``, grown left to right (a new run starts at
    the sample that broke the previous one), kept when ``t[j-1] - t[i] >= min_s`` and
    ``j - i >= 2``. Returns an int array of shape (n_holds, 2).
    """
    # A hold lies inside a run of consecutive steps |du| <= tol; runs too short are skipped at
    # once in numpy; the greedy growth inside the remaining runs is one compiled pass, O(1) per
    # sample (a slowly moving input otherwise costs a Python iteration every few samples).
    still = np.abs(np.diff(u)) <= tol
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
    a, b = edges[::2], edges[1::2] + 1                       # samples a .. b-1 of one run
    keep = t[b - 1] - t[a] >= min_s
    if not np.any(keep):
        return np.empty((0, 2), dtype=np.int64)
    # read-only views of t, u (their dtype kept): one compiled signature whether the caller's arrays are writable
    return _greedy_spans(readonly(t, None), readonly(u, None), readonly(a[keep], np.int64), readonly(b[keep], np.int64),
                         float(tol), float(min_s))


@njit(cache=True)
def _greedy_spans(t, u, starts, stops, tol, min_s):
    """The left-to-right growth of :func:`_hold_spans` inside runs ``starts[r] .. stops[r]-1``."""
    out = np.empty((t.size // 2 + 1, 2), dtype=np.int64)
    m = 0
    for r in range(starts.size):
        i, b = starts[r], stops[r]
        while i < b - 1:
            lo = u[i]
            hi = u[i]
            j = i + 1
            while j < b:
                hi = max(hi, u[j])
                lo = min(lo, u[j])
                if hi - lo > tol:
                    break
                j += 1
            if j - i >= 2 and t[j - 1] - t[i] >= min_s:
                out[m, 0] = i
                out[m, 1] = j
                m += 1
            i = j
    return out[:m].copy()


def _holds(t, u, e, tol, min_s):
    """Constant-input segments (spread <= tol, duration >= min_s) and the residual's drift in each."""
    return [_drift(t[i:j], u[i:j], e[i:j]) for i, j in _hold_spans(t, u, tol, min_s)]


def _drift(t, u, e):
    """One hold's entry: the least-squares slope of the residual and its total over the hold."""
    tc = t - t.mean()
    rate = float(tc @ (e - e.mean()) / (tc @ tc))
    duration = float(t[-1] - t[0])
    return {"t_start_s": float(t[0]), "t_end_s": float(t[-1]), "input_value": float(np.mean(u)),
            "drift_rate_per_s": rate, "drift_total": rate * duration}


def analyze_residual(t_s, u, y_meas, y_model, max_lag=50, confidence=0.99, hold_min_s=1.0,
                     hold_tol=None, unit=None, nperseg=256):
    """Residual analysis of one channel (see the module notes for the definitions).

    Parameters
    ----------
    t_s : array_like
        Sample times in s, strictly increasing and evenly spaced.
    u : array_like
        The input (e.g. the voltage in V), same length.
    y_meas, y_model : array_like
        Measured channel and the model's prediction of it, same length and unit.
    max_lag : int
        Largest correlation lag in samples (>= 1); N must be >= 2 max_lag + 10.
    confidence : float
        Per-lag two-sided confidence of the bands, 0 < confidence < 1 (0.99 as ``resid``).
    hold_min_s : float
        Shortest constant-input hold reported, s (>= 0).
    hold_tol : float, optional
        Largest input spread inside a hold (default 1e-3 of the input's peak-to-peak range).
    unit : str, optional
        The channel's unit, used only to label ``units`` (default ``"[y]"``).
    nperseg : int
        Welch segment length, clipped to N.

    Raises
    ------
    ValueError
        Arrays of different lengths, non-finite values, too few samples, uneven or
        non-increasing time, or an out-of-range parameter.
    """
    if not _is_int(max_lag) or max_lag < 1:
        raise ValueError(f"max_lag must be an integer >= 1, got {max_lag!r}")
    if not _is_real(confidence) or not 0 < confidence < 1:
        raise ValueError(f"confidence must be a number with 0 < confidence < 1, e.g. 0.99, "
                         f"got {confidence!r}")
    if not _is_real(hold_min_s) or not (np.isfinite(hold_min_s) and hold_min_s >= 0):
        raise ValueError(f"hold_min_s must be a finite number >= 0, got {hold_min_s!r}")
    if hold_tol is not None and (not _is_real(hold_tol) or not (np.isfinite(hold_tol) and hold_tol >= 0)):
        raise ValueError(f"hold_tol must be None or a finite number >= 0, got {hold_tol!r}")
    if not _is_int(nperseg) or nperseg < 2:
        raise ValueError(f"nperseg must be an integer >= 2, got {nperseg!r}")
    t, (u, y, yhat) = _series(t_s, (u, y_meas, y_model), ("u", "y_meas", "y_model"),
                              2 * max_lag + 10, uniform=True)
    n = t.size
    e = y - yhat
    z = float(stats.norm.ppf(0.5 + confidence / 2.0))
    white_bound = z / np.sqrt(n)

    # k = 0 .. max_lag for r_e, r_u; tau = -max_lag .. max_lag for r_eu (FFT, see _covariance_set)
    r_e, r_u, r_eu = _covariance_set(e, u, max_lag)
    # a signal constant up to round-off (e.g. a constant model error) has no correlation structure
    e_varies = np.sqrt(r_e[0]) > 1e-12 * np.max(np.abs(e))
    u_varies = np.sqrt(r_u[0]) > 1e-12 * np.max(np.abs(u))
    if e_varies:
        autocorr = r_e / r_e[0]
        autocorr[0] = 1.0
    else:                                                   # constant residual: no structure
        autocorr = np.zeros(max_lag + 1)
        autocorr[0] = 1.0
    rho_u = r_u / r_u[0] if u_varies else np.r_[1.0, np.zeros(max_lag)]
    if e_varies and u_varies:
        crosscorr = r_eu / np.sqrt(r_e[0] * r_u[0])
    else:
        crosscorr = np.zeros(2 * max_lag + 1)
    p1 = 1.0 + 2.0 * float(autocorr[1:] @ rho_u[1:])       # P1 / (R_e(0) R_u(0)), |k| <= max_lag
    if not p1 > 0:
        w = 1.0 - np.arange(1, max_lag + 1) / (max_lag + 1.0)
        p1 = 1.0 + 2.0 * float(w @ (autocorr[1:] * rho_u[1:]))
        if not p1 > 0:
            p1 = 1.0
    cross_bound = white_bound * np.sqrt(p1)

    fs = (n - 1) / (t[-1] - t[0])
    freq, psd = _welch(e, fs, min(nperseg, n))
    tol = 1e-3 * float(np.ptp(u)) if hold_tol is None else float(hold_tol)
    holds = _holds(t, u, e, tol, float(hold_min_s))

    y_unit = "[y]" if unit is None else str(unit)
    units = {"residual": y_unit, "rms": y_unit, "max_abs": y_unit, "fit_percent": "%",
             "lags": "samples", "autocorr": "1", "crosscorr": "1", "freq_hz": "Hz",
             "psd": f"{y_unit}^2/Hz", "t_start_s": "s", "t_end_s": "s", "input_value": "[u]",
             "drift_rate_per_s": f"{y_unit}/s", "drift_total": y_unit}
    arrays = [e, np.arange(max_lag + 1), autocorr, np.arange(-max_lag, max_lag + 1), crosscorr,
              freq, psd]
    for a in arrays:
        a.flags.writeable = False
    e, lags, autocorr, xlags, crosscorr, freq, psd = arrays
    return ResidualReport(
        residual=e, rms=float(np.sqrt(np.mean(e * e))), max_abs=float(np.max(np.abs(e))),
        fit_percent=fit_percent(y, yhat), lags=lags, autocorr=autocorr,
        autocorr_bound=float(white_bound), crosscorr_lags=xlags, crosscorr=crosscorr,
        crosscorr_bound=float(cross_bound),
        white=_passes(autocorr[1:], white_bound, confidence),
        independent=_passes(crosscorr, cross_bound, confidence),
        freq_hz=freq, psd=psd, holds=holds, units=units, n=int(n), confidence=float(confidence),
        sample_period_s=float(1.0 / fs))


def charge_from_current(t_s, i_a, q0=0.0, current="sampled"):
    """Charge in C from a current record in A, by the record's current convention.

    Parameters
    ----------
    t_s : array_like
        Sample times, s; may be uneven but must increase strictly.
    i_a : array_like
        The recorded current, A.
    q0 : float
        The charge at the first sample, C (an integrated charge has no absolute zero).
    current : {"sampled", "averaged"}
        What each current sample is (the record's ``# current:`` header,
        :data:`~workbench.calibrate.record.CURRENT_KINDS`):

        * ``"sampled"`` -- the instantaneous current at the sample time (a monitor sampled by an
          ordinary ADC): ``q`` is the cumulative trapezoid, ``q_k = q_{k-1} + (i_{k-1} + i_k)
          (t_k - t_{k-1}) / 2``;
        * ``"averaged"`` -- the mean current over the interval ENDING at the sample (an
          integrating ADC, or the project's simulator, ``plant.kernels.pzt_run``): the running
          sum ``q_k = q_{k-1} + i_k (t_k - t_{k-1})`` is exact. Trapezoid on such a record lags
          the charge by ``(i_k - i_{k-1}) dt / 2`` per step, half a sample.

    Returns
    -------
    ndarray
        The charge at each sample, C; the first is ``q0``.
    """
    if not _is_real(q0) or not np.isfinite(q0):
        raise ValueError(f"q0 must be a finite number, got {q0!r}")
    if current not in CURRENT_KINDS:
        raise ValueError(f"current must be one of {', '.join(CURRENT_KINDS)}, got {current!r}")
    t, (i,) = _series(t_s, (i_a,), ("i_a",), 2, uniform=False)
    if current == "averaged":
        q = np.empty_like(i)
        q[0] = 0.0
        np.cumsum(i[1:] * np.diff(t), out=q[1:])
        return q + float(q0)
    return cumulative_trapezoid(i, t, initial=0.0) + float(q0)


def record_charge(record, q0=0.0):
    """The record's charge in C: its ``charge_c`` channel, else its current integrated by
    :func:`charge_from_current` under the record's ``# current:`` convention (default
    ``"sampled"``) starting at ``q0``; None when the record has neither."""
    if "charge_c" in record.channels:
        return record.channels["charge_c"]
    if "current_a" not in record.channels:
        return None
    return charge_from_current(record.t_s, record.channels["current_a"], q0=q0,
                               current=record.current_kind)


def analyze_record(record, predicted, **kwargs):
    """Residual analysis of each predicted channel of a :class:`~workbench.calibrate.record.Record`.

    ``predicted`` maps channel keys (``displacement_m``, ``charge_c``, ``gauge_v``, ...) to the
    model's prediction over the record. The input is the record's ``voltage_v``. A ``charge_c``
    prediction is compared with the record's charge, or, when it has none, with its current
    integrated by :func:`record_charge` (the record's ``# current:`` convention) starting at the
    prediction's first value (the integrated charge has no absolute zero). Other keyword arguments go to
    :func:`analyze_residual`; returns ``{key: ResidualReport}``.
    """
    out = {}
    for key, y_model in predicted.items():
        if key in record.channels:
            y = record.channels[key]
        elif key == "charge_c" and "current_a" in record.channels:
            y = record_charge(record, q0=float(np.asarray(y_model, dtype=float)[0]))
        else:
            raise ValueError(f"the record has no {key!r} channel"
                             + (" and no current to integrate" if key == "charge_c" else "")
                             + f"; it has {', '.join(sorted(record.channels))}")
        options = {"unit": CHANNEL_UNITS.get(key), **kwargs}
        out[key] = analyze_residual(record.t_s, record.channels["voltage_v"], y, y_model, **options)
    return out
