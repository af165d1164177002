"""The refitted core: the fitted model's base, a PI of the terminal voltage, written as the plant's C_h.

Issue 13 item 6 asks that the updated plant file, simulated on the record, leave the fitted model's
``error_after``. Every effect is fitted jointly with the base REFITTED on the record (play weights of a
Prandtl-Ishlinskii (PI) operator of the terminal voltage ``V_t``), which takes part of each effect; a
file that keeps the declared C_h is not the fitted model. This module turns the fitted model's core into
the plant file's C_h, so the file is the fitted model.

**Physics** (``workbench.plant.pzt``, R out, no creep, no mode): ``V_t = V_h + q / C_pp`` with
``q = C_h(V_h)`` (C_h's PI: ``pzt.hysteresis``) and ``x = k_q2x q`` (eq. 10, ``pzt.k_q2x_m_per_c`` from the
declared ``T_em``, ``k_p``, ``C_p``). The base gives ``q = Pi(V_t)`` (the charge channel; the displacement's
``x = Pi_x(V_t)`` gives ``Pi = Pi_x / k_q2x``; the gauge's through the base's gauge line, ``x = (g - a) / b``).
A PI with non-negative weights and a positive reversal slope ``w_0`` is inverted in closed form (Kuhnen
2003, :meth:`~workbench.plant.hysteresis.PrandtlIshlinskii.inverse`): ``V_t = Pi^-1(q)``, so
``V_h = Pi^-1(q) - q / C_pp`` (a PI of ``q``: ``plus_linear(-1/C_pp)``) and ``C_h = (V_h(q))^-1``. Its
partial weight sums are ``1 / (1/W_i - 1/C_pp)``, ``W_i = w_0 + ... + w_i`` the loading slopes of ``Pi``:
C_h exists (non-negative weights, positive partial sums) iff every ``W_i < C_pp``; otherwise the record's
core cannot be a C_h in series with the declared C_pp, and the declared core is kept (said). The
thresholds come out in ``V_h`` volts. The written C_h starts at rest (zero play states) whatever the
record's start: the base fit's start states are a monotonic approach from 0 V, which the simulator's first
sample (a step from rest to the record's first ``V_t``) reaches again.

**Beyond the record.** The thresholds reach the training input's span; beyond the record's ``V_t`` range
the written C_h continues as any PI does: every play moving, at its last loading slope. That is an
extrapolation (the record says nothing there), stated in the file.

**Creep.** The creep spectrum's columns are ``c_j (lowpass_j(u0) - u0)`` with ``u0`` the BASE-ALONE
prediction and the joint fit's plays ``Pi_j``: the fitted model's instant response (every lowpass held) is
``Pi_j - (sum c) Pi_b``, its settled one ``Pi_j``. A branch slower than the record (``tau > T``) is nearly
``-c u0`` plus a ramp within the record: its ``-c u0`` (collinear with the plays: ``Pi_j`` and its ``c`` trade
freely) is part of the core, its rate the creep's (``plant_update.SLOW_BRANCHES``). The file's core is
``Pi_j - (sum c) Pi_b`` (less only a share of the branches within the record when branches across C_h
cannot carry them all: ``plant_update.core_for``), refitted with weights >= 0
(:func:`instant_weights`), and the branches across it carry the rest (``plant_update.creep_branches``).
"""

import numpy as np

from ..plant.hysteresis import PrandtlIshlinskii
from .stacking import column_stack

__all__ = ["hysteresis_from_terminal_pi", "instant_weights", "refitted_core", "direct_core_and_branches", "CAP_OF_C_PP",
           "CAPPED_GAP"]

#: The instant core's reversal slope (the threshold-0 play's weight) is at least this fraction of its
#: weights' sum (:func:`instant_weights`); the base fit can leave it 0, and a PI without one has no C_h.
REVERSAL_FLOOR = 0.01

#: A fitted loading slope at or above C_pp has no C_h; it is capped at this fraction of C_pp
#: (:func:`refitted_core`; the file says by how much).
CAP_OF_C_PP = 0.99

#: A cap (:data:`CAP_OF_C_PP`) taking more than this share of the instant core's weights is a gap
#: (``plant_update.plant_file_gaps``, the round trip's warning): the record's loading slope is beyond what
#: any C_h in series with the declared C_pp gives, so the declared C_pp or k_q2x do not fit the record (a
#: record of a stack with twice the declared stroke capped 29 % and left 292x error_after, said nowhere).
#: 1 %: the top plays' weights, the least determined, move by rounding-sized amounts below it.
CAPPED_GAP = 0.01


def hysteresis_from_terminal_pi(terminal_pi, c_pp_f):
    """C_h whose series with ``C_pp`` maps the terminal voltage to the charge as ``terminal_pi`` does.

    Parameters
    ----------
    terminal_pi : PrandtlIshlinskii
        ``q = Pi(V_t)``: charge (C) as a PI of the terminal voltage (V), weights >= 0 (F), first
        threshold 0 with a positive weight, initial states (V) reachable by some input history.
    c_pp_f : float
        ``C_pp = C_p + T_em^2 / k_p``, F.

    Returns
    -------
    PrandtlIshlinskii
        C_h: charge (C) as a PI of ``V_h`` (V), non-negative weights (F).

    Raises
    ------
    ValueError
        A negative weight, no positive reversal slope, or a loading slope of ``Pi`` at or above ``C_pp``
        (no C_h in series with that ``C_pp`` gives it), with the figures.
    """
    r, w = terminal_pi.thresholds, terminal_pi.weights
    if r[0] != 0.0 or not w[0] > 0:
        raise ValueError(f"the terminal PI's reversal slope (the threshold-0 play's weight) is {w[0]:.4g} F, "
                         f"not positive: no finite C_h gives it")
    if np.any(w < 0):
        raise ValueError(f"the terminal PI has negative weights ({w.min():.4g} F)")
    W = np.cumsum(w)
    if not W[-1] < c_pp_f:
        i = int(np.argmax(W >= c_pp_f))
        raise ValueError(f"the record's loading slope {W[i]:.4g} F (beyond {r[i]:.4g} V) is not below C_pp "
                         f"{c_pp_f:.4g} F: no C_h in series with the declared C_pp gives it")
    pi = PrandtlIshlinskii(r, w, terminal_pi.initial_states)
    v_h_of_q = pi.inverse().plus_linear(-1.0 / c_pp_f)
    ch = v_h_of_q.inverse()
    # the weights are w'_i = W'_i - W'_(i-1) with W'_i = 1 / (1/W_i - 1/C_pp) increasing: >= 0 but for rounding
    wc = np.where(np.abs(ch.weights) <= 1e-12 * W[-1], np.abs(ch.weights), ch.weights)
    return PrandtlIshlinskii(ch.thresholds, wc, ch.initial_states)


def instant_weights(basis, rows, joint_w, base_w, creep_share):
    """The fitted model's instant response as a PI with non-negative weights and a reversal slope.

    The instant response ``P (joint_w - creep_share base_w)`` (``P`` the plays) is refitted by bounded least
    squares with weights >= 0 and a free offset over ``rows`` (the difference can have negative weights: the
    joint fit's plays are not the base-alone's), the threshold-0 play's weight at least
    :data:`REVERSAL_FLOOR` of the sum (a PI without a reversal slope has no inverse: no C_h gives it;
    the base fit leaves it at 0 on some records).

    Parameters
    ----------
    basis : ndarray
        The base's columns, plays then a column of ones (``BaseFit.basis``).
    rows : ndarray of bool
        The development rows.
    joint_w, base_w : ndarray
        Play weights of the joint fit and of the base alone (channel units per V).
    creep_share : float
        ``sum c`` of the creep branches within the record (0 without creep).

    Returns
    -------
    w : ndarray
        Play weights >= 0.
    misfit : float
        RMS of the refit's residual over the span of the instant response (0: exact).
    """
    from .base_fit import _gram_solve
    P = np.asarray(basis, float)
    k = P.shape[1] - 1
    target = P[:, :k] @ (np.asarray(joint_w, float) - float(creep_share) * np.asarray(base_w, float))
    direct = np.asarray(joint_w, float) - float(creep_share) * np.asarray(base_w, float)
    floor = REVERSAL_FLOOR * float(np.sum(np.maximum(direct, 0.0)))
    if np.all(direct >= 0) and direct[0] >= floor:
        return direct, 0.0
    A, b = P[rows], target[rows]
    col = np.sqrt(np.mean(A * A, axis=0))
    col[col == 0] = 1.0
    As = A / col
    lb = np.r_[floor * col[0], np.zeros(k - 1), -np.inf]
    x = _gram_solve(As.T @ As, As.T @ b, lb) / col      # the base fit's own bounded solve
    w = np.maximum(x[:k], 0.0)
    res = A @ np.r_[w, x[k]] - b
    span = float(np.ptp(b))
    return w, float(np.sqrt(np.mean(res * res))) / span if span > 0 else float("inf")


def creep_within_record(params, duration_s):
    """``sum c`` of the creep branches with ``tau <= duration_s`` (slower ones: a rate, not a share)."""
    g = np.maximum(np.asarray(params["gains"], float), 0.0)
    return float(np.sum(g[np.asarray(params["taus_s"], float) <= duration_s]))


def _charge_per_unit(channel, plant):
    """Channel units per coulomb of the terminal charge, or (None, reason)."""
    k = float(plant.pzt.k_q2x_m_per_c)
    if channel == "charge":
        return 1.0, None
    if channel == "displacement":
        return k, None
    if channel == "gauge":
        # measured (seeds 1306 draws, 2026-11-26): through the base's gauge line the replay left 8.7x and 27x
        # error_after where the declared core left 1.0x: the line is fitted against a displacement that drifts
        # and the bridge's bow is read again by the simulated gauge
        return None, ("the gauge reads x through its bridge (eq. 27) and trim, not a line: the core is not "
                      "refitted from the gauge")
    return None, f"the {channel} channel is not the stack's charge or motion"


def refitted_core(plant, base, core_fit, creep_scale=1.0):
    """C_h from the fitted model of the first effect's channel (see the module notes).

    Parameters
    ----------
    plant : workbench.plant.files.Plant
        The declared plant (its ``C_pp`` and ``k_q2x`` stay).
    base : workbench.calibrate.base_fit.BaseFit
        The base fit (the channel's base-alone weights, the drive, ``input_kind``, ``train_range_v``).
    core_fit : dict or None
        The tracing's ``core_fit``: ``channel``, joint ``weights``, ``thresholds_v``, ``initial_states_v``
        and the channel's ``stages`` with their jointly refitted parameters.
    creep_scale : float
        The share of a creep stage's branches the file carries (1: all; less when branches across C_h cannot
        carry them all, ``plant_update.core_for``): the core is ``Pi_j - creep_scale (sum c) Pi_b``.

    Returns
    -------
    dict
        ``hysteresis`` (PrandtlIshlinskii or None), ``reason`` (why None), ``channel``, ``range_v`` (the
        training rows' ``V_t`` range), ``instant`` (the channel's instant weights, its units per V),
        ``creep_scale``, ``capped`` (the share of the instant weights taken by the cap at
        :data:`CAP_OF_C_PP` C_pp, 0 without) and ``how`` (the file's comment).
    """
    out = {"hysteresis": None, "reason": None, "channel": None, "range_v": None, "instant": None,
           "how": None, "creep_scale": float(creep_scale), "capped": 0.0}
    if not core_fit:
        out["reason"] = "the fitted model's joint weights are not at hand"
        return out
    ch = core_fit["channel"]
    out["channel"] = ch
    if getattr(base, "input_kind", "terminal") != "terminal":
        out["reason"] = "the record's input is an amplifier command (its volts are not the stack's terminal volts)"
        return out
    per_c, why = _charge_per_unit(ch, plant)
    if per_c is None:
        out["reason"] = why
        return out
    m = base.channels[ch]
    creep = [s for s in core_fit.get("stages", ()) if s["effect"] == "creep"]
    dur = float(base.t[-1] - base.t[0])
    within = float(sum(creep_within_record(s["parameters"], dur) for s in creep))
    slow = float(sum(np.sum(np.maximum(np.asarray(s["parameters"]["gains"], float), 0.0)) for s in creep)) - within
    # the share carried applies to every branch: the core keeps (1 - share) of the slow ones' -c u0 as of the
    # others', and plant_update._creep_fractions writes share of their rate
    total = float(creep_scale) * (slow + within)
    slow = float(creep_scale) * slow
    # a V_h-driven creep (:mod:`.creep_across`) settles to c (s V_h), not to c u0: its held part in play weights
    # is the plays' least-squares fit of the drive on the training rows (review of s17_creep: with u0's weights
    # a 1 kHz sine creep + delay record's file stood at 1.49x error_after, with the drive's 1.18x)
    from .base_fit import plays_basis
    held_w = m.weights
    drive = core_fit.get("creep_drive")
    if drive is not None and any(s["parameters"].get("driver") in ("v_h", "refit") for s in creep):
        rows = np.asarray(base.train, bool)     # the basis with its offset column (the plays' means are not 0)
        held_w = np.linalg.lstsq(np.asarray(plays_basis(base, ch), float)[rows], np.asarray(drive, float)[rows],
                                 rcond=None)[0][:-1]
    w, misfit = instant_weights(plays_basis(base, ch), np.asarray(base.train, bool), core_fit["weights"], held_w, total)
    out["instant"] = w
    lo, hi = base.train_range_v if base.train_range_v is not None else (float(np.min(base.v_drive)),
                                                                         float(np.max(base.v_drive)))
    out["range_v"] = (float(lo), float(hi))
    # the top loading slope at or above C_pp (the highest plays move only at the record's peaks: their weights
    # are the least determined) is capped at CAP_OF_C_PP C_pp, taken from the highest plays first
    wq = w / per_c
    cap = CAP_OF_C_PP * float(plant.pzt.c_pp_f)
    capped = 0.0
    if wq.sum() > cap:
        excess = float(wq.sum() - cap)
        capped = excess / float(wq.sum())
        for i in range(wq.size - 1, 0, -1):
            take = min(wq[i], excess)
            wq[i] -= take
            excess -= take
            if excess <= 0:
                break
    w = wq * per_c
    out["instant"] = w
    try:
        pi = PrandtlIshlinskii(np.asarray(core_fit["thresholds_v"], float), w / per_c,
                               np.asarray(core_fit["initial_states_v"], float), check_invertible=False)
        ch_op = hysteresis_from_terminal_pi(pi, plant.pzt.c_pp_f)
    except ValueError as err:
        out["reason"] = str(err)
        return out
    out["capped"] = capped          # (only for a core written: review of 9611620, a declared core said 0.405)
    # the file's C_h starts at rest (zero play states), whatever the record's start: a plant file loaded for
    # design sits uncharged at 0 V. The record's start state is the monotonic approach from 0 V (the base
    # fit's plays), which the simulator's first sample, a step from rest to V_t(0), reaches again
    out["hysteresis"] = PrandtlIshlinskii(ch_op.thresholds, ch_op.weights, np.zeros(ch_op.size))
    unit = {"displacement": "x = k_q2x q, k_q2x declared", "charge": "q itself"}[ch]
    out["how"] = (f"C_h refitted on the record's {ch} channel ({unit}) over V_t {lo:.4g} .. {hi:.4g} V: the fitted "
                  f"model's plays (the base refitted jointly with every effect found there"
                  + (f", less the creep's sum c = {total:.4g} ({slow:.4g} of branches slower than the record) times "
                     f"the base's own: its instant response, refitted with weights >= 0 and a reversal slope of at least "
                     f"{100 * REVERSAL_FLOOR:g} % of the weights' sum to "
                     f"{100 * misfit:.2g} % of its span" if creep or misfit else "")
                  + ")" + (f", its top loading slope capped at {CAP_OF_C_PP:g} C_pp ({100 * capped:.2g} % of the weights "
                           f"taken from the highest plays)" if capped else "")
                  + "; inverted in closed form (Kuhnen) through the declared C_pp; beyond that range it continues "
                  "at its last loading slope (extrapolated, every play moving)")
    return out


#: The branch refit (:func:`refine_branches`) simulates at most this many samples of the record (the drive
#: taken every k-th sample): the core is rate-independent and the branches' fastest time constant is the
#: spectrum's 10 samples. 10,000 (was 20,000): seeds 24-25 creep+delay round trip the same to 1 % on all 16
#: records with a stage (25 #31 1.30x -> 1.31x), half the simulations' cost (measured 2026-11-26).
REFINE_SAMPLES = 10000
#: At most this many evaluations of the branch refit's residual (each a simulation). The Jacobian is
#: taken by forward differences once, at the closed-form start (``2 n`` branches' parameters: that many
#: simulations), and then updated from the evaluations themselves (Broyden's rank-one update: no
#: simulation), then once more from the solution with a fresh one and half the evaluations: a
#: finite-difference Jacobian at every iteration cost ``2 n`` more simulations each, 240 simulations for 3
#: branches where this takes at most ``1.5 REFINE_NFEV + 4 n + 3``.
REFINE_NFEV = 30


#: Hold the refit's summed C_j to the closed form's (the settled ratio the spectrum says): measured on seeds
#: 24-25 creep+delay it costs the record's fit (24 #20 3.66x -> 5.69x error_after), see README.
HOLD_CAPACITANCE = False


def creep_target(base, core_fit, core, params):
    """The fitted model's creep part over the file's core, channel units (m), every sample.

    ``P (w_joint - w_core) + sum c_j (lowpass_j(u0) - u0)``: the fitted model (its plays and the creep's
    columns on the base-alone prediction ``u0``) less the core the file carries.
    """
    from .base_fit import plays_basis
    from .effects import lowpass
    t = np.asarray(base.t, float)
    dt = float(np.mean(np.diff(t)))
    P = np.asarray(plays_basis(base, core["channel"]), float)[:, :-1]
    u0 = np.asarray(base.channels[core["channel"]].yhat, float)
    out = P @ (np.asarray(core_fit["weights"], float) - np.asarray(core["instant"], float))
    from .plant_update import creep_driver
    u = creep_driver(core_fit, params, u0)
    for c, tau in zip(params["gains"], params["taus_s"]):
        if c > 0:
            out = out + c * (lowpass(u, tau, dt) - u)
    return out


def refine_branches(plant, base, target, caps_f, taus_s, rows, max_nfev=None):
    """Kelvin-Voigt branches across the file's C_h fitted to the fitted model's creep part by simulation.

    The plant (its refitted core, R out and no amplifier as the replay drives it:
    :meth:`~workbench.plant.pzt.PZTParams.terminal_driven`; no mode) is simulated on the record's drive (every k-th sample, at
    most :data:`REFINE_SAMPLES`) with and without the branches; their difference is fitted to ``target``
    (:func:`creep_target`) on the development ``rows`` (a constant free: the replay takes out a sensor's
    zero) by least squares over ``log C_j`` and ``log tau_j`` from the closed-form sizes ``caps_f``,
    ``taus_s`` (``plant_update.creep_branches``).

    Returns
    -------
    caps_f, taus_s : ndarray
        The refitted branches (sorted by time constant).
    before, after : float
        RMS misfit on ``rows`` relative to the target's RMS there, from the closed form and refitted.
    """
    import dataclasses

    from scipy.optimize import least_squares

    from ..plant.creep import CreepParams
    from .synthetic import SensorNoise, simulate_record
    t = np.asarray(base.t, float)
    k = max(1, int(np.ceil(t.size / REFINE_SAMPLES)))
    td, vd = t[::k], np.asarray(base.v_drive, float)[::k]
    rd = np.asarray(rows, bool)[::k]
    y = np.asarray(target, float)[::k][rd]
    y = y - y.mean()
    scale = float(np.sqrt(np.mean(y * y))) or 1.0
    pzt = dataclasses.replace(plant.pzt.terminal_driven(), modes=(), creep=None)     # V_t in, as the replay
    quiet = SensorNoise(0.0, 0.0, 0.0)

    def sim(creep):
        p = dataclasses.replace(plant, pzt=dataclasses.replace(pzt, creep=creep))
        return simulate_record(p, td, vd, noise=quiet, gauge=False, gauge_noise=False)["x_true_m"]
    x0 = sim(None)
    n = len(caps_f)

    cache = {}

    def resid(z):
        key = np.asarray(z, float).tobytes()
        if key not in cache:
            caps, taus = np.exp(z[:n]), np.exp(z[n:])
            order = np.argsort(taus)
            d = (sim(CreepParams(taus[order], caps[order])) - x0)[rd]
            cache[key] = (d - d.mean() - y) / scale
        return cache[key]
    caps0, taus0 = np.asarray(caps_f, float), np.asarray(taus_s, float)
    z0 = np.r_[np.log(caps0), np.log(taus0)]
    c_pp = float(plant.pzt.c_pp_f)
    # bounds: C_j up to the closed form's sum with HOLD_CAPACITANCE (the settled/instant ratio the spectrum says, 1 + sum a, is
    # that sum's: more is a settled response the record never showed), tau_j within a decade of the closed
    # form and not beyond the record's length T unless the closed form is (a branch slower than the record is
    # its rate: plant_update.SLOW_BRANCHES); with HOLD_CAPACITANCE (off) the sum is held to the closed form's
    # after the fit, else C_j reach 100 C_pp
    dur = float(t[-1] - t[0])
    c_sum = float(np.sum(caps0))
    lo = np.r_[np.full(n, np.log(1e-6 * c_pp)), np.log(taus0) - np.log(10.0)]
    c_top = c_sum if HOLD_CAPACITANCE else 100.0 * c_pp
    hi = np.r_[np.full(n, np.log(c_top)), np.log(np.minimum(10.0 * taus0, np.maximum(taus0, dur)))]
    lo = np.minimum(lo, hi - 2e-9)
    z0 = np.clip(z0, lo + 1e-9, hi - 1e-9)
    r0 = resid(z0)
    state = {}

    def jac(z):
        """Forward differences at the start (one simulation a parameter), Broyden's update after."""
        z = np.asarray(z, float)
        f = resid(z)
        if "J" not in state:
            h = 1e-3 * np.where(hi - z > 2e-3, 1.0, -1.0)      # inside the bounds
            J = np.empty((f.size, z.size))
            for i in range(z.size):
                zi = z.copy()
                zi[i] += h[i]
                J[:, i] = (resid(zi) - f) / h[i]
        else:
            J, dz = state["J"], z - state["z"]
            dd = float(dz @ dz)
            if dd > 0:
                J = J + np.outer(f - state["f"] - J @ dz, dz) / dd
        state.update(J=J, z=z, f=f)
        return J
    nfev = max_nfev or REFINE_NFEV
    sol = least_squares(resid, z0, jac=jac, bounds=(lo, hi), x_scale=1.0, max_nfev=nfev)
    # once more from there with a fresh Jacobian by differences (Broyden's drifts from the true one)
    state.clear()
    sol = least_squares(resid, np.clip(sol.x, lo + 1e-9, hi - 1e-9), jac=jac, bounds=(lo, hi), x_scale=1.0,
                        max_nfev=max(1, nfev // 2))
    z = np.asarray(sol.x, float).copy()
    over = float(np.sum(np.exp(z[:n]))) / c_sum
    if HOLD_CAPACITANCE and over > 1.0:      # the sum held to the closed form's (each branch scaled alike)
        z[:n] -= np.log(over)
    fun = resid(z)
    before = float(np.sqrt(np.mean(r0 * r0)))
    after = float(np.sqrt(np.mean(fun * fun)))
    caps, taus = (caps0, taus0) if after >= before else (np.exp(z[:n]), np.exp(z[n:]))
    after = min(after, before)
    order = np.argsort(taus)          # the closed form's, scaled by its factors, need not be in order
    return caps[order], taus[order], before, after


#: The direct fit's slowest branch, in record lengths: a branch slower than the record is seen by its rate
#: only (its charge a ramp within the record), so its C_j and tau_j trade; up to 10 T the fit's grid
#: follows a slow branch's curvature within the record (drawn records, 1401: a 16 s branch in a 10 s record
#: left 15 % of the creep with the grid stopped at T).
SLOWEST_BRANCH = 10.0


#: A branch of the direct fit is at most this many C_pp (:func:`direct_core_and_branches`; the synthetic records'
#: largest is 2.5 C_pp of the P-888.51's; the plant file takes at most 1 mF).
BRANCH_CAP_OF_C_PP = 10.0

#: With the series resistor in and the drive the recorded ``V`` (no current column: not ``V - R i``) the direct
#: fit's fastest branch is this many ``R C_pp`` (a decade above the ``R C`` lag ``V_h = V - q / C_pp`` carries,
#: which a branch near it copies: R = 80 ohm, the grid from 10 samples, held-out 0.12 -> 0.40 of the creep's RMS).
FASTEST_BRANCH_OF_RC = 10.0

#: A branch of the direct fit is at most this, F: the plant file's limit on a branch's capacitance
#: (``workbench.plant.files``, ``[creep] capacitances_f``).
BRANCH_CAP_F = 1e-3

#: Ridge of the direct fit's normal equations, relative to its unit-RMS columns (:func:`direct_core_and_branches`):
#: added to the Gram matrix of the unit-RMS columns divided by the rows (unit diagonal). Session 15: it was added
#: to the undivided one (diagonal = the rows, 32,000-355,000), 3e-14 relative, no ridge at all.
DIRECT_RIDGE = 1e-9


def _bounded_gram_solve(G, h, lower):
    """min ``w'G w - 2 h'w`` subject to ``w >= lower``, for a Gram matrix ``G`` of unit-diagonal scale.

    Two solves, the better kept: the base fit's bounded solve (:func:`~workbench.calibrate.base_fit._gram_solve`)
    on the target scaled to unit norm, and Lawson-Hanson NNLS on the Cholesky factor of ``G`` (ridged until it
    factors), shifted by ``lower``; each must be finite and feasible, and neither is kept above the objective at
    ``max(lower, 0)`` (a feasible point, returned when both fail). Why both: the bvls on a near-singular
    square-root system (session 14's 25 #75, a 34-column fit of condition 1e15) came out at 2.5e3 with an
    objective above zero's, and the reversal floor raised on it ran away; a check against the trivial point
    alone keeps a bvls answer that is worse than NNLS's but better than zero (review of s15_rt). NNLS stopping
    at its iteration limit (scipy raises RuntimeError) leaves the other candidates, never a crash.
    """
    from scipy.optimize import nnls

    from .base_fit import _gram_solve
    G, h, lower = np.asarray(G, float), np.asarray(h, float), np.asarray(lower, float)
    s = float(np.linalg.norm(h)) or 1.0

    def obj(x):
        return float(x @ G @ x - 2.0 * h @ x)

    def feasible(x):
        return x is not None and bool(np.all(np.isfinite(x))) \
            and bool(np.all(x >= lower - 1e-9 * (np.abs(lower) + 1e-300)))
    start = np.maximum(lower, 0.0)
    with np.errstate(all="ignore"):
        try:
            x_bvls = _gram_solve(G, h / s, lower / s) * s
        except (ValueError, np.linalg.LinAlgError, RuntimeError):
            x_bvls = None
    x_nnls = None
    eye, d = np.eye(G.shape[0]), float(np.mean(np.diag(G))) or 1.0
    for ridge in (0.0, 1e-12, 1e-9, 1e-6):
        try:
            L = np.linalg.cholesky(G + ridge * d * eye)
        except np.linalg.LinAlgError:
            continue
        # x = lower + z, z >= 0: min |L' z - (L^-1 h - L' lower)|
        with np.errstate(all="ignore"):
            c = np.linalg.solve(L, h / s) - L.T @ (lower / s)
            try:
                z, _ = nnls(L.T, c, maxiter=50 * G.shape[0])
                x_nnls = lower + z * s
            except RuntimeError:  # scipy >= 1.12: the iteration limit raises
                x_nnls = None
        break
    # the better of the two solves (bvls on a tie), the feasible start where neither beats it
    best, best_obj = start, obj(start) + 1e-12 * abs(obj(start))
    for x in (x_nnls, x_bvls):
        if feasible(x):
            with np.errstate(all="ignore"):
                f = obj(x)
            if np.isfinite(f) and f <= best_obj:
                best, best_obj = x, f
    return best


def _lowpass_from_rest(u, tau, dt):
    """First-order lowpass of ``u`` from 0 (a Kelvin-Voigt branch's charge per farad, uncharged at the start),
    exact for ``u`` linear between samples (the replay's drive, ``plant_update.updated_plant_error``):
    ``y_k = a y_(k-1) + b0 u_k + b1 u_(k-1)``, ``a = exp(-dt/tau)``, ``b0 = 1 - tau (1 - a) / dt``,
    ``b1 = tau (1 - a) / dt - a`` (``u_(-1) = 0``: from rest, as the simulator's first step)."""
    from scipy import signal
    a = float(np.exp(-dt / tau))
    g = float(-np.expm1(-dt / tau)) * tau / dt
    return signal.lfilter([1.0 - g, g - a], [1.0, -a], np.asarray(u, float))


def _sensor_view(t, x, delay_s):
    """``x(t - delay)`` by linear interpolation (the plant file's ``[displacement_sensor]`` delay)."""
    return x if not delay_s else np.interp(t - delay_s, t, x)


def direct_core_and_branches(plant, base, rows, delay_s=0.0, sensor_offset=None, thresholds_v=None, model=None,
                             offset_m=None, fastest_branch_s=None):
    """C_h and Kelvin-Voigt branches across it, fitted together to the record's displacement (one linear fit).

    Why (session 14, issue 13 item 6): the core :func:`refitted_core` writes with creep is the fitted model's
    INSTANT response ``Pi_j - (sum c) Pi_b``, the creep spectrum's split of the record into plays and a lowpass
    of the base's output ``u0``. Branches across a C_h relax toward ``C_j V_h``, not toward ``c_j u0``, and
    across that instant core no branches copy the spectrum's creep: on seeds 24-25 the branch refit
    (:func:`refine_branches`) stopped at 22-37 % of the creep's RMS whatever the number of branches and
    their time constants (fitted to the record itself instead of the spectrum's creep: the same), 3.9-6.6x
    ``error_after``; across the declared core (the one that made those simulated records) branches fitted
    to the record left 0.3x. The core must be fitted WITH the branches.

    With the series resistor out the plant is ``V_t = V_h + q / C_pp``, ``q = C_h(V_h) + sum Q_j``,
    ``tau_j dQ_j/dt = C_j V_h - Q_j`` (uncharged at rest), ``x = k_q2x q`` (:mod:`workbench.plant.pzt`,
    :mod:`workbench.plant.creep`). The record gives ``q`` (its displacement with the file's sensor drift
    and the base fit's offset out), hence ``V_h = V_t - q / C_pp``; then
    ``q = sum_i w_i play_i(V_h) + sum_j C_j lowpass_j(V_h)`` is LINEAR in C_h's weights ``w_i`` and the
    branches' ``C_j`` at fixed time constants: one non-negative least-squares fit (an equation-error fit;
    the record's noise enters ``V_h`` divided by ``k_q2x C_pp``), in the sensor's time (``V_t`` delayed as
    the record's motion is). Time constants half a decade apart from 10 samples to :data:`SLOWEST_BRANCH`
    record lengths (a branch slower than the record is identified by its rate: which of the slow ones
    carries it is the fit's); play states from a monotonic approach from 0 V, as the base's.

    Parameters
    ----------
    plant : workbench.plant.files.Plant
        The declared plant (``C_pp``, ``k_q2x``).
    base : workbench.calibrate.base_fit.BaseFit
        The base fit (``t``, ``v_drive``; the displacement's ``y``, ``valid``, ``offset``, ``thresholds_v`` and
        ``yhat``).
    rows : ndarray of bool
        The development rows (the fit's rows; the test rows take no part, not even through ``V_h``'s history).
    delay_s : float
        The file's displacement-sensor delay, s (undone on the record).
    sensor_offset : ndarray, optional
        The file's sensor drift, m, every sample (taken off the record).
    model : ndarray, optional
        A model of the displacement fitted on ``rows`` alone, m, every sample: it stands in for the record off
        ``rows`` in ``V_h``'s history (default the base's ``yhat``; ``plant_update`` passes the fitted model's
        core, creep and delay terms).
    thresholds_v : array_like, optional
        C_h's thresholds in V_h, V (``plant_update`` passes the refitted instant core's: the base's plays
        inverted in closed form); default the base's, scaled to the span of ``V_h``.
    fastest_branch_s : float, optional
        The fastest branch's time constant, s (default 10 samples; ``plant_update`` passes
        :data:`FASTEST_BRANCH_OF_RC` ``R C_pp`` when the resistor is in and the drive is the recorded ``V``, not
        ``V - R i``: ``V_h = V - q / C_pp`` then carries the ``R C`` lag, which a branch near it would copy).
    offset_m : float, optional
        The record's displacement offset, m (taken off before ``V_h``). Default: searched (:func:`_offset_search`)
        on the development rows' residual around the base fit's ``offset``, which is fitted without creep and
        biased by it: an offset error ``d`` moves ``V_h`` by ``d / (k_q2x C_pp)`` (4.3 V per um on the
        P-888.51 sn637) and neither the free intercept nor the branches absorb it (the plays' states and the
        branches' start from rest are not shift invariant).

    Returns
    -------
    dict or None
        ``hysteresis`` (C_h: thresholds in V_h, V; weights, F), ``caps_f``, ``taus_s`` (the branches with
        ``C_j > 0``), ``residual_m`` (RMS of the fit's residual on ``rows``, as displacement, m), ``offset_m`` (the
        offset used, m). C_h's reversal slope is held to at least :data:`REVERSAL_FLOOR` of its weights' sum.
        None when the record gives no C_h (no positive weight).
    """
    m = base.channels["displacement"]
    t = np.asarray(base.t, float)
    dt = float(np.mean(np.diff(t)))
    ok = np.asarray(m.valid, bool) & np.isfinite(m.y)
    fit = np.asarray(rows, bool) & ok
    # V_h runs over the whole record (the plays' and branches' states carry its history), but only the fit's
    # rows may enter it: elsewhere (the test rows, invalid samples) the record's motion is replaced by a model
    # of it fitted on the development rows (``model``: the fitted model; its misfit moves V_h by that over
    # k_q2x C_pp, a large factor: the base alone, creep left out, moved it by volts and spoilt the fit)
    stand_in = np.asarray(m.yhat if model is None else model, float)
    y = np.where(fit, np.asarray(m.y, float), stand_in)
    if sensor_offset is not None:
        y = y - np.asarray(sensor_offset, float)
    y_raw = y
    if offset_m is not None:
        return _direct_at_offset(plant, base, fit, y_raw - float(offset_m), t, dt, delay_s, thresholds_v, m,
                                 float(offset_m), fastest_branch_s)
    return _offset_search(lambda off: _direct_at_offset(plant, base, fit, y_raw - off, t, dt, delay_s, thresholds_v,
                                                        m, off, fastest_branch_s), float(m.offset), y_raw[fit])


#: The offset search's half-width, in the development rows' displacement span (:func:`_offset_search`): the
#: base fit's offset, fitted without creep, is off by a part of the creep's motion, itself a part of the span.
OFFSET_SEARCH_OF_SPAN = 0.1


def _offset_search(fit_at, offset0, y_rows):
    """The direct fit (``fit_at(offset)``) at the offset, m, within ``offset0 +- OFFSET_SEARCH_OF_SPAN`` of the
    rows' span that leaves the least residual (bounded golden section to 1e-5 of the span; ``offset0`` kept
    unless beaten). Noise-free the residual is 0 at the record's offset only (a wrong one shifts ``V_h``)."""
    from scipy.optimize import minimize_scalar
    span = float(np.ptp(y_rows)) if y_rows.size else 0.0
    first = fit_at(offset0)
    if not span > 0:
        return first

    def cost(off):
        j = fit_at(off)
        return float("inf") if j is None else j["residual_m"]
    h = OFFSET_SEARCH_OF_SPAN * span
    sol = minimize_scalar(cost, bounds=(offset0 - h, offset0 + h), method="bounded",
                          options={"xatol": 1e-5 * span, "maxiter": 40})
    if first is None or sol.fun < first["residual_m"]:
        return fit_at(float(sol.x))
    return first


def _direct_at_offset(plant, base, fit, y, t, dt, delay_s, thresholds_v, m, offset_m, fastest_branch_s=None):
    """:func:`direct_core_and_branches` with the record's offset taken off ``y`` (``offset_m``, m)."""
    from .pi_fit import play_matrix
    k, c_pp = float(plant.pzt.k_q2x_m_per_c), float(plant.pzt.c_pp_f)
    # V_h as the sensor sees it: the record's charge y / k is q(t - delay), interpolated between samples as
    # the sensor's delay is (linear); V_t(t - delay) interpolated alike, so their difference is V_h(t - delay)
    # blended with the same weights. (Undoing the delay on y instead smears a step's sample and puts V_h
    # past both its ends there, which sets every play's state after it: drawn records with a fractional
    # delay left 100x the residual of an integer one.) Plays and lowpasses are time-invariant: the columns
    # of the delayed V_h are the delayed columns.
    vt = np.asarray(base.v_drive, float)
    vh = _sensor_view(t, vt, float(delay_s)) - y / (k * c_pp)
    if thresholds_v is None:
        rt = np.asarray(m.thresholds_v, float)
        r = rt * (float(np.ptp(vh)) / float(np.ptp(vt)))
    else:
        r = np.asarray(thresholds_v, float)
    z0 = np.where(r < abs(vh[0]), vh[0] - np.sign(vh[0]) * r, 0.0)
    dur = float(t[-1] - t[0])
    fastest = max(10 * dt, float(fastest_branch_s or 0.0))
    taus = 10.0 ** np.arange(np.log10(fastest), np.log10(max(SLOWEST_BRANCH * dur, fastest)) + 1e-9, 0.5)
    n = int(np.count_nonzero(fit))
    cols = [play_matrix(vh, r, z0)] + [_lowpass_from_rest(vh, tau, dt)[:, None] for tau in taus]
    # only the fit rows are stacked (the columns run over the whole record; the same values as X[fit]): one
    # 355,000-row matrix less to allocate
    Xf = column_stack([c[fit] for c in cols])
    del cols
    # weights and C_j >= 0, the charge's offset free (every column and q centred on the fit's rows), C_h's
    # reversal slope (the threshold-0 play, V_h itself) at least REVERSAL_FLOOR of the weights' sum (as
    # instant_weights): the base fit's bounded solve on the Gram matrix of the centred unit-RMS columns (a few
    # dozen; nnls on the rows cost 0.4 s a solve at 355,000 rows). Centred, a play that moves once and then
    # holds is its own small column, not a near copy of the offset's (uncentred, the solve traded the two at
    # 4e7 and a 28x creep record came out at 4e4 m); the ridge (DIRECT_RIDGE) keeps a play that never moves
    # on the rows (a zero column) at zero.
    q = y / k
    mu = Xf.mean(axis=0)
    Xc = Xf - mu
    qc = q[fit] - q[fit].mean()
    sc = np.sqrt(np.einsum("ij,ij->j", Xc, Xc) / n)
    sc[sc == 0] = 1.0
    Xc /= sc                   # in place: As, the centred unit-RMS columns (the same values as Xc / sc)
    As = Xc
    # the Gram matrix of the unit-RMS columns per row (unit diagonal: the ridge relative, as documented)
    G, h = As.T @ As / n + DIRECT_RIDGE * np.eye(Xf.shape[1]), As.T @ qc / n
    del Xc, As
    use = np.ones(Xf.shape[1], bool)
    cap = min(BRANCH_CAP_OF_C_PP * c_pp, BRANCH_CAP_F)
    while True:
        lower = np.zeros(Xf.shape[1])
        idx = np.flatnonzero(use)
        coef = np.zeros(Xf.shape[1])
        coef[idx] = _bounded_gram_solve(G[np.ix_(idx, idx)], h[idx], lower[idx]) / sc[idx]
        # the floor is of the weights' sum, which the bounded re-solve moves: raised until it holds after it
        for _ in range(20):
            floor = REVERSAL_FLOOR * float(np.sum(np.maximum(coef[:r.size], 0.0)))
            if coef[0] >= floor * (1.0 - 1e-9):
                break
            lower[0] = floor * sc[0]
            coef[idx] = _bounded_gram_solve(G[np.ix_(idx, idx)], h[idx], lower[idx]) / sc[idx]
        # a branch beyond the cap is a slow column the centring left small, traded against the others (seed 25
        # #31: 12627 F at 10 record lengths): the slowest such column is dropped and the fit made again
        over = np.flatnonzero(coef[r.size:] > cap)
        if not over.size:
            break
        use[r.size + over.max()] = False
    coef = np.maximum(coef, 0.0)
    coef = np.r_[coef, q[fit].mean() - mu @ coef]
    A = column_stack([Xf, np.ones(n)])
    w, c = coef[:r.size], coef[r.size:r.size + taus.size]
    if not w[0] > 0:
        return None
    res = q[fit] - A @ coef
    keep = c > 1e-9 * max(float(c.sum()), 1e-300)
    return {"hysteresis": PrandtlIshlinskii(r, w, np.zeros(r.size)), "caps_f": c[keep], "taus_s": taus[keep],
            "residual_m": float(np.sqrt(np.mean(res * res))) * k, "offset_m": offset_m}
