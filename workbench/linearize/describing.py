"""Describing functions of play and Prandtl-Ishlinskii operators, in closed form.

For the input v = b + A sin(wt) a play of threshold r settles, after one period, on
a parallelogram loop; its first harmonic divided by A sin(wt) is (u = r / A < 1)

    N(A) = 1/2 + [asin(1 - 2u) + 2 (1 - 2u) sqrt(u (1 - u))] / pi  -  j 4 u (1 - u) / pi,

and 0 for A <= r (the play does not move, its output is constant). The imaginary
part is a phase lag. A PI operator is a weighted sum of plays, so its describing
function is the same sum: N_PI(A) = sum_i w_i N(A; r_i). It does not depend on the
bias b: plays are shift-equivariant and the periodic loop forgets the history (the
"wiping-out" property), so only the amplitude matters once the response is
periodic. The tests check this, and the closed form against sampled first harmonics.

:class:`PINonlinearity` wraps a PI operator for python-control's
``describing_function`` (which uses the analytic method when one is present).
python-control's numerical routine warms a stateful nonlinearity up once, at the
smallest amplitude, then sweeps all amplitudes in one pass, so each amplitude starts
from the state the previous one left: the first quarter period of each is not on
the periodic loop, and for a play that is off by a few per cent.
:func:`numerical_df` and :func:`control_df` evaluate each amplitude from its own
warm-up instead.
"""

import numpy as np
from control import DescribingFunctionNonlinearity, describing_function

from ..plant.hysteresis import PrandtlIshlinskii

__all__ = ["play_df", "pi_df", "numerical_df", "control_df", "PINonlinearity"]


def play_df(amplitude, threshold):
    """Describing function of a unit-weight play operator of threshold ``threshold``.

    Parameters
    ----------
    amplitude : float or array_like
        Input amplitude(s) A >= 0, same unit as the threshold.
    threshold : float
        r >= 0 (half the deadband width).

    Returns
    -------
    complex ndarray (shape of ``amplitude``); 0 where A <= r.
    """
    a = np.asarray(amplitude, dtype=float)
    if np.any(a < 0) or not threshold >= 0:
        raise ValueError("amplitude and threshold must be >= 0")
    out = np.zeros(a.shape, dtype=complex)
    moving = a > threshold
    u = threshold / a[moving]
    re = 0.5 + (np.arcsin(1.0 - 2.0 * u) + 2.0 * (1.0 - 2.0 * u) * np.sqrt(u * (1.0 - u))) / np.pi
    out[moving] = re - 1j * 4.0 * u * (1.0 - u) / np.pi
    return out


def pi_df(op, amplitude):
    """Describing function of the PI operator ``op``: sum_i w_i N(A; r_i) (any bias)."""
    a = np.asarray(amplitude, dtype=float)
    return sum(w * play_df(a, r) for r, w in zip(op.thresholds, op.weights))


def numerical_df(op, amplitude, bias=0.0, num_points=4096, warmup_periods=1):
    """First harmonic of ``op`` driven by b + A sin, each amplitude warmed up on its own.

    The operator runs from its initial states through ``warmup_periods`` periods,
    then the next period is integrated (rectangle rule, spectrally accurate for the
    periodic output up to the kinks at reversals and thresholds).
    """
    theta = 2 * np.pi * np.arange(num_points) / num_points
    s = np.sin(theta)
    out = []
    for a in np.atleast_1d(np.asarray(amplitude, dtype=float)):
        v = bias + a * np.tile(s, warmup_periods + 1)
        y = op(v)[warmup_periods * num_points:]
        # y = Re(Y e^{j theta}); the input's first harmonic is A sin = Re(-j A e^{j theta})
        y1 = 2.0 / num_points * np.sum(y * np.exp(-1j * theta))
        out.append(y1 / (-1j * a) if a > 0 else 0j)
    return np.array(out) if np.ndim(amplitude) else out[0]


class PINonlinearity(DescribingFunctionNonlinearity):
    """A PI operator as python-control's stateful nonlinearity (memory between calls)."""

    def __init__(self, op: PrandtlIshlinskii):
        super().__init__()
        self.op = op
        self.reset()

    def reset(self):
        self._z = self.op.initial_states.copy()

    def __call__(self, x):
        x = float(np.squeeze(x))
        self._z = self.op.final_states([x], self._z)
        return float(self.op.weights @ self._z)

    def _isstatic(self):
        return False

    def describing_function(self, A):
        return complex(pi_df(self.op, A))


def control_df(op, amplitudes, num_points=200, warm_each=True):
    """python-control's numerical describing function of ``op`` (analytic method bypassed).

    With ``warm_each`` every amplitude is a separate call, so python-control's own
    warm-up runs at that amplitude; without it, one call sweeps all amplitudes and
    carries the operator state from one to the next (python-control's behaviour).
    """
    f = PINonlinearity(op)
    amps = np.asarray(amplitudes, dtype=float)
    if not warm_each:
        return describing_function(f, amps, num_points=num_points, try_method=False)
    out = []
    for a in amps:
        f.reset()
        out.append(complex(np.squeeze(describing_function(f, a, num_points=num_points, try_method=False))))
    return np.array(out)
