"""The electromechanical PZT of seed 000 Fig. 3 (eqs. 1-5, 9).

Circuit: V_pea drives the series resistor R (with the amplifier's current limit),
then the hysteretic capacitance C_h (q = C_h(V_h), a PI operator), then the working
capacitance C_p, whose voltage V_p makes the piezo force F_p = T_em V_p. The
environmental force F_e and F_p act on the mechanical impedance M, here the stack
spring 1/k_p with optional modes.

Elimination used by the simulator (quasi-static spring, M = 1/k_p):
x = (F_e + T_em V_p)/k_p and V_p = (q - T_em x)/C_p (eq. 9) give
V_p = (q - T_em F_e/k_p) / C_pp with C_pp = C_p + T_em^2/k_p, so the charge sees
C_h in series with C_pp. The terminal voltage V_t = V_h + V_p is then a PI operator
of the hysteretic charge q_h:

    V_t = G[q_h] + (Q_c - T_em F_e/k_p)/C_pp,   G = C_h^{-1} + (1/C_pp) I,

with Q_c the charge in the creep branches. G is a PI operator too (the exact
inverse of C_h plus a linear term), so the dynamic form integrates
R dq_h/dt = V_pea - V_t exactly over each step on the local slope of G, and the
quasi-static form (R = 0) applies G^{-1} to V_pea directly where the charge that
takes is within the amplifier's current limit over the step (else the limit's
charge moves: V_t slews at I / C).

Modes filter the quasi-static displacement (unit DC gain); the charge the modal
motion would induce through T_em is not fed back. At the 70 kHz stack mode and any
servo rate below it that is far below the resolution that matters; a structural
mode near the loop's crossover should be modelled with care (see README).
"""

from dataclasses import dataclass, field

import numpy as np

from .creep import CreepParams
from .hysteresis import PrandtlIshlinskii

__all__ = ["Mode", "PZTParams"]


@dataclass(frozen=True)
class Mode:
    """A mechanical mode of M(s): a unit-DC-gain second-order section."""

    freq_hz: float
    damping_ratio: float

    def __post_init__(self):
        if not (self.freq_hz > 0 and 0 < self.damping_ratio <= 1):
            raise ValueError(f"mode needs freq_hz > 0 and 0 < damping_ratio <= 1; got {self}")


@dataclass(frozen=True)
class PZTParams:
    """Parameters of the Fig. 3 model, all SI.

    Parameters
    ----------
    series_resistance_ohm : float
        R; 0 selects the quasi-static form: no RC dynamics, the amplifier drives the terminal directly, its
        current limit still bounds the charge a step moves (V_t slews at I / C toward the command).
    current_limit_source_a, current_limit_sink_a : float
        Amplifier current limits, A, both given as positive magnitudes.
    voltage_min_v, voltage_max_v : float
        Amplifier output range, V; commands outside are clipped.
    working_capacitance_f : float
        C_p, F.
    transducer_constant_n_per_v : float
        T_em, N/V (= C/m).
    stiffness_n_per_m : float
        k_p, N/m.
    hysteresis : PrandtlIshlinskii
        C_h: charge (C) as a PI operator of V_h (V).
    modes : tuple of Mode
        Optional mechanical modes.
    creep : CreepParams or None
        Optional creep branches across C_h.
    """

    series_resistance_ohm: float
    current_limit_source_a: float
    current_limit_sink_a: float
    voltage_min_v: float
    voltage_max_v: float
    working_capacitance_f: float
    transducer_constant_n_per_v: float
    stiffness_n_per_m: float
    hysteresis: PrandtlIshlinskii
    modes: tuple = field(default=())
    creep: CreepParams | None = None

    def __post_init__(self):
        if self.series_resistance_ohm < 0:
            raise ValueError("series_resistance_ohm must be >= 0")
        for name in ("current_limit_source_a", "current_limit_sink_a", "working_capacitance_f",
                     "transducer_constant_n_per_v", "stiffness_n_per_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive; got {getattr(self, name)}")
        if not self.voltage_min_v < self.voltage_max_v:
            raise ValueError("voltage_min_v must be below voltage_max_v")

    @property
    def c_pp_f(self):
        """C_p + T_em^2 / k_p, F: the working branch with the spring eliminated."""
        t = self.transducer_constant_n_per_v
        return self.working_capacitance_f + t * t / self.stiffness_n_per_m

    @property
    def k_q2x_m_per_c(self):
        """Seed eq. 10: x / q = T_em / (k_p C_p + T_em^2), m/C."""
        t = self.transducer_constant_n_per_v
        return t / (self.stiffness_n_per_m * self.working_capacitance_f + t * t)

    @property
    def open_circuit_stiffness_n_per_m(self):
        """k_p + T_em^2 / C_p: the stack's stiffness with its terminals open."""
        t = self.transducer_constant_n_per_v
        return self.stiffness_n_per_m + t * t / self.working_capacitance_f

    def terminal_operator(self):
        """G = C_h^{-1} + (1/C_pp) I: terminal voltage as a PI operator of q_h."""
        return self.hysteresis.inverse().plus_linear(1.0 / self.c_pp_f)

    @property
    def min_capacitance_f(self):
        """The terminal's smallest incremental capacitance ``dq/dV``, F: the PI operator's at a reversal (as at
        rest, where either direction reverses), ``1 / max slope`` of :meth:`terminal_operator` (6.0 uF on the
        P-888.51; a continuing step's is larger, ~11.6 uF). A property of the declared plant, not of a record."""
        g = self.terminal_operator()
        q0 = self.hysteresis.output_at_rest()
        return float(min(1.0 / g.slope(q0, +1), 1.0 / g.slope(q0, -1)))

    def settle_time_constant_s(self, resistance_ohm=None):
        """``R C_min`` (s): the fastest settle of a held command step through the series resistor ``R`` (default
        :attr:`series_resistance_ohm`; 0 without one) on :attr:`min_capacitance_f` (0.48 ms on the P-888.51's
        80 ohm). The gate of the held drive (:func:`~workbench.calibrate.tracing.held_drive`) and the simulator's
        sub-step (:func:`~workbench.calibrate.synthetic.substeps`) both read it: a declared quantity, so a record's
        fit (eq. 12's ``C_p``, biased by a drift) never moves either."""
        r = self.series_resistance_ohm if resistance_ohm is None else float(resistance_ohm)
        return float(r) * self.min_capacitance_f if r > 0 else 0.0

    def quasi_static_x_m(self, v_v):
        """Displacement along a terminal-voltage sequence from rest, quasi-static, m.

        Parameters
        ----------
        v_v : ndarray of float
            Terminal voltage, V, starting from rest (its first sample at 0 V for a stack at rest).

        Returns
        -------
        ndarray of float
            x = k_q2x G^{-1}(v) (seed eq. 10 on the hysteretic branch), m; the series resistor, modes and
            creep are left out (a slow drive).
        """
        return self.k_q2x_m_per_c * self.terminal_operator().inverse()(np.asarray(v_v, dtype=float))

    def with_resistance(self, resistance_ohm):
        from dataclasses import replace
        return replace(self, series_resistance_ohm=float(resistance_ohm))

    def terminal_driven(self):
        """This stack driven at its terminal by an ideal voltage source: R = 0 and no current limit (both infinite).

        The model of a recorded terminal voltage ``V_t = V - R i`` replayed through the stack: the record's current
        already obeyed the amplifier, which the replay leaves out (its limit would act again on the replay's own
        discretization of the path). A stack whose resistor is out is :meth:`with_resistance` (0): its amplifier
        still limits the current.
        """
        from dataclasses import replace
        return replace(self, series_resistance_ohm=0.0, current_limit_source_a=float("inf"),
                       current_limit_sink_a=float("inf"))
