"""The plant tests' one step-by-step runner: a compiled step (``kernels.pzt_step`` or a variant) over a drive.

Not cached (plain ``@njit``): numba's cache would keep the step compiled into it after kernels.py changes.
"""

import numpy as np
from numba import njit

from workbench.plant import kernels as K


@njit
def run_steps(step, m, st, v, f):
    """Rows of the step's outputs (``kernels.OUT_NAMES``), one a sample of ``v`` (V) and ``f`` (N)."""
    out = np.empty(K.N_OUT)
    rec = np.empty((v.size, K.N_OUT))
    for k in range(v.size):
        step(m, st, v[k], f[k], out)
        rec[k] = out
    return rec


@njit
def run_steps_with_creep_charge(step, m, st, v, f):
    """:func:`run_steps` with the creep branches' summed charge after each step as a seventh column, C."""
    out = np.empty(K.N_OUT)
    rec = np.empty((v.size, K.N_OUT + 1))
    for k in range(v.size):
        step(m, st, v[k], f[k], out)
        rec[k, :K.N_OUT] = out
        rec[k, K.N_OUT] = st[K.S_QC]
    return rec
