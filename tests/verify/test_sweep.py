"""Sweep runner: the same rows inline, in local processes and on a dask cluster; failures, tables."""

import importlib.util
import math
import multiprocessing
import os
import re
import socket
import sys
import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from workbench.errors import WorkbenchError
from workbench.verify.sweep import Case, SweepError, grid, run_cases, worst, write_table

from .sweep_cases import meet, square

ROOT = Path(__file__).resolve().parents[2]


def _cases(n=6, fail_at=None, sleep_s=0.0):
    """Cases x = 0..n-1; case x sleeps (n - x) * sleep_s, so later cases tend to finish first."""
    return [Case(key={"x": k["x"], "label": f"c{k['x']}"},
                 payload={"x": k["x"], "fail_at": fail_at, "sleep_s": (n - k["x"]) * sleep_s})
            for k in grid(x=list(range(n)))]


class _Unprintable:
    """A cell neither table format can hold: CSV needs str(), Parquet a known type."""

    def __str__(self):
        raise RuntimeError("no text for this cell")


def _without_pid(rows):
    return [{name: value for name, value in row.items() if name != "pid"} for row in rows]


@pytest.fixture(scope="module", autouse=True)
def workers_import_tests():
    """Put the repository on sys.path, which spawned processes inherit, so they can import
    tests.verify.sweep_cases however pytest was started (`python -m pytest` adds it, the
    `pytest` script does not; pytest's importlib mode registers the module only in this process)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(ROOT))
        yield


def _local_cluster(n_workers):
    from distributed import LocalCluster

    # dashboard_address=":0", not None: with None the scheduler's HTTP server still binds 8787 and
    # warns (an error here) when that port is busy: another cluster in this run, or a developer's
    # `dask scheduler`. Port 0 takes a free port and never warns.
    return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=":0")


@pytest.fixture(scope="module")
def dask_address(request, workers_import_tests):
    cluster = _local_cluster(2)
    request.addfinalizer(cluster.close)
    return cluster.scheduler_address


def test_grid_is_the_cartesian_product_first_axis_slowest():
    points = grid(serial=["sn637", "sn629"], amplitude_v=np.array([1.0, 2.0, 3.0]))
    assert points == [{"serial": s, "amplitude_v": a} for s in ("sn637", "sn629") for a in (1.0, 2.0, 3.0)]
    assert all(type(p["amplitude_v"]) is float for p in points)    # numpy scalars became Python floats


@pytest.mark.parametrize("axes, error, match", [
    ({}, ValueError, r"at least one axis"),
    ({"amplitude_v": []}, ValueError, r"axis 'amplitude_v' is empty"),
    ({"serial": "sn637"}, TypeError, r"axis 'serial' must be a sequence.*wrap a single value"),
])
def test_grid_rejects_bad_axes(axes, error, match):
    with pytest.raises(error, match=match):
        grid(**axes)


@pytest.mark.parametrize("key, error, match", [
    ([("x", 1)], TypeError, r"Case.key must be a dict.*got list"),
    ({"ok": 1}, ValueError, r"names must be strings other than \('ok', 'error'\), got 'ok'"),
    ({"x": [1, 2]}, TypeError, r"Case.key\['x'\] must be a str, int or float, got list"),
])
def test_case_rejects_keys_that_cannot_be_columns(key, error, match):
    with pytest.raises(error, match=match):
        Case(key=key, payload=None)


def test_local_processes_give_the_inline_rows_in_case_order():
    cases = _cases(8, sleep_s=0.02)       # two workers finish case 1 before case 0
    inline = run_cases(square, cases, scheduler="inline")
    local = run_cases(square, cases, workers=2)
    assert [row["x"] for row in inline] == list(range(8))
    assert [row["y"] for row in inline] == [x**2 for x in range(8)]
    assert _without_pid(local) == _without_pid(inline)
    assert {row["pid"] for row in inline} == {os.getpid()}
    assert os.getpid() not in {row["pid"] for row in local}


def test_two_workers_run_cases_in_two_processes(tmp_path):
    # each case waits (up to 20 s) until two distinct processes have checked in: one process alone
    # would run the cases one after the other and never meet the second
    payload = {"dir": str(tmp_path), "n": 2, "wait_s": 20.0}
    rows = run_cases(meet, [Case(key={"i": i}, payload=payload) for i in range(2)], workers=2)
    assert [row["met"] for row in rows] == [True, True]
    assert len({row["pid"] for row in rows}) == 2


@pytest.mark.parametrize("scheduler", ["inline", None])
def test_a_failing_case_is_a_row_and_the_others_succeed(scheduler):
    rows = run_cases(square, _cases(5, fail_at=3), scheduler=scheduler)
    assert [row["ok"] for row in rows] == [True, True, True, False, True]
    assert rows[3]["error"].startswith("ValueError: planned failure at x = 3 [sweep_cases.py:")
    assert "y" not in rows[3]
    assert [row["y"] for row in rows if row["ok"]] == [0, 1, 4, 16]
    assert all(row["error"] == "" for row in rows if row["ok"])


def test_dask_cluster_gives_the_inline_rows(dask_address):
    cases = _cases(6, fail_at=2)
    calls = []
    rows = run_cases(square, cases, scheduler=dask_address, progress=lambda *a: calls.append(a))
    assert _without_pid(rows) == _without_pid(run_cases(square, cases, scheduler="inline"))
    assert rows[2]["error"].startswith("ValueError: planned failure at x = 2")
    assert os.getpid() not in {row["pid"] for row in rows if row["ok"]}
    assert calls[-1] == (6, 6) and len(calls) == 6


@pytest.mark.parametrize("where", ["local", "dask"])
def test_a_function_workers_cannot_import_fails_its_rows_not_the_sweep(tmp_path, where, request):
    # registered in this process only: pickling by reference works here, importing it there cannot
    (tmp_path / "sweep_elsewhere.py").write_text("def f(payload):\n    return {'y': payload}\n")
    spec = importlib.util.spec_from_file_location("sweep_elsewhere", tmp_path / "sweep_elsewhere.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sys.modules["sweep_elsewhere"] = module
    request.addfinalizer(lambda: sys.modules.pop("sweep_elsewhere"))
    scheduler = request.getfixturevalue("dask_address") if where == "dask" else None
    cases = [Case(key={"x": x}, payload=x) for x in range(3)]
    assert [row["y"] for row in run_cases(module.f, cases, scheduler="inline")] == [0, 1, 2]
    rows = run_cases(module.f, cases, scheduler=scheduler, timeout_s=60.0)
    assert [row["ok"] for row in rows] == [False] * 3
    assert all(row["error"].startswith("ModuleNotFoundError: No module named 'sweep_elsewhere'; the worker "
                                       "cannot unpickle") for row in rows)


def test_an_unpicklable_payload_fails_its_row_only():
    cases = _cases(3)
    cases[1] = Case(key={"x": 1}, payload={"x": 1, "fail_at": None, "lock": threading.Lock()})
    rows = run_cases(square, cases, workers=1)
    assert [row["ok"] for row in rows] == [True, False, True]
    assert re.match(r"TypeError: cannot pickle '_thread.lock' object.*payload cannot be pickled", rows[1]["error"])


def test_an_unreachable_scheduler_raises_sweep_error_naming_address_and_fix():
    with socket.socket() as sock:          # a port that was free a moment ago: nothing listens there
        sock.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{sock.getsockname()[1]}"
    with pytest.raises(SweepError, match=rf"{address} within 2 s.*`dask scheduler`.*omit --scheduler") as info:
        run_cases(square, _cases(2), scheduler=address, connect_timeout_s=2.0)
    assert isinstance(info.value, WorkbenchError)


def test_a_scheduler_without_workers_raises_sweep_error():
    with _local_cluster(0) as cluster:
        with pytest.raises(SweepError, match=r"has no worker after 1 s.*`dask worker tcp://"):
            run_cases(square, _cases(2), scheduler=cluster.scheduler_address, connect_timeout_s=1.0)


@pytest.mark.parametrize("kwargs, error, match", [
    ({"cases": []}, ValueError, r"no cases"),
    ({"fn": "square"}, ValueError, r"fn must be a function.*got str"),
    ({"scheduler": "localhost:8786"}, ValueError, r"'inline' or a dask scheduler address.*got 'localhost:8786'"),
    ({"scheduler": "tcp://127.0.0.1"}, ValueError, r"dask scheduler address"),
    ({"scheduler": "tcp://127.0.0.1:99999"}, ValueError, r"dask scheduler address"),
    ({"scheduler": "tcp://127.0.0.1:8786", "workers": 2}, ValueError, r"local processes only"),
    ({"workers": 0}, ValueError, r"workers must be a positive integer, got 0"),
    ({"timeout_s": 0}, ValueError, r"timeout_s must be a positive number"),
    ({"cases": [{"x": 1}]}, TypeError, r"cases must be Case instances, got dict"),
    ({"fn": lambda p: {}}, ValueError, r"cannot be sent to worker processes.*scheduler='inline'"),
])
def test_run_cases_rejects_bad_arguments(kwargs, error, match):
    arguments = {"fn": square, "cases": _cases(2), **kwargs}
    with pytest.raises(error, match=match):
        run_cases(arguments.pop("fn"), arguments.pop("cases"), **arguments)


@pytest.mark.parametrize("fn, match", [
    (lambda p: [p], r"TypeError: fn must return a dict of metrics, got list"),
    (lambda p: {"y": [p]}, r"TypeError: metric 'y' must .* got list"),
    (lambda p: {"x": p}, r"ValueError: fn returned metrics named \['x'\]"),
])
def test_malformed_metrics_fail_the_case(fn, match):
    (row,) = run_cases(fn, [Case(key={"x": 1}, payload=1)], scheduler="inline")
    assert row["ok"] is False
    assert re.match(match, row["error"])


def test_a_sweep_past_its_time_limit_marks_the_rest_and_stops_its_processes(tmp_path):
    # the lone case waits for a partner that never comes: only the time limit ends it
    payload = {"dir": str(tmp_path), "n": 2, "wait_s": 60.0}
    others = set(multiprocessing.active_children())    # e.g. a dask cluster of another test in this module
    (row,) = run_cases(meet, [Case(key={"i": 0}, payload=payload)], workers=1, timeout_s=1.5)
    assert row == {"i": 0, "ok": False, "error": "TimeoutError: not finished within timeout_s = 1.5 s"}
    assert set(multiprocessing.active_children()) <= others   # the pool's workers were killed and reaped
    # under heavy load the worker may not even have started the case within 1.5 s: no check-in then
    for checked_in in tmp_path.iterdir():
        with pytest.raises(ProcessLookupError):    # the worker that ran the case was killed and reaped
            os.kill(int(checked_in.name), 0)


def test_worst_picks_among_ok_rows_and_ignores_nan():
    rows = [{"k": 0, "e": 2.0, "ok": True}, {"k": 1, "e": math.nan, "ok": True},
            {"k": 2, "e": 99.0, "ok": False}, {"k": 3, "ok": True}, {"k": 4, "e": 5.0, "ok": True},
            {"k": 5, "e": -1.0, "ok": True}]
    assert worst(rows, "e")["k"] == 4
    assert worst(rows, "e", larger_is_worse=False)["k"] == 5
    assert worst([*rows, {"k": 6, "e": math.inf, "ok": True}], "e")["k"] == 6     # an unstable case is worst
    with pytest.raises(ValueError, match=r"no ok row has a numeric, non-NaN value of 'f' \(6 rows, 5 ok\)"):
        worst(rows, "f")


@pytest.mark.parametrize("suffix, read", [(".csv", pd.read_csv), (".parquet", pd.read_parquet)])
def test_tables_round_trip_and_are_written_whole(tmp_path, suffix, read):
    rows = run_cases(square, _cases(4, fail_at=0), scheduler="inline")   # first row lacks y and pid
    path = write_table(rows, tmp_path / f"sweep{suffix}")
    frame = read(path)
    assert list(frame.columns) == ["x", "label", "ok", "error", "y", "pid"]
    assert frame["x"].tolist() == [0, 1, 2, 3]
    assert frame["ok"].tolist() == [False, True, True, True]
    assert math.isnan(frame["y"][0]) and frame["y"][1:].tolist() == [1, 4, 9]
    assert frame["error"][0].startswith("ValueError: planned failure")
    before = path.read_bytes()
    with pytest.raises((RuntimeError, pa.ArrowException), match=r"no text for this cell|did not recognize"):
        write_table([{"x": _Unprintable()}], path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_write_table_rejects_an_unknown_suffix(tmp_path):
    with pytest.raises(ValueError, match=r"suffix must be one of \('.csv', '.parquet'\), got '.xlsx'"):
        write_table([{"x": 1}], tmp_path / "sweep.xlsx")
    assert not list(tmp_path.iterdir())


def test_progress_is_called_once_per_case_up_to_total():
    calls = []
    run_cases(square, _cases(5), workers=2, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(i, 5) for i in range(1, 6)]


# --- workbench sweep: the study's grid on local processes and on a dask cluster ----------------------

def _sweep_study(tmp_path):
    text = (ROOT / "studies" / "sn637_servo.toml").read_text().replace('"../plants/', f'"{ROOT}/plants/')
    text = re.sub(r'serials = \[.*?\]', "serials = []", text)
    study = tmp_path / "study.toml"
    study.write_text(text)
    return study


@pytest.mark.parametrize("where", ["local", "dask"])
def test_workbench_sweep_runs_the_study_grid_and_names_the_worst_case(tmp_path, where, request):
    from workbench.cli import main
    from workbench.verify.sweep_job import run_sweep
    study = _sweep_study(tmp_path)
    scheduler = request.getfixturevalue("dask_address") if where == "dask" else None
    out = tmp_path / "out"
    controller = ROOT / "controllers" / "sn637_loopshape.json"
    if where == "local":
        # the first case run in this process: the worker process's row must be the same numbers. It also compiles
        # the closed loop here, once, into the kernel cache the two spawned workers load (into an empty cache each
        # compiled it at the same time: ~11 s CPU twice, session 30)
        from workbench.study.spec import load_study
        from workbench.verify.sweep_job import run_case, sweep_cases
        inline = run_case(sweep_cases(load_study(study), controller, [0.3])[0].payload)
    summary = run_sweep(study, controller, out_dir=out, scheduler=scheduler,
                        workers=2 if scheduler is None else None, amplitudes_v=[0.3])
    rows = summary["rows"]
    if where == "local":
        same = {k: rows[0][k] == v or (isinstance(v, float) and math.isnan(v) and math.isnan(rows[0][k]))
                for k, v in inline.items()}
        assert all(same.values()), {k: (rows[0][k], inline[k]) for k, ok in same.items() if not ok}
    # SN637 x C_p (0.8, 1, 1.2) x one amplitude, all run
    assert [(r["cp_factor"], r["amplitude_v"]) for r in rows] == [(0.8, 0.3), (1.0, 0.3), (1.2, 0.3)]
    assert all(r["ok"] for r in rows), [r["error"] for r in rows]
    # a larger working capacitance lowers the loop gain: the crossover falls with C_p
    xo = [r["crossover_hz"] for r in rows]
    assert xo[0] > xo[1] > xo[2] > 0
    assert all(r["phase_margin_deg"] > 45 and r["triangle_error_percent"] < 1.0 for r in rows)
    assert summary["worst"]["crossover_hz"]["cp_factor"] == 1.2
    table = pd.read_csv(out / "sweep.csv")
    assert len(table) == 3 and {"serial", "phase_margin_deg", "step_overshoot_percent"} <= set(table.columns)
    if where == "local":
        # the command line: bad scheduler address -> exit 2 with the reason, nothing written
        bad = tmp_path / "bad"
        assert main(["sweep", str(study), "--amplitudes", "0.3V", "--scheduler", "tcp://127.0.0.1:1",
                     "--out", str(bad)]) == 2
        assert not bad.exists()


def test_sweep_margins_are_the_study_familys_members(root):
    """One definition of the worst member: a sweep case's margins are the study family's describing-function
    members of that serial, C_p and amplitude (K_g min and max), worst of the two, on the same grid."""
    from workbench.design.loopshape import family_loops
    from workbench.design.margins import family_margins
    from workbench.linearize.limit_cycle import load_controller
    from workbench.linearize.uncertainty import FamilySpec, plant_family
    from workbench.plant import load_plant
    from workbench.verify.sweep_job import run_case
    plant_file = root / "plants" / "p888_51_sn629.toml"
    ctrl_file = root / "controllers" / "sn637_loopshape.json"
    grid_hz = (1.0, 4990.0, 30)
    row = run_case({"plant": str(plant_file), "cp_factor": 1.2, "amplitude_v": 0.3, "controller": str(ctrl_file),
                    "bias_v": 50.0, "noise": False, "imbalance_tolerance_ohm": 0.4, "freq_hz": grid_hz})
    assert "DF A=0.3 V" in row["members"] and "small-signal members not swept" in row["members"]
    fam = plant_family([load_plant(plant_file)], FamilySpec(amplitudes_v=(0.3,), freq_hz=tuple(np.geomspace(*grid_hz)),
                                                            small_signal_biases_v=(), imbalance_tolerance_ohm=0.4))
    mine = {n: g for n, g in fam.members.items() if n.startswith("SN629 C_p x1.20, DF A=0.3 V")}
    assert len(mine) == 2
    _, w = family_margins(fam.freq_hz, family_loops(load_controller(ctrl_file), fam.freq_hz, mine))
    assert row["phase_margin_deg"] == pytest.approx(w["phase_margin_deg"]["value"], abs=1e-6)
    assert row["gain_margin_db"] == pytest.approx(w["gain_margin_db"]["value"], abs=1e-6)
    assert row["crossover_hz"] == pytest.approx(w["crossover_hz_min"]["value"], rel=1e-6)


def test_run_sweep_refuses_a_table_suffix_before_running_any_case(tmp_path, monkeypatch):
    """The library checks the table's format first (review 3, item 9): a .txt table used to fail in
    write_table after every case ran. The accepted suffixes are write_table's own."""
    from workbench.paths import FileArgumentError
    from workbench.verify import sweep_job
    from workbench.verify.sweep import TABLE_SUFFIXES, check_table_path

    def no_cases(*a, **k):
        raise AssertionError("a case ran before the table's suffix was checked")
    monkeypatch.setattr(sweep_job, "run_cases", no_cases)
    root = Path(__file__).resolve().parents[2]
    for bad in ("t.txt", "t", "t.xlsx"):
        with pytest.raises(FileArgumentError, match="suffix must be one of .csv, .parquet"):
            sweep_job.run_sweep(root / "studies" / "sn637_servo.toml", table=tmp_path / bad)
    for ok in TABLE_SUFFIXES + (".CSV",):
        check_table_path(tmp_path / f"t{ok}")                 # accepted: no error


def test_the_sweeps_triangle_is_fed_the_exports_lead(root, tmp_path):
    """workbench sweep's 0.1 Hz triangle runs the export's velocity feedforward as verify's triangles do. Noise
    off, a ramp of slope v lags a type-1 loop by v / K_v (a square wave of that height on the triangle: RMS
    v / K_v); the export's lead L = 1/K_v takes it out, so the squared RMS errors differ by (v / K_v)^2 (the
    hysteresis residual in quadrature beside it). v = 2 x span x 0.1 Hz."""
    import json
    from dataclasses import replace
    from workbench.controller import Controller
    from workbench.plant import load_plant
    from workbench.verify.sensors import velocity_constant_per_s
    from workbench.verify.sweep_job import run_case
    plant_file = root / "plants" / "p888_51_sn637_creep.toml"
    plant = load_plant(plant_file)
    c = Controller.load(root / "controllers" / "sn637_loopshape.json", plant=plant).with_sensor("gauge")
    kv = velocity_constant_per_s(c, c.sensor, plant)
    led = replace(c, sensor=replace(c.sensor, ref_lead_s=1.0 / kv))
    rows = {}
    for name, ctrl in (("bare", c), ("led", led)):
        path = ctrl.write(tmp_path / name, "c")["json"]
        assert (json.loads(Path(path).read_text())["sensor"].get("ref_lead_s") is not None) == (name == "led")
        rows[name] = run_case({"plant": str(plant_file), "cp_factor": 1.0, "amplitude_v": 3.0, "controller": str(path),
                               "bias_v": 50.0, "noise": False, "freq_hz": (1.0, 4990.0, 20)})
    v = 2 * rows["bare"]["triangle_span_m"] * 0.1
    e0, e1 = rows["bare"]["triangle_error_rms_m"], rows["led"]["triangle_error_rms_m"]
    assert e1 < e0
    assert e0 ** 2 - e1 ** 2 == pytest.approx((v / kv) ** 2, rel=0.2)
