"""The mirror angle's bandwidth cap: plant zeros at the housing's free rocking frequency (issue 15, item 4)."""

import dataclasses
from pathlib import Path

import control
import numpy as np
import pytest

from workbench.design.mimo import nominal_name
from workbench.design.mimo_sweep import limit_markdown, mirror_angle_limit, transmission_zeros
from workbench.linearize.mimo import mirror_family
from workbench.plant.mirror import load_mirror

ROOT = Path(__file__).resolve().parents[2]
FSM = load_mirror(ROOT / "plants" / "fsm_p888_51.toml")


def _nominal(fsm):
    return mirror_family(fsm, branches=("ascending",))[nominal_name()]


# housing inertia x mirror inertia x rocking frequencies over the range a user may bring:
# housing 3x lighter to 30x heavier than the mirror, rocking 80 Hz to 3 kHz (below and above the flexure modes)
CASES = [(3.0e-4, 3.0e-5, 420.0, 520.0),      # the committed file
         (1.0e-5, 3.0e-5, 150.0, 900.0),
         (9.0e-4, 3.0e-5, 80.0, 3000.0),
         (5.0e-5, 1.5e-5, 1800.0, 610.0)]


@pytest.mark.parametrize("i_h, j, fx, fy", CASES)
def test_zeros_at_the_free_housing_frequency(i_h, j, fx, fy):
    """v -> (tip, tilt, piston) transmission zeros = f_rock sqrt(1 + J/I_h) per axis, and no others below 10 kHz."""
    fsm = dataclasses.replace(FSM, housing_inertia_kg_m2=i_h, inertia_kg_m2=j, rocking_freq_x_hz=fx,
                              rocking_freq_y_hz=fy)
    lim = mirror_angle_limit(fsm, _nominal(fsm))
    closed = np.array([fx, fy]) * np.sqrt(1 + j / i_h)
    assert lim["closed_form_hz"]["tip"] == pytest.approx(closed[0], rel=1e-12)
    assert sorted(lim["zeros_hz"]) == pytest.approx(sorted(closed), rel=1e-6)
    assert [lim["cap_hz"]["tip"], lim["cap_hz"]["tilt"]] == pytest.approx(closed, rel=1e-6)
    # lightly damped: |T| at the zero is ~2 zeta_z of its neighbourhood, far below -3 dB
    assert np.all(lim["zeros_zeta"] > 0) and np.all(lim["zeros_zeta"] < 0.05)


def test_committed_mirror_numbers():
    """The plant file's numbers: 420 / 520 Hz locked, J/I_h = 0.1 -> 440.5 / 545.4 Hz."""
    lim = mirror_angle_limit(FSM, _nominal(FSM))
    assert lim["cap_hz"]["tip"] == pytest.approx(420 * np.sqrt(1.1), abs=0.01)
    assert lim["cap_hz"]["tilt"] == pytest.approx(520 * np.sqrt(1.1), abs=0.01)
    text = limit_markdown(FSM, lim, notch_mirror_bw_hz=[431.0, 534.0])
    assert "| tip | 420 | 440.50 | 440.50" in text and text.count("| no |") == 2
    assert "| yes |" in limit_markdown(FSM, lim, notch_mirror_bw_hz=[200.0, 534.0])


@pytest.mark.parametrize("gain", [0.3, 3.0, 30.0])
def test_feedback_does_not_move_the_zeros(gain):
    """Closing the stacks on their gauges (v = r - k g) leaves the reference -> angle zeros where they were."""
    m = _nominal(FSM)
    plant = m[[m.output_labels.index(o) for o in ("g0", "g1", "g2", "tip_rad", "tilt_rad", "piston_m")], :3]
    k = gain * np.diag(1.0 / np.abs(np.diag(control.dcgain(plant)[:3])))   # loop gain ~ `gain` at DC
    k_sys = control.ss([], [], [], np.hstack([k, np.zeros((3, 3))]))
    cl = control.feedback(plant, k_sys, sign=-1)
    cl.input_labels, cl.output_labels = list(m.input_labels[:3]), list(plant.output_labels)
    assert np.all(control.poles(cl).real < 0)
    z_open = transmission_zeros(m, ("v0", "v1", "v2"), ("tip_rad", "tilt_rad", "piston_m"))
    z_cl = transmission_zeros(cl, ("v0", "v1", "v2"), ("tip_rad", "tilt_rad", "piston_m"))
    low = lambda z: sorted(z[np.abs(z) < 2 * np.pi * 1e4], key=lambda c: c.imag)    # conjugates apart
    np.testing.assert_allclose(low(z_cl), low(z_open), rtol=1e-6)


def test_bad_channels():
    m = _nominal(FSM)
    with pytest.raises(ValueError, match="square channel"):
        transmission_zeros(m, ("v0", "v1"), ("tip_rad",))
    with pytest.raises(ValueError, match="unknown channel label"):
        transmission_zeros(m, ("v0",), ("nope",))
