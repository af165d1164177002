"""Force self-sensing on the stack (seed 000 Fig. 3 read backwards; seed 002 sec. 2.4): exactness on the model,
the physics of separating force from displacement, the staged force step and the Table 1 runs."""


import numpy as np
import pytest

from workbench.plant.simulator import PZTSimulator
from workbench.selfsense.command import main as selfsense_main
from workbench.selfsense.force import estimate_force, instron_from_table, run_force_study

DT = 5e-4


def _random_profiles(rng, n, dt):
    """A voltage staircase in [0, 100] V and a force made of steps and ramps in [-600, 300] N."""
    edges = np.sort(rng.integers(1, n, 6))
    v = np.zeros(n)
    f = np.zeros(n)
    for a in edges:
        v[a:] = rng.uniform(0.0, 100.0)
    for a in np.sort(rng.integers(1, n, 4)):
        f[a:] = rng.uniform(-600.0, 300.0)
    ramp = np.clip((np.arange(n) * dt - rng.uniform(0, n * dt)) / 2.0, 0.0, 1.0) * rng.uniform(-200, 200)
    return v, f + ramp


@pytest.mark.parametrize("draw", range(3))
@pytest.mark.parametrize("plant", ["sn637", "sn637_creep"])
def test_force_and_elongation_exact_on_the_model(draw, plant, request):
    """At the simulator's own step the inversion is exact: V_h, V_p, quasi-static x and F_e to round-off."""
    pl = request.getfixturevalue(plant)
    rng = np.random.default_rng(100 + draw)
    v, f = _random_profiles(rng, int(40.0 / DT), DT)
    tr = PZTSimulator(pl.pzt, DT).run(v, f_e_n=f)
    est = estimate_force(tr.t_s, tr.v_t_v, tr.q_c, pl.pzt)
    np.testing.assert_allclose(est.v_h_v, tr.v_h_v, rtol=0, atol=1e-9)
    np.testing.assert_allclose(est.f_e_n, f, rtol=0, atol=1e-6)
    p = pl.pzt
    x_qs = (f + p.transducer_constant_n_per_v * tr.v_p_v) / p.stiffness_n_per_m     # seed 000 eq. 5
    np.testing.assert_allclose(est.x_m, x_qs, rtol=0, atol=1e-14)
    # the hysteresis voltage is what lets V_t separate the two: taking V_p = V_t instead is far off
    wrong = (p.stiffness_n_per_m / p.transducer_constant_n_per_v) * (tr.q_c - p.c_pp_f * tr.v_t_v)
    assert np.max(np.abs(wrong - f)) > 100.0


def test_charge_alone_misreads_a_pushed_stack(sn637_creep):
    """With F_e present x = k_q2x q is off by -C_p F_e / (k_p C_pp) (closed form); the V_t-aware estimate is not."""
    p = sn637_creep.pzt
    n = int(10.0 / DT)
    f = np.where(np.arange(n) * DT > 5.0, -100.0, 0.0)
    tr = PZTSimulator(p, DT).run(np.full(n, 50.0), f_e_n=f)
    x_qs = (f + p.transducer_constant_n_per_v * tr.v_p_v) / p.stiffness_n_per_m
    off = p.k_q2x_m_per_c * tr.q_c - x_qs
    expected = -p.working_capacitance_f * f / (p.stiffness_n_per_m * p.c_pp_f)
    np.testing.assert_allclose(off, expected, rtol=1e-9, atol=1e-15)
    assert abs(expected[-1]) > 150e-9                     # 100 N: ~170 nm, 10x the staged estimator's error
    est = estimate_force(tr.t_s, tr.v_t_v, tr.q_c, p)
    assert np.max(np.abs(est.x_m - x_qs)) < 1e-13


@pytest.mark.parametrize("v_emf", [0.5, 11.68, 12.63, 40.0])
def test_open_leads_read_the_closed_form(sn637_creep, v_emf):
    """R out (q = 0): V_h = 0, V_p = V_t, x = -C_p V / T_em (eq. 9), F_e = -(k_p C_pp / T_em) V (eq. 5)."""
    p = sn637_creep.pzt
    f, x = instron_from_table(p, v_emf)
    t_em = p.transducer_constant_n_per_v
    assert f == pytest.approx(-p.stiffness_n_per_m * p.c_pp_f / t_em * v_emf, rel=1e-12)
    assert x == pytest.approx(-p.working_capacitance_f * v_emf / t_em, rel=1e-12)


@pytest.fixture(scope="module")
def force_study(root):
    """The --force study, reduced: 5e-4 s plant step, 300 s identification holds."""
    return run_force_study(root / "plants/p888_51_sn637_creep.toml", dt_s=DT, id_hold_s=300.0, seed=2)


def test_force_step_stages_and_target(force_study):
    st = force_study["force_step"]
    names = [s["name"] for s in st["stages"]]
    abs_err = [s["abs_error_max_n"]["1s_end"] for s in st["stages"]]
    # the staged drift compensation takes the error from the reset down by more than 10x
    assert abs_err[0] > 10 * abs_err[-1], dict(zip(names, abs_err))
    last = st["stages"][-1]
    # issue 16 target, tared (seed 002's reset before each measurement), 1-5 s after the step: 2 % of 100 N
    assert last["tared_error_max_n"]["1_5s"] <= 0.02 * abs(st["force_n"])
    # the V_t-aware elongation beats x = k_q2x q on the pushed stack
    assert last["x_error_max_m"] < 0.25 * last["x_from_charge_only_error_max_m"]


def test_instron_runs(force_study):
    ins = force_study["instron"]
    assert len(ins["runs"]) == 18
    # every run simulated in its configuration: the estimated peak force within 5 % (issue 16)
    assert ins["simulated_max_error_fraction"] <= 0.05 and ins["target_met_simulated"]
    for r in ins["runs"]:
        s = r["simulated"]
        if r["config"] == "R_in":
            assert abs(s["model_back_emf_v"]) < 0.01          # 200 ohm across the leads: no back EMF
        else:
            # the model's back EMF is within 12 % of the measured one (the seed's parameters; see README)
            assert s["model_back_emf_v"] == pytest.approx(r["back_emf_v"], rel=0.12)
    # from the measured back EMF, the model's gain reads every R out run too compressive (C_p / T_em mismatch)
    assert all(r["measured_back_emf"]["error_fraction"] < 0 for r in ins["runs"] if "measured_back_emf" in r)


def test_cli_force_bad_input(root, capsys):
    assert selfsense_main([str(root / "plants/p888_51_sn637_creep.toml"), "--force", "--step-force", "0N"]) == 2
    assert "--step-force" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        selfsense_main([str(root / "plants/p888_51_sn637_creep.toml"), "--force", "--step-force", "100V"])
    assert exc.value.code == 2


def test_cli_force_prints_and_writes(force_study, root, tmp_path, monkeypatch, capsys):
    """`selfsense --force --out --json` on the reduced study's data: lines, figure, report and JSON written whole."""
    import json

    import workbench.selfsense.force as force_mod
    monkeypatch.setattr(force_mod, "run_force_study", lambda *a, **k: dict(force_study))
    out, js = tmp_path / "out", tmp_path / "f.json"
    assert selfsense_main([str(root / "plants/p888_51_sn637_creep.toml"), "--force", "--out", str(out),
                           "--json", str(js)]) == 0
    text = capsys.readouterr().out
    assert "hysteresis and creep" in text and "Table 1" in text
    data = json.loads(js.read_text())
    assert "_arrays" not in data and len(data["instron"]["runs"]) == 18
    assert {"force.png", "force_report.md", "force.json"} <= {p.name for p in out.iterdir()}
    assert "| serial | run |" in (out / "force_report.md").read_text()
