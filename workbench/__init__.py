"""workbench: control design for piezoelectric stack actuators read by strain gauges.

The Python API (``import workbench as wb``); the ``workbench`` command is a thin layer on
top of it. Names are imported on first use, so ``import workbench`` stays fast.

Plants
    :func:`load_plant`, :class:`Plant`, :class:`PZTSimulator`
Linearization and the family
    :func:`operating_point`, :func:`small_signal_model`, :func:`firmware_plant`,
    :func:`gauge_gain_v_per_m`, :func:`nominal_loop_plant` (the discrete nominal plant as firmware
    sees it, minimal), :func:`pzt_describing_function`, :class:`FamilySpec`, :func:`plant_family`,
    :func:`uncertainty_bound`
Margins
    :func:`loop_margins` (a frequency response), :func:`margins_of` (an LTI loop),
    :func:`family_margins` (worst over a family)
Designs
    :class:`LoopShapeSpec`, :func:`tune_loop_shape`, :func:`structured_controller`,
    :func:`mixed_sensitivity` (your W_s, W_ks, W_t in :class:`MixedSensitivityWeights`),
    :func:`default_weights`, :func:`ncf_synthesis`, :func:`youla_mixed_sensitivity`,
    :func:`reduce_controller`, :func:`discretize`
Controller
    :class:`Controller` (``from_lti``, ``load``, ``write``, ``run``, ``as_lti``), :func:`to_sos`,
    :func:`quantize`
Verification
    :func:`verify` -> :class:`VerifyResult`, :data:`SCENARIOS`
Mirror (three stacks, MIMO)
    :class:`MimoController` (the exported MIMO controller), :func:`run_mirror_scenarios` (its closed loop)
Calibration
    :func:`read_record`, :func:`calibrate_record` (``workbench.calibrate.run.run_calibrate``; not
    ``wb.calibrate``, which is the subpackage once any of its modules is imported)
Errors
    :class:`WorkbenchError` (every error a user's input can cause), :class:`ControllerError`
"""

import importlib

from . import _jit_cache

_jit_cache.configure()      # compiled kernels cached per source digest (see _jit_cache: numba's own check misses inlined helpers)

# name -> module (relative to this package) that is its one home
_API = {
    "load_plant": "plant", "Plant": "plant", "PZTSimulator": "plant",
    "operating_point": "linearize.small_signal", "small_signal_model": "linearize.small_signal",
    "firmware_plant": "linearize.sampled", "gauge_gain_v_per_m": "linearize.sampled",
    "nominal_loop_plant": "verify.scenarios", "pzt_describing_function": "linearize.pzt_describing",
    "FamilySpec": "linearize.uncertainty", "plant_family": "linearize.uncertainty",
    "uncertainty_bound": "linearize.uncertainty",
    "loop_margins": "design.margins", "margins_of": "design.margins", "family_margins": "design.margins",
    "LoopShapeSpec": "design.loopshape", "tune_loop_shape": "design.loopshape",
    "structured_controller": "design.loopshape",
    "mixed_sensitivity": "design.hinf", "MixedSensitivityWeights": "design.hinf", "default_weights": "design.hinf",
    "ncf_synthesis": "design.coprime", "youla_mixed_sensitivity": "design.convex",
    "reduce_controller": "design.reduce", "discretize": "design.antiwindup",
    "Controller": "controller", "ControllerError": "controller", "to_sos": "export", "quantize": "export",
    "verify": "verify", "VerifyResult": "verify.run", "SCENARIOS": "verify.scenarios",
    "read_record": "calibrate.record", "calibrate_record": ("calibrate.run", "run_calibrate"),
    "WorkbenchError": "errors",
    "MimoController": "export.mimo", "run_mirror_scenarios": "verify.mirror",
}

__all__ = sorted(_API)

# ``wb.verify`` is the subpackage, made callable: wb.verify(plant, controller, scenarios) runs
# workbench.verify.run.verify, and ``import workbench.verify.sweep_job`` keeps working
from . import verify  # noqa: E402


def __getattr__(name):
    home = _API.get(name)
    if home is None:
        raise AttributeError(f"module 'workbench' has no attribute {name!r}")
    module, attr = home if isinstance(home, tuple) else (home, name)
    value = getattr(importlib.import_module(f".{module}", __name__), attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
