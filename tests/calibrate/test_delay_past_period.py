"""A sensor lag longer than one period of a periodic drive is found (issue 13, 82 #152 at 1 MHz).

On a periodic drive a lag ``d`` and ``d + P`` are nearly the same phase: the refitted delay's
cost has a narrow valley at a lag past the period (only the drive's decay tells the cycles
apart) and broad copies below it. The log grid (27 % steps) can step over the narrow valley;
the search then also scores the grid's sub-period minima shifted by whole periods
(:meth:`workbench.calibrate.effects.Delay._search_refit`, the period from the record:
:func:`workbench.calibrate.tracing.periodic_drive_period`).

Records: the declared plant (sn637) with creep (the benchmark's draw, size 3: its slow motion is
outside the drive model, so the valley's floor is not zero) and a sensor lag of 1.12 or 1.4 of
the drive's period, the benchmark's sine protocol at 100 kHz (40,000 rows, ~3 s each), simulated,
split and base-fitted as the confusion benchmark does. Before the change the search returned
5,028.6 and 6,076.7 samples (true 7,209.4 and 9,011.8: the valley stepped over); now 7,259.1 and
9,004.6.
"""

import dataclasses

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate import tracing as T
from workbench.calibrate.base_fit import fit_base
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record

RATE, ROWS = 1e5, 40_000


def _record(plant0, lag_periods):
    bm = load_benchmark("calibrate_confusion")
    t, v = benchmark_protocol("sine", RATE, ROWS)
    period = T.excitation_period_s(t, v) * RATE          # the command's period (samples)
    plant, _ = plant_with_effect(plant0, "creep", 7, duration_s=float(t[-1]), size=3.0)
    lag = lag_periods * period
    plant = dataclasses.replace(plant, additions=dataclasses.replace(plant.additions, sensor_delay_s=lag / RATE))
    r = simulate_record(plant, t, v, seed=11)
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(bm._record(r, 1.0 / RATE), plant0.pzt.series_resistance_ohm, train=sp.train, test=sp.test,
                    pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    return t, sp, base, period, lag


@pytest.mark.parametrize("lag_periods", reduced_draws([(1.12,), (1.4,)], keep=(0,)))
def test_a_lag_past_the_drive_period_is_found(sn637, lag_periods):
    t, sp, base, period, lag = _record(sn637, lag_periods)
    m = base.channels["displacement"]
    plan = T.candidate_plan(base.channels, t, base.v_drive, tau_min_s=sp.block_s, basis=base.basis)
    (dl,) = [e for ch, e, _ in plan if e.name == "delay" and ch == "displacement"]
    assert dl.max_delay > lag
    p = dl.fit(t, m.yhat, m.y - m.yhat, T._search_rows(sp.train & m.valid), y_model=m.yhat)
    # the lag's own cycle: within a twentieth of a period (the creep outside the model biases it by
    # tens of samples; the grid's minima below the period are a third of a period and more away)
    assert abs(p["delay_samples"] - lag) < 0.05 * period
    # the drive is read as periodic, its period (from the terminal voltage, not the command) within 2 %
    assert dl.period == pytest.approx(period, rel=0.02)


def test_only_a_repeating_drive_has_a_period():
    """The benchmark's steps and calibration commands are not periodic; its sine is, at its period."""
    for rate, n in ((1e3, 10_000), (1e6, 100_000)):
        for proto in ("steps", "calibration"):
            t, v = benchmark_protocol(proto, rate, n)
            assert T.periodic_drive_period(t, v) is None, (rate, proto)
        t, v = benchmark_protocol("sine", rate, n)
        # six cycles over the record after a rest of 0.5/14.5 of it
        assert T.periodic_drive_period(t, v) == pytest.approx(n * (1 - 0.5 / 14.5) / 6, rel=0.01)


def test_the_period_shifts_are_the_nearest_and_at_most_the_grid_s_size():
    """On a drive of many cycles (a 200-sample period under a 25,000-sample bound) every sub-period minimum
    has ~125 whole-period shifts; the search keeps the nearest, at most as many as the grid has points (the
    batch at most doubles; review finding 1: 622 candidates on a 78-point grid, 3.6x the fit's time), and
    with few cycles (the benchmark's sine: a bound of ~1.4 periods) every shift."""
    from workbench.calibrate.effects import Delay
    grid = np.concatenate([-np.geomspace(150.0, 1.0, 20), np.geomspace(1.0, 25_000.0, 60)])
    costs = 1.0 + 0.5 * np.cos(2 * np.pi * grid / 200.0)       # minima every 200 samples: the phase's aliases
    minima = [k for k in range(grid.size) if abs(grid[k]) < 200.0
              and (k == 0 or costs[k] <= costs[k - 1]) and (k + 1 == grid.size or costs[k] <= costs[k + 1])]
    assert minima                                                # the construction has sub-period minima
    many = Delay(max_delay=25_000.0, period=200.0)._period_shifts(grid, costs)
    assert len(many) == grid.size
    shifts = [s for _, s in many]
    assert shifts == sorted(shifts)                              # the nearest first
    every = [(k, j * 200.0) for k in minima for j in range(1, 126) if 0.25 < grid[k] + j * 200.0 <= 25_000.0]
    assert max(shifts) < max(s for _, s in every)                # far shifts dropped
    few = Delay(max_delay=280.0, period=200.0)._period_shifts(grid, costs)
    assert sorted(few) == sorted((k, j * 200.0) for k in minima for j in (1, 2)
                                 if 0.25 < grid[k] + j * 200.0 <= 280.0)
