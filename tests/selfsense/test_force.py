"""Force self-sensing on the stack (seed 000 Fig. 3 read backwards; seed 002 sec. 2.4): exactness on the model,
the physics of separating force from displacement, the staged force step and the Table 1 runs."""


import numpy as np
import pytest

from tests.conftest import FULL
from workbench.plant import load_plant
from workbench.plant.hysteresis import play
from workbench.plant.simulator import PZTSimulator
from workbench.selfsense.charge_amp import ChargeAmpParams, cumulative_integral, relax_foh
from workbench.selfsense.charge_drift import identify_charge_drift, reversal_alpha
from workbench.identify.transducer import identify_transducer, table1_swap_decision
from workbench.selfsense.force import (FORCE_STAGE, estimate_force, force_step_errors, instron_from_table,
                                       run_force_study, simulate_force_step)
from workbench.selfsense.table1 import (TABLE1_FORM_TITLES, TABLE1_FORMS, TABLE1_FORMS_BACK_EMF_WITH_GAUGE,
                                        TABLE1_FORMS_PURE_BACK_EMF, instron_held_out, nested_held_out, table1_held_out,
                                        table1_spreads)
from workbench.selfsense.identify import identify, simulate_identification

from ..conftest import selfsense_main

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


def _triangles(dt, top_v, rate_v_per_s, n):
    up = np.arange(0.0, top_v / rate_v_per_s, dt) * rate_v_per_s
    return np.concatenate([np.concatenate([up, top_v - up]) for _ in range(n)])


@pytest.mark.parametrize("draw", range(4))
def test_reversal_alpha_is_blind_to_drift(draw):
    """q = alpha x + leakage + bias + two absorption relaxations, x hysteretic and creeping: the slope jumps at
    the reversals give alpha (drift slopes are continuous there), where the charge over a ramp does not."""
    rng = np.random.default_rng(500 + draw)
    dt, rate, top = 0.01, rng.uniform(5.0, 50.0), rng.uniform(20.0, 120.0)
    v = np.concatenate([np.zeros(1000), _triangles(dt, top, rate, 3), _triangles(dt, top / 2, rate, 2), np.zeros(500)])
    t = (np.arange(v.size) + 1) * dt
    x = 0.1e-6 * v + sum(rng.uniform(0.0, 0.02e-6) * play(v, r, 0.0) for r in (1.0, 3.0, 8.0)) \
        + 0.02e-6 * relax_foh(v, rng.uniform(1.0, 50.0), dt)
    alpha = 71.55
    drift = (rng.uniform(0.1, 1.0) * 1e-6 * relax_foh(v, rng.uniform(2.0, 20.0), dt)
             + rng.uniform(0.05, 0.5) * 1e-6 * relax_foh(v, rng.uniform(30.0, 300.0), dt)
             + cumulative_integral(t, v / rng.uniform(1e8, 1e10)) + rng.uniform(-1e-9, 1e-9) * t)
    got, sem, n = reversal_alpha(t, v, alpha * x + drift, x)
    assert n == 9
    k0, k1 = 1000, 1000 + int(top / rate / dt) - 1
    over_ramp = (alpha * x + drift)[k1] - (alpha * x + drift)[k0]
    over_ramp /= alpha * (x[k1] - x[k0])
    assert abs(got / alpha - 1.0) < 2e-4 and abs(got / alpha - 1.0) < 0.05 * abs(over_ramp - 1.0)


def test_reversal_alpha_needs_reversals():
    t = np.arange(1, 1001) * 0.01
    with pytest.raises(ValueError, match="reversals"):
        reversal_alpha(t, 10.0 * t, t, t)


def test_force_step_stages_and_target(force_study):
    st = force_study["force_step"]
    names = [s["name"] for s in st["stages"]]
    assert names[-1] == FORCE_STAGE
    abs_err = [s["abs_error_max_n"]["1s_end"] for s in st["stages"]]
    # the staged drift compensation takes the error from the reset down by more than 10x
    assert abs_err[0] > 10 * abs_err[-1], dict(zip(names, abs_err))
    last = st["stages"][-1]
    # issue 16 target, strict reading: within 2 % of the step at every sample from 1 s after it to the end of
    # the record, from the reset (no tare) and tared (seed 002's reset before each measurement)
    tol = 0.02 * abs(st["force_n"])
    assert last["abs_error_max_n"]["1s_end"] <= tol and last["tared_error_max_n"]["1s_end"] <= tol
    assert st["target_met_absolute_1s_end"] and st["target_met_tared_1s_end"]
    # the V_t-aware elongation beats x = k_q2x q on the pushed stack
    assert last["x_error_max_m"] < 0.25 * last["x_from_charge_only_error_max_m"]


def test_step_alpha_carries_absorption_and_the_reversals_do_not(force_study, sn637_creep):
    """The 0 -> 20 V step's alpha holds the absorption charge of the ramp (biased up); the reversal alpha is
    the model's 1 / k_q2x to within the reference noise."""
    true = 1.0 / sn637_creep.pzt.k_q2x_m_per_c
    step = force_study["identified"]["alpha_c_per_m"] / true - 1.0
    rev = force_study["charge_drift"]["alpha_c_per_m"] / true - 1.0
    assert step > 3e-4 and abs(rev) < 2e-4 and abs(rev) < 0.3 * step


@pytest.mark.parametrize("draw", range(4) if FULL else range(1))
def test_force_step_held_out_draws(draw, root):
    """Bias, force (either sign, 20-500 N) and noise drawn: within 2 N from 1 s after the step to the end."""
    rng = np.random.default_rng(9100 + draw)
    bias, force = rng.uniform(10.0, 100.0), np.exp(rng.uniform(np.log(20.0), np.log(500.0))) * rng.choice([-1, 1])
    seed = int(rng.integers(1000, 10 ** 6))
    pzt = load_plant(root / "plants/p888_51_sn637_creep.toml").pzt
    amp = ChargeAmpParams()
    idrec = simulate_identification(pzt, amp, hold_s=300.0, seed=seed + 100, dt_s=DT)
    ident = identify(idrec, amp)
    drift = identify_charge_drift(idrec, ident)
    rec, f = simulate_force_step(pzt, amp, dt_s=DT, seed=seed, bias_v=bias, force_n=force)
    e = force_step_errors(rec, f, ident, pzt, 30.0, (FORCE_STAGE,), drift)[FORCE_STAGE]
    assert e["abs_error_max_n"]["1s_end"] <= 2.0 and e["tared_error_max_n"]["1s_end"] <= 2.0, (bias, force, e)


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
    # the simulated runs' swap flag is the one swap decision's
    decided = {(d["serial"], d["run"]) for d in table1_swap_decision() if d["swap"]}
    assert {(r["serial"], r["run"]) for r in ins["runs"] if r["suspected_swap"]} == decided
    # from the measured back EMF, the model's gain reads every R out run too compressive (C_p / T_em mismatch)
    assert all(r["measured_back_emf"]["error_fraction"] < 0 for r in ins["runs"] if "measured_back_emf" in r)
    # the repeat runs' spread: closed form of the best single gain's max error over the nine R out runs
    ratio = np.array([r["force_n"] / r["back_emf_v"] for r in ins["runs"] if r["config"] == "R_out"])
    best = ins["measured_r_out_best_single_gain_max_error_fraction"]
    g = 2.0 / (1.0 / ratio.min() + 1.0 / ratio.max())
    assert best == pytest.approx(np.max(np.abs(g / ratio - 1.0)), rel=1e-9)
    lo, hi = ins["measured_r_out_gain_window_for_target_n_per_v"]
    for gain in (lo, hi):
        assert np.max(np.abs(gain / np.abs(ratio) - 1.0)) <= 0.05 + 1e-12


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
    html = (out / "force_report.html").read_text()               # the report module's one renderer, figure inlined
    assert "Table 1" in html and "data:image/png;base64," in html
    assert "| serial | run |" in (out / "force_report.md").read_text()
    # the held-out Table 1 figures: the line printed, the section in the report, the JSON's values those of the library
    assert "held out" in text and "nested" in text
    assert "## Table 1 R out runs held out" in (out / "force_report.md").read_text()
    ref = table1_held_out(root / TABLE1)
    assert data["instron"]["held_out"]["reported"]["loo"]["max_error_fraction"] == ref["reported"]["loo"]["max_error_fraction"]
    # the held-out lines lead with self-sensing proper (the run's own back EMF), its verdict as the library gives it,
    # and name the reported form as what it is
    pure = ref["nested_pure_back_emf"]
    verdict = "met" if ref["target_met_nested_pure_back_emf"] else "MISSED"
    first = next(ln for ln in text.splitlines() if "held out" in ln and "Table 1" in ln)
    assert f"pure back EMF) max {100 * pure['max_error_fraction']:.2f} % ({verdict})" in first
    assert ref["reported_form_title"] in text and "back EMF through the gauge" not in text
    report = (out / "force_report.md").read_text()
    assert report.index("Force self-sensing from the run's own back EMF") < report.index("(reported)")
    assert f"RMS {100 * pure['rms_error_fraction']:.2f} % **{verdict}**" in report.split("(reported)")[0]
    # the back EMF through the hysteresis inverse, each serial's state carried: the line and report give the
    # library's figures for the model estimates the JSON holds
    from workbench.plant import load_plant
    from workbench.selfsense.instron_sequence import table1_sequence_estimates
    seq = table1_sequence_estimates(load_plant(root / "plants/p888_51_sn637_creep.toml").pzt, root / TABLE1)
    assert [d["estimate_n"] for d in data["instron"]["sequence"]["runs"]] == [d["estimate_n"] for d in seq]
    hi = table1_held_out(root / TABLE1, model_estimate_n=[d["estimate_n"] for d in seq])
    hv = "met" if hi["target_met_nested_pure_back_emf_hysteresis_inverse"] else "MISSED"
    n = hi["nested_pure_back_emf_hysteresis_inverse"]
    line = next(ln for ln in text.splitlines() if "through the hysteresis inverse" in ln)
    assert f"max {100 * n['max_error_fraction']:.2f} % RMS {100 * n['rms_error_fraction']:.2f} % (without it" in line
    assert f") ({hv}); V/F" in line
    # beside it, the plain F = G V figures of the same library call (the new form is not an improvement by itself)
    assert f"F = G V: {100 * hi['forms']['back_emf']['loo']['max_error_fraction']:.2f} %" in line
    assert f"max {100 * n['max_error_fraction']:.2f} %, RMS {100 * n['rms_error_fraction']:.2f} % **{hv}**" in report


# ---- Table 1 peak force, held out (issue 16 item 2: within 5 %) ---------------------------------------------

TABLE1 = "plants/data/p888_51_instron_table1.csv"


def _rewrite_table(root, tmp_path, edit):
    """Table 1 with ``edit(cells)`` applied to each R out data row's cells (list of str); returns the new path."""
    lines = []
    for line in (root / TABLE1).read_text().splitlines():
        cells = line.split(",")
        if not line.startswith("#") and len(cells) == 7 and cells[2] == "R_out":
            cells = edit(cells)
        lines.append(",".join(cells))
    path = tmp_path / "table1.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_swap_decision_follows_from_the_gauge_calibration(root):
    """SN618 R out run 3 is read swapped because of its gauge: -1.078 V x 3.246 um/V = -3.499 um against a printed
    -0.336 um (941 % off), exchanged -0.336 V x 3.246 um/V = -1.091 um against -1.078 um (1.2 %); and exchanged its
    V/x lies by the serial's other runs'. No other run is swapped."""
    decided = table1_swap_decision(root / TABLE1)
    assert len(decided) == 9
    swapped = [(d["serial"], d["run"]) for d in decided if d["swap"]]
    assert swapped == [("SN618", 3)]
    d = next(d for d in decided if d["swap"])
    assert d["gauge_disagreement_printed"] == pytest.approx((1.078 * 3.246 - 0.336) / 0.336, rel=1e-12)
    assert d["gauge_disagreement_swapped"] == pytest.approx((0.336 * 3.246 - 1.078) / 1.078, rel=1e-12)
    k_others = np.mean([12.20 / (-0.334 * 3.246e-6), 12.21 / (-0.334 * 3.246e-6)])
    assert d["v_per_x_others_v_per_m"] == pytest.approx(k_others, rel=1e-12)
    assert abs(d["v_per_x_swapped_v_per_m"] / k_others - 1) < 0.02 < 0.5 < abs(d["v_per_x_printed_v_per_m"] / k_others - 1)
    assert d["x_gauge_m"] == pytest.approx(-0.336 * 3.246e-6, rel=1e-12)
    # the transducer check flags the same run, and only it, as swapped
    res = identify_transducer(root / TABLE1)
    looks = [(f["serial"], f["run"]) for f in res.runs_flagged if "look swapped" in f["reason"]]
    assert looks == swapped


@pytest.mark.parametrize("draw", range(3))
def test_swap_decision_never_reads_the_force(root, tmp_path, draw):
    """Every R out force replaced by a draw over 100-2000 N of compression: the decision and its evidence stand."""
    rng = np.random.default_rng(40 + draw)
    path = _rewrite_table(root, tmp_path, lambda c: c[:5] + [f"{-rng.uniform(100.0, 2000.0):.1f}", c[6]])
    keep = ("swap", "gauge_disagreement_printed", "gauge_disagreement_swapped", "v_per_x_printed_v_per_m", "x_gauge_m")
    a, b = table1_swap_decision(root / TABLE1), table1_swap_decision(path)
    assert [[r[k] for k in keep] for r in a] == [[r[k] for k in keep] for r in b]


def test_swap_decision_finds_a_swap_anywhere_and_leaves_unfixable_runs(root, tmp_path):
    """SN637 run 2 exchanged in the file: found (and SN618 run 3 still). A gauge that disagrees however it is read
    (gauge x 1.5) is not 'fixed' by a swap."""
    def edit(c):
        if c[0] == "SN637" and c[1] == "2":
            c = c[:3] + [c[4], c[3]] + c[5:]
        if c[0] == "SN629" and c[1] == "1":
            c = c[:3] + [f"{1.5 * float(c[3]):.4f}"] + c[4:]
        return c
    decided = table1_swap_decision(_rewrite_table(root, tmp_path, edit))
    assert [(d["serial"], d["run"]) for d in decided if d["swap"]] == [("SN637", 2), ("SN618", 3)]
    sn629 = next(d for d in decided if (d["serial"], d["run"]) == ("SN629", 1))
    assert sn629["gauge_disagreement_printed"] > 0.05 and not sn629["swap"]


def _synthetic_runs(rng, n_serials=3, n_runs=3):
    """R out runs with F/V = G and V/x = kappa_s exactly; G, kappa_s and the forces drawn over wide ranges."""
    g = -np.exp(rng.uniform(np.log(10.0), np.log(500.0)))                 # N/V
    kappa = np.exp(rng.uniform(np.log(1e6), np.log(1e8), n_serials))     # V/m, one per serial
    serial = np.repeat([f"S{k}" for k in range(n_serials)], n_runs)
    f = -np.exp(rng.uniform(np.log(10.0), np.log(5000.0), serial.size))
    v = f / g
    x = v / np.repeat(kappa, n_runs)
    return f, v, x, serial


@pytest.mark.parametrize("draw", range(3))
def test_held_out_forms_are_exact_on_exact_data(draw):
    """F = G V and V = kappa_s x exactly (the open-lead stack of the model, one kappa per serial, as each serial's
    gauge calibration may be off): every form but the pooled gauge gain, in either scheme, and the nested choice
    estimate every run exactly; the pooled F/x cannot, its serials' F/x differ."""
    f, v, x, s = _synthetic_runs(np.random.default_rng(60 + draw))
    for form in TABLE1_FORMS:
        for scheme in ("loo", "loso"):
            h = instron_held_out(f, v, x, s, form=form, scheme=scheme)
            if form.endswith("_serial") and scheme == "loso":
                assert np.all(np.isnan(h["estimate_n"]))          # no force of the serial to calibrate on
            elif form == "gauge":
                assert h["max_error_fraction"] > 1e-3
            else:
                np.testing.assert_allclose(h["estimate_n"], f, rtol=1e-9)
    np.testing.assert_allclose(nested_held_out(f, v, x, s)["estimate_n"], f, rtol=1e-9)


@pytest.mark.parametrize("form", TABLE1_FORMS)
@pytest.mark.parametrize("scheme", ["loo", "loso"])
def test_held_out_never_uses_the_runs_own_force(form, scheme):
    """Perturbing run i's force (x 0.3 to x 3) changes no estimate of run i: it is held out of its own gains."""
    rng = np.random.default_rng(7)
    f, v, x, s = _synthetic_runs(rng)
    f = f * rng.uniform(0.9, 1.1, f.size)            # repeat-run scatter, so the gains depend on the forces
    base = instron_held_out(f, v, x, s, form=form, scheme=scheme)["estimate_n"]
    for i in range(f.size):
        g = f.copy()
        g[i] *= rng.uniform(0.3, 3.0)
        assert instron_held_out(g, v, x, s, form=form, scheme=scheme)["estimate_n"][i] == pytest.approx(
            base[i], rel=1e-12, nan_ok=True)


def test_nested_loo_never_uses_the_runs_own_force():
    """Form chosen without run i: perturbing run i's force (x 0.3 to x 3) changes neither its estimate nor the form
    chosen for it."""
    rng = np.random.default_rng(7)
    f, v, x, s = _synthetic_runs(rng)
    f = f * rng.uniform(0.9, 1.1, f.size)
    base = nested_held_out(f, v, x, s)
    for i in range(f.size):
        g = f.copy()
        g[i] *= rng.uniform(0.3, 3.0)
        got = nested_held_out(g, v, x, s)
        assert got["estimate_n"][i] == pytest.approx(base["estimate_n"][i], rel=1e-12)
        assert got["chosen_form"][i] == base["chosen_form"][i]


def test_nested_loso_never_uses_the_serials_forces():
    """Leave one serial out, form chosen without it: scaling every force of run i's serial (x 0.3 to x 3) changes
    neither the estimate of run i nor the form chosen for it."""
    rng = np.random.default_rng(8)
    f, v, x, s = _synthetic_runs(rng)
    f = f * rng.uniform(0.9, 1.1, f.size)
    base = nested_held_out(f, v, x, s, scheme="loso")
    for i in range(f.size):
        g = np.where(s == s[i], f * rng.uniform(0.3, 3.0), f)
        got = nested_held_out(g, v, x, s, scheme="loso")
        assert got["estimate_n"][i] == pytest.approx(base["estimate_n"][i], rel=1e-12)
        assert got["chosen_form"][i] == base["chosen_form"][i]


def test_held_out_forms_by_hand(root):
    """loo on Table 1 (SN618 run 3 as decided) against the closed forms written out for one run."""
    decided = table1_swap_decision(root / TABLE1)
    f, v, x = (np.array([d[k] for d in decided]) for k in ("force_n", "back_emf_v", "x_gauge_m"))
    s = np.array([d["serial"] for d in decided])
    i = 8                                                                  # SN618 run 3
    others, same = np.arange(8), np.array([6, 7])
    g = np.mean(f[others] / v[others])
    kappa = np.mean(v[same] / x[same])
    assert instron_held_out(f, v, x, s, form="back_emf")["estimate_n"][i] == pytest.approx(g * v[i], rel=1e-12)
    assert instron_held_out(f, v, x, s)["estimate_n"][i] == pytest.approx(g * kappa * x[i], rel=1e-12)
    g_loso = np.mean(f[:6] / v[:6])
    assert instron_held_out(f, v, x, s, scheme="loso")["estimate_n"][i] == pytest.approx(g_loso * kappa * x[i],
                                                                                          rel=1e-12)


def test_table1_pure_back_emf_is_scored_on_the_back_emf_alone(root):
    """Self-sensing proper: the forms that read only the run's own back EMF, F = G V with G the mean F/V of the other
    runs (or of the serial's other runs), written out by hand; the nested choice among them picks only them, and
    its verdict is its max error against 5 %, whatever that is."""
    h = table1_held_out(root / TABLE1)
    f, v = (np.array([d[k] for d in h["runs"]]) for k in ("force_n", "back_emf_v"))
    s = np.array([d["serial"] for d in h["runs"]])
    n = f.size
    est = {"back_emf": [np.mean(np.delete(f / v, i)) * v[i] for i in range(n)],
           "back_emf_serial": [np.mean([f[j] / v[j] for j in range(n) if j != i and s[j] == s[i]]) * v[i]
                               for i in range(n)]}
    for form, e in est.items():
        err = np.abs(np.array(e) - f) / np.abs(f)
        assert h["forms"][form]["loo"]["max_error_fraction"] == pytest.approx(err.max(), rel=1e-12)
    pure = h["nested_pure_back_emf"]
    assert set(pure["chosen_form"]) <= set(TABLE1_FORMS_PURE_BACK_EMF)
    assert set(h["nested_back_emf_with_gauge"]["chosen_form"]) <= set(TABLE1_FORMS_BACK_EMF_WITH_GAUGE)
    assert h["target_met_nested_pure_back_emf"] == (pure["max_error_fraction"] <= 0.05)
    # each nested estimate is one of its candidate forms' estimates on the run's training runs alone
    for i, form in enumerate(pure["chosen_form"]):
        assert pure["estimate_n"][i] == pytest.approx(est[form][i], rel=1e-12)
    # the reported form reads no back EMF of the run it scores: the run's own V (x 0.5) leaves its estimate
    # unchanged, while the pure back-EMF form follows it
    assert "back EMF" in TABLE1_FORM_TITLES[h["reported_form"]] and "gauge only" in h["reported_form_title"]
    x = np.array([d["x_gauge_m"] for d in h["runs"]])
    for i in range(n):
        w = v.copy()
        w[i] *= 0.5
        assert instron_held_out(f, w, x, s)["estimate_n"][i] == pytest.approx(h["reported"]["loo"]["estimate_n"][i],
                                                                             rel=1e-12)
        assert instron_held_out(f, w, x, s, form="back_emf")["estimate_n"][i] == pytest.approx(
            0.5 * est["back_emf"][i], rel=1e-12)


def test_table1_spreads_when_the_held_out_error_vanishes():
    """A table the form fits exactly (held-out RMS 0): no new run exceeds the target (the division by the RMS must not
    raise); NaN RMS (a run without an estimate) stays NaN."""
    decided = [{"serial": "S", "force_n": -100.0 * k, "back_emf_v": 2.0 * k} for k in (1.0, 2.0)]
    sp = table1_spreads(decided, {"rms_error_fraction": 0.0})
    assert sp["exceed_target_fraction_normal"] == 0.0
    assert sp["f_per_v_relative_std"]["S"] == 0.0
    assert np.isnan(table1_spreads(decided, {"rms_error_fraction": np.nan})["exceed_target_fraction_normal"])


def test_table1_peak_force_target(root):
    """Issue 16: peak force of the Table 1 R out runs within 5 %, each run on gains its force never entered; and
    with the form chosen without the held-out run (nested). These forms read the run's gauge."""
    h = table1_held_out(root / TABLE1)
    rep = h["reported"]
    assert rep["loo"]["max_error_fraction"] <= 0.05 and rep["loso"]["max_error_fraction"] <= 0.05
    assert h["nested"]["max_error_fraction"] <= 0.05 and h["nested_loso"]["max_error_fraction"] <= 0.05
    assert h["target_met_loo"] and h["target_met_loso"] and h["target_met_nested"] and h["target_met_nested_loso"]
    # the spread's implied share of new runs beyond 5 % (normal errors, the held-out RMS): closed form
    from scipy.stats import norm
    for sch in ("loo", "loso"):
        sp = h["spreads"][sch]
        assert sp["exceed_target_fraction_normal"] == pytest.approx(
            2 * norm.sf(0.05 / rep[sch]["rms_error_fraction"]), rel=1e-9)
    fv = np.array([d["force_n"] / d["back_emf_v"] for d in h["runs"] if d["serial"] == "SN629"])
    assert h["spreads"]["loo"]["f_per_v_relative_std"]["SN629"] == pytest.approx(np.std(fv, ddof=1) / abs(fv.mean()))


def test_table1_held_out_bad_arguments():
    f, v, x, s = _synthetic_runs(np.random.default_rng(1))
    for fn in (instron_held_out, nested_held_out):
        with pytest.raises(ValueError, match="nonzero back EMF"):
            fn(f, v, np.where(np.arange(x.size) == 4, 0.0, x), s)
        with pytest.raises(ValueError, match="one length"):
            fn(f[:-1], v, x, s)
        with pytest.raises(ValueError, match="at least 3 runs"):
            fn(f[:2], v[:2], x[:2], s[:2])
        with pytest.raises(ValueError, match="finite"):
            fn(np.where(np.arange(f.size) == 1, np.nan, f), v, x, s)
        with pytest.raises(ValueError, match="nonzero peak force"):
            fn(np.where(np.arange(f.size) == 1, 0.0, f), v, x, s)
        with pytest.raises(ValueError, match="loso"):
            fn(f, v, x, s, scheme="kfold")
    with pytest.raises(ValueError, match="unknown Table 1 form"):
        instron_held_out(f, v, x, s, form="quadratic")
    with pytest.raises(ValueError, match="loso"):
        instron_held_out(f, v, x, s, scheme="kfold")
    with pytest.raises(ValueError, match="nonzero back EMF"):
        instron_held_out(f, np.zeros_like(v), x, s)
    with pytest.raises(ValueError, match="unknown Table 1 form"):
        nested_held_out(f, v, x, s, forms=("back_emf", "cubic"))
    with pytest.raises(ValueError, match="can be scored"):
        nested_held_out(f, v, x, s, forms=("gauge_serial",), scheme="loso")
    with pytest.raises(ValueError, match="x_source"):
        table1_held_out(x_source="laser")
