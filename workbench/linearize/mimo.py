"""MIMO linear models of the three-stack mirror: stack voltages -> gauges and tip/tilt/piston (issue 15, item 3).

Each stack is linearized as in :mod:`workbench.linearize.small_signal` (C_h replaced by its
incremental slope c_h at an operating point; R, the creep branches, C_p, T_em kept) and closed
around the mirror's structure (:meth:`workbench.plant.mirror.FastSteeringMirror.structure`)
exactly as the coupled kernel does: for stack j with residual compliance r_j,
C_pp = C_p + T^2 r_j, and with x_dyn the elongation the structure's states give,

    V_h = (q - sum_k Q_k) / c_h,      V_p = (q - T x_dyn) / C_pp,
    R dq/dt = V - V_h - V_p,          dQ_k/dt = (C_k V_h - Q_k) / tau_k,
    F = T V_p  (the force on the structure),   x = x_dyn + r F  (the gauge's measurand).

Inputs: ``v0, v1, v2`` (V_pea per stack, V), then ``tau_x``, ``tau_y`` (N m), ``f_piston`` (N)
on the mirror. Outputs: ``x0..x2`` (m), ``tip_rad``, ``tilt_rad``, ``piston_m``, ``i0..i2``
(A), ``g0..g2`` (the gauge chains' firmware readings, V: K_g x with the chain's small-signal
gain at mid-stroke, :func:`workbench.linearize.sampled.gauge_gain_v_per_m`).

A small-signal member is a python-control ``StateSpace`` (:func:`mirror_small_signal`). A
describing-function member is an ``FRD`` (:func:`mirror_frd`): each stack's describing function,
simulated on its own spring, is turned into the complex admittance of its C_h (with creep),
y_h(jw) = q_h / V_h = 1 / (k_q2x M(jw) / P(jw) - jw R - 1/C_pp), which does not depend on the
mechanics, and put into the mirror's frequency response in its place.
"""

import itertools

import control
import numpy as np

from ..plant.mirror import AXES
from .pzt_describing import pzt_describing_function
from .sampled import gauge_gain_v_per_m
from .small_signal import BRANCHES, operating_point

__all__ = ["INPUTS", "OUTPUTS", "mirror_small_signal", "mirror_response", "mirror_frd", "stack_admittance",
           "df_admittance", "mirror_family", "structural_modes", "terminated_structure", "gauge_gains"]

INPUTS = ("v0", "v1", "v2", "tau_x", "tau_y", "f_piston")
OUTPUTS = ("x0", "x1", "x2") + AXES + ("i0", "i1", "i2", "g0", "g1", "g2")


def gauge_gains(fsm, x0_range_m=(0.0, 15e-6), tolerance_ohm=0.4):
    """Per stack (nominal, min, max) firmware V per m: mid-stroke, and the extremes over x0 and the imbalance corners."""
    out = []
    for pl in fsm.plants:
        g = pl.gauge
        gains = [gauge_gain_v_per_m(x0, g.replace(imbalance_ohm=c)) for c in
                 itertools.product((-tolerance_ohm, tolerance_ohm), repeat=4) for x0 in x0_range_m]
        out.append((gauge_gain_v_per_m(0.5 * sum(x0_range_m), g), min(gains), max(gains)))
    return np.array(out)


def _stack_consts(fsm, st):
    res = st.residual_compliance_m_per_n
    t = np.array([pz.transducer_constant_n_per_v for pz in fsm.stacks])
    cpp = np.array([pz.working_capacitance_f for pz in fsm.stacks]) + t * t * res
    r = np.array([pz.series_resistance_ohm for pz in fsm.stacks])
    return t, cpp, r


def mirror_small_signal(fsm, capacitances_f, gauge_v_per_m=None, name=None):
    """The mirror with each stack's C_h at the slope ``capacitances_f[j]`` as a MIMO StateSpace.

    Parameters
    ----------
    fsm : FastSteeringMirror
    capacitances_f : array_like, shape (3,)
        Incremental C_h of each stack, F (e.g. ``operating_point(...).capacitance_f``).
    gauge_v_per_m : array_like, shape (3,), optional
        Gauge chain gains, firmware V per m (default: nominal, :func:`gauge_gains`).

    Returns
    -------
    control.StateSpace
        Inputs :data:`INPUTS`, outputs :data:`OUTPUTS`. States: the structure's (eta, eta'),
        then q_j / C_pp,j per stack (V), then Q_k / C_k per creep branch (V).
    """
    st = fsm.structure()
    ns, n = 3, st.n_states
    ch = np.asarray(capacitances_f, float)
    if ch.shape != (ns,) or np.any(ch <= 0):
        raise ValueError(f"need three positive capacitances in F; got {capacitances_f}")
    kg = gauge_gains(fsm)[:, 0] if gauge_v_per_m is None else np.asarray(gauge_v_per_m, float)
    t, cpp, r = _stack_consts(fsm, st)
    creeps = [(np.zeros(0), np.zeros(0)) if pz.creep is None else
              (pz.creep.capacitances_f, pz.creep.time_constants_s) for pz in fsm.stacks]
    nc = sum(c.size for c, _ in creeps)
    nz = n + ns + nc
    cx = st.c[:ns]
    # F = Fz z
    fz = np.zeros((ns, nz))
    fz[:, :n] = -(t * t / cpp)[:, None] * cx
    fz[:, n:n + ns] = np.diag(t)
    a = np.zeros((nz, nz))
    b = np.zeros((nz, 6))
    a[:n] = st.b[:, :ns] @ fz
    a[:n, :n] += st.a
    b[:n, 3:] = st.b[:, ns:]
    k0 = n + ns
    for j, (cj, tau) in enumerate(creeps):
        sq = n + j
        vh = np.zeros(nz)
        vh[sq] = cpp[j] / ch[j]
        vh[k0:k0 + cj.size] = -cj / ch[j]
        vp = np.zeros(nz)
        vp[sq] = 1.0
        vp[:n] = -(t[j] / cpp[j]) * cx[j]
        a[sq] = (-vh - vp) / (r[j] * cpp[j])
        b[sq, j] = 1.0 / (r[j] * cpp[j])
        for k in range(cj.size):
            a[k0 + k] = vh / tau[k]
            a[k0 + k, k0 + k] -= 1.0 / tau[k]
        k0 += cj.size
    # outputs: structure outputs (C xi + D [F; w]), currents C_pp dsq/dt, gauges K_g x
    cs, ds = st.c, st.d
    c_st = np.zeros((cs.shape[0], nz))
    c_st[:, :n] = cs
    c_st += ds[:, :ns] @ fz
    d_st = np.zeros((cs.shape[0], 6))
    d_st[:, 3:] = ds[:, ns:]
    rows_c = [c_st[:ns], c_st[2 * ns:2 * ns + 3], cpp[:, None] * a[n:n + ns], kg[:, None] * c_st[:ns]]
    rows_d = [d_st[:ns], d_st[2 * ns:2 * ns + 3], cpp[:, None] * b[n:n + ns], kg[:, None] * d_st[:ns]]
    return control.ss(a, b, np.vstack(rows_c), np.vstack(rows_d), inputs=list(INPUTS), outputs=list(OUTPUTS),
                      name=name or "fsm_small_signal")


def stack_admittance(pzt, capacitance_f, s):
    """y_h(s) = q_h / V_h of C_h at slope ``capacitance_f`` with the creep branches across it, F."""
    y = np.full(np.shape(s), capacitance_f, complex)
    if pzt.creep is not None:
        for c, tau in zip(pzt.creep.capacitances_f, pzt.creep.time_constants_s):
            y = y + c / (1.0 + s * tau)
    return y


def df_admittance(pzt, p_m_per_v, freq_hz):
    """The C_h admittance y_h(jw) (F) that a stack's describing function ``p_m_per_v`` implies.

    ``p_m_per_v`` is V_pea -> x of the stack alone on its spring with its own modes (as
    :func:`~workbench.linearize.pzt_describing.pzt_describing_function` computes it):
    P = k_q2x M(s) / (s R + 1/y_h + 1/C_pp).
    """
    s = 2j * np.pi * np.asarray(freq_hz, float)
    m = np.ones_like(s)
    for md in pzt.modes:
        w, z = 2 * np.pi * md.freq_hz, md.damping_ratio
        m = m * w * w / (s * s + 2 * z * w * s + w * w)
    return 1.0 / (pzt.k_q2x_m_per_c * m / np.asarray(p_m_per_v) - s * pzt.series_resistance_ohm - 1.0 / pzt.c_pp_f)


def mirror_response(fsm, admittances_f, freq_hz, gauge_v_per_m=None):
    """Frequency response of the mirror with complex C_h admittances, shape (freqs, outputs, inputs).

    Parameters
    ----------
    admittances_f : array_like, shape (3, freqs)
        y_h,j(jw) of each stack, F (complex).
    """
    st = fsm.structure()
    ns, n = 3, st.n_states
    freq = np.atleast_1d(np.asarray(freq_hz, float))
    y_h = np.asarray(admittances_f, complex).reshape(ns, freq.size)
    kg = gauge_gains(fsm)[:, 0] if gauge_v_per_m is None else np.asarray(gauge_v_per_m, float)
    t, cpp, r = _stack_consts(fsm, st)
    cx = st.c[:ns]
    out = np.zeros((freq.size, len(OUTPUTS), 6), complex)
    for k, f in enumerate(freq):
        s = 2j * np.pi * f
        z = s * r + 1.0 / y_h[:, k] + 1.0 / cpp
        m = np.zeros((n + ns, n + ns), complex)
        m[:n, :n] = s * np.eye(n) - st.a + st.b[:, :ns] @ ((t * t / cpp)[:, None] * cx)
        m[:n, n:] = -st.b[:, :ns] * (t / cpp)[None, :]
        m[n:, :n] = -(t / cpp)[:, None] * cx
        m[n:, n:] = np.diag(z)
        rhs = np.zeros((n + ns, 6), complex)
        rhs[:n, 3:] = st.b[:, ns:]
        rhs[n:, :3] = np.eye(ns)
        sol = np.linalg.solve(m, rhs)
        xi, q = sol[:n], sol[n:]
        force = (t / cpp)[:, None] * q - (t * t / cpp)[:, None] * (cx @ xi)
        u = np.vstack([force, np.hstack([np.zeros((3, 3)), np.eye(3)])])
        y = st.c @ xi + st.d @ u
        out[k] = np.vstack([y[:ns], y[2 * ns:2 * ns + 3], s * q, kg[:, None] * y[:ns]])
    return out


def mirror_frd(fsm, admittances_f, freq_hz, gauge_v_per_m=None, name=None):
    """:func:`mirror_response` as a python-control FRD (inputs :data:`INPUTS`, outputs :data:`OUTPUTS`)."""
    resp = mirror_response(fsm, admittances_f, freq_hz, gauge_v_per_m)
    return control.FRD(np.moveaxis(resp, 0, -1), 2 * np.pi * np.asarray(freq_hz, float), inputs=list(INPUTS),
                       outputs=list(OUTPUTS), name=name or "fsm_frd")


def mirror_family(fsm, bias_v=50.0, v_range=(0.0, 100.0), branches=BRANCHES, df_amplitudes_v=(),
                  freq_hz=tuple(np.geomspace(1.0, 3000.0, 40)), progress=None):
    """The 3x3 family: small-signal branches and describing functions of each stack, gauge extremes.

    Members, by name: ``"<branch> at <bias> V, K_g <nom|min|max>"`` (StateSpace: all three stacks
    on that branch of their own loops, at their own slopes) and ``"DF A=<a> V, K_g <...>"``
    (FRD: each stack's describing function at amplitude a about the bias, frequencies where
    any stack slews, clips or is not periodic dropped; an amplitude with none left gives no member).
    """
    kg = gauge_gains(fsm)
    members = {}
    for branch in branches:
        caps = [operating_point(pz, bias_v, branch, v_range).capacitance_f for pz in fsm.stacks]
        for c, label in enumerate(("nom", "min", "max")):
            members[f"{branch} at {bias_v:g} V, K_g {label}"] = mirror_small_signal(
                fsm, caps, kg[:, c], name=f"fsm_{branch}_{label}")
    freq = np.asarray(freq_hz, float)
    for amp in df_amplitudes_v:
        ys, keep = [], np.ones(freq.size, bool)
        for j, pz in enumerate(fsm.stacks):
            fam = pzt_describing_function(pz, [amp], freq, (bias_v,), skip_above_saturation=True,
                                          progress=None if progress is None else
                                          (lambda d, t, j=j: progress(j * t + d, 3 * t)))
            keep &= fam.linear_ok[0, 0]
            ys.append(df_admittance(pz, fam.x_m_per_v[0, 0], freq))
        if not keep.any():
            continue                       # every frequency slews or clips: no linear member at this amplitude
        ys = np.array(ys)[:, keep]
        for c, label in enumerate(("nom", "min", "max")):
            members[f"DF A={amp:g} V, K_g {label}"] = mirror_frd(fsm, ys, freq[keep], kg[:, c],
                                                                 name=f"fsm_df_{amp:g}V_{label}".replace(".", "p"))
    return members


def terminated_structure(fsm, termination, capacitances_f=None):
    """The structure with every stack's leads open or shorted, as a StateSpace (closed form).

    ``"open"``: each stack adds the spring T^2/C_pp at its elongation; ``"shorted"``:
    T^2/(C_pp + c_h), the slope c_h of C_h in series. Inputs ``tau_x``, ``tau_y``,
    ``f_piston``; outputs :data:`~workbench.plant.mirror.AXES`.
    """
    st = fsm.structure()
    t, cpp, _ = _stack_consts(fsm, st)
    if termination not in ("open", "shorted"):
        raise ValueError(f"termination must be 'open' or 'shorted'; got {termination!r}")
    c = np.zeros(3) if termination == "open" else np.asarray(capacitances_f, float)
    k_e = t * t / (cpp + c)
    a = st.a - st.b[:, :3] @ (k_e[:, None] * st.c[:3])
    return control.ss(a, st.b[:, 3:], st.c[6:9], st.d[6:9, 3:], inputs=list(INPUTS[3:]), outputs=list(AXES),
                      name=f"fsm_{termination}")


def structural_modes(fsm, termination, capacitances_f=None):
    """Natural frequencies (Hz) and damping ratios of the mirror's modes with the stacks' leads terminated.

    ``"open"`` / ``"shorted"``: the poles of :func:`terminated_structure`; ``"amplifier"``: the
    complex poles of :func:`mirror_small_signal` (R and creep in the loop). Sorted by frequency.
    """
    if termination in ("open", "shorted"):
        poles = terminated_structure(fsm, termination, capacitances_f).poles()
    elif termination == "amplifier":
        poles = mirror_small_signal(fsm, capacitances_f).poles()
    else:
        raise ValueError(f"termination must be 'open', 'shorted' or 'amplifier'; got {termination!r}")
    poles = poles[poles.imag > 1e-6 * np.abs(poles)]
    wn = np.abs(poles)
    order = np.argsort(wn)
    return wn[order] / (2 * np.pi), -poles.real[order] / wn[order]
