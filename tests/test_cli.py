"""The command line: every command answers --help, writes --json, and refuses bad input with status 2."""

import json
import subprocess
import sys

import pytest

from workbench.cli import main

COMMANDS = [["gauge"], ["identify"], ["identify", "transducer"], ["freefree"], ["bench"], ["demo"], ["selfsense"], ["calibrate"], ["synth"], ["linearize"],
            ["study"], ["verify"]]


@pytest.mark.parametrize("cmd", COMMANDS)
def test_help(cmd, capsys):
    with pytest.raises(SystemExit) as err:
        main(cmd + ["--help"])
    assert err.value.code == 0
    assert "usage: workbench" in capsys.readouterr().out


def test_gauge_json(tmp_path, root):
    out = tmp_path / "g.json"
    assert main(["gauge", str(root / "plants/p888_51_sn637.toml"), "--x0", "7.5um", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["bridge_v_per_m"] == pytest.approx(354.18, abs=0.01)
    assert {"chain_v_per_m", "bias_v"} <= data.keys()


def test_identify_transducer_json(tmp_path, root):
    out = tmp_path / "t.json"
    assert main(["identify", "transducer", str(root / "plants/data/p888_51_instron_table1.csv"),
                 "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert {"t_em_n_per_v", "runs_used", "runs_flagged", "stiffness_from_r_in_n_per_um"} <= data.keys()
    assert data["t_em_n_per_v"] == pytest.approx(46.71, rel=0.015)
    assert [(f["serial"], f["run"], f["config"]) for f in data["runs_flagged"]] == [("SN618", 3, "R_out")]


def test_freefree_json_and_figure(tmp_path, root):
    out = tmp_path / "ff"
    assert main(["freefree", str(root / "plants/p888_51_sn629.toml"), "--cycles", "1", "--out", str(out),
                 "--json", str(out / "ff.json")]) == 0
    data = json.loads((out / "ff.json").read_text())
    assert (out / "freefree.png").stat().st_size > 10_000
    assert 0.08 < data["hysteresis_x_percent_of_stroke"] / 100 < 0.15


@pytest.mark.parametrize("argv, fragment", [
    (["gauge", "plants/missing.toml"], "plants/missing.toml: no such file"),
    (["gauge", "plants/p888_51_sn637.toml", "--x0", "7.5parsec"], "is not 'm' with an SI prefix"),
    (["freefree", "plants/p888_51_sn637.toml", "--v-peak", "500V"], "--v-peak 500 V: out of range"),
    (["identify", "transducer", "plants/p888_51_sn637.toml"], "p888_51_sn637.toml"),
    (["bench", "--steps", "0"], "must be >= 1"),
    (["linearize", "plants/p888_51_sn637.toml", "--freq-min", "1kHz", "--freq-max", "10Hz"], "must be below"),
    (["linearize", "plants/p888_51_sn637.toml", "--amplitudes", "0V"], "--amplitudes 0 V: out of range"),
    (["verify", "plants/p888_51_sn637.toml", "--controller", "controllers/sn637_loopshape.json", "--form", "hanus"],
     "drop --form hanus"),
    (["verify", "plants/p888_51_sn637.toml", "--controller", "controllers/missing.json"], "missing.json: no such file"),
    (["verify", "plants/p888_51_sn637.toml", "--controller", "controllers/sn637_loopshape.json", "--hold", "5m"],
     "is not 's'"),
    (["linearize", "plants/p888_51_sn637.toml", "--cp-tolerance", "1.5"], "cp-tolerance"),
    (["linearize", "plants/p888_51_sn637.toml", "--bias", "5A"], "is not 'V'"),
    (["linearize", "plants/p888_51_sn637.toml", "--freq-points", "4", "--amplitudes", "1V",
      "--controller", "plants/missing.json"], "missing.json"),
])
def test_bad_input_exits_2_without_traceback(argv, fragment, root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    try:
        code = main(argv)
    except SystemExit as err:   # argparse's own errors
        code = err.code
    err = capsys.readouterr().err
    assert code == 2
    assert fragment in err and "Traceback" not in err


def test_module_entry_point(root):
    done = subprocess.run([sys.executable, "-m", "workbench", "gauge", "plants/p888_51_sn618.toml"],
                          cwd=root, capture_output=True, text=True, check=False)
    assert done.returncode == 0 and "bridge gain" in done.stdout


def test_bench_smoke(tmp_path, root, monkeypatch):
    # a short run of the benchmark's machinery (the figures themselves come from `workbench bench`)
    monkeypatch.chdir(root)
    out = tmp_path / "b.json"
    assert main(["bench", "--steps", "20000", "--reference-steps", "50", "--memory-periods", "0", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["steps_per_second"] > 0 and data["ratio_vs_python_control"] > 0


def test_linearize_json_and_figures(tmp_path, root, monkeypatch):
    # a reduced grid of the full command, with the example controller: every JSON key and figure
    monkeypatch.chdir(root)
    out = tmp_path / "lin"
    assert main(["linearize", "plants/p888_51_sn637.toml", "--serials", "plants/p888_51_sn629.toml",
                 "--amplitudes", "0.1V", "1V", "10V", "--freq-min", "1Hz", "--freq-max", "2kHz",
                 "--freq-points", "6", "--controller", "controllers/example_p250_limit_cycle.json",
                 "--out", str(out), "--json", str(out / "lin.json")]) == 0
    data = json.loads((out / "lin.json").read_text())
    assert {"df", "small_signal", "gauge", "uncertainty", "capacitances", "controller"} <= data.keys()
    assert len(data["df"]) == 3 * 6
    assert {"amplitude_v", "bias_v", "freq_hz", "mag_m_per_v", "phase_deg"} <= data["df"][0].keys()
    assert {"dc_gain_m_per_v", "capacitance_f", "poles_hz"} <= data["small_signal"][0].keys()
    assert data["gauge"]["volts_per_meter"] == pytest.approx(325_000, rel=0.01)
    u = data["uncertainty"]
    assert {"zeros_hz", "poles_hz", "gain"} <= u["weight"].keys() and u["coverage_margin_db"] >= 0
    for name in ("df_bode", "capacitances", "uncertainty", "sampled", "nyquist"):
        assert (out / f"{name}.png").stat().st_size > 10_000


def test_verify_json(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    out = tmp_path / "v.json"
    assert main(["verify", "plants/p888_51_sn637_creep.toml", "--controller", "controllers/sn637_loopshape.json",
                 "--scenario", "hold", "--hold", "5s", "--json", str(out)]) == 0
    m = json.loads(out.read_text())["scenarios"][0]
    assert m["scenario"] == "hold" and abs(m["drift_m"]) < 5e-9 and m["open_loop_creep_m"] > 1e-8


def test_calibrate_prints_an_inconclusive_answer_without_an_agreement(tmp_path, root, capsys, monkeypatch):
    """s22_outsider D: ``inconclusive`` was printed with "(5 of 5 validation folds)", the leading answer's count,
    which reads as an agreement; an inconclusive answer prints its fold winners instead."""
    import workbench.calibrate.run as run
    err = {"rms": 1e-8, "max": 3e-8, "units": "m"}
    data = {"effect": "inconclusive", "channel": "displacement", "agreement": "5 of 5", "error_before": err,
            "error_after": err, "stages": [], "reason": "no answer wins 4 of 5 validation folds",
            "leading": [{"answer": "creep", "folds": 3}, {"answer": "none", "folds": 2}], "candidates": [],
            "base_fit": {"warnings": []}, "elapsed_s": 1.0}
    monkeypatch.setattr(run, "run_calibrate", lambda *a, **k: data)
    rec = tmp_path / "r.csv"
    rec.write_text("time[s],voltage[V],displacement[m]\n" + "".join(f"{k * 1e-3},{k % 50},{k % 50}e-7\n"
                                                                     for k in range(200)))
    assert main(["calibrate", str(rec), "--plant", str(root / "plants/p888_51_sn637.toml")]) == 0
    out = capsys.readouterr().out
    assert "effect inconclusive on the displacement channel (fold winners: creep 3, none 2)" in out
    assert "5 of 5" not in out


def test_whole_process_calibrate_pauses_the_gc_for_its_imports_only(tmp_path, root, monkeypatch):
    """The console command (argv from sys.argv) runs its imports and file checks with the cyclic collector off
    and turns it back on after freezing the imported objects, before any computation (cli._pause_gc_for_imports);
    an in-process main([...]) never touches it."""
    import contextlib
    import gc
    import workbench._malloc
    import workbench.calibrate.run as run
    import workbench.preflight
    monkeypatch.setattr(workbench._malloc, "keep_freed_memory", lambda: True)    # process-wide: not the test's
    monkeypatch.setattr(workbench._malloc, "small_pages", lambda: True)
    seen = {}
    real_preflight = workbench.preflight.preflight

    @contextlib.contextmanager
    def spy(args):
        seen["checks"] = gc.isenabled()
        with real_preflight(args):
            yield

    monkeypatch.setattr(workbench.preflight, "preflight", spy)
    err = {"rms": 1e-8, "max": 3e-8, "units": "m"}
    data = {"effect": "none", "channel": "displacement", "agreement": "5 of 5", "error_before": err,
            "error_after": err, "stages": [], "reason": "r", "candidates": [], "base_fit": {"warnings": []},
            "elapsed_s": 1.0}

    def fake_run(*a, **k):
        seen["run"] = gc.isenabled()
        return data

    monkeypatch.setattr(run, "run_calibrate", fake_run)
    rec = tmp_path / "r.csv"
    rec.write_text("time[s],voltage[V],displacement[m]\n" + "".join(f"{k * 1e-3},{k % 50},{k % 50}e-7\n"
                                                                     for k in range(200)))
    argv = ["calibrate", str(rec), "--plant", str(root / "plants/p888_51_sn637.toml")]
    assert gc.isenabled()
    try:
        assert main(argv) == 0                                   # in-process: left alone
        assert seen == {"checks": True, "run": True}
        seen.clear()
        monkeypatch.setattr(sys, "argv", ["workbench"] + argv)
        assert main() == 0                                       # the console command
        assert seen == {"checks": False, "run": True} and gc.isenabled()
    finally:
        gc.enable()
        gc.unfreeze()
