"""The mirror's exported MIMO controller in closed loop with the nonlinear three-stack mirror (issue 15, item 5).

Per servo period T (the gauges' modulation period), as :mod:`workbench.verify.closed_loop` does
for one stack:

1. the three stacks and the mirror's structure run one period of the coupled kernel
   (:class:`~workbench.plant.coupled.CoupledSimulator`: R and the P-888.51 current limits,
   each stack's hysteresis and creep, the structure's five modes, an external torque/force)
   with the commands held;
2. each stack's gauge chain reads the period with the per-period equivalent model of
   :func:`workbench.plant.gauge.gauge_run_equivalent` (the bridge of eq. 26 with its imbalance a
   quarter and three quarters into the period, the ADC range, one Gaussian noise term, the trim
   and the servo DAC's quantization), its own serial's gauge;
3. the exported controller's fixed-point step (:meth:`workbench.export.mimo.MimoController.step_words`,
   bit for bit its C header) computes the three stack commands from the three readings;
4. those are applied at the next period (one sample of compute delay).

With an IFF-damped controller (:attr:`MimoController.iff`) each stack's charge bridge is read too:
the charge amplifier of :mod:`workbench.selfsense.charge_amp` stepped once per period
(:func:`~workbench.selfsense.charge_amp.charge_amp_step`: b_j = (C_R,j V_t,j - q_j - leakage through R_FP -
bias current - dielectric absorption) / C_int), its integrator reset when the loop starts (the stack has
sat at the operating point: absorption settled there), plus the amplifier's output noise, converted by its
ADC (:func:`~workbench.selfsense.charge_amp.adc_convert`, clipped to the range). C_R, C_int, the ADC's range
and bits and the noise are the controller JSON's ``iff.bridge`` (what the cascades were designed for); the
parasitics (R_FP, bias current, absorption) are :class:`~workbench.selfsense.charge_amp.ChargeAmpParams`'
defaults. C_R is the nominal incremental C_h, so the verified mirror's unequal C_h make the bridge's force
estimate imperfect. What this bridge leaves out of a bench: the C_h's drift with temperature and the cable.

The plant is stepped one period per call from Python (``CoupledSimulator.run`` keeps its state
between calls), about 0.1 ms of wall time per servo period: fine for the scenarios here (tens of
seconds of mirror time), not for sweeps.

Scenarios (:func:`mirror_scenarios`, every size from the plant): tip and tilt steps (1 % of the
tip range: linear), the 0.1 Hz tip triangle over 10-90 % of the tip range (tracking RMS and the
cross-coupling into tilt, in % of the range), a piston hold (creep), a large tip step (80 % of the
range: the current limits slew it; the coupling into tilt), a torque step about x whose
open-loop static tip deflection is 10 % of the range. The tip range is what the stacks reach
statically within their amplifier range about the operating point (every stack at the gauge's
trim centre, 7.5 um), on each stack's static gain on the mirror.
"""

import dataclasses
import inspect
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..design.mimo import stack_charge_amps
from ..design.step import rise_time, step_metrics
from ..export.mimo import iff_step, mimo_step
from ..plant.coupled import STACK_OUT_NAMES, coupled_run
from ..plant.gauge import TRIM_CENTER_M, _bridge, _quantize, demod_noise_sigma_v
from ..selfsense.charge_amp import (ChargeAmpParams, adc_convert, adc_lsb_v, charge_amp_arrays,
                                    charge_amp_step)

__all__ = ["MirrorLoop", "MirrorRun", "mirror_operating_point", "tip_range_rad", "mirror_scenarios",
           "verification_mirror", "run_mirror_verify", "check_pairing",
           "run_mirror_scenarios", "model_peak_current_a", "TARGETS"]

# the coupled kernel's arguments this module's compiled loop passes (plant/coupled.py is being sped up on
# another branch: if its signature changes, the loop falls back to one CoupledSimulator.run per period)
_KERNEL_ARGS = ("sc", "g_r", "g_w", "g_off", "c_cap", "c_dec", "c_off", "es", "zg", "qc", "ad", "b0", "b1", "hx", "hu",
                "cy", "dy", "xi", "xi_tmp", "g_prev", "g_now", "u_now", "y", "h", "v", "fe", "w", "n_sub", "decimate",
                "rec_s", "rec_y", "rec_xi")
# the kernel's per-stack record columns this module reads
_X, _Q, _I, _VP, _VT = (STACK_OUT_NAMES.index(k) for k in ("x_m", "q_c", "i_a", "v_p_v", "v_t_v"))
_FAST = tuple(inspect.signature(coupled_run.py_func).parameters) == _KERNEL_ARGS

TARGETS = {"tip_rms_percent": 0.1, "tilt_coupling_rms_percent": 0.1}   # issue 15's floors, % of the tip range (RMS)


@njit(cache=True)
def _gauges(x_prev, x, gp, r0, noise, out):
    """The per-period equivalent gauge chain of each stack (as plant.gauge._gauge_kernel_eq), firmware V."""
    for j in range(x.shape[0]):
        L, W, kgf, vm, amp, adc_fs = gp[j, 0], gp[j, 1], gp[j, 2], gp[j, 3], gp[j, 4], gp[j, 5]
        demod, trim_s, trim_b, dac_fs, dac_bits = gp[j, 6], gp[j, 7], gp[j, 8], gp[j, 9], gp[j, 10]
        dx = x[j] - x_prev[j]
        vp = min(max(amp * _bridge(x_prev[j] + 0.25 * dx, L, W, kgf, r0[j], vm), -adc_fs), adc_fs)
        vn = min(max(amp * _bridge(x_prev[j] + 0.75 * dx, L, W, kgf, r0[j], -vm), -adc_fs), adc_fs)
        d = 0.5 * demod * (vp - vn) + noise[j]
        out[j] = _quantize(trim_s * d + trim_b, dac_fs, dac_bits)


def _gauge_table(fsm):
    gp, r0, sig = [], [], []
    for pl in fsm.plants:
        g = pl.gauge
        gp.append([g.rest_length_m, g.rest_width_m, g.gauge_factor, g.modulation_v, g.amplifier_gain, g.adc_range_v,
                   g.demodulation_gain, g.trim_scale, g.trim_bias_v, g.dac_range_v, float(g.dac_bits)])
        r0.append([g.arm_nominal_ohm + d for d in g.imbalance_ohm])
        sig.append(demod_noise_sigma_v(g))
    return np.array(gp), np.array(r0), np.array(sig)


def mirror_operating_point(fsm, controller, x0_m=TRIM_CENTER_M):
    """(stack volts, piston axis volts) holding every stack at ``x0_m`` on its static gain on the mirror.

    The static gain p_j (m per V) is the decoupler's (the controller's axes -> stacks matrix is
    diag(1/p) K^-1 S): the piston command that puts every stack at x0 is u = a g x0 / s_piston.
    """
    k = fsm.kinematics
    q0 = k @ np.full(3, x0_m)
    u0 = q0 / controller.axis_scale
    return controller.axes_to_stacks @ u0, u0


def tip_range_rad(fsm, controller, x0_m=TRIM_CENTER_M):
    """Half-range of tip (rad) the stacks reach statically within their amplifier ranges about the operating point."""
    v0, _ = mirror_operating_point(fsm, controller, x0_m)
    col = controller.axes_to_stacks[:, 0] / controller.axis_scale[0]      # V per rad of tip
    lo, hi = controller.stack_limits_v[:, 0], controller.stack_limits_v[:, 1]
    eps = 1e-12 * np.abs(col).max()
    pos, neg = col > eps, col < -eps
    up = min(np.min((hi - v0)[pos] / col[pos], initial=np.inf), np.min((v0 - lo)[neg] / -col[neg], initial=np.inf))
    dn = min(np.min((v0 - lo)[pos] / col[pos], initial=np.inf), np.min((hi - v0)[neg] / -col[neg], initial=np.inf))
    return float(min(up, dn))


@dataclass(frozen=True)
class MirrorRun:
    """A closed-loop run (SI). Arrays (samples,) or (samples, 3).

    Attributes
    ----------
    t_s : ndarray
    ref : ndarray, (samples, 3)
        Tip, tilt (rad) and piston (m, about the operating point) references.
    tip_rad, tilt_rad, piston_m : ndarray
        The mirror's motion (piston about the operating point).
    x_m, i_a, v_cmd_v, v_t_v, reading_v, v_p_v, q_c : ndarray, (samples, 3)
        Per stack: elongation, mean current, command, terminal voltage, gauge reading (firmware V),
        the piezo voltage V_p (T V_p: the stack's force, the quantity the charge bridge estimates), charge (C).
    bridge_v : ndarray, (samples, 3) or None
        Per stack: the charge bridge's reading (V), with an IFF-damped controller.
    """

    t_s: np.ndarray
    ref: np.ndarray
    tip_rad: np.ndarray
    tilt_rad: np.ndarray
    piston_m: np.ndarray
    x_m: np.ndarray
    i_a: np.ndarray
    v_cmd_v: np.ndarray
    v_t_v: np.ndarray
    reading_v: np.ndarray
    v_p_v: np.ndarray = None
    q_c: np.ndarray = None
    bridge_v: np.ndarray = None


class MirrorLoop:
    """The mirror with the MIMO controller's fixed-point step in the loop (module docstring).

    Parameters
    ----------
    fsm : FastSteeringMirror
    controller : MimoController
    n_sub : int
        Plant sub-steps per servo period.
    noise : bool
        Gauge noise on.
    seed : int
    """

    def __init__(self, fsm, controller, n_sub=1, noise=True, seed=0):
        self.fsm, self.ctrl = fsm, controller
        dt = controller.dt_s
        periods = {pl.gauge.period_s for pl in fsm.plants}
        if any(abs(p - dt) > 1e-9 * dt for p in periods):
            raise ValueError(f"the controller runs at {1 / dt:g} Hz but the gauges' periods are {sorted(periods)} s")
        self.sim = fsm.simulator(dt, n_sub)
        self.gp, self.r0, self.sigma = _gauge_table(fsm)
        self.noise = bool(noise)
        self.rng = np.random.default_rng(seed)
        self.v0, self.u0 = mirror_operating_point(fsm, controller)
        self.q0 = fsm.kinematics @ np.full(3, TRIM_CENTER_M)
        self.bridge = _bridge_table(controller, stack_charge_amps(fsm))

    def start(self, settle_s=0.3):
        """Drive the stacks open loop to the operating point for ``settle_s``, then reset the controller there."""
        n = max(1, int(round(settle_s / self.ctrl.dt_s)))
        tr = self.sim.run(np.tile(self.v0, (n, 1)))
        self.x_prev = tr.x_m[-1].copy()
        self.bridge_state, self.bridge_zero = _bridge_reset(self.bridge, tr.q_c[-1], tr.v_t_v[-1])
        self.v_p_reset_v = tr.v_p_v[-1].copy()       # the stacks' V_p and q at the reset (the bridge reads changes)
        self.q_reset_c, self.v_t_reset_v = tr.q_c[-1].copy(), tr.v_t_v[-1].copy()
        self.state = self.ctrl.reset(self.u0)
        self.iff_state = self.ctrl.reset_iff(self.u0) if self.ctrl.iff is not None else _no_iff_state()
        self.v_cmd = self.v0.copy()

    def run(self, ref, external=None, progress=None, chunk=20000):
        """Closed loop over the rows of ``ref`` (tip rad, tilt rad, piston m about the operating point).

        ``external``: (samples, 3) torque about x, about y (N m), piston force (N). Compiled
        (:func:`_loop`) when the coupled kernel has the signature this module was written against,
        else one ``CoupledSimulator.run`` call per period (same arithmetic, ~10x slower).
        """
        ref = np.asarray(ref, float)
        n = ref.shape[0]
        w = np.zeros((n, 3)) if external is None else np.ascontiguousarray(np.asarray(external, float))
        rw = self.ctrl.reference_words(ref)
        out = np.empty((n, 7, 3))
        mir = np.empty((n, 3))
        noise = (self.rng.standard_normal((n, 3)) * self.sigma) if self.noise else np.zeros((n, 3))
        bnoise = (self.rng.standard_normal((n, 3)) * self.bridge[0][:, 1] if self.noise and self.ctrl.iff is not None
                  else np.zeros((n, 3)))
        ctrl = self.ctrl
        ifp = ctrl.iff_plan if ctrl.iff is not None else _NO_IFF_PLAN
        si, vmi, smi = self.iff_state
        bout = np.empty((n, 3))
        io = np.concatenate([self.x_prev, self.v_cmd])
        s, vm = self.state
        for k0 in range(0, n, chunk):
            k1 = min(n, k0 + chunk)
            kernel = self._kernel_args() if _FAST else None
            if kernel is not None:
                _loop(*kernel, w[k0:k1], rw[k0:k1], noise[k0:k1], self.gp, self.r0, np.int64(ctrl.gauge_frac_bits),
                      float(2.0 ** -ctrl.stack_frac_bits), io, s, vm, out[k0:k1], mir[k0:k1],
                      np.int64(ctrl.iff is not None), self.bridge_state, self.bridge_zero, *self.bridge, bnoise[k0:k1],
                      si, vmi, smi, bout[k0:k1], *ifp, *ctrl.plan)
            else:
                self._run_python(w[k0:k1], rw[k0:k1], noise[k0:k1], io, s, vm, out[k0:k1], mir[k0:k1],
                                 bnoise[k0:k1], bout[k0:k1])
            if progress is not None:
                progress(k1, n)
        self.x_prev, self.v_cmd = io[:3].copy(), io[3:].copy()
        t = (np.arange(n) + 1) * ctrl.dt_s
        names = ("x_m", "i_a", "v_cmd_v", "v_t_v", "reading_v", "v_p_v", "q_c")
        return MirrorRun(t_s=t, ref=ref, tip_rad=mir[:, 0] - self.q0[0], tilt_rad=mir[:, 1] - self.q0[1],
                         piston_m=mir[:, 2] - self.q0[2], **{nm: out[:, i] for i, nm in enumerate(names)},
                         bridge_v=bout if ctrl.iff is not None else None)

    def _kernel_args(self):
        """The simulator's buffers in coupled_run's order (None if the simulator no longer has them)."""
        sim = self.sim
        try:
            return (sim.sc, sim.g_r, sim.g_w, sim.g_off, sim.c_cap, sim.c_dec, sim.c_off, sim.es, sim.zg, sim.qc,
                    sim.ad, sim.b0, sim.b1, sim.hx, sim.hu, sim.cy, sim.dy, sim.xi, sim.xi_tmp, sim.g_prev,
                    sim.g_now, sim.u_now, sim.y, sim.h_s, sim.n_sub, np.zeros((2, 3, len(STACK_OUT_NAMES))),
                    np.zeros((1, sim.y.size)), np.zeros((0, sim.structure.n_states)))
        except AttributeError:
            return None

    def _run_python(self, w, rw, noise, io, s, vm, out, mir, bnoise, bout):
        ctrl, sim = self.ctrl, self.sim
        gscale, fv = 2.0 ** ctrl.gauge_frac_bits, 2.0 ** -ctrl.stack_frac_bits
        g = np.empty(3)
        vw = np.empty(3, np.int64)
        dv = np.zeros(3, np.int64)
        bsc = self.bridge[-1]
        sm = self.iff_state[2]
        for k in range(w.shape[0]):
            tr = sim.run(io[3:][None, :].copy(), external_n=w[k:k + 1])
            x = np.ascontiguousarray(tr.x_m[0])         # a strided row: C-contiguous, as _loop passes (one signature)
            _gauges(io[:3], x, self.gp, self.r0, noise[k], g)
            out[k] = x, tr.i_a[0], io[3:], tr.v_t_v[0], g, tr.v_p_v[0], tr.q_c[0]
            mir[k] = tr.y[0, 6:9]
            io[:3] = x
            if ctrl.iff is not None:
                b = np.empty(3)
                _bridge_reading(np.ascontiguousarray(tr.q_c[0]), np.ascontiguousarray(tr.v_t_v[0]), self.bridge_state, self.bridge_zero, *self.bridge[:-1],
                                bnoise[k], b)
                bout[k] = b
                iff_step(np.rint(b * bsc).astype(np.int64), self.iff_state[0], self.iff_state[1], dv, *ctrl.iff_plan)
            mimo_step(np.rint(g * gscale).astype(np.int64), rw[k], s, vm, vw, dv, sm, *ctrl.plan)
            io[3:] = vw * fv


def _no_iff_state():
    """Placeholders for the compiled loop's IFF state without IFF (cascade states, their models, stack models)."""
    return np.zeros((3, 1, 2), np.int64), np.zeros(3, np.int64), np.zeros(3, np.int64)
_NO_IFF_PLAN = (np.zeros((3, 1, 3), np.int64), np.zeros((3, 1, 2), np.int64), np.zeros((3, 1), np.int64),
                np.ones(3, np.int64), np.full(3, 30, np.int64), np.zeros((3, 5), np.int64), np.zeros(3, np.int64),
                np.ones(3, np.int64))


def _bridge_table(controller, amps=(ChargeAmpParams(),) * 3):
    """Each stack's charge amplifier as the loop steps it.

    Returns ``(adc, cp, k, a, b0, b1, scale)``: ``adc`` (3, 3) per stack [ADC range V, output noise V RMS,
    ADC LSB V]; ``cp`` (3, 5), ``k, a, b0, b1`` (3, branches):
    :func:`~workbench.selfsense.charge_amp.charge_amp_arrays` per stack (C_R, C_int, the ADC and the noise
    from the controller's ``iff.bridge``; R_FP, bias current and absorption from ``amps[j]``, stack j's channel,
    :func:`~workbench.design.mimo.stack_charge_amps`); absorption branches padded with k = 0 to the most any
    stack has; ``scale`` (3,): the bridge word scale 2^FI_j. Without IFF: ``amps``' numbers (C_R unused).
    """
    dt = controller.dt_s
    br = None if controller.iff is None else controller.iff["bridge"]
    adc, rows = np.zeros((3, 3)), []
    for j, amp in enumerate(amps):
        a_j = amp if br is None else dataclasses.replace(
            amp, c_ref_f=float(br["reference_capacitance_f"][j]), c_int_f=float(br["integrator_capacitance_f"]),
            adc_range_v=float(br["adc_range_v"]), adc_bits=int(br["adc_bits"]),
            out_noise_v_rms=float(br["out_noise_v_rms"]))
        adc[j] = a_j.adc_range_v, a_j.out_noise_v_rms, adc_lsb_v(a_j.adc_bits, a_j.adc_range_v)
        rows.append(charge_amp_arrays(a_j, dt))
    nb = max(r[1].size for r in rows)
    cp = np.array([r[0] for r in rows], float)
    k, a, b0, b1 = (np.array([np.pad(r[i], (0, nb - r[i].size)) for r in rows], float) for i in range(1, 5))
    if br is None:
        return adc, cp, k, a, b0, b1, np.ones(3)
    fi = np.array([controller.iff[key].fixed.input_frac_bits for key in ("stack0", "stack1", "stack2")], float)
    return adc, cp, k, a, b0, b1, 2.0 ** fi


def _bridge_reset(bridge, q0, vt0):
    """The charge amplifiers' states at their reset, the stacks long at (q0, V_t0), and their outputs there, V.

    The state is :func:`~workbench.selfsense.charge_amp.charge_amp_step`'s [t, V_in, leakage charge,
    absorption states]: absorption settled at V_t0; the reset output is subtracted from every reading."""
    _, cp, k, *_ = bridge
    state = np.zeros((3, 3 + k.shape[1]))
    state[:, 1] = vt0
    state[:, 3:] = np.asarray(vt0)[:, None]
    zero = -(np.asarray(q0) + k.sum(axis=1) * vt0 - cp[:, 3] * vt0) / cp[:, 4]
    return state, zero


@njit(cache=True)
def _bridge_reading(q, vt, state, zero, adc, cp, k, a, b0, b1, noise, out):
    """Each stack's charge-bridge ADC reading, V, into ``out``: one charge-amplifier step
    (:func:`~workbench.selfsense.charge_amp.charge_amp_step`) less its reset output, plus the noise,
    converted by :func:`~workbench.selfsense.charge_amp.adc_convert`."""
    for j in range(q.shape[0]):
        v = charge_amp_step(state[j], q[j], vt[j], cp[j], k[j], a[j], b0[j], b1[j]) - zero[j] + noise[j]
        out[j] = adc_convert(v, adc[j, 2], adc[j, 0])


@njit(cache=True)
def _loop(sc, g_r, g_w, g_off, c_cap, c_dec, c_off, es, zg, qc, ad, b0, b1, hx, hu, cy, dy, xi, xi_tmp, g_prev,
          g_now, u_now, y, h, n_sub, rec_s, rec_y, rec_xi, w, rw, noise, gp, r0, gf, fv, io, s, vm, out, mir,
          has_iff, bstate, bzero, badc, bcp, bk, ba, bb0, bb1, bsc, bnoise, si, vmi, smi, bout, iB, iA, iBSH, insec, ifrac, ilim,
          iin_lim, idsh, oq, osh, iq, ish, vsh, lw, B, A, BSH, nsec, frac, lim, in_lim, sw):
    """Periods of the closed loop (module docstring): the coupled kernel one period at a time, the gauges, the
    charge bridges and IFF (``has_iff``), the MIMO step."""
    ns = 3
    vrow = np.empty((1, ns))
    fe = np.zeros((1, ns))
    g = np.empty(ns)
    gw = np.empty(ns, np.int64)
    vw = np.empty(ns, np.int64)
    dv = np.zeros(ns, np.int64)
    bw = np.empty(ns, np.int64)
    qv = np.empty(ns)
    b = np.empty(ns)
    vt = np.empty(ns)
    gscale = 2.0 ** gf
    one = np.int64(1)         # decimate as int64, not the literal 1: coupled_run's one compiled signature
    for k in range(w.shape[0]):
        for j in range(ns):
            vrow[0, j] = io[3 + j]
        coupled_run(sc, g_r, g_w, g_off, c_cap, c_dec, c_off, es, zg, qc, ad, b0, b1, hx, hu, cy, dy, xi, xi_tmp,
                    g_prev, g_now, u_now, y, h, vrow, fe, w[k:k + 1], n_sub, one, rec_s, rec_y, rec_xi)
        x = rec_s[0, :, _X].copy()
        _gauges(io[:3], x, gp, r0, noise[k], g)
        for j in range(ns):
            out[k, 0, j] = x[j]
            out[k, 1, j] = rec_s[0, j, _I]
            out[k, 2, j] = io[3 + j]
            out[k, 3, j] = rec_s[0, j, _VT]
            out[k, 4, j] = g[j]
            out[k, 5, j] = rec_s[0, j, _VP]
            out[k, 6, j] = rec_s[0, j, _Q]
            io[j] = x[j]
            gw[j] = np.int64(np.rint(g[j] * gscale))
        for o in range(3):
            mir[k, o] = rec_y[0, 2 * ns + o]
        if has_iff:
            for j in range(ns):
                qv[j] = rec_s[0, j, _Q]
                vt[j] = rec_s[0, j, _VT]
            _bridge_reading(qv, vt, bstate, bzero, badc, bcp, bk, ba, bb0, bb1, bnoise[k], b)
            for j in range(ns):
                bout[k, j] = b[j]
                bw[j] = np.int64(np.rint(b[j] * bsc[j]))
            iff_step(bw, si, vmi, dv, iB, iA, iBSH, insec, ifrac, ilim, iin_lim, idsh)
        mimo_step(gw, rw[k], s, vm, vw, dv, smi, oq, osh, iq, ish, vsh, lw, B, A, BSH, nsec, frac, lim, in_lim, sw)
        for j in range(ns):
            io[3 + j] = vw[j] * fv


def _torque_for(fsm, tip_rad):
    """Torque about x (N m) whose open-loop static tip deflection is ``tip_rad`` (the structure's DC compliance)."""
    st = fsm.structure()
    ns = st.n_stacks
    # open leads aside, the stacks at rest hold their charge only through the amplifier: use the
    # mechanical compliance with the stacks' short-circuit stiffness (the structure's static map)
    dc = st.d - st.c @ np.linalg.solve(st.a, st.b)
    return float(tip_rad / dc[2 * ns, ns])


def mirror_scenarios(fsm, controller, hold_s=0.1, large_hold_s=2.5, triangle_periods=2, piston_hold_s=5.0):
    """The scenarios of the module docstring: name -> (ref (samples, 3), external (samples, 3) or None, info).

    Sizes: steps 1 % of the tip range (``hold_s`` before and after); the 0.1 Hz triangle over 10-90 %
    of the tip range (``triangle_periods`` periods, the last scored); a piston step of 25 % of the
    piston at the operating point, held ``piston_hold_s``; a tip step -40 % -> +40 % of the range
    (``large_hold_s`` per level: 110 V on stack 1, which the axis current-limit window slews at ~65 V/s); a
    torque step about x whose open-loop static tip deflection is 1 % of the range.
    """
    dt = controller.dt_s
    tr = tip_range_rad(fsm, controller)
    span = 2 * tr

    def steps(axis, size, hold):
        n = int(round(hold / dt))
        ref = np.zeros((2 * n, 3))
        ref[n:, axis] = size
        return ref
    out = {}
    n_h = int(round(hold_s / dt))
    out["tip_step"] = (steps(0, 0.01 * span, hold_s), None, {"axis": 0, "size": 0.01 * span, "t_step_s": hold_s})
    out["tilt_step"] = (steps(1, 0.01 * span, hold_s), None, {"axis": 1, "size": 0.01 * span, "t_step_s": hold_s})
    period = 10.0
    n = int(round(triangle_periods * period / dt))
    t = np.arange(n) * dt
    ref = np.zeros((n, 3))
    ref[:, 0] = 0.8 * tr * (1 - 4 * np.abs((t / period + 0.25) % 1.0 - 0.5))   # from the centre, rising
    out["tip_triangle"] = (ref, None, {"amplitude_rad": 0.8 * tr, "period_s": period,
                                       "scored_from_s": (triangle_periods - 1) * period})
    n = int(round(piston_hold_s / dt))
    pist = 0.25 * fsm.kinematics[2].sum() * TRIM_CENTER_M
    ref = np.zeros((n_h + n, 3))
    ref[n_h:, 2] = pist
    out["piston_hold"] = (ref, None, {"size_m": pist, "t_step_s": hold_s})
    n_l = int(round(large_hold_s / dt))
    ref = np.zeros((2 * n_l, 3))
    ref[:n_l, 0] = -0.4 * span
    ref[n_l:, 0] = 0.4 * span
    out["tip_large_step"] = (ref, None, {"axis": 0, "size": 0.8 * span, "t_step_s": large_hold_s,
                                         "y0": -0.4 * span})
    tau = _torque_for(fsm, 0.01 * span)
    ext = np.zeros((2 * n_h, 3))
    ext[n_h:, 0] = tau
    out["torque_step"] = (np.zeros((2 * n_h, 3)), ext, {"torque_n_m": tau, "open_loop_tip_rad": 0.01 * span,
                                                       "t_step_s": hold_s})
    return out


def verification_mirror(fsm, c_h_scales=(1.0, 0.85, 1.15), creep_plant=None):
    """The mirror as verified: each stack's C_h scaled (unequal hysteresis) and, optionally, creep branches.

    The serial files share one assumed C_h shape and carry no creep; ``c_h_scales`` (assumed,
    within PI's +/-20 % capacitance tolerance) makes the hysteresis unequal and ``creep_plant`` (a
    loaded Plant with ``[creep]``, e.g. ``plants/p888_51_sn637_creep.toml``, assumed for all three)
    gives every stack those creep branches.
    """
    out = fsm.with_capacitance_scales(c_h_scales)
    if creep_plant is not None:
        cr = creep_plant.pzt.creep
        out = dataclasses.replace(out, plants=tuple(dataclasses.replace(pl, pzt=dataclasses.replace(pl.pzt, creep=cr))
                                                    for pl in out.plants))
    return out


def _settling_why(tail, band, noise_rms, step):
    """Why a step has no 2 % settling time (the response is outside the band at the run's last sample), from the
    last quarter of the run (``tail``: response minus reference, rad) against the band's half-width ``band``, rad."""
    urad = 1e6
    mean = float(np.mean(tail))
    if abs(mean) > band:
        return (f"not settled: the last quarter's mean is {mean * urad:+.3g} urad from the reference, beyond the "
                f"2 % band (+/-{band * urad:.3g} urad)")
    outside = float(np.mean(np.abs(tail) > band))
    return (f"the last quarter's mean is inside the 2 % band (+/-{band * urad:.3g} urad of this {step * urad:.3g} urad "
            f"step) but {100 * outside:.2g} % of its samples are outside it: the gauge noise ({noise_rms * urad:.3g} "
            f"urad RMS before the step) keeps the reading out, not the loop (--no-noise measures the settling)")


def _metrics(name, run, info, span):
    t, dt = run.t_s, run.t_s[1] - run.t_s[0]
    urad = 1e6
    m = {"scenario": name, "tip_range_urad": span * urad}
    m["peak_current_ma"] = (np.abs(run.i_a).max(axis=0) * 1e3).tolist()
    m["stack_v_min_max"] = [[float(run.v_t_v[:, j].min()), float(run.v_t_v[:, j].max())] for j in range(3)]
    axes = (run.tip_rad, run.tilt_rad, run.piston_m)
    if name in ("tip_step", "tilt_step", "tip_large_step"):
        a = info["axis"]
        k0 = int(round(info["t_step_s"] / dt))
        y = axes[a][k0:]
        y0 = info.get("y0", 0.0)
        y1 = y0 + info["size"]
        base = float(np.mean(axes[a][k0 // 2:k0]))
        ov, ts = step_metrics(t[k0:] - t[k0 - 1], y - base + y0, y0, y1)
        noise_rms = float(np.std(axes[a][k0 // 2:k0]))
        m.update({"step_urad": info["size"] * urad, "noise_rms_urad": noise_rms * urad,
                  "overshoot_percent": ov, "settling_s": ts,
                  "rise_s": rise_time(t[k0:] - t[k0 - 1], y - base + y0, y0, y1),
                  "final_error_urad": float((np.mean(y[-len(y) // 4:]) - base + y0 - y1) * urad)})
        if not np.isfinite(ts):
            m["settling_s_why"] = _settling_why(y[-len(y) // 4:] - base + y0 - y1, 0.02 * abs(info["size"]),
                                                noise_rms, info["size"])
        other = 1 - a if a < 2 else 0
        cross = axes[other][k0:] - np.mean(axes[other][k0 // 2:k0])
        m["coupling_peak_urad"] = float(np.abs(cross).max() * urad)
        m["coupling_peak_percent"] = float(np.abs(cross).max() / span * 100)
        m["coupling_final_urad"] = float(np.mean(cross[-len(cross) // 4:]) * urad)
        if name == "tip_large_step":
            m["time_at_current_limit_ms"] = [float(np.sum(np.isclose(np.abs(run.i_a[k0:, j]), 2e-3, rtol=1e-3)
                                                        | (np.abs(run.i_a[k0:, j]) >= 2e-3)) * dt * 1e3)
                                             for j in range(3)]
    elif name == "tip_triangle":
        k0 = int(round(info["scored_from_s"] / dt))
        err = run.tip_rad[k0:] - run.ref[k0:, 0]
        tilt = run.tilt_rad[k0:] - run.ref[k0:, 1]
        m.update({"tip_rms_error_urad": float(np.sqrt(np.mean(err ** 2)) * urad),
                  "tip_rms_percent": float(np.sqrt(np.mean(err ** 2)) / span * 100),
                  "tip_peak_error_urad": float(np.abs(err).max() * urad),
                  "tilt_coupling_rms_urad": float(np.sqrt(np.mean(tilt ** 2)) * urad),
                  "tilt_coupling_peak_urad": float(np.abs(tilt).max() * urad),
                  "tilt_coupling_percent": float(np.abs(tilt).max() / span * 100),
                  "tilt_coupling_rms_percent": float(np.sqrt(np.mean(tilt ** 2)) / span * 100),
                  "amplitude_urad": info["amplitude_rad"] * urad})
    elif name == "piston_hold":
        k0 = int(round(info["t_step_s"] / dt))
        p = run.piston_m[k0:]
        k1, kw = int(round(0.5 / dt)), int(round(0.05 / dt))     # from 0.5 s after the step; 50 ms means
        late, v = p[k1:], run.v_cmd_v[k0 + k1:]
        m.update({"step_nm": float(info["size_m"] * 1e9),
                  "piston_drift_nm": float((np.mean(late[-kw:]) - np.mean(late[:kw])) * 1e9),
                  "piston_final_error_nm": float((np.mean(late[-kw:]) - info["size_m"]) * 1e9),
                  "stack_voltage_drift_v": [float(np.mean(v[-kw:, j]) - np.mean(v[:kw, j])) for j in range(3)],
                  "scored_s": float(t[-1] - t[k0 + k1])})
    elif name == "torque_step":
        k0 = int(round(info["t_step_s"] / dt))
        dev = run.tip_rad[k0:] - np.mean(run.tip_rad[k0 // 2:k0])
        m.update({"open_loop_tip_urad": info["open_loop_tip_rad"] * urad, "torque_n_m": info["torque_n_m"],
                  "peak_tip_urad": float(np.abs(dev).max() * urad),
                  "tip_after_20ms_urad": float(np.mean(dev[int(0.02 / dt):int(0.025 / dt)]) * urad),
                  "final_tip_urad": float(np.mean(dev[-len(dev) // 4:]) * urad),
                  "rejection_ratio": float(np.abs(dev).max() / info["open_loop_tip_rad"])})
    return m


def _open_loop_creep(fsm, controller, run, info):
    """The same piston step open loop: the stacks held at the voltages the loop reached 0.5 s after the step.

    Returns the open-loop piston drift over the same window (nm), beside the closed loop's.
    """
    dt = controller.dt_s
    k0 = int(round(info["t_step_s"] / dt))
    k1, kw = int(round(0.5 / dt)), int(round(0.05 / dt))
    v_hold = run.v_cmd_v[k0 + k1:k0 + k1 + kw].mean(axis=0)
    sim = fsm.simulator(dt)
    v0, _ = mirror_operating_point(fsm, controller)
    n = run.t_s.size
    v = np.empty((int(round(0.3 / dt)) + n, 3))
    v[:int(round(0.3 / dt)) + k0] = v0
    v[int(round(0.3 / dt)) + k0:] = v_hold
    tr = sim.run(v)
    p = tr.y[int(round(0.3 / dt)) + k0 + k1:, 8]
    return {"open_loop_piston_drift_nm": float((np.mean(p[-kw:]) - np.mean(p[:kw])) * 1e9)}


def model_peak_current_a(controller, v_cmd_v, r_ohm):
    """Largest |current| per stack (A, list of 3) the controller's own RC model predicts for the commands it sent.

    Each stack's command v is replayed through the model its window keeps, m += alpha (v - m) (the
    damped export's per-stack ``iff.stack_window`` alpha; else the axis windows' alpha, whose box every
    stack's command shares), from the first command; the predicted current is (v - m) / R. The window
    bounds it by min(I_source, I_sink); the simulated current differs where the stack's terminal voltage
    leaves the model (hysteresis, a disturbance's back-EMF)."""
    v = np.asarray(v_cmd_v, float)
    if controller.iff is not None:
        alpha = np.asarray(controller.iff["stack_window"]["alpha"], float)
    else:
        vm = controller.axes["tip"].voltage_model
        if vm is None:
            return [float("nan")] * v.shape[1]
        alpha = np.full(v.shape[1], float(vm[0]))
    m = v[0].copy()
    peak = np.zeros(v.shape[1])
    for k in range(v.shape[0]):
        d = v[k] - m
        peak = np.maximum(peak, np.abs(d))
        m += alpha * d
    return (peak / np.asarray(r_ohm, float)).tolist()


def run_mirror_scenarios(fsm, controller, names=None, noise=True, seed=0, progress=None, **sizes):
    """Run the scenarios (each from the operating point) and score them; returns (metrics list, runs dict, targets)."""
    sc = mirror_scenarios(fsm, controller, **sizes)
    names = list(sc) if names is None else list(names)
    span = 2 * tip_range_rad(fsm, controller)
    metrics, runs = [], {}
    for i, name in enumerate(names):
        ref, ext, info = sc[name]
        loop = MirrorLoop(fsm, controller, noise=noise, seed=seed + i)
        loop.start()
        r = loop.run(ref, ext, progress=None if progress is None else (lambda d, t, nm=name: progress(nm, d, t)))
        runs[name] = r
        m = _metrics(name, r, info, span)
        m["model_peak_current_ma"] = [1e3 * i for i in model_peak_current_a(
            controller, r.v_cmd_v, [pz.series_resistance_ohm for pz in fsm.stacks])]
        if name == "piston_hold":
            m.update(_open_loop_creep(fsm, controller, r, info))
        metrics.append(m)
    targets = {}
    tri = next((m for m in metrics if m["scenario"] == "tip_triangle"), None)
    if tri is not None:
        for key, lim in TARGETS.items():
            targets[key] = {"value": tri[key], "limit": lim, "unit": "% of the tip range", "met": tri[key] <= lim}
    return metrics, runs, targets


# ----------------------------------------------------------------------------- the command

def _clean(obj):
    """JSON-safe: NaN/inf -> None, numpy scalars -> Python."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def check_pairing(plant_path, controller_path):
    """Refuse a SISO controller on a mirror file and a MIMO controller on a single-stack plant (exit 2 in the CLI).

    Returns True when ``plant_path`` is a mirror file (schema ``workbench.fsm/1``).
    """
    import tomllib
    from pathlib import Path
    from ..controller import ControllerError
    from ..export.mimo import MIMO_SCHEMA, is_mimo_controller_file
    from ..plant.mirror import FSM_SCHEMA_VERSION
    try:
        schema = tomllib.loads(Path(plant_path).read_text(encoding="utf-8")).get("schema")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False            # the plant loader reports it, naming the file
    mirror = schema == FSM_SCHEMA_VERSION
    mimo = is_mimo_controller_file(controller_path)
    if mirror and not mimo and Path(controller_path).is_file():
        raise ControllerError(controller_path, "schema", f"is not a MIMO controller ({MIMO_SCHEMA!r}), but "
                                                         f"{plant_path} is a three-stack mirror ({FSM_SCHEMA_VERSION}): "
                                                         f"give the controller `workbench study "
                                                         f"studies/fsm_servo.toml` exports (controllers/NAME.json)")
    if mimo and not mirror:
        raise ControllerError(controller_path, "schema", f"is a MIMO mirror controller ({MIMO_SCHEMA!r}), but "
                                                         f"{plant_path} is a single-stack plant: give a mirror file "
                                                         f"(plants/fsm_*.toml) or a SISO controller")
    return mirror


# the creep file (next to the mirror file) whose branches every stack gets in the verification (assumed)
VERIFY_CREEP_FILE = "p888_51_sn637_creep.toml"


def run_mirror_verify(plant_path, controller_path, out_dir=None, c_h_scales=(1.0, 0.85, 1.15),
                      creep_file=VERIFY_CREEP_FILE, noise=True, seed=0, names=None, progress=None,
                      **sizes):
    """``workbench verify plants/fsm_*.toml --controller NAME.json``: scenarios, figures, report.

    Parameters
    ----------
    plant_path : path
        The mirror file (``workbench.fsm/1``).
    controller_path : path
        The exported :class:`~workbench.export.mimo.MimoController` JSON.
    c_h_scales : sequence of 3 float
        Each stack's C_h scale (unequal hysteresis; assumed, see :func:`verification_mirror`).
    creep_file : str or None
        A plant file with ``[creep]`` (relative to the mirror file) whose branches every stack gets
        (assumed); None: the serial files' (no creep).

    Returns
    -------
    dict
        ``metrics`` (per scenario), ``targets``, ``assumptions``, paths of ``report``/``json``/``figures``.
    """
    import hashlib
    from pathlib import Path
    from ..export.mimo import MimoController
    from ..plant.files import load_plant
    from ..plant.mirror import load_mirror
    fsm0 = load_mirror(plant_path)
    ctrl = MimoController.load(controller_path)
    ctrl.check_mirror(fsm0)                 # a damped export's stack windows and IFF corner are this mirror's
    creep_plant = None if creep_file is None else load_plant(Path(plant_path).parent / creep_file)
    fsm = verification_mirror(fsm0, c_h_scales, creep_plant)
    metrics, runs, targets = run_mirror_scenarios(fsm, ctrl, names=names, noise=noise, seed=seed,
                                                  progress=progress, **sizes)
    notes = []
    prov = ctrl.record.get("provenance") or {}
    sha = hashlib.sha256(Path(plant_path).read_bytes()).hexdigest()
    if prov.get("plant_sha256") and prov["plant_sha256"] != sha:
        notes.append(f"WARNING: the controller was exported for {prov.get('plant_file', 'another mirror file')} "
                     f"(SHA-256 {prov['plant_sha256'][:12]}...), this file is {sha[:12]}...")
    assumptions = notes + [f"stacks' C_h scaled by {list(c_h_scales)} (unequal hysteresis; the serial files share one "
                   f"assumed C_h shape)",
                   ("no creep (the serial files have none)" if creep_plant is None else
                    f"every stack has the creep branches of {creep_plant.source} (assumed)"),
                   f"gauge noise {'on' if noise else 'off'} (seed {seed}); amplifier current limits of each serial "
                   f"file; one sample of compute delay"]
    data = {"plant": str(plant_path), "controller": str(controller_path), "controller_name": ctrl.name,
            "tip_range_urad": 2e6 * tip_range_rad(fsm, ctrl), "assumptions": assumptions,
            "compiled_loop": bool(_FAST), "metrics": metrics, "targets": targets}
    if out_dir is not None:
        from ..report.html import write_html_report
        from ..report.mirror_figures import plot_mirror_run
        from ..report.output import write_json, write_text
        out = Path(out_dir)
        figs = {}
        for name, r in runs.items():
            figs[name] = plot_mirror_run(out / f"mirror_{name}.png", r, f"{name} ({ctrl.name} on {fsm0.name})")
        data["figures"] = {k: str(v) for k, v in figs.items()}
        data["json"] = str(write_json(out / "verify.json", _clean(data)))
        md = out / "report.md"
        write_text(md, mirror_verify_markdown(data, figs, md))
        data["report"] = str(md)
        data["report_html"] = str(write_html_report(md))
    return _clean(data)


def _fmt(v, f=".3g"):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    if isinstance(v, str):
        return v
    if isinstance(v, (list, tuple)):
        if v and isinstance(v[0], (list, tuple)):
            return " / ".join("..".join(_fmt(x, f) for x in row) for row in v)      # per stack: lo..hi
        return " / ".join(_fmt(x, f) for x in v)                                   # per stack
    return format(v, f)


def mirror_verify_markdown(data, figs, report_path):
    """The verification report (GitHub Markdown)."""
    from ..report.markdown import md_image, md_table
    lines = [f"# Mirror verification: {data['controller_name']} on {data['plant']}", "",
             f"Controller `{data['controller']}` (fixed-point MIMO step, bit for bit its C header) in closed loop "
             f"with the coupled three-stack mirror. Tip range (static, amplifier ranges about the operating point): "
             f"{data['tip_range_urad']:.0f} urad (+/-{data['tip_range_urad'] / 2:.0f}). Per-stack values: stack 1 / "
             f"2 / 3.", "", "Assumptions:", ""]
    lines += [f"- {a}" for a in data["assumptions"]]
    lines += ["", "## Targets (issue 15)", ""]
    rows = [[k, _fmt(t["value"]), f"{t['limit']:g} {t['unit']}", "met" if t["met"] else "**MISSED**"]
            for k, t in data["targets"].items()]
    lines += md_table(["target", "value", "limit", "result"], rows) if rows else ["(no triangle run)"]
    lines += ["", "## Scenarios", ""]
    for m in data["metrics"]:
        lines += [f"### {m['scenario']}", ""]
        rows = [[k, _fmt(v) + (f" ({m[k + '_why']})" if _fmt(v) == "n/a" and k + "_why" in m else "")]
                for k, v in m.items() if k != "scenario" and not k.endswith("_why")]
        lines += md_table(["metric", "value"], rows)
        if m["scenario"] in figs:
            lines += ["", md_image(m["scenario"], figs[m["scenario"]], report_path)]
        lines.append("")
    return "\n".join(lines) + "\n"
