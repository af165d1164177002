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
creep's part left out) and the branches delayed by ``d`` (gains ``>= 0``), which *replace* the
found delay's column (``replaces``). The stage's fold test compares it with the delay alone by
the bars every candidate clears (noise floor, random term, ``min_share``, the folds it must win)
and the stage's rival (a second delay on what the first leaves): creep is named where the joint
model explains what the delay alone cannot. Named, the delay's stage carries the refitted delay
(:func:`refitted_delay_stage`). Every number comes from the record: the branches are the
record's creep grid, the delay's bounds the found delay's.
"""

import numpy as np

from .effects import CreepSpectrum, Delay, _dt

__all__ = ["DelayedCreep", "creep_beside_delay", "refitted_delay_stage"]


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


def _found(extra, key, tag):
    return [x for x in extra.get(key, ()) if getattr(x, "tag", None) == tag]


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
        channel's problem.
    """
    key = c["key"]
    ch = c["channel"]
    tag = ("delay", ch)
    if key[1] != "model" or not _found(extra, key, tag):
        return None
    dl = next((d for d in cands if (d["name"], d["channel"]) == tag and d["key"] == key), None)
    if dl is None or getattr(dl["eff"], "basis", None) is None or not dl["params"].get("refit"):
        return None
    prob = probs[key]
    m = base.channels[ch]
    y = np.asarray(m.y, float)
    ym = np.asarray(m.yhat, float)
    taus = np.asarray(c["params"]["taus_s"], float)
    dt = _dt(t)
    K = CreepSpectrum._columns(ym, taus, dt)           # the stack's branches, driven by its model
    n_b = dl["eff"].basis.shape[1]
    search = Delay(max_delay=dl["eff"].max_delay, basis=np.column_stack([dl["eff"].basis, K]),
                   max_lead=dl["eff"].max_lead)
    mask = prob.search                                  # (development rows, valid)
    d, _ = search._fit_refit(t, y, ym, mask)
    # the joint least squares at d on the search rows: drive columns, branches and prediction, delayed
    rows = np.flatnonzero(mask)
    Z = np.column_stack([dl["eff"].basis, K, ym])
    Zr = Delay._rows_shifted(np.ascontiguousarray(Z), rows, d)
    coef = np.linalg.lstsq(Zr, y[rows], rcond=1e-10)[0]
    # the delay's column: the refitted drive model (without the branches) shifted; its change of
    # weights from the base is left to the base's own columns, as the delay's own refit does
    drive = dl["eff"].basis @ coef[:n_b] + ym * coef[-1]
    all_rows = np.arange(t.size, dtype=float)
    D = Delay._rows_shifted(drive[:, None], all_rows, d)[:, 0] - ym
    Kd = Delay._rows_shifted(np.ascontiguousarray(K), all_rows, d)
    C = np.column_stack([Kd, D])
    lower = [0.0] * taus.size + [0.0]
    g = prob.grams(C, lower)
    if not g["ok"][-1]:
        return None
    # the branches the joint fit keeps, with the found effects other than the delay, on the dev rows
    rest = [x for x in extra[key] if getattr(x, "tag", None) != tag]
    from .tracing import _stacked
    gs = _stacked(prob, rest, {"g": g})
    w = prob.solve(gs, prob.split.dev_blocks)
    k_c = int(np.count_nonzero(g["ok"][:taus.size]))
    own = w[w.size - g["C"].shape[1]:][:k_c]
    n_pos = int(np.count_nonzero(own > 0))
    if n_pos == 0:
        return None
    eff = DelayedCreep(taus_s=taus)
    eff.n_params = n_pos + 1
    params = {"gains": np.zeros(taus.size).tolist(), "taus_s": taus.tolist()}
    return {**c, "eff": eff, "params": params, "g": g, "n_params": n_pos + 1, "researched": True,
            "fold_g": None, "replaces": tag, "refit": {"delay_samples": float(d), "delay_s": float(d * dt)}}


def refitted_delay_stage(stages):
    """The found delay's stage after creep is named beside it (:func:`creep_beside_delay`).

    The last stage is the creep; its candidate's columns are the branches and then the delay's
    column at the refitted delay, its gains (``_gains``) in that order. The delay's stage then
    carries the refitted ``delay_samples`` / ``delay_s`` and its column's gain ``scale``, what the
    calibrated model holds, and says so in ``refitted`` (the delay it was named with alone).
    """
    cr = stages[-1]
    refit, gains = cr["_cand"].get("refit"), cr.get("_gains")
    tag = cr["_cand"].get("replaces")
    if refit is None or gains is None or tag is None or tag[0] != "delay":
        return
    for st in stages[:-1]:
        if (st["effect"], st["channel"]) == tag:
            alone = st["parameters"].get("delay_s")
            st["parameters"] = {**st["parameters"], "delay_samples": refit["delay_samples"],
                                "delay_s": refit["delay_s"], "scale": float(np.asarray(gains)[-1])}
            st["refitted"] = (f"refitted beside the creep: delay {refit['delay_s']:.6g} s "
                              f"(alone {alone:.6g} s, its refit taking part of the creep)")
