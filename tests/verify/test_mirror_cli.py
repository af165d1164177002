"""Commands refuse what they do not implement or cannot run, before any work: mirror flags they would ignore,
an export outside --out, a controller name that is no C identifier (review findings)."""

import pytest

from workbench.cli import main
from workbench.export.mimo import MimoController
from workbench.plant.mirror import load_mirror

from .mirror_cases import quick_design


@pytest.fixture(scope="module")
def mimo_json(root, tmp_path_factory):
    fsm = load_mirror(root / "plants" / "fsm_p888_51.toml")
    design, _ = quick_design(fsm)
    return MimoController.from_design(design, fsm, name="fsm_quick").write(tmp_path_factory.mktemp("c"), "fsm_quick")["json"]


@pytest.mark.parametrize("flags, named", [(["--hold", "2s"], "--hold"), (["--sensor", "fused"], "--sensor"),
                                          (["--scenario", "small_step"], "--scenario"), (["--strict"], "--strict"),
                                          (["--target", "small_step_settling_ratio=3"], "--target")])
def test_mirror_verify_refuses_flags_it_would_ignore(root, tmp_path, mimo_json, capsys, flags, named):
    out = tmp_path / "o"
    assert main(["verify", str(root / "plants" / "fsm_p888_51.toml"), "--controller", str(mimo_json),
                 "--out", str(out)] + flags) == 2
    err = capsys.readouterr().err
    assert named in err and "Traceback" not in err
    assert not out.exists()


def _study(root, tmp_path, old=None, new=None):
    text = (root / "studies" / "fsm_servo.toml").read_text().replace(
        'plant = "../plants/fsm_p888_51.toml"', f'plant = "{root / "plants" / "fsm_p888_51.toml"}"')
    if old is not None:
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "s.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("old, new, key", [('directory = "controllers"', 'directory = "/tmp/escaped_fsm"', "export.directory"),
                                           ('name = "fsm_servo"', 'name = "fsm servo"', "export.name"),
                                           ('name = "fsm_servo"', 'name = "9fsm"', "export.name")])
def test_mirror_study_export_checked_before_design(root, tmp_path, capsys, old, new, key):
    out = tmp_path / "o"
    assert main(["study", str(_study(root, tmp_path, old, new)), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"[{key}]" in err and "Traceback" not in err
    assert not out.exists()


def test_mirror_study_refuses_set(root, tmp_path, capsys):
    assert main(["study", str(_study(root, tmp_path)), "--out", str(tmp_path / "o"), "--set", "design.bias_v=40"]) == 2
    assert "--set" in capsys.readouterr().err


def test_sensor_hold_too_short_is_refused_before_identification(root, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["verify", str(root / "plants" / "p888_51_sn637_creep.toml"), "--controller",
                 str(root / "controllers" / "sn637_fused_loopshape.json"), "--sensor", "fused", "--hold", "2s",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--hold" in err and "at least 3s" in err and "identification" not in err
    assert not out.exists()


@pytest.mark.parametrize("hz", ["0.005", "6000"])
def test_a_blend_crossover_the_firmware_cannot_hold_is_refused_before_design(root, tmp_path, capsys, hz):
    out = tmp_path / "o"
    assert main(["study", str(root / "studies" / "sn637_fused_servo.toml"), "--out", str(out), "--only", "loopshape",
                 "--set", f"sensor.blend_crossover_hz={hz}Hz"]) == 2
    err = capsys.readouterr().err
    assert "[sensor.blend_crossover_hz]" in err and "Traceback" not in err
    assert not (out / "summary.json").exists()


@pytest.mark.parametrize("old, new, key, text", [
    ("[family]\nbias_v = 50.0", "family = 5", "family", "must be a table [family], got 5"),
    ("bias_v = 50.0", "bias_v = 900.0", "family.bias_v", "got 900.0"),
    ("noise_budget = true", "noise_budget = true\nfc_max_hz = 1e4", "design.fc_max_hz", "Nyquist frequency 5000 Hz"),
])
def test_mirror_study_file_faults_named_before_design(root, tmp_path, capsys, old, new, key, text):
    out = tmp_path / "o"
    assert main(["study", str(_study(root, tmp_path, old, new)), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"[{key}]" in err and text in err and "Traceback" not in err
    assert not out.exists()


def test_study_damped_verdict_reads_the_unrounded_ratios():
    """Issue 15's 2x on the damped / notch-only ratios themselves: 1.995 (printed "2.00") is missed."""
    from workbench.study.mirror import damped_ratio_met
    assert not damped_ratio_met([1.995, 3.0, 0.1]) and not damped_ratio_met([3.0, 1.9999999, 5.0])
    assert damped_ratio_met([2.0, 2.0, 0.1])          # piston does not count
