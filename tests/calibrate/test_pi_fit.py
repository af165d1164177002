"""Tests for workbench.calibrate.pi_fit: Prandtl-Ishlinskii fit of voltage -> displacement."""

import os
from pathlib import Path

import numpy as np
import pytest

from workbench.calibrate import read_record
from workbench.calibrate.pi_fit import (fit_pi, pi_thresholds, rms, split_by_cycles,
                                        straight_line_rms, turning_points)
from workbench.plant.hysteresis import PrandtlIshlinskii


def _real_folder():
    """The shared data folder: $WORKBENCH_SHARED_DIR, else next to the repository, else /work/shared
    (a clone elsewhere, e.g. CI's, still finds the machine's copy)."""
    roots = [Path(os.environ["WORKBENCH_SHARED_DIR"])] if os.environ.get("WORKBENCH_SHARED_DIR") else []
    roots += [Path(__file__).resolve().parents[2].parent / "shared", Path("/work/shared")]
    for root in roots:
        if (root / "data" / "real").is_dir():
            return root / "data" / "real"
    return roots[0] / "data" / "real"


REAL = _real_folder()
REAL_CSV = REAL / "hysteresis_v_150_1hz.csv"
REAL_HEADER = "index,time[s],displacement[um],voltage[V]"


def _decaying_sine(v0=2.0, n=6000, cycles=10):
    t = np.linspace(0.0, 1.0, n)
    return v0 + 100.0 * np.exp(-1.5 * t) * np.sin(2 * np.pi * cycles * t)


def test_synthetic_pi_is_recovered_out_of_sample(rng):
    v = _decaying_sine()                       # bipolar, starts at rest at V0 = 2 V
    r = pi_thresholds(v, 8)
    w_true = rng.uniform(0.0, 1.0, 8) * 1e-7   # m/V
    w_true[3] = 0.0                            # a zero weight sits on the bound
    offset = -3e-6
    truth = PrandtlIshlinskii(r, w_true, np.full(8, v[0]), check_invertible=False)
    x = truth(v) + offset

    half = np.arange(v.size) < v.size // 2
    fit = fit_pi(v, x, n_plays=8, train=half)
    assert np.all(fit.weights >= 0)
    np.testing.assert_allclose(fit.thresholds_v, r)
    np.testing.assert_allclose(fit.initial_states_v, v[0])
    span = np.ptp(x)
    assert np.max(np.abs(fit.predict(v)[~half] - x[~half])) < 1e-3 * span
    assert fit.rms_train_m < 1e-6 * span
    np.testing.assert_allclose(fit.weights, w_true, atol=1e-6 * w_true.max())
    assert fit.offset_m == pytest.approx(offset, rel=1e-6)

    # the same split by cycles and as a slice
    by_cycles = fit_pi(v, x, n_plays=8, train=split_by_cycles(v, 5))
    by_slice = fit_pi(v, x, n_plays=8, train=slice(0, v.size // 2))
    for f in (by_cycles, by_slice):
        assert np.max(np.abs(f.predict(v) - x)) < 1e-3 * span


def test_weights_stay_non_negative_when_truth_needs_a_negative_one():
    v = _decaying_sine(v0=0.0)
    r = pi_thresholds(v, 6)
    w = np.array([1.0, 0.5, -0.4, 0.3, 0.2, 0.1]) * 1e-7
    x = PrandtlIshlinskii(r, w, np.zeros(6))(v)
    fit = fit_pi(v, x, n_plays=6)
    assert np.all(fit.weights >= 0)
    assert fit.rms_train_m > 0


def test_quadratic_grid_and_explicit_thresholds():
    v = _decaying_sine()
    q = pi_thresholds(v, 4, grid="quadratic")
    span = np.max(np.abs(v - v[0]))
    np.testing.assert_allclose(q, span * np.array([0, 1, 4, 9]) / 16)
    x = PrandtlIshlinskii(q, np.array([1.0, 2.0, 0.5, 1.0]) * 1e-8, np.full(4, v[0]))(v)
    assert fit_pi(v, x, thresholds=q).rms_train_m < 1e-6 * np.ptp(x)
    with pytest.raises(ValueError):
        fit_pi(v, x, thresholds=[0.0, 5.0, 5.0])
    with pytest.raises(ValueError):
        pi_thresholds(v, 4, grid="log")


def _reversals_reference(v, band=0.01):
    """The reversals walk in plain Python, as ``turning_points`` defines it (its compiled loop must agree)."""
    v = np.asarray(v, float)
    tol = band * float(np.ptp(v))
    out, direction, k_ext = [], 0, 0
    for k in range(1, v.size):
        if direction == 0:
            if abs(v[k] - v[0]) > tol:
                direction, k_ext = (1 if v[k] > v[0] else -1), k
            continue
        if (v[k] - v[k_ext]) * direction > 0:
            k_ext = k
        elif (v[k_ext] - v[k]) * direction > tol:
            out.append(k_ext)
            direction, k_ext = -direction, k
    return out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_compiled_reversals_match_the_plain_walk(seed):
    # drives of every kind a record brings: random walks (rough, many near-band wiggles), a noisy triangle,
    # steps with flat holds, a bipolar decaying sine, a constant; lengths from 2 samples up
    r = np.random.default_rng(seed)
    n = int(r.integers(2000, 8000))
    tri = np.abs(((np.arange(n) / r.integers(200, 900)) % 2.0) - 1.0) * r.uniform(1, 150)
    steps = np.repeat(r.uniform(-50, 100, 12), n // 12 + 1)[:n]
    for v in (np.cumsum(r.normal(size=n)), tri + r.normal(0, r.uniform(0, 2), n), steps,
              steps + r.normal(0, 0.3, n), _decaying_sine(n=n, cycles=int(r.integers(2, 30))), np.full(n, 3.0),
              r.normal(size=2), np.cumsum(r.normal(size=n)) * 1e-9):
        for band in (0.0, 0.01, 0.2):
            tp = turning_points(v, band)
            assert tp.dtype == np.asarray([0]).dtype
            assert tp.tolist() == _reversals_reference(v, band)


def test_cycles_are_counted_by_reversals():
    t = np.linspace(0, 3, 3001)                # three periods of a sine from 0
    v = np.sin(2 * np.pi * t) + 1e-4 * np.cos(400 * t)   # wiggles below the band
    tp = turning_points(v)
    assert tp.size == 6
    np.testing.assert_allclose(t[tp], [0.25, 0.75, 1.25, 1.75, 2.25, 2.75], atol=2e-3)
    mask = split_by_cycles(v, 2)
    assert mask[: tp[3] + 1].all() and not mask[tp[3] + 1:].any()
    assert split_by_cycles(v, 1.5).sum() == tp[2] + 1
    with pytest.raises(ValueError, match="reversals"):
        split_by_cycles(v, 4)
    with pytest.raises(ValueError):
        split_by_cycles(v, 1.2)
    assert turning_points(np.zeros(50)).size == 0   # at rest: no reversals


def test_straight_line_rms():
    v = np.linspace(-1, 1, 200)
    x = 3e-6 * v + 1e-7
    line = straight_line_rms(v, x, train=slice(0, 100))
    assert line.slope_m_per_v == pytest.approx(3e-6)
    assert line.rms_train_m < 1e-15 and line.rms_test_m < 1e-15
    assert np.isnan(straight_line_rms(v, x).rms_test_m)


@pytest.fixture(scope="module")
def real_record(tmp_path_factory):
    if not REAL_CSV.is_file():
        pytest.skip(f"real record not found at {REAL_CSV} (the shared data folder is not mounted)")
    path = tmp_path_factory.mktemp("real") / "hysteresis_v_150_1hz.csv"
    path.write_bytes(REAL_HEADER.encode() + b"\n" + REAL_CSV.read_bytes())
    return read_record(path)


def test_real_record_pi_beats_straight_line_out_of_sample(real_record):
    """Fit on the first cycles of the measured record, predict the rest.

    The record: at rest at 0 V until 3.257 s, then the commanded sine switches on with a step
    to -87 V, so the first reversal is the step itself. Three cycles (six reversals) end at
    t = 5.61 s; the held-out part (5.61 s to 10 s) is about 4.4 cycles.

    The training rows start at the first maximum: the rest stretch, the step (with its
    ringing) and the virgin branch are left out. The plays still run from the start, but the
    stack at rest sits about 1.6 um below what a PI operator in its virgin state at 0 V
    predicts (see test below), so those rows would bias the weights; after the first
    maximum, the play memory no longer depends on the initial states.
    """
    v = real_record.channels["voltage_v"]
    x = real_record.channels["displacement_m"]
    t = real_record.t_s
    tp = turning_points(v)
    assert tp.size == 14 and t[tp[0]] == pytest.approx(3.2572, abs=1e-3)
    first_cycles = split_by_cycles(v, 3)
    idx = np.arange(v.size)
    train = first_cycles & (idx >= tp[1])
    held = ~first_cycles

    fit = fit_pi(v, x, n_plays=20, train=train)
    resid = fit.predict(v) - x
    pi_in, pi_out = fit.rms_train_m, rms(resid[held])
    line = straight_line_rms(v, x, train)
    print(f"\nreal record, 20 plays, uniform grid, train t = {t[tp[1]]:.2f}..{t[tp[5]]:.2f} s: "
          f"PI in-sample {pi_in * 1e6:.4f} um, out-of-sample {pi_out * 1e6:.4f} um; "
          f"straight line in-sample {line.rms_train_m * 1e6:.3f} um, "
          f"out-of-sample {line.rms_test_m * 1e6:.3f} um")
    assert np.all(fit.weights >= 0)
    assert pi_in < 0.2e-6                      # measured 0.082 um; published 0.0915 um
    assert pi_out < 0.15e-6                    # measured 0.078 um
    assert line.rms_test_m > 1.5e-6            # measured 1.78 um (the issue: about 1.9 um)
    assert pi_out < 0.1 * line.rms_test_m

    # no creep or drift over the held-out cycles: the mean residual per cycle stays put
    means = [resid[a:b].mean() for a, b in zip(tp[5:-2:2], tp[7::2])]
    print("mean residual per held-out cycle [um]:", np.round(np.array(means) * 1e6, 4))
    assert np.ptp(means) < 0.03e-6


def test_real_record_rest_level_and_published_window(real_record):
    """The rest level does not fit the loop; the published two cycles fit to ~0.07 um."""
    v = real_record.channels["voltage_v"]
    x = real_record.channels["displacement_m"]
    t = real_record.t_s
    tp = turning_points(v)
    rest = np.arange(v.size) < tp[0]

    # naive split: rest, step and virgin branch in the training rows
    naive = split_by_cycles(v, 3)
    fit = fit_pi(v, x, n_plays=20, train=naive)
    resid = fit.predict(v) - x
    loop = np.arange(v.size) >= tp[1]
    print(f"\nnaive split (rest + virgin branch in training): in-sample "
          f"{fit.rms_train_m * 1e6:.3f} um, out-of-sample {rms(resid[~naive]) * 1e6:.3f} um")
    assert rms(resid[~naive]) < 1.5e-6        # measured 0.97 um: the offset is a compromise

    good = fit_pi(v, x, n_plays=20, train=naive & loop)
    rest_gap = np.mean(good.predict(v)[rest] - x[rest])
    print(f"stack at rest sits {rest_gap * 1e6:.3f} um below the PI loop's virgin state")
    assert 1.0e-6 < rest_gap < 2.5e-6          # measured 1.62 um

    window = (t >= 7.0) & (t < 9.0)
    pub = fit_pi(v, x, n_plays=20, train=window)
    print(f"published window t = 7..9 s, in-sample: {pub.rms_train_m * 1e6:.4f} um "
          f"(published sparse Duhem model: 0.0915 um)")
    assert pub.rms_train_m < 0.12e-6           # measured 0.074 um


def test_play_unexcited_in_training_gets_no_weight(rng):
    """Training on small cycles, predicting a larger one: the grid spans the training input, a play
    it never moves gets weight 0, and the prediction stays bounded (no offset traded against it)."""
    t = np.linspace(0.0, 8.0, 8000)
    amp = np.where(t < 6.0, rng.uniform(0.4, 0.8), 1.0) * rng.uniform(10.0, 200.0)       # V
    v = amp * 0.5 * (1.0 - np.cos(2 * np.pi * t))                 # unipolar, from rest
    r = pi_thresholds(v, 8)
    x = PrandtlIshlinskii(r, rng.uniform(0.2, 1.0, 8) * 1e-8, np.zeros(8))(v)
    train = (t >= 0.5) & (t < 6.0)          # from the first reversal: the virgin rise is not trained on
    fit = fit_pi(v, x, n_plays=10, train=train)
    span_train = np.max(v[train])
    assert fit.thresholds_v[-1] < span_train                     # the grid is the training input's
    moved = np.array([np.ptp(PrandtlIshlinskii(np.array([ri]), np.ones(1), np.zeros(1),
                                               check_invertible=False)(v)[train]) for ri in fit.thresholds_v])
    assert np.all(fit.weights[moved < 1e-3 * span_train] == 0) and np.any(moved < 1e-3 * span_train)
    assert np.max(np.abs(fit.predict(v) - x)) < 0.5 * np.ptp(x)
