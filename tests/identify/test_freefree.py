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
