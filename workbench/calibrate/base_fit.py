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
* the electromechanical gains of eqs. 10-12 -- ``k_q2x`` by eq. 11 from the recorded charge and
  displacement, and ``C_p`` by eq. 12 with the plant's ``T_em`` and ``k_p`` -- and the gauge's
  gain and offset against the recorded displacement (the line the linear gauge model is) are
  reported beside them.

When a record's voltage is the amplifier's command rather than its output, ``V - R i`` is not
the terminal voltage; both readings are fitted and the one that fits the first output channel
better on the training rows is kept (``voltage_source`` says which).

A record starts **from rest** when its first 20 ms hold within 0.5 V of 0 V: the plays start at
0 (the seed's "leads shorted and drained" state) and the charge integral at 0. Otherwise the
plays start where a monotonic approach from 0 V leaves them (``max(0, V0 - r)`` for ``V0 > 0``),
which is stated in ``notes``.
"""

from dataclasses import dataclass, field

import numpy as np

from .pi_fit import play_matrix, pi_thresholds, rms, split_by_cycles, turning_points
from .residual import charge_from_current

__all__ = ["ChannelModel", "BaseFit", "fit_base", "holdout_mask", "small_problem", "CHANNEL_KEYS", "CHANNEL_UNITS"]

CHANNEL_KEYS = {"displacement": "displacement_m", "charge": "charge_c", "gauge": "gauge_v"}
CHANNEL_UNITS = {"displacement": "m", "charge": "C", "gauge": "V"}
REST_S, REST_TOL_V = 0.02, 0.5


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
    basis: np.ndarray = None          # plays + a column of ones: the columns every channel's model spans
    test: np.ndarray = None           # held-out rows (default: every row not trained on)
    k_q2x_m_per_c: float | None = None
    working_capacitance_f: float | None = None
    gauge_gain_v_per_m: float | None = None
    gauge_offset_v: float | None = None
    notes: list = field(default_factory=list)


from .splits import holdout_mask  # noqa: E402,F401  (moved to splits.py; re-exported for callers)


def _starts_from_rest(t, v):
    head = v[t - t[0] <= REST_S]
    return bool(head.size and np.all(np.abs(head) <= REST_TOL_V))


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


def _fit_channel(name, P, y, train, valid, thresholds, z0):
    from scipy.optimize import lsq_linear
    rows = train & valid
    a = np.column_stack([P[rows], np.ones(int(rows.sum()))])
    col = np.sqrt(np.mean(a * a, axis=0))
    col[col == 0] = 1.0
    bscale = rms(y[rows]) or 1.0
    lb = np.r_[np.zeros(thresholds.size), -np.inf]
    r, rhs = small_problem(a / col, y[rows] / bscale)
    sol = lsq_linear(r, rhs, bounds=(lb, np.full(thresholds.size + 1, np.inf)), method="bvls", tol=1e-12)
    p = sol.x / col * bscale
    w = np.maximum(p[:-1], 0.0)
    yhat = P @ w + p[-1]
    return ChannelModel(name, y, yhat, valid, thresholds, w, float(p[-1]), z0)


def _gauge_valid(g, dac_range_v=None):
    """Rows where the gauge is not pinned at its DAC rails (a clipped reading says nothing)."""
    lim = dac_range_v if dac_range_v else max(abs(g.max()), abs(g.min()))
    return np.abs(g) < 0.998 * lim


def fit_base(record, resistance_ohm=0.0, train=None, n_plays=24, grid="quadratic", pzt=None, dac_range_v=None,
             test=None):
    """Fit the base model of every recorded output channel (see the module notes).

    Parameters
    ----------
    record : Record
        From :func:`~workbench.calibrate.record.read_record`.
    resistance_ohm : float
        Series resistor R between amplifier and stack; ``V - R i`` is the terminal voltage.
    train : ndarray of bool, optional
        Training rows (default :func:`holdout_mask` with blocks).
    pzt : PZTParams, optional
        The declared PZT: its ``T_em`` and ``k_p`` turn ``k_q2x`` into ``C_p`` (eq. 12).
    dac_range_v : float, optional
        The gauge's DAC range; readings at the rails are left out of its fit and errors.
    """
    t = record.t_s
    ch = record.channels
    v = ch["voltage_v"]
    train = holdout_mask(t, v) if train is None else np.asarray(train, bool)
    notes = []
    outputs = {}
    if "charge_c" in ch:
        outputs["charge"] = ch["charge_c"]
    elif "current_a" in ch:
        outputs["charge"] = charge_from_current(t, ch["current_a"])
    if "displacement_m" in ch:
        outputs["displacement"] = ch["displacement_m"]
    if "gauge_v" in ch:
        outputs["gauge"] = ch["gauge_v"]
    if not outputs:
        raise ValueError("the record has no output channel (charge, current, displacement or gauge)")
    drives = {"recorded voltage": v}
    if "current_a" in ch and resistance_ohm > 0:
        drives = {"terminal voltage V - R i": v - resistance_ohm * ch["current_a"], "recorded voltage": v}
    from_rest = _starts_from_rest(t, v)
    if not from_rest:
        notes.append(f"the record does not start from rest (V = {v[0]:.3g} V at the start): the plays start "
                     f"as if reached monotonically from 0 V")
    valid = {name: (_gauge_valid(y, dac_range_v) if name == "gauge" else np.ones(y.size, bool))
             for name, y in outputs.items()}
    for name in list(outputs):
        if int((train & valid[name]).sum()) < 100:
            notes.append(f"the {name} channel has {int((train & valid[name]).sum())} usable training rows "
                         f"(pinned at its rails or too short); it is left out")
            del outputs[name], valid[name]
    if not outputs:
        raise ValueError(f"no output channel has usable training rows ({'; '.join(notes)})")
    first = next(iter(outputs))
    best = None
    for label, vd in drives.items():
        r = pi_thresholds(vd, n_plays, grid)
        z0 = _initial_states(vd[0], r, from_rest)
        P = play_matrix(vd, r, z0)
        m = _fit_channel(first, P, outputs[first], train, valid[first], r, z0)
        score = rms(m.residual[train & valid[first]]) / (np.std(outputs[first]) or 1.0)
        if best is None or score < best[0]:
            best = (score, label, vd, r, z0, m, P)
    _, label, vd, r, z0, m0, P = best
    if len(drives) > 1:
        notes.append(f"driven by the {label} (fits {first} better on the training rows than the other reading)")
    models = {first: m0}
    for name, y in outputs.items():
        if name not in models:
            models[name] = _fit_channel(name, P, y, train, valid[name], r, z0)
    models = {k: models[k] for k in outputs}
    fit = BaseFit(t=t, v_drive=vd, voltage_source=label, train=train, channels=models, starts_from_rest=from_rest,
                  basis=np.column_stack([P, np.ones(t.size)]), notes=notes,
                  test=~train if test is None else np.asarray(test, bool) & ~train)
    if "charge" in outputs and "displacement" in outputs:
        q = outputs["charge"] - outputs["charge"][0]
        x = outputs["displacement"] - (np.mean(outputs["displacement"][t - t[0] <= REST_S]) if from_rest else 0.0)
        k = float(q[train] @ x[train] / (q[train] @ q[train]))       # eq. 11
        fit.k_q2x_m_per_c = k
        if pzt is not None:
            tem, kp = pzt.transducer_constant_n_per_v, pzt.stiffness_n_per_m
            fit.working_capacitance_f = float((tem - tem * tem * k) / (kp * k))     # eq. 12
    if "gauge" in outputs and "displacement" in outputs:
        rows = train & valid["gauge"]
        b, a = np.polyfit(outputs["displacement"][rows], outputs["gauge"][rows], 1)
        fit.gauge_gain_v_per_m, fit.gauge_offset_v = float(b), float(a)
    return fit
