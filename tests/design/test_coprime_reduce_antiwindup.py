"""Glover-McFarlane synthesis, balanced reduction and the Hanus anti-windup form."""

import control
import numpy as np
import pytest

from workbench.design.antiwindup import (discretize, hanus, hanus_initial_state, rate_limits_v_per_s,
                                         run_hanus)
from workbench.design.coprime import ncf_margin, ncf_synthesis
from workbench.design.reduce import hankel_singular_values, reduce_controller
from workbench.errors import DesignError


def test_ncf_integrator_closed_form():
    # G = 1/s: X = Z = 1, so gamma_min = sqrt(2) and the best margin is 1/sqrt(2)
    g = control.tf([1], [1, 0])
    r = ncf_synthesis(g, control.tf([1], [1]), beta=0.9)
    assert r.eps_max == pytest.approx(1 / np.sqrt(2), rel=1e-9)
    assert 0.9 * r.eps_max <= r.eps <= r.eps_max                  # the controller keeps >= beta x optimum
    assert np.all(control.feedback(control.ss(g) * r.controller, 1).poles().real < 0)


def test_ncf_on_a_shaped_lag():
    g = control.tf([1], [1, 2, 1]) * control.tf([1], [1e-3, 1])
    w1 = control.tf([10, 10], [1, 0])
    r = ncf_synthesis(g, w1)
    assert np.all(control.feedback(control.ss(g) * r.controller, 1).poles().real < 0)
    # the central controller at gamma = gamma_min / beta guarantees b(G W1, K_inf) >= beta eps_max
    assert 0.9 * r.eps_max * (1 - 1e-6) <= r.eps <= r.eps_max < 1
    assert r.eps == pytest.approx(ncf_margin(r.shaped_plant, -r.controller * control.ss(1 / w1)), rel=1e-3)
    with pytest.raises(DesignError, match="beta"):
        ncf_synthesis(g, w1, beta=1.0)


def test_reduction_error_within_its_bound():
    rng = np.random.default_rng(3)
    poles = -np.sort(rng.uniform(1, 1e3, 6))
    k = control.zpk(-rng.uniform(1, 1e3, 5), poles, 1e3) * control.tf([1, 30], [1, 0])   # keeps an integrator
    red = reduce_controller(k, 4)
    assert red.order_after == 4 and red.controller.nstates == 4
    assert red.error_measured <= red.error_bound * (1 + 1e-6)
    assert np.min(np.abs(red.controller.poles())) < 1e-9             # the integrator survives
    with pytest.raises(ValueError, match="marginal"):
        reduce_controller(k, 0)


@pytest.mark.parametrize("slycot", [True, False])
def test_hankel_singular_values_closed_form(slycot, monkeypatch):
    """b c / (s + a) has the one Hankel singular value |b c| / (2 a); a sum of two far-apart lags has
    about one each. Without slycot (its Lyapunov solver refused) scipy's Gramians give the same."""
    if not slycot:
        monkeypatch.setattr(control, "hsvd", lambda sys: (_ for _ in ()).throw(ValueError("refused")))
    assert hankel_singular_values(control.ss(control.tf([3.0], [1, 2.0]))) == pytest.approx([0.75], rel=1e-12)
    two = control.ss(control.tf([1.0], [1, 1e-3]) + control.tf([1.0], [1, 1e3]))
    hsv = hankel_singular_values(two)
    assert np.all(np.isreal(hsv)) and hsv[0] == pytest.approx(1 / 2e-3, rel=1e-3)
    assert hsv[1] == pytest.approx(1 / 2e3, rel=1e-2)


def test_reduction_of_a_large_gain_integrator_controller_stays_within_its_bound():
    """An integrator of gain 1e3 with fast weak modes: the error measured on the stable parts stays
    under the bound (on K itself the integrator's rounding at 10 mHz would exceed it)."""
    s = control.tf("s")
    k = 1e3 / s * (1 + s / 300) + sum(1e-6 * 10.0 ** i / (s / (2e3 * (i + 1)) + 1) for i in range(4))
    red = reduce_controller(k, 3)
    assert np.isfinite(red.error_bound) and red.error_measured <= red.error_bound * (1 + 1e-6)


def test_a_near_integrator_is_kept_with_the_integrators_not_balanced():
    """A pole at -1e-11 rad/s (a synthesis's perturbed integrator) beside fast modes: balancing it
    would make the Gramians singular (slycot refuses, scipy perturbs and warns, which the suite turns
    into an error); it is kept exactly like the integrator, and the bound stays finite and holds."""
    s = control.tf("s")
    k = 1e3 / s + 50 / (s + 1e-11) + sum(1e-3 * 10.0 ** i / (s / (3e3 * (i + 1)) + 1) for i in range(4))
    red = reduce_controller(k, 4)
    assert np.isfinite(red.error_bound) and red.error_measured <= red.error_bound * (1 + 1e-6)
    assert np.sum(np.abs(red.controller.poles()) < 1e-6) == 2          # both slow poles survive


def _pi_lead():
    s = control.tf("s")
    return 300 * (1 + 2 * np.pi * 30 / s) * (1 + s / (2 * np.pi * 150)) / (1 + s / (2 * np.pi * 600))


def test_hanus_is_the_linear_controller_when_nothing_limits(sn637_creep):
    kd = discretize(_pi_lead(), 1e-4, 300.0)
    h = hanus(kd, (-20.0, 120.0), rate_limits_v_per_s(sn637_creep.pzt))
    x0 = hanus_initial_state(h, 50.0)
    assert float(np.squeeze(h.c @ x0)) == pytest.approx(50.0, rel=1e-12)     # bumpless start at the bias
    e = np.random.default_rng(1).normal(0, 1e-6, 300)
    u = run_hanus(h, e, 50.0, x0)
    lin = control.forced_response(kd, U=e, X0=x0).outputs
    assert np.max(np.abs(u - lin)) < 1e-9


def test_hanus_respects_rate_and_range_and_does_not_wind_up(sn637_creep):
    kd = discretize(_pi_lead(), 1e-4, 300.0)
    up, down = rate_limits_v_per_s(sn637_creep.pzt)
    h = hanus(kd, (-20.0, 120.0), (up, down))
    x0 = hanus_initial_state(h, 50.0)
    e = np.concatenate([np.full(3000, 0.5), np.full(3000, -0.5)])      # a large error, then reversed
    u = run_hanus(h, e, 50.0, x0)
    du = np.diff(np.concatenate([[50.0], u])) / 1e-4
    assert du.max() <= up * (1 + 1e-9) and -du.min() <= down * (1 + 1e-9)
    assert u.min() >= -20.0 and u.max() <= 120.0
    # conditioned on the limited output, the controller turns around as soon as the error does
    assert u[3001] < u[2999]
    with pytest.raises(DesignError, match="feedthrough"):
        hanus(control.ss(control.tf([1], [1, -0.5], 1e-4)), (-20, 120), (up, down))


def test_rate_limits_from_the_current_limits(sn637_creep):
    up, down = rate_limits_v_per_s(sn637_creep.pzt)
    assert down / up == pytest.approx(7.0, rel=1e-12)                   # 14 mA / 2 mA
    assert 100 < up < 228                                               # below the measured 228 V/s slew
    with pytest.raises(DesignError, match="prewarp"):
        discretize(_pi_lead(), 1e-4, 6000.0)
