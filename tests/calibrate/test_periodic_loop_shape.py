"""A loop shape the base's hysteresis lacks, on one repeated drive period, is no mode (issue 13, outsider A1).

Session 34's outside pass named ``resonance`` on 10 of 30 clean records of a foreign stack, all but one on a
single-frequency sine or triangle: a "mode" at 2-6x the drive took the stack's loop-shape misfit, which repeats
every cycle. On one repeated period a mode's steady response ``g (H(s) - 1) u`` and a rate-independent misfit are
both sums of the drive's harmonics; only what does not repeat tells them apart. The engine now asks a term of the
base's prediction on a periodic drive to beat the base plus free harmonics of the drive too
(:func:`workbench.calibrate.tracing.periodic_mode_test`): a linear term of the drive or of the base's prediction.

The records here are the workbench's simulator (the declared plant, SN637) on periodic drives of our own: a sine or
a triangle from rest, drive frequencies, rates and cycle counts drawn. The foreign loop shape is not the engine's
model: a polynomial in the drive's level and its direction of travel (a loop's asymmetry, even harmonics no PI
operator makes, and a widening), added to the displacement at 10-60x the sensor's noise. The real modes are the
plant's own (``pzt.modes``), 5-60x the drive frequency, excited by a triangle's corners (each corner rings: a
response at harmonics the loop itself does not reach, :meth:`~workbench.calibrate.tracing.PeriodicDrive.harmonics_of`,
or a start-up that does not repeat). Measured (full form): the six loop shapes none named, all six modes
named within their bandwidth (session 35, after the rival reading of :func:`~workbench.calibrate.tracing.
periodic_mode_test`; before it, draw 2 was answered none).
"""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import reduced_draws
from workbench.calibrate.base_fit import fit_base
from workbench.calibrate.record import Record
from workbench.calibrate.splits import make_split
from workbench.calibrate.synthetic import CURRENT_KIND, SensorNoise, simulate_record
from workbench.calibrate.tracing import trace_effect
from workbench.plant.pzt import Mode

MODEL_TERMS = ("resonance", "delay", "creep")


def _drive(rate_hz, f_hz, cycles, shape):
    """Rest for a quarter period, then ``cycles`` periods of a 0-100 V sine (from 0 V, ``50 (1 - cos)``) or triangle."""
    n = int(round((cycles + 0.25) / f_hz * rate_hz))
    t = np.arange(n) / rate_hz
    ph = np.clip(t - 0.25 / f_hz, 0.0, None) * f_hz
    if shape == "sine":
        v = 50.0 * (1.0 - np.cos(2 * np.pi * ph))
    else:
        v = 100.0 * 2.0 * np.abs(ph - np.floor(ph + 0.5))
    return t, v


def _trace(plant, t, v, seed, misfit=None):
    r = simulate_record(plant, t, v, seed=seed, gauge=False)
    x = r["displacement_m"] + (misfit(r["v_t_v"]) if misfit is not None else 0.0)
    rec = Record(Path("periodic.csv"), {"current": CURRENT_KIND}, r["time_s"],
                 {"voltage_v": r["voltage_v"], "current_a": r["current_a"], "displacement_m": x},
                 float(t[1] - t[0]))
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(rec, plant.pzt.series_resistance_ohm, train=sp.train, test=sp.test, pzt=plant.pzt)
    return trace_effect(base, split=sp)


def _loop_shape(rng, size):
    """A rate-independent misfit of the loop: ``a (u^2 - 1/2) + b d (1 - u^2) + c u^3`` in the drive's level
    ``u`` (-1 at 0 V, 1 at 100 V) and direction ``d``, scaled to ``size`` x the displacement noise (RMS)."""
    a, b, c = rng.uniform(-1, 1, 3)

    def misfit(vt):
        u = (np.asarray(vt) - 50.0) / 50.0
        d = np.sign(np.diff(vt, prepend=vt[0]))
        d = np.where(d == 0, 1.0, d)
        m = a * (u * u - 0.5) + b * d * (1.0 - u * u) + c * u ** 3
        m = m - m.mean()
        return m * size * SensorNoise().displacement_m / np.sqrt(np.mean(m * m))
    return misfit


_RNG = np.random.default_rng(3535)
#: (rate, drive, f_drive, cycles, misfit size x noise, seed): 1-10 kHz, 0.5-20 Hz at >= 100 samples a period
LOOP_DRAWS = []
for _shape in ("sine", "triangle", "sine", "triangle", "sine", "triangle"):
    _rate = float(_RNG.choice([1e3, 1e4]))
    _f = float(np.exp(_RNG.uniform(np.log(0.5), np.log(min(20.0, _rate / 100)))))
    LOOP_DRAWS.append((_rate, _shape, _f, int(_RNG.integers(6, 11)), float(np.exp(_RNG.uniform(np.log(10), np.log(60)))),
                       int(_RNG.integers(1 << 30))))
#: reduced form: draw 2, a 3.78 Hz sine at 1 kHz (6 cycles), which main before the rule named (review B3: the
#: triangles pass without the rule, so a triangle draw would not guard it); the full form all six
LOOP_DRAWS = reduced_draws(LOOP_DRAWS, keep=(2,))


@pytest.mark.parametrize("rate, shape, f, cycles, size, seed", LOOP_DRAWS)
def test_a_periodic_loop_shape_misfit_is_not_named_a_mode(sn637, rate, shape, f, cycles, size, seed):
    """A clean record of the declared stack whose loop carries a shape the PI base lacks: no mode, delay or creep."""
    plant = dataclasses.replace(sn637, pzt=dataclasses.replace(sn637.pzt, creep=None))
    t, v = _drive(rate, f, cycles, shape)
    res = _trace(plant, t, v, seed, _loop_shape(np.random.default_rng(seed), size))
    named = [s["effect"] for s in res["stages"]]
    assert not set(named) & set(MODEL_TERMS), (named, res["fold_winners"], res["reason"])


_RNG_MODE = np.random.default_rng(3536)
#: (rate, f_drive, cycles, mode at ratio x f_drive, damping, seed)
MODE_DRAWS = []
for _ in range(6):
    _rate = float(_RNG_MODE.choice([1e3, 1e4]))
    _ratio = float(np.exp(_RNG_MODE.uniform(np.log(5), np.log(60))))
    _f = float(np.exp(_RNG_MODE.uniform(np.log(0.5), np.log(min(20.0, 0.3 * _rate / _ratio)))))
    MODE_DRAWS.append((_rate, _f, int(_RNG_MODE.integers(6, 11)), _ratio, float(_RNG_MODE.uniform(0.005, 0.03)),
                       int(_RNG_MODE.integers(1 << 30))))
# draw 2, a 78 Hz mode at zeta 0.026 under a 3.38 Hz triangle at 10 kHz (23x), each corner's ring dying within the
# cycle at harmonics the loop reaches: the free harmonics take its folds (28 of them); it is named because alone it
# explains at least what they do, held out (before that second reading it was answered none)
#: reduced form: draw 1 (1 kHz, a 30 Hz mode under a 2.7 Hz triangle, ~2.6 s); the full form all six
MODE_DRAWS = reduced_draws(MODE_DRAWS, keep=(1,))


@pytest.mark.parametrize("rate, f, cycles, ratio, zeta, seed", MODE_DRAWS)
def test_a_ringing_mode_on_a_periodic_triangle_is_still_named(sn637, rate, f, cycles, ratio, zeta, seed):
    """The stack's own mode, rung by every corner of a triangle: named ``resonance`` at its frequency (within its
    half-power bandwidth, ``2 zeta f_n``, or 2 % where that is narrower)."""
    fn = ratio * f
    pzt = dataclasses.replace(sn637.pzt, creep=None, modes=(Mode(fn, zeta),))
    t, v = _drive(rate, f, cycles, "triangle")
    res = _trace(dataclasses.replace(sn637, pzt=pzt), t, v, seed)
    st = [s for s in res["stages"] if s["effect"] == "resonance"]
    assert st, (res["effect"], res["fold_winners"], res["reason"])
    assert abs(st[0]["parameters"]["f_n_hz"] - fn) <= max(2 * zeta, 0.02) * fn, (st[0]["parameters"], fn)
