"""Fused gauge + charge feedback: the complementary blend, the crossover choice, the closed loops, the CLI."""

import control
import numpy as np
import pytest

from workbench.selfsense.charge_amp import ChargeAmpParams
from workbench.selfsense.fusion import (Blend, SensorSpectra, choose_crossover, fused_error_variance,
                                        fused_noise_rms_per_sample, sensor_spectra)

from ..conftest import selfsense_main

RNG = np.random.default_rng(20261123)
DRAWS = [(float(10 ** RNG.uniform(-2.5, 2.5)), float(10 ** RNG.uniform(-5, -3))) for _ in range(12)]


@pytest.mark.parametrize("fc_hz, dt_s", DRAWS)
def test_blend_is_exactly_complementary(fc_hz, dt_s):
    """F_low + F_high = 1: continuous pair as transfer functions, the discrete pair at every frequency."""
    if fc_hz >= 0.45 / dt_s:
        fc_hz = 0.1 / dt_s
    b = Blend(fc_hz, dt_s)
    total = control.minreal(b.low() + b.high(), verbose=False)
    assert control.ss(total).nstates == 0 and float(np.real(total.dcgain())) == pytest.approx(1.0, abs=1e-12)
    f = np.geomspace(1e-3, 0.49 / dt_s, 300)
    for lo, hi in ((b.low(), b.high()), (b.low_d(), b.high_d())):
        s = np.asarray(lo(2j * np.pi * f if lo.dt == 0 else np.exp(2j * np.pi * f * dt_s))).ravel() \
            + np.asarray(hi(2j * np.pi * f if hi.dt == 0 else np.exp(2j * np.pi * f * dt_s))).ravel()
        assert np.max(np.abs(s - 1.0)) < 1e-9
    # the firmware form: equal sensors pass unchanged; a constant offset goes to the gauge (DC belongs to it)
    x = np.cumsum(RNG.standard_normal(4000)) * 1e-9
    fused, _ = b.run(x, x)
    assert np.array_equal(fused, x)
    n_settle = int(10 / (2 * np.pi * fc_hz * dt_s)) + 10
    g = np.full(n_settle, 3e-6)
    fused, _ = b.run(g, g - 1e-6, state=0.0)
    assert fused[-1] == pytest.approx(3e-6, rel=1e-4)


def _analytic_spectra(s_g, a_drift, dt_s, f_lo, f_hi):
    f = np.geomspace(f_lo, f_hi, 4000)
    return SensorSpectra(freq_hz=f, gauge_m2_per_hz=np.full_like(f, s_g), charge_m2_per_hz=a_drift / f ** 2,
                         charge_noise_m2_per_hz=0.0, gauge_noise_rms_m=np.sqrt(s_g / (2 * dt_s)),
                         charge_noise_rms_m=0.0, dt_s=dt_s)


@pytest.mark.parametrize("seed", range(6))
def test_crossover_is_the_closed_form_optimum_and_beats_a_grid(seed):
    """White gauge S_g against a random-walk drift A / f^2: J(f_c) = (S_g f_c^2 + A) pi / (2 f_c) on [0, inf),
    minimal at f_c = sqrt(A / S_g); the search finds it and no point of a dense grid does better."""
    r = np.random.default_rng(seed)
    dt = 1e-4
    s_g = 2 * (r.uniform(5e-9, 50e-9)) ** 2 * dt
    f_star = 10 ** r.uniform(-1.0, 1.0)
    a = s_g * f_star ** 2
    sp = _analytic_spectra(s_g, a, dt, f_star * 1e-4, min(f_star * 1e4, 0.4999 / dt))
    fc = choose_crossover(sp, lo_hz=f_star / 100, hi_hz=f_star * 100)
    assert fc == pytest.approx(f_star, rel=0.02)
    grid = np.geomspace(f_star / 100, f_star * 100, 2000)
    assert fused_error_variance(sp, fc) <= min(fused_error_variance(sp, g) for g in grid) * (1 + 1e-9)


def test_spectra_from_a_record_and_the_fused_noise():
    """The drift spectrum of a white record is 2 sigma^2 / fs (Welch); the fused white noise per sample is what
    the firmware blend makes of white gauge and charge noise (measured on 2e6 samples)."""
    fs, sigma = 1000.0, 3e-9
    t = np.arange(1, 200001) / fs
    e = RNG.standard_normal(t.size) * sigma
    sp = sensor_spectra(22e-9, 0.27e-9, 1e-4, t, e)
    band = (sp.freq_hz > 1) & (sp.freq_hz < 400)
    drift = sp.charge_m2_per_hz[band] - sp.charge_noise_m2_per_hz
    assert np.median(drift) == pytest.approx(2 * sigma ** 2 / fs, rel=0.05)
    # the fused white noise: the firmware blend run on independent white noises of the two sensors
    r = np.random.default_rng(5)
    for fc in (20.0, 300.0, 2000.0):          # correlation <= 80 samples: 2e6 samples pin the RMS to ~0.5 %
        g = r.standard_normal(2000000) * 22e-9
        c = r.standard_normal(2000000) * 0.27e-9
        fused, _ = Blend(fc, 1e-4).run(g, c, state=0.0)
        measured = float(np.std(fused[1000:]))
        assert fused_noise_rms_per_sample(sp, fc) == pytest.approx(measured, rel=0.02)


@pytest.fixture(scope="module")
def loop_parts(root):
    from workbench.plant.files import load_plant
    from workbench.selfsense.identify import identify, simulate_identification
    from workbench.controller import Controller
    plant = load_plant(root / "plants/p888_51_sn637_creep.toml")
    amp = ChargeAmpParams()
    ident = identify(simulate_identification(plant.pzt, amp, hold_s=300.0, dt_s=5e-4, seed=31), amp)
    ctrl = Controller.load(root / "controllers/sn637_fused_loopshape.json")
    ctrl_g = Controller.load(root / "controllers/sn637_loopshape.json")
    e_d = control.ss([], [], [], [[1.0]], 1e-4)     # E ~ 1 in the servo band (the module notes of run.py)
    return plant, amp, ident, ctrl, ctrl_g, e_d


def test_fused_loop_has_charge_noise_and_gauge_drift(loop_parts):
    """On the nonlinear plant with every charge and gauge imperfection: the fused loop's position noise in a
    hold is far below the gauge loop's (charge noise 0.27 nm vs gauge 22 nm per sample) and it tracks."""
    from workbench.selfsense.fused_loop import closed_loop_run
    plant, amp, ident, ctrl, ctrl_g, e_d = loop_parts
    kw = dict(triangle_hz=0.5, triangle_periods=2, hold_s=3.0, stroke_m=15e-6, seed=7)
    from workbench.selfsense.blend_fixed import FixedBlend
    fused = closed_loop_run(plant, ident, amp, e_d, ctrl, sensor="fused", blend=FixedBlend(Blend(1.0)), **kw)
    gauge = closed_loop_run(plant, ident, amp, e_d, ctrl_g, sensor="gauge", **kw)    # each with its own design
    assert fused["hold_noise_rms_m"] < gauge["hold_noise_rms_m"] / 5
    assert abs(fused["hold_drift_m"]) < 3e-9
    assert fused["triangle_rms_percent_stroke"] < 1.0


@pytest.mark.parametrize("argv, needle", [
    (["plants/p888_51_sn637_creep.toml", "--fused", "--hold", "1s"], "--hold must be at least 3s"),
    (["plants/p888_51_sn637_creep.toml", "--fused", "--force"], "separate studies"),
    (["plants/p888_51_sn637_creep.toml", "--fused", "--fused-controller", "nope.json"], "nope.json: no such"),
])
def test_cli_bad_input_exits_2(argv, needle, root, capsys, monkeypatch):
    monkeypatch.chdir(root)
    assert selfsense_main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err


def test_blend_rejects_a_crossover_above_nyquist():
    with pytest.raises(ValueError, match="Nyquist"):
        Blend(6000.0, 1e-4)


C_MAIN = r"""
#include <stdio.h>
#include "fused_blend.h"
int main(void) {
    long n; long long y0; fused_blend_state s;
    if (scanf("%ld %lld", &n, &y0) != 2) return 1;
    s.y = y0;
    for (long i = 0; i < n; i++) {
        long g, c;
        if (scanf("%ld %ld", &g, &c) != 2) return 1;
        printf("%ld\n", (long)fused_blend_step(&s, (int32_t)g, (int32_t)c));
    }
    printf("%lld\n", (long long)s.y);
    return 0;
}
"""


@pytest.mark.parametrize("fc_hz, seed", [(0.05, 1), (0.89, 2), (12.0, 3), (150.0, 4)])
def test_fixed_point_blend_bit_for_bit_with_its_c_header(fc_hz, seed, tmp_path):
    """The C header compiled with gcc gives every output and the final state of FixedBlend.run, on records
    with a sensor offset of microns, a drifting charge and noise of both signs; and the fixed point follows
    the floating-point blend (with the quantized pole) within its truncation bound."""
    import shutil
    import subprocess
    from workbench.selfsense.blend_fixed import FixedBlend, blend_header
    if shutil.which("gcc") is None:
        pytest.skip("no gcc: the header cannot be compiled here")
    r = np.random.default_rng(seed)
    n = 20000
    x = 7e-6 + 6e-6 * np.sin(2 * np.pi * r.uniform(0.05, 5.0) * np.arange(n) * 1e-4)
    fb = FixedBlend(Blend(fc_hz, 1e-4))
    g = fb.counts(x + r.standard_normal(n) * 22e-9)
    c = fb.counts(x - r.uniform(-10e-6, 10e-6) + np.linspace(0, r.uniform(-50e-9, 50e-9), n)
                  + r.standard_normal(n) * 0.3e-9)
    y0 = int(r.integers(-2 ** 36, 2 ** 36))
    out, y_end = fb.run(g, c, y0=y0)
    (tmp_path / "fused_blend.h").write_text(blend_header(fb))
    (tmp_path / "main.c").write_text(C_MAIN)
    subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Werror", "-o", str(tmp_path / "blend"),
                    str(tmp_path / "main.c")], check=True, cwd=tmp_path)
    stdin = f"{n} {y0}\n" + "\n".join(f"{a} {b}" for a, b in zip(g, c)) + "\n"
    res = subprocess.run([str(tmp_path / "blend")], input=stdin, capture_output=True, text=True, check=True)
    vals = np.array([int(v) for v in res.stdout.split()], dtype=np.int64)
    assert np.array_equal(vals[:-1], out) and int(vals[-1]) == y_end
    y, stepped = y0, []
    for a, b in zip(g[:500], c[:500]):         # the per-sample step the closed loop runs is the same recursion
        y, o = fb.step(y, a, b)
        stepped.append(o)
    assert np.array_equal(np.array(stepped), out[:500])
    a_q = 1.0 - fb.k / 2 ** fb.coef_bits
    d = (g - c).astype(float)
    from scipy import signal as sps
    y_f, _ = sps.lfilter([1 - a_q], [1, -a_q], d, zi=[a_q * y0 / 2 ** fb.frac_bits])
    # the floor in the state update loses < 1 LSB of Q F per step: a bias below 1 / ((1 - a) 2^F) counts, + rounding
    assert np.max(np.abs(out - (c + y_f))) <= 1.0 + 1.0 / ((1 - a_q) * 2 ** fb.frac_bits)
