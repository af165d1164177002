"""``--set section.key=value`` overrides of plant and study values, validated like the files.

A value may carry a unit (``20mA``, ``1.5 kHz``, ``80ohm``); the key's unit suffix
(``_a``, ``_v``, ``_hz``, ...) names the SI unit it must have and the value is
converted to SI. A bare value is read as TOML (``45``, ``[0.1, 1]``, ``true``,
``"name"``) and taken as already SI. The sections of a plant file
(``electrical``, ``gauge``, ...) apply to every plant of the study (the nominal and
the other serials); the sections of a study file to the study. The result is then
validated by the same schema as the files, so a bad override fails before any work
starts with the file, the key and the fix named.
"""

import contextlib
import re
import tomllib

from ..errors import StudyDefinitionError, UnitError
from ..units import BASE_UNITS as _SI_UNITS, parse_quantity, unit_of_key

__all__ = ["PLANT_SECTIONS", "parse_overrides", "split_overrides"]

PLANT_SECTIONS = ("electrical", "hysteresis", "mechanics", "creep", "gauge", "leakage", "dielectric_absorption",
                  "displacement_sensor", "gauge_nonlinearity")
STUDY_SECTIONS = ("family", "targets", "loop_shape", "sensor", "hinf", "export")

_KEY = re.compile(r"^([a-z_]+)\.([a-z0-9_]+)$")
_WITH_UNIT = re.compile(r"^\s*[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?\s*[A-Za-zµμ/]+\s*$")


def _unit_of(key):
    """The SI unit a value for ``key`` must carry (its suffix, as ``units.unit_of_key`` reads it), or
    None when the key takes a plain number (no suffix, or %, deg, dB...)."""
    unit, _ = unit_of_key(key)
    parts = unit.split("/") if unit else []
    return unit if parts and all(p in _SI_UNITS for p in parts) else None


_NUMBER_UNIT = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(\S+)\s*$")


def _value(where, key, text):
    unit = _unit_of(key)
    if _WITH_UNIT.match(text) and text.strip().lower() not in ("true", "false", "nan", "inf"):
        if unit is None:
            # a key whose name carries a non-SI unit (phase_margin_deg, gain_margin_db, overshoot_percent): that
            # unit, written as in the key's name, is the number itself
            named, _ = unit_of_key(key)
            m = _NUMBER_UNIT.match(text)
            if named and m and m.group(2).lower() == named.lower():
                return float(m.group(1))
            raise UnitError(f"--set {where}={text}: {key} takes " + (
                f"its unit from its name ({named}): give a plain number or the number with {named}, e.g. "
                f"{where}={m.group(1) if m else 50}{named}" if named else "no unit; give a plain number"))
        try:
            return parse_quantity(text, unit)
        except UnitError as err:
            raise UnitError(f"--set {where}={text}: {err}") from None
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text          # a bare word: a string (the schema decides whether that is allowed)


def parse_overrides(items):
    """``["section.key=value", ...]`` -> ``{"section.key": value}`` (SI), in order.

    Raises
    ------
    StudyDefinitionError, UnitError
        On a malformed item, an unknown section, or a unit that does not fit the key.
    """
    out = {}
    for item in items or ():
        where, sep, text = item.partition("=")
        where = where.strip()
        m = _KEY.match(where)
        if not sep or m is None:
            raise StudyDefinitionError("--set", item, "expected section.key=value, e.g. "
                                                      "electrical.current_limit_source_a=20mA")
        section = m.group(1)
        if section not in PLANT_SECTIONS + STUDY_SECTIONS:
            raise StudyDefinitionError("--set", where, f"unknown section {section!r}; plant sections: "
                                                       f"{', '.join(PLANT_SECTIONS)}; study sections: "
                                                       f"{', '.join(STUDY_SECTIONS)}")
        out[where] = _value(where, m.group(2), text.strip())
    return out


@contextlib.contextmanager
def naming_set(overrides, items=None):
    """Within the block, a plant or study file error at a key ``--set`` gave is said as the flag's:
    ``--set targets.phase_margin_deg=500: ...`` (it named the file, which holds no 500).

    Parameters
    ----------
    overrides : dict
        ``{"section.key": value}`` as applied.
    items : list of str, optional
        The ``--set`` items as given (their text is quoted); default the values.
    """
    from ..errors import PlantDefinitionError
    try:
        yield
    except (StudyDefinitionError, PlantDefinitionError) as err:
        key = getattr(err, "key", None)
        if key not in (overrides or {}) or str(getattr(err, "path", "")).startswith("--set"):
            raise
        given = {i.partition("=")[0].strip(): i.partition("=")[2].strip() for i in items or () if "=" in i}
        text = given.get(key, repr(overrides[key]))
        head = f"{err.path}: [{key}] "
        message = str(err)[len(head):] if str(err).startswith(head) else str(err)
        raise type(err)(f"--set {key}={text}", key, f"{message} (the value --set puts into {err.path}; the file is "
                                                     f"not modified)") from None


def split_overrides(overrides):
    """(plant overrides, study overrides), each ``{"section.key": value}``."""
    plant = {k: v for k, v in overrides.items() if k.split(".", 1)[0] in PLANT_SECTIONS}
    study = {k: v for k, v in overrides.items() if k not in plant}
    return plant, study

