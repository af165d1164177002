"""Identification of the self-sensing parameters (seed 002 sec. 2.3.2) on a simulated record.

The identification record (:func:`identification_voltage`) is separate from any evaluation
record. Its reference displacement is an interferometer (the seed's SIOS SP-120: 0.5 nm
RMS), here the simulation's x plus that noise. The procedure, in the order it runs:

1. **alpha** (eq. 2.10): a 0 -> 20 V step ramped at 100 V/s (the seed ramps at 20 V/s to keep
   its 630 Hz cantilever from ringing; the stack's mode is 70 kHz, and a faster ramp lets
   less absorption charge in before the "immediately after" reading). alpha is the charge
   change over the step divided by the displacement change, both averaged over 50 ms
   before and 50 ms after (leakage and bias move the charge by < 1e-4 of that in the step).
2. **i_bias** (sec. 2.3.2.1): the drift of the charge during the first 100 s at V_in = 0.
3. **R_FP** (sec. 2.3.2.2): the drift of the non-displacement charge Q - alpha delta_ref over
   the second half of each long hold at constant V_in (700 s at 20, 50 and 80 V, 300 s at
   30 V after the triangles), minus i_bias, regressed on V_in through the origin (the seed's
   Fig. 2.10 line). Subtracting alpha delta_ref removes the stack's own creep (its charge
   tracks its displacement), so the seed's 1000-2000 s wait is not needed for that; the
   absorption's tail is taken out in a second pass (step 5).
4. **Dielectric absorption k_s, tau** (eq. 2.11): delta_s - delta_ref with alpha, i_bias and
   R_FP compensated, fitted by k_s / (tau s + 1) V_in over the record after the first step
   (tau by a bounded search on log tau, k_s by least squares at each tau).
5. Steps 3-4 once more with the fitted absorption taken out of the hold drifts.
6. **Stage 4** (eqs. 2.28-2.29, 2.36-2.38 as they apply): the residual delta_s - delta_ref
   of the fully compensated static estimate, fitted by least squares (small ridge) with a
   bank of first-order relaxations of V_in (tau 0.3 s to 300 s: an LTI creep operator) and
   plays of V_in (a PI operator; the triangles at the seed's 20 V/s, 0-100 V, exercise it).
   The structure is chosen on held-out data, as the seed checks its PI operator on
   smaller triangles: both are fitted without the 0-50 V triangles and the last hold, and
   the PI part is kept only if it lowers the residual there by 10 %. In the seed 000 stack
   the charge has no hysteresis against displacement, so the PI part has nothing physical
   to find; with the default circuit it is dropped (the run reports both RMS values).
"""

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize_scalar

from ..plant.simulator import PZTSimulator
from .charge_amp import ChargeAmpParams, measure, relax_foh
from .estimator import EstimatorParams, ResidualCorrection, charge_estimate, static_estimate

__all__ = ["IdentificationRecord", "Identified", "identification_voltage", "simulate_identification",
           "identify", "fit_absorption", "fit_residual_correction", "REFERENCE_NOISE_M"]

REFERENCE_NOISE_M = 0.5e-9        # seed 002 sec. 2.3.3: SIOS SP-120 interferometer, 0.5 nm RMS
CREEP_TAUS_S = (0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0)
N_PLAYS = 6
PI_KEEP_RATIO = 0.9    # the PI part stays only if it cuts the held-out residual by 10 %


def _segment(level_from, level_to, rate_v_per_s, hold_s, dt):
    """A ramp from level_from to level_to at rate, then a hold: samples at dt."""
    n_ramp = max(1, int(round(abs(level_to - level_from) / rate_v_per_s / dt)))
    ramp = np.linspace(level_from, level_to, n_ramp + 1)[1:]
    return np.concatenate([ramp, np.full(int(round(hold_s / dt)), float(level_to))])


def identification_voltage(dt_s, hold_s=700.0, zero_s=100.0):
    """(v, holds, step_index, validation): the identification profile at dt_s.

    0 V for ``zero_s``; 20, 50, 80 V each held ``hold_s`` (first step ramped at 100 V/s, the
    others at 20 V/s); three 0-100 V triangles at 20 V/s (the seed's PI identification
    signal, Fig. 2.28); two 0-50 V triangles (the seed's smaller-amplitude check of the
    identified operator); 30 V held ``hold_s``/2 (at least 100 s). ``holds`` lists
    (start_s, end_s) of every constant-voltage hold; ``step_index`` the sample where the
    alpha step starts; ``validation`` the (start_s, end_s) of the small triangles and the
    last hold, held out when the stage-4 structure is chosen.
    """
    dt = float(dt_s)
    parts = [np.zeros(int(round(zero_s / dt)))]
    step_index = parts[0].size
    holds = [(0.0, zero_s)]
    t = zero_s
    level = 0.0
    for k, target in enumerate((20.0, 50.0, 80.0)):
        seg = _segment(level, target, 100.0 if k == 0 else 20.0, hold_s, dt)
        ramp_s = (seg.size - int(round(hold_s / dt))) * dt
        holds.append((t + ramp_s, t + seg.size * dt))
        parts.append(seg)
        t += seg.size * dt
        level = target
    tri = [_segment(level, 0.0, 20.0, 0.0, dt)]
    for _ in range(3):
        tri += [_segment(0.0, 100.0, 20.0, 0.0, dt), _segment(100.0, 0.0, 20.0, 0.0, dt)]
    tri = np.concatenate(tri)
    parts.append(tri)
    t += tri.size * dt
    small = np.concatenate([_segment(0.0, 50.0, 20.0, 0.0, dt), _segment(50.0, 0.0, 20.0, 0.0, dt)] * 2)
    validation = (t, None)
    parts.append(small)
    t += small.size * dt
    last = _segment(0.0, 30.0, 20.0, max(100.0, hold_s / 2), dt)
    ramp_s = (last.size - int(round(max(100.0, hold_s / 2) / dt))) * dt
    holds.append((t + ramp_s, t + last.size * dt))
    parts.append(last)
    validation = (validation[0], t + last.size * dt)
    return np.concatenate(parts), holds, step_index, validation


@dataclass(frozen=True)
class IdentificationRecord:
    """A simulated identification record: the charge-amplifier record and the reference."""

    record: object          # ChargeRecord
    x_ref_m: np.ndarray
    holds: list
    step_index: int
    validation: tuple


def simulate_identification(pzt, amp=ChargeAmpParams(), hold_s=700.0, sample_hz=100.0, seed=1, dt_s=1e-4):
    """Run the PZT model at dt_s over :func:`identification_voltage`, keep ``sample_hz``."""
    dec = int(round(1.0 / (sample_hz * dt_s)))
    v, holds, step_index, validation = identification_voltage(dt_s, hold_s)
    n = (v.size // dec) * dec
    traj = PZTSimulator(pzt, dt_s).run(v[:n], decimate=dec)
    rec = measure(traj, amp, seed=seed, average=dec)
    rng = np.random.default_rng(seed + 7919)
    x_ref = rec.x_m + REFERENCE_NOISE_M * rng.standard_normal(rec.x_m.size)
    return IdentificationRecord(rec, x_ref, holds, step_index // dec, validation)


@dataclass(frozen=True)
class Identified:
    """Identified estimator parameters per stage, with the evidence."""

    alpha_c_per_m: float
    i_bias_a: float
    r_leak_ohm: float
    da_gain_f: float
    da_time_constant_s: float
    correction: ResidualCorrection
    c_int_f: float
    c_ref_f: float
    hold_drifts: list = field(default_factory=list)   # (V, drift A) per hold
    stage4_validation_rms_m: dict = field(default_factory=dict)   # {"creep": .., "creep_and_pi": ..}
    stage4_pi_kept: bool = False

    def stage(self, name):
        """EstimatorParams for a stage: uncompensated, leakage_bias, dielectric_absorption, hysteresis_creep."""
        p = EstimatorParams(self.alpha_c_per_m, self.c_int_f, self.c_ref_f)
        if name == "uncompensated":
            return p
        p = replace(p, r_leak_ohm=self.r_leak_ohm, i_bias_a=self.i_bias_a)
        if name == "leakage_bias":
            return p
        p = replace(p, da_gain_f=self.da_gain_f, da_time_constant_s=self.da_time_constant_s)
        if name == "dielectric_absorption":
            return p
        if name == "hysteresis_creep":
            return replace(p, correction=self.correction)
        raise ValueError(f"unknown stage {name!r}")

    def as_dict(self):
        c = self.correction
        return {"alpha_c_per_m": self.alpha_c_per_m, "i_bias_a": self.i_bias_a, "r_leak_ohm": self.r_leak_ohm,
                "da_gain_f": self.da_gain_f, "da_time_constant_s": self.da_time_constant_s,
                "hold_drifts": [{"v_in_v": v, "drift_a": d} for v, d in self.hold_drifts],
                "stage4_validation_rms_m": dict(self.stage4_validation_rms_m),
                "stage4_pi_kept": self.stage4_pi_kept,
                "correction": {"creep_time_constants_s": list(c.creep_time_constants_s),
                               "creep_gains_m_per_v": list(c.creep_gains_m_per_v),
                               "thresholds_v": list(c.thresholds_v),
                               "play_weights_m_per_v": list(c.play_weights_m_per_v)}}


def _slope(t, y):
    tc = t - t.mean()
    return float(np.dot(tc, y - y.mean()) / np.dot(tc, tc))


def _window(t, a, b):
    return (t >= a) & (t <= b)


def fit_absorption(t, v, residual_c, mask, tau_bounds=(0.1, 1000.0)):
    """(k_s F, tau s): residual charge ~ k_s relax(V_in, tau) (eq. 2.11 in charge units)."""
    dt = float(t[1] - t[0])
    y = residual_c[mask]

    def solve(log_tau):
        col = relax_foh(v, float(np.exp(log_tau)), dt)[mask]
        k = float(np.dot(col, y) / np.dot(col, col))
        r = y - k * col
        return float(np.dot(r, r)), k

    grid = np.linspace(np.log(tau_bounds[0]), np.log(tau_bounds[1]), 25)
    costs = [solve(g)[0] for g in grid]
    i = int(np.argmin(costs))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    best = minimize_scalar(lambda g: solve(g)[0], bounds=(lo, hi), method="bounded",
                           options={"xatol": 1e-4})
    return solve(best.x)[1], float(np.exp(best.x))


def fit_residual_correction(t, v, residual_m, mask, taus_s=CREEP_TAUS_S, n_plays=N_PLAYS, ridge=1e-6):
    """Stage-4 operator fitted to ``residual_m`` (see the module notes): a ResidualCorrection."""
    vmax = float(np.max(np.abs(v)))
    thresholds = tuple(vmax * np.arange(n_plays) / (2 * n_plays))   # 0 .. just under half the span
    proto = ResidualCorrection(tuple(taus_s), (0.0,) * len(taus_s), thresholds, (0.0,) * n_plays)
    cc, pc = proto.columns(t, v)
    X = np.hstack([cc, pc])[mask]
    y = residual_m[mask]
    scale = np.sqrt(np.mean(X * X, axis=0))
    scale[scale == 0] = 1.0
    Xs = X / scale
    gram = Xs.T @ Xs
    gram += ridge * np.trace(gram) / gram.shape[0] * np.eye(gram.shape[0])
    beta = np.linalg.solve(gram, Xs.T @ y) / scale
    k = len(taus_s)
    return ResidualCorrection(tuple(taus_s), tuple(float(b) for b in beta[:k]), thresholds,
                              tuple(float(b) for b in beta[k:]))


def identify(idrec, amp=ChargeAmpParams()):
    """Identified parameters from an :class:`IdentificationRecord` (the procedure of the module notes).

    ``amp`` supplies only the circuit's known component values (C_int, C_R); the
    leakage, bias and absorption it also holds are not read.
    """
    rec, x_ref = idrec.record, idrec.x_ref_m
    t, v = rec.t_s, rec.v_in_v
    dt = float(t[1] - t[0])
    base = EstimatorParams(1.0, amp.c_int_f, amp.c_ref_f)
    q_raw = charge_estimate(t, v, rec.v_out_v, base)           # C_R V_in - C_int V_out

    # 1. alpha from the ramped step (eq. 2.10)
    k0 = idrec.step_index
    w = max(1, int(round(0.05 / dt)))
    ramp_end = k0 + int(np.argmax(v[k0:] >= 0.999 * v[k0 + int(round(2.0 / dt))]))
    before, after = slice(k0 - w, k0), slice(ramp_end + 1, ramp_end + 1 + w)
    alpha = float((q_raw[after].mean() - q_raw[before].mean()) / (x_ref[after].mean() - x_ref[before].mean()))

    # 2. bias current from the zero-volt hold
    t0, t1 = idrec.holds[0]
    zero = _window(t, t0 + 0.1 * (t1 - t0), t1 - 1.0)
    i_bias = _slope(t[zero], q_raw[zero])

    da_k, da_tau = 0.0, 1.0
    r_leak = float("inf")
    drifts = []
    for _ in range(2):
        # 3. leakage from the holds' drift of the non-displacement charge
        q_nd = q_raw - alpha * x_ref - i_bias * t
        if da_k:
            q_nd = q_nd - da_k * relax_foh(v, da_tau, dt)
        drifts = []
        for a, b in idrec.holds[1:]:
            m = _window(t, 0.5 * (a + b), b)
            drifts.append((float(np.mean(v[m])), _slope(t[m], q_nd[m])))
        vv, dd = np.array(drifts).T
        inv_r = float(np.dot(vv, dd) / np.dot(vv, vv))
        r_leak = 1.0 / inv_r if inv_r > 0 else float("inf")
        # 4. absorption from the leakage-compensated residual (eq. 2.11)
        p = EstimatorParams(alpha, amp.c_int_f, amp.c_ref_f, r_leak_ohm=r_leak, i_bias_a=i_bias)
        resid_c = charge_estimate(t, v, rec.v_out_v, p) - alpha * x_ref
        after_step = t > t[k0]
        da_k, da_tau = fit_absorption(t, v, resid_c, after_step)

    # 6. stage 4 on what remains
    p3 = EstimatorParams(alpha, amp.c_int_f, amp.c_ref_f, r_leak_ohm=r_leak, i_bias_a=i_bias,
                         da_gain_f=da_k, da_time_constant_s=da_tau)
    resid_m = static_estimate(t, v, rec.v_out_v, p3) - x_ref
    val = _window(t, *idrec.validation)
    rms = {}
    for name, n_plays in (("creep", 0), ("creep_and_pi", N_PLAYS)):
        c = fit_residual_correction(t, v, resid_m, ~val, n_plays=n_plays)
        r = (resid_m - c(t, v))[val]
        rms[name] = float(np.sqrt(np.mean(r * r)))
    keep_pi = rms["creep_and_pi"] < PI_KEEP_RATIO * rms["creep"]
    corr = fit_residual_correction(t, v, resid_m, np.ones(t.size, bool), n_plays=N_PLAYS if keep_pi else 0)
    return Identified(alpha, i_bias, r_leak, da_k, da_tau, corr, amp.c_int_f, amp.c_ref_f,
                      [(float(a), float(b)) for a, b in drifts], rms, bool(keep_pi))
