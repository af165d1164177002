"""Controller export: second-order sections, fixed-point quantization, firmware files.

The front door is :class:`workbench.Controller` (``from_lti``, ``load``, ``write``); these are
the steps it is made of.

Flow: :func:`to_sos` (a python-control controller to sections and a gain),
:func:`quantize` (sections to a :class:`FixedPointController` that cannot
overflow), :func:`write_controller` (NAME.json, NAME.h, NAME.csv, NAME.mat).
:func:`run_float` and :func:`run_fixed` simulate the two C steps of NAME.h.
"""

from .fixed_point import (FixedPointController, fixed_point_peaks, node_impulse_responses, quantize,
                          run_fixed, run_float)
from .sos import ExportError, from_sos, to_sos
from .writers import write_controller

__all__ = ["ExportError", "to_sos", "from_sos", "FixedPointController", "quantize", "run_float", "run_fixed",
           "fixed_point_peaks", "node_impulse_responses", "write_controller"]
