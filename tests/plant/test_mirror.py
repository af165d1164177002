"""The three-stack tip/tilt/piston mirror (issue 15 item 2): file, kinematics, structure, simulation."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import find_peaks

from workbench.errors import PlantDefinitionError
from workbench.linearize.mimo import mirror_small_signal, structural_modes, terminated_structure
from workbench.linearize.small_signal import operating_point
from workbench.plant.coupled import CoupledSimulator
from workbench.plant.mirror import load_mirror, mirror_run
from workbench.plant.structure import spring

ROOT = Path(__file__).resolve().parents[2]
FSM = ROOT / "plants" / "fsm_p888_51.toml"


@pytest.fixture(scope="module")
def fsm():
    return load_mirror(FSM)


def _draw(fsm, rng, angles=None):
    """A mirror with geometry and mechanics drawn over the range a designer may bring."""
    if angles is None:
        while True:
            angles = rng.uniform(0, 360, 3)
            d = np.abs((angles[:, None] - angles[None, :] + 180) % 360 - 180)
            if d[np.triu_indices(3, 1)].min() > 30:
                break
    return dataclasses.replace(
        fsm, angles_deg=np.asarray(angles, float), radius_m=rng.uniform(0.005, 0.1),
        amplification=rng.uniform(1, 10), mass_kg=rng.uniform(0.01, 2), inertia_kg_m2=rng.uniform(1e-6, 1e-3),
        series_stiffness_n_per_m=10 ** rng.uniform(6, 9), guide_stiffness_n_per_m=10 ** rng.uniform(4, 7),
        housing_inertia_kg_m2=rng.uniform(1e-5, 1e-2), rocking_freq_x_hz=rng.uniform(100, 3000),
        rocking_freq_y_hz=rng.uniform(100, 3000))


# -- kinematics ---------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", range(6))
def test_kinematics_round_trip_and_piston(fsm, seed):
    """K K^-1 = I for any non-collinear layout; equal elongations give pure piston."""
    m = _draw(fsm, np.random.default_rng(seed))
    k, kinv = m.kinematics, m.inverse_kinematics
    assert np.allclose(k @ kinv, np.eye(3), atol=1e-12)
    assert np.allclose(kinv @ k, np.eye(3), atol=1e-12)
    q = k @ np.full(3, 1e-6)
    assert abs(q[0]) < 1e-12 * abs(q[2]) / m.radius_m and abs(q[1]) < 1e-12 * abs(q[2]) / m.radius_m
    assert q[2] == pytest.approx(1e-6 * m.amplification * m.transmission[0], rel=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_kinematics_closed_form_at_120_deg(fsm, seed):
    """Stacks at 90/210/330 deg: tip = a g (x1 - (x2+x3)/2)/(1.5 r), tilt = a g (x2 - x3)/(sqrt 3 r) (z = piston + tip y - tilt x)."""
    m = _draw(fsm, np.random.default_rng(10 + seed), angles=[90.0, 210.0, 330.0])
    x = np.random.default_rng(seed).uniform(-5e-6, 5e-6, 3)
    ag, r = m.amplification * m.transmission[0], m.radius_m
    tip, tilt, piston = m.kinematics @ x
    assert tip == pytest.approx(ag * (x[0] - (x[1] + x[2]) / 2) / (1.5 * r), rel=1e-12)
    assert tilt == pytest.approx(ag * (x[1] - x[2]) / (np.sqrt(3) * r), rel=1e-12)
    assert piston == pytest.approx(ag * x.mean(), rel=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_structure_static_map_is_the_kinematics(fsm, seed):
    """The stacks push mirror and housing apart: at DC the housing stays, x -> q is K exactly."""
    m = _draw(fsm, np.random.default_rng(20 + seed))
    assert m.kinematic_error < 1e-9


@pytest.mark.parametrize("seed", range(4))
def test_piston_mode_closed_form(fsm, seed):
    """Piston does not rock the housing: f = sqrt(3 K_u / (a^2 M)) / 2 pi with K_u = k_s k_p/(k_s+k_p) + a^2 k_g."""
    m = _draw(fsm, np.random.default_rng(30 + seed), angles=[90.0, 210.0, 330.0])
    kp, ks, kg, a = 2e8, m.series_stiffness_n_per_m, m.guide_stiffness_n_per_m, m.amplification
    k_u = ks * kp / (ks + kp) + a * a * kg
    f = np.sqrt(3 * k_u / (a * a * m.mass_kg)) / (2 * np.pi)
    freqs = m.modes()[0]
    assert np.min(np.abs(freqs - f)) < 1e-9 * f


def test_file_modes_in_or_near_the_servo_band(fsm):
    """The plant file's five modes sit between a few hundred Hz and ~1.1 kHz (crossover 60-160 Hz)."""
    f = fsm.modes()[0]
    assert f.size == 5 and 300 < f.min() and f.max() < 1200


# -- the file -----------------------------------------------------------------------------------

@pytest.mark.parametrize("old,new,key", [
    ("radius_m = 0.020", "radius_m = -0.020", "geometry.radius_m"),
    ("radius_m = 0.020", "radius_mm = 20.0", "geometry.radius_mm"),
    ("mass_kg = 0.20 ", "", "mirror.mass_kg"),
    ("damping_ratio = 0.01 ", "damping_ratio = 1.5 ", "flexures.damping_ratio"),
    ('"p888_51_sn618.toml"]', '"p888_51_sn999.toml"]', "stacks.files[2]"),
    ('"p888_51_sn618.toml"]', '"p888_51_sn637_on_flexure.toml"]', "stacks.files[2]"),
    ('"p888_51_sn629.toml", "p888_51_sn618.toml"]', '"p888_51_sn629.toml"]', "stacks.files"),
    ("angles_deg = [90.0, 210.0, 330.0]", "angles_deg = [90.0, 90.0, 330.0]", "stacks.angles_deg"),
    ("rocking_freq_y_hz = 520.0", "rocking_freq_y_hz = \"520 Hz\"", "housing.rocking_freq_y_hz"),
    ("[housing]", "[housings]", "housings"),
    ('schema = "workbench.fsm/1"', 'schema = "workbench.fsm/2"', "schema"),
])
def test_bad_file_names_file_and_key(tmp_path, old, new, key):
    """Every bad value is a PlantDefinitionError naming the file and the key; the input is untouched."""
    text = FSM.read_text()
    assert old in text
    bad = tmp_path / "fsm_bad.toml"
    bad.write_text(text.replace(old, new, 1))
    for f in ("p888_51_sn637.toml", "p888_51_sn629.toml", "p888_51_sn618.toml", "p888_51_sn637_on_flexure.toml"):
        (tmp_path / f).write_text((ROOT / "plants" / f).read_text())
    before = bad.read_text()
    with pytest.raises(PlantDefinitionError) as err:
        load_mirror(bad)
    assert str(bad) in str(err.value) and f"[{key}" in str(err.value)
    assert bad.read_text() == before


def test_missing_file_and_scales(fsm, tmp_path):
    with pytest.raises(PlantDefinitionError, match=r"fsm_none.toml: \[file\]"):
        load_mirror(tmp_path / "fsm_none.toml")
    with pytest.raises(ValueError, match="three positive"):
        fsm.with_capacitance_scales([1.0, -1.0, 1.0])
    m = fsm.with_capacitance_scales([1.0, 2.0, 1.0])
    assert np.allclose(m.stacks[1].hysteresis.weights, 2 * fsm.stacks[1].hysteresis.weights)
    assert np.array_equal(m.stacks[0].hysteresis.weights, fsm.stacks[0].hysteresis.weights)


# -- simulation ---------------------------------------------------------------------------------

def _tip_sine(m, dt):
    """50 V bias (smooth ramp over 1 s), then a 1 Hz tip sine through K^-1 swinging stack 1 by +/-30 V."""
    caps = [operating_point(pz, 50.0, "initial").capacitance_f for pz in m.stacks]
    g = mirror_small_signal(m, caps).dcgain()[0, 0]       # nominal stack gain in the mirror, m/V
    t = np.arange(int(3.0 / dt)) * dt
    ramp = np.where(t < 1, 0.5 - 0.5 * np.cos(np.pi * t), 1.0)
    kinv = m.inverse_kinematics
    tip = 30 * g / kinv[0, 0] * np.sin(2 * np.pi * np.clip(t - 1, 0, None))
    return t, 50 * ramp[:, None] + kinv[:, 0][None, :] * tip[:, None] / g


@pytest.mark.parametrize("scales", [(1.0, 1.0, 1.0), (1.0, 0.85, 1.15), (0.9, 1.1, 1.0), (1.2, 0.8, 0.95)])
def test_tip_command_cross_coupling(fsm, scales):
    """A tip sine through K^-1 moves tip; tilt follows the stacks' own hysteresis, zero if they are equal.

    Prediction: each stack simulated alone on a spring of the mirror's static stiffness at its
    place, mapped through K (the structure's static compliance is diagonal, so quasi-statically the
    stacks are independent). The serial files share one C_h shape, so the draw scales it.
    """
    m = fsm.with_capacitance_scales(scales)
    dt, n_sub = 1e-4, 4
    t, v = _tip_sine(m, dt)
    tr = mirror_run(m.simulator(dt, n_sub), v)
    k_static = 1 / np.diag(m.structure().static_compliance_m_per_n())
    xs = np.column_stack([CoupledSimulator([pz], spring(k), dt, n_sub).run(v[:, j]).x_m[:, 0]
                          for j, (pz, k) in enumerate(zip(m.stacks, k_static))])
    pred = xs @ m.kinematics.T
    last = t >= 2
    tip_ptp = np.ptp(tr.tip_rad[last])
    assert tip_ptp > 1e-3                                               # a ~1.6 mrad swing
    assert np.abs(pred[:, 0] - tr.tip_rad).max() < 1e-3 * tip_ptp
    assert np.abs(pred[:, 1] - tr.tilt_rad).max() < 1e-4 * tip_ptp
    coupling = np.ptp(tr.tilt_rad[last]) / tip_ptp
    if len(set(scales)) == 1:
        assert coupling < 1e-9
    else:
        assert coupling > 1e-3


def _peaks(y, dt, n_fft, band=(100.0, 3000.0)):
    fr = np.fft.rfftfreq(n_fft, dt)
    mag = np.abs(np.fft.rfft(y, n_fft))
    keep = (fr > band[0]) & (fr < band[1])
    pk, _ = find_peaks(mag, prominence=0.02 * mag[keep].max())
    return fr[pk][keep[pk]]


def ring_down(m, terminations, dt=25e-6, n_sub=4, n=16000):
    """Torque about x, about y and a piston force (one-sample impulses, small: V_h < 0.14 V) and the mirror's ringing."""
    w = np.zeros((n, 3))
    w[0] = [0.01, 0.01, 0.1]
    tr = mirror_run(m.simulator(dt, n_sub, terminations), np.zeros((n, 3)), external=w)
    return tr, [tr.tip_rad, tr.tilt_rad, tr.piston_m]


@pytest.mark.parametrize("termination", ["open", "shorted"])
def test_modes_at_the_closed_form_frequencies(fsm, termination):
    """Ring-down peaks of the coupled simulation = the closed-form terminated structure's |H| peaks.

    Shorted is a 1 mohm load; the closed form puts T^2/(C_pp + c_h) at each stack (c_h the r = 0
    play, 9.36 uF), open T^2/C_pp. The two differ by ~20 Hz at 860-1060 Hz; the check is 0.1 Hz.
    """
    caps = [operating_point(pz, 0.0, "initial").capacitance_f for pz in fsm.stacks]
    dt, n_fft = 25e-6, 1 << 20
    tr, ys = ring_down(fsm, [termination if termination == "open" else 1e-3] * 3, dt)
    assert np.abs(tr.coupled.v_h_v).max() < 0.14                      # only the r = 0 play moves
    lin = terminated_structure(fsm, termination, caps)
    fr = np.fft.rfftfreq(n_fft, dt)
    band = (fr > 100) & (fr < 3000)
    h = np.asarray(lin(2j * np.pi * fr[band]))
    found = []
    for ax in range(3):
        mag = np.zeros(fr.size)
        mag[band] = np.abs(h[ax, ax])
        pk, _ = find_peaks(mag, prominence=0.02 * mag.max())
        sim = _peaks(ys[ax], dt, n_fft)
        assert sim.size == pk.size and np.abs(sim - fr[pk]).max() < 0.1
        found += list(sim)
    fn, zeta = structural_modes(fsm, termination, caps)
    # all five modes seen, each within its ringing's peak shift (sqrt(1 - 2 zeta^2), neighbours) of f_n
    assert np.abs(np.sort(found) / fn - 1).max() < 3e-3
