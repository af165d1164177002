"""Typed, range-checked fields of the workbench's TOML files (plants, studies).

One checker so every file reports a bad value the same way: the file, the key, the
value found and what is expected, as the error class the caller names.
"""

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Field", "check_value"]


@dataclass(frozen=True)
class Field:
    kind: str            # "float", "int", "bool", "str", "floats"
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    expect: str = ""
    required: bool = True


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
