"""SI conventions and conversions at the edges (CLI flags, tables, reports).

Inside the package every quantity is SI: m, V, A, C, F, N, s, ohm. Strings such as
``"7.5um"`` or ``"2 mA"`` are parsed only here.
"""

import re

from .errors import UnitError

__all__ = ["PREFIXES", "BASE_UNITS", "KEY_SUFFIX_UNITS", "parse_quantity", "scale_of", "unit_of_key"]

PREFIXES = {"": 1.0, "p": 1e-12, "n": 1e-9, "u": 1e-6, "µ": 1e-6, "μ": 1e-6,
            "m": 1e-3, "k": 1e3, "M": 1e6, "G": 1e9}

BASE_UNITS = _BASE_UNITS = ("m", "V", "A", "C", "F", "N", "s", "ohm", "Hz")
_QUANTITY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([^\s\d].*)?$")


def scale_of(unit, expected):
    """Return the factor that converts ``unit`` (e.g. ``"um"``) to the SI unit ``expected``.

    Parameters
    ----------
    unit : str
        Unit with an optional SI prefix: ``"um"``, ``"mA"``, ``"kHz"``.
    expected : str
        SI base unit the value must have: one of m, V, A, C, F, N, s, ohm, Hz.

    Raises
    ------
    UnitError
        If ``unit`` is not ``expected`` with a known prefix.
    """
    if "/" in expected:
        num, den = expected.split("/", 1)
        if "/" not in unit:
            raise UnitError(f"unit {unit!r} is not {expected!r} with SI prefixes; write for example "
                            f"'200{num}/u{den}'")
        unum, uden = unit.split("/", 1)
        return scale_of(unum, num) / scale_of(uden, den)
    if expected not in _BASE_UNITS:
        raise UnitError(f"unknown base unit {expected!r}; known: {', '.join(_BASE_UNITS)}")
    unit = unit.strip()
    if unit.endswith(expected):
        prefix = unit[: len(unit) - len(expected)]
        if prefix in PREFIXES:
            return PREFIXES[prefix]
    raise UnitError(f"unit {unit!r} is not {expected!r} with an SI prefix "
                    f"({', '.join(p or '(none)' for p in PREFIXES)}); "
                    f"write for example '7.5u{expected}'")


def parse_quantity(text, expected):
    """Parse ``"7.5um"`` into 7.5e-6 (SI), checking the unit is ``expected``.

    A bare number is taken as already SI.

    Examples
    --------
    >>> round(parse_quantity("7.5um", "m"), 12)
    7.5e-06
    >>> parse_quantity("2 mA", "A")
    0.002
    """
    match = _QUANTITY.match(str(text))
    if not match:
        raise UnitError(f"cannot read {text!r} as a quantity in {expected}; "
                        f"write a number with a unit, for example '7.5u{expected}'")
    value = float(match.group(1))
    unit = match.group(2)
    if unit is None:
        return value
    return value * scale_of(unit, expected)


# the unit suffixes of the workbench's SI keys (``current_limit_source_a``, ``stiffness_n_per_m``,
# ``noise_rms_m``): one table for the --set parser and the reports
KEY_SUFFIX_UNITS = {"v": "V", "s": "s", "m": "m", "a": "A", "hz": "Hz", "n": "N", "ohm": "ohm", "f": "F",
                    "c": "C", "w": "W", "j": "J", "pa": "Pa", "m_per_v": "m/V", "v_per_m": "V/m",
                    "v_per_s": "V/s", "percent": "%", "deg": "deg", "db": "dB", "rad": "rad",
                    "points": "points", "fraction": "1"}


def unit_of_key(key):
    """The unit a key's suffix names, and the key's other words.

    ``stiffness_n_per_m`` -> ``("N/m", ["stiffness"])``, ``gain_per_s`` -> ``("1/s", ["gain"])``,
    ``noise_rms_m`` -> ``("m", ["noise", "rms"])``; a key without a known suffix gives
    ``("", words)``.

    Parameters
    ----------
    key : str
        A snake_case key whose last words name its unit.

    Returns
    -------
    unit : str
        The unit (``""`` for none).
    words : list of str
        The key's words before the unit, in their original case.
    """
    words = str(key).split("_")
    low = [w.lower() for w in words]
    k = len(low) - 1 - low[::-1].index("per") if "per" in low else -1
    if 1 < k < len(low) - 1 and low[k - 1] in KEY_SUFFIX_UNITS and "_".join(low[k + 1:]) in KEY_SUFFIX_UNITS:
        # a ratio: stiffness_n_per_m -> N/m
        return f"{KEY_SUFFIX_UNITS[low[k - 1]]}/{KEY_SUFFIX_UNITS['_'.join(low[k + 1:])]}", words[:k - 1]
    if 0 < k < len(low) - 1 and "_".join(low[k + 1:]) in KEY_SUFFIX_UNITS:
        return f"1/{KEY_SUFFIX_UNITS['_'.join(low[k + 1:])]}", words[:k]          # gain_per_s -> 1/s
    for n in (3, 2, 1):
        if len(words) > n and "_".join(low[-n:]) in KEY_SUFFIX_UNITS:
            return KEY_SUFFIX_UNITS["_".join(low[-n:])], words[:-n]
    return "", words
