"""Error hierarchy.

Every error a user can cause (a plant file, a record, a CLI flag) derives from
:class:`WorkbenchError`; the CLI turns these into a one-paragraph message and exit
status 2. Each class also subclasses the matching built-in so library callers can
catch ``ValueError`` as usual.
"""

__all__ = ["WorkbenchError", "PlantDefinitionError", "StudyDefinitionError", "UnitError", "DataFileError",
           "UnsupportedError", "DesignError", "StudyFailed", "FileArgumentError", "FlagRangeError",
           "OutputOntoInputError", "ControllerError", "ControllerMismatchError", "ExportError",
           "SweepError", "MimoControllerError", "ChargeChannelError", "WorkbenchWarning",
           "ControllerMismatchWarning", "ArgumentKindError"]


class WorkbenchError(Exception):
    """Base class of every error caused by user input."""


class PlantDefinitionError(WorkbenchError, ValueError):
    """A plant TOML file is malformed: names the file, the key, the value and the fix."""

    def __init__(self, path, key, message):
        self.path = str(path)
        self.key = key
        super().__init__(f"{self.path}: [{key}] {message}")


class StudyDefinitionError(WorkbenchError, ValueError):
    """A study TOML file is malformed: names the file, the key, the value and the fix."""

    def __init__(self, path, key, message):
        self.path = str(path)
        self.key = key
        super().__init__(f"{self.path}: [{key}] {message}")


class UnitError(WorkbenchError, ValueError):
    """A quantity carries a unit the workbench cannot convert."""


class DataFileError(WorkbenchError, ValueError):
    """A data file (CSV record, table) is malformed: names the file, the line and column."""


class UnsupportedError(WorkbenchError, NotImplementedError):
    """A requested combination of options is not supported."""


class DesignError(WorkbenchError):
    """A design that cannot be met: infeasible weights, a failed or timed-out synthesis."""


class FileArgumentError(WorkbenchError, ValueError):
    """A file or folder argument that cannot be used: names the argument, the path and the fix."""


class ControllerError(DataFileError):
    """A controller file or object is not a valid controller: names the file, the key and the fix."""

    def __init__(self, source, key, message):
        self.source, self.key, self.detail = str(source or "<controller>"), key, message
        super().__init__(f"{self.source}: [{key}] {message}" if key else f"{self.source}: {message}")


class ControllerMismatchError(WorkbenchError, ValueError):
    """The controller was exported for another plant (raised by ``verify --strict``)."""


class OutputOntoInputError(WorkbenchError, ValueError):
    """An output path that is one of the run's input files: refused, the input is kept."""


class ExportError(WorkbenchError, ValueError):
    """A controller cannot be exported as asked: says what is wrong and what to change."""


class FlagRangeError(WorkbenchError, ValueError):
    """A flag outside its sane range: names the flag, the value with its unit, the range and why."""


class SweepError(WorkbenchError, ConnectionError):
    """A dask cluster cannot run the sweep (unreachable, no workers, no workbench): names the address and the fix."""


class StudyFailed(DesignError):
    """The study ran but its best design misses a target; its report is written (names the constraint and the fix)."""

    outputs_are_the_result = True      # the CLI keeps the failed study's report (exit 2), unlike a broken run's


class MimoControllerError(ControllerError):
    """A MIMO controller file or object is not valid: names the file, the key and the fix."""


class ChargeChannelError(WorkbenchError, ValueError):
    """The plant has no charge channel model for a charge or fused loop."""


class ArgumentKindError(WorkbenchError, TypeError):
    """A library function given the wrong kind of object (a Plant where its ``.pzt`` is wanted, a number for a
    plant): says what was given and what to pass."""


class WorkbenchWarning(UserWarning):
    """Base class of the warnings the library emits (``warnings.warn``) where the CLI prints a WARNING line."""


class ControllerMismatchWarning(WorkbenchWarning):
    """The controller was exported for another plant; the run goes on (``strict=True`` raises
    :class:`ControllerMismatchError` instead)."""
