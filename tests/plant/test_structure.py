"""M(.) as a structure coupled both ways (issue 15 item 1): special cases, energy, Table 1, mode shift."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from workbench.errors import DataFileError, PlantDefinitionError
from workbench.plant import PZTSimulator, load_plant, play
from workbench.plant.coupled import CoupledSimulator
from workbench.plant.structure import Structure, load_state_space, mode_filter, modal_structure, spring

ROOT = Path(__file__).resolve().parents[2]
SN637 = ROOT / "plants" / "p888_51_sn637.toml"
SN637_CREEP = ROOT / "plants" / "p888_51_sn637_creep.toml"
FLEXURE = ROOT / "plants" / "p888_51_sn637_on_flexure.toml"
TABLE1 = ROOT / "plants" / "data" / "p888_51_instron_table1.csv"


@pytest.fixture(scope="module")
def pz():
    return load_plant(SN637).pzt


# -- special cases: today's kernel ------------------------------------------------------------

@pytest.mark.parametrize("seed,plant", [(0, SN637), (1, SN637), (2, SN637), (3, SN637_CREEP)])
def test_spring_is_todays_kernel(seed, plant):
    """M = 1/k_p: the coupled kernel is today's arithmetic (slews, limits, F_e, creep), to rounding."""
    rng = np.random.default_rng(seed)
    bare = dataclasses.replace(load_plant(plant).pzt, modes=())
    dt = 10 ** rng.uniform(-5, -3)
    n = 4000
    t = np.arange(n) * dt
    v = rng.uniform(0, 60) + rng.uniform(5, 60) * np.sin(2 * np.pi * rng.uniform(0.5, 0.2 / dt) * t)
    f = rng.uniform(-800, 800) * np.sin(2 * np.pi * rng.uniform(0.1, 0.1 / dt) * t)
    ref = PZTSimulator(bare, dt).run(v, f)
    got = CoupledSimulator([bare], spring(bare.stiffness_n_per_m), dt).run(v, f)
    scale = np.abs(ref.x_m).max()
    assert np.abs(got.x_m[:, 0] - ref.x_m).max() <= 1e-9 * scale
    assert np.abs(got.v_t_v[:, 0] - ref.v_t_v).max() <= 1e-9 * np.abs(ref.v_t_v).max()
    assert np.abs(got.q_c[:, 0] - ref.q_c).max() <= 1e-9 * np.abs(ref.q_c).max()


@pytest.mark.parametrize("freq_hz,amp_v", [(20.0, 40.0), (200.0, 5.0), (3.0, 60.0)])
def test_mode_filter_matches_today_below_the_mode(freq_hz, amp_v):
    """Today's 70 kHz mode as a structure gives today's x to a tenth of the gauge noise.

    The coupled mode also feeds eq. 9 (today's filter does not) and is stiffened by it; below the
    mode that differs only in the ringing the slews' corners excite, sub-nanometre.
    """
    p = load_plant(SN637)
    pz = p.pzt
    dt = 1e-5
    t = np.arange(int(2.0 / freq_hz / dt)) * dt
    v = 50 + amp_v * np.sin(2 * np.pi * freq_hz * t)
    ref = PZTSimulator(pz, dt).run(v)
    got = CoupledSimulator([pz], mode_filter(pz.stiffness_n_per_m, pz.modes), dt, n_sub=10).run(v)
    assert np.abs(got.x_m[:, 0] - ref.x_m).max() <= 0.1 * p.gauge.noise_rms_m
    assert np.abs(got.q_c[:, 0] - ref.q_c).max() <= 1e-4 * np.abs(ref.q_c).max()


# -- energy ----------------------------------------------------------------------------------

def _energy_terms(pz, st, v, fe, h):
    tr = CoupledSimulator([pz], st, h).run(v, fe, record_states=True)
    dq = np.diff(np.concatenate([[0.0], tr.q_c[:, 0]]))
    e_in = np.sum(v * dq)                                   # V_pea held over each step: exact
    d_r = np.sum(pz.series_resistance_ohm * dq ** 2 / h)
    vh = tr.v_h_v[:, 0]
    ch = pz.hysteresis
    d_h = e_h = 0.0
    for r, w, z0 in zip(ch.thresholds, ch.weights, ch.initial_states):
        z = np.concatenate([[z0], play(vh, r, z0)])
        d_h += w * r * np.abs(np.diff(z)).sum()             # a play dissipates w r |dz|
        e_h += 0.5 * w * (z[-1] ** 2 - z0 ** 2)              # and stores w z^2 / 2
    e_cp = 0.5 * pz.working_capacitance_f * tr.v_p_v[-1, 0] ** 2
    e_st = st.stored_energy_j(tr.states[-1:], tr.force_n[-1:])[0]
    pw = np.concatenate([[0.0], st.damping_power_w(tr.states)])
    d_d = np.sum(0.5 * (pw[1:] + pw[:-1])) * h
    x = np.concatenate([[0.0], tr.x_m[:, 0]])
    fz = np.concatenate([[0.0], fe])
    w_env = np.sum(0.5 * (fz[1:] + fz[:-1]) * np.diff(x))   # work the environment does on the stack
    return dict(e_in=e_in, d_r=d_r, d_h=d_h, d_d=d_d, stored=e_h + e_cp + e_st, w_env=w_env)


@pytest.mark.parametrize("force_n", [0.0, 20.0])
def test_energy_balance_over_a_cycle(force_n):
    """Electrical work in = R, play and modal-damping losses + stored - environment's work, within 1e-3.

    SN637 on the flexure, 5 V at 2 Hz from rest (plays engage), with and without a 1.5 kHz force
    near the coupled mode (the shunt through R then takes most of its work). The amplifier is
    an ideal source behind R here (limits raised): a current-limited amplifier is not at V_pea.
    """
    fl = load_plant(FLEXURE)
    pz = dataclasses.replace(fl.pzt, current_limit_source_a=10.0, current_limit_sink_a=10.0)
    h = 1e-6
    t = np.arange(int(0.5 / h)) * h
    e = _energy_terms(pz, fl.structure, 5 * np.sin(2 * np.pi * 2 * t), force_n * np.sin(2 * np.pi * 1500 * t), h)
    assert e["d_h"] > 0.3 * e["e_in"]                        # the hysteresis is exercised
    if force_n:
        assert e["d_d"] > 0.05 * e["w_env"] and e["d_r"] > 0.5 * e["w_env"]
    rhs = e["d_r"] + e["d_h"] + e["d_d"] + e["stored"] - e["w_env"]
    assert abs(e["e_in"] - rhs) <= 1e-3 * (abs(e["e_in"]) + abs(e["w_env"]))


# -- Table 1: the Instron runs -----------------------------------------------------------------

def _table1(serial, config):
    rows = [ln.split(",") for ln in TABLE1.read_text().splitlines() if ln.startswith(serial + ",")]
    return [(float(r[4]) * 1e-6, float(r[5]), float(r[6])) for r in rows if r[2] == config]


def _instron(pz, force_n, termination):
    """A force ramp over 2 s (the load frame runs in displacement mode, seed 000 sec. 3.2), then held."""
    dt = 1e-3
    ramp = force_n * np.minimum(np.arange(3000) / 2000.0, 1.0)
    sim = CoupledSimulator([pz], spring(pz.stiffness_n_per_m), dt, terminations=[termination])
    return sim.run(np.zeros_like(ramp), ramp)


def test_instron_open_leads(pz):
    """R_out: ~800 N on open leads gives the closed form and Table 1's ~12 V within 10 % per run."""
    t_em, cp, kp = pz.transducer_constant_n_per_v, pz.working_capacitance_f, pz.stiffness_n_per_m
    for x_tab, f_tab, v_tab in _table1("SN637", "R_out"):
        tr = _instron(pz, f_tab, "open")
        x, vt = tr.x_m[-1, 0], tr.v_t_v[-1, 0]
        x_cf = f_tab / (kp + t_em ** 2 / cp)                # q fixed: open-circuit stiffness
        assert x == pytest.approx(x_cf, rel=1e-9)
        assert vt == pytest.approx(-t_em * x_cf / cp, rel=1e-9)
        assert abs(vt / v_tab - 1) < 0.10
        assert 1.0e-6 < -x < 1.6e-6                          # ~1.3 um; per-run comparison below


@pytest.mark.xfail(strict=True, reason="measured miss: open leads give 1.39-1.45 um where Table 1 shows "
                   "1.27-1.31 um (8.6-10.5 % over; the model's V/x = T_em/C_p is 15 % below the table's)")
def test_instron_open_leads_displacement_per_run(pz):
    for x_tab, f_tab, _ in _table1("SN637", "R_out"):
        assert abs(_instron(pz, f_tab, "open").x_m[-1, 0] / x_tab - 1) < 0.10


def test_instron_load_resistor_closed_form(pz):
    """R_in (200 ohm): the charge bleeds, V_t -> 0, stiffness k_p + T^2/(C_p + C_h secant) at the reached V_h."""
    t_em, cp, kp = pz.transducer_constant_n_per_v, pz.working_capacitance_f, pz.stiffness_n_per_m
    for x_tab, f_tab, _ in _table1("SN637", "R_in"):
        tr = _instron(pz, f_tab, 200.0)
        x, vh, q = tr.x_m[-1, 0], tr.v_h_v[-1, 0], tr.q_c[-1, 0]
        assert abs(tr.v_t_v[-1, 0]) < 1e-9
        c_h = q / vh
        assert x == pytest.approx(f_tab / (kp + t_em ** 2 / (cp + c_h)), rel=1e-6)
        assert 2.0e-6 < -x < 4.0e-6                          # ~3 um; per-run comparison below


@pytest.mark.xfail(strict=True, reason="measured miss: the assumed C_h shape gives 2.49-2.51 um (310 N/um) on "
                   "R_in where Table 1 shows 2.85-3.20 um (~259 N/um); see README 'Structure'")
def test_instron_load_resistor_matches_table1(pz):
    for x_tab, f_tab, _ in _table1("SN637", "R_in"):
        x = _instron(pz, f_tab, 200.0).x_m[-1, 0]
        assert abs(x / x_tab - 1) < 0.10


# -- the mode shift between open and shorted leads ---------------------------------------------

def _ringing_freq_hz(tr):
    v = tr.y[:, 1]
    s = np.sign(v)
    i = np.flatnonzero(s[1:] * s[:-1] < 0)
    tz = tr.t_s[i] + (tr.t_s[i + 1] - tr.t_s[i]) * v[i] / (v[i] - v[i + 1])
    return (tz.size - 1) / 2 / (tz[-1] - tz[0])


@pytest.mark.parametrize("f_hz,share,zeta", [(1200.0, 0.9, 0.01), (310.0, 1.0, 0.03), (4000.0, 0.6, 0.005)])
def test_mode_shift_open_vs_shorted(pz, f_hz, share, zeta):
    """A mode stiffens by T^2/(C_pp + c) with c = 0 (open) or the small-signal C_h (shorted).

    Closed form with C_pp = C_p + T^2 r (r the residual compliance) and c_h = the r = 0 play's
    weight (ringing of a few nm stays inside the first threshold):
    w_d^2 = w^2 + psi^2 T^2 / (m (C_pp + c)) - zeta^2 w^2.
    """
    k = 2.2e8
    w = 2 * np.pi * f_hz
    m = k * 1.0 / (share * w * w)
    st = modal_structure([f_hz], [zeta], [m], [0.0], [1.0], k)
    t_em = pz.transducer_constant_n_per_v
    cpp = pz.working_capacitance_f + t_em ** 2 * st.residual_compliance_m_per_n[0]
    c_h = pz.hysteresis.weights[0]
    h = 1.0 / (f_hz * 800)
    n = int(8 / (f_hz * h) / max(zeta * 40, 1))
    found = {}
    for term, c in (("open", 0.0), (1e-3, c_h)):
        tr = CoupledSimulator([pz], st, h, terminations=[term]).run(np.zeros(n), np.full(n, -0.05))
        assert np.abs(tr.v_h_v).max() < pz.hysteresis.thresholds[1]
        expect = np.sqrt(w * w + t_em ** 2 / (m * (cpp + c)) - (zeta * w) ** 2) / (2 * np.pi)
        found[term] = _ringing_freq_hz(tr)
        assert found[term] == pytest.approx(expect, rel=2e-4)
    assert found["open"] > found[1e-3] > f_hz


# -- plant file ------------------------------------------------------------------------------

def test_flexure_plant_file(tmp_path):
    fl = load_plant(FLEXURE)
    assert fl.structure is not None and fl.pzt.modes == ()
    assert 1.0 / fl.structure.static_compliance_m_per_n()[0, 0] == pytest.approx(2.2e8)
    text = FLEXURE.read_text()
    bad = tmp_path / "soft.toml"
    bad.write_text(text.replace("static_stiffness_n_per_m = 2.2e8", "static_stiffness_n_per_m = 1.5e8"))
    with pytest.raises(PlantDefinitionError, match="structure"):
        load_plant(bad)
    short = tmp_path / "short.toml"
    short.write_text(text.replace("damping_ratios = [0.01, 0.02]", "damping_ratios = [0.01]"))
    with pytest.raises(PlantDefinitionError, match="structure.damping_ratios"):
        load_plant(short)
    both = tmp_path / "both.toml"
    both.write_text(text + "\n[[mechanics.modes]]\nfreq_hz = 70000.0\ndamping_ratio = 0.02\n")
    with pytest.raises(PlantDefinitionError):
        load_plant(both)


@pytest.mark.parametrize("suffix", [".npz", ".mat"])
def test_state_space_file_is_the_modal_model(tmp_path, pz, suffix):
    """A structure read from A, B, C, D runs exactly as the modal model it was written from."""
    import scipy.io

    st = load_plant(FLEXURE).structure
    path = tmp_path / f"flexure{suffix}"
    if suffix == ".npz":
        np.savez(path, A=st.a, B=st.b, C=st.c, D=st.d)
    else:
        scipy.io.savemat(path, {"A": st.a, "B": st.b, "C": st.c, "D": st.d})
    loaded = load_state_space(path)
    t = np.arange(3000) * 1e-5
    v = 40 + 30 * np.sin(2 * np.pi * 50 * t)
    a = CoupledSimulator([pz], st, 1e-5).run(v)
    b = CoupledSimulator([pz], loaded, 1e-5).run(v)
    assert np.array_equal(a.x_m, b.x_m)
    bad = tmp_path / "bad.npz"
    np.savez(bad, A=st.a, B=st.b, C=st.c)
    with pytest.raises(DataFileError, match="missing matrices"):
        load_state_space(bad)


def test_state_space_section_in_a_plant_file(tmp_path):
    st = load_plant(FLEXURE).structure
    np.savez(tmp_path / "m.npz", A=st.a, B=st.b, C=st.c, D=st.d)
    text = FLEXURE.read_text()
    i, j = text.index("\n[structure]\n") + 1, text.index("\n[gauge]\n") + 1
    (tmp_path / "p.toml").write_text(text[:i] + '[structure]\nstate_space_file = "m.npz"\n\n' + text[j:])
    got = load_plant(tmp_path / "p.toml").structure
    assert np.array_equal(got.a, st.a) and got.modal is None


def test_two_stacks_on_one_mode_are_one_stack_on_half_the_mass(pz):
    """Two identical stacks driven alike push one mode with twice the force: one stack on m/2 does the same."""
    f_hz, k = 900.0, 2.2e8
    w = 2 * np.pi * f_hz
    m = k / (0.8 * w * w)                                    # modal mass, kg
    r = 0.2 / k                                              # residual per stack, m/N
    # static stiffness per stack: 1/(r + psi^2/(m w^2)) for the pair (each alone sees the shared mode)
    two = modal_structure([f_hz], [0.02], [m], [[0.0, 0.0]], [[1.0, 1.0]],
                          [1.0 / (r + 1.0 / (m * w * w))] * 2)
    one = modal_structure([f_hz], [0.02], [m / 2], [0.0], [1.0], 1.0 / (r + 2.0 / (m * w * w)))
    assert two.residual_compliance_m_per_n == pytest.approx([r, r], rel=1e-12)
    assert one.residual_compliance_m_per_n == pytest.approx([r], rel=1e-12)
    dt = 2e-5
    t = np.arange(5000) * dt
    v = 40 + 30 * np.sin(2 * np.pi * 30 * t)
    f = 50 * np.sin(2 * np.pi * 700 * t)
    a = CoupledSimulator([pz, pz], two, dt).run(np.column_stack([v, v]), np.column_stack([f, f]))
    b = CoupledSimulator([pz], one, dt).run(v, f)
    for got in (a.x_m[:, 0], a.x_m[:, 1]):
        assert np.abs(got - b.x_m[:, 0]).max() <= 1e-9 * np.abs(b.x_m).max()
    assert np.abs(a.i_a[:, 1] - b.i_a[:, 0]).max() <= 1e-9 * np.abs(b.i_a).max()


def test_an_open_stack_senses_its_neighbour(pz):
    """Stack 2 with open leads on the mode stack 1 drives: its back EMF is -T_em x_2 / C_pp (eq. 9, q = 0)."""
    f_hz, k = 900.0, 2.2e8
    m = 8.0
    st = modal_structure([f_hz], [0.02], [m], [[0.0, 0.0]], [[1.0, -0.5]], [k, k])
    dt = 2e-5
    v = np.full(5000, 30.0)
    tr = CoupledSimulator([pz, pz], st, dt, terminations=["amplifier", "open"]).run(np.column_stack([v, v]))
    r2 = st.residual_compliance_m_per_n[1]
    t_em = pz.transducer_constant_n_per_v
    cpp = pz.working_capacitance_f + t_em ** 2 * r2
    x2_dyn = tr.x_m[:, 1] - r2 * tr.force_n[:, 1]
    assert np.abs(tr.q_c[:, 1]).max() == 0.0
    assert np.abs(tr.x_m[:, 1]).max() > 1e-8                  # the neighbour moves it (psi = -0.5)
    assert np.allclose(tr.v_t_v[:, 1], -t_em * x2_dyn / cpp, rtol=0, atol=1e-3 * np.abs(tr.v_t_v[:, 1]).max())


def test_structure_and_simulator_reject_bad_input(pz):
    st = modal_structure([900.0, 2000.0], [0.02, 0.02], [50.0, 50.0], [[0, 0], [0, 0]], [[1, 1], [1, -1]],
                         [3e8, 3e8])
    with pytest.raises(ValueError, match="diagonal"):
        Structure(st.a, st.b, st.c, st.d + np.pad([[0, 1e-12], [1e-12, 0]], ((0, 2), (0, 0))), 2)
    with pytest.raises(ValueError, match="rates"):
        Structure(st.a, st.b, st.c, st.d + np.pad([[1e-12, 0]], ((2, 1), (0, 0))), 2)
    with pytest.raises(ValueError, match="more compliance"):
        modal_structure([900.0], [0.02], [1.0], [0.0], [1.0], 2e8)   # the mode alone is softer than k_static
    with pytest.raises(ValueError, match="termination"):
        CoupledSimulator([pz], spring(2e8), 1e-5, terminations=["shorted"])
    with pytest.raises(ValueError, match="2 stack"):
        CoupledSimulator([pz], st, 1e-5)
    with pytest.raises(ValueError, match="finite"):
        CoupledSimulator([pz], spring(2e8), 1e-5).run(np.array([0.0, np.nan]))


def test_external_force_at_the_stack_end_is_f_e(pz):
    """With no residual compliance, a force on the structure at the stack's moving end is Fig. 3's F_e."""
    f_hz = 700.0
    w = 2 * np.pi * f_hz
    m = 2.2e8 / w ** 2                                       # all the static compliance in the mode
    st = modal_structure([f_hz], [0.02], [m], [0.0], [1.0], 2.2e8, input_participation=[1.0])
    assert st.residual_compliance_m_per_n[0] == pytest.approx(0.0, abs=1e-20)
    dt = 2e-5
    t = np.arange(4000) * dt
    v = 30 + 20 * np.sin(2 * np.pi * 40 * t)
    f = 200 * np.sin(2 * np.pi * 650 * t)
    a = CoupledSimulator([pz], st, dt).run(v, f)
    b = CoupledSimulator([pz], st, dt).run(v, external_n=f[:, None])
    assert np.abs(a.x_m - b.x_m).max() <= 1e-9 * np.abs(a.x_m).max()
    assert np.abs(a.i_a - b.i_a).max() <= 1e-9 * np.abs(a.i_a).max()


@pytest.mark.parametrize("volts", [-30.0, 20.0, 100.0])
def test_open_leads_with_creep_hold_the_charge(volts):
    """Open leads with charged creep branches (C_h at rest, each branch at C_j times ``volts``): the branches
    discharge into C_h inside the stack, the terminal charge stays put (the coupled kernel moves no charge through
    open leads: to rounding), and V_h follows today's kernel at the Keithley's 2e14 ohm to its leak."""
    from workbench.plant.coupled import E_QC, E_QH
    from workbench.plant.kernels import OS_QC, S_QC
    bare = dataclasses.replace(load_plant(SN637_CREEP).pzt, modes=())
    dt, n = 1e-3, 5000
    cs = CoupledSimulator([bare], spring(bare.stiffness_n_per_m), dt, terminations=["open"])
    qj = bare.creep.capacitances_f * volts
    cs.qc[:] = qj
    cs.es[0, E_QC] = qj.sum()
    q0 = cs.es[0, E_QH] + cs.es[0, E_QC]
    ref = PZTSimulator(bare.with_resistance(2e14), dt)
    o = int(ref.m[OS_QC])
    ref.st[o:o + qj.size] = qj
    ref.st[S_QC] = qj.sum()
    got = cs.run(np.zeros(n))
    tr = ref.run(np.zeros(n))
    assert np.max(np.abs(got.q_c[:, 0] - q0)) <= 16 * np.finfo(float).eps * abs(q0)
    v_h = got.v_h_v[:, 0]
    assert np.ptp(v_h) > 0.05 * abs(volts)                 # the branches did move charge into C_h
    # the 2e14 ohm lets a little charge out: V_h differs by at most that charge over C_h (>= w0), plus rounding
    leak = np.abs(tr.q_c - q0) / bare.hysteresis.weights[0]
    assert np.all(np.abs(v_h - tr.v_h_v) <= leak + 1e-12 * np.max(np.abs(tr.v_h_v)))
