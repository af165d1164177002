"""Base fit of the declared plant to a record: one rate-independent model per output channel.

The seed-000 stack is, at frequencies well below its 70 kHz mode, a static hysteretic map from
the TERMINAL voltage ``V_t`` to the charge ``q`` (the hysteretic capacitance C_h in series with
the working branch: the inverse of a Prandtl-Ishlinskii operator plus a line is again one), and
the displacement follows the charge, ``x = k_q2x q`` (eq. 10). The series resistor and the
amplifier's current limits only decide how fast ``V_t`` moves; with the current recorded,
``V_t = V - R i`` (``R`` from the plant file or the record's ``series_resistor_ohm``), so no
model of the amplifier is needed. The base model of each recorded channel is therefore a
Prandtl-Ishlinskii operator of ``V_t`` plus an offset, its weights non-negative, fitted by
bounded least squares (:func:`~workbench.calibrate.pi_fit.fit_pi`) on the training rows:

* ``charge`` (from the integrated current), ``displacement``, and ``gauge`` each get their own
  weights, so an effect in one channel (leakage in the charge, a drifting sensor) does not leak
  into another's model: comparing the channels is what traces an effect to its physics;
* a gauge declared ``averaged`` (``# gauge: averaged``: each reading the chain's mean over the
  interval ending at it, as the project's simulator logs it) gets the same mean of its model,
  each play column averaged over the interval (:func:`interval_mean`, exact for the chain's
  linear interpolation between samples): the reading lags the motion by half a sample, which is
  the sampling, not an effect (a 100 Hz steps record had a 0.5-sample delay named on the gauge);
  a ``sampled`` gauge (the default) keeps the point model;
* the electromechanical gains of eqs. 10-12 -- ``k_q2x`` by eq. 11 from the recorded charge and
  displacement, and ``C_p`` by eq. 12 with the plant's ``T_em`` and ``k_p`` -- and the gauge's
  gain and offset against the recorded displacement (the line the linear gauge model is) are
  reported beside them.

When a record's voltage is the amplifier's command rather than its output, ``V - R i`` is not
the terminal voltage; both readings are fitted and the one that fits the stack's motion (the
displacement, else the gauge, else the charge: :func:`_drive_judge`) better on the training
rows is kept (``voltage_source`` says which).

A record starts **from rest** when its first 20 ms hold within 0.5 V of 0 V: the plays start at
0 (the seed's "leads shorted and drained" state) and the charge integral at 0. Otherwise the
plays start where a monotonic approach from 0 V leaves them (``max(0, V0 - r)`` for ``V0 > 0``),
which is stated in ``notes``.
"""

from dataclasses import dataclass, field

import numpy as np

from .bvls import bvls
from .pi_fit import MOVE_REL, play_matrix, pi_thresholds, rms, turning_points
from .residual import record_charge
from .stacking import column_stack

__all__ = ["ChannelModel", "BaseFit", "fit_base", "holdout_mask", "small_problem", "interval_mean", "CHANNEL_KEYS",
           "CHANNEL_UNITS"]

CHANNEL_KEYS = {"displacement": "displacement_m", "charge": "charge_c", "gauge": "gauge_v"}
CHANNEL_UNITS = {"displacement": "m", "charge": "C", "gauge": "V"}
#: "From rest": the first REST_S (at most 2 % of the record) hold within REST_TOL_REL of the record's
#: peak |V| of 0 V (0.5 V on a 100 V protocol: the amplifier monitor's noise and offset, not motion).
REST_S, REST_TOL_REL = 0.02, 0.005
#: Held-out drive more than this fraction of the training span outside the training range is
#: "beyond" it (sampling alone puts a sine's held-out peaks a hair outside the trained ones).
BEYOND_REL = 0.01
#: Ridge strengths tried by the blocked cross-validation, relative to the Gram diagonal of the
#: unit-RMS columns (0 = plain bounded least squares; ``inf`` is the straight line itself: the
#: identity play and the offset alone).
RIDGE_GRID = (0.0,) + tuple(10.0 ** np.arange(-8, 3)) + (np.inf,)
#: Contiguous folds of the training rows for that cross-validation.
RIDGE_FOLDS = 5
#: One-sided level at which the grid's base must predict the motion's held-out training blocks better than the
#: declared core's thresholds to replace them (:func:`_grid_predicts_better`): a tie keeps the declared core's.
GATE_LEVEL = 1e-3
#: The base is "clearly better" than a straight line when its held-out error is at most this
#: fraction of the line's (the margin the tracing asks of an effect, ``max_ratio``).
LINE_MARGIN = 0.8


@dataclass(eq=False)
class ChannelModel:
    """One channel: measurement, base prediction, and the rows where the measurement is valid."""

    name: str
    y: np.ndarray
    yhat: np.ndarray
    valid: np.ndarray
    thresholds_v: np.ndarray
    weights: np.ndarray
    offset: float
    initial_states_v: np.ndarray
    ridge: float = 0.0                # the ridge chosen by cross-validation on the training rows (relative)
    rms_test: float = float("nan")    # held-out RMS of the base, channel units
    line_rms_test: float = float("nan")   # held-out RMS of a straight line of the drive fitted on training rows
    line_slope: float = float("nan")      # that line: y = line_slope * v_drive + line_offset (an averaged gauge: of
    #                                       v_drive's interval mean, :func:`interval_mean`)
    line_offset: float = float("nan")
    sampling: str = "sampled"         # "averaged": the model is the interval mean of the plays (:func:`interval_mean`)

    @property
    def clearly_better_than_line(self):
        """True when the base's held-out error is at most ``LINE_MARGIN`` of the straight line's."""
        return bool(self.rms_test <= LINE_MARGIN * self.line_rms_test)

    @property
    def units(self):
        return CHANNEL_UNITS[self.name]

    @property
    def residual(self):
        return self.y - self.yhat


@dataclass(eq=False)
class BaseFit:
    """The base fit: driving voltage, split, per-channel models and the reported gains."""

    t: np.ndarray
    v_drive: np.ndarray
    voltage_source: str
    train: np.ndarray
    channels: dict
    starts_from_rest: bool
    basis: np.ndarray = None          # plays + a column of ones: the columns every channel's model spans (but one in
    #                                   ``channel_plays``: the charge's, see :meth:`plays_basis`)
    test: np.ndarray = None           # held-out rows (default: every row not trained on)
    k_q2x_m_per_c: float | None = None
    working_capacitance_f: float | None = None
    #: k_p / T_em of the declared PZT (V/m): V_h = V_t - a x (eqs. 9-12), the creep branches' driver
    #: (:mod:`.creep_across`); None without a declared PZT
    stack_v_per_m: float | None = None
    gauge_gain_v_per_m: float | None = None
    gauge_offset_v: float | None = None
    notes: list = field(default_factory=list)
    warnings: list = field(default_factory=list)      # also in ``notes``; the CLI prints them
    input_kind: str = "terminal"      # "terminal" or "command" (amplifier command, see ``command_map``)
    command_map: dict | None = None   # command -> terminal: gain, offset_v, lag_s, delay_s, note
    train_range_v: tuple | None = None    # (lo, hi) of the drive over the training rows
    beyond_train: np.ndarray = None   # held-out rows whose drive leaves ``train_range_v``
    dropped_thresholds_v: np.ndarray = None   # plays never excited in the training rows (left out)
    current_kind: str | None = None   # the charge integrated from a current: "sampled" or "averaged" (# current:)
    gauge_kind: str | None = None     # the gauge's readings: "sampled" or "averaged" (# gauge:); None: no gauge
    #: a channel whose plays are not :attr:`basis`'s: its plays + a column of ones (the charge on the grid when the
    #: motion's base took the declared core's thresholds, :func:`fit_base`)
    channel_plays: dict = field(default_factory=dict)
    #: the declared thresholds against the grid (:func:`_grid_predicts_better`: ``grid``, ``z``, ``bar``, ``ridge``,
    #: ``blocks``, ``channel``); None where the declared thresholds were not tried
    threshold_gate: dict | None = None
    #: the amplifier's series resistor R (ohm) and the declared PZT's current limits ``(source, sink)`` (A, both
    #: positive): the drive's path between samples of a held command (:func:`~.tracing.held_drive`); None when
    #: not declared (``resistance_ohm`` 0, no ``pzt``)
    series_resistance_ohm: float | None = None
    current_limits_a: tuple | None = None
    #: ``R C_min`` (s) of the declared PZT and resistor (:meth:`~workbench.plant.pzt.PZTParams.settle_time_constant_s`):
    #: the held drive's gate and settle (:func:`~.tracing.held_drive`), never eq. 12's record-fitted
    #: :attr:`working_capacitance_f` (a drift biases that to 0.08-0.98 uF against ~5.8 uF: review of s32_alias B2);
    #: None without a declared PZT and resistor
    settle_time_constant_s: float | None = None
    #: ``R C_pp`` (s): the slowest settle of the declared PZT (its incremental capacitance at most the linear
    #: branch's ``C_pp``: the terminal operator is ``C_h^{-1} + I / C_pp``, ``C_h^{-1}`` nondecreasing), the bound of
    #: the held drive's per-step settle read from the record (:func:`~.tracing.held_drive`); None as above
    settle_time_constant_max_s: float | None = None
    #: with no series resistor (``resistance_ohm`` 0, a terminal-voltage record, a declared PZT): the fastest the
    #: declared amplifier moves the stack's terminal, its current limits over the terminal's smallest incremental
    #: capacitance ``(I_source / C_min, I_sink / C_min)`` (V/s, both positive; seed 000 sec. 2's current saturation,
    #: :attr:`~workbench.plant.pzt.PZTParams.min_capacitance_f`): the shortest path a step of the record's voltage
    #: can take between samples (:func:`~.tracing.direct_slew_reach`); None otherwise
    direct_slew_v_per_s: tuple | None = None

    def plays_basis(self, name):
        """Channel ``name``'s plays + a column of ones, point-sampled: :attr:`basis` unless the channel has its own."""
        return plays_basis(self, name)

    def channel_basis(self, name):
        """The columns channel ``name``'s model spans: :meth:`plays_basis`, interval-averaged for an averaged gauge."""
        m = self.channels[name]
        if m.sampling != "averaged":
            return self.plays_basis(name)
        # before the first row the plays hold their initial states (and the offset its 1)
        return interval_mean(self.plays_basis(name), np.r_[np.asarray(m.initial_states_v, float), 1.0])


def plays_basis(base, name):
    """:meth:`BaseFit.plays_basis` of any object with a ``basis`` (and perhaps ``channel_plays``)."""
    own = getattr(base, "channel_plays", None)
    return own.get(name, base.basis) if own else base.basis


from .splits import holdout_mask  # noqa: E402,F401  (moved to splits.py; re-exported for callers)


def interval_mean(x, x_before=None):
    """Each sample's mean over the interval ending at it, of ``x`` interpolated linearly between
    samples: ``(x_{k-1} + x_k) / 2`` (the gauge chain's reading, :func:`~workbench.plant.gauge.gauge_run`:
    the bridge averaged over a period, the displacement interpolated linearly within it; exact for a
    linear bridge).

    A ramp comes out delayed by exactly half a sample; a sampled sine of frequency ``f`` with gain
    ``cos(pi f dt)`` and a lag of exactly ``dt / 2`` (the continuous signal's interval mean has the
    gain ``sinc(f dt)``: the same to first order in ``f dt``, within ``(pi f dt)^2 / 3``).

    Parameters
    ----------
    x : ndarray
        ``(n,)`` or ``(n, k)`` samples, uniform in time (any units; columns averaged each).
    x_before : float or ndarray, optional
        The value before the first sample (default: ``x[0]``, held).

    Returns
    -------
    ndarray
        Same shape as ``x``, same units.
    """
    x = np.asarray(x, float)
    prev = np.empty_like(x)
    prev[1:] = x[:-1]
    prev[0] = x[0] if x_before is None else x_before
    return 0.5 * (prev + x)


def _rest_window_s(t):
    """The start window that decides "from rest": REST_S, but at most 2 % of a short record."""
    return min(REST_S, 0.02 * float(t[-1] - t[0]))


def _starts_from_rest(t, v):
    """The first window holds within REST_TOL_REL of the record's peak |V| of 0 V."""
    head = v[t - t[0] <= _rest_window_s(t)]
    tol = REST_TOL_REL * float(np.max(np.abs(v)))
    return bool(head.size and np.all(np.abs(head) <= tol))


def _starts_flat(t, u):
    """The first window holds within REST_TOL_REL of the input's span of its first value."""
    head = u[t - t[0] <= _rest_window_s(t)]
    return bool(head.size and np.all(np.abs(head - u[0]) <= REST_TOL_REL * float(np.ptp(u))))


def _initial_states(v0, thresholds, from_rest):
    if from_rest:
        return np.zeros(thresholds.size)
    # reached monotonically from 0 V: each play lags the input by its threshold
    return np.sign(v0) * np.maximum(0.0, abs(v0) - thresholds)


def small_problem(A, b=None):
    """``(R, c)`` with ``R^T R = A^T A`` and ``R^T c = A^T b``: ``||A w - b||`` equals
    ``||R w - c||`` up to a constant, so a bounded least squares over a long record runs on a
    columns x columns system.

    From the Gram matrix's eigen-decomposition (far cheaper than a QR of the tall matrix, and
    exact when plays that never engage leave zero or duplicate columns: those directions get
    zero rows).
    """
    gram = np.einsum("ij,ik->jk", A, A)
    lam, V = np.linalg.eigh(gram)
    ok = lam > 1e-12 * max(lam.max(), 0.0)
    s = np.where(ok, np.sqrt(np.where(ok, lam, 1.0)), 0.0)
    R = s[:, None] * V.T
    if b is None:
        return R, None
    c = np.where(ok, (V.T @ np.einsum("ij,i->j", A, b)) / np.where(ok, s, 1.0), 0.0)
    return R, c


def _gram_solve(G, h, lower):
    """min w'G w - 2 h'w subject to w >= lower (BVLS on the square-root system of ``G``, :func:`.bvls.bvls`)."""
    lam, V = np.linalg.eigh(G)
    ok = lam > 1e-12 * max(lam.max(), 0.0)
    sq = np.sqrt(np.where(ok, lam, 1.0))
    R = np.where(ok, sq, 0.0)[:, None] * V.T
    c = np.where(ok, (V.T @ h) / sq, 0.0)
    return bvls(R, c, lower, tol=1e-12)


def _fit_channel(name, P, y, train, valid, thresholds, z0, ridge=None, sampling="sampled"):
    """Non-negative play weights and a free offset by bounded, ridge-regularized least squares.

    Columns are scaled to unit RMS on the fitting rows. The ridge penalizes every play but the
    r = 0 one (the identity) and the offset, so a large ridge leaves the straight line
    ``w_0 V + c``: the path runs from the free PI to the line. Its strength is chosen from
    :data:`RIDGE_GRID` by blocked cross-validation over :data:`RIDGE_FOLDS` contiguous stretches
    of the fitting rows (plays run over the whole record; only the scored rows differ), unless
    ``ridge`` is given. ``sampling="averaged"``: ``P`` is already the plays' interval mean
    (:func:`interval_mean`); recorded on the model.
    """
    rows = train & valid
    n = int(rows.sum())
    an, b, lower, pen, col, bscale = _scaled(P, y, rows, thresholds)
    k = thresholds.size
    G, h = an.T @ an, an.T @ b
    if ridge is None:
        ridge = float(RIDGE_GRID[int(np.argmin(_ridge_cv(an, b, lower, pen)))])
    p = _ridge_solve(G, h, lower, pen, ridge, n) / col * bscale
    w = np.maximum(p[:-1], 0.0)
    if np.isinf(ridge) and k and thresholds[0] == 0:
        # the straight line of :func:`_line` on the same rows, to the last bit (its slope >= 0)
        slope, off, _ = _line(P[:, 0], y, rows, rows)
        if slope >= 0:
            w, p = np.r_[slope, np.zeros(k - 1)], np.r_[slope, np.zeros(k - 1), off]
    yhat = P @ w + p[-1]
    return ChannelModel(name, y, yhat, valid, thresholds, w, float(p[-1]), z0, ridge=ridge, sampling=sampling)


def _scaled(P, y, rows, thresholds, extra=None):
    """:func:`_fit_channel`'s fitting problem: the unit-RMS columns (plays + ones) on ``rows``, the scaled
    target, the bounds, the penalty (the identity play and the offset free), the columns' RMS and the
    target's (to scale the weights back).

    ``extra`` (rows x m, already scaled): columns written after the ones in the same array, free (lower bound
    ``-inf``, no penalty), as :func:`_grid_predicts_better`'s drift columns: the scaled plays are divided into
    that array in place of a second copy (every element the same one rounding, its layout the same C order as
    ``column_stack([a / col, extra])``'s)."""
    n = int(rows.sum())
    a = column_stack([P[rows], np.ones(n)])
    col = np.sqrt(np.mean(a * a, axis=0))
    col[col == 0] = 1.0
    bscale = rms(y[rows]) or 1.0
    k = thresholds.size
    lower = np.r_[np.zeros(k), -np.inf]
    pen = np.r_[0.0 if k and thresholds[0] == 0 else 1.0, np.ones(max(k - 1, 0)), 0.0][: k + 1]
    if extra is None:
        return a / col, y[rows] / bscale, lower, pen, col, bscale
    m = extra.shape[1]
    an = np.empty((n, k + 1 + m))
    np.divide(a, col, out=an[:, : k + 1])
    an[:, k + 1:] = extra
    return (an, y[rows] / bscale, np.r_[lower, np.full(m, -np.inf)], np.r_[pen, np.zeros(m)], col,
            bscale)


def _ridge_cv(an, b, lower, pen, ridges=RIDGE_GRID, gram=None):
    """Blocked cross-validation error of each ridge: :data:`RIDGE_FOLDS` contiguous stretches of the rows.

    ``gram``: ``(an.T @ an, an.T @ b)`` when the caller has them (the same products, not computed again)."""
    n = b.size
    G, h = (an.T @ an, an.T @ b) if gram is None else gram
    edges = np.linspace(0, n, RIDGE_FOLDS + 1).astype(int)
    folds = [(an[i:j].T @ an[i:j], an[i:j].T @ b[i:j], float(b[i:j] @ b[i:j]))
             for i, j in zip(edges[:-1], edges[1:]) if j > i]
    cv = []
    for lam in ridges:
        err = 0.0
        for Gf, hf, sf in folds:
            w = _ridge_solve(G - Gf, h - hf, lower, pen, lam, n)
            err += float(w @ Gf @ w - 2 * w @ hf + sf)
        cv.append(err)
    return np.asarray(cv)


def _grid_predicts_better(P_d, r_d, P_g, r_g, y, rows, t, level=None):
    """Whether the grid's plays predict the motion's held-out training rows better than the declared core's.

    Both threshold sets are fitted as :func:`_fit_channel` fits them, at one common ridge: the one whose blocked
    cross-validation error (:func:`_ridge_cv`), summed over the two sets, is least, so neither set's fit is
    judged by its own ridge choice. The training rows are cut into the split's blocks
    (:func:`~workbench.calibrate.splits.block_length_s`); each block is held out in turn, both sets fitted on
    the other training rows and the block predicted: ``d_b`` is the declared set's squared prediction error on
    it minus the grid's. The grid replaces the declared thresholds only when the mean of ``d_b`` over its
    standard error (the blocks' scatter and their correlation: Newey-West) (``z``) passes Student's t quantile ``1 - level`` at (blocks - 1)
    degrees of freedom (one-sided) and the grid is clearly better: its held-out RMS over the blocks at most
    :data:`LINE_MARGIN` of the declared set's (``ratio``, the margin the tracing asks of an effect). A tie keeps
    them. (The rows are the split's training rows, its folds' validation rows among them, as the base's own fit;
    the test part takes no part.)

    Both sets also carry the tracing's drift columns (:class:`~workbench.calibrate.effects.Drift`: ``s``,
    ``s^2`` of normalized time), free and alike: without them a drift on the file's own stack moved ``z`` and
    ``ratio`` toward the grid while its effect-free twin kept the declared core (seed 105 #40, a 2.04x drift at
    10 kHz: z 3.74, ratio 0.996, twin z -3.77; with them the record's z -3.77, its twin's; seed 105 #110 at
    100 Hz, a drift + resonance: ratio 0.716 -> 1.51).

    Why the margin: an effect the base lacks (a large creep) is in both sets' residuals, and the grid's other
    thresholds take a small part of it that holds from block to block, so ``z`` alone passed on file's-own
    stacks whose effect-free twins keep the declared core (the confusion benchmark's seed 45 #90, a 8.56x creep
    at 100 kHz steps: z 3.45 over 81 blocks with their scatter alone, ratio 0.974; twin z -3.69; 2.90 and -2.69
    with their correlation); a core the file has wrong is
    rate-independent misfit the grid removes in bulk (C_h thresholds 0.9x the file's, 250 Hz slow triangle:
    z 6.71, ratio 0.70). Returns a dict: ``grid``, ``z``, ``bar``, ``mean``, ``ridge``, ``blocks``, ``ratio``.
    """
    from scipy.special import stdtrit
    from .splits import block_length_s
    level = GATE_LEVEL if level is None else level
    idx = np.flatnonzero(rows)
    bl = np.floor((t[idx] - t[0]) / block_length_s(t)).astype(int)
    at = np.flatnonzero(np.r_[True, np.diff(bl) != 0])
    sets = []
    # the tracing's drift (:class:`~workbench.calibrate.effects.Drift`, a polynomial of normalized time) taken
    # from both sets alike, free: a slow trend in the motion is not the core's
    from .effects import Drift
    X = Drift()._X(t)[rows][:, 1:]
    X = X / np.sqrt(np.mean(X * X, axis=0))
    for P, r in ((P_d, r_d), (P_g, r_g)):
        an, b, lower, pen, _, _ = _scaled(P, y, rows, r, extra=X)
        sets.append((an, b, lower, pen, (an.T @ an, an.T @ b)))
    cv = sum(_ridge_cv(an, b, lower, pen, gram=gram) for an, b, lower, pen, gram in sets)
    lam = float(RIDGE_GRID[int(np.argmin(cv))])
    n = idx.size
    errs = []
    for an, b, lower, pen, (G, h) in sets:
        e = []
        for i, j in zip(at, np.r_[at[1:], n]):
            Gf, hf = an[i:j].T @ an[i:j], an[i:j].T @ b[i:j]
            w = _ridge_solve(G - Gf, h - hf, lower, pen, lam, n)
            e.append(float(w @ Gf @ w - 2 * w @ hf + b[i:j] @ b[i:j]))
        errs.append(np.asarray(e))
    d = errs[0] - errs[1]
    nb = d.size
    mean = float(d.mean())
    ratio = float(np.sqrt(errs[1].sum() / errs[0].sum())) if errs[0].sum() > 0 else 1.0
    if nb < 2 or np.isinf(lam):
        return {"grid": False, "z": 0.0, "bar": np.inf, "mean": mean, "ridge": lam, "blocks": nb, "ratio": ratio}
    # the standard error allows for the blocks' correlation (Newey-West, Bartlett weights, the usual lag
    # floor(4 (nb / 100)^(2/9)): 3 at 81 blocks): neighbouring blocks' d_b correlate (lag 1 +0.36-0.5 at 1 MHz
    # steps, up to +0.88; the review of s27_ridge), where the blocks' own scatter made se ~1.5x too small and
    # z passed on the file's own stack (the confusion benchmark's 88 #156, a 8.36x creep at 1 MHz steps: z 4.28
    # over the bar 3.20, its twin -0.07; 2.99 with the correlation)
    c = d - mean
    lag = min(int(4 * (nb / 100.0) ** (2.0 / 9.0)), nb - 1)
    var = float(c @ c) / nb + 2 * sum((1 - k / (lag + 1)) * float(c[k:] @ c[:-k]) / nb for k in range(1, lag + 1))
    se = float(np.sqrt(max(var, 0.0) / (nb - 1)))
    z = mean / se if se > 0 else 0.0
    bar = float(stdtrit(nb - 1, 1.0 - level))
    grid = bool(z > bar and ratio <= LINE_MARGIN)
    return {"grid": grid, "z": float(z), "bar": bar, "mean": mean, "ridge": lam, "blocks": nb, "ratio": ratio}


def _ridge_solve(G, h, lower, pen, lam, n):
    """The ridge-penalized bounded solve; ``lam = inf`` keeps only the unpenalized columns."""
    if not np.isinf(lam):
        return _gram_solve(G + lam * n * np.diag(pen), h, lower)
    free = pen == 0
    w = np.zeros(h.size)
    w[free] = _gram_solve(G[np.ix_(free, free)], h[free], lower[free])
    return w


def _lagged(t, u, lag_s=0.0, delay_s=0.0):
    """The command through a first-order lag ``lag_s`` or a pure delay ``delay_s`` (settled at u[0])."""
    from scipy.signal import lfilter
    if delay_s > 0:
        return np.interp(t - delay_s, t, u, left=u[0])
    if lag_s > 0:
        dt = float(t[1] - t[0])
        a = 1.0 - np.exp(-dt / lag_s)
        return lfilter([a], [1.0, a - 1.0], u, zi=[(1.0 - a) * u[0]])[0]
    return np.asarray(u, float)


def excitation_period_s(t, u):
    """The input's period, s: twice the median time between its reversals (NaN with fewer than 3)."""
    tp = turning_points(u)
    return 2.0 * float(np.median(np.diff(t[tp]))) if tp.size >= 3 else float("nan")


def _gauge_pinned(g, dac_range_v=None):
    """The gauge's rows pinned at its rails, and the rows beside a pinned one: ``(pinned, beside)``.

    Pinned: ``|g|`` within 0.2 % of the DAC range ``dac_range_v`` (V), or of the record's own peak
    when no range is declared. Beside: a row next to a pinned one, only with a declared DAC range.
    A row's reading is the chain's mean over its sample interval (the demodulator averages each
    half modulation period): a row beside a rail-pinned one was taken while the signal crossed the
    rail, so part of its interval was clipped and its mean is neither the rail nor the reading.
    (Seen: a 41x gauge bow whose reading swings from one rail to the other at the top of a 1 kHz
    sine's stroke left one such row among the test rows, 7.5 V off the line; its bow,
    extrapolated there, made the test error rise, 0.33 -> 0.36 V.) Without a declared range the
    "rail" is the record's own peak, where a bow is largest: its neighbours are readings, kept.

    Parameters
    ----------
    g : ndarray
        The gauge's reading, V.
    dac_range_v : float, optional
        The DAC's range (V, symmetric); ``None`` or 0: not declared.

    Returns
    -------
    pinned, beside : ndarray of bool
        Disjoint masks.
    """
    g = np.asarray(g, float)
    lim = dac_range_v if dac_range_v else max(abs(g.max()), abs(g.min()))
    pinned = np.abs(g) >= 0.998 * lim
    near = pinned.copy()
    if dac_range_v:
        near[1:] |= pinned[:-1]
        near[:-1] |= pinned[1:]
    return pinned, near & ~pinned


def _gauge_valid(g, dac_range_v=None):
    """Rows where the gauge is neither pinned at its rails nor, with a declared DAC range
    ``dac_range_v`` (V), beside a pinned row (:func:`_gauge_pinned`)."""
    pinned, beside = _gauge_pinned(g, dac_range_v)
    return ~(pinned | beside)


def _line(v, y, rows, test):
    """Straight line y = a v + b on ``rows``; (a, b, held-out RMS on ``test``)."""
    a = np.column_stack([v[rows], np.ones(int(rows.sum()))])
    (slope, off), *_ = np.linalg.lstsq(a, y[rows], rcond=None)
    return float(slope), float(off), rms((slope * v + off - y)[test])


def fit_base(record, resistance_ohm=0.0, train=None, n_plays=24, grid="quadratic", pzt=None, dac_range_v=None,
             test=None, input_kind=None, gauge_kind=None, spread_plays=False):
    """Fit the base model of every recorded output channel (see the module notes).

    Parameters
    ----------
    record : Record
        From :func:`~workbench.calibrate.record.read_record`.
    resistance_ohm : float
        Series resistor R between amplifier and stack; ``V - R i`` is the terminal voltage
        (0: the resistor is out, the recorded voltage is the terminal voltage).
    train : ndarray of bool, optional
        Training rows (default :func:`holdout_mask` with blocks).
    pzt : PZTParams, optional
        The declared PZT: its ``T_em`` and ``k_p`` turn ``k_q2x`` into ``C_p`` (eq. 12).
    dac_range_v : float, optional
        The gauge's DAC range; readings at the rails are left out of its fit and errors.
    test : ndarray of bool, optional
        Held-out rows scored (default: every row not trained on).
    input_kind : {"terminal", "command"}, optional
        What the voltage column is (default: the record's ``# input:``, else ``"terminal"``). A
        command is mapped to the terminal voltage by a gain, an offset and a first-order lag or a
        delay (seconds, searched up to a quarter of the excitation period); the lag or delay is
        fitted on the training rows; gain and offset are absorbed by the play weights and
        thresholds (the model runs in command volts), see ``command_map``.
    gauge_kind : {"sampled", "averaged"}, optional
        What each gauge reading is (default: the record's ``# gauge:``, else ``"sampled"``):
        ``"averaged"``, the chain's mean over the interval ending at it, makes the gauge's model
        the same mean of its plays (:func:`interval_mean`, half a sample of lag); ``"sampled"``
        keeps the point model.
    spread_plays : bool
        The grid reaches ``max |V - V0|`` over the input to the last training row (the excursion from the
        record's start, :func:`~workbench.calibrate.pi_fit.pi_thresholds`), and the plays that never move
        in the training rows are left out. True: when some are left out, the ``n_plays`` are placed again on
        ``grid`` up to the first of them, so all ``n_plays`` serve the training rows (a generic stack's
        file declares its ``n_plays``; run.py).
    """
    t = record.t_s
    ch = record.channels
    v = ch["voltage_v"]
    train = holdout_mask(t, v) if train is None else np.asarray(train, bool)
    test = ~train if test is None else np.asarray(test, bool) & ~train
    input_kind = input_kind or record.metadata.get("input", "terminal")
    if input_kind not in ("terminal", "command"):
        raise ValueError(f"input_kind must be 'terminal' or 'command', got {input_kind!r}")
    gauge_kind = gauge_kind or getattr(record, "gauge_kind", "sampled")
    if gauge_kind not in ("sampled", "averaged"):
        raise ValueError(f"gauge_kind must be 'sampled' or 'averaged', got {gauge_kind!r}")
    notes, warnings = [], []
    outputs = {}
    charge = record_charge(record)
    current_kind = None
    if charge is not None:
        outputs["charge"] = charge
        if "charge_c" not in ch:
            current_kind = record.current_kind
            notes.append(f"the charge is the recorded current integrated as {current_kind} "
                         + ("(each sample the mean over the interval ending at it: running sum i dt)"
                            if current_kind == "averaged" else
                            "(each sample the instantaneous current: trapezoid; write '# current: averaged' "
                            "in the record if the monitor averages over the sample interval)"))
    if "displacement_m" in ch:
        outputs["displacement"] = ch["displacement_m"]
    if "gauge_v" in ch:
        outputs["gauge"] = ch["gauge_v"]
    if not outputs:
        raise ValueError("the record has no output channel (charge, current, displacement or gauge)")
    valid = {name: (_gauge_valid(y, dac_range_v) if name == "gauge" else np.ones(y.size, bool))
             for name, y in outputs.items()}
    if "gauge" in outputs:
        pinned, beside = _gauge_pinned(outputs["gauge"], dac_range_v)
        n_p, n_b = int((test & pinned).sum()), int((test & beside).sum())
        if n_p or n_b:
            rail = (f"the DAC range +/-{dac_range_v:.4g} V" if dac_range_v
                    else "the record's own peak (no DAC range declared)")
            notes.append(f"the gauge: {n_p} of {int(test.sum())} test rows pinned at {rail} and {n_b} beside a "
                         f"pinned row are left out of its fit and its test error")
    for name in list(outputs):
        if int((train & valid[name]).sum()) < 100:
            notes.append(f"the {name} channel has {int((train & valid[name]).sum())} usable training rows "
                         f"(pinned at its rails or too short); it is left out")
            del outputs[name], valid[name]
    if not outputs:
        raise ValueError(f"no output channel has usable training rows ({'; '.join(notes)})")
    first = _drive_judge(outputs)
    last = int(np.flatnonzero(train)[-1])
    # the declared core's V_t -> charge thresholds replace grid ones on a terminal-voltage record once its drive
    # is judged V_t (a command's volts differ from V_t by the amplifier's unknown gain)
    extra = declared_thresholds(pzt) if input_kind == "terminal" and pzt is not None else None
    command_map = None
    if input_kind == "command":
        from_rest = _starts_flat(t, v)
        period = excitation_period_s(t, v)
        bound = 0.25 * (period if np.isfinite(period) else float(t[-1] - t[0]) / 4)
        dt = float(record.sample_period_s)
        taus = np.geomspace(min(dt / 2, bound), bound, 16) if bound > 0 else np.array([])
        drives = {("none", 0.0): v}
        drives.update({("lag", x): _lagged(t, v, lag_s=x) for x in taus})
        drives.update({("delay", x): _lagged(t, v, delay_s=x) for x in taus})
        notes.append(f"the voltage column is the amplifier's command: its lag or delay is searched from "
                     f"{min(dt / 2, bound):.3g} s to {bound:.3g} s (a quarter of the excitation period "
                     f"{period:.4g} s); the plays start at the first command value")
    else:
        from_rest = _starts_from_rest(t, v)
        drives = {"recorded voltage": v}
        if "current_a" in ch and resistance_ohm > 0:
            drives = {"terminal voltage V - R i": v - resistance_ohm * ch["current_a"], "recorded voltage": v}
        if not from_rest:
            notes.append(f"the record does not start from rest (V = {v[0]:.3g} V at the start): the plays start "
                         f"as if reached monotonically from 0 V")
    # V against V - R i on a terminal record: V leads V_t by ~R C, so a motion sensor that leads
    # the drive makes V fit better and the base hides part of the lead. When V wins, both are
    # judged again with the sensor allowed a timing offset of either sign; V_t is kept when it
    # then fits at least as well (the lead, not the drive, made V win)
    shifts_s = _judge_shifts(t, record.sample_period_s) if input_kind != "command" and len(drives) == 2 else None

    # an averaged gauge judging the drive (no displacement recorded) is judged on its own model, the
    # plays' interval mean: on the point plays the judgment takes the chain's half sample as the
    # drive's lag (100 Hz steps, gauge only, amplifier command: a 0.55-sample delay found, then
    # averaged again, held-out 0.019 V against 0.007 V; review of s14_ends)

    def judged(vd, r, keep, P, name, shifts=None, residual=False):
        Pj = P[:, keep]
        if name == "gauge" and gauge_kind == "averaged":
            Pj = interval_mean(Pj, _z0(vd, r, from_rest, input_kind)[keep])
        return _judge_rms(t, Pj, outputs[name], train & valid[name], shifts, residual=residual)

    def trial(vd, shifts=None):
        r, keep, P = _plays(vd, train, last, n_plays, grid, from_rest, input_kind, spread_plays)
        return judged(vd, r, keep, P, first, shifts), r, keep, P

    judges = [ch for ch in ("displacement", "gauge") if ch in outputs] if shifts_s is not None else []
    best = None
    tried, on_first = {}, {}
    for label, vd in drives.items():
        if judges:                   # the residual kept for :func:`_judgment_resolves` (first is judges[0])
            r, keep, P = _plays(vd, train, last, n_plays, grid, from_rest, input_kind, spread_plays)
            on_first[label] = judged(vd, r, keep, P, first, residual=True)
            score = on_first[label][0]
        else:
            score, r, keep, P = trial(vd)
        tried[label] = (score, label, vd, r, keep, P)
        if best is None or score < best[0]:
            best = tried[label]
    judge = first
    if judges:
        # the judgment is the record's only when the judging channel resolves the term the two readings
        # differ by (:func:`_judgment_resolves`); else the next motion channel judges, else V - R i stands
        vt, vr = tried["terminal voltage V - R i"], tried["recorded voltage"]
        ri = vr[2] - vt[2]
        for k, name in enumerate(judges):
            scores = on_first if k == 0 else {lab: judged(*tr[2:], name, residual=True) for lab, tr in tried.items()}
            win = min(scores, key=lambda lab: scores[lab][0])
            if _judgment_resolves(scores[win], outputs[name], vt[2], ri, train & valid[name]):
                judge, best = name, tried[win]
                if k:
                    notes.append(f"the drive is judged on the {name}: the {judges[0]}'s misfit is larger than the "
                                 f"term V and V - R i differ by on it, so it cannot tell them apart")
                break
        else:
            judge, best = None, vt
            notes.append(f"the drive is V - R i, the terminal voltage by the declared resistor: on "
                         f"{' and '.join(judges)} the misfit of either reading is larger than the term V and V - R i "
                         f"differ by, so the record cannot tell them apart (the stack's motion carries an effect the "
                         f"base lacks)")
    if judge is not None and shifts_s is not None and best[1] == "recorded voltage":
        vt = tried["terminal voltage V - R i"]
        if (judged(*vt[2:], judge, shifts_s) <= judged(*best[2:], judge, shifts_s)):
            best = vt
            notes.append(f"the {judge} fits the recorded V better than V - R i only through a timing offset "
                         "(a sensor that leads the drive): V - R i is the drive, the offset is left to the tracing")
    if input_kind == "command" and best[1][0] != "none":
        # refine the winning lag or delay between its grid neighbours (log scale)
        from scipy.optimize import minimize_scalar
        kind, x = best[1]
        i = int(np.flatnonzero(taus == x)[0])
        lo_, hi_ = np.log(taus[max(i - 1, 0)]), np.log(taus[min(i + 1, taus.size - 1)])
        res = minimize_scalar(lambda z: trial(_lagged(t, v, **{f"{kind}_s": float(np.exp(z))}))[0],
                              bounds=(lo_, hi_), method="bounded", options={"xatol": 0.01})
        if res.fun < best[0]:
            x = float(np.exp(res.x))
            vd = _lagged(t, v, **{f"{kind}_s": x})
            best = (float(res.fun), (kind, x), vd, *trial(vd)[1:])
    _, label, vd, r_all, keep, P = best
    grid_plays = None           # the charge's own plays when the motion's differ: (thresholds, kept, P)
    threshold_gate = None
    motion = [name for name in ("displacement", "gauge") if name in outputs]
    if (extra is not None and motion
            and label == ("terminal voltage V - R i" if len(drives) > 1 else "recorded voltage")):
        # the declared thresholds are of V_t: the drive that is V_t (V - R i; the recorded V when it is the only
        # reading) takes them once judged. The judgment itself is on the grid for both readings: the recorded V
        # beside V - R i is V_t + R i, and one reading on the declared thresholds, the other on the grid, judged
        # unequal bases (1 MHz steps, drift + resonance 6.1x: V won on a 4.0e-7 m misfit and the charge then
        # fitted 3.7e-8 C against 1.3e-8 C on its effect-free twin; test_one_megahertz).
        # Only the motion's base (displacement, gauge) takes them; the charge keeps the grid on the same judged
        # drive. The charge is the summed current: the monitor's white noise is a random walk on it, and on the
        # declared thresholds' closer charge base that walk's slow bend passed as an absorption (seed 92 #103,
        # 100 Hz, a 0.24x leakage named absorption 5 of 5; s24_triangle2), while the misfit the declared
        # thresholds remove is the motion's (a clean slow triangle's mid-ramp 3.3e-9 m a mode took)
        r_d, keep_d, P_d = _plays(vd, train, last, n_plays, grid, from_rest, input_kind, spread_plays, extra,
                                  known=(r_all, P))
        if not np.array_equal(r_d, r_all):      # (none inside the grid's range: the same plays, no gate)
            # the file's core is a guess for the stack (its C_h shape assumed, C_p +-20 %): its thresholds stay out
            # of the base when the grid's predict the motion's held-out training blocks better
            # (:func:`_grid_predicts_better`)
            ch_m = motion[0]

            def cols(r_, keep_, P_):
                c = P_[:, keep_]
                if ch_m == "gauge" and gauge_kind == "averaged":
                    c = interval_mean(c, _z0(vd, r_[keep_], from_rest, input_kind))
                return c, r_[keep_]

            gate = _grid_predicts_better(*cols(r_d, keep_d, P_d), *cols(r_all, keep, P), outputs[ch_m],
                                         train & valid[ch_m], t)
            gate["channel"] = ch_m
            threshold_gate = gate
            if gate["grid"]:
                notes.append(f"the declared core's thresholds are left out of the base: the grid's plays predict the "
                             f"{ch_m}'s held-out training blocks better at a common ridge (z {gate['z']:.3g} over "
                             f"{gate['blocks']} blocks, bar {gate['bar']:.3g}): the file's core is not the stack's")
            else:
                if "charge" in outputs:
                    grid_plays = (r_all, keep, P)
                r_all, keep, P = r_d, keep_d, P_d
    if input_kind == "command":
        kind, x = label
        command_map = {"gain": 1.0, "offset_v": 0.0, "lag_s": float(x) if kind == "lag" else 0.0,
                       "delay_s": float(x) if kind == "delay" else 0.0,
                       "note": "gain and offset are absorbed by the play weights and thresholds (the "
                               "model runs in command volts): the outputs alone cannot tell them apart"}
        label = ("amplifier command" + (f" through a {x:.4g} s first-order lag" if kind == "lag" else
                                        f" delayed {x:.4g} s" if kind == "delay" else ", no lag"))
        notes.append(f"driven by the {label} (best of {len(drives)} lags and delays on the training rows)")
    elif len(drives) > 1 and judge is not None:     # judge None: V - R i stood by default, said above
        notes.append(f"driven by the {label} (fits the {judge} better on the training rows than the other reading)")
    r, P = r_all[keep], P[:, keep]
    z0 = _z0(vd, r, from_rest, input_kind)
    if not keep.all():
        notes.append(f"{int((~keep).sum())} of {keep.size} plays never move in the training rows (thresholds "
                     f"{', '.join(f'{x:.4g}' for x in r_all[~keep])} V) and are left out; the training input's "
                     f"range does not reach them")
    models = {}
    averaged = gauge_kind == "averaged" and "gauge" in outputs
    if averaged:
        notes.append("the gauge's readings are each the chain's mean over the interval ending at them (# gauge: "
                     "averaged): its model is the same mean of the plays, half a sample behind the motion")
    bases = {}                  # a channel's own plays + ones (BaseFit.channel_plays)
    if grid_plays is not None:
        r_c = grid_plays[0][grid_plays[1]]
        bases["charge"] = np.column_stack([grid_plays[2][:, grid_plays[1]], np.ones(t.size)])
        grid_plays = None       # (the grid's full-record columns freed)
    for name, y in outputs.items():
        if name == "gauge" and averaged:
            # the plays before the first row hold their initial states (the record's drive before it)
            m = _fit_channel(name, interval_mean(P, z0), y, train, valid[name], r, z0, sampling="averaged")
        elif name == "charge" and "charge" in bases:
            m = _fit_channel(name, bases["charge"][:, :-1], y, train, valid[name], r_c,
                             _z0(vd, r_c, from_rest, input_kind))
        else:
            m = _fit_channel(name, P, y, train, valid[name], r, z0)
        rows, tst = train & valid[name], test & valid[name]
        m.rms_test = rms(m.residual[tst])
        # the straight line of the drive as the channel reads it: an averaged gauge's line is of the
        # drive's interval mean (the identity play's, so the base reduced to a line is this line)
        v_line = interval_mean(vd, z0[0] if r.size and r[0] == 0 else vd[0]) if m.sampling == "averaged" else vd
        m.line_slope, m.line_offset, m.line_rms_test = _line(v_line, y, rows, tst)
        models[name] = m
        if tst.any() and not m.clearly_better_than_line:
            warnings.append(f"the base's held-out error on the {name} channel ({m.rms_test:.4g} {m.units}) is not "
                            f"clearly below a straight line's ({m.line_rms_test:.4g} {m.units}; clearly = at most "
                            f"{LINE_MARGIN:g}x): the declared model explains this record no better than a line")
    lo, hi = float(vd[train].min()), float(vd[train].max())
    tol = BEYOND_REL * (hi - lo)
    beyond = test & ((vd < lo - tol) | (vd > hi + tol))
    if beyond.any():
        warnings.append(f"{100 * beyond.sum() / max(int(test.sum()), 1):.3g} % of the held-out rows drive beyond "
                        f"the training input's range {lo:.4g} .. {hi:.4g} V (to {vd[test].min():.4g} .. "
                        f"{vd[test].max():.4g} V): there the base extrapolates")
    fit = BaseFit(t=t, v_drive=vd, voltage_source=label, train=train, channels=models, starts_from_rest=from_rest,
                  basis=np.column_stack([P, np.ones(t.size)]), notes=notes + [f"warning: {w}" for w in warnings],
                  test=test, warnings=warnings, input_kind=input_kind, command_map=command_map,
                  train_range_v=(lo, hi), beyond_train=beyond, dropped_thresholds_v=r_all[~keep],
                  current_kind=current_kind, gauge_kind=gauge_kind if "gauge" in outputs else None,
                  channel_plays=bases, threshold_gate=threshold_gate)
    if "charge" in outputs and "displacement" in outputs:
        q = outputs["charge"] - outputs["charge"][0]
        x = outputs["displacement"]
        if from_rest:          # eq. 11 through the origin, the displacement measured from its rest level
            x = x - np.mean(x[t - t[0] <= _rest_window_s(t)])
            k = float(q[train] @ x[train] / (q[train] @ q[train]))
        else:                  # not from rest: neither the charge nor the displacement has a known zero
            k = float(np.polyfit(q[train], x[train], 1)[0])
            fit.notes.append("k_q2x (eq. 11) fitted with an offset: the record does not start from rest")
        fit.k_q2x_m_per_c = k
        if pzt is not None:
            tem, kp = pzt.transducer_constant_n_per_v, pzt.stiffness_n_per_m
            fit.working_capacitance_f = float((tem - tem * tem * k) / (kp * k))     # eq. 12
    if resistance_ohm > 0 and input_kind != "command":
        fit.series_resistance_ohm = float(resistance_ohm)
        if pzt is not None:
            fit.current_limits_a = (float(pzt.current_limit_source_a), float(pzt.current_limit_sink_a))
            fit.settle_time_constant_s = pzt.settle_time_constant_s(resistance_ohm)
            fit.settle_time_constant_max_s = float(resistance_ohm) * float(pzt.c_pp_f)
    elif input_kind != "command" and pzt is not None:
        c_min = pzt.min_capacitance_f
        fit.direct_slew_v_per_s = (float(pzt.current_limit_source_a) / c_min, float(pzt.current_limit_sink_a) / c_min)
    if pzt is not None and pzt.transducer_constant_n_per_v > 0:
        fit.stack_v_per_m = float(pzt.stiffness_n_per_m / pzt.transducer_constant_n_per_v)
    if "gauge" in outputs and "displacement" in outputs:
        rows = train & valid["gauge"]
        # an averaged gauge reads the motion's interval mean: its line is against that mean
        x_g = interval_mean(outputs["displacement"]) if averaged else outputs["displacement"]
        b, a = np.polyfit(x_g[rows], outputs["gauge"][rows], 1)
        fit.gauge_gain_v_per_m, fit.gauge_offset_v = float(b), float(a)
    return fit


def _judge_shifts(t, dt):
    """Sensor timing offsets (s) the drive's judgment allows: 0 and +/- half a sample to
    ``max(30 dt, duration / 200)`` (the tracing's delay bound without its excitation-period
    term), 12 per sign on a log grid."""
    dur = float(t[-1] - t[0])
    mags = np.geomspace(0.5 * dt, max(30.0 * dt, dur / 200.0), 12)
    return np.r_[-mags[::-1], 0.0, mags]


def _judgment_resolves(judged, y, v_t, ri, rows):
    """Whether a channel's judgment between V and V - R i is the record's, not its misfit's.

    ``judged``: the better reading's ``(rms, residual)`` from :func:`_judge_rms`. The two readings
    differ by ``R i``, which reaches the channel through its slope on the drive: ``s = |slope| rms(R i)``
    on the judged rows (the channel's units). The judgment resolves when the better reading's misfit
    beyond the channel's white noise (:func:`~workbench.calibrate.tracing.noise_floor` of the residual)
    is below ``s``. A larger misfit is an effect the base lacks (a mode, a sensor delay, a drift beside
    one); its low-frequency part is a lag ``-d dy/dt``, the form ``R i ~ R C dV/dt`` takes, so the two
    readings' fits differ by the misfit's chance alignment: 0.3 % of it on the 1 MHz benchmark's
    drift + 52 Hz mode sine records (57 #154, 56 #154) and its 48.7 ms sensor delay (48 #138), where
    the recorded V won and the charge then carried a spurious R C relaxation (an absorption) above
    the straight line's error. On an effect-free record the better reading leaves the noise and the
    other ~8x more.
    """
    from .tracing import noise_floor
    score, e = judged
    slope = np.polyfit(v_t[rows], y[rows], 1)[0]
    s = abs(float(slope)) * rms(ri[rows])
    white = noise_floor(e)
    return bool(np.sqrt(max(score * score - white * white, 0.0)) < s)


def _judge_rms(t, P, y, rows, shifts_s=None, residual=False):
    """Training RMS of ``y`` fitted by the plays (>= 0), an offset and a slow quadratic in time.

    The quadratic is a nuisance for the drive's judgment only: a drifting sensor (microns over
    the record) would otherwise swamp the small difference two drives make, and the choice would
    fall to chance (a wrong drive shows later as a spurious ~R C delay). With ``shifts_s`` the
    least RMS over ``y(t - d)`` for each ``d`` (a sensor timing offset, linear interpolation) is
    returned: the Gram matrix is shared, only ``a' y`` changes.
    """
    s = (t - t[0]) / max(float(t[-1] - t[0]), 1e-300)
    a = np.column_stack([P[rows], np.ones(int(rows.sum())), s[rows], s[rows] ** 2])
    col = np.sqrt(np.mean(a * a, axis=0))
    col[col == 0] = 1.0
    an = a / col
    G = an.T @ an
    k = P.shape[1]
    lower = np.r_[np.zeros(k), np.full(3, -np.inf)]
    best = np.inf
    for d in (0.0,) if shifts_s is None else shifts_s:
        b = y[rows] if d == 0.0 else np.interp(t[rows] - d, t, y)
        w = _gram_solve(G, an.T @ b, lower)
        e = b - an @ w
        best = min(best, rms(e))
    return (best, e) if residual and shifts_s is None else best


def _drive_judge(outputs):
    """The channel that decides the driving voltage (V or V - R i, a command's lag or delay).

    The stack's motion when it is recorded (displacement, else the gauge): the charge carries
    leakage and dielectric absorption, which the base model lacks and which a leading drive
    (the recorded V = V_t + R i leads V_t by ~R C) partly mimics; judged on the charge, such a
    record would be driven by the wrong voltage and the displacement would then show a spurious
    delay of ~R C. The judgment fits a slow quadratic in time beside the plays
    (:func:`_judge_rms`), so a drifting sensor does not decide it either.
    """
    for name in ("displacement", "gauge"):
        if name in outputs:
            return name
    return next(iter(outputs))


def _z0(vd, r, from_rest, input_kind):
    """Initial play states: at the first command value for a command, else see ``_initial_states``."""
    if input_kind == "command":
        return np.full(r.size, float(vd[0]))
    return _initial_states(vd[0], r, from_rest)


def declared_thresholds(pzt):
    """The declared core's own thresholds of the terminal voltage -> charge map, V (empty without one).

    The stack's charge is ``G^{-1}[V_t]`` with ``G = C_h^{-1} + (1/C_pp) I`` (:meth:`PZTParams.terminal_operator`):
    a PI operator of ``V_t`` whose thresholds are not the file's ``C_h`` thresholds (Kuhnen's inverse moves
    them). A base whose grid straddles them misfits the clean stack where each play engages, mid-ramp on a
    slow triangle (3.3e-9 m at 0.15-0.25 of the period from a corner, noise-free, 2.5 kHz 0.5 Hz; 7.5e-14 m on
    these thresholds alone), a misfit a mode 10x above the drive took (s22_outsider A1).
    """
    op = getattr(pzt, "terminal_operator", None)
    if op is None:
        return np.zeros(0)
    try:
        return np.asarray(op().inverse().thresholds, float)
    except (ValueError, AttributeError):
        return np.zeros(0)


def _plays(vd, train, last, n_plays, grid, from_rest, input_kind, spread=False, extra=None, known=None):
    """Thresholds from the input up to the last training row, which plays move there, the play matrix.

    ``extra``: thresholds that replace grid thresholds (the declared core's, :func:`declared_thresholds`): each
    inside the grid's own range (above 0, below its largest threshold) takes the place of the nearest interior
    grid threshold not yet taken, so the play count stays the grid's. Joined beside the grid instead (s23, up
    to 11 plays more, +29 % CPU on the speed record), a declared threshold could sit a few hundredths of a volt
    from a grid one (6.03 V beside 6.11 V), two near-copies of a column; measured then: a refitted delay's
    per-fold weights moved with rows outside the fold's training rows (test_tracing R2, 10 kHz) and the 1 kHz
    creep + delay steps records lost their delay (creep 11.9x, delay 5.9x); replacing, neither. Above the grid's largest threshold a play moves less than the grid's own
    top play, only in the rows at the record's extreme, where it is a column of those few rows: the declared
    core's 39.8 V threshold on a calibration record whose span is 39.97 V moved 0.13 V, took a weight 8x the
    identity's and the creep held at the peak (seed 88 #68, 100 kHz: the base's test error 1.85e-8 ->
    2.49e-8 m, the creep then leaving 9.9e-9 m against 1.8e-9 m and a spurious delay named after it).
    ``known``: ``(thresholds, P)`` already computed on this drive; their columns are reused (a play's column
    depends on its threshold and the drive alone).
    ``spread``: when a play never moves in the training rows, the grid is placed again up to the first such
    threshold (see :func:`fit_base`'s ``spread_plays``); the declared thresholds then replace grid ones inside
    that range. With ``known`` the grid (spread included) is ``known``'s thresholds.
    Returns ``(thresholds, kept, P)`` with ``P`` over the whole record for every threshold.
    """
    span = float(np.ptp(vd[train]))

    def moving(r, known=None):
        z0 = _z0(vd, r, from_rest, input_kind)
        if known is None:
            P = play_matrix(vd, r, z0)
        else:
            r_k, P_k = known
            at = {float(x): j for j, x in enumerate(r_k)}
            new = [j for j, x in enumerate(r) if float(x) not in at]
            P = np.empty((vd.size, r.size))
            for j, x in enumerate(r):
                if float(x) in at:
                    P[:, j] = P_k[:, at[float(x)]]
            if new:
                P[:, new] = play_matrix(vd, r[new], z0[new])
        keep = np.ptp(P[train], axis=0) > MOVE_REL * span
        keep[0] = True                          # the identity (r = 0) always moves with the input
        return keep, P

    if known is None:
        r = pi_thresholds(vd[: last + 1], n_plays, grid)
        keep, P = moving(r)
        if spread and not keep.all():
            r = pi_thresholds(np.array([0.0, r[int(np.argmin(keep))]]), n_plays, grid)
            keep, P = moving(r)
    else:
        r = np.asarray(known[0], float)
    if extra is not None and len(extra) and r.size > 2:
        e = np.asarray(extra, float)
        e = e[(e > 0) & (e < r[-1])]
        r = r.copy()
        free = np.ones(r.size, bool)
        free[0] = free[-1] = False          # the identity and the grid's top stay
        for x in e:
            if not free.any():
                break
            i = int(np.flatnonzero(free)[np.argmin(np.abs(r[free] - x))])
            r[i], free[i] = x, False
        r = np.unique(r)
        keep, P = moving(r, known)
    elif known is not None:
        keep, P = moving(r, known)
    return r, keep, P
