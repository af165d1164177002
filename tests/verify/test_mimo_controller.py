"""The mirror's exported MIMO controller (workbench/export/mimo.py): the C header bit for bit, the
composition against the float design, validation on load."""

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import control
import numpy as np
import pytest

from workbench.export.mimo import MIMO_SCHEMA, MimoController, MimoControllerError
from workbench.plant.mirror import load_mirror

from .mirror_cases import quick_design

MAIN_C = r"""
#include <stdio.h>
#include "mimo.h"
int main(void)
{
    mimo_fixed_state st;
    int32_t u0[3], g[3], r[3], v[3];
    long long a, b, c;
    if (scanf("%lld %lld %lld", &a, &b, &c) != 3) return 1;
    u0[0] = (int32_t)a; u0[1] = (int32_t)b; u0[2] = (int32_t)c;
    mimo_fixed_reset(&st, u0);
    long long x[6];
    while (scanf("%lld %lld %lld %lld %lld %lld", &x[0], &x[1], &x[2], &x[3], &x[4], &x[5]) == 6) {
        for (int j = 0; j < 3; j++) { g[j] = (int32_t)x[j]; r[j] = (int32_t)x[3 + j]; }
        mimo_fixed_step(&st, g, r, v);
        printf("%ld %ld %ld\n", (long)v[0], (long)v[1], (long)v[2]);
    }
    return 0;
}
"""


@pytest.fixture(scope="module")
def fsm(root):
    return load_mirror(root / "plants" / "fsm_p888_51.toml")


@pytest.fixture(scope="module")
def ctrl(fsm):
    design, _ = quick_design(fsm)
    return MimoController.from_design(design, fsm, name="mimo")


MAIN_IFF_C = MAIN_C.replace("int32_t u0[3], g[3], r[3], v[3];", "int32_t u0[3], g[3], r[3], w[3], v[3];").replace(
    "long long x[6];", "long long x[9];").replace(
    'while (scanf("%lld %lld %lld %lld %lld %lld", &x[0], &x[1], &x[2], &x[3], &x[4], &x[5]) == 6) {',
    'while (scanf("%lld %lld %lld %lld %lld %lld %lld %lld %lld", &x[0], &x[1], &x[2], &x[3], &x[4], &x[5], '
    '&x[6], &x[7], &x[8]) == 9) {').replace(
    "for (int j = 0; j < 3; j++) { g[j] = (int32_t)x[j]; r[j] = (int32_t)x[3 + j]; }",
    "for (int j = 0; j < 3; j++) { g[j] = (int32_t)x[j]; r[j] = (int32_t)x[3 + j]; w[j] = (int32_t)x[6 + j]; }").replace(
    "mimo_fixed_step(&st, g, r, v);", "mimo_fixed_step(&st, g, r, w, v);")


@pytest.fixture(scope="module")
def design_iff(fsm):
    return quick_design(fsm, iff=True)[0]


@pytest.fixture(scope="module")
def ctrl_iff(fsm, design_iff):
    return MimoController.from_design(design_iff, fsm, name="mimo")


def _bridge_records(ctrl, rng, n):
    """Bridge readings over the charge amplifier's ADC range and past it (random, then held extremes)."""
    top = 1.2 * ctrl.iff["bridge"]["adc_range_v"]
    held = min(1000, n // 4)
    return np.concatenate([rng.uniform(-top, top, (n - 2 * held, 3)), np.full((held, 3), top), np.full((held, 3), -top)])


@pytest.fixture
def rng():
    return np.random.default_rng(15)


def _records(ctrl, rng, n, n_held):
    """Gauge readings over the DAC range and beyond, references over the axes' reach: random, then held
    extremes (``n_held`` samples each: the window slews ~65 V/s) that drive the cascades into their
    output clamps and the stacks into theirs."""
    g = np.concatenate([rng.uniform(-3.0, 3.0, (n, 3)), np.tile([2.6, -2.6, 2.6], (n_held, 1)),
                        np.tile([-2.6, 2.6, -2.6], (n_held, 1))])
    reach = 80.0 * ctrl.axis_scale                          # ~ the axis ranges, in rad / m
    r = np.concatenate([rng.uniform(-1, 1, (n, 3)) * reach, np.tile(reach, (n_held, 1)),
                        -np.tile(reach, (n_held, 1))])
    return g, r


def _compile_main(cc, tmp_path, source):
    """Write ``source`` as main.c beside the headers in ``tmp_path`` and build ./main (UBSan when available)."""
    (tmp_path / "main.c").write_text(source)
    base = [cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-I", str(tmp_path), "-o", str(tmp_path / "main"),
            str(tmp_path / "main.c")]
    for extra in (["-fsanitize=undefined", "-fno-sanitize-recover=all"], []):
        done = subprocess.run(base + extra, capture_output=True, text=True)
        if done.returncode == 0:
            break
    else:
        pytest.fail(f"the header does not compile:\n{done.stderr}")


def test_header_step_equals_python_step_bit_for_bit(ctrl, tmp_path, rng):
    cc = os.environ.get("CC") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no gcc: the header cannot be compiled here")
    ctrl.write(tmp_path, "mimo")
    _compile_main(cc, tmp_path, MAIN_C)
    g, r = _records(ctrl, rng, 1500, 25000)
    u0_axes = np.array([3.0, -2.0, 40.0])                 # at rest at a bias (axis volts)
    st = ctrl.reset(u0_axes)
    u0_words = st[1].copy()                               # the window models start at the output words
    gw, rw = ctrl.gauge_words(g), ctrl.reference_words(r)
    want = np.array([ctrl.step_words(st, gw[k], rw[k]) for k in range(len(gw))])
    stdin = " ".join(map(str, u0_words.tolist())) + "\n" + "".join(
        " ".join(map(str, list(a) + list(b))) + "\n" for a, b in zip(gw.tolist(), rw.tolist()))
    out = subprocess.run([str(tmp_path / "main")], input=stdin, capture_output=True, text=True, check=True).stdout
    got = np.array(out.split(), dtype=np.int64).reshape(-1, 3)
    np.testing.assert_array_equal(got, want)
    lim = ctrl.stack_limit_words
    assert np.any(want == lim[:, 0]) and np.any(want == lim[:, 1]), "the records must reach the stack clamps"


def test_header_with_iff_equals_python_step_bit_for_bit(ctrl_iff, tmp_path, rng):
    """The damped export: gauges, references and the three charge-bridge readings in, bit for bit."""
    cc = os.environ.get("CC") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no gcc: the header cannot be compiled here")
    ctrl = ctrl_iff
    paths = ctrl.write(tmp_path, "mimo")
    assert "iff_stack2_h" in paths
    _compile_main(cc, tmp_path, MAIN_IFF_C)
    g, r = _records(ctrl, rng, 1500, 25000)
    b = _bridge_records(ctrl, rng, len(g))
    st, ist = ctrl.reset(np.array([3.0, -2.0, 40.0])), ctrl.reset_iff(np.array([3.0, -2.0, 40.0]))
    u0_words = st[1].copy()
    gw, rw, bw = ctrl.gauge_words(g), ctrl.reference_words(r), ctrl.bridge_words(b)
    want = np.array([ctrl.step_words(st, gw[k], rw[k], bw[k], ist) for k in range(len(gw))])
    stdin = " ".join(map(str, u0_words.tolist())) + "\n" + "".join(
        " ".join(map(str, list(a) + list(c) + list(d))) + "\n" for a, c, d in zip(gw.tolist(), rw.tolist(), bw.tolist()))
    out = subprocess.run([str(tmp_path / "main")], input=stdin, capture_output=True, text=True, check=True).stdout
    got = np.array(out.split(), dtype=np.int64).reshape(-1, 3)
    np.testing.assert_array_equal(got, want)
    lim = ctrl.stack_limit_words
    assert np.any(want == lim[:, 0]) and np.any(want == lim[:, 1]), "the records must reach the stack clamps"
    # and the stack windows: some command reaches its model +/- R min(I) (the model replayed in float)
    v = ctrl.stack_volts(want)
    alpha, h = (np.array(ctrl.iff["stack_window"][k]) for k in ("alpha", "headroom_v"))
    m = ctrl.stack_volts(ctrl.stack_words_at(ctrl.reset(np.array([3.0, -2.0, 40.0]))[1]))
    reach = 0.0
    for vk in v:
        reach = max(reach, float(np.max(np.abs(vk - m) / h)))
        m = m + alpha * (vk - m)
    assert 0.99 <= reach <= 1.0 + 4 * 2.0 ** -ctrl.stack_frac_bits / h.min(), reach   # float replay of the words: 4 LSB


def test_iff_path_is_the_designed_force_feedback(ctrl_iff, fsm, rng):
    """Small signals: the damped export's stacks get In K (r' - Out' g) - g s/(s + w_l) T C_int b / C_R, the
    last term computed here from the design's IFF (float, continuous high-pass prewarped as designed)."""
    from workbench.design.antiwindup import discretize
    ctrl = ctrl_iff
    n = 4000
    # small enough that no command reaches its stack's current-limit window (R min(I) = 0.16 V about its RC
    # model): there the step is linear
    g = 2e-4 * rng.standard_normal((n, 3))
    r = 2e-4 * rng.standard_normal((n, 3)) * ctrl.axis_scale
    b = 2e-3 * rng.standard_normal((n, 3))                 # 2 mV of bridge reading: ~0.03 V RMS of correction
    v = ctrl.run(g, r, b_v=b)
    v0 = ctrl.run(g, r, b_v=np.zeros_like(b))
    br = ctrl.iff["bridge"]
    hp = discretize(control.tf([br["gain_v_per_n"], 0.0], [1.0, 2 * np.pi * br["corner_hz"]]), ctrl.dt_s, br["corner_hz"])
    force = b * (np.array(br["transducer_n_per_v"]) * br["integrator_capacitance_f"]
                 / np.array(br["reference_capacitance_f"]))[None]
    want = -np.column_stack([control.forced_response(hp, U=force[:, j]).outputs for j in range(3)])
    assert np.abs(want).max() > 1e-3
    np.testing.assert_allclose(v - v0, want, atol=2e-5 * np.abs(want).max() + 2e-6, rtol=0)
    with pytest.raises(ValueError, match="bridge readings"):
        ctrl.run(g, r)


def test_iff_json_round_trip_and_bad_keys(ctrl_iff, tmp_path, rng):
    paths = ctrl_iff.write(tmp_path, "mimo")
    back = MimoController.load(paths["json"])
    g, r = _records(ctrl_iff, rng, 200, 200)
    b = _bridge_records(ctrl_iff, rng, len(g))
    np.testing.assert_array_equal(back.run(g, r, b_v=b), ctrl_iff.run(g, r, b_v=b))
    for change, key in ((lambda d: d["iff"]["bridge"].pop("corner_hz"), "iff.bridge"),
                        (lambda d: d["iff"]["bridge"].__setitem__("reference_capacitance_f", [1e-5, -1e-5, 1e-5]),
                         "iff.bridge.reference_capacitance_f"),
                        (lambda d: d["iff"]["controllers"].pop("stack1"), "iff.controllers.stack1"),
                        (lambda d: d["iff"]["controllers"]["stack0"]["sos"][0].__setitem__(5, 1.5),
                         "iff.controllers.stack0"),
                        (lambda d: d["iff"]["bridge"].__setitem__("corner_hz", True), "iff.bridge.corner_hz"),
                        (lambda d: d["iff"]["bridge"].__setitem__("adc_range_v", float("inf")),
                         "iff.bridge.adc_range_v"),
                        (lambda d: d["iff"]["bridge"].__setitem__("adc_bits", 17.5), "iff.bridge.adc_bits"),
                        # a headroom past the stack's range (its words would overflow int64 and the step
                        # would clamp every stack to its bottom limit): refused on load
                        (lambda d: d["iff"]["stack_window"].__setitem__("headroom_v", [1e15] * 3),
                         "iff.stack_window.headroom_v"),
                        (lambda d: d["iff"]["stack_window"].__setitem__(
                            "headroom_v", [1.0, 1.0 + np.ptp(d["stack_limits_v"][1]), 1.0]),
                         "iff.stack_window.headroom_v"),
                        (lambda d: d["iff"]["stack_window"].__setitem__("alpha", [0.1, 0.1, 1.5]),
                         "iff.stack_window.alpha"),
                        (lambda d: d["iff"]["bridge"].__setitem__("out_noise_v_rms", -1e-6),
                         "iff.bridge.out_noise_v_rms"),
                        # bridge numbers that are not the cascades' (C_int doubled): -g T C_int / C_R off
                        (lambda d: d["iff"]["bridge"].__setitem__(
                            "integrator_capacitance_f", 2 * d["iff"]["bridge"]["integrator_capacitance_f"]),
                         "iff.controllers.stack0")):
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(_corrupt(ctrl_iff.to_dict(), change)))
        with pytest.raises(MimoControllerError) as err:
            MimoController.load(path)
        assert f"[{key}]" in str(err.value) and str(path) in str(err.value)


def test_only_the_bridge_iff_exports(fsm):
    from types import SimpleNamespace
    from workbench.design.mimo import IFF
    from workbench.export.sos import ExportError
    design, _ = quick_design(fsm)
    design = SimpleNamespace(**{**vars(design), "iff": IFF(0.08, 0.88, "charge+gauge")})
    with pytest.raises(ExportError, match="only the charge bridge"):
        MimoController.from_design(design, fsm, name="mimo")


def test_an_iff_over_the_current_window_budget_does_not_export(fsm):
    """A bridge IFF whose force-estimate noise alone (gain x sigma_F, ~1 x through the high-pass and the RC lead)
    is twice each stack's budget R min(I_source, I_sink) / 3 is refused by the export, naming the budget."""
    import dataclasses
    from types import SimpleNamespace
    from workbench.design.mimo import force_noise_n
    from workbench.export.sos import ExportError
    design, _ = quick_design(fsm, iff=True)
    b = min(p.pzt.series_resistance_ohm * min(p.pzt.current_limit_source_a, p.pzt.current_limit_sink_a) / 3
            for p in fsm.plants)
    g = 2 * b / float(np.min(force_noise_n(fsm, "bridge")))
    loud = SimpleNamespace(**{**vars(design), "iff": dataclasses.replace(design.iff, gain_v_per_n=g)})
    with pytest.raises(ExportError, match=rf"noise budget R min\(I_source, I_sink\) / 3 = {re.escape(f'{1e3 * b:.3g}')} mV"
                                          r".*use at most"):
        MimoController.from_design(loud, fsm, name="mimo")


def test_step_composes_the_float_matrices_and_cascades(ctrl, rng):
    """Small inputs (no clamp, no window): the words give In' K (r' - Out' g), K the axis cascades' own LTI,
    to within quantization; a transposed or swapped matrix would miss by the signal itself."""
    n = 400
    g = 1e-3 * rng.standard_normal((n, 3))
    r = 1e-3 * rng.standard_normal((n, 3)) * ctrl.axis_scale
    v = ctrl.run(g, r)
    e = r / ctrl.axis_scale - g @ ctrl.gauge_to_axes.T
    u = np.column_stack([control.forced_response(ctrl.axes[k].as_lti(), U=e[:, a]).outputs
                         for a, k in enumerate(("tip", "tilt", "piston"))])
    want = u @ ctrl.axes_to_stacks.T
    # the words' rounding, integrated over the record: ~1e-5 V (1e-7 of the 140 V range); a swapped or
    # transposed matrix misses by the signal (~1e-3 V)
    assert np.abs(want).max() > 1e-3
    np.testing.assert_allclose(v, want, atol=2e-5, rtol=0)


def test_json_round_trip_is_the_same_controller(ctrl, tmp_path, rng):
    paths = ctrl.write(tmp_path, "mimo")
    back = MimoController.load(paths["json"])
    g, r = _records(ctrl, rng, 200, 200)
    np.testing.assert_array_equal(back.run(g, r), ctrl.run(g, r))
    assert back.record["provenance"]["serials"] == ctrl.record["provenance"]["serials"]


def _corrupt(data, change):
    data = json.loads(json.dumps(data))
    change(data)
    return data


@pytest.mark.parametrize("change, key", [
    (lambda d: d.update(schema="workbench.controller/9"), "schema"),
    (lambda d: d["gauge_to_axes"][1].__setitem__(2, float("nan")), "gauge_to_axes"),
    (lambda d: d.update(axes_to_stacks=[[1, 1, 1], [1, 1, 1], [0, 1, 0]]), "axes_to_stacks"),
    (lambda d: d.update(axis_scale=[1.0, -1.0, 1.0]), "axis_scale"),
    (lambda d: d.update(stack_limits_v=[[120, -20], [-20, 120], [-20, 120]]), "stack_limits_v"),
    (lambda d: d["controllers"]["tilt"]["sos"][0].__setitem__(5, 1.5), "controllers.tilt"),
    (lambda d: d["controllers"].pop("piston"), "controllers.piston"),
    (lambda d: d.update(sample_rate_hz=20000.0), "sample_rate_hz"),
    (lambda d: d["fixed_point"]["axes_to_stacks_q"][0].__setitem__(0, 7), "fixed_point.axes_to_stacks_q"),
    (lambda d: d.update(name="../../evil"), "name"),
    (lambda d: d.update(name="9lives"), "name"),
])
def test_bad_controller_files_name_the_key(ctrl, tmp_path, change, key):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(_corrupt(ctrl.to_dict(), change)))
    with pytest.raises(MimoControllerError) as err:
        MimoController.load(path)
    assert f"[{key}]" in str(err.value) and str(path) in str(err.value)


def test_a_siso_controller_is_named_as_such(root, tmp_path):
    with pytest.raises(MimoControllerError, match=r"\[schema\].*SISO"):
        MimoController.load(root / "controllers" / "sn637_loopshape.json")
    assert MIMO_SCHEMA.startswith("workbench.mimo_controller/")


def _unequal_stacks(fsm):
    """The mirror with three different series resistors and current limits (R x 1, 1.7, 0.6; I_source x 1.3,
    0.8, 1; I_sink x 1, 0.8, 1.5): every stack's alpha and R min(I_source, I_sink) differ, and in a different
    order, so a swapped stack index or one stack's alpha used for all moves some stack's lead off its window."""
    import dataclasses
    plants = []
    for pl, r, i_src, i_snk in zip(fsm.plants, (1.0, 1.7, 0.6), (1.3, 0.8, 1.0), (1.0, 0.8, 1.5)):
        pz = pl.pzt
        plants.append(dataclasses.replace(pl, pzt=dataclasses.replace(
            pz, series_resistance_ohm=r * pz.series_resistance_ohm,
            current_limit_source_a=i_src * pz.current_limit_source_a,
            current_limit_sink_a=i_snk * pz.current_limit_sink_a)))
    return dataclasses.replace(fsm, plants=tuple(plants))


@pytest.mark.parametrize("unequal", [False, True])
def test_damped_step_keeps_every_stack_in_its_current_window(ctrl_iff, design_iff, fsm, rng, unequal):
    """With IFF the whole stack command (axes + IFF correction) leads the stack's RC model of it by at most
    R min(I_source, I_sink) (each serial file's window, as the notch-only axes keep): replayed here in float
    from the plant's R, current limits and largest capacitance, on records that drive the axes, the bridges
    and the stacks to their clamps (the window is reached, so the bound is the clamp's, not the records')."""
    from workbench.controller import plant_window
    ctrl = ctrl_iff
    if unequal:
        fsm = _unequal_stacks(fsm)
        ctrl = MimoController.from_design(design_iff, fsm, name="mimo")
        w = [plant_window(pl, ctrl.dt_s) for pl in fsm.plants]
        assert len({x[0] for x in w}) == 3 and len({min(x[1:]) for x in w}) == 3
    g, r = _records(ctrl, rng, 3000, 5000)
    b = _bridge_records(ctrl, rng, len(g))
    u0 = np.array([3.0, -2.0, 40.0])
    v = ctrl.run(g, r, u0_axes_v=u0, b_v=b)
    lsb = 2.0 ** -ctrl.stack_frac_bits
    for j, pl in enumerate(fsm.plants):
        alpha, h_up, h_down = plant_window(pl, ctrl.dt_s)
        h = min(h_up, h_down)
        m = ctrl.stack_volts(ctrl.stack_words_at(ctrl.reset(u0)[1]))[j]
        lead = np.empty(len(v))
        for k in range(len(v)):
            lead[k] = v[k, j] - m
            m += alpha * lead[k]
        assert np.abs(lead).max() <= h + 4 * lsb, j
        assert np.abs(lead).max() >= 0.99 * h, j


GOLDEN = Path(__file__).parent / "golden_notch_only"
# sha256 of the stack words (little-endian int64, 13000 x 3) the pre-IFF exporter (commit 135d64e^1) produced
# for _golden_records on its export of quick_design(fsm); the record reaches the top stack clamp
GOLDEN_RUN_SHA256 = "102783092bf92d61cd3ed629825eebfaaa9bab8f7640d37d90572685fe683db5"


def _golden_records(ctrl):
    rng = np.random.default_rng(15)
    n, held = 1000, 6000
    g = np.concatenate([rng.uniform(-3.0, 3.0, (n, 3)), np.tile([2.6, -2.6, 2.6], (held, 1)),
                        np.tile([-2.6, 2.6, -2.6], (held, 1))])
    reach = 80.0 * ctrl.axis_scale
    r = np.concatenate([rng.uniform(-1, 1, (n, 3)) * reach, np.tile(reach, (held, 1)), -np.tile(reach, (held, 1))])
    return g, r


def _run_sha(ctrl):
    import hashlib
    g, r = _golden_records(ctrl)
    w = np.rint(ctrl.run(g, r, u0_axes_v=np.array([3.0, -2.0, 40.0])) * 2.0 ** ctrl.stack_frac_bits).astype("<i8")
    assert np.any(w == ctrl.stack_limit_words[:, 1])
    return hashlib.sha256(np.ascontiguousarray(w).tobytes()).hexdigest()


def test_notch_only_export_is_the_pre_iff_one(ctrl, root, tmp_path):
    """Golden: the notch-only export of quick_design (headers, JSON, the step's words on a record reaching the
    stack clamp) is the one the exporter wrote before the IFF stack windows (files written by commit 135d64e^1,
    tests/verify/golden_notch_only; plant paths made relative). The IFF work must leave it alone; a legitimate
    change to the notch-only design or export must regenerate these files from a reviewed commit."""
    paths = ctrl.write(tmp_path, "mimo")
    for f in ("mimo.h", "mimo_tip.h", "mimo_tilt.h", "mimo_piston.h"):
        assert paths[{"mimo.h": "h"}.get(f, f[5:].replace(".h", "_h"))].read_text() == (GOLDEN / f).read_text(), f
    want = json.loads((GOLDEN / "mimo.json").read_text())
    got = json.loads(paths["json"].read_text())
    for d in (want, got):
        prov = d["provenance"]
        prov["plant_file"] = Path(prov["plant_file"]).name
        prov["stack_files"] = [Path(p).name for p in prov["stack_files"]]
    assert got == want
    assert _run_sha(ctrl) == GOLDEN_RUN_SHA256
    assert _run_sha(MimoController.load(GOLDEN / "mimo.json")) == GOLDEN_RUN_SHA256
