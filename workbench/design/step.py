"""Step-response metrics: the one home of overshoot, settling and rise time.

Used by the loop-shaping search (the nominal step), ``verify`` (nonlinear runs beside the
linear prediction), the sweep and ``selfsense``, so every command reports a step the same way.
"""

import numpy as np

__all__ = ["step_metrics", "rise_time"]


def step_metrics(t_s, y, y0, y1, band=0.02):
    """(overshoot %, settling time s) of a step response from ``y0`` to ``y1``.

    Parameters
    ----------
    t_s : ndarray of float
        Time, s, from the step (``t_s[0]`` is the step's instant).
    y : ndarray of float
        The response, in the units of ``y0``/``y1``.
    y0, y1 : float
        Level before the step and the reference after it.
    band : float, default 0.02
        Settling band as a fraction of the step.

    Returns
    -------
    overshoot_percent : float
        Peak beyond ``y1``, % of the step (0 if it never passes ``y1``).
    settling_s : float
        First time after which the response stays within ``band`` of ``y1``, s from ``t_s[0]``;
        NaN if it is still outside at the last sample.
    """
    t_s = np.asarray(t_s, dtype=float)
    r = (np.asarray(y, dtype=float) - y0) / (y1 - y0)
    overshoot = max(0.0, float(np.max(r) - 1.0)) * 100
    outside = np.flatnonzero(np.abs(r - 1.0) > band)
    if not outside.size:
        return overshoot, 0.0
    if outside[-1] + 1 >= t_s.size:
        return overshoot, float("nan")
    return overshoot, float(t_s[outside[-1] + 1] - t_s[0])


def rise_time(t_s, y, y0, y1):
    """10-90 % rise time of a step from ``y0`` to ``y1``, s; NaN if the response never reaches 90 %."""
    r = (np.asarray(y, dtype=float) - y0) / (y1 - y0)
    k10, k90 = np.flatnonzero(r >= 0.1), np.flatnonzero(r >= 0.9)
    if not k90.size:
        return float("nan")
    return float(t_s[k90[0]] - t_s[k10[0]])
