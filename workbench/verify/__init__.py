"""Nonlinear verification: the exported controller in closed loop with the full plant; sweeps.

The package is callable: ``workbench.verify(plant, controller, scenarios)`` is
:func:`workbench.verify.run.verify` (the Python API's entry point), while
``workbench.verify.run``, ``.closed_loop``... stay importable as modules.
"""

import sys
import types


_PACKAGE_DOC = __doc__


class _CallableModule(types.ModuleType):
    """The package, callable as :func:`workbench.verify.run.verify`; ``inspect.signature`` and ``help()``
    show that function's parameters and docstring (issue 17: they showed ``(*args, **kwargs)``)."""

    def __call__(self, *args, **kwargs):
        from .run import verify
        return verify(*args, **kwargs)

    @property
    def __signature__(self):
        import inspect
        from .run import verify
        return inspect.signature(verify)

    @property
    def __doc__(self):
        import inspect
        from .run import verify
        return f"{_PACKAGE_DOC}\nworkbench.verify{inspect.signature(verify)}:\n\n{verify.__doc__}"


sys.modules[__name__].__class__ = _CallableModule
