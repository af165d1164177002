"""MIMO design of the three-stack mirror: kinematic decoupling, per-axis loop shaping, active damping (issue 15, item 4).

**Decoupling** (what practice does). The firmware reads the three gauges g (firmware V), turns
them into elongations with each chain's nominal gain K_g,j and into the mirror's axes with the
kinematics K (:attr:`~workbench.plant.mirror.FastSteeringMirror.kinematics`):
q_hat = K diag(1/K_g) g. Each axis controller's output is an axis command u (rad, rad, m) that
the inverse kinematics turn into elongations and each stack's DC gain p_j (m per V on the
mirror's static stiffness, from the nominal member) into voltages: v = diag(1/p) K^-1 u. The
decoupled plant G_dec = K diag(1/K_g) G_gv diag(1/p) K^-1 has DC gain I on the nominal member
(the stacks' elongations do not couple statically; the structure's static map is K).

**Per-axis loops.** Tip, tilt and piston each get the structured controller of
:mod:`~workbench.design.loopshape` (PI + lead + roll-off [+ notch]), tuned with
:func:`~workbench.design.loopshape.tune_loop_shape` shape by shape on that axis' diagonal of the
decoupled family (every member, sampled chain: hold, period-averaging gauge, compute delay); the
shape whose worst member's closed-loop bandwidth is highest wins.

**Notch-only design**: a notch at each axis' structural resonance (the largest peak of the
nominal diagonal above 100 Hz; width to cover its spread over the family).

**Active damping** with the stack's own signals: integral force feedback (IFF). The force each
stack puts on the structure, F = T V_p, follows from the charge q = integral of the stack
current and its gauge elongation x with the stack's own T_em and C_p (Fig. 3: V_p = (q -
T x_dyn) / C_pp, x = x_dyn + r F, C_pp = C_p + T^2 r):

    F_hat = T (q - T x) / C_p,

and each stack's voltage gets v_j = v_outer,j - g s / (s + w_l) F_hat_j: the amplifier's R in series
with the stack's capacitance integrates the command into charge, so a gain high-passed at w_l
(:func:`iff_corner_hz`: no force loop at DC, where the bridge drifts; as high as the outer loop's
phase allows) is integral force feedback. The gain g maximizes the smallest damping ratio of the flexure modes
on the nominal member, with the firmware's two-sample loop delay (Pade) in the loop, among the
gains whose sampled IFF loops keep PM/GM and that keep every small-signal member stable (and, with a
noise budget, whose force-estimate noise keeps each stack's command inside its current window:
:func:`iff_command_noise_v`). The
outer loops are then tuned on the damped family, without a notch. The force estimate above has the
gauge in it (its noise reaches the drive x T^2 / C_p); ``iff_source="bridge"`` uses instead what the
stack's charge amplifier with a reference capacitor C_R reads, F_hat = T (V_t - q / C_R) (the force
itself where C_h = C_R; no gauge), and ``"charge"`` the charge alone, T q / C_p (:func:`force_estimate`).

**Margins.** Loop-at-a-time: axis i broken with the other two closed, l_i = L_ii - L_io (I +
L_oo)^-1 L_oi (:func:`loop_at_a_time`). Simultaneous: the balanced (skew 0) multiloop disk
margin alpha = 1 / max_w mu(S - I/2) for independent complex perturbations in each channel
(upper bound of mu by slycot's AB13MD, as python-control's ``disk_margins``), beside the
unstructured bound 1 / max_w sigma_max(S - I/2) <= alpha (:func:`mimo_disk_margin`), at the
stack inputs (each amplifier's gain and phase) and at the axis outputs.
"""

import warnings
from dataclasses import dataclass, field, replace

import control
import numpy as np
from slycot import ab13md

from .margins import closed_loop_bandwidth_hz
from ..linearize.limit_cycle import sampled_factor
from ..linearize.mimo import gauge_gains
from .antiwindup import discretize
from ..errors import DesignError
from .loopshape import LoopShapeSpec, family_loops, tune_loop_shape
from .margins import family_margins, loop_margins, response
from .nominal import NOMINAL_BIAS_V, NOMINAL_BRANCH, SLOW_HZ, minimal

__all__ = ["Decoupler", "kinematic_decoupler", "member_responses", "force_estimate", "bridge_capacitances_f", "IFF", "IFF_SOURCES", "iff_response",
           "tune_iff", "iff_corner_hz", "stack_charge_amps", "IFF_PHASE_COST_DEG", "IFF_DRIFT_MARGIN", "IFF_MIN_OUTER_NOISE_SHARE", "force_noise_n", "iff_command_noise_v",
           "check_iff_noise", "axis_resonances_hz", "damped_gauges", "decoupled", "mimo_disk_margin", "closed_loop_bandwidth_hz", "lowest_bandwidth_hz", "closed_loop_poles", "loop_at_a_time", "MimoDesign",
           "design_mimo", "MIMO_SPEC", "default_freq_hz", "nominal_name", "AXIS_NAMES"]

G = ["g0", "g1", "g2"]
V = ["v0", "v1", "v2"]
X = ["x0", "x1", "x2"]
I_ = ["i0", "i1", "i2"]
AXIS_NAMES = ("tip", "tilt", "piston")


def nominal_name(bias_v=NOMINAL_BIAS_V, branch=NOMINAL_BRANCH):
    """The family member :mod:`~workbench.design.nominal` calls nominal (ascending at 50 V, K_g nominal)."""
    return f"{branch} at {bias_v:g} V, K_g nom"


def default_freq_hz(dt_s=1e-4, n=700):
    """Log grid from 1 Hz to 0.49 / dt_s, refined (linear, 2 Hz) over 200-2000 Hz where the modes are, Hz."""
    top = 0.49 / dt_s
    return np.unique(np.concatenate([np.geomspace(1.0, top, n), np.arange(200.0, min(2000.0, top), 2.0)]))


@dataclass(frozen=True)
class Decoupler:
    """Static decoupling: q_hat = ``out_q_per_v`` g (axes per firmware V); v = ``in_v_per_q`` u (V per axis unit)."""

    out_q_per_v: np.ndarray
    in_v_per_q: np.ndarray


def kinematic_decoupler(fsm, nominal_member, gauge_v_per_m=None):
    """The kinematic decoupler of the module docstring.

    Parameters
    ----------
    fsm : FastSteeringMirror
    nominal_member : control.StateSpace
        A :func:`~workbench.linearize.mimo.mirror_small_signal` member; its DC gains v_j -> x_j
        (m per V) set the per-stack voltage scaling.
    gauge_v_per_m : array_like, shape (3,), optional
        The chains' gains the firmware assumes (default: nominal,
        :func:`~workbench.linearize.mimo.gauge_gains`).
    """
    kg = gauge_gains(fsm)[:, 0] if gauge_v_per_m is None else np.asarray(gauge_v_per_m, float)
    p = np.diag(np.asarray(nominal_member[X, V].dcgain()))
    return Decoupler(fsm.kinematics @ np.diag(1.0 / kg), np.diag(1.0 / p) @ fsm.inverse_kinematics)


def member_responses(member, freq_hz, outputs):
    """Response of ``member`` (StateSpace or FRD) from v0..v2 to ``outputs``, shape (freqs, 3, 3).

    An FRD gives its own samples where ``freq_hz`` matches its grid (1e-9 relative) and NaN elsewhere.
    """
    f = np.asarray(freq_hz, float)
    sub = member[outputs, V]
    if isinstance(sub, control.FRD):
        out = np.full((f.size, 3, 3), np.nan + 0j)
        fo = np.asarray(sub.omega) / (2 * np.pi)
        for k, fk in enumerate(f):
            j = np.flatnonzero(np.isclose(fo, fk, rtol=1e-9, atol=0))
            if j.size:
                out[k] = np.asarray(sub.fresp)[:, :, j[0]]
        return out
    return np.moveaxis(np.asarray(sub(2j * np.pi * f)).reshape(3, 3, f.size), -1, 0)


def _force_consts(fsm):
    t = np.array([pz.transducer_constant_n_per_v for pz in fsm.stacks])
    cp = np.array([pz.working_capacitance_f for pz in fsm.stacks])
    return t, cp


IFF_SOURCES = ("charge+gauge", "charge", "bridge")


def _gauge_weight(source):
    """1 if the force estimate subtracts the gauge's T x (``"charge+gauge"``), 0 otherwise."""
    if source not in IFF_SOURCES:
        raise ValueError(f"IFF source must be one of {IFF_SOURCES}; got {source!r}")
    return 1.0 if source == "charge+gauge" else 0.0


def bridge_capacitances_f(fsm, bias_v=NOMINAL_BIAS_V, branch=NOMINAL_BRANCH):
    """Each stack's incremental C_h at the nominal operating point, F: the bridge's reference capacitor C_R."""
    from ..linearize.small_signal import operating_point
    return tuple(float(operating_point(pz, bias_v, branch).capacitance_f) for pz in fsm.stacks)


def force_estimate(fsm, member, freq_hz, source="charge+gauge", bridge_capacitance_f=None):
    """v -> F_hat per stack (N per V), q = i / (j w), shape (freqs, 3, 3).

    ``source="charge+gauge"``: F_hat = T (q - T x) / C_p, the force on the structure (the gauge's
    elongation x removes the mechanical part of the charge). ``source="charge"``: F_hat = T q / C_p,
    the charge alone (scaled to newtons the same way): the electrical part stays in it, but none of
    the gauge's noise (7.1 mV per reading is ~8 N of T^2 x / C_p on the P-888.51; the charge
    amplifier's 2.4 nC is ~0.02 N). ``source="bridge"``: F_hat = T (V_t - q / C_R) with V_t = v - R i
    the stack's terminal voltage and C_R = ``bridge_capacitance_f`` (the nominal incremental C_h,
    :func:`bridge_capacitances_f`): the charge amplifier with its reference capacitor
    (:mod:`workbench.selfsense.charge_amp`, V_out = -(q - C_R V_t) / C_int) reads -C_R V_p, so this is
    T V_p, the force itself (exact on a member whose C_h is C_R, without creep), with no gauge in it.
    """
    f = np.asarray(freq_hz, float)
    t, cp = _force_consts(fsm)
    i = member_responses(member, f, I_)
    q = i / (2j * np.pi * f)[:, None, None]
    if source == "bridge":
        r = np.array([pz.series_resistance_ohm for pz in fsm.stacks])
        cr = np.asarray(bridge_capacitances_f(fsm) if bridge_capacitance_f is None else bridge_capacitance_f, float)
        return t[None, :, None] * (np.eye(3)[None] - r[None, :, None] * i - q / cr[None, :, None])
    x = member_responses(member, f, X)
    return (t / cp)[None, :, None] * (q - _gauge_weight(source) * t[None, :, None] * x)


def _force_rows(fsm, member, iff):
    """(C, D) of v -> F_hat (``iff``'s source) over ``member``'s states: rows appended to its StateSpace."""
    t, cp = _force_consts(fsm)
    st = fsm.structure()
    n = st.n_states
    sub = control.ss(member[X + I_, V])
    cq = np.zeros((3, sub.nstates))
    cq[:, n:n + 3] = np.diag(cp + t * t * st.residual_compliance_m_per_n)     # q_j from the states
    cx, dx, ci, di = sub.C[:3], sub.D[:3], sub.C[3:], sub.D[3:]
    if iff.source == "bridge":
        r = np.array([pz.series_resistance_ohm for pz in fsm.stacks])
        cr = np.asarray(iff.bridge_capacitance_f, float)
        return t[:, None] * (-r[:, None] * ci - cq / cr[:, None]), t[:, None] * (np.eye(3) - r[:, None] * di)
    w = _gauge_weight(iff.source)
    return (t / cp)[:, None] * (cq - w * t[:, None] * cx), -(t / cp)[:, None] * w * t[:, None] * dx


@dataclass(frozen=True)
class IFF:
    """Integral force feedback per stack through the amplifier: v_j -= gain s / (s + w_l) F_hat_j, w_l = 2 pi corner_hz.

    The amplifier's series R with the stack's capacitance is the integrator (v -> F_hat lags
    60-75 deg over 300-1000 Hz on the P-888.51 mirror), so the firmware's part is a gain (V per N)
    high-passed at w_l: no force loop at DC, where it would fight the outer loops' commands.
    """

    gain_v_per_n: float
    corner_hz: float
    source: str = "charge+gauge"
    bridge_capacitance_f: tuple = None     # C_R per stack (F), for source "bridge"

    def __post_init__(self):
        _gauge_weight(self.source)
        if self.source == "bridge" and (self.bridge_capacitance_f is None or len(self.bridge_capacitance_f) != 3
                                        or not all(c > 0 for c in self.bridge_capacitance_f)):
            raise ValueError(f"an IFF from the bridge needs three positive reference capacitances; "
                             f"got {self.bridge_capacitance_f!r}")

    def tf(self):
        """The controller as a continuous TransferFunction (V per N)."""
        return control.tf([self.gain_v_per_n, 0.0], [1.0, 2 * np.pi * self.corner_hz])


def iff_response(iff, freq_hz, dt_s, delay_samples=1):
    """The sampled IFF controller's response times the firmware chain (hold, averaging, delay), V per N."""
    ctrl_d = discretize(iff.tf(), dt_s, iff.corner_hz)
    return response(ctrl_d, freq_hz) * sampled_factor(freq_hz, dt_s, delay_samples)


# the phase the IFF's low-frequency doublet may take from an outer loop at the lowest crossover searched, deg.
# ASSUMED design choice (as the notch depth is). The tuner's margins see the doublet anyway (the damped
# members carry it), so this only trades the crossover the outer loops can reach against the tail of the
# doublet's slow pole (:func:`iff_corner_hz`).
IFF_PHASE_COST_DEG = 10.0

# the factor by which the IFF corner must clear the fastest drift the bridge reads. ASSUMED design choice: a
# first-order high-pass passes a drift at f_d with gain f_d / sqrt(f_d^2 + f_l^2), so at f_l >= 3 f_d at most
# 1 / sqrt(10) = 32 % (-10 dB) of it reaches the IFF's command; with f_l barely above f_d ~70 % of it does, and
# the drift is then fed back as if it were force.
IFF_DRIFT_MARGIN = 3.0

# the smallest share of each stack's noise budget (amplitude: the outer loops' rho is scaled by it) the IFF may
# leave the outer loops before design_mimo warns. ASSUMED: 1/sqrt(2), an equal split of the budget's variance
# between the two uncorrelated contributions (the IFF's bridge noise, the outer loops' gauge noise): below it
# the damping loop takes more of the current window than the tracking loops the floors are set on.
IFF_MIN_OUTER_NOISE_SHARE = float(1.0 / np.sqrt(2.0))


def iff_corner_hz(fsm, fc_min_hz, phase_cost_deg=IFF_PHASE_COST_DEG, amp=None, drift_margin=IFF_DRIFT_MARGIN):
    """The IFF high-pass corner f_l, Hz: the one place it is derived (design, study and export take it from here).

    Upper bound, the servo band. Between f_l and the amplifier's R C corner (~70 Hz) v -> F_hat is
    flat, so an IFF with loop gain L0 there turns each axis plant into P / (1 + L0) (s + w_l) / (s +
    w_l / (1 + L0)): a lag doublet whose phase at an outer crossover f_c is atan(f_l / f_c) - atan(f_l /
    ((1 + L0) f_c)) < atan(f_l / f_c), whatever the gain. f_l = tan(``phase_cost_deg``) ``fc_min_hz``
    keeps it under ``phase_cost_deg`` at the lowest crossover the outer loops may take (8.8 Hz for 10
    deg at 50 Hz), and under less at any higher one. (The RC corner sits near these crossovers, so the
    real lag differs from the doublet's; tests/design measures it on the damped nominal: under 10 deg.)
    The corner is taken at that bound, as high as the band allows, because the doublet leaves a slow
    closed-loop pole near w_l whose tail decays with 1 / (2 pi f_l): at 0.88 Hz (0.1 % of the lowest
    flexure mode, session 9's first choice) the verified mirror still pulled its 78 urad open-loop tilt
    in 0.1 s after the loop started (README, mirror section); at 8.8 Hz the tail lasts 18 ms.

    Lower bound, the drifts. Besides the force, the charge bridge reads charges that drift: the charge
    amplifier's leakage (R_FP C_int) and dielectric absorption, each stack's own channel
    (:func:`stack_charge_amps`: its plant file's ``[leakage]`` and ``[dielectric_absorption]`` when given, else
    the assumed :class:`~workbench.selfsense.charge_amp.ChargeAmpParams`; ``amp`` for all three when passed),
    and each stack's creep branches if its file has them. The corner must lie ``drift_margin`` (:data:`IFF_DRIFT_MARGIN`) times above the fastest of
    them, 1 / (2 pi tau_min), or the high-pass passes them into the drive. Check it against the mirror the
    verification runs (its creep branches: :func:`workbench.verify.mirror.verification_mirror`), as the
    study does, not only against serial files without creep.

    Returns
    -------
    corner_hz : float
    info : dict
        ``drift_hz`` (1 / (2 pi tau_min)), ``drift_source``, ``drift_margin`` (corner / drift_hz) and
        ``drift_gain`` (the high-pass's gain at drift_hz, f_d / sqrt(f_d^2 + f_l^2)).

    Raises
    ------
    DesignError
        When the band's bound lies at or below the drift bound.
    """
    amps = stack_charge_amps(fsm, amp)
    shared = all(a == amps[0] for a in amps)
    taus = {}
    for j, a in enumerate(amps[:1] if shared else amps):
        who = "the charge amplifier's" if shared else f"stack {j}'s charge amplifier's"
        taus[f"{who} R_FP C_int"] = a.r_leak_ohm * a.c_int_f
        for k, t in enumerate(a.da_time_constants_s):
            taus[f"{who} dielectric absorption {k + 1}"] = float(t)
    for j, pz in enumerate(fsm.stacks):
        if pz.creep is not None:
            taus[f"stack {j}'s fastest creep branch"] = float(np.min(pz.creep.time_constants_s))
    src = min(taus, key=taus.get)
    drift_hz = 1.0 / (2 * np.pi * taus[src])
    corner = float(np.tan(np.radians(phase_cost_deg)) * fc_min_hz)
    if not corner >= drift_margin * drift_hz:
        raise DesignError(f"the IFF high-pass corner tan({phase_cost_deg:g} deg) x {fc_min_hz:g} Hz = {corner:.3g} Hz "
                          f"(the lowest crossover searched) lies below {drift_margin:g} x {drift_hz:.3g} Hz, the "
                          f"drift of {src} (tau {taus[src]:.3g} s) the bridge reads: raise the lowest crossover "
                          f"(fc_range_hz) to at least {drift_margin * drift_hz / np.tan(np.radians(phase_cost_deg)):.3g}"
                          f" Hz")
    return corner, {"drift_hz": float(drift_hz), "drift_source": src, "drift_margin": float(corner / drift_hz),
                    "drift_gain": float(drift_hz / np.hypot(drift_hz, corner))}


def stack_charge_amps(fsm, amp=None):
    """Each stack's charge channel, a list of three :class:`~workbench.selfsense.charge_amp.ChargeAmpParams`.

    ``amp`` given: that one channel for all three stacks. Else :func:`~workbench.selfsense.charge_amp.charge_amp_params`
    of each stack's own plant file (``fsm.plants[j]``): the assumed circuit with that file's ``[leakage]``
    R_FP (ohm) and ``[dielectric_absorption]`` relaxation (F, s) when it gives them.
    """
    from ..selfsense.charge_amp import charge_amp_params
    return [amp] * 3 if amp is not None else [charge_amp_params(pl) for pl in fsm.plants]


def force_noise_n(fsm, source, bridge_capacitance_f=None, amp=None):
    """RMS noise of each stack's force estimate per reading, N (3,), from the sensors' noise in the plant files.

    ``"bridge"``: the charge amplifier's output noise and ADC LSB (sqrt(n^2 + lsb^2 / 12)) times T C_int / C_R;
    ``"charge"``: the same reading times T C_int / C_p (q = C_int b); ``"charge+gauge"``: that plus the gauge's
    reading noise as elongation (sigma_g / K_g) times T^2 / C_p.
    """
    from ..plant.gauge import demod_noise_sigma_v
    from ..selfsense.charge_amp import adc_lsb_v
    amps = stack_charge_amps(fsm, amp)
    t, cp = _force_consts(fsm)
    sb = np.array([np.hypot(a.out_noise_v_rms, adc_lsb_v(a.adc_bits, a.adc_range_v) / np.sqrt(12.0)) for a in amps])
    c_int = np.array([a.c_int_f for a in amps])
    _gauge_weight(source)
    if source == "bridge":
        cr = np.asarray(bridge_capacitances_f(fsm) if bridge_capacitance_f is None else bridge_capacitance_f, float)
        return t * c_int / cr * sb
    q = t * c_int / cp * sb
    if source == "charge":
        return q
    sg = np.array([demod_noise_sigma_v(p.gauge) * p.gauge.trim_scale for p in fsm.plants]) / gauge_gains(fsm)[:, 0]
    return np.hypot(q, t * t / cp * sg)


def iff_command_noise_v(fsm, iff, dt_s):
    """RMS lead of each stack's command over its RC model from the IFF's force-estimate noise, V (3,).

    White noise sigma_F (:func:`force_noise_n`) through the sampled IFF cascade C(z) and the lead
    H = (1 - z^-1) / (1 - (1 - alpha) z^-1) of the command over the stack's model v <- v + alpha (u - v)
    (alpha of its current-limit window, :func:`~workbench.controller.plant_window`): sigma^2 = sigma_F^2
    (1/pi) int_0^pi |H C|^2 d theta, as the outer loops' noise budget is scored
    (:func:`~workbench.design.loopshape.noise_command_rms_v`). The IFF loop's own sensitivity is left out
    (it is ~1 where H C is largest, above the flexure modes).
    """
    from ..controller import plant_window
    from .loopshape import _noise_grid, _noise_rms
    f = _noise_grid(dt_s)
    k = response(discretize(iff.tf(), dt_s, iff.corner_hz), f)
    sf = force_noise_n(fsm, iff.source, iff.bridge_capacitance_f)
    out = np.empty(3)
    for j, pl in enumerate(fsm.plants):
        w = plant_window(pl, dt_s)
        out[j] = _noise_rms(k, 0.0, f, dt_s, sf[j], 1, None if w is None else w[0])
    return out


def check_iff_noise(fsm, iff, dt_s):
    """Refuse an IFF whose force-estimate noise alone breaks a stack's current-window noise budget.

    The budget is the outer loops': R min(I_source, I_sink) / 3 RMS of command lead per stack
    (:func:`~workbench.design.budgets.plant_budgets`, from each serial file). Returns (lead V RMS (3,),
    budgets V (3,); NaN without a series resistor). Raises :class:`DesignError` naming the stack, the
    numbers and the largest gain that fits (the lead is proportional to the gain).
    """
    from .budgets import NOISE_SIGMAS, plant_budgets
    lead = iff_command_noise_v(fsm, iff, dt_s)
    b = np.array([np.nan if (v := plant_budgets(pl, dt_s)["noise_command_v"].value) is None else v
                  for pl in fsm.plants], float)
    over = np.flatnonzero(lead > b)
    if over.size:
        j = int(over[np.argmax(lead[over] / b[over])])
        gmax = abs(iff.gain_v_per_n) * float(np.nanmin(b / lead))
        raise DesignError(f"the IFF gain {iff.gain_v_per_n:.3g} V/N puts {1e3 * lead[j]:.3g} mV RMS of force-estimate "
                          f"noise ({iff.source}) on stack {j}'s command lead over its RC model, over its current "
                          f"window's noise budget R min(I_source, I_sink) / {NOISE_SIGMAS:g} = {1e3 * b[j]:.3g} mV "
                          f"({fsm.plants[j].source}); use at most {gmax:.3g} V/N")
    return lead, b


def _iff_closed(fsm, member, iff, dt_s):
    """Continuous v_outer -> (x, F_hat) of ``member`` with IFF closed through a 2nd-order Pade of the 2-sample delay."""
    # q_j from the states (mirror_small_signal: the structure's states, then q_j / C_pp,j), not as
    # the integral of i (that adds a pole at 0 the current's zero at 0 only cancels in exact arithmetic)
    xm = control.ss(member[X, V])
    cf_, df_ = _force_rows(fsm, member, iff)
    p6 = control.ss(xm.A, xm.B, np.vstack([xm.C, cf_]), np.vstack([xm.D, df_]))   # v -> (x, F_hat)
    num, den = control.pade(2 * dt_s, 2)
    c1 = control.ss(iff.tf() * control.tf(num, den))
    k = control.append(c1, c1, c1)
    a, b, c, d = (np.asarray(z) for z in (p6.A, p6.B, p6.C, p6.D))
    ak, bk, ck, dk = (np.asarray(z) for z in (k.A, k.B, k.C, k.D))
    cf, df = c[3:], d[3:]
    # v = v_o - (ck xi + dk (cf z + df v))  ->  v = e (v_o - ck xi - dk cf z)
    e = np.linalg.inv(np.eye(3) + dk @ df)
    vz, vxi, vo = -e @ dk @ cf, -e @ ck, e
    yf_z, yf_xi, yf_o = cf + df @ vz, df @ vxi, df @ vo
    acl = np.block([[a + b @ vz, b @ vxi], [bk @ yf_z, ak + bk @ yf_xi]])
    bcl = np.vstack([b @ vo, bk @ yf_o])
    ccl = np.hstack([c + d @ vz, d @ vxi])
    return control.ss(acl, bcl, ccl, d @ vo)


def _mode_damping(sys, band_hz):
    p = sys.poles()
    wn = np.abs(p)
    sel = (p.imag > 0) & (wn > 2 * np.pi * band_hz[0]) & (wn < 2 * np.pi * band_hz[1])
    return float(np.max(p.real)), (-p.real[sel] / wn[sel])


def _inner_ok(f, loop, pm_deg, gm_db):
    """Every stack's IFF loop (the others open and closed) keeps PM and GM (sampled chain)."""
    for l in (np.einsum("fii->fi", loop).T, loop_at_a_time(loop).T):
        for li in l:
            m = loop_margins(f, li)
            if abs(m.phase_margin_deg) < pm_deg or abs(m.gain_margin_db) < gm_db:
                return False
    return True


def tune_iff(fsm, family, nominal=None, dt_s=1e-4, gains=None, target_hz=None, corner_hz=None,
             pm_deg=45.0, gm_db=6.0, source="charge+gauge", noise_budget=False):
    """IFF gain maximizing the smallest damping ratio of the target modes on the nominal member.

    Parameters
    ----------
    target_hz : sequence of float, optional
        The modes to damp: the nominal member's modes within 10 % of these frequencies (default:
        the axis resonances the gauges see, :func:`axis_resonances_hz`).
    corner_hz : float, optional
        High-pass corner f_l, Hz (default :func:`iff_corner_hz` at the lowest crossover of
        :data:`MIMO_SPEC`).
    pm_deg, gm_db : float
        Margins each stack's sampled IFF loop must keep on the nominal member (others open,
        and others closed).
    source : {"charge+gauge", "charge", "bridge"}
        The force estimate fed back (:func:`force_estimate`).
    noise_budget : bool
        Only gains that pass :func:`check_iff_noise` (each stack's current-window noise budget) count;
        when every gain tried breaks it, its :class:`DesignError` names the largest that would; when some
        pass it but none of those keeps the margins, the :class:`DesignError` says so and cites the budget.

    Only gains that keep those margins and every StateSpace member of ``family`` stable (Pade
    of the two-sample delay in the loop) count.

    Returns
    -------
    iff : IFF
    info : dict
        ``zeta_min_open``, ``zeta_min_damped`` (nominal member), ``modes_hz`` (the band's modes).
    """
    nominal = family[nominal_name()] if nominal is None else nominal
    target_hz = np.asarray(axis_resonances_hz(fsm, nominal) if target_hz is None else target_hz, float)
    p = nominal.poles()
    p = p[p.imag > 0]
    fp = np.abs(p) / (2 * np.pi)
    sel = np.any(np.abs(fp[:, None] / target_hz[None, :] - 1) < 0.1, axis=1)
    modes_hz = np.sort(fp[sel])
    band_hz = (0.9 * target_hz.min(), 1.1 * target_hz.max())
    corner = iff_corner_hz(fsm, MIMO_SPEC.fc_range_hz[0])[0] if corner_hz is None else float(corner_hz)
    cr = bridge_capacitances_f(fsm) if source == "bridge" else None
    zeta_open = float((-p.real[sel] / np.abs(p[sel])).min())
    if gains is None:
        # both signs, 5 decades about the inverse of the loop's DC force per volt (T x blocked fraction)
        g0 = 1.0 / np.abs(force_estimate(fsm, nominal, [1.0], source, cr)[0].diagonal()).mean()
        mags = g0 * np.geomspace(1e-3, 1e2, 41)
        gains = np.concatenate([mags, -mags])
    f = default_freq_hz(dt_s)
    fh = force_estimate(fsm, nominal, f, source, cr)
    best = refused = None
    n_refused = 0
    for g in gains:
        iff = IFF(float(g), float(corner), source, cr)
        if noise_budget:
            try:
                check_iff_noise(fsm, iff, dt_s)
            except DesignError as err:
                refused = refused or err
                n_refused += 1
                continue
        if not _inner_ok(f, iff_response(iff, f, dt_s)[:, None, None] * fh, pm_deg, gm_db):
            continue
        cl = _iff_closed(fsm, nominal, iff, dt_s)
        re, z = _mode_damping(cl, band_hz)
        if re >= 0 or z.size == 0:
            continue
        if best is None or z.min() > best[1]:
            best = (iff, float(z.min()))
    if best is None and refused is not None and n_refused == len(gains):
        raise refused           # every gain broke the budget: its message names the largest that fits
    if best is None:
        why = (f"; the other {n_refused} broke the current window's noise budget (the first: {refused})"
               if refused is not None else "")
        raise DesignError(f"no IFF gain of the {len(gains) - n_refused} tried within the noise budget keeps the "
                          f"nominal member stable with PM >= {pm_deg:g} deg and GM >= {gm_db:g} dB on every stack's "
                          f"loop and damps the target modes{why}; try other gains or corner_hz")
    iff, zmin = best
    for name, m in family.items():
        if isinstance(m, control.StateSpace) and np.max(_iff_closed(fsm, m, iff, dt_s).poles().real) >= 0:
            raise ValueError(f"the IFF gain {iff.gain_v_per_n:.3g} V/N destabilizes member {name!r}")
    return iff, {"zeta_min_open": zeta_open, "zeta_min_damped": zmin, "modes_hz": modes_hz.tolist()}


def axis_resonances_hz(fsm, nominal, freq_hz=None):
    """Frequency of the largest resonance peak above 100 Hz of each decoupled axis (tip, tilt, piston), Hz."""
    f = default_freq_hz() if freq_hz is None else np.asarray(freq_hz, float)
    dg = decoupled(kinematic_decoupler(fsm, nominal), member_responses(nominal, f, G))
    return [_peak_hz(f, dg[:, a, a]) for a in range(3)]


def _peak_hz(f, resp):
    mag = np.abs(resp)
    loc = np.flatnonzero((f[1:-1] > 100.0) & (mag[1:-1] > mag[:-2]) & (mag[1:-1] > mag[2:])) + 1
    return None if loc.size == 0 else float(f[loc[np.argmax(mag[loc])]])


def damped_gauges(fsm, member, freq_hz, iff, dt_s=1e-4, delay_samples=1):
    """v_outer -> g with the IFF loop closed per stack: G_g (I + C_iff F_hat)^-1, shape (freqs, 3, 3)."""
    f = np.asarray(freq_hz, float)
    gg = member_responses(member, f, G)
    if iff is None:
        return gg
    c = iff_response(iff, f, dt_s, delay_samples)
    fh = force_estimate(fsm, member, f, iff.source, iff.bridge_capacitance_f)
    return gg @ np.linalg.inv(np.eye(3)[None] + c[:, None, None] * fh)


def decoupled(dec, gauges):
    """G_dec = out G in (per frequency), shape (freqs, 3, 3)."""
    return dec.out_q_per_v[None] @ gauges @ dec.in_v_per_q[None]


def loop_at_a_time(loop):
    """SISO loops l_i (freqs, 3): channel i broken, the other two closed, l_i = L_ii - L_io (I + L_oo)^-1 L_oi."""
    loop = np.asarray(loop)
    out = np.empty(loop.shape[:2], complex)
    for i in range(3):
        o = [j for j in range(3) if j != i]
        l_oo = loop[:, o][:, :, o]
        corr = loop[:, i:i + 1, o] @ np.linalg.solve(np.eye(2)[None] + l_oo, loop[:, o, i:i + 1])
        out[:, i] = loop[:, i, i] - corr[:, 0, 0]
    return out


def mimo_disk_margin(freq_hz, loop):
    """Balanced simultaneous disk margin of a square loop response (freqs, n, n).

    Returns
    -------
    dict
        ``alpha`` = 1 / max mu(S - I/2) (independent complex perturbations per channel, the AB13MD
        upper bound of mu, so alpha is a guaranteed lower bound), ``freq_hz`` where it is set,
        ``alpha_unstructured`` = 1 / max sigma_max(S - I/2) (one full perturbation, <= alpha),
        ``gain_margin_db`` and ``phase_margin_deg`` of the disk (20 log10((1 + a/2)/(1 - a/2)), 2 atan(a/2)).
        NaN samples are skipped.
    """
    f = np.asarray(freq_hz, float)
    loop = np.asarray(loop, complex)
    n = loop.shape[1]
    mu = np.full(f.size, np.nan)
    sig = np.full(f.size, np.nan)
    ok = np.flatnonzero(np.all(np.isfinite(loop.reshape(f.size, -1)), axis=1))
    m = np.linalg.inv(np.eye(n)[None] + loop[ok]) - 0.5 * np.eye(n)[None]
    sig[ok] = np.linalg.svd(m, compute_uv=False)[:, 0]
    # mu <= sigma_max (the D = I scaling is one AB13MD may take; its bound came out at most 1.7e-6 above
    # sigma_max on the mirror's 48 design loops), so mu is only evaluated in decreasing order of sigma_max
    # until sigma_max (x 1.001, the guard) falls below the largest mu found: the same maximum and frequency
    # as evaluating every sample (checked on those loops), in a few AB13MD calls instead of ~1600
    best = -np.inf
    for i in np.argsort(-sig[ok], kind="stable"):
        k = ok[i]
        if sig[k] * 1.001 < best:
            break
        mk = m[i]
        mu[k] = ab13md(np.asfortranarray(mk), np.ones(n, int), np.full(n, 2, int))[0] if n > 1 else abs(mk[0, 0])
        best = max(best, mu[k])
    k = int(np.nanargmax(mu))
    a = 1.0 / mu[k]
    gm = 20 * np.log10((1 + a / 2) / (1 - a / 2)) if a < 2 else np.inf
    return {"alpha": float(a), "freq_hz": float(f[k]), "alpha_unstructured": float(1.0 / np.nanmax(sig)),
            "gain_margin_db": float(gm), "phase_margin_deg": float(np.degrees(2 * np.arctan(a / 2)))}


@dataclass(frozen=True)
class MimoDesign:
    """A decoupled MIMO design on a family (see :func:`design_mimo`)."""

    decoupler: Decoupler
    iff: IFF | None
    axes: dict                 # axis -> LoopShapeResult
    notches: dict              # axis -> (freq_hz, depth_db, width_ratio) or None
    freq_hz: np.ndarray = field(repr=False)
    loop_in: dict = field(repr=False)      # member -> L at the stack inputs (freqs, 3, 3)
    loop_out: dict = field(repr=False)     # member -> L at the axis outputs (freqs, 3, 3)
    lat: dict = field(repr=False)          # axis -> (rows, worst) loop-at-a-time margins over the family
    disk_in: dict = None                   # worst member's simultaneous disk margin at the stack inputs
    disk_out: dict = None                  # ... at the axis outputs
    iff_info: dict = None

    def bandwidth_hz(self, axis):
        """(Hz, member): lowest closed-loop bandwidth of ``axis`` over the family (:func:`lowest_bandwidth_hz`)."""
        return lowest_bandwidth_hz(self.freq_hz, self.loop_out, axis)

    def summary(self):
        """Plain dict of the headline numbers (per axis and simultaneous), worst members named."""
        out = {"iff": None if self.iff is None else {
                   "gain_v_per_n": self.iff.gain_v_per_n, "corner_hz": self.iff.corner_hz, "source": self.iff.source,
                   "bridge_capacitance_f": (None if self.iff.bridge_capacitance_f is None
                                            else [float(c) for c in self.iff.bridge_capacitance_f]),
                   **(self.iff_info or {})},
               "axes": {}, "disk_in": self.disk_in, "disk_out": self.disk_out}
        for ax in AXIS_NAMES:
            w = self.lat[ax][1]
            bw, bw_member = self.bandwidth_hz(ax)
            out["axes"][ax] = {"notch": self.notches[ax], "design_fc_hz": float(self.axes[ax].params["fc_hz"]),
                               "bandwidth_hz": {"value": bw, "member": bw_member},
                               **{k: {"value": w[k]["value"], "member": w[k]["member"]}
                                  for k in ("crossover_hz_min", "phase_margin_deg", "gain_margin_db", "disk_margin")}}
        return out


def _axis_notch(f, nominal_diag, family_diags, depth_db):
    """(freq_hz, depth_db, width_ratio) at the largest resonance peak above 100 Hz of the nominal diagonal."""
    def peak(resp):
        return _peak_hz(f, resp)
    fn = peak(nominal_diag)
    if fn is None:
        return None
    spread = [p for p in (peak(r) for r in family_diags) if p is not None and abs(p / fn - 1) < 0.3]
    width = max(0.2, 2.0 * (max(spread) - min(spread)) / fn + 0.2)
    return (float(fn), float(depth_db), float(width))


def lowest_bandwidth_hz(freq_hz, loops, axis):
    """(Hz, member): the lowest closed-loop bandwidth of ``axis`` over ``loops`` (member -> (n, 3, 3) loop at
    the axis outputs), :func:`~workbench.design.margins.closed_loop_bandwidth_hz` of each."""
    a = AXIS_NAMES.index(axis)
    bw = {n: closed_loop_bandwidth_hz(freq_hz, l)[a] for n, l in loops.items()}
    n = min(bw, key=bw.get)
    return float(bw[n]), n


def _siso_bandwidth_hz(f, loop):
    """First frequency where |L / (1 + L)| falls below 1/sqrt(2), Hz."""
    return closed_loop_bandwidth_hz(f, np.asarray(loop)[:, None, None])[0]


def _tune_axis(f, members, nominal, spec):
    """:func:`tune_loop_shape` per shape of ``spec``; the shape whose worst member's closed-loop bandwidth is highest.

    The SISO tuner ranks shapes by the members' highest gain crossover, which a loop whose |L|
    hovers near 1 over a band (a lead on a flat plant) wins without tracking anything there;
    the closed-loop bandwidth cannot be gamed that way. Ties: the larger worst disk margin.
    """
    best = None
    for ri in spec.integral_ratios:
        for al in spec.lead_ratios:
            for rr in spec.rolloff_ratios:
                one = replace(spec, integral_ratios=(ri,), lead_ratios=(al,), rolloff_ratios=(rr,))
                try:
                    res = tune_loop_shape(f, members, nominal, one)
                except DesignError:
                    continue
                loops = family_loops(res.controller_d, f, members, spec.delay_samples)
                bw = min(_siso_bandwidth_hz(f, l) for l in loops.values())
                key = (bw, res.worst["disk_margin"]["value"])
                if best is None or key > best[0]:
                    best = (key, res)
    if best is None:
        raise DesignError("no shape meets the margins on every member of this axis; lower the targets")
    return best[1]


# integral-dominated PIs only (r_i <= 1; the SISO lead and roll-off grid): the decoupled (and more so
# the damped) plant is flat over the servo band, where a PI zero below crossover lets |L| hover near 1
# over a band, and the tuner (which ranks a shape by its members' highest crossover) prefers such loops
MIMO_SPEC = LoopShapeSpec(integral_ratios=(0.1, 0.25, 1.0))


def design_mimo(fsm, family, damping=False, spec=MIMO_SPEC, freq_hz=None, notch_depth_db=20.0,
                nominal=None, progress=None, iff_source="charge+gauge"):
    """Kinematic decoupling + per-axis loop shaping, notch-only or with IFF damping (module docstring).

    Parameters
    ----------
    fsm : FastSteeringMirror
    family : dict name -> StateSpace or FRD
        :func:`~workbench.linearize.mimo.mirror_family`.
    damping : bool
        False: a notch per axis at its resonance. True: IFF per stack, no notch.
    spec : LoopShapeSpec
        Targets and shapes searched per axis (``notch`` is set here).
    iff_source : {"charge+gauge", "charge", "bridge"}
        With ``damping``: the force estimate the IFF feeds back (:func:`force_estimate`).

    With ``damping`` the IFF's high-pass corner is :func:`iff_corner_hz` at ``spec``'s lowest crossover; with a
    noise budget in ``spec`` (``max_noise_command_v``) the IFF gain must pass :func:`check_iff_noise` and the
    outer loops' budget is what the IFF's noise leaves of it, rho sqrt(1 - max_j (sigma_iff,j / B_j)^2), so
    that each stack's command noise stays within R min(I_source, I_sink) / 3. That share is reported
    (``iff_info["outer_noise_share"]``) and warned about (a ``UserWarning``, and
    ``iff_info["outer_noise_share_warning"]``) below :data:`IFF_MIN_OUTER_NOISE_SHARE`: the IFF tuner takes
    its gain first, so a noisy force estimate can leave the outer loops little (the gauge-fed estimate: 0.31).
    """
    f = default_freq_hz(spec.dt_s) if freq_hz is None else np.asarray(freq_hz, float)
    nominal = family[nominal_name()] if nominal is None else nominal
    dec = kinematic_decoupler(fsm, nominal)
    iff, iff_info = None, None
    if damping:
        budget = spec.max_noise_command_v is not None
        corner, cinfo = iff_corner_hz(fsm, spec.fc_range_hz[0])
        iff, iff_info = tune_iff(fsm, family, nominal, spec.dt_s, corner_hz=corner, source=iff_source,
                                 noise_budget=budget)
        lead, b = check_iff_noise(fsm, iff, spec.dt_s) if budget else (iff_command_noise_v(fsm, iff, spec.dt_s), None)
        iff_info = {**iff_info, **cinfo, "command_noise_v": lead.tolist()}
        if budget:
            share = float(np.sqrt(max(0.0, 1.0 - np.nanmax(lead / b) ** 2)))
            spec = replace(spec, max_noise_command_v=spec.max_noise_command_v * share)
            iff_info["outer_noise_share"] = share
            iff_info["outer_noise_share_warning"] = None
            if share < IFF_MIN_OUTER_NOISE_SHARE:
                msg = (f"the IFF ({iff_source}, {iff.gain_v_per_n:.3g} V/N) takes {np.nanmax(lead / b):.2f} of a stack's "
                       f"noise budget (RMS): the outer loops keep {share:.2f} of it, less than "
                       f"IFF_MIN_OUTER_NOISE_SHARE = {IFF_MIN_OUTER_NOISE_SHARE:.3f} (an equal split of its variance); "
                       f"damping {100 * iff_info['zeta_min_open']:.2f} % -> {100 * iff_info['zeta_min_damped']:.2f} %")
                iff_info["outer_noise_share_warning"] = msg
                warnings.warn(msg, stacklevel=2)
    plants = {n: decoupled(dec, damped_gauges(fsm, m, f, iff, spec.dt_s, spec.delay_samples))
              for n, m in family.items()}
    if iff is None:
        nom_ss = control.ss(nominal[G, V])
        nom_dec = control.ss([], [], [], dec.out_q_per_v) * nom_ss * control.ss([], [], [], dec.in_v_per_q)
    else:
        # the damped nominal for crossover placement: continuous, IFF closed with the Pade delay
        cl = _iff_closed(fsm, nominal, iff, spec.dt_s)           # v_outer -> (x, F_hat)
        kg = gauge_gains(fsm)[:, 0]
        gx = control.ss([], [], [], np.hstack([np.diag(kg), np.zeros((3, 3))]))
        nom_dec = (control.ss([], [], [], dec.out_q_per_v) * gx * cl * control.ss([], [], [], dec.in_v_per_q))
    axes, notches = {}, {}
    for a, ax in enumerate(AXIS_NAMES):
        members = {n: p[:, a, a] for n, p in plants.items()}
        # creep truncated as design.nominal does, but never the IFF's own slow poles (its shelf sets the band's gain)
        nom_axis, _ = minimal(control.ss(nom_dec[a, a]), SLOW_HZ if iff is None else min(SLOW_HZ, iff.corner_hz / 10))
        nt = None if damping else _axis_notch(f, plants[nominal_name()][:, a, a] if nominal_name() in plants
                                                else members[next(iter(members))], list(members.values()),
                                                notch_depth_db)
        notches[ax] = nt
        axes[ax] = _tune_axis(f, members, nom_axis, replace(spec, notch=nt))
        if progress is not None:
            progress(a + 1, 3)
    ctrl = np.array([response(axes[ax].controller_d, f) for ax in AXIS_NAMES]).T   # (freqs, 3)
    sf = sampled_factor(f, spec.dt_s, spec.delay_samples)
    loop_out, loop_in = {}, {}
    for n, p in plants.items():
        cdiag = np.einsum("fi,ij->fij", ctrl * sf[:, None], np.eye(3))
        loop_out[n] = p @ cdiag
        # at the stack inputs: in C out G_damped  (G_damped = out^-1 p in^-1)
        gd = np.linalg.solve(dec.out_q_per_v[None], p) @ np.linalg.inv(dec.in_v_per_q)[None]
        loop_in[n] = dec.in_v_per_q[None] @ cdiag @ dec.out_q_per_v[None] @ gd
    lat = {}
    for a, ax in enumerate(AXIS_NAMES):
        lat[ax] = family_margins(f, {n: loop_at_a_time(l)[:, a] for n, l in loop_out.items()})

    def worst_disk(loops):
        res = {n: mimo_disk_margin(f, l) for n, l in loops.items()}
        n = min(res, key=lambda k: res[k]["alpha"])
        return {"member": n, **res[n]}
    return MimoDesign(dec, iff, axes, notches, f, loop_in, loop_out, lat, worst_disk(loop_in), worst_disk(loop_out),
                      iff_info)


def closed_loop_poles(fsm, member, design, dt_s=1e-4):
    """Poles (rad/s) of ``member`` (a StateSpace) with the whole design closed, continuous approximation.

    The axis controllers as designed in continuous time (before their prewarped Tustin map), the
    IFF likewise, and the sampled chain (hold, averaging gauge, one sample of delay: two samples
    of lag at low frequency) as a 2nd-order Pade of 2 dt_s in each loop. Independent of the
    frequency-response margins, which take the closed loop's stability for granted.
    """
    gm = control.ss(member[G, V])
    cf_, df_ = _force_rows(fsm, member, design.iff or IFF(0.0, 1.0))
    p6 = control.ss(gm.A, gm.B, np.vstack([gm.C, cf_]), np.vstack([gm.D, df_]))              # v -> (g, F_hat)
    num, den = control.pade(2 * dt_s, 2)
    pade = control.ss(control.tf(num, den))
    outer = control.append(*[control.ss(design.axes[ax].controller_c) * pade for ax in AXIS_NAMES])
    k_out = control.ss([], [], [], design.decoupler.in_v_per_q) * outer * \
        control.ss([], [], [], design.decoupler.out_q_per_v)
    if design.iff is None:
        k_in = control.ss([], [], [], np.zeros((3, 3)))
    else:
        c1 = control.ss(design.iff.tf()) * pade
        k_in = control.append(c1, c1, c1)
    k = control.ss(k_out.A, k_out.B, k_out.C, k_out.D)
    k = control.append(k, k_in)                                       # (g, F_hat) -> (v from outer, v from IFF)
    k = control.ss([], [], [], np.hstack([np.eye(3), np.eye(3)])) * k
    return control.feedback(p6, k, sign=-1).poles()


def comparison_markdown(notch, damped, hinf=None):
    """GitHub Markdown table of a notch-only and a damped :class:`MimoDesign` (and optionally a
    :class:`~workbench.design.mimo_hinf.HinfDesign`) on the same family, worst members named."""
    lines = ["| axis | design | closed-loop bandwidth, Hz (worst member) | lowest crossover, Hz | PM deg (worst) "
             "| GM dB (worst) | SISO disk alpha |", "|---|---|---|---|---|---|---|"]
    designs = [(lbl, d) for lbl, d in (("notch only", notch), ("IFF damped", damped), ("MIMO H-inf", hinf))
               if d is not None]
    for ax in AXIS_NAMES:
        for label, d in designs:
            a = d.summary()["axes"][ax]
            lines.append(f"| {ax} | {label} | {a['bandwidth_hz']['value']:.0f} ({a['bandwidth_hz']['member']}) | "
                         f"{a['crossover_hz_min']['value']:.0f} | {a['phase_margin_deg']['value']:.1f} "
                         f"({a['phase_margin_deg']['member']}) | {a['gain_margin_db']['value']:.2f} "
                         f"({a['gain_margin_db']['member']}) | {a['disk_margin']['value']:.3f} |")
    lines += ["", "| design | simultaneous disk alpha at stack inputs (worst member, Hz) | at axis outputs | "
              "unstructured bound (inputs) |", "|---|---|---|---|"]
    for label, d in designs:
        lines.append(f"| {label} | {d.disk_in['alpha']:.3f} ({d.disk_in['member']}, {d.disk_in['freq_hz']:.0f}) | "
                     f"{d.disk_out['alpha']:.3f} ({d.disk_out['member']}) | {d.disk_in['alpha_unstructured']:.3f} |")
    return "\n".join(lines)


def main(argv=None):
    """``python -m workbench.design.mimo plants/fsm_p888_51.toml``: both designs on the small-signal family, Markdown."""
    import sys
    from ..plant.mirror import load_mirror
    from ..linearize.mimo import mirror_family
    path = (sys.argv[1:] if argv is None else argv) or ["plants/fsm_p888_51.toml"]
    fsm = load_mirror(path[0])
    fam = mirror_family(fsm)
    notch = design_mimo(fsm, fam, damping=False)
    damped = design_mimo(fsm, fam, damping=True)
    i = damped.summary()["iff"]
    print(f"IFF: gain {i['gain_v_per_n']:.4g} V/N, high-pass {i['corner_hz']:.3g} Hz; flexure modes "
          f"{', '.join(f'{m:.0f}' for m in i['modes_hz'])} Hz; smallest damping {100 * i['zeta_min_open']:.2f} % -> "
          f"{100 * i['zeta_min_damped']:.2f} %\n")
    print(comparison_markdown(notch, damped))


if __name__ == "__main__":
    from ..arguments import run_script                   # one-line errors, Ctrl-C / SIGTERM without a traceback
    raise SystemExit(run_script("python -m workbench.design.mimo", main))
