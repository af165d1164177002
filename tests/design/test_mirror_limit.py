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


def test_cap_is_the_plants_lowest_zero_not_the_formulas():
    """On a structure the closed form does not describe, ``cap_hz`` still reports the plant's zeros by direction."""
    m = _nominal(FSM)
    wrong = dataclasses.replace(FSM, rocking_freq_x_hz=900.0, rocking_freq_y_hz=150.0)    # formula off the plant
    lim = mirror_angle_limit(wrong, m)
    truth = np.array([FSM.rocking_freq_x_hz, FSM.rocking_freq_y_hz]) * np.sqrt(1 + FSM.inertia_kg_m2
                                                                               / FSM.housing_inertia_kg_m2)
    assert [lim["cap_hz"]["tip"], lim["cap_hz"]["tilt"]] == pytest.approx(truth, rel=1e-6)
    assert lim["closed_form_hz"]["tip"] == pytest.approx(900.0 * np.sqrt(1.1), rel=1e-12)
    assert sorted(lim["zeros_axis"]) == ["tilt", "tip"]


def test_closed_loop_dips_at_the_zero():
    """A notch-only design's |T| reference -> tip angle has its minimum within the plant zero's half-power band
    f_z (1 +/- 2 zeta_z), below -3 dB of its low-frequency value there, and the mirror angle's -3 dB bandwidth
    stays below the zero, on both angles (f_z, zeta_z, T and the bandwidths all from the plant and the design).

    Not asserted: a dip to ~2 zeta_z (0.04): the closed loop's own resonance next to the zero lifts |T| at
    f_z to ~0.3 of its DC value on the committed mirror (README, mirror section)."""
    from workbench.design.mimo import MIMO_SPEC, default_freq_hz, design_mimo
    from workbench.design.mimo_sweep import mirror_bandwidth_hz, mirror_closed_loop
    fam = mirror_family(FSM, branches=("ascending",))
    member = fam[nominal_name()]
    lim = mirror_angle_limit(FSM, member)
    f_z = np.array([lim["cap_hz"]["tip"], lim["cap_hz"]["tilt"]])
    zeta = np.array([lim["zeros_zeta"][list(lim["zeros_axis"]).index(ax)] for ax in ("tip", "tilt")])
    band = [np.linspace(f * (1 - 2 * z), f * (1 + 2 * z), 81) for f, z in zip(f_z, zeta)]
    grid = np.unique(np.concatenate([default_freq_hz(MIMO_SPEC.dt_s, 300)] + band))
    design = design_mimo(FSM, fam, damping=False, freq_hz=grid)
    t = mirror_closed_loop(FSM, member, design, design.loop_out[nominal_name()], MIMO_SPEC.dt_s,
                           MIMO_SPEC.delay_samples)
    bw, _ = mirror_bandwidth_hz(FSM, fam, design, MIMO_SPEC.dt_s, MIMO_SPEC.delay_samples)
    for a in range(2):
        mag = np.abs(t[:, a, a]) / np.abs(t[0, a, a])
        inside = (grid >= band[a][0]) & (grid <= band[a][-1])
        k = np.flatnonzero(inside)[np.argmin(mag[inside])]
        assert inside[k - 1] and inside[k + 1], "the minimum lies on the band's edge: no dip at the zero"
        assert mag[np.abs(grid - f_z[a]).argmin()] < 1 / np.sqrt(2)
        assert 0 < bw[a] < f_z[a]


def test_limit_command_bad_input_exits_2(capsys):
    """A misspelt flag or a missing plant file: one line naming it, exit status 2, no traceback, no sweep."""
    from workbench.design.mimo_sweep import main
    for argv, named in ((["--limt"], "--limt"), (["no_such_mirror.toml", "--limit"], "no_such_mirror.toml")):
        with pytest.raises(SystemExit) as ex:
            main(argv)
        assert ex.value.code == 2
        err = capsys.readouterr().err
        assert named in err and "Traceback" not in err
