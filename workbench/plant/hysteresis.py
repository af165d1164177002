"""Play (backlash) operators and their weighted sum, the Prandtl-Ishlinskii operator.

The hysteretic capacitance of seed 000 (eq. 13) is a weighted sum of backlash
operators, q = sum_i k_i B_i(V_h, x_i^o, w_i); seed 002 (eqs. 2.35-2.36) writes the
same thing as a Prandtl-Ishlinskii (PI) operator. Here an operator is described by
its thresholds r_i (half the deadband width w_i of seed 000), weights and initial
states. The first threshold must be 0: that play is the identity and gives the slope
right after a reversal, which must be positive for the operator to be invertible.

The inverse of a PI operator is again a PI operator (Kuhnen's formula, see
:meth:`PrandtlIshlinskii.inverse`), which the simulator uses to turn the charge, its
state variable, back into the voltage across the hysteretic capacitance.

The ``*_step`` functions are numba kernels for running an operator over a record
(:meth:`PrandtlIshlinskii.__call__`). The PZT time stepping has its own copy of the
play update over packed arrays (``kernels._pi_update``), because handing it these
separate arrays per step cost more in reference counting than the update itself;
the property tests here and the closed-form tests of the simulator cover both.
"""

from dataclasses import dataclass

import numpy as np
from numba import njit

from .._kernel_args import readonly

__all__ = ["PrandtlIshlinskii", "play", "play_step", "pi_step", "pi_slope"]


@njit(cache=True, error_model="numpy", inline="always")
def play_step(z, r, v):
    """One update of a play operator: state ``z``, threshold ``r``, input ``v``."""
    lo = v - r
    hi = v + r
    if z < lo:
        return lo
    if z > hi:
        return hi
    return z


@njit(cache=True, error_model="numpy", inline="always")
def pi_step(z, r, w, v):
    """Advance every play of a PI operator to input ``v`` (``z`` updated in place).

    Returns the operator output sum_i w_i z_i.
    """
    y = 0.0
    for i in range(z.shape[0]):
        zi = play_step(z[i], r[i], v)
        z[i] = zi
        y += w[i] * zi
    return y


@njit(cache=True, error_model="numpy")
def pi_slope(z, r, w, v, direction):
    """Incremental slope dy/dv at input ``v`` for motion in ``direction`` (+1 or -1).

    A play moves with the input only when it sits on the edge the input pushes:
    z = v - r for rising input, z = v + r for falling input. The tolerance is
    relative to the threshold so states rounded by float arithmetic still count.
    """
    s = 0.0
    for i in range(z.shape[0]):
        tol = 1e-12 * (1.0 + abs(v) + r[i])
        if direction > 0:
            if z[i] <= v - r[i] + tol:
                s += w[i]
        else:
            if z[i] >= v + r[i] - tol:
                s += w[i]
    return s


@njit(cache=True, error_model="numpy")
def _pi_run(z, r, w, v):
    out = np.empty(v.shape[0])
    for k in range(v.shape[0]):
        out[k] = pi_step(z, r, w, v[k])
    return out


def play(v, threshold, initial_state=0.0):
    """Output of one play (backlash) operator for the input sequence ``v``.

    Parameters
    ----------
    v : array_like of float
        Input samples.
    threshold : float
        Half the deadband width, same unit as ``v``; must be >= 0.
    initial_state : float
        Output before the first sample.
    """
    op = PrandtlIshlinskii(np.array([float(threshold)]), np.array([1.0]),
                           np.array([float(initial_state)]), check_invertible=False)
    return op(v)


@dataclass(frozen=True)
class PrandtlIshlinskii:
    """y = sum_i w_i F_{r_i}[v], a weighted sum of play operators with initial states.

    Parameters
    ----------
    thresholds : ndarray of float
        r_i >= 0, strictly increasing, first one 0 when ``check_invertible``.
    weights : ndarray of float
        w_i; the partial sums w_0 + ... + w_i must be positive for the operator to be
        invertible (the inverse has negative weights, so single weights may be < 0).
    initial_states : ndarray of float
        z_i before the first input; |z_i - v_0| <= r_i is not required (the first
        input pulls each play onto its band).
    check_invertible : bool
        Enforce r_0 = 0 and positive partial sums.
    """

    thresholds: np.ndarray
    weights: np.ndarray
    initial_states: np.ndarray
    check_invertible: bool = True

    def __post_init__(self):
        r = np.asarray(self.thresholds, dtype=float)
        w = np.asarray(self.weights, dtype=float)
        z = np.asarray(self.initial_states, dtype=float)
        object.__setattr__(self, "thresholds", r)
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "initial_states", z)
        if not (r.ndim == w.ndim == z.ndim == 1 and r.size == w.size == z.size >= 1):
            raise ValueError(f"thresholds, weights and initial states must be 1-D of one length; "
                             f"got {r.shape}, {w.shape}, {z.shape}")
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(w)) and np.all(np.isfinite(z))):
            raise ValueError("thresholds, weights and initial states must be finite")
        if np.any(r < 0) or np.any(np.diff(r) <= 0):
            raise ValueError(f"thresholds must be >= 0 and strictly increasing; got {r.tolist()}")
        if self.check_invertible:
            if r[0] != 0.0:
                raise ValueError(f"the first threshold must be 0 (the reversal slope); got {r[0]}")
            if np.any(np.cumsum(w) <= 0):
                raise ValueError(f"partial sums of the weights must be positive so the operator "
                                 f"is invertible; got weights {w.tolist()}")

    @property
    def size(self):
        return self.thresholds.size

    def __call__(self, v, states=None):
        """Run the operator over the input samples ``v`` from ``states`` (default: initial).

        Returns the output samples; the operator itself is not changed.
        """
        z = (self.initial_states if states is None else np.asarray(states, float)).copy()
        return _pi_run(z, self.thresholds, self.weights, readonly(v))

    def final_states(self, v, states=None):
        """Play states after the input samples ``v``."""
        z = (self.initial_states if states is None else np.asarray(states, float)).copy()
        _pi_run(z, self.thresholds, self.weights, readonly(v))
        return z

    def output_at_rest(self):
        """Output at the initial states."""
        return float(self.weights @ self.initial_states)

    def with_states(self, states):
        return PrandtlIshlinskii(self.thresholds, self.weights, np.asarray(states, float),
                                 self.check_invertible)

    def plus_linear(self, gain):
        """The operator v -> P[v] + gain * v (adds ``gain`` to the r = 0 weight)."""
        if self.thresholds[0] != 0.0:
            raise ValueError("adding a linear term needs a play with threshold 0")
        w = self.weights.copy()
        w[0] += gain
        return PrandtlIshlinskii(self.thresholds, w, self.initial_states, self.check_invertible)

    def slope(self, v, direction, states=None):
        """Incremental slope at input ``v`` (the input the states were last driven to)."""
        z = self.initial_states if states is None else np.asarray(states, float)
        return pi_slope(z, self.thresholds, self.weights, float(v), int(np.sign(direction)))

    def states_admissible(self, states=None, tol=1e-12):
        """True when the states could result from some input history.

        Reachable play states form a 1-Lipschitz memory curve over the thresholds:
        |z_i - z_j| <= r_j - r_i. Only such states map onto the inverse operator.
        """
        z = self.initial_states if states is None else np.asarray(states, float)
        r = self.thresholds
        gap = np.abs(z[:, None] - z[None, :]) - np.abs(r[:, None] - r[None, :])
        return bool(np.all(gap <= tol * (1 + np.abs(z).max() + r.max())))

    def inverse(self):
        """The exact inverse operator (Kuhnen 2003), itself a PI operator.

        Notes
        -----
        With W_i = w_0 + ... + w_i,

        r'_i = sum_{j<=i} w_j (r_i - r_j),
        w'_0 = 1 / w_0,   w'_i = -w_i / (W_i W_{i-1}),
        z'_i = W_i z_i + sum_{j>i} w_j z_j.

        The inverse's input is this operator's output, so z'_0 equals that output,
        and the partial sums of the inverse are 1 / W_i: the inverse of the inverse
        is the operator again.
        """
        r, w, z = self.thresholds, self.weights, self.initial_states
        if not self.check_invertible:
            raise ValueError("operator was built without the invertibility checks")
        if not self.states_admissible():
            raise ValueError(f"initial states {z.tolist()} cannot result from any input history "
                             f"(need |z_i - z_j| <= |r_i - r_j|); the inverse is defined only for such states")
        W = np.cumsum(w)
        r_inv = np.array([np.sum(w[: i + 1] * (r[i] - r[: i + 1])) for i in range(r.size)])
        w_inv = np.empty_like(w)
        w_inv[0] = 1.0 / w[0]
        w_inv[1:] = -w[1:] / (W[1:] * W[:-1])
        tail = np.concatenate([np.cumsum((w * z)[::-1])[::-1][1:], [0.0]])
        z_inv = W * z + tail
        return PrandtlIshlinskii(r_inv, w_inv, z_inv)
