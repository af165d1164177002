"""Compiled time stepping of the PZT (numba).

One call to :func:`pzt_step` advances the plant by one sub-step with the inputs
held; :func:`pzt_run` loops over a whole input record. Both take two packed float
vectors, the model ``m`` (parameters, operator tables, creep and mode matrices) and
the state ``st``, so later stages (closed-loop verification) can call ``pzt_step``
from their own compiled loops. Packing matters: numba reference-counts every array
handed to a function, and with a dozen separate arrays that bookkeeping cost more
than the physics. ``pzt_step.py_func`` is the same code run by the interpreter,
which the benchmark hands to python-control. A long loop reads the model's scalars
and offsets once with :func:`plant_params` and calls :func:`pzt_advance` (the same
step, returning its outputs instead of writing an array), as :func:`pzt_run` and the
closed loop do; :func:`pzt_step` is that pair in one call.

:class:`workbench.plant.simulator.PZTSimulator` builds ``m`` and ``st``; the index
constants below are their layout.
"""

import math

import numpy as np
from numba import njit

__all__ = ["pzt_step", "pzt_advance", "plant_params", "pzt_run", "OUT_NAMES", "pack_model", "pack_state"]

# scalars at the head of m (reciprocals too: divisions otherwise dominate a step)
(R, I_SRC, I_SNK, V_MIN, V_MAX, T_EM, K_P, C_PP, DT, QUASI_STATIC,
 INV_R, INV_I_SRC, INV_I_SNK, INV_K_P, INV_C_PP, INV_DT) = range(16)
# table layout in m: sizes and offsets (stored as floats)
(N_G, O_RG, O_WG, N_Q, O_RQ, O_WQ, N_C, O_CC, O_CDEC, N_M, O_AD, O_BD, O_CD, O_DD,
 OS_ZG, OS_ZQ, OS_QC, OS_XM) = range(16, 34)
M_HEAD = 34
# scalars at the head of st: hysteretic charge, G output (= V_h + q_h/C_pp), creep charge,
# and the incremental capacitances (1 / G's slope) for rising and falling q_h at the current state
S_QH, S_U, S_QC, S_GUP, S_GDN = range(5)
S_HEAD = 5
OUT_NAMES = ("x_m", "q_c", "i_a", "v_h_v", "v_p_v", "v_t_v")
N_OUT = len(OUT_NAMES)


def pack_model(scalars, G, Q, creep_c, creep_decay, Ad, Bd, Cd, Dd):
    """Build the model vector from the scalar parameters and the tables."""
    nm = Cd.size
    tables = [G.thresholds, G.weights, Q.thresholds, Q.weights, creep_c, creep_decay,
              Ad.ravel(), Bd, Cd, Dd]
    offs = np.cumsum([M_HEAD] + [t.size for t in tables])
    m = np.zeros(offs[-1])
    m[:16] = scalars
    for t, o in zip(tables, offs[:-1]):
        m[o:o + t.size] = t
    s_offs = np.cumsum([S_HEAD, G.size, Q.size, creep_c.size, 2 * nm + 1])
    m[N_G:OS_XM + 1] = [G.size, offs[0], offs[1], Q.size, offs[2], offs[3], creep_c.size, offs[4],
                         offs[5], nm, offs[6], offs[7], offs[8], offs[9],
                         s_offs[0], s_offs[1], s_offs[2], s_offs[3]]
    return m, int(s_offs[4])


def pack_state(m, size, qh, u, cap_up, cap_dn, zG, zQ, qc, xm):
    """Build the state vector (xm: modal state, scratch copy, previous x_qs)."""
    st = np.zeros(size)
    st[S_QH], st[S_U], st[S_GUP], st[S_GDN] = qh, u, cap_up, cap_dn
    st[S_QC] = np.sum(qc)
    for off, arr in ((OS_ZG, zG), (OS_ZQ, zQ), (OS_QC, qc), (OS_XM, xm)):
        o = int(m[off])
        st[o:o + arr.size] = arr
    return st


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "reassoc"})
def _pi_update(m, o_r, o_w, st, o_z, n, v):
    """Advance a packed PI operator to input v; return its output."""
    y = 0.0
    for i in range(n):
        ri = m[o_r + i]
        zi = st[o_z + i]
        if zi < v - ri:
            zi = v - ri
        elif zi > v + ri:
            zi = v + ri
        st[o_z + i] = zi
        y += m[o_w + i] * zi
    return y


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "reassoc"})
def _pi_update_slopes(m, o_r, o_w, st, o_z, n, v):
    """_pi_update fused with the incremental capacitances for the next step (one pass)."""
    y = 0.0
    up = 0.0
    dn = 0.0
    for i in range(n):
        ri = m[o_r + i]
        wi = m[o_w + i]
        lo = v - ri
        hi = v + ri
        zi = st[o_z + i]
        if zi < lo:
            zi = lo
        elif zi > hi:
            zi = hi
        if zi <= lo:
            up += wi
        if zi >= hi:
            dn += wi
        st[o_z + i] = zi
        y += wi * zi
    st[S_GUP] = 1.0 / up
    st[S_GDN] = 1.0 / dn
    return y


@njit(cache=True, error_model="numpy", inline="always")
def plant_params(m):
    """The scalars and table offsets at the head of ``m``, read once (a tuple for :func:`pzt_advance`).

    A loop that calls :func:`pzt_advance` with these keeps them in registers: read from
    ``m`` at every step they must be reloaded after each store to ``st`` (the compiler
    cannot tell the two arrays apart), and the offsets converted from float again.
    """
    return (m[R], m[I_SRC], m[I_SNK], m[V_MIN], m[V_MAX], m[T_EM], m[DT], m[QUASI_STATIC] > 0.5,
            m[INV_I_SRC], m[INV_I_SNK], m[INV_K_P], m[INV_C_PP], m[INV_DT],
            int(m[N_G]), int(m[O_RG]), int(m[O_WG]), int(m[OS_ZG]),
            int(m[N_Q]), int(m[O_RQ]), int(m[O_WQ]), int(m[OS_ZQ]),
            int(m[N_C]), int(m[O_CC]), int(m[O_CDEC]), int(m[OS_QC]),
            int(m[N_M]), int(m[OS_XM]), int(m[O_AD]), int(m[O_BD]), int(m[O_CD]), m[int(m[O_DD])])


@njit(cache=True, error_model="numpy", inline="always")
def pzt_advance(p, m, st, v_cmd, f_e):
    """Advance the PZT by one sub-step; return (x, q, i, V_h, V_p).

    ``p`` is :func:`plant_params` of ``m``. Electrical part (dynamic form): with the creep
    charge and force held, R dq_h/dt = u* - G[q_h]. On the local slope of G this is an RC
    relaxation; while |u* - u|/R exceeds the current limit the charge moves at the limit
    (exactly), then relaxes exponentially for the rest of the step. The slope is the one
    at the start of the step; G's slope only falls as more plays engage, so the step never
    overshoots u* and creates no spurious reversal.
    """
    (r, i_src, i_snk, v_min, v_max, t_em, dt, quasi_static, inv_i_src, inv_i_snk, inv_kp, inv_cpp, inv_dt,
     n_g, o_rg, o_wg, o_zg, n_q, o_rq, o_wq, o_zq, n_c, o_cc, o_cdec, o_qc, n, o_x, o_a, o_b, o_cd, d_d) = p
    v = min(max(v_cmd, v_min), v_max)
    qh = st[S_QH]
    u = st[S_U]
    f_term = t_em * f_e * inv_kp              # T_em F_e / k_p, C
    u_target = v - (st[S_QC] - f_term) * inv_cpp
    if quasi_static:
        qh_new = _pi_update(m, o_rq, o_wq, st, o_zq, n_q, u_target)
        u_new = u_target
    else:
        du = u_target - u
        if du != 0.0:
            if du > 0:
                d = 1.0
                cap = st[S_GUP]
                i_lim = i_src
                inv_i = inv_i_src
            else:
                d = -1.0
                cap = st[S_GDN]
                i_lim = i_snk
                inv_i = inv_i_snk
            gap = abs(du)
            t_left = dt
            dq = 0.0
            if gap > r * i_lim:
                # current-limited: charge moves at the limit until the gap is R i_lim
                t_sat = (gap - r * i_lim) * inv_i * cap
                if t_sat >= dt:
                    dq = d * i_lim * dt
                    t_left = 0.0
                else:
                    dq = d * i_lim * t_sat
                    t_left = dt - t_sat
                    gap = r * i_lim
            if t_left > 0.0:
                # RC relaxation on the local slope: tau = R C
                dq += d * gap * cap * (1.0 - math.exp(-t_left / (r * cap)))
            qh_new = qh + dq
            u_new = _pi_update_slopes(m, o_rg, o_wg, st, o_zg, n_g, qh_new)
        else:
            qh_new = qh
            u_new = u
    v_h = u_new - qh_new * inv_cpp
    # creep branches relax toward C_j V_h (tau_j >> dt: V_h held over the step)
    qc_tot = 0.0
    for j in range(n_c):
        target = m[o_cc + j] * v_h
        qj = target + (st[o_qc + j] - target) * m[o_cdec + j]
        st[o_qc + j] = qj
        qc_tot += qj
    q_old = qh + st[S_QC]
    q = qh_new + qc_tot
    st[S_QH] = qh_new
    st[S_U] = u_new
    st[S_QC] = qc_tot
    v_p = (q - f_term) * inv_cpp
    x_qs = (f_e + t_em * v_p) * inv_kp
    # modes: the quasi-static displacement drives them, taken as linear over the step
    # (first-order hold: no delay, unlike a zero-order hold of the end value). st holds
    # the modal state, a scratch copy and the previous x_qs, so the step allocates nothing.
    if n > 0:
        x_before = st[o_x + 2 * n]
        for a in range(n):
            acc = m[o_b + a] * x_before + m[o_b + n + a] * x_qs
            for b in range(n):
                acc += m[o_a + a * n + b] * st[o_x + b]
            st[o_x + n + a] = acc
        x = d_d * x_qs
        for a in range(n):
            st[o_x + a] = st[o_x + n + a]
            x += m[o_cd + a] * st[o_x + a]
        st[o_x + 2 * n] = x_qs
    else:
        x = x_qs
    return x, q, (q - q_old) * inv_dt, v_h, v_p


@njit(cache=True, error_model="numpy", inline="always")
def pzt_step(m, st, v_cmd, f_e, out):
    """Advance the PZT by one sub-step; write x, q, i, V_h, V_p, V_t into ``out`` (:func:`pzt_advance`)."""
    x, q, i, v_h, v_p = pzt_advance(plant_params(m), m, st, v_cmd, f_e)
    out[0] = x
    out[1] = q
    out[2] = i
    out[3] = v_h
    out[4] = v_p
    out[5] = v_h + v_p


@njit(cache=True, error_model="numpy")
def pzt_run(m, st, v, f, n_sub, decimate, rec):
    """Run the plant over the samples ``v`` (V) and ``f`` (N), each held for n_sub sub-steps.

    Every ``decimate``-th sample's outputs go into ``rec`` (rows: samples, columns:
    OUT_NAMES); the current column holds the mean current over the sample so that
    the recorded charge is the integral of the recorded current. Returns the peak
    source and sink currents seen at sub-step resolution.
    """
    p = plant_params(m)
    i_max = 0.0
    i_min = 0.0
    row = 0
    count = 0
    inv_sample = m[INV_DT] / n_sub
    x = q = i = v_h = v_p = 0.0
    for k in range(v.shape[0]):
        q0 = st[S_QH] + st[S_QC]
        vk = v[k]
        fk = f[k]
        for _ in range(n_sub):
            x, q, i, v_h, v_p = pzt_advance(p, m, st, vk, fk)
            if i > i_max:
                i_max = i
            if i < i_min:
                i_min = i
        count += 1
        if count == decimate:
            count = 0
            rec[row, 0] = x
            rec[row, 1] = q
            rec[row, 2] = (q - q0) * inv_sample
            rec[row, 3] = v_h
            rec[row, 4] = v_p
            rec[row, 5] = v_h + v_p
            row += 1
    return i_max, i_min
