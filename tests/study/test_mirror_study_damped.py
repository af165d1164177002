"""The mirror study with the IFF-damped design on (``[design] iff = true``), end to end (issue 15, workbench/study/mirror.py).

One study run and one verification of its damped export (module fixture, ``slow``): the floors the damped
design meets are asserted (loop-at-a-time PM >= 40 deg / GM >= 6 dB, simultaneous alpha >= 0.4, the tip
triangle <= 0.1 % of the range RMS with tilt coupling <= 0.1 %, every stack's current inside the window
R min(I_source, I_sink) that the notch-only design keeps), and the two it misses are documented as strict
xfails: the 2x damped bandwidth (the housing's mirror-angle zeros and the plant's noise budget: README,
mirror section; full form only, the reduced form cannot reach it) and the torque step's sink current (~2.1 mA
against the design's symmetric 2 mA window; inside the amplifier's 14 mA sink limit), where the disturbance's
back-EMF adds to a command at the window's edge. Reduced form (make test): crossovers searched over 50-70 Hz
(one loop-shape evaluation per shape instead of ~10); full (WORKBENCH_FULL=1): studies/fsm_servo.toml as
shipped, plus ``iff = true``. The plant's noise budget stays on in both.
"""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from workbench.cli import main

pytestmark = pytest.mark.slow

FLOORS = {"phase_margin_deg": 40.0, "gain_margin_db": 6.0, "alpha": 0.4, "bandwidth_ratio": 2.0}
FULL = os.environ.get("WORKBENCH_FULL") == "1"
REDUCED_FC_HZ = (50.0, 70.0)        # the reduced form's crossover search (make test)


@pytest.fixture(scope="module")
def damped(root, tmp_path_factory):
    from workbench.plant.mirror import load_mirror
    tmp = tmp_path_factory.mktemp("fsm_iff")
    plant = root / "plants" / "fsm_p888_51.toml"
    text = (root / "studies" / "fsm_servo.toml").read_text().replace(
        'plant = "../plants/fsm_p888_51.toml"', f'plant = "{plant.as_posix()}"')
    assert "\n[design]\n" in text
    extra = "iff = true\n" + ("" if FULL else "fc_min_hz = {:g}\nfc_max_hz = {:g}\n".format(*REDUCED_FC_HZ))
    text = text.replace("\n[design]\n", "\n[design]\n" + extra)
    study = tmp / "fsm_iff.toml"
    study.write_text(text)
    assert main(["study", str(study), "--out", str(tmp / "o"), "--json", str(tmp / "s.json")]) == 0
    data = json.loads((tmp / "s.json").read_text())
    ctrl = data["damped"]["exported"]["json"]
    assert main(["verify", str(plant), "--controller", ctrl, "--out", str(tmp / "v"), "--json", str(tmp / "v.json")]) == 0
    return data, json.loads((tmp / "v.json").read_text()), load_mirror(plant)


def _ratios(data):
    return {ax: data["damped"]["design"]["axes"][ax]["bandwidth_hz"]["value"]
            / data["design"]["axes"][ax]["bandwidth_hz"]["value"] for ax in ("tip", "tilt", "piston")}


def test_damped_design_meets_the_margin_floors(damped):
    """Loop-at-a-time PM/GM on every axis and member, simultaneous alpha at the stack inputs and axis outputs;
    the IFF high-pass at tan(10 deg) x the lowest crossover searched (design.mimo.iff_corner_hz)."""
    from workbench.design.mimo import IFF_PHASE_COST_DEG, MIMO_SPEC
    data, _, _ = damped
    d = data["damped"]["design"]
    for ax, a in d["axes"].items():
        assert a["phase_margin_deg"]["value"] >= FLOORS["phase_margin_deg"], ax
        assert a["gain_margin_db"]["value"] >= FLOORS["gain_margin_db"], ax
    assert min(d["disk_in"]["alpha"], d["disk_out"]["alpha"]) >= FLOORS["alpha"]
    fc_min = MIMO_SPEC.fc_range_hz[0] if FULL else REDUCED_FC_HZ[0]     # studies/fsm_servo.toml: MIMO_SPEC's
    assert d["iff"]["corner_hz"] == pytest.approx(np.tan(np.radians(IFF_PHASE_COST_DEG)) * fc_min, rel=1e-9)
    assert d["iff"]["source"] == "bridge" and d["iff"]["zeta_min_damped"] > 2 * d["iff"]["zeta_min_open"]


def test_iff_corner_clears_the_verified_mirrors_drift(damped, root):
    """The corner against the drift of the mirror verify runs (every stack with the sn637 creep branches: the
    fastest, 0.1 s, reads at 1/(2 pi tau) = 1.6 Hz): at least IFF_DRIFT_MARGIN above it, reported with the
    high-pass's gain there, not only against the serial files (no creep: dielectric absorption)."""
    from workbench.design.mimo import IFF_DRIFT_MARGIN
    from workbench.plant.files import load_plant
    from workbench.verify.mirror import VERIFY_CREEP_FILE
    data, _, _ = damped
    vd, corner = data["damped"]["verified_drift"], data["damped"]["design"]["iff"]["corner_hz"]
    tau = float(np.min(load_plant(root / "plants" / VERIFY_CREEP_FILE).pzt.creep.time_constants_s))
    assert vd["drift_hz"] == pytest.approx(1 / (2 * np.pi * tau), rel=1e-9) and "creep" in vd["drift_source"]
    assert vd["drift_hz"] > data["damped"]["design"]["iff"]["drift_hz"]
    assert vd["drift_margin"] == pytest.approx(corner / vd["drift_hz"]) and vd["drift_margin"] >= IFF_DRIFT_MARGIN
    text = Path(data["report"]).read_text(encoding="utf-8")
    assert f"corner {vd['drift_margin']:.3g}x above it" in text


def test_damped_export_tracks_the_triangle(damped):
    """Issue 15's tip triangle (0.1 Hz, 10-90 % of the range) with unequal hysteresis, creep, gauge and bridge
    noise: tip error and tilt coupling <= 0.1 % of the range RMS."""
    _, v, _ = damped
    for key in ("tip_rms_percent", "tilt_coupling_rms_percent"):
        assert v["targets"][key]["met"] and v["targets"][key]["value"] <= 0.1, (key, v["targets"][key])


def _window_ma(fsm):
    return 1e3 * min(min(p.pzt.current_limit_source_a, p.pzt.current_limit_sink_a) for p in fsm.plants)


def test_damped_export_keeps_every_stack_in_its_current_window(damped):
    """The window the notch-only export keeps, R min(I_source, I_sink) of command lead over the stack's RC model
    (2 mA on the P-888.51 serials): the damped export's commands stay inside it on every scenario (the current
    its model predicts, replayed from the commands), and so does the simulated current on every scenario the
    reference drives (steps, triangle, piston hold with creep, the 80 % tip step the window slews)."""
    _, v, fsm = damped
    w = _window_ma(fsm)
    for m in v["metrics"]:
        assert max(m["model_peak_current_ma"]) <= w * (1 + 1e-3), (m["scenario"], m["model_peak_current_ma"])
        if m["scenario"] != "torque_step":
            assert max(m["peak_current_ma"]) <= w, (m["scenario"], m["peak_current_ma"])


@pytest.mark.xfail(strict=True, reason="the torque step rings the ~1 kHz tip mode: its back-EMF (V_p moves up to ~0.03 V "
                                       "per period) adds to an IFF command at the window's edge: a sink current "
                                       "of ~2.1 mA, above the design's own symmetric window R min(I_source, I_sink) "
                                       "(2 mA) and well inside the amplifier's 14 mA sink limit; the firmware's RC "
                                       "model does not see the mechanics (README, mirror section)")
def test_damped_torque_step_current_inside_the_window(damped):
    """The design's symmetric window min(I_source, I_sink) on the simulated current of the torque step (a sink
    current here): missed (xfail). The amplifier's own sink limit (14 mA) is not what is missed; the metrics
    carry |i| only, so the source/sink limits are not asserted separately here."""
    _, v, fsm = damped
    m = next(m for m in v["metrics"] if m["scenario"] == "torque_step")
    assert max(m["peak_current_ma"]) <= _window_ma(fsm), m["peak_current_ma"]


def test_damped_bandwidth_ratio_is_reported(damped):
    """The report states the 2x target's outcome as the unrounded tip/tilt ratios give it (no floor asserted)."""
    from workbench.study.mirror import damped_ratio_met
    data, _, _ = damped
    r = _ratios(data)
    print(f"damped / notch-only bandwidth: {', '.join(f'{k} {x:.2f}x' for k, x in r.items())}")
    text = Path(data["report"]).read_text(encoding="utf-8")
    assert ("2x target: **met**" in text) == damped_ratio_met([r["tip"], r["tilt"]])


@pytest.mark.skipif(not FULL, reason="only the full form (WORKBENCH_FULL=1) can test the 2x floor: the reduced form "
                                      "caps both crossovers at 70 Hz, so a damped bandwidth of 2x the notch-only "
                                      "one (~130 Hz) is out of its reach whatever the damping does")
@pytest.mark.xfail(strict=True, reason="issue 15's 2x floor is missed: the mirror-angle zeros at f_rock sqrt(1 + J/I_h) "
                                       "(440/545 Hz) cap the mirror's bandwidth, and with the IFF closed the plant's "
                                       "gain is ~3x lower under the same noise budget (README, mirror section)")
def test_damped_bandwidth_is_twice_the_notch_only(damped):
    data, _, _ = damped
    r = _ratios(data)
    assert min(r["tip"], r["tilt"]) >= FLOORS["bandwidth_ratio"], r
