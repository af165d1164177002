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
from workbench.calibrate.kernels import lowpass_rows, mode_column_rows
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
    search range (1 Hz to 0.4 of the sample rate, damping 0.002 to 0.3) at 100 Hz .. 1 MHz."""
    rng = np.random.default_rng(seed)
    rate = RATES_HZ[seed % len(RATES_HZ)]
    n = int(rng.integers(2_000, 40_000))
    dt = 1.0 / rate
    u = _input(rng, n)
    rows = _rows(rng, n)
    for _ in range(8):
        f_n = float(np.exp(rng.uniform(np.log(1.0), np.log(0.4 * rate))))
        zeta = float(np.exp(rng.uniform(np.log(0.002), np.log(0.3))))
        ref = Resonance._column(u, f_n, zeta, dt)[rows]
        fast = mode_column_rows(u, *_foh_mode(f_n, zeta, dt), rows)
        np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))


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
