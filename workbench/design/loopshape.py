"""Structured loop shaping: PI, lead, roll-off (and an optional notch) tuned against the whole family.

The controller, in continuous time and then Tustin-discretized at the servo rate
with prewarp at the crossover f_c:

    C(s) = k (1 + w_i / s) (1 + s / w_z) / (1 + s / w_p) w_r^2 / (s^2 + 2 zeta w_r s + w_r^2) [notch]

with w_i = 2 pi f_c / r_i, a lead centred on f_c (w_z = 2 pi f_c / sqrt(alpha),
w_p = 2 pi f_c sqrt(alpha)) and the roll-off at r_r f_c. k puts the nominal loop's
crossover at f_c. For every shape on a small grid the highest f_c whose loops keep
the margin targets on EVERY member of the family (the describing functions and
small-signal models of issue 3, seen through the sampled gauge chain) is found; the
shape whose lowest crossover over the family is highest wins, ties broken by the worst
disk margin. With a
noise budget, shapes whose gain turns the gauge noise into larger command steps than the
output rate limit allows are skipped (verification showed that such a controller keeps
the output rate limit busy on noise alone and biases the loop).

Margins are checked first on the members that bound the family at each frequency
(largest and smallest gain and phase), then on all members for the chosen design.
"""

from dataclasses import dataclass, field, replace

import control
import numpy as np

from ..errors import DesignError
from ..linearize.limit_cycle import sampled_factor
from .antiwindup import discretize
from .margins import family_margins, response

__all__ = ["LoopShapeSpec", "LoopShapeResult", "structured_controller", "family_loops", "tune_loop_shape",
           "noise_command_rms_v", "nominal_step", "shape_response", "tustin_s", "CONSTRAINTS", "relaxed",
           "triangle_harmonics", "tracking_rms"]


@dataclass(frozen=True)
class LoopShapeSpec:
    """Targets and the grid of shapes searched."""

    phase_margin_deg: float = 45.0
    gain_margin_db: float = 6.0
    fc_range_hz: tuple = (50.0, 1500.0)
    fc_points: int = 24
    # r_i < 1 (the PI zero above the crossover, integral action dominating) is the low-noise
    # choice for this flat plant; with a noise budget try e.g. (0.1, 0.25, 1, 8)
    integral_ratios: tuple = (4.0, 8.0)
    # 1: PI (type-1 loop: a ramp leaves r'/K_v); 2: (1 + w_i/s)^2, a type-2 loop that tracks a ramp without
    # steady error (the triangle's error is then left at its corners)
    integral_orders: tuple = (1,)
    lead_ratios: tuple = (1.0, 3.0, 6.0)
    rolloff_ratios: tuple = (4.0, 8.0)
    rolloff_damping: float = 0.6
    notch: tuple | None = None        # (freq_hz, depth_db, width_ratio) for a structural mode
    # gauge noise through K S must not make the command lead the stack voltage by more than this
    # RMS, V: the lead over R is the current asked of the amplifier, and noise that reaches the
    # +2 mA source limit (R I = 0.16 V) is rectified by the asymmetric limits into a position
    # bias (the verification found this); R I_source / 3 keeps it below the limit at 3 sigma.
    # The stack voltage follows the command as v <- v + alpha (u - v) (``voltage_alpha``;
    # None: the per-sample change of the command). None: no limit
    max_noise_command_v: float | None = None
    noise_reading_v: float = 0.0      # RMS noise of one gauge reading, firmware V
    voltage_alpha: float | None = None
    # overshoot of the nominal sampled loop's step response, %: a small step the current limit
    # slews (as a 0.1 um step does on the ascending branch at > 100 Hz) loses its overshoot, so a
    # design that promises little is one the hardware can keep; None: no limit
    max_overshoot_percent: float | None = None
    # reference tracking (:func:`triangle_harmonics`): the steady-state RMS of S r over the reference's
    # harmonics (``tracking_freq_hz``, peak ``tracking_amplitudes``, fraction of stroke) on the nominal
    # loop may be at most ``max_tracking_rms`` (fraction of stroke); None: no limit
    tracking_freq_hz: tuple = ()
    tracking_amplitudes: tuple = ()
    max_tracking_rms: float | None = None
    # with a tracking limit and this crossover floor (Hz), shapes are ranked by the smaller of their two
    # target ratios, min(lowest crossover / target_crossover_hz, max_tracking_rms / tracking RMS): the design
    # keeps the most margin on both floors; None: ranked by the lowest crossover alone
    target_crossover_hz: float | None = None
    dt_s: float = 1e-4
    delay_samples: int = 1


@dataclass(frozen=True)
class LoopShapeResult:
    controller_c: control.TransferFunction
    controller_d: control.StateSpace
    params: dict
    crossover_hz: float               # the lowest crossover over the family (the nominal sits at f_c)
    worst: dict                       # metric -> {value, member, freq_hz}
    rows: list = field(repr=False)    # margins per member
    searched: int = 0
    binding: dict = None              # the constraint that bound the crossover (see tune_loop_shape)
    tracking: dict = None             # the reference-tracking check (None without one): winner's RMS, shapes it ruled out
    tracking_loop: np.ndarray = field(default=None, repr=False)   # the winner's nominal L at the harmonics


def structured_controller(k, fc_hz, integral_ratio, lead_ratio, rolloff_ratio, rolloff_damping=0.6, notch=None,
                          integral_order=1):
    """C(s) of the module docstring (continuous TransferFunction); ``integral_order`` 2: (1 + w_i/s)^2 (type 2)."""
    return control.minreal(shape_response(control.tf("s"), k, fc_hz, integral_ratio, lead_ratio, rolloff_ratio,
                                          rolloff_damping, notch, integral_order), verbose=False)


def _discrete_response(ctrl_d, freq_hz):
    return response(ctrl_d, freq_hz)


def shape_response(s, k, fc_hz, integral_ratio, lead_ratio, rolloff_ratio, rolloff_damping=0.6, notch=None,
                   integral_order=1):
    """C(s) of the module docstring at ``s``: a complex array (rad/s, vectorized) or ``control.tf("s")``.

    The one formula of the structured controller; :func:`structured_controller` is this at
    ``tf("s")``, minimal.
    """
    wc = 2 * np.pi * fc_hz
    c = k * (1 + (wc / integral_ratio) / s) ** int(integral_order)
    if lead_ratio > 1:
        c = c * (1 + s / (wc / np.sqrt(lead_ratio))) / (1 + s / (wc * np.sqrt(lead_ratio)))
    wr = wc * rolloff_ratio
    c = c * wr ** 2 / (s ** 2 + 2 * rolloff_damping * wr * s + wr ** 2)
    if notch is not None:
        fn, depth_db, width = notch
        wn = 2 * np.pi * fn
        zd = width / 2
        c = c * (s ** 2 + 2 * zd * 10 ** (-depth_db / 20) * wn * s + wn ** 2) / (s ** 2 + 2 * zd * wn * s + wn ** 2)
    return c


def tustin_s(freq_hz, dt_s, prewarp_hz):
    """The s at which a continuous C gives the response of its prewarped Tustin map at ``freq_hz``.

    Tustin prewarped at w_c maps s = (w_c / tan(w_c T / 2)) (z - 1) / (z + 1), and on the
    unit circle (z - 1) / (z + 1) = j tan(w T / 2): C_d(e^{jwT}) = C(j w_c tan(w T / 2) / tan(w_c T / 2)).
    """
    wc = 2 * np.pi * prewarp_hz
    return 1j * wc * np.tan(np.pi * np.asarray(freq_hz, dtype=float) * dt_s) / np.tan(wc * dt_s / 2)


def family_loops(ctrl_d, freq_hz, members, delay_samples=1):
    """L_i(jw) = C(e^{jwT}) x hold/average/delay x G_i(jw) for every member (NaN where it is left out)."""
    common = _discrete_response(ctrl_d, freq_hz) * sampled_factor(freq_hz, ctrl_d.dt, delay_samples)
    return {name: common * g for name, g in members.items()}


def _bounding_members(names, resp):
    """Members that bound the family's value set at some frequency (gain and phase extremes)."""
    mag = np.where(np.isnan(resp), np.nan, np.abs(resp))
    ph = np.where(np.isnan(resp), np.nan, np.unwrap(np.angle(np.nan_to_num(resp)), axis=1))
    keep = set()
    for arr in (mag, ph):
        with np.errstate(all="ignore"):
            valid = ~np.all(np.isnan(arr), axis=0)
            keep |= set(np.nanargmax(arr[:, valid], axis=0)) | set(np.nanargmin(arr[:, valid], axis=0))
    return [names[i] for i in sorted(keep)]


def _meets(worst, spec):
    return (worst["phase_margin_deg"]["value"] >= spec.phase_margin_deg
            and worst["gain_margin_db"]["value"] >= spec.gain_margin_db)


def _noise_grid(dt_s, n=4096):
    return (np.arange(n) + 0.5) / n * 0.5 / dt_s


def _noise_rms(k, g, f, dt_s, noise_reading_v, delay_samples, alpha):
    ks = k / (1 + k * sampled_factor(f, dt_s, delay_samples) * g)
    zi = np.exp(-2j * np.pi * f * dt_s)
    a = 1.0 if alpha is None else float(alpha)
    h = (1 - zi) / (1 - (1 - a) * zi)
    return float(noise_reading_v * np.sqrt(np.mean(np.abs(h * ks) ** 2)))


def noise_command_rms_v(ctrl_d, nominal, noise_reading_v, delay_samples=1, alpha=None, n=4096, nominal_factor=None):
    """RMS lead of the command over the stack voltage that the gauge noise causes through K S, V.

    White noise of ``noise_reading_v`` RMS per reading; the nominal sampled loop; the stack
    voltage follows the command as v <- v + alpha (u - v), so u - v = H u with
    H = (1 - z^-1) / (1 - (1 - alpha) z^-1) and sigma^2 = sigma_n^2 (1/pi) int_0^pi
    |H K S|^2 d theta. ``alpha`` None (or 1): H = 1 - z^-1, the change per sample.
    ``nominal_factor``: the sensor's path (as in :func:`tune_loop_shape`).
    """
    f = _noise_grid(ctrl_d.dt, n)
    g = response(nominal, f) * (1.0 if nominal_factor is None else nominal_factor(f))
    return _noise_rms(response(ctrl_d, f), g, f, ctrl_d.dt, noise_reading_v, delay_samples, alpha)


def sampled_nominal(nominal, dt_s, delay_samples=1):
    """The continuous ``nominal`` (K_g P) held, period-averaged and delayed exactly, as firmware sees it."""
    from ..linearize.sampled import compute_delay, period_average
    return period_average(control.ss(nominal), dt_s) * compute_delay(dt_s, delay_samples)


def nominal_step(ctrl_d, nominal, delay_samples=1, n=2000, plant_d=None):
    """(overshoot %, 2 % settling time s) of the nominal loop as firmware closes it.

    The continuous ``nominal`` (K_g P, firmware V per V) is held, period-averaged and
    delayed exactly (:mod:`workbench.linearize.sampled`; or give that discrete plant as
    ``plant_d``), the loop closed with ``ctrl_d``; the unit step is run on the closed
    loop's state space sample by sample (what ``control.step_response`` computes).
    """
    dt = ctrl_d.dt
    g = sampled_nominal(nominal, dt, delay_samples) if plant_d is None else plant_d
    cl = control.feedback(control.ss(ctrl_d) * g, 1)
    a, b = np.asarray(cl.A), np.asarray(cl.B)[:, 0]
    c, d = np.asarray(cl.C)[0], float(np.asarray(cl.D)[0, 0])
    x = np.zeros(a.shape[0])
    y = np.empty(n)
    for k in range(n):
        y[k] = c @ x + d
        x = a @ x + b
    from .step import step_metrics
    return step_metrics(np.arange(n) * dt, y, 0.0, 1.0)


def triangle_harmonics(freq_hz, span_fraction=0.8, f_max_hz=None, n_max=20001):
    """(harmonic frequencies Hz, peak amplitudes) of a triangle of ``freq_hz`` spanning ``span_fraction``
    peak to peak (10-90 % of stroke: 0.8; amplitudes in the same unit).

    A triangle of peak A (p-p 2A) is (8 A / pi^2) sum over odd k of (-1)^((k-1)/2) sin(k w t) / k^2: the
    k-th amplitude is 4 span / (pi^2 k^2). Harmonics up to ``f_max_hz`` (and k <= ``n_max``).
    """
    k = np.arange(1, n_max + 1, 2, dtype=float)
    if f_max_hz is not None:
        k = k[k * freq_hz <= f_max_hz]
    return k * freq_hz, 4.0 * span_fraction / (np.pi ** 2 * k ** 2)


def tracking_rms(loop, amplitudes, freq_hz=None, lead_s=0.0, dt_s=None):
    """Steady-state RMS error of a reference with harmonics of peak ``amplitudes`` through S = 1 / (1 + L)
    (``loop``: L at those harmonics): sqrt(sum |S_k r_k|^2 / 2); with velocity feedforward ``lead_s``,
    sqrt(sum |S_k (1 - D_k lead_s L_k) r_k|^2 / 2).

    Without a lead, for a type-1 loop and a triangle this tends to ramp rate / K_v (the error is a square
    wave of +/- r' / K_v) when every harmonic that matters lies well below the crossover.

    With the lead (the sensor block's ``ref_lead_s``: the loop is fed r + lead_s v, v the planned slope, the
    forward difference (r_{k+1} - r_k) / T of :func:`workbench.verify.scenarios.planned_slope_lead`), the fed
    reference is (1 + D lead_s) r with D(w) = (e^{j w T} - 1) / T (j w as T -> 0), so the error is
    e = r - T_cl (1 + D lead_s) r = (S - D lead_s T_cl) r = S (1 - D lead_s L) r, since T_cl = S L. With
    lead_s = 1/K_v and L ~ K_v / (j w) at the low harmonics, the bracket vanishes to first order: what is
    left is L's departure from K_v / (j w) (its other poles and zeros, and the nominal loop's K_v against the
    one the lead was taken from).

    Parameters
    ----------
    loop : array_like of complex
        L at the harmonics.
    amplitudes : array_like
        Peak amplitude of each harmonic (any unit: the RMS comes in it).
    freq_hz : array_like, optional
        The harmonics' frequencies, Hz (required with a lead).
    lead_s : float, default 0
        Velocity feedforward, s (0: none, the first form).
    dt_s : float, optional
        Sample time T of the forward difference, s (None: j w).

    Returns
    -------
    float
        The RMS error, in the unit of ``amplitudes``.
    """
    lo = np.asarray(loop)
    bracket = 1.0
    if lead_s:
        if freq_hz is None:
            raise ValueError("tracking_rms with a lead needs the harmonics' freq_hz")
        jw = 2j * np.pi * np.asarray(freq_hz, float)
        d = jw if dt_s is None else (np.exp(jw * dt_s) - 1.0) / dt_s
        bracket = 1.0 - d * lead_s * lo
    e = np.abs(np.asarray(amplitudes) * bracket / (1.0 + lo))
    return float(np.sqrt(0.5 * np.sum(e ** 2)))


# what the search can be bound by: constraint -> (LoopShapeSpec field, unit, relaxation, relaxation said)
CONSTRAINTS = {
    "noise budget": ("max_noise_command_v", "V RMS", lambda v: 2.0 * v, "doubled"),
    "phase margin": ("phase_margin_deg", "deg", lambda v: v - 5.0, "5 deg lower"),
    "gain margin": ("gain_margin_db", "dB", lambda v: v - 1.0, "1 dB lower"),
    "overshoot": ("max_overshoot_percent", "%", lambda v: v + 2.0, "2 points higher"),
    "triangle tracking": ("max_tracking_rms", "fraction of stroke RMS", lambda v: 2.0 * v, "doubled"),
    "crossover search range": ("fc_range_hz", "Hz", lambda v: (v[0], 2.0 * v[1]), "upper end doubled"),
}


def relaxed(spec, constraint, times=1):
    """``spec`` with ``constraint`` (a key of :data:`CONSTRAINTS`) relaxed ``times`` times by its stated amount."""
    field_name, _, step, _ = CONSTRAINTS[constraint]
    value = getattr(spec, field_name)
    for _ in range(times):
        value = step(value)
    if field_name in ("phase_margin_deg", "gain_margin_db"):
        value = max(value, 0.0)
    if field_name == "fc_range_hz":              # the prewarp must stay below Nyquist
        value = (value[0], min(value[1], 0.45 / spec.dt_s))
    return replace(spec, **{field_name: value})


def _evaluate(s_loop, sf, bounding, f, nominal_fc, spec, fc, ri, al, rr, noise, no=1):
    """Gain and checks of one shape at one f_c; returns (k, reason, value, limit, worst)."""
    sw = tustin_s([fc], spec.dt_s, fc)
    l1 = shape_response(sw, 1.0, fc, ri, al, rr, spec.rolloff_damping, spec.notch, no)[0] * nominal_fc
    k = 1.0 / abs(l1)
    c = shape_response(s_loop, k, fc, ri, al, rr, spec.rolloff_damping, spec.notch, no)
    if spec.max_noise_command_v is not None:
        fn, gn, sn = noise
        rms = _noise_rms(shape_response(sn, k, fc, ri, al, rr, spec.rolloff_damping, spec.notch, no), gn, fn,
                         spec.dt_s, spec.noise_reading_v, spec.delay_samples, spec.voltage_alpha)
        if rms > spec.max_noise_command_v:
            return k, "noise budget", rms, spec.max_noise_command_v, None
    _, worst = family_margins(f, {n: c * sf * g for n, g in bounding.items()})
    pm, gm = worst["phase_margin_deg"]["value"], worst["gain_margin_db"]["value"]
    if pm < spec.phase_margin_deg:
        return k, "phase margin", pm, spec.phase_margin_deg, worst
    if gm < spec.gain_margin_db:
        return k, "gain margin", gm, spec.gain_margin_db, worst
    return k, None, None, None, worst


def tune_loop_shape(freq_hz, members, nominal, spec=LoopShapeSpec(), progress=None, step_plant=None,
                    nominal_factor=None, step_plant_d=None):
    """Highest-crossover structured controller meeting the margins on every member.

    Parameters
    ----------
    freq_hz : ndarray
        Grid of the members (dense enough around the crossover, up to Nyquist).
    members : dict name -> complex ndarray
        Loop plants K_g P_i(jw), firmware volts per PZT volt (NaN: left out there).
    nominal : continuous SISO LTI
        K_g P_nom(s), used to place the crossover.
    step_plant : continuous SISO LTI, optional
        K_g P(s) the overshoot limit is judged on (default ``nominal``); e.g. the
        ascending-branch model, where a small step up runs.
    nominal_factor : callable(freq_hz) -> complex ndarray, optional
        Multiplies the nominal's response wherever the search uses it (crossover placement,
        noise, tracking): the sensor's path relative to the gauge chain
        (:meth:`workbench.study.sensor.SensorModel.factor`); None: the gauge chain.
    step_plant_d : discrete SISO LTI, optional
        The sampled plant the overshoot is judged on, as firmware closes the loop (default:
        ``step_plant`` held, averaged and delayed).

    Returns
    -------
    LoopShapeResult
        With ``binding``: the constraint that stopped the winning shape from crossing
        over at the next f_c of the grid (``constraint``, the ``value`` it reached there
        against its ``limit``, ``at_fc_hz``), or the top of the search range.

    Notes
    -----
    Candidates are scored by their exact responses (the prewarped Tustin map evaluated
    on the unit circle, :func:`tustin_s`), so no state space is built in the search.
    """
    step_plant = nominal if step_plant is None else step_plant
    f = np.asarray(freq_hz, dtype=float)
    # a member left out at every frequency (it slews everywhere on the grid) has no loop to measure
    members = {n: g for n, g in members.items() if np.any(np.isfinite(g))}
    names = list(members)
    resp = np.array([members[n] for n in names])
    bounding = {n: members[n] for n in _bounding_members(names, resp)}
    fcs = np.geomspace(*spec.fc_range_hz, spec.fc_points)

    def nominal_resp(fr):
        r = response(nominal, fr)
        return r if nominal_factor is None else r * nominal_factor(fr)
    nominal_at = nominal_resp(fcs)
    sf = sampled_factor(f, spec.dt_s, spec.delay_samples)
    fn = _noise_grid(spec.dt_s)
    g_noise = nominal_resp(fn)
    step_d = None
    if spec.max_overshoot_percent:
        step_d = (sampled_nominal(step_plant, spec.dt_s, spec.delay_samples) if step_plant_d is None
                  else step_plant_d)
    track = spec.max_tracking_rms is not None
    if track:
        f_tr = np.asarray(spec.tracking_freq_hz, dtype=float)
        g_tr = nominal_resp(f_tr) * sampled_factor(f_tr, spec.dt_s, spec.delay_samples)
    tracking_misses = []       # (shape, f_c, RMS): shapes whose highest admissible f_c tracks too poorly
    shapes = [(ri, al, rr, no) for no in spec.integral_orders for ri in spec.integral_ratios
              for al in spec.lead_ratios for rr in spec.rolloff_ratios]
    best, searched = None, 0
    for n_shape, (ri, al, rr, no) in enumerate(shapes):
        above = None               # why the next-higher f_c of this shape failed
        for j in range(fcs.size - 1, -1, -1):
            fc = fcs[j]
            searched += 1
            s_loop = tustin_s(f, spec.dt_s, fc)
            noise = (fn, g_noise, tustin_s(fn, spec.dt_s, fc))
            l_nom = sampled_factor([fc], spec.dt_s, spec.delay_samples)[0] * nominal_at[j]
            k, reason, value, limit, worst = _evaluate(s_loop, sf, bounding, f, l_nom, spec, fc, ri, al, rr, noise, no)
            e_tr = None
            if reason is None and track:
                l_tr = shape_response(tustin_s(f_tr, spec.dt_s, fc), k, fc, ri, al, rr, spec.rolloff_damping,
                                      spec.notch, no) * g_tr
                e_tr = tracking_rms(l_tr, spec.tracking_amplitudes)
                if e_tr > spec.max_tracking_rms:
                    # a lower f_c only weakens the low-frequency gain: this shape cannot track the reference
                    tracking_misses.append(((ri, al, rr, no), float(fc), e_tr))
                    break
            if reason is None and spec.max_overshoot_percent is not None:
                ctrl_d = discretize(structured_controller(k, fc, ri, al, rr, spec.rolloff_damping, spec.notch, no),
                                    spec.dt_s, fc)
                ov = nominal_step(ctrl_d, step_plant, spec.delay_samples, plant_d=step_d)[0]
                if ov > spec.max_overshoot_percent:   # (checked last: a step response costs more)
                    reason, value, limit = "overshoot", ov, spec.max_overshoot_percent
            if reason is not None:
                above = {"constraint": reason, "value": float(value), "limit": float(limit), "at_fc_hz": float(fc),
                         "unit": CONSTRAINTS[reason][1]}
                continue       # a lower f_c may do
            if above is None:
                above = {"constraint": "crossover search range", "value": float(fc),
                         "limit": float(spec.fc_range_hz[1]), "at_fc_hz": float(fc), "unit": "Hz"}
            # the lowest crossover over the family is what the bandwidth target is about
            score = worst["crossover_hz_min"]["value"]
            if e_tr is not None and spec.target_crossover_hz:
                score = min(score / spec.target_crossover_hz, spec.max_tracking_rms / max(e_tr, 1e-300))
            cand = (score, worst["disk_margin"]["value"],
                    dict(k=k, fc_hz=fc, integral_ratio=ri, lead_ratio=al, rolloff_ratio=rr,
                         rolloff_damping=spec.rolloff_damping, notch=spec.notch, integral_order=no), above)
            if best is None or (cand[0], cand[1]) > (best[0], best[1]):
                best = cand
            break          # lower f_c on this shape can only be slower
        if progress is not None:
            progress(n_shape + 1, len(shapes))
    if best is None:
        raise DesignError(f"no structured controller meets PM >= {spec.phase_margin_deg:g} deg and GM >= "
                          f"{spec.gain_margin_db:g} dB on every member"
                          + (f" and keeps the gauge noise on the command below {spec.max_noise_command_v:.3g} V RMS"
                             if spec.max_noise_command_v is not None else "")
                          + (f" and overshoots at most {spec.max_overshoot_percent:g} %"
                             if spec.max_overshoot_percent is not None else "")
                          + (f" and tracks the reference within {spec.max_tracking_rms:.3g} of stroke RMS (best "
                             f"found {min(m[2] for m in tracking_misses):.3g})"
                             if track and tracking_misses else "")
                          + f" with a crossover in {spec.fc_range_hz[0]:g}-{spec.fc_range_hz[1]:g} Hz; "
                            f"lower the range or the targets")
    p = best[2]
    ctrl_c = structured_controller(p["k"], p["fc_hz"], p["integral_ratio"], p["lead_ratio"], p["rolloff_ratio"],
                                   p["rolloff_damping"], p["notch"], p["integral_order"])
    ctrl_d = discretize(ctrl_c, spec.dt_s, p["fc_hz"])
    rows, worst = family_margins(f, family_loops(ctrl_d, f, members, spec.delay_samples))
    if not _meets(worst, spec):
        raise DesignError(f"the chosen design misses the targets on a member outside the bounding set "
                          f"({worst['phase_margin_deg']['member']}); refine the frequency grid")
    tracking = None
    if track:
        l_tr = shape_response(tustin_s(f_tr, spec.dt_s, p["fc_hz"]), p["k"], p["fc_hz"], p["integral_ratio"],
                              p["lead_ratio"], p["rolloff_ratio"], p["rolloff_damping"], p["notch"],
                              p["integral_order"]) * g_tr
        tracking = {"rms": tracking_rms(l_tr, spec.tracking_amplitudes), "limit": spec.max_tracking_rms,
                    "harmonics": int(f_tr.size),
                    "ruled_out": [{"integral_ratio": sh[0], "lead_ratio": sh[1], "rolloff_ratio": sh[2],
                                   "integral_order": sh[3],
                                   "fc_hz": fc_, "rms": e_} for sh, fc_, e_ in tracking_misses]}
    return LoopShapeResult(ctrl_c, ctrl_d, p, float(worst["crossover_hz_min"]["value"]), worst, rows, searched,
                           best[3], tracking, l_tr if track else None)
