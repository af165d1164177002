"""Self-sensing: displacement from the stack's own charge (seed 002), staged compensation.

:mod:`.charge_amp` the charge amplifier on the PZT model; :mod:`.estimator` the static
(eqs. 2.5-2.9, 2.30) and dynamic (eqs. 2.42-2.48) estimators; :mod:`.identify` the
identification of sec. 2.3.2 on a simulated record; :mod:`.run` the staged study behind
`workbench selfsense` (:mod:`.command`); :mod:`.force` force and elongation from V_t and the
charge (`--force`); :mod:`.table1` the Table 1 peak forces held out; :mod:`.instron_sequence` a
serial's Instron runs in sequence, the stack's memory carried; :mod:`.sysid` K D(s) and
H(s) identified from a step record (`--dynamics`);
:mod:`.fusion` the complementary gauge + charge blend and :mod:`.fused_loop` the three sensors'
closed loops (`--fused`).
"""

from .charge_amp import ChargeAmpParams, ChargeAmpStream, ChargeRecord, measure
from .estimator import (EstimatorParams, ResidualCorrection, StreamingEstimator, band_limited, dynamic_estimator,
                        dynamic_gains, static_estimate)
from .fused_loop import closed_loop_run, run_fused_study
from .fusion import Blend, choose_crossover, sensor_spectra
from ..identify.transducer import table1_swap_decision
from .force import ForceEstimate, estimate_force, run_force_study, staged_charge
from .table1 import instron_held_out, nested_held_out, table1_held_out
from .identify import Identified, identify, simulate_identification
from .sysid import IdentifiedDynamics, fit_relaxations, identify_dynamics, identified_estimator, run_dynamics_study

__all__ = ["ChargeAmpParams", "ChargeAmpStream", "ChargeRecord", "measure", "EstimatorParams", "ResidualCorrection",
           "StreamingEstimator", "band_limited", "static_estimate", "dynamic_gains", "dynamic_estimator",
           "Identified", "identify", "simulate_identification", "ForceEstimate", "estimate_force", "staged_charge",
           "run_force_study", "table1_held_out", "table1_swap_decision", "instron_held_out", "nested_held_out",
           "IdentifiedDynamics", "fit_relaxations", "identify_dynamics", "identified_estimator",
           "run_dynamics_study", "Blend", "sensor_spectra", "choose_crossover", "closed_loop_run", "run_fused_study"]

# the force path's charge, identified in coulombs (:mod:`.charge_drift`)
from .charge_drift import ChargeDrift, identify_charge_drift, reversal_alpha  # noqa: E402

__all__ += ["ChargeDrift", "identify_charge_drift", "reversal_alpha"]

# a serial's Instron runs in sequence, C_h's memory and the creep carried (:mod:`.instron_sequence`)
from .instron_sequence import SequenceRun, read_open_lead_run, serial_sequence, table1_sequence_estimates  # noqa: E402

__all__ += ["SequenceRun", "read_open_lead_run", "serial_sequence", "table1_sequence_estimates"]
