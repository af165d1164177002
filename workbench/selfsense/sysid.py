"""The dynamic estimator's K D(s) and H(s) identified from a step record (seed 002 sec. 2.5.3), beside the model's.

Seed 002 applies a 20 V step, records the deflection (optical sensor) and V_out, and fits
K D(s) = delta / V_in and H(s) = V_out / V_in by ARMAX (eq. 2.49). Here the same record is
simulated for the stack (the creep plant, the charge amplifier of :mod:`.charge_amp`, an
interferometer-grade reference as :mod:`.identify` uses) and both transfer functions are
fitted in continuous time by nonlinear least squares (:func:`scipy.optimize.least_squares`),
with the parameter covariance sigma^2 (J^T J)^-1 at the optimum:

- K D(s) = g_0 + sum_j g_j / (tau_j s + 1): a direct term and n first-order relaxations. The
  relaxations are the creep operator (seed 002 eq. 2.38 identifies it separately as an LTI
  transfer function; here it is D(s)'s slow part: D(s) - D(inf)), K = g_0 + sum_j g_j.
- H(s) = H_r(s) - 1 / (R_FP C_int s), H_r(s) = h_0 + sum_j h_j / (tau_j s + 1). The leakage
  integrator and the bias ramp are the static estimator's, already identified (seed 002: "the
  different parameters related to the static self-sensing are known and only K, D(s) and H(s)
  have to be identified"); they are taken out of V_out before the fit, so the integrator of H
  and the c3/s of eq. 2.48 cancel exactly and G2 + G3 = c1 H_r + c2 - k_s / (tau s + 1).

Why not a discrete ARMAX: the stack's creep spans 0.1-1000 s, which at any sample rate that
sees the 0.1 s branch puts the poles within 1e-4 of z = 1, where an ARX/ARMAX polynomial fit is
ill-conditioned; the continuous relaxations keep the time constants as parameters with
uncertainties. The step record at 100 Hz cannot see the 70 kHz mode (nor could the seed's
sensor see far above its 630 Hz mode): the identified D(s) has none, which for firmware at
10 kHz is what :func:`~.estimator.band_limited` leaves of the model's D(s) anyway. (Python
system-identification packages with ARMAX exist on PyPI, e.g. SIPPY; adding one was not worth a
new dependency for a fit that this structure does with scipy.)

The number of relaxations (0 to 4, the seed's 4th order as the cap) is chosen by BIC on the
step record (:func:`identify_dynamics` says why not on a second step record).

The estimators are compared on a third record: a staircase, the stage-3 static estimate
(the stage-4 operator is nonlinear and stays out of E, as in :func:`~.run.loop_analysis`)
filtered by each E(s) discretized at the record's rate, against the true x.
"""

import itertools
from dataclasses import dataclass, replace

import control
import numpy as np
from numba import njit
from scipy.optimize import least_squares

from ..plant.simulator import PZTSimulator
from .charge_amp import ChargeAmpParams, cumulative_integral, measure, relax_foh
from .estimator import band_limited, charge_transfer, dynamic_estimator, dynamic_gains, output_transfer, ss_inverse
from .identify import REFERENCE_NOISE_M

__all__ = ["RelaxationFit", "fit_relaxations", "step_voltage", "simulate_step_record", "identify_dynamics",
           "IdentifiedDynamics", "model_dynamics", "identified_estimator", "apply_estimator", "compare_estimators",
           "MAX_ORDER", "run_dynamics_study", "DYNAMICS_TARGET_RATIO"]

MAX_ORDER = 4              # seed 002 eq. 2.38 / 2.49: 4th order


@dataclass(frozen=True)
class RelaxationFit:
    """y = g_0 u + sum_j g_j relax(u, tau_j): the fit, its 1-sigma uncertainties and residual RMS (units of y per u)."""

    direct: float
    gains: tuple
    time_constants_s: tuple
    sigma_direct: float
    sigma_gains: tuple
    sigma_time_constants_s: tuple
    residual_rms: float

    @property
    def dc_gain(self):
        return self.direct + float(np.sum(self.gains))

    @property
    def sigma_dc_gain(self):
        """1-sigma of g_0 + sum g_j (correlations included)."""
        return float(self._sigma_dc)

    def transfer(self):
        """g_0 + sum_j g_j / (tau_j s + 1) as a StateSpace (diagonal, one state per relaxation)."""
        n = len(self.gains)
        if n == 0:
            return control.ss([], [], [], [[self.direct]])
        tau = np.asarray(self.time_constants_s, float)
        return control.ss(np.diag(-1.0 / tau), (1.0 / tau)[:, None], np.asarray(self.gains, float)[None, :],
                          [[self.direct]])

    def predict(self, t_s, u):
        dt = float(t_s[1] - t_s[0])
        y = self.direct * np.asarray(u, float)
        for g, tau in zip(self.gains, self.time_constants_s):
            y = y + g * relax_foh(u, tau, dt)
        return y

    def as_dict(self):
        return {"direct": self.direct, "gains": list(self.gains), "time_constants_s": list(self.time_constants_s),
                "sigma_direct": self.sigma_direct, "sigma_gains": list(self.sigma_gains),
                "sigma_time_constants_s": list(self.sigma_time_constants_s), "dc_gain": self.dc_gain,
                "sigma_dc_gain": self.sigma_dc_gain, "residual_rms": self.residual_rms}


def fit_relaxations(t_s, u, y, order, tau_range_s=None):
    """Least-squares :class:`RelaxationFit` of ``order`` relaxations; time constants on a log scale.

    Start: the best set of time constants from a 10-point log grid over ``tau_range_s`` (default
    2 samples to 1/3 of the record; gains by linear least squares for each set); then all parameters jointly
    (:func:`scipy.optimize.least_squares`, Levenberg-Marquardt). Covariance sigma^2 (J^T J)^-1,
    sigma^2 = RSS / (N - p); the time constants' sigma by the delta method.
    """
    t = np.asarray(t_s, float)
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    dt = float(t[1] - t[0])
    lo, hi = tau_range_s if tau_range_s is not None else (2 * dt, (t[-1] - t[0]) / 3)
    n = int(order)
    scale_y = float(np.std(y)) or 1.0

    def columns(log_tau):
        return np.column_stack([u] + [relax_foh(u, float(np.exp(lt)), dt) for lt in log_tau])

    def linear(log_tau):
        x = columns(log_tau)
        return np.linalg.lstsq(x, y, rcond=None)[0]

    # start: the best combination of n time constants on a log grid (linear least squares for each)
    grid = np.log(np.geomspace(lo, hi, 10))
    cols = np.column_stack([relax_foh(u, float(np.exp(lt)), dt) for lt in grid])
    full = np.column_stack([u, cols])
    sc = np.linalg.norm(full, axis=0)
    sc[sc == 0] = 1.0
    gram, xty, yty = (full / sc).T @ (full / sc), (full / sc).T @ y, float(y @ y)
    best, lt0 = np.inf, np.zeros(0)
    for combo in itertools.combinations(range(1, grid.size + 1), n):
        idx = [0, *combo]
        b = xty[idx]
        try:
            rss = yty - float(b @ np.linalg.solve(gram[np.ix_(idx, idx)], b))   # normal equations per set
        except np.linalg.LinAlgError:
            continue
        if rss < best:
            best, lt0 = rss, grid[[c - 1 for c in combo]]
    g0 = linear(lt0)

    def resid(p):
        return (columns(p[n + 1:]) @ p[:n + 1] - y) / scale_y

    p0 = np.concatenate([g0, lt0])
    if n:
        sol = least_squares(resid, p0, method="lm", x_scale="jac")
        p, jac = sol.x, sol.jac * scale_y
    else:
        p, jac = g0, columns(lt0)
    r = columns(p[n + 1:]) @ p[:n + 1] - y
    dof = max(1, y.size - p.size)
    s2 = float(r @ r) / dof
    norm = np.linalg.norm(jac, axis=0)
    norm[norm == 0] = 1.0
    jn = jac / norm                                   # columns scaled: g (m/V) and log tau differ by 1e9
    cov = s2 * np.linalg.pinv(jn.T @ jn, rcond=1e-12) / np.outer(norm, norm)
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    tau = np.exp(p[n + 1:])
    order_idx = np.argsort(tau)
    fit = RelaxationFit(float(p[0]), tuple(float(g) for g in p[1:n + 1][order_idx]), tuple(float(x) for x in tau[order_idx]),
                        float(sig[0]), tuple(float(s) for s in sig[1:n + 1][order_idx]),
                        tuple(float(s) for s in (tau * sig[n + 1:])[order_idx]), float(np.sqrt(np.mean(r * r))))
    ones = np.zeros(p.size)
    ones[:n + 1] = 1.0
    object.__setattr__(fit, "_sigma_dc", float(np.sqrt(max(ones @ cov @ ones, 0.0))))
    return fit


# ---- records ------------------------------------------------------------------------------------

def step_voltage(dt_s, levels_v=(20.0,), hold_s=300.0, rest_s=1.0):
    """V_pea per sample: ``rest_s`` at 0 V, then each level held ``hold_s`` (the amplifier slews the edges)."""
    parts = [np.zeros(int(round(rest_s / dt_s)))] + [np.full(int(round(hold_s / dt_s)), float(v)) for v in levels_v]
    return np.concatenate(parts)


def simulate_step_record(pzt, amp=ChargeAmpParams(), levels_v=(20.0,), hold_s=300.0, sample_hz=100.0, dt_s=1e-4,
                         seed=21):
    """(ChargeRecord, interferometer reference x) of a step record from rest (seed 002: a 20 V step)."""
    dec = max(1, int(round(1.0 / (sample_hz * dt_s))))
    v = step_voltage(dt_s, levels_v, hold_s)
    n = (v.size // dec) * dec
    rec = measure(PZTSimulator(pzt, dt_s).run(v[:n], decimate=dec), amp, seed=seed, average=dec)
    x_ref = rec.x_m + REFERENCE_NOISE_M * np.random.default_rng(seed + 7919).standard_normal(rec.x_m.size)
    return rec, x_ref


def _h_output(rec, ident):
    """V_out with the identified leakage integral and bias ramp taken out: the H_r(s) V_in part, V."""
    return rec.v_out_v + (cumulative_integral(rec.t_s, rec.v_in_v / ident.r_leak_ohm)
                          + ident.i_bias_a * rec.t_s) / ident.c_int_f


@dataclass(frozen=True)
class IdentifiedDynamics:
    """K D(s) and H_r(s) fitted on a step record, the orders chosen on a held-out one."""

    kd: RelaxationFit
    h_r: RelaxationFit
    order_kd: int
    order_h: int
    bic: dict               # {"kd": [BIC per order 0..MAX_ORDER], "h": [...]}

    def creep_operator(self):
        """D(s)'s slow part K D(s) - g_0 (the relaxations), m/V, StateSpace."""
        return self.kd.transfer() - self.kd.direct

    def as_dict(self):
        return {"kd": self.kd.as_dict(), "h_r": self.h_r.as_dict(), "order_kd": self.order_kd, "order_h": self.order_h,
                "bic": self.bic}


def identify_dynamics(pzt, ident, amp=ChargeAmpParams(), dt_s=1e-4, hold_s=300.0, seed=21):
    """Fit K D(s) and H_r(s) on a 20 V step record (seed 002 sec. 2.5.3); each order by BIC, 0 to ``MAX_ORDER``.

    BIC = N ln(RSS / N) + p ln N with p = 2 n + 1. (The order cannot be chosen on a second
    step record at other levels: a linear model of a hysteretic stack predicts a record with a
    different amplitude or direction no better at any order, so the held-out error would pick the
    hysteresis, not the dynamics. The estimators are scored on a record neither fit saw:
    :func:`compare_estimators`.)
    """
    rec, x_ref = simulate_step_record(pzt, amp, (20.0,), hold_s, dt_s=dt_s, seed=seed)
    y_h = _h_output(rec, ident)
    n_s = rec.t_s.size
    chosen, bic = {}, {}
    for key, y in (("kd", x_ref), ("h", y_h)):
        fits = [fit_relaxations(rec.t_s, rec.v_in_v, y, n) for n in range(MAX_ORDER + 1)]
        crit = [n_s * np.log(f.residual_rms ** 2) + (2 * i + 1) * np.log(n_s) for i, f in enumerate(fits)]
        i = int(np.argmin(crit))
        chosen[key], bic[key] = (fits[i], i), [float(c) for c in crit]
    return IdentifiedDynamics(chosen["kd"][0], chosen["h"][0], chosen["kd"][1], chosen["h"][1], bic)


# ---- estimators -----------------------------------------------------------------------------------

def model_dynamics(pzt, ident, amp=ChargeAmpParams(), bias_v=50.0):
    """(K D(s), H(s), E(s)) from the model as :func:`~.run.loop_analysis` builds them.

    Small-signal at ``bias_v`` on the ascending branch: K D = x / V_t (creep and mode), q / V_t
    from the model without modes, H with the IDENTIFIED leakage and absorption, the stage-3
    estimator; E minimal (the leakage integrators cancel).
    """
    from ..linearize.small_signal import operating_point, small_signal_model
    c_h = operating_point(pzt, bias_v, "ascending").capacitance_f
    pz0 = replace(pzt, series_resistance_ohm=0.0)
    kd = small_signal_model(pz0, c_h)
    qv = small_signal_model(replace(pz0, modes=()), c_h) * (1.0 / pzt.k_q2x_m_per_c)
    p3 = ident.stage("dielectric_absorption")
    h = output_transfer(charge_transfer(qv, p3.r_leak_ohm, (p3.da_gain_f,), (p3.da_time_constant_s,)),
                        amp.c_int_f, amp.c_ref_f)
    g1, g2, g3 = dynamic_gains(kd, h, p3)
    e = control.minreal(dynamic_estimator(g1, g2, g3), tol=1e-9, verbose=False)
    return kd, h, e


def identified_estimator(dyn, ident):
    """E(s) = K D(s) / (c1 H_r(s) + c2 - k_s / (tau s + 1)) from identified dynamics (eqs. 2.44, 2.48)."""
    p3 = ident.stage("dielectric_absorption")
    c1, c2 = -p3.c_int_f / p3.alpha_c_per_m, p3.c_ref_f / p3.alpha_c_per_m
    g23 = dyn.h_r.transfer() * c1 + c2
    if p3.da_gain_f:
        tau = p3.da_time_constant_s
        g23 = g23 - control.ss([[-1.0 / tau]], [[1.0 / tau]], [[p3.da_gain_f / p3.alpha_c_per_m]], [[0.0]])
    return ss_inverse(g23) * dyn.kd.transfer()


def apply_estimator(e, t_s, delta_s):
    """delta_d = E delta_s on uniform samples from rest: E band-limited to the rate, Tustin, zero initial state
    (the discrete state-space recursion, compiled)."""
    dt = float(t_s[1] - t_s[0])
    ed = control.c2d(band_limited(e, dt), dt, "tustin")
    a, b, c, d = (np.ascontiguousarray(np.asarray(m_, float)) for m_ in (ed.A, ed.B, ed.C, ed.D))
    return _ss_run(a, b[:, 0].copy(), c[0].copy(), float(d[0, 0]), np.ascontiguousarray(delta_s, dtype=float))


@njit(cache=True)
def _ss_run(a, b, c, d, u):
    """y_k = c x_k + d u_k, x_{k+1} = a x_k + b u_k from x_0 = 0 (SISO)."""
    x = np.zeros(a.shape[0])
    y = np.empty(u.shape[0])
    for k in range(u.shape[0]):
        y[k] = c @ x + d * u[k]
        x = a @ x + b * u[k]
    return y


def compare_estimators(pzt, ident, dyn, amp=ChargeAmpParams(), duration_s=300.0, sample_hz=1000.0, dt_s=1e-4,
                       seed=31, bias_v=50.0):
    """Errors of the dynamic estimate from the model's E and from the identified E on a staircase record, m."""
    from .estimator import static_estimate
    from .run import staircase_voltage
    dec = max(1, int(round(1.0 / (sample_hz * dt_s))))
    v = staircase_voltage(duration_s, dt_s, seed)
    n = (v.size // dec) * dec
    rec = measure(PZTSimulator(pzt, dt_s).run(v[:n], decimate=dec), amp, seed=seed, average=dec)
    d_s = static_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, ident.stage("dielectric_absorption"))
    _, _, e_model = model_dynamics(pzt, ident, amp, bias_v)
    e_id = identified_estimator(dyn, ident)
    out = {"t_s": rec.t_s, "x_m": rec.x_m, "static_m": d_s}
    for key, e in (("model", e_model), ("identified", e_id)):
        out[key + "_m"] = apply_estimator(e, rec.t_s, d_s)
    stats = {}
    for key in ("static", "model", "identified"):
        err = out[key + "_m"] - rec.x_m
        stats[key] = {"error_rms_m": float(np.sqrt(np.mean(err * err))), "error_pp_m": float(np.ptp(err))}
    stats["ratio_rms_identified_over_model"] = stats["identified"]["error_rms_m"] / stats["model"]["error_rms_m"]
    stats["ratio_pp_identified_over_model"] = stats["identified"]["error_pp_m"] / stats["model"]["error_pp_m"]
    stats["e_identified_poles_hz"] = sorted(float(abs(p) / (2 * np.pi)) for p in e_id.poles())
    stats["e_identified_stable"] = bool(np.all(np.real(e_id.poles()) < 0))
    return stats, out, {"model": e_model, "identified": e_id}


DYNAMICS_TARGET_RATIO = 1.2   # issue 16: the estimator from the identified D/H within 1.2x the model-derived one's error


def run_dynamics_study(plant_path, amp=None, seed=2, dt_s=1e-4, id_hold_s=700.0, step_hold_s=300.0,
                       eval_s=300.0, progress=None):
    """Identify the static estimator (:mod:`.identify`), then K D(s) and H(s) from a step record, and compare the
    dynamic estimators from the model and from the identified dynamics on a staircase record neither saw.

    ``amp``: the charge channel (default :func:`~.charge_amp.charge_amp_params` of the plant: the assumed
    circuit with the plant file's ``[leakage]`` / ``[dielectric_absorption]`` when given).

    Returns the JSON-ready dict with ``_arrays`` (responses and records for the figure).
    """
    from ..plant.files import load_plant
    from .charge_amp import charge_amp_params
    from .identify import identify, simulate_identification

    def tick(stage):
        if progress:
            progress(stage)

    plant = load_plant(plant_path)
    amp = charge_amp_params(plant) if amp is None else amp
    pzt = plant.pzt
    tick("identification record")
    ident = identify(simulate_identification(pzt, amp, hold_s=id_hold_s, seed=seed + 100, dt_s=dt_s), amp)
    tick("step record")
    dyn = identify_dynamics(pzt, ident, amp, dt_s=dt_s, hold_s=step_hold_s, seed=seed + 20)
    tick("evaluation record")
    stats, rec, systems = compare_estimators(pzt, ident, dyn, amp, duration_s=eval_s, dt_s=dt_s, seed=seed + 30)
    kd_m, h_m, _ = model_dynamics(pzt, ident, amp)
    h_id = dyn.h_r.transfer() - control.ss([[0.0]], [[1.0]], [[1.0 / (ident.r_leak_ohm * ident.c_int_f)]], [[0.0]])
    f = np.geomspace(1e-4, 50.0, 300)
    w = 2j * np.pi * f
    resp = {"freq_hz": f}
    for key, sys in (("kd_model", kd_m), ("kd_identified", dyn.kd.transfer()), ("h_model", h_m), ("h_identified", h_id),
                     ("e_model", systems["model"]), ("e_identified", systems["identified"])):
        resp[key] = np.asarray(sys(w)).ravel()
    creep_model = control.minreal(control.ss(kd_m), tol=1e-9, verbose=False)
    data = {"plant": str(plant_path), "static_identified": ident.as_dict(), "dynamics": dyn.as_dict(),
            "model": {"k_m_per_v": float(np.real(kd_m.dcgain())),
                      "kd_poles_hz": sorted(float(abs(p) / (2 * np.pi)) for p in creep_model.poles())},
            "comparison": {k: v for k, v in stats.items()}, "evaluation_duration_s": float(rec["t_s"][-1]),
            "target_ratio": DYNAMICS_TARGET_RATIO,
            "target_met": bool(stats["ratio_rms_identified_over_model"] <= DYNAMICS_TARGET_RATIO),
            "_arrays": {"responses": resp, "records": rec}}
    return data
