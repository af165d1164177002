"""The calibration's fast paths give the numbers of the code as first written (issue 13).

Each speed-up keeps its slow reference in the product code: ``_varpro`` without
``row_columns`` (every column over the whole record, then the search rows),
``Delay._residual_fn_reference`` (the whole prediction shifted, then the rows) and the scipy
filters of the effects (``Resonance._column``, ``lowpass``) for the compiled kernels of
:mod:`workbench.calibrate.kernels`. The kernels are compared with the filters over a wide
draw of modes, time constants and sample rates; the whole calibration of a synthetic record
is run both ways and its JSON compared number by number.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import PLANTS
from workbench.calibrate import effects
from workbench.calibrate.effects import Delay, Resonance, _foh_mode, lowpass
from workbench.calibrate.kernels import lowpass_rows, mode_column_rows, mode_columns_rows
from workbench.calibrate.run import run_calibrate
from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record, write_record

RATES_HZ = (100.0, 1e3, 1e4, 1e5, 1e6)


def _input(rng, n):
    """A wandering input with steps and a sine: the kind of drive the searches filter."""
    u = np.cumsum(rng.standard_normal(n)) / np.sqrt(n)
    u += np.where(np.arange(n) > n // 3, 0.7, 0.0) + 0.3 * np.sin(np.linspace(0, 12 * np.pi, n))
    return 1e-5 * u + rng.uniform(-2e-5, 2e-5)


def _rows(rng, n):
    keep = rng.random(n) < rng.uniform(0.05, 1.0)
    keep[rng.integers(n)] = True
    return np.flatnonzero(keep)


@pytest.mark.parametrize("seed", range(6))
def test_mode_kernel_equals_scipy_filter(seed):
    """The compiled biquad = ``Resonance._column`` at the rows, for modes drawn over the whole
    search range (1 Hz to the Nyquist frequency since session 19, damping 0.002 to 0.3 within the
    search's half-power cap ``f_N / f - 1``) at 100 Hz .. 1 MHz."""
    rng = np.random.default_rng(seed)
    rate = RATES_HZ[seed % len(RATES_HZ)]
    n = int(rng.integers(2_000, 40_000))
    dt = 1.0 / rate
    u = _input(rng, n)
    rows = _rows(rng, n)
    for _ in range(8):
        f_n = float(np.exp(rng.uniform(np.log(1.0), np.log(0.5 * rate))))
        zeta = min(float(np.exp(rng.uniform(np.log(0.002), np.log(0.3)))), max(0.5 * rate / f_n - 1.0, 0.002))
        ref = Resonance._column(u, f_n, zeta, dt)[rows]
        fast = mode_column_rows(u, *_foh_mode(f_n, zeta, dt), rows)
        np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))


@pytest.mark.parametrize("seed", range(5))
def test_batched_mode_kernel_equals_one_filter_at_a_time(seed):
    """Several biquads in one pass (the grid search's and the Jacobian's form) = each filter
    alone, bit for bit, for modes over the whole search range at 100 Hz .. 1 MHz, batches of 1,
    2 (the pair kernel), 3 (the triple: a point and its Jacobian's) and up to 40 filters, rows from a
    few to all (and none)."""
    rng = np.random.default_rng(400 + seed)
    rate = RATES_HZ[seed % len(RATES_HZ)]
    n = int(rng.integers(2_000, 40_000))
    dt = 1.0 / rate
    u = _input(rng, n)
    for rows, k in ((_rows(rng, n), 1), (_rows(rng, n), 2), (_rows(rng, n), 3), (_rows(rng, n), int(rng.integers(4, 41))),
                    (np.arange(n), int(rng.integers(1, 41))), (np.array([n - 1]), 2), (np.zeros(0, np.int64), 3)):
        fs_n = np.exp(rng.uniform(0.0, np.log(0.5 * rate), k))          # up to Nyquist (session 19)
        filters = [_foh_mode(float(f), min(float(np.exp(rng.uniform(np.log(0.002), np.log(0.3)))),
                                           max(0.5 * rate / float(f) - 1.0, 0.002)), dt) for f in fs_n]
        many = mode_columns_rows(u, filters, rows)
        assert many.shape == (k, rows.size)
        for j, (b, a) in enumerate(filters):
            assert np.array_equal(many[j], mode_column_rows(u, b, a, rows))


def _mode_record(seed, n, f_hz, zeta, frac, dt=1e-4):
    """A drawn drive with a mode's response (0.3 of it) and 1e-8 noise at 10 kHz; the search rows
    (``frac`` of them) and the projection off the drive and an offset on those rows."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    u = _input(rng, n)
    e = 0.3 * Resonance._column(u, f_hz, zeta, dt) + 1e-8 * rng.standard_normal(n)
    mask = rng.random(n) < frac
    Q = np.linalg.qr(np.column_stack([u, np.ones(n)])[mask])[0]
    return t, u, e, mask, (lambda X: X - Q @ (Q.T @ X))


@pytest.mark.parametrize("project_kind", ("none", "projected", "shared"))
def test_resonance_search_with_batched_grid_equals_one_column_at_a_time(monkeypatch, project_kind):
    """A resonance's search whose grid columns are filtered in batches returns the numbers of the
    search that filters one grid point at a time (plain, with a projection, and the pair of
    searches sharing the plain grid's costs)."""
    import copy
    t, u, e, mask, proj = _mode_record(11, 30_000, 240.0, 0.03, 0.4)
    project = None if project_kind == "none" else proj

    def run():
        eff = Resonance()
        if project_kind != "shared":
            return eff.fit(t, u, e, mask, project=project)
        memo = eff.__dict__.setdefault("_grid_costs", {})
        first = copy.deepcopy(eff, {id(memo): memo})
        second = copy.deepcopy(eff, {id(memo): memo})
        return first.fit(t, u, e, mask, project=project), second.fit(t, u, e, mask, project=None)

    fast = run()
    varpro = effects._varpro
    monkeypatch.setattr(effects, "_varpro", lambda *a, row_columns_many=None, **k: varpro(*a, **k))
    assert run() == fast


@pytest.mark.parametrize("seed", range(6))
def test_lowpass_kernel_equals_scipy_filter(seed):
    """The compiled lowpass = ``lowpass`` (and creep's ``lowpass - u``) at the rows, time
    constants from half a sample to ten record lengths."""
    rng = np.random.default_rng(100 + seed)
    rate = RATES_HZ[seed % len(RATES_HZ)]
    n = int(rng.integers(2_000, 40_000))
    dt = 1.0 / rate
    u = _input(rng, n)
    rows = _rows(rng, n)
    for _ in range(8):
        tau = float(np.exp(rng.uniform(np.log(0.5 * dt), np.log(10 * n * dt))))
        for minus_input in (False, True):
            ref = (lowpass(u, tau, dt) - (u if minus_input else 0.0))[rows]
            fast = lowpass_rows(u, tau, dt, rows, minus_input=minus_input)
            np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))


@pytest.mark.parametrize("seed", range(4))
def test_delay_residual_at_rows_equals_reference(seed):
    """Shifting only the rows = shifting the whole prediction and taking the rows, for delays of
    either sign up to hundreds of samples, with and without a projection."""
    rng = np.random.default_rng(200 + seed)
    n = int(rng.integers(2_000, 30_000))
    t = np.arange(n) / RATES_HZ[seed % len(RATES_HZ)]
    y = _input(rng, n)
    e = 1e-7 * rng.standard_normal(n)
    mask = np.zeros(n, bool)
    mask[_rows(rng, n)] = True
    A = np.column_stack([np.ones(int(mask.sum())), y[mask]])
    gram_inv = np.linalg.pinv(A.T @ A)
    for project in (None, lambda X: X - A @ (gram_inv @ (A.T @ X))):
        fast = Delay._residual_fn(t, e, y, mask, project)
        ref = Delay._residual_fn_reference(t, e, y, mask, project)
        for d in rng.uniform(-300, 300, 6):
            r = ref(d)
            np.testing.assert_allclose(fast(d), r, rtol=0, atol=1e-12 * np.max(np.abs(r)))


def _compare(a, b, path=""):
    """Every number of two JSON documents equal within 1e-9 relative (to the largest entry of
    the list it sits in: a gain at exactly zero on one side may be 1e-19 on the other)."""
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            if k != "elapsed_s":
                _compare(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        nums = [abs(x) for x in a + b if isinstance(x, float) and math.isfinite(x)]
        scale = max(nums) if nums else 0.0
        for k, (x, y) in enumerate(zip(a, b)):
            if isinstance(x, float) and isinstance(y, float) and math.isfinite(x):
                assert abs(x - y) <= 1e-9 * max(abs(x), abs(y), scale), (f"{path}[{k}]", x, y)
            else:
                _compare(x, y, f"{path}[{k}]")
    elif isinstance(a, float) and isinstance(b, float):
        if math.isnan(a):
            assert math.isnan(b), path
        else:
            assert abs(a - b) <= 1e-9 * max(abs(a), abs(b)), (path, a, b)
    else:
        assert a == b, (path, a, b)


def test_calibration_json_equals_the_reference_code(sn637, tmp_path, monkeypatch):
    """The whole calibration (base fit, every candidate's search on every channel, folds,
    stages) of a 20,000-row synthetic record with a resonance: the JSON with the fast paths
    equals the JSON with every reference path within 1e-9 relative."""
    t, v = benchmark_protocol("calibration", 10_000.0, 20_000)
    plant, _ = plant_with_effect(sn637, "resonance", 7, duration_s=float(t[-1] - t[0]))
    data = write_record(tmp_path / "rec.csv", simulate_record(plant, t, v, seed=7))
    plant_file = PLANTS / "p888_51_sn637.toml"
    fast = json.loads(json.dumps(run_calibrate(data, plant_file), default=str))
    varpro = effects._varpro
    monkeypatch.setattr(effects, "_varpro", lambda *a, row_columns=None, **k: varpro(*a, **k))
    monkeypatch.setattr(Delay, "_residual_fn", staticmethod(Delay._residual_fn_reference))
    ref = json.loads(json.dumps(run_calibrate(data, plant_file), default=str))
    assert fast["effect"] == ref["effect"] and Path(fast["record"]) == Path(ref["record"])
    _compare(fast, ref)


def test_a_repeated_search_answer_is_not_scored_twice(sn637, tmp_path, monkeypatch):
    """When a candidate's two searches (projected and plain) return the same parameters (the
    delay's memo), its columns and Gram matrices are built once: the calibration's JSON equals
    the one that builds them for both searches, exactly, on a delay record (effect, stages,
    every score and parameter)."""
    from workbench.calibrate import tracing
    t, v = benchmark_protocol("calibration", 10_000.0, 20_000)
    plant, _ = plant_with_effect(sn637, "delay", 5, duration_s=float(t[-1] - t[0]))
    data = write_record(tmp_path / "rec.csv", simulate_record(plant, t, v, seed=5))
    plant_file = PLANTS / "p888_51_sn637.toml"
    seen = []
    same = tracing._same_params
    monkeypatch.setattr(tracing, "_same_params", lambda a, b: seen.append(same(a, b)) or seen[-1])
    fast = json.loads(json.dumps(run_calibrate(data, plant_file), default=str))
    assert any(seen)                        # the skip was taken
    monkeypatch.setattr(tracing, "_same_params", lambda a, b: False)
    ref = json.loads(json.dumps(run_calibrate(data, plant_file), default=str))
    fast.pop("elapsed_s", None), ref.pop("elapsed_s", None)
    assert Path(fast.pop("record")) == Path(ref.pop("record"))
    assert fast == ref


def test_same_params_compares_values_bit_for_bit():
    from workbench.calibrate.tracing import _same_params
    a = {"delay_s": 1e-4, "taus_s": np.array([1e-3, 1e-2]), "refit": True}
    assert _same_params(a, {"delay_s": 1e-4, "taus_s": np.array([1e-3, 1e-2]), "refit": True})
    assert not _same_params(a, {**a, "delay_s": np.nextafter(1e-4, 1.0)})
    assert not _same_params(a, {**a, "taus_s": np.array([1e-3, 1e-2, 1e-1])})
    assert not _same_params(a, {**a, "refit": False})
    assert not _same_params(a, {"delay_s": 1e-4})


def _refit_cost_reference(Z, y, rows, d):
    """The refitted delay's cost at one delay: the rows shifted by the formula, then the least
    squares minimum by SVD of unit-RMS columns (rcond 1e-13), and as first written (LAPACK's
    QR, gelsy, cond 1e-10 on the raw columns)."""
    from scipy import linalg
    n = Z.shape[0]
    s = np.clip(rows - d, 0.0, n - 1.0)
    i0 = np.floor(s).astype(np.int64)
    f = (s - i0)[:, None]
    Zd = Z[i0] * (1.0 - f) + Z[np.minimum(i0 + 1, n - 1)] * f
    rms = np.sqrt(np.mean(Zd * Zd, axis=0))
    Zn = Zd / np.where(rms > 0, rms, 1.0)
    c = np.linalg.lstsq(Zn, y[rows], rcond=1e-13)[0]
    cq = linalg.lstsq(Zd, y[rows], cond=1e-10, lapack_driver="gelsy")[0]
    return float(np.sum((y[rows] - Zn @ c) ** 2)), float(np.sum((y[rows] - Zd @ cq) ** 2)), Zd


@pytest.mark.parametrize("seed", range(4))
def test_refit_delay_grid_costs_equal_the_per_delay_least_squares(seed):
    """``Delay._grid_cost_batch`` (normal equations of unit-RMS columns, batched) = the least
    squares minimum per delay (SVD), to 1e-7 of the cost, and picks the grid minimum the
    per-delay QR of the code before picked; with the model column an exact combination of the
    basis (the first stage: rank-deficient) and not (a later stage's model), columns of scales
    1e-6-50 as on protocol records, delays of both signs up to a quarter of the record.
    ``_rows_shifted`` equals the formula bit for bit. (The QR with cond 1e-10 on the raw
    columns is not scale-free: on seed 1 it drops a 1e-6-scale column and its cost is 3e-4
    above the minimum; the batch is scale-free.)"""
    rng = np.random.default_rng(seed)
    n, k = int(rng.integers(3_000, 20_000)), int(rng.integers(4, 25))
    u = np.cumsum(rng.standard_normal(n))
    thr = np.quantile(u, np.linspace(0.05, 0.95, k - 1))
    B = np.column_stack([np.maximum(u - r, 0.0) for r in thr] + [np.ones(n)])
    B *= 10.0 ** rng.uniform(-6, 1.7, k)
    ym = B @ rng.uniform(0.1, 1.0, k)
    if seed % 2:
        ym = ym + 0.01 * np.std(ym) * np.sin(np.linspace(0, 40, n) ** 1.3)
    Z = np.ascontiguousarray(np.column_stack([B, ym]))
    d_true = rng.uniform(0.5, 0.25 * n) * rng.choice([-1, 1])
    y = Delay._rows_shifted(ym[:, None], np.arange(n, dtype=float), d_true)[:, 0] \
        + 1e-3 * np.std(ym) * rng.standard_normal(n)
    rows = np.flatnonzero(rng.random(n) < 0.3)[::3]
    eff = Delay(max_delay=0.25 * n, basis=B)
    grid = eff._grid()
    fast = Delay._grid_cost_batch(Z, y, rows, grid)
    ref, qr = [], []
    for d in grid:
        c, cq, Zd = _refit_cost_reference(Z, y, rows, d)
        ref.append(c)
        qr.append(cq)
        assert np.array_equal(Delay._rows_shifted(Z, rows, d), Zd)
    np.testing.assert_allclose(fast, ref, rtol=1e-7, atol=1e-12 * float(np.sum(y[rows] ** 2)))
    assert int(np.argmin(fast)) == int(np.argmin(qr))


def test_researched_resonance_shares_the_plain_grid_costs(monkeypatch):
    """The later stage's two searches of a resonance (with the found columns projected out,
    then plain) share the plain grid's costs, as the first stage does: the plain search's
    answer equals a search of its own, and its grid is not filtered a second time."""
    import copy
    t, u, e, mask, project = _mode_record(3, 20_000, 180.0, 0.02, 0.3)
    ref = Resonance().fit(t, u, e, mask, project=None)
    eff = Resonance()
    eff.__dict__.setdefault("_grid_costs", {})
    calls = {"n": 0}
    kernel, kernel_many = effects.mode_column_rows, effects.mode_columns_rows

    def counted(*a, **k):
        calls["n"] += 1
        return kernel(*a, **k)

    def counted_many(u, filters, rows):          # the grid's columns, filtered in batches
        calls["n"] += len(filters)
        return kernel_many(u, filters, rows)
    monkeypatch.setattr(effects, "mode_column_rows", counted)
    monkeypatch.setattr(effects, "mode_columns_rows", counted_many)
    memo = eff.__dict__["_grid_costs"]
    first = copy.deepcopy(eff, {id(memo): memo})
    first.fit(t, u, e, mask, project=project)
    n_first = calls["n"]
    second = copy.deepcopy(eff, {id(memo): memo})
    assert second._grid_costs is memo
    got = second.fit(t, u, e, mask, project=None)
    assert got == ref
    assert calls["n"] - n_first < 0.5 * n_first      # the refinement only, no grid


def test_the_c_ordered_copy_lives_only_as_long_as_its_basis():
    """effects._c_ordered keeps one C-ordered copy of a record's columns (tens of MB) while that
    record's basis lives, and drops it with the basis; a C-ordered basis is its own copy."""
    import gc

    from workbench.calibrate import effects as E

    basis = np.asfortranarray(np.random.default_rng(0).normal(size=(1000, 7)))
    c = E._c_ordered(basis)
    assert c.flags.c_contiguous and np.array_equal(c, basis) and E._c_ordered(basis) is c
    del c, basis
    gc.collect()
    assert not E._C_BASIS
    own = np.zeros((10, 3))
    assert E._c_ordered(own) is own and not E._C_BASIS


@pytest.mark.parametrize("n_rows", [1, 1000, 50_000, 131_072, 355_000, 1_000_000, 10_000_000])
def test_a_grid_pass_holds_at_most_32_mb_of_columns(n_rows):
    """The batched filter's pass: at most GRID_BATCH columns, at most 32 MB of them, at least one."""
    from workbench.calibrate.effects import GRID_BATCH, _grid_batch
    k = _grid_batch(n_rows)
    assert 1 <= k <= GRID_BATCH
    assert k == 1 or k * 8 * n_rows <= 1 << 25
    assert k == GRID_BATCH or (k + 1) * 8 * n_rows > 1 << 25      # no smaller than it needs to be


def test_same_params_only_for_equal_numeric_values():
    """The shortcut's equality: bit for bit and dtype for dtype; anything else is 'not the same'."""
    from workbench.calibrate import tracing
    same = tracing._same_params
    assert same({"tau_s": 0.1, "w": np.array([1.0, 2.0])}, {"tau_s": 0.1, "w": np.array([1.0, 2.0])})
    assert not same({"tau_s": 0.1}, {"tau_s": np.nextafter(0.1, 1.0)})
    assert not same({"tau_s": 0.0}, {"tau_s": -0.0})
    assert not same({"n": np.int32(97)}, {"n": "a"})                 # equal bytes, other dtype
    assert not same({"w": [[1.0], [1.0, 2.0]]}, {"w": [[1.0], [1.0, 2.0]]})     # ragged: not judged
    assert not same({"a": 1.0}, {"b": 1.0})


def _drawn_linear_record(rng):
    """A drawn record for the linear problems: its length, split, three drive columns of drawn scales and a
    white residual of drawn size: ``(n, split, A, r)``."""
    from workbench.calibrate.splits import make_split
    n = int(rng.integers(3000, 12000))
    t = np.arange(n) / float(rng.choice(RATES_HZ))
    v = 50 + 40 * np.sin(2 * np.pi * rng.uniform(1, 5) / t[-1] * t)
    sp = make_split(t, v, "blocks")
    A = np.column_stack([v, np.abs(v - 50), np.ones(n)]) * 10.0 ** rng.uniform(-3, 3, 3)
    r = 10.0 ** rng.uniform(-9, -3) * rng.standard_normal(n)
    return n, sp, A, r


def _found_problem(rng, n_found):
    """A linear problem on a drawn record with ``n_found`` found columns of drawn scales."""
    from workbench.calibrate.tracing import _Problem
    n, sp, A, r = _drawn_linear_record(rng)
    prob = _Problem(sp, np.ones(n, bool), A, [0.0, 0.0, -np.inf], r, sp.train)
    found = [(rng.standard_normal((n, int(rng.integers(1, 4)))) * 10.0 ** rng.uniform(-6, 6), [0.0])
             for _ in range(n_found)]
    found = [(C, [0.0] * C.shape[1]) for C, _ in found]
    return prob, found


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_the_found_effects_grams_are_formed_once_and_equal_fresh_ones(seed):
    """``tracing._stacked`` with the found columns alone (every candidate's joint search and the stage's
    scores ask for them) returns the Gram matrices formed from those columns, bit for bit, the second
    time without forming them again; another found set (a column more, other bounds, another array of
    the same values) is formed afresh."""
    from workbench.calibrate.tracing import _stacked
    rng = np.random.default_rng(seed)
    prob, found = _found_problem(rng, int(rng.integers(1, 4)))
    fresh = prob.grams(np.column_stack([C for C, _ in found]), [x for _, lo in found for x in lo])
    g1 = _stacked(prob, found, None)
    assert np.array_equal(g1["G"], fresh["G"]) and np.array_equal(g1["C"], fresh["C"])
    assert _stacked(prob, list(found), None) is g1                 # the same columns: no new products
    copy_ = [(C.copy(), lo) for C, lo in found]                      # equal values, other arrays
    g2 = _stacked(prob, copy_, None)
    assert g2 is not g1 and np.array_equal(g2["G"], g1["G"])
    bounds = [(C, [-np.inf] * len(lo)) for C, lo in copy_]           # other bounds: other lb
    g3 = _stacked(prob, bounds, None)
    assert g3 is not g2 and np.all(np.isinf(g3["lb"][prob.A.shape[1]:]))
    more = bounds + [(rng.standard_normal((prob.r.size, 1)), [0.0])]
    assert _stacked(prob, more, None)["G"].shape[1] == g3["G"].shape[1] + 1


@pytest.mark.parametrize("seed", [21, 22])
def test_the_research_memo_gives_the_values_formed_afresh(seed):
    """``stages._research`` forms the found effects' fit, the joint projection and the found columns on
    the development rows once per found set: a candidate researched with them held equals the same
    candidate researched with them formed afresh (its columns and Gram matrices bit for bit), and a
    changed found set is not served the held ones."""
    from types import SimpleNamespace

    from workbench.calibrate import stages
    from workbench.calibrate.effects import Drift
    rng = np.random.default_rng(seed)
    prob, found = _found_problem(rng, 2)
    t = np.arange(prob.r.size, dtype=float)
    base = SimpleNamespace(channels={"displacement": SimpleNamespace(y=prob.r * prob.scale + 1.0)})
    c = {"name": "drift", "channel": "displacement", "key": ("displacement", "time"), "eff": Drift(),
         "driver": "time", "u": t, "n_params": 3}
    probs, extra = {c["key"]: prob}, {c["key"]: found}
    first = stages._research(c, probs, extra, t, base)
    held = prob._research_found
    again = stages._research(c, probs, extra, t, base)
    assert prob._research_found is held
    del prob._research_found
    fresh = stages._research(c, probs, extra, t, base)
    for r in (again, fresh):
        assert np.array_equal(r["g"]["G"], first["g"]["G"]) and np.array_equal(r["g"]["C"], first["g"]["C"])
        assert np.array_equal(r["yhat"], first["yhat"])
    extra[c["key"]] = found[:1]
    stages._research(c, probs, extra, t, base)
    assert prob._research_found[0][0] is found[0][0] and len(prob._research_found[0]) == 1


def _layouts(rng, n, m):
    """The same (n, m) values in the layouts the tracing meets: C order, Fortran order, a row slice of a
    wider array, a column of a 1-D array, a column selection's copy."""
    X = rng.standard_normal((n, m)) * 10.0 ** rng.uniform(-8, 8, m)
    out = [X, np.asfortranarray(X), np.vstack([X, X])[::2], X[:, np.ones(m, bool)]]
    if m == 1:
        out.append(np.atleast_2d(X[:, 0].copy().T).T)
    return out


@pytest.mark.parametrize("seed", [31, 32, 33, 34])
def test_scaled_columns_equal_the_column_selection_in_values_and_layout(seed):
    """``tracing._scaled_columns(X, keep, n)`` is ``X[:, keep] / n[keep]`` bit for bit and stride for stride
    (the later Gram products read the layout), over row counts from 1 to 40,000, 1 to 40 columns, every
    kept or some dropped, and every input layout the tracing passes."""
    from workbench.calibrate.tracing import _scaled_columns
    rng = np.random.default_rng(seed)
    for _ in range(12):
        n, m = int(rng.choice([1, 2, 7, int(rng.integers(100, 40_000))])), int(rng.integers(1, 41))
        norms = 10.0 ** rng.uniform(-8, 8, m)
        for keep in (np.ones(m, bool), rng.random(m) < 0.6):
            for X in _layouts(rng, n, m):
                got, ref = _scaled_columns(X, keep, norms), X[:, keep] / norms[keep]
                assert got.shape == ref.shape and got.dtype == ref.dtype and got.strides == ref.strides
                assert np.array_equal(got, ref)


@pytest.mark.parametrize("seed", [41, 42, 43])
def test_stacked_columns_give_the_grams_of_column_stack(seed):
    """``tracing._stack_columns`` lays 2+ columns out in Fortran order: the values of ``np.column_stack``,
    and ``_Problem.grams`` of either is the same, bit for bit (Gram matrices, scaled columns and their
    strides, norms), for found sets and candidates of 1 to 8 columns of scales 1e-6 .. 1e6."""
    from workbench.calibrate.tracing import _stack_columns
    rng = np.random.default_rng(seed)
    prob, found = _found_problem(rng, int(rng.integers(1, 4)))
    n = prob.r.size
    for _ in range(4):
        cols = [C for C, _ in found][: int(rng.integers(0, len(found) + 1))] + \
            [rng.standard_normal((n, int(rng.integers(1, 4)))) * 10.0 ** rng.uniform(-6, 6)
             for _ in range(int(rng.integers(1, 3)))]
        if rng.random() < 0.3:
            cols = [cols[0][:, 0]]                                      # one 1-D column
        lows = [0.0] * sum(np.shape(C)[1] if np.ndim(C) == 2 else 1 for C in cols)
        ref = np.column_stack(cols)
        got = _stack_columns(cols)
        assert np.array_equal(got, ref)
        g1, g2 = prob.grams(got, lows), prob.grams(ref, lows)
        for key in ("G", "lb", "C", "norms", "ok"):
            assert np.array_equal(g1[key], g2[key]), key
        assert g1["C"].strides == g2["C"].strides


def _drawn_grid_columns(rng, n, widths):
    """Grid points' columns of drawn scales (1e-9 to 1e3, a zero column among them), ``widths[j]`` each."""
    out = []
    for j, w in enumerate(widths):
        X = rng.standard_normal((n, w)) * np.exp(rng.uniform(np.log(1e-9), np.log(1e3), w))
        if j == 1:
            X[:, 0] = 0.0                   # a column the pseudo-inverse gives no gain
        out.append(X)
    return out


@pytest.mark.parametrize("seed", [51, 52, 53, 54])
def test_grid_costs_equal_each_points_least_squares_cost(seed):
    """``_grid_costs`` (one pass over a block of one-column points; ``_lstsq`` per point when wider)
    = ``||_lstsq(X, y) residual||^2`` of each point alone, over drawn row counts, scales and widths."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(50, 20_000))
    y = rng.standard_normal(n) * rng.uniform(0.1, 10.0)
    for widths in ([1] * int(rng.integers(2, 33)), [int(w) for w in rng.integers(1, 5, int(rng.integers(2, 9)))]):
        cols = _drawn_grid_columns(rng, n, widths)
        y_fit = y + cols[0][:, 0] * rng.uniform(-3, 3)        # a point that explains part of the target
        for target in (y, y_fit):
            ref = [float(np.sum(effects._lstsq(X, target)[1] ** 2)) for X in cols]
            fast = effects._grid_costs(widths, np.hstack(cols), target)
            np.testing.assert_allclose(fast, ref, rtol=1e-9, atol=1e-12 * float(target @ target))


@pytest.mark.parametrize("seed", [61, 62, 63])
def test_grid_blocks_project_each_point_as_alone(seed):
    """``_grid_blocks``: every point's columns in order, unchanged, in blocks of at most ``_grid_batch``
    columns, and each block's projection equal (to rounding) to each point's projection alone."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(50, 20_000))
    widths = [int(w) for w in rng.integers(1, 6, int(rng.integers(5, 40)))]
    cols = _drawn_grid_columns(rng, n, widths)
    E = np.linalg.qr(rng.standard_normal((n, int(rng.integers(1, 12)))))[0]

    def project(X):
        return X - E @ (E.T @ X)
    seen = []
    for proj in (project, None):
        j = 0
        for ws, XB, PB in effects._grid_blocks(iter(cols), proj, n):
            assert sum(ws) <= max(effects._grid_batch(n), max(ws))
            c = 0
            for w in ws:
                X = cols[j]
                assert w == X.shape[1] and np.array_equal(XB[:, c:c + w], X)
                ref = X if proj is None else project(X)
                np.testing.assert_allclose(PB[:, c:c + w], ref, rtol=0,
                                           atol=1e-12 * max(float(np.max(np.abs(X))), 1e-300))
                c += w
                j += 1
        seen.append(j)
    assert seen == [len(cols), len(cols)]


@pytest.mark.parametrize("seed", [61, 62, 63])
def test_block_rows_equal_the_row_gather_in_values_and_layout(seed):
    """``_Problem._block_rows(X, b)`` is ``X[prob.idx[b]]`` bit for bit and stride for stride (the Gram products
    read the layout), for every input layout the tracing passes, with every row valid (each block one run of
    rows: read by a slice) and with invalid rows scattered (blocks with gaps: gathered); and ``grams`` of a
    candidate equals the per-block products of the gathered rows (``X.T @ z``, ``X.T @ X``) bit for bit."""
    from workbench.calibrate.tracing import _Problem
    rng = np.random.default_rng(seed)
    n, sp, A, r = _drawn_linear_record(rng)
    gaps = np.ones(n, bool)
    gaps[rng.integers(0, n, n // 50)] = False
    for valid in (np.ones(n, bool), gaps):
        prob = _Problem(sp, valid, A, [0.0, 0.0, -np.inf], r, sp.train)
        runs = sum(s is not None for s in prob.spans)
        assert runs == len(prob.idx) if valid.all() else runs < len(prob.idx)     # both paths are met
        for m in (1, 2, 5):
            for X in _layouts(rng, n, m):
                for b in range(len(prob.idx)):
                    got, ref = prob._block_rows(X, b), X[prob.idx[b]]
                    assert got.shape == ref.shape and got.dtype == ref.dtype and got.strides == ref.strides
                    assert got.flags.c_contiguous == ref.flags.c_contiguous
                    assert got.flags.f_contiguous == ref.flags.f_contiguous
                    assert np.array_equal(got, ref)
            C = rng.standard_normal((n, m)) * 10.0 ** rng.uniform(-6, 6, m)
            g = prob.grams(C, [0.0] * m)
            k, Cs = prob.A.shape[1], g["C"]
            for b, i in enumerate(prob.idx):
                if not i.size:
                    continue
                Xb, z = Cs[i], np.column_stack([prob.A, prob.r])[i]
                assert np.array_equal(z, prob.Z0b[b])
                XZ = Xb.T @ z
                assert np.array_equal(g["G"][b, k:k + m, :k], XZ[:, :k])
                assert np.array_equal(g["G"][b, k:k + m, -1], XZ[:, k])
                assert np.array_equal(g["G"][b, k:k + m, k:k + m], Xb.T @ Xb)


@pytest.mark.parametrize("seed", [71, 72, 73])
def test_dev_rows_and_in_place_scaling_equal_the_gather_and_the_copy(seed):
    """``_Problem._dev_rows(X)`` is ``X[prob.rows_dev_idx]`` bit for bit and stride for stride, and so are the
    norms summed from it (``einsum``), with whole blocks held out (the rows copied run by run) and with
    invalid rows scattered (gathered); ``grams(C, own=True)`` (a fresh stack divided in place) equals
    ``grams`` of a copy (Gram matrices, scaled columns and their strides, norms); and a candidate stacked
    beside C-ordered found columns (held as a Fortran-ordered copy, :func:`tracing._fortran_found`) has the
    Gram matrices of ``np.column_stack`` of the columns, the copy made once per found array."""
    from workbench.calibrate.tracing import _Problem, _stack_columns, _stacked
    rng = np.random.default_rng(seed)
    n, sp, A, r = _drawn_linear_record(rng)
    gaps = np.ones(n, bool)
    gaps[rng.integers(0, n, n // 4)] = False             # more runs than 4 a block: gathered
    paths = set()
    for valid in (np.ones(n, bool), gaps):
        prob = _Problem(sp, valid, A, [0.0, 0.0, -np.inf], r, sp.train)
        paths.add(prob.dev_runs is None)
        for m in (1, 2, 5):
            for X in _layouts(rng, n, m):
                got, ref = prob._dev_rows(X), X[prob.rows_dev_idx]
                assert got.shape == ref.shape and got.dtype == ref.dtype and got.strides == ref.strides
                assert np.array_equal(got, ref)
                assert np.array_equal(np.einsum("ij,ij->j", got, got), np.einsum("ij,ij->j", ref, ref))
            cols = [rng.standard_normal((n, m)) * 10.0 ** rng.uniform(-6, 6, m), rng.standard_normal(n)]
            lows = [0.0] * (m + 1)
            g1, g2 = prob.grams(_stack_columns(cols), lows, own=True), prob.grams(np.column_stack(cols), lows)
            for key in ("G", "lb", "C", "norms", "ok"):
                assert np.array_equal(g1[key], g2[key]), key
            assert g1["C"].strides == g2["C"].strides
        found = [(np.ascontiguousarray(rng.standard_normal((n, 3)) * 10.0 ** rng.uniform(-6, 6, 3)), [0.0] * 3),
                 (rng.standard_normal((n, 2)) * 10.0 ** rng.uniform(-6, 6, 2), [-np.inf] * 2)]
        cand = {"g": prob.grams(rng.standard_normal((n, 2)), [0.0, 0.0])}
        cols = [C for C, _ in found] + [cand["g"]["C"] * cand["g"]["norms"]]
        ref = prob.grams(np.column_stack(cols), [0.0] * 3 + [-np.inf] * 2 + [0.0, 0.0])
        # (the candidate's Gram matrices joined to the found ones' when it is this problem's own: another
        # problem's candidate is stacked and multiplied as before, bit for bit)
        alien = {"g": {**cand["g"], "_of": None}}
        for _ in range(2):
            got = _stacked(prob, found, alien)
            for key in ("G", "lb", "C", "norms", "ok"):
                assert np.array_equal(got[key], ref[key]), key
            assert got["C"].strides == ref["C"].strides
        held = prob._found_fortran[id(found[0][0])]
        assert held[0] is found[0][0] and held[1].flags.f_contiguous and np.array_equal(held[1], found[0][0])
        assert _stacked(prob, found, alien) is not None and prob._found_fortran[id(found[0][0])] is held
    assert paths == {True, False}                   # both paths are met


def _stack_inputs(rng, n):
    """2-5 inputs of ``n`` rows in the kinds the calibration stacks: columns (contiguous or a view of
    every k-th element), C-ordered blocks (0-4 columns), Fortran-ordered blocks, a column selection (neither
    order), an integer column."""
    out = []
    for _ in range(int(rng.integers(1, 6))):
        kind = int(rng.integers(0, 7))
        if kind == 0:
            c = rng.standard_normal(n)
        elif kind == 1:
            c = rng.standard_normal((n, int(rng.integers(0, 5))))
        elif kind == 2:
            c = np.asfortranarray(rng.standard_normal((n, int(rng.integers(1, 4)))))
        elif kind == 3:
            c = rng.standard_normal((n, 3))[:, 1]
        elif kind == 4:
            c = rng.standard_normal((n, 1))
        elif kind == 5:
            c = rng.standard_normal((n, 4))[:, ::2]
        else:
            c = np.arange(n)
        out.append(c * 10.0 ** rng.uniform(-9, 9) if c.dtype == np.float64 else c)
    return out


@pytest.mark.parametrize("seed", [61, 62])
def test_blocked_column_stack_is_numpys_array_in_values_and_layout(seed):
    """``stacking.column_stack`` returns ``np.column_stack``'s array: values, dtype, shape and strides (the later
    products read the layout), for 0 to 200,000 rows (blocks of rows copied, a last partial block) and every
    kind of input the calibration stacks; a length mismatch raises as numpy does."""
    from workbench.calibrate.stacking import column_stack
    rng = np.random.default_rng(seed)
    fast = 0
    for _ in range(150):
        n = int(rng.choice([0, 1, 2, 7, 4095, int(rng.integers(8_000, 200_000))]))
        cols = _stack_inputs(rng, n)
        ref, got = np.column_stack(cols), column_stack(cols)
        assert got.shape == ref.shape and got.dtype == ref.dtype and got.strides == ref.strides
        assert got.flags.c_contiguous == ref.flags.c_contiguous and got.flags.f_contiguous == ref.flags.f_contiguous
        assert np.array_equal(got, ref)
        fast += all(c.dtype == np.float64 and (c.ndim == 1 or c.flags.c_contiguous) for c in cols) and n > 7
    assert fast >= 10                                  # the blocked path is met, on many blocks
    with pytest.raises(ValueError):
        column_stack([np.zeros(5), np.zeros((4, 2))])


@pytest.mark.parametrize("seed", [81, 82, 83, 84, 85])
def test_refit_mode_trial_columns_equal_lfilter_bit_for_bit(seed):
    """``kernels.filtered_rows_scaled`` (the refitted mode's trial columns, one compiled pass) =
    ``(lfilter(b, a, V, axis=-1) + z0)[:, rows] * inv[:, None]``, the expression it replaced in
    ``Resonance._fit_refit``, to the last bit and in its (Fortran) layout: drive-model columns of scales
    0.1..5e6 started at their first value, modes drawn over 1 Hz .. the Nyquist frequency at 100 Hz ..
    1 MHz (thinned rates)."""
    from scipy import signal

    from workbench.calibrate.kernels import filtered_rows_scaled
    rng = np.random.default_rng(seed)
    rate = RATES_HZ[seed % len(RATES_HZ)]
    m, n = int(rng.integers(3, 30)), int(rng.integers(300, 4_000))
    ZT = np.array([_input(rng, n) for _ in range(m)]) * 10.0 ** rng.uniform(-1, 6.7, m)[:, None]
    z0 = ZT[:, :1]
    V = ZT - z0
    rows = _rows(rng, n)
    nrm = np.sqrt(np.mean(ZT[:, rows] ** 2, axis=1))
    inv = 1.0 / np.where(nrm > 0, nrm, 1.0)
    for _ in range(6):
        f_n = float(np.exp(rng.uniform(np.log(1.0), np.log(0.5 * rate))))
        zeta = min(float(np.exp(rng.uniform(np.log(0.002), np.log(0.3)))), max(0.5 * rate / f_n - 1.0, 0.002))
        b, a = _foh_mode(f_n, zeta, 1.0 / rate)
        ref = (signal.lfilter(b, a, V, axis=-1) + z0)[:, rows] * inv[:, None]
        fast = filtered_rows_scaled(V, b, a, z0, inv, rows)
        # the same values in the same layout (a product of it, BLAS's ``c @ X``, sums in its order)
        assert np.array_equal(fast, ref) and fast.strides == ref.strides
    with pytest.raises(ValueError):
        filtered_rows_scaled(V, b, a, z0, inv, rows[::-1])


@pytest.mark.parametrize("seed", [91, 92, 93, 94])
def test_shifted_rows_kernel_equals_the_numpy_interpolation_bit_for_bit(seed):
    """``Delay._rows_shifted`` (compiled since session 29) = its numpy reference to the last bit, at
    lags and leads of fractional and whole samples, past either end of the record (the ends held),
    on unsorted rows with repeats; ``kernels.shifted_rows_into`` with a scale and a column offset
    writes the reference times the scale into its columns and leaves the others alone."""
    from workbench.calibrate.kernels import shifted_rows_into
    rng = np.random.default_rng(seed)
    n, k = int(rng.integers(50, 5_000)), int(rng.integers(1, 30))
    Z = np.ascontiguousarray(rng.standard_normal((n, k)) * 10.0 ** rng.uniform(-6, 2, k))
    rows = rng.integers(0, n, int(rng.integers(1, 2 * n)))
    ds = np.r_[rng.uniform(-1.2 * n, 1.2 * n, 6), rng.integers(-n, n, 3), 0.0, -0.5, 0.5]
    for d in ds:
        ref = Delay._rows_shifted_reference(Z, rows, float(d))
        fast = Delay._rows_shifted(Z, rows, float(d))
        assert np.array_equal(fast, ref) and fast.strides == ref.strides
        out = np.full((rows.size, k + 3), 7.0)
        scale = 10.0 ** rng.uniform(-3, 3, k + 3)
        shifted_rows_into(Z, rows, float(d), out, 2, scale)
        assert np.array_equal(out[:, 2:2 + k], ref * scale[2:2 + k])
        assert np.all(out[:, :2] == 7.0) and np.all(out[:, 2 + k:] == 7.0)
    # a layout the kernel does not take goes to the reference, the same values
    F = np.asfortranarray(Z)
    assert np.array_equal(Delay._rows_shifted(F, rows, 3.25), Delay._rows_shifted_reference(Z, rows, 3.25))


@pytest.mark.parametrize("seed", [95, 96])
def test_refit_delay_grid_costs_equal_the_unbatched_columns_bit_for_bit(seed):
    """``Delay._grid_cost_batch`` with its columns written in place (C-ordered blocks, int64 rows) =
    the same costs from the numpy stack of shifted blocks (F-ordered blocks take that path), to the
    last bit, with two column blocks side by side."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2_000, 8_000))
    B = np.ascontiguousarray(np.cumsum(rng.standard_normal((n, 7)), axis=0) * 10.0 ** rng.uniform(-6, 1, 7))
    K = np.ascontiguousarray(rng.standard_normal((n, 3)))
    y = rng.standard_normal(n)
    rows = np.flatnonzero(rng.random(n) < 0.4)
    grid = Delay(max_delay=0.2 * n)._grid()
    fast = Delay._grid_cost_batch((B, K), y, rows, grid)
    slow = Delay._grid_cost_batch((np.asfortranarray(B), np.asfortranarray(K)), y, rows, grid)
    assert np.array_equal(fast, slow)


def test_the_kept_mode_discretisations_equal_fresh_ones_and_are_the_callers_own():
    """``_foh_mode`` answers from its cache with the matrix exponential's values to the last bit, and
    each call's arrays are fresh (a caller writing into them changes no later answer)."""
    from workbench.calibrate.effects import _foh_mode_of
    rng = np.random.default_rng(97)
    for _ in range(20):
        rate = float(rng.choice(RATES_HZ))
        f_n = float(np.exp(rng.uniform(0.0, np.log(0.5 * rate))))
        zeta = float(np.exp(rng.uniform(np.log(0.002), np.log(0.3))))
        fresh = _foh_mode_of.__wrapped__(f_n, zeta, 1.0 / rate)
        b, a = _foh_mode(f_n, zeta, 1.0 / rate)
        assert np.array_equal(b, fresh[0]) and np.array_equal(a, fresh[1])
        b[:] = 0.0
        a[:] = 0.0
        b2, a2 = _foh_mode(f_n, zeta, 1.0 / rate)
        assert np.array_equal(b2, fresh[0]) and np.array_equal(a2, fresh[1])


def test_gelsy_called_directly_equals_scipy_lstsq_bit_for_bit():
    """``effects._gelsy`` (gelsy called with scipy's own arguments) = ``scipy.linalg.lstsq(...,
    lapack_driver="gelsy")`` to the last bit: full-rank and rank-deficient columns of scales 1e-6..50,
    C- and Fortran-ordered, and a wide system (the fallback)."""
    from scipy import linalg
    rng = np.random.default_rng(98)
    for m, n in ((1_600, 27), (40, 3), (2_000, 1), (7, 7), (5, 9)):
        A = rng.standard_normal((m, n)) * 10.0 ** rng.uniform(-6, 1.7, n)
        if n > 2 and m >= n:
            A[:, -1] = A[:, :-1] @ rng.uniform(0.1, 1.0, n - 1)          # an exact combination
        y = rng.standard_normal(m)
        for X in (A, np.asfortranarray(A)):
            ref = linalg.lstsq(X, y, cond=1e-10, lapack_driver="gelsy", check_finite=False)[0]
            assert np.array_equal(effects._gelsy(X, y, 1e-10), ref)


def _refit_record(seed, n=6_000, rate=1e3):
    """A drive model's columns (plays of a wandering drive, an offset), its prediction, and a record of
    it through a lightly damped mode plus noise; a mask of held-out blocks."""
    from scipy import signal
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    u = _input(rng, n) * 1e5
    thr = np.quantile(u, np.linspace(0.1, 0.9, 8))
    basis = np.column_stack([np.maximum(u - r, 0.0) for r in thr] + [np.ones(n)])
    y_model = basis @ rng.uniform(0.1, 1.0, basis.shape[1])
    f_n = float(np.exp(rng.uniform(np.log(5.0), np.log(0.3 * rate))))
    b, a = _foh_mode(f_n, 0.02, 1.0 / rate)
    y = signal.lfilter(b, a, y_model - y_model[0]) + y_model[0] + 1e-3 * np.std(y_model) * rng.standard_normal(n)
    mask = (np.arange(n) // 500) % 5 != 2
    return t, basis, y_model, y, mask


@pytest.mark.parametrize("seed", [101, 102])
def test_refit_searches_equal_their_reference_forms_bit_for_bit(monkeypatch, seed):
    """The refitted mode's and delay's searches (``Resonance._fit_refit``, ``Delay._search_refit``) with
    session 29's paths (compiled trial columns and shifts, gelsy called directly, kept discretisations,
    reused evaluations) = the same searches with every reference form (lfilter and gather, numpy
    interpolation, ``scipy.linalg.lstsq``, a fresh matrix exponential, each evaluation afresh): the same
    mode, damping, column and delay to the last bit."""
    from scipy import linalg, signal

    from workbench.calibrate.effects import _foh_mode_of
    t, basis, y_model, y, mask = _refit_record(seed)
    rows = np.flatnonzero(mask)

    def run():
        f, z, col = Resonance(basis=basis)._fit_refit(t, y, y_model, mask)
        blocks = (np.ascontiguousarray(basis), np.ascontiguousarray(y_model[:, None]))
        d = Delay(max_delay=300.0, basis=basis)._search_refit(blocks, y, rows)
        return f, z, col, d
    fast = run()
    monkeypatch.setattr(effects, "filtered_rows_scaled",
                        lambda V, b, a, z0, inv, r: (signal.lfilter(b, a, V, axis=-1) + z0)[:, r] * inv[:, None])

    def shifted_reference(Z, r, d, out, col0=0, scale=None):
        ref = Delay._rows_shifted_reference(Z, r, d)
        out[:, col0:col0 + Z.shape[1]] = ref if scale is None else ref * scale[col0:col0 + Z.shape[1]]
        return out
    monkeypatch.setattr(effects, "shifted_rows_into", shifted_reference)
    monkeypatch.setattr(effects, "_gelsy",
                        lambda A, b, cond: linalg.lstsq(A, b, cond=cond, lapack_driver="gelsy", check_finite=False)[0])
    monkeypatch.setattr(effects, "_foh_mode_of", _foh_mode_of.__wrapped__)
    monkeypatch.setattr(effects, "_REFIT_REUSE", False)
    ref = run()
    assert fast[0] == ref[0] and fast[1] == ref[1] and fast[3] == ref[3]
    assert np.array_equal(fast[2], ref[2])


def _joined_bound(G):
    """The most two sums of the same products in different orders (and one operand rescaled by its norm
    and back, ~2 eps) can differ by, per Gram entry: each sum of ``n`` products rounds by at most
    ``n eps sum |x_i y_i| <= n eps sqrt(G_ii G_jj)`` (Cauchy-Schwarz), ``n`` the block's rows, bounded here by
    the record's (``G`` one block's matrix; the diagonal's own rounding is below eps of it)."""
    d = np.sqrt(np.abs(np.diagonal(G, axis1=-2, axis2=-1)))
    return d[..., :, None] * d[..., None, :]


@pytest.mark.parametrize("seed", [71, 72, 73])
def test_joined_grams_are_the_stacked_columns_grams_to_rounding(seed):
    """``_stacked`` of found columns and a candidate of this problem joins their Gram matrices
    (:meth:`_Problem.joined`): per block, every entry equals the Gram matrix of the stacked columns
    (``np.column_stack``, as before) within the bound of summing the same products in another order
    (:func:`_joined_bound`); bounds, kept columns and norms are the stacked ones (norms to a few eps); the
    stacked scaled columns, formed when first asked, equal the stacked ones to a few eps and are kept;
    a single found set's Gram matrices are formed once for every candidate; with whole blocks held out and
    with scattered invalid rows (the block rows gathered), found sets and candidates of 1-3 columns of
    scales 1e-6 .. 1e6, a zero found column among them."""
    from workbench.calibrate.tracing import _JoinedGrams, _Problem, _stacked
    rng = np.random.default_rng(seed)
    n, sp, A, r = _drawn_linear_record(rng)
    gaps = np.ones(n, bool)
    gaps[rng.integers(0, n, n // 4)] = False
    eps = np.finfo(float).eps
    for valid in (np.ones(n, bool), gaps):
        prob = _Problem(sp, valid, A, [0.0, 0.0, -np.inf], r, sp.train)
        found = [(rng.standard_normal((n, int(rng.integers(2, 4)))) * 10.0 ** rng.uniform(-6, 6), None)
                 for _ in range(int(rng.integers(1, 3)))]
        found = [(C, [0.0] * C.shape[1]) for C, _ in found]
        found[0][0][:, 0] = 0.0                                   # a found column the fit drops
        lows = [x for _, lo in found for x in lo]
        for q in (1, 2, 3):
            cand = {"g": prob.grams(rng.standard_normal((n, q)) * 10.0 ** rng.uniform(-6, 6, q), [-np.inf] * q)}
            got = _stacked(prob, found, cand)
            assert isinstance(got, _JoinedGrams) and "C" not in got
            ref = prob.grams(np.column_stack([C for C, _ in found] + [cand["g"]["C"] * cand["g"]["norms"]]),
                             lows + [-np.inf] * q)
            assert got["G"].shape == ref["G"].shape
            # the stacked path rescales the candidate's scaled columns by their norm summed again over the
            # development rows: that sum of squares of unit RMS rounds by at most n_dev eps, its root by half
            tol_n = (prob.rows_dev_idx.size / 2 + 2) * eps
            rows = max(i.size for i in prob.idx)
            bound = ((2 * rows + 8) * eps + 2 * tol_n) * _joined_bound(ref["G"])
            assert np.all(np.abs(got["G"] - ref["G"]) <= bound)
            assert np.array_equal(got["G"], np.swapaxes(got["G"], 1, 2))
            assert np.array_equal(got["lb"], ref["lb"]) and np.array_equal(got["ok"], ref["ok"])
            assert np.all(np.abs(got["norms"] - ref["norms"]) <= tol_n * ref["norms"])
            C = got["C"]
            assert "C" in got and got["C"] is C and C.shape == ref["C"].shape
            assert np.all(np.abs(C - ref["C"]) <= (tol_n + 2 * eps) * np.abs(ref["C"]))
        assert len(prob._found_grams) == 1                        # one found set, formed once


@pytest.mark.parametrize("seed", [81, 82])
def test_forward_points_are_the_points_least_squares_differences(seed):
    """``effects._forward_points(x)`` are the points ``least_squares``' 2-point Jacobian at ``x`` evaluates,
    bit for bit, with the steps turned back at a bound: recorded over whole bounded fits of a 2- and a
    3-parameter model started near their upper bounds."""
    from scipy.optimize import least_squares

    from workbench.calibrate.effects import _MAP_KW, _forward_points
    rng = np.random.default_rng(seed)
    tt = np.linspace(0.0, 1.0, 200)
    for n_p in (2, 3):
        lo, hi = -rng.uniform(1, 3, n_p), rng.uniform(1, 3, n_p)
        truth = rng.uniform(0.5, 1.0, n_p) * hi
        data = sum(np.exp(truth[j] * tt ** (j + 1)) for j in range(n_p))
        seen, batches = [], []

        def fun(x):
            seen.append(np.array(x, float))
            return sum(np.exp(x[j] * tt ** (j + 1)) for j in range(n_p)) - data

        def jmap(f, points):
            points = [np.array(p, float) for p in points]
            batches.append((seen[-1], points))
            return [f(p) for p in points]

        x0 = hi - 1e-9 * (hi - lo)                                  # at the bound: steps turned back
        if not _MAP_KW(jmap):
            pytest.skip("this scipy takes no map for its finite differences")
        least_squares(fun, x0, bounds=(lo, hi), x_scale="jac", max_nfev=60, jac="2-point", **_MAP_KW(jmap))
        assert len(batches) >= 2
        for at, points in batches:
            want = _forward_points(at, lo, hi)
            assert len(want) == len(points)
            assert all(a.tobytes() == b.tobytes() for a, b in zip(want, points))
