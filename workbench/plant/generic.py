"""A stack known only by its voltage -> displacement behaviour (``workbench.generic_stack/1``).

A measured record of an unnamed actuator (no capacitance, stiffness, amplifier or gauge data)
supports only a phenomenological model: a Prandtl-Ishlinskii operator from the drive voltage to
the displacement plus an offset, ``x = sum_i w_i F_{r_i}[V] + offset`` (seed 002 eqs.
2.35-2.36; :mod:`workbench.calibrate.pi_fit` fits it). A generic-stack file states that form:

* ``schema = "workbench.generic_stack/1"``, ``name``;
* ``[voltage]`` ``min_v`` < ``max_v``: the drive range, V (bipolar allowed). A file to be fitted
  (no weights) may leave the section out: ``workbench calibrate`` then takes the range from the
  record and says so; a calibrated file needs it;
* ``[hysteresis]`` ``n_plays`` and ``threshold_grid`` (``"uniform"`` or ``"quadratic"``, the
  grids of :func:`~workbench.calibrate.pi_fit.pi_thresholds`), and optionally
  ``thresholds_v`` (>= 0, strictly increasing, ``n_plays`` of them), ``weights_m_per_v``
  (>= 0, one per threshold; present = a calibrated model, absent = to be fitted) and
  ``initial_states_v`` (one per threshold, each reachable: within ``[min_v - r_i, max_v +
  r_i]``; absent = every play starts at the first voltage of the input, at rest, as
  ``fit_pi`` assumes);
* ``[output]`` ``offset_m``: the signed displacement offset, m (required with the weights).
  There is no gain key: the weights carry m/V, so a gain would be a second name for their scale.

Thresholds without weights fix the grid for a fit. Weights need thresholds and an offset.
Every problem is a :class:`~workbench.errors.PlantDefinitionError` naming the file, the key,
the value and the fix. :func:`to_toml` writes a calibrated stack back as such a file, every
value commented with its source; :func:`plant_kind` tells a full PZT file
(:func:`~workbench.plant.files.load_plant`) from a generic one by the schema string alone.
"""

import math
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..errors import PlantDefinitionError
from ..fields import Field, check_table, read_toml
from .files import SCHEMA_VERSION as PZT_SCHEMA
from .hysteresis import PrandtlIshlinskii

__all__ = ["GenericStack", "load_generic_stack", "to_toml", "plant_kind", "GENERIC_SCHEMA",
           "THRESHOLD_GRIDS"]

GENERIC_SCHEMA = "workbench.generic_stack/1"
THRESHOLD_GRIDS = ("uniform", "quadratic")
_KINDS = {PZT_SCHEMA: "pzt", GENERIC_SCHEMA: "generic_stack"}

_SCHEMA = {
    "": {
        "schema": Field("str", expect=f'the string "{GENERIC_SCHEMA}"'),
        "name": Field("str", expect="a descriptive name, e.g. \"150 V stack, Chandra et al. 2023\""),
    },
    "voltage": {
        "min_v": Field("float", -1e4, 1e4, expect="the lowest drive voltage in V, e.g. -150.0"),
        "max_v": Field("float", -1e4, 1e4, expect="the highest drive voltage in V, e.g. 150.0"),
    },
    "hysteresis": {
        "n_plays": Field("int", 1, 10000, expect="an integer number of play operators, e.g. 20"),
        "threshold_grid": Field("str", expect=f"one of {', '.join(map(repr, THRESHOLD_GRIDS))}"),
        "thresholds_v": Field("floats", 0.0, 1e4, required=False,
                              expect="thresholds in V, >= 0 and strictly increasing"),
        "weights_m_per_v": Field("floats", 0.0, math.inf, required=False,
                                 expect="play weights in m/V, >= 0 (non-negative least squares)"),
        "initial_states_v": Field("floats", -2e4, 2e4, required=False,
                                  expect="one initial play state in V per threshold"),
    },
    "output": {
        "offset_m": Field("float", -1.0, 1.0, required=False,
                          expect="the signed displacement offset in m, e.g. -1.2e-7"),
    },
}
_SECTIONS_REQUIRED = ("hysteresis",)


def _tuple(a):
    return None if a is None else tuple(float(x) for x in a)


@dataclass(frozen=True)
class GenericStack:
    """A voltage -> displacement stack model: Prandtl-Ishlinskii operator plus offset.

    Parameters
    ----------
    name : str
    min_v, max_v : float or None
        Drive voltage range, V (``min_v < max_v``); both None for an uncalibrated stack whose range
        is to be taken from the record it is fitted to.
    n_plays : int
        Number of plays.
    threshold_grid : {"uniform", "quadratic"}
        Grid a fit places the thresholds on when ``thresholds_v`` is None.
    thresholds_v : tuple of float, optional
        r_i, V, >= 0 and strictly increasing.
    weights_m_per_v : tuple of float, optional
        w_i, m/V, >= 0; present = calibrated.
    initial_states_v : tuple of float, optional
        Play states before the first sample, V (None: the first input sample).
    offset_m : float, optional
        Signed offset, m.

    Arrays are stored as tuples so that ``==`` compares whole models (round trips).
    """

    name: str
    min_v: float
    max_v: float
    n_plays: int
    threshold_grid: str = "uniform"
    thresholds_v: tuple = None
    weights_m_per_v: tuple = None
    initial_states_v: tuple = None
    offset_m: float = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"name must be a non-blank string, got {self.name!r}")
        for key in ("thresholds_v", "weights_m_per_v", "initial_states_v"):
            object.__setattr__(self, key, _tuple(getattr(self, key)))
        problem = _problem(self)
        if problem:
            raise ValueError(f"{problem[0]}: {problem[1]}")

    @property
    def calibrated(self):
        """True when the weights (hence thresholds and offset) are known."""
        return self.weights_m_per_v is not None

    def with_calibration(self, *, thresholds_v, weights_m_per_v, offset_m, initial_states_v=None):
        """A new, calibrated stack (e.g. from a :class:`~workbench.calibrate.pi_fit.PIFit`)."""
        return replace(self, n_plays=len(thresholds_v), thresholds_v=thresholds_v,
                       weights_m_per_v=weights_m_per_v, offset_m=float(offset_m),
                       initial_states_v=initial_states_v)

    def predict(self, v):
        """Displacement, m, for the drive voltage record ``v`` (V), from the initial states.

        Raises
        ------
        ValueError
            The stack is not calibrated, or ``v`` is not finite or leaves ``[min_v, max_v]``.
        """
        if not self.calibrated:
            raise ValueError(f"stack {self.name!r} is not calibrated (no weights_m_per_v); fit it "
                             f"with workbench.calibrate.pi_fit.fit_pi and with_calibration first")
        v = np.ascontiguousarray(v, dtype=float)
        if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)):
            raise ValueError(f"v must be a non-empty 1-D array of finite voltages, got shape {v.shape}")
        slack = 1e-9 * (self.max_v - self.min_v)
        out = np.flatnonzero((v < self.min_v - slack) | (v > self.max_v + slack))
        if out.size:
            raise ValueError(f"v[{out[0]}] = {v[out[0]]:g} V is outside the stack's range "
                             f"{self.min_v:g} .. {self.max_v:g} V")
        z0 = (np.full(self.n_plays, v[0]) if self.initial_states_v is None
              else np.array(self.initial_states_v))
        op = PrandtlIshlinskii(np.array(self.thresholds_v), np.array(self.weights_m_per_v), z0,
                               check_invertible=False)
        return op(v) + self.offset_m


def _problem(s):
    """(key, message) of the first inconsistency of a stack, or None."""
    if s.min_v is None or s.max_v is None:
        if s.min_v is not None or s.max_v is not None:
            return "voltage.min_v", "give both min_v and max_v, or neither (range from the record)"
        if s.weights_m_per_v is not None:
            return "voltage", ("section missing; a calibrated stack (weights given) needs its drive range "
                               "min_v, max_v in V")
    elif not s.min_v < s.max_v:
        return "voltage.min_v", (f"min_v {s.min_v:g} V must be below max_v {s.max_v:g} V; swap them "
                                 f"or widen the range")
    if s.threshold_grid not in THRESHOLD_GRIDS:
        return "hysteresis.threshold_grid", (f"got {s.threshold_grid!r}; expected one of "
                                             f"{', '.join(map(repr, THRESHOLD_GRIDS))}")
    r = s.thresholds_v
    if r is not None:
        if len(r) != s.n_plays:
            return "hysteresis.thresholds_v", (f"{len(r)} thresholds but n_plays = {s.n_plays}; "
                                               f"give one threshold per play")
        if any(x < 0 or not math.isfinite(x) for x in r) or any(b <= a for a, b in zip(r, r[1:])):
            return "hysteresis.thresholds_v", (f"got {list(r)}; thresholds must be finite, >= 0 "
                                               f"and strictly increasing")
    w = s.weights_m_per_v
    if w is not None:
        if r is None:
            return "hysteresis.weights_m_per_v", "weights need thresholds_v: give both, or neither"
        if len(w) != len(r):
            return "hysteresis.weights_m_per_v", (f"{len(w)} weights for {len(r)} thresholds; "
                                                  f"give one weight per threshold")
        bad = [i for i, x in enumerate(w) if not (math.isfinite(x) and x >= 0)]
        if bad:
            return f"hysteresis.weights_m_per_v[{bad[0]}]", (
                f"got {w[bad[0]]!r}; weights must be finite and >= 0 (a PI fit with non-negative "
                f"least squares gives such weights)")
        if s.offset_m is None:
            return "output.offset_m", "missing; a calibrated stack (weights given) needs its offset in m"
    z = s.initial_states_v
    if z is not None:
        if r is None:
            return "hysteresis.initial_states_v", "initial states need thresholds_v"
        if len(z) != len(r):
            return "hysteresis.initial_states_v", (f"{len(z)} initial states for {len(r)} "
                                                   f"thresholds; give one per threshold")
        lo, hi = (-math.inf, math.inf) if s.min_v is None else (s.min_v, s.max_v)
        for i, (zi, ri) in enumerate(zip(z, r)):
            if not (math.isfinite(zi) and lo - ri <= zi <= hi + ri):
                return f"hysteresis.initial_states_v[{i}]", (
                    f"got {zi!r} V; a play of threshold {ri:g} V driven within {s.min_v:g} .. "
                    f"{s.max_v:g} V stays within {s.min_v - ri:g} .. {s.max_v + ri:g} V")
    if s.offset_m is not None and not math.isfinite(s.offset_m):
        return "output.offset_m", f"got {s.offset_m!r}; expected a finite offset in m"
    return None


def _read(path):
    path = Path(path)
    return path, read_toml(path, PlantDefinitionError)


def _table(path, section, table):
    return check_table(path, section, table, _SCHEMA[section], PlantDefinitionError,
                       sections=[k for k in _SCHEMA if k], missing_hint="see plants/generic_stack.toml")


def load_generic_stack(path):
    """Load and validate a ``workbench.generic_stack/1`` file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    GenericStack

    Raises
    ------
    PlantDefinitionError
        Unreadable file or bad TOML; an unknown section or key, a missing key, a wrong type, a
        non-finite or out-of-range value, ``min_v >= max_v``, thresholds not increasing or
        negative, negative weights, lengths that differ from ``n_plays`` or from each other,
        unreachable initial states, weights without an offset. The message names the file,
        the key, the value and the fix.

    Examples
    --------
    >>> plants = Path(__file__).resolve().parents[2] / "plants"
    >>> stack = load_generic_stack(plants / "generic_stack.toml")
    >>> stack.n_plays, stack.calibrated
    (20, False)
    """
    path, doc = _read(path)
    for key, value in doc.items():
        if isinstance(value, dict) and key not in _SCHEMA:
            raise PlantDefinitionError(path, key, f"unknown section; known sections: "
                                                  f"{', '.join(s for s in _SCHEMA if s)}")
    top = _table(path, "", doc)
    if top["schema"] != GENERIC_SCHEMA:
        raise PlantDefinitionError(path, "schema", f"got {top['schema']!r}; expected "
                                                   f"{GENERIC_SCHEMA!r} (a full PZT plant file "
                                                   f"is read by load_plant)")
    sec = {}
    for name in _SCHEMA:
        if not name:
            continue
        if name not in doc:
            if name in _SECTIONS_REQUIRED:
                raise PlantDefinitionError(path, name, "section missing; see plants/generic_stack.toml")
            sec[name] = {}
            continue
        if not isinstance(doc[name], dict):
            raise PlantDefinitionError(path, name, f"must be a table [{name}], got {doc[name]!r}")
        sec[name] = _table(path, name, doc[name])
    h = sec["hysteresis"]
    fields = dict(name=top["name"], min_v=sec["voltage"].get("min_v"), max_v=sec["voltage"].get("max_v"),
                  n_plays=h["n_plays"], threshold_grid=h["threshold_grid"],
                  thresholds_v=h.get("thresholds_v"), weights_m_per_v=h.get("weights_m_per_v"),
                  initial_states_v=h.get("initial_states_v"), offset_m=sec["output"].get("offset_m"))
    problem = _problem(SimpleNamespace(**{k: _tuple(v) if isinstance(v, np.ndarray) else v
                                          for k, v in fields.items()}))
    if problem:
        raise PlantDefinitionError(path, problem[0], problem[1])
    return GenericStack(**fields)


def _is_control(c):
    return (ord(c) < 0x20 and c != "\t") or ord(c) == 0x7F


def _toml_string(text):
    """A TOML basic string: backslash, quote and control characters escaped, the rest literal."""
    body = "".join("\\\\" if c == "\\" else '\\"' if c == '"' else
                   f"\\u{ord(c):04x}" if _is_control(c) else c for c in text)
    return f'"{body}"'


def _floats(a):
    return "[" + ", ".join(repr(float(x)) for x in a) + "]"


def to_toml(stack, source_note):
    """The TOML text of a calibrated stack; ``load_generic_stack`` of it gives ``stack`` back.

    Parameters
    ----------
    stack : GenericStack
        Calibrated (weights, thresholds and offset known).
    source_note : str
        Where the fitted values come from (record, training window, fit), written as the source
        comment of every fitted value, e.g. ``"fit_pi on hysteresis_v_150_1hz.csv, 3 cycles"``.

    Returns
    -------
    str
        The file's text (write it with the report writers or ``Path.write_text``). Floats are
        written with ``repr``, so they read back bit for bit.

    Raises
    ------
    ValueError
        The stack is not calibrated, or ``source_note`` is empty or spans lines.
    """
    if not isinstance(stack, GenericStack) or not stack.calibrated:
        raise ValueError("to_toml writes calibrated stacks only: fit the weights first "
                         "(GenericStack.with_calibration)")
    if (not isinstance(source_note, str) or not source_note.strip()
            or any(_is_control(c) for c in source_note)):
        raise ValueError(f"source_note must be one non-empty line without control characters "
                         f"naming where the fitted values come from, got {source_note!r}")
    note = source_note.strip()
    lines = [
        "# Voltage -> displacement Prandtl-Ishlinskii model of a stack, calibrated.",
        f"# Written by workbench.plant.generic.to_toml; fitted values: {note}.",
        f'schema = "{GENERIC_SCHEMA}"',
        f"name = {_toml_string(stack.name)}",
        "",
        "[voltage]",
        f"min_v = {stack.min_v!r}   # V; drive range of the plant file calibrated (or of the record if it had none)",
        f"max_v = {stack.max_v!r}   # V; drive range of the plant file calibrated (or of the record if it had none)",
        "",
        "[hysteresis]",
        f"n_plays = {stack.n_plays}   # plays; {note}",
        f'threshold_grid = "{stack.threshold_grid}"   # grid the thresholds were placed on',
        f"thresholds_v = {_floats(stack.thresholds_v)}   # V; {note}",
        f"weights_m_per_v = {_floats(stack.weights_m_per_v)}   # m/V; {note}",
    ]
    if stack.initial_states_v is not None:
        lines.append(f"initial_states_v = {_floats(stack.initial_states_v)}   # V; {note}")
    else:
        lines.append("# initial_states_v absent: every play starts at the input's first voltage")
    lines += ["", "[output]", f"offset_m = {stack.offset_m!r}   # m; {note}", ""]
    return "\n".join(lines)


def plant_kind(path):
    """``"pzt"`` or ``"generic_stack"`` from a plant file's ``schema`` string alone.

    Raises
    ------
    PlantDefinitionError
        Unreadable file, bad TOML, or a schema that is missing or neither kind.
    """
    path, doc = _read(path)
    schema = doc.get("schema")
    if schema not in _KINDS:
        known = ", ".join(f"{k!r} ({v})" for k, v in _KINDS.items())
        raise PlantDefinitionError(path, "schema", f"got {schema!r}; expected one of {known}")
    return _KINDS[schema]
