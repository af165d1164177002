"""Plant files: every field validated, errors name file, key, value and expectation."""

import re

import numpy as np
import pytest

from workbench.errors import PlantDefinitionError
from workbench.plant import design_trim, load_plant

from ..conftest import PLANTS, SERIALS

CAL_UM_PER_V = {"sn637": 3.077, "sn629": 3.183, "sn618": 3.246}


@pytest.mark.parametrize("serial", SERIALS)
def test_seed_values(serial):
    p = load_plant(PLANTS / f"p888_51_{serial}.toml")
    pz, g = p.pzt, p.gauge
    assert pz.stiffness_n_per_m == 2.0e8 and pz.working_capacitance_f == 5.802e-6
    assert pz.series_resistance_ohm == 80.0 and pz.transducer_constant_n_per_v == 46.71
    assert (pz.current_limit_source_a, pz.current_limit_sink_a) == (2e-3, 14e-3)
    assert (pz.voltage_min_v, pz.voltage_max_v) == (-20.0, 120.0)
    assert pz.hysteresis.size >= 10 and pz.creep is None
    assert [m.freq_hz for m in pz.modes] == [70000.0]
    assert g.calibration_m_per_v == pytest.approx(CAL_UM_PER_V[serial] * 1e-6)
    assert all(abs(d) <= 0.4 for d in g.imbalance_ohm)  # seed: bounded by +/-0.4 ohm
    # the firmware trim in the file is the one design_trim derives for this serial
    scale, bias = design_trim(g)
    assert g.trim_scale == pytest.approx(scale, rel=1e-6)
    assert g.trim_bias_v == pytest.approx(bias, abs=1e-6)


def test_every_value_has_a_source_comment():
    for path in PLANTS.glob("*.toml"):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if re.match(r"^\s*[a-z_]+\s*=", line) and not line.startswith(("schema", "name", "serial")):
                assert "#" in line or _commented_above(path, n), f"{path.name}:{n} has no source: {line}"


def _commented_above(path, n):
    lines = path.read_text().splitlines()
    k = n - 2
    while k >= 0 and re.match(r"^\s*[a-z_]+\s*=", lines[k]):
        k -= 1
    return k >= 0 and lines[k].lstrip().startswith("#")


def test_creep_plant_is_sn637_plus_creep(sn637, sn637_creep):
    assert sn637_creep.creep is not None and sn637_creep.creep.size >= 4
    assert sn637_creep.pzt.working_capacitance_f == sn637.pzt.working_capacitance_f
    assert np.array_equal(sn637_creep.pzt.hysteresis.weights, sn637.pzt.hysteresis.weights)


BASE = (PLANTS / "p888_51_sn637.toml").read_text()


@pytest.mark.parametrize("old, new, key, fragment", [
    ("stiffness_n_per_m = 2.0e8", "stiffness_n_per_m = -2.0e8", "mechanics.stiffness_n_per_m", "got -200000000.0"),
    ("stiffness_n_per_m = 2.0e8", "stiffnes_n_per_m = 2.0e8", "mechanics.stiffnes_n_per_m", "unknown key"),
    ("series_resistor_ohm = 80.0", "", "electrical.series_resistor_ohm", "missing"),
    ("gauge_factor = 2.05", 'gauge_factor = "2.05"', "gauge.gauge_factor", "expected a number"),
    ("gauge_factor = 2.05", "gauge_factor = nan", "gauge.gauge_factor", "finite"),
    ("adc_bits = 14", "adc_bits = 14.5", "gauge.adc_bits", "integer"),
    ("damping_ratio = 0.02", "damping_ratio = 2.0", "mechanics.modes.damping_ratio", "(0, 1]"),
    ("samples_per_half_period = 40", "samples_per_half_period = 41", "gauge", "adc_rate_hz"),
    ("voltage_min_v = -20.0", "voltage_min_v = 5.0", "electrical.voltage_min_v", "<= 0"),
    ("initial_states_v = [0, 0,", "initial_states_v = [0, 9,", "hysteresis.initial_states_v",
     "no input history"),
    ("weights_f = [9.361e-6,", "weights_f = [-9.361e-6,", "hysteresis", "partial sums"),
    ('schema = "workbench.plant/1"', 'schema = "workbench.plant/9"', "schema", "expected"),
    ("[mechanics]", "[mechanic]", "mechanic", "unknown section"),
])
def test_bad_fields_are_named(tmp_path, old, new, key, fragment):
    assert old in BASE
    path = tmp_path / "bad.toml"
    path.write_text(BASE.replace(old, new, 1))
    with pytest.raises(PlantDefinitionError, match=re.escape(f"[{key}]")) as err:
        load_plant(path)
    assert fragment in str(err.value) and str(path) in str(err.value)
    assert path.read_text() == BASE.replace(old, new, 1)  # never modified


def test_syntax_error_is_named(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("schema = \n")
    with pytest.raises(PlantDefinitionError, match=r"\[syntax\] is not valid TOML"):
        load_plant(path)
