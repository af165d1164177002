"""Describing-function loop analysis against a closed-loop simulation of the nonlinear plant."""

import json

import control
import numpy as np
import pytest

from workbench.errors import DataFileError
from workbench.linearize.limit_cycle import load_controller, loop_responses, predict_limit_cycles, sampled_factor
from workbench.linearize.pzt_describing import pzt_describing_function
from workbench.linearize.sampled import firmware_plant, gauge_gain_v_per_m
from workbench.linearize.small_signal import small_signal_model
from workbench.plant import PZTSimulator

T = 1e-4


def _proportional(tmp_path, kp):
    path = tmp_path / f"p{kp:g}.json"
    path.write_text(json.dumps({"sample_rate_hz": 1 / T, "gain": kp, "sos": [[1, 0, 0, 1, 0, 0]]}))
    return load_controller(path)


def _closed_loop(pzt, k_g, kp, n=4000, sub=16, bias=50.0):
    """u -> PZT (sub-stepped) -> period mean of x -> K_g -> -kp, output applied one sample later."""
    sim = PZTSimulator(pzt, T / sub)
    sim.run(np.full(int(1.5 * sub / T), bias))
    x0 = sim.run(np.full(sub, bias)).x_m.mean()
    u = np.empty(n)
    pending, nxt = bias + 0.05, bias
    for k in range(n):
        u[k] = pending
        r = k_g * (sim.run(np.full(sub, u[k])).x_m.mean() - x0)
        pending, nxt = nxt, bias - kp * r
    tail = u[n // 2:] - u[n // 2:].mean()
    spec = np.abs(np.fft.rfft(tail))
    k = int(np.argmax(spec[1:])) + 1
    return 2 * spec[k] / tail.size, k / (tail.size * T)


@pytest.fixture(scope="module")
def df(sn637):
    return pzt_describing_function(sn637.pzt, np.geomspace(0.03, 3.0, 9), np.geomspace(800.0, 2500.0, 14))


def test_predicted_limit_cycle_matches_the_simulated_one(tmp_path, sn637, df):
    k_g = gauge_gain_v_per_m(7.5e-6, sn637.gauge)
    ctrl = _proportional(tmp_path, 250.0)
    cycles, crossings = predict_limit_cycles(df.amplitudes_v, df.freq_hz, loop_responses(ctrl, k_g, df))
    assert len(cycles) == 1 and cycles[0].stable
    # small amplitudes: linear and unstable (|L| > 1 at the phase crossover); large: the slew limit wins
    assert crossings[0][1] > 1 > crossings[-1][1]
    amp, freq = _closed_loop(sn637.pzt, k_g, 250.0)
    assert cycles[0].amplitude_v == pytest.approx(amp, rel=0.3)       # measured: 0.35 V predicted, 0.34 V simulated
    assert cycles[0].freq_hz == pytest.approx(freq, rel=0.1)          # 1388 Hz predicted, 1360 Hz simulated


def test_a_modest_gain_predicts_nothing_and_settles(tmp_path, sn637, df):
    k_g = gauge_gain_v_per_m(7.5e-6, sn637.gauge)
    cycles, crossings = predict_limit_cycles(df.amplitudes_v, df.freq_hz,
                                             loop_responses(_proportional(tmp_path, 60.0), k_g, df))
    assert cycles == [] and all(m < 1 for _, m in crossings)
    amp, _ = _closed_loop(sn637.pzt, k_g, 60.0, n=1000)
    assert amp < 1e-6


def test_sampled_factor_matches_the_exact_sampled_model(sn637):
    # the harmonic-balance form of hold + period average + delay against the exact discrete model
    p = small_signal_model(sn637.pzt, 15e-6)[0, 0]
    fw = firmware_plant(p, sn637.gauge, 7.5e-6, 1)
    k_g = gauge_gain_v_per_m(7.5e-6, sn637.gauge)
    for f in (10.0, 100.0, 1000.0):
        exact = complex(np.squeeze(fw(np.exp(2j * np.pi * f * T))))
        approx = k_g * complex(p(2j * np.pi * f)) * sampled_factor(f, T, 1)
        assert approx == pytest.approx(exact, rel=0.02 if f > 500 else 2e-3)


def test_controller_file_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(DataFileError, match="bad.json"):
        load_controller(bad)
    bad.write_text(json.dumps({"sos": [[1, 0, 0, 1, 0, 0]]}))
    with pytest.raises(DataFileError, match="sample_rate_hz"):
        load_controller(bad)
    bad.write_text(json.dumps({"sample_rate_hz": 1e4, "sos": [[1, 0, 0, 0, 0, 0]]}))
    with pytest.raises(DataFileError, match="a0 = 0.0, must be 1"):
        load_controller(bad)
    ok = tmp_path / "ok.json"
    ok.write_text(json.dumps({"sample_rate_hz": 1e4, "gain": 2.0, "sos": [[1, 0.5, 0, 1, -0.5, 0], [0, 1, 0, 1, -1, 0]]}))
    c = load_controller(ok)
    z = np.exp(0.3j)
    assert complex(np.squeeze(c(z))) == pytest.approx(2 * (1 + 0.5 / z) / (1 - 0.5 / z) * (1 / z) / (1 - 1 / z))
    assert c.dt == pytest.approx(1e-4)
    assert isinstance(c, control.TransferFunction)


def test_an_unstable_controller_is_analysed_only_when_asked(tmp_path):
    # linearize is an analysis run: --allow-unstable (allow_unstable) lets it study a controller with a
    # pole outside the unit circle, which every other path refuses
    import json
    from workbench.controller import ControllerError
    from ..conftest import ROOT
    d = json.loads((ROOT / "controllers" / "sn637_loopshape.json").read_text())
    d["sos"][0] = [1.0, 0.0, 0.0, 1.0, -1.5, 0.0]          # a pole at z = 1.5
    d.pop("fixed_point")
    path = tmp_path / "unstable.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ControllerError, match="--allow-unstable"):
        load_controller(path)
    ctrl = load_controller(path, allow_unstable=True)
    assert max(abs(p) for p in ctrl.poles()) == pytest.approx(1.5, rel=1e-9)
