"""Trace a base fit's residuals to the one physical effect the declared plant lacks.

Every candidate of the effect library is fitted to the residual of every channel it can
appear in (on the training rows) and scored on the held-out rows by

    ratio = rms_after (1 + penalty n_params) / rms_before

The lowest ratio wins, unless it does not reach ``max_ratio`` (default 0.8: the effect must
remove at least a fifth of the held-out error, penalty included); then the answer is ``none``
-- the residual is what the sensors' noise and the base model's own approximation leave.

Which signal drives each candidate follows its physics:

* charge channel: ``dielectric_absorption`` and ``leakage`` by the driving voltage (charge per
  volt, seed 002 eqs. 2.7 and 2.9), ``drift`` by time (linear only: a current monitor's offset, seed 002's bias current), ``creep`` (by the channel's base
  prediction) only when no displacement is recorded;
* displacement channel: ``creep`` and ``resonance`` act on the motion, so they are driven by
  the channel's base prediction (the hysteretic quasi-static displacement), ``delay`` shifts
  it, ``drift`` is a function of time;
* gauge channel: the same four against its own voltage-driven model, and
  ``gauge_nonlinearity`` against the LINE from the recorded displacement (eq. 27's bow is a
  property of the gauge's reading of x, not of the stack).

Cross-channel rules turn a fit into a diagnosis (the "tracing"):

1. A relaxation in the charge that the displacement shows too is creep, not dielectric
   absorption or leakage: seed 002 defines Q_DA and the leakage charge as charge that does not
   move the stack, while creep moves both (the charge tracks the displacement). So when the
   best candidate is ``dielectric_absorption`` or ``leakage`` on the charge and ``creep`` on
   the displacement also passes ``max_ratio``, the answer is creep on the displacement.
2. A mechanical effect (creep, resonance) found on the gauge that the displacement shows too
   is reported on the displacement: it is the stack's, not the gauge's.
"""

import numpy as np
from scipy.optimize import lsq_linear

from .base_fit import BaseFit, small_problem
from .effects import CreepSpectrum, Delay, DielectricAbsorption, Drift, GaugeNonlinearity, Leakage, Resonance
from .pi_fit import rms

__all__ = ["trace_effect", "candidate_plan"]


def _errors(e):
    return {"rms": rms(e), "max": float(np.max(np.abs(e))) if e.size else float("nan")}


def candidate_plan(channels):
    """(channel, effect, driver) triples for the recorded ``channels`` (see the module notes)."""
    plan = []
    has_x = "displacement" in channels
    if "displacement" in channels:
        plan += [("displacement", CreepSpectrum(), "model"), ("displacement", Resonance(), "model"),
                 ("displacement", Delay(max_delay=30), "model"), ("displacement", Drift(), "time")]
    if "charge" in channels:
        plan += [("charge", DielectricAbsorption(), "voltage"), ("charge", Leakage(), "voltage"),
                 ("charge", Drift(degree=1), "time")]
        if not has_x:
            plan.append(("charge", CreepSpectrum(), "model"))
    if "gauge" in channels:
        plan += [("gauge", CreepSpectrum(), "model"), ("gauge", Resonance(), "model"),
                 ("gauge", Delay(max_delay=30), "model"), ("gauge", Drift(), "time")]
        if has_x:
            plan.append(("gauge", GaugeNonlinearity(), "displacement"))
    return plan


def _gauge_line(base):
    x = base.channels["displacement"].y
    return base.gauge_offset_v + base.gauge_gain_v_per_m * x, x


class _Joint:
    """The base model's columns on the fitting rows, for joint effect fits.

    ``project(X)`` removes from training-row columns what the base columns explain (the
    unconstrained projection, for an effect's own nonlinear parameters); ``fit_with`` solves
    base and effect columns together with their sign constraints. With ``R^T R`` the Gram
    matrix of the (unit-scaled) columns, the bounded solve runs on a columns x columns system
    (``base_fit.small_problem``).
    """

    def __init__(self, A_full, rows, nonneg):
        A = A_full[rows]
        norms = np.sqrt(np.einsum("ij,ij->j", A, A) / max(int(rows.sum()), 1))
        keep = norms > 1e-12 * norms.max()
        self.A_full = A_full[:, keep] / norms[keep]
        self.nonneg = np.asarray(nonneg, bool)[keep]
        self.rows = rows
        self.A = self.A_full[rows]
        # the search for an effect's nonlinear parameters scores every 3rd fitting row: the
        # columns are still computed at the full rate (filters need it), only the cost is thinned
        idx = np.flatnonzero(rows)[::3]
        self.search = np.zeros(rows.size, bool)
        self.search[idx] = True
        self.A_s = self.A_full[idx]
        self.gram_inv_s = np.linalg.pinv(self.A_s.T @ self.A_s, rcond=1e-12)

    def project(self, X):
        """Project out the base columns from columns on the SEARCH rows (``self.search``)."""
        return X - self.A_s @ (self.gram_inv_s @ (self.A_s.T @ X))

    def fit_with(self, C_full, y, lower):
        """Base and extra columns ``C_full`` (bounds ``lower``, upper +inf) fitted jointly to ``y``.

        Returns ``(prediction over the whole record, extra gains)``.
        """
        C_full = np.atleast_2d(np.asarray(C_full, float).T).T
        C = C_full[self.rows]
        norms = np.sqrt(np.einsum("ij,ij->j", C, C) / C.shape[0])
        norms[norms == 0] = 1.0
        k = self.A.shape[1]
        R, rhs = small_problem(np.column_stack([self.A, C / norms]), np.asarray(y)[self.rows])
        lb = np.r_[np.where(self.nonneg, 0.0, -np.inf), np.asarray(lower, float)]
        sol = lsq_linear(R, rhs, bounds=(lb, np.full(lb.size, np.inf)), method="bvls", tol=1e-12).x
        g = sol[k:] / norms
        return self.A_full @ sol[:k] + C_full @ g, g


def _fit_candidate(eff, t, u, y, yhat, rows, joint):
    """Fit one effect together with the base model.

    The effect's nonlinear parameters (a time constant, a mode, a delay) come from its own fit
    with the base columns projected out (variable projection against the unconstrained base,
    so a term the base would otherwise absorb -- a charge term proportional to V, say -- is
    found). Then the base and the effect's columns are solved jointly by one bounded least
    squares with the base's sign constraints (play weights >= 0) and the effect's own (creep
    gains >= 0): the constrained joint optimum, so the two cannot trade a term against negative
    weights that only fit the training rows. Effects without ``columns`` enter as their fitted
    term with a free non-negative scale.
    """
    best = None
    # effects with nonlinear parameters search twice: against the projected base (finds what the
    # base would absorb) and on the plain residual (no projection to distort a narrow valley);
    # the joint constrained fit on the training rows decides (held-out rows never do)
    modes = (joint.project, None) if getattr(eff, "nonlinear", False) else (joint.project,)
    for project in modes:
        p = eff.fit(t, u, y - yhat, joint.search, y_model=yhat, project=project)
        if hasattr(eff, "columns"):
            C, lower = eff.columns(t, u, p, y_model=yhat)
            C = np.atleast_2d(np.asarray(C, float).T).T
            pred, g = joint.fit_with(C, y, lower)
            p = eff.with_gains(p, g)
            term = C @ g
        else:
            term0 = eff.term(t, u, p, y_model=yhat)
            pred, g = joint.fit_with(term0, y, [0.0])
            term = term0 * g[0]
            p = {**p, "scale": float(g[0])}
        cost = rms((y - pred)[rows])
        if best is None or cost < best[0]:
            best = (cost, pred, term, p)
    _, pred, term, p = best
    return pred, term, p


def trace_effect(base: BaseFit, penalty=0.02, max_ratio=0.8, progress=None):
    """Fit every candidate, score it on the held-out rows and name the effect.

    Returns
    -------
    dict
        ``effect`` (name or ``"none"``), ``channel``, ``error_before`` / ``error_after``
        (``{rms, max, units}`` on the held-out rows of that channel), ``parameters``,
        ``candidates`` (``name``, ``channel``, ``score`` = the penalized ratio,
        ``error_after``), ``channels`` (each channel's held-out error before), ``reason``,
        and, for plotting, ``terms``: (channel, base prediction, fitted term) of the answer.
    """
    t = base.t
    train = base.train
    plan = candidate_plan(base.channels)
    before = {}
    cands = []
    fitted = {}
    joints = {}
    for k, (ch, eff, driver) in enumerate(plan):
        if progress:
            progress("effects", k, len(plan))
        m = base.channels[ch]
        test = base.test & m.valid
        fit_rows = train & m.valid
        if eff.name == "gauge_nonlinearity":
            yhat, u = _gauge_line(base)
            key = (ch, "line")
            if key not in joints:
                joints[key] = _Joint(np.column_stack([np.ones(t.size), u]), fit_rows, [False, False])
        else:
            yhat = m.yhat
            u = {"model": m.yhat, "voltage": base.v_drive, "time": t}[driver]
            key = (ch, "model")
            if key not in joints:
                joints[key] = _Joint(base.basis, fit_rows, np.r_[np.ones(base.basis.shape[1] - 1, bool), False])
        joint = joints[key]
        e = m.y - yhat
        if key not in before:
            before[key] = _errors(e[test])
        if not before[key]["rms"] > 0 or int(fit_rows.sum()) < 10 * (base.basis.shape[1] + 3):
            continue                        # a dead or fully clipped channel: nothing to explain
        try:
            pred, term, p = _fit_candidate(eff, t, u, m.y, yhat, fit_rows, joint)
        except ValueError:
            continue
        after = _errors((m.y - pred)[test])
        ratio = after["rms"] * (1 + penalty * eff.n_params) / before[key]["rms"]
        cands.append({"name": eff.name, "channel": ch, "score": float(ratio), "n_params": int(eff.n_params),
                      "error_after": {**after, "units": m.units},
                      "error_before": {**before[key], "units": m.units}})
        fitted[(eff.name, ch)] = (p, pred - term, term)
    if progress:
        progress("effects", len(plan), len(plan))
    cands.sort(key=lambda c: c["score"] if np.isfinite(c["score"]) else np.inf)
    by = {(c["name"], c["channel"]): c for c in cands}
    out = {"candidates": cands,
           "channels": {ch: {**before[(ch, "model")], "units": base.channels[ch].units} for ch in base.channels
                        if (ch, "model") in before}}
    passing = [c for c in cands if np.isfinite(c["score"]) and c["score"] <= max_ratio]
    if not passing:
        first = next(iter(base.channels))
        ch = "displacement" if "displacement" in base.channels else first
        err = {**before[(ch, "model")], "units": base.channels[ch].units}
        out.update(effect="none", channel=ch, error_before=err, error_after=err, parameters={},
                   reason=f"no candidate brings the held-out error ratio to {max_ratio} (best "
                          f"{cands[0]['score']:.2f} > {max_ratio})" if cands else "no candidate applies")
        return out
    best = passing[0]
    reason = "lowest penalized held-out error ratio"
    creep_x = by.get(("creep", "displacement"))
    if best["channel"] == "charge" and best["name"] in ("dielectric_absorption", "leakage") and creep_x \
            and creep_x["score"] <= max_ratio:
        reason = (f"the charge's {best['name']} (ratio {best['score']:.2f}) moves the stack too (creep on the "
                  f"displacement, ratio {creep_x['score']:.2f}): charge and displacement relax together, so creep")
        best = creep_x
    elif best["channel"] == "gauge" and best["name"] in ("creep", "resonance"):
        twin = by.get((best["name"], "displacement"))
        if twin and twin["score"] <= max_ratio:
            reason = f"{best['name']} seen on the gauge and the displacement alike: the stack's, reported there"
            best = twin
    p, yhat, term = fitted[(best["name"], best["channel"])]
    out.update(effect=best["name"], channel=best["channel"], error_before=best["error_before"],
               error_after=best["error_after"], parameters=_jsonable(p), reason=reason,
               terms={"channel": best["channel"], "base": yhat, "term": term})
    return out


def _jsonable(p):
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in p.items()}
