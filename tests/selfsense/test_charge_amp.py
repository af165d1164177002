"""The charge channel reads the plant file's [leakage] and [dielectric_absorption] (charge_amp_params)."""

import numpy as np
import pytest

from workbench.plant import load_plant
from workbench.plant.simulator import PZTSimulator
from workbench.selfsense.charge_amp import ChargeAmpParams, charge_amp_params, measure
from workbench.selfsense.estimator import EstimatorParams, static_estimate

from ..conftest import PLANTS

CREEP = PLANTS / "p888_51_sn637_creep.toml"
DT = 1e-3          # the channel's closed forms hold at any rate; 1 kHz keeps the records short


def _plant(tmp_path, extra, name):
    p = tmp_path / f"{name}.toml"
    p.write_text(CREEP.read_text() + "\n" + extra)
    return load_plant(p)


def _uncompensated_estimate(plant, amp, v_hold, ramp_s, hold_s):
    """The stage-1 estimate (no leakage, bias or absorption taken out) of a ramp from rest to ``v_hold`` over
    ``ramp_s`` and a hold to ``hold_s``, noise-free channel: (t, estimate m, V_t)."""
    n_r, n = int(round(ramp_s / DT)), int(round(hold_s / DT))
    v = np.concatenate([np.linspace(0.0, v_hold, n_r + 1)[1:], np.full(n - n_r, v_hold)])
    rec = measure(PZTSimulator(plant.pzt, DT).run(v), amp)
    p = EstimatorParams(1.0 / plant.pzt.k_q2x_m_per_c, amp.c_int_f, amp.c_ref_f)
    return rec.t_s, static_estimate(rec.t_s, rec.v_in_v, rec.v_out_v, p)


def test_a_plant_without_the_sections_keeps_the_assumed_channel():
    assert charge_amp_params(load_plant(CREEP)) == ChargeAmpParams()
    base = ChargeAmpParams(c_int_f=22e-6)
    assert charge_amp_params(load_plant(CREEP), base) is base


@pytest.mark.parametrize("r_ohm", [1e8, 2e8, 5e9])
def test_a_stronger_leakage_drifts_the_charge_estimate_by_its_closed_form(tmp_path, r_ohm):
    """R_FP from the file: the uncompensated estimate gains int V_t dt / R_FP / alpha (seed 002 eq. 2.7), so
    against the assumed 1 GOhm a 50 V hold reached by a 1 s ramp drifts by 50 V (T - 0.5 s) (1/R - 1/1e9) / alpha
    more at T (the RC lag of V_t behind the command, ~1 ms, is 1e-4 of it)."""
    leaky = _plant(tmp_path, f"[leakage]\nresistance_ohm = {r_ohm!r}\n", "leaky")
    base = _plant(tmp_path, "", "base")
    ideal = ChargeAmpParams().ideal()
    amp = charge_amp_params(leaky, ideal)
    assert amp.r_leak_ohm == r_ohm and amp.da_gains_f == ideal.da_gains_f
    t, e_leaky = _uncompensated_estimate(leaky, amp, 50.0, 1.0, 20.0)
    _, e_base = _uncompensated_estimate(base, charge_amp_params(base, ideal), 50.0, 1.0, 20.0)
    alpha = 1.0 / leaky.pzt.k_q2x_m_per_c
    want = 50.0 * (t[-1] - 0.5) * (1.0 / r_ohm - 1.0 / ideal.r_leak_ohm) / alpha
    assert abs(want) > 1e-9                                    # nanometres at least: a visible drift
    assert e_leaky[-1] - e_base[-1] == pytest.approx(want, rel=2e-3)


@pytest.mark.parametrize("gain_f, tau_s", [(0.1e-6, 0.5), (1.0e-6, 2.0)])
def test_the_files_absorption_replaces_the_assumed_two_branches(tmp_path, gain_f, tau_s):
    """[dielectric_absorption] k_s, tau: one relaxation in place of the assumed two. Two plants that differ only
    in k_s differ in the uncompensated estimate, once the hold is many tau long, by V (k_2 - k_1) / alpha
    (Q_DA -> k_s V, seed 002 eq. 2.9)."""
    def plant(k, name):
        return _plant(tmp_path, f"[dielectric_absorption]\ngain_f = {k!r}\ntime_constant_s = {tau_s!r}\n", name)
    ideal = ChargeAmpParams().ideal()
    p1, p2 = plant(gain_f, "a"), plant(2.5 * gain_f, "b")
    amp1, amp2 = charge_amp_params(p1, ideal), charge_amp_params(p2, ideal)
    assert amp1.da_gains_f == (gain_f,) and amp1.da_time_constants_s == (tau_s,)
    assert amp1.r_leak_ohm == ideal.r_leak_ohm
    hold = 1.0 + 15 * tau_s
    _, e1 = _uncompensated_estimate(p1, amp1, 50.0, 1.0, hold)
    _, e2 = _uncompensated_estimate(p2, amp2, 50.0, 1.0, hold)
    alpha = 1.0 / p1.pzt.k_q2x_m_per_c
    assert e2[-1] - e1[-1] == pytest.approx(50.0 * 1.5 * gain_f / alpha, rel=1e-3)


def test_the_verify_harness_reads_the_plants_leakage(tmp_path):
    """sensor_setup builds its channel from the plant file, and the staged identification finds the file's
    R_FP (the stage-2 compensation then takes out the stronger leakage, not the assumed one)."""
    from workbench.controller import Controller
    from workbench.verify.sensors import sensor_setup
    from ..conftest import ROOT
    leaky = _plant(tmp_path, "[leakage]\nresistance_ohm = 2e8\n", "leaky")
    st = sensor_setup(leaky, Controller.load(ROOT / "controllers" / "sn637_fused_loopshape.json"),
                      ident_hold_s=150.0)
    assert st.amp.r_leak_ohm == 2e8
    assert st.ident.r_leak_ohm == pytest.approx(2e8, rel=0.1)


@pytest.mark.parametrize("study", ["force", "dynamics"])
def test_the_force_and_dynamics_studies_identify_on_the_plant_files_channel(tmp_path, monkeypatch, study):
    """selfsense --force and --dynamics build the same channel from the plant file as selfsense does: the
    identification record they simulate first is made with the file's R_FP and single absorption branch
    (caught at that first call, so no record is simulated)."""
    import importlib
    ident_mod = importlib.import_module("workbench.selfsense.identify")      # the module (the package shadows it)
    from workbench.selfsense.force import run_force_study
    from workbench.selfsense.sysid import run_dynamics_study
    path = tmp_path / "leaky.toml"
    path.write_text(CREEP.read_text() + "\n[leakage]\nresistance_ohm = 2e8\n"
                    "[dielectric_absorption]\ngain_f = 1.5e-7\ntime_constant_s = 3.0\n")

    class Seen(Exception):
        pass

    def catch(pzt, amp, **kw):
        raise Seen(amp)

    monkeypatch.setattr(ident_mod, "simulate_identification", catch)
    run = run_force_study if study == "force" else run_dynamics_study
    with pytest.raises(Seen) as got:
        run(path)
    amp = got.value.args[0]
    assert amp == charge_amp_params(load_plant(path))
    assert (amp.r_leak_ohm, amp.da_gains_f, amp.da_time_constants_s) == (2e8, (1.5e-7,), (3.0,))
