"""The free-free test of seed 000 section 3.3, simulated, and its estimators (eqs. 7-12).

The stack, shorted and drained (at rest), is driven by a slow 0-100 V sine with no
load (F_e = 0) and no series resistor; the current is integrated into the charge q
and the displacement is read through the strain-gauge chain and the serial's
calibration, as in the seed. From (q, x):

- eq. 11: k_q2x by least squares, x = k_q2x q;
- eq. 12: C_p = (T_em - T_em^2 k_q2x) / (k_p k_q2x);
- eqs. 7-8: V_h = V_pea - V_r - k_p x / T_em (V_r = 0 with R out), the input of C_h.

V_pea is what the rig's voltmeter reads at the amplifier's output, not the command: the
simulated terminal voltage V_t plus the resistor's drop R i (V_pea = V_t with R out).
Where the amplifier's current limit binds (a fast or large sine with R out: the terminal
slews at I / C) the two differ, and V_h read from the command would be wrong by the lag;
where it never binds (the default 100 V, 0.1 Hz sine draws 0.38 mA) they agree to
round-off (1.8e-15 V on SN637, 2.8e-14 V with creep).

The large-signal capacitance is read as the chord of Fig. 7 from rest to the 100 V
peak, q/V_h there (the seed quotes ~30.5 uF); the secant of the steady loop that
follows is smaller and is reported beside it.

The hysteresis figure is the seed's (Fig. 9): the largest vertical thickness of the
x-V loop relative to the peak displacement.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FlagRangeError
from ..plant.gauge import displacement_from_reading, gauge_run_equivalent
from ..plant.simulator import PZTSimulator

__all__ = ["check_v_peak", "v_peak_floor_v", "FreeFreeResult", "estimate_k_q2x", "estimate_cp", "hysteresis_fraction", "run_freefree",
           "v_h_from_measurements", "loop_secant"]


def estimate_k_q2x(q_c, x_m):
    """Eq. 11: k_q2x = (q^T q)^-1 q^T x, m/C."""
    q = np.asarray(q_c, float)
    x = np.asarray(x_m, float)
    return float(q @ x / (q @ q))


def estimate_cp(k_q2x, t_em_n_per_v, k_p_n_per_m):
    """Eq. 12: C_p = (T_em - T_em^2 k_q2x) / (k_p k_q2x), F."""
    return (t_em_n_per_v - t_em_n_per_v ** 2 * k_q2x) / (k_p_n_per_m * k_q2x)


def v_h_from_measurements(v_pea_v, x_m, t_em_n_per_v, k_p_n_per_m, v_r_v=0.0):
    """Eqs. 7-8: V_h = V_pea - V_r - k_p x / T_em, V."""
    return np.asarray(v_pea_v) - v_r_v - k_p_n_per_m * np.asarray(x_m) / t_em_n_per_v


def hysteresis_fraction(v, y, n_grid=200):
    """Largest vertical gap between the falling and rising branches, over the peak of |y|.

    Only the last complete loop matters: samples are split by the sign of dv, and
    the gap is taken on a voltage grid inside the range both branches cover.
    """
    v = np.asarray(v, float)
    y = np.asarray(y, float)
    dv = np.gradient(v)
    up, dn = dv > 0, dv < 0
    lo = max(v[up].min(), v[dn].min())
    hi = min(v[up].max(), v[dn].max())
    grid = np.linspace(lo, hi, n_grid)[1:-1]
    ia, idn = np.argsort(v[up]), np.argsort(v[dn])
    ya = np.interp(grid, v[up][ia], y[up][ia])
    yd = np.interp(grid, v[dn][idn], y[dn][idn])
    return float(np.max(np.abs(yd - ya)) / np.max(np.abs(y)))


def loop_secant(x_in, y_out):
    """Large-signal secant of a loop: (max y - min y) / (max x - min x)."""
    return float((np.max(y_out) - np.min(y_out)) / (np.max(x_in) - np.min(x_in)))


@dataclass(frozen=True)
class FreeFreeResult:
    """Outputs of :func:`run_freefree` (SI).

    ``v_cmd_v`` is the commanded sine, ``v_pea_v`` the amplifier's output as a voltmeter reads it
    (the simulated V_t + R i, the command's lag where the current limit binds), the input of
    eqs. 7-8 and of the x-V_pea loop.
    """

    t_s: np.ndarray
    v_cmd_v: np.ndarray
    v_pea_v: np.ndarray
    x_true_m: np.ndarray
    x_meas_m: np.ndarray
    q_c: np.ndarray
    v_h_true_v: np.ndarray
    v_h_est_v: np.ndarray
    stroke_m: float
    v_h_over_v_pea: float
    hysteresis_x_fraction: float
    hysteresis_q_fraction: float
    k_q2x_m_per_c: float
    cp_recovered_f: float
    cp_true_f: float
    ch_secant_f: float
    ch_loop_secant_f: float
    peak_index: int
    peak_current_a: tuple

    def summary(self):
        return {
            "stroke_m": self.stroke_m,
            "v_h_over_v_pea_at_peak": self.v_h_over_v_pea,
            "hysteresis_x_percent_of_stroke": 100 * self.hysteresis_x_fraction,
            "hysteresis_q_vs_v_h_percent": 100 * self.hysteresis_q_fraction,
            "k_q2x_m_per_c": self.k_q2x_m_per_c,
            "cp_recovered_f": self.cp_recovered_f,
            "cp_true_f": self.cp_true_f,
            "cp_error_percent": 100 * (self.cp_recovered_f / self.cp_true_f - 1),
            "ch_large_signal_secant_f": self.ch_secant_f,
            "ch_steady_loop_secant_f": self.ch_loop_secant_f,
            "peak_current_a": list(self.peak_current_a),
        }


def v_peak_floor_v(pzt, stroke_m):
    """The lowest positive voltage whose quasi-static stroke from rest reaches ``stroke_m`` (bisection), V.

    Parameters
    ----------
    pzt : PZTParams
    stroke_m : float
        Displacement from rest, m.

    Returns
    -------
    float
        Voltage, V; the amplifier's highest when even it does not reach ``stroke_m``.
    """
    def x(v):
        return float(pzt.quasi_static_x_m([0.0, v])[-1])
    lo, hi = 0.0, pzt.voltage_max_v
    if x(hi) <= stroke_m:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if x(mid) < stroke_m else (lo, mid)
    return hi


def check_v_peak(plant, v_peak_v, *, name="v_peak_v", where="the plant"):
    """Refuse a free-free peak voltage outside ``(0, Vmax]`` or whose stroke is under the gauge noise.

    A sine whose stroke from rest is under the gauge's noise RMS cannot be read: eqs. 10-12 then
    return noise (1e-9 V gave C_p = -10.9 uF). The floor does not fall with more cycles: the C_p
    error at a small peak is a bias, not noise (SN637, seeds 0-3: +22 to +25 % at 0.3 V and +78 to
    +90 % at 0.1 V for 1, 2 and 8 cycles alike), so averaging does not lower it.

    Parameters
    ----------
    plant : Plant
    v_peak_v : float
        Peak of the 0..v_peak sine, V.
    name, where : str
        The parameter's and the plant's names in the message (the CLI passes ``--v-peak`` and the file).

    Raises
    ------
    FlagRangeError
        Naming the parameter, the range and why.
    """
    vmax = plant.pzt.voltage_max_v
    v = float(v_peak_v)
    if not (0.0 < v <= vmax):
        raise FlagRangeError(f"{name} {v:g} V: out of range (0, {vmax:g}] V: the amplifier's highest output in {where}")
    noise_m = plant.gauge.noise_rms_m
    stroke = float(plant.pzt.quasi_static_x_m([0.0, v])[-1])
    if stroke < noise_m:
        raise FlagRangeError(f"{name} {v:g} V: out of range [{v_peak_floor_v(plant.pzt, noise_m):.3g}, {vmax:g}] V: its "
                             f"stroke from rest, {stroke * 1e9:.3g} nm, is under the gauge noise {noise_m * 1e9:.3g} nm "
                             f"RMS of {where}, so the test cannot read the stack's motion; e.g. 100V")


def run_freefree(plant, *, v_peak_v=100.0, freq_hz=0.1, cycles=2, sample_hz=None, resistor_in=False,
                 seed=0):
    """Simulate the free-free test on ``plant`` and apply eqs. 7-12 to the result.

    Parameters
    ----------
    plant : Plant
    v_peak_v : float
        Peak of the 0..v_peak sine, V.
    freq_hz : float
        Sine frequency, Hz (the seed applies it "slowly").
    cycles : int
        Number of sine periods from rest.
    sample_hz : float, optional
        Sample rate; default the gauge modulation rate (the gauge is read every period).
    resistor_in : bool
        Keep the series resistor (the seed ran this test without it).
    seed : int
        Gauge noise seed.
    """
    check_v_peak(plant, v_peak_v)
    if not freq_hz > 0 or int(cycles) < 1:
        raise ValueError("freq_hz must be positive and cycles >= 1")
    fs = plant.gauge.modulation_hz if sample_hz is None else float(sample_hz)
    n = int(round(cycles * fs / freq_hz))
    t = np.arange(1, n + 1) / fs
    v = 0.5 * v_peak_v * (1 - np.cos(2 * np.pi * freq_hz * t))
    params = plant.pzt if resistor_in else plant.pzt.with_resistance(0.0)
    sim = PZTSimulator(params, 1.0 / fs)
    tr = sim.run(v)
    # read the displacement through the gauge chain and the serial's calibration
    g = plant.gauge
    reading = gauge_run_equivalent(tr.x_m, g, seed=seed)
    x_meas = displacement_from_reading(reading.demod_v, g)
    t_em, k_p = params.transducer_constant_n_per_v, params.stiffness_n_per_m
    kq = estimate_k_q2x(tr.q_c, x_meas)
    cp = estimate_cp(kq, t_em, k_p)
    # eqs. 7-8 on what the rig measures: the amplifier's output voltage (the stack's terminal voltage
    # plus the resistor's drop) and the current, not the command, which it does not follow where the
    # current limit binds
    v_r = params.series_resistance_ohm * tr.i_a
    v_pea = tr.v_t_v + v_r
    v_h_est = v_h_from_measurements(v_pea, x_meas, t_em, k_p, v_r_v=v_r)
    ipk = int(np.argmax(v_pea[: int(round(fs / freq_hz))]))
    last = t > (cycles - 1) / freq_hz
    return FreeFreeResult(
        t_s=t, v_cmd_v=v, v_pea_v=v_pea, x_true_m=tr.x_m, x_meas_m=x_meas, q_c=tr.q_c, v_h_true_v=tr.v_h_v,
        v_h_est_v=v_h_est, stroke_m=float(tr.x_m[ipk]), v_h_over_v_pea=float(tr.v_h_v[ipk] / v_pea[ipk]),
        hysteresis_x_fraction=hysteresis_fraction(v_pea[last], x_meas[last]),
        hysteresis_q_fraction=hysteresis_fraction(v_h_est[last], tr.q_c[last]),
        k_q2x_m_per_c=kq, cp_recovered_f=float(cp), cp_true_f=params.working_capacitance_f,
        ch_secant_f=float(tr.q_c[ipk] / v_h_est[ipk]), ch_loop_secant_f=loop_secant(v_h_est[last], tr.q_c[last]),
        peak_index=ipk, peak_current_a=tr.peak_current_a)


def plot_freefree(res, title=""):
    """Four panels: time traces, q-V_h (C_h), x-V_pea (hysteresis), x-q (eq. 10)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    a = ax[0, 0]
    a.plot(res.t_s, res.v_pea_v, label="V_pea [V]")
    if not np.allclose(res.v_pea_v, res.v_cmd_v, rtol=0, atol=1e-9):
        a.plot(res.t_s, res.v_cmd_v, ":", label="command [V] (current limit binds)")
    a.plot(res.t_s, res.v_h_est_v, label="V_h (eqs. 7-8) [V]")
    a.plot(res.t_s, res.x_meas_m * 1e6 * 5, label="x [um] x5")
    a.set_xlabel("time [s]")
    a.legend(loc="upper right", fontsize=8)
    a.set_title("Free-free test, simulated")
    a = ax[0, 1]
    a.plot(res.v_h_est_v, res.q_c * 1e3, lw=1)
    vh = np.array([0.0, res.v_h_est_v[res.peak_index]])
    a.plot(vh, vh * res.ch_secant_f * 1e3, "--",
           label=f"large-signal secant, rest to peak: {res.ch_secant_f * 1e6:.1f} uF (seed ~30.5 uF)")
    a.set_xlabel("V_h [V]")
    a.set_ylabel("q [mC]")
    a.set_title("Hysteretic capacitance C_h")
    a.legend(fontsize=8)
    a = ax[1, 0]
    a.plot(res.v_pea_v, res.x_meas_m * 1e6, lw=1)
    a.set_xlabel("V_pea [V]")
    a.set_ylabel("x [um]")
    a.set_title(f"Displacement: hysteresis {100 * res.hysteresis_x_fraction:.1f} % of stroke, "
                f"stroke {res.stroke_m * 1e6:.2f} um")
    a = ax[1, 1]
    a.plot(res.q_c * 1e3, res.x_meas_m * 1e6, lw=1, label="simulated, gauge-read")
    qq = np.linspace(0, res.q_c.max(), 2)
    a.plot(qq * 1e3, res.k_q2x_m_per_c * qq * 1e6, "--",
           label=f"eq. 11 fit: C_p = {res.cp_recovered_f * 1e6:.3f} uF (true {res.cp_true_f * 1e6:.3f})")
    a.set_xlabel("q [mC]")
    a.set_ylabel("x [um]")
    a.set_title("Charge to displacement (eqs. 10-12)")
    a.legend(fontsize=8)
    for a in ax.flat:
        a.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
