"""Tests for workbench.calibrate.record: the record CSV reader."""

import re

import numpy as np
import pytest

from workbench.calibrate import read_record
from workbench.errors import DataFileError

N = 200
HEADER = "time[s],voltage[V],current[mA]"     # line 3 of the base record; data from line 4
FIRST = 4


def _rows(n=N):
    return [f"{k * 1e-3!r},{np.sin(k / 7):.6f},{0.5 + k * 1e-3:.6f}" for k in range(n)]


def _base(n=N):
    return ["# serial: SN637", "# series_resistor_ohm: 80", HEADER] + _rows(n)


def _write(tmp_path, lines, name="rec.csv", bom=False, newline="\n"):
    path = tmp_path / name
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + (newline.join(lines) + newline).encode())
    return path


def test_good_record_round_trips_to_si(tmp_path):
    rows = [(k * 0.1, -1.5 + k * 0.01, 0.25 * k, 12.5 - k * 1e-3, 3.0 + k, 293.0) for k in range(N)]
    # columns reordered, prefixed units, an ignored column, spaces around cells
    header = "displacement[um], charge[uC],time[ms],current[mA],voltage[V],temperature[K]"
    lines = ["# serial: SN 637-b", "# series_resistor_ohm: 79.5", "# operator: ab", "# run: 007", header]
    lines += [f"{d!r}, {q!r},{t!r},{i!r},{v!r},{temp!r}" for t, v, i, q, d, temp in rows]
    path = _write(tmp_path, lines)
    before = path.read_bytes()
    rec = read_record(path)
    assert path.read_bytes() == before
    cols = np.array(rows)
    expect = {"voltage_v": cols[:, 1], "current_a": cols[:, 2] * 1e-3, "charge_c": cols[:, 3] * 1e-6,
              "displacement_m": cols[:, 4] * 1e-6}
    assert set(rec.channels) == set(expect)
    for key, values in expect.items():
        np.testing.assert_allclose(rec.channels[key], values, rtol=1e-12, atol=0)
        assert rec.channels[key].dtype == np.float64
    np.testing.assert_allclose(rec.t_s, cols[:, 0] * 1e-3, rtol=1e-12, atol=0)
    assert rec.sample_period_s == pytest.approx(1e-4, rel=1e-12)
    assert rec.n == N and rec.has("current_a") and rec.has("charge") and not rec.has("force_n")
    assert rec.metadata == {"serial": "SN 637-b", "series_resistor_ohm": 79.5, "operator": "ab",
                            "run": "007"}
    assert len(rec.notices) == 1 and "temperature[K]" in rec.notices[0] and "column 6" in rec.notices[0]
    with pytest.raises(ValueError):
        rec.t_s[0] = 1.0                          # frozen record: arrays are read-only


def test_metadata_overrides_parsed(tmp_path):
    lines = ["#Serial:SN629", "# series_resistor_ohm: 0.1 kohm", "#", "# free comment, no key"]
    rec = read_record(_write(tmp_path, lines + _base()[2:]))
    assert rec.metadata == {"serial": "SN629", "series_resistor_ohm": pytest.approx(100.0)}
    assert rec.notices == []


def test_bom_and_crlf_accepted(tmp_path):
    plain = read_record(_write(tmp_path, _base(), "lf.csv"))
    windows = read_record(_write(tmp_path, _base(), "crlf.csv", bom=True, newline="\r\n"))
    assert windows.metadata == plain.metadata == {"serial": "SN637", "series_resistor_ohm": 80.0}
    np.testing.assert_array_equal(windows.t_s, plain.t_s)
    for key in plain.channels:
        np.testing.assert_array_equal(windows.channels[key], plain.channels[key])


def test_trailing_blank_lines_accepted(tmp_path):
    assert read_record(_write(tmp_path, _base() + ["", ""])).n == N


def _set(row, col, text):
    """Mutation: cell (0-based data row, 0-based column) := text."""
    def mutate(lines):
        cells = lines[FIRST - 1 + row].split(",")
        cells[col] = text
        lines[FIRST - 1 + row] = ",".join(cells)
    return mutate


def _line(lineno, text):
    def mutate(lines):
        lines[lineno - 1] = text
    return mutate


def _time(row, value):
    return _set(row, 0, repr(value))


def _drop(row):
    def mutate(lines):
        del lines[FIRST - 1 + row]
    return mutate


def _insert(lineno, text):
    def mutate(lines):
        lines.insert(lineno - 1, text)
    return mutate


# id, mutation of the base record, expected line, expected column (None: no column), text in message
CASES = [
    ("unit-mismatch", _line(3, "time[s],voltage[m],current[mA]"), 3, 2, "expected V"),
    ("unknown-unit", _line(3, "time[s],voltage[V],current[furlong]"), 3, 3, "unknown unit"),
    ("no-unit", _line(3, "time,voltage[V],current[mA]"), 3, 1, "unit in brackets"),
    ("duplicate", _line(3, "time[s],voltage[V],voltage[mV]"), 3, 3, "repeats column 2"),
    ("no-time", _line(3, "stamp[s],voltage[V],current[mA]"), 3, None, "time column"),
    ("no-voltage", _line(3, "time[s],volts[V],current[mA]"), 3, None, "voltage column"),
    ("no-output", _line(3, "time[s],voltage[V],temperature[K]"), 3, None, "output column"),
    ("nan", _set(10, 2, "nan"), 14, 3, "not a finite number"),
    ("inf", _set(20, 1, "inf"), 24, 2, "not a finite number"),
    ("minus-inf", _set(199, 2, "-inf"), 203, 3, "not a finite number"),
    ("text", _set(30, 1, "1.0V"), 34, 2, "not a number"),
    ("empty-cell", _set(40, 2, ""), 44, 3, "empty cell"),
    ("short-row", _line(9, "0.005,1.0"), 9, None, "2 fields"),
    ("long-row", _line(10, "0.006,1.0,2.0,3.0"), 10, None, "4 fields"),
    ("blank-in-data", _line(12, ""), 12, None, "blank line"),
    ("hash-in-data", _insert(12, "# gain: 2"), 12, 1, "'#' line after the header"),
    ("time-repeats", _time(30, 0.029), 34, 1, "not after"),
    ("time-backwards", _time(31, 0.0295), 35, 1, "not after"),
    ("gap", _drop(50), 54, 1, "gap of about 1 missing"),
    ("uneven", _time(60, 0.0603), 64, 1, "uneven sampling"),
    ("resistor-negative", _line(2, "# series_resistor_ohm: -5"), 2, 24, ">= 0"),
    ("resistor-text", _line(2, "# series_resistor_ohm: eighty"), 2, 24, "not a resistance"),
    ("metadata-repeat", _line(2, "# serial: SN629"), 2, 11, "repeats line 1"),
]


@pytest.mark.parametrize("mutate, line, column, fragment", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_errors_name_file_line_column(tmp_path, mutate, line, column, fragment):
    lines = _base()
    mutate(lines)
    path = _write(tmp_path, lines, name="bad_record.csv")
    with pytest.raises(DataFileError) as info:
        read_record(path)
    message = str(info.value)
    assert "bad_record.csv" in message
    assert re.search(rf"\bline {line}\b", message), message
    if column is not None:
        assert re.search(rf"\bcolumn {column}\b", message), message
    assert fragment in message


def test_gap_reports_found_and_expected_step(tmp_path):
    lines = _base()
    _drop(50)(lines)
    with pytest.raises(DataFileError, match=r"step 0\.002 s from line 53, expected 0\.001 s"):
        read_record(_write(tmp_path, lines))


def test_too_few_samples(tmp_path):
    path = _write(tmp_path, _base(50), name="short.csv")
    with pytest.raises(DataFileError, match=r"short\.csv, line 53: only 50 data row\(s\).*at least 100"):
        read_record(path)
    assert read_record(path, min_samples=50).n == 50


def test_headerless_record_is_named_as_such(tmp_path):
    # the format of ../shared/data/real: no header, an empty first column
    lines = [f",{k * 2e-4!r},{k * 0.01:.4f},0" for k in range(N)]
    with pytest.raises(DataFileError, match=r"line 1: .*looks like data"):
        read_record(_write(tmp_path, lines))


def test_no_header_at_all(tmp_path):
    with pytest.raises(DataFileError, match=r"rec\.csv: no header line"):
        read_record(_write(tmp_path, ["# serial: SN637"]))


def test_bad_arguments(tmp_path):
    path = _write(tmp_path, _base())
    with pytest.raises(ValueError, match="min_samples"):
        read_record(path, min_samples=1)
    with pytest.raises(ValueError, match="rel_jitter"):
        read_record(path, rel_jitter=0)


def test_large_record_loads(tmp_path):
    n = 350_000
    # a 1000-row pattern of preformatted cells keeps writing fast; time is k microseconds
    phase = 2 * np.pi * np.arange(1000) / 1000
    tail = [f",{100 * np.sin(p):.6f},{np.cos(p):.6f},{p * 1e-9:.4e},{np.sin(2 * p):.6f}" for p in phase]
    path = tmp_path / "big.csv"
    path.write_text("# serial: SN618\ntime[us],voltage[V],current[mA],charge[C],displacement[um]\n"
                    + "\n".join([f"{k}{tail[k % 1000]}" for k in range(n)]) + "\n")
    rec = read_record(path)
    assert rec.n == n and rec.t_s.shape == (n,)
    assert sorted(rec.channels) == ["charge_c", "current_a", "displacement_m", "voltage_v"]
    assert all(v.shape == (n,) for v in rec.channels.values())
    assert rec.sample_period_s == pytest.approx(1e-6, rel=1e-12)


def test_resistor_out_and_input_kind(tmp_path):
    """Seed 000's free-free test logs with the series resistor out: 0 ohm is a valid value."""
    rec = read_record(_write(tmp_path, ["# series_resistor_ohm: 0", "# Input: Command", HEADER] + _rows()))
    assert rec.metadata == {"series_resistor_ohm": 0.0, "input": "command"}
    with pytest.raises(DataFileError, match=r"line 1, column 10: input 'amplifier' is not one of terminal, command"):
        read_record(_write(tmp_path, ["# input: amplifier", HEADER] + _rows()))


@pytest.mark.parametrize("column", [2, 3])
@pytest.mark.parametrize("glitch, shown", [("1e300", r"1e\+300"), ("-4e12", "-4e\\+12")])
def test_one_absurd_cell_is_named(tmp_path, column, glitch, shown, rng):
    """A single glitch anywhere in the input or an output is refused with its line and column."""
    n = int(rng.integers(120, 3000))
    rows = _rows(n)
    k = int(rng.integers(0, n))
    cells = rows[k].split(",")
    cells[column - 1] = glitch
    rows[k] = ",".join(cells)
    with pytest.raises(DataFileError, match=rf"line {2 + k}, column {column} \(.*\): {shown} .* glitch"):
        read_record(_write(tmp_path, [HEADER] + rows))


@pytest.mark.parametrize("value", ["0", "0.25"])
@pytest.mark.parametrize("column", [2, 3])
def test_constant_channel_is_refused(tmp_path, value, column):
    rows = []
    for row in _rows():
        cells = row.split(",")
        cells[column - 1] = value
        rows.append(",".join(cells))
    with pytest.raises(DataFileError, match=rf"column {column} .*lines 2-{N + 1}: every value is {value}.*dead"):
        read_record(_write(tmp_path, [HEADER] + rows))


def test_large_but_genuine_swings_are_kept(tmp_path):
    """A step from a long rest to the full stroke is not a glitch: the bulk spans both levels."""
    rows = [f"{k * 1e-3!r},{0.0 if k < 150 else 100.0},{(0.0 if k < 150 else 20.0) + 1e-3 * np.sin(k):.6f}"
            for k in range(N)]
    rec = read_record(_write(tmp_path, [HEADER] + rows))
    assert rec.channels["voltage_v"].max() == 100.0


# ---- a last line cut while the file was written (issue 17: "0.35,1.2" cut to "0.35,1." read as 1.0) ----------

def _cut(tmp_path, last_text, name="cut.csv"):
    """The base record with its last line replaced by ``last_text`` and no line end after it."""
    lines = _base()[:-1] + [last_text]
    path = tmp_path / name
    path.write_bytes("\n".join(lines).encode())
    return path


@pytest.mark.parametrize("field", [1, 2])                  # the voltage or the current cut after its point
def test_a_last_number_cut_after_its_point_is_refused(tmp_path, field):
    cells = _rows()[-1].split(",")
    cells[field] = cells[field].split(".")[0] + "."
    path = _cut(tmp_path, ",".join(cells[:field + 1]) + ("," + ",".join(cells[field + 1:]) if field < 2 else ""))
    with pytest.raises(DataFileError, match=rf"line {FIRST + N - 1}, column {field + 1} .*no line end.*cut"):
        read_record(path)


def test_a_cut_in_a_fixed_width_column_is_refused(tmp_path):
    # every current cell is written with 6 decimals (8 characters here); a cut one is shorter
    cells = _rows()[-1].split(",")
    cells[2] = cells[2][:-2]
    assert re.fullmatch(r"\d\.\d{4}", cells[2])                         # still a number: a silent shortening
    with pytest.raises(DataFileError, match=rf"line {FIRST + N - 1}, column 3 .*shorter than the 8 characters"):
        read_record(_cut(tmp_path, ",".join(cells)))


def test_a_cut_that_drops_a_field_is_refused(tmp_path):
    cells = _rows()[-1].split(",")
    with pytest.raises(DataFileError, match=rf"line {FIRST + N - 1}: 2 fields, the header .* has 3"):
        read_record(_cut(tmp_path, ",".join(cells[:2])))


def test_a_whole_last_line_without_its_end_is_read_with_a_notice(tmp_path):
    whole = read_record(_write(tmp_path, _base(), name="whole.csv"))
    assert not any("no line end" in n for n in whole.notices)
    last = read_record(_cut(tmp_path, _rows()[-1]))
    assert any(f"line {FIRST + N - 1}: the last line has no line end" in n for n in last.notices)
    assert np.array_equal(last.t_s, whole.t_s)
    for key in whole.channels:
        assert np.array_equal(last.channels[key], whole.channels[key])


def test_header_names_are_read_in_any_case(tmp_path):
    """s22_outsider D: ``Time[s]`` was refused as a missing time column. A quantity's name is a word in any case;
    the unit keeps its case (m is milli, M mega)."""
    lower = read_record(_write(tmp_path, _base(), name="lower.csv"))
    upper = read_record(_write(tmp_path, ["# serial: SN637", "# series_resistor_ohm: 80",
                                          "Time[s],VOLTAGE[V],Current[mA]"] + _rows(), name="upper.csv"))
    assert sorted(upper.channels) == sorted(lower.channels) == ["current_a", "voltage_v"]
    assert np.array_equal(upper.t_s, lower.t_s)
    assert all(np.array_equal(upper.channels[k], lower.channels[k]) for k in lower.channels)
    with pytest.raises(DataFileError, match=r"repeats column 1"):
        read_record(_write(tmp_path, ["time[s],Time[ms],voltage[V],current[mA]"]
                           + [r + ",0" for r in _rows()], name="twice.csv"))
