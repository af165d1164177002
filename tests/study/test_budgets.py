"""Budgets derived from the plant, --set overrides, the binding constraint, a failed study's report,
the family cache, and the one nominal loop checked with python-control."""

import json

import control
import numpy as np
import pytest

from workbench.cli import main
from workbench.design.budgets import plant_budgets
from workbench.errors import PlantDefinitionError, StudyDefinitionError, UnitError
from workbench.plant import load_plant
from workbench.study.overrides import parse_overrides, split_overrides

from .test_study import _study_text

AMP_20MA = ["--set", "electrical.current_limit_source_a=20mA", "--set", "electrical.current_limit_sink_a=20 mA"]


@pytest.mark.parametrize("source_a, sink_a", [(2e-3, 14e-3), (20e-3, 20e-3), (5e-3, 1e-3)])
def test_noise_budget_follows_the_amplifier(root, source_a, sink_a):
    plant_file = root / "plants" / "p888_51_sn637_creep.toml"
    plant = load_plant(plant_file, {"electrical.current_limit_source_a": source_a,
                                    "electrical.current_limit_sink_a": sink_a})
    b = plant_budgets(plant, 1e-4)
    # the smaller limit at 3 sigma through the 80 ohm series resistor
    assert b["noise_command_v"].value == pytest.approx(80.0 * min(source_a, sink_a) / 3)
    assert b["noise_command_v"].source == "plant"
    up, down = b["slew_v_per_s"].value
    assert down / up == pytest.approx(sink_a / source_a)
    assert b["current_window"].value[1:] == pytest.approx((80.0 * source_a, 80.0 * sink_a))
    # a study's own value wins and says so
    s = plant_budgets(plant, 1e-4, noise_override_v=0.02, study_path="s.toml")
    assert s["noise_command_v"].value == 0.02 and s["noise_command_v"].source == "study"
    # the file itself is untouched by the overrides
    assert load_plant(plant_file).pzt.current_limit_source_a == 2e-3


def test_set_parses_units_and_routes_to_plant_or_study():
    o = parse_overrides(["electrical.current_limit_source_a=20mA", "targets.min_crossover_hz=0.1kHz",
                         "family.amplitudes_v=[0.1, 3]", "export.name=lab", "electrical.series_resistor_in=false"])
    assert o["electrical.current_limit_source_a"] == pytest.approx(0.02)
    assert o["targets.min_crossover_hz"] == pytest.approx(100.0)
    assert o["family.amplitudes_v"] == [0.1, 3] and o["export.name"] == "lab"
    assert o["electrical.series_resistor_in"] is False
    plant, study = split_overrides(o)
    assert set(plant) == {"electrical.current_limit_source_a", "electrical.series_resistor_in"}
    with pytest.raises(UnitError, match="current_limit_source_a"):
        parse_overrides(["electrical.current_limit_source_a=20mV"])
    with pytest.raises(StudyDefinitionError, match="unknown section"):
        parse_overrides(["amplifier.current_a=1"])
    with pytest.raises(StudyDefinitionError, match="section.key=value"):
        parse_overrides(["electrical.current_limit_source_a"])


@pytest.mark.parametrize("item, key", [("electrical.current_limit_source_a=-2mA", "electrical.current_limit_source_a"),
                                       ("electrical.current_limit_source_a=20mV", "current_limit_source_a"),
                                       ("targets.phase_margin_deg=120", "targets.phase_margin_deg"),
                                       ("loop_shape.fc_max_hz=fast", "loop_shape.fc_max_hz"),
                                       ("electrical.no_such_key=1", "electrical.no_such_key")])
def test_bad_set_is_exit_2_before_any_work(tmp_path, root, capsys, item, key):
    study = tmp_path / "study.toml"
    study.write_text(_study_text(root))
    assert main(["study", str(study), "--out", str(tmp_path / "o"), "--set", item]) == 2
    assert key in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_override_errors_name_the_plant_file(root):
    with pytest.raises(PlantDefinitionError, match=r"p888_51_sn637_creep.toml: \[electrical.current_limit_sink_a\]"):
        load_plant(root / "plants" / "p888_51_sn637_creep.toml", {"electrical.current_limit_sink_a": -1.0})


@pytest.fixture(scope="module")
def studies(tmp_path_factory, root):
    """The reduced study for the flight (+2/-14 mA) and a +/-20 mA amplifier, then a 100 Hz floor (fails)."""
    base = tmp_path_factory.mktemp("budgets")
    study = base / "study.toml"
    study.write_text(_study_text(root))
    cache = base / "cache"
    runs = {}
    for name, extra in (("flight", []), ("lab", AMP_20MA),
                        ("floor", ["--set", "targets.min_crossover_hz=100Hz"])):
        out = base / name
        code = main(["study", str(study), "--out", str(out), "--only", "loopshape", "--cache-dir", str(cache),
                     *extra])
        runs[name] = (code, out, json.loads((out / "summary.json").read_text()))
    return runs


@pytest.mark.slow
def test_noise_budget_binds_the_flight_design_and_a_20ma_amplifier_crosses_higher(studies):
    code, out, s = studies["flight"]
    assert code == 0
    b = s["binding"]
    assert b["constraint"] == "noise budget" and b["value"] > b["limit"] == pytest.approx(80 * 0.002 / 3)
    assert b["relaxed"]["crossover_hz_min"] > s["designs"]["loop_shape"]["crossover_hz"]
    assert "noise budget" in (out / "report.md").read_text()
    code_lab, out_lab, lab = studies["lab"]
    assert code_lab == 0
    assert lab["budgets"]["noise_command_v"]["value"] == pytest.approx(80 * 0.020 / 3)
    assert lab["family_cache"]["hit"] is False           # another plant: another cache key
    fl, lb = s["designs"]["loop_shape"], lab["designs"]["loop_shape"]
    assert lb["nominal"]["crossover_hz"] > 1.2 * fl["nominal"]["crossover_hz"]
    assert lb["crossover_hz"] > fl["crossover_hz"]
    c_fl = json.loads((out / "controllers" / "sn637_loopshape.json").read_text())
    c_lab = json.loads((out_lab / "controllers" / "sn637_loopshape.json").read_text())
    assert not np.allclose(np.asarray(c_fl["sos"]) * c_fl["gain"], np.asarray(c_lab["sos"]) * c_lab["gain"])
    assert c_lab["anti_windup"]["voltage_model"]["headroom_v"] == pytest.approx([80 * 0.02, 80 * 0.02])


@pytest.mark.slow
def test_a_failed_study_reports_the_constraint_and_the_fix(studies):
    code, out, s = studies["floor"]
    assert code == 2
    assert s["family_cache"]["hit"] is True              # same plants and grid as the flight run
    f = s["failure"]
    assert f["constraint"] == "targets.min_crossover_hz" and f["value"] < f["limit"] == 100.0
    report = (out / "report.md").read_text()
    assert "FAILED" in report and "noise budget" in report and "What would make it pass" in report
    assert (out / "loop_bode.png").stat().st_size > 10_000
    assert not (out / "controllers").exists()            # nothing exported
    from ..report.test_reports import html_problems, markdown_problems
    assert markdown_problems(out / "report.md") == []                   # renders on GitHub
    assert html_problems(out / "report.html", out / "report.md") == []  # and as HTML, figures embedded
    fix = f["fix"]
    assert fix["changes"][0]["constraint"] == "noise budget"
    if fix["passes"]:
        assert fix["crossover_hz_min"] >= 100.0


@pytest.mark.slow
def test_python_control_closes_the_nominal_loop_as_the_study_reports(studies, root):
    """control.feedback of the exported controller with the nominal plant (minimal StateSpace): poles
    inside the unit circle; python-control's margins within 0.5 deg / 0.2 dB of the study's."""
    from workbench.design.nominal import nominal_plant
    from workbench.linearize.limit_cycle import load_controller
    _, out, s = studies["flight"]
    plant = load_plant(root / "plants" / "p888_51_sn637_creep.toml")
    nom = nominal_plant(plant, s["nominal_plant"]["bias_v"])
    c = load_controller(out / "controllers" / "sn637_loopshape.json")
    loop = control.ss(c) * nom.firmware
    cl = control.feedback(loop, 1)
    assert np.max(np.abs(cl.poles())) < 1.0
    gm, pm = control.stability_margins(loop, method="frd")[:2]      # what python-control picks for this loop
    reported = s["designs"]["loop_shape"]["nominal"]
    assert pm == pytest.approx(reported["phase_margin_deg"], abs=0.5)
    assert 20 * np.log10(gm) == pytest.approx(reported["gain_margin_db"], abs=0.2)


def test_an_unwritable_family_cache_costs_time_never_the_run(tmp_path):
    # a cache folder that is a file (or read-only) is warned about; the family is still returned
    from workbench.study.cache import cached_family
    blocker = tmp_path / "cache"
    blocker.write_text("a file where the cache folder should be\n")
    with pytest.warns(RuntimeWarning, match="not written"):
        fam, path, hit = cached_family("ab" * 32, blocker / "sub", lambda: {"members": 3})
    assert fam == {"members": 3} and path is None and hit is False
    fam, path, hit = cached_family("ab" * 32, tmp_path / "ok", lambda: {"members": 3})
    assert path.is_file() and not hit
    assert cached_family("ab" * 32, tmp_path / "ok", lambda: {"members": 4})[0] == {"members": 3}   # served


def test_a_plant_without_series_resistor_exports_a_slew_window():
    """`study --set electrical.series_resistor_ohm=0` (the schema's quasi-static form, legal) died in the export with
    a TypeError after the design (session 32). With the resistor out the window is a slew window (alpha 1, headroom
    I T / C_max), so the slew recorded is I / C_max each way, the amplifier's slew at the largest capacitance;
    with the resistor it is the window's alpha h / T each way."""
    import control
    from workbench.controller import Controller
    from workbench.plant import load_plant
    from workbench.study.run import _anti_windup_record
    from ..conftest import PLANTS
    path = PLANTS / "p888_51_sn637_creep.toml"
    pi = control.tf([1.0, 200.0], [1.0, 0.0])                          # a PI, continuous; from_lti discretizes it
    with_r = Controller.from_lti(pi, load_plant(path))
    without = Controller.from_lti(pi, load_plant(path, {"electrical.series_resistor_ohm": 0.0}))
    pz = load_plant(path).pzt
    c_h = float(np.sum(pz.hysteresis.weights)) + float(np.sum(pz.creep.capacitances_f))
    c_max = c_h * pz.c_pp_f / (c_h + pz.c_pp_f)
    assert without.fixed.voltage_model[0] == 1.0
    assert _anti_windup_record(without)["output_slew_limit_v_per_s"] == pytest.approx(
        [pz.current_limit_source_a / c_max, pz.current_limit_sink_a / c_max], rel=1e-12)
    alpha, h_up, h_down = with_r.fixed.voltage_model
    up, down = _anti_windup_record(with_r)["output_slew_limit_v_per_s"]
    assert up == pytest.approx(alpha * h_up / with_r.fixed.dt_s) and down == pytest.approx(alpha * h_down / with_r.fixed.dt_s)
    assert up > 0 and down > 0


@pytest.mark.parametrize("name", ["p888_51_sn637_creep", "p888_51_sn618"])
@pytest.mark.parametrize("source_a, sink_a", [(2e-3, 14e-3), (20e-3, 5e-3)])
def test_with_the_resistor_out_the_noise_budget_is_the_slew_windows_smaller_headroom(root, name, source_a, sink_a):
    """R out: the window is a slew of I T / C_max a sample around the last output, so the gauge noise's change of
    the command per sample is held at 3 sigma within the smaller headroom: min(I_source, I_sink) T / (3 C_max),
    C_max the file's plays and creep branches summed, in series with C_pp."""
    plant = load_plant(root / "plants" / f"{name}.toml", {"electrical.series_resistor_in": False,
                                                          "electrical.current_limit_source_a": source_a,
                                                          "electrical.current_limit_sink_a": sink_a})
    pz = plant.pzt
    c_h = float(np.sum(pz.hysteresis.weights)) + (0.0 if pz.creep is None else float(np.sum(pz.creep.capacitances_f)))
    c_max = c_h * pz.c_pp_f / (c_h + pz.c_pp_f)
    b = plant_budgets(plant, 1e-4)
    assert b["noise_command_v"].value == pytest.approx(min(source_a, sink_a) * 1e-4 / (3 * c_max), rel=1e-12)
    assert b["current_window"].value == pytest.approx((1.0, source_a * 1e-4 / c_max, sink_a * 1e-4 / c_max), rel=1e-12)
    assert "series resistor out" in b["noise_command_v"].derivation
