"""Typed, range-checked fields of the workbench's TOML files (plants, studies).

One checker so every file reports a bad value the same way: the file, the key, the
value found and what is expected, as the error class the caller names.
"""

import math
import tomllib
from pathlib import Path
from dataclasses import dataclass

import numpy as np

__all__ = ["Field", "check_value", "check_table", "read_toml", "check_seed"]


@dataclass(frozen=True)
class Field:
    kind: str            # "float", "int", "bool", "str", "floats"
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    expect: str = ""
    required: bool = True


def check_seed(seed, name="seed"):
    """Refuse a random seed numpy cannot take: not an integer in ``[0, 2**63 - 1]``.

    Parameters
    ----------
    seed : int
    name : str
        The parameter's name in the message (the CLI passes ``--seed``).

    Raises
    ------
    FlagRangeError
        Naming the parameter, the value and the range.
    """
    from .errors import FlagRangeError
    ok = isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and 0 <= int(seed) <= 2 ** 63 - 1
    if not ok:
        raise FlagRangeError(f"{name} {seed}: out of range [0, {2 ** 63 - 1}]: numpy seeds are non-negative "
                             f"integers; e.g. 0")


def check_value(path, key, field, value, error):
    """``value`` checked against ``field``; raises ``error(path, key, message)`` when it does not fit."""
    if field.kind == "str":
        if not isinstance(value, str) or not value.strip():
            raise error(path, key, f"got {value!r}; expected {field.expect}")
        return value
    if field.kind == "bool":
        if not isinstance(value, bool):
            raise error(path, key, f"got {value!r}; expected {field.expect}")
        return value
    if field.kind == "floats":
        if not isinstance(value, list) or not value:
            raise error(path, key, f"got {value!r}; expected a non-empty list: {field.expect}")
        return np.array([check_value(path, f"{key}[{i}]", Field("float", field.lo, field.hi, field.lo_open,
                                                                field.expect), v, error)
                         for i, v in enumerate(value)])
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise error(path, key, f"got {value!r}; expected a number: {field.expect}")
    if field.kind == "int" and not isinstance(value, int):
        raise error(path, key, f"got {value!r}; expected an integer: {field.expect}")
    if not math.isfinite(value):
        raise error(path, key, f"got {value!r}; expected a finite number: {field.expect}")
    too_low = value <= field.lo if field.lo_open else value < field.lo
    if too_low or value > field.hi:
        bound = f"{'>' if field.lo_open else '>='} {field.lo:g} and <= {field.hi:g}"
        raise error(path, key, f"got {value!r}; expected {field.expect} ({bound})")
    return float(value) if field.kind == "float" else int(value)


def check_table(path, section, table, schema, error, *, sections=(), check=None, missing_hint=""):
    """One table of a TOML file checked against its schema: unknown and missing keys, each value.

    Parameters
    ----------
    path : path-like
        The file, named in every message.
    section : str
        The table's name (``""`` for the file's top level).
    table : dict
        The parsed table.
    schema : dict of str to Field
        The keys this table may hold.
    error : type
        The error class raised as ``error(path, key, message)``.
    sections : iterable of str, optional
        At the top level: the names of the file's sections, read on their own (skipped here; each
        must be a table).
    check : callable, optional
        ``check(path, key, field, value)`` for one value; :func:`check_value` by default.
    missing_hint : str, optional
        Appended to the message of a missing key (e.g. "see plants/generic_stack.toml").

    Returns
    -------
    dict
        The checked values by key.
    """
    check = check or (lambda p, k, fld, v: check_value(p, k, fld, v, error))
    out = {}
    for key, value in table.items():
        where = f"{section}.{key}" if section else key
        if not section and key in sections:
            if not isinstance(value, dict):
                raise error(path, key, f"must be a table [{key}], got {value!r}")
            continue                                   # sections are read on their own
        if key not in schema:
            raise error(path, where, f"unknown key (value {value!r}); known keys here: {', '.join(sorted(schema))}")
        out[key] = check(path, where, schema[key], value)
    for key, field in schema.items():
        if field.required and key not in out:
            where = f"{section}.{key}" if section else key
            raise error(path, where, f"missing; expected {field.expect}" + (f" ({missing_hint})" if missing_hint else ""))
    return out


def read_toml(path, error, fix="check the path"):
    """The parsed TOML file ``path``; an unreadable, non-UTF-8 or invalid file raises ``error``.

    Parameters
    ----------
    path : path-like
    error : type
        Raised as ``error(path, "file" | "syntax", message)``.
    fix : str, optional
        What to do about an unreadable file, appended to its message.

    Returns
    -------
    dict
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise error(path, "file", f"cannot be read ({err.strerror or err}); {fix}") from None
    except UnicodeDecodeError as err:
        raise error(path, "file", f"is not UTF-8 text (byte {err.start}); save it as UTF-8 TOML") from None
    if text.startswith("\ufeff"):       # a plant a study names is not seen by the preflight's file checks
        raise error(path, "file", "line 1, column 1: starts with a byte-order mark (BOM, 'UTF-8 with BOM'); "
                                  "save it as UTF-8 without BOM")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise error(path, "syntax", f"is not valid TOML: {err}") from None
