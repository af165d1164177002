"""A serial's Instron runs in sequence (selfsense/instron_sequence.py): what C_h's memory and the creep branches
can and cannot do to the open-lead back EMF, and the hysteresis-inverse read of a run with its state carried."""

from dataclasses import replace

import numpy as np
import pytest

from workbench.plant import load_plant
from workbench.plant.simulator import PZTSimulator
from workbench.selfsense.force import INSTRON_R_OUT_OHM, estimate_force, instron_force_profile
from workbench.selfsense.instron_sequence import read_open_lead_run, serial_sequence, table1_sequence_estimates
from workbench.selfsense.table1 import (TABLE1_FORM_HYSTERESIS_INVERSE, instron_held_out, nested_held_out,
                                        table1_held_out)

PLANT = load_plant("plants/p888_51_sn637.toml").pzt
CREEP = load_plant("plants/p888_51_sn637_creep.toml").pzt


def _history(rng):
    """0-4 earlier runs of either configuration, peak forces over -1500..-50 N, then one open-lead run."""
    runs = [(str(rng.choice(["R_in", "R_out"])), float(rng.uniform(-1500.0, -50.0)))
            for _ in range(int(rng.integers(0, 5)))]
    return runs + [("R_out", float(rng.uniform(-1500.0, -50.0)))]


@pytest.mark.parametrize("draw", range(4))
def test_open_leads_back_emf_is_linear_whatever_the_memory(draw):
    """Leads open: q held -> C_h's output held -> V_h held (C_h is strictly increasing on every branch), so the
    back EMF is -T_em F / (k_p C_pp) exactly, whatever state earlier runs left the plays in."""
    rng = np.random.default_rng(draw)
    runs = _history(rng)
    seq = serial_sequence(PLANT, runs, drain_s=float(rng.uniform(0.0, 60.0)))
    closed = -PLANT.transducer_constant_n_per_v / (PLANT.stiffness_n_per_m * PLANT.c_pp_f)
    for (config, f), r in zip(runs, seq):
        if config == "R_out":
            assert abs(r.delta_v_h_v) < 1e-12          # V: round-off
            assert r.back_emf_v == pytest.approx(closed * f, rel=1e-10)
    if any(c == "R_in" for c, _ in runs[:-1]):       # the plays did move: the memory is there, and does nothing
        assert np.any(seq[-1].states_v != 0.0)


def test_keithley_input_drains_nothing_measurable():
    """200 TOhm on the open leads (the library simulator): the back EMF is the closed form within 1e-6."""
    load = replace(PLANT, series_resistance_ohm=INSTRON_R_OUT_OHM, current_limit_source_a=1.0,
                   current_limit_sink_a=1.0)
    dt = 1e-3
    f = instron_force_profile(-800.0, dt)
    tr = PZTSimulator(load, dt).run(np.zeros(f.size), f_e_n=f)
    closed = -PLANT.transducer_constant_n_per_v / (PLANT.stiffness_n_per_m * PLANT.c_pp_f) * -800.0
    assert np.max(np.abs(tr.v_t_v)) == pytest.approx(closed, rel=1e-6)


@pytest.mark.parametrize("draw", range(3))
def test_open_lead_run_leaves_a_state_its_force_does_not_set(draw):
    """An R_out run's force moves no charge, so the next run starts from the same state whatever that force was:
    the Table 1 estimates use no R_out run's force."""
    rng = np.random.default_rng(10 + draw)
    before = [("R_in", float(rng.uniform(-1500, -100))) for _ in range(int(rng.integers(1, 4)))]
    drain = float(rng.uniform(0, 20))
    a = serial_sequence(CREEP, before + [("R_out", -800.0), ("R_out", -500.0)], drain_s=drain)
    b = serial_sequence(CREEP, before + [("R_out", float(rng.uniform(-1500, -100))), ("R_out", -500.0)], drain_s=drain)
    np.testing.assert_allclose(a[-1].states_v, b[-1].states_v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a[-1].creep_charges_c, b[-1].creep_charges_c, rtol=0, atol=1e-18)
    assert a[-1].delta_v_h_v == pytest.approx(b[-1].delta_v_h_v, abs=1e-12)


def test_run_order_sign_and_decay_from_creep():
    """The creep branches charged by earlier shorted compressions relax at constant charge during the next
    open-lead run: C_h gives charge up, V_h falls, so the back EMF per newton of the first open-lead run is the
    lowest and the deficit shrinks run by run (the sign Table 1 shows for SN637 and SN629). From rest, with no
    earlier shorted run, the branches are in equilibrium and nothing moves."""
    runs = [("R_in", -780.0)] * 3 + [("R_out", -800.0)] * 3
    seq = serial_sequence(CREEP, runs, drain_s=1.0)[3:]
    dvh = [r.delta_v_h_v for r in seq]
    assert dvh[0] < dvh[1] < dvh[2] < 0.0
    per_n = [abs(r.back_emf_per_force_v_per_n) for r in seq]
    assert per_n[0] < per_n[1] < per_n[2]
    virgin = serial_sequence(CREEP, [("R_out", -800.0)] * 3, drain_s=0.0)
    assert all(abs(r.delta_v_h_v) < 1e-12 for r in virgin)
    # a longer drain lets the branches relax before the run: a smaller deficit
    assert abs(serial_sequence(CREEP, runs, drain_s=10.0)[3].delta_v_h_v) < abs(dvh[0])


@pytest.mark.parametrize("pzt", [PLANT, CREEP], ids=["sn637", "sn637_creep"])
@pytest.mark.parametrize("draw", range(3))
def test_hysteresis_inverse_read_recovers_the_force(pzt, draw):
    """Reading a simulated open-lead run's back EMF through the inverse from its start state gives back the
    applied peak force (round-off), for any history."""
    rng = np.random.default_rng(20 + draw)
    runs = _history(rng)
    dt = 0.01
    seq = serial_sequence(pzt, runs, drain_s=float(rng.uniform(0.0, 30.0)), dt_s=dt)
    last = seq[-1]
    f, _, dvh = read_open_lead_run(pzt, last, last.back_emf_v, last.peak_time_s, dt_s=dt)
    assert f == pytest.approx(runs[-1][1], rel=1e-9)
    assert dvh == pytest.approx(last.delta_v_h_v, abs=1e-12)


def test_table1_hysteresis_inverse_form_held_out():
    """The form's gain comes from the training runs only (the held-out run's force moves nothing of its own
    estimate), and without creep the form is back_emf exactly (the read is linear in the back EMF)."""
    est = table1_sequence_estimates(PLANT)
    u = np.array([d["estimate_n"] for d in est])
    np.testing.assert_allclose(u, [d["linear_estimate_n"] for d in est], rtol=1e-12)
    h = table1_held_out(model_estimate_n=u)
    np.testing.assert_allclose(h["forms"][TABLE1_FORM_HYSTERESIS_INVERSE]["loo"]["estimate_n"],
                               h["forms"]["back_emf"]["loo"]["estimate_n"], rtol=1e-12)
    f = np.array([d["force_n"] for d in est])
    v = np.array([d["back_emf_v"] for d in est])
    s = np.array([d["serial"] for d in est])
    x = np.full(f.size, -1e-6)
    for i in (0, 4):
        f2 = f.copy()
        f2[i] *= 1.3
        a = instron_held_out(f, v, x, s, form=TABLE1_FORM_HYSTERESIS_INVERSE, model_estimate_n=u)["estimate_n"][i]
        b = instron_held_out(f2, v, x, s, form=TABLE1_FORM_HYSTERESIS_INVERSE, model_estimate_n=u)["estimate_n"][i]
        assert a == b
    with pytest.raises(ValueError, match="needs model_estimate_n"):
        instron_held_out(f, v, x, s, form=TABLE1_FORM_HYSTERESIS_INVERSE)
    with pytest.raises(ValueError, match="model_estimate_n must be 9"):
        nested_held_out(f, v, x, s, forms=(TABLE1_FORM_HYSTERESIS_INVERSE,), model_estimate_n=u[:-1])


def test_serial_sequence_bad_arguments():
    with pytest.raises(ValueError, match="R_in' or 'R_out"):
        serial_sequence(PLANT, [("open", -800.0)])
    with pytest.raises(ValueError, match="dt_s"):
        serial_sequence(PLANT, [("R_out", -800.0)], dt_s=0.0)


@pytest.mark.parametrize("draw", range(3))
def test_inverse_with_carried_state_reads_a_library_simulated_run(draw):
    """The library simulator (its own kernel) runs 1-3 shorted compressions through 200 ohm, then an open-lead
    run: estimate_force started from C_h's play states after that history (the plays run over the recorded V_h)
    and the charge left reads the force to round-off; started from the plant's rest state it is off by tens of N
    (the remanent charge read as if it were load)."""
    rng = np.random.default_rng(30 + draw)
    dt = 1e-3

    def sim(r):
        return PZTSimulator(replace(PLANT, series_resistance_ohm=r, current_limit_source_a=1.0,
                                    current_limit_sink_a=1.0), dt)

    a, b = sim(200.0), sim(INSTRON_R_OUT_OHM)
    v_h = []
    for _ in range(int(rng.integers(1, 4))):
        f = instron_force_profile(float(rng.uniform(-1500.0, -100.0)), dt)
        tr = a.run(np.zeros(f.size), f_e_n=f)
        v_h.append(tr.v_h_v)
    q_left = tr.q_c[-1]
    states = PLANT.hysteresis.final_states(np.concatenate(v_h))
    b.st[:] = a.st
    f = instron_force_profile(float(rng.uniform(-1500.0, -100.0)), dt)
    tr = b.run(np.zeros(f.size), f_e_n=f)
    t = np.arange(1, f.size + 1) * dt
    est = estimate_force(t, tr.v_t_v, tr.q_c - q_left, PLANT, states_v=states)
    assert np.max(np.abs(est.f_e_n - f)) < 1e-9 * np.max(np.abs(f))
    np.testing.assert_allclose(est.v_p_v, tr.v_p_v, rtol=0, atol=1e-9)
    rest = estimate_force(t, tr.v_t_v, tr.q_c, PLANT)
    assert np.max(np.abs(rest.f_e_n - f)) > 10.0


def test_table1_sequence_estimates_read_no_r_out_force(tmp_path):
    """Every R out run's printed force changed: the model's reads of Table 1 do not move (they use the R in runs'
    forces for the history and each R out run's back EMF, nothing else of it)."""
    from pathlib import Path
    src = Path("plants/data/p888_51_instron_table1.csv").read_text().splitlines()
    out = []
    for line in src:
        cells = line.split(",")
        if len(cells) == 7 and cells[2] == "R_out":
            cells[5] = f"{float(cells[5]) * 1.37:.1f}"
        out.append(",".join(cells))
    path = tmp_path / "t1.csv"
    path.write_text("\n".join(out) + "\n")
    a = table1_sequence_estimates(CREEP)
    b = table1_sequence_estimates(CREEP, path)
    assert [d["estimate_n"] for d in a] == [d["estimate_n"] for d in b]
    assert [d["force_n"] for d in a] != [d["force_n"] for d in b]


@pytest.mark.parametrize("draw", range(2))
def test_the_library_simulator_reproduces_the_sequence(draw):
    """One physics in two homes: since the kernels keep Kirchhoff's current law (tests/plant/test_kcl.py), the
    library simulator, with the seed's 200 ohm across the leads for the R in runs and the drains and the Keithley's
    200 TOhm for the R out runs, gives the sequence's open-lead back EMF and V_h's fall. The sequence takes the
    200 ohm as a short (V_t = 0) and the 200 TOhm as open: the two differ by at most the drop the 200 ohm's
    current makes, R_in T_em max|dF/dt| / k_p (the whole force term's charge rate through it)."""
    from workbench.selfsense.force import INSTRON_R_IN_OHM
    rng = np.random.default_rng(40 + draw)
    pz = replace(CREEP, modes=())
    # Table 1's forces (~-800 N) and a drain near the 1 s assumed for it: the first open-lead run's creep fall
    # (tens of mV) stands above the bound, so a simulator whose open leads let the creep move q fails
    runs = [("R_in", float(rng.uniform(-900.0, -500.0))) for _ in range(3)]
    runs += [("R_out", float(rng.uniform(-1500.0, -100.0))) for _ in range(2)]
    dt, drain = 0.01, float(rng.uniform(0.5, 2.0))
    seq = serial_sequence(pz, runs, drain_s=drain, dt_s=dt)
    shorted = PZTSimulator(pz.with_resistance(INSTRON_R_IN_OHM), dt)
    opened = PZTSimulator(pz.with_resistance(INSTRON_R_OUT_OHM), dt)
    st = shorted.st.copy()
    k_f = pz.transducer_constant_n_per_v / pz.stiffness_n_per_m
    slope_max = 0.0
    for (config, peak_n), sr in zip(runs, seq):
        shorted.st[:] = st
        v_h_before = shorted.run(np.zeros(int(round(drain / dt)))).v_h_v[-1]
        st = shorted.st
        f = instron_force_profile(peak_n, dt, rest_s=1.0, ramp_s=5.0, hold_s=2.0)
        slope_max = max(slope_max, np.max(np.abs(np.diff(f))) / dt)
        sim = shorted if config == "R_in" else opened
        sim.st[:] = st
        tr = sim.run(np.zeros_like(f), f)
        st = sim.st.copy()
        if config == "R_out":
            k = int(np.argmax(np.abs(tr.v_t_v)))
            bound = INSTRON_R_IN_OHM * k_f * slope_max
            assert abs(tr.v_t_v[k] - sr.back_emf_v) <= bound, (tr.v_t_v[k], sr.back_emf_v, bound)
            assert abs((tr.v_h_v[k] - v_h_before) - sr.delta_v_h_v) <= bound
    assert abs(seq[3].delta_v_h_v) > 2 * bound           # the first open-lead run's creep fall is resolved
