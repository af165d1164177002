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

    Firmware models the stack voltage as the RC response to its output at the largest
    terminal capacitance C (slowest, so never optimistic): v <- v + alpha (u - v),
    alpha = 1 - exp(-T / (R C)); it keeps u within [v - R I_sink, v + R I_source], so the
    current it asks for stays within the amplifier's limits (see
    :mod:`workbench.export.fixed_point`).

    Returns None when the series resistor is out (R = 0, seed 000's free-free configuration):
    the window [v - R I_sink, v + R I_source] would have zero width and pin the command to
    the modelled voltage, so the controller could never move the stack. There the current
    limit is the amplifier's own slew limit, which no resistor drop lets firmware anticipate:
    no window, and the run says "anti-windup off".
    """
    r = pzt.series_resistance_ohm
    if not r > 0:
        return None
    alpha = -np.expm1(-dt_s / (r * _largest_capacitance_f(pzt)))
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
