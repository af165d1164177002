"""Design studies: the study file is validated; a reduced study runs end to end (the full one: make demo)."""

import json
import re

import numpy as np
import pytest

from ..conftest import FULL
from workbench.cli import main
from workbench.errors import StudyDefinitionError
from workbench.study.spec import load_study


def _study_text(root, reduced=True):
    text = (root / "studies" / "sn637_servo.toml").read_text()
    text = text.replace('"../plants/', f'"{root}/plants/')
    if reduced:
        text = re.sub(r"amplitudes_v = \[.*?\]", "amplitudes_v = [0.1, 3.0]", text)
        text = re.sub(r"freq_points = \d+", "freq_points = 36", text)
        text = re.sub(r'serials = \[.*?\]', f'serials = ["{root}/plants/p888_51_sn618.toml"]', text)
        text = text.replace("fc_min_hz = 50.0", "fc_min_hz = 80.0")
        text = re.sub(r"integral_ratios = \[.*?\]", "integral_ratios = [0.1, 0.25]", text)
    return text


def test_the_shipped_study_loads(root):
    s = load_study(root / "studies" / "sn637_servo.toml")
    assert s.plant.name == "p888_51_sn637_creep.toml" and len(s.serials) == 2
    assert s.targets["phase_margin_deg"] == 45.0 and s.export["output_limits_v"].tolist() == [-20.0, 120.0]


@pytest.mark.parametrize("old, new, key", [
    ("freq_points = 60", "freq_points = 3", "family.freq_points"),
    ("phase_margin_deg = 45.0", "phase_margin_deg = \"45\"", "targets.phase_margin_deg"),
    ("bias_v = 50.0", "bias_v = 50.0\nbias_mv = 1", "family.bias_mv"),
    ("time_limit_s = 60.0", "time_limit_s = nan", "hinf.time_limit_s"),
    ("output_limits_v = [-20.0, 120.0]", "output_limits_v = [120.0, -20.0]", "export.output_limits_v"),
    ("plant = \"../plants/p888_51_sn637_creep.toml\"", "plant = \"../plants/nothing.toml\"", "plant"),
    ("[targets]", "[target]", "target"),
])
def test_bad_study_files_name_file_and_key(tmp_path, root, old, new, key):
    text = (root / "studies" / "sn637_servo.toml").read_text()
    assert old in text
    (tmp_path / "studies").mkdir()
    (tmp_path / "plants").symlink_to(root / "plants")
    bad = tmp_path / "studies" / "bad.toml"
    bad.write_text(text.replace(old, new, 1))
    with pytest.raises(StudyDefinitionError, match=re.escape(f"[{key}]")) as err:
        load_study(bad)
    assert str(bad) in str(err.value)
    assert main(["study", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_study_end_to_end(tmp_path, root):
    study = tmp_path / "study.toml"
    study.write_text(_study_text(root, reduced=not FULL))
    out = tmp_path / "out"
    assert main(["study", str(study), "--out", str(out), "--cache-dir", str(tmp_path / "cache")]) == 0
    summary = json.loads((out / "summary.json").read_text())
    ls = summary["designs"]["loop_shape"]
    assert ls["meets_targets"]
    q = ls["worst_quantized"]
    assert q["phase_margin_deg"]["value"] >= 45 and q["gain_margin_db"]["value"] >= 6
    assert q["crossover_hz_min"]["value"] >= 60
    # the exported controller carries what the verification issue needs
    ctrl = json.loads((out / "controllers" / "sn637_loopshape.json").read_text())
    for key in ("name", "method", "sample_rate_hz", "input", "output", "gain", "sos", "output_limits_v",
                "gauge_chain", "margins", "fixed_point", "provenance", "anti_windup"):
        assert key in ctrl, key
    assert ctrl["input"] == {"signal": "gauge_error", "units": "V"}
    aw = ctrl["anti_windup"]
    assert aw["method"] == "conditioned_cascade"
    up, down = aw["output_slew_limit_v_per_s"]
    assert down / up == pytest.approx(7.0)                    # +2 / -14 mA through the same capacitance
    assert aw["voltage_model"]["headroom_v"] == pytest.approx([80 * 0.002, 80 * 0.014])     # R I_max
    # the slew the window allows: the source current into the largest capacitance (~168 V/s), a little
    # less for the discrete RC step (alpha = 1 - exp(-T / RC) < T / RC): never faster than the stack
    assert 0.9 * 0.002 / 11.9e-6 < up < 1.01 * 0.002 / 11.9e-6
    # the fixed-point step firmware runs carries the same window (the verification runs that step)
    block = ctrl["fixed_point"]["output"]["voltage_model"]
    assert block["alpha"] == pytest.approx(aw["voltage_model"]["alpha"])
    assert block["headroom_v"] == pytest.approx(aw["voltage_model"]["headroom_v"])
    # the gauge noise on the command and the nominal overshoot stay inside the study's budgets
    budget = summary["budgets"]["noise_command_v"]
    assert budget["source"] == "plant" and budget["value"] == pytest.approx(80 * 0.002 / 3)
    assert ls["noise_command_rms_v"] <= budget["value"] + 1e-12 and ls["step_overshoot_percent"] <= 3.0
    for ext in ("h", "csv", "mat"):
        assert (out / "controllers" / f"sn637_loopshape.{ext}").stat().st_size > 100
    report = (out / "report.md").read_text()
    for png in re.findall(r"\(([a-z_]+\.png)\)", report):
        assert (out / png).stat().st_size > 10_000, png
    # the other designs ran (or said clearly why not)
    d = summary["designs"]
    assert d["coprime"]["eps"] > 0.2
    for key in ("hinf", "convex"):
        assert "gamma" in d[key] or "error" in d[key]
    assert np.isfinite(d["hinf"].get("gamma", 1.0))


def test_the_committed_controller_matches_its_plant_and_holds_the_margins(root):
    # controllers/sn637_loopshape.json is what the verification issue runs: it must come from the
    # plant file as it is now, and keep the targets on the family (reduced grid here)
    import hashlib

    from workbench.design.loopshape import family_loops
    from workbench.design.margins import family_margins
    from workbench.linearize.limit_cycle import load_controller
    from workbench.linearize.uncertainty import FamilySpec, plant_family
    from workbench.plant import load_plant
    ctrl_json = json.loads((root / "controllers" / "sn637_loopshape.json").read_text())
    plant_file = root / "plants" / "p888_51_sn637_creep.toml"
    assert ctrl_json["provenance"]["plant_sha256"] == hashlib.sha256(plant_file.read_bytes()).hexdigest(), \
        "plant file changed: re-run `make demo` and copy out/study/controllers/sn637_loopshape.* to controllers/"
    ctrl = load_controller(root / "controllers" / "sn637_loopshape.json")
    fam = plant_family([load_plant(plant_file)], FamilySpec(amplitudes_v=(0.1,), freq_hz=tuple(np.geomspace(1, 4990, 40)),
                                                           small_signal_biases_v=(50.0,)))
    members = {n: g for n, g in fam.members.items() if np.any(np.isfinite(g))}
    _, worst = family_margins(fam.freq_hz, family_loops(ctrl, fam.freq_hz, members))
    assert worst["phase_margin_deg"]["value"] >= 45 and worst["gain_margin_db"]["value"] >= 6
    assert worst["crossover_hz_min"]["value"] >= 60
