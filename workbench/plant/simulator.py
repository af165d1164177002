"""Open-loop simulation of a plant: arrays in, arrays out, compiled inside.

:class:`PZTSimulator` turns :class:`~workbench.plant.pzt.PZTParams` into the flat
arrays of :mod:`workbench.plant.kernels` for one sample time, keeps the plant state
between calls, and returns :class:`Trajectory` records.
"""

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.signal

from . import kernels as K

__all__ = ["PZTSimulator", "Trajectory"]


@dataclass(frozen=True)
class Trajectory:
    """Sampled outputs of a simulation (SI): t, V_pea, x, q, i, V_h, V_p, V_t."""

    t_s: np.ndarray
    v_pea_v: np.ndarray
    x_m: np.ndarray
    q_c: np.ndarray
    i_a: np.ndarray
    v_h_v: np.ndarray
    v_p_v: np.ndarray
    v_t_v: np.ndarray
    peak_current_a: tuple


def _modes_ss(modes, dt_s):
    """Cascade of unit-DC-gain second-order modes (x_qs -> x), discretized with a first-order hold.

    Returns (Ad, [B0, B1], Cd, Dd): x_{k+1} = Ad x_k + B0 u_k + B1 u_{k+1} for an input
    linear over the step (Franklin-Powell-Workman; blocks of one matrix exponential).
    A zero-order hold of the step's end value would delay the displacement by a step.
    """
    if not modes:
        return np.zeros((0, 0)), np.zeros(0), np.zeros(0), np.ones(1)
    num, den = np.array([1.0]), np.array([1.0])
    for m in modes:
        w = 2 * np.pi * m.freq_hz
        num = np.polymul(num, [w * w])
        den = np.polymul(den, [1.0, 2 * m.damping_ratio * w, w * w])
    a, b, c, d = scipy.signal.tf2ss(num, den)
    n = a.shape[0]
    blk = np.zeros((n + 2, n + 2))
    blk[:n, :n] = a * dt_s
    blk[:n, n] = b[:, 0] * dt_s
    blk[n, n + 1] = 1.0
    e = scipy.linalg.expm(blk)
    ad, g1, g2 = e[:n, :n], e[:n, n], e[:n, n + 1]
    return (np.ascontiguousarray(ad), np.concatenate([g1 - g2, g2]), np.ascontiguousarray(c[0]),
            np.array([d[0, 0]]))


def _as_pzt(params):
    """The PZTParams of ``params``: itself, else the ``.pzt`` of a Plant or a plant file (:func:`~.files.as_plant`)."""
    from .files import as_plant
    from .pzt import PZTParams
    if isinstance(params, PZTParams):
        return params
    return as_plant(params, "PZTSimulator(params, dt_s): params (or the stack itself, plant.pzt)").pzt


class PZTSimulator:
    """The Fig. 3 PZT, stepped at ``dt_s`` with ``n_sub`` sub-steps per sample.

    Parameters
    ----------
    params : PZTParams or Plant or str or path-like
        The stack (``plant.pzt``); a :class:`~workbench.plant.Plant` or a plant file gives its ``.pzt``.
    dt_s : float
        Sample time, s: inputs are held over it.
    n_sub : int
        Sub-steps per sample (the electrical step is exact on the local slope, so 1
        is usually enough; more resolve current-limited slews and reversals finer).

    Examples
    --------
    >>> from pathlib import Path
    >>> from workbench.plant import load_plant
    >>> plants = Path(__file__).resolve().parents[2] / "plants"
    >>> sim = PZTSimulator(load_plant(plants / "p888_51_sn637.toml").pzt, 1e-4)
    >>> traj = sim.run(np.full(10000, 100.0))   # 1 s: the 2 mA limit slews for ~0.5 s
    >>> bool(14e-6 < traj.x_m[-1] < 18e-6)
    True
    """

    def __init__(self, params, dt_s, n_sub=1):
        params = _as_pzt(params)
        if not dt_s > 0:
            raise ValueError(f"dt_s must be positive; got {dt_s}")
        if int(n_sub) < 1:
            raise ValueError(f"n_sub must be >= 1; got {n_sub}")
        self.params = params
        self.dt_s = float(dt_s)
        self.n_sub = int(n_sub)
        h = self.dt_s / self.n_sub
        pz = params
        scalars = np.zeros(16)
        scalars[K.R] = pz.series_resistance_ohm
        scalars[K.I_SRC] = pz.current_limit_source_a
        scalars[K.I_SNK] = pz.current_limit_sink_a
        scalars[K.V_MIN] = pz.voltage_min_v
        scalars[K.V_MAX] = pz.voltage_max_v
        scalars[K.T_EM] = pz.transducer_constant_n_per_v
        scalars[K.K_P] = pz.stiffness_n_per_m
        scalars[K.C_PP] = pz.c_pp_f
        scalars[K.DT] = h
        scalars[K.QUASI_STATIC] = 1.0 if pz.series_resistance_ohm == 0.0 else 0.0
        scalars[K.INV_R] = 1.0 / pz.series_resistance_ohm if pz.series_resistance_ohm > 0 else 0.0
        scalars[K.INV_I_SRC] = 1.0 / pz.current_limit_source_a
        scalars[K.INV_I_SNK] = 1.0 / pz.current_limit_sink_a
        scalars[K.INV_K_P] = 1.0 / pz.stiffness_n_per_m
        scalars[K.INV_C_PP] = 1.0 / pz.c_pp_f
        scalars[K.INV_DT] = 1.0 / h
        self._G = pz.terminal_operator()
        self._Q = self._G.inverse()
        if pz.creep is not None:
            cc, cdec = pz.creep.capacitances_f.copy(), np.exp(-h / pz.creep.time_constants_s)
        else:
            cc, cdec = np.zeros(0), np.zeros(0)
        self._modes = _modes_ss(pz.modes, h)
        self._n_creep = 0 if pz.creep is None else pz.creep.size
        self.m, self._state_size = K.pack_model(scalars, self._G, self._Q, cc, cdec, *self._modes)
        self.reset()

    def reset(self):
        """Return to the plant file's initial state (at rest, no force, no creep charge)."""
        G = self._G
        qh = self.params.hysteresis.output_at_rest()
        ad, bd, _, _ = self._modes
        nm = ad.shape[0]
        xm = np.zeros(2 * nm + 1)
        if nm:
            # start the modes at the static displacement of the initial charge
            x0 = self.params.k_q2x_m_per_c * qh
            xm[:nm] = np.linalg.solve(np.eye(nm) - ad, (bd[:nm] + bd[nm:]) * x0)
            xm[-1] = x0
        self.st = K.pack_state(self.m, self._state_size, qh, G.output_at_rest(),
                               1.0 / G.slope(qh, +1), 1.0 / G.slope(qh, -1), G.initial_states,
                               self._Q.initial_states, np.zeros(self._n_creep), xm)

    @property
    def creep_charges_c(self):
        """Charge in each creep branch, C (a copy)."""
        o = int(self.m[K.OS_QC])
        return self.st[o:o + self._n_creep].copy()

    def set_creep_charges(self, charges_c):
        """Overwrite the creep branches' charges (steady-state solvers shoot on them)."""
        q = np.asarray(charges_c, dtype=float)
        if q.shape != (self._n_creep,) or not np.all(np.isfinite(q)):
            raise ValueError(f"need {self._n_creep} finite creep charges; got {q!r}")
        o = int(self.m[K.OS_QC])
        self.st[o:o + q.size] = q
        self.st[K.S_QC] = q.sum()

    def step_function(self):
        """(pzt_step, m, st): the compiled step and this simulator's live model and state."""
        return K.pzt_step, self.m, self.st

    def run(self, v_pea_v, f_e_n=None, decimate=1, t0_s=0.0):
        """Simulate from the current state; the state is kept for the next call.

        Parameters
        ----------
        v_pea_v : array_like of float
            Amplifier voltage command per sample, V (clipped to the amplifier range).
        f_e_n : array_like of float, optional
            Environmental force per sample, N (compression negative). Default 0.
        decimate : int
            Keep every ``decimate``-th sample (long runs need not keep every step).
        """
        v = np.ascontiguousarray(v_pea_v, dtype=float)
        f = np.zeros_like(v) if f_e_n is None else np.ascontiguousarray(f_e_n, dtype=float)
        if v.ndim != 1 or f.shape != v.shape:
            raise ValueError("voltage and force must be 1-D arrays of one length")
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(f))):
            raise ValueError("voltage and force must be finite (found NaN or inf)")
        decimate = int(decimate)
        rec = np.empty((v.size // decimate, K.N_OUT))
        i_max, i_min = K.pzt_run(self.m, self.st, v, f, self.n_sub, decimate, rec)
        idx = np.arange(1, rec.shape[0] + 1) * decimate - 1
        t = t0_s + (idx + 1) * self.dt_s
        vc = np.clip(v[idx], self.params.voltage_min_v, self.params.voltage_max_v)
        return Trajectory(t_s=t, v_pea_v=vc, x_m=rec[:, 0], q_c=rec[:, 1], i_a=rec[:, 2],
                          v_h_v=rec[:, 3], v_p_v=rec[:, 4], v_t_v=rec[:, 5],
                          peak_current_a=(float(i_max), float(i_min)))
