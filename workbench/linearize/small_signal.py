"""Small-signal models of the PZT at an operating point on its hysteresis loop.

Around an operating point the hysteretic capacitance C_h acts, for small motion, as
its incremental slope there: the sum of the weights of the plays the motion drags.
Which plays those are depends on the history, so the operating point is a bias V0
reached along a branch:

- ``initial``: from rest straight up to V0 (the virgin curve);
- ``ascending`` / ``descending``: on the major loop of the range (lo, hi), rising
  from lo or falling from hi to V0;
- ``reversal``: at V0 on the ascending branch, just after the input turns back.
  Only the r = 0 play moves, so this slope (w_0) is the smallest.

The path is followed slowly (the creep branches settled, so they add their
capacitance to C_h: the charge is (C_h + sum C_j)[V_h], which fixes V_h and x0).
The linear model then keeps R, the creep branches as first-order relaxations, C_pp
and the modes: V_pea -> (x, i) as a python-control StateSpace. States are scaled
to volts (charge over a capacitance) so the matrices stay well conditioned.
"""

from dataclasses import dataclass

import control
import numpy as np

__all__ = ["BRANCHES", "OperatingPoint", "operating_point", "small_signal_model", "dc_gain_m_per_v",
           "capacitances"]

BRANCHES = ("initial", "ascending", "descending", "reversal")


@dataclass(frozen=True)
class OperatingPoint:
    """Where the stack sits: bias, branch, the voltage across C_h, x, and C_h's slope there."""

    branch: str
    bias_v: float
    v_h_v: float
    x_m: float
    capacitance_f: float


def _settled_operator(pzt):
    """V_t -> total charge with the creep branches settled: (C_h + sum C_j) in series with C_pp."""
    ch = pzt.hysteresis
    if pzt.creep is not None:
        ch = ch.plus_linear(float(np.sum(pzt.creep.capacitances_f)))
    return ch.inverse().plus_linear(1.0 / pzt.c_pp_f).inverse()


def _path(branch, bias_v, lo_v, hi_v):
    """Voltage vertices from rest (0 V) to the operating point, and the last direction of motion."""
    if branch == "initial":
        return [0.0, bias_v], 1.0 if bias_v >= 0 else -1.0
    if branch in ("ascending", "reversal"):
        return [0.0, hi_v, lo_v, bias_v], 1.0
    if branch == "descending":
        return [0.0, lo_v, hi_v, bias_v], -1.0
    raise ValueError(f"unknown branch {branch!r}; expected one of {', '.join(BRANCHES)}")


def operating_point(pzt, bias_v, branch, v_range=(0.0, 100.0)):
    """The operating point at ``bias_v`` on ``branch`` (see the module docstring).

    Parameters
    ----------
    pzt : PZTParams
    bias_v : float
        V0, inside ``v_range`` for the loop branches.
    branch : str
        One of :data:`BRANCHES`.
    v_range : (float, float)
        The major loop (lo, hi), V, inside the amplifier range.
    """
    lo, hi = map(float, v_range)
    if not (pzt.voltage_min_v <= lo < hi <= pzt.voltage_max_v):
        raise ValueError(f"v_range {v_range} must lie inside the amplifier range "
                         f"[{pzt.voltage_min_v:g}, {pzt.voltage_max_v:g}] V with lo < hi")
    if branch != "initial" and not lo <= bias_v <= hi:
        raise ValueError(f"bias {bias_v:g} V is outside the loop range [{lo:g}, {hi:g}] V")
    vertices, direction = _path(branch, float(bias_v), lo, hi)
    if branch == "reversal":
        direction = -direction
    v = np.array(vertices)
    q = _settled_operator(pzt)(v)
    v_h = v - q / pzt.c_pp_f
    # V_h is monotone in V along each segment (dV_h/dV = 1 - C_series/C_pp > 0), so the
    # vertices carry the whole history for the rate-independent C_h
    states = pzt.hysteresis.final_states(v_h)
    slope = pzt.hysteresis.slope(v_h[-1], direction, states)
    return OperatingPoint(branch, float(bias_v), float(v_h[-1]), float(pzt.k_q2x_m_per_c * q[-1]), float(slope))


def _modes_ss(modes, gain):
    """Cascade of unit-DC-gain modes times ``gain``, states scaled like the input.

    Each mode in the form (y, y'/w): entries of order w rather than the companion
    form's w^2, which keeps the 70 kHz mode and the creep's millihertz poles in one
    well-conditioned matrix.
    """
    sys = control.ss([], [], [], [[gain]])
    for m in modes:
        w, z = 2 * np.pi * m.freq_hz, m.damping_ratio
        sys = control.series(sys, control.ss([[0.0, w], [-w, -2 * z * w]], [[0.0], [w]], [[1.0, 0.0]], [[0.0]]))
    return sys


def small_signal_model(pzt, capacitance_f, name=None):
    """Linear PZT with C_h replaced by the incremental capacitance ``capacitance_f``.

    Input ``v`` (V_pea, V); outputs ``x`` (m) and ``i`` (A) when R > 0, ``x`` only in
    the quasi-static form (R = 0: the current would be an improper derivative).
    States: u = q / C_pp (V) for the total charge q, u_j = Q_j / C_j (V) for each creep
    branch, then the modes (unit DC gain, driven by the quasi-static displacement).
    """
    if not capacitance_f > 0:
        raise ValueError(f"incremental capacitance must be positive; got {capacitance_f}")
    c_h, c_pp, r = float(capacitance_f), pzt.c_pp_f, pzt.series_resistance_ohm
    cj = np.zeros(0) if pzt.creep is None else pzt.creep.capacitances_f
    tau = np.zeros(0) if pzt.creep is None else pzt.creep.time_constants_s
    n = cj.size
    # V_h = (q - sum Q_j) / c_h = (C_pp u - sum C_j u_j) / c_h, a row over the states [u, u_j]
    vh_row = np.concatenate([[c_pp / c_h], -cj / c_h])
    if r > 0:
        # R dq/dt = V - V_h - u:  du/dt = (V - V_h - u) / (R C_pp)
        a_u = (-vh_row - np.eye(1, n + 1)[0]) / (r * c_pp)
        b_u = 1.0 / (r * c_pp)
        a_c = np.zeros((n, n + 1))
        for j in range(n):
            # dQ_j/dt = (C_j V_h - Q_j)/tau_j:  du_j/dt = (V_h - u_j)/tau_j
            a_c[j] = vh_row / tau[j]
            a_c[j, 1 + j] -= 1.0 / tau[j]
        a = np.vstack([a_u, a_c])
        b = np.concatenate([[b_u], np.zeros(n)])[:, None]
        c_x = np.eye(1, n + 1)[0] * c_pp * pzt.k_q2x_m_per_c
        c_i = a_u * c_pp
        c = np.vstack([c_x, c_i])
        d = np.array([[0.0], [b_u * c_pp]])
        outputs = ["x", "i"]
    else:
        if n == 0:
            gain = pzt.k_q2x_m_per_c / (1.0 / c_h + 1.0 / c_pp)
            a, b, c, d = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[gain]])
        else:
            # V = V_h + q/C_pp with q = c_h V_h + sum Q_j: V_h = (V - sum Q_j / C_pp) / (1 + c_h/C_pp)
            k = 1.0 / (1.0 + c_h / c_pp)
            a = np.zeros((n, n))
            for j in range(n):
                a[j] = -k * cj / c_pp / tau[j]
                a[j, j] -= 1.0 / tau[j]
            b = np.full((n, 1), k) / tau[:, None]
            c = (pzt.k_q2x_m_per_c * (cj - c_h * k * cj / c_pp))[None, :]
            d = np.array([[pzt.k_q2x_m_per_c * c_h * k]])
        outputs = ["x"]
    sys = control.ss(a, b, c, d)
    if pzt.modes:
        # modes act on x only: scale x to volts (u) before them and back after
        k = pzt.k_q2x_m_per_c * c_pp
        mode = _modes_ss(pzt.modes, k)
        pre = np.diag([1.0 / k] + [1.0] * (len(outputs) - 1))
        extra = control.ss([], [], [], np.eye(len(outputs) - 1)) if len(outputs) > 1 else None
        post = mode if extra is None else control.append(mode, extra)
        sys = control.series(control.series(sys, control.ss([], [], [], pre)), post)
    return control.ss(sys.A, sys.B, sys.C, sys.D, inputs=["v"], outputs=outputs,
                      name=name or f"pzt_small_signal_{round(c_h * 1e9)}nF")


def dc_gain_m_per_v(pzt, capacitance_f):
    """Static V_pea -> x of the small-signal model: creep settled, so C_h + sum C_j in series with C_pp."""
    c = capacitance_f + (0.0 if pzt.creep is None else float(np.sum(pzt.creep.capacitances_f)))
    return pzt.k_q2x_m_per_c / (1.0 / c + 1.0 / pzt.c_pp_f)


def capacitances(pzt, bias_v=50.0, v_range=(0.0, 100.0)):
    """The capacitances a designer compares, F: reversal slope, on-branch slopes, secants.

    ``secant_from_rest_f`` is the chord from rest to the peak of a slow 0 -> hi sweep,
    q_h / V_h there (the seed's ~30.5 uF large-signal value); ``loop_secant_f`` the
    chord of the periodic major loop, (max q_h - min q_h) / (max V_h - min V_h).
    """
    out = {f"{b}_f": operating_point(pzt, bias_v, b, v_range).capacitance_f for b in BRANCHES}
    lo, hi = map(float, v_range)
    ch = pzt.hysteresis
    q_of_v = ch.inverse().plus_linear(1.0 / pzt.c_pp_f).inverse()
    v = np.array([0.0, hi, lo, hi, lo])
    qh = q_of_v(v)
    v_h = v - qh / pzt.c_pp_f
    out["secant_from_rest_f"] = float(qh[1] / v_h[1])
    out["loop_secant_f"] = float((qh[3] - qh[2]) / (v_h[3] - v_h[2]))
    return out
