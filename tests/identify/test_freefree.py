"""The simulated free-free test reproduces seed 000 sec. 3.3 on every serial."""

from pathlib import Path

import numpy as np
import pytest

from workbench.identify import estimate_cp, estimate_k_q2x, hysteresis_fraction, run_freefree




def test_freefree_reproduces_the_seed(any_serial):
    res = run_freefree(any_serial)
    assert res.stroke_m == pytest.approx(15e-6, rel=0.05)            # ~15 um at 100 V
    assert 0.28 <= res.v_h_over_v_pea <= 0.40                        # V_h about a third of V_pea
    assert 0.08 <= res.hysteresis_x_fraction <= 0.15                 # 8-15 % of stroke
    assert res.ch_secant_f == pytest.approx(30.5e-6, rel=0.05)       # Fig. 7: ~30.5 uF
    assert res.cp_recovered_f == pytest.approx(res.cp_true_f, rel=0.01)  # eqs. 10-12 within 1 %
    # Fig. 9 vs Fig. 7: the voltage feedback of the full model shrinks the hysteresis in x
    assert res.hysteresis_x_fraction < res.hysteresis_q_fraction
    # currents of a 0.1 Hz sine stay far below the 2 mA source limit
    assert res.peak_current_a[0] < 1e-3


def test_eq12_inverts_eq10():
    t_em, k_p, c_p = 46.71, 2e8, 5.802e-6
    k_q2x = t_em / (k_p * c_p + t_em ** 2)
    assert estimate_cp(k_q2x, t_em, k_p) == pytest.approx(c_p, rel=1e-12)
    q = np.linspace(0, 1e-3, 50)
    assert estimate_k_q2x(q, k_q2x * q) == pytest.approx(k_q2x, rel=1e-12)


def test_hysteresis_fraction_of_a_known_loop():
    # an ellipse-like loop y = sin(t - phi) against v = sin(t): vertical thickness 2 sin(phi)
    t = np.linspace(0, 4 * np.pi, 4001)
    phi = 0.1
    frac = hysteresis_fraction(np.sin(t), np.sin(t - phi) + 2.0)
    assert frac == pytest.approx(2 * np.sin(phi) / (1 + 2.0), rel=1e-3)


def test_the_library_refuses_a_peak_whose_stroke_is_under_the_gauge_noise():
    """run_freefree itself (not only the CLI) refuses a v_peak below the stroke-equals-noise floor, naming
    the parameter; just above the floor it is accepted (review 3, item 9)."""
    from workbench.errors import FlagRangeError
    from workbench.identify.freefree import check_v_peak, v_peak_floor_v
    from workbench.plant import load_plant
    root = Path(__file__).resolve().parents[2]
    for name in ("p888_51_sn637", "p888_51_sn629", "p888_51_sn618"):
        plant = load_plant(root / "plants" / f"{name}.toml")
        floor = v_peak_floor_v(plant.pzt, plant.gauge.noise_rms_m)
        stroke = float(plant.pzt.quasi_static_x_m([0.0, floor])[-1])
        assert stroke == pytest.approx(plant.gauge.noise_rms_m, rel=1e-9)
        check_v_peak(plant, 1.01 * floor)                              # accepted
        check_v_peak(plant, plant.pzt.voltage_max_v)
        for bad in (0.99 * floor, 1e-9, 0.0, -1.0, 1.01 * plant.pzt.voltage_max_v):
            with pytest.raises(FlagRangeError, match="v_peak_v"):
                check_v_peak(plant, bad)
        with pytest.raises(FlagRangeError, match="under the gauge noise"):
            run_freefree(plant, v_peak_v=0.5 * floor)


@pytest.mark.parametrize("v_peak_v, freq_hz, resistor_in", [(100.0, 2.0, False), (60.0, 5.0, False),
                                                           (30.0, 20.0, False), (100.0, 2.0, True)])
def test_v_h_is_read_from_the_measured_voltage_where_the_current_limit_binds(any_serial, v_peak_v, freq_hz,
                                                                            resistor_in):
    """Where the amplifier's current limit binds (a 0..V sine faster than I / (pi C V) allows), the stack's
    voltage lags the command by tens of volts; eqs. 7-8 on the measured V_pea = V_t + R i recover the simulator's
    V_h to the gauge's noise (k_p sigma_x / T_em RMS), the command-based V_h does not (off by the lag). The
    draws span 2-20 Hz and 30-100 V, R out (seed 000's configuration) and in."""
    from workbench.identify import v_h_from_measurements
    pz = any_serial.pzt
    res = run_freefree(any_serial, v_peak_v=v_peak_v, freq_hz=freq_hz, cycles=2, resistor_in=resistor_in, seed=7)
    lag = np.abs(res.v_cmd_v - res.v_pea_v).max()
    noise_v = any_serial.gauge.noise_rms_m * pz.stiffness_n_per_m / pz.transducer_constant_n_per_v
    assert lag > 20 * noise_v                                   # it binds: the limit is not a round-off matter
    err = res.v_h_est_v - res.v_h_true_v
    assert np.sqrt(np.mean(err ** 2)) < 1.1 * noise_v          # to the gauge's noise
    assert abs(np.mean(err)) < 0.1 * noise_v                    # no bias from the lag
    cmd = v_h_from_measurements(res.v_cmd_v, res.x_meas_m, pz.transducer_constant_n_per_v, pz.stiffness_n_per_m)
    assert np.sqrt(np.mean((cmd - res.v_h_true_v) ** 2)) > 10 * noise_v


def test_where_the_limit_never_binds_the_measured_voltage_is_the_command(sn637_creep):
    """The default test (100 V, 0.1 Hz: 0.38 mA against the 2 mA source limit) with R out: V_pea = V_t is the
    command to round-off, so eqs. 7-8 give what they gave on the command."""
    from workbench.identify import v_h_from_measurements
    pz = sn637_creep.pzt
    res = run_freefree(sn637_creep, seed=2)
    assert np.abs(res.v_pea_v - res.v_cmd_v).max() < 1e-12 * 100.0
    cmd = v_h_from_measurements(res.v_cmd_v, res.x_meas_m, pz.transducer_constant_n_per_v, pz.stiffness_n_per_m)
    np.testing.assert_allclose(res.v_h_est_v, cmd, rtol=0, atol=1e-12 * 100.0)
