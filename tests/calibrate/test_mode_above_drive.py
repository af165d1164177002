"""The refitted mode's search runs only where a mode can turn the motion (issue 13, session 21, s21_modespeed).

``Resonance(basis=...)``'s third variant (``refit=True``, the mode acting on the drive model refitted per trial)
exists for a mode below the drive's frequency, whose motion turns against the drive
(tests/calibrate/test_mode_below_drive.py). A mode far above the drive's frequency leaves the motion in phase
(a gain ``1 / (1 - (f_d / f_n)^2)`` the base's plays absorb), and the plain form finds it on the base's
prediction: the variant is searched only when its reach holds a mode below ``f_d / (1 - zeta_max)``
(:meth:`~workbench.calibrate.effects.Resonance.refit_reach`), and on a slow drive (a 1 kHz steps record, its motion reversing
about every 1.2 s: f_turn ~0.6 Hz, the search's floor 1 Hz) it is skipped. The mode's frequency is read from the record's
drive (its reversals) times a ratio, the plant the benchmark's simulator on the declared sn637.
"""

import dataclasses

import numpy as np
import pytest

from tests.conftest import load_benchmark
from workbench.calibrate.effects import Resonance

ZETA = 0.015


def _record(sn637, monkeypatch, protocol, rate, rows, ratio, seed):
    """The ``protocol`` record with the plant's one mode at ``ratio`` times the drive's frequency, base-fitted."""
    from workbench.calibrate.synthetic import benchmark_protocol
    from workbench.calibrate.tracing import excitation_period_s
    from workbench.plant.pzt import Mode
    cc = load_benchmark("calibrate_confusion")
    t, v = benchmark_protocol(protocol, rate, rows)
    f_drive = 1.0 / excitation_period_s(t, v)
    f_mode = f_drive * ratio
    draw = cc.plant_with_effect

    def moved(plant, effect, rng, duration_s=35.0, size=1.0):
        p, _ = draw(plant, "none", rng, duration_s=duration_s, size=size)
        return dataclasses.replace(p, pzt=dataclasses.replace(p.pzt, modes=(Mode(f_mode, ZETA),))), \
            {"freq_hz": f_mode, "damping_ratio": ZETA}
    monkeypatch.setattr(cc, "plant_with_effect", moved)
    t, sp, base, _, truth, _ = cc.simulated_base(sn637, "resonance", rate, protocol, 1.0, seed, n_rows=rows)
    return t, sp, base, truth, f_drive


def test_a_mode_far_above_a_slow_drive_is_found_by_the_plain_form_and_the_refit_is_skipped(sn637, monkeypatch):
    """1 kHz steps record (10 s, 0.4 Hz reversals), a 30 Hz-class mode (75x the drive): the refitted variant's
    reach (1-20 Hz trials) holds no mode that turns the motion, ``fit(refit=True)`` declines (ValueError, as a
    record too short for it), and the plain form returns the mode within a quarter of its half-power
    bandwidth."""
    from workbench.calibrate.tracing import _search_rows
    seed = int(np.random.default_rng(2121).integers(1 << 30))
    t, sp, base, truth, f_drive = _record(sn637, monkeypatch, "steps", 1e3, 10_000, 75.0, seed)
    f, zeta = truth["freq_hz"], truth["damping_ratio"]
    m = base.channels["displacement"]
    mask = _search_rows(sp.train & m.valid)
    e = m.y - m.yhat
    r = Resonance(basis=base.channel_basis("displacement"))
    f_lo, f_hi, f_turn = r.refit_reach(t, m.yhat)
    assert f_turn < f_lo < f, (f_lo, f_turn, f_drive, f)
    with pytest.raises(ValueError):
        r.fit(t, m.yhat, e, mask, y_model=m.yhat, refit=True)
    p = Resonance().fit(t, m.yhat, e, mask, y_model=m.yhat)
    assert abs(p["f_n_hz"] - f) < 0.25 * 2 * zeta * f, (p, truth)


def test_a_mode_below_a_fast_drive_keeps_the_refit(sn637, monkeypatch):
    """1 MHz sine record (0.02 s, a ~310 Hz drive), the mode at the drive / 1.56 (78 #148's ratio): the reach
    holds it (``f_lo < f < f_turn``) and the refitted variant runs (``refit`` True)."""
    from workbench.calibrate.tracing import _search_rows
    seed = int(np.random.default_rng(2122).integers(1 << 30))
    t, sp, base, truth, f_drive = _record(sn637, monkeypatch, "sine", 1e6, 20_000, 1 / 1.56, seed)
    m = base.channels["displacement"]
    r = Resonance(basis=base.channel_basis("displacement"))
    f_lo, f_hi, f_turn = r.refit_reach(t, m.yhat)
    assert f_lo < truth["freq_hz"] < f_turn, (f_lo, f_turn, truth)
    p = r.fit(t, m.yhat, m.y - m.yhat, _search_rows(sp.train & m.valid), y_model=m.yhat, refit=True)
    assert p["refit"]
