"""The creep branches' driver: the voltage across the hysteretic capacitance, creep included.

In the simulator's physics (:mod:`workbench.plant.creep`, seed 000 Fig. 3) the Kelvin-Voigt branches sit
across C_h and relax toward ``C_j V_h``. With the terminal voltage ``V_t`` known and ``x = k q`` (eq. 10),

    V_h = V_t - q / C_pp = V_t - a x,        a = 1 / (k_q2x C_pp) = k_p / T_em   (eq. 12: k_q2x C_pp = T_em / k_p),

and the terminal charge splits into the hysteretic one and the branches', ``q = q_h + Q_c``; ``q_h`` is
the creep-free map ``G^-1`` (the base model's Prandtl-Ishlinskii operator of ``V_t``) of the drive less the
branches' voltage, so in the channel's units (``X = k Q_c``)

    x = PI_w[V_t - a X] + X,        X = sum_j g_j lowpass_tau_j(V_h),   g_j = k C_j >= 0.

Two things the spectrum of the base model (``sum_j c_j (lowpass_j(x_model) - x_model)``) misses: the branches
are driven by ``V_h``, which the creep itself pulls back as it charges (the loop shortens the relaxation, the
more the larger the creep), and that pull-back is a reversal of C_h's input, which the plays follow only past
their thresholds (the hysteresis bends the creep). Measured on creep-only simulator records at 1 kHz (10 s,
seed 1234, sizes 0.3-20): the base-model spectrum leaves 1.2-76x the noise floor (error ratio 0.10-0.44 at
every size); the same spectrum on a linear C_h leaves 1.0-1.6x (7.9x at size 10, steps): the misfit is the
hysteresis' (``/work/notes/s17`` session log; README "Session 17, creep's form at 1 kHz").

:func:`creep_drive` solves the loop for ``V_h`` on the development rows (a fixed point: the model's own
prediction, never the recorded output, sets ``V_h``; the plays of ``V_t - a X`` carry the pull-back through
C_h's reversal). The tracing's creep columns are then ``lowpass_j(V_h) - V_h``
(:class:`~workbench.calibrate.effects.CreepSpectrum` with ``loop``), gains >= 0, linear, so they join the base's
Gram matrices as before. The base model's response to the pull-back, ``PI_w[V_t - a X] - PI_w[V_t]``, as a
column of its own (a "backswing" beside the branches) took the 1 kHz oracle records closer still (1.0-1.2x
against 1.8-2.1x the floor at sizes 0.3-3, steps) but made the per-fold refits unstable: on 59 #20 (1 kHz
sine, creep 22x + delay) its gain, ~0 on the development rows, left 1.6x the base on two validation folds
(the gauge's 5.6e6x): it is not a column.
"""

from dataclasses import dataclass, field

import numpy as np

from .stacking import column_stack


__all__ = ["CreepLoop", "creep_drive", "drive_taus", "DRIVE_ITERATIONS"]

#: Fixed-point passes of :func:`creep_drive` at most: the loop's correction shrinks by the branches' share of
#: the capacitance per pass, so the first passes carry it; measured on the 1 kHz records (sizes 0.3-20) the
#: development SSE settles within 6-8 passes (damped by half from the third on: the loop gain of a creep
#: far larger than C_h exceeds one, and the undamped iteration oscillated at size 20). A pass that leaves a
#: higher SSE than the best is an overshoot: the next starts again from the best pass with half the step
#: (session 18; it used to stop there, keeping the first pass's drive, the creep-free ``V_t - a PI[V_t]``).
#: The passes stop earlier when one improves the SSE by less than :data:`DRIVE_RTOL` of it (each costs the
#: plays over the whole record: 0.3-0.6 s at 355,000 rows).
DRIVE_ITERATIONS = 8
DRIVE_RTOL = 0.01


@dataclass(frozen=True, eq=False)
class CreepLoop:
    """What the branches' loop needs of one channel (the base fit's; :func:`creep_drive`).

    Parameters
    ----------
    v_t_v : ndarray of float
        The terminal voltage (the base's drive), V.
    v_per_unit : float
        ``a`` in the channel's units: V per metre for the displacement (``k_p / T_em``), V per volt of
        the gauge (``a`` over the gauge's gain, V/m).
    thresholds_v, initial_states_v : ndarray of float
        The channel model's plays (V).
    y : ndarray of float, optional
        The channel's recorded values (its units): what the drive is solved against when this channel is
        the record's source (``shared["source"]``).
    valid : ndarray of bool, optional
        The channel's valid rows.
    shared : dict
        One dict for every channel of a record: ``V_h`` is the stack's, whichever channel reads it, so one
        solve serves every channel and later stage (``shared["v_h"]``), made on ``shared["source"]`` (the
        gauge's loop when the record has one, :func:`~workbench.calibrate.tracing.creep_loops`), else on the
        calling channel's.
    """

    v_t_v: np.ndarray
    v_per_unit: float
    thresholds_v: np.ndarray
    initial_states_v: np.ndarray
    y: np.ndarray = None
    valid: np.ndarray = None
    shared: dict = field(default_factory=dict)


def drive_taus(taus_s):
    """The branches the drive is solved with: the record's grid and the geometric midpoints between its
    neighbours (a quarter decade on the half-decade grid), s.

    ``V_h`` carries the fitted creep's pull-back, so a misfit of the branches' sum goes into the drive of every
    later column. On the record's own grid the sum of the two neighbours of a branch between grid points
    leaves a lag error in it: on a 10 kHz sine record with a 13x creep (67 #46, the plant's 0.1 s branch
    between 0.063 and 0.2 s) the drive solved on the record's grid settles at a development SSE of 0.831 and
    the spectrum on it leaves 1.04e-8 m (~3.5x the benchmark's floor), which a 0.58 ms sensor *lead* takes up
    as a second effect; solved on this grid, 0.825, and the same half-decade columns leave 8.0e-9 m (~2.7x),
    no delay named (session 18). The midpoints are the grid's own (no typed time constant); the columns the
    tracing fits stay the record's grid.

    Parameters
    ----------
    taus_s : array_like of float
        The record's branch time constants, s, increasing.

    Returns
    -------
    ndarray of float
        ``taus_s`` with the midpoints ``sqrt(tau_j tau_{j+1})`` interleaved, s.
    """
    taus = np.asarray(taus_s, float)
    if taus.size < 2:
        return taus
    return np.sort(np.r_[taus, np.sqrt(taus[:-1] * taus[1:])])


def creep_drive(loop, y, taus_s, dt, rows, n_iter=DRIVE_ITERATIONS, rtol=DRIVE_RTOL):
    """``v_h``: the branches' driver, the voltage across C_h with the creep's pull-back (V).

    Fits ``y = PI_w[V_t - a X] + c + X`` (plays >= 0, ``X = sum_j g_j lowpass_j(V_h)``, ``g_j >= 0``, the
    branches of :func:`drive_taus`) on ``rows`` by bounded least squares, ``V_h = V_t - a (PI_w[V_t - a X] + X)``
    from the previous pass's fit (half the new one mixed in from the third pass; after a pass whose SSE is
    no lower than the best's or not finite, the best pass's fit and gains with half the step it took toward the fit
    and gains it gave), and
    keeps the pass of the lowest SSE on ``rows``; stops when a pass improves it by less than ``rtol`` of it.
    Solved once per record: a later call (another channel, a later stage) returns ``loop.shared["v_h"]``.

    Parameters
    ----------
    loop : CreepLoop
        The channel's drive, scale and plays.
    y : ndarray of float
        The channel's recorded values (its units).
    taus_s : array_like of float
        The branches' time constants, s.
    dt : float
        Sample period, s.
    rows : ndarray of bool
        The rows fitted (development search rows).

    Returns
    -------
    v_h : ndarray of float
        The voltage across C_h, V, over the whole record.
    """
    from .base_fit import _gram_solve
    if "v_h" in loop.shared:
        return loop.shared["v_h"]
    src = loop.shared.get("source", loop)
    if src is not loop and src.y is not None:
        # the stack's V_h from the channel that reads the stack itself (the gauge): a displacement sensor's
        # own delay or drift is no part of it
        y = src.y
        rows = np.asarray(rows, bool) & (np.ones(len(y), bool) if src.valid is None else np.asarray(src.valid, bool))
        loop = src
    from ..plant.hysteresis import PrandtlIshlinskii
    from .effects import lowpass
    from .kernels import plays_rows
    vt = np.asarray(loop.v_t_v, float)
    a = float(loop.v_per_unit)
    th, z0 = np.asarray(loop.thresholds_v, float), np.asarray(loop.initial_states_v, float)
    taus = drive_taus(taus_s)
    idx = np.flatnonzero(rows)
    y_r = np.asarray(y, float)[idx]
    n_p = th.size
    lower = np.r_[np.zeros(n_p), -np.inf, np.zeros(taus.size)]

    def pi(u, w):                 # the weighted plays over the whole record (one compiled pass)
        return PrandtlIshlinskii(th, w, z0, check_invertible=False)(u)

    def solve(Z, low):
        nrm = np.sqrt(np.mean(Z * Z, axis=0))
        nrm[nrm == 0] = 1.0
        Zs = Z / nrm
        return _gram_solve(Zs.T @ Zs, Zs.T @ y_r, low * nrm) / nrm

    # the plays alone first: the base's model on these rows
    P_r = plays_rows(vt, th, z0, idx)
    w = solve(column_stack([P_r, np.ones(idx.size)]), lower[:n_p + 1])[:n_p]
    P_0 = P_r
    fit = pi(vt, w)               # the previous pass's plays and creep (channel units, no offset)
    g = np.zeros(taus.size)
    best = None                   # (sse, v_h, the fit and gains it came from, the fit and gains it gave)
    step = 1.0                    # the next move's step from the best pass toward the fit it gave
    taken = step                  # the step the last move took
    for k in range(1, int(n_iter)):
        v_h = vt - a * fit
        L_r = np.empty((idx.size, taus.size))
        x_c = np.zeros(vt.size)
        for j, tau in enumerate(taus):
            col = lowpass(v_h, tau, dt)
            L_r[:, j] = col[idx]
            if g[j] > 0:
                x_c += g[j] * col
        u = vt - a * x_c
        P_r = plays_rows(u, th, z0, idx) if g.any() else P_0
        Z = column_stack([P_r, np.ones(idx.size), L_r])
        beta = solve(Z, lower)
        g_new = beta[n_p + 1:]
        sse = float(np.sum((y_r - Z @ beta) ** 2))
        if k == int(n_iter) - 1:
            if best is None or sse < best[0]:
                best = (sse, v_h)
            break
        if best is not None and not sse < best[0]:
            # the pass overshot (the loop gain of a creep far larger than C_h exceeds one; a non-finite
            # SSE counts as one): back to the best pass, half the step it took toward what it gave, in
            # its fit and in its gains alike, so a vanishing step returns the best pass itself (the
            # review of s18_creepdelay: blending the fit alone with the new gains in full tends to
            # another SSE as the step shrinks)
            step = taken = 0.5 * taken
            _, _, f_b, g_b, new_b, gn_b = best
            fit = f_b + step * (new_b - f_b)
            g = g_b + step * (gn_b - g_b)
            continue
        if best is not None and sse > (1.0 - rtol) * best[0]:
            best = (sse, v_h)     # converged: the pass improves on the best by less than rtol
            break
        # this pass's creep over the whole record, on this pass's drive
        x_new = sum(gj * lowpass(v_h, tau, dt) for gj, tau in zip(g_new, taus) if gj > 0)
        new = pi(u, beta[:n_p]) + x_new
        best = (sse, v_h, fit, g, new, g_new)
        fit = fit + step * (new - fit)
        g = g_new                 # (the pass's gains in full, as before the back-off existed)
        taken, step = step, min(step, 0.5)
    loop.shared["v_h"] = vt - a * fit if best is None else best[1]
    return loop.shared["v_h"]
