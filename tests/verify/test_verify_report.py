"""Verification figures and report: a figure per scenario, every scenario in the report, NaN metrics survive."""

import json

import pytest

from workbench.report.verify_figures import plot_scenario
from workbench.report.verify_report import TITLES, write_verify_report
from workbench.verify.closed_loop import controller_from_json
from workbench.verify.scenarios import run_scenario

# the fast scenarios (a few seconds together); the hold is cut to 20 s
RUNS = (("small_step", {}), ("large_step", {}), ("hold", {"hold_s": 20.0}), ("sine_sweep", {}),
        ("triangle_0p1hz", {}))


@pytest.fixture(scope="module")
def runs(sn637_creep, root):
    ctrl = controller_from_json(json.loads((root / "controllers" / "sn637_loopshape.json").read_text()))
    out = {name: run_scenario(sn637_creep, ctrl, name, **kw) for name, kw in RUNS}
    out["large_step_no_aw"] = run_scenario(sn637_creep, ctrl, "large_step", anti_windup=False)
    return out


@pytest.fixture(scope="module")
def figures(runs, tmp_path_factory):
    folder = tmp_path_factory.mktemp("verify")
    return folder, {name: plot_scenario(*runs[name], folder / f"{name}.png",
                                        companion=runs["large_step_no_aw"] if name == "large_step" else None)
                    for name, _ in RUNS}


def test_every_scenario_has_a_figure(figures):
    _, figs = figures
    for name, _ in RUNS:
        assert figs[name].name == f"{name}.png" and figs[name].stat().st_size > 10_000, name


def test_report_names_every_scenario_and_links_its_figure(runs, figures):
    folder, figs = figures
    results = [{"metrics": runs[name][0], "figure": figs[name].name} for name, _ in RUNS]
    results.append({"metrics": runs["large_step_no_aw"][0], "figure": str(figs["large_step"])})   # absolute path
    m = runs["small_step"][0]
    targets = {"small-step overshoot within 3 points of linear": (m["overshoot_difference_points"], 3.0, "points", True),
               "1 Hz triangle error": (5.7, 0.1, "% of stroke", False)}
    path = write_verify_report(folder / "report.md", {"plant": "sn637_creep", "controller": "sn637_loopshape",
                                                      "controller_form": "fixed", "targets": targets}, results)
    text = path.read_text()
    for name, _ in RUNS:
        assert f"## {TITLES[name]}" in text and f"]({name}.png)" in text, name
    assert "## Large step (anti-windup OFF)" in text and text.count("](large_step.png)") == 2
    assert "1 of 2 targets met" in text and "**MISSED**" in text
    assert "| frequency (Hz) |" in text                                   # the sweep's per-tone table


def test_nan_and_missing_metrics_do_not_crash(runs, tmp_path):
    step = dict(runs["small_step"][0], overshoot_percent=float("nan"), settling_s=float("nan"), final_error_m=None)
    del step["linear_overshoot_percent"]
    sweep = dict(runs["sine_sweep"][0], bandwidth_hz=float("nan"))
    assert plot_scenario(step, runs["small_step"][1], tmp_path / "step.png").stat().st_size > 10_000
    assert plot_scenario(sweep, runs["sine_sweep"][1], tmp_path / "sweep.png").stat().st_size > 10_000
    text = write_verify_report(tmp_path / "r.md", {"plant": "p", "controller": "c", "controller_form": "float",
                                                   "targets": {"drift": (float("nan"), 1.0, "nm", True)}},
                               [{"metrics": step, "figure": "step.png"}, {"metrics": sweep, "figure": None}]).read_text()
    assert "| overshoot | n/a | % |" in text and "**not measured**" in text and "_No figure._" in text
    assert "0 of 1 targets met" in text
