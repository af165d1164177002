"""The stack's charge, not its displacement: drift compensation identified in coulombs for the force path.

Why the force path needs its own identification. The displacement estimator of :mod:`.identify`
fits its stage-4 operator to delta_s - delta_ref in metres, with alpha from the 0 -> 20 V step
(eq. 2.10). The step's alpha carries the absorption charge that flows during the ramp and the
50 ms after it (~0.08 % with the default circuit), and the stage-4 fit then absorbs
(alpha_true / alpha - 1) x as a function of V_in: the displacement comes out right, and the
"charge" alpha delta_s is alpha x, not q. The force reads q (k_p / T_em ~ 4 N per uC before the
hysteresis inverse amplifies it), so at 50 V that 0.08 % is ~0.4 uC, ~5 N of offset.

What this module does instead (on the same identification record, no extra test):

1. **alpha from the triangle reversals.** At a reversal of V_in the slope of every drift term
   is continuous: leakage (V_in / R_FP), bias (constant) and each absorption relaxation
   (tau y' = V_in - y) have derivatives that are continuous functions of V_in, which is
   continuous. The stack's charge and its displacement jump in slope together (q = alpha x at
   F_e = 0, seed 000 eq. 10, creep included). So alpha = (jump in dq/dt) / (jump in dx_ref/dt).
   The jump is read by least squares with a continuous piecewise cubic around the reversal
   (one value, each side its own slope and curvature) over ``REVERSAL_WINDOW_FRACTION`` of
   the shorter adjacent ramp. The fit is linear, applied alike to q and x_ref, so the
   stack's hysteresis (x's kinks after a reversal) cancels in the ratio; only the drift's
   departure from a cubic and the reference noise remain, so the window is as long as the
   ramps allow. The reversals are pooled by least squares (sum dq dx / sum dx^2); their
   scatter gives alpha's standard error.
2. **Leakage, bias and absorption in coulombs.** With that alpha fixed, q_raw - alpha x_ref
   (q_raw = C_R V_in - C_int V_out) is fitted by linear least squares with int V_in dt
   (1/R_FP), t (i_bias) and relaxations of V_in: real absorption is a spread of time
   constants (eq. 2.11's single relaxation leaves the slower branch in the residual). The
   bank's density (:data:`ABSORPTION_BANKS`) is chosen on the record's held-out part, the
   small triangles and the last hold, as :mod:`.identify` chooses its stage-4 structure.
   No alpha sits between the fit and the charge it corrects.

Only the circuit's known C_int and C_R are taken from :func:`.identify.identify`.
"""

from dataclasses import dataclass, replace

import numpy as np

from .charge_amp import cumulative_integral, relax_foh
from .estimator import charge_estimate

__all__ = ["ChargeDrift", "reversal_alpha", "identify_charge_drift", "ABSORPTION_BANKS", "REVERSAL_WINDOW_FRACTION",
           "REVERSAL_MIN_RATE_V_PER_S"]

#: Candidate absorption banks: relaxations of V_in spaced 1, 2, 3 or 4 per decade over 0.1-1000 s.
ABSORPTION_BANKS = {f"{n} per decade": tuple(float(x) for x in 10.0 ** np.arange(-1.0, 3.0 + 1e-9, 1.0 / n))
                    for n in (1, 2, 3, 4)}
REVERSAL_WINDOW_FRACTION = 0.9     # each side of the fit spans 90 % of the shorter adjacent ramp
REVERSAL_DEGREE = 3                # each side: cubic (the hysteresis cancels; see the module notes)
REVERSAL_MIN_RATE_V_PER_S = 1.0    # a reversal: V_in's slope changes sign, at least this fast on both sides


@dataclass(frozen=True)
class ChargeDrift:
    """Drift compensation of the stack's charge (SI), identified in coulombs (module notes).

    ``alpha_c_per_m`` and its standard error ``alpha_sem_c_per_m`` (from ``n_reversals``
    reversals); leakage ``r_leak_ohm`` and bias ``i_bias_a`` from stage 2; absorption gains
    ``gains_f`` on ``time_constants_s`` (signed: the bank is a fit, not a circuit).
    """

    alpha_c_per_m: float
    alpha_sem_c_per_m: float
    n_reversals: int
    base: object                    # EstimatorParams of stage 2 (leakage and bias)
    time_constants_s: tuple
    gains_f: tuple
    fit_rms_c: float
    bank: str = ""
    held_out_rms_c: dict = None

    def charge(self, t_s, v_in_v, v_out_v):
        """The stack's terminal charge since the reset from a charge-amplifier record, C."""
        t = np.asarray(t_s, float)
        v = np.asarray(v_in_v, float)
        dt = float(t[1] - t[0])
        q = charge_estimate(t, v, v_out_v, self.base)
        for k, tau in zip(self.gains_f, self.time_constants_s):
            q = q - k * relax_foh(v, tau, dt)
        return q

    def as_dict(self):
        return {"alpha_c_per_m": self.alpha_c_per_m, "alpha_sem_c_per_m": self.alpha_sem_c_per_m,
                "n_reversals": self.n_reversals, "r_leak_ohm": self.base.r_leak_ohm, "i_bias_a": self.base.i_bias_a,
                "time_constants_s": list(self.time_constants_s), "gains_f": list(self.gains_f),
                "fit_rms_c": self.fit_rms_c, "bank": self.bank, "held_out_rms_c": dict(self.held_out_rms_c or {})}


def _slope_jump(y, i, n, dt):
    """Jump in dy/dt at sample i: a continuous piecewise cubic (one value at i, its own slope and
    curvature on each side) fitted over the n samples either side, least squares."""
    tau = np.arange(-n, n + 1) * dt
    lo, hi = np.minimum(tau, 0.0), np.maximum(tau, 0.0)
    cols = np.column_stack([np.ones_like(tau)] + [c ** p for p in range(1, REVERSAL_DEGREE + 1) for c in (lo, hi)])
    scale = np.max(np.abs(cols), axis=0)
    c, *_ = np.linalg.lstsq(cols / scale, y[i - n:i + n + 1], rcond=None)
    c = c / scale
    return c[2] - c[1]


def _reversals(t, v, min_rate):
    """(index, samples of ramp before, samples of ramp after) for each reversal of V_in.

    V_in's slope, averaged over 0.25 s, is classed as rising, falling (faster than ``min_rate``)
    or neither; a reversal is a rising run followed by a falling one (or the reverse) with less
    than 0.25 s between them, placed at V_in's extreme in that gap.
    """
    dt = float(t[1] - t[0])
    n0 = max(4, int(round(0.25 / dt)))
    rate = np.convolve(np.diff(v) / dt, np.ones(n0) / n0, mode="same")
    s = np.where(rate > min_rate, 1, np.where(rate < -min_rate, -1, 0))
    edges = np.flatnonzero(np.diff(s)) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [s.size]])
    runs = [(a, b, s[a]) for a, b in zip(starts, ends) if s[a] != 0]
    out = []
    for (a1, b1, s1), (a2, b2, s2) in zip(runs[:-1], runs[1:]):
        if s1 == -s2 and a2 - b1 < n0:
            lo, hi = max(b1 - n0, 0), min(a2 + n0, v.size - 1)
            seg = v[lo:hi + 1]
            i = lo + int(np.argmax(seg) if s1 > 0 else np.argmin(seg))
            out.append((i, i - a1, b2 - i))
    return out


def reversal_alpha(t_s, v_in_v, q_c, x_ref_m, window_fraction=REVERSAL_WINDOW_FRACTION,
                   min_rate_v_per_s=REVERSAL_MIN_RATE_V_PER_S):
    """alpha = jump in dq/dt over jump in dx/dt at V_in's reversals (module notes, step 1).

    Parameters
    ----------
    t_s, v_in_v, q_c, x_ref_m : array_like of float
        Uniform sample times (s), terminal voltage (V), charge (C; any drift that is an LTI
        function of V_in or of time may remain in it) and reference displacement (m), at F_e = 0.

    Returns
    -------
    (alpha C/m, standard error C/m, number of reversals used)
    """
    t, v = np.asarray(t_s, float), np.asarray(v_in_v, float)
    q, x = np.asarray(q_c, float), np.asarray(x_ref_m, float)
    dt = float(t[1] - t[0])
    jq, jx = [], []
    for i, n_l, n_r in _reversals(t, v, min_rate_v_per_s):
        n = int(window_fraction * min(n_l, n_r))
        if n < 8 or i - n < 0 or i + n >= v.size:
            continue
        jq.append(_slope_jump(q, i, n, dt))
        jx.append(_slope_jump(x, i, n, dt))
    if len(jx) < 2:
        raise ValueError("the record has fewer than two reversals of V_in to read alpha from "
                         f"(ramps faster than {min_rate_v_per_s} V/s that change direction)")
    jq, jx = np.array(jq), np.array(jx)
    alpha = float(np.dot(jq, jx) / np.dot(jx, jx))
    resid = jq - alpha * jx
    sem = float(np.sqrt(np.dot(resid, resid) / (jx.size - 1) / np.dot(jx, jx)))
    return alpha, sem, int(jx.size)


def _drift_columns(t, v, taus_s):
    dt = float(t[1] - t[0])
    return np.column_stack([cumulative_integral(t, v), t] + [relax_foh(v, tau, dt) for tau in taus_s])


def _fit(cols, y, mask):
    scale = np.sqrt(np.mean(cols[mask] ** 2, axis=0))
    scale[scale == 0] = 1.0
    k, *_ = np.linalg.lstsq(cols[mask] / scale, y[mask], rcond=None)
    return k / scale


def identify_charge_drift(idrec, ident, banks=ABSORPTION_BANKS):
    """:class:`ChargeDrift` from an identification record (module notes).

    Parameters
    ----------
    idrec : IdentificationRecord
        The record :func:`.identify.identify` used (F_e = 0, interferometer reference).
    ident : Identified
        Supplies only the circuit's known C_int and C_R.
    banks : dict of str to tuple of float
        Candidate absorption banks (time constants, s). Each is fitted without the record's
        validation part (the small triangles and the last hold) and scored on it; the one with
        the lowest held-out RMS is refitted on the whole record.
    """
    rec, x_ref = idrec.record, idrec.x_ref_m
    t, v = rec.t_s, rec.v_in_v
    raw = replace(ident.stage("uncompensated"), alpha_c_per_m=1.0)
    q_raw = charge_estimate(t, v, rec.v_out_v, raw)             # C_R V_in - C_int V_out
    alpha, sem, n = reversal_alpha(t, v, q_raw, x_ref)
    y = q_raw - alpha * x_ref
    val = (t >= idrec.validation[0]) & (t <= idrec.validation[1])
    held_out = {}
    for name, taus in banks.items():
        cols = _drift_columns(t, v, taus)
        r = (y - cols @ _fit(cols, y, ~val))[val]
        held_out[name] = float(np.sqrt(np.mean(r * r)))
    best = min(held_out, key=held_out.get)
    taus = tuple(float(x) for x in banks[best])
    cols = _drift_columns(t, v, taus)
    k = _fit(cols, y, np.ones(t.size, bool))
    if k[0] <= 0:
        # a negative conductance is no leakage: refit without that column, so the bias and the
        # absorption gains are not the ones fitted beside an unphysical leak
        k = np.concatenate([[0.0], _fit(cols[:, 1:], y, np.ones(t.size, bool))])
    r = y - cols @ k
    base = replace(raw, alpha_c_per_m=alpha, r_leak_ohm=1.0 / k[0] if k[0] > 0 else float("inf"), i_bias_a=float(k[1]))
    return ChargeDrift(alpha, sem, n, base, taus, tuple(float(x) for x in k[2:]), float(np.sqrt(np.mean(r * r))),
                       best, held_out)
