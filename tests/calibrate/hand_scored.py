"""The first stage of the tracing scored with a hand-built delay and mode as the only candidates.

Shared by tests that score constructed records through :func:`workbench.calibrate.tracing._score_stage` itself
(test_delay_or_mode, test_periodic_candidates): the base is the line ``y`` (the stack's model) and an offset, the
candidates are built as ``trace_effect``'s are (each effect's search on the residual ``x - y``), the null reference is
three phase-randomized copies of the development residual.
"""

import numpy as np

from workbench.calibrate import tracing as T
from workbench.calibrate.creep_beside_delay import _columns
from workbench.calibrate.effects import Delay, Resonance
from workbench.calibrate.splits import make_split

KEY = ("displacement", "model")


def score_delay_and_mode(t, v, y, x, noise_floor, drive=None, driver=None, lazy=False):
    """``_score_stage``'s result for the displacement ``x`` (m) of a record driven by ``v`` (V) at times ``t`` (s).

    ``drive``: the record's :class:`~workbench.calibrate.tracing.PeriodicDrive` (None: the periodic rule is not
    asked); ``driver``: set on the candidates (None: left out, as tests building them by hand do); ``lazy``: their
    columns kept without Gram matrices, as a later stage's creep beside a delay keeps them
    (:func:`~workbench.calibrate.creep_beside_delay._columns`).
    """
    sp = make_split(t, v, "blocks")
    prob = T._Problem(sp, np.ones(t.size, bool), np.column_stack([y, np.ones(t.size)]), [-np.inf, -np.inf],
                      x - y, sp.train)
    cands = []
    for eff in (Delay(max_delay=30), Resonance()):
        p = eff.fit(t, y, x - y, prob.search, y_model=y)
        C, lo = eff.columns(t, y, p, y_model=y) if hasattr(eff, "columns") else (eff.term(t, y, p, y_model=y), [0.0])
        g = _columns(prob, np.atleast_2d(np.asarray(C, float).T).T, lo) if lazy else prob.grams(C, lo)
        c = {"name": eff.name, "channel": "displacement", "key": KEY, "g": g, "n_params": eff.n_params, "params": p,
             "yhat": y}                                                    # (the model, as trace_effect's)
        if driver is not None:
            c["driver"] = driver
        cands.append(c)
    rng = np.random.default_rng(1)
    e_dev = np.where(prob.rows_dev, prob.r, 0.0)
    nulls = {KEY: [prob.grams(T._phase_randomized(e_dev, rng), [-np.inf]) for _ in range(3)]}
    infos = {"displacement": {"noise_floor": noise_floor}, "duration_s": float(t[-1] - t[0]), "t": t}
    if drive is not None:
        infos["drive"] = drive
    return T._score_stage(cands, {KEY: prob}, nulls, {KEY: []}, sp, 0.02, 1.0, infos, [], T.MIN_SHARE)
