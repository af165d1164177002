"""Firmware files: JSON/CSV/MAT round trips, atomic writing, and the C header against run_fixed bit for bit."""

import dataclasses
import json
import os
import shutil
import subprocess

import control
import numpy as np
import pytest
from scipy import io as sio

from workbench.export import ExportError, from_sos, quantize, run_fixed, run_float, to_sos, write_controller
from workbench.linearize.limit_cycle import load_controller

DT = 1e-4
LIMITS_V = (-20.0, 120.0)
RANGE_V = 2.6
RECORD = {"name": "pi_lead", "method": "loop shaping by hand", "input": {"signal": "gauge_error", "units": "V"},
          "output": {"signal": "pzt_voltage", "units": "V"}}
MAIN_C = """\
#include <stdio.h>
#include "ctrl.h"

int main(void)
{
    ctrl_fixed_state fixed;
    ctrl_float_state flt;
    long long e_q, u0_q;
    double e_v, u0_v;
    if (scanf("%lld %lf", &u0_q, &u0_v) != 2) return 1;
    ctrl_fixed_reset(&fixed, (int32_t)u0_q);
    ctrl_float_reset(&flt, u0_v);
    while (scanf("%lld %lf", &e_q, &e_v) == 2) {
        const int32_t u_q = ctrl_fixed_step(&fixed, (int32_t)e_q);
        printf("%ld %.17g\\n", (long)u_q, ctrl_float_step(&flt, e_v));
    }
    return 0;
}
"""


def _controller(notch=False, voltage_model=None):
    """PI (30 Hz), lead 200-800 Hz, 2 kHz roll-off; optionally a 5-50 Hz lag and a 1.5 kHz notch."""
    s = control.tf("s")
    w_i, w_z, w_p, w_r, w_n = 2 * np.pi * np.array([30.0, 200.0, 800.0, 2000.0, 1500.0])
    ctrl = 5.0 * (1 + w_i / s) * (1 + s / w_z) / (1 + s / w_p) * w_r**2 / (s**2 + 1.4 * w_r * s + w_r**2)
    ctrl = control.sample_system(ctrl, DT, method="tustin")
    if notch:   # discretized apart: Tustin of the 8th-order product is ill-conditioned
        extra = (s**2 + 0.1 * w_n * s + w_n**2) / (s**2 + w_n * s + w_n**2) * (1 + s / 314.0) / (1 + s / 31.4)
        ctrl = ctrl * control.sample_system(extra, DT, method="tustin")
    gain, sos = to_sos(ctrl)
    return quantize(gain, sos, DT, input_range_v=RANGE_V, output_limits_v=LIMITS_V, f_max_hz=3000.0,
                    voltage_model=voltage_model)


@pytest.fixture(scope="module")
def fxp():
    return _controller()


@pytest.fixture
def written(fxp, tmp_path):
    return write_controller(tmp_path, "ctrl", RECORD, fxp)


def test_json_round_trip(written, fxp):
    data = json.loads(written["json"].read_text())
    assert {k: data[k] for k in RECORD} == RECORD
    assert data["sample_rate_hz"] == 1.0 / DT and data["gain"] == fxp.gain
    np.testing.assert_array_equal(data["sos"], fxp.sos)
    block = data["fixed_point"]
    np.testing.assert_array_equal([sec["b"] for sec in block["sections"]], fxp.b)
    np.testing.assert_array_equal([sec["a"] for sec in block["sections"]], fxp.a)
    np.testing.assert_array_equal([sec["b_shift"] for sec in block["sections"]], fxp.b_shift)
    assert [sec["signal_q"] for sec in block["sections"]] == fxp.q_formats["signals"]
    assert (block["input"]["q"], block["a_q"]) == ("Q2.29", "Q2.29")
    assert block["output"]["limits_q"] == list(fxp.output_limits)
    assert block["error_db"] == fxp.error_db and block["error_deg"] == fxp.error_deg
    assert any("anti-windup" in line for line in block["assumptions"])


def test_json_is_the_format_linearize_reads(written, fxp):
    """workbench linearize --controller takes the file as it is."""
    z = np.exp(2j * np.pi * np.geomspace(1.0, 4000.0, 50) * DT)
    expected = from_sos(fxp.gain, fxp.sos, DT)(z)
    np.testing.assert_allclose(load_controller(written["json"])(z), expected, rtol=1e-9)


def test_csv_round_trip(written, fxp):
    first = written["csv"].read_text().splitlines()[:2]
    assert first[1] == "b0,b1,b2,a0,a1,a2"
    assert float(first[0].removeprefix("# gain = ")) == fxp.gain
    np.testing.assert_array_equal(np.loadtxt(written["csv"], delimiter=",", skiprows=2, ndmin=2), fxp.sos)


def test_mat_round_trip(written, fxp):
    mat = sio.loadmat(written["mat"], squeeze_me=True)
    np.testing.assert_array_equal(mat["sos"], fxp.sos)
    assert mat["gain"] == fxp.gain and mat["fs"] == 1.0 / DT
    np.testing.assert_array_equal(mat["b_q"], fxp.b)
    np.testing.assert_array_equal(mat["a_q"], fxp.a)
    np.testing.assert_array_equal(mat["b_shift"], fxp.b_shift)
    np.testing.assert_array_equal(mat["signal_frac_bits"], fxp.signal_frac_bits)
    assert mat["output_frac_bits"] == fxp.output_frac_bits and mat["input_limit_q"] == fxp.input_limit
    assert mat["b_q"].dtype == np.int32


def test_nothing_is_written_when_a_file_cannot_be_rendered(fxp, tmp_path):
    with pytest.raises(TypeError):
        write_controller(tmp_path, "ctrl", {**RECORD, "note": object()}, fxp)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name, record, match", [
    ("2ctrl", RECORD, "C identifier"),
    ("ctrl-1", RECORD, "C identifier"),
    ("ctrl", {**RECORD, "sos": [[1, 0, 0, 1, 0, 0]]}, r"record holds \['sos'\]"),
    ("ctrl", {**RECORD, "sample_rate_hz": 20000.0}, "quantized for 10000 Hz"),
])
def test_bad_names_and_records_are_refused(fxp, tmp_path, name, record, match):
    with pytest.raises(ExportError, match=match):
        write_controller(tmp_path, name, record, fxp)
    assert list(tmp_path.iterdir()) == []


def _compiler():
    cc = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler found (set CC or install gcc) to check the exported header")
    return cc


def _build(cc, folder):
    """Compile the test main; with the undefined-behaviour sanitizer when the compiler has one,
    so a signed overflow anywhere in the fixed-point step would abort the run."""
    (folder / "main.c").write_text(MAIN_C)
    base = [cc, "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O2", "-o", str(folder / "main"),
            str(folder / "main.c")]
    for extra in (["-fsanitize=undefined", "-fno-sanitize-recover=all"], []):
        done = subprocess.run(base + extra, capture_output=True, text=True)
        if done.returncode == 0:
            return folder / "main"
    pytest.fail(f"the header does not compile:\n{done.stderr}")


@pytest.mark.parametrize("variant", ["pi_lead_rolloff", "notched", "left_shift", "current_window", "slew_window"])
def test_header_steps_equal_run_fixed_bit_for_bit_and_run_float(variant, tmp_path, rng):
    cc = _compiler()
    # R = 80 ohm, C = 11.9 uF, +2 / -14 mA: the SN637 amplifier and stack; with R out (slew_window) alpha = 1
    # and the headroom is the charge I T the limits move in a sample over C
    model = {"current_window": (1 - np.exp(-DT / (80 * 11.9e-6)), 0.16, 1.12),
             "slew_window": (1.0, 2e-3 * DT / 11.9e-6, 14e-3 * DT / 11.9e-6)}.get(variant)
    u0_v = 50.0 if model else 0.0     # a bumpless start at the bias
    fxp = _controller(notch=variant == "notched", voltage_model=model)
    if variant == "left_shift":
        # the same controller with 4 fewer b fraction bits: negative shifts, the other branch of align
        fxp = dataclasses.replace(fxp, b=fxp.b // 16, b_frac_bits=fxp.b_frac_bits - 4)
        assert np.all(fxp.b_shift < 0)
    write_controller(tmp_path, "ctrl", RECORD, fxp)
    main = _build(cc, tmp_path)
    # beyond the input range (clamped), then pushes into both output limits
    e = np.concatenate([rng.uniform(-1.2 * RANGE_V, 1.2 * RANGE_V, 3000), np.full(9000, RANGE_V),
                        np.full(9000, -RANGE_V), 0.1 * rng.standard_normal(1000)])
    words = np.round(e * 2.0 ** fxp.input_frac_bits).astype(np.int64)    # not clamped: the C step clamps
    u0_q = int(np.rint(u0_v * 2.0 ** fxp.output_frac_bits))
    stdin = f"{u0_q} {u0_v!r}\n" + "".join(f"{q} {v!r}\n" for q, v in zip(words.tolist(), e.tolist()))
    out = subprocess.run([str(main)], input=stdin, capture_output=True, text=True, check=True).stdout.split()
    u_q = np.array(out[0::2], dtype=np.int64)
    u_v = np.array(out[1::2], dtype=float)
    np.testing.assert_array_equal(u_q * 2.0 ** -fxp.output_frac_bits, run_fixed(fxp, e, u0_v))   # exact: 2^-n scale
    assert u_v.min() == LIMITS_V[0] and u_v.max() == LIMITS_V[1]
    np.testing.assert_allclose(u_v, run_float(fxp.gain, fxp.sos, e, output_limits_v=LIMITS_V, voltage_model=model,
                                              u0_v=u0_v), rtol=1e-12, atol=1e-9)
    if model is not None:
        # the command never asks for more current than the limits: u - v within [-R I_sink, R I_source]
        alpha, h_up, h_down = model
        v = u0_v
        lead = np.empty(u_v.size)
        for i, u in enumerate(u_v):
            lead[i] = u - v
            v += alpha * (u - v)
        assert -h_down - 1e-9 <= lead.min() and lead.max() <= h_up + 1e-9
        assert lead.max() > 0.99 * h_up and lead.min() < -0.99 * h_down     # and the window is used
        # so over the push up the command climbs no faster than the source current charges the stack
        k = np.arange(9000)
        rise = u_v[3000:12000] - u_v[3000]
        assert np.all(rise <= k * alpha * h_up + h_up + h_down + 1e-9)
    if variant == "slew_window":
        # alpha = 1 is exact in Q1.30 (v += ((u - v) 2^30 + 2^29) >> 30 is v = u): the output words never move by
        # more than the headroom words a sample, so the charge 11.9 uF x du never exceeds I T
        assert fxp.limit_words[2] == 1 << 30
        du = np.diff(np.concatenate([[u0_q], u_q]))
        assert du.max() == fxp.limit_words[3] and du.min() == -fxp.limit_words[4]
        assert 11.9e-6 * du.max() * 2.0 ** -fxp.output_frac_bits <= 2e-3 * DT
        assert -11.9e-6 * du.min() * 2.0 ** -fxp.output_frac_bits <= 14e-3 * DT
