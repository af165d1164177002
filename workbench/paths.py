"""Checks of the files a user names: inputs readable and decodable, outputs writable, never an input.

Each check raises :class:`FileArgumentError` (a :class:`~workbench.errors.WorkbenchError`
and a ``ValueError``) with one message naming the argument, the file, the place (line
and column for an undecodable byte) and the fix. They only look at the file system, so
an entry point runs all of them before any work starts.

Examples
--------
>>> from workbench.paths import is_inside, same_path
>>> same_path("plants/../plants/a.toml", "plants/a.toml")
True
>>> is_inside("out/study/../../elsewhere", "out/study")
False
"""

import os
from pathlib import Path

from .errors import FileArgumentError

__all__ = ["FileArgumentError", "check_input_file", "check_input_dir", "check_output_file", "check_output_dir",
           "check_text_file", "same_path", "is_inside"]

# how much of a text input is read to find an undecodable byte (the plant, study and record files of
# the workbench are at most a few MB; a larger file is still read whole by its loader)
_TEXT_SUFFIXES = (".toml", ".csv", ".json", ".txt", ".md")


def _name(path, what):
    return f"{what} {path}" if what else str(path)


def same_path(a, b):
    """True when ``a`` and ``b`` name the same file (after resolving links, ``..`` and case)."""
    a, b = Path(a), Path(b)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.normcase(os.path.realpath(a)) == os.path.normcase(os.path.realpath(b))


def is_inside(path, folder):
    """True when ``path`` (resolved) lies in ``folder`` (resolved) or is ``folder``."""
    p, f = Path(os.path.realpath(path)), Path(os.path.realpath(folder))
    return p == f or f in p.parents


# Only the TOML and JSON readers take a byte-order mark as text; the record and table
# readers (.csv, .txt, .dat, ...) skip one, so a BOM there is legal input.
BOM_REFUSED_SUFFIXES = (".toml", ".json")


def check_text_file(path, what=""):
    """Refuse a text input that is binary or not UTF-8, naming the line and column of the first bad byte."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise FileArgumentError(f"{_name(path, what)}: cannot be read ({err.strerror}); "
                                f"check the file's permissions") from None
    if data.startswith(b"\xef\xbb\xbf") and path.suffix.lower() in BOM_REFUSED_SUFFIXES:
        raise FileArgumentError(f"{_name(path, what)}: line 1, column 1: starts with a byte-order mark (BOM, bytes "
                                f"ef bb bf, as Windows editors save 'UTF-8 with BOM'), which the TOML and JSON "
                                f"readers take as text; save the file as UTF-8 without BOM")
    if b"\x00" in data:
        line = data[: data.index(b"\x00")].count(b"\n") + 1
        raise FileArgumentError(f"{_name(path, what)}: line {line}: a NUL byte: this is a binary file, not text; "
                                f"give the text ({path.suffix or 'UTF-8'}) file")
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data[: err.start].count(b"\n") + 1
        col = err.start - (data.rfind(b"\n", 0, err.start) + 1) + 1
        raise FileArgumentError(f"{_name(path, what)}: line {line}, column {col}: byte 0x{data[err.start]:02x} is "
                                f"not UTF-8; save the file as UTF-8 text") from None
    return path


def check_input_file(path, what="", *, text=None):
    """An input file: exists, is a file, is readable and (for text suffixes, or ``text=True``) UTF-8.

    Parameters
    ----------
    path : path-like
    what : str
        The argument's name in messages, e.g. ``"--controller"``.
    text : bool, optional
        Check the content decodes as UTF-8 text; default by suffix (.toml, .csv, .json, ...).
    """
    path = Path(path)
    if not path.exists():
        raise FileArgumentError(f"{_name(path, what)}: no such file; check the path "
                                f"(relative paths start at {Path.cwd()})")
    if path.is_dir():
        raise FileArgumentError(f"{_name(path, what)}: is a folder; give a file in it")
    if not path.is_file():
        raise FileArgumentError(f"{_name(path, what)}: is not a regular file; give a file")
    if not os.access(path, os.R_OK):
        raise FileArgumentError(f"{_name(path, what)}: cannot be read (permission denied); check its permissions")
    if text is None:
        text = path.suffix.lower() in _TEXT_SUFFIXES
    if text:
        check_text_file(path, what)
    return path


def check_input_dir(path, what=""):
    """An input folder: exists, is a folder, is readable."""
    path = Path(path)
    if not path.exists():
        raise FileArgumentError(f"{_name(path, what)}: no such folder; check the path")
    if not path.is_dir():
        raise FileArgumentError(f"{_name(path, what)}: is a file; give a folder")
    if not os.access(path, os.R_OK | os.X_OK):
        raise FileArgumentError(f"{_name(path, what)}: cannot be read (permission denied)")
    return path


def _writable_parent(path, what):
    """The nearest existing ancestor must be a writable folder (a file there would be 'under a file')."""
    for parent in Path(os.path.abspath(path)).parents:
        if parent.exists():
            if not parent.is_dir():
                raise FileArgumentError(f"{_name(path, what)}: {parent} is a file, so nothing can be written "
                                        f"under it; give a path in a folder")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise FileArgumentError(f"{_name(path, what)}: folder {parent} is not writable; "
                                        f"give a path in a writable folder")
            _probe_write(parent, path, what)
            return parent
    return None


def _probe_write(folder, path, what):
    """Create and remove a file in ``folder``: permission bits say nothing of a read-only or virtual
    file system (/proc, a read-only mount), where only trying tells (and root passes every access test)."""
    import tempfile
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".workbench-probe.")
    except OSError as err:
        raise FileArgumentError(f"{_name(path, what)}: nothing can be written in folder {folder} "
                                f"({err.strerror or err}); give a path in a writable folder") from None
    os.close(fd)
    os.unlink(tmp)


def _not_an_input(path, what, inputs):
    for name, src in inputs:
        if src is not None and same_path(path, src):
            raise FileArgumentError(f"{_name(path, what)}: is the input {name} {src}; an output never overwrites "
                                    f"an input: give another path")


def check_output_file(path, what="", *, inputs=(), suffix=".json"):
    """An output file: not a folder, not under a file, in a writable folder, and not one of ``inputs``.

    Parameters
    ----------
    inputs : iterable of (name, path)
        The run's input files; an output equal to any of them is refused.
    suffix : str, default ".json"
        The suffix of the file the argument writes, for the example in the message (synth: ".csv").
    """
    path = Path(path)
    if str(path).endswith(("/", os.sep)) or path.is_dir():
        raise FileArgumentError(f"{_name(path, what)}: is a folder; give a file path, e.g. "
                                f"{path / ('result' + suffix)}")
    if path.exists() and not path.is_file():
        raise FileArgumentError(f"{_name(path, what)}: is not a regular file; give a file path")
    _writable_parent(path, what)
    if path.exists() and not os.access(path, os.W_OK):
        raise FileArgumentError(f"{_name(path, what)}: exists and is not writable; give another path")
    _not_an_input(path, what, inputs)
    return path


def check_output_dir(path, what="", *, inputs=()):
    """An output folder: a folder or not yet there, not under a file, writable, and not an input file."""
    path = Path(path)
    _not_an_input(path, what, inputs)
    if path.exists() and not path.is_dir():
        raise FileArgumentError(f"{_name(path, what)}: exists and is a file; give a folder path")
    if path.exists():
        if not os.access(path, os.W_OK | os.X_OK):
            raise FileArgumentError(f"{_name(path, what)}: folder is not writable; give a writable folder")
        _probe_write(path, path, what)
    else:
        _writable_parent(path, what)
    return path
