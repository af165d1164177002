"""A serial's Instron runs in sequence, C_h's memory and creep carried from run to run (issue 16 item 2).

Seed 000 sec. 3.2 loads each stack six times (three runs with the leads through 200 ohm, ``R_in``,
three with the leads open to the Keithley 617, ``R_out``) and tabulates the peak back EMF of the
``R_out`` runs. The question this module answers: can the memory of the hysteretic capacitance
C_h (its plays) or of its creep branches, left by earlier runs, make the back EMF per newton depend
on the run's place in the sequence, and does reading V_t through the hysteresis inverse with that
memory carried (V_h, then V_p, then x and F_e by eqs. 5 and 9) estimate the peak force better than
a gain times the back EMF?

The model, quasi-static (the 200 ohm leads relax in R C ~ 3 ms against 5 s ramps; the 70 kHz
mode is far above the load frame), charge-conserving, one step of ``dt_s``:

- the creep branches (Kelvin-Voigt, across C_h): Q_j,k = a_j Q_j,k-1 + (1 - a_j) C_j V_h*,
  a_j = exp(-dt / tau_j), V_h* = V_h,k-1 - k S semi-implicit (S the branches' summed charge, k = 1 / C_h on
  the segment V_h moves along with the leads open, 1 / C_pp shorted: stable for any dt), as
  :mod:`workbench.plant.kernels` and :func:`.force.estimate_force` step them;
- the stack charge q = C_h[V_h] + sum_j Q_j; V_p = (q - T_em F_e / k_p) / C_pp; V_t = V_h + V_p
  (seed 000 eqs. 5 and 9 with the spring eliminated);
- leads **shorted** (``R_in``, and the drain before every run): V_t = 0, i.e.
  (C_h + C_pp I)[V_h] = T_em F_e / k_p - sum_j Q_j,k;
- leads **open** (``R_out``): q is held, i.e. C_h[V_h] = q - sum_j Q_j,k.
  The Keithley's 200 TOhm drains the stack in R C ~ 10^9 s: 10^-8 of the charge over a run.

Both are PI operators in V_h (C_h, or C_h with C_pp added to its linear term), inverted exactly
(Kuhnen) from C_h's current play states at every step, so the states stay one set.

**What follows from the structure** (tests): with the leads open q is held, so C_h's output is
held, and C_h is strictly increasing along any branch (its r = 0 weight is positive), so V_h is
held whatever state the plays are in. The back EMF is then V_t - V_t,0 = -T_em Delta F_e / (k_p C_pp)
exactly, for every history: **C_h's memory cannot make V/F depend on the run order**. Only a
charge moving at constant q can, which in the model is the creep branches relaxing toward C_j V_h
(a charge redistribution inside the stack, no terminal current) when an earlier run left them
out of equilibrium. :func:`serial_sequence` measures that term, Delta V_h over each open-lead run.

Note on the library simulator: :class:`~workbench.plant.simulator.PZTSimulator` once fed the creep
branches' charge change to the terminal with no current through R (+387 nC by the peak of an open-lead run after three
``R_in`` runs in the creep plant, at 200 TOhm), so this module stepped its own
charge-conserving form. The kernels now keep Kirchhoff's current law at the terminal
(tests/plant/test_kcl.py) and step the creep branches as this module does (semi-implicit V_h*);
the module keeps its stepper because its shorted runs are the quasi-static V_t = 0, and the simulator's
quasi-static form (R = 0) kept G^-1's plays where its dynamic form (open leads) keeps G's, so one state
could not pass between the two. (Since session 37 both forms keep G's plays, and a short, which has no current
limit, is :meth:`~workbench.plant.pzt.PZTParams.terminal_driven`: the simulator could now step these runs too;
not changed.)
"""

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..plant.hysteresis import pi_slope, play_step
from ..plant.kernels import creep_branch_update, creep_explicit_charge, creep_node_voltage
from .force import estimate_force, instron_force_profile

__all__ = ["SequenceRun", "serial_sequence", "read_open_lead_run", "table1_sequence_estimates",
           "TABLE1_SEQUENCE_DRAIN_S"]

#: drain before each run, s, for Table 1 (assumed; seed 000 gives no timing, only "shorted and drained"): a short
#: drain, near the bound most favourable to a run-order effect (the creep branches the previous run left have
#: little time to relax: the first open-lead run's V_h falls by 0.086 V at 1 s, 0.113 V as the drain -> 0,
#: 0.029 V at 10 s). With no drain at all the meter would start each run from what the last one left.
TABLE1_SEQUENCE_DRAIN_S = 1.0


@njit(cache=True, error_model="numpy")
def _solve_v_h(z, r, w, r_inv, w_inv, y):
    """V_h with P[V_h] = y for the PI operator P = (r, w) at forward play states z, exactly (Kuhnen).

    The inverse's states follow from the forward ones (z'_i = W_i z_i + sum_{j>i} w_j z_j,
    W_i = w_0 + ... + w_i); z is then advanced to the solution, so one set of states is kept.
    """
    n = z.shape[0]
    tail = 0.0
    big_w = np.cumsum(w)
    v = 0.0
    for i in range(n - 1, -1, -1):
        v += w_inv[i] * play_step(big_w[i] * z[i] + tail, r_inv[i], y)
        tail += w[i] * z[i]
    for i in range(n):
        z[i] = play_step(z[i], r[i], v)
    return v


@njit(cache=True, error_model="numpy")
def _segment(z, qc, q, shorted, f_term, r, w_h, w_open, r_open_inv, w_open_inv, w_short, r_short_inv,
             w_short_inv, cap, dec, c_pp, out):
    """Step one segment, leads shorted or open, over ``f_term`` = T_em F_e / k_p per sample (C).

    z (C_h's play states, V) and qc (creep charges, C) are updated in place; returns the stack
    charge q at the end. ``w_open`` / ``w_short``: C_h's weights / with C_pp added to the r = 0
    play, and their inverses' thresholds and weights. ``out`` rows: V_h, V_p, V_t, q. The creep
    branches step first from V_h at the step's start (the r = 0 play's state), semi-implicit as
    :func:`workbench.plant.kernels.pzt_advance` steps them: toward C_j V_h*, V_h* = V_h - k S on the
    slope k = 1 / C_h of the segment V_h moves along (open leads) or k = 1 / C_pp (shorted: the quasi-static
    form's bound on 1 / (C_pp + C_h)), S = E / (1 + b k) their charge, E that of the explicit step.
    """
    n_c = cap.shape[0]
    b = (1.0 - dec) * cap                        # the branches' input coefficients b_j = (1 - d_j) C_j, F
    b_tot = 0.0
    for j in range(n_c):
        b_tot += b[j]
    for k in range(f_term.shape[0]):
        v_h0 = z[0]
        qc_old = 0.0
        for j in range(n_c):
            qc_old += qc[j]
        v_h_s = v_h0
        if n_c > 0:
            _, e_c = creep_explicit_charge(dec, 0, qc, 0, n_c, b_tot, v_h0, qc_old)
            if shorted:
                k_h = 1.0 / c_pp
            else:
                k_h = 1.0 / pi_slope(z, r, w_h, v_h0, -1 if e_c > 0 else 1)
            v_h_s = creep_node_voltage(v_h0, e_c, b_tot, k_h)
        creep_branch_update(dec, 0, b, 0, qc, 0, n_c, v_h_s)
        s_qc = 0.0
        for j in range(n_c):
            s_qc += qc[j]
        if shorted:
            v_h = _solve_v_h(z, r, w_short, r_short_inv, w_short_inv, f_term[k] - s_qc)
            q = 0.0
            for i in range(z.shape[0]):
                q += w_h[i] * z[i]
            q += s_qc
        else:
            v_h = _solve_v_h(z, r, w_open, r_open_inv, w_open_inv, q - s_qc)
        v_p = (q - f_term[k]) / c_pp
        out[k, 0] = v_h
        out[k, 1] = v_p
        out[k, 2] = v_h + v_p
        out[k, 3] = q
    return q


@dataclass(frozen=True)
class SequenceRun:
    """One run of a serial's sequence, simulated (SI).

    ``back_emf_v``: V_t at the run's largest |V_t| (the meter's reading; V_t is 0 before the run after a
    drain);
    ``delta_v_h_v``: V_h at that sample minus V_h before the run (0 for every history without creep);
    ``back_emf_per_force_v_per_n``: back_emf_v / peak_force_n; ``states_v``, ``creep_charges_c``,
    ``charge_c``: C_h's play states, the creep charges and the stack charge at the run's start
    (after its drain), the state :func:`~.force.estimate_force` needs to read the run;
    ``peak_time_s``: time of the peak from the run's start.
    """

    config: str
    peak_force_n: float
    back_emf_v: float
    delta_v_h_v: float
    back_emf_per_force_v_per_n: float
    states_v: np.ndarray
    creep_charges_c: np.ndarray
    charge_c: float
    peak_time_s: float


def serial_sequence(pzt, runs, *, drain_s=TABLE1_SEQUENCE_DRAIN_S, dt_s=0.01, rest_s=1.0, ramp_s=5.0, hold_s=2.0):
    """Simulate a serial's Instron runs one after another, the stack's state carried (module notes).

    Parameters
    ----------
    pzt : PZTParams
        The stack; its hysteresis initial states are the state before the first run.
    runs : sequence of (str, float)
        (``"R_in"`` or ``"R_out"``, peak force N, compression negative) in the order taken.
    drain_s : float
        Leads shorted before each run ("shorted and drained", seed 000 sec. 2), s. Assumed:
        the seed gives no timing.
    dt_s : float
        Step, s (the shortest creep time constant is 0.1 s; the ramps 5 s).
    rest_s, ramp_s, hold_s : float
        The run's force shape, s (:func:`~.force.instron_force_profile`: assumed, seed 000
        Fig. 5 is not tabulated).

    Returns
    -------
    list of SequenceRun
    """
    if not (dt_s > 0 and drain_s >= 0 and rest_s > 0 and ramp_s > 0 and hold_s >= 0):
        raise ValueError("dt_s, rest_s and ramp_s must be positive; drain_s and hold_s non-negative (s)")
    h = pzt.hysteresis
    r, w_h = h.thresholds, h.weights
    if pzt.creep is not None:
        cap = np.asarray(pzt.creep.capacitances_f, float)
        dec = np.exp(-dt_s / np.asarray(pzt.creep.time_constants_s, float))
    else:
        cap, dec = np.zeros(0), np.zeros(0)
    c_pp, k_f = pzt.c_pp_f, pzt.transducer_constant_n_per_v / pzt.stiffness_n_per_m
    p_open, p_short = h, h.plus_linear(c_pp)
    w_open, w_short = p_open.weights, p_short.weights
    inv_open, inv_short = p_open.inverse(), p_short.inverse()      # thresholds and weights (states rebuilt per step)
    ri_open, wi_open, ri_short, wi_short = inv_open.thresholds, inv_open.weights, inv_short.thresholds, inv_short.weights
    z = h.initial_states.copy()
    qc = np.zeros(cap.size)
    q = float(w_h @ z)
    n_drain = int(round(drain_s / dt_s))

    def seg(shorted, f_n):
        nonlocal q
        out = np.empty((f_n.size, 4))
        q = _segment(z, qc, q, shorted, k_f * np.asarray(f_n, float), r, w_h, w_open, ri_open, wi_open, w_short,
                     ri_short, wi_short, cap, dec, c_pp, out)
        return out

    result = []
    last = np.zeros(4)          # V_h, V_p, V_t, q before the run (V_t = 0 after a drain)
    last[0] = z[0]
    for config, peak_n in runs:
        if config not in ("R_in", "R_out"):
            raise ValueError(f"run config must be 'R_in' or 'R_out'; got {config!r}")
        if n_drain:
            last = seg(True, np.zeros(n_drain))[-1]
        start = (z.copy(), qc.copy(), q)
        f = instron_force_profile(float(peak_n), dt_s, rest_s=rest_s, ramp_s=ramp_s, hold_s=hold_s)
        out = seg(config == "R_in", f)
        # the peak: largest |V_t| (R_in holds V_t = 0: its peak is the largest |F_e|)
        k = int(np.argmax(np.abs(out[:, 2]))) if config == "R_out" else int(np.argmax(np.abs(f)))
        # the meter reads V_t itself (0 before the run after a drain; with no drain, what the last run left)
        emf = float(out[k, 2])
        result.append(SequenceRun(config, float(peak_n), emf, float(out[k, 0] - last[0]),
                                  emf / float(peak_n), *start, float((k + 1) * dt_s)))
        last = out[-1]
    return result


def read_open_lead_run(pzt, start, back_emf_v, peak_time_s, *, dt_s=0.01):
    """The peak force of an open-lead run from its back EMF, through the hysteresis inverse, state carried.

    :func:`~.force.estimate_force` on the run: the charge held at its value after the drain
    (q = 0 since the run's start), V_t rising from 0 to ``back_emf_v`` at ``peak_time_s``, C_h's
    plays and the creep charges at ``start``. V_h from the inverse (it moves only as the creep
    branches relax at constant charge, whatever V_t does), V_p = V_t - V_h, x by eq. 9, F_e by eq. 5.

    Parameters
    ----------
    pzt : PZTParams
    start : SequenceRun
        The run, for its state at the start (``states_v``, ``creep_charges_c``).
    back_emf_v : float
        Measured peak back EMF, V (V_t itself; 0 before the run after a drain).
    peak_time_s : float
        Time from the run's start to the peak, s.
    dt_s : float
        Step, s.

    Returns
    -------
    (float, float, float)
        F_e (N, compression negative), elongation (m) and V_h's change from before the run (V) at the peak.
    """
    n = max(2, int(round(peak_time_s / dt_s)))       # samples dt, 2 dt, ..., peak_time_s after the start
    t = np.arange(1, n + 1) * dt_s
    est = estimate_force(t, np.linspace(0.0, float(back_emf_v), n), np.zeros(n), pzt, states_v=start.states_v,
                         creep_charges_c=start.creep_charges_c)
    # C_h's r = 0 play holds the last V_h: the change is from the state before the run
    return float(est.f_e_n[-1]), float(est.x_m[-1]), float(est.v_h_v[-1] - start.states_v[0])


def table1_sequence_estimates(pzt, path=None, *, drain_s=TABLE1_SEQUENCE_DRAIN_S, dt_s=0.01):
    """Table 1's ``R_out`` runs read by the model through the hysteresis inverse, each serial's runs in sequence.

    Each serial's runs are simulated in the table's column order (its three ``R_in`` runs, then
    its three ``R_out`` runs; assumed, the seed gives no order or timing) with their printed peak
    forces, the state carried (:func:`serial_sequence`); each ``R_out`` run's measured back EMF is
    then read from its simulated start state (:func:`read_open_lead_run`). No ``R_out`` run's force
    enters any estimate: with the leads open the charge is held, so an ``R_out`` run leaves the
    state as the creep relaxation alone leaves it, whatever its force (tests).

    Parameters
    ----------
    pzt : PZTParams
        The stack, for every serial (the plant files share C_h, C_p, T_em, k_p).
    path : str or path-like, optional
        Table 1 CSV; default ``plants/data/p888_51_instron_table1.csv``.
    drain_s, dt_s : float
        As :func:`serial_sequence`, s.

    Returns
    -------
    list of dict
        Per ``R_out`` run in file order: ``serial``, ``run``, ``force_n``, ``back_emf_v``,
        ``estimate_n`` (model, no fitted gain), ``linear_estimate_n`` (-k_p C_pp / T_em x back
        EMF: the same read with V_h held), ``delta_v_h_v`` (V_h's change to the peak in the
        read), ``simulated_back_emf_per_force_v_per_n`` (the model's own run at the printed force).
    """
    from ..identify.transducer import DEFAULT_CALIBRATIONS_M_PER_V, DEFAULT_TABLE1_PATH, _read_table
    runs, _, _ = _read_table(DEFAULT_TABLE1_PATH if path is None else path, DEFAULT_CALIBRATIONS_M_PER_V)
    gain = -pzt.stiffness_n_per_m * pzt.c_pp_f / pzt.transducer_constant_n_per_v
    out = {}
    for sn in dict.fromkeys(r.serial for r in runs):
        mine = [r for r in runs if r.serial == sn]
        order = [r for r in mine if r.config == "R_in"] + [r for r in mine if r.config == "R_out"]
        seq = serial_sequence(pzt, [(r.config, r.force_n) for r in order], drain_s=drain_s, dt_s=dt_s)
        for r, sr in zip(order, seq):
            if r.config != "R_out":
                continue
            f, _, dvh = read_open_lead_run(pzt, sr, r.back_emf_v, sr.peak_time_s, dt_s=dt_s)
            out[(r.serial, r.run)] = {"serial": r.serial, "run": r.run, "force_n": r.force_n,
                                      "back_emf_v": r.back_emf_v, "estimate_n": f,
                                      "linear_estimate_n": gain * r.back_emf_v, "delta_v_h_v": dvh,
                                      "simulated_back_emf_per_force_v_per_n": sr.back_emf_per_force_v_per_n}
    return [out[(r.serial, r.run)] for r in runs if r.config == "R_out"]
