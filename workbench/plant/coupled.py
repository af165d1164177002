"""Stacks and their structure stepped together (numba): Fig. 3 coupled both ways.

Each stack is the electrical side of seed 000 Fig. 3 (R with the amplifier's current limits,
the C_h plays, optional creep branches across C_h, C_p, T_em); the mechanical side M(.) is a
:class:`~workbench.plant.structure.Structure`. Both directions of Fig. 3 are in the loop:
the stack force T_em V_p (+ F_e) drives the structure, and the structure's motion sets the
elongation x in eq. 9, V_p = (q - T_em x)/C_p, and so the current (the piezo effect).

Elimination per stack j (r_j its residual compliance, x_dyn,j the elongation the structure's
states give): x_j = x_dyn,j + r_j (F_e,j + T_em V_p,j), so

    V_p = (q - T_em (x_dyn + r F_e)) / C_pp,   C_pp = C_p + T_em^2 r,

and the terminal voltage is V_t = G[q_h] + (q_c - T_em (x_dyn + r F_e)) / C_pp with
G = C_h^{-1} + I/C_pp, exactly today's kernel (:mod:`workbench.plant.kernels`) with
T_em F_e / k_p replaced by T_em (x_dyn + r F_e). For the bare spring (no states, r = 1/k_p)
the two are the same arithmetic.

One sub-step of length h:

The stack force splits as T_em V_p + F_e = g - (T_em^2/C_pp) x_dyn with the charge force
g = T_em q / C_pp + F_e C_p / C_pp: the open-circuit stiffness T_em^2/C_pp is a linear spring
at the stack, so it is put into the structure's matrices (stepped exactly), and only the
charge, which moves through R, is exchanged between the two sides. Stepping the whole force
explicitly instead went unstable at h f_mode = 0.07 (70 kHz mode, 1 us; stable at 0.012).

1. x_dyn at mid-step from the (stiffened) structure with g held at its last value (exact
   zero-order-hold half step);
2. per stack, the electrical step of today's kernel on that x_dyn: the creep branches relax at a
   held terminal charge (C_h gives what they take, Kirchhoff's current law at the terminal as in
   :mod:`workbench.plant.kernels`; semi-implicit on C_h's local slope, stable for any h), then
   R dq/dt = V - V_t over the gap after them on G's local slope, exact through current-limited slews
   (open leads: q fixed, the creep branches redistribute charge inside); first order in h with creep;
3. the stiffened structure advanced over h with g linear between the two step ends
   (first-order hold, one matrix exponential).

Why not ``kernels.pzt_step``: its packed model bakes T_em F_e / k_p with k_p > 0 into C_pp and
G and holds one stack; a structure without residual compliance (pure modes, today's mode
filter) needs C_pp = C_p and a force term from the structure's states, and several stacks
share one structure. The play updates are ``hysteresis.pi_step`` and ``pi_slope``.

The charge step through R and the current limit is :func:`workbench.plant.kernels.rc_charge` (its
one home), with each stack's capacitance and exp(-h/(R C)) worked out once per capacitance segment
(when a play engages or lets go), and G's plays, output and slopes in one pass.

The step allocates nothing: every buffer is made once by :class:`CoupledSimulator`.
"""

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numba import njit

from .kernels import creep_branch_update, creep_explicit_charge, rc_charge, rc_factor
from .structure import Structure, mode_filter

__all__ = ["CoupledSimulator", "CoupledTrajectory", "coupled_run", "STACK_OUT_NAMES"]

# per-stack scalar columns
(C_R, C_ISRC, C_ISNK, C_VMIN, C_VMAX, C_T, C_RES, C_INVCPP, C_OPEN, C_INVISRC, C_INVISNK, C_GF) = range(12)
N_SC = 12
# per-stack electrical state columns: hysteretic charge, G output, creep charge, 1/slopes of G, the slopes
# as summed (the capacitance segment's key) and the segment's rc_factor, rising and falling, and the
# sub-step and R those factors were formed with (re-formed at the start of a run if they differ)
E_QH, E_U, E_QC, E_GUP, E_GDN, E_KUP, E_KDN, E_FUP, E_FDN, E_FDT, E_FR = range(11)
N_ES = 11
STACK_OUT_NAMES = ("x_m", "q_c", "i_a", "v_h_v", "v_p_v", "v_t_v", "force_n")


@njit(cache=True, error_model="numpy", inline="always")
def _pi_update_segment(z, r, w, o0, o1, v, es, j, h, r_ohm):
    """Advance stack j's G plays (``z[o0:o1]``) to v; keep its capacitance segment in ``es[j]``; return G's output.

    One pass for :func:`workbench.plant.hysteresis.pi_step` and both
    :func:`~workbench.plant.hysteresis.pi_slope` (same tolerance, same sums); the
    capacitances 1/slope and their :func:`~workbench.plant.kernels.rc_factor` are recomputed
    only when a slope changes.
    """
    y = 0.0
    up = 0.0
    dn = 0.0
    for i in range(o0, o1):
        ri = r[i]
        lo = v - ri
        hi = v + ri
        zi = z[i]
        if zi < lo:
            zi = lo
        elif zi > hi:
            zi = hi
        z[i] = zi
        wi = w[i]
        y += wi * zi
        tol = 1e-12 * (1.0 + abs(v) + ri)
        if zi <= lo + tol:
            up += wi
        if zi >= hi - tol:
            dn += wi
    if up != es[j, E_KUP]:
        es[j, E_KUP] = up
        cap = 1.0 / up
        es[j, E_GUP] = cap
        es[j, E_FUP] = rc_factor(cap, h, r_ohm)
    if dn != es[j, E_KDN]:
        es[j, E_KDN] = dn
        cap = 1.0 / dn
        es[j, E_GDN] = cap
        es[j, E_FDN] = rc_factor(cap, h, r_ohm)
    return y


@njit(cache=True, error_model="numpy")
def coupled_run(sc, g_r, g_w, g_off, c_cap, c_dec, c_off, es, zg, qc,
                ad, b0, b1, hx, hu, cy, dy, xi, xi_tmp, g_prev, g_now, u_now, y,
                h, v, fe, w, n_sub, decimate, rec_s, rec_y, rec_xi):
    """Run stacks + structure over the samples (rows of ``v``, ``fe``, ``w``), each held n_sub sub-steps.

    Every ``decimate``-th sample goes into ``rec_s`` (rows, stacks, STACK_OUT_NAMES), ``rec_y``
    (structure outputs) and, when it has rows, ``rec_xi`` (structure states); ``rec_s`` needs one
    scratch row beyond the kept ones. The current is the mean over the sample. Returns the
    number of rows kept.
    """
    ns = sc.shape[0]
    n = xi.shape[0]
    nu = u_now.shape[0]
    ny = y.shape[0]
    ne = nu - ns
    inv_h = 1.0 / h
    for j in range(ns):
        # a state copied from a simulator with another sub-step or R: its RC factors are re-formed
        if es[j, E_FDT] != h or es[j, E_FR] != sc[j, C_R]:
            es[j, E_FUP] = rc_factor(es[j, E_GUP], h, sc[j, C_R])
            es[j, E_FDN] = rc_factor(es[j, E_GDN], h, sc[j, C_R])
            es[j, E_FDT] = h
            es[j, E_FR] = sc[j, C_R]
    # per stack, constant over the run: the creep branches' summed input coefficient b = sum (1 - d_i) C_i and
    # G's smallest slope (the running sum of its weights' minimum)
    c_b = (1.0 - c_dec) * c_cap                 # each branch's input coefficient b_i = (1 - d_i) C_i, F
    b_stack = np.zeros(ns)
    g_min_stack = np.full(ns, np.inf)
    for j in range(ns):
        for i in range(c_off[j], c_off[j + 1]):
            b_stack[j] += c_b[i]
        g_acc = 0.0
        for i in range(g_off[j], g_off[j + 1]):
            g_acc += g_w[i]
            g_min_stack[j] = min(g_min_stack[j], g_acc)
    row = 0
    count = 0
    for k in range(v.shape[0]):
        for s in range(n_sub):
            for j in range(ns):
                # 1. elongation from the structure at mid-step (force held at its last value)
                xd = 0.0
                for b in range(n):
                    xd += hx[j, b] * xi[b]
                for c in range(nu):
                    xd += hu[j, c] * g_prev[c]
                for e in range(ne):
                    xd += dy[j, ns + e] * w[k, e]
                t_em = sc[j, C_T]
                inv_cpp = sc[j, C_INVCPP]
                f_e = fe[k, j]
                f_term = t_em * (xd + sc[j, C_RES] * f_e)
                qh = es[j, E_QH]
                u = es[j, E_U]
                o0 = g_off[j]
                o1 = g_off[j + 1]
                c0 = c_off[j]
                c1 = c_off[j + 1]
                qc_old = es[j, E_QC]
                q_old = qh + qc_old
                # 2a. the creep branches relax toward C_j V_h* at a held terminal charge: C_h gives what they
                # take (Kirchhoff's current law at the terminal). Semi-implicit, as pzt_advance: V_h* = V_h - k S
                # at the sub-step's end on C_h's local slope k (the segment q_h moves along), S = E / (1 + b k)
                # the branches' charge, E that of the explicit step: stable for any h and tau_j
                # (the branches' sums and update: kernels.creep_explicit_charge / creep_branch_update, one home; V_h*
                # written here on G's capacitance C with one division, S = E C / (C + b h): pzt_advance forms the two
                # directions' reciprocals off its chain instead, the same physics rounded otherwise)
                v_h = u - qh * inv_cpp
                b_tot = b_stack[j]
                n_cj = c1 - c0
                _, e_c = creep_explicit_charge(c_dec, c0, qc, c0, n_cj, b_tot, v_h, qc_old)
                g_fall = 0.0
                if c1 > c0:
                    cap = es[j, E_GDN] if e_c > 0 else es[j, E_GUP]
                    hh = 1.0 - cap * inv_cpp
                    t_c = e_c / (cap + b_tot * hh)
                    v_h = v_h - t_c * hh
                    # G's fall from the branches' charge t_c C on its smallest slope (never overstated, as
                    # pzt_advance takes it)
                    g_fall = t_c * cap * g_min_stack[j]
                creep_branch_update(c_dec, c0, c_b, c0, qc, c0, n_cj, v_h)
                qc_tot = 0.0
                for i in range(c0, c1):
                    qc_tot += qc[i]
                dq = 0.0
                if sc[j, C_OPEN] < 0.5:
                    # 2b. the charge through R into the node (today's kernel) over the gap after the branches'
                    # step (G's output fell by g_fall); open leads (2b'): none, q is fixed
                    vc = min(max(v[k, j], sc[j, C_VMIN]), sc[j, C_VMAX])
                    du = vc - (qc_tot - f_term) * inv_cpp - (u - g_fall)
                    if du != 0.0:
                        r = sc[j, C_R]
                        if du > 0:
                            dq = rc_charge(du, es[j, E_GUP], es[j, E_FUP], h, r, sc[j, C_ISRC], sc[j, C_INVISRC],
                                           r * sc[j, C_ISRC])
                        else:
                            dq = rc_charge(du, es[j, E_GDN], es[j, E_FDN], h, r, sc[j, C_ISNK], sc[j, C_INVISNK],
                                           r * sc[j, C_ISNK])
                qh_new = qh + (dq - (qc_tot - qc_old))
                if qh_new != qh:
                    u_new = _pi_update_segment(zg, g_r, g_w, o0, o1, qh_new, es, j, h, sc[j, C_R])
                else:
                    u_new = u
                v_h = u_new - qh_new * inv_cpp
                es[j, E_QH] = qh_new
                es[j, E_U] = u_new
                es[j, E_QC] = qc_tot
                q = qh_new + qc_tot
                v_p = (q - f_term) * inv_cpp
                u_now[j] = t_em * v_p + f_e
                g_now[j] = t_em * inv_cpp * q + sc[j, C_GF] * f_e
                rec_s[row, j, 1] = q
                rec_s[row, j, 2] = (q - q_old) * inv_h if s == 0 else rec_s[row, j, 2] + (q - q_old) * inv_h
                rec_s[row, j, 3] = v_h
                rec_s[row, j, 4] = v_p
                rec_s[row, j, 5] = v_h + v_p
                rec_s[row, j, 6] = u_now[j]
            for e in range(ne):
                u_now[ns + e] = w[k, e]
                g_now[ns + e] = w[k, e]
            # 3. structure over the sub-step, inputs linear between its ends
            for a in range(n):
                acc = 0.0
                for b in range(n):
                    acc += ad[a, b] * xi[b]
                for c in range(nu):
                    acc += b0[a, c] * g_prev[c] + b1[a, c] * g_now[c]
                xi_tmp[a] = acc
            for a in range(n):
                xi[a] = xi_tmp[a]
            for c in range(nu):
                g_prev[c] = g_now[c]
        for o in range(ny):
            acc = 0.0
            for b in range(n):
                acc += cy[o, b] * xi[b]
            for c in range(nu):
                acc += dy[o, c] * u_now[c]
            y[o] = acc
        for j in range(ns):
            rec_s[row, j, 0] = y[j]
            rec_s[row, j, 2] /= n_sub
        count += 1
        if count == decimate:
            count = 0
            for o in range(ny):
                rec_y[row, o] = y[o]
            if rec_xi.shape[0] > 0:
                for b in range(n):
                    rec_xi[row, b] = xi[b]
            row += 1
    return row


@dataclass(frozen=True)
class CoupledTrajectory:
    """Sampled outputs of a coupled run (SI). Stack arrays have shape (samples, stacks).

    Attributes
    ----------
    t_s : ndarray
        Sample end times, s.
    v_pea_v : ndarray
        Terminal drive per stack (amplifier command clipped to its range; 0 for a load
        resistor; NaN for open leads), V.
    x_m, q_c, i_a, v_h_v, v_p_v, v_t_v : ndarray
        Elongation (m), charge (C), mean current over the sample (A), V_h, V_p and the terminal
        voltage V_t (V).
    force_n : ndarray
        The force on each stack's ends, T_em V_p + F_e, N.
    f_e_n : ndarray
        The environmental force at each stack, N.
    y : ndarray, shape (samples, outputs)
        All structure outputs (elongations, rates, others).
    states : ndarray or None
        Structure states per sample when asked for.
    """

    t_s: np.ndarray
    v_pea_v: np.ndarray
    x_m: np.ndarray
    q_c: np.ndarray
    i_a: np.ndarray
    v_h_v: np.ndarray
    v_p_v: np.ndarray
    v_t_v: np.ndarray
    force_n: np.ndarray
    f_e_n: np.ndarray
    y: np.ndarray
    states: np.ndarray | None = None


def _foh(a, b, h):
    """(Ad, B0, B1): x+ = Ad x + B0 u_k + B1 u_k+1 for inputs linear over h (one expm)."""
    n, nu = b.shape
    blk = np.zeros((n + 2 * nu, n + 2 * nu))
    blk[:n, :n] = a * h
    blk[:n, n:n + nu] = b * h
    blk[n:n + nu, n + nu:] = np.eye(nu)
    e = scipy.linalg.expm(blk)
    ad, g1, g2 = e[:n, :n], e[:n, n:n + nu], e[:n, n + nu:]
    return ad, g1 - g2, g2


def _zoh(a, b, h):
    n, nu = b.shape
    blk = np.zeros((n + nu, n + nu))
    blk[:n, :n] = a * h
    blk[:n, n:] = b * h
    e = scipy.linalg.expm(blk)
    return e[:n, :n], e[:n, n:]


class CoupledSimulator:
    """Stacks (seed 000 Fig. 3 electrical side each) on one structure, stepped at ``dt_s``.

    Parameters
    ----------
    stacks : sequence of PZTParams
        One per stack, in the structure's stack order. Their ``modes`` are ignored (the
        structure is M); R must be > 0 (the quasi-static R = 0 form stays in PZTSimulator).
    structure : Structure
    dt_s : float
        Sample time, s: inputs are held over it.
    n_sub : int
        Sub-steps per sample; resolve the fastest structural mode (h << 1/f).
    terminations : sequence, optional
        Per stack: ``"amplifier"`` (default: the plant's R and current limits), ``"open"``
        (leads open, as the Instron R_out runs), or a resistance in ohm (a load resistor
        across the leads: 0 V through it, no current limit, as the Instron R_in runs).

    Examples
    --------
    >>> from pathlib import Path
    >>> from workbench.plant import load_plant
    >>> from workbench.plant.structure import spring
    >>> pz = load_plant(Path(__file__).resolve().parents[2] / "plants" / "p888_51_sn637.toml").pzt
    >>> sim = CoupledSimulator([pz], spring(pz.stiffness_n_per_m), 1e-4, terminations=["open"])
    >>> tr = sim.run(np.zeros(100), np.full(100, -800.0))   # 800 N on open leads
    >>> round(float(tr.v_t_v[-1, 0]), 1), round(float(tr.x_m[-1, 0]) * 1e6, 2)
    (11.2, -1.39)
    """

    def __init__(self, stacks, structure, dt_s, n_sub=1, terminations=None):
        stacks = list(stacks)
        if not isinstance(structure, Structure):
            raise TypeError(f"structure must be a Structure; got {type(structure).__name__}")
        ns = structure.n_stacks
        if len(stacks) != ns:
            raise ValueError(f"the structure has {ns} stack(s); got {len(stacks)} stack parameter sets")
        if not dt_s > 0 or int(n_sub) < 1:
            raise ValueError(f"need dt_s > 0 and n_sub >= 1; got {dt_s}, {n_sub}")
        terminations = ["amplifier"] * ns if terminations is None else list(terminations)
        if len(terminations) != ns:
            raise ValueError(f"one termination per stack; got {len(terminations)} for {ns}")
        self.stacks, self.structure = stacks, structure
        self.dt_s, self.n_sub = float(dt_s), int(n_sub)
        self.terminations = terminations
        h = self.dt_s / self.n_sub
        self.h_s = h
        res = structure.residual_compliance_m_per_n
        sc = np.zeros((ns, N_SC))
        self._G = []
        g_tabs, c_tabs = [], []
        for j, (pz, term) in enumerate(zip(stacks, terminations)):
            t = pz.transducer_constant_n_per_v
            c_pp = pz.working_capacitance_f + t * t * res[j]
            sc[j, C_T], sc[j, C_RES], sc[j, C_INVCPP] = t, res[j], 1.0 / c_pp
            sc[j, C_GF] = pz.working_capacitance_f / c_pp
            sc[j, C_VMIN], sc[j, C_VMAX] = pz.voltage_min_v, pz.voltage_max_v
            if term == "amplifier":
                if pz.series_resistance_ohm <= 0:
                    raise ValueError(f"stack {j}: the coupled kernel needs R > 0 (the plant has R = 0, "
                                     f"the quasi-static form); set series_resistor_in = true")
                sc[j, C_R] = pz.series_resistance_ohm
                sc[j, C_ISRC], sc[j, C_ISNK] = pz.current_limit_source_a, pz.current_limit_sink_a
            elif term == "open":
                sc[j, C_OPEN] = 1.0
                sc[j, C_R], sc[j, C_ISRC], sc[j, C_ISNK] = 1.0, 1.0, 1.0
            elif isinstance(term, (int, float)) and term > 0:
                sc[j, C_R] = float(term)
                sc[j, C_ISRC] = sc[j, C_ISNK] = 1e30   # a resistor has no current limit
                sc[j, C_VMIN] = sc[j, C_VMAX] = 0.0
            else:
                raise ValueError(f"stack {j}: termination must be 'amplifier', 'open' or a resistance "
                                 f"in ohm > 0; got {term!r}")
            sc[j, C_INVISRC], sc[j, C_INVISNK] = 1.0 / sc[j, C_ISRC], 1.0 / sc[j, C_ISNK]
            G = pz.hysteresis.inverse().plus_linear(1.0 / c_pp)
            self._G.append(G)
            g_tabs.append(G)
            if pz.creep is not None:
                c_tabs.append((pz.creep.capacitances_f, np.exp(-h / pz.creep.time_constants_s)))
            else:
                c_tabs.append((np.zeros(0), np.zeros(0)))
        self.sc = sc
        self.g_r = np.concatenate([G.thresholds for G in g_tabs])
        self.g_w = np.concatenate([G.weights for G in g_tabs])
        self.g_off = np.concatenate([[0], np.cumsum([G.size for G in g_tabs])]).astype(np.int64)
        self.c_cap = np.concatenate([c for c, _ in c_tabs])
        self.c_dec = np.concatenate([d for _, d in c_tabs])
        self.c_off = np.concatenate([[0], np.cumsum([c.size for c, _ in c_tabs])]).astype(np.int64)
        st = structure
        n = st.n_states
        # the open-circuit stiffness T^2/C_pp moves into the stepped structure (exact, so a stiff
        # coupled mode cannot go unstable); the structure is then driven by the charge force
        # g = T q / C_pp + F_e C_p / C_pp and the external inputs
        k_e = sc[:, C_T] ** 2 * sc[:, C_INVCPP]
        cx, dxw = st.c[:ns], st.d[:ns, ns:]
        a_cl = st.a - st.b[:, :ns] @ (k_e[:, None] * cx)
        b_cl = st.b.copy()
        b_cl[:, ns:] -= st.b[:, :ns] @ (k_e[:, None] * dxw)
        self.ad, self.b0, self.b1 = (np.ascontiguousarray(m) for m in _foh(a_cl, b_cl, h))
        ah, bh = _zoh(a_cl, b_cl, h / 2)
        self.hx = np.ascontiguousarray(st.c[:ns] @ ah)
        self.hu = np.ascontiguousarray(st.c[:ns] @ bh)
        self.cy, self.dy = np.ascontiguousarray(st.c), np.ascontiguousarray(st.d)
        self.xi, self.xi_tmp = np.zeros(n), np.zeros(n)
        nu = st.d.shape[1]
        self.g_prev, self.g_now, self.u_now = np.zeros(nu), np.zeros(nu), np.zeros(nu)
        self.y = np.zeros(st.d.shape[0])
        self.reset()

    def reset(self):
        """Return to rest: plays at the plant files' states, no creep charge, structure at static equilibrium."""
        ns = self.structure.n_stacks
        self.es = np.zeros((ns, N_ES))
        self.es[:, E_KUP] = self.es[:, E_KDN] = np.nan      # no segment yet: the first play pass sets it
        self.zg = np.concatenate([G.initial_states for G in self._G])
        self.qc = np.zeros(self.c_cap.size)
        qh = np.array([pz.hysteresis.output_at_rest() for pz in self.stacks])
        for j, G in enumerate(self._G):
            self.es[j, E_QH] = qh[j]
            self.es[j, E_U] = G.output_at_rest()
            self.es[j, E_GUP] = 1.0 / G.slope(qh[j], +1)
            self.es[j, E_GDN] = 1.0 / G.slope(qh[j], -1)
            for c, f in ((E_GUP, E_FUP), (E_GDN, E_FDN)):
                self.es[j, f] = getattr(rc_factor, "py_func", rc_factor)(self.es[j, c], self.h_s, self.sc[j, C_R])
            self.es[j, E_FDT], self.es[j, E_FR] = self.h_s, self.sc[j, C_R]
        # static equilibrium of the initial charge: V_p = (C_p + T S T)^-1 q, F = T V_p
        t = np.array([pz.transducer_constant_n_per_v for pz in self.stacks])
        cp = np.array([pz.working_capacitance_f for pz in self.stacks])
        s = self.structure.static_compliance_m_per_n() if self.structure.n_states else \
            np.diag(self.structure.residual_compliance_m_per_n)
        vp = np.linalg.solve(np.diag(cp) + t[:, None] * s * t[None, :], qh)
        self.u_now[:] = 0.0
        self.u_now[:ns] = t * vp
        self.g_prev[:] = 0.0
        self.g_prev[:ns] = t * self.sc[:, C_INVCPP] * qh
        self.g_now[:] = self.g_prev
        self.xi[:] = 0.0
        if self.structure.n_states and np.any(self.u_now):
            # a structure with rigid-body modes has no static equilibrium under a net force
            self.xi[:] = -np.linalg.solve(self.structure.a, self.structure.b @ self.u_now)
        self.y[:] = 0.0

    def run(self, v_pea_v, f_e_n=None, external_n=None, decimate=1, record_states=False, t0_s=0.0):
        """Simulate from the current state (kept for the next call).

        Parameters
        ----------
        v_pea_v : array_like, shape (samples,) or (samples, stacks)
            Amplifier command per stack, V (ignored for open leads and load resistors).
        f_e_n : array_like, same shape, optional
            Environmental force at each stack's ends, N (compression negative). Default 0.
        external_n : array_like, shape (samples, n_external), optional
            The structure's further force inputs, N.
        decimate : int
            Keep every ``decimate``-th sample.
        record_states : bool
            Also keep the structure's states (for energy accounting).
        """
        ns = self.structure.n_stacks
        v = np.asarray(v_pea_v, float)
        v = np.ascontiguousarray(v.reshape(-1, 1) if v.ndim == 1 else v)
        f = np.zeros_like(v) if f_e_n is None else np.asarray(f_e_n, float)
        f = np.ascontiguousarray(f.reshape(-1, 1) if f.ndim == 1 else f)
        ne = self.structure.n_external
        w = np.zeros((v.shape[0], ne)) if external_n is None else np.ascontiguousarray(
            np.asarray(external_n, float).reshape(v.shape[0], ne))
        if v.shape[1] != ns or f.shape != v.shape:
            raise ValueError(f"voltage and force need shape (samples, {ns}); got {v.shape}, {f.shape}")
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(f)) and np.all(np.isfinite(w))):
            raise ValueError("inputs must be finite (found NaN or inf)")
        decimate = int(decimate)
        rows = v.shape[0] // decimate
        rec_s = np.zeros((rows + 1, ns, len(STACK_OUT_NAMES)))
        rec_y = np.zeros((rows, self.y.size))
        rec_xi = np.zeros((rows if record_states else 0, self.structure.n_states))
        kept = coupled_run(self.sc, self.g_r, self.g_w, self.g_off, self.c_cap, self.c_dec, self.c_off,
                           self.es, self.zg, self.qc, self.ad, self.b0, self.b1, self.hx, self.hu,
                           self.cy, self.dy, self.xi, self.xi_tmp, self.g_prev, self.g_now, self.u_now, self.y,
                           self.h_s, v, f, w, self.n_sub, decimate, rec_s, rec_y, rec_xi)
        rec_s = rec_s[:kept]
        idx = np.arange(1, kept + 1) * decimate - 1
        vp = np.clip(v[idx], self.sc[:, C_VMIN], self.sc[:, C_VMAX])
        vp[:, self.sc[:, C_OPEN] > 0.5] = np.nan
        return CoupledTrajectory(t_s=t0_s + (idx + 1) * self.dt_s, v_pea_v=vp,
                                 **{name: rec_s[:, :, c] for c, name in enumerate(STACK_OUT_NAMES)},
                                 f_e_n=f[idx], y=rec_y, states=rec_xi if record_states else None)


def structure_of(plant):
    """The plant's M(.): its ``[structure]`` if it has one, else k_p with today's modes."""
    st = getattr(plant, "structure", None)
    if st is not None:
        return st
    return mode_filter(plant.pzt.stiffness_n_per_m, plant.pzt.modes)
