"""Tests for workbench.identify.transducer: seed 000 eq. 6 over Table 1."""

import json
from pathlib import Path

import pytest

from workbench.errors import DataFileError, UnitError
from workbench.identify import SEED_T_EM_N_PER_V, identify_transducer

TABLE1 = Path(__file__).resolve().parents[2] / "plants" / "data" / "p888_51_instron_table1.csv"
HEADER = "serial,run,config,gauge_change[V],displacement[um],force[N],back_emf[V]"
# Two rows of Table 1 as printed (SN637 R_out run 1, SN637 R_in run 1).
ROW_OUT = "SN637,1,R_out,-0.415,-1.277,-798.8,11.68"
ROW_IN = "SN637,1,R_in,-0.925,-2.847,-772.2,0.0"


@pytest.fixture(scope="module")
def table1():
    return identify_transducer(TABLE1)


def _write(tmp_path, *lines):
    path = tmp_path / "runs.csv"
    path.write_text("\n".join(("# test file",) + lines) + "\n", encoding="utf-8")
    return path


def test_table1_has_all_18_runs(table1):
    runs = table1.runs_used + table1.runs_flagged
    keys = {(r["serial"], r["run"], r["config"]) for r in runs}
    # every R_out run is used or flagged; every R_in run has a stiffness
    assert len([k for k in keys if k[2] == "R_out"]) == 9
    assert len(table1.r_in_runs) == 9


def test_t_em_within_1_5_percent_of_seed(table1):
    assert table1.seed_t_em_n_per_v == SEED_T_EM_N_PER_V == 46.71
    assert table1.t_em_n_per_v == pytest.approx(46.71, rel=0.015)
    # and it is not the seed's number exactly: the mean of the eight used runs is 46.12 N/V
    assert table1.t_em_n_per_v == pytest.approx(46.1248, abs=1e-3)


def test_only_sn618_run3_r_out_is_flagged(table1):
    flagged_out = [r for r in table1.runs_flagged if r["config"] == "R_out"]
    assert [(r["serial"], r["run"]) for r in flagged_out] == [("SN618", 3)]
    reason = flagged_out[0]["reason"]
    assert "gauge x calibration = -3.499 um" in reason
    assert "recorded displacement -0.336 um" in reason
    assert "look swapped" in reason
    assert len(table1.runs_used) == 8
    assert all(r["config"] == "R_out" for r in table1.runs_used)


def test_used_runs_give_plausible_t_em(table1):
    for run in table1.runs_used:
        assert 40.0 < run["t_em_n_per_v"] < 55.0, run


def test_eq6_by_hand_for_one_run(table1):
    # SN637 R_out run 1: (200 N/um x -1.277 um - (-798.8 N)) / 11.68 V
    by_hand = (200.0 * -1.277 + 798.8) / 11.68
    run = next(r for r in table1.runs_used if (r["serial"], r["run"]) == ("SN637", 1))
    assert run["t_em_n_per_v"] == pytest.approx(by_hand, rel=1e-12)


def test_stiffness_from_r_in_is_computed_from_the_data(tmp_path, table1):
    # Independent check on two rows of Table 1 (SN637 R_in run 1, SN618 R_in run 3).
    k_637_1 = -772.2 / -2.847
    k_618_3 = -809.8 / -3.005
    two = identify_transducer(_write(tmp_path, HEADER, ROW_OUT, ROW_IN,
                                     "SN618,3,R_in,-0.926,-3.005,-809.8,0.0"))
    assert two.stiffness_from_r_in_n_per_um == pytest.approx((k_637_1 + k_618_3) / 2, rel=1e-12)
    # The full table: about 259 N/um, not the 200 N/um of the spec sheet the seed uses.
    assert table1.stiffness_from_r_in_n_per_um == pytest.approx(258.63, abs=0.01)
    stiff = {(r["serial"], r["run"]): r["stiffness_n_per_um"] for r in table1.r_in_runs}
    assert stiff[("SN637", 1)] == pytest.approx(k_637_1, rel=1e-12)
    assert stiff[("SN618", 3)] == pytest.approx(k_618_3, rel=1e-12)


def test_r_in_runs_agree_with_the_shorted_stack_not_the_bare_spring(table1):
    # Fig. 3 with the leads shorted: C_h stays in series with C_p, so the stack is stiffer than
    # k_p by T_em^2 / (C_p + C_h). With the identified T_em, 5.802 uF and 30.5 uF:
    k_short = 200.0 + table1.t_em_n_per_v ** 2 / (5.802e-6 + 30.5e-6) * 1e-6
    assert table1.stiffness_r_in_model_n_per_um == pytest.approx(k_short, rel=1e-12)
    # ... which the nine R_in runs bear out within 1 %, where the bare 200 N/um misses by 29 %
    assert table1.stiffness_from_r_in_n_per_um == pytest.approx(k_short, rel=0.01)
    assert table1.stiffness_from_r_in_n_per_um / 200.0 - 1 > 0.25
    flagged_in = [r for r in table1.runs_flagged if r["config"] == "R_in"]
    assert flagged_in == []  # every R_in run within +/-20 % of k_short (226-276 N/um)


def test_r_in_check_flags_a_run_far_from_the_model(tmp_path):
    # a run at 542 N/um (x halved) is about twice the shorted-stack stiffness
    res = identify_transducer(_write(tmp_path, HEADER, ROW_OUT, "SN637,1,R_in,-0.4625,-1.4235,-772.2,0.0"))
    (flag,) = res.runs_flagged
    assert flag["config"] == "R_in" and "542.5 N/um" in flag["reason"] and "+/-20 %" in flag["reason"]


def test_alternative_means(table1):
    # All nine R_out runs as printed: SN618 run 3 gives 63.9 N/V and pulls the mean to 48.10.
    assert table1.t_em_all_runs_as_printed_n_per_v == pytest.approx(48.1036, abs=1e-3)
    # With its gauge and displacement values exchanged (x = -1.078 um): 46.75, within 0.1 %.
    swapped = (200.0 * -1.078 + 844.0) / 12.15
    assert table1.t_em_with_sn618_run3_swapped_n_per_v == pytest.approx(
        (sum(r["t_em_n_per_v"] for r in table1.runs_used) + swapped) / 9, rel=1e-12)
    assert table1.t_em_with_sn618_run3_swapped_n_per_v == pytest.approx(46.71, rel=0.005)
    assert table1.t_em_with_sn618_run3_swapped_n_per_v == pytest.approx(46.71, rel=0.001)
    # The swapped variant reproduces the seed better than the mean over the used runs.
    assert (abs(table1.t_em_with_sn618_run3_swapped_n_per_v - 46.71)
            < abs(table1.t_em_n_per_v - 46.71))
    # With k_p from the R_in runs instead of the spec sheet, T_em drops to about 40 N/V.
    assert table1.t_em_with_r_in_stiffness_n_per_v == pytest.approx(40.34, abs=0.01)


def test_to_json_is_plain_json(table1):
    data = table1.to_json()
    for key in ("t_em_n_per_v", "runs_used", "runs_flagged", "stiffness_from_r_in_n_per_um",
                "seed_t_em_n_per_v", "t_em_all_runs_as_printed_n_per_v",
                "t_em_with_sn618_run3_swapped_n_per_v"):
        assert key in data
    assert json.loads(json.dumps(data, allow_nan=False)) == data


def test_units_are_converted(tmp_path):
    # The same run in mm, kN and mV gives the same T_em.
    path = _write(tmp_path, "serial,run,config,gauge_change[mV],displacement[mm],force[kN],back_emf[V]",
                  "SN637,1,R_out,-415,-0.001277,-0.7988,11.68")
    assert identify_transducer(path).t_em_n_per_v == pytest.approx((200.0 * -1.277 + 798.8) / 11.68)


def test_tolerance_and_stiffness_are_used(tmp_path):
    path = _write(tmp_path, HEADER, ROW_OUT, ROW_IN)
    result = identify_transducer(path, stiffness_n_per_m=2.5e8, stiffness_tolerance=0.1)
    assert result.t_em_n_per_v == pytest.approx((250.0 * -1.277 + 798.8) / 11.68)
    assert not [r for r in result.runs_flagged if r["config"] == "R_in"]


@pytest.mark.parametrize("lines, match", [
    ((HEADER, "SN637,1,R_out,-0.415,nan,-798.8,11.68"),
     r"runs\.csv, line 3, column 5 \(displacement\): 'nan' is not a finite number"),
    ((HEADER, "SN637,1,R_out,-0.415,,-798.8,11.68"),
     r"runs\.csv, line 3, column 5 \(displacement\): empty cell"),
    (("serial,run,config,gauge_change[V],displacement[um],back_emf[V]", ROW_OUT),
     r"runs\.csv, line 2: header lacks column\(s\) force"),
    (("serial,run,config,gauge_change[V],displacement[furlong],force[N],back_emf[V]", ROW_OUT),
     r"runs\.csv, line 2, column 5 \(displacement\[furlong\]\): unknown unit \[furlong\]"),
    ((HEADER, "SN637,1,R_out,-0.415,-1.277,about 800,11.68"),
     r"runs\.csv, line 3, column 6 \(force\): 'about 800' is not a number"),
    ((HEADER, "SN637,1,R_out,-0.415,-1.277,-798.8"),
     r"runs\.csv, line 3: 6 fields, expected 7"),
    ((HEADER, "SN999,1,R_out,-0.415,-1.277,-798.8,11.68"),
     r"runs\.csv, line 3, column 1 \(serial\): unknown serial 'SN999'"),
    ((HEADER, "SN637,1,R_open,-0.415,-1.277,-798.8,11.68"),
     r"runs\.csv, line 3, column 3 \(config\): unknown configuration 'R_open'"),
    ((HEADER, "SN637,0,R_out,-0.415,-1.277,-798.8,11.68"),
     r"runs\.csv, line 3, column 2 \(run\): '0' is not a run number"),
    ((HEADER.replace("force[N]", "force"), ROW_OUT),
     r"runs\.csv, line 2, column 6: column 'force' needs its unit"),
    ((HEADER.replace("force[N]", "forse[N]"), ROW_OUT),
     r"runs\.csv, line 2, column 6: unknown column 'forse'"),
    ((HEADER, ROW_OUT, ROW_OUT),
     r"runs\.csv, line 4: SN637 run 1 R_out repeats line 3"),
    ((HEADER, ROW_IN),
     r"runs\.csv: no R_out run passed the checks"),
])
def test_bad_input_raises_data_file_error(tmp_path, lines, match):
    with pytest.raises(DataFileError, match=match):
        identify_transducer(_write(tmp_path, *lines))


def test_data_file_error_is_a_value_error(tmp_path):
    path = _write(tmp_path, HEADER, "SN637,1,R_out,-0.415,NaN,-798.8,11.68")
    with pytest.raises(ValueError, match=r"line 3"):
        identify_transducer(path)


@pytest.mark.parametrize("kwargs, error, match", [
    ({"stiffness_n_per_m": -2.0e8}, ValueError, r"stiffness_n_per_m must be a finite number > 0"),
    ({"gauge_tolerance": float("nan")}, ValueError, r"gauge_tolerance must be a finite number > 0"),
    ({"stiffness_tolerance": "20 %"}, TypeError, r"stiffness_tolerance must be a number"),
    ({"calibrations_m_per_v": {"SN637": 3.077}}, ValueError, r"is not a gauge calibration in m/V"),
    ({"calibrations_m_per_v": [3.077e-6]}, TypeError, r"calibrations_m_per_v must map serial"),
])
def test_bad_parameters(kwargs, error, match):
    with pytest.raises(error, match=match):
        identify_transducer(TABLE1, **kwargs)


def test_swapped_t_em_follows_the_one_swap_decision(tmp_path, table1):
    """The swapped-runs T_em reads table1_swap_decision, not a named run: SN637 R out run 2 printed with its gauge and
    displacement exchanged is found and read back, so T_em with the swapped runs exchanged is the original table's
    (eq. 6 on the same numbers), while the as-printed mean moves."""
    from workbench.identify.transducer import table1_swap_decision
    lines = []
    for line in TABLE1.read_text().splitlines():
        c = line.split(",")
        if c[:3] == ["SN637", "2", "R_out"]:
            c = c[:3] + [c[4], c[3]] + c[5:]
        lines.append(",".join(c))
    path = tmp_path / "t1.csv"
    path.write_text("\n".join(lines) + "\n")
    assert [(d["serial"], d["run"]) for d in table1_swap_decision(path) if d["swap"]] == [("SN637", 2), ("SN618", 3)]
    edited = identify_transducer(path)
    looks = [(f["serial"], f["run"]) for f in edited.runs_flagged if "look swapped" in f["reason"]]
    assert looks == [("SN637", 2), ("SN618", 3)]
    assert edited.t_em_with_sn618_run3_swapped_n_per_v == pytest.approx(
        table1.t_em_with_sn618_run3_swapped_n_per_v, rel=1e-12)
    assert abs(edited.t_em_all_runs_as_printed_n_per_v / table1.t_em_all_runs_as_printed_n_per_v - 1) > 0.01


def test_a_byte_order_mark_is_skipped(tmp_path):
    """Excel's "CSV UTF-8" starts the file with a BOM: the table reads as without it (as calibrate's records do)."""
    from workbench.identify.transducer import identify_transducer
    src = Path(__file__).resolve().parents[2] / "plants" / "data" / "p888_51_instron_table1.csv"
    bom = tmp_path / "table_bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + src.read_bytes())
    with_bom, without = identify_transducer(bom).to_json(), identify_transducer(src).to_json()
    assert with_bom.pop("source") != without.pop("source")           # the file each came from
    assert with_bom == without


# ---- a force no stack can carry (issue 17: one cell of -1e300 ran, its R_in run only flagged) -----------------

def _table_rows():
    lines = TABLE1.read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("serial,")) + 1
    return lines, start


@pytest.mark.parametrize("glitch", ["-1e300", "1e300", "-5e7", "-1e20"])
def test_an_impossible_force_cell_is_refused_naming_its_line(tmp_path, glitch):
    # every row of Table 1 in turn, R_in and R_out: |F| beyond 1e12 N/m (the stiffest stack a plant file holds)
    # times the row's displacement; the rows' displacements are 0.34-3.5 um, so 5e7 N is beyond every row's bound.
    # A cell the next unit down would make possible (5e7 N: 5e4 N) may meet the T_em diagnosis of the columns'
    # units first (an R_out row); every other is named by its line.
    lines, start = _table_rows()
    for k in range(start, len(lines)):
        cells = lines[k].split(",")
        cells[5] = glitch
        path = tmp_path / f"glitch_{k}.csv"
        path.write_text("\n".join(lines[:k] + [",".join(cells)] + lines[k + 1:]) + "\n", encoding="utf-8")
        cell = rf"line {k + 1}, column 6 \(force\): .*beyond 1e\+12 N/m"
        units = r"eq\. 6 over the \d+ R_out runs .* outside \(0, 10000\] N/V.*units"
        named = cell if glitch != "-5e7" or cells[2] == "R_in" else rf"(?:{cell})|(?:{units})"
        with pytest.raises(DataFileError, match=named):
            identify_transducer(path)


@pytest.mark.parametrize("scale", [1e-2, 1e-1, 10.0, 100.0])
def test_forces_a_load_frame_can_apply_are_never_refused_as_impossible(tmp_path, scale):
    # Table 1's forces x 0.01 .. x 100 (8 N .. 84 kN, past 20 times a P-888.51's ~3.7 kN blocked force): eq. 6
    # may then give a T_em no plant holds (refused as such), or R_in runs a unit slip from --stiffness (x 100: 25,900
    # N/um against k_p's 200; session 32), never the impossible-cell refusal
    lines, start = _table_rows()
    rows = []
    for line in lines[start:]:
        cells = line.split(",")
        cells[5] = f"{float(cells[5]) * scale:.6g}"
        rows.append(",".join(cells))
    path = tmp_path / "scaled.csv"
    path.write_text("\n".join(lines[:start] + rows) + "\n", encoding="utf-8")
    try:
        res = identify_transducer(path)
    except (DataFileError, UnitError) as err:
        assert "|F/x|" not in str(err) and ("eq. 6" in str(err) or "R_in runs" in str(err))
    else:
        assert res.t_em_n_per_v > 0
