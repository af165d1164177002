"""Self-sensing: displacement from the stack's own charge (seed 002), staged compensation.

:mod:`.charge_amp` the charge amplifier on the PZT model; :mod:`.estimator` the static
(eqs. 2.5-2.9, 2.30) and dynamic (eqs. 2.42-2.48) estimators; :mod:`.identify` the
identification of sec. 2.3.2 on a simulated record; :mod:`.run` the staged study behind
`workbench selfsense` (:mod:`.command`).
"""

from .charge_amp import ChargeAmpParams, ChargeAmpStream, ChargeRecord, measure
from .estimator import (EstimatorParams, ResidualCorrection, StreamingEstimator, band_limited, dynamic_estimator,
                        dynamic_gains, static_estimate)
from .identify import Identified, identify, simulate_identification

__all__ = ["ChargeAmpParams", "ChargeAmpStream", "ChargeRecord", "measure", "EstimatorParams", "ResidualCorrection",
           "StreamingEstimator", "band_limited", "static_estimate", "dynamic_gains", "dynamic_estimator",
           "Identified", "identify", "simulate_identification"]
