"""The refitted mode's and delay's per-fold weights from shared row groups (issue 13, speed).

:meth:`Resonance.fold_columns` and :meth:`Delay.fold_columns` refit the drive model's ~26 weights on six row
sets (the development search rows and each fold's training search rows, ~4/5 of them each). Their normal
equations are now summed from the groups of rows the sets share (:func:`effects._row_groups`,
:func:`effects._row_set_normals`): one pass over the rows in place of six. These tests hold the sums to the
per-set products they replace (a numerical identity, to rounding) and the columns to the per-set fits.
Cheap: drawn arrays of a few thousand rows.
"""

import numpy as np
import pytest

from workbench.calibrate import effects as E
from workbench.calibrate.base_fit import _gram_solve


def _fold_sets(rng, n, n_folds=5):
    """Development rows and each fold's training rows among them, as the tracing builds them (sorted)."""
    dev = rng.random(n) < 0.8
    block = (np.arange(n) * n_folds) // n
    return [np.flatnonzero(dev)] + [np.flatnonzero(dev & (block != f) & (rng.random(n) < 0.97))
                                    for f in range(n_folds)]


@pytest.mark.parametrize("extra", ["none", "empty", "unsorted"])
def test_the_grouped_normal_equations_are_the_per_set_products(extra):
    rng = np.random.default_rng(31)
    n, k = 4_000, 7
    X = rng.standard_normal((n, k)) * np.logspace(-3, 3, k)
    r = rng.standard_normal(n)
    sets = _fold_sets(rng, n)
    if extra == "empty":
        sets.append(np.zeros(0, np.int64))
    elif extra == "unsorted":       # not strictly increasing (a repeated row): every set its own group
        sets.append(np.r_[np.flatnonzero(rng.random(n) < 0.3), 5, 5][::-1])
    union, groups = E._row_groups(sets, n)
    if extra != "unsorted":
        assert np.array_equal(union, np.flatnonzero(np.isin(np.arange(n), np.concatenate(sets))))
        # every row of the union in exactly one group; a group's rows in exactly the sets it names
        assert np.array_equal(np.sort(np.concatenate([idx for idx, _ in groups])), np.arange(union.size))
        for idx, ks in groups:
            for j, s in enumerate(sets):
                assert np.isin(union[idx], s).all() == (j in ks)
                assert np.isin(union[idx], s).any() == (j in ks)
    for full in (False, True):
        got = E._row_set_normals(X if full else X[union], r if full else r[union], groups, len(sets),
                                 union if full else None)
        for s, (G, h, m) in zip(sets, got):
            assert m == s.size
            # to rounding: each entry within 1e-12 of its Cauchy-Schwarz bound |x_i| |x_j| (|x_i| |r|)
            cn = np.sqrt(np.sum(X[s] ** 2, axis=0))
            assert np.all(np.abs(G - X[s].T @ X[s]) <= 1e-12 * np.outer(cn, cn))
            assert np.all(np.abs(h - X[s].T @ r[s]) <= 1e-12 * cn * np.linalg.norm(r[s]))


def _per_set_delta(X, r, lower):
    # the per-set construction the grouped one replaces (session 20's fold_columns, as written there)
    nrm = np.sqrt(np.mean(X * X, axis=0)) if X.shape[0] else np.ones(X.shape[1])
    nrm = np.where(nrm > 0, nrm, 1.0)
    Xs = X / nrm
    return _gram_solve(Xs.T @ Xs, Xs.T @ r, lower * nrm) / nrm


def _drive(rng, n, k):
    """A drive, plays-like columns of it (weights >= 0 in the model) and the model's prediction."""
    t = np.arange(n) * 1e-3
    u = np.sin(2 * np.pi * 3.0 * t) * (1 + 0.3 * t) + 0.05 * np.cumsum(rng.standard_normal(n)) / np.sqrt(n)
    q = np.linspace(-0.8, 0.8, k - 2)
    B = np.column_stack([u] + [np.abs(u - qj) for qj in q] + [np.ones(n)])
    w0 = rng.uniform(0.2, 1.0, k)
    return t, B, B @ w0, np.r_[-w0[:-1], -np.inf]


@pytest.mark.parametrize("kind, unsorted", [("resonance", False), ("delay", False), ("resonance", True)])
def test_the_fold_columns_are_the_per_set_fits(kind, unsorted):
    """Each row set's column from the grouped normal equations equals the column of the per-set fit (the
    drive model's corrections bounded as the base's), to 1e-7 of its RMS; also with a set not strictly
    increasing (a repeated row counted twice, as the per-set fit counts it)."""
    rng = np.random.default_rng(7)
    n, k = 6_000, 9
    t, B, ym, lower = _drive(rng, n, k)
    y = ym + 0.3 * np.sin(2 * np.pi * 7.0 * t) * ym + 1e-3 * rng.standard_normal(n)
    sets = _fold_sets(rng, n)
    if unsorted:
        sets[2] = np.r_[sets[2][::-1], sets[2][:50]]
    if kind == "resonance":
        eff, p = E.Resonance(basis=B), {"f_n_hz": 9.0, "zeta": 0.05}
        b, a = E._foh_mode(p["f_n_hz"], p["zeta"], E._dt(t))
        HB = B + eff._filtered(b, a, B)
        Hy = ym + eff._filtered(b, a, ym[:, None])[:, 0]
        ref = []
        for s in sets:
            m = ym + B @ _per_set_delta(HB[s], y[s] - Hy[s], lower)
            ref.append(eff._filtered(b, a, m[:, None])[:, 0])
    else:
        eff, p = E.Delay(basis=B), {"delay_samples": 13.6}
        d, all_rows = p["delay_samples"], np.arange(n, dtype=float)
        ref = []
        for s in sets:
            X = eff._rows_shifted(B, s, d)
            m = ym + B @ _per_set_delta(X, y[s] - eff._rows_shifted(ym[:, None], s, d)[:, 0], lower)
            ref.append(eff._rows_shifted(m[:, None], all_rows, d)[:, 0] - m)
    got = eff.fold_columns(t, y, ym, p, sets, lower)
    assert len(got) == len(sets)
    for g, c in zip(got, ref):
        assert np.sqrt(np.mean((g - c) ** 2)) <= 1e-7 * np.sqrt(np.mean(c * c))


def test_mode_column_rows_refuses_rows_out_of_order():
    """The review of s22_localrefit: rows not strictly increasing made the one-pass kernel return unset values
    ([50, 10, 60] gave [nan, 0, 0]); they are refused."""
    from workbench.calibrate.kernels import mode_column_rows
    u = np.sin(np.arange(100) / 7.0)
    b, a = [0.1, 0.2, 0.1], [1.0, -1.5, 0.7]
    for rows in ([50, 10, 60], [5, 5, 6], [-1, 3], [3, 100]):
        with pytest.raises(ValueError):
            mode_column_rows(u, b, a, np.array(rows))
    from scipy.signal import lfilter
    v = u - u[0]
    assert np.array_equal(mode_column_rows(u, b, a, np.array([0, 10, 99])), (lfilter(b, a, v) - v)[[0, 10, 99]])
