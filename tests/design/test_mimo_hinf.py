"""MIMO H-infinity mixed sensitivity on the mirror (issue 15 item 4) and the mass sweep's mirror scaling."""

import warnings
from pathlib import Path

import control
import numpy as np
import pytest

from workbench.design import mimo, mimo_hinf as mh
from workbench.design.mimo_sweep import scaled_mirror
from workbench.linearize.mimo import mirror_family
from workbench.plant.mirror import load_mirror

ROOT = Path(__file__).resolve().parents[2]
FSM = ROOT / "plants" / "fsm_p888_51.toml"
FREQ = np.unique(np.concatenate([np.geomspace(1.0, 4900.0, 260), np.arange(700.0, 1300.0, 4.0)]))


@pytest.fixture(scope="module")
def fsm():
    return load_mirror(FSM)


@pytest.fixture(scope="module")
def family(fsm):
    return mirror_family(fsm, branches=("ascending", "reversal"))


@pytest.fixture(scope="module")
def design(fsm, family):
    # one synthesis at a fixed W_s bandwidth (the bisection is the same call repeated), full firmware order
    return mh.design_hinf(fsm, family, bandwidth_rad_s=400.0, freq_hz=FREQ, start_method="fork", time_limit_s=120.0)


def test_design_plant_is_the_nominal_in_gauge_coordinates(fsm, family):
    """T^-1 G_dec T = G_gv diag(1/(p K_g)): DC gain I on the nominal member (the Pade's DC gain is 1)."""
    gp = mh.design_plant(fsm, family[mimo.nominal_name()])
    assert np.allclose(np.asarray(gp.dcgain()), np.eye(3), atol=1e-5)
    # and the members' responses (exact sampled chain) match the continuous model to the Pade's error at 10 Hz
    dec = mimo.kinematic_decoupler(fsm, family[mimo.nominal_name()])
    p = mh.member_plants(fsm, {"n": family[mimo.nominal_name()]}, dec, [10.0])["n"][0]
    assert np.allclose(p, mh._mimo_response(gp, [10.0])[0], atol=1e-4)


def test_weights_from_the_targets_and_the_family(fsm, family):
    """W_s's floor from the triangle target, W_u from the amplifier span, W_t covers the family's deviation."""
    assert mh.min_bandwidth_rad_s() == pytest.approx(2 * 0.8 * 0.1 / 1e-3)        # 160 rad/s
    w = mh.hinf_weights(fsm, family, bandwidth_rad_s=500.0, freq_hz=FREQ)
    assert abs(complex(np.squeeze(w.w_s(0)))) == pytest.approx(1 / mh.LOW_FREQ_S, rel=1e-9)
    assert abs(complex(np.squeeze(w.w_s(1e9j)))) == pytest.approx(1 / mh.PEAK_S, rel=1e-6)
    # |W_s(j w_b)| ~ 1: the sensitivity bandwidth
    assert abs(complex(np.squeeze(w.w_s(500j)))) == pytest.approx(1.0, rel=0.15)
    assert np.squeeze(np.asarray(w.w_u.D)) == pytest.approx(100.0 / 140.0)           # 0-100 V stroke of -20..120 V
    env = w.derivation["w_t_envelope"]
    wt = np.abs(mh._mimo_response(w.w_t, FREQ)[:, 0, 0])
    assert np.all(wt >= env * 10 ** (0.4 / 20)), "W_t must cover every member's relative deviation"
    # the reversal branch and the gauge corners deviate by tens of percent at DC; the Pade near Nyquist by ~1
    assert 0.2 < env[0] < 0.8 and env[-1] > 0.8


def test_weighted_norms_below_gamma_two_ways(fsm, design):
    """SB10AD's gamma = the stacked norm from frequency responses = L-inf norm of the state-space closed loop."""
    p = design.peaks
    g = design.gamma
    for key in ("S", "KS", "T"):
        assert p[key] <= g * (1 + 1e-6), key
    assert p["stacked"] == pytest.approx(g, rel=2e-3)             # the grid's sup reaches gamma
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        aug = control.augw(design.plant, design.weights.w_s, design.weights.w_u, design.weights.w_t)
    cl = aug.lft(design.controller_full)
    assert cl.poles().real.max() < 0
    # the state-space closed loop on the grid is the frequency-response computation
    sv = np.linalg.svd(mh._mimo_response(cl, FREQ), compute_uv=False)[:, 0]
    # (2e-3: at 1 Hz |S| ~ 1e-3 is a difference of near-equal numbers in (I + G K)^-1)
    assert sv.max() == pytest.approx(p["stacked"], rel=2e-3)
    # slycot AB13DD's L-inf norm over all frequencies: measured 1.5 % above gamma, at DC exactly, where the
    # controller's near-integrator meets W_s's pole (rcond of the X-Riccati ~1e-16); 1e-3 above 0.05 Hz
    assert control.linfnorm(cl)[0] == pytest.approx(g, rel=2e-2)


def test_every_member_stable_and_margins(fsm, family, design):
    """The reduced, sampled controller: closed loop stable on every member (Pade chain); margins named per member."""
    for name, member in family.items():
        assert mh.hinf_closed_loop_poles(fsm, member, design).real.max() < 0, name
    assert design.reduction["order_after"] == mh.FIRMWARE_ORDER
    # balanced truncation: the measured error never exceeds twice the discarded Hankel singular values
    assert design.reduction["error_measured"] <= design.reduction["error_bound"] * (1 + 1e-6)
    for disk in (design.disk_in, design.disk_out):
        assert disk["member"] in family
        assert disk["alpha_unstructured"] <= disk["alpha"] * (1 + 1e-6)
    for ax in mimo.AXIS_NAMES:
        rows, worst = design.lat[ax]
        assert len(rows) == len(family)
    # the comparison table renders: 2 tables, every row with its header's column count
    table = mimo.comparison_markdown(design, design, design)
    for block in table.split("\n\n"):
        lines = block.splitlines()
        assert all(line.count("|") == lines[0].count("|") for line in lines)
    assert len(table.splitlines()) == 2 + 9 + 1 + 2 + 3


@pytest.mark.parametrize("seed", range(3))
def test_mimo_reduction_within_its_bound(seed, stable_rss):
    """reduce_mimo: sigma_max(K - K_r) <= 2 x sum of the discarded Hankel singular values, with an integrator kept."""
    rng = np.random.default_rng(seed)
    k = stable_rss(seed, 10, 3, 3, 1e-2)
    integ = control.ss([[0.0]], [[1.0, 0.5, rng.normal()]], [[1.0], [0.3], [rng.normal()]], np.zeros((3, 3)))
    full = control.parallel(k, integ)
    f = np.geomspace(1e-3, 1e3, 400)
    kr, bound, err = mh.reduce_mimo(full, 5, f)
    assert kr.nstates == 5
    assert err <= bound * (1 + 1e-6)


def test_scaled_mirror_moves_the_modes_not_the_statics(fsm):
    """Mass and inertia x s: kinematics and the static map unchanged; the piston mode moves by exactly 1/sqrt(s).

    (Piston does not rock the housing, so its mode is the lever stiffness over the moving mass alone;
    tip and tilt share their motion with the unscaled housing, which the sweep measures instead.)
    """
    f0 = fsm.modes()[0]
    f_piston = 827.0                                              # README: mechanics-only piston mode, Hz
    for s in (0.25, 4.0):
        m = scaled_mirror(fsm, s)
        assert np.allclose(m.kinematics, fsm.kinematics, rtol=1e-12)
        assert m.kinematic_error < 1e-12
        f1 = m.modes()[0]
        p0 = f0[np.argmin(np.abs(f0 - f_piston))]
        assert np.min(np.abs(f1 / (p0 / np.sqrt(s)) - 1)) < 1e-9, (s, f1)
    assert fsm.mass_kg == load_mirror(FSM).mass_kg                  # the loaded object is not modified
    with pytest.raises(ValueError):
        scaled_mirror(fsm, 0.0)
