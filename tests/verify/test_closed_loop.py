"""The exported controller in closed loop with the nonlinear plant (issue 5, first part)."""

import json

import pytest

from workbench.verify.closed_loop import controller_from_json
from workbench.verify.scenarios import run_scenario


@pytest.fixture(scope="module")
def ctrl(root):
    return controller_from_json(json.loads((root / "controllers" / "sn637_loopshape.json").read_text()))


def test_small_step_matches_the_linear_prediction(sn637_creep, ctrl):
    # noise off: the step's shape against the nominal sampled loop; the issue allows 3 points
    m, _ = run_scenario(sn637_creep, ctrl, "small_step", noise=False)
    assert abs(m["overshoot_difference_points"]) <= 3.0
    assert abs(m["final_error_m"]) < 1e-9 and m["settling_s"] < 0.05


def test_large_step_anti_windup_prevents_the_limit_cycle(sn637_creep, ctrl):
    with_aw, _ = run_scenario(sn637_creep, ctrl, "large_step", noise=False)
    without, _ = run_scenario(sn637_creep, ctrl, "large_step", noise=False, anti_windup=False)
    # the current limit slews the stack at ~200 V/s; the plain controller winds up and oscillates
    assert without["time_at_current_limit_s"] > 0.1 and without["oscillation_m"] > 1e-6
    assert with_aw["oscillation_m"] < 1e-8 and with_aw["overshoot_percent"] < 1.0
    assert abs(with_aw["final_error_m"]) < 1e-9


def test_slow_triangle_tracks_through_the_hysteresis(sn637_creep, ctrl):
    m, _ = run_scenario(sn637_creep, ctrl, "triangle_0p1hz", noise=False)
    assert m["error_rms_percent_of_stroke"] < 0.1                    # the seed: 0.1 % with gauge feedback
    assert m["hysteresis_open_loop_percent"] > 5 > 0.2 > m["hysteresis_closed_loop_percent"]


def test_force_step_is_rejected(sn637_creep, ctrl):
    m, _ = run_scenario(sn637_creep, ctrl, "force_step", noise=False)
    assert abs(m["final_deviation_m"]) < 1e-9 < abs(m["open_loop_deflection_m"])


def test_unknown_scenario(sn637_creep, ctrl):
    with pytest.raises(ValueError, match="unknown scenario"):
        run_scenario(sn637_creep, ctrl, "cartwheel")
