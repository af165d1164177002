"""Force self-sensing on the stack: the environmental force and the elongation from V_t and the charge.

The seed 000 model (Fig. 3) read backwards, one sample at a time (seed 002 sec. 2.4 does the
same for its cantilever with a linear force sensitivity beta and PI/creep operators; on the
stack the model's own operators are used):

1. **V_h** from the terminal charge q through the hysteretic capacitance and its creep
   branches. q = q_h + Q_c with q_h = C_h[V_h] (a PI operator) and each creep branch
   relaxing toward C_j V_h (tau_j Q_j' = C_j V_h - Q_j, stepped as the simulator steps it:
   Q_j,k = a_j Q_j,k-1 + (1 - a_j) C_j V_h*, a_j = exp(-dt/tau_j), V_h* = V_h,k-1 - k S on C_h's
   local slope k = dV_h/dq_h with S the branches' summed charge, semi-implicit and stable for any dt;
   :mod:`workbench.plant.kernels`). Per sample C_h[V_h,k] = q_k - sum_j Q_j,k, so V_h is
   the exact inverse of C_h (Kuhnen, :meth:`~workbench.plant.hysteresis.PrandtlIshlinskii.inverse`),
   no iteration.
2. **V_p** = V_t - V_h (the two capacitances in series carry the terminal voltage).
3. **Elongation** from eq. 9: C_p V_p = q - T_em x, so x = (q - C_p V_p) / T_em.
4. **Force** from eq. 5 (quasi-static spring): k_p x = F_e + T_em V_p, so F_e = k_p x - T_em V_p
   = (k_p / T_em) (q - C_pp V_p) with C_pp = C_p + T_em^2 / k_p.

How the force and the displacement are told apart. With F_e = 0 the charge tracks the
displacement (x = k_q2x q, seed 000 eq. 10) and the displacement estimator of
:mod:`.estimator` reads x from q alone. With a force present the charge also carries
T_em F_e / k_p (V_p = (q - T_em F_e / k_p) / C_pp), so q alone cannot say whether the stack
moved because of the voltage or was pushed: x = k_q2x q is then off by
-C_p F_e / (k_p C_pp) (about 0.35 F_e / k_p). The second measurement separates them: V_t
minus the hysteresis voltage V_h gives V_p, the voltage that makes the piezo force, and eqs.
5 and 9 are two equations for the two unknowns x and F_e. The separation needs the
hysteresis inverse because V_h is a sizeable, hysteretic share of V_t (about 1/3 of it in
the SN637 model).

What the estimate rests on: the model's C_p, T_em, k_p, C_h and creep branches (plant file);
the charge with its drift compensation identified in coulombs at F_e = 0 (:mod:`.charge_drift`;
the displacement estimator's four stages of :mod:`.identify` are kept beside it: their stage 4
returns alpha times the displacement, which is off the charge by the step alpha's bias); the integrator
reset with the stack at rest (the plant file's initial state). The force is ~4.3 N per uC of
charge error (k_p / T_em) and ~72 N per volt of V_p error (k_p C_pp / T_em): a 1 % error in
the charge of a stack held at 50 V is ~20 N, which is why the drift compensation matters
more here than for the displacement.
"""

from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from ..errors import FlagRangeError
from ..plant.hysteresis import pi_slope, pi_step
from ..plant.kernels import creep_branch_update, creep_explicit_charge, creep_node_voltage
from ..plant.simulator import PZTSimulator
from .charge_amp import ChargeAmpParams, charge_amp_params, measure
from .estimator import charge_estimate, static_estimate

__all__ = ["check_step_force", "check_force_table", "force_resolution_n", "step_force_range_n", "ForceEstimate", "estimate_force", "staged_charge", "FORCE_STAGE", "FORCE_STAGE_TITLE",
           "force_step_voltage", "simulate_force_step",
           "instron_force_profile", "simulate_instron_run", "instron_from_table", "force_step_errors", "run_force_study",
           "INSTRON_R_IN_OHM",
           "INSTRON_R_OUT_OHM", "FORCE_TARGET_STEP_FRACTION", "FORCE_TARGET_PEAK_FRACTION"]

INSTRON_R_IN_OHM = 200.0        # seed 000 sec. 3.2 / Fig. 4: the 200 ohm load resistor across the leads
INSTRON_R_OUT_OHM = 200e12      # seed 000 sec. 3.2: Keithley 617, 200 TOhm input impedance
FORCE_STAGE = "charge_drift"    # the force path's own stage after the displacement estimator's four (charge_drift.py)
FORCE_STAGE_TITLE = "+ absorption in coulombs, alpha from reversals"


@dataclass(frozen=True)
class ForceEstimate:
    """The Fig. 3 model read backwards (SI): per sample V_h, V_p, elongation and environmental force."""

    t_s: np.ndarray
    q_c: np.ndarray
    v_h_v: np.ndarray
    v_p_v: np.ndarray
    x_m: np.ndarray
    f_e_n: np.ndarray


@njit(cache=True, error_model="numpy")
def _invert(q, r, w, z, cap, dec, qc, vh):
    """V_h per sample: inverse PI of (q_k - sum Q_j,k), the creep branches (``qc``, updated) stepped first as
    :func:`workbench.plant.kernels.pzt_advance` steps them (semi-implicit on C_h's local slope, from the previous
    V_h: ``vh`` at the reset). ``z[0]``: the threshold-0 play's state, C_h's charge q_h."""
    n = q.shape[0]
    n_c = cap.shape[0]
    v_h = np.empty(n)
    b = (1.0 - dec) * cap                        # the branches' input coefficients b_j = (1 - d_j) C_j, F
    b_tot = 0.0                                  # their sum, constant over the run
    for j in range(n_c):
        b_tot += b[j]
    for k in range(n):
        qc_old = 0.0
        for j in range(n_c):
            qc_old += qc[j]
        vh_s = vh
        if n_c > 0:
            _, e_c = creep_explicit_charge(dec, 0, qc, 0, n_c, b_tot, vh, qc_old)
            # k = dV_h/dq_h on the segment q_h moves along (falling while the branches charge)
            k_h = pi_slope(z, r, w, z[0], -1 if e_c > 0 else 1)
            vh_s = creep_node_voltage(vh, e_c, b_tot, k_h)
        creep_branch_update(dec, 0, b, 0, qc, 0, n_c, vh_s)
        rhs = q[k]
        for j in range(n_c):
            rhs -= qc[j]
        vh = pi_step(z, r, w, rhs)
        v_h[k] = vh
    return v_h


def estimate_force(t_s, v_t_v, q_c, pzt, *, states_v=None, creep_charges_c=None):
    """Elongation and environmental force from the terminal voltage and charge (module notes, steps 1-4).

    Parameters
    ----------
    t_s : array_like of float
        Uniform sample times, s, from the reset at rest (t = 0 is the sample before the first).
    v_t_v : array_like of float
        Terminal voltage V_t, V (the HV monitor).
    q_c : array_like of float
        Terminal charge since the reset, C (drift-compensated: :func:`staged_charge`).
    pzt : PZTParams
        The stack model (C_p, T_em, k_p, C_h, creep branches); its hysteresis initial states
        are the state at the reset unless ``states_v`` is given.
    states_v : array_like of float, optional
        C_h's play states at the reset, V (the memory an earlier test left: e.g.
        :attr:`~.instron_sequence.SequenceRun.states_v`); default the plant's.
    creep_charges_c : array_like of float, optional
        The creep branches' charges at the reset, C; default 0. The charge at the reset is
        C_h[states] + sum of these.

    Returns
    -------
    ForceEstimate
    """
    t = np.asarray(t_s, float)
    v = np.asarray(v_t_v, float)
    q = np.asarray(q_c, float)
    if not (t.ndim == v.ndim == q.ndim == 1 and t.size == v.size == q.size >= 2):
        raise ValueError("t, V_t and q must be 1-D arrays of one length (at least 2 samples)")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(q))):
        raise ValueError("V_t and q must be finite (found NaN or inf)")
    dt = float(t[1] - t[0])
    if not dt > 0:
        raise ValueError("sample times must increase")
    if pzt.creep is not None:
        cap = np.asarray(pzt.creep.capacitances_f, float)
        dec = np.exp(-dt / np.asarray(pzt.creep.time_constants_s, float))
    else:
        cap, dec = np.zeros(0), np.zeros(0)
    hyst = pzt.hysteresis if states_v is None else pzt.hysteresis.with_states(states_v)
    qc0 = np.zeros(cap.size) if creep_charges_c is None else np.array(creep_charges_c, float)
    if qc0.shape != cap.shape or not np.all(np.isfinite(qc0)):
        raise ValueError(f"creep_charges_c needs {cap.size} finite charges (C), one per creep branch; got {qc0!r}")
    inv = hyst.inverse()                        # exact (Kuhnen)
    q0 = hyst.output_at_rest() + float(np.sum(qc0))
    # V_h at the reset: the threshold-0 play's state (it follows its input)
    v_h = _invert(q + q0, inv.thresholds, inv.weights, inv.initial_states.copy(), cap, dec, qc0.copy(),
                  float(hyst.initial_states[0]))
    v_p = v - v_h
    t_em, k_p = pzt.transducer_constant_n_per_v, pzt.stiffness_n_per_m
    x = (q + q0 - pzt.working_capacitance_f * v_p) / t_em          # seed 000 eq. 9
    f = k_p * x - t_em * v_p                                       # seed 000 eq. 5
    return ForceEstimate(t, q + q0, v_h, v_p, x, f)


def staged_charge(rec, ident, stage, drift=None):
    """The stack's charge from a :class:`~.charge_amp.ChargeRecord` with one stage of drift compensation, C.

    Stages as the displacement estimator's (:meth:`~.identify.Identified.stage`); the stage-4
    operator, identified in metres at F_e = 0, enters as charge through the identified alpha
    (so that stage returns alpha times the displacement estimate, not q: see
    :mod:`.charge_drift`). ``FORCE_STAGE`` is the compensation identified in coulombs,
    ``drift`` (a :class:`~.charge_drift.ChargeDrift`).
    """
    if stage == FORCE_STAGE:
        if drift is None:
            raise ValueError(f"stage {FORCE_STAGE!r} needs the ChargeDrift (charge_drift.identify_charge_drift)")
        return drift.charge(rec.t_s, rec.v_in_v, rec.v_out_v)
    p = ident.stage(stage)
    if p.correction is None:
        return charge_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, p)
    return p.alpha_c_per_m * static_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, p)


# ---- scenarios --------------------------------------------------------------------------------

def force_step_voltage(duration_s, dt_s, step_at_s, bias_v=50.0, force_n=-100.0):
    """(V_pea, F_e) per sample: V_pea held at ``bias_v`` from t = 0, F_e stepping to ``force_n`` at ``step_at_s``."""
    n = int(round(duration_s / dt_s))
    t = np.arange(n) * dt_s
    return np.full(n, float(bias_v)), np.where(t >= step_at_s, float(force_n), 0.0)


def simulate_force_step(pzt, amp=ChargeAmpParams(), duration_s=60.0, step_at_s=30.0, bias_v=50.0,
                        force_n=-100.0, dt_s=1e-4, sample_hz=1000.0, seed=3):
    """The stack driven at ``bias_v`` through its amplifier, a force step at ``step_at_s``.

    Returns (ChargeRecord, true F_e per kept sample). Compression is negative.
    """
    dec = max(1, int(round(1.0 / (sample_hz * dt_s))))
    v, f = force_step_voltage(duration_s, dt_s, step_at_s, bias_v, force_n)
    n = (v.size // dec) * dec
    traj = PZTSimulator(pzt, dt_s).run(v[:n], f_e_n=f[:n], decimate=dec)
    rec = measure(traj, amp, seed=seed, average=dec)
    f_true = f[:n][dec - 1::dec]
    return rec, f_true


def instron_force_profile(peak_n, dt_s, rest_s=1.0, ramp_s=5.0, hold_s=2.0):
    """Force per sample for one Instron run: rest, a ramp to ``peak_n``, a hold, a ramp back (assumed shape:
    seed 000 Fig. 5 is not tabulated; the load frame ran in displacement mode, ~800 N in a few seconds)."""
    seg = [np.zeros(int(round(rest_s / dt_s))), np.linspace(0.0, peak_n, int(round(ramp_s / dt_s)) + 1)[1:],
           np.full(int(round(hold_s / dt_s)), float(peak_n)), np.linspace(peak_n, 0.0, int(round(ramp_s / dt_s)) + 1)[1:],
           np.zeros(int(round(rest_s / dt_s)))]
    return np.concatenate(seg)


def simulate_instron_run(pzt, config, peak_n, amp=ChargeAmpParams(), dt_s=1e-4, sample_hz=1000.0, seed=5):
    """One Table 1 run on the model: the leads through 200 ohm (``R_in``) or open to 200 TOhm (``R_out``).

    The amplifier is replaced by the test's load (V_pea = 0 behind the load resistance, no
    current limit); the stack's charge is read by the charge amplifier as in the self-sensing
    circuit. Returns (ChargeRecord, true F_e per kept sample, (start, end) of the peak hold, s).
    """
    if config not in ("R_in", "R_out"):
        raise ValueError(f"config must be 'R_in' or 'R_out'; got {config!r}")
    r = INSTRON_R_IN_OHM if config == "R_in" else INSTRON_R_OUT_OHM
    load = replace(pzt, series_resistance_ohm=r, current_limit_source_a=1.0, current_limit_sink_a=1.0)
    dec = max(1, int(round(1.0 / (sample_hz * dt_s))))
    f = instron_force_profile(peak_n, dt_s)
    n = (f.size // dec) * dec
    traj = PZTSimulator(load, dt_s).run(np.zeros(n), f_e_n=f[:n], decimate=dec)
    rec = measure(traj, amp, seed=seed, average=dec)
    return rec, f[:n][dec - 1::dec], (6.0, 8.0)


def instron_from_table(pzt, back_emf_v):
    """Table 1 ``R_out`` run read by the estimator: leads open after draining, so q = 0 and V_t = the back EMF.

    Returns (force N, elongation m) at the peak. (``R_in`` runs hold V_t = 0 and Table 1 has
    no charge, so they cannot be read this way; :func:`simulate_instron_run` covers them.)
    """
    est = estimate_force(np.array([0.0, 1.0]), np.array([0.0, float(back_emf_v)]), np.zeros(2), pzt)
    return float(est.f_e_n[-1]), float(est.x_m[-1])


# ---- the `workbench selfsense --force` study ----------------------------------------------------

FORCE_TARGET_STEP_FRACTION = 0.02     # issue 16: the 100 N step within 2 % after 1 s
FORCE_TARGET_PEAK_FRACTION = 0.05     # issue 16: Table 1 peak forces within 5 %
TARE_S = 1.0                          # the estimate is zeroed over the last second before the load (seed 002 sec. 2.4.1)


def _window(t, a, b):
    return (t >= a) & (t < b)


def force_step_errors(rec, f_true, ident, pzt, step_at_s, stages, drift=None):
    """Per stage: the force estimate's error on a force-step record, absolute and tared (N), and x errors (m).

    ``tared``: the estimate minus its mean over the ``TARE_S`` before the step (the load is known
    to be zero then: seed 002's reset before each measurement). Windows after the step: 1-2 s,
    1-5 s and 1 s to the end of the record (the strictest reading of "within 2 % after 1 s").
    """
    t = rec.t_s
    out = {}
    for name in stages:
        est = estimate_force(t, rec.v_in_v, staged_charge(rec, ident, name, drift), pzt)
        err = est.f_e_n - f_true
        tare = float(np.mean(est.f_e_n[_window(t, step_at_s - TARE_S, step_at_s)]))
        after = {k: _window(t, step_at_s + a, step_at_s + b) for k, (a, b) in
                 {"1_2s": (1.0, 2.0), "1_5s": (1.0, 5.0), "1s_end": (1.0, np.inf)}.items()}
        k_q2x = pzt.k_q2x_m_per_c
        out[name] = {
            "estimate_n": est.f_e_n, "x_estimate_m": est.x_m,
            "abs_error_max_n": {k: float(np.max(np.abs(err[m]))) for k, m in after.items()},
            "tared_error_max_n": {k: float(np.max(np.abs(err[m] - tare))) for k, m in after.items()},
            "tare_n": tare,
            "x_error_max_m": float(np.max(np.abs(est.x_m - rec.x_m)[after["1s_end"]])),
            "x_from_charge_only_error_max_m": float(np.max(np.abs(k_q2x * est.q_c - rec.x_m)[after["1s_end"]])),
        }
    return out


#: Tension the stack may take, as a share of its blocked force: seed 000 sec. 2, the P-888.51 (3600 N
#: blocked) is "brittle and fractures easily in tension"; it is run under the recommended 15 MPa preload,
#: 1500 N on its 10 x 10 mm section, so a tensile step beyond the preload puts the ceramic in tension.
TENSION_SHARE_OF_BLOCKED = 1500.0 / 3600.0
#: Compression, as a multiple of the blocked force, within which the linear model is taken as valid
#: (review 3's choice, not a datasheet figure: 10 strokes of compression).
COMPRESSION_MULTIPLE_OF_BLOCKED = 10.0


def step_force_range_n(pzt):
    """The legal force step (N, compression negative): ``(-10 F_block, 1500/3600 F_block)``.

    ``F_block = k_p x`` the quasi-static stroke from rest at the amplifier's highest voltage
    (SN637: 3666 N, seed 000: "up to 3600 N"). Compression is bounded by the linear model's
    validity (:data:`COMPRESSION_MULTIPLE_OF_BLOCKED`), tension by the preload the stack runs
    under (:data:`TENSION_SHARE_OF_BLOCKED`): much lower, as the ceramic breaks in tension.

    Returns
    -------
    (float, float, float)
        Most compressive step, most tensile step, blocked force; N.
    """
    f_block = float(pzt.stiffness_n_per_m * pzt.quasi_static_x_m([0.0, pzt.voltage_max_v])[-1])
    return -COMPRESSION_MULTIPLE_OF_BLOCKED * f_block, TENSION_SHARE_OF_BLOCKED * f_block, f_block


def force_resolution_n(pzt, amp=None):
    """One ADC step of the charge amplifier read as force, N: k_p / T_em x C_int x LSB.

    A force F on the stack at a held terminal voltage moves its charge by T_em F / k_p (Fig. 3:
    x = F / k_p, q = T_em x); the amplifier reads q as V = q / C_int in steps of
    :func:`~.charge_amp.adc_lsb_v` (SN637 with the default amplifier: 0.0154 N).
    """
    from .charge_amp import adc_lsb_v
    amp = ChargeAmpParams() if amp is None else amp
    return float(pzt.stiffness_n_per_m / pzt.transducer_constant_n_per_v * amp.c_int_f
                 * adc_lsb_v(amp.adc_bits, amp.adc_range_v))


def check_step_force(pzt, step_n, *, name="step_n", where="the plant", amp=None):
    """Refuse a force step that is zero, not finite, outside :func:`step_force_range_n`, or so small that its
    target (:data:`FORCE_TARGET_STEP_FRACTION` of it) is finer than one ADC step of the force reading
    (:func:`force_resolution_n`: a 1 pN step was reported as a "+0 N step" missing its target by 1e12).

    Raises
    ------
    FlagRangeError
        Naming the parameter, the range and which side (compression or tension) it breaks.
    """
    lo, hi, f_block = step_force_range_n(pzt)
    f = float(step_n)
    span = (f"out of range [{lo:.4g}, {hi:.4g}] N and nonzero (compression negative) for the blocked force "
            f"{f_block:.4g} N of {where}")
    if not np.isfinite(f) or f == 0.0:
        raise FlagRangeError(f"{name} {f:g} N: {span}; e.g. -100N (compression)")
    if f < lo:
        raise FlagRangeError(f"{name} {f:g} N: {span}: a compression beyond {COMPRESSION_MULTIPLE_OF_BLOCKED:g}x the "
                             f"blocked force is outside the linear model; e.g. -100N")
    if f > hi:
        raise FlagRangeError(f"{name} {f:g} N: {span}: a tension beyond the 15 MPa preload share "
                             f"({hi:.4g} N) would break the brittle ceramic (seed 000); e.g. -100N (compression)")
    res = force_resolution_n(pzt, amp)
    if abs(f) * FORCE_TARGET_STEP_FRACTION < res:
        floor = res / FORCE_TARGET_STEP_FRACTION
        raise FlagRangeError(f"{name} {f:g} N: under {floor:.3g} N in size, where the study's target "
                             f"({100 * FORCE_TARGET_STEP_FRACTION:g} % of the step) is finer than one ADC step of the "
                             f"charge amplifier read as force ({res:.3g} N = k_p / T_em C_int LSB, {where}); "
                             f"e.g. -100N")


def check_force_table(path, runs):
    """Refuse a Table 1 the force study cannot score, before any simulation (:class:`DataFileError`).

    Every ``R_out`` run is read from its back EMF (leads open: V_t is the back EMF), so each needs a nonzero one;
    the held-out scores leave one run out of at least three (:func:`.table1.table1_held_out`); and the table's
    columns must give a T_em in the plant files' range (:func:`workbench.identify.transducer.identify_transducer`,
    whose diagnosis names a unit slip such as back_emf in mV labelled V).
    """
    from ..errors import DataFileError
    from ..identify.transducer import identify_transducer
    r_out = [r for r in runs if r.config == "R_out"]
    for r in r_out:
        if r.back_emf_v == 0.0:
            raise DataFileError(f"{path}, line {r.line} (back_emf): {r.serial} run {r.run} R_out has a back EMF of "
                                f"0 V; an R_out run (leads open) is read from its measured back EMF: write it, or "
                                f"delete the row")
    if len(r_out) < 3:
        raise DataFileError(f"{path}: {len(r_out)} R_out run(s); the force study reads each from its back EMF and "
                            f"scores it held out from the others: give at least 3 R_out rows")
    identify_transducer(path)           # the table's units, by T_em (raises naming the file and the column)


def run_force_study(plant_path, amp=None, seed=2, dt_s=1e-4, id_hold_s=700.0, step_n=-100.0,
                    bias_v=50.0, table_path=None, progress=None):
    """Force self-sensing on the plant: the simulated force step and the Table 1 Instron runs.

    1. The charge amplifier's drift compensation identified on a separate record at F_e = 0
       (:mod:`.identify`, as the displacement study does), and the force path's own
       compensation in coulombs from the same record (:mod:`.charge_drift`: alpha from the
       triangle reversals, leakage, bias and an absorption bank with alpha fixed).
    2. A force step of ``step_n`` at 30 s on the stack held at ``bias_v``, 60 s at 1 kHz; the force
       estimate per compensation stage, absolute and tared (:func:`force_step_errors`), and the
       elongation estimate beside x = k_q2x q (which ignores the force).
    3. Every Table 1 run simulated in its configuration with its peak force (the serials' plant
       files share the stack's parameters; only their gauges differ): estimated peak force
       (mean over the 2 s hold, the force path's stage, tared) against the applied one, and the model's
       displacement and back EMF beside the measured ones; and each ``R_out`` run read straight
       from its measured back EMF (q = 0: leads open after draining).
    4. The measured ``R out`` runs' peak forces held out (:func:`table1_held_out`), with each
       run's displacement from its gauge (``held_out``) and from the printed displacement
       column (``held_out_displacement_column``); among the forms, each run's back EMF read
       through the hysteresis inverse with its serial's earlier runs' state carried
       (:func:`~.instron_sequence.table1_sequence_estimates`; ``sequence``: per run the model's
       read and V_h's change, and the run-order change of V/F, model against Table 1).

    ``amp``: the charge channel (default :func:`~.charge_amp.charge_amp_params` of the plant: the assumed
    circuit with the plant file's ``[leakage]`` / ``[dielectric_absorption]`` when given).

    Returns the JSON-ready dict plus ``_arrays`` (records for the figure; drop before writing).
    """
    from ..identify.transducer import (DEFAULT_CALIBRATIONS_M_PER_V, DEFAULT_TABLE1_PATH, _read_table,
                                       table1_swap_decision)
    from .instron_sequence import TABLE1_SEQUENCE_DRAIN_S, table1_sequence_estimates
    from .table1 import table1_held_out
    from ..plant.files import load_plant
    from .charge_drift import identify_charge_drift
    from .identify import identify, simulate_identification
    from .run import STAGES, STAGE_TITLES

    def tick(stage):
        if progress:
            progress(stage)

    plant = load_plant(plant_path)
    amp = charge_amp_params(plant) if amp is None else amp
    pzt = plant.pzt
    check_step_force(pzt, step_n, where=str(plant_path), amp=amp)
    if table_path is None:
        table_path = DEFAULT_TABLE1_PATH
    runs, _, _ = _read_table(table_path, DEFAULT_CALIBRATIONS_M_PER_V)     # validated before any simulation
    check_force_table(table_path, runs)
    swapped = {(d["serial"], d["run"]) for d in table1_swap_decision(table_path) if d["swap"]}
    tick("identification record")
    idrec = simulate_identification(pzt, amp, hold_s=id_hold_s, seed=seed + 100, dt_s=dt_s)
    ident = identify(idrec, amp)
    drift = identify_charge_drift(idrec, ident)
    stages_all = (*STAGES, FORCE_STAGE)
    titles = {**STAGE_TITLES, FORCE_STAGE: FORCE_STAGE_TITLE}
    tick("force step")
    step_at = 30.0
    rec, f_true = simulate_force_step(pzt, amp, duration_s=60.0, step_at_s=step_at, bias_v=bias_v, force_n=step_n,
                                      dt_s=dt_s, seed=seed)
    errs = force_step_errors(rec, f_true, ident, pzt, step_at, stages_all, drift)
    stages = [{"name": n, "title": titles[n], **{k: v for k, v in errs[n].items()
                                                 if k not in ("estimate_n", "x_estimate_m")}} for n in stages_all]
    last = errs[FORCE_STAGE]
    # alpha's own uncertainty as force: at F_e = 0 the charge is alpha x, so a relative error s of alpha is a
    # charge error s q; read through the estimator over the second before the step
    pre = _window(rec.t_s, step_at - TARE_S, step_at)
    q_f = staged_charge(rec, ident, FORCE_STAGE, drift)
    rel = drift.alpha_sem_c_per_m / drift.alpha_c_per_m
    f_hi = estimate_force(rec.t_s, rec.v_in_v, q_f * (1.0 + rel), pzt).f_e_n
    f_lo = estimate_force(rec.t_s, rec.v_in_v, q_f, pzt).f_e_n
    alpha_offset = float(np.mean(np.abs(f_hi - f_lo)[pre]))
    step = {"force_n": step_n, "bias_v": bias_v, "step_at_s": step_at, "duration_s": float(rec.t_s[-1]),
            "sample_hz": 1.0 / float(rec.t_s[1] - rec.t_s[0]), "stages": stages,
            "target_fraction": FORCE_TARGET_STEP_FRACTION, "alpha_offset_1sigma_n": alpha_offset,
            "target_met_tared_1s_end": bool(last["tared_error_max_n"]["1s_end"] <= FORCE_TARGET_STEP_FRACTION * abs(step_n)),
            "target_met_tared_1_5s": bool(last["tared_error_max_n"]["1_5s"] <= FORCE_TARGET_STEP_FRACTION * abs(step_n)),
            "target_met_absolute_1s_end": bool(last["abs_error_max_n"]["1s_end"] <= FORCE_TARGET_STEP_FRACTION * abs(step_n))}
    tick("Instron runs")
    table = []
    for r in runs:
        srec, sf, (a, b) = simulate_instron_run(pzt, r.config, r.force_n, amp, dt_s=dt_s, seed=seed + r.run)
        est = estimate_force(srec.t_s, srec.v_in_v, staged_charge(srec, ident, FORCE_STAGE, drift), pzt)
        hold = _window(srec.t_s, a, b)
        tare = float(np.mean(est.f_e_n[_window(srec.t_s, 0.0, TARE_S)]))
        peak = float(np.mean(est.f_e_n[hold])) - tare
        row = {"serial": r.serial, "run": r.run, "config": r.config, "force_n": r.force_n,
               "displacement_m": r.displacement_m, "back_emf_v": r.back_emf_v,
               "suspected_swap": r.config == "R_out" and (r.serial, r.run) in swapped,
               "simulated": {"peak_force_estimate_n": peak, "error_fraction": (peak - r.force_n) / abs(r.force_n),
                             "model_displacement_m": float(np.mean(srec.x_m[hold])),
                             "model_back_emf_v": float(np.mean(srec.v_in_true_v[hold]))}}
        if r.config == "R_out":
            f_m, x_m = instron_from_table(pzt, r.back_emf_v)
            row["measured_back_emf"] = {"peak_force_estimate_n": f_m, "error_fraction": (f_m - r.force_n) / abs(r.force_n),
                                        "displacement_estimate_m": x_m}
        table.append(row)
    # seed 002 eq. 2.32: the force sensitivity identified with a known load instead of taken from the model;
    # each R_out run scored with the gain F/V_t of the other R_out runs (leave one out)
    r_out = [row for row in table if "measured_back_emf" in row]
    gains = np.array([row["force_n"] / row["back_emf_v"] for row in r_out])
    for i, row in enumerate(r_out):
        g = float(np.mean(np.delete(gains, i)))
        f_c = g * row["back_emf_v"]
        row["measured_back_emf"]["calibrated_leave_one_out"] = {
            "gain_n_per_v": g, "peak_force_estimate_n": f_c, "error_fraction": (f_c - row["force_n"]) / abs(row["force_n"])}
    loo_err = [abs(row["measured_back_emf"]["calibrated_leave_one_out"]["error_fraction"]) for row in r_out]
    # the repeat runs' own spread: the best single gain, chosen on all nine runs (in sample), still misses by
    # (r_max - r_min) / (r_max + r_min); a gain within 5 % on every run must lie in [0.95 r_max, 1.05 r_min]
    ratio = np.abs(gains)
    best_gain_err = float((ratio.max() - ratio.min()) / (ratio.max() + ratio.min()))
    window = [float((1.0 - FORCE_TARGET_PEAK_FRACTION) * ratio.max()),
              float((1.0 + FORCE_TARGET_PEAK_FRACTION) * ratio.min())]
    seq = table1_sequence_estimates(pzt, table_path)
    u = [d["estimate_n"] for d in seq]
    sequence = {"drain_s": TABLE1_SEQUENCE_DRAIN_S, "order": "per serial: R_in runs 1-3, then R_out runs 1-3 (assumed)",
                "runs": seq, "run_order_v_per_f_change_1_to_2": {}}
    for sn in dict.fromkeys(d["serial"] for d in seq):
        rows = [d for d in seq if d["serial"] == sn]
        if len(rows) >= 2:
            sequence["run_order_v_per_f_change_1_to_2"][sn] = {
                "measured": (rows[1]["back_emf_v"] / rows[1]["force_n"]) / (rows[0]["back_emf_v"] / rows[0]["force_n"]) - 1,
                "model": rows[1]["simulated_back_emf_per_force_v_per_n"] / rows[0]["simulated_back_emf_per_force_v_per_n"] - 1}
    sim_err = [abs(row["simulated"]["error_fraction"]) for row in table]
    meas_err = [abs(row["measured_back_emf"]["error_fraction"]) for row in table if "measured_back_emf" in row]
    instron = {"table": str(table_path), "runs": table,
               "simulated_max_error_fraction": float(max(sim_err)),
               "measured_r_out_max_error_fraction": float(max(meas_err)),
               "measured_r_out_mean_error_fraction": float(np.mean([row["measured_back_emf"]["error_fraction"]
                                                                    for row in table if "measured_back_emf" in row])),
               "target_fraction": FORCE_TARGET_PEAK_FRACTION,
               "target_met_simulated": bool(max(sim_err) <= FORCE_TARGET_PEAK_FRACTION),
               "target_met_measured_r_out": bool(max(meas_err) <= FORCE_TARGET_PEAK_FRACTION),
               "measured_r_out_calibrated_max_error_fraction": float(max(loo_err)),
               "measured_r_out_calibrated_rms_error_fraction": float(np.sqrt(np.mean(np.square(loo_err)))),
               "target_met_measured_r_out_calibrated": bool(max(loo_err) <= FORCE_TARGET_PEAK_FRACTION),
               "measured_r_out_best_single_gain_max_error_fraction": best_gain_err,
               "measured_r_out_gain_window_for_target_n_per_v": window,
               "force_per_back_emf_model_n_per_v": float(pzt.stiffness_n_per_m * pzt.c_pp_f / pzt.transducer_constant_n_per_v),
               # the back EMF read through the gauge strain, each run on gains its force never entered
               "held_out": table1_held_out(table_path, model_estimate_n=u),
               "held_out_displacement_column": table1_held_out(table_path, x_source="displacement", model_estimate_n=u),
               "sequence": sequence}
    data = {"plant": str(plant_path), "identified": ident.as_dict(), "charge_drift": drift.as_dict(),
            "force_step": step, "instron": instron,
            "_arrays": {"t_s": rec.t_s, "f_true_n": f_true, "x_m": rec.x_m,
                        "estimates_n": {n: errs[n]["estimate_n"] for n in stages_all},
                        "x_estimate_m": last["x_estimate_m"], "tare_n": last["tare_n"],
                        "x_from_charge_m": pzt.k_q2x_m_per_c * estimate_force(
                            rec.t_s, rec.v_in_v, staged_charge(rec, ident, FORCE_STAGE, drift), pzt).q_c}}
    return data
