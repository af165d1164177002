"""Stability margins of a SISO loop known as a frequency response, and of a family of such loops.

The loop L is given as complex samples on an increasing frequency grid: a measured or
describing-function response is all the family has, so everything here works on samples
and :func:`margins_of` only evaluates an LTI model on a grid first.

Crossings are located between grid samples by linear interpolation against log
frequency: of ln|L| for gain crossovers (|L| = 1), and of the unwrapped phase for phase
crossovers (phase = odd multiple of 180 deg, i.e. L on the negative real axis). The
other quantity at a crossing is interpolated at the same fraction of the interval.
Samples that are NaN, infinite or zero split the curve into segments; nothing is
interpolated or unwrapped across a split. Peaks (|S|, |T|, |S - 1/2|) are refined by the
parabola through the largest sample and its two neighbours (dB against log frequency).

Frequencies are in hertz, gains in dB and phases in degrees because these are reported
quantities; the field names carry the units.
"""

import math
from dataclasses import asdict, dataclass

import control
import numpy as np

__all__ = ["Margins", "loop_margins", "margins_of", "family_margins", "response", "closed_loop_bandwidth_hz"]

_DB_PER_NEPER = 20.0 / math.log(10.0)
_DEFAULT_POINTS = 2000
_DEFAULT_LOW_HZ = 0.01
_DEFAULT_HIGH_HZ = 1e5          # continuous loops: well past any piezo-servo crossover
_BELOW_NYQUIST = 1.0 - 1e-6     # discrete loops: L is real at Nyquist, so stop just short of it


@dataclass(frozen=True)
class Margins:
    """Stability margins of one SISO loop L.

    Attributes
    ----------
    gain_margin_db : float
        Gain margin, dB, at the phase crossover whose gain margin is smallest in magnitude
        (negative: a gain *decrease* reaches -1). +inf if L never crosses the negative
        real axis.
    gm_freq_hz : float
        Frequency of that phase crossover, Hz (nan if none).
    phase_margin_deg : float
        Phase margin, deg, in [-180, 180), at the gain crossover whose margin is smallest
        in magnitude. +inf if |L| never crosses 1.
    pm_freq_hz : float
        Frequency of that gain crossover, Hz (nan if none).
    crossover_hz : float
        Highest gain-crossover frequency, Hz (nan if none).
    delay_margin_s : float
        Smallest extra loop delay that puts L on -1 at a gain crossover, s: min over
        crossovers of (PM_i mod 360 deg) / omega_i. +inf if there is no gain crossover.
    dm_freq_hz : float
        Frequency of the gain crossover that sets the delay margin, Hz (nan if none).
    disk_margin : float
        Balanced (sigma = 0) disk margin alpha = 1 / max |S - 1/2|, dimensionless.
    disk_freq_hz : float
        Frequency of max |S - 1/2|, Hz.
    disk_gain_margin_db : float
        Disk-based gain margin 20 log10((1 + alpha/2) / (1 - alpha/2)), dB; +inf if alpha >= 2.
    disk_phase_margin_deg : float
        Disk-based phase margin 2 atan(alpha / 2), deg.
    s_peak_db, s_peak_hz : float
        Peak of |S| = |1 / (1 + L)|, dB, and its frequency, Hz.
    t_peak_db, t_peak_hz : float
        Peak of |T| = |L / (1 + L)|, dB, and its frequency, Hz.
    """

    gain_margin_db: float
    gm_freq_hz: float
    phase_margin_deg: float
    pm_freq_hz: float
    crossover_hz: float
    delay_margin_s: float
    dm_freq_hz: float
    disk_margin: float
    disk_freq_hz: float
    disk_gain_margin_db: float
    disk_phase_margin_deg: float
    s_peak_db: float
    s_peak_hz: float
    t_peak_db: float
    t_peak_hz: float

    def as_dict(self):
        """Fields as a dict of Python floats (inf and nan kept; the caller converts for JSON)."""
        return {name: float(value) for name, value in asdict(self).items()}


def _check_response(freq_hz, loop):
    f = np.asarray(freq_hz, dtype=float)
    resp = np.asarray(loop, dtype=complex)
    if f.ndim != 1 or f.size < 2:
        raise ValueError(f"freq_hz must be a 1-D array of at least 2 frequencies; got shape {f.shape}")
    if resp.shape != f.shape:
        raise ValueError(f"loop must have the shape of freq_hz {f.shape}; got {resp.shape}")
    if not (np.all(np.isfinite(f)) and f[0] > 0 and np.all(np.diff(f) > 0)):
        raise ValueError("freq_hz must be finite, positive and strictly increasing, in Hz; "
                         f"got values from {f.min()} to {f.max()} Hz")
    return f, resp


def _runs(valid):
    """(start, stop) index pairs of the runs of True in ``valid``."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], valid.astype(np.int8), [0]))))
    return zip(edges[::2], edges[1::2])


def _crossings(logf, logmag, phase):
    """Gain crossovers, rows (logf, phase), and phase crossovers, rows (logf, logmag), of one segment."""
    # |L| = 1: ln|L| changes sign; a sample exactly at 0 counts once, on the side it is left.
    i = np.flatnonzero((logmag[:-1] >= 0) != (logmag[1:] >= 0))
    t = -logmag[i] / (logmag[i + 1] - logmag[i])
    gain = np.stack((logf[i] + t * (logf[i + 1] - logf[i]), phase[i] + t * (phase[i + 1] - phase[i])))
    # Negative real axis: the unwrapped phase passes (2m - 1) pi, i.e. floor((phase + pi) / 2 pi)
    # changes; unwrapped steps are below pi, so an interval holds at most one such level.
    band = np.floor((phase + np.pi) / (2 * np.pi))
    i = np.flatnonzero(band[:-1] != band[1:])
    level = (2 * np.maximum(band[i], band[i + 1]) - 1) * np.pi
    t = (level - phase[i]) / (phase[i + 1] - phase[i])
    cross = np.stack((logf[i] + t * (logf[i + 1] - logf[i]), logmag[i] + t * (logmag[i + 1] - logmag[i])))
    return gain, cross


def _peak(logf, y):
    """Largest y (ignoring NaN) and its log frequency, refined by a parabola through 3 samples."""
    k = int(np.nanargmax(y))
    if not (0 < k < y.size - 1 and np.isfinite(y[k - 1:k + 2]).all()):
        return float(y[k]), float(logf[k])
    h0, h1 = logf[k] - logf[k - 1], logf[k + 1] - logf[k]
    d0, d1 = (y[k] - y[k - 1]) / h0, (y[k + 1] - y[k]) / h1
    curv = (d1 - d0) / (h0 + h1)
    if curv >= 0:  # flat top: the sample is the peak
        return float(y[k]), float(logf[k])
    slope = (d0 * h1 + d1 * h0) / (h0 + h1)
    return float(y[k] - slope ** 2 / (4 * curv)), float(logf[k] - slope / (2 * curv))


def loop_margins(freq_hz, loop):
    """Stability margins of a SISO loop from its frequency response.

    Parameters
    ----------
    freq_hz : array_like of float
        Frequencies, Hz, positive and strictly increasing.
    loop : array_like of complex
        Loop response L(j omega) (or L(exp(j omega T)) for a discrete loop) at ``freq_hz``.
        NaN entries mark missing samples and split the curve.

    Returns
    -------
    Margins
        Gain, phase, delay and disk margins, crossover frequency, S and T peaks.

    Raises
    ------
    ValueError
        If ``freq_hz`` is not 1-D, positive, finite and increasing, if ``loop`` has
        another shape, or if no sample of ``loop`` is finite.

    Notes
    -----
    Among several crossovers the margin smallest in magnitude is reported (as
    python-control's ``stability_margins`` does): a negative gain margin of a
    conditionally stable loop is a distance to -1 like a positive one. Whether the
    nominal closed loop is stable cannot be told from the response alone and is not
    checked. The disk margin is the balanced one of [1]_: alpha = 1 / max |S - 1/2|,
    S = 1 / (1 + L), from the refined peak of |S - 1/2|.

    References
    ----------
    .. [1] P. Seiler, A. Packard, P. Gahinet, "An introduction to disk margins",
       IEEE Control Systems Magazine 40(5), 2020.

    Examples
    --------
    The loop 2 / (j omega + 1) crosses |L| = 1 at omega = sqrt(3), with phase -60 deg:

    >>> w = np.logspace(-2, 2, 4001)
    >>> m = loop_margins(w / (2 * np.pi), 2 / (1j * w + 1))
    >>> round(m.phase_margin_deg, 3), round(m.crossover_hz * 2 * np.pi, 4), m.gain_margin_db
    (120.0, 1.7321, inf)
    """
    f, resp = _check_response(freq_hz, loop)
    finite = np.isfinite(resp)
    if not finite.any():
        raise ValueError("loop has no finite sample; drop this loop rather than measure it")
    mag = np.abs(resp)
    logf = np.log(f)

    gains, phases = [np.empty((2, 0))], [np.empty((2, 0))]
    for start, stop in _runs(finite & (mag > 0)):  # |L| = 0 has no phase: a split too
        seg = slice(start, stop)
        gain, phase = _crossings(logf[seg], np.log(mag[seg]), np.unwrap(np.angle(resp[seg])))
        gains.append(gain)
        phases.append(phase)
    gain_logf, gain_phase = np.concatenate(gains, axis=1)
    phase_logf, phase_logmag = np.concatenate(phases, axis=1)

    inf, nan = math.inf, math.nan
    gm_db, gm_hz = inf, nan
    if phase_logf.size:
        k = np.argmin(np.abs(phase_logmag))
        gm_db, gm_hz = float(-_DB_PER_NEPER * phase_logmag[k]), math.exp(phase_logf[k])

    pm_deg, pm_hz, crossover_hz, delay_s, dm_hz = inf, nan, nan, inf, nan
    if gain_logf.size:
        pm_rad = np.mod(gain_phase, 2 * np.pi) - np.pi  # [-pi, pi), as python-control
        k = np.argmin(np.abs(pm_rad))
        pm_deg, pm_hz = math.degrees(pm_rad[k]), math.exp(gain_logf[k])
        crossover_hz = math.exp(gain_logf.max())
        # An added delay only lags, so a negative margin needs a further full turn.
        delays = np.mod(pm_rad, 2 * np.pi) / (2 * np.pi * np.exp(gain_logf))
        k = np.argmin(delays)
        delay_s, dm_hz = float(delays[k]), math.exp(gain_logf[k])

    # 1 + L = 0 on a sample is an infinite peak and S = 1/2 is -inf dB: both are the right answer.
    with np.errstate(divide="ignore", invalid="ignore"):
        sens = 1.0 / (1.0 + resp)
        s_db, s_logf = _peak(logf, _DB_PER_NEPER * np.log(np.abs(sens)))
        t_db, t_logf = _peak(logf, _DB_PER_NEPER * np.log(np.abs(resp * sens)))
        d_db, d_logf = _peak(logf, _DB_PER_NEPER * np.log(np.abs(sens - 0.5)))
    alpha = 10.0 ** (-d_db / 20.0)
    disk_gm_db = _DB_PER_NEPER * math.log((1 + alpha / 2) / (1 - alpha / 2)) if alpha < 2 else inf

    return Margins(
        gain_margin_db=gm_db, gm_freq_hz=gm_hz,
        phase_margin_deg=pm_deg, pm_freq_hz=pm_hz, crossover_hz=crossover_hz,
        delay_margin_s=delay_s, dm_freq_hz=dm_hz,
        disk_margin=alpha, disk_freq_hz=math.exp(d_logf),
        disk_gain_margin_db=disk_gm_db, disk_phase_margin_deg=math.degrees(2 * math.atan(alpha / 2)),
        s_peak_db=s_db, s_peak_hz=math.exp(s_logf), t_peak_db=t_db, t_peak_hz=math.exp(t_logf))


def margins_of(loop_sys, freq_hz=None):
    """Stability margins of a python-control SISO loop, evaluated on a frequency grid.

    Parameters
    ----------
    loop_sys : control.LTI
        Loop transfer function C G, continuous or discrete (with a numeric ``dt``, s).
    freq_hz : array_like of float, optional
        Evaluation grid, Hz. Default: 2000 log-spaced points from 0.01 Hz to just below
        the Nyquist frequency (discrete) or to 1e5 Hz (continuous).

    Returns
    -------
    Margins
        As :func:`loop_margins`.

    Raises
    ------
    TypeError
        If ``loop_sys`` is not a python-control LTI system.
    ValueError
        If ``loop_sys`` is not SISO, is discrete with an unspecified sample time or with
        ``freq_hz`` above its Nyquist frequency, or the grid is invalid (see :func:`loop_margins`).

    Examples
    --------
    1 / (s (s + 1)) crosses over at omega^2 = (sqrt(5) - 1) / 2 with PM = 90 - atan(omega) deg:

    >>> m = margins_of(control.tf([1], [1, 1, 0]))
    >>> round(m.phase_margin_deg, 2), m.gain_margin_db
    (51.83, inf)
    """
    if not isinstance(loop_sys, control.LTI):
        raise TypeError(f"loop_sys must be a python-control LTI system (tf or ss); got {type(loop_sys).__name__}")
    if not loop_sys.issiso():
        raise ValueError(f"loop_sys must be SISO; it has {loop_sys.ninputs} inputs and "
                         f"{loop_sys.noutputs} outputs")
    discrete = loop_sys.isdtime(strict=True)
    if discrete and loop_sys.dt is True:
        raise ValueError("loop_sys is discrete with an unspecified sample time (dt=True); "
                         "give it a numeric dt in seconds, e.g. 1e-4")
    if freq_hz is None:
        high_hz = _BELOW_NYQUIST * 0.5 / loop_sys.dt if discrete else _DEFAULT_HIGH_HZ
        freq_hz = np.geomspace(_DEFAULT_LOW_HZ, high_hz, _DEFAULT_POINTS)
    f = np.asarray(freq_hz, dtype=float)
    if discrete and f.size and np.max(f) > 0.5 / loop_sys.dt:
        raise ValueError(f"freq_hz reaches {np.max(f)} Hz, above the Nyquist frequency {0.5 / loop_sys.dt} Hz "
                         f"of loop_sys (dt = {loop_sys.dt} s); a discrete response aliases there")
    s = 2j * np.pi * f
    resp = loop_sys(np.exp(s * loop_sys.dt) if discrete else s, squeeze=True, warn_infinite=False)
    return loop_margins(f, np.atleast_1d(resp))


def response(sys, freq_hz):
    """Frequency response of a SISO python-control system on ``freq_hz`` (Hz), vectorized.

    The same values as ``control.frequency_response(sys, 2 pi f).complex`` (continuous:
    at s = j 2 pi f; discrete: at z = exp(j 2 pi f dt)), computed as C (s I - A)^-1 B + D
    with one batched solve instead of one slycot call per frequency, which is what the
    design searches spend their time on otherwise.
    """
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    s = 2j * np.pi * f
    if sys.isdtime(strict=True):
        s = np.exp(s * sys.dt)
    if isinstance(sys, control.TransferFunction):
        num, den = np.asarray(sys.num[0][0], float), np.asarray(sys.den[0][0], float)
        return np.polyval(num, s) / np.polyval(den, s)
    a, b, c, d = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
    if a.shape[0] == 0:
        return np.full(f.shape, complex(d[0, 0]))
    m = s[:, None, None] * np.eye(a.shape[0]) - a
    x = np.linalg.solve(m, np.broadcast_to(b[:, :1].astype(complex), (s.size,) + b[:, :1].shape))
    return (c[:1] @ x)[:, 0, 0] + d[0, 0]


# metric -> (frequency field, key whose smallest value is the worst member)
_WORST = {
    "gain_margin_db": ("gm_freq_hz", abs),
    "phase_margin_deg": ("pm_freq_hz", abs),
    "delay_margin_s": ("dm_freq_hz", float),
    "disk_margin": ("disk_freq_hz", float),
    "s_peak_db": ("s_peak_hz", lambda v: -v),
    "t_peak_db": ("t_peak_hz", lambda v: -v),
}


def _pick(rows, metric, freq_field, key):
    usable = [r for r in rows if not math.isnan(r[metric])]
    if not usable:
        return {"value": math.nan, "member": None, "freq_hz": math.nan}
    row = min(usable, key=lambda r: key(r[metric]))  # ties: the first member in order
    return {"value": row[metric], "member": row["member"], "freq_hz": row[freq_field]}


def family_margins(freq_hz, loops):
    """Margins of every member of a loop family, and the worst member for each metric.

    Parameters
    ----------
    freq_hz : array_like of float
        Common frequency grid, Hz.
    loops : dict of str to array_like of complex
        Member name -> loop response on ``freq_hz`` (NaN where the member has no sample).

    Returns
    -------
    rows : list of dict
        One per member, in ``loops`` order: ``member`` plus the :class:`Margins` fields.
    worst : dict
        Metric -> ``{"value", "member", "freq_hz"}``. The smallest is worst for
        ``gain_margin_db`` and ``phase_margin_deg`` (in magnitude, as within a loop),
        ``delay_margin_s`` and ``disk_margin``; the largest for ``s_peak_db`` and
        ``t_peak_db``. ``crossover_hz_min`` and ``crossover_hz_max`` give the range of
        crossover frequencies (members without a crossover are skipped; member None if
        no member has one). Ties go to the first member.

    Raises
    ------
    ValueError
        If ``loops`` is empty or a member's response is invalid (the message names it).
    """
    if not loops:
        raise ValueError("loops is empty; give at least one member as name -> complex response")
    rows = []
    for name, loop in loops.items():
        try:
            margins = loop_margins(freq_hz, loop)
        except ValueError as err:
            raise ValueError(f"family member {name!r}: {err}") from err
        rows.append({"member": name, **margins.as_dict()})
    worst = {metric: _pick(rows, metric, freq, key) for metric, (freq, key) in _WORST.items()}
    worst["crossover_hz_min"] = _pick(rows, "crossover_hz", "crossover_hz", float)
    worst["crossover_hz_max"] = _pick(rows, "crossover_hz", "crossover_hz", lambda v: -v)
    return rows, worst


def closed_loop_bandwidth_hz(freq_hz, loop, reference="unity"):
    """The -3 dB bandwidth of T = L (I + L)^-1 from a loop's frequency response, per channel, Hz.

    The first frequency where |T_ii| falls below 1/sqrt(2) of the reference, interpolated in log
    frequency and dB; NaN when it never does, the first frequency when it starts below.

    Parameters
    ----------
    freq_hz : array_like, shape (n,)
    loop : array_like of complex, shape (n,) (SISO) or (n, k, k) (MIMO, T's diagonal)
    reference : {"unity", "low_frequency"}
        1 (a loop with integral action), or |T_ii| at the first frequency.

    Returns
    -------
    float (SISO) or ndarray of shape (k,)
    """
    f = np.asarray(freq_hz, float)
    arr = np.asarray(loop, complex)
    siso = arr.ndim == 1
    if siso:
        arr = arr[:, None, None]
    t = arr @ np.linalg.inv(np.eye(arr.shape[1])[None] + arr)
    out = []
    for i in range(arr.shape[1]):
        mag = np.abs(t[:, i, i])
        ref = 1.0 if reference == "unity" else mag[0]
        db = 20 * np.log10(mag / ref) + 10 * np.log10(2)
        below = np.flatnonzero(db < 0)
        if below.size == 0 or below[0] == 0:
            out.append(np.nan if below.size == 0 else f[0])
            continue
        k = below[0]
        out.append(float(np.exp(np.interp(0.0, [db[k], db[k - 1]], [np.log(f[k]), np.log(f[k - 1])]))))
    return float(out[0]) if siso else np.array(out)
