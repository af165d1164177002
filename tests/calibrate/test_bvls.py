"""The compiled bounded solve (workbench.calibrate.bvls) against scipy's lsq_linear(method="bvls").

Both run the same algorithm; only the BLAS/LAPACK builds doing the arithmetic differ (numba binds
SciPy's, numpy its own), so the answers may differ by rounding, never by more. The agreement is
stated where it is unique: the objective and the fitted values ``R x`` (unique at the optimum even
when ``x`` is not: a rank-deficient ``R``), and ``x`` itself when ``R`` is well conditioned.
"""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.optimize import lsq_linear

from workbench.calibrate import base_fit
from workbench.calibrate.base_fit import small_problem
from workbench.calibrate.bvls import bvls

#: Agreement bounds, relative to ``||c||`` (fitted values, objective's square root) and to ``max |x|``
#: (``x``, condition number of ``R'R`` below ``WELL_CONDITIONED``): rounding of the same iterations,
#: ~1e-16 per operation, amplified by the condition of the free columns' solves (<= 1e12 by the
#: square root's eigenvalue cut) at most to ~1e-10; a different iterate (a bound taken or released
#: that the reference did not) moves them by far more.
FIT_RTOL = 1e-8
X_RTOL = 1e-8
WELL_CONDITIONED = 1e6


def _reference(R, c, lower, upper):
    return lsq_linear(R, c, bounds=(lower, upper), method="bvls", tol=1e-12).x


def _assert_agrees(R, c, lower, upper, x_ref, x):
    assert x.shape == x_ref.shape
    # feasible up to the rounding of BVLS's step to a bound (x (1 - alpha) + alpha z, not the bound itself)
    slack = 1e-12 * max(float(np.max(np.abs(x_ref))), 1.0)
    assert np.all(x >= lower - slack) and np.all(x <= upper + slack)
    scale = max(float(np.linalg.norm(c)), 1e-300)
    fit_ref, fit = R @ x_ref - c, R @ x - c
    assert np.linalg.norm(fit - fit_ref) <= FIT_RTOL * scale                  # fitted values
    assert abs(np.linalg.norm(fit) - np.linalg.norm(fit_ref)) <= FIT_RTOL * scale   # objective's root
    sv = np.linalg.svd(R, compute_uv=False)
    if sv.size and sv[-1] * np.sqrt(WELL_CONDITIONED) > sv[0]:          # cond(R'R) < WELL_CONDITIONED
        assert np.max(np.abs(x - x_ref)) <= X_RTOL * max(float(np.max(np.abs(x_ref))), 1.0)


@settings(max_examples=80, deadline=None)
@given(n=st.integers(1, 40), rank_share=st.floats(0.05, 1.0), spread=st.floats(0.0, 3.0),
       p_free=st.floats(0.0, 0.6), p_upper=st.sampled_from([0.0, 0.0, 0.3]), seed=st.integers(0, 2**31 - 1))
def test_compiled_bvls_equals_scipys_on_drawn_problems(n, rank_share, spread, p_free, p_upper, seed):
    """Rank-deficient Gram matrices (rank down to 1 of 40), columns scaled over ``10**+-spread``, lower bounds
    ``-inf`` (share ``p_free``), above (active) or below (inactive) the unconstrained solution, some upper
    bounds: the square-root system the callers build (``small_problem``), solved both ways."""
    rng = np.random.default_rng(seed)
    rank = max(1, int(round(rank_share * n)))
    A = rng.standard_normal((3 * n + 5, rank)) @ rng.standard_normal((rank, n))
    A *= 10.0 ** rng.uniform(-spread, spread, n)
    y = A @ rng.standard_normal(n) + rng.standard_normal(A.shape[0])
    R, c = small_problem(A, y)
    x_u = np.linalg.lstsq(R, c, rcond=None)[0]
    mag = np.abs(x_u) + np.max(np.abs(x_u)) * 1e-3 + 1e-300
    lower = x_u + mag * rng.uniform(-1.0, 1.0, n)              # about half above x_u: active
    lower[rng.random(n) < p_free] = -np.inf
    upper = np.full(n, np.inf)
    up = rng.random(n) < p_upper
    upper[up] = np.maximum(lower[up], x_u[up]) + mag[up] * rng.uniform(0.01, 1.0, up.sum())
    x_ref = _reference(R, c, lower, upper)
    x = bvls(R, c, lower, upper)
    _assert_agrees(R, c, lower, upper, x_ref, x)


def test_unconstrained_solution_inside_the_bounds_is_returned():
    """lsq_linear's first step: a lstsq solution within the bounds is the answer (no BVLS iteration)."""
    rng = np.random.default_rng(7)
    A = rng.standard_normal((30, 6))
    R, c = small_problem(A, A @ np.arange(1.0, 7.0) + 0.01 * rng.standard_normal(30))
    lower = np.zeros(6)
    x = bvls(R, c, lower)
    np.testing.assert_allclose(x, np.linalg.lstsq(R, c, rcond=-1)[0], rtol=1e-12)
    assert np.all(x > lower)


def test_base_fit_problems_of_a_traced_record(sn637, monkeypatch):
    """The problems a base fit of a short creep record poses (3,000 rows of the steps protocol at 1 kHz: play
    columns, rank-deficient where plays never engage, a free offset), each solved both ways."""
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
    from tests.conftest import load_benchmark
    cc = load_benchmark("calibrate_confusion")
    plant, _ = plant_with_effect(sn637, "creep", 3)
    t, v = benchmark_protocol("steps", 1e3, 3000)
    r = simulate_record(plant, t, v, seed=3)
    sp = make_split(t, r["voltage_v"], "blocks")
    seen = []

    def record(R, c, lower, tol=1e-12):
        seen.append((np.array(R), np.array(c), np.array(lower, float), tol))
        return bvls(R, c, lower, tol=tol)

    monkeypatch.setattr(base_fit, "bvls", record)
    base_fit.fit_base(cc._record(r, 1e-3), sn637.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                      pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    bounded = [s for s in seen if not np.all(np.linalg.lstsq(s[0], s[1], rcond=-1)[0] >= s[2])]
    assert len(bounded) >= 20                      # the record exercises BVLS, not only its first step
    for R, c, lower, tol in bounded[:: max(1, len(bounded) // 40)]:
        upper = np.full(lower.size, np.inf)
        _assert_agrees(R, c, lower, upper, _reference(R, c, lower, upper), bvls(R, c, lower, tol=tol))


def test_a_non_finite_system_goes_to_scipy():
    """Non-finite systems get scipy's own answer (an infinite right-hand side: NaN weights), where the compiled
    kernel itself would raise (numba's lstsq refuses non-finite input): the fallback is what answers."""
    from workbench.calibrate.bvls import _bvls
    R, c, lower, upper = np.eye(2), np.array([np.inf, 1.0]), np.zeros(2), np.full(2, np.inf)
    ref = _reference(R, c, lower, upper)
    assert np.all(np.isnan(ref))
    with pytest.raises(Exception):
        _bvls(R.copy(), c.copy(), lower.copy(), upper.copy(), 1e-12)
    np.testing.assert_array_equal(bvls(R, c, lower), ref)


def test_bounds_of_the_wrong_shape_go_to_scipy():
    """A ``lower`` shorter than the unknowns: scipy's error, not a read past the array's end."""
    R, c = np.eye(5), np.arange(5.0)
    with pytest.raises(ValueError, match="shape"):
        _reference(R, c, np.zeros(3), np.full(3, np.inf))
    with pytest.raises(ValueError, match="shape"):
        bvls(R, c, np.zeros(3))
