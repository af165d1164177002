"""MIMO design of the three-stack mirror (issue 15 item 4): decoupling, margins two ways, IFF, the design's margins."""

import dataclasses
import re
from pathlib import Path

import control

import numpy as np
import pytest

from workbench.design import mimo
from workbench.design.margins import loop_margins
from workbench.linearize.mimo import gauge_gains, mirror_family, structural_modes
from workbench.linearize.small_signal import operating_point
from workbench.plant.mirror import load_mirror

ROOT = Path(__file__).resolve().parents[2]
FSM = ROOT / "plants" / "fsm_p888_51.toml"
# a lean grid: log 1 Hz - Nyquist, refined over the flexure modes
FREQ = np.unique(np.concatenate([np.geomspace(1.0, 4900.0, 260), np.arange(700.0, 1300.0, 4.0)]))


@pytest.fixture(scope="module")
def fsm():
    return load_mirror(FSM)


@pytest.fixture(scope="module")
def family(fsm):
    # the nominal branch (ascending) and the reversal (the smallest C_h slope: the lowest gain)
    return mirror_family(fsm, branches=("ascending", "reversal"))


@pytest.mark.parametrize("scales", [(1.0, 1.0, 1.0), (1.0, 0.85, 1.15), (1.2, 0.8, 0.95)])
def test_decoupled_dc_gain(fsm, scales):
    """Nominal member: G_dec(0) = I. Another branch: K diag(p_j / p_nom,j) K^-1 (closed form from the x outputs)."""
    m = fsm.with_capacitance_scales(scales)
    fam = mirror_family(m, branches=("ascending", "reversal"))
    nom = fam[mimo.nominal_name()]
    dec = mimo.kinematic_decoupler(m, nom)
    g_dc = np.asarray(nom[mimo.G, mimo.V].dcgain())
    assert np.allclose(dec.out_q_per_v @ g_dc @ dec.in_v_per_q, np.eye(3), atol=1e-5)   # the DC solve of a 13-state model: ~1e-6
    other = fam["reversal at 50 V, K_g nom"]
    ratio = np.diag(other[mimo.X, mimo.V].dcgain()) / np.diag(nom[mimo.X, mimo.V].dcgain())
    expect = m.kinematics @ np.diag(ratio) @ m.inverse_kinematics
    got = dec.out_q_per_v @ np.asarray(other[mimo.G, mimo.V].dcgain()) @ dec.in_v_per_q
    assert np.allclose(got, expect, atol=1e-5 * np.abs(expect).max())
    if len(set(scales)) > 1:    # unequal hysteresis: the branch member couples the axes
        assert np.abs(got - np.diag(np.diag(got))).max() > 1e-3


def test_force_estimate_dc_is_static_stiffness(fsm, family):
    """F_hat = T (q - T x) / C_p at DC equals the structure's static stiffness at each stack times x (closed form)."""
    kp = np.array([pz.stiffness_n_per_m for pz in fsm.stacks])
    ks, kg, a = fsm.series_stiffness_n_per_m, fsm.guide_stiffness_n_per_m, fsm.amplification
    k_u = ks * kp / (ks + kp) + a * a * kg
    beta = ks / (kp + ks)
    k_static = 1.0 / (1.0 / (kp + ks) + beta ** 2 / k_u)
    for name, member in family.items():
        # 10 mHz: quasi-static (the slowest pole is at 190 Hz), above where q = i / (j w) loses digits
        fh = mimo.force_estimate(fsm, member, [1e-2])[0]
        x = mimo.member_responses(member, [1e-2], mimo.X)[0]
        assert np.allclose(np.diag(fh) / np.diag(x), k_static, rtol=1e-4), name
        assert np.abs(fh - np.diag(np.diag(fh))).max() < 1e-5 * np.abs(np.diag(fh)).max()   # stacks decouple statically


@pytest.mark.parametrize("scales", [(1.0, 1.0, 1.0), (1.0, 0.85, 1.15), (1.3, 0.7, 1.0)])
def test_bridge_force_is_the_force_where_c_h_is_the_reference(fsm, scales):
    """T (V_t - q / C_R) with V_t = v - R i is T V_p = T (q - T x) / C_p exactly when C_R is the member's own
    C_h (no creep on the serial files); with C_R from another C_h (a stack scaled) it is not (> 1 % off)."""
    m = fsm.with_capacitance_scales(scales)
    nom = mirror_family(m, branches=("ascending",))[mimo.nominal_name()]
    own = mimo.bridge_capacitances_f(m)
    for cr, same in ((own, True), (mimo.bridge_capacitances_f(fsm), len(set(scales)) == 1)):
        fb = mimo.force_estimate(m, nom, FREQ, "bridge", cr)
        fg = mimo.force_estimate(m, nom, FREQ, "charge+gauge")
        err = np.abs(fb - fg).max(axis=0) / np.abs(fg).max(axis=0)          # per channel, over the grid
        if same:
            assert err.max() < 1e-6, (cr, err)
        else:
            assert err.max() > 1e-2, (cr, err)
    with pytest.raises(ValueError, match="reference capacitances"):
        mimo.IFF(0.1, 1.0, "bridge")
    with pytest.raises(ValueError, match="IFF source"):
        mimo.IFF(0.1, 1.0, "gauge")


def test_bridge_iff_damps_as_the_gauge_fed_one(fsm, family):
    """On the nominal member the bridge's estimate is the force itself: tune_iff picks the same gain and damping."""
    a, ia = mimo.tune_iff(fsm, family, source="charge+gauge")
    b, ib = mimo.tune_iff(fsm, family, source="bridge")
    assert b.gain_v_per_n == pytest.approx(a.gain_v_per_n, rel=1e-6)
    assert ib["zeta_min_damped"] == pytest.approx(ia["zeta_min_damped"], rel=1e-6)
    assert ib["zeta_min_damped"] > 2 * ib["zeta_min_open"]


def test_charge_only_iff_is_the_charge_and_damps_less(fsm, family):
    """``iff_source="charge"``: F_hat = T q / C_p, i.e. the gauge-fed estimate plus T^2 x / C_p (closed form, every
    member); tuned, it damps the flexure modes, but less than the force estimate does (its electrical part
    carries no force)."""
    t = np.array([pz.transducer_constant_n_per_v for pz in fsm.stacks])
    cp = np.array([pz.working_capacitance_f for pz in fsm.stacks])
    for name, member in family.items():
        fc = mimo.force_estimate(fsm, member, FREQ, "charge")
        fg = mimo.force_estimate(fsm, member, FREQ, "charge+gauge")
        x = mimo.member_responses(member, FREQ, mimo.X)
        np.testing.assert_allclose(fc - fg, (t * t / cp)[None, :, None] * x, rtol=1e-9,
                                   atol=1e-12 * np.abs(fc).max(), err_msg=name)
    c, ic = mimo.tune_iff(fsm, family, source="charge")
    g, ig = mimo.tune_iff(fsm, family, source="charge+gauge")
    assert ic["zeta_min_open"] < ic["zeta_min_damped"] < ig["zeta_min_damped"]


@pytest.mark.parametrize("seed", range(5))
def test_loop_at_a_time_is_the_schur_complement(seed):
    """With the other loops closed, channel i's sensitivity 1 / (1 + l_i) is [(I + L)^-1]_ii."""
    rng = np.random.default_rng(seed)
    loop = rng.normal(size=(50, 3, 3)) * 10 ** rng.uniform(-1, 1, (50, 1, 1)) + 1j * rng.normal(size=(50, 3, 3))
    l_i = mimo.loop_at_a_time(loop)
    s = np.linalg.inv(np.eye(3)[None] + loop)
    assert np.allclose(1.0 / (1.0 + l_i), np.einsum("fii->fi", s), rtol=1e-9, atol=1e-12)


def test_disk_margin_siso_and_diagonal_agree_with_loop_margins():
    """1x1 and diagonal loops: mu = sigma = |S - 1/2|, alpha = the worst channel's SISO disk margin."""
    f = np.geomspace(0.1, 1000.0, 4001)
    s = 2j * np.pi * f
    chans = [w / (s * (1 + s / 200.0)) for w in (100.0, 300.0, 600.0)]
    siso = [loop_margins(f, c).disk_margin for c in chans]
    for c, alpha in zip(chans, siso):
        assert mimo.mimo_disk_margin(f, c[:, None, None])["alpha"] == pytest.approx(alpha, rel=1e-4)
    diag = np.zeros((f.size, 3, 3), complex)
    for i, c in enumerate(chans):
        diag[:, i, i] = c
    dm = mimo.mimo_disk_margin(f, diag)
    assert dm["alpha"] == pytest.approx(min(siso), rel=1e-4)
    assert dm["alpha_unstructured"] == pytest.approx(dm["alpha"], rel=1e-6)


@pytest.mark.parametrize("seed", range(3))
def test_disk_margin_full_loop_agrees_with_python_control(seed, stable_rss):
    """Coupled 3x3 loop: alpha as python-control's disk_margins computes it; the unstructured bound below it."""
    rng = np.random.default_rng(seed)
    p = stable_rss(seed, 4, 3, 3, 1e-3, strictly_proper=True)
    k = control.ss([], [], [], 0.3 * np.eye(3) + 0.2 * rng.normal(size=(3, 3)))
    loop = p * k
    w = np.geomspace(1e-2, 1e3, 600)
    resp = np.moveaxis(np.asarray(loop(1j * w)), -1, 0)
    dm = mimo.mimo_disk_margin(w / (2 * np.pi), resp)
    ref = control.disk_margins(loop, w)[0]
    assert dm["alpha"] == pytest.approx(ref, rel=1e-6)
    assert dm["alpha_unstructured"] <= dm["alpha"] * (1 + 1e-9)


def test_notch_sits_on_the_flexure_modes(fsm, family):
    """The decoupled axes' resonance peaks are the amplifier-terminated tip, tilt and piston modes (poles)."""
    nom = family[mimo.nominal_name()]
    peaks = mimo.axis_resonances_hz(fsm, nom)
    caps = [operating_point(pz, 50.0, "ascending").capacitance_f for pz in fsm.stacks]
    modes, _ = structural_modes(fsm, "amplifier", caps)
    flex = np.sort(modes)[-3:]                       # piston, tip, tilt (the housing's two lie below)
    assert peaks[2] == pytest.approx(flex[0], rel=0.02)
    assert peaks[0] == pytest.approx(flex[1], rel=0.02)
    assert peaks[1] == pytest.approx(flex[2], rel=0.02)


def _torque_to_tip(fsm, member, f, iff):
    """tau_x -> tip_rad with the IFF loop closed (frequency domain, sampled IFF), rad per N m."""
    s = 2j * np.pi * f
    t = np.array([pz.transducer_constant_n_per_v for pz in fsm.stacks])
    cp = np.array([pz.working_capacitance_f for pz in fsm.stacks])
    def resp(outs, ins):
        return np.moveaxis(np.asarray(member[outs, ins](s)).reshape(len(outs), len(ins), f.size), -1, 0)
    def fhat(ins):
        return (t / cp)[None, :, None] * (resp(mimo.I_, ins) / s[:, None, None] - t[None, :, None] * resp(mimo.X, ins))
    direct = resp(["tip_rad"], ["tau_x"])[:, 0, 0]
    if iff is None:
        return direct
    c = mimo.iff_response(iff, f, 1e-4)[:, None, None]
    v = -np.linalg.solve(np.eye(3)[None] + c * fhat(mimo.V), c * fhat(["tau_x"]))      # stack voltages per N m
    return direct + (resp(["tip_rad"], mimo.V) @ v)[:, 0, 0]


def test_iff_damps_the_flexure_modes(fsm, family):
    """IFF from charge + gauge raises the flexure modes' damping (poles) and cuts the mirror's tip compliance peak."""
    nom = family[mimo.nominal_name()]
    iff, info = mimo.tune_iff(fsm, family)
    assert info["zeta_min_damped"] > 1.5 * info["zeta_min_open"]
    f = np.arange(950.0, 1200.0, 0.5)
    peaks = [np.abs(_torque_to_tip(fsm, nom, f, d)).max() for d in (None, iff)]
    # a resonance's peak scales as 1 / zeta: the pole damping's gain shows in the disturbance response
    assert peaks[1] < peaks[0] / 1.5, peaks


@pytest.mark.parametrize("damping", [False, True])
def test_design_margins_over_the_family(fsm, family, damping):
    """Per-axis design on the diagonal keeps PM 45 / GM 6 loop-at-a-time (MIMO) and alpha >= 0.4 simultaneous."""
    # a reduced shape grid (the margins must hold for whatever shape wins)
    spec = dataclasses.replace(mimo.MIMO_SPEC, fc_points=12, integral_ratios=(0.25, 1.0), rolloff_ratios=(8.0,))
    d = mimo.design_mimo(fsm, family, damping=damping, freq_hz=FREQ, spec=spec)
    for ax in mimo.AXIS_NAMES:
        rows, worst = d.lat[ax]
        assert len(rows) == len(family)
        assert abs(worst["phase_margin_deg"]["value"]) >= 45.0 - 0.5
        assert abs(worst["gain_margin_db"]["value"]) >= 6.0 - 0.1
        assert (d.notches[ax] is None) == damping
    iff = d.summary()["iff"]
    assert (iff is None) != damping
    if damping:       # the record names the force estimate (gauge-fed or bridge) and, for the bridge, its C_R
        assert iff["source"] == d.iff.source and iff["bridge_capacitance_f"] == (
            None if d.iff.bridge_capacitance_f is None else list(d.iff.bridge_capacitance_f))
    for disk in (d.disk_in, d.disk_out):
        assert disk["alpha"] >= 0.4
        assert disk["member"] in family
    # closed-loop poles (continuous, Pade of the sampled chain's lag): stable on every member, and the
    # smallest loop-at-a-time gain margin is where it stops being so (2.5 dB either side: Pade vs sampled)
    for name, member in family.items():
        assert mimo.closed_loop_poles(fsm, member, d).real.max() < 0, name
    gm_db = min(d.lat[ax][1]["gain_margin_db"]["value"] for ax in mimo.AXIS_NAMES)
    worst = family[d.lat[mimo.AXIS_NAMES[0]][1]["gain_margin_db"]["member"]]
    for db, stable in ((gm_db - 2.5, True), (gm_db + 2.5, False)):
        scaled = dataclasses.replace(d, axes={ax: dataclasses.replace(r, controller_c=r.controller_c * 10 ** (db / 20))
                                              for ax, r in d.axes.items()})
        assert (mimo.closed_loop_poles(fsm, worst, scaled).real.max() < 0) == stable, db
    # the firmware's gauge gains: the design uses the nominal chains
    assert np.allclose(np.linalg.inv(d.decoupler.out_q_per_v) @ fsm.kinematics, np.diag(gauge_gains(fsm)[:, 0]))


def test_iff_corner_is_derived_from_the_band_and_the_drifts(fsm, family, sn637_creep):
    """The IFF high-pass corner (iff_corner_hz): tan(phase cost) x the lowest crossover searched; the doublet it
    leaves in the damped plant, P / (1 + L0) (s + w_l) / (s + w_l / (1 + L0)), lags less than the phase cost at
    that crossover for any IFF loop gain L0 (closed form) and on the mirror's own damped nominal (the damped
    plant with the corner against the same IFF without a high-pass); the corner lies above the drifts the
    bridge reads, and a band too low for them is refused naming the drift."""
    from workbench.errors import DesignError
    fc_min = mimo.MIMO_SPEC.fc_range_hz[0]
    corner, info = mimo.iff_corner_hz(fsm, fc_min)
    assert corner == pytest.approx(np.tan(np.radians(mimo.IFF_PHASE_COST_DEG)) * fc_min, rel=1e-12)
    s = 2j * np.pi * fc_min
    wl = 2 * np.pi * corner
    for l0 in (0.1, 1.0, 3.0, 100.0, 1e6):
        lag = -np.degrees(np.angle((s + wl) / (s + wl / (1 + l0))))
        assert 0 < lag < mimo.IFF_PHASE_COST_DEG, l0
    # the real plant: the tuned bridge IFF, with and without its high-pass (corner 1e-9 Hz: the DC loop)
    nom = family[mimo.nominal_name()]
    iff, _ = mimo.tune_iff(fsm, family, source="bridge")
    assert iff.corner_hz == pytest.approx(corner)
    f = np.array([fc_min, 2 * fc_min])
    with_hp = mimo.damped_gauges(fsm, nom, f, iff)
    no_hp = mimo.damped_gauges(fsm, nom, f, dataclasses.replace(iff, corner_hz=1e-9))
    lag = -np.degrees(np.angle(np.einsum("fii->fi", with_hp) / np.einsum("fii->fi", no_hp)))
    assert np.all(lag[0] > 0) and np.all(lag[0] < mimo.IFF_PHASE_COST_DEG), lag
    assert np.all(lag[1] < lag[0])                     # the doublet's lag falls off above the corner
    # drifts: the charge amplifier's fastest (dielectric absorption, 5 s); with creep branches, the fastest (0.1 s)
    from workbench.selfsense.charge_amp import ChargeAmpParams
    tau = min(min(ChargeAmpParams().da_time_constants_s), ChargeAmpParams().r_leak_ohm * ChargeAmpParams().c_int_f)
    assert info["drift_hz"] == pytest.approx(1 / (2 * np.pi * tau)) and corner > 10 * info["drift_hz"]
    crept = dataclasses.replace(fsm, plants=tuple(dataclasses.replace(p, pzt=dataclasses.replace(
        p.pzt, creep=sn637_creep.pzt.creep)) for p in fsm.plants))
    tau_c = float(np.min(sn637_creep.pzt.creep.time_constants_s))
    assert mimo.iff_corner_hz(crept, fc_min)[1]["drift_hz"] == pytest.approx(1 / (2 * np.pi * tau_c))
    low = 0.5 / (2 * np.pi * tau_c) / np.tan(np.radians(mimo.IFF_PHASE_COST_DEG))
    with pytest.raises(DesignError, match="creep branch.*raise the lowest crossover"):
        mimo.iff_corner_hz(crept, low)
    # above the drift but inside the margin (corner = 2 x drift, the high-pass passing 45 % of it): refused too;
    # at the margin it passes, with margin and gain f_d / sqrt(f_d^2 + f_l^2) = 1 / sqrt(1 + m^2) reported
    m = mimo.IFF_DRIFT_MARGIN
    with pytest.raises(DesignError, match=rf"below {m:g} x .*creep branch.*raise the lowest crossover"):
        mimo.iff_corner_hz(crept, 4 * low)
    ok = mimo.iff_corner_hz(crept, 2 * m * low * (1 + 1e-9))[1]
    assert ok["drift_margin"] == pytest.approx(m) and ok["drift_gain"] == pytest.approx(1 / np.sqrt(1 + m * m))


def _bridge_noise_n(fsm):
    """Each bridge's force noise per reading, N: the charge amplifier's output noise and ADC LSB times T C_int / C_R."""
    from workbench.selfsense.charge_amp import ChargeAmpParams
    a = ChargeAmpParams()
    sb = np.sqrt(a.out_noise_v_rms ** 2 + (2 * a.adc_range_v / 2 ** a.adc_bits) ** 2 / 12)
    t = np.array([pz.transducer_constant_n_per_v for pz in fsm.stacks])
    return t * a.c_int_f / np.array(mimo.bridge_capacitances_f(fsm)) * sb


def test_iff_noise_is_held_to_the_current_window_budget(fsm, family):
    """The IFF's force-estimate noise on each stack's command lead must fit R min(I_source, I_sink) / 3 (the
    current window's noise budget, from the serial files): a bridge IFF gain twice the closed-form limit
    B / sigma_F is refused naming the budget and the largest gain; the gauge-fed IFF (8 N of force noise) under
    the budget gets its gain reduced below that limit."""
    from workbench.errors import DesignError
    b = np.array([p.pzt.series_resistance_ohm * min(p.pzt.current_limit_source_a, p.pzt.current_limit_sink_a) / 3
                  for p in fsm.plants])
    sf = _bridge_noise_n(fsm)
    np.testing.assert_allclose(mimo.force_noise_n(fsm, "bridge"), sf, rtol=1e-6)
    # white noise through the high-pass (|C| <= g) and the lead over the RC model (|H| <= 2 / (2 - alpha), at
    # Nyquist): sigma = g sigma_F x (a weighted mean of |H C / g|^2 that is ~1 above both corners)
    from workbench.controller import plant_window
    alpha = np.array([plant_window(p, 1e-4)[0] for p in fsm.plants])
    g_lim = float(np.min(b / sf))
    iff = mimo.IFF(g_lim, mimo.iff_corner_hz(fsm, mimo.MIMO_SPEC.fc_range_hz[0])[0], "bridge",
                   mimo.bridge_capacitances_f(fsm))
    ratio = mimo.iff_command_noise_v(fsm, iff, 1e-4) / (g_lim * sf)
    assert np.all(ratio > 0.9) and np.all(ratio <= 2 / (2 - alpha)), ratio
    budget = rf"noise budget R min\(I_source, I_sink\) / 3 = {re.escape(f'{1e3 * b.min():.3g}')} mV"
    with pytest.raises(DesignError, match=rf"^the IFF gain .* V/N .* {budget}.*use at most"):
        mimo.tune_iff(fsm, family, source="bridge", gains=[2 * g_lim], noise_budget=True)
    # half the limit fits the budget but not the IFF loop's margins (closed form: the tuned gain is ~0.08 V/N):
    # the refusal is the margins', citing the budget, not "use at most" a gain that fails anyway
    with pytest.raises(DesignError, match=rf"^no IFF gain of the 1 tried within the noise budget .*PM >= .*"
                                          rf"the other 1 broke .*{budget}"):
        mimo.tune_iff(fsm, family, source="bridge", gains=[2 * g_lim, 0.5 * g_lim], noise_budget=True)
    free, _ = mimo.tune_iff(fsm, family, source="charge+gauge")
    held, _ = mimo.tune_iff(fsm, family, source="charge+gauge", noise_budget=True)
    g_gauge = float(np.min(b / mimo.force_noise_n(fsm, "charge+gauge")))
    assert abs(held.gain_v_per_n) <= g_gauge < abs(free.gain_v_per_n)


@pytest.mark.parametrize("source", ["charge+gauge", "bridge"])
def test_iff_share_of_the_noise_budget_is_reported_and_warned(fsm, family, source):
    """design_mimo with the study's noise budget: the outer loops keep sqrt(1 - max_j (sigma_iff,j / B_j)^2) of
    it (recomputed from check_iff_noise of the designed IFF); the gauge-fed IFF (8 N of force-estimate noise)
    leaves them less than an equal split of the variance (1/sqrt(2)) and is warned about, the bridge IFF
    (~4 mN) is not."""
    import warnings
    from workbench.controller import plant_window
    from workbench.study.mirror import noise_gain_bound
    nom = family[mimo.nominal_name()]
    dt = float(fsm.plants[0].gauge.period_s)
    rho, _, _ = noise_gain_bound(fsm, mimo.kinematic_decoupler(fsm, nom), dt)
    spec = dataclasses.replace(mimo.MIMO_SPEC, dt_s=dt, fc_range_hz=(50.0, 70.0), max_noise_command_v=rho,
                               noise_reading_v=1.0,
                               voltage_alpha=float(min(plant_window(p, dt)[0] for p in fsm.plants)))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = mimo.design_mimo(fsm, family, damping=True, spec=spec, iff_source=source)
    lead, b = mimo.check_iff_noise(fsm, d.iff, dt)
    share = float(np.sqrt(1 - np.max(lead / b) ** 2))
    assert d.iff_info["outer_noise_share"] == pytest.approx(share, rel=1e-9)
    msgs = [str(w.message) for w in caught if "noise budget" in str(w.message)]
    low = share < mimo.IFF_MIN_OUTER_NOISE_SHARE
    assert low == (source == "charge+gauge"), share
    assert (len(msgs) == 1) == low and (d.iff_info["outer_noise_share_warning"] is not None) == low, msgs
    if low:
        assert f"keep {share:.2f}" in msgs[0] and source in msgs[0]


@pytest.mark.parametrize("stack,tau_s", [(0, 0.5), (1, 2.0), (2, 50.0)])
def test_iff_corner_reads_each_stacks_own_leakage(tmp_path, stack, tau_s):
    """A stack file's ``[leakage]`` moves the IFF corner's drift bound by its own channel only: tau = R_FP C_int
    of that stack (closed form), the fastest drift when under the assumed absorption's 5 s, named by its stack;
    the other stacks keep the assumed channel; a band whose corner lies inside the margin of that drift is
    refused naming the stack. The verified loop's bridge steps each stack with its own R_FP."""
    import shutil
    import tomllib
    from workbench.errors import DesignError
    from workbench.selfsense.charge_amp import ChargeAmpParams
    from workbench.verify.mirror import _bridge_table
    base = ChargeAmpParams()
    r_ohm = tau_s / base.c_int_f
    files = tomllib.loads(FSM.read_text())["stacks"]["files"]
    shutil.copy(FSM, tmp_path / FSM.name)
    for j, name in enumerate(files):
        text = (FSM.parent / name).read_text()
        if j == stack:
            text += f"\n[leakage]\nresistance_ohm = {r_ohm!r}\n"
        (tmp_path / name).write_text(text)
    fsm = load_mirror(tmp_path / FSM.name)
    amps = mimo.stack_charge_amps(fsm)
    assert amps[stack].r_leak_ohm == r_ohm
    assert all(a == base for j, a in enumerate(amps) if j != stack)
    fc_min = mimo.MIMO_SPEC.fc_range_hz[0]
    corner, info = mimo.iff_corner_hz(fsm, fc_min)
    tau_min = min(tau_s, min(base.da_time_constants_s))
    assert info["drift_hz"] == pytest.approx(1 / (2 * np.pi * tau_min), rel=1e-12)
    if tau_s < min(base.da_time_constants_s):
        assert info["drift_source"] == f"stack {stack}'s charge amplifier's R_FP C_int"
        m = mimo.IFF_DRIFT_MARGIN
        low = 0.5 * m / (2 * np.pi * tau_s) / np.tan(np.radians(mimo.IFF_PHASE_COST_DEG))
        with pytest.raises(DesignError, match=rf"stack {stack}'s charge amplifier's R_FP C_int \(tau {tau_s:.3g} s\)"):
            mimo.iff_corner_hz(fsm, low)
    else:
        assert "dielectric absorption" in info["drift_source"]

    class _Ctrl:                                       # the loop's bridge table without IFF reads only dt_s
        dt_s, iff = 1e-4, None
    cp = _bridge_table(_Ctrl, amps)[1]
    np.testing.assert_array_equal(cp[:, 1], [r_ohm if j == stack else base.r_leak_ohm for j in range(3)])
