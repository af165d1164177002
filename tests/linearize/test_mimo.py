"""MIMO linearization of the three-stack mirror (issue 15 item 3): DC gain, two derivations, DF members, modes."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import find_peaks

from workbench.linearize.mimo import (INPUTS, OUTPUTS, df_admittance, gauge_gains, mirror_family, mirror_response,
                                      mirror_small_signal, stack_admittance, structural_modes)
from workbench.linearize.small_signal import BRANCHES, dc_gain_m_per_v, operating_point, small_signal_model
from workbench.plant import load_plant
from workbench.plant.mirror import load_mirror, mirror_run

ROOT = Path(__file__).resolve().parents[2]
FSM = ROOT / "plants" / "fsm_p888_51.toml"
CREEP = ROOT / "plants" / "p888_51_sn637_creep.toml"


@pytest.fixture(scope="module")
def fsm():
    return load_mirror(FSM)


@pytest.fixture(scope="module")
def fsm_creep(fsm):
    """Stack 0 with its creep branches, stack 2 with C_h 15 % larger: the stacks unequal."""
    m = fsm.with_capacitance_scales([1.0, 1.0, 1.15])
    return dataclasses.replace(m, plants=(load_plant(CREEP),) + m.plants[1:])


@pytest.mark.parametrize("bias_v", [20.0, 50.0, 80.0])
def test_dc_gain_is_kinematics_times_stack_gains(fsm_creep, bias_v):
    """DC: x = diag(g_j) V with g_j each stack's static gain on the mirror's static stiffness; q = K x; gauges K_g x."""
    m = fsm_creep
    k_static = 1 / np.diag(m.structure().static_compliance_m_per_n())
    kg = gauge_gains(m)[:, 0]
    for branch in BRANCHES:
        caps = [operating_point(pz, bias_v, branch).capacitance_f for pz in m.stacks]
        dc = mirror_small_signal(m, caps).dcgain()
        g = [dc_gain_m_per_v(dataclasses.replace(pz, stiffness_n_per_m=k, modes=()), c)
             for pz, k, c in zip(m.stacks, k_static, caps)]
        # A holds 1 kHz modes and 1000 s creep (condition ~1e11): dcgain's solve is good to ~1e-6
        assert np.allclose(dc[:3, :3], np.diag(g), rtol=0, atol=1e-5 * max(g))
        assert np.allclose(dc[3:6, :3], m.kinematics @ np.diag(g), rtol=0,
                           atol=1e-5 * np.abs(m.kinematics @ np.diag(g)).max())
        assert np.allclose(dc[9:12, :3], np.diag(kg) @ dc[:3, :3], rtol=0, atol=1e-9 * np.abs(dc[9:12, :3]).max())
        assert np.abs(dc[6:9, :3]).max() < 1e-9     # A/V: no DC current into a capacitor (0.1 A/V at 1 kHz)


def test_state_space_equals_frequency_domain_derivation(fsm_creep):
    """The StateSpace and the direct solve with y_h = c_h + sum C_k/(1 + s tau_k) agree, all 12 x 6 channels."""
    m = fsm_creep
    f = np.geomspace(1e-3, 5e3, 30)
    caps = [operating_point(pz, 50.0, "ascending").capacitance_f for pz in m.stacks]
    ss = mirror_small_signal(m, caps)
    assert list(ss.input_labels) == list(INPUTS) and list(ss.output_labels) == list(OUTPUTS)
    a = np.moveaxis(np.asarray(ss(2j * np.pi * f)), -1, 0)
    b = mirror_response(m, [stack_admittance(pz, c, 2j * np.pi * f) for pz, c in zip(m.stacks, caps)], f)
    scale = np.abs(a).max(axis=(0, 1), keepdims=True)          # per input
    assert np.abs(a - b).max(axis=0).max() < 1e-5 * scale.max() and np.all(np.abs(a - b) <= 1e-5 * scale)


@pytest.mark.parametrize("cap_uf", [9.361, 20.0, 35.0])
def test_df_admittance_recovers_the_stack_admittance(sn637_creep, cap_uf):
    """From the stack's own SISO P(jw) (R, creep, 70 kHz mode, spring k_p) back to y_h(jw)."""
    pz = sn637_creep.pzt
    f = np.geomspace(1e-3, 5e3, 25)
    p = np.asarray(small_signal_model(pz, cap_uf * 1e-6)(2j * np.pi * f))[0, 0]
    got = df_admittance(pz, p, f)
    want = stack_admittance(pz, cap_uf * 1e-6, 2j * np.pi * f)
    assert np.abs(got / want - 1).max() < 1e-6


def test_family_small_amplitude_df_is_the_reversal_member(fsm):
    """At 0.1 V about 50 V only the r = 0 play moves: the DF member (FRD) is the reversal branch (StateSpace)."""
    f = np.array([3.0, 100.0, 400.0, 900.0, 2000.0])
    fam = mirror_family(fsm, df_amplitudes_v=(0.1,), freq_hz=f)
    assert len(fam) == 3 * len(BRANCHES) + 3
    df, ref = fam["DF A=0.1 V, K_g min"], fam["reversal at 50 V, K_g min"]
    a = np.moveaxis(np.asarray(ref(2j * np.pi * f)), -1, 0)
    b = np.moveaxis(df.frdata, -1, 0)
    assert np.abs(b - a).max(axis=(1, 2)).max() < 1e-3 * np.abs(a).max()
    # the gauge extremes bracket the nominal chain
    lo, nom, hi = (fam[f"reversal at 50 V, K_g {k}"].dcgain()[9, 0] for k in ("min", "nom", "max"))
    assert lo < nom < hi


def test_modes_match_the_simulation_with_amplifiers(fsm):
    """Ring-down of the coupled simulation (amplifiers at 0 V, R = 80 ohm) peaks where the MIMO model's |H| does."""
    caps = [operating_point(pz, 0.0, "initial").capacitance_f for pz in fsm.stacks]
    ss = mirror_small_signal(fsm, caps)
    dt, n, n_fft = 25e-6, 16000, 1 << 20
    w = np.zeros((n, 3))
    w[0] = [0.01, 0.01, 0.1]                    # tau_x, tau_y (N m), piston force (N), one sample
    tr = mirror_run(fsm.simulator(dt, 4), np.zeros((n, 3)), external=w)
    assert np.abs(tr.coupled.v_h_v).max() < 0.14                     # only the r = 0 play moves
    fr = np.fft.rfftfreq(n_fft, dt)
    band = (fr > 100) & (fr < 3000)
    h = np.asarray(ss[3:6, 3:6](2j * np.pi * fr[band]))
    found = []
    for ax, y in enumerate((tr.tip_rad, tr.tilt_rad, tr.piston_m)):
        mag_lin = np.zeros(fr.size)
        mag_lin[band] = np.abs(h[ax, ax])
        mag_sim = np.where(band, np.abs(np.fft.rfft(y, n_fft)), 0.0)
        pk_lin, _ = find_peaks(mag_lin, prominence=0.02 * mag_lin.max())
        pk_sim, _ = find_peaks(mag_sim, prominence=0.02 * mag_sim.max())
        assert pk_sim.size == pk_lin.size and np.abs(fr[pk_sim] - fr[pk_lin]).max() < 0.1
        found += list(fr[pk_sim])
    fn, _ = structural_modes(fsm, "amplifier", caps)
    assert np.abs(np.sort(found) / fn - 1).max() < 3e-3
    # and the amplifier case is told apart from open leads by more than the tolerance above
    f_open, _ = structural_modes(fsm, "open", caps)
    assert np.abs(f_open / fn - 1).max() > 1e-3


def test_family_large_amplitude_df_between_the_branches(fsm):
    """At 5 V about 50 V more plays move: each stack's gain lies between its reversal slope (only r = 0) and the
    virgin slope (every play), at every frequency, with the stacks' C_h unequal."""
    m = fsm.with_capacitance_scales([1.0, 0.85, 1.15])
    f = np.array([0.3, 1.0, 3.0])
    fam = mirror_family(m, df_amplitudes_v=(5.0,), freq_hz=f, branches=("reversal", "initial"))
    df = np.abs(np.diagonal(fam["DF A=5 V, K_g nom"].frdata[:3, :3], axis1=0, axis2=1))
    lo, hi = (np.abs(np.diagonal(np.asarray(fam[f"{b} at 50 V, K_g nom"](2j * np.pi * f))[:3, :3], axis1=0, axis2=1))
              for b in ("reversal", "initial"))
    assert df.shape == (3, 3) and np.all(lo < df) and np.all(df < hi)
    assert np.all(df > 1.05 * lo)                      # hysteresis visible at this amplitude
