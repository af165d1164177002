"""Inputs the workbench accepts but reads otherwise than written, or runs on what they were not made for
(issue 17, session 32's outside pass): each is refused or said, on the console, in the JSON and to Python.

The numbers come from the plant files and Table 1; nothing is pinned from the code's own output.
"""

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from workbench.cli import main

ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / "plants/data/p888_51_instron_table1.csv"
SN637 = ROOT / "plants/p888_51_sn637.toml"
SN629 = ROOT / "plants/p888_51_sn629.toml"
SN618 = ROOT / "plants/p888_51_sn618.toml"
CTRL = ROOT / "controllers/sn637_loopshape.json"


def _r_in_stiffness_n_per_m():
    """The mean F/x of Table 1's R_in runs, read here from the CSV (not through the library)."""
    import csv
    lines = [ln for ln in TABLE.read_text(encoding="utf-8").splitlines() if ln.strip() and not ln.startswith("#")]
    rows = list(csv.DictReader(lines))
    ks = [float(r["force[N]"]) / (float(r["displacement[um]"]) * 1e-6) for r in rows
          if r["config"] == "R_in" and float(r["displacement[um]"]) != 0.0]
    return float(np.mean(ks))


def test_identify_refuses_a_stiffness_one_unit_prefix_or_more_from_the_r_in_runs():
    """The R_in runs measure k_p + T_em^2/(C_p + C_h) >= k_p: the seed's 200 N/um (1.3x below) and the R_in value
    itself are stiffnesses; a value 1000x off either way (N/mm, N/m for N/um's kilo) is a unit slip."""
    from workbench.errors import UnitError
    from workbench.identify.transducer import identify_transducer
    k = _r_in_stiffness_n_per_m()
    assert 2e8 < k < 3e8                                   # seed 000: ~259 N/um from the R_in runs
    for ok in (2e8, k, k / 5):                             # k_p <= k_R_in: above it eq. 6 turns negative
        identify_transducer(TABLE, stiffness_n_per_m=ok)
    for bad in (k / 1e3, 200.0, 200.0 * 1e3):
        with pytest.raises(UnitError, match="R_in runs"):
            identify_transducer(TABLE, stiffness_n_per_m=bad)
    with pytest.raises(ValueError, match="--stiffness"):       # above: eq. 6's T_em turns negative first
        identify_transducer(TABLE, stiffness_n_per_m=k * 1e3)


def test_amplitudes_are_bounded_by_each_plant_amplifier_span():
    """One home for the (0, span] V range: linearize's flag, sweep's flag and the sweep library."""
    from workbench.errors import FlagRangeError
    from workbench.linearize.run import check_amplitudes
    from workbench.plant import load_plant
    for path in (SN637, SN629, SN618):
        pzt = load_plant(path).pzt
        span = pzt.voltage_max_v - pzt.voltage_min_v
        check_amplitudes(pzt, [1e-3, 0.5 * span, span])
        for bad in (1.001 * span, 0.0, -1.0, float("nan"), float("inf")):
            with pytest.raises(FlagRangeError, match="out of range"):
                check_amplitudes(pzt, [bad], name="--amplitudes", where=str(path))


def _command_record(path, plant, serial=None):
    """A 0.2 s quasi-static sine of ``plant`` whose voltage column holds volts under a voltage[mV] label."""
    from workbench.plant import load_plant
    pzt = load_plant(plant).pzt
    t = np.arange(2000) / 1e4
    v = 50.0 + 40.0 * np.sin(2 * np.pi * 5.0 * t)
    x = pzt.quasi_static_x_m(np.r_[0.0, v])[1:] + 1e-9 * np.random.default_rng(3).standard_normal(t.size)
    rows = "\n".join(f"{a:.12g},{b:.9g},{c:.9g}" for a, b, c in zip(t, v, x))
    pre = f"# serial: {serial}\n" if serial else ""
    path.write_text(pre + "time[s],voltage[mV],displacement[m]\n" + rows + "\n", encoding="utf-8")
    return path


def test_calibrate_says_its_reinterpretations_on_the_console_and_in_the_json(tmp_path, capsys):
    """A voltage column in mV holding volts is taken for the amplifier's command, and a record's serial that is
    not the plant's: both were only in report.md's notes ("warnings": [] in --json). Now both are warnings, and
    the serial's message says what the run does with it (the updated plant keeps the plant's serial)."""
    from workbench.plant import load_plant
    rec = _command_record(tmp_path / "mv.csv", SN629, serial="SN637")
    assert load_plant(SN629).serial == "SN629"
    js = tmp_path / "c.json"
    assert main(["calibrate", str(rec), "--plant", str(SN629), "--json", str(js)]) == 0
    out = capsys.readouterr().out
    warns = json.loads(js.read_text(encoding="utf-8"))["warnings"]
    command = [w for w in warns if "amplifier's command" in w]
    serial = [w for w in warns if "SN637" in w and "SN629" in w]
    assert len(command) == 1 and "voltage[mV]" in command[0], warns
    assert len(serial) == 1 and "keeps serial SN629" in serial[0], warns
    for w in command + serial:
        assert f"WARNING: {w}" in out


def test_verify_warns_in_python_on_a_controller_for_another_plant():
    """wb.verify returned silently ("5 preflight mismatches" only in the repr); the CLI warned. SN618's trim
    differs from SN637's, for which the controller was exported; with strict it is refused."""
    import workbench as wb
    from workbench.controller import Controller
    from workbench.errors import ControllerMismatchError, ControllerMismatchWarning
    plant, ctrl = wb.load_plant(SN618), Controller.load(CTRL)
    assert plant.gauge.trim_scale != wb.load_plant(ROOT / "plants/p888_51_sn637_creep.toml").gauge.trim_scale
    with warnings.catch_warnings():
        # the warning as an error: verify warns before its runs (the test stays cheap)
        warnings.simplefilter("error", ControllerMismatchWarning)
        with pytest.raises(ControllerMismatchWarning, match="trim_scale"):
            wb.verify(plant, ctrl, ["small_step"])
    with pytest.raises(ControllerMismatchError, match="trim_scale"):
        wb.verify(plant, ctrl, ["small_step"], strict=True)
    from workbench.verify.run import check_controller_for_plant
    with warnings.catch_warnings():
        warnings.simplefilter("error", ControllerMismatchWarning)      # its own plant: no warning
        assert check_controller_for_plant(wb.load_plant(ROOT / "plants/p888_51_sn637_creep.toml"), ctrl) == []


def test_the_api_takes_a_plant_or_its_file_and_names_what_to_pass_otherwise():
    """wb.PZTSimulator(plant, dt) and wb.nominal_loop_plant("plants/...toml") raised AttributeErrors ('Plant' object
    has no attribute 'series_resistance_ohm'; 'str' object has no attribute 'gauge'): the obvious input is taken,
    and the same model results as from the object each function documents; anything else is a WorkbenchError."""
    import workbench as wb
    from workbench.errors import ArgumentKindError, WorkbenchError
    plant = wb.load_plant(SN637)
    v = np.linspace(0.0, 100.0, 200)
    ref = wb.PZTSimulator(plant.pzt, 1e-4).run(v).x_m
    for given in (plant, SN637, str(SN637)):
        np.testing.assert_array_equal(wb.PZTSimulator(given, 1e-4).run(v).x_m, ref)
    creep = ROOT / "plants/p888_51_sn637_creep.toml"
    a = wb.nominal_loop_plant(wb.load_plant(creep))
    b = wb.nominal_loop_plant(str(creep))
    np.testing.assert_array_equal(a.A, b.A)
    assert a.dt == b.dt == 1.0 / wb.load_plant(creep).gauge.modulation_hz
    for call in (lambda: wb.PZTSimulator(3.0, 1e-4), lambda: wb.nominal_loop_plant(plant.pzt),
                 lambda: wb.verify(None, CTRL)):
        with pytest.raises(ArgumentKindError, match="give") as info:
            call()
        assert isinstance(info.value, (WorkbenchError, TypeError))


def test_help_and_signature_of_wb_verify_show_its_parameters():
    import inspect
    import pydoc

    import workbench as wb
    from workbench.verify.run import verify
    assert inspect.signature(wb.verify) == inspect.signature(verify)
    assert {"hold_s", "strict", "seed", "sensor"} <= set(inspect.signature(wb.verify).parameters)
    text = pydoc.render_doc(wb.verify, renderer=pydoc.plaintext)
    assert "hold_s : float" in text and "ControllerMismatchError" in text
    import workbench.verify.sweep_job  # noqa: F401      the package stays a package


def test_set_takes_the_unit_a_key_is_named_in_and_integer_flags_take_integer_valued_floats():
    """--set targets.phase_margin_deg=50deg was refused ("takes no unit") though the key names its unit; bench
    --steps 1e6 was refused though its help writes the default as 1e7."""
    import argparse
    from workbench.cli import _positive_int
    from workbench.errors import UnitError
    from workbench.study.overrides import parse_overrides
    got = parse_overrides(["targets.phase_margin_deg=50deg", "targets.gain_margin_db=6dB",
                           "targets.phase_margin_deg=50", "electrical.current_limit_source_a=20mA"])
    assert got == {"targets.phase_margin_deg": 50.0, "targets.gain_margin_db": 6.0,
                   "electrical.current_limit_source_a": 0.02}
    for bad in ("targets.phase_margin_deg=50rad", "targets.phase_margin_deg=50dB"):
        with pytest.raises(UnitError, match="deg"):
            parse_overrides([bad])
    assert _positive_int("1e6") == 10 ** 6 and _positive_int("2.0e7") == 2 * 10 ** 7 and _positive_int("12") == 12
    for bad in ("1.5", "1e-3", "x", "0", "-1e3"):
        with pytest.raises(argparse.ArgumentTypeError):
            _positive_int(bad)
