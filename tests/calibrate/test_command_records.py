"""Amplifier-command records (``# input: command``) and the generic stack's threshold grid (session 24,
``s24_command``; issue 13 item 1).

* :func:`~workbench.calibrate.splits.settled_row`: a play forgets its initial state once the input has swept
  twice its threshold; the rows before every play the record can settle is settled are left out of a command
  record's fits and scores (its plays' states there are the amplifier's offset and the stack's past).
* Clean command records drawn over rates 100 Hz - 100 kHz, sine / triangle / steps drives, first-order lags
  0-20 ms, gains 4-40 and offsets +-5 V: no effect named (full form: a few seconds to ~20 s a record).
"""
import numpy as np
import pytest

from tests.conftest import PLANTS, reduced_draws
from workbench.calibrate.pi_fit import pi_thresholds, play


def _drive(kind, n, rng):
    t = np.arange(n) / n
    if kind == "sine_mid":                        # starts mid-range, falls first
        return 3.0 + 2.0 * np.sin(2 * np.pi * 3 * t + np.pi)
    if kind == "sine_rest":                       # from its bottom
        return 2.5 * (1 - np.cos(2 * np.pi * 2 * t))
    if kind == "triangle":
        ph = 2.5 * t
        return 4.0 * 2 * np.abs(ph - np.floor(ph + 0.5)) - 1.0
    if kind == "steps":
        lv = rng.uniform(-2, 6, 7)
        return lv[np.minimum((t * 7).astype(int), 6)]
    s = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3)) for f in (1.3, 2.9, 6.1, 11.7))
    return s * np.clip(t / 0.3, 0, 1)             # a multisine ramped in: its span grows late


@pytest.mark.parametrize("kind", ["sine_mid", "sine_rest", "triangle", "steps", "multisine"])
@pytest.mark.parametrize("grid", ["uniform", "quadratic"])
def test_settled_row_is_where_every_settleable_play_forgets_its_start(kind, grid):
    """From ``settled_row`` on, each play of ``2 r <= span`` but the largest gives the same output from either
    end of its initial band ``u0 -+ r`` (the extremes: every start in between is squeezed between them), and
    the largest differs by at most one grid step (its state is off by ``2 r`` minus the sweep); on the row
    before it, the largest differs by more than the step: the row is the first."""
    from workbench.calibrate.splits import settled_row
    rng = np.random.default_rng(len(kind) + len(grid))
    u = _drive(kind, 4000, rng)
    k0 = settled_row(u, 20, grid)
    r_all = pi_thresholds(u, 20, grid)
    k = int(np.flatnonzero(2 * r_all <= np.ptp(u)).max())
    step = r_all[k] - r_all[k - 1]
    assert 0 < k0 < u.size
    for ri in r_all[1:k]:
        lo, hi = play(u, ri, u[0] - ri), play(u, ri, u[0] + ri)
        assert np.array_equal(lo[k0:], hi[k0:]), ri
    big = r_all[k]
    gap = play(u, big, u[0] + big) - play(u, big, u[0] - big)
    assert np.all(gap[k0:] <= step * (1 + 1e-12)), (gap[k0:].max(), step)
    assert gap[k0 - 1] > step


def test_settled_row_does_not_wait_for_the_noisiest_peak():
    """A command from rest whose top play sits at half its span (a uniform grid of an even count): asked for
    the full span, the settle row was wherever the noisiest sample fell (0.91-10.91 s of a 12 s, 0.55 Hz sine,
    review of s24_command); within one grid step it is on the first rise (0.78 s), on every draw."""
    from workbench.calibrate.splits import settled_row
    fs, f = 1e3, 0.55
    t = np.arange(int(12 * fs)) / fs
    clean = 50.0 * (1 - np.cos(2 * np.pi * f * t))
    rows = []
    for seed in range(20):
        u = clean + 1e-5 * 100.0 * np.random.default_rng(seed).standard_normal(t.size)
        rows.append(settled_row(u, 20, "uniform"))
    rows = np.asarray(rows) / fs
    # the sweep reaches (1 - 1/20) of the span on the first rise, before the first peak (at 1/(2f) = 0.91 s)
    assert np.all(rows < 1.0 / f), rows
    assert np.ptp(rows) < 0.02, rows


RATES = (100.0, 1e3, 1e4, 1e5)


def _command_record(tmp_path, i, seed, kind, rate):
    """A clean SN637 record driven through an amplifier of drawn gain, offset and first-order lag whose
    command is logged (``# input: command``). Sine and triangle keep under the plant's 2 mA source limit
    (peak slope 50 V/s: beyond it the terminal slews, which no gain, offset and lag describe); the steps are
    through an amplifier without a current limit (a lag alone shapes them)."""
    import dataclasses

    from scipy.signal import lfilter

    from workbench.calibrate.synthetic import plant_with_effect, simulate_record, write_record
    from workbench.plant import load_plant
    rng = np.random.default_rng([seed, i])
    dur = min(12.0, 2e5 / rate)
    n = int(round(dur * rate))
    t = np.arange(n) / rate
    f = rng.uniform(0.3, 1.0) * max(1.0, 4.0 / dur)
    if kind == "sine":
        a = min(110.0, 50.0 / (np.pi * f))
        v = 0.5 * a * (1 - np.cos(2 * np.pi * f * t))
    elif kind == "triangle":
        a = min(110.0, 50.0 / (2 * f))
        v = a * 2 * np.abs(t * f - np.floor(t * f + 0.5))
    else:
        k = int(rng.integers(5, 9))
        lv = np.r_[rng.uniform(0, 110, k - 1), 0.0]
        v = np.r_[0.0, lv][np.minimum((t / (dur / (k + 1))).astype(int), k)]
    gain, off, lag = rng.uniform(4, 40), rng.uniform(-5, 5), min(rng.uniform(0, 20e-3), 0.25 / f)
    u = v / gain
    ul = u
    if lag > 0:
        c = 1.0 - np.exp(-1.0 / (rate * lag))
        ul = lfilter([c], [1.0, c - 1.0], u, zi=[(1.0 - c) * u[0]])[0]
    plant, _ = plant_with_effect(load_plant(PLANTS / "p888_51_sn637.toml"), "none", int(rng.integers(1 << 30)),
                                 duration_s=float(t[-1]))
    if kind == "steps":
        plant = dataclasses.replace(plant, pzt=dataclasses.replace(plant.pzt, current_limit_source_a=10.0,
                                                                   current_limit_sink_a=10.0))
    r = simulate_record(plant, t, gain * ul + off, seed=int(rng.integers(1 << 30)))
    rec = {k: r[k] for k in ("time_s", "voltage_v", "current_a", "displacement_m", "gauge_v")}
    rec["voltage_v"] = u + 1e-5 * float(np.ptp(u)) * rng.standard_normal(n)
    return write_record(tmp_path / f"cmd{i}.csv", rec, {"input": "command"}), (gain, off, lag)


#: Steps at 10 kHz and 100 kHz are named a displacement delay (s24_command: 4.1 ms, 41 samples, at 10 kHz; the
#: command's lag found 2.9 ms against the amplifier's 2.3 ms), most likely because the terminal voltage is the command through
#: the amplifier's lag AND the 80 ohm resistor into the stack's capacitance, a second lag a command record's single
#: lag or delay (base_fit ``command_map``) cannot take, and a step excites it. Main names the 10 kHz one too, and
#: the 100 kHz triangle (#7), which passes here.
_STEPS_LAG_RC = pytest.mark.xfail(strict=True, reason="steps through the amplifier's lag and the series R C: the "
                                                      "command map's single lag leaves the R C to a delay")
COMMAND_DRAWS = [pytest.param(i, kind, RATES[i % 4], marks=[_STEPS_LAG_RC] if i in (2, 11) else [])
                 for i, kind in enumerate(["sine", "triangle", "steps"] * 4)]


@pytest.mark.parametrize("i,kind,rate", reduced_draws(COMMAND_DRAWS, keep=()))
def test_clean_command_records_name_no_effect(tmp_path, i, kind, rate):
    from workbench.calibrate.run import run_calibrate
    path, truth = _command_record(tmp_path, i, 24, kind, rate)
    res = run_calibrate(path, PLANTS / "p888_51_sn637.toml", figures=False)
    assert res["effect"] in ("none", "inconclusive"), (truth, res["effect"], res["parameters"],
                                                       res["base_fit"]["command_map"])
