"""Self-sensing (seed 002 on the stack): the charge amplifier, the estimators, identification, the stages, the CLI."""

import json
from dataclasses import replace
from types import SimpleNamespace

import control
import numpy as np
import pytest

from workbench.plant.simulator import PZTSimulator
from workbench.selfsense import ChargeAmpParams, EstimatorParams, ResidualCorrection, measure, static_estimate
from workbench.selfsense.charge_amp import ChargeAmpStream
from workbench.selfsense.estimator import (StreamingEstimator, band_limited, charge_transfer, dynamic_estimator,
                                           dynamic_gains, output_transfer, static_transfer)
from workbench.selfsense.identify import identify, simulate_identification
from workbench.selfsense.run import STAGES, run_selfsense, staircase_voltage

from ..conftest import selfsense_main

DT = 5e-4                      # plant step for the tests (the CLI runs 1e-4); RC of R and C_h is ~1-2 ms
ONE_BRANCH = replace(ChargeAmpParams(), da_gains_f=(0.3e-6,), da_time_constants_s=(20.0,))


@pytest.fixture(scope="module")
def study(root):
    """A shortened staged study: 300 s staircase, 300 s identification holds, loop analysis on."""
    return run_selfsense(root / "plants/p888_51_sn637_creep.toml", duration_s=300.0, dt_s=DT, id_hold_s=300.0,
                         loop=True)


def _record(pzt, amp, seconds=120.0, seed=3):
    v = staircase_voltage(seconds, DT, seed=seed)
    return measure(PZTSimulator(pzt, DT).run(v, decimate=2), amp, seed=seed, average=2)


def test_charge_record_adds_up_and_stays_in_range(sn637_creep):
    amp = ChargeAmpParams().ideal()
    rec = _record(sn637_creep.pzt, amp)
    q = rec.q_stack_c + rec.q_leak_c + rec.q_bias_c + rec.q_da_c
    np.testing.assert_allclose(-(q - amp.c_ref_f * rec.v_in_true_v) / amp.c_int_f, rec.v_out_v, rtol=0, atol=1e-12)
    # leakage charge is int V/R: at a constant V its rate is V/R
    assert rec.clipped_fraction == 0.0 and np.max(np.abs(rec.v_out_v)) < 0.8 * amp.adc_range_v
    # the terminal charge tracks the free stack's displacement (seed 000 eq. 10) up to the 70 kHz mode
    np.testing.assert_allclose(rec.x_m, sn637_creep.pzt.k_q2x_m_per_c * rec.q_stack_c, rtol=0, atol=1e-10)


def test_static_estimator_exact_when_every_effect_is_known(sn637_creep):
    amp = ChargeAmpParams().ideal()               # two absorption branches, no noise
    rec = _record(sn637_creep.pzt, amp)
    alpha = 1.0 / sn637_creep.pzt.k_q2x_m_per_c
    # first branch in eq. 2.9's term, the second as the stage-4 creep operator (gain in m/V)
    second = ResidualCorrection((amp.da_time_constants_s[1],), (amp.da_gains_f[1] / alpha,), (), ())
    p = EstimatorParams(alpha, amp.c_int_f, amp.c_ref_f, r_leak_ohm=amp.r_leak_ohm, i_bias_a=amp.i_bias_a,
                        da_gain_f=amp.da_gains_f[0], da_time_constant_s=amp.da_time_constants_s[0], correction=second)
    err = static_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, p) - rec.x_m
    assert np.max(np.abs(err)) < 1e-10                # 0.1 nm over a 15 um stroke
    # leaving out the leakage is not exact: the test can fail
    bad = static_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, replace(p, r_leak_ohm=float("inf"))) - rec.x_m
    assert np.max(np.abs(bad)) > 3e-8


def test_identification_recovers_the_circuit(sn637_creep):
    idrec = simulate_identification(sn637_creep.pzt, ONE_BRANCH, hold_s=300.0, dt_s=DT, seed=11)
    ide = identify(idrec, ONE_BRANCH)
    assert ide.alpha_c_per_m == pytest.approx(1.0 / sn637_creep.pzt.k_q2x_m_per_c, rel=2e-3)
    assert ide.i_bias_a == pytest.approx(ONE_BRANCH.i_bias_a, rel=0.05)
    assert ide.r_leak_ohm == pytest.approx(ONE_BRANCH.r_leak_ohm, rel=0.02)
    assert ide.da_gain_f == pytest.approx(ONE_BRANCH.da_gains_f[0], rel=0.05)
    assert ide.da_time_constant_s == pytest.approx(ONE_BRANCH.da_time_constants_s[0], rel=0.05)
    # the drift of each hold lies on the seed's Fig. 2.10 line V / R_FP
    for v, drift in ide.hold_drifts:
        assert drift == pytest.approx(v / ONE_BRANCH.r_leak_ohm, rel=0.1)


def test_stages_decrease_and_the_last_is_within_one_percent_of_stroke(study):
    names = [s["name"] for s in study["stages"]]
    assert names == list(STAGES)
    pp = [s["error_pp_m"] for s in study["stages"]]
    rms = [s["error_rms_m"] for s in study["stages"]]
    assert all(a > b for a, b in zip(pp, pp[1:])), pp
    assert all(a > b for a, b in zip(rms, rms[1:])), rms
    assert study["stroke_m"] > 14e-6
    assert pp[-1] <= 0.01 * study["stroke_m"] and study["target_met"]
    assert pp[0] > 0.03 * study["stroke_m"]            # the uncompensated estimate is visibly off
    assert study["v_out_clipped_fraction"] == 0.0


def test_noise_beside_the_gauge(study):
    n = study["noise_per_10khz_sample"]
    assert n["gauge_rms_m"] == pytest.approx(22e-9, rel=0.15)          # seed 000 sec. 3.1
    assert n["self_sensed_rms_m"] < n["gauge_rms_m"] / 10


def test_dynamic_estimator_matches_eqs_2_43_to_2_48(sn637_creep):
    from workbench.linearize.small_signal import small_signal_model
    pzt = replace(sn637_creep.pzt, series_resistance_ohm=0.0)
    alpha = 1.0 / pzt.k_q2x_m_per_c
    kd = small_signal_model(pzt, 17.5e-6)                               # K D(s) = x / V_in
    qv = small_signal_model(replace(pzt, modes=()), 17.5e-6) * alpha    # q / V_in
    amp = ChargeAmpParams()
    h = output_transfer(charge_transfer(qv, amp.r_leak_ohm, amp.da_gains_f[:1], amp.da_time_constants_s[:1]),
                        amp.c_int_f, amp.c_ref_f)
    p = EstimatorParams(alpha, amp.c_int_f, amp.c_ref_f, r_leak_ohm=amp.r_leak_ohm,
                        da_gain_f=amp.da_gains_f[0], da_time_constant_s=amp.da_time_constants_s[0])
    s = 2j * np.pi * np.geomspace(1e-3, 2e4, 60)
    # eq. 2.43 by hand: c1 H + c2 - c3/s - k_s/(tau s + 1), c1 = -C/alpha, c2 = C_R/alpha, c3 = 1/(R alpha)
    hand = (-amp.c_int_f / alpha * h(s) + amp.c_ref_f / alpha - 1 / (amp.r_leak_ohm * alpha * s)
            - amp.da_gains_f[0] / alpha / (amp.da_time_constants_s[0] * s + 1))
    np.testing.assert_allclose(static_transfer(h, p)(s), hand, rtol=1e-9)
    g1, g2, g3 = dynamic_gains(kd, h, p)
    assert g3 == pytest.approx(amp.c_ref_f / alpha)
    e = dynamic_estimator(g1, g2, g3)
    # eq. 2.44: E = G1 / (G2 + G3); eq. 2.47: delta_d / V_in = K D(s) when the models are exact
    np.testing.assert_allclose(e(s) * (g2(s) + g3), g1(s), rtol=1e-7)
    np.testing.assert_allclose(e(s) * static_transfer(h, p)(s), kd(s), rtol=1e-7)
    # for the stack the static estimate is already x below the 70 kHz mode: E = 1 in the servo band
    assert np.max(np.abs(e(s[np.abs(s) < 2 * np.pi * 2e3]) - 1)) < 2e-3


def test_static_transfer_matches_the_time_domain_estimator():
    """Eq. 2.43 as a transfer function and eq. 2.8 on samples agree for a linear capacitor stack."""
    amp = replace(ChargeAmpParams(), da_gains_f=(0.3e-6,), da_time_constants_s=(7.0,)).ideal()
    c_stack, alpha, dt = 11e-6, 70.0, 1e-2
    t = np.arange(1, 20001) * dt
    v = 40 * np.sin(2 * np.pi * 0.02 * t) ** 2 + 10 * np.sin(2 * np.pi * 0.3 * t)
    traj = SimpleNamespace(t_s=t, v_t_v=v, q_c=c_stack * v, x_m=c_stack * v / alpha)
    rec = measure(traj, amp)
    p = EstimatorParams(alpha, amp.c_int_f, amp.c_ref_f, r_leak_ohm=2 * amp.r_leak_ohm, i_bias_a=0.0,
                        da_gain_f=0.2e-6, da_time_constant_s=3.0)   # deliberately not the truth
    h = output_transfer(charge_transfer(control.ss([], [], [], [[c_stack]]), amp.r_leak_ohm, amp.da_gains_f,
                                        amp.da_time_constants_s), amp.c_int_f, amp.c_ref_f)
    # the bias current is a ramp outside the transfer function (eq. 2.43 leaves it out): add it by hand
    lin = control.forced_response(static_transfer(h, p), T=np.concatenate([[0.0], t]),
                                  U=np.concatenate([[0.0], v])).outputs[1:] + amp.i_bias_a * t / alpha
    est = static_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, p)
    assert np.max(np.abs(est - lin)) < 1e-4 * np.max(np.abs(est - rec.x_m))


def test_loop_with_the_self_sensed_signal(study):
    lp = study["loop"]
    mg, ms = lp["margins_gauge"], lp["margins_self_sensed"]
    assert ms["phase_margin_deg"] >= 45 and ms["gain_margin_db"] >= 6
    # no half-period averaging in the charge path: a little more phase than the gauge chain, same crossover
    assert ms["phase_margin_deg"] >= mg["phase_margin_deg"]
    assert ms["crossover_hz"] == pytest.approx(mg["crossover_hz"], rel=0.05)
    # the gauge loop is the study's nominal loop (one definition, design/nominal.py): same margins
    from workbench.controller import Controller
    from workbench.design.nominal import nominal_margins, nominal_plant
    from workbench.plant import load_plant
    nom = nominal_margins(Controller.load(lp["controller"]).as_lti(), nominal_plant(load_plant(study["plant"])))
    assert mg["phase_margin_deg"] == pytest.approx(nom.phase_margin_deg, abs=0.2)
    assert mg["crossover_hz"] == pytest.approx(nom.crossover_hz, rel=0.01)
    assert lp["estimate_over_true_max_dev_0p1_1khz"] < 0.02
    # E has the stack's mode and nothing else that matters: minimal realization of 4 states at most
    assert lp["e_states_minimal"] <= 4 and max(lp["e_poles_hz"]) == pytest.approx(70e3, rel=1e-3)
    # closed loop on the self-sensed estimate, nonlinear plant: a 0.1 um step as the linear loop predicts
    cl, cg = lp["closed_loop_small_step"], lp["closed_loop_small_step_gauge_noise_free"]
    assert cl["overshoot_percent"] < 1.0 and cl["settling_s"] < 0.02
    assert abs(cl["final_error_m"]) < 2e-9
    assert cl["settling_s"] == pytest.approx(cg["settling_s"], rel=0.3)


def test_streaming_amplifier_and_estimator_equal_the_batch_ones(sn637_creep):
    amp = ChargeAmpParams().ideal()
    traj = PZTSimulator(sn637_creep.pzt, DT).run(staircase_voltage(20.0, DT, seed=9), decimate=2)
    rec = measure(traj, amp, average=2)
    stream = ChargeAmpStream(amp, rec.t_s[1] - rec.t_s[0])
    v_out = np.array([stream.update(q, v)[1] for q, v in zip(traj.q_c, traj.v_t_v)])
    np.testing.assert_allclose(v_out, rec.v_out_v, rtol=0, atol=1e-12)
    corr = ResidualCorrection((2.0, 30.0), (1e-9, -2e-9), (0.0, 5.0), (3e-10, 4e-10))
    p = EstimatorParams(70.0, amp.c_int_f, amp.c_ref_f, r_leak_ohm=2e9, i_bias_a=1e-10, da_gain_f=3e-7,
                        da_time_constant_s=12.0, correction=corr)
    est = StreamingEstimator(p, rec.t_s[1] - rec.t_s[0])
    streamed = np.array([est.update(a, b) for a, b in zip(rec.v_in_v, rec.v_out_v)])
    np.testing.assert_allclose(streamed, static_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, p), rtol=0, atol=1e-13)


def test_band_limited_drops_only_what_is_above_nyquist():
    w = 2 * np.pi * 70e3
    mode = control.ss(control.tf([w * w], [1, 2 * 0.02 * w, w * w]))
    slow = control.ss(control.tf([1, 2.0], [1, 1.0]))
    b = band_limited(mode * slow, 1e-4)
    assert b.nstates == 1 and float(np.real(b.dcgain())) == pytest.approx(2.0)
    s = 2j * np.pi * np.geomspace(0.01, 1000, 20)
    np.testing.assert_allclose(b(s), (mode * slow)(s), rtol=1e-3)


def test_cli_writes_json_and_figures(tmp_path, root):
    out, js = tmp_path / "out", tmp_path / "s.json"
    assert selfsense_main([str(root / "plants/p888_51_sn637.toml"), "--duration", "150s", "--no-loop",
                           "--out", str(out), "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert [s["name"] for s in data["stages"]] == list(STAGES)
    assert all({"name", "error_pp_m", "error_rms_m"} <= s.keys() for s in data["stages"])
    assert {f"stage_{n}.png" for n in STAGES} | {"noise.png", "report.md"} <= {p.name for p in out.iterdir()}


@pytest.mark.parametrize("argv, needle", [
    (["plants/no_such_plant.toml"], "no_such_plant.toml"),
    (["{plant}", "--duration", "20s"], "--duration"),
    (["{plant}", "--controller", "no_such_controller.json"], "no_such_controller.json"),
])
def test_cli_bad_input_exits_2_with_a_message(argv, needle, root, capsys):
    argv = [a.format(plant=root / "plants/p888_51_sn637_creep.toml") for a in argv]
    assert selfsense_main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "error" in err


def test_cli_bad_unit_is_an_argparse_error(root):
    with pytest.raises(SystemExit) as exc:
        selfsense_main([str(root / "plants/p888_51_sn637_creep.toml"), "--duration", "5V"])
    assert exc.value.code == 2


def test_selfsense_modules_do_not_import_the_cli(root):
    """Library first: nothing under workbench/selfsense imports workbench.cli (no library -> CLI cycle)."""
    import ast
    for path in sorted((root / "workbench/selfsense").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            assert not any(n == "cli" or n.endswith(".cli") or n == "workbench.cli" for n in names), (path, names)
