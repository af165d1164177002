"""Discretization at the servo rate and the anti-windup form firmware runs.

The amplifier's current limit bounds how fast the PZT voltage can move (about
I_max / C with C the stack's largest terminal capacitance), so a large reference
step winds up an integrating controller even while the command stays inside its
range. The exported controller therefore carries a rate limit on its output and is
conditioned on the limited output (Hanus): with a discrete realization (a, b, c, d),
d != 0, each sample

    u_raw = c x + d e
    u     = clip(u_raw rate-limited from the last u, output limits)
    x    <- (a - b c / d) x + (b / d) u

which is the linear controller exactly whenever nothing limits (u = u_raw gives
x <- a x + b e).

The exported fixed-point cascade carries the limit as a current-limit window instead
(:func:`current_limit_model`): with the series resistor in, a window of R I around an RC
model of the stack voltage; with it out (R = 0), a slew window of I T / C around the
last command (alpha = 1).
"""

from dataclasses import dataclass

import control
import numpy as np

from ..errors import DesignError

__all__ = ["discretize", "rate_limits_v_per_s", "current_limit_model", "HanusController", "hanus", "run_hanus", "hanus_initial_state"]


def discretize(ctrl, dt_s, prewarp_hz):
    """Tustin at the servo rate, prewarped at ``prewarp_hz`` (the crossover) so the response matches there."""
    if not 0 < prewarp_hz < 0.5 / dt_s:
        raise DesignError(f"prewarp frequency {prewarp_hz:g} Hz must lie in (0, Nyquist = {0.5 / dt_s:g} Hz)")
    return control.sample_system(control.ss(ctrl), dt_s, method="tustin", prewarp_frequency=2 * np.pi * prewarp_hz)


def _largest_capacitance_f(pzt):
    c_h = float(np.sum(pzt.hysteresis.weights))
    if pzt.creep is not None:
        c_h += float(np.sum(pzt.creep.capacitances_f))
    return 1.0 / (1.0 / c_h + 1.0 / pzt.c_pp_f)


def current_limit_model(pzt, dt_s):
    """(alpha, h_up, h_down) of the current-limit window the exported controller runs.

    Firmware keeps a model v of the stack voltage, v <- v + alpha (u - v), and keeps its
    output u within [v - h_down, v + h_up], so the current it asks for stays within the
    amplifier's limits (see :mod:`workbench.export.fixed_point`).

    - Series resistor in (R > 0): v is the RC response to the output at the largest terminal
      capacitance C (slowest, so never optimistic), alpha = 1 - exp(-T / (R C)), and
      h = R I_source up, R I_sink down: the current (u - v) / R is within the limits.
    - Series resistor out (R = 0, seed 000's free-free configuration): the current is
      C dV_t/dt, so what the amplifier can follow in one sample T is a slew of I T / C. The
      model follows the (clamped) command, alpha = 1 (exact in the fixed-point step's Q1.30:
      v += ((u - v) 2^30 + 2^29) >> 30 is v = u), and h = I_source T / C up, I_sink T / C down:
      the charge a sample asks for, C |u - v|, is at most I T. C is again the largest terminal
      capacitance (every play engaged and the settled creep branches, in series with C_pp):
      at any smaller capacitance the stack slews faster than the window, so the command never
      runs ahead of the stack and the integrator never winds up. Measured
      (``benchmarks/logs/s38_phys/rout_window.log``, the five stack files R out, session 37's
      loop-shaped controller, +/-0.5 and +/-5 um steps, no noise): with C_max the stack reaches
      the command within each sample (the amplifier slews at its limit inside the sample; with
      the plant stepped once a sample no sample ends short of its command, and with ten steps a
      sample ~1600 of the +5 um step's sub-steps are at the limit: review of s38_phys) and the
      overshoot is the unlimited amplifier's (0.01 %, 0.04-0.08 % with creep),
      settling 175 ms for +5 um against 209 ms without a window and 38 ms against 118-123 ms for
      -5 um; with the smallest capacitance (only the first play engaged, 6.0 uF) the window lets
      the command run ahead where all plays are engaged and the loop winds up (11 % overshoot at
      +5 um, 15-20 % at +0.5 um, 24-25 % at -5 um, against 12.5 %, 76 % and 24 % without a
      window). Between the two (``rout_c_sweep.log``: the R-out loop-shaped design on SN637 with
      creep, C = 0.6-0.9 C_max) the +5 um overshoot grows with the window's speed, 1.6 % at
      0.9 C_max to 5.9 % at 0.6 C_max, samples ending short of their command for 180 ms: only
      C_max keeps the integrator from winding up. The cost of C_max: the stack away from the largest capacitance
      could slew up to 1.9x faster, so a down step rises slower (-5 um: 27 ms against 20 ms), and a
      ramp faster than I / C_max is held back: `verify`'s 1 Hz triangle (0.8 stroke, ~220 V/s on
      average) tracks to 592 nm RMS against 1.6 nm without a window, as the R-in window (the same
      I / C_max bound) holds the committed R-in controller to 846 nm there.

    Returns None for an amplifier without a current limit (R = 0 and infinite limits,
    :meth:`~workbench.plant.pzt.PZTParams.terminal_driven`): no window.
    """
    r = pzt.series_resistance_ohm
    c = _largest_capacitance_f(pzt)
    if not r > 0:
        if not (np.isfinite(pzt.current_limit_source_a) and np.isfinite(pzt.current_limit_sink_a)):
            return None               # no current limit (PZTParams.terminal_driven): nothing to keep within
        return 1.0, pzt.current_limit_source_a * dt_s / c, pzt.current_limit_sink_a * dt_s / c
    alpha = -np.expm1(-dt_s / (r * c))
    return float(alpha), r * pzt.current_limit_source_a, r * pzt.current_limit_sink_a


def rate_limits_v_per_s(pzt):
    """(up, down) slew of the PZT voltage the current limits allow, V/s, at the largest capacitance.

    The largest terminal capacitance is every play engaged plus the settled creep
    branches, in series with C_pp: the slowest slew, so a safe output rate limit.
    """
    c = _largest_capacitance_f(pzt)
    return pzt.current_limit_source_a / c, pzt.current_limit_sink_a / c


@dataclass(frozen=True)
class HanusController:
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: float
    dt_s: float
    output_limits_v: tuple
    rate_limits_v_per_s: tuple

    def as_dict(self, voltage_model=None):
        """The ``anti_windup`` block of a controller JSON that ``workbench verify --form hanus`` runs;
        ``voltage_model`` (alpha, h_up, h_down): the current-limit window to run it with."""
        block = {"method": "hanus", "output_limits_v": list(self.output_limits_v),
                 "a": self.a.tolist(), "b": self.b.ravel().tolist(), "c": self.c.ravel().tolist(), "d": self.d}
        if voltage_model is not None:
            block["voltage_model"] = {"alpha": voltage_model[0], "headroom_v": list(voltage_model[1:])}
        return block


def hanus(ctrl_d, output_limits_v, rate_limits):
    """The Hanus form of the discrete controller ``ctrl_d`` (needs a direct feedthrough d != 0)."""
    s = control.ss(ctrl_d)
    d = float(np.squeeze(s.D))
    if abs(d) < 1e-12 * max(1.0, float(np.abs(s.C).max())):
        raise DesignError("the Hanus anti-windup form needs a controller with direct feedthrough (d != 0); "
                          "a strictly proper controller cannot be conditioned on its output this way")
    return HanusController(np.asarray(s.A, float), np.asarray(s.B, float), np.asarray(s.C, float), d,
                           float(s.dt), tuple(map(float, output_limits_v)), tuple(map(float, rate_limits)))


def hanus_initial_state(h, u0):
    """Controller state at rest with zero error and output ``u0`` (bumpless start at the bias)."""
    a_aw = h.a - h.b @ h.c / h.d
    return np.linalg.solve(np.eye(h.a.shape[0]) - a_aw, h.b[:, 0] / h.d * u0)


def run_hanus(h, e, u0, x0=None):
    """Run the anti-windup controller over the error samples ``e`` from output ``u0``; returns u."""
    x = np.zeros(h.a.shape[0]) if x0 is None else np.array(x0, dtype=float)
    a_aw = h.a - h.b @ h.c / h.d
    b_aw = h.b[:, 0] / h.d
    c = h.c[0]
    lo, hi = h.output_limits_v
    up, down = h.rate_limits_v_per_s[0] * h.dt_s, h.rate_limits_v_per_s[1] * h.dt_s
    u_last = float(u0)
    out = np.empty(len(e))
    for k, ek in enumerate(e):
        u_raw = c @ x + h.d * ek
        u = min(max(u_raw, u_last - down), u_last + up)
        u = min(max(u, lo), hi)
        x = a_aw @ x + b_aw * u
        out[k] = u_last = u
    return out
