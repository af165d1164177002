"""The servo-rate sweep of the mirror's MIMO designs (issue 15, item 4: the 2x damping target vs the rate)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from workbench.design import mimo
from workbench.design.mimo_sweep import (mirror_closed_loop, rate_markdown, rate_spec, scaled_mirror,
                                         sensitivity_bandwidth_hz)
from workbench.linearize.limit_cycle import sampled_factor
from workbench.linearize.mimo import mirror_family
from workbench.plant.mirror import load_mirror

ROOT = Path(__file__).resolve().parents[2]
FSM = ROOT / "plants" / "fsm_p888_51.toml"


@pytest.mark.parametrize("rate_hz", [5e3, 10e3, 20e3, 40e3, 33.3e3])
def test_rate_spec_scales_the_chain_and_the_search(rate_hz):
    """dt = 1/rate; the crossover search ends at the same fraction of the rate, same points per decade."""
    base = mimo.MIMO_SPEC
    s = rate_spec(rate_hz)
    assert s.dt_s == pytest.approx(1.0 / rate_hz, rel=1e-15)
    assert s.fc_range_hz[1] * s.dt_s == pytest.approx(base.fc_range_hz[1] * base.dt_s, rel=1e-12)
    assert s.fc_range_hz[1] < 0.45 * rate_hz                      # prewarp below Nyquist
    per_decade = (base.fc_points - 1) / np.log10(base.fc_range_hz[1] / base.fc_range_hz[0])
    got = (s.fc_points - 1) / np.log10(s.fc_range_hz[1] / s.fc_range_hz[0])
    assert got == pytest.approx(per_decade, abs=per_decade / (s.fc_points - 1))
    # everything else is the committed spec
    assert dataclasses.replace(s, dt_s=base.dt_s, fc_range_hz=base.fc_range_hz, fc_points=base.fc_points) == base
    with pytest.raises(ValueError, match="rate_hz"):
        rate_spec(0.0)


def test_crossover_rises_with_the_rate():
    """Modes far above the band: doubling the rate raises the notch-only crossover by more than a grid step.

    The mirror's flexure modes moved to ~3.6 kHz (mass x 0.08, ``scaled_mirror``), out of the
    band at both rates. If dt_s did not reach the chain (hold, averaging gauge, compute delay) the
    crossover would not move. How far it moves depends on the shapes searched: the decoupled plant
    is not flat over the band (the amplifier's R with each stack's capacitance, a first-order lag
    whose phase at the 10 kHz crossover is more than twice the chain's, asserted here from the
    plant and ``sampled_factor``), which a lead can partly buy back; with this reduced grid (lead
    <= 3) it moves 1.3x, with the full grid (lead 6) the sweep's reference mirror 2.07x.
    A reduced shape grid and family keep this lean.
    """
    fsm = scaled_mirror(load_mirror(FSM), 0.08)
    fam = mirror_family(fsm, branches=("ascending",))
    nom = fam[mimo.nominal_name()]
    fc = {}
    for rate in (10e3, 20e3):
        spec = dataclasses.replace(rate_spec(rate), integral_ratios=(0.25,), lead_ratios=(1.0, 3.0),
                                   rolloff_ratios=(4.0,))
        d = mimo.design_mimo(fsm, fam, damping=False, spec=spec)
        fc[rate] = d.summary()["axes"]["tip"]["crossover_hz_min"]["value"]
        assert fc[rate] < 0.2 * d.notches["tip"][0]               # the mode is out of the band
        # the mirror's own angles follow the reference at low frequency: the static map is the
        # kinematics exactly and the nominal member's decoupled DC gain is I (|S| ~ f / f_i at 1 Hz)
        t = mirror_closed_loop(fsm, nom, d, d.loop_out[mimo.nominal_name()], spec.dt_s)
        assert np.max(np.abs(t[0] - np.eye(3))) < 0.03
    step = 10 ** (1 / 15.57)
    assert fc[20e3] / fc[10e3] > step
    dec = mimo.kinematic_decoupler(fsm, nom)
    plant = mimo.decoupled(dec, mimo.damped_gauges(fsm, nom, [fc[10e3]], None))[0, 0, 0]
    chain = sampled_factor(np.array([fc[10e3]]), 1e-4, 1)[0]
    assert np.angle(plant) < 2.0 * np.angle(chain) < 0.0


def test_rate_markdown_judges_the_floors():
    """The table marks a rate met only with the ratio, both loop-at-a-time margins and alpha at their floors."""
    def row(bw_n, bw_d, pm, gm, alpha):
        axes = {a: (bw_n, 100.0, 50.0, 8.0, bw_n / 2) for a in mimo.AXIS_NAMES}
        daxes = {a: (bw_d, 150.0, pm, gm, bw_d / 2) for a in mimo.AXIS_NAMES}
        return {"rate_hz": 20e3, "tip_mode_hz": 1000.0, "delay_limited_crossover_hz": 600.0,
                "designs": {"notch only": {"axes": axes, "alpha_in": 0.5, "alpha_out": 0.5},
                            "IFF damped": {"axes": daxes, "alpha_in": alpha, "alpha_out": alpha}},
                "iff": {"zeta_open": 0.016, "zeta_damped": 0.05}}
    rows = [row(300, 650, 45, 7, 0.5), row(300, 550, 45, 7, 0.5), row(300, 650, 39, 7, 0.5),
            row(300, 650, 45, 5.9, 0.5), row(300, 650, 45, 7, 0.39), row(300, 650, 45, 7, 0.5)]
    d = rows[-1]["designs"]["IFF damped"]["axes"]
    for a in d:                                    # |T| bandwidth 2.17x, |S| bandwidth only 1.5x: missed
        d[a] = d[a][:4] + (225.0,)
    lines = rate_markdown(rows).splitlines()[2:]
    assert [ln.endswith("**met** |") for ln in lines] == [True, False, False, False, False, False]
    assert "| 2.17 | 2.17 |" in lines[0] and "| 1.83 | 1.83 |" in lines[1] and "| 2.17 | 1.50 |" in lines[5]


def test_sensitivity_bandwidth_closed_forms():
    """|S| bandwidth: an integrator loop w_c/s gives exactly f_c; |L| = 1 at -120 deg is never attenuating."""
    f = np.geomspace(1.0, 1e4, 2001)
    fc = np.array([37.0, 310.0, 2200.0])
    integ = np.einsum("fi,ij->fij", fc[None, :] / (1j * f[:, None]), np.eye(3))
    assert sensitivity_bandwidth_hz(f, integ) == pytest.approx(fc, rel=1e-4)
    hover = np.einsum("f,ij->fij", np.full(f.size, np.exp(-2j * np.pi / 3)), np.eye(3))
    assert np.all(sensitivity_bandwidth_hz(f, hover) == f[0])      # |S| = 1 everywhere
