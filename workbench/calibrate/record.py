"""Measured records: the CSV reader of time series (voltage in, current/charge/displacement/gauge out).

Format (UTF-8, an optional BOM, LF or CRLF line ends)::

    # serial: SN637
    # series_resistor_ohm: 80
    time[ms],voltage[V],displacement[um],current[mA]
    0.0,0.0,0.012,0.0
    0.1,0.5,0.013,0.21
    ...

Leading ``#`` lines are metadata, ``# key: value``. Known keys (``serial``, a string,
``series_resistor_ohm``, a resistance >= 0, ``80`` or ``80 ohm``, where ``0`` means the resistor is
out and the terminal voltage is the recorded one, seed 000's free-free test; ``input``,
``terminal`` or ``command``: the voltage column is the stack's terminal voltage or the command to
its amplifier, of unknown gain, offset and lag; and ``current``, ``sampled`` (the default: the
instantaneous current at each sample time, integrated by the trapezoid) or ``averaged`` (each sample the
mean current over the interval ending at it, as an integrating ADC and the project's simulator log:
integrated by the running sum ``i dt``); and ``gauge``, ``sampled`` (the default: each gauge reading the
displacement at its sample time, the base's gauge model as before) or ``averaged`` (each reading the gauge
chain's mean over the interval ending at it, as the project's simulator logs it: the base's gauge model is
the same mean of its prediction, :func:`~workbench.calibrate.base_fit.interval_mean`, a half-sample lag))
override the plant file for this record; other keys
are kept with their values as written (strings). The first other line is
the header: names from :data:`QUANTITIES` (in any case) with the unit in brackets, any SI prefix, in any order;
columns with other names are ignored with a notice. Time and voltage are required, and at least one
output (:data:`OUTPUTS`). Every used cell must be a finite number, time must increase strictly and
evenly (within ``rel_jitter`` of the median step), and there must be ``min_samples`` rows.
Record-level garbage is refused too: the voltage or an output that never changes (a dead or
unplugged channel: nothing to fit), and a single absurd cell (a glitch such as ``1e300``): a value
more than :data:`GLITCH_SPANS` times the channel's bulk span outside that bulk (the bulk: the
channel without its 0.1 % most extreme cells at either end, at least one); a current, a rate that
spikes genuinely when a step meets the stack without its resistor, is judged by the charge one
cell carries against the span of the charge the bulk carries.

Values are SI in the returned :class:`Record`. The file is read once, parsed by pandas' C engine and
checked with vectorised numpy; the line-by-line scan that names a bad cell runs only on failure.
"""

import codecs
import csv
import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import DataFileError, UnitError
from ..units import parse_quantity, scale_of

__all__ = ["Record", "read_record", "QUANTITIES", "OUTPUTS", "METADATA_KEYS", "INPUT_KINDS", "CURRENT_KINDS",
           "DEFAULT_CURRENT", "GLITCH_SPANS", "GAUGE_KINDS", "DEFAULT_GAUGE"]

#: Header name -> (SI unit, key in Record.channels; time goes to Record.t_s).
QUANTITIES = {"time": ("s", "t_s"), "voltage": ("V", "voltage_v"), "current": ("A", "current_a"),
              "charge": ("C", "charge_c"), "displacement": ("m", "displacement_m"),
              "gauge": ("V", "gauge_v"), "force": ("N", "force_n")}
#: Measured responses; a record needs at least one of them.
OUTPUTS = ("current", "charge", "displacement", "gauge")
#: Metadata keys with a meaning (they override the plant file); other keys are kept as strings.
METADATA_KEYS = ("serial", "series_resistor_ohm", "input", "current", "gauge")
#: Values of ``# input:``: the voltage column is the stack's terminal voltage or its amplifier's command.
INPUT_KINDS = ("terminal", "command")
#: Values of ``# current:``: each current sample is the instantaneous current at its time (``sampled``, an
#: ordinary ADC: the charge is the trapezoid) or the mean over the interval ending at it (``averaged``, an
#: integrating ADC or the project's simulator: the running sum ``i dt`` is exact). See
#: :func:`~workbench.calibrate.residual.charge_from_current`.
CURRENT_KINDS = ("sampled", "averaged")
#: The convention of a record that does not say.
DEFAULT_CURRENT = "sampled"
#: Values of ``# gauge:``: each gauge reading is the displacement's reading at its time (``sampled``) or the
#: chain's mean over the interval ending at it (``averaged``: a demodulator whose averaging period is the
#: sample period, as the project's simulator logs it, ``synthetic.GAUGE_KIND``): a half-sample lag.
GAUGE_KINDS = ("sampled", "averaged")
#: The gauge convention of a record that does not say (the base's gauge model before it could be declared).
DEFAULT_GAUGE = "sampled"
#: A cell this many bulk spans (the range without the 0.1 % extreme cells) outside the bulk is a glitch, not
#: physics: no stack, amplifier or sensor moves 100 times its own range for one sample.
GLITCH_SPANS = 100.0

_EXAMPLE = "time[s],voltage[V],displacement[um]"
_NAMES = ", ".join(QUANTITIES)
# The decimal numbers a data cell may hold; stricter than float(), which also takes "1_0" and "nan".
_NUMBER = re.compile(r"^\s*[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?\s*$")
_META = re.compile(r"^#\s*([A-Za-z_][\w.-]*)\s*:\s*(.*?)\s*$")


@dataclass(frozen=True, eq=False)      # eq=False: == on arrays is elementwise, not a bool
class Record:
    """One measured record, SI throughout; arrays are read-only (the record is frozen).

    ``metadata`` maps key -> value (``series_resistor_ohm`` a float in ohm, others strings);
    ``channels`` maps keys among voltage_v, current_a, charge_c, displacement_m, gauge_v, force_n
    to float64 arrays as long as ``t_s``; ``sample_period_s`` is the mean step; ``notices`` says
    what was ignored.
    """

    path: Path
    metadata: dict
    t_s: np.ndarray
    channels: dict
    sample_period_s: float
    notices: list = field(default_factory=list)

    @property
    def n(self):
        """Number of samples."""
        return int(self.t_s.size)

    @property
    def current_kind(self):
        """What each current sample is: the ``# current:`` header, else :data:`DEFAULT_CURRENT`."""
        return self.metadata.get("current", DEFAULT_CURRENT)

    @property
    def gauge_kind(self):
        """What each gauge reading is: the ``# gauge:`` header, else :data:`DEFAULT_GAUGE`."""
        return self.metadata.get("gauge", DEFAULT_GAUGE)

    def has(self, name):
        """True if the record holds ``name``, a channel key (``"current_a"``) or a quantity (``"current"``)."""
        key = QUANTITIES.get(name, (None, name))[1]
        return key == "t_s" or key in self.channels


def read_record(path, min_samples=100, rel_jitter=1e-3):
    """Read and validate a record CSV; see the module docstring for the format.

    Parameters
    ----------
    path : str or Path
        The CSV file (never modified).
    min_samples : int
        Fewest data rows accepted (>= 2).
    rel_jitter : float
        Largest accepted deviation of a time step from the median step, relative (0 < x < 1).

    Raises
    ------
    DataFileError
        The file breaks a rule; the message names the file, the line, the column and the fix.
    """
    if isinstance(min_samples, bool) or not isinstance(min_samples, (int, np.integer)) or min_samples < 2:
        raise ValueError(f"min_samples must be an integer >= 2, got {min_samples!r}")
    if isinstance(rel_jitter, bool) or not (isinstance(rel_jitter, (int, float, np.floating))
                                            and 0 < rel_jitter < 1):
        raise ValueError(f"rel_jitter must be a number with 0 < rel_jitter < 1, e.g. 1e-3, got {rel_jitter!r}")
    path = Path(path)
    data = path.read_bytes()
    metadata, notices = {}, []
    header_line, header, offset = _read_preamble(path, data, metadata, notices)
    columns = _read_header(path, header_line, header, notices)          # name -> (index, scale)
    first = header_line + 1
    # Trailing blank lines are harmless; blank lines inside the data are kept as rows (and then
    # rejected) so that row i is exactly line first + i in every message.
    body = data[offset:].rstrip()
    used = sorted(index for index, _ in columns.values())
    frame, failure = None, None
    if body:
        try:
            frame = pd.read_csv(io.BytesIO(body), header=None, names=list(range(len(header))),
                                usecols=used, dtype=np.float64, engine="c", index_col=False,
                                skip_blank_lines=False, encoding="utf-8")
        except (ValueError, pd.errors.ParserError) as err:        # a non-number, bad UTF-8, ...
            failure = err
    n_rows = 0 if frame is None else len(frame)
    n_lines = body.count(b"\n") + 1 if body else 0
    # pandas pads short rows with NaN and silently drops extra fields when usecols is given, so
    # the comma count is the cheap check of the field count (quoted commas only cost a rescan).
    clean = failure is None and n_rows == n_lines and (
        frame is None or (body.count(b",") == n_rows * (len(header) - 1)
                          and all(np.isfinite(frame[i].to_numpy()).all() for i in used)))
    if not clean:
        error = _find_bad_cell(path, body, first, header, header_line, columns)
        if error is not None:
            raise error
        if failure is not None or n_rows != n_lines:
            raise DataFileError(f"{path}, lines {first}-{first + n_lines - 1}: cannot read the data "
                                f"({failure or 'rows do not match lines'}); write one row of numbers "
                                f"per line, as many fields as the header")
    if n_rows < min_samples:
        raise DataFileError(f"{path}, line {first + n_rows - 1 if n_rows else header_line}: only "
                            f"{n_rows} data row(s) after the header on line {header_line}, need at "
                            f"least {min_samples}; record longer or pass a smaller min_samples")
    arrays = {}
    for name, (index, scale) in columns.items():
        values = frame[index].to_numpy(dtype=np.float64, copy=True)
        if scale != 1.0:
            values *= scale
        values.flags.writeable = False
        arrays[QUANTITIES[name][1]] = values
    _check_last_line(path, data, body, first + n_rows - 1, header, used, notices)
    t = arrays.pop("t_s")
    _check_time(path, t, first, columns["time"][0] + 1, rel_jitter)
    for name, (index, scale) in columns.items():
        if name != "time":
            _check_channel(path, name, header[index].strip(), arrays[QUANTITIES[name][1]] / scale, first, index + 1,
                           float(np.mean(np.diff(t))))
    period = float((t[-1] - t[0]) / (t.size - 1))     # the mean step: immune to rounding of single times
    return Record(path, metadata, t, arrays, period, notices)


def _read_preamble(path, data, metadata, notices):
    """Read the ``#`` lines into ``metadata``; return (header line number, header cells, data offset)."""
    offset = len(codecs.BOM_UTF8) if data.startswith(codecs.BOM_UTF8) else 0
    lineno, seen = 0, {}
    while offset < len(data):
        end = data.find(b"\n", offset)
        end = len(data) if end < 0 else end + 1
        lineno += 1
        text = _decode(path, lineno, data[offset:end]).rstrip("\r\n")
        offset = end
        if not text.strip():
            continue
        if not text.lstrip().startswith("#"):
            return lineno, next(csv.reader([text])), offset
        match = _META.match(text.strip())
        if match is None:
            # A free comment is fine; one that names a known key is a likely mistyped override.
            if any(text.lstrip("# ").startswith(key) for key in METADATA_KEYS):
                notices.append(f"line {lineno}: {text.strip()!r} is not '# key: value'; not read as metadata")
            continue
        key, value = match.groups()
        key = key.lower() if key.lower() in METADATA_KEYS else key
        where = f"{path}, line {lineno}, column {len(text) - len(text.lstrip()) + match.start(2) + 1}"
        if key in seen:
            raise DataFileError(f"{where}: metadata key {key!r} repeats line {seen[key]}; give it once")
        seen[key] = lineno
        metadata[key] = _metadata_value(where, key, value)
    raise DataFileError(f"{path}: no header line; after the '#' metadata lines write the column "
                        f"names with units, e.g. {_EXAMPLE}, then the data")


def _metadata_value(where, key, value):
    if key == "serial":
        if not value:
            raise DataFileError(f"{where}: empty serial; write e.g. '# serial: SN637'")
        return value
    if key == "series_resistor_ohm":
        try:
            ohm = parse_quantity(value, "ohm")
        except UnitError as err:
            raise DataFileError(f"{where}: series_resistor_ohm {value!r} is not a resistance; "
                                f"write e.g. '# series_resistor_ohm: 80' or '80 ohm'") from err
        if not (math.isfinite(ohm) and ohm >= 0):
            raise DataFileError(f"{where}: series_resistor_ohm must be a resistance >= 0 (0: the resistor "
                                f"is out), got {value!r}; write e.g. '# series_resistor_ohm: 80'")
        return ohm
    if key == "current":
        kind = value.strip().lower()
        if kind not in CURRENT_KINDS:
            raise DataFileError(f"{where}: current {value!r} is not one of {', '.join(CURRENT_KINDS)}; write "
                                f"'# current: sampled' (the instantaneous current at each sample time, the "
                                f"default) or '# current: averaged' (each sample the mean over the interval "
                                f"ending at it, an integrating ADC)")
        return kind
    if key == "gauge":
        kind = value.strip().lower()
        if kind not in GAUGE_KINDS:
            raise DataFileError(f"{where}: gauge {value!r} is not one of {', '.join(GAUGE_KINDS)}; write "
                                f"'# gauge: sampled' (each reading taken at its sample time, the default) or "
                                f"'# gauge: averaged' (each reading the chain's mean over the interval ending at it)")
        return kind
    if key == "input":
        kind = value.strip().lower()
        if kind not in INPUT_KINDS:
            raise DataFileError(f"{where}: input {value!r} is not one of {', '.join(INPUT_KINDS)}; write "
                                f"'# input: terminal' (the stack's voltage) or '# input: command' (the "
                                f"amplifier's command, of unknown gain, offset and lag)")
        return kind
    return value


def _read_header(path, lineno, cells, notices):
    """Map each known name to (0-based column, SI scale); note the ignored columns."""
    columns, ignored = {}, []
    for index, cell in enumerate(cells, start=1):
        where = f"{path}, line {lineno}, column {index}"
        name, bracket, rest = cell.partition("[")
        # the quantity's name in any case (Time[s], VOLTAGE[V]: s22_outsider D); the unit's case is its prefix's
        name = name.strip().lower()
        if name not in QUANTITIES:
            ignored.append(cell.strip())
            notices.append(f"line {lineno}, column {index}: column {cell.strip()!r} ignored "
                           f"(not one of {_NAMES})")
            continue
        base = QUANTITIES[name][0]
        example = f"{name}[{base}]" + (" or displacement[um]" if base == "m" else f" or {name}[m{base}]")
        rest = rest.strip()
        if not bracket or not rest.endswith("]") or not rest[:-1].strip():
            raise DataFileError(f"{where}: {cell.strip()!r} needs its unit in brackets; write {example}")
        unit = rest[:-1].strip()
        try:
            scale = scale_of(unit, base)
        except UnitError as err:
            raise DataFileError(f"{where}: unknown unit [{unit}] for {name}, expected {base} with an "
                                f"optional SI prefix; write {example}") from err
        if name in columns:
            raise DataFileError(f"{where}: {name} repeats column {columns[name][0] + 1}; give each "
                                f"quantity once (rename or delete one)")
        columns[name] = (index - 1, scale)
    missing = [f"a {name} column" for name in ("time", "voltage") if name not in columns]
    if not any(name in columns for name in OUTPUTS):
        missing.append(f"an output column ({' or '.join(OUTPUTS)})")
    if missing:
        hint = ""
        if all(_NUMBER.match(cell) or not cell.strip() for cell in cells):
            hint = " (this line looks like data: the first line that is not '#' must be the header)"
        elif ignored:
            hint = f" (ignored: {', '.join(repr(c) for c in ignored)})"
        raise DataFileError(f"{path}, line {lineno}: the header lacks {', '.join(missing)}{hint}; "
                            f"name the columns with units, e.g. {_EXAMPLE}")
    return columns


def _find_bad_cell(path, body, first, header, header_line, columns):
    """The first malformed data line or cell as a DataFileError, or None. Slow; run only on failure."""
    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError as err:
        start = body.rfind(b"\n", 0, err.start) + 1
        _decode(path, first + body.count(b"\n", 0, start), body[start:body.find(b"\n", err.start)])
    used = sorted(index for index, _ in columns.values())
    # csv.reader over the whole text runs in C; rows of plain numbers (nearly all) cost one check
    for k, cells in enumerate(csv.reader(io.StringIO(text))):
        if len(cells) == len(header) and all(_NUMBER.match(cells[i]) for i in used):
            continue
        line = first + k
        if not "".join(cells).strip():
            return DataFileError(f"{path}, line {line}: blank line inside the data; delete it")
        if cells[0].lstrip().startswith("#"):
            return DataFileError(f"{path}, line {line}, column 1: '#' line after the header; move "
                                 f"metadata above the header (line {header_line})")
        if len(cells) != len(header):
            return DataFileError(f"{path}, line {line}: {len(cells)} fields, the header (line "
                                 f"{header_line}) has {len(header)}; check for a missing or extra comma")
        index = next(i for i in used if not _NUMBER.match(cells[i]))
        cell = cells[index].strip()
        what = "an empty cell" if not cell else f"{cell!r} is not a number"
        try:
            if not math.isfinite(float(cell)):
                what = f"{cell!r} is not a finite number (NaN or inf)"
        except ValueError:
            pass
        return DataFileError(f"{path}, line {line}, column {index + 1} ({header[index].strip()}): "
                             f"{what}; write a finite number or cut the record before this line")
    return None


#: Rows before the last one whose cells set the shortest way each column is written.
_TAIL_ROWS = 1000
# how a number cut mid-write ends: a bare point or an exponent without its digits ("1.", "1e", "1e-")
_CUT_NUMBER = re.compile(r"(?:\.|[eE][-+]?)$")


def _check_last_line(path, data, body, line, header, used, notices):
    """A last line without its line end, in a file whose other lines have one, may be cut mid-write.

    The field count is checked with every row (a cut that drops a field is refused there); a cut inside the
    last number leaves a shorter number that still parses (``0.35,1.2`` cut to ``0.35,1.``). The last line
    is refused when a used cell ends as a cut number does (a bare point, an exponent without digits, where
    no row before ends so) or is shorter than a column written at one width on each of the
    :data:`_TAIL_ROWS` rows before it (a fixed format such as ``%.6e``); otherwise a missing line end is a
    notice. A cut that leaves a well-formed number in a variable-width column (``1.25`` cut to ``1.2``)
    cannot be told from data.
    """
    if data.endswith((b"\n", b"\r")) or body.count(b"\n") < 1:
        return                                                  # line-terminated, or a single data line
    start = body.rfind(b"\n") + 1
    last = next(csv.reader([body[start:].decode("utf-8")]))
    tail = body[:start].rstrip(b"\r\n").split(b"\n")[-_TAIL_ROWS:]
    rows = list(csv.reader(row.decode("utf-8") for row in tail))
    for i in used:
        cell = last[i].strip() if i < len(last) else ""
        widths = [len(r[i].strip()) for r in rows if i < len(r)]
        cut = _CUT_NUMBER.search(cell) is not None and not any(_CUT_NUMBER.search(r[i].strip()) for r in rows
                                                                if i < len(r))
        fixed = bool(widths) and min(widths) == max(widths)       # a fixed-width format: any shorter cell is cut
        if cut or (fixed and len(cell) < min(widths)):
            why = (f"{cell!r} ends as a cut number does" if cut else
                   f"{cell!r} is shorter than the {min(widths)} characters the column has on each of the "
                   f"{len(widths)} lines before it")
            raise DataFileError(f"{path}, line {line}, column {i + 1} ({header[i].strip()}): the last line has no "
                                f"line end and {why}: the file looks cut while it was written; delete the last "
                                f"line or copy the whole file again")
    notices.append(f"line {line}: the last line has no line end (every other line has one); check the file "
                   f"was copied whole")


def _check_time(path, t, first, column, rel_jitter):
    """Time must increase strictly and evenly: a gap or an uneven step names its line."""
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise DataFileError(f"{path}, line {first + i}, column {column} (time): {t[i]:.9g} s is not "
                            f"after {t[i - 1]:.9g} s on line {first + i - 1}; time must increase "
                            f"strictly (remove repeated or unsorted rows)")
    step = float(np.median(dt))
    off = np.flatnonzero(np.abs(dt - step) > rel_jitter * step)
    if off.size:
        i = int(off[0]) + 1
        ratio = dt[i - 1] / step
        kind = (f"a gap of about {round(ratio) - 1} missing sample(s)" if ratio > 1.5
                else "uneven sampling")
        raise DataFileError(f"{path}, line {first + i}, column {column} (time): step {dt[i - 1]:.6g} s "
                            f"from line {first + i - 1}, expected {step:.6g} s (the median step) within "
                            f"{rel_jitter:g} relative: {kind}; resample the record on a uniform grid "
                            f"or cut it at this line")


def _check_channel(path, name, label, y, first, column, dt_s):
    """A channel that never changes, or one absurd cell in it, is refused (see the module notes).

    ``y`` is in the file's unit (as the cells are written), so the message quotes the cell; ``dt_s``
    is the time step (a current's cell is judged by the charge it carries)."""
    where = f"{path}, column {column} ({label})"
    if name == "force":
        return                                      # read but not used by the calibration
    k = max(1, y.size // 1000)                      # the bulk leaves out the k lowest and k highest cells
    part = np.partition(y, [0, k, y.size // 2, y.size - 1 - k, y.size - 1])
    if not part[-1] > part[0]:
        what = "the input" if name == "voltage" else "an output"
        raise DataFileError(f"{where}, lines {first}-{first + y.size - 1}: every value is {y[0]:.6g}; {what} "
                            f"that never changes is a dead or unplugged channel with nothing to fit: "
                            f"check the logger's channel, or delete the column")
    lo, hi = float(part[k]), float(part[y.size - 1 - k])
    span = hi - lo
    if name == "current":
        # a current is a rate: a step of the voltage into the stack (resistor out) is a genuine spike
        # far above the bulk. Its cell is absurd only when the charge it carries in one sample,
        # |i - median| dt, exceeds GLITCH_SPANS times the span of the charge the bulk carries.
        med = float(part[y.size // 2])
        q = np.cumsum(np.clip(y, lo, hi) - med) * dt_s
        bad = np.flatnonzero(np.abs(y - med) * dt_s > GLITCH_SPANS * max(float(np.ptp(q)), span * dt_s))
    elif span > 0:
        bad = np.flatnonzero((y < lo - GLITCH_SPANS * span) | (y > hi + GLITCH_SPANS * span))
    else:                                           # constant but for a few cells: they are the glitch
        bad = np.flatnonzero(y != lo)
    if 0 < bad.size <= 2 * k:
        i = int(bad[0])
        raise DataFileError(f"{path}, line {first + i}, column {column} ({label}): {y[i]:.6g} is more than "
                            f"{GLITCH_SPANS:g} times the channel's range ({lo:.6g} .. {hi:.6g} without its extreme "
                            f"cells{'; for a current, in charge per sample' if name == 'current' else ''}) "
                            f"away from it: a logging glitch, not a measurement"
                            f"{f' ({bad.size} such cells)' if bad.size > 1 else ''}; correct the cell or "
                            f"cut the record before this line")


def _decode(path, lineno, raw):
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise DataFileError(f"{path}, line {lineno}: not UTF-8 text (byte {err.start + 1} of the line); "
                            f"save the file as UTF-8 (\"CSV UTF-8\")") from None
