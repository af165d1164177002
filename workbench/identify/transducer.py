"""Transducer constant T_em from the Instron load test (seed 000 sec. 3.2, eq. 6, Table 1).

With the PZT leads open (``R_out``: only the 200 TOhm voltmeter across them) and the charge
drained before the test, a compressive environmental force F_e makes the stack generate the
back EMF V_pea, whose electrical force T_em V_pea opposes the compression. At steady state the
free stack obeys seed 000 eq. 5, k_p x_pzt = F_e + T_em V_p with V_p = V_pea, so

    T_em = (k_p x_pzt - F_e) / V_pea                                     (seed 000 eq. 6)

with k_p the spec-sheet stiffness (200 N/um). Sign convention, as in Table 1: compression is
negative for both the force F_e and the displacement x_pzt; the back EMF under compression is
positive, so T_em comes out positive (k_p x_pzt - F_e > 0 because the stack shortens less than
F_e / k_p).

With the 200 ohm load resistor across the leads (``R_in``) V_pea = 0 and eq. 6 is 0/0: those
runs measure a stiffness, not T_em. The seed reads them as the bare k_p ("leaves only the
mechanical stiffness"), but its own Fig. 3 model disagrees: shorting the leads leaves C_h in
series with C_p, so V_p = -T_em x / (C_p + C_h) and the stack's shorted stiffness is

    k_short = k_p + T_em^2 / (C_p + C_h),

about 259 N/um with the identified T_em, C_p = 5.802 uF and the large-signal C_h = 30.5 uF;
the nine R_in runs average 258.6 N/um. The R_in runs are therefore checked against k_short
(the physics), and their disagreement with the bare k_p is reported beside it.

Every run is also checked against the gauge calibration of seed 000 sec. 3.1: the recorded
displacement must equal the strain-gauge voltage change times the serial's calibration. A run
that disagrees is flagged, with a reason that carries the numbers, and is left out of T_em.

The table is read from a CSV file whose header names each column with its unit in brackets
(``displacement[um]``); values are converted to SI on reading and are SI everywhere inside.
"""

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np

from ..errors import DataFileError, UnitError
from ..plant.files import _SCHEMA as PLANT_FIELDS   # the plant file's ranges (one home)
from ..units import scale_of

__all__ = ["TransducerResult", "identify_transducer", "table1_swap_decision", "DEFAULT_CALIBRATIONS_M_PER_V",
           "SEED_T_EM_N_PER_V", "CONFIGS", "DEFAULT_TABLE1_PATH"]

#: T_em the seed reports (seed 000 sec. 3.2), N/V = C/m.
SEED_T_EM_N_PER_V = 46.71

#: Gauge calibration per serial, m/V (seed 000 sec. 3.1: 3.077, 3.183, 3.246 um/V).
DEFAULT_CALIBRATIONS_M_PER_V = MappingProxyType(
    {"SN637": 3.077e-6, "SN629": 3.183e-6, "SN618": 3.246e-6})

#: Load-resistor configurations of Table 1: resistor across the leads, or leads open.
CONFIGS = ("R_in", "R_out")

#: Seed 000 Table 1 as shipped with the workbench.
DEFAULT_TABLE1_PATH = Path(__file__).resolve().parents[2] / "plants" / "data" / "p888_51_instron_table1.csv"

# Column name -> SI base unit its values must convert to (None: the column takes no unit).
_COLUMNS = {"serial": None, "run": None, "config": None, "gauge_change": "V",
            "displacement": "m", "force": "N", "back_emf": "V"}
_HEADER_EXAMPLE = "serial,run,config,gauge_change[V],displacement[um],force[N],back_emf[V]"
_HEADER_CELL = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(?:\[([^\]]*)\])?\s*$")


@dataclass(frozen=True)
class TransducerResult:
    """Outcome of :func:`identify_transducer`.

    Attributes
    ----------
    t_em_n_per_v : float
        Mean of eq. 6 over the ``R_out`` runs that passed every check, N/V (= C/m).
    t_em_std_n_per_v : float
        Sample standard deviation (ddof=1) over the same runs, N/V; NaN if only one run is used.
    runs_used : tuple of dict
        One ``{"serial", "run", "config", "t_em_n_per_v"}`` per run averaged into T_em.
    runs_flagged : tuple of dict
        One ``{"serial", "run", "config", "reason"}`` per run that failed a check; ``reason``
        joins every failed check with "; " and quotes the numbers.
    stiffness_from_r_in_n_per_um : float or None
        Mean of F_e / x_pzt over all ``R_in`` runs (flagged or not), N/um; None without any.
    stiffness_r_in_model_n_per_um : float
        k_p + T_em^2 / (C_p + C_h) with the identified T_em: what the Fig. 3 model predicts
        for the ``R_in`` runs, N/um.
    r_in_runs : tuple of dict
        One ``{"serial", "run", "stiffness_n_per_um"}`` per ``R_in`` run.
    t_em_all_runs_as_printed_n_per_v : float
        Mean of eq. 6 over every ``R_out`` run as recorded, flagged or not, N/V.
    t_em_with_sn618_run3_swapped_n_per_v : float or None
        As ``t_em_all_runs_as_printed_n_per_v`` but with the gauge and displacement values
        exchanged on the runs :func:`table1_swap_decision` reads as swapped (on Table 1 only
        SN618 ``R_out`` run 3: displacement -1.078 um), N/V; None if it reads none swapped.
    t_em_with_r_in_stiffness_n_per_v : float or None
        Mean of eq. 6 over ``runs_used`` with k_p set to the ``R_in`` stiffness instead of the
        spec-sheet value, N/V; None without ``R_in`` runs.
    stiffness_n_per_m : float
        The k_p used in eq. 6, N/m.
    source : str
        The CSV file read.
    seed_t_em_n_per_v : float
        The value the seed reports, 46.71 N/V.
    """

    t_em_n_per_v: float
    t_em_std_n_per_v: float
    runs_used: tuple
    runs_flagged: tuple
    stiffness_from_r_in_n_per_um: float | None
    stiffness_r_in_model_n_per_um: float
    r_in_runs: tuple
    t_em_all_runs_as_printed_n_per_v: float
    t_em_with_sn618_run3_swapped_n_per_v: float | None
    t_em_with_r_in_stiffness_n_per_v: float | None
    stiffness_n_per_m: float
    source: str
    seed_t_em_n_per_v: float = SEED_T_EM_N_PER_V

    def to_json(self):
        """Return the result as a dict of plain JSON types (NaN becomes None).

        Returns
        -------
        dict
            Keys ``t_em_n_per_v``, ``t_em_std_n_per_v``, ``runs_used``, ``runs_flagged``,
            ``stiffness_from_r_in_n_per_um``, ``r_in_runs``, ``seed_t_em_n_per_v``,
            ``t_em_all_runs_as_printed_n_per_v``, ``t_em_with_sn618_run3_swapped_n_per_v``,
            ``t_em_with_r_in_stiffness_n_per_v``, ``stiffness_assumed_n_per_um`` and ``source``.
        """
        return {
            "t_em_n_per_v": _plain(self.t_em_n_per_v),
            "t_em_std_n_per_v": _plain(self.t_em_std_n_per_v),
            "runs_used": [{k: _plain(v) for k, v in r.items()} for r in self.runs_used],
            "runs_flagged": [dict(r) for r in self.runs_flagged],
            "stiffness_from_r_in_n_per_um": _plain(self.stiffness_from_r_in_n_per_um),
            "stiffness_r_in_model_n_per_um": _plain(self.stiffness_r_in_model_n_per_um),
            "r_in_runs": [{k: _plain(v) for k, v in r.items()} for r in self.r_in_runs],
            "stiffness_assumed_n_per_um": _plain(self.stiffness_n_per_m * 1e-6),
            "seed_t_em_n_per_v": _plain(self.seed_t_em_n_per_v),
            "t_em_all_runs_as_printed_n_per_v": _plain(self.t_em_all_runs_as_printed_n_per_v),
            "t_em_with_sn618_run3_swapped_n_per_v": _plain(self.t_em_with_sn618_run3_swapped_n_per_v),
            "t_em_with_r_in_stiffness_n_per_v": _plain(self.t_em_with_r_in_stiffness_n_per_v),
            "source": self.source,
        }


@dataclass(frozen=True)
class _Run:
    """One row of the table, SI, plus the numbers as printed (for the swap check)."""

    line: int
    serial: str
    run: int
    config: str
    gauge_v: float
    displacement_m: float
    force_n: float
    back_emf_v: float
    gauge_printed: float
    displacement_printed: float


def _plain(value):
    """Convert numpy scalars to Python ones and NaN to None, for JSON."""
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    value = float(value)
    return None if math.isnan(value) else value


def _check_parameters(stiffness_n_per_m, calibrations_m_per_v, gauge_tolerance,
                      stiffness_tolerance):
    for name, value in (("stiffness_n_per_m", stiffness_n_per_m),
                        ("gauge_tolerance", gauge_tolerance),
                        ("stiffness_tolerance", stiffness_tolerance)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}; for example "
                             f"stiffness_n_per_m=2.0e8 (200 N/um), gauge_tolerance=0.05, "
                             f"stiffness_tolerance=0.20")
    if not hasattr(calibrations_m_per_v, "items"):
        raise TypeError(f"calibrations_m_per_v must map serial to m/V, e.g. "
                        f"{{'SN637': 3.077e-6}}, got {type(calibrations_m_per_v).__name__}")
    for serial, cal in calibrations_m_per_v.items():
        if not isinstance(serial, str):
            raise TypeError(f"calibrations_m_per_v keys must be serial strings like 'SN637', "
                            f"got {serial!r}")
        if isinstance(cal, bool) or not isinstance(cal, (int, float, np.floating, np.integer)):
            raise TypeError(f"calibrations_m_per_v[{serial!r}] must be a number in m/V, got {cal!r}")
        if not (math.isfinite(cal) and 0 < cal < 1e-3):
            raise ValueError(f"calibrations_m_per_v[{serial!r}] = {cal!r} is not a gauge "
                             f"calibration in m/V (expected 0 < value < 1e-3, e.g. 3.077e-6 "
                             f"for 3.077 um/V)")


# A k_p this far from the stiffness the table's R_in runs measure is a unit slip, not a stack: the R_in runs
# measure k_p + T_em^2 / (C_p + C_h) >= k_p (eq. 5 with the leads shorted), and a wrong SI prefix moves a
# value by 1e3 at least, so the bound is the geometric midpoint between right (ratio ~1) and one prefix off
STIFFNESS_SLIP_FACTOR = 10 ** 1.5


def _check_stiffness_against_r_in(path, kp, runs):
    """Refuse a k_p (N/m) a unit slip away from the R_in runs' F/x (issue 17: ``--stiffness 200`` as N/m)."""
    ks = [r.force_n / r.displacement_m for r in runs if r.config == "R_in" and r.displacement_m != 0.0]
    ks = [k for k in ks if math.isfinite(k) and k > 0]
    if not ks:
        return
    k_r_in = float(np.mean(ks))
    ratio = kp / k_r_in
    if not 1 / STIFFNESS_SLIP_FACTOR <= ratio <= STIFFNESS_SLIP_FACTOR:
        raise UnitError(f"--stiffness (stiffness_n_per_m) {kp:g} N/m = {kp * 1e-6:g} N/um is {ratio:.3g} times the "
                        f"{k_r_in * 1e-6:.1f} N/um the {len(ks)} R_in runs of {path} measure (k_p + T_em^2/(C_p + "
                        f"C_h) >= k_p); more than {STIFFNESS_SLIP_FACTOR:.3g}x apart is a unit slip: give the unit, "
                        f"e.g. --stiffness 200N/um (stiffness_n_per_m=2e8), or check the R_in runs' force and "
                        f"displacement units")


def _read_header(path, lineno, cells):
    """Map column name -> (index, SI scale) from the header row, validating names and units."""
    columns = {}
    for index, cell in enumerate(cells, start=1):
        match = _HEADER_CELL.match(cell)
        if not match:
            raise DataFileError(f"{path}, line {lineno}, column {index}: cannot read header "
                                f"cell {cell!r}; write name[unit], e.g. {_HEADER_EXAMPLE}")
        name, unit = match.group(1), match.group(2)
        if name not in _COLUMNS:
            raise DataFileError(f"{path}, line {lineno}, column {index}: unknown column "
                                f"{name!r}; the columns are {', '.join(_COLUMNS)} "
                                f"(header e.g. {_HEADER_EXAMPLE})")
        if name in columns:
            raise DataFileError(f"{path}, line {lineno}, column {index}: column {name!r} "
                                f"repeats column {columns[name][0] + 1}; give each column once")
        base = _COLUMNS[name]
        if base is None:
            if unit is not None:
                raise DataFileError(f"{path}, line {lineno}, column {index}: column {name!r} "
                                    f"takes no unit, got [{unit}]; write plain {name}")
            scale = 1.0
        else:
            if unit is None or not unit.strip():
                raise DataFileError(f"{path}, line {lineno}, column {index}: column {name!r} "
                                    f"needs its unit in brackets, a unit of {base} such as "
                                    f"{name}[{'um' if base == 'm' else base}]")
            try:
                scale = scale_of(unit, base)
            except UnitError as err:
                raise DataFileError(f"{path}, line {lineno}, column {index} ({cell.strip()}): "
                                    f"unknown unit [{unit}]; {name} needs a unit of {base} "
                                    f"with an SI prefix, e.g. {name}[{'um' if base == 'm' else base}]"
                                    ) from err
        columns[name] = (index - 1, scale)
    missing = [name for name in _COLUMNS if name not in columns]
    if missing:
        raise DataFileError(f"{path}, line {lineno}: header lacks column(s) "
                            f"{', '.join(missing)}; the header must name all of {_HEADER_EXAMPLE}")
    return columns


def _read_table(path, calibrations_m_per_v, deferred=None):
    """Read and validate the CSV; return the runs (SI) and the gauge/displacement scales.

    A force no stack can carry (:func:`_check_force`) is refused at once, unless it would be possible in the
    next SI unit down (x 1/1000: a column's unit slip) and ``deferred`` is a list: then its error is appended
    there, for the caller to raise after its own whole-column diagnosis of units (T_em out of range)."""
    from ..paths import check_input_file
    path = check_input_file(Path(path), "Table 1", text=True)     # a folder, binary or not UTF-8: named here
    if path.suffix.lower() in (".toml", ".json"):
        # a plant, study or controller file given as the table: say so, not "cannot read header cell"
        raise DataFileError(f"{path}: is a {path.suffix} file, not a Table 1 CSV; give the Instron table, e.g. "
                            f"plants/data/p888_51_instron_table1.csv")
    columns = None
    runs = []
    seen = {}
    # utf-8-sig: an optional BOM, as Excel saves "CSV UTF-8" (calibrate's record reader skips it too)
    with path.open(newline="", encoding="utf-8-sig") as handle:
        for lineno, text in enumerate(handle, start=1):
            if not text.strip() or text.lstrip().startswith("#"):
                continue
            cells = next(csv.reader([text]))
            if columns is None:
                columns = _read_header(path, lineno, cells)
                header_line = lineno
                names = sorted(columns, key=lambda n: columns[n][0])
                continue
            if len(cells) != len(columns):
                raise DataFileError(f"{path}, line {lineno}: {len(cells)} fields, expected "
                                    f"{len(columns)} ({', '.join(names)}); check for a missing "
                                    f"or extra comma")

            def cell(name):
                index = columns[name][0]
                return index + 1, cells[index].strip()

            def number(name):
                index, raw = cell(name)
                where = f"{path}, line {lineno}, column {index} ({name})"
                if not raw:
                    raise DataFileError(f"{where}: empty cell; write a finite number")
                try:
                    value = float(raw)
                except ValueError as err:
                    raise DataFileError(f"{where}: {raw!r} is not a number; write a finite "
                                        f"number such as -1.277") from err
                if not math.isfinite(value):
                    raise DataFileError(f"{where}: {raw!r} is not a finite number; write the "
                                        f"measured value, or delete the row if there is none")
                return value

            index, serial = cell("serial")
            if serial not in calibrations_m_per_v:
                raise DataFileError(f"{path}, line {lineno}, column {index} (serial): unknown "
                                    f"serial {serial!r}; known serials are "
                                    f"{', '.join(calibrations_m_per_v)}; pass its gauge "
                                    f"calibration in calibrations_m_per_v to add one")
            index, raw_run = cell("run")
            try:
                run = int(raw_run)
            except ValueError:
                run = 0
            if run < 1:
                raise DataFileError(f"{path}, line {lineno}, column {index} (run): {raw_run!r} "
                                    f"is not a run number; write an integer >= 1")
            index, config = cell("config")
            if config not in CONFIGS:
                raise DataFileError(f"{path}, line {lineno}, column {index} (config): unknown "
                                    f"configuration {config!r}; write R_in (load resistor "
                                    f"across the leads) or R_out (leads open)")
            key = (serial, run, config)
            if key in seen:
                raise DataFileError(f"{path}, line {lineno}: {serial} run {run} {config} "
                                    f"repeats line {seen[key]}; give each run once")
            seen[key] = lineno
            gauge, displacement = number("gauge_change"), number("displacement")
            _check_force(path, lineno, columns["force"][0] + 1, number("force") * columns["force"][1],
                         displacement * columns["displacement"][1], deferred)
            runs.append(_Run(line=lineno, serial=serial, run=run, config=config,
                             gauge_v=gauge * columns["gauge_change"][1],
                             displacement_m=displacement * columns["displacement"][1],
                             force_n=number("force") * columns["force"][1],
                             back_emf_v=number("back_emf") * columns["back_emf"][1],
                             gauge_printed=gauge, displacement_printed=displacement))
    if columns is None:
        raise DataFileError(f"{path}: no header line; the first line that is not a # comment "
                            f"must be {_HEADER_EXAMPLE}")
    if not runs:
        raise DataFileError(f"{path}: no data rows after the header (line {header_line}); "
                            f"add one row per run")
    return runs, columns["gauge_change"][1], columns["displacement"][1]


#: The stiffest stack a plant file holds (``[mechanics] stiffness_n_per_m``'s bound), N/m: no run's force can
#: exceed this times its displacement (the open-circuit stiffness k_p + T_em^2/C_p of a P-888.51, ~5.6e8 N/m,
#: is 1/1800 of it; seed 000 Table 1 has |F/x| 2.2e8-2.5e9 N/m).
STIFFNESS_MAX_N_PER_M = PLANT_FIELDS["mechanics"]["stiffness_n_per_m"].hi


def _check_force(path, lineno, column, force_n, displacement_m, deferred=None):
    """A force no stack could carry over the row's displacement is a bad cell (a glitch such as -1e300)."""
    bound_n = STIFFNESS_MAX_N_PER_M * abs(displacement_m)
    if displacement_m != 0.0 and abs(force_n) > bound_n:
        error = DataFileError(f"{path}, line {lineno}, column {column} (force): {force_n:.4g} N over the row's "
                            f"displacement {displacement_m * 1e6:.4g} um is a stiffness |F/x| = "
                            f"{abs(force_n / displacement_m):.3g} N/m, beyond {STIFFNESS_MAX_N_PER_M:.3g} N/m, the "
                            f"stiffest stack a plant file holds (|F| <= {bound_n:.4g} N here): physically "
                            f"impossible; correct the cell (a logging glitch or the force column's unit)")
        if deferred is None or abs(force_n) > 1000.0 * bound_n:
            raise error
        deferred.append(error)


def _gauge_disagreement(gauge_v, displacement_m, calibration_m_per_v):
    """Relative disagreement |gauge x calibration - displacement| / |displacement|."""
    return abs(gauge_v * calibration_m_per_v - displacement_m) / abs(displacement_m)


def _eq6(stiffness_n_per_m, run, displacement_m=None):
    """T_em by seed 000 eq. 6, N/V."""
    x = run.displacement_m if displacement_m is None else displacement_m
    return (stiffness_n_per_m * x - run.force_n) / run.back_emf_v


def _swap_decision(runs, gauge_scale, displacement_scale, calibrations_m_per_v, gauge_tolerance):
    """:func:`table1_swap_decision` on runs already read by :func:`_read_table`."""
    r_out = [r for r in runs if r.config == "R_out"]
    out = []
    for r in r_out:
        cal = calibrations_m_per_v[r.serial]
        x_printed = r.gauge_v * cal
        x_swapped = r.displacement_printed * gauge_scale * cal
        d_printed = _gauge_disagreement(r.gauge_v, r.displacement_m, cal) if r.displacement_m else np.inf
        d_swapped = (_gauge_disagreement(r.displacement_printed * gauge_scale, r.gauge_printed * displacement_scale,
                                         cal) if r.gauge_printed else np.inf)
        others = [o.back_emf_v / (o.gauge_v * calibrations_m_per_v[o.serial]) for o in r_out
                  if o.serial == r.serial and o is not r and o.gauge_v != 0.0]
        k_others = float(np.mean(others)) if others else np.nan
        k_printed = r.back_emf_v / x_printed if x_printed else np.inf
        k_swapped = r.back_emf_v / x_swapped if x_swapped else np.inf
        closer = bool(np.isfinite(k_others) and abs(k_swapped / k_others - 1.0) < abs(k_printed / k_others - 1.0))
        swap = bool(d_printed > gauge_tolerance and d_swapped <= gauge_tolerance and closer)
        out.append({"serial": r.serial, "run": r.run, "swap": swap,
                    "gauge_disagreement_printed": float(d_printed), "gauge_disagreement_swapped": float(d_swapped),
                    "v_per_x_printed_v_per_m": float(k_printed), "v_per_x_swapped_v_per_m": float(k_swapped),
                    "v_per_x_others_v_per_m": k_others, "x_gauge_m": float(x_swapped if swap else x_printed),
                    "displacement_m": float(r.gauge_printed * displacement_scale if swap else r.displacement_m),
                    "force_n": r.force_n, "back_emf_v": r.back_emf_v})
    return out


def table1_swap_decision(path=None, *, calibrations_m_per_v=None, gauge_tolerance=0.05):
    """Decide, per ``R_out`` run, whether its printed gauge change and displacement are exchanged.

    The one home of this decision: :func:`identify_transducer` (its swapped-runs T_em),
    :func:`workbench.selfsense.force.run_force_study` (the simulated runs' flag) and
    :func:`workbench.selfsense.table1.table1_held_out` all read it from here.

    Decided from the gauge calibration only, never from the force: a run is read swapped when
    (1) as printed, gauge change x the serial's calibration disagrees with the printed
    displacement by more than ``gauge_tolerance`` while exchanged they agree within it (seed 000
    sec. 3.1), and (2) exchanged, its back EMF per gauge displacement V/x is closer to the mean
    V/x of the same serial's other runs than as printed (the open-lead stack's V/x is a property
    of the stack, C_p / T_em in the model).

    Parameters
    ----------
    path : str or path-like, optional
        Table 1 CSV (:func:`identify_transducer`'s format); default ``DEFAULT_TABLE1_PATH``.
    calibrations_m_per_v : mapping of str to float, optional
        Gauge calibration per serial, m/V; default seed 000 sec. 3.1.
    gauge_tolerance : float, default 0.05
        Largest relative gauge/displacement disagreement read as consistent (the transducer
        check's tolerance).

    Returns
    -------
    list of dict
        One per ``R_out`` run, in file order: ``serial``, ``run``, ``swap`` (bool), and the
        evidence: ``gauge_disagreement_printed`` and ``gauge_disagreement_swapped`` (fractions),
        ``v_per_x_printed_v_per_m``, ``v_per_x_swapped_v_per_m``, ``v_per_x_others_v_per_m``
        (mean over the serial's other runs as printed; NaN if it has none); and the run as decided:
        ``x_gauge_m`` (gauge change x calibration, m), ``displacement_m`` (the displacement
        column, m), ``force_n`` (N), ``back_emf_v`` (V).

    Raises
    ------
    DataFileError
        If the table is malformed (as :func:`identify_transducer`).
    """
    cals = DEFAULT_CALIBRATIONS_M_PER_V if calibrations_m_per_v is None else calibrations_m_per_v
    _check_parameters(2.0e8, cals, gauge_tolerance, 0.2)
    runs, gauge_scale, displacement_scale = _read_table(DEFAULT_TABLE1_PATH if path is None else Path(path), cals)
    return _swap_decision(runs, gauge_scale, displacement_scale, cals, gauge_tolerance)


def identify_transducer(path, *, stiffness_n_per_m=2.0e8, calibrations_m_per_v=None,
                        gauge_tolerance=0.05, stiffness_tolerance=0.20,
                        working_capacitance_f=5.802e-6, hysteretic_capacitance_f=30.5e-6):
    """Identify the transducer constant T_em from Instron load-test runs (seed 000 eq. 6).

    Parameters
    ----------
    path : str or path-like
        CSV with the header ``serial,run,config,gauge_change[V],displacement[um],force[N],
        back_emf[V]`` (any column order, any SI prefix on the units); lines starting with
        ``#`` are comments. ``plants/data/p888_51_instron_table1.csv`` holds seed 000 Table 1.
    stiffness_n_per_m : float, default 2.0e8
        Mechanical stiffness k_p used in eq. 6, N/m (PI spec sheet: 200 N/um).
    calibrations_m_per_v : mapping of str to float, optional
        Gauge calibration per serial, m/V. Default: seed 000 sec. 3.1, 3.077e-6 (SN637),
        3.183e-6 (SN629), 3.246e-6 (SN618). Its keys are the serials the file may contain.
    gauge_tolerance : float, default 0.05
        Largest accepted relative difference between gauge change x calibration and the
        recorded displacement.
    stiffness_tolerance : float, default 0.20
        Largest accepted relative deviation of an ``R_in`` run's F_e / x_pzt from the
        shorted-stack stiffness k_p + T_em^2 / (C_p + C_h). The seed gives no tolerance;
        +/-20 % is assumed, the tolerance PI quotes for its other stack data (e.g.
        capacitance 6.0 uF +/- 20 %, seed 000 sec. 3.3).
    working_capacitance_f : float, default 5.802e-6
        C_p for the shorted-stack stiffness, F (seed 000 sec. 3.3).
    hysteretic_capacitance_f : float, default 30.5e-6
        Large-signal C_h for the shorted-stack stiffness, F (seed 000 Fig. 7).

    Returns
    -------
    TransducerResult
        T_em over the ``R_out`` runs that passed every check, the flagged runs with reasons,
        the ``R_in`` stiffness, and the alternative means (all runs as printed; SN618 run 3
        with gauge and displacement exchanged; k_p from ``R_in``).

    Raises
    ------
    DataFileError
        If the file is malformed (no header, a missing, repeated or unknown column, a unit
        that is not a prefixed V, m or N, a row with the wrong number of fields, an empty,
        non-numeric or non-finite value, a force beyond ``STIFFNESS_MAX_N_PER_M`` times the
        row's displacement, an unknown serial or configuration, a repeated run),
        or if no ``R_out`` run passes the checks. The message names the file, the line and
        (where there is one) the column, and what is expected.
    TypeError
        If a parameter is not a number, or ``calibrations_m_per_v`` is not a mapping of
        serial strings to numbers.
    ValueError
        If a parameter is not finite and positive.
    OSError
        If the file cannot be opened.

    Notes
    -----
    ``R_out`` runs (leads open): T_em = (k_p x_pzt - F_e) / V_pea per run (eq. 6); a run enters
    the mean unless its gauge check fails or V_pea = 0. ``R_in`` runs (200 ohm across the
    leads, V_pea = 0): eq. 5 reduces to k_p x_pzt = F_e, so F_e / x_pzt is a stiffness
    measurement, compared with k_p; these runs never enter T_em (eq. 6 would be 0/0).
    Compression is negative for F_e and x_pzt.

    With the gauge check, Table 1 gives 46.12 N/V over eight runs (SN618 ``R_out`` run 3 is
    flagged: -1.078 V x 3.246 um/V = -3.499 um against a recorded -0.336 um). The seed's 46.71
    is matched more closely (46.75) by all nine runs with that run's gauge and displacement
    values exchanged. The ``R_in`` runs give about 259 N/um rather than the 200 N/um the seed
    uses in eq. 6.

    References
    ----------
    Seed 000, "Modeling of Piezoceramic Actuators for Control": eqs. 5-6, sec. 3.1 (gauge
    calibration), sec. 3.2 and Table 1 (Instron test).

    Examples
    --------
    >>> result = identify_transducer("plants/data/p888_51_instron_table1.csv")
    >>> round(result.t_em_n_per_v, 2), len(result.runs_used)
    (46.12, 8)
    >>> [(r["serial"], r["run"]) for r in result.runs_flagged if r["config"] == "R_out"]
    [('SN618', 3)]
    >>> round(result.t_em_with_sn618_run3_swapped_n_per_v, 2)
    46.75
    """
    if calibrations_m_per_v is None:
        calibrations_m_per_v = DEFAULT_CALIBRATIONS_M_PER_V
    _check_parameters(stiffness_n_per_m, calibrations_m_per_v, gauge_tolerance,
                      stiffness_tolerance)
    kp = float(stiffness_n_per_m)
    impossible = []                 # force cells a column's unit slip would explain: after the T_em diagnosis
    runs, gauge_scale, displacement_scale = _read_table(path, calibrations_m_per_v, impossible)

    used, flagged, r_in, t_all, t_swapped = [], [], [], [], []
    swapped_runs = {(d["serial"], d["run"]) for d in _swap_decision(runs, gauge_scale, displacement_scale,
                                                                    calibrations_m_per_v, gauge_tolerance) if d["swap"]}
    for run in runs:
        cal = calibrations_m_per_v[run.serial]
        reasons = []
        # Gauge check, every run.
        if run.displacement_m == 0.0:
            reasons.append("recorded displacement is 0 um, so the gauge check (and F/x or "
                           "eq. 6) cannot be evaluated")
        else:
            mismatch = _gauge_disagreement(run.gauge_v, run.displacement_m, cal)
            if mismatch > gauge_tolerance:
                reason = (f"gauge x calibration = {run.gauge_v * cal * 1e6:.3f} um "
                          f"({run.gauge_v:.3f} V x {cal * 1e6:.3f} um/V) disagrees with "
                          f"recorded displacement {run.displacement_m * 1e6:.3f} um by "
                          f"{mismatch * 100:.1f} % (tolerance {gauge_tolerance * 100:.1f} %)")
                gauge_swapped_v = run.displacement_printed * gauge_scale
                displacement_swapped_m = run.gauge_printed * displacement_scale
                if displacement_swapped_m != 0.0:
                    swapped = _gauge_disagreement(gauge_swapped_v, displacement_swapped_m, cal)
                    # R out runs: as table1_swap_decision reads them (gauge and V/x); R in runs have no V/x
                    if swapped <= gauge_tolerance and (run.config != "R_out" or (run.serial, run.run) in swapped_runs):
                        reason += (f"; with the gauge and displacement values exchanged "
                                   f"({gauge_swapped_v:.3f} V x {cal * 1e6:.3f} um/V = "
                                   f"{gauge_swapped_v * cal * 1e6:.3f} um against "
                                   f"{displacement_swapped_m * 1e6:.3f} um) they agree within "
                                   f"{swapped * 100:.1f} %: the two values look swapped")
                reasons.append(reason)

        if run.config == "R_in":
            if run.back_emf_v != 0.0:
                reasons.append(f"back EMF is {run.back_emf_v:.3f} V; an R_in run should read "
                               f"0 V, which the reduction k_p x = F_e assumes")
            if run.displacement_m != 0.0:
                # checked against the shorted-stack stiffness once T_em is known (below)
                r_in.append({"serial": run.serial, "run": run.run,
                             "stiffness_n_per_um": run.force_n / run.displacement_m * 1e-6,
                             "_run": run})
        else:  # R_out
            t_em = None
            if run.back_emf_v == 0.0:
                reasons.append("back EMF is 0 V, so eq. 6 is undefined for this R_out run")
            elif run.displacement_m != 0.0:
                t_em = _eq6(kp, run)
                t_all.append(t_em)
                if (run.serial, run.run) in swapped_runs:
                    t_swapped.append(_eq6(kp, run, run.gauge_printed * displacement_scale))
                else:
                    t_swapped.append(t_em)
            if reasons and t_em is not None:
                reasons.append(f"eq. 6 as recorded would give T_em = {t_em:.2f} N/V")
            if not reasons:
                used.append({"serial": run.serial, "run": run.run, "config": run.config,
                             "t_em_n_per_v": t_em, "_run": run})
        if reasons:
            flagged.append({"serial": run.serial, "run": run.run, "config": run.config,
                            "reason": "; ".join(reasons)})

    if not used:
        summary = "; ".join(f"{f['serial']} run {f['run']} {f['config']}" for f in flagged)
        raise DataFileError(f"{path}: no R_out run passed the checks (flagged: "
                            f"{summary or 'none; the file has no R_out runs'}); T_em cannot be "
                            f"identified. Check the runs, or widen gauge_tolerance")

    t_used = np.array([u["t_em_n_per_v"] for u in used])
    t_em_mean = float(t_used.mean())
    t_em_field = PLANT_FIELDS["electrical"]["transducer_constant_n_per_v"]
    if not t_em_field.lo < t_em_mean <= t_em_field.hi:
        # eq. 6 returns a number for any columns; one no plant file can hold is a table read wrongly
        # (forces in kN labelled N, forces of 0, a sign flipped), not a transducer
        raise DataFileError(f"{path}: eq. 6 over the {len(used)} R_out runs that pass the checks gives T_em = "
                            f"{t_em_mean:.4g} N/V, outside ({t_em_field.lo:g}, {t_em_field.hi:g}] N/V, the range a "
                            f"plant file accepts for transducer_constant_n_per_v (seed 000: 46.71 N/V); check the "
                            f"force, displacement and back_emf columns' units and signs (compression negative) "
                            f"and --stiffness ({kp:g} N/m)")
    if impossible:
        raise impossible[0]
    # after the T_em range (a table in kN labelled N fails there, naming its columns) and the impossible cells
    # (named by their line), before the R_in comparison (which would flag every R_in run, as with --stiffness 200
    # read as N/m)
    _check_stiffness_against_r_in(path, kp, runs)
    k_short = kp + t_em_mean ** 2 / (working_capacitance_f + hysteretic_capacitance_f)
    for rec in r_in:
        run = rec.pop("_run")
        k_run = rec["stiffness_n_per_um"] * 1e6
        deviation = (k_run - k_short) / k_short
        if abs(deviation) > stiffness_tolerance:
            reason = (f"stiffness F/x = {run.force_n:.1f} N / {run.displacement_m * 1e6:.3f} um "
                      f"= {k_run * 1e-6:.1f} N/um deviates from the shorted-stack stiffness "
                      f"k_p + T_em^2/(C_p + C_h) = {k_short * 1e-6:.1f} N/um by {deviation * 100:+.1f} % "
                      f"(tolerance +/-{stiffness_tolerance * 100:.0f} %, assumed as the spec-sheet tolerance)")
            for f in flagged:
                if (f["serial"], f["run"], f["config"]) == (run.serial, run.run, run.config):
                    f["reason"] += "; " + reason
                    break
            else:
                flagged.append({"serial": run.serial, "run": run.run, "config": run.config,
                                "reason": reason})
    stiffness_r_in = float(np.mean([r["stiffness_n_per_um"] for r in r_in])) if r_in else None
    t_em_r_in = (float(np.mean([_eq6(stiffness_r_in * 1e6, u["_run"]) for u in used]))
                 if r_in else None)
    return TransducerResult(
        t_em_n_per_v=t_em_mean,
        stiffness_r_in_model_n_per_um=k_short * 1e-6,
        t_em_std_n_per_v=float(t_used.std(ddof=1)) if t_used.size > 1 else math.nan,
        runs_used=tuple({k: v for k, v in u.items() if k != "_run"} for u in used),
        runs_flagged=tuple(flagged),
        stiffness_from_r_in_n_per_um=stiffness_r_in,
        r_in_runs=tuple(r_in),
        t_em_all_runs_as_printed_n_per_v=float(np.mean(t_all)),
        t_em_with_sn618_run3_swapped_n_per_v=float(np.mean(t_swapped)) if swapped_runs else None,
        t_em_with_r_in_stiffness_n_per_v=t_em_r_in,
        stiffness_n_per_m=kp,
        source=str(path),
    )
