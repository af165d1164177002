"""The current-limit window with the series resistor out (R = 0): a slew window around the last output.

With R out the current is C dV_t/dt; the exported controller keeps its output within I T / C_max of the last one
(alpha = 1, :func:`workbench.design.antiwindup.current_limit_model`). Closed loop with every stack plant file
R out, the committed loop-shaped cascade re-exported for that plant, steps up and down that the limit slews:
the window never asks for more than the limit moves, the integrator does not wind up (overshoot as with an
unlimited amplifier), and without the window (session 37's export) it does.
"""

from dataclasses import replace

import numpy as np
import pytest

from workbench.controller import Controller
from workbench.plant import load_plant
from workbench.verify import scenarios as S
from workbench.verify.closed_loop import ClosedLoop

from ..conftest import PLANTS, ROOT

STACK_FILES = ["p888_51_sn637", "p888_51_sn637_creep", "p888_51_sn618", "p888_51_sn629", "p888_51_sn637_on_flexure"]
# steps, m: up and down, from one the limit slews for ~15 ms to one it slews for ~150 ms, and two drawn in between
_rng = np.random.default_rng(3801)
STEPS_M = [5e-6, -5e-6, 0.5e-6, -0.5e-6] + [float(s) for s in _rng.choice([-1, 1], 2) * _rng.uniform(0.3e-6, 6e-6, 2)]


@pytest.fixture(scope="module")
def design():
    return Controller.load(ROOT / "controllers" / "sn637_loopshape.json").as_lti()


def _c_max_f(pz):
    """Every play and settled creep branch engaged, in series with C_pp (from the file's numbers)."""
    c_h = float(np.sum(pz.hysteresis.weights)) + (0.0 if pz.creep is None else float(np.sum(pz.creep.capacitances_f)))
    return c_h * pz.c_pp_f / (c_h + pz.c_pp_f)


def _step(plant, fw, dx):
    cl = ClosedLoop(plant, fw, noise=False, seed=0)
    S._approach(cl, plant.gauge, S.X_START_M, fw.dt_s)
    x1 = S.X_START_M + dx
    r = cl.run(S._to_volts(np.full(int(0.5 / fw.dt_s), x1), plant.gauge))
    ov, st = S._step_metrics(r.t_s, r.x_m, S.X_START_M, x1)
    return {"ov": ov, "st": st, "limit_s": r.periods_at_current_limit * fw.dt_s, "u": r.u_v}


@pytest.mark.parametrize("name", STACK_FILES)
def test_the_slew_window_keeps_the_integrator_from_winding_up(design, name):
    plant = load_plant(PLANTS / f"{name}.toml", overrides={"electrical.series_resistor_in": False})
    pz = plant.pzt
    dt = 1.0 / plant.gauge.modulation_hz
    windowed = Controller.from_lti(design, plant, name="rout")
    alpha, h_up, h_down = windowed.voltage_model
    c_max = _c_max_f(pz)
    assert alpha == 1.0
    assert h_up == pytest.approx(pz.current_limit_source_a * dt / c_max, rel=1e-12)
    assert h_down == pytest.approx(pz.current_limit_sink_a * dt / c_max, rel=1e-12)
    bare = Controller.from_lti(design, plant, window=False, name="rout").firmware()
    unlimited = replace(plant, pzt=pz.terminal_driven())
    lsb = 2.0 ** -windowed.fixed.output_frac_bits
    for dx in STEPS_M:
        w = _step(plant, windowed.firmware(), dx)
        free = _step(unlimited, bare, dx)
        off = _step(plant, bare, dx)
        where = f"{name} R out, step {dx * 1e6:+.3g} um"
        assert off["limit_s"] >= 1e-3, where                 # the limit binds without the window: 1 ms at least
        # with it the command never asks for more charge in a sample than the limit moves at C_max ...
        du = np.diff(w["u"])
        assert du.max() <= h_up + lsb and -du.min() <= h_down + lsb, where
        assert c_max * du.max() <= pz.current_limit_source_a * dt * (1 + 1e-6), where
        assert w["limit_s"] == 0.0, where                      # ... so the amplifier never reaches its limit
        # and the integrator does not wind up: the overshoot is the unlimited amplifier's (within 0.1 point)
        assert w["ov"] <= free["ov"] + 0.1, (where, w["ov"], free["ov"])
        if off["ov"] > free["ov"] + 5.0:                       # where the bare loop winds up, the window settles sooner
            assert w["ov"] < off["ov"] - 5.0 and w["st"] < off["st"], (where, w, off)
    # the upward steps of 0.5 um and more are where it winds up without the window (session 37's export)
    assert _step(plant, bare, 5e-6)["ov"] > 5.0


def test_verify_on_a_resistor_out_plant_runs_and_reports_the_window(design, tmp_path):
    """`workbench verify` on an R-out plant: the controller exported for it runs with its slew window and the
    report's form line says so (session 37's said "no current-limit window (anti-windup off)"); a controller
    exported without one (session 37's R-out export) is named in the preflight, and a bare controller gets the
    plant's window."""
    from workbench.controller import NO_WINDOW_TEXT
    from workbench.verify.run import verify
    plant = load_plant(PLANTS / "p888_51_sn637_creep.toml", overrides={"electrical.series_resistor_in": False})
    ctrl = Controller.from_lti(design, plant, name="rout")
    res = verify(plant, ctrl, ["large_step"], noise=False)
    assert "slew window" in res.form and "anti-windup off" not in res.form
    assert [m for m in res.mismatches if m["check"] == "window"] == []
    m = res.metrics("large_step")
    assert m["time_at_current_limit_s"] == 0.0 and m["overshoot_percent"] < 0.1
    off = res.metrics("large_step_no_anti_windup")                 # the report's companion run winds up
    assert off["overshoot_percent"] > 5.0
    old = Controller.from_lti(design, plant, window=False, name="rout")
    assert any(m["check"] == "window" and NO_WINDOW_TEXT in m["message"] for m in old.compare_plant(plant))
    res = verify(plant, old, ["small_step"], noise=False)      # verify runs it with the plant's window and says so
    assert res.controller.window_source == "plant" and "slew window" in res.form
    assert any("has no current-limit window" in n for n in res.notes)
    bare = Controller.from_dict({"sample_rate_hz": 1e4, "gain": 0.5, "sos": [[1, 0, 0, 1, -1, 0]]})
    res = verify(plant, bare, ["small_step"], noise=False)
    assert res.controller.window_source == "plant" and "slew window" in res.form
