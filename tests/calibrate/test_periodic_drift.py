"""A drift on a repeating drive, and a mode no ring of the record shows (issue 13, session 38).

Main f975e1a / e86bf87 named a wrong effect on 3 of 73 answered records of the independent simulator
(``benchmarks/outsider2``). Two of them are the rules here (the third, a mechanical creep the charge does not share
named ``drift`` on the gauge, is open: ``benchmarks/logs/s38_wrong/``):

* ``p_10k_sine__clean_PIdensity`` (a 2 Hz sine, 10 cycles, a Preisach density unlike the base's operator) was named
  ``drift`` 5 of 5: the drift's terms fitted the loop-shape misfit, which repeats every cycle. A drift is now asked
  the periodic-drive rule (:data:`~workbench.calibrate.tracing.PERIODIC_ASKED`), against a null reference refitted
  beside the drive's harmonics (:func:`~workbench.calibrate.tracing.periodic_mode_test`). A real drift (gen.py's
  ``drift_sine`` at 3x the noise on the same drive, our own simulator's sensor drift on sines and triangles at
  100 Hz-100 kHz) is still named: it explains what the harmonics leave.
* ``s_1k_proto__clean`` (the small stack, no series resistor, the calibration protocol) is named ``resonance`` 4 of
  5 at 1 Hz, the search's floor, gain 0.029: open (a strict full-form xfail). A rule refusing a named mode whose
  folds' own rings' gains are consistent with zero (session 38's ``ring_not_shown``) was withdrawn after its review:
  on our own simulator's 100 Hz records it refused right modes main named (seeds 106 #104, 107 #121, 108 #115: folds
  that find the ring at different alias members fit gains of different sign). gen.py's mode above Nyquist on a
  100 Hz record, named at its image with a negative gain the folds repeat, stays named (not placed).
"""

import dataclasses
import importlib.util
import sys

import numpy as np
import pytest

from tests.conftest import FULL_ONLY as FULL_ONLY_MARK, ROOT, reduced_draws
from tests.calibrate.test_periodic_loop_shape import _drive, _trace
from workbench.calibrate.run import run_calibrate
from workbench.calibrate.synthetic import plant_with_effect


def _outsider():
    """benchmarks/outsider2's batch and fresh modules (gen.py, the independent simulator)."""
    here = ROOT / "benchmarks" / "outsider2"
    if str(here) not in sys.path:
        sys.path.insert(0, str(here))
    mods = {}
    for name in ("gen", "batch", "fresh"):
        if name in sys.modules and str(getattr(sys.modules[name], "__file__", "")).startswith(str(here)):
            mods[name] = sys.modules[name]
            continue
        spec = importlib.util.spec_from_file_location(name, here / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
        mods[name] = mod
    return mods


def _calibrate_case(tmp_path, name):
    """A batch.py case of the independent simulator, written as the CLI's CSV and calibrated (the JSON dict)."""
    o = _outsider()
    case = [c for c in o["batch"].cases() + o["batch"].cases_extra() if c["name"] == name][0]
    rec, meta, plant, _params, _sizes = o["batch"].build(case)
    csv = tmp_path / f"{name}.csv"
    o["gen"].write_csv(csv, rec, meta)
    return run_calibrate(csv, ROOT / plant, figures=False)


def _calibrate_fresh(tmp_path, c):
    """A fresh.py draw (the independent simulator), written and calibrated."""
    o = _outsider()
    rec, meta, plant, _size = o["fresh"].build(c)
    csv = tmp_path / "fresh.csv"
    o["gen"].write_csv(csv, rec, meta)
    return run_calibrate(csv, ROOT / plant, figures=False)


def _named(res):
    return [(s["effect"], s["channel"]) for s in res.get("stages", [])]


# ---- a drift on a repeating drive

def test_a_foreign_loop_shape_on_a_sine_is_not_named_drift(tmp_path):
    """gen.py's 2 Hz sine at 10 kHz, 10 cycles, a Preisach density unlike the base's: main named ``drift`` 5 of 5 (its
    terms fitted the loop's misfit, which the drive's free harmonics fit as well held out)."""
    res = _calibrate_case(tmp_path, "p_10k_sine__clean_PIdensity")
    assert "drift" not in [e for e, _ in _named(res)], (res["effect"], res["fold_winners"], res["reason"][:600])


def test_a_small_sensor_drift_on_a_sine_is_still_named(tmp_path):
    """gen.py's slow sinusoidal sensor drift (period 0.7 of the record) at 3x the noise on the same 2 Hz sine: named
    ``drift`` on the displacement. Against the base-alone null reference the rule refused it on every fold: it
    explained 71-84 % of what the harmonics left, the base-alone null was 25-157x that (session 38)."""
    res = _calibrate_case(tmp_path, "p_10k_sine__drift_sine3")
    assert ("drift", "displacement") in _named(res), (res["effect"], res["fold_winners"], res["reason"][:600])


_RNG_CLEAN = np.random.default_rng(3745)
#: fresh.py's clean periodic draws (sine or triangle, 0.1-20 Hz, 100 Hz-100 kHz, 5-9 cycles, the Preisach density
#: and rest state drawn), seed 3745 (session 38's range): none may be named ``drift``
#: (drawn until six can be split: 12 blocks of ``max(50 dt, duration / 100)``, the blocks split's need)
CLEAN_DRAWS = []
for _k in range(40):
    _c = _outsider()["fresh"].draw_clean(_RNG_CLEAN, _k)
    if _c["dur"] >= 12 * max(50.0 / _c["rate"], _c["dur"] / 100.0) * 1.05 and len(CLEAN_DRAWS) < 6:
        CLEAN_DRAWS.append(pytest.param(_c, id=_c["name"]))
#: the full form only (each 1-14 s); the reduced form keeps the record main named (above)
CLEAN_DRAWS = reduced_draws(CLEAN_DRAWS, keep=())


@pytest.mark.parametrize("case", CLEAN_DRAWS)
def test_foreign_clean_periodic_records_are_not_named_drift(tmp_path, case):
    res = _calibrate_fresh(tmp_path, case)
    assert "drift" not in [e for e, _ in _named(res)], (res["effect"], res["fold_winners"], res["reason"][:600])


_RNG_DRIFT = np.random.default_rng(3746)
#: (rate, shape, f_drive, cycles, drift size, seed): our own simulator's sensor drift (a t + b t^2, 100-400 nm x size)
#: on a sine or a triangle from rest, one of each per decade of rate, 100 Hz-100 kHz; at least 100 samples a period,
#: at most 200,000 rows
DRIFT_DRAWS = []
for _rate in (100.0, 1e3, 1e4, 1e5):
    for _shape in ("sine", "triangle"):
        _cyc = int(_RNG_DRIFT.integers(6, 11))
        _lo = max(0.2, (_cyc + 0.25) * _rate / 2e5)
        _f = float(np.exp(_RNG_DRIFT.uniform(np.log(_lo), np.log(min(20.0, _rate / 100)))))
        DRIFT_DRAWS.append((_rate, _shape, _f, _cyc, float(np.exp(_RNG_DRIFT.uniform(np.log(0.3), np.log(3.0)))),
                            int(_RNG_DRIFT.integers(1 << 30))))
#: reduced form: draw 0 (100 Hz, a 0.89 Hz sine, 6 cycles); the full form all eight
DRIFT_DRAWS = reduced_draws(DRIFT_DRAWS, keep=(0,))


@pytest.mark.parametrize("rate, shape, f, cycles, size, seed", DRIFT_DRAWS)
def test_a_sensor_drift_on_a_periodic_drive_is_still_named(sn637, rate, shape, f, cycles, size, seed):
    """The declared stack (no creep) on a repeating drive with the displacement sensor's drift: named ``drift``."""
    t, v = _drive(rate, f, cycles, shape)
    plant, truth = plant_with_effect(dataclasses.replace(sn637, pzt=dataclasses.replace(sn637.pzt, creep=None)),
                                     "drift", np.random.default_rng(seed), duration_s=float(t[-1]), size=size)
    res = _trace(plant, t, v, seed)
    assert ("drift", "displacement") in _named(res), (truth, res["effect"], res["fold_winners"], res["reason"][:600])


# ---- a mode no ring of the record shows

@FULL_ONLY_MARK
@pytest.mark.xfail(strict=True, reason="open (session 38): gen.py's small stack on the calibration protocol, clean, is "
                   "named resonance 4 of 5 at 1.0 Hz (the search's floor), gain 0.029 (no stack mode's share), the "
                   "folds' own rings' gains 0.12 to -0.07; the rule that refused it (ring_not_shown) also refused "
                   "right modes at 100 Hz (review of s38_wrong, B1-B3) and was withdrawn")
def test_a_slow_column_at_the_search_floor_is_not_named_a_mode(tmp_path):
    """gen.py's small stack (no series resistor) on the calibration protocol at 1 kHz, clean: main named
    ``resonance`` 4 of 5 at 1.0 Hz (the search's floor), gain 0.029, the folds' own rings' gains 0.12 to -0.07."""
    res = _calibrate_case(tmp_path, "s_1k_proto__clean")
    assert "resonance" not in [e for e, _ in _named(res)], (res["effect"], res["fold_winners"], res["reason"][:600])
    assert res["effect"] in ("none", "inconclusive")


@pytest.mark.parametrize("name, channel_any", reduced_draws([("p_100_proto__mode_above", True),
                                                             ("p_100_proto__mode_below", True)], keep=(0,)))
def test_foreign_modes_at_100_hz_stay_named(tmp_path, name, channel_any):
    """gen.py's mode at a third of Nyquist (placed, gain 0.93) and at 1.3x Nyquist (read at its 35.4 Hz image, gain
    -0.36 on every fold, not placed): both still named ``resonance``."""
    res = _calibrate_case(tmp_path, name)
    assert "resonance" in [e for e, _ in _named(res)], (res["effect"], res["fold_winners"], res["reason"][:600])


# ---- open: a mechanical creep the charge does not share (item 3 of session 38's brief)

@FULL_ONLY_MARK
@pytest.mark.xfail(strict=True, reason="open (session 38): gen.py's Kelvin creep on a steps record (p_1k_steps__creep30) "
                   "is named drift on the gauge 4 of 5. The gauge's drift already scores 0.70 on the clean twin and "
                   "is refused there only by the hold check (gain -0.0003 +/- 0.011); the creep's relaxation in the "
                   "holds moves them (gain 0.23 +/- 0.01, its form's chi-square 1.4e5 on 4 dof), which switches the "
                   "veto off (drift_holds: 'the holds move in the drift's form'); creep on the displacement explains "
                   "~18 % of that channel's misfit (below MIN_SHARE) and passes no fold")
def test_a_mechanical_creep_on_steps_is_not_named_a_gauge_drift(tmp_path):
    res = _calibrate_case(tmp_path, "p_1k_steps__creep30")
    assert "drift" not in [e for e, _ in _named(res)], (res["effect"], res["fold_winners"])
