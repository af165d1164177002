"""Sinusoidal-input describing function of the full PZT, by simulation to periodic steady state.

For V_pea = b + A sin(wt) the compiled plant (R and the current limit, C_h, C_p,
T_em, creep, modes) runs period after period until the first harmonic of x stops
changing; P(jw; A, b) = X_1 / V_1 and the current's first harmonic likewise. The
input is held over each of the N samples per period (the kernel's zero-order hold),
so V_1 is the held staircase's fundamental, A sinc(pi/N) e^{-j pi/N}, not A: the
ratio is then the describing function of the continuous plant to within the
staircase's harmonics near N.

Creep branches reach their periodic state only after several of their time
constants (up to 1000 s), far longer than a period at 1 kHz. They are linear given
V_h, so after each period the solver sets each branch to the periodic solution of
its own recursion for the V_h it just saw (a shooting step on the linear part);
with V_h converged this is exact. The bias is reached first by a slow hold, with
the creep branches set to equilibrium.

Each point reports the harmonic distortion of x, whether the current hit a limit
(the amplifier slews: the response is periodic but no longer close to a sine, and
the member is not a linear behaviour), whether the command was clipped by the
voltage range, and whether the response became periodic at all (if it repeats only
every two periods: a subharmonic).
"""

from dataclasses import dataclass, replace

import control
import numpy as np
from scipy.signal import lfilter

from ..plant.simulator import PZTSimulator

__all__ = ["DFFamily", "pzt_describing_function", "quasi_static_below_hz"]


@dataclass(frozen=True)
class DFFamily:
    """P(jw; A, b) on a grid. Arrays are indexed [bias, amplitude, frequency].

    ``x_m_per_v`` and ``i_a_per_v`` are complex first-harmonic ratios; ``thd_x`` is
    sqrt(sum_{h>=2} |X_h|^2) / |X_1|; ``x_mean_shift_m`` the mean of x over the period
    minus x at rest at the bias reached from below: hysteresis centres the loop between
    its branches (positive), the asymmetric current limits rectify while slewing (rising
    is slower: negative). With integral action the loop's bias moves to cancel it,
    which a single-input describing function does not follow; ``saturated``: the current limit was reached in
    the final period; ``clipped``: b +/- A leaves the amplifier range; ``periodic``:
    the harmonic converged; ``subharmonic``: it did not, but the response repeats
    every second period.
    """

    amplitudes_v: np.ndarray
    biases_v: np.ndarray
    freq_hz: np.ndarray
    x_m_per_v: np.ndarray
    i_a_per_v: np.ndarray
    thd_x: np.ndarray
    x_mean_shift_m: np.ndarray
    saturated: np.ndarray
    clipped: np.ndarray
    periodic: np.ndarray
    subharmonic: np.ndarray
    cycles: np.ndarray

    @property
    def linear_ok(self):
        """Points that describe linear-like behaviour: periodic, not slewing, not clipped."""
        return self.periodic & ~self.saturated & ~self.clipped

    def frd(self, bias_index, amp_index, only_linear=True):
        """The member at (bias, amplitude) as a python-control FRD (V_pea -> x, m/V).

        With ``only_linear`` the frequencies where the point is saturated, clipped or
        not periodic are dropped (an FRD cannot carry gaps).
        """
        keep = self.linear_ok[bias_index, amp_index] if only_linear else np.ones(self.freq_hz.size, bool)
        return control.FRD(self.x_m_per_v[bias_index, amp_index, keep], 2 * np.pi * self.freq_hz[keep],
                           name=f"df_A{self.amplitudes_v[amp_index]:g}V_b{self.biases_v[bias_index]:g}V"
                           .replace(".", "p"))

    def records(self):
        """One JSON-ready row per point (SI; phase in degrees)."""
        rows = []
        for b, bias in enumerate(self.biases_v):
            for a, amp in enumerate(self.amplitudes_v):
                for k, f in enumerate(self.freq_hz):
                    h = self.x_m_per_v[b, a, k]
                    rows.append({"amplitude_v": float(amp), "bias_v": float(bias), "freq_hz": float(f),
                                 "mag_m_per_v": float(abs(h)), "phase_deg": float(np.degrees(np.angle(h))),
                                 "current_mag_a_per_v": float(abs(self.i_a_per_v[b, a, k])),
                                 "thd_x": float(self.thd_x[b, a, k]),
                                 "x_mean_shift_m": float(self.x_mean_shift_m[b, a, k]),
                                 "current_saturated": bool(self.saturated[b, a, k]),
                                 "voltage_clipped": bool(self.clipped[b, a, k]),
                                 "periodic": bool(self.periodic[b, a, k]),
                                 "subharmonic": bool(self.subharmonic[b, a, k])})
        return rows


def _settle_at_bias(pzt, bias_v):
    """Plant state (and x) after a slow approach to ``bias_v``, creep branches in equilibrium."""
    sim = PZTSimulator(pzt, 1e-4)
    # the current limit slews at >= ~50 V/s into <= ~40 uF; hold long enough for that and RC
    n_hold = int(np.ceil((abs(bias_v) / 40.0 + 0.05) / sim.dt_s))
    hold = np.full(n_hold, float(bias_v))
    tr = sim.run(hold)
    if pzt.creep is not None:
        for _ in range(50):
            v_h = tr.v_h_v[-1]
            sim.set_creep_charges(pzt.creep.capacitances_f * v_h)
            tr = sim.run(hold[: int(0.05 / sim.dt_s)])
            if abs(tr.v_h_v[-1] - v_h) < 1e-9 * (1 + abs(v_h)):
                break
    return sim.st.copy(), float(tr.x_m[-1])


def _periodic_creep(pzt, v_h, dt_s):
    """Per branch, the charge at the period boundary of the periodic solution driven by ``v_h``.

    The kernel's recursion Q_k = a Q_{k-1} + (1 - a) C V_h[k], a = exp(-dt/tau), is
    periodic when Q_N = Q_0, i.e. Q_0 = (1 - a) C sum_k a^(N-1-k) V_h[k] / (1 - a^N).
    """
    n = v_h.size
    a = np.exp(-dt_s / pzt.creep.time_constants_s)
    # sum_k a^(N-1-k) V_h[k] is the last output of the recursion y_k = a y_{k-1} + V_h[k]
    s = np.array([lfilter([1.0], [1.0, -aj], v_h)[-1] for aj in a])
    return (1 - a) * pzt.creep.capacitances_f * s / (1 - a ** n)


def _harmonics(y, n):
    """Complex Fourier coefficients Y_h of one period sampled at the end of each step (y = Re sum Y_h e^{jh wt})."""
    c = np.fft.rfft(y) * 2.0 / n
    c[0] /= 2.0
    # samples sit at t = (k + 1) dt: undo the one-step shift of the time origin
    return c * np.exp(-2j * np.pi * np.arange(c.size) / n)


def _samples_per_period(pzt, freq_hz, n_min):
    """Steps per period: at least ``n_min``, and short against the fastest RC time constant.

    Samples taken at the end of each step give the continuous x's harmonic only when x
    is smooth on the step; when RC is much shorter than the step, x jumps at every
    step like the input staircase and the estimate lags by half a step.
    """
    r = pzt.series_resistance_ohm
    if r == 0.0:
        return n_min       # quasi-static: x is a staircase on the input's steps, handled exactly
    c_min = 1.0 / (1.0 / pzt.hysteresis.weights[0] + 1.0 / pzt.c_pp_f)
    dt_max = r * c_min / 2.0
    # a power of two keeps the final FFT fast
    return max(n_min, 1 << int(np.ceil(np.log2(1.0 / (freq_hz * dt_max)))))


def quasi_static_below_hz(pzt, phase_rad=1e-3):
    """Frequency below which a period is long against every time constant but creep's, Hz.

    The electrical one R C (C the largest terminal capacitance: all plays engaged, creep
    settled, in series with C_pp) and the modes' 1 / (2 pi f_mode): below the returned
    frequency each lags by at most ``phase_rad``, so the describing function is its
    quasi-static limit (R = 0, modes static) to that accuracy. Creep is kept: its
    branches (0.1-1000 s) are not fast against any period.
    """
    c_h = float(np.sum(pzt.hysteresis.weights))
    if pzt.creep is not None:
        c_h += float(np.sum(pzt.creep.capacitances_f))
    taus = [pzt.series_resistance_ohm / (1.0 / c_h + 1.0 / pzt.c_pp_f)]
    taus += [1.0 / (2 * np.pi * m.freq_hz) for m in pzt.modes]
    tau = max(taus)
    return np.inf if tau == 0 else phase_rad / (2 * np.pi * tau)


def pzt_describing_function(pzt, amplitudes_v, freq_hz, biases_v=(50.0,), samples_per_period=1024,
                            tol=1e-7, max_cycles=400, skip_above_saturation=False, progress=None,
                            quasi_static_phase_rad=None):
    """Describing-function family of the PZT ``pzt`` (a PZTParams), V_pea -> x and V_pea -> i.

    Parameters
    ----------
    amplitudes_v, freq_hz, biases_v : array_like
        The grid, V, Hz, V.
    samples_per_period : int
        Steps per period at least (a multiple of 4, so the peaks are sampled); more at
        low frequencies so each step stays half the fastest RC time constant.
    tol : float
        Relative change of the first harmonic between periods that counts as periodic.
    max_cycles : int
        Periods simulated at most per point.
    quasi_static_phase_rad : float, optional
        Below :func:`quasi_static_below_hz` of this phase, compute the point as its
        quasi-static limit (series R and modes left out, creep kept; ``samples_per_period``
        steps): the full computation there needs ~1/(f R C) steps per period for the same
        answer. Current saturation is judged from the charge's rate of change. None: never.
    skip_above_saturation : bool
        Once an amplitude saturates the current at a frequency, mark the larger ones
        saturated without simulating them (their response is NaN): the slew limit
        only tightens with amplitude. For families that keep only linear members.
    progress : callable(done, total) or None
    """
    amps = np.atleast_1d(np.asarray(amplitudes_v, dtype=float))
    freqs = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    biases = np.atleast_1d(np.asarray(biases_v, dtype=float))
    n = int(samples_per_period)
    if n < 16 or n % 4:
        raise ValueError(f"samples_per_period must be a multiple of 4, at least 16; got {samples_per_period}")
    if np.any(amps <= 0) or np.any(freqs <= 0) or not np.all(np.isfinite(np.concatenate([amps, freqs, biases]))):
        raise ValueError("amplitudes and frequencies must be positive and finite, biases finite")
    shape = (biases.size, amps.size, freqs.size)
    x1, i1 = np.zeros(shape, complex), np.zeros(shape, complex)
    thd, shift = np.zeros(shape), np.zeros(shape)
    sat, clip, per, sub = (np.zeros(shape, bool) for _ in range(4))
    cycles = np.zeros(shape, int)
    i_limits = (pzt.current_limit_source_a, pzt.current_limit_sink_a)
    quasi_static = pzt.series_resistance_ohm == 0.0
    total, done = int(np.prod(shape)), 0
    f_qs = -np.inf if quasi_static_phase_rad is None else quasi_static_below_hz(pzt, quasi_static_phase_rad)
    pzt_qs = replace(pzt, series_resistance_ohm=0.0, modes=())
    st0_qs = {}
    for b, bias in enumerate(biases):
        st0_full, x_static = _settle_at_bias(pzt, bias)
        for k, f in enumerate(freqs):
            qs_point = f <= f_qs and not quasi_static
            if qs_point and bias not in st0_qs:
                st0_qs[bias] = _settle_at_bias(pzt_qs, bias)[0]
            st0 = st0_qs[bias] if qs_point else st0_full
            n_f = n if qs_point else _samples_per_period(pzt, f, n)
            sim = PZTSimulator(pzt_qs if qs_point else pzt, 1.0 / (f * n_f))
            theta = 2 * np.pi * np.arange(n_f) / n_f
            v1_unit = -1j * np.sinc(1.0 / n_f) * np.exp(-1j * np.pi / n_f)
            fundamental = np.exp(-1j * theta)
            for a, amp in enumerate(amps):
                if skip_above_saturation and a > 0 and sat[b, a - 1, k] and amp > amps[a - 1]:
                    sat[b, a, k] = True
                    x1[b, a, k] = i1[b, a, k] = np.nan
                    thd[b, a, k] = shift[b, a, k] = np.nan
                    clip[b, a, k] = bias - amp < pzt.voltage_min_v or bias + amp > pzt.voltage_max_v
                    done += 1
                    if progress is not None:
                        progress(done, total)
                    continue
                sim.st[:] = st0
                v = bias + amp * np.sin(theta)
                prev = None
                history = []
                for c in range(1, max_cycles + 1):
                    tr = sim.run(v)
                    if pzt.creep is not None:
                        sim.set_creep_charges(_periodic_creep(pzt, tr.v_h_v, sim.dt_s))
                    h1 = 2.0 / n_f * (tr.x_m @ fundamental)    # convergence needs the fundamental only
                    history = (history + [tr.x_m])[-3:]        # enough to tell a period-2 response
                    # a slewing response is excluded from the linear family anyway: its
                    # mean level settles slowly (asymmetric limits), 1e-4 is plenty for it
                    slewing = max(tr.peak_current_a[0] / i_limits[0], -tr.peak_current_a[1] / i_limits[1]) >= 1 - 1e-9
                    tol_c = max(tol, 1e-4) if slewing else tol
                    if prev is not None and abs(h1 - prev) <= tol_c * abs(h1) and c >= 3:
                        per[b, a, k] = True
                        break
                    prev = h1
                if not per[b, a, k] and len(history) >= 3:
                    scale = np.ptp(history[-1]) + 1e-30
                    sub[b, a, k] = (np.max(np.abs(history[-1] - history[-3])) < 1e-6 * scale
                                    < np.max(np.abs(history[-1] - history[-2])))
                hx = _harmonics(tr.x_m, n_f)
                hq = _harmonics(tr.q_c, n_f)
                if quasi_static or qs_point:
                    # output and input are staircases on the same steps: no hold correction
                    vx = _harmonics(v, n_f)[1]
                else:
                    vx = amp * v1_unit
                x1[b, a, k] = hx[1] / vx
                i1[b, a, k] = 1j * 2 * np.pi * f * hq[1] / vx
                shift[b, a, k] = hx[0].real - x_static
                thd[b, a, k] = np.sqrt(np.sum(np.abs(hx[2:n_f // 2]) ** 2)) / abs(hx[1])
                i_max, i_min = tr.peak_current_a
                if qs_point:           # no series R in the run: the current is the charge's rate
                    dq = np.diff(np.concatenate([tr.q_c[-1:], tr.q_c])) / sim.dt_s
                    i_max, i_min = float(dq.max()), float(dq.min())
                # (R out too: the amplifier's limit bounds the charge each step moves, kernels' quasi-static step)
                sat[b, a, k] = i_max >= i_limits[0] * (1 - 1e-9) or -i_min >= i_limits[1] * (1 - 1e-9)
                clip[b, a, k] = bias - amp < pzt.voltage_min_v or bias + amp > pzt.voltage_max_v
                cycles[b, a, k] = c
                done += 1
                if progress is not None:
                    progress(done, total)
    return DFFamily(amps, biases, freqs, x1, i1, thd, shift, sat, clip, per, sub, cycles)
