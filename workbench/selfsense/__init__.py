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

import importlib
import sys
import types

# name -> module (relative to this package) that is its home. Imported on first use: the
# estimators import python-control (~1.5 s), which `workbench calibrate` and every other
# command that only builds the CLI's parser (`workbench selfsense`'s options) never need.
_API = {
    **dict.fromkeys(["ChargeAmpParams", "ChargeAmpStream", "ChargeRecord", "measure"], "charge_amp"),
    **dict.fromkeys(["EstimatorParams", "ResidualCorrection", "StreamingEstimator", "band_limited",
                     "dynamic_estimator", "dynamic_gains", "static_estimate"], "estimator"),
    **dict.fromkeys(["closed_loop_run", "run_fused_study"], "fused_loop"),
    **dict.fromkeys(["Blend", "choose_crossover", "sensor_spectra"], "fusion"),
    "table1_swap_decision": "..identify.transducer",
    **dict.fromkeys(["ForceEstimate", "estimate_force", "run_force_study", "staged_charge"], "force"),
    **dict.fromkeys(["instron_held_out", "nested_held_out", "table1_held_out"], "table1"),
    **dict.fromkeys(["Identified", "identify", "simulate_identification"], "identify"),
    **dict.fromkeys(["IdentifiedDynamics", "fit_relaxations", "identify_dynamics", "identified_estimator",
                     "run_dynamics_study"], "sysid"),
    # the force path's charge, identified in coulombs (:mod:`.charge_drift`)
    **dict.fromkeys(["ChargeDrift", "identify_charge_drift", "reversal_alpha"], "charge_drift"),
    # a serial's Instron runs in sequence, C_h's memory and the creep carried (:mod:`.instron_sequence`)
    **dict.fromkeys(["SequenceRun", "read_open_lead_run", "serial_sequence", "table1_sequence_estimates"],
                    "instron_sequence"),
}

__all__ = list(_API)


def __getattr__(name):
    home = _API.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(home if home.startswith("..") else f".{home}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """``selfsense.identify`` is the function (as when this package imported it eagerly), not the
    submodule of that name that the import system would bind here once it is imported."""

    def __setattr__(self, name, value):
        if name == "identify" and isinstance(value, types.ModuleType):
            value = value.identify
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
