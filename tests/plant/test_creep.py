"""Creep branches against seed 001's logarithmic law, and the law's least squares."""

import numpy as np
import pytest

from workbench.demo import creep_hold
from workbench.plant import log_creep, log_creep_fit

from ..conftest import FULL


def test_creep_plant_creeps_one_to_two_percent_per_decade(sn637_creep):
    hold = 1000.0 if FULL else 100.0
    tr, fit = creep_hold(sn637_creep, hold_s=hold, sample_s=1e-3)
    assert 0.01 <= fit.gamma <= 0.02           # seed 001: gamma between 0.01 and 0.02
    assert fit.l0 == pytest.approx(15e-6, rel=0.1)
    assert tr.x_m[-1] > tr.x_m[np.searchsorted(tr.t_s, 0.1)]  # it drifts up while held


def test_no_creep_section_means_no_drift(sn637):
    tr, _ = creep_hold(sn637, hold_s=20.0, sample_s=1e-3)
    late = tr.t_s > 1.0
    assert np.ptp(tr.x_m[late]) < 1e-15


def test_log_fit_recovers_the_law_and_its_uncertainty(rng):
    t = np.linspace(0.2, 20, 400)
    sigma = 2e-9
    truth = log_creep(t, 1.84e-6, 0.0137)      # seed 001 Fig. 7 values
    gammas, chis = [], []
    for _ in range(200):
        fit = log_creep_fit(t, truth + rng.normal(0, sigma, t.size), sigma=sigma)
        gammas.append(fit.gamma)
        chis.append(fit.chi2_reduced)
    fit = log_creep_fit(t, truth + rng.normal(0, sigma, t.size), sigma=sigma)
    assert np.mean(gammas) == pytest.approx(0.0137, abs=4 * np.std(gammas) / np.sqrt(len(gammas)))
    # the propagated sigma of gamma (eq. 7 with covariance) matches the scatter of the estimates
    assert fit.sigma_gamma == pytest.approx(np.std(gammas), rel=0.15)
    assert np.mean(chis) == pytest.approx(1.0, abs=0.05)
