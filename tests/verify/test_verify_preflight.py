"""Verify's preflight (controller against plant), configurable targets, several scenarios, --seed."""

import argparse
import json

import pytest

from workbench.cli import main
from workbench.controller import Controller
from workbench.plant import load_plant
from workbench.verify.run import (TARGETS, evaluate_targets, load_verify_targets, parse_target, verify)
from workbench.verify.scenarios import run_scenario

from ..conftest import PLANTS, ROOT

CTRL = str(ROOT / "controllers" / "sn637_loopshape.json")


def _plant_20ma(tmp_path):
    text = (PLANTS / "p888_51_sn637_creep.toml").read_text()
    text = text.replace("current_limit_source_a = 2.0e-3", "current_limit_source_a = 20.0e-3")
    text = text.replace("current_limit_sink_a = 14.0e-3", "current_limit_sink_a = 20.0e-3")
    path = tmp_path / "sn637_20ma.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("plant", ["p888_51_sn629.toml", "p888_51_sn618.toml", "20ma"])
def test_strict_refuses_a_controller_exported_for_another_plant(plant, tmp_path, capsys):
    path = _plant_20ma(tmp_path) if plant == "20ma" else PLANTS / plant
    out = tmp_path / "out"
    assert main(["verify", str(path), "--controller", CTRL, "--scenario", "small_step", "--strict",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--strict" in err and "plant_sha256" in err and "Traceback" not in err
    assert ("window" in err) and (plant != "20ma" or "+1.6/-1.6 V" in err)
    assert not out.exists()                                   # refused before any work: nothing written


def test_the_matching_plant_passes_strict_preflight():
    plant = load_plant(PLANTS / "p888_51_sn637_creep.toml")
    assert [p for p in Controller.load(CTRL).compare_plant(plant) if p["check"] != "not recorded"] == []


def test_mismatch_warns_on_stdout_and_in_the_report(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    out = tmp_path / "v"
    assert main(["verify", "plants/p888_51_sn629.toml", "--controller", CTRL, "--scenario", "small_step",
                 "force_step", "--no-noise", "--out", str(out), "--target", "small_step_settling_ratio=4"]) == 0
    text = capsys.readouterr().out
    assert "WARNING preflight plant_sha256" in text and "WARNING preflight gauge_v_per_m" in text
    assert "nan" not in text.lower().replace("nano", "")
    report = (out / "report.md").read_text()
    assert "## Preflight" in report and "mismatch" in report and report.index("## Preflight") < report.index("## Targets")
    data = json.loads((out / "verify.json").read_text())
    assert [m["scenario"] for m in data["scenarios"]] == ["small_step", "force_step"]
    assert data["targets"]["small_step_settling_ratio"]["limit"] == 4.0
    assert {p["check"] for p in data["preflight"]} >= {"plant_sha256", "trim_scale", "window"}


def test_seed_sets_the_noise(sn637_creep):
    fw = Controller.load(CTRL).firmware()
    a = run_scenario(sn637_creep, fw, "small_step", seed=5)[0]
    b = run_scenario(sn637_creep, fw, "small_step", seed=5)[0]
    c = run_scenario(sn637_creep, fw, "small_step", seed=6)[0]
    assert a["overshoot_percent"] == b["overshoot_percent"] and a["final_error_m"] == b["final_error_m"]
    assert a["final_error_m"] != c["final_error_m"]


def test_library_verify_scores_what_it_ran(sn637_creep):
    res = verify(sn637_creep, CTRL, ["small_step"], noise=False, seed=1, targets={"small_step_rise_ratio": 100.0})
    m = res.metrics("small_step")
    assert res.mismatches == [] and res.seed == 1 and set(res.targets) == {
        k for k, t in TARGETS.items() if t.scenario == "small_step"}
    rise = res.targets["small_step_rise_ratio"]
    assert rise["limit"] == 100.0 and rise["value"] == pytest.approx(m["rise_s"] / m["linear_rise_s"])
    assert rise["met"] == (rise["value"] <= 100.0)
    assert 0 < m["linear_rise_s"] < m["linear_settling_s"]          # 10-90 % rise comes before 2 % settling


def test_unmeasurable_targets_say_why():
    runs = [{"scenario": "small_step", "anti_windup": True, "overshoot_difference_points": 1.0,
             "settling_ratio": float("nan"), "settling_ratio_why": "the step did not stay within 2 %",
             "rise_ratio": 1.2},
            {"scenario": "triangle_1hz", "anti_windup": True, "hysteresis_ratio": 1.3},
            {"scenario": "hold", "anti_windup": False, "drift_m": 1.0}]           # not scored: anti-windup off
    t = evaluate_targets(runs, {"small_step_rise_ratio": 1.1})
    assert set(t) == {"small_step_overshoot_points", "small_step_settling_ratio", "small_step_rise_ratio",
                      "triangle_1hz_hysteresis_ratio"}
    assert t["small_step_settling_ratio"]["met"] is False and "2 %" in t["small_step_settling_ratio"]["why"]
    assert t["small_step_rise_ratio"]["met"] is False and t["small_step_overshoot_points"]["met"] is True
    assert t["triangle_1hz_hysteresis_ratio"]["met"] is False       # closed loop worse than open loop


def test_verify_table_and_target_flags(tmp_path):
    study = tmp_path / "s.toml"
    study.write_text("[verify]\nsmall_step_settling_ratio = 3.0\nhold_drift_m = 2e-9\n")
    assert load_verify_targets(study) == {"small_step_settling_ratio": 3.0, "hold_drift_m": 2e-9}
    for body, key in (("[verify]\nsettle = 3.0\n", "verify.settle"), ("[verify]\nhold_drift_m = -1\n", "verify.hold_drift_m"),
                      ("[verify]\nhold_drift_m = '1nm'\n", "verify.hold_drift_m"), ("[other]\nx = 1\n", "verify"),
                      ("verify = 5\n", "verify")):
        study.write_text(body)
        with pytest.raises(Exception, match=rf"s.toml: \[{key}\]"):
            load_verify_targets(study)
    assert parse_target("large_step_overshoot_percent=8") == ("large_step_overshoot_percent", 8.0)
    for bad in ("large_step_overshoot_percent", "nope=3", "hold_drift_m=abc", "hold_drift_m=nan"):
        with pytest.raises(Exception, match="--target"):
            parse_target(bad)


def test_bad_target_flag_exits_2(capsys):
    assert main(["verify", str(PLANTS / "p888_51_sn637_creep.toml"), "--controller", CTRL, "--target", "x=1"]) == 2
    assert "unknown target 'x'" in capsys.readouterr().err


def test_multiple_scenarios_deduplicated_and_checked():
    with pytest.raises(Exception, match="unknown scenario 'wobble'"):
        verify(PLANTS / "p888_51_sn637_creep.toml", CTRL, ["small_step", "wobble"])


def test_a_bare_controller_runs_with_the_plants_window_and_says_so(sn637_creep):
    # an integrator crossing over near 40 Hz: gain 0.5 x the plant's 0.047 V/V x 1e4 / (2 pi)
    bare = Controller.from_dict({"sample_rate_hz": 1e4, "gain": 0.5, "sos": [[1, 0, 0, 1, -1, 0]]})
    assert "no current-limit window (anti-windup off)" in bare.describe()
    res = verify(sn637_creep, bare, ["force_step"], noise=False)
    assert res.controller.window_source == "plant" and "derived from" in res.notes[0]
    assert "current-limit window +0.16/-1.12 V" in res.form and res.mismatches == []
    m = res.metrics("force_step")
    assert abs(m["final_deviation_m"]) < 0.1 * abs(m["open_loop_deflection_m"])   # the integrator holds x


def test_a_study_file_carries_its_verify_table(tmp_path):
    # issue 14: targets in a [verify] table of the study itself; the study accepts the section
    # (it is verify's to read) and verify reads its limits from the same file
    from workbench.preflight import _check_study_file
    from workbench.study.spec import load_study
    text = (ROOT / "studies" / "sn637_servo.toml").read_text()
    copy = tmp_path / "studies" / "s.toml"
    copy.parent.mkdir()
    copy.write_text(text.replace('"../plants/', f'"{PLANTS}/') + "\n[verify]\nsmall_step_settling_ratio = 2.5\n")
    assert load_study(copy).path == copy
    _check_study_file(argparse.Namespace(command="study", study=str(copy), out=str(tmp_path / "out")))
    assert load_verify_targets(copy) == {"small_step_settling_ratio": 2.5}
    copy.write_text(copy.read_text() + "\n[verifyy]\nx = 1\n")          # a misspelt section is still refused
    with pytest.raises(Exception, match="verifyy"):
        load_study(copy)


def test_fail_on_miss_exits_1_on_a_missed_target_and_keeps_the_outputs(tmp_path, capsys, monkeypatch):
    """`verify` exited 0 with MISSED targets (no way to fail a CI job on a miss): with --fail-on-miss a target over
    its limit, or one that could not be measured, is exit status 1, after the JSON is written; all met is 0, and
    without the flag a miss is 0 as before. The runs are replaced by metrics given here (the CLI's decision is
    under test); the scoring is evaluate_targets's."""
    import math
    import workbench.verify.run as vrun
    from workbench.verify.run import missed_targets
    within = {"scenario": "small_step", "overshoot_difference_points": 1.0, "settling_ratio": 1.5, "rise_ratio": 1.0}
    cases = [({**within, "settling_ratio": 2.5}, ["small_step_settling_ratio"]),         # 2.5x over the 2x limit
             ({**within, "rise_ratio": math.nan}, ["small_step_rise_ratio"]),             # not measurable: missed
             (within, [])]
    for metrics, missed in cases:
        targets = evaluate_targets([metrics])
        assert missed_targets(targets) == missed
        summary = {"plant": "p", "controller_name": "c", "controller_form": "f", "seed": 0, "noise": True,
                   "preflight": [], "notes": [], "scenarios": [], "predicted_limit_cycles": [], "targets": targets,
                   "sensors": []}
        monkeypatch.setattr(vrun, "run_verify", lambda *a, **k: summary)
        for flag in ([], ["--fail-on-miss"]):
            out = tmp_path / f"v{len(missed)}{len(flag)}.json"
            code = main(["verify", str(PLANTS / "p888_51_sn637_creep.toml"), "--controller", CTRL,
                         "--scenario", "small_step", "--json", str(out), *flag])
            err = capsys.readouterr().err
            assert code == (1 if (flag and missed) else 0), err
            assert json.loads(out.read_text())["targets"] == targets             # written in every case
            assert ("--fail-on-miss" in err and missed[0] in err) == bool(flag and missed), err
