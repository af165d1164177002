"""Compiled time stepping of the PZT (numba).

One call to :func:`pzt_step` advances the plant by one sub-step with the inputs
held; :func:`pzt_run` loops over a whole input record. Both take two packed float
vectors, the model ``m`` (parameters, operator tables, creep and mode matrices) and
the state ``st``, so later stages (closed-loop verification) can call ``pzt_step``
from their own compiled loops. Packing matters: numba reference-counts every array
handed to a function, and with a dozen separate arrays that bookkeeping cost more
than the physics (and a long loop takes :func:`_borrowed` views of ``m`` and ``st`` once, so that the
step inlined into it counts no reference at all). ``pzt_step.py_func`` is the same code run by the interpreter,
which the benchmark hands to python-control. A long loop reads the model's scalars
and offsets once with :func:`plant_params` and calls :func:`pzt_advance` (the same
step, returning its outputs instead of writing an array), as :func:`pzt_run` and the
closed loop do; :func:`pzt_step` is that pair in one call. The step's arithmetic is arranged for a
short dependency chain (capacitance and RC factor per capacitance segment, G's plays run only when
the charge leaves their band, semi-implicit creep and exact mode steps, no division but the creep step's); :func:`pzt_step_reference`
keeps the same equations in their plainest form (per-step divisions and exp), the oracle the tests hold it to (1e-12 of the stroke).

Kirchhoff's current law at the terminal (seed 000 Fig. 3, the creep branches across C_h as
:mod:`workbench.plant.creep` describes them): the current through R feeds C_h and the creep branches
together, R (dq_h/dt + sum_j dQ_j/dt) = v - V_t. A step splits this in two parts, each keeping the law (the
terminal charge q = q_h + sum_j Q_j changes only by the charge through R): first the branches move toward
C_j V_h at a held terminal charge (q_h gives what they take: V_h falls as they charge), semi-implicitly, i.e.
toward C_j V_h* with V_h* the node voltage at the step's end on C_h's local slope, which is stable for any dt
and tau_j; then R moves the charge (v - V_t)/R carries over the gap left after the branches' step. The split
is first order in dt (as a whole the step is exact only without creep, on G's local slope). With the leads
open (R = 2e14 ohm) q stays put while the branches relax. (Before this was fixed the branches' charge reached
the terminal without passing R or the amplifier's current limit: small at 80 ohm while the amplifier is not
limited, where the loop corrects it within R C, but 27.7 uC and 387 nm apart during a 2 mA slew and tens of
uC of "held" charge moved at open leads; tests/plant/test_kcl.py, benchmarks/kcl_creep.py.)

Without the series resistor (R = 0, the quasi-static form: seed 000's free-free configuration) the amplifier
drives the terminal directly and still saturates on its current: a step moves the charge that brings V_t to the
command, or exactly i_lim dt where that is more (the source's rising, the sink's falling), so V_t slews at
i_lim / C. (Before session 37 V_t was set to the command at every sub-step, no limit at all: resistor-out records
stepped 30-270x faster than the declared amplifier can; tests/plant/test_current_limit_without_resistor.py.)

:class:`workbench.plant.simulator.PZTSimulator` builds ``m`` and ``st``; the index
constants below are their layout.
"""

import math

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic, overload

__all__ = ["pzt_step", "pzt_advance", "plant_params", "pzt_run", "pzt_step_reference", "rc_charge", "rc_factor",
           "OUT_NAMES", "pack_model", "pack_state"]

# scalars at the head of m (reciprocals too: divisions otherwise dominate a step)
(R, I_SRC, I_SNK, V_MIN, V_MAX, T_EM, K_P, C_PP, DT, QUASI_STATIC,
 INV_R, INV_I_SRC, INV_I_SNK, INV_K_P, INV_C_PP, INV_DT) = range(16)
# table layout in m: sizes and offsets (stored as floats); O_CB: the creep branches' exact
# step input coefficients (1 - decay_j) C_j, so a branch steps as q_j <- decay_j q_j + b_j V_h
(N_G, O_RG, O_WG, N_Q, O_RQ, O_WQ, N_C, O_CC, O_CDEC, N_M, O_AD, O_BD, O_CD, O_DD,
 OS_ZG, OS_ZQ, OS_QC, OS_XM, O_CB) = range(16, 35)
M_HEAD = 35
# scalars at the head of st: hysteretic charge, G output (= V_h + q_h/C_pp), creep charge,
# the incremental capacitances (1 / G's slope) for rising and falling q_h at the current state,
# the slopes themselves as summed (the key of the capacitance segment: the two entries after
# them are recomputed only when it changes), and the charge per volt of gap that a step
# of dt moves through R on each segment, C (1 - exp(-dt / (R C))) (see :func:`rc_factor`); then the
# band of G's input over which its plays after the first stay strictly inside their deadbands (lower,
# upper, shrunk by a rounding margin) and their summed output there (see :func:`_pi_update_segment`);
# then the step dt and R the RC factors were formed with (a state copied into a model with another dt
# or R has them re-formed before its first step, see :func:`_check_segment`)
S_QH, S_U, S_QC, S_GUP, S_GDN, S_KUP, S_KDN, S_FUP, S_FDN, S_PL, S_PU, S_Y1, S_FDT, S_FR = range(14)
S_HEAD = 14
OUT_NAMES = ("x_m", "q_c", "i_a", "v_h_v", "v_p_v", "v_t_v")
N_OUT = len(OUT_NAMES)


def _index(x):
    """A table size or offset read from ``m`` as an index: a Python int when interpreted."""
    return int(x)


@overload(_index, inline="always")
def _index_compiled(x):
    # compiled: unsigned, so an index into m or st needs no negative-index wraparound test (numba adds one
    # to every signed index it cannot prove >= 0; the offsets come from m, so it never can)
    return lambda x: np.uint64(x)


def _borrowed(arr):
    """``arr`` as a borrowed view for a compiled loop: the same data, no reference count; the array itself when interpreted.

    numba passes an array into a function it inlines (:func:`pzt_advance`, ``fixed_step``) as a new
    reference: an atomic increment before the call and a decrement after it, which its reference-count
    pruning does not remove inside a loop with this many branches. A locked increment is a full memory
    barrier on x86, so each one waits for every store before it (the plant state's) and holds back every
    load after it: four to eight a servo period kept the closed loop's periods from overlapping at all.
    The view has a null meminfo (the runtime skips a null one without an atomic), so a long loop takes
    views of its arrays once, before the loop. Only while ``arr`` itself is alive (the caller's argument).

    Private on purpose: the view must never leave the compiled function (returned, stored, boxed), nor
    be taken of an array the function allocates. numba boxes it as the caller's array only when data,
    shape and strides match; a returned slice of it becomes a NumPy array with no owner, which reads
    freed memory once the caller's array is gone. Index it, or pass it to an inlined step; return scalars.

    Measured with numba 0.68.1 / llvmlite 0.50 (2026-11-26, ``PYTHONPATH=. python benchmarks/borrowed_codegen.py``):
    as written, ``pzt_run`` and ``verify.closed_loop._loop`` hold no reference count on a cycle of their
    control-flow graphs; with the arrays themselves in place of the views (an inlined identity), a plain view
    ``a[:]`` or a copy, 10 NRT_incref/NRT_decref calls sit inside each function's loops (numba increfs an
    array handed to an inlined step; a null meminfo it skips). Tests check the compiled loops hold none
    (``tests/compiled_loops.py``).
    """
    return arr


@intrinsic
def _null_meminfo(typingctx, arr):
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, sig, args):
        src = context.make_array(arr)(context, builder, value=args[0])
        view = context.make_array(arr)(context, builder)
        for name in ("parent", "nitems", "itemsize", "data", "shape", "strides"):
            setattr(view, name, getattr(src, name))
        view.meminfo = cgutils.get_null_value(view.meminfo.type)
        return view._getvalue()

    return arr(arr), codegen


@overload(_borrowed, inline="always")
def _borrowed_compiled(arr):
    return lambda arr: _null_meminfo(arr)


def pack_model(scalars, G, Q, creep_c, creep_decay, Ad, Bd, Cd, Dd):
    """Build the model vector from the scalar parameters and the tables."""
    nm = Cd.size
    creep_b = (1.0 - creep_decay) * creep_c
    tables = [G.thresholds, G.weights, Q.thresholds, Q.weights, creep_c, creep_decay,
              Ad.ravel(), Bd, Cd, Dd, creep_b]
    offs = np.cumsum([M_HEAD] + [t.size for t in tables])
    m = np.zeros(offs[-1])
    m[:16] = scalars
    for t, o in zip(tables, offs[:-1]):
        m[o:o + t.size] = t
    s_offs = np.cumsum([S_HEAD, G.size, Q.size, creep_c.size, 2 * nm + 1])
    m[N_G:O_CB + 1] = [G.size, offs[0], offs[1], Q.size, offs[2], offs[3], creep_c.size, offs[4],
                        offs[5], nm, offs[6], offs[7], offs[8], offs[9],
                        s_offs[0], s_offs[1], s_offs[2], s_offs[3], offs[10]]
    return m, int(s_offs[4])


def pack_state(m, size, qh, u, cap_up, cap_dn, zG, zQ, qc, xm):
    """Build the state vector (xm: modal state, scratch copy, previous x_qs).

    ``zQ``, Q = G^-1's play states: the quasi-static step keeps them and G's (``zG``); the dynamic form keeps
    G's only, and a state it hands to the quasi-static form has Q's formed from them (:func:`_q_states_from_g`).
    """
    st = np.zeros(size)
    st[S_QH], st[S_U], st[S_GUP], st[S_GDN] = qh, u, cap_up, cap_dn
    # no segment key yet: the first step's play pass recomputes the capacitances from the plays
    st[S_KUP] = st[S_KDN] = np.nan
    st[S_PL] = st[S_PU] = np.nan              # no band yet: the first step runs every play
    r = m[R]
    fac = getattr(rc_factor, "py_func", rc_factor)       # plain Python when numba's JIT is disabled
    st[S_FUP], st[S_FDN] = (cap_up, cap_dn) if r == 0.0 else (fac(cap_up, m[DT], r), fac(cap_dn, m[DT], r))
    st[S_FDT], st[S_FR] = m[DT], r
    st[S_QC] = np.sum(qc)
    for off, arr in ((OS_ZG, zG), (OS_ZQ, zQ), (OS_QC, qc), (OS_XM, xm)):
        o = int(m[off])
        st[o:o + arr.size] = arr
    return st


@njit(cache=True, error_model="numpy", inline="always")
def rc_factor(cap, dt, r):
    """C (1 - exp(-dt / (R C))), F: the charge per volt of gap an RC step of dt moves (no current limit).

    ``cap`` the capacitance C (F) on the segment, ``dt`` (s), ``r`` (ohm). Worked out once per
    capacitance segment (:func:`rc_charge`'s ``f_full``), not once per step.
    """
    return cap * (1.0 - math.exp(-dt / (r * cap)))


@njit(cache=True, error_model="numpy", inline="always")
def rc_charge(du, cap, f_full, dt, r, i_lim, inv_i, r_ilim):
    """Charge (C) that R with a current limit moves in dt into a capacitance ``cap`` behind a gap ``du``.

    R dq/dt = du - q/cap with |dq/dt| <= i_lim, exact: while the gap exceeds R i_lim (``r_ilim``, V)
    the charge moves at the limit; then, or from the start, it relaxes exponentially (tau = R cap).
    ``f_full`` = :func:`rc_factor` (cap, dt, r), the segment's precomputed unlimited step;
    ``inv_i`` = 1 / i_lim. ``i_lim``, ``inv_i``, ``r_ilim`` are the limit in the direction of
    ``du`` (source for du > 0). The one home of the step for :mod:`workbench.plant.kernels`
    and :mod:`workbench.plant.coupled`.
    """
    gap = abs(du)
    if gap <= r_ilim:
        return du * f_full
    d = 1.0 if du > 0 else -1.0
    t_sat = (gap - r_ilim) * inv_i * cap
    if t_sat >= dt:
        return d * i_lim * dt
    # current-limited for t_sat, then the RC relaxation from a gap of R i_lim for the rest
    return d * i_lim * t_sat + d * r_ilim * cap * (1.0 - math.exp(-(dt - t_sat) / (r * cap)))


@njit(cache=True, error_model="numpy", inline="always")
def _check_segment(st, dt, r):
    """Re-form the RC factors if ``st`` was made for another dt or R (a state copied between models)."""
    if st[S_FDT] != dt or st[S_FR] != r:
        st[S_FUP] = rc_factor(st[S_GUP], dt, r)
        st[S_FDN] = rc_factor(st[S_GDN], dt, r)
        st[S_FDT] = dt
        st[S_FR] = r
        st[S_PL] = st[S_PU] = np.nan


@njit(cache=True, error_model="numpy", inline="always")
def _pi_update_segment(m, o_r, o_w, st, o_z, n, v, dt, r):
    """Advance G's plays to v; return G's output; keep the capacitance segment up to date.

    The first play (threshold 0: it follows v) is advanced every step. The others are run
    (one branch-free pass) only when v leaves the band [S_PL, S_PU] over which all of them
    sit strictly inside their deadbands, by a margin of 1e-12 (|v| + the largest threshold),
    far above rounding: inside it no play moves or touches an edge (the same decision the
    full pass would make), and their summed output S_Y1 stands (G's output is then the first
    play's term plus S_Y1; the full pass sums in play order). A hold or a small signal
    stays in the band; a slew leaves it every step. The incremental capacitances for the
    next step (1 / the sums of the weights of the plays on the edge each direction pushes)
    and their :func:`rc_factor` are recomputed only when the sums change (a play engages
    or lets go).
    """
    r0 = m[o_r]
    w0 = m[o_w]
    lo0 = v - r0
    hi0 = v + r0
    z0 = min(max(st[o_z], lo0), hi0)
    st[o_z] = z0
    up = w0 if z0 <= lo0 else 0.0
    dn = w0 if z0 >= hi0 else 0.0
    if st[S_PL] < v < st[S_PU]:
        y = w0 * z0 + st[S_Y1]
    else:
        # the output summed in play order, as pzt_step_reference sums it: at a play's edge (where this
        # pass runs) the slopes follow the sign of a residual of an ulp, so the sums round alike there
        y = w0 * z0
        y1 = 0.0
        pl = -math.inf
        pu = math.inf
        r_max = r0
        for i in range(_index(1), n):
            ri = m[o_r + i]
            wi = m[o_w + i]
            lo = v - ri
            hi = v + ri
            zi = min(max(st[o_z + i], lo), hi)
            up += wi if zi <= lo else 0.0
            dn += wi if zi >= hi else 0.0
            st[o_z + i] = zi
            y += wi * zi
            y1 += wi * zi
            pl = max(pl, zi - ri)
            pu = min(pu, zi + ri)
            r_max = max(r_max, ri)
        margin = 1e-12 * (abs(v) + r_max)
        st[S_PL] = pl + margin
        st[S_PU] = pu - margin
        st[S_Y1] = y1
    if up != st[S_KUP]:
        st[S_KUP] = up
        cap = 1.0 / up
        st[S_GUP] = cap
        st[S_FUP] = rc_factor(cap, dt, r)
    if dn != st[S_KDN]:
        st[S_KDN] = dn
        cap = 1.0 / dn
        st[S_GDN] = cap
        st[S_FDN] = rc_factor(cap, dt, r)
    return y


@njit(cache=True, error_model="numpy", inline="always")
def plant_params(m):
    """The scalars and table offsets at the head of ``m``, read once (a tuple for :func:`pzt_advance`).

    A loop that calls :func:`pzt_advance` with these keeps them in registers: read from
    ``m`` at every step they must be reloaded after each store to ``st`` (the compiler
    cannot tell the two arrays apart), and the offsets converted from float again. The
    step's fixed products are formed here: R i_lim per direction, T_em / k_p,
    T_em / (C_pp k_p), the creep branches' summed input coefficient and the modes'
    direct gain from the quasi-static displacement (D + C B1 of the first-order hold), and
    the coefficients of x over the charge and the force (D_eff k_x, D_eff / k_p).
    """
    r = m[R]
    t_em = m[T_EM]
    inv_kp = m[INV_K_P]
    inv_cpp = m[INV_C_PP]
    n_c = _index(m[N_C])
    o_cb = _index(m[O_CB])
    b_tot = 0.0
    for j in range(n_c):
        b_tot += m[o_cb + j]
    n = _index(m[N_M])
    o_b = _index(m[O_BD])
    o_cd = _index(m[O_CD])
    d_eff = m[_index(m[O_DD])] if n > 0 else 1.0
    for a in range(n):
        d_eff += m[o_cd + a] * m[o_b + n + a]
    k_x = t_em * inv_cpp * inv_kp
    o_wg = _index(m[O_WG])
    g_acc = 0.0
    g_min = math.inf
    for i in range(_index(m[N_G])):
        g_acc += m[o_wg + i]
        g_min = min(g_min, g_acc)
    return (r, m[I_SRC], m[I_SNK], m[V_MIN], m[V_MAX], t_em, m[DT], m[QUASI_STATIC] > 0.5,
            m[INV_I_SRC], m[INV_I_SNK], inv_kp, inv_cpp, m[INV_DT],
            _index(m[N_G]), _index(m[O_RG]), _index(m[O_WG]), _index(m[OS_ZG]),
            _index(m[N_Q]), _index(m[O_RQ]), _index(m[O_WQ]), _index(m[OS_ZQ]),
            n_c, o_cb, _index(m[O_CDEC]), _index(m[OS_QC]),
            n, _index(m[OS_XM]), _index(m[O_AD]), o_b, o_cd, d_eff,
            r * m[I_SRC], r * m[I_SNK], t_em * inv_kp, k_x, b_tot,
            # x of a plant with modes as one sum over this step's charges and force (pzt_advance)
            d_eff * k_x, d_eff * inv_kp,
            # the quasi-static creep step's semi-implicit factor k / (1 + b_tot k), k = 1 / C_pp (pzt_advance)
            inv_cpp / (1.0 + b_tot * inv_cpp),
            # 1 / C_h's largest capacitance: G's smallest slope (its least prefix sum of weights, the slope after a
            # long monotone move) less 1 / C_pp, the bound pzt_advance takes V_t's drop from the branches on
            g_min - inv_cpp)


@njit(cache=True, error_model="numpy", inline="always")
def creep_explicit_charge(dec, o_dec, qc, o_qc, n_c, b_tot, v_h, qc_sum):
    """(sum_j d_j Q_j, E): the branches' decayed charge and E, the charge the explicit creep step moves, C.

    The creep step's first half, one home for every compiled stepper (:func:`pzt_advance`, the coupled
    kernel, ``selfsense.force``, ``selfsense.instron_sequence``): branch j (``dec[o_dec + j]`` = d_j =
    exp(-dt/tau_j), its charge ``qc[o_qc + j]`` = Q_j, C) steps exactly toward C_j V_h over the step,
    Q_j' = d_j Q_j + b_j V_h with b_j = (1 - d_j) C_j, so with V_h held the branches take
    E = (sum_j d_j Q_j + b_tot V_h) - sum_j Q_j. ``b_tot`` = sum_j b_j (F), ``v_h`` the node voltage at the
    step's start (V), ``qc_sum`` = sum_j Q_j (C). The semi-implicit step then takes V_h* = V_h - k E / (1 + b_tot k)
    on C_h's local slope k (each caller forms it from its own slope: :func:`creep_node_voltage`) and moves the
    branches with :func:`creep_branch_update`.
    """
    s_dec = 0.0
    for j in range(n_c):
        s_dec += dec[o_dec + j] * qc[o_qc + j]
    return s_dec, (s_dec + b_tot * v_h) - qc_sum


@njit(cache=True, error_model="numpy", inline="always")
def creep_node_voltage(v_h, e_c, b_tot, k):
    """V_h* = V_h - k S, S = E / (1 + b_tot k): the node voltage at the creep step's end on C_h's slope k (V/C).

    The semi-implicit step's node voltage where the caller holds the slope k = dV_h/dq_h itself
    (``selfsense.force``, ``selfsense.instron_sequence``). :func:`pzt_advance` and the coupled kernel form the
    same V_h* from G's capacitance C and h = 1 - C / C_pp (k = h / C, S = E C / (C + b_tot h)) or, quasi-static,
    with k / (1 + b_tot k) formed once per run: the same physics, other roundings (the factors formed off the
    step's dependency chain; the C loop of the benchmark repeats ``pzt_advance``'s bit for bit).
    """
    return v_h - k * (e_c / (1.0 + b_tot * k))


@njit(cache=True, error_model="numpy", inline="always")
def creep_branch_update(dec, o_dec, b, o_b, qc, o_qc, n_c, v_h_s):
    """Move every branch exactly toward C_j V_h* over the step: Q_j <- d_j Q_j + b_j V_h* (in place, C).

    ``b[o_b + j]`` = b_j = (1 - d_j) C_j, F; ``v_h_s`` the semi-implicit node voltage V_h*, V. See
    :func:`creep_explicit_charge`.
    """
    for j in range(n_c):
        qc[o_qc + j] = dec[o_dec + j] * qc[o_qc + j] + b[o_b + j] * v_h_s


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
def _pi_output_at(m, o_r, o_w, st, o_z, n, v):
    """The output :func:`_pi_update` would return at input v, nothing written (its arithmetic, so the two agree)."""
    y = 0.0
    for i in range(n):
        ri = m[o_r + i]
        zi = st[o_z + i]
        if zi < v - ri:
            zi = v - ri
        elif zi > v + ri:
            zi = v + ri
        y += m[o_w + i] * zi
    return y


@njit(cache=True, error_model="numpy", inline="always")
def _q_states_from_g(m, st, o_wg, o_zg, o_zq, n, u):
    """Q = G^-1's play states from G's (Kuhnen's state map, :meth:`~.hysteresis.PrandtlIshlinskii.inverse`).

    z'_i = W_i z_i + sum_{j>i} w_j z_j (W_i = w_0 + ... + w_i, G's weights ``w``, states ``z``), written
    z'_i = (u - sum_{j<i} w_j z_j) + W_{i-1} z_i with ``u`` = sum_j w_j z_j, G's present output (V). For a state
    that comes from the dynamic form, which keeps G's plays only.
    """
    s = 0.0
    w_acc = 0.0
    for i in range(n):
        zi = st[o_zg + i]
        wi = m[o_wg + i]
        st[o_zq + i] = (u - s) + w_acc * zi
        s += wi * zi
        w_acc += wi


@njit(cache=True, error_model="numpy")
def _quasi_static_step(m, st, qh, u, v, qc_old, qc_new, f_term):
    """The quasi-static (R = 0) electrical step after the creep branches' step: q_h' (C), G's output u' written to st.

    The amplifier drives the terminal directly, to V_t = v at the step's end with the branches' new charge (u_t:
    G's output there, Q = G^-1's input) if the charge that takes, Q[u_t] + Q_c' - q, is within its current limit
    over the step: Q's plays move to u_t and G's follow the charge (the step before session 37, bit for bit).
    Else exactly the limit's charge moves (i_src dt rising, i_snk dt falling): G gives the terminal from the
    charge and Q's plays follow it, so V_t slews at i_lim / C toward v and never passes it. Where
    |u_t - u| C_max + |dQ_c| is within the limit (C_max: Q's largest slope) it cannot bind and Q moves at once;
    otherwise Q is read first (:func:`_pi_output_at`). A state from another model (the dynamic form keeps G's
    plays only; marker S_FR, S_FDT) has its RC factors re-formed and Q's plays formed from G's.

    Not inlined into :func:`pzt_advance`, and returning one float: the compiled loops that inline the step
    (``pzt_run``, the closed loop) keep the dynamic form's code as it was. Measured (2026-11-29, the closed loop's
    CPU time against the plain C loop's, benchmarks/closed_loop_vs_c.py, 2e6 periods, load ~3-4): f975e1a 0.84-0.85;
    this branch inlined 1.02; a call returning the pair (q_h', u') 0.96-0.99; returning q_h' alone 0.89; f975e1a
    with only a bare call in its quasi-static branch 0.88-0.89.
    """
    (r, i_src, i_snk, dt, inv_cpp, n_g, o_rg, o_wg, o_zg, n_q, o_rq, o_wq, o_zq) = (
        m[R], m[I_SRC], m[I_SNK], m[DT], m[INV_C_PP], _index(m[N_G]), _index(m[O_RG]), _index(m[O_WG]),
        _index(m[OS_ZG]), _index(m[N_Q]), _index(m[O_RQ]), _index(m[O_WQ]), _index(m[OS_ZQ]))
    if st[S_FR] != r or st[S_FDT] != dt:
        _check_segment(st, dt, r)
        _q_states_from_g(m, st, o_wg, o_zg, o_zq, n_g, u)
    u_t = v - (qc_new - f_term) * inv_cpp
    dqc = qc_new - qc_old
    q_src = i_src * dt
    q_snk = i_snk * dt
    c_q_max = 0.0                                # Q's largest slope: its largest partial sum of weights (their
    w_acc = 0.0                                  # sum where all are positive, as the inverse of a C_h whose own
    for i in range(n_q):                         # weights are; a C_h with a negative one may give Q one too)
        w_acc += m[o_wq + i]
        c_q_max = max(c_q_max, w_acc)
    span = abs(u_t - u) * c_q_max
    dq = 0.0
    limited = False
    if dqc + span > q_src or dqc - span < -q_snk:
        dq = (_pi_output_at(m, o_rq, o_wq, st, o_zq, n_q, u_t) - qh) + dqc
        limited = dq > q_src or dq < -q_snk
    if limited:
        qh_new = qh + ((q_src if dq > 0 else -q_snk) - dqc)
        u_new = _pi_update_segment(m, o_rg, o_wg, st, o_zg, n_g, qh_new, dt, r)
        _pi_update(m, o_rq, o_wq, st, o_zq, n_q, u_new)          # Q's plays follow the terminal G gives
        st[S_U] = u_new
        return qh_new
    qh_new = _pi_update(m, o_rq, o_wq, st, o_zq, n_q, u_t)
    if qh_new != qh:
        _pi_update_segment(m, o_rg, o_wg, st, o_zg, n_g, qh_new, dt, r)
    st[S_U] = u_t
    return qh_new                                           # V_t = v exactly (G's output there to rounding)


@njit(cache=True, error_model="numpy", inline="always")
def pzt_advance(p, m, st, v_cmd, f_e):
    """Advance the PZT by one sub-step; return (x, q, i, V_h, V_p).

    ``p`` is :func:`plant_params` of ``m``. Electrical part (dynamic form), split in two parts that each
    keep Kirchhoff's current law at the terminal (the terminal charge moves only by the charge through
    R): first the creep branches relax toward C_j V_h*, taking their charge from C_h's node, with V_h* the
    node voltage at the step's end on C_h's local slope (semi-implicit: the step of each branch is its exact
    one for that held V_h*; stable for any dt and tau_j, first order in dt, as the whole split); then, with the
    creep charge and force held, R dq_h/dt = u* - G[q_h] moves the charge through R into the node over the
    gap after the branches' step (so V_t -> v as R -> 0, the quasi-static form). On the local slope of G this
    is an RC relaxation; while |u* - u|/R exceeds the current limit the charge moves at the limit
    (exactly), then relaxes exponentially for the rest of the step (:func:`rc_charge`). The
    slope is the one at the start of the step; G's slope only falls as more plays engage, so
    the step never overshoots u* and creates no spurious reversal.

    Quasi-static form (R = 0, the series resistor out): the amplifier drives the terminal itself, after the same
    creep step (V_t held, k = 1 / C_pp), to V_t = v if the charge that takes is within its current limit over the
    step (Q = G^-1 at u*: its plays move there, G's follow the charge); otherwise exactly i_lim dt moves (the
    source's rising, the sink's falling) and G gives the terminal from the charge (Q's plays follow it), so V_t
    slews at i_lim / C toward v and never passes it. G's plays are kept in both forms (a state passes between
    them: Q's are formed from G's where the state comes from the dynamic form, :func:`_q_states_from_g`).

    The arithmetic is arranged for a short dependency chain per step (the physics is that of
    :func:`pzt_step_reference`, equal to ~1e-15 relative, the tests hold the two together):
    the capacitance and its exp(-dt/(R C)) worked out once per capacitance segment, the play
    pass branch-free, the creep branches and the modes as their discrete steps with the
    parts that do not depend on this step's charge formed off the chain, no division but the
    creep step's one (plants with creep, dynamic form: S = E C / (C + b_tot h)).
    """
    (r, i_src, i_snk, v_min, v_max, t_em, dt, quasi_static, inv_i_src, inv_i_snk, inv_kp, inv_cpp, inv_dt,
     n_g, o_rg, o_wg, o_zg, n_q, o_rq, o_wq, o_zq, n_c, o_cb, o_cdec, o_qc, n, o_x, o_a, o_b, o_cd, d_eff,
     r_isrc, r_isnk, k_f, k_x, b_tot, kx_c, kx_f, qs_k, k_h_min) = p
    v = min(max(v_cmd, v_min), v_max)
    qh = st[S_QH]
    u = st[S_U]
    qc_old = st[S_QC]
    q_old = qh + qc_old
    f_term = f_e * k_f                       # T_em F_e / k_p, C
    # the creep branches first, at a held terminal charge: they take their charge from C_h's node (KCL, see
    # the module docstring). Semi-implicit: each branch steps exactly toward C_j V_h* (decay_j q_j + b_j V_h*),
    # V_h* the node voltage at the step's end on the local slope k = dV_h/dq_h of the direction the branches
    # move q_h, V_h* = V_h - k S with S = E / (1 + b_tot k) their summed charge and E the charge of the
    # explicit step (V_h held). Stable for any dt and tau_j (the open-lead multiplier is d_j / (1 + b_j k),
    # in (0, 1)); first order in dt, as the explicit step.
    v_h_old = u - qh * inv_cpp
    t_c = 0.0                                # the branches' charge over G's capacitance: G's fall, V
    th_c = 0.0                               # V_t's drop from the branches' step, S / C_h, V
    if n_c > 0:
        s_dec, e_c = creep_explicit_charge(m, o_cdec, st, o_qc, n_c, b_tot, v_h_old, qc_old)
        if quasi_static:
            # V_t held: k = 1 / (C_pp + C_h) <= 1 / C_pp; any k at or above the slope is stable, first order. (In a
            # current-limited step the terminal charge is held instead, slope 1 / C_h; k = 1 / C_pp stays first order
            # and stable while b_tot / C_h < 1 + d_j + 2 b_j / C_pp: for any dt while the branches' sum C_j < C_h)
            v_h_s = v_h_old - e_c * qs_k       # creep_node_voltage with k / (1 + b_tot k) formed once (plant_params)
        else:
            # k = 1 / C_h on the segment q_h moves along (falling when the branches charge): with G's
            # capacitance C = 1 / (1/C_h + 1/C_pp), h = 1 - C / C_pp, k = h / C, S = E C / (C + b_tot h)
            # (both directions' factors formed from the state alone: the divisions stay off the step's chain)
            h_dn = 1.0 - st[S_GDN] * inv_cpp
            h_up = 1.0 - st[S_GUP] * inv_cpp
            a_dn = 1.0 / (st[S_GDN] + b_tot * h_dn)
            a_up = 1.0 / (st[S_GUP] + b_tot * h_up)
            falling = e_c > 0
            t_c = e_c * (a_dn if falling else a_up)
            v_h_s = v_h_old - t_c * (h_dn if falling else h_up)   # creep_node_voltage's V_h*, k = h / C
            # V_t's drop from the branches' charge S = t_c C for the RC step's gap, taken on C_h's largest
            # capacitance: the local slope overstates it across a reversal (there C_h is at its smallest and grows
            # as plays engage along the move) and the RC step then overfilled (V_t 0.18 V above a 90 V command at
            # dt = 10 ms); this bound never overstates it (V_t stays at or below v), exact for a linear C_h
            th_c = t_c * (st[S_GDN] if falling else st[S_GUP]) * k_h_min
        creep_branch_update(m, o_cdec, m, o_cb, st, o_qc, n_c, v_h_s)
        qc_new = s_dec + b_tot * v_h_s          # the branches' new sum from the decayed one (off the update's chain)
    else:
        qc_new = 0.0
    if quasi_static:
        if inv_i_src == 0.0 and inv_i_snk == 0.0:
            # no amplifier (PZTParams.terminal_driven: a recorded terminal voltage replayed, both limits infinite):
            # V_t = v at the step's end with the branches' new charge, Q's plays only (the step before session 37, bit
            # for bit and as fast: the calibration's replays run here). G's plays are not kept, so such a model's state
            # is not handed to another model (as before session 37)
            u_new = v - (qc_new - f_term) * inv_cpp
            qh_new = _pi_update(m, o_rq, o_wq, st, o_zq, n_q, u_new)
        else:
            # R = 0: the amplifier drives the terminal directly, within its current limit (_quasi_static_step: not
            # inlined, so the loops that inline this step keep the dynamic form's code as compact as it was)
            qh_new = _quasi_static_step(m, st, qh, u, v, qc_old, qc_new, f_term)
            u_new = st[S_U]                      # G's output the step wrote (returning a pair cost the closed loop ~8 %)
    else:
        # then R moves dq into the node over the gap left after the branches' step (V_t dropped by S over C_h, at
        # least S / C_h,max = th_c), so V_t tends to v as R -> 0 (the quasi-static form) to within that bound's
        # miss. C_h keeps dq less what the branches took.
        # (= v - (qc_new - f_term) / C_pp - (u - t_c): qc_new - qc_old = S = t_c C, and t_c (1 - C / C_pp) = th_c;
        # formed from the step's start and the drop, off the branches' sum)
        du = (v - (qc_old - f_term) * inv_cpp - u) + th_c
        dq = 0.0
        if du != 0.0:
            _check_segment(st, dt, r)
            rising = du > 0
            dq = rc_charge(du, st[S_GUP] if rising else st[S_GDN], st[S_FUP] if rising else st[S_FDN], dt, r,
                           i_src if rising else i_snk, inv_i_src if rising else inv_i_snk,
                           r_isrc if rising else r_isnk)
        qh_new = qh + (dq - (qc_new - qc_old))
        if qh_new != qh:
            u_new = _pi_update_segment(m, o_rg, o_wg, st, o_zg, n_g, qh_new, dt, r)
        else:
            u_new = u
    v_h = u_new - qh_new * inv_cpp
    q = qh_new + qc_new
    st[S_QH] = qh_new
    st[S_U] = u_new
    st[S_QC] = qc_new
    qf = q - f_term
    v_p = qf * inv_cpp
    x_qs = qf * k_x + f_e * inv_kp           # (F_e + T_em V_p) / k_p
    # modes: the quasi-static displacement drives them, taken as linear over the step
    # (first-order hold: no delay, unlike a zero-order hold of the end value). st holds
    # the modal state, a scratch copy and the previous x_qs, so the step allocates nothing.
    # The part of the new state and output not driven by this step's x_qs first (off the chain).
    if n > 0:
        x_before = st[o_x + n + n]
        x_part = 0.0
        for a in range(n):
            acc = m[o_b + a] * x_before
            for b in range(n):
                acc += m[o_a + a * n + b] * st[o_x + b]
            st[o_x + n + a] = acc
            x_part += m[o_cd + a] * acc
        for a in range(n):
            st[o_x + a] = st[o_x + n + a] + m[o_b + n + a] * x_qs
        # x = D_eff x_qs + x_part with x_qs's chain (q, x_qs) expanded: this step's hysteretic charge and the
        # held terms (the branches' new charge, the force), two operations after qh_new instead of five
        # (equal to rounding: the tests hold it to pzt_step_reference)
        x = (kx_c * qh_new + (kx_c * (qc_new - f_term) + kx_f * f_e)) + x_part
        st[o_x + n + n] = x_qs
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
def _g_output_at(m, st, qh):
    """G's output (V) if its plays were moved from their present states to the charge ``qh`` (C); nothing written."""
    o_r, o_w, o_z = int(m[O_RG]), int(m[O_WG]), int(m[OS_ZG])
    y = 0.0
    for i in range(int(m[N_G])):
        zi = min(max(st[o_z + i], qh - m[o_r + i]), qh + m[o_r + i])
        y += m[o_w + i] * zi
    return y


@njit(cache=True, error_model="numpy")
def _g_inverse_between(m, st, lo, hi, u_t):
    """The charge in [lo, hi] (C) at which :func:`_g_output_at` is ``u_t`` (V), by bisection to the last bit,
    then linear on the last interval (G is linear there). G's output at ``lo`` must be <= u_t <= that at ``hi``."""
    g_lo = _g_output_at(m, st, lo)
    g_hi = _g_output_at(m, st, hi)
    for _ in range(2000):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        g = _g_output_at(m, st, mid)
        if g < u_t:
            lo, g_lo = mid, g
        else:
            hi, g_hi = mid, g
    if g_hi > g_lo:
        return lo + (u_t - g_lo) * (hi - lo) / (g_hi - g_lo)
    return lo


@njit(cache=True, error_model="numpy")
def pzt_step_reference(m, st, v_cmd, f_e, out):
    """The step's equations in their plainest form (per-step divisions and exp): the oracle of :func:`pzt_step`.

    Same effect on ``st`` and ``out`` as :func:`pzt_step` up to rounding (~1e-15 relative);
    it also keeps the capacitance segment entries of ``st`` current, so the two can be
    mixed on one state. For tests and ``verify.closed_loop._loop_reference`` only.
    """
    r, i_src, i_snk, v_min, v_max, t_em, dt = m[R], m[I_SRC], m[I_SNK], m[V_MIN], m[V_MAX], m[T_EM], m[DT]
    inv_kp, inv_cpp = m[INV_K_P], m[INV_C_PP]
    v = min(max(v_cmd, v_min), v_max)
    qh = st[S_QH]
    u = st[S_U]
    qc_old = st[S_QC]
    q_old = qh + qc_old
    f_term = t_em * f_e * inv_kp              # T_em F_e / k_p, C
    # creep branches relax toward C_j V_h* at a held terminal charge (C_h gives what they take), semi-implicit:
    # V_h* = V_h - k S at the step's end on the local slope k, S = E / (1 + b_tot k) (pzt_advance). Written out
    # here, not through creep_explicit_charge / creep_branch_update: the reference is the step's independent first
    # formulation (each branch's target C_j V_h and its exact relaxation), which the tests hold pzt_advance to
    v_h_old = u - qh * inv_cpp
    o_cc, o_cdec, o_qc = int(m[O_CC]), int(m[O_CDEC]), int(m[OS_QC])
    n_c = int(m[N_C])
    e_c = 0.0
    b_tot = 0.0
    for j in range(n_c):
        target = m[o_cc + j] * v_h_old
        e_c += target + (st[o_qc + j] - target) * m[o_cdec + j] - st[o_qc + j]
        b_tot += (1.0 - m[o_cdec + j]) * m[o_cc + j]
    g_fall = 0.0                              # G's fall from the branches' charge, V
    if m[QUASI_STATIC] > 0.5:
        k = inv_cpp                           # V_t held: the slope is 1 / (C_pp + C_h) <= 1 / C_pp
    else:
        cap = st[S_GDN] if e_c > 0 else st[S_GUP]
        k = 1.0 / cap - inv_cpp               # 1 / C_h on the segment q_h moves along
    s_c = e_c / (1.0 + b_tot * k)
    v_h_s = v_h_old - k * s_c
    if m[QUASI_STATIC] <= 0.5:
        # G's fall from the branches' charge on its smallest slope (pzt_advance: never overstated)
        g_acc = 0.0
        g_min = math.inf
        for i in range(int(m[N_G])):
            g_acc += m[int(m[O_WG]) + i]
            g_min = min(g_min, g_acc)
        g_fall = s_c * g_min
    qc_new = 0.0
    for j in range(n_c):
        target = m[o_cc + j] * v_h_s
        qj = target + (st[o_qc + j] - target) * m[o_cdec + j]
        st[o_qc + j] = qj
        qc_new += qj
    at_v = False                              # quasi-static within the current limit: V_t = v exactly
    u_target = u
    no_amp = m[QUASI_STATIC] > 0.5 and m[INV_I_SRC] == 0.0 and m[INV_I_SNK] == 0.0
    if no_amp:
        # no amplifier (PZTParams.terminal_driven, both limits infinite): V_t = v through Q = G^-1, Q's plays only,
        # as pzt_advance (G's plays not kept: such a model's state is not handed over)
        u_target = v - (qc_new - f_term) * inv_cpp
        qh_new = _pi_update(m, int(m[O_RQ]), int(m[O_WQ]), st, int(m[OS_ZQ]), int(m[N_Q]), u_target)
        at_v = True
    elif m[QUASI_STATIC] > 0.5:
        # R = 0: the amplifier moves the terminal charge to V_t = v, G[q_h'] + (Q_c' - T_em F_e / k_p) / C_pp = v,
        # unless that takes more than its current limit over the step, i_lim dt: then it moves exactly that much.
        # Written with G alone (pzt_advance reads Q = G^-1): G's output is monotone in the charge from any state, so
        # the limit binds where G at the limit's charge is still short of u_target, and otherwise the charge in
        # between is found by bisection
        if st[S_FR] != r or st[S_FDT] != dt:
            # a state from another model (the dynamic form keeps G's plays only): Q's plays from G's, Kuhnen's map
            # z'_i = W_i z_i + sum_{j>i} w_j z_j as written (W_i: G's partial sums), and the RC factors for R = 0
            o_w, o_zg, o_zq, n_g = int(m[O_WG]), int(m[OS_ZG]), int(m[OS_ZQ]), int(m[N_G])
            for i in range(n_g):
                w_i = 0.0
                for j in range(i + 1):
                    w_i += m[o_w + j]
                tail = 0.0
                for j in range(i + 1, n_g):
                    tail += m[o_w + j] * st[o_zg + j]
                st[o_zq + i] = w_i * st[o_zg + i] + tail
            st[S_FUP], st[S_FDN] = rc_factor(st[S_GUP], dt, r), rc_factor(st[S_GDN], dt, r)
            st[S_FDT], st[S_FR] = dt, r
            st[S_PL] = st[S_PU] = np.nan
        u_target = v - (qc_new - f_term) * inv_cpp
        qh_up = qh + (i_src * dt - (qc_new - qc_old))
        qh_dn = qh + (-i_snk * dt - (qc_new - qc_old))
        if u_target == u:
            qh_new = qh                       # V_t at v already: no charge moves
            at_v = True
        elif _g_output_at(m, st, qh_up) < u_target:
            qh_new = qh_up
        elif _g_output_at(m, st, qh_dn) > u_target:
            qh_new = qh_dn
        else:
            qh_new = _g_inverse_between(m, st, qh_dn, qh_up, u_target)
            at_v = True
    else:
        # then the charge through R into the node, over the gap after the branches' step
        du = v - (qc_new - f_term) * inv_cpp - (u - g_fall)
        dq = 0.0
        if du != 0.0:
            if du > 0:
                d = 1.0
                cap = st[S_GUP]
                i_lim = i_src
                inv_i = m[INV_I_SRC]
            else:
                d = -1.0
                cap = st[S_GDN]
                i_lim = i_snk
                inv_i = m[INV_I_SNK]
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
        qh_new = qh + (dq - (qc_new - qc_old))
    # G's plays to the new charge (both forms: the quasi-static one keeps them too; not without an amplifier)
    if qh_new != qh and not no_amp:
        o_r, o_w, o_z = int(m[O_RG]), int(m[O_WG]), int(m[OS_ZG])
        y = 0.0
        up = 0.0
        dn = 0.0
        for i in range(int(m[N_G])):
            ri = m[o_r + i]
            wi = m[o_w + i]
            lo = qh_new - ri
            hi = qh_new + ri
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
        st[S_KUP], st[S_KDN] = up, dn
        st[S_FUP], st[S_FDN] = rc_factor(st[S_GUP], dt, r), rc_factor(st[S_GDN], dt, r)
        st[S_PL] = st[S_PU] = np.nan     # the fast step runs every play next
        st[S_FDT], st[S_FR] = dt, r
        u_new = y
    else:
        u_new = u
    if at_v:
        u_new = u_target                      # V_t = v exactly (G's output there to rounding)
    if m[QUASI_STATIC] > 0.5:
        # Q's plays follow the terminal voltage (the quasi-static form keeps them beside G's)
        o_r, o_w, o_z = int(m[O_RQ]), int(m[O_WQ]), int(m[OS_ZQ])
        for i in range(int(m[N_Q])):
            st[o_z + i] = min(max(st[o_z + i], u_new - m[o_r + i]), u_new + m[o_r + i])
    v_h = u_new - qh_new * inv_cpp
    q = qh_new + qc_new
    st[S_QH] = qh_new
    st[S_U] = u_new
    st[S_QC] = qc_new
    v_p = (q - f_term) * inv_cpp
    x_qs = (f_e + t_em * v_p) * inv_kp
    n = int(m[N_M])
    if n > 0:
        o_x, o_a, o_b, o_cd = int(m[OS_XM]), int(m[O_AD]), int(m[O_BD]), int(m[O_CD])
        x_before = st[o_x + n + n]
        for a in range(n):
            acc = m[o_b + a] * x_before + m[o_b + n + a] * x_qs
            for b in range(n):
                acc += m[o_a + a * n + b] * st[o_x + b]
            st[o_x + n + a] = acc
        x = m[int(m[O_DD])] * x_qs
        for a in range(n):
            st[o_x + a] = st[o_x + n + a]
            x += m[o_cd + a] * st[o_x + a]
        st[o_x + 2 * n] = x_qs
    else:
        x = x_qs
    out[0] = x
    out[1] = q
    out[2] = (q - q_old) * m[INV_DT]
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
    m, st = _borrowed(m), _borrowed(st)         # no reference count per step (see _borrowed)
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
