"""Error hierarchy.

Every error a user can cause (a plant file, a record, a CLI flag) derives from
:class:`WorkbenchError`; the CLI turns these into a one-paragraph message and exit
status 2. Each class also subclasses the matching built-in so library callers can
catch ``ValueError`` as usual.
"""

__all__ = ["WorkbenchError", "PlantDefinitionError", "UnitError", "DataFileError", "DesignError",
           "StudyDefinitionError",
           "UnsupportedError"]


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
