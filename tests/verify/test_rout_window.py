"""The current-limit window with the series resistor out (R = 0): a slew window around the last output.

With R out the current is C dV_t/dt; the exported controller keeps its output within I T / C_max of the last one
(alpha = 1, :func:`workbench.design.antiwindup.current_limit_model`). Closed loop with every stack plant file
R out, the committed loop-shaped cascade re-exported for that plant, steps up and down that the limit slews, on
the flight amplifier and on drawn ones: the window never asks for more charge in a sample than the limit moves, so
the stack reaches each command within its sample (the amplifier slews at its limit inside the sample: it is not
"never at its limit"), the integrator does not wind up (overshoot as with an unlimited amplifier), and without the
window (session 37's export) it does.
"""

from dataclasses import replace

import numpy as np
import pytest

from workbench.controller import Controller
from workbench.plant import load_plant
from workbench.verify import scenarios as S
from workbench.verify.closed_loop import ClosedLoop

from ..conftest import PLANTS, ROOT, reduced_draws

STACK_FILES = ["p888_51_sn637", "p888_51_sn637_creep", "p888_51_sn618", "p888_51_sn629", "p888_51_sn637_on_flexure"]
# steps, m: up and down, from one the limit slews for ~15 ms to one it slews for ~150 ms, and two drawn in between
_rng = np.random.default_rng(3801)
STEPS_M = [5e-6, -5e-6, 0.5e-6, -0.5e-6] + [float(s) for s in _rng.choice([-1, 1], 2) * _rng.uniform(0.3e-6, 6e-6, 2)]


def _amplifier_draw(seed):
    """(file, I_source A, I_sink A, two steps m) from ``default_rng(seed)``: each limit log-uniform in 1-30 mA
    drawn on its own (so either may be the smaller), each step's sign drawn and its size log-uniform in
    0.3-6 um."""
    rng = np.random.default_rng(seed)
    name = str(rng.choice(STACK_FILES))
    i_src, i_snk = (float(v) for v in np.exp(rng.uniform(np.log(1e-3), np.log(30e-3), 2)))
    steps = [float(v) for v in rng.choice([-1.0, 1.0], 2) * np.exp(rng.uniform(np.log(0.3e-6), np.log(6e-6), 2))]
    return pytest.param(name, i_src, i_snk, steps, id=f"seed{seed}")


# the amplifier drawn too (seeds 3802-3810): make test runs three draws, WORKBENCH_FULL=1 all nine
AMPLIFIER_DRAWS = reduced_draws([_amplifier_draw(s) for s in range(3802, 3811)], keep={0, 1, 2})


@pytest.fixture(scope="module")
def design():
    return Controller.load(ROOT / "controllers" / "sn637_loopshape.json").as_lti()


def _c_max_f(pz):
    """Every play and settled creep branch engaged, in series with C_pp (from the file's numbers)."""
    c_h = float(np.sum(pz.hysteresis.weights)) + (0.0 if pz.creep is None else float(np.sum(pz.creep.capacitances_f)))
    return c_h * pz.c_pp_f / (c_h + pz.c_pp_f)


def _step(plant, fw, dx, run_s=0.5):
    cl = ClosedLoop(plant, fw, noise=False, seed=0)
    S._approach(cl, plant.gauge, S.X_START_M, fw.dt_s)
    x1 = S.X_START_M + dx
    r = cl.run(S._to_volts(np.full(int(run_s / fw.dt_s), x1), plant.gauge))
    ov, st = S._step_metrics(r.t_s, r.x_m, S.X_START_M, x1)
    return {"ov": ov, "st": st, "limit_s": r.periods_at_current_limit * fw.dt_s, "u": r.u_v}


def _check_window(design, plant, steps):
    """Closed loop on ``plant`` (R out) with the committed cascade re-exported for it, each step of ``steps``:
    with the window, without it (session 37's export) and on an amplifier without a current limit."""
    pz = plant.pzt
    dt = 1.0 / plant.gauge.modulation_hz
    windowed = Controller.from_lti(design, plant, name="rout")
    alpha, h_up, h_down = windowed.voltage_model
    c_max = _c_max_f(pz)
    assert alpha == 1.0 and windowed.series_resistor_out
    assert h_up == pytest.approx(pz.current_limit_source_a * dt / c_max, rel=1e-12)
    assert h_down == pytest.approx(pz.current_limit_sink_a * dt / c_max, rel=1e-12)
    bare = Controller.from_lti(design, plant, window=False, name="rout").firmware()
    unlimited = replace(plant, pzt=pz.terminal_driven())
    lsb = 2.0 ** -windowed.fixed.output_frac_bits
    # long enough for the window's slew over the step (the stack's stroke per volt at rest, 3x over) and to settle
    v_per_m = 100.0 / S.stroke_m(pz)
    for dx in steps:
        run_s = 0.3 + 3.0 * abs(dx) * v_per_m * c_max / min(pz.current_limit_source_a, pz.current_limit_sink_a)
        w = _step(plant, windowed.firmware(), dx, run_s)
        free = _step(unlimited, bare, dx, run_s)
        off = _step(plant, bare, dx, run_s)
        where = (f"{plant.source} R out, +{pz.current_limit_source_a * 1e3:.3g}/-{pz.current_limit_sink_a * 1e3:.3g} "
                 f"mA, step {dx * 1e6:+.3g} um")
        assert off["limit_s"] >= 1e-3, where                 # the limit binds without the window: 1 ms at least
        # with it the command never asks for more charge in a sample than the limit moves at C_max ...
        du = np.diff(w["u"])
        assert du.max() <= h_up + lsb and -du.min() <= h_down + lsb, where
        assert c_max * du.max() <= pz.current_limit_source_a * dt * (1 + 1e-6), where
        assert -c_max * du.min() <= pz.current_limit_sink_a * dt * (1 + 1e-6), where
        # ... so the stack reaches each command within its sample: no plant step of a servo sample is clipped at
        # the limit (the amplifier still slews at its limit inside the sample: the plant is stepped once a sample
        # here, ClosedLoop's n_sub = 1, so this counts samples that end short of their command)
        assert w["limit_s"] == 0.0, where
        # and the integrator does not wind up: the overshoot is the unlimited amplifier's (within 0.1 point) and
        # the step settles within the run (not sooner than without the window everywhere: at C_max the window
        # slews slower than the stack can at smaller C, so a step may settle later without overshooting)
        assert w["ov"] <= free["ov"] + 0.1, (where, w["ov"], free["ov"])
        assert np.isfinite(w["st"]), where
        if off["ov"] > free["ov"] + 5.0:                       # where the bare loop winds up, the window removes it
            assert w["ov"] < off["ov"] - 5.0, (where, w["ov"], off["ov"])
    return bare


@pytest.mark.parametrize("name", STACK_FILES)
def test_the_slew_window_keeps_the_integrator_from_winding_up(design, name):
    """The flight amplifier (+2/-14 mA) on every stack file, steps of both signs from 0.5 to 6 um."""
    plant = load_plant(PLANTS / f"{name}.toml", overrides={"electrical.series_resistor_in": False})
    bare = _check_window(design, plant, STEPS_M)
    # the upward steps of 0.5 um and more are where it winds up without the window (session 37's export)
    assert _step(plant, bare, 5e-6)["ov"] > 5.0


@pytest.mark.parametrize("name, i_src, i_snk, steps", AMPLIFIER_DRAWS)
def test_the_slew_window_holds_for_a_drawn_amplifier(design, name, i_src, i_snk, steps):
    """The window's headroom is I T / C_max with the amplifier's own limits: drawn 1-30 mA each, either the
    smaller, on a drawn stack file, with drawn steps (sign and size)."""
    plant = load_plant(PLANTS / f"{name}.toml", overrides={"electrical.series_resistor_in": False,
                                                          "electrical.current_limit_source_a": i_src,
                                                          "electrical.current_limit_sink_a": i_snk})
    _check_window(design, plant, steps)


def test_verify_on_a_resistor_out_plant_runs_and_reports_the_window(design, tmp_path):
    """`workbench verify` on an R-out plant: the controller exported for it runs with its slew window and the
    report's form line says so (session 37's said "no current-limit window (anti-windup off)"); a controller
    exported without one (session 37's R-out export) is named in the preflight, and a bare controller gets the
    plant's window."""
    from workbench.controller import NO_WINDOW_TEXT, ControllerMismatchError
    from workbench.errors import ControllerMismatchWarning
    from workbench.verify.run import verify
    plant = load_plant(PLANTS / "p888_51_sn637_creep.toml", overrides={"electrical.series_resistor_in": False})
    ctrl = Controller.from_lti(design, plant, name="rout")
    res = verify(plant, ctrl, ["large_step"], noise=False)
    assert "slew window" in res.form and "anti-windup off" not in res.form
    assert [m for m in res.mismatches if m["check"] == "window"] == []
    m = res.metrics("large_step")
    # no servo sample ends short of its command (verify steps the plant once a sample: this counts samples, and
    # inside each slewing sample the amplifier is at its limit), and no windup
    assert m["time_at_current_limit_s"] == 0.0 and m["overshoot_percent"] < 0.1
    off = res.metrics("large_step_no_anti_windup")                 # the report's companion run winds up
    assert off["overshoot_percent"] > 5.0
    old = Controller.from_lti(design, plant, window=False, name="rout")
    assert any(m["check"] == "window" and NO_WINDOW_TEXT in m["message"] for m in old.compare_plant(plant))
    # verify runs its words with the plant's window and says so, but the firmware built from that file's header
    # has no window and winds up (the companion run above: > 5 %): a preflight WARNING, refused with strict
    with pytest.warns(ControllerMismatchWarning, match="firmware has no current-limit window.*re-export"):
        res = verify(plant, old, ["small_step"], noise=False)
    assert res.controller.window_source == "plant" and "slew window" in res.form
    assert any("has no current-limit window" in n for n in res.notes)
    assert [m["check"] for m in res.mismatches] == ["window"]
    with pytest.raises(ControllerMismatchError, match="--strict.*firmware has no current-limit window"):
        verify(plant, old, ["small_step"], noise=False, strict=True)
    # the same words read from the file it was written to, as `workbench verify` reads them
    path = old.write(tmp_path)["json"]
    with pytest.warns(ControllerMismatchWarning, match="firmware has no current-limit window"):
        verify(plant, path, [], noise=False)
    # with the resistor in, words without a window keep the note only (unchanged)
    plant_in = load_plant(PLANTS / "p888_51_sn637_creep.toml")
    old_in = Controller.from_lti(design, plant_in, window=False, name="rin")
    assert verify(plant_in, old_in, [], noise=False).mismatches == []
    bare = Controller.from_dict({"sample_rate_hz": 1e4, "gain": 0.5, "sos": [[1, 0, 0, 1, -1, 0]]})
    res = verify(plant, bare, ["small_step"], noise=False)
    assert res.controller.window_source == "plant" and "slew window" in res.form
