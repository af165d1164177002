"""One table of key-suffix units, read the same way by the --set parser and the reports."""

import pytest

from workbench.errors import UnitError
from workbench.report.markdown import readable_quantity
from workbench.study.overrides import parse_overrides
from workbench.units import unit_of_key


@pytest.mark.parametrize("key, unit, words", [
    ("stiffness_n_per_m", "N/m", ["stiffness"]),
    ("transducer_n_per_v", "N/V", ["transducer"]),
    ("slew_v_per_s", "V/s", ["slew"]),
    ("gain_per_s", "1/s", ["gain"]),
    ("noise_rms_m", "m", ["noise", "rms"]),
    ("current_limit_source_a", "A", ["current", "limit", "source"]),
    ("phase_margin_deg", "deg", ["phase", "margin"]),
    ("alpha", "", ["alpha"]),
])
def test_unit_of_key(key, unit, words):
    assert unit_of_key(key) == (unit, words)


def test_set_parser_and_report_agree_on_the_unit():
    # 200 N/um on a stiffness key is 2e8 N/m for the parser; the report shows the same key in N/m
    (entry,) = parse_overrides(["mechanics.stiffness_n_per_m=200N/um"]).items()
    assert entry[1] == pytest.approx(2e8)
    assert readable_quantity("stiffness_n_per_m", 2e8)[2] == "N/m"
    # a rate key is V/s, not seconds (the old parser read its last suffix only)
    (entry,) = parse_overrides(["targets.max_slew_v_per_s=2kV/s"]).items()
    assert entry[1] == pytest.approx(2e3)
    # a percentage key takes a plain number
    with pytest.raises(UnitError):
        parse_overrides(["targets.max_overshoot_percent=3V"])
