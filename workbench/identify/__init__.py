"""Identification of plant parameters from test records: the transducer constant (seed 000
eq. 6, Instron Table 1) and the free-free test (eqs. 7-12)."""

from .freefree import (FreeFreeResult, estimate_cp, estimate_k_q2x, hysteresis_fraction, loop_secant,
                       run_freefree, v_h_from_measurements)
from .transducer import (CONFIGS, DEFAULT_CALIBRATIONS_M_PER_V, SEED_T_EM_N_PER_V, TransducerResult,
                         identify_transducer, table1_swap_decision)

__all__ = ["CONFIGS", "DEFAULT_CALIBRATIONS_M_PER_V", "SEED_T_EM_N_PER_V", "TransducerResult",
           "identify_transducer", "table1_swap_decision", "FreeFreeResult", "estimate_cp", "estimate_k_q2x",
           "hysteresis_fraction",
           "loop_secant", "run_freefree", "v_h_from_measurements"]
