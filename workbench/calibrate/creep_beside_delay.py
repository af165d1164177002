"""Creep beside a found sensor delay: the two fitted jointly (issue 13 item 5, session 14).

A displacement sensor that lags by ``d`` reads the stack's crept motion late: the record is
``x(t - d)`` with ``x = base(u) + creep(u)``. A delay found first was searched and refitted
without creep (:class:`~workbench.calibrate.effects.Delay`'s refit: the drive model's weights at
each trial delay): its refit takes what it can of the creep into the play weights and its
delay moves to meet the creep's fast branch halfway (a branch of ``tau`` near ``d`` mimics the
delay, ``-tau du/dt`` against ``-d dy/dt``; seen, 30 #97 at 100 kHz: a 38.80 ms delay found at
38.68 ms, 11 samples short, whose step edges then leave more than the creep, so creep's columns
taken orthogonal to that delay explained ~15 % of the leftover and passed no fold).

Here the later stage's creep candidate on that channel is the **joint model**
(:func:`creep_beside_delay`): the delay searched again with the creep spectrum's columns in its
refit (the drive model's columns, its prediction and the branches, all delayed by the trial
``d``: the record's own search, :meth:`~workbench.calibrate.effects.Delay._fit_refit`, with a
wider basis), then the delay's column at that ``d`` (the refitted drive model shifted, the
creep's part left out) and the branches delayed by ``d`` (gains ``>= 0``; driven by the stack's motion as
the found delay reads it, the drive model refitted at its lag, :func:`_stack_motion`, recorded as the
creep's drive, ``driver: refit``, for the written plant and the other channels), which *replace* the
found delay's column (``replaces``). The stage's fold test compares it with the delay alone by
the bars every candidate clears (noise floor, random term, ``min_share``, the folds it must win)
and the stage's rival (a second delay on what the first leaves): creep is named where the joint
model explains what the delay alone cannot. Named, the delay's stage carries the refitted delay
(:func:`refitted_joint_stage`). Every number comes from the record: the branches are the
record's creep grid, the delay's bounds the found delay's.
"""

import copy

import numpy as np

from .stacking import column_stack
from .effects import CreepSpectrum, Delay, _bounded_delta, _c_ordered, _dt
from .tracing import _base_lower

__all__ = ["DelayedCreep", "creep_beside_delay", "delay_beside_creep", "refitted_joint_stage"]


class DelayedCreep(CreepSpectrum):
    """The creep spectrum of a joint creep + delay candidate (:func:`creep_beside_delay`).

    Its candidate's columns are the branches (delayed by the refitted delay) then the delay's
    column; the gains a joint fit returns are in that order, and the branches' are the first
    ``len(taus_s)``. :meth:`columns` gives the stack's branches undelayed (what the charge and the
    gauge, which the displacement sensor's delay does not reach, read of the same creep).
    """

    def with_gains(self, params, gains):
        k = len(params["taus_s"])
        return super().with_gains(params, np.asarray(gains, float)[:k])

    def _uses_drive(self, params):
        # the drive of :func:`creep_beside_delay` (``driver: "refit"``): the drive model refitted at the found delay
        return params.get("driver") in ("v_h", "refit") and self._drive is not None


def _found(extra, key, tag):
    return [x for x in extra.get(key, ()) if getattr(x, "tag", None) == tag]


def _branch_drive(cr):
    """What drives a found creep's branches: its ``V_h`` (scaled to the model's units,
    :class:`~workbench.calibrate.effects.CreepSpectrum` with ``loop``) when it was fitted with one, else
    ``None`` (the channel's base model drives them).

    :func:`delay_beside_creep`'s branches are the found creep's own: driven by the base model while the
    creep alone is driven by ``V_h``, the joint model's creep part was a second, different creep, and on
    a 10 kHz sine with a large creep (71 #46, 27.6x) it replaced the ``V_h`` creep and won through that
    part, its "delay" a 3.3-sample *lead* (the simulator's sensor delays are lags) (session 18).
    :func:`creep_beside_delay` (no creep found yet) takes no ``V_h`` (its branches are driven by the drive
    model refitted at the found delay, :func:`_stack_motion`): with ``V_h`` there, 71 #53
    (creep 22.8x behind a 35 ms delay, 10 kHz sine) kept its answer but left 4.39e-8 m against 2.03e-8 m.
    """
    eff = cr.get("eff")
    uses = getattr(eff, "_uses_drive", None)
    return eff._drive if uses is not None and uses(cr["params"]) else None


def _joint(cr, dl, prob, base, t, lower=None, rows_list=None, drive=None):
    """The joint creep + delay columns of one model problem: ``(d, Kd, D)``.

    The delay ``d`` (samples) searched with the creep branches in the drive model's refit
    (:meth:`~workbench.calibrate.effects.Delay._fit_refit` with the branches beside the drive's
    columns, on the problem's search rows, within the found delay's bounds); ``Kd``: the branches,
    driven by ``drive`` (a found creep's ``V_h``, :func:`_branch_drive`; the drive model refitted at the
    found delay, :func:`_stack_motion`; by default the channel's base model), delayed by ``d``; ``D``: the drive model refitted at ``d``
    with the branches beside it (its weights' corrections bounded as the base's, ``lower``: the
    plays stay >= 0; the branches' gains >= 0), without the branches, delayed by ``d``, less itself:
    the latency alone, as the delay's own column; its change of weights from the base is left to the
    base's columns, which the bounded refit keeps within their bounds, so the joint fit's base weights
    are the refitted core the plant file carries (a column carrying the change too left them at the
    base's and the written plant off by 9x on a drawn 1 kHz record). With ``rows_list``, ``D`` is
    a list, the refit made on each row set (a fold's training search rows: its validation rows
    never shape the column, as :meth:`~workbench.calibrate.effects.Delay.fold_columns`).
    """
    from .base_fit import _gram_solve
    ch = cr["channel"]
    m = base.channels[ch]
    y = np.asarray(m.y, float)
    ym = np.asarray(m.yhat, float)
    taus = np.asarray(cr["params"]["taus_s"], float)
    K = CreepSpectrum._columns(ym if drive is None else drive, taus, _dt(t))   # the stack's branches
    B = dl["eff"].basis
    Bc = _c_ordered(B)                                     # (the delay's own C-ordered copy, shared)
    Kc = np.ascontiguousarray(K)
    ymc = ym[:, None]
    rows = np.flatnonzero(prob.search)                     # (search rows: development rows, valid)
    # the found lag is tried too: the joint model nests the plain one, so its cost there is no higher
    d = Delay(max_delay=dl["eff"].max_delay, basis=B, max_lead=dl["eff"].max_lead,
              period=getattr(dl["eff"], "period", None))._search_refit(
        (Bc, Kc, ymc), y, rows, near=(dl.get("params") or {}).get("delay_samples"))
    all_rows = np.arange(t.size, dtype=float)
    Kd = Delay._rows_shifted(Kc, all_rows, d)
    lo = np.r_[np.full(B.shape[1], -np.inf) if lower is None else np.asarray(lower, float), np.zeros(taus.size)]

    def column(rows):
        # the bounded refit at d on ``rows``: y(t) ~ ym(t - d) + [B, K](t - d) [delta, c]
        X = np.hstack([Delay._rows_shifted(Bc, rows, d), Delay._rows_shifted(Kc, rows, d)])
        r = y[rows] - Delay._rows_shifted(ymc, rows, d)[:, 0]
        nrm = np.sqrt(np.mean(X * X, axis=0)) if rows.size else np.ones(X.shape[1])
        nrm = np.where(nrm > 0, nrm, 1.0)
        Xs = X / nrm
        delta = _gram_solve(Xs.T @ Xs, Xs.T @ r, lo * nrm) / nrm
        drive = ym + B @ delta[:B.shape[1]]
        return Delay._rows_shifted(drive[:, None], all_rows, d)[:, 0] - drive

    D = column(rows)
    if rows_list is None:
        return float(d), Kd, D
    return float(d), Kd, D, [column(np.asarray(r)) for r in rows_list]


def _columns(prob, C, lower):
    """A candidate's columns as :meth:`~workbench.calibrate.tracing._Problem.grams` keeps them (unit
    RMS on the development rows, zero columns dropped), without the Gram matrices: the scoring
    (:func:`~workbench.calibrate.tracing._stacked`) forms them with the found effects' columns."""
    Cd = C[prob.rows_dev_idx]
    n = np.sqrt(np.einsum("ij,ij->j", Cd, Cd) / max(prob.rows_dev_idx.size, 1))
    ok = n > 0
    # (every column kept, the usual case: one division, no fancy-indexed copy first; the same values)
    return {"G": None, "C": C / n if ok.all() else C[:, ok] / n[ok], "norms": n[ok], "ok": ok,
            "lb": np.r_[prob.lower_A, np.asarray(lower, float)[ok]]}


def _fold_rows(prob):
    """Each fold's training search rows (as :func:`~workbench.calibrate.tracing._fold_grams`)."""
    return [np.flatnonzero(prob.search & prob.split.rows(tr)) for tr, _ in prob.split.folds]


def _pair(c, cands, extra, found_name):
    """The found effect's and the candidate's partner rows of one problem, or None."""
    key, ch = c["key"], c["channel"]
    if key[1] != "model" or not _found(extra, key, (found_name, ch)):
        return None
    other = "delay" if c["name"] == "creep" else "creep"
    o = next((d for d in cands if (d["name"], d["channel"]) == (other, ch) and d["key"] == key), None)
    if o is None:
        return None
    cr, dl = (c, o) if c["name"] == "creep" else (o, c)
    if getattr(dl["eff"], "basis", None) is None or not dl["params"].get("refit") or "taus_s" not in cr["params"]:
        return None
    return cr, dl


def _own_gains(prob, extra, key, gone, g):
    """The candidate's gains of the joint fit on the development rows (the found ``gone`` left out)."""
    from .tracing import _stacked
    rest = [x for x in extra[key] if getattr(x, "tag", None) != gone]
    w = prob.solve(_stacked(prob, rest, {"g": g}), prob.split.dev_blocks)
    own = np.zeros(g["ok"].size)
    own[g["ok"]] = w[w.size - g["C"].shape[1]:]
    return own


def _stack_motion(dl, prob, base, ch, lower):
    """The stack's motion as the found delay reads it: the drive model refitted at the found lag.

    The base model was fitted to the lagging record as if it were not lagged (:class:`~.effects.Delay`'s
    refit); the found delay's refit is the drive model whose shift by the lag matches the record, so it,
    not the base model, is the stack's motion that creeps: ``ym + B delta`` with ``delta`` the bounded
    least squares of ``y(t) - ym(t - d) ~ B(t - d) delta`` on the search rows (as :func:`_joint`'s column)."""
    d0 = (dl.get("params") or {}).get("delay_samples")
    if d0 is None:
        return None
    m = base.channels[ch]
    y, ym = np.asarray(m.y, float), np.asarray(m.yhat, float)
    B = dl["eff"].basis
    rows = np.flatnonzero(prob.search)
    X = Delay._rows_shifted(_c_ordered(B), rows, float(d0))
    r = y[rows] - Delay._rows_shifted(ym[:, None], rows, float(d0))[:, 0]
    lo = np.full(B.shape[1], -np.inf) if lower is None else np.asarray(lower, float)
    return ym + B @ _bounded_delta(X.T @ X, X.T @ r, rows.size, lo)


def creep_beside_delay(c, cands, probs, extra, t, base):
    """The later stage's creep candidate once a delay is found on its channel: the two jointly.

    Parameters
    ----------
    c : dict
        The first stage's creep candidate (the displacement's or the gauge's model problem).
    cands : list of dict
        The first stage's candidates (the delay's among them: its bounds and the drive's columns).
    probs, extra : dict
        The linear problems and the found effects' columns per problem
        (:func:`~workbench.calibrate.tracing._absorb`).
    t : ndarray of float
        Sample times, s (uniform).
    base : BaseFit
        The base fit.

    Returns
    -------
    dict or None
        The candidate row (``g``: the branches delayed by the refitted delay, then the delay's
        column; ``n_params``: the branches with a positive gain on the development rows, plus
        one for the moved delay; ``replaces``: the found delay; ``refit``: its ``delay_samples``
        and ``delay_s``), or ``None`` when no delay with a drive model was found on the
        channel's problem or no branch takes a positive gain.
    """
    pair = _pair(c, cands, extra, "delay")
    if pair is None:
        return None
    key, tag = c["key"], ("delay", c["channel"])
    prob = probs[key]
    taus = np.asarray(c["params"]["taus_s"], float)
    lower_b = _base_lower(base, c["channel"])
    # the branches driven by the stack's motion as the found delay reads it, not by the base model fitted to the
    # lagging record as if it were not late (seed 88 #97, 100 kHz steps, creep + 36 ms delay: on the base model the
    # joint fit put gain on the 4 ms and 40 s branches only, the latter copying -ym(t - d), and creep passed no fold)
    drive = _stack_motion(pair[1], prob, base, c["channel"], lower_b)
    d, Kd, D, Df = _joint(c, pair[1], prob, base, t, lower_b, _fold_rows(prob), drive)
    lower = [0.0] * (taus.size + 1)
    g = _columns(prob, column_stack([Kd, D]), lower)
    if not g["ok"][-1]:
        return None
    fold_g = [_columns(prob, column_stack([Kd, Dk]), lower) for Dk in Df]
    if any(gk["ok"].tolist() != g["ok"].tolist() for gk in fold_g):
        return None
    n_pos = int(np.count_nonzero(_own_gains(prob, extra, key, tag, g)[:taus.size] > 0))
    if n_pos == 0:
        return None
    eff = DelayedCreep(taus_s=taus)
    eff.n_params = n_pos + 1
    # the drive recorded (``driver: "refit"``): the written plant and the other channels rebuild the branches on it
    eff._drive = None if drive is None else np.asarray(drive, float)
    params = {"gains": np.zeros(taus.size).tolist(), "taus_s": taus.tolist()}
    if drive is not None:
        params["driver"] = "refit"
    return {**c, "eff": eff, "params": params, "g": g, "n_params": n_pos + 1, "researched": True,
            "fold_g": fold_g, "replaces": tag, "refit": {"delay_samples": d, "delay_s": d * _dt(t)}}


def delay_beside_creep(c, cands, probs, extra, t, base):
    """The later stage's delay candidate once creep is found on its channel: the two jointly.

    The mirror of :func:`creep_beside_delay`: the creep found first took the part of a short
    delay its fast branches mimic (``-tau du/dt`` against ``-d dy/dt``), and the delay searched on
    what it leaves sees only the rest. The candidate is the delay's column at the delay searched
    with the branches in its refit, then the branches delayed by it (gains ``>= 0``), in the
    found creep's place (``replaces``); ``n_params`` 1 (the delay; the branches' gains were the
    found creep's). Same parameters and return as :func:`creep_beside_delay` (``refit``: the
    branches' time constants; the creep stage's gains are the joint fit's,
    :func:`refitted_joint_stage`).
    """
    pair = _pair(c, cands, extra, "creep")
    if pair is None:
        return None
    cr = pair[0]
    key, tag = c["key"], ("creep", c["channel"])
    prob = probs[key]
    taus = np.asarray(cr["params"]["taus_s"], float)
    # the branches driven as the found creep's: the joint model is that creep beside a delay, not a second creep
    # in its place (:func:`_branch_drive`)
    drive = _branch_drive(cr)
    d, Kd, D, Df = _joint(cr, c, prob, base, t, _base_lower(base, c["channel"]), _fold_rows(prob), drive)
    lower = [0.0] * (taus.size + 1)
    g = _columns(prob, column_stack([D, Kd]), lower)
    if not g["ok"][0]:
        return None
    fold_g = [_columns(prob, column_stack([Dk, Kd]), lower) for Dk in Df]
    if any(gk["ok"].tolist() != g["ok"].tolist() for gk in fold_g):
        return None
    eff = copy.deepcopy(c["eff"])
    eff.n_params = 1
    params = {"delay_samples": d, "delay_s": d * _dt(t), "refit": False}
    ym = base.channels[c["channel"]].yhat if drive is None else drive
    return {**c, "eff": eff, "params": params, "g": g, "n_params": 1, "researched": True,
            "fold_g": fold_g, "replaces": tag,
            "refit": {"taus_s": taus.tolist(), "driver": "model" if drive is None else "v_h"},
            "undelayed": {"drive": ym, "taus_s": taus, "dt_s": _dt(t)}}


def refitted_joint_stage(stages):
    """The found stage a joint creep + delay candidate replaced, as the joint fit left it.

    The last stage is the joint candidate (:func:`creep_beside_delay`: the branches then the delay's
    column; :func:`delay_beside_creep`: the delay's column then the branches), its gains
    (``_gains``) in that order. The found delay's stage then carries the refitted
    ``delay_samples`` / ``delay_s`` and its column's gain ``scale``; the found creep's stage the
    branches' gains of the joint fit: what the calibrated model holds. Its ``refitted`` says so
    (with the delay it was named with alone).
    """
    last = stages[-1]
    refit, gains = last["_cand"].get("refit"), last.get("_gains")
    tag = last["_cand"].get("replaces")
    if refit is None or gains is None or tag is None or tag[0] not in ("delay", "creep") \
            or last["effect"] not in ("delay", "creep"):
        return
    gains = np.asarray(gains, float)
    for st in stages[:-1]:
        if (st["effect"], st["channel"]) != tag:
            continue
        if tag[0] == "delay":
            alone = st["parameters"].get("delay_s")
            st["parameters"] = {**st["parameters"], "delay_samples": refit["delay_samples"],
                                "delay_s": refit["delay_s"], "scale": float(gains[-1])}
            st["refitted"] = (f"refitted beside the creep: delay {refit['delay_s']:.6g} s "
                              f"(alone {alone:.6g} s, its refit taking part of the creep)")
        else:
            # the joint fit's branches are driven as the found creep's were (delay_beside_creep's columns,
            # _branch_drive): V_h, its "driver" kept; the base model, its "driver" dropped, so the plant file
            # rebuilds them on the model they were fitted on (review of s17_creep: a V_h-driven rebuild of
            # base-model gains put a 1 kHz 28x creep + delay file at 3.53e-8 m against 8.71e-9 m)
            keep = refit.get("driver") == "v_h"
            st["parameters"] = {**{k: v for k, v in st["parameters"].items() if keep or k != "driver"},
                                "gains": np.maximum(gains[1:], 0.0).tolist(), "taus_s": list(refit["taus_s"])}
            st["refitted"] = ("refitted beside the delay: the branches' gains of the joint fit (alone, "
                              "its fast branches took part of the delay)")
