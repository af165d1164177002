"""Nonlinear verification: the exported controller in closed loop with the full plant; sweeps.

The package is callable: ``workbench.verify(plant, controller, scenarios)`` is
:func:`workbench.verify.run.verify` (the Python API's entry point), while
``workbench.verify.run``, ``.closed_loop``... stay importable as modules.
"""

import sys
import types


class _CallableModule(types.ModuleType):
    def __call__(self, *args, **kwargs):
        from .run import verify
        return verify(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
