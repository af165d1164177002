"""A mode below a sine drive's frequency is found on the drive model refitted per trial (session 20, s20_modebasis).

Seed 78 #148 at 1 MHz (a 130x 39.8 Hz, zeta 0.015 mode under a 62 Hz sine) was answered ``inconclusive``:
above its mode the stack moves against the drive (``H ~ -0.7`` at 1.56x the mode), a motion the base's plays
(weights >= 0) cannot follow, so the base's prediction is a distorted drive for the mode and the mode
filtering it (:class:`~workbench.calibrate.effects.Resonance`'s first form) was found at 44.1 Hz, explaining
about as much as a random term of its size. The mode acting on the drive model's columns with their weights
refitted per trial (``Resonance(basis=...)``, ``refit=True``, as ``Delay(basis=...)`` refits per trial delay)
is found at the mode's frequency.

The records are the benchmark's simulator on the declared plant (sn637) with one mode, placed at the sine
protocol's own drive frequency over 1.56 (78 #148's ratio), damping 0.015 (78 #148's, inside the drawn
0.005-0.02); the drive frequency is read from the record (its reversals), not pinned.
"""

import dataclasses

import numpy as np
import pytest

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate.effects import Resonance

RATIO = 1.56            # drive / mode of 78 #148 (62.1 / 39.8)
ZETA = 0.015
# (rows at 1 MHz, noise seed): 0.02 s (a ~310 Hz drive, the mode ~200 Hz, 4 cycles) in the reduced form; the
# 0.1 s record of 78 #148 (a 62 Hz drive) in the full one. default_rng(2020) seeds, fixed before any fit was run
_RNG = np.random.default_rng(2020)
RECORDS = reduced_draws([(20_000, int(_RNG.integers(1 << 30))), (100_000, int(_RNG.integers(1 << 30)))], keep=(0,))


def _record(sn637, monkeypatch, rows, seed):
    """The sine record with the plant's one mode at the drive's frequency / RATIO, base-fitted."""
    from workbench.calibrate.synthetic import benchmark_protocol
    from workbench.calibrate.tracing import excitation_period_s
    from workbench.plant.pzt import Mode
    cc = load_benchmark("calibrate_confusion")
    rate = 1e6
    t, v = benchmark_protocol("sine", rate, rows)
    f_drive = 1.0 / excitation_period_s(t, v)
    f_mode = f_drive / RATIO
    draw = cc.plant_with_effect

    def moved(plant, effect, rng, duration_s=35.0, size=1.0):
        p, truth = draw(plant, "none", rng, duration_s=duration_s, size=size)
        truth = {"freq_hz": f_mode, "damping_ratio": ZETA}
        return dataclasses.replace(p, pzt=dataclasses.replace(p.pzt, modes=(Mode(f_mode, ZETA),))), truth
    monkeypatch.setattr(cc, "plant_with_effect", moved)
    t, sp, base, _, truth, _ = cc.simulated_base(sn637, "resonance", rate, "sine", 1.0, seed, n_rows=rows)
    return t, sp, base, truth, f_drive


@pytest.mark.parametrize("rows, seed", RECORDS)
def test_a_mode_below_the_drive_is_found_on_the_refitted_drive_model(sn637, monkeypatch, rows, seed):
    """On the development search rows the refitted form returns the mode within a quarter of its half-power
    bandwidth ``2 zeta f`` and its damping within 25 %. The first form (the mode on the base's prediction),
    searched plain (without the base's projection; the projected search is not run here), misses it by more
    than a bandwidth: that assertion records why the refitted form exists (the parent commit has the first
    form only: ``Resonance`` takes no ``basis``) and is to be revisited if the first form is improved."""
    from workbench.calibrate.tracing import _search_rows
    t, sp, base, truth, f_drive = _record(sn637, monkeypatch, rows, seed)
    f, zeta = truth["freq_hz"], truth["damping_ratio"]
    band = 2 * zeta * f
    assert f < f_drive
    m = base.channels["displacement"]
    mask = _search_rows(sp.train & m.valid)
    e = m.y - m.yhat
    p = Resonance().fit(t, m.yhat, e, mask, y_model=m.yhat)
    assert abs(p["f_n_hz"] - f) > band, (p, truth)
    p = Resonance(basis=base.channel_basis("displacement")).fit(t, m.yhat, e, mask, y_model=m.yhat, refit=True)
    assert p["refit"]
    assert abs(p["f_n_hz"] - f) < 0.25 * band, (p, truth)
    assert p["zeta"] == pytest.approx(zeta, rel=0.25)


@pytest.mark.skipif(not __import__("tests.conftest", fromlist=["FULL"]).FULL,
                    reason="reduced form: WORKBENCH_FULL=1 (make test-full) runs the tracing")
@pytest.mark.parametrize("rows, seed", RECORDS)
def test_the_tracing_names_the_mode_below_the_drive(sn637, monkeypatch, rows, seed):
    """The tracing names the mode (at least 4 of 5 folds, no other effect) at its frequency (a quarter of its
    half-power bandwidth) and halves the displacement's test error."""
    from workbench.calibrate.tracing import trace_effect
    t, sp, base, truth, _ = _record(sn637, monkeypatch, rows, seed)
    res = trace_effect(base, split=sp)
    named = [s["effect"] for s in res["stages"]]
    assert res["effect"] == "resonance" and set(named) == {"resonance"}, (res["effect"], res.get("fold_winners"))
    f, band = truth["freq_hz"], 2 * truth["damping_ratio"] * truth["freq_hz"]
    assert abs(res["stages"][0]["parameters"]["f_n_hz"] - f) < 0.25 * band, (res["stages"][0]["parameters"], truth)
    assert res["error_after"]["rms"] < 0.5 * res["error_before"]["rms"]
