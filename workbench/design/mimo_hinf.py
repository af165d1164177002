"""MIMO H-infinity mixed sensitivity for the three-stack mirror (issue 15, item 4), beside the decoupled designs.

**Loop.** The same decoupled channels as :mod:`~workbench.design.mimo`: the firmware's axis
estimate q_hat = K diag(1/K_g) g and the stack voltages v = diag(1/p) K^-1 u, so the design
plant is G_dec (3x3, axis units per axis unit, DC gain I on the nominal member); the controller
is one full 3x3 block u = K e, e = r - q_hat (axes may talk to each other, unlike the
per-axis loops).

**Design plant.** The nominal member (ascending at 50 V, K_g nominal), creep modes truncated
(:func:`~workbench.design.nominal.minimal`, at the stacks), decoupled, in gauge coordinates
(:func:`gauge_coordinates`: T^-1 G_dec T = G_gv diag(1/(p K_g)), DC gain I, every channel in
firmware V), times a 2nd-order Pade of the sampled chain's lag (hold + period-averaging gauge +
``delay_samples`` of compute: (1 + delay_samples) dt_s at low frequency, as
:func:`~workbench.design.mimo.closed_loop_poles`) in each channel. The structural modes stay in it.

**Weights**, each derived (:func:`hinf_weights`):

- W_s = (s / M + w_b) / (s + A w_b) I. M = 2 bounds sigma_max(S) <= 2 on the design plant,
  so sigma_max(S - I/2) <= 2.5: the unstructured (hence the simultaneous) disk margin there is
  at least 0.4, the issue's floor. A = 1e-3 (integral-like). w_b is the sensitivity bandwidth:
  its floor comes from the tip-triangle target (0.1 Hz, 10-90 % of range, error <= 0.1 % of
  range: a ramp of slope 0.16 range/s tracked with velocity error slope / w_b, so w_b >=
  160 rad/s), and :func:`design_hinf` raises it by bisection to the largest value with gamma <= 1.
- W_t: the family's output multiplicative uncertainty, |W_t| >= sigma_max((G_i - G_nom) G_nom^-1)
  over every member, where G_i is the member *with the exact sampled chain* and G_nom the
  design plant (Pade): the Pade's own error near Nyquist is uncertainty too. Fitted by
  :func:`~workbench.linearize.weight.fit_weight` as
  :func:`~workbench.linearize.uncertainty.uncertainty_bound` does for one stack.
- W_u on K S (:func:`range_weight`): at DC K S = G^-1, so a full-scale error (a gauge's reading
  over the 0-100 V stroke) asks for exactly that stroke; the amplifier's -20..120 V span allows
  140/100 of it: W_u = 100/140 I. Constant: the roll-off is left to W_t (a roll-off at 5 w_b,
  :func:`~workbench.design.hinf.default_weights`' rule, capped the crossover near 5 w_b). The gauge
  noise on the stack voltages is then measured (:func:`noise_rms_v`) against the plant's budget
  R min(I_source, I_sink) / 3 (:func:`noise_budget`), not imposed.

**Synthesis**: python-control's ``mixsyn`` (slycot SB10AD) in a child process with a time limit,
the matrices balanced first (:mod:`~workbench.design.hinf`'s runner). **Firmware order**: the
controller is balanced-truncated to ``order`` states (:func:`~workbench.design.reduce.stable_part`
and python-control's ``balred``; the bound 2 x the discarded Hankel singular values of the
stable part, measured error sigma_max(K - K_r) on the grid) and discretized (Tustin, prewarped
at the crossover). **Margins** on the family exactly as for the decoupled designs: loop-at-a-time
and simultaneous disk margins at the stack inputs and the axis outputs with the sampled chain,
worst member named, and the closed-loop poles of every StateSpace member with the Pade chain.
"""

import time
import warnings
from dataclasses import dataclass, field

import control
import numpy as np

from ..errors import DesignError
from ..linearize.limit_cycle import sampled_factor
from ..linearize.weight import fit_weight
from .antiwindup import discretize
from .hinf import _SB10AD_ADVICE, _balanced_matrices, _run_with_limit
from .margins import family_margins, response
from .mimo import (AXIS_NAMES, G, V, comparison_markdown, lowest_bandwidth_hz, decoupled, default_freq_hz,
                   kinematic_decoupler, loop_at_a_time, member_responses, mimo_disk_margin, nominal_name)
from .nominal import SLOW_HZ, minimal
from .reduce import stable_part

__all__ = ["HinfWeights", "HinfDesign", "design_plant", "hinf_weights", "synthesize", "design_hinf",
           "weighted_peaks", "range_weight", "noise_rms_v", "noise_budget", "min_bandwidth_rad_s", "reduce_mimo", "hinf_closed_loop_poles"]

PEAK_S = 2.0                 # sigma_max(S) bound on the design plant: alpha >= 1 / (2 + 1/2) = 0.4 (the floor)
LOW_FREQ_S = 1e-3            # |S(0)| bound relative to 1 (integral-like; 1e-4 left SB10AD's Riccati singular)
# tip triangle target (issue 15): 0.1 Hz, 10-90 % of range, error <= 0.1 % of range RMS
TRIANGLE_HZ = 0.1
TRIANGLE_SPAN = 0.8
TRIANGLE_ERROR = 1e-3
STROKE_V = 100.0             # V: the stacks' nominal stroke (0-100 V, the family's v_range)
# W_u's roll-off corner in multiples of w_b; None: constant (the roll-off is left to W_t, the family's
# uncertainty incl. the Pade's error near Nyquist). 5 (hinf.default_weights' rule) caps the crossover near 5 w_b
ROLLOFF_RATIO = None
FIRMWARE_ORDER = 18          # states: as many as the three notch-only axis controllers (PI + lead + roll-off + notch)


def min_bandwidth_rad_s(triangle_hz=TRIANGLE_HZ, span=TRIANGLE_SPAN, error=TRIANGLE_ERROR):
    """W_s bandwidth floor from the triangle target: ramp slope 2 span f (range/s) over the allowed error, rad/s."""
    return 2.0 * span * triangle_hz / error


@dataclass(frozen=True)
class HinfWeights:
    """Mixed-sensitivity weights (continuous; SISO ones act on every channel) and how they were derived."""

    w_s: control.StateSpace
    w_u: control.StateSpace
    w_t: control.StateSpace
    bandwidth_rad_s: float
    derivation: dict = field(default_factory=dict)


def gauge_coordinates(dec):
    """T = K diag(1/K_g): axes per firmware V of the three gauges.

    The synthesis works in gauge coordinates (e = T e_g, u = T u_g, K = T K_g T^-1), where the
    decoupled plant is G_gv diag(1/(p K_g)), DC gain I, every channel in firmware V: tip, tilt
    (rad) and piston (m) are then commensurate, and a full-scale error is the same size in each.
    """
    return np.asarray(dec.out_q_per_v, float)


def _static(m):
    return control.ss([], [], [], np.asarray(m, float))


def design_plant(fsm, nominal, dec=None, dt_s=1e-4, delay_samples=1):
    """The continuous 3x3 design plant T^-1 G_dec T (gauge coordinates): nominal (creep truncated), Pade of the sampled lag."""
    dec = kinematic_decoupler(fsm, nominal) if dec is None else dec
    gs, _ = minimal(control.ss(nominal[G, V]), SLOW_HZ)        # truncate at the stacks (well-scaled), not after K
    g = gs * _static(dec.in_v_per_q @ gauge_coordinates(dec))
    num, den = control.pade((1 + delay_samples) * dt_s, 2)
    pade = control.ss(control.tf(num, den))
    return control.ss(g * control.append(pade, pade, pade))


def _mimo_response(sys, f):
    """(freqs, p, m) response of a continuous system."""
    sys = control.ss(sys)
    r = np.asarray(sys(2j * np.pi * np.asarray(f, float)))
    return np.moveaxis(r.reshape(sys.noutputs, sys.ninputs, -1), -1, 0)


def member_plants(fsm, family, dec, freq_hz, dt_s=1e-4, delay_samples=1):
    """Each member in gauge coordinates, T^-1 G_dec T, with the exact sampled chain, (freqs, 3, 3)."""
    sf = sampled_factor(freq_hz, dt_s, delay_samples)[:, None, None]
    t = gauge_coordinates(dec)
    return {n: member_responses(m, freq_hz, G) @ (dec.in_v_per_q @ t)[None] * sf for n, m in family.items()}


def range_weight(fsm, bandwidth_rad_s, stroke_v=STROKE_V, rolloff_ratio=ROLLOFF_RATIO):
    """W_u (on K S in gauge coordinates) from the stacks' voltage range, and its derivation (dict).

    In gauge coordinates an error of one stack's full-scale reading (its elongation over the
    0-100 V stroke, K_g p 100 V) asks, at DC where K S = G^-1, for exactly that stroke on that stack;
    the amplifier's span (voltage_max_v - voltage_min_v: -20..120 V, seed 000 sec. 1) allows
    span / stroke times more. So W_u = rolloff(s) (stroke / span) I, rolloff = (1 + s / (r w_b)) /
    (1 + s / (100 r w_b)): above r times the bandwidth the allowed controller gain falls at
    20 dB/decade (the SISO :func:`~workbench.design.hinf.default_weights` rule; the far pole keeps
    D12 full rank).
    """
    span = min(pz.voltage_max_v - pz.voltage_min_v for pz in fsm.stacks)
    if rolloff_ratio is None:
        return control.ss([], [], [], [[stroke_v / span]]), {"stroke_v": stroke_v, "span_v": span,
                                                              "dc_level": stroke_v / span, "rolloff_ratio": None}
    wb = float(bandwidth_rad_s)
    wr = rolloff_ratio * wb
    w = control.ss(control.tf([stroke_v / span / wr, stroke_v / span], [1.0 / (100.0 * wr), 1.0]))
    return w, {"stroke_v": stroke_v, "span_v": span, "dc_level": stroke_v / span, "rolloff_ratio": rolloff_ratio}


def noise_rms_v(fsm, dec, member, ctrl_resp, freq_hz=None, dt_s=1e-4, delay_samples=1):
    """Per stack, the RMS voltage that white gauge noise (n_g RMS per reading, each gauge) puts on the command, V.

    H = diag(1/p) K^-1 (I + C P)^-1 C K diag(1/K_g) with the sampled chain in P (``ctrl_resp``:
    callable freq_hz -> the sampled controller's (freqs, 3, 3) response in axis units), averaged
    over a uniform grid to Nyquist (white noise). Compared with the plant's budget
    R min(I_source, I_sink) / 3 (:mod:`~workbench.design.budgets`) by :func:`noise_budget`.
    """
    f = np.linspace(0.5, 0.5 / dt_s, 2000) if freq_hz is None else np.asarray(freq_hz, float)
    from ..plant.gauge import demod_noise_sigma_v
    n_g = np.array([demod_noise_sigma_v(pl.gauge) * pl.gauge.trim_scale for pl in fsm.plants])
    c = ctrl_resp(f)
    p = decoupled(dec, member_responses(member, f, G)) * sampled_factor(f, dt_s, delay_samples)[:, None, None]
    ks = np.linalg.solve(np.eye(3)[None] + c @ p, c)
    h = dec.in_v_per_q[None] @ ks @ dec.out_q_per_v[None]
    return np.sqrt(np.mean(np.sum(np.abs(h) ** 2 * (n_g ** 2)[None, None, :], axis=2), axis=0))


def noise_budget(fsm, dt_s=1e-4):
    """The smallest stack's gauge-noise command budget R min(I_source, I_sink) / 3, V RMS."""
    from .budgets import plant_budgets
    return min(plant_budgets(pl, dt_s)["noise_command_v"].value for pl in fsm.plants)


def hinf_weights(fsm, family, nominal=None, bandwidth_rad_s=None, dt_s=1e-4, delay_samples=1, freq_hz=None,
                 plant=None, members=None):
    """The three weights of the module docstring at sensitivity bandwidth ``bandwidth_rad_s`` (default: the floor)."""
    nominal = family[nominal_name()] if nominal is None else nominal
    dec = kinematic_decoupler(fsm, nominal)
    f = default_freq_hz(dt_s) if freq_hz is None else np.asarray(freq_hz, float)
    gp = design_plant(fsm, nominal, dec, dt_s, delay_samples) if plant is None else plant
    members = member_plants(fsm, family, dec, f, dt_s, delay_samples) if members is None else members
    g_nom = _mimo_response(gp, f)
    g_inv = np.linalg.inv(g_nom)
    env = np.zeros(f.size)
    for p in members.values():
        d = (p - g_nom) @ g_inv
        env = np.maximum(env, np.linalg.svd(d, compute_uv=False)[:, 0])
    fit = fit_weight(f, env, max_order=3)
    w_t = _cap_fast_poles(fit.weight, 10.0 * f[-1])
    wb = min_bandwidth_rad_s() if bandwidth_rad_s is None else float(bandwidth_rad_s)
    s = control.tf("s")
    w_s = control.ss((s / PEAK_S + wb) / (s + LOW_FREQ_S * wb))
    wu, wu_info = range_weight(fsm, wb)
    return HinfWeights(w_s, wu, w_t, wb,
                       {"w_t_fit": fit, "w_t_envelope": env, "freq_hz": f, "w_u": wu_info,
                        "bandwidth_floor_rad_s": min_bandwidth_rad_s()})


def _time_scaled(sys, w0):
    """(A, B, C, D) of sys(w0 s~): the same transfer function on the frequency axis s~ = s / w0."""
    a, b, c, d = (np.asarray(m, float) for m in (sys.A, sys.B, sys.C, sys.D))
    return control.ss(a / w0, b / w0, c, d) if a.size else control.ss([], [], [], d)


def _cap_fast_poles(w, cap_hz):
    """``w`` with real poles and zeros above ``cap_hz`` moved to it, DC gain kept (the fit parks unused
    corners at 1e3 x the grid's top, eight decades from W_s's pole: SB10AD's Riccati equations then fail).
    Below cap_hz / 10 the magnitude changes by < 0.05 dB per moved corner, inside the fit's 0.5 dB guard."""
    z, p, k = control.zeros(w), control.poles(w), None
    cap = 2 * np.pi * cap_hz
    z2 = np.where(np.abs(z) > cap, -cap, z)
    p2 = np.where(np.abs(p) > cap, -cap, p)
    g0 = np.real(np.squeeze(w(0)))
    num, den = np.real(np.poly(z2)), np.real(np.poly(p2))
    k = g0 * den[-1] / num[-1]
    return control.ss(control.tf(k * num, den))


def synthesize(plant, weights, time_limit_s=60.0, start_method="spawn", w0_rad_s=None):
    """mixsyn on ``plant`` with ``weights`` in a child process; (K continuous StateSpace, gamma, rcond).

    The problem is posed on s~ = s / w0 (default w0: the W_s bandwidth) and the controller mapped
    back: the structural modes (~1e4 rad/s) and the W_s pole (~1e-1 rad/s) are far apart, and
    SB10AD's Riccati equations came out near-singular (rcond ~1e-17) with a gamma below the closed
    loop's true norm; with this scaling and W_t's parked corners moved (:func:`_cap_fast_poles`)
    the gamma agrees with the closed loop (tested).
    """
    w0 = float(weights.bandwidth_rad_s if w0_rad_s is None else w0_rad_s)
    ws = [_time_scaled(control.ss(w), w0) for w in (weights.w_s, weights.w_u, weights.w_t)]
    msg = _run_with_limit(_balanced_matrices(_time_scaled(plant, w0)), [_balanced_matrices(w) for w in ws],
                          float(time_limit_s), start_method, time.perf_counter())
    if msg[0] != "ok":
        _, kind, info, text = msg
        code = None if info is None else int(np.atleast_1d(info)[0])
        raise DesignError(f"MIMO H-infinity synthesis failed ({kind}, SB10AD info {code}: "
                          f"{_SB10AD_ADVICE.get(code, text.splitlines()[-1] if text else '')})")
    _, (ak, bk, ck, dk), gamma, rcond = msg
    return control.ss(ak * w0, bk * w0, ck, dk), float(gamma), rcond


def weighted_peaks(plant, k, weights, freq_hz):
    """Peaks over ``freq_hz`` of sigma_max(W_s S), sigma_max(W_u K S), sigma_max(W_t T) and of the stacked matrix.

    Computed from frequency responses (L = G K, S = (I + L)^-1, T = L S): independent of the
    synthesis' own state-space closed loop.
    """
    f = np.asarray(freq_hz, float)
    g = _mimo_response(plant, f)
    kk = _mimo_response(k, f)
    n = g.shape[1]
    s_ = np.linalg.inv(np.eye(n)[None] + g @ kk)
    t_ = np.eye(n)[None] - s_
    ks = kk @ s_
    out = {}
    stacked = []
    for key, w, m in (("S", weights.w_s, s_), ("KS", weights.w_u, ks), ("T", weights.w_t, t_)):
        wr = _mimo_response(w, f)
        wm = wr[:, 0, 0][:, None, None] * m if wr.shape[1:] == (1, 1) else wr @ m
        stacked.append(wm)
        out[key] = float(np.linalg.svd(wm, compute_uv=False)[:, 0].max())
    out["stacked"] = float(np.linalg.svd(np.concatenate(stacked, axis=1), compute_uv=False)[:, 0].max())
    return out


def reduce_mimo(k, order, freq_hz):
    """Balanced truncation of a MIMO controller (balred keeps the unstable part); (K_r, bound, measured error)."""
    k = control.ss(k)
    if order >= k.nstates:
        return k, 0.0, 0.0
    stable, n_unst = stable_part(k)
    if order < n_unst:
        raise DesignError(f"cannot reduce below the {n_unst} marginal/unstable controller modes")
    try:
        # the Hankel singular values from slycot AB09AD's square-root method (control.hsvd's plain
        # Gramians came out complex on this controller: W_s's 0.4 rad/s pole beside 1e5 rad/s modes)
        from slycot import ab09ad
        a, b, c = (np.asarray(m, float) for m in (stable.A, stable.B, stable.C))
        hsv = np.sort(ab09ad("C", "B", "N", a.shape[0], b.shape[1], c.shape[0], a, b, c, nr=a.shape[0],
                             tol=0.0)[-1])[::-1]
        bound = float(2 * np.sum(hsv[order - n_unst:]))
    except Exception:            # slycot's Lyapunov solver on an ill-conditioned part: bound unknown
        bound = float("nan")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        kr = control.balred(k, order, method="truncate")
    d = _mimo_response(k, freq_hz) - _mimo_response(kr, freq_hz)
    return control.ss(kr), bound, float(np.linalg.svd(d, compute_uv=False)[:, 0].max())


@dataclass(frozen=True)
class HinfDesign:
    """A MIMO H-infinity design and its margins on a family (see :func:`design_hinf`)."""

    controller_full: control.StateSpace     # continuous, as synthesized, gauge coordinates
    controller_c: control.StateSpace        # continuous, reduced to the firmware order, axis units: T K_r T^-1
    controller_d: control.StateSpace        # controller_c by Tustin at the servo rate
    gamma: float
    weights: HinfWeights
    plant: control.StateSpace = field(repr=False)         # the design plant (with the Pade chain)
    peaks: dict = None                      # weighted_peaks of the full controller on the design plant
    peaks_reduced: dict = None              # ... of the reduced one
    reduction: dict = None                  # order_before, order_after, error_bound, error_measured
    decoupler: object = None
    freq_hz: np.ndarray = field(default=None, repr=False)
    loop_in: dict = field(default=None, repr=False)
    loop_out: dict = field(default=None, repr=False)
    lat: dict = field(default=None, repr=False)
    disk_in: dict = None
    disk_out: dict = None
    bandwidth_search: list = field(default_factory=list)   # (w_b rad/s, gamma or None)
    controller_scaled: control.StateSpace = field(default=None, repr=False)   # K_g reduced (gauge coordinates)

    def bandwidth_hz(self, axis):
        """(Hz, member): lowest closed-loop bandwidth of ``axis`` over the family (as :class:`MimoDesign`'s)."""
        return lowest_bandwidth_hz(self.freq_hz, self.loop_out, axis)

    def summary(self):
        """Plain dict of the headline numbers, in the shape of :meth:`MimoDesign.summary`'s ``axes``."""
        out = {"gamma": self.gamma, "w_b_rad_s": self.weights.bandwidth_rad_s, "peaks": self.peaks,
               "peaks_reduced": self.peaks_reduced, "reduction": self.reduction, "disk_in": self.disk_in,
               "disk_out": self.disk_out, "axes": {}}
        for ax in AXIS_NAMES:
            w = self.lat[ax][1]
            bw, member = self.bandwidth_hz(ax)
            out["axes"][ax] = {"bandwidth_hz": {"value": bw, "member": member},
                               **{k: {"value": w[k]["value"], "member": w[k]["member"]}
                                  for k in ("crossover_hz_min", "phase_margin_deg", "gain_margin_db", "disk_margin")}}
        return out


def _evaluate(fsm, family, dec, kd, f, dt_s, delay_samples):
    """Loops at the axis outputs and the stack inputs of every member with the sampled controller ``kd``."""
    kr = np.moveaxis(np.asarray(kd(np.exp(2j * np.pi * f * dt_s))).reshape(3, 3, -1), -1, 0)
    sf = sampled_factor(f, dt_s, delay_samples)[:, None, None]
    loop_out, loop_in = {}, {}
    for n, m in family.items():
        gg = member_responses(m, f, G)
        p = decoupled(dec, gg)
        loop_out[n] = p @ kr * sf
        loop_in[n] = dec.in_v_per_q[None] @ kr @ dec.out_q_per_v[None] @ gg * sf
    return loop_in, loop_out


def _gamma_at(plant, fsm, family, nominal, wb, dt_s, delay_samples, f, members, time_limit_s, start_method):
    w = hinf_weights(fsm, family, nominal, wb, dt_s, delay_samples, f, plant=plant, members=members)
    try:
        k, gamma, _ = synthesize(plant, w, time_limit_s, start_method)
    except DesignError:
        return w, None, None
    return w, k, gamma


def design_hinf(fsm, family, nominal=None, dt_s=1e-4, delay_samples=1, order=FIRMWARE_ORDER, freq_hz=None, bisections=6,
                time_limit_s=60.0, start_method="spawn", bandwidth_rad_s=None, progress=None):
    """MIMO mixed-sensitivity design at the largest W_s bandwidth with gamma <= 1 (module docstring).

    Parameters
    ----------
    order : int
        Firmware order of the controller (balanced truncation), states (default: the notch-only
        design's 3 x 6; at 8 the truncation error reached 0.68 and the GM fell below 6 dB).
    bisections : int
        Bisection steps on log w_b between the triangle floor and 0.3 x the Nyquist rate.
    bandwidth_rad_s : float, optional
        Skip the search and design at this w_b (gamma may then exceed 1; reported).

    Raises
    ------
    DesignError
        If even the floor bandwidth has no controller with gamma <= 1, or the reduced
        controller does not stabilize every StateSpace member.
    """
    nominal = family[nominal_name()] if nominal is None else nominal
    f = default_freq_hz(dt_s) if freq_hz is None else np.asarray(freq_hz, float)
    dec = kinematic_decoupler(fsm, nominal)
    plant = design_plant(fsm, nominal, dec, dt_s, delay_samples)
    members = member_plants(fsm, family, dec, f, dt_s, delay_samples)
    search = []
    if bandwidth_rad_s is not None:
        w, k, gamma = _gamma_at(plant, fsm, family, nominal, bandwidth_rad_s, dt_s, delay_samples, f, members,
                                time_limit_s, start_method)
        search.append((float(bandwidth_rad_s), gamma))
        if k is None:
            raise DesignError(f"MIMO H-infinity synthesis failed at w_b = {bandwidth_rad_s:g} rad/s")
        best = (w, k, gamma)
    else:
        lo = min_bandwidth_rad_s()
        hi = 0.3 * np.pi / dt_s
        w, k, gamma = _gamma_at(plant, fsm, family, nominal, lo, dt_s, delay_samples, f, members, time_limit_s,
                                start_method)
        search.append((lo, gamma))
        if k is None or gamma > 1.0:
            raise DesignError(f"no MIMO H-infinity controller meets the weights at the triangle target's bandwidth "
                              f"floor w_b = {lo:.0f} rad/s (gamma {gamma}); the family's uncertainty, the delay or the "
                              f"voltage range leaves no room")
        best = (w, k, gamma)
        for i in range(int(bisections)):
            mid = np.sqrt(lo * hi)
            w, k, gamma = _gamma_at(plant, fsm, family, nominal, mid, dt_s, delay_samples, f, members,
                                    time_limit_s, start_method)
            search.append((float(mid), gamma))
            if k is not None and gamma <= 1.0:
                lo, best = mid, (w, k, gamma)
            else:
                hi = mid
            if progress is not None:
                progress(i + 1, bisections)
    w, k, gamma = best
    peaks = weighted_peaks(plant, k, w, f)
    kr, bound, err = reduce_mimo(k, order, f)
    peaks_r = weighted_peaks(plant, kr, w, f)
    fc = _crossover_hz(f, _mimo_response(plant, f) @ _mimo_response(kr, f))
    t = gauge_coordinates(dec)
    kc = control.ss(_static(t) * kr * _static(np.linalg.inv(t)))
    kd = discretize(kc, dt_s, min(fc, 0.45 / dt_s))
    loop_in, loop_out = _evaluate(fsm, family, dec, kd, f, dt_s, delay_samples)
    lat = {ax: family_margins(f, {n: loop_at_a_time(l)[:, a] for n, l in loop_out.items()})
           for a, ax in enumerate(AXIS_NAMES)}

    def worst_disk(loops):
        res = {n: mimo_disk_margin(f, l) for n, l in loops.items()}
        n = min(res, key=lambda key: res[key]["alpha"])
        return {"member": n, **res[n]}
    design = HinfDesign(k, kc, kd, gamma, w, plant, peaks, peaks_r,
                        {"order_before": int(k.nstates), "order_after": int(kr.nstates), "error_bound": bound,
                         "error_measured": err}, dec, f, loop_in, loop_out, lat, worst_disk(loop_in),
                        worst_disk(loop_out), search, kr)
    for name, m in family.items():
        if isinstance(m, control.StateSpace):
            p = hinf_closed_loop_poles(fsm, m, design, dt_s, delay_samples)
            if np.max(p.real) >= 0:
                raise DesignError(f"the reduced H-infinity controller ({kr.nstates} states) does not stabilize "
                                  f"member {name!r}; raise the firmware order")
    return design


def _crossover_hz(f, loop):
    """Lowest frequency where the largest singular value of the loop falls through 1, Hz."""
    s = np.linalg.svd(loop, compute_uv=False)[:, 0]
    k = np.flatnonzero((s[:-1] >= 1) & (s[1:] < 1))
    return float(f[k[0]]) if k.size else float(f[-1])


def hinf_closed_loop_poles(fsm, member, design, dt_s=1e-4, delay_samples=1):
    """Poles (rad/s) of ``member`` (StateSpace) with the reduced continuous controller and the Pade chain closed."""
    dec = design.decoupler
    g = control.ss([], [], [], dec.out_q_per_v) * control.ss(member[G, V]) * control.ss([], [], [], dec.in_v_per_q)
    num, den = control.pade((1 + delay_samples) * dt_s, 2)
    pade = control.ss(control.tf(num, den))
    loop_plant = g * control.append(pade, pade, pade)
    return control.feedback(loop_plant, design.controller_c, sign=-1).poles()


def _diag_ctrl_resp(design, dt_s):
    """callable freq_hz -> the decoupled design's sampled axis controllers as (freqs, 3, 3) diagonal responses."""
    def resp(f):
        c = np.array([response(design.axes[ax].controller_d, f) for ax in AXIS_NAMES]).T
        return np.einsum("fi,ij->fij", c, np.eye(3))
    return resp


def _hinf_ctrl_resp(design, dt_s):
    def resp(f):
        kd = design.controller_d
        return np.moveaxis(np.asarray(kd(np.exp(2j * np.pi * np.asarray(f) * dt_s))).reshape(3, 3, -1), -1, 0)
    return resp


def main(argv=None):
    """``python -m workbench.design.mimo_hinf plants/fsm_p888_51.toml``: the three designs on the family, Markdown."""
    import sys
    from ..linearize.mimo import mirror_family
    from ..plant.mirror import load_mirror
    from .mimo import design_mimo
    path = (sys.argv[1:] if argv is None else argv) or ["plants/fsm_p888_51.toml"]
    fsm = load_mirror(path[0])
    fam = mirror_family(fsm)
    t0 = time.perf_counter()
    notch = design_mimo(fsm, fam, damping=False)
    damped = design_mimo(fsm, fam, damping=True)
    t1 = time.perf_counter()
    hinf = design_hinf(fsm, fam, progress=lambda i, n: print(f"w_b bisection {i}/{n}", file=sys.stderr, flush=True))
    t2 = time.perf_counter()
    w = hinf.weights
    print(f"H-inf: w_b = {w.bandwidth_rad_s:.0f} rad/s ({w.bandwidth_rad_s / 2 / np.pi:.0f} Hz; floor "
          f"{min_bandwidth_rad_s():.0f} rad/s), gamma {hinf.gamma:.3f}; search (w_b rad/s, gamma): "
          + ", ".join(f"({b:.0f}, {'fail' if g is None else f'{g:.3f}'})" for b, g in hinf.bandwidth_search))
    fit = w.derivation["w_t_fit"]
    print(f"W_t order {fit.order}, |W_t| {abs(complex(np.squeeze(w.w_t(0)))):.3f} at DC; W_u {float(np.squeeze(w.w_u.D)):.3f}; "
          f"controller {hinf.reduction['order_before']} -> {hinf.reduction['order_after']} states, error "
          f"{hinf.reduction['error_measured']:.3g} (bound {hinf.reduction['error_bound']:.3g}); weighted peaks full "
          + ", ".join(f"{k} {v:.3f}" for k, v in hinf.peaks.items()) + "; reduced "
          + ", ".join(f"{k} {v:.3f}" for k, v in hinf.peaks_reduced.items()))
    nom = fam[nominal_name()]
    budget = noise_budget(fsm)
    for label, d, resp in (("notch only", notch, _diag_ctrl_resp(notch, 1e-4)), ("MIMO H-inf", hinf,
                                                                                  _hinf_ctrl_resp(hinf, 1e-4))):
        rms = noise_rms_v(fsm, hinf.decoupler, nom, resp)
        print(f"gauge noise on the stack commands, {label}: " + ", ".join(f"{1e3 * r:.1f}" for r in rms)
              + f" mV RMS (budget {1e3 * budget:.1f} mV)")
    print(f"(decoupled designs {t1 - t0:.0f} s, H-inf {t2 - t1:.0f} s)\n")
    print(comparison_markdown(notch, damped, hinf))


if __name__ == "__main__":
    from ..arguments import run_script                   # one-line errors, Ctrl-C / SIGTERM without a traceback
    raise SystemExit(run_script("python -m workbench.design.mimo_hinf", main))
