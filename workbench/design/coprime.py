"""Glover-McFarlane loop shaping: robust stabilization of normalized coprime factors.

python-control has no ``ncfsyn``. For a shaped plant Gs = G W1 (strictly proper,
state space A, B, C, D = 0) the two Riccati equations

    A'X + XA - XBB'X + C'C = 0        (control)
    AZ + ZA' - ZC'CZ + BB' = 0        (filter)

give the largest stability margin any controller can reach for Gs,
eps_max = 1 / sqrt(1 + rho(XZ)) (Glover and McFarlane 1989), and with
gamma = gamma_min / beta (beta <= 1 relaxes the optimum) the central controller

    K_inf = [A - BB'X + gamma^2 W^-T Z C'C | gamma^2 W^-T Z C' ;  B'X | 0],
    W = (1 - gamma^2) I + XZ,

in POSITIVE feedback (u = K_inf y). The implemented controller is W1 K_inf, sign
flipped for the workbench's negative-feedback convention (u = K e, e = r - y). The
Riccati equations are solved by slycot through python-control's ``care``.
"""

from dataclasses import dataclass

import control
import numpy as np

from ..errors import DesignError

__all__ = ["NcfResult", "ncf_synthesis", "ncf_margin"]


@dataclass(frozen=True)
class NcfResult:
    """The loop-shaping controller (negative feedback), the margins and the shaped plant."""

    controller: control.StateSpace
    eps_max: float         # best achievable stability margin of the shaped plant, b_opt
    eps: float             # margin of the controller returned (<= eps_max)
    shaped_plant: control.StateSpace


def ncf_synthesis(plant, w1, beta=0.9):
    """Glover-McFarlane controller for ``plant`` shaped by the pre-compensator ``w1``.

    Parameters
    ----------
    plant : continuous SISO LTI, strictly proper (y = G u)
    w1 : continuous SISO LTI, the loop shape's compensator (integrator, lead, roll-off)
    beta : float in (0, 1]
        Fraction of the optimal margin to aim for (1 is the optimum itself, which makes
        W singular; 0.9 is customary).
    """
    if not 0 < beta < 1:
        raise DesignError(f"beta must lie in (0, 1) (1 is singular); got {beta}")
    gs = control.minreal(control.ss(plant) * control.ss(w1), verbose=False)
    a, b, c, d = (np.asarray(m, dtype=float) for m in (gs.A, gs.B, gs.C, gs.D))
    if np.any(np.abs(d) > 1e-12 * max(1.0, np.abs(c).max())):
        raise DesignError("the shaped plant G W1 must be strictly proper (D = 0); add roll-off to W1")
    try:
        x, _, _ = control.care(a, b, c.T @ c)
        z, _, _ = control.care(a.T, c.T, b @ b.T)
    except Exception as exc:  # slycot reports unstabilizable / undetectable shaped plants
        raise DesignError(f"Riccati equations of the shaped plant have no stabilizing solution ({exc}); "
                          f"W1 must not cancel an unstable pole or add one on the imaginary axis other "
                          f"than an integrator the plant can stabilize") from None
    rho = max(abs(np.linalg.eigvals(x @ z)))
    gamma_min = np.sqrt(1.0 + rho)
    gamma = gamma_min / beta
    n = a.shape[0]
    w = (1.0 - gamma ** 2) * np.eye(n) + x @ z
    wit = np.linalg.inv(w.T)
    ak = a - b @ b.T @ x + gamma ** 2 * wit @ z @ c.T @ c
    bk = gamma ** 2 * wit @ z @ c.T
    ck = b.T @ x
    k_inf = control.ss(ak, bk, ck, np.zeros((1, 1)))
    controller = -control.ss(w1) * k_inf
    return NcfResult(controller=control.minreal(controller, verbose=False), eps_max=float(1.0 / gamma_min),
                     eps=float(ncf_margin(gs, -k_inf)), shaped_plant=gs)


def ncf_margin(plant, controller, freq_hz=None):
    """Stability margin b(G, K) = 1 / || [I; K] (I + G K)^-1 [I, G] ||_inf for negative feedback.

    Evaluated on a log grid (default 1e-3 to 1e6 Hz, 2000 points): the largest
    singular value of the 2 x 2 transfer matrix at each frequency.
    """
    f = np.geomspace(1e-3, 1e6, 2000) if freq_hz is None else np.asarray(freq_hz, dtype=float)
    w = 2j * np.pi * f
    g = np.array([complex(np.squeeze(plant(s))) for s in w])
    k = np.array([complex(np.squeeze(controller(s))) for s in w])
    s_inv = 1.0 / (1.0 + g * k)
    peak = 0.0
    for gi, ki, si in zip(g, k, s_inv):
        m = si * np.array([[1.0, gi], [ki, ki * gi]])
        peak = max(peak, np.linalg.norm(m, 2))
    return 1.0 / peak
