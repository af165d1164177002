"""s34_outsider: an INDEPENDENT record generator for red-teaming `workbench calibrate`.

Nothing here imports the workbench's simulator or plant kernels (only `calibration_protocol`, to make the
protocol's drive, as the brief allows). The physics is deliberately outside the engine's model family:

* amplifier: an ideal voltage source behind a current limit (lab amplifier, 0.2 A), optionally slew-limited,
  with gain/offset when the logged voltage is the command;
* series resistor R between the amplifier's monitor (the logged voltage) and the stack's terminals;
* stack: displacement x = d u, u = s_lin v_t + H(v_t), where H is a **Preisach** operator with a continuous 2-D
  density mu(r, m) = exp(-r/r0) exp(-(m-m_c)^2/2s^2) (r half-width, m mean of a relay; 1500 alpha rows, continuous
  in beta): it depends on the relay's mean, so it is NOT a Prandtl-Ishlinskii (backlash) operator, whose Preisach
  density depends on r only (minor loops are not congruent; wiping-out holds). The stack starts at rest on the
  descending branch of an earlier 0..drive_max cycle (a poled stack used before), not demagnetised.
  The charge is linear, q = C v_t (the current charges C through R): this generator's charge channel carries no
  hysteresis. (Tried first and dropped, logs/*_v0_*: a Bouc-Wen state, whose minor loops do not close -- a ~1 um
  accommodation drift under the protocol's 0.5 V chirp, no stack shows that -- and a Preisach in the charge
  integrated on the fine grid, whose row switching pumped charge: a generator artefact, not physics);
* amplifier current limit and slew on a fine grid of RC/10 (numba); H, creep and modes on the sample grid (the
  modes on a grid up to 64x finer, u linear between samples);
* creep (effect): a long-tail Kelvin chain of 8 first-order branches, tau log-spaced 20 ms..200 s, equal weights,
  i.e. x_creep ~ gamma log10(t / t0) after a step;
* the stack's own axial mode (70 kHz, zeta 0.02; 110 kHz for the small stack), and optionally a structural mode,
  each an exact zero-order-hold 2-state filter (stable for any step);
* sensors: a displacement channel (capacitive sensor: own offset, white noise), a strain gauge (own gain,
  offset, white noise, in volts: ~1/3.1 um per V), current (white noise), voltage (white noise), all sampled at
  the sample instant (the reader's default `sampled` convention).

The electrical part is integrated by explicit Euler on a fine grid of at most RC/10 (numba).
"""
import math

import numpy as np
from numba import njit
from scipy.linalg import expm

RIGS = {
    # P-888.51-class: 15 um at 100 V (-20..120 V), ~5.8 uF large-signal, 80 ohm
    "p888": dict(R=80.0, d=0.089e-6, s_lin=0.9, C=5.8e-6, preisach={'n_alpha': 1500}, vmin=-20.0, vmax=120.0,
                 drive_max=100.0, i_lim=0.2, f_stack=70e3, noise_x=3e-9, noise_i=3e-6, noise_v=5e-3,
                 gauge_m_per_v=3.1e-6, gauge_x0=7.5e-6, noise_g=1.5e-3, plant="plants/p888_51_sn637.toml"),
    # a smaller stack: 20 um at 150 V, 1.5 uF, 50 ohm; calibrated against the generic plant (-150..150 V)
    "small": dict(R=50.0, d=0.080e-6, s_lin=0.9, C=1.5e-6, preisach={'n_alpha': 1500}, vmin=0.0, vmax=150.0,
                  drive_max=150.0, i_lim=0.2, f_stack=110e3, noise_x=4e-9, noise_i=1e-6, noise_v=5e-3,
                  gauge_m_per_v=4e-6, gauge_x0=10e-6, noise_g=1.5e-3, plant="plants/generic_stack.toml"),
}
CREEP_TAUS = np.geomspace(0.02, 200.0, 8)


def mode_zoh(f_hz, zeta, dt):
    """Exact ZOH discretisation (A_d, B_d) of x'' + 2 zeta w x' + w^2 x = w^2 u, state (x, x')."""
    w = 2 * math.pi * f_hz
    A = np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]])
    M = np.zeros((3, 3))
    M[:2, :2] = A * dt
    M[1, 2] = w * w * dt
    E = expm(M)
    return E[:2, :2].copy(), E[:2, 2].copy()


@njit(cache=True)
def _preisach(D, alphas, bgrid, cum, db):
    # sum over alpha rows of (up part - down part) = 2 F_row(D) - F_row(alpha)
    out = 0.0
    for r_ in range(alphas.size):
        pos = (D[r_] - bgrid[0]) / db
        k = int(pos)
        if k >= bgrid.size - 1:
            fd = cum[r_, bgrid.size - 1]
        else:
            fr = pos - k
            fd = cum[r_, k] * (1 - fr) + cum[r_, k + 1] * fr
        out += 2 * fd - cum[r_, bgrid.size - 1]
    return out


def preisach_table(vmin, vmax, n_alpha=120, n_beta=600, r0_frac=0.10, m_sigma_frac=0.35, m_center_frac=0.45):
    """Rows alpha_i, a beta grid, and each row's cumulative weight over beta (a relay (alpha, beta) is up
    above alpha, down below beta). Density mu = exp(-r / r0) exp(-(m - m_c)^2 / 2 s^2), r = (alpha - beta) / 2,
    m = (alpha + beta) / 2: it depends on the mean m, so this is not a Prandtl-Ishlinskii operator
    (whose Preisach density depends on r only). Normalised so the relays' total weight is 1 per volt of span."""
    span = vmax - vmin
    lo, hi = vmin - 0.3 * span, vmax + 0.3 * span
    alphas = np.linspace(lo, hi, n_alpha)
    bgrid = np.linspace(lo, hi, n_beta)
    A, B = np.meshgrid(alphas, bgrid, indexing="ij")
    r = (A - B) / 2
    m = (A + B) / 2
    mu = np.where(B <= A, np.exp(-r / (r0_frac * span)) * np.exp(-0.5 * ((m - (vmin + m_center_frac * span)) / (m_sigma_frac * span)) ** 2), 0.0)
    cum = np.cumsum(mu, axis=1)
    cum *= 0.5 * span / cum[:, -1].sum()
    return alphas, bgrid, cum


@njit(cache=True)
def _electrical(cmd_f, sub, R, C, i_lim, slew, dt):
    """Amplifier (current limit, optional slew) -> R -> a linear stack capacitance C (the charge channel is
    hysteresis-free in this generator: see the module note); returns v_mon, i, v_t at the samples."""
    nf = cmd_f.size
    n = nf // sub
    v_mon = np.empty(n)
    i_s = np.empty(n)
    vt_s = np.empty(n)
    v_t = cmd_f[0]
    va_slewed = cmd_f[0]
    k = 0
    for j in range(nf):
        target = cmd_f[j]
        if slew > 0:
            dv = target - va_slewed
            lim = slew * dt
            if dv > lim:
                dv = lim
            elif dv < -lim:
                dv = -lim
            va_slewed += dv
        else:
            va_slewed = target
        i = (va_slewed - v_t) / R
        if i > i_lim:
            i = i_lim
        elif i < -i_lim:
            i = -i_lim
        va = v_t + R * i
        if (j + 1) % sub == 0:      # the instant's triple: va = v_t + R i holds before the step
            v_mon[k] = va
            i_s[k] = i
            vt_s[k] = v_t
            k += 1
        v_t += i * dt / C
    return v_mon, i_s, vt_s


@njit(cache=True)
def _hyst(vt, alphas, bgrid, cum, D0):
    """Preisach output H at each sample of the terminal voltage (rows of alpha, continuous in beta)."""
    D = D0.copy()
    na = alphas.size
    db = bgrid[1] - bgrid[0]
    H = np.empty(vt.size)
    u_prev = vt[0]
    for k in range(vt.size):
        v = vt[k]
        if v > u_prev:
            for r_ in range(na):
                if alphas[r_] <= v:
                    D[r_] = alphas[r_]
        elif v < u_prev:
            lo = max(v, bgrid[0])
            for r_ in range(na):
                if D[r_] > lo:
                    D[r_] = lo
        u_prev = v
        H[k] = _preisach(D, alphas, bgrid, cum, db)
    return H


@njit(cache=True)
def _creep_modes(u, creep_w, creep_a, Ad1, Bd1, Ad2, Bd2, use2, up):
    """Kelvin-chain creep on the sample grid, then the modes on a grid ``up`` times finer (u linear between samples)."""
    n = u.size
    nc = creep_a.size
    s = np.full(nc, u[0])
    xq = np.empty(n)
    W = creep_w.sum()
    for k in range(n):
        xc = 0.0
        for c in range(nc):
            s[c] += (u[k] - s[c]) * creep_a[c]
            xc += creep_w[c] * (u[k] - s[c])
        xq[k] = u[k] * (1.0 + W) - xc
    out = np.empty(n)
    m1 = np.array([xq[0], 0.0])
    m2 = np.array([xq[0], 0.0])
    for k in range(n):
        x0 = xq[k - 1] if k > 0 else xq[0]
        for j in range(up):
            xin = x0 + (xq[k] - x0) * (j + 1) / up
            y0 = Ad1[0, 0] * m1[0] + Ad1[0, 1] * m1[1] + Bd1[0] * xin
            y1 = Ad1[1, 0] * m1[0] + Ad1[1, 1] * m1[1] + Bd1[1] * xin
            m1[0] = y0
            m1[1] = y1
            xo = m1[0]
            if use2:
                z0 = Ad2[0, 0] * m2[0] + Ad2[0, 1] * m2[1] + Bd2[0] * xo
                z1 = Ad2[1, 0] * m2[0] + Ad2[1, 1] * m2[1] + Bd2[1] * xo
                m2[0] = z0
                m2[1] = z1
                xo = m2[0]
        out[k] = xo
    return out


def simulate(rig, t, drive, seed=0, creep_gamma=0.0, mode=None, slew_v_per_s=0.0, cmd_gain=1.0, cmd_offset=0.0,
             preisach=None, rest="descending"):
    """Simulate rig ``rig`` (a RIGS entry) driven by ``drive(t_fine)`` (V, the amplifier's target).

    ``creep_gamma``: the summed Kelvin-chain weight (x grows by ~creep_gamma of the step over 20 ms..200 s,
    ~ creep_gamma/4 per decade). ``mode``: (f_hz, zeta) of a structural mode in series with the stack's.
    The amplifier target is ``cmd_gain * drive + cmd_offset`` (a command record logs ``drive``).
    Returns a dict of noise-free sampled truths: v_mon, i, x (SI) and ``cmd`` (the drive at the samples).
    """
    p = RIGS[rig]
    dt_s = float(t[1] - t[0])
    C = p["C"]
    rc = p["R"] * C
    sub = max(1, int(math.ceil(dt_s / (rc / 10))))
    dt = dt_s / sub
    tf = t[0] - dt_s + (np.arange(t.size * sub) + 1) * dt       # fine points; every sub-th lands on a sample
    cmd_f = cmd_gain * drive(tf) + cmd_offset
    v, i, vt = _electrical(cmd_f, sub, p["R"], C, p["i_lim"], float(slew_v_per_s), dt)
    del tf, cmd_f
    alphas, bgrid, cum = preisach_table(p["vmin"], p["vmax"], **{**p["preisach"], **(preisach or {})})
    # the stack at rest at the first command after earlier use: up to the drive's maximum, then down to it
    # (not a demagnetised state: a poled stack that was cycled before rests on a descending branch)
    D0 = np.where(alphas <= p["drive_max"], alphas, bgrid[0])
    D0 = np.maximum(np.minimum(D0, vt[0]), bgrid[0])
    if rest == "demag":     # AC-demagnetised about the first voltage (the PI's plays all at it: the engine's rest)
        D0 = np.where(alphas > vt[0], np.maximum(2 * vt[0] - alphas, bgrid[0]), alphas)
    u = p["s_lin"] * vt + _hyst(vt, alphas, bgrid, cum, D0)
    fmax = max(p["f_stack"], mode[0] if mode else 0.0)
    up = int(min(64, max(1, math.ceil(fmax * 8 * dt_s))))
    Ad1, Bd1 = mode_zoh(p["f_stack"], 0.02, dt_s / up)
    Ad2, Bd2 = mode_zoh(mode[0], mode[1], dt_s / up) if mode else (Ad1, Bd1)
    w = np.full(CREEP_TAUS.size, creep_gamma / CREEP_TAUS.size)
    ca = 1 - np.exp(-dt_s / CREEP_TAUS)
    x = p["d"] * _creep_modes(u, w, ca, Ad1, Bd1, Ad2, Bd2, bool(mode), up)
    return {"t": t, "v_mon": v, "i": i, "x": x, "cmd": drive(t)}


# ---------------------------------------------------------------------------------------------- drives
def drive_protocol(rate, vmax):
    from workbench.calibrate.protocol import calibration_protocol   # the drive only (allowed by the brief)
    t, v = calibration_protocol(dt_s=1 / rate, v_max=vmax, stairs_v=tuple(vmax * np.array([.25, .5, .75, 1, .6, .3, .1])))
    t = t - t[0]
    return t, (lambda tt: np.interp(tt, t, v))


def drive_triangle(f, vmax, rest=0.5):
    def fn(tt):
        ph = np.clip(tt - rest, 0, None) * f
        return vmax * 2 * np.abs(ph - np.floor(ph + 0.5))
    return fn


def drive_sine(f, vmax, rest=0.5):
    return lambda tt: vmax * 0.5 * (1 - np.cos(2 * np.pi * f * np.clip(tt - rest, 0, None)))


def drive_steps(levels, hold, vmax, rest=0.5, tau=2e-3):
    """Steps (smoothed by a 2 ms first-order edge, as a function generator's) through the levels (0..1)."""
    levels = np.asarray(levels, float) * vmax
    def fn(tt):
        out = np.zeros_like(tt)
        prev = 0.0
        for k, L in enumerate(levels):
            t0 = rest + k * hold
            on = tt >= t0
            out = np.where(on, L + (prev - L) * np.exp(-np.clip(tt - t0, 0, None) / tau), out)
            prev = L
        return out
    return fn


def drive_multisine(f0, f1, vmax, seed, n=10, rest=0.5, ramp=2.0):
    rng = np.random.default_rng(seed)
    fs = np.geomspace(f0, f1, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    amp = 1 / np.sqrt(np.arange(1, n + 1))
    tt0 = np.arange(0, 1 / f0, 1 / (50 * f1))
    raw = lambda tt: sum(a_ * np.sin(2 * np.pi * f_ * tt + p_) for a_, f_, p_ in zip(amp, fs, ph))
    span = raw(tt0)
    lo, hi = span.min() * 1.05, span.max() * 1.05
    def fn(tt):
        tr = np.clip(tt - rest, 0, None)
        env = np.clip(tr / ramp, 0, 1)
        return vmax * env * (raw(tr) - lo) / (hi - lo) + vmax * 0.5 * (1 - env) * 0 + 0 * tt
    return fn


# ---------------------------------------------------------------------------------------------- records
def add_noise(sim, rig, seed, gauge=True, gauge_gain=1.0, gauge_offset=0.05, x_offset=0.3e-6):
    p = RIGS[rig]
    rng = np.random.default_rng(seed + 7919)
    n = sim["t"].size
    rec = {"time[s]": sim["t"], "voltage[V]": sim["v_mon"] + p["noise_v"] * rng.standard_normal(n),
           "current[A]": sim["i"] + p["noise_i"] * rng.standard_normal(n),
           "displacement[m]": sim["x"] + x_offset + p["noise_x"] * rng.standard_normal(n)}
    if gauge:
        rec["gauge[V]"] = (gauge_gain * (sim["x"] - p["gauge_x0"]) / p["gauge_m_per_v"] + gauge_offset
                           + p["noise_g"] * rng.standard_normal(n))
    return rec


def write_csv(path, rec, meta):
    cols = list(rec)
    lines = [f"# {k}: {v}" for k, v in meta.items()]
    lines.append(",".join(cols))
    data = np.column_stack([rec[c] for c in cols])
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
        np.savetxt(fh, data, fmt="%.10g", delimiter=",")
