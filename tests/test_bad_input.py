"""Bad input, as a careless user gives it, to every command: exit 2, one message, nothing lost.

Each case runs ``workbench.cli.main`` in-process (a few through a subprocess, as a user runs
it) in a workspace holding copies of the repository's plant, study, controller and table files
and a set of broken ones, and asserts what issue 17 asks of every failure:

- exit status 2 and no traceback;
- the message names the file (or the flag) and the place (key, line, flag, range);
- every input file's hash is unchanged (no input overwritten);
- no output at all (nothing left in the output folder or at the --json path).

The cases are the probes of issue 17 that failed (tracebacks, overwritten inputs, values
accepted that should fail, unbounded runs, weak messages) and the ones the validators already
caught, so that what is fixed stays fixed.
"""

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from workbench.cli import main

ROOT = Path(__file__).resolve().parents[1]
REAL_RECORD = Path("/work/shared/data/real/hysteresis_v_150_1hz.csv")

PLANT = "plants/p888_51_sn637.toml"
CREEP = "plants/p888_51_sn637_creep.toml"
CTRL = "controllers/sn637_loopshape.json"
STUDY = "studies/sn637_servo.toml"
TABLE = "plants/data/p888_51_instron_table1.csv"
RECORD = "data/record.csv"
FUSED = "controllers/sn637_fused_loopshape.json"
FSM = "plants/fsm_p888_51.toml"


def _study_text(replace=None, append=""):
    text = (ROOT / STUDY).read_text(encoding="utf-8")
    for old, new in (replace or {}).items():
        assert old in text, old
        text = text.replace(old, new)
    return text + append


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    """A workspace: copies of the repository's inputs and the broken files of the cases."""
    ws = tmp_path_factory.mktemp("ws")
    for folder in ("plants", "studies", "controllers"):
        shutil.copytree(ROOT / folder, ws / folder)
    (ws / "data").mkdir()
    if REAL_RECORD.is_file():
        shutil.copy(REAL_RECORD, ws / RECORD)
    else:                                      # a record of the calibrate format
        (ws / RECORD).write_text("time[s],voltage[V],displacement[m]\n0,0,0\n0.001,1,1e-7\n", encoding="utf-8")
    bad = ws / "bad"
    bad.mkdir()
    plant_text = (ROOT / PLANT).read_bytes()
    # non-UTF-8: a Latin-1 degree sign in a comment on line 3
    lines = plant_text.split(b"\n")
    lines[2] = lines[2] + b"   # 25 \xb0C"
    (bad / "latin1.toml").write_bytes(b"\n".join(lines))
    (bad / "binary.toml").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)))
    (bad / "utf16.toml").write_bytes(plant_text.decode("utf-8").encode("utf-16"))
    (bad / "dir.toml").mkdir()
    (bad / "empty.toml").write_bytes(b"")
    table = (ROOT / TABLE).read_bytes()
    (bad / "latin1_table.csv").write_bytes(table.replace(b"# Instron", b"# Instron \xe9", 1))
    (bad / "binary.csv").write_bytes(b"\x00\x01\x02" * 100)
    (bad / "dir.csv").mkdir()
    (bad / "semicolon.csv").write_text("time[s];voltage[V];displacement[m]\n0;0;0\n0.001;1;1e-7\n",
                                       encoding="utf-8")
    (bad / "tabs.csv").write_text("# a table\nserial\trun\tconfig\nSN637\t1\tR_in\n", encoding="utf-8")
    (bad / "header_only.csv").write_text("time[s],voltage[V],displacement[m]\n", encoding="utf-8")
    (bad / "empty.csv").write_text("", encoding="utf-8")
    (bad / "latin1_study.toml").write_bytes(_study_text().encode("utf-8").replace(b"# The SN637", b"# The \xc9SN637"))
    (bad / "binary.json").write_bytes(b"\x00\xff" * 50)
    (bad / "latin1.json").write_bytes(b'{"name": "caf\xe9"}')
    (bad / "dir.json").mkdir()
    (bad / "not_json.json").write_text("sample_rate_hz = 10000\n", encoding="utf-8")
    # study variants (paths inside are relative to the study file: keep them in studies/)
    studies = {
        "family_scalar": _study_text({"[family]\n": "family = 5\n[family_x]\n"}),
        "targets_array": _study_text({"[targets]\n": "[[targets]]\n"}),
        "export_absolute": _study_text({'directory = "controllers"': f'directory = "{ws / "elsewhere"}"'}),
        "export_escape": _study_text({'directory = "controllers"': 'directory = "../../escaped"'}),
        "export_name_slash": _study_text({'name = "sn637_loopshape"': 'name = "../sn637_loopshape"'}),
        "export_name_empty": _study_text({'name = "sn637_loopshape"': 'name = ""'}),
        "unknown_section": _study_text(append="\n[famly]\nbias_v = 1.0\n"),
        "unknown_key": _study_text({"bias_v = 50.0": "bias_v = 50.0\nbias_mv = 3.0"}),
        "bad_schema": _study_text({'schema = "workbench.study/1"': 'schema = "workbench.study/9"'}),
        "missing_plant": _study_text({'plant = "../plants/p888_51_sn637_creep.toml"': 'plant = "../plants/nope.toml"'}),
        "freq_reversed": _study_text({"freq_min_hz = 1.0 ": "freq_min_hz = 6000.0 "}),
        "amplitude_negative": _study_text({"amplitudes_v = [0.1,": "amplitudes_v = [-0.1,"}),
        "limits_reversed": _study_text({"output_limits_v = [-20.0, 120.0]": "output_limits_v = [120.0, -20.0]"}),
        "bad_toml": _study_text(append="\n[hinf\n"),
        "string_number": _study_text({"freq_points = 60": 'freq_points = "60"'}),
        "missing_section": _study_text({"[hinf]\ntime_limit_s = 60.0\n": ""}),
    }
    for name, text in studies.items():
        (ws / "studies" / f"{name}.toml").write_text(text, encoding="utf-8")
    # plant variants
    plants = {
        "neg_capacitance": plant_text.replace(b"working_capacitance_f = 5.802e-06", b"working_capacitance_f = -5.8e-06"),
        "unknown_key": plant_text.replace(b"[electrical]\n", b"[electrical]\nvoltage_mid_v = 50.0\n"),
        "nan_value": plant_text.replace(b"series_resistor_ohm = 80.0", b"series_resistor_ohm = nan"),
        "limits_reversed": plant_text.replace(b"voltage_min_v = -20.0", b"voltage_min_v = 130.0"),
    }
    for name, text in plants.items():
        assert text != plant_text, name
        (bad / f"plant_{name}.toml").write_bytes(text)
    ctrl = json.loads((ROOT / CTRL).read_text(encoding="utf-8"))
    (bad / "ctrl_rate0.json").write_text(json.dumps({**ctrl, "sample_rate_hz": 0.0}), encoding="utf-8")
    (bad / "ctrl_rate20k.json").write_text(json.dumps({**ctrl, "sample_rate_hz": 20000.0}), encoding="utf-8")
    (bad / "ctrl_no_sos.json").write_text(json.dumps({k: v for k, v in ctrl.items() if k != "sos"}), encoding="utf-8")
    (bad / "ctrl_one_limit.json").write_text(json.dumps({**ctrl, "output_limits_v": [120.0]}), encoding="utf-8")
    (bad / "ctrl_limits_reversed.json").write_text(json.dumps({**ctrl, "output_limits_v": [120.0, -20.0]}),
                                                   encoding="utf-8")
    huge = json.loads(json.dumps(ctrl))                           # clamp words beyond the firmware's int32
    huge["fixed_point"]["output"]["limits_v"] = [-3e5, 3e5]
    (bad / "ctrl_limit_words.json").write_text(json.dumps(huge), encoding="utf-8")
    wide_in = json.loads(json.dumps(ctrl))                        # an input clamp word beyond int32
    wide_in["fixed_point"]["input"]["range_v"] = 1e6
    (bad / "ctrl_input_words.json").write_text(json.dumps(wide_in), encoding="utf-8")
    unstable = json.loads(json.dumps(ctrl))
    unstable["sos"][0] = [1.0, 0.0, 0.0, 1.0, -1.5, 0.0]          # a pole at z = 1.5
    (bad / "ctrl_unstable.json").write_text(json.dumps(unstable), encoding="utf-8")
    nan_sos = json.loads(json.dumps(ctrl))
    nan_sos["sos"][0][1] = "NaN"
    (bad / "ctrl_nan.json").write_text(json.dumps(nan_sos).replace('"NaN"', "NaN"), encoding="utf-8")
    (bad / "a_file").write_text("not a folder\n", encoding="utf-8")
    (bad / "ctrl_sos_text.json").write_text(json.dumps({**ctrl, "sos": [[str(c) for c in row] for row in ctrl["sos"]]}),
                                            encoding="utf-8")
    # a record of the plant, simulated (its displacement in m) and labelled displacement[um]: a 1e-6 unit slip
    from workbench.plant import load_plant
    pzt = load_plant(ROOT / PLANT).pzt
    t = np.arange(2000) * 1e-3
    v = 50.0 * (1.0 - np.cos(2 * np.pi * 2.0 * t))                    # 0..100 V from rest
    x = pzt.quasi_static_x_m(v)
    rows = "\n".join(f"{a:.4f},{b:.6f},{c:.6e}" for a, b, c in zip(t, v, x))
    (bad / "um_label.csv").write_text(f"time[s],voltage[V],displacement[um]\n{rows}\n", encoding="utf-8")
    # issue 17's last four: a simulated record (1 kHz, a 2 Hz raised cosine 0-100 V: current-limited) with its time
    # column 1000 times off either way, its last line cut mid-write; Table 1 with one force cell of -1e300
    from workbench.calibrate.synthetic import simulate_record
    plant = load_plant(ROOT / PLANT)
    v_cmd = 50.0 * (1.0 - np.cos(2 * np.pi * 2.0 * t))
    sim = simulate_record(plant, t, v_cmd, seed=3, gauge=False)
    cells = [(f"{a:.6f}", f"{b:.6f}", f"{c:.6e}", f"{d:.6e}")
             for a, b, c, d in zip(sim["time_s"], sim["voltage_v"], sim["current_a"], sim["displacement_m"])]
    sim_rows = "\n".join(",".join(r) for r in cells)
    (bad / "time_s_under_ms.csv").write_text(f"time[ms],voltage[V],current[A],displacement[m]\n{sim_rows}\n",
                                             encoding="utf-8")
    ms_rows = "\n".join(",".join((f"{float(r[0]) * 1e3:.3f}",) + r[1:]) for r in cells)
    (bad / "time_ms_under_s.csv").write_text(f"time[s],voltage[V],current[A],displacement[m]\n{ms_rows}\n",
                                             encoding="utf-8")
    # s22_outsider A5: the current's sign reversed (a probe turned round) and the current logged under charge[C]
    # were calibrated (a 6.6 Hz resonance named on a clean record)
    flip_rows = "\n".join(",".join((r[0], r[1], f"{-float(r[2]):.6e}", r[3])) for r in cells)
    (bad / "current_flipped.csv").write_text(f"time[s],voltage[V],current[A],displacement[m]\n{flip_rows}\n",
                                             encoding="utf-8")
    (bad / "current_as_charge.csv").write_text(f"time[s],voltage[V],charge[C],displacement[m]\n{sim_rows}\n",
                                               encoding="utf-8")
    # a current convention misspelled (issue 13): '# current:' is sampled or averaged
    (bad / "current_word.csv").write_text(f"# current: integrating\ntime[s],voltage[V],current[A],displacement[m]\n"
                                          f"{sim_rows}\n", encoding="utf-8")
    cut = ",".join(cells[-1][:3]) + "," + cells[-1][3].split(".")[0] + "."          # "...,-1.234567e-07" -> "...,-1."
    (bad / "cut_last_line.csv").write_text("time[s],voltage[V],current[A],displacement[m]\n"
                                           + "\n".join(",".join(r) for r in cells[:-1]) + "\n" + cut,
                                           encoding="utf-8")
    head_t, _, body_t = table.decode("utf-8").partition("back_emf[V]\n")
    body_t = body_t.replace("SN637,2,R_in,-1.040,-3.200,-778.1,", "SN637,2,R_in,-1.040,-3.200,-1e300,")
    (bad / "table_force_1e300.csv").write_text(head_t + "back_emf[V]\n" + body_t, encoding="utf-8")
    # the outside pass (README "Bad input"): files as other tools save them
    (bad / "bom.toml").write_bytes(b"\xef\xbb\xbf" + plant_text)                     # Notepad's "UTF-8 with BOM"
    (bad / "bom.json").write_bytes(b"\xef\xbb\xbf" + (ROOT / CTRL).read_bytes())
    # Table 1 read wrongly: forces in N labelled kN (T_em x 1000), every force 0 (T_em < 0)
    (bad / "table_kn.csv").write_bytes(table.replace(b"force[N]", b"force[kN]"))
    head, _, body = table.decode("utf-8").partition("back_emf[V]\n")
    zero = [",".join(r.split(",")[:5] + ["0.0"] + r.split(",")[6:]) for r in body.splitlines()]
    (bad / "table_zero_force.csv").write_text(head + "back_emf[V]\n" + "\n".join(zero) + "\n", encoding="utf-8")
    _fuzz3_files(ws)
    return ws


def _fuzz3_files(ws):
    """The third outside pass's inputs (README "Bad input", fuzz3): sensor blocks, MIMO controllers, mirror studies."""
    import copy
    import importlib.util
    bad = ws / "bad"
    fused = json.loads((ROOT / FUSED).read_text(encoding="utf-8"))

    def dump(name, data):
        # NaN / Infinity written as JSON's extensions, as Python's json (and a careless script) writes them
        (bad / name).write_text(json.dumps(data, indent=1), encoding="utf-8")

    for name, key, value in (("wait_1e300", "startup_wait_s", 1e300), ("wait_1e9", "startup_wait_s", 1e9),
                             ("wait_neg", "startup_wait_s", -1.0), ("wait_text", "startup_wait_s", "4.7"),
                             ("wait_nan", "startup_wait_s", float("nan")), ("lead_1e3", "ref_lead_s", 1e3),
                             ("lead_1e300", "ref_lead_s", 1e300), ("lead_inf", "ref_lead_s", float("inf")),
                             ("curv_1e300", "gauge_curvature_per_m", 1e300), ("curv_m1e9", "gauge_curvature_per_m", -1e9),
                             ("curv_1e6", "gauge_curvature_per_m", 1e6), ("curv_sign", "gauge_curvature_per_m", 25.3),
                             ("typo_key", "startup_wait_ms", 4707.6), ("kind_case", "kind", "Fused")):
        d = copy.deepcopy(fused)
        d["sensor"][key] = value
        dump(f"f_{name}.json", d)
    d = copy.deepcopy(fused)
    d["sensor"]["blend"]["kk"] = 1
    dump("f_blend_typo.json", d)
    # the mirror: a quick decoupled design (tests/verify/mirror_cases.py), notch-only and IFF-damped
    from workbench.export.mimo import MimoController
    from workbench.plant.mirror import load_mirror
    spec = importlib.util.spec_from_file_location("mirror_cases", ROOT / "tests" / "verify" / "mirror_cases.py")
    cases = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cases)
    fsm = load_mirror(ws / FSM)
    for name, iff in (("mimo", False), ("mimo_iff", True)):
        design, _ = cases.quick_design(fsm, iff=iff)
        MimoController.from_design(design, fsm, name=name).write(ws / "controllers", name)
    m = json.loads((ws / "controllers" / "mimo_iff.json").read_text(encoding="utf-8"))
    for name, change in (("alpha_off", lambda d: d["iff"]["stack_window"].__setitem__("alpha", [0.5] * 3)),
                         ("alpha_one", lambda d: d["iff"]["stack_window"].__setitem__("alpha", [1.0] * 3)),
                         ("head_1e300", lambda d: d["iff"]["stack_window"].__setitem__("headroom_v", [1e300] * 3)),
                         ("head_tiny", lambda d: d["iff"]["stack_window"].__setitem__("headroom_v", [1e-30] * 3)),
                         ("head_inf", lambda d: d["iff"]["stack_window"].__setitem__("headroom_v", [float("inf")] * 3)),
                         ("alpha_two", lambda d: d["iff"]["stack_window"].__setitem__("alpha", [0.1, 0.1])),
                         ("corner_1e300", lambda d: d["iff"]["bridge"].__setitem__("corner_hz", 1e300)),
                         ("corner_off", lambda d: d["iff"]["bridge"].__setitem__("corner_hz", 88.0)),
                         ("noise_1e300", lambda d: d["iff"]["bridge"].__setitem__("out_noise_v_rms", 1e300)),
                         ("adc_1e300", lambda d: d["iff"]["bridge"].__setitem__("adc_range_v", 1e300)),
                         ("typo_key", lambda d: d["iff"].__setitem__("stack_windows", d["iff"]["stack_window"])),
                         ("bridge_typo", lambda d: d["iff"]["bridge"].__setitem__("corner", 8.8)),
                         ("iff_null", lambda d: d.__setitem__("iff", None)),
                         ("sw_missing", lambda d: d["iff"].pop("stack_window"))):
        d = copy.deepcopy(m)
        change(d)
        dump(f"m_{name}.json", d)
    # Table 1 as the force study cannot read it (library cases: tests beside check_force_table); identify's view
    table = (ROOT / TABLE).read_text(encoding="utf-8")
    (bad / "t_back_emf_mv.csv").write_text(table.replace("back_emf[V]", "back_emf[mV]"), encoding="utf-8")
    (bad / "t_r_in_only.csv").write_text("\n".join(r for r in table.splitlines() if "R_out" not in r) + "\n",
                                         encoding="utf-8")
    # a stack study given the mirror's design key; mirror studies with odd [design] values
    (ws / "studies" / "stack_iff.toml").write_text(_study_text(append="\n[design]\niff = true\n"), encoding="utf-8")
    fsm_study = (ROOT / "studies" / "fsm_servo.toml").read_text(encoding="utf-8")
    for name, old, new in (("fsm_iff_text", "noise_budget = true", 'noise_budget = true\niff = "yes"'),
                           ("fsm_iff_corner", "noise_budget = true", "noise_budget = true\niff = true\niff_corner_hz = 8.8"),
                           ("fsm_fc_reversed", "noise_budget = true",
                            "noise_budget = true\nfc_min_hz = 900.0\nfc_max_hz = 100.0"),
                           ("fsm_plant_stack", 'plant = "../plants/fsm_p888_51.toml"',
                            'plant = "../plants/p888_51_sn637.toml"')):
        assert old in fsm_study, old
        (ws / "studies" / f"{name}.toml").write_text(fsm_study.replace(old, new), encoding="utf-8")


def _hashes(ws):
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(ws.rglob("*")) if p.is_file()}


# (id, argv with {out} for the test's empty output folder, fragments every message must contain)
CASES = [
    # ---- input files: missing, a folder, binary, not UTF-8 -------------------------------------------------
    ("gauge-missing", ["gauge", "plants/missing.toml"], ["plants/missing.toml", "no such file"]),
    ("gauge-dir", ["gauge", "bad/dir.toml"], ["bad/dir.toml", "is a folder"]),
    ("gauge-latin1", ["gauge", "bad/latin1.toml"], ["bad/latin1.toml", "line 3", "not UTF-8"]),
    ("gauge-binary", ["gauge", "bad/binary.toml"], ["bad/binary.toml", "line 3", "binary"]),
    ("gauge-utf16", ["gauge", "bad/utf16.toml"], ["bad/utf16.toml", "line 1"]),
    ("gauge-empty", ["gauge", "bad/empty.toml"], ["bad/empty.toml"]),
    ("gauge-folder-dot", ["gauge", "plants"], ["plants", "is a folder"]),
    ("freefree-missing", ["freefree", "plants/none.toml"], ["plants/none.toml", "no such file"]),
    ("freefree-latin1", ["freefree", "bad/latin1.toml"], ["bad/latin1.toml", "line 3"]),
    ("synth-missing", ["synth", "plants/none.toml", "--out", "{out}/r.csv"], ["plants/none.toml", "no such file"]),
    ("synth-binary", ["synth", "bad/binary.toml", "--out", "{out}/r.csv"], ["bad/binary.toml", "binary"]),
    ("identify-missing", ["identify", "transducer", "plants/data/none.csv"], ["plants/data/none.csv", "no such file"]),
    ("identify-dir", ["identify", "transducer", "bad/dir.csv"], ["bad/dir.csv", "is a folder"]),
    ("identify-latin1", ["identify", "transducer", "bad/latin1_table.csv"], ["bad/latin1_table.csv", "line 1",
                                                                              "column 11"]),
    ("identify-binary", ["identify", "transducer", "bad/binary.csv"], ["bad/binary.csv", "binary"]),
    ("identify-plant", ["identify", "transducer", PLANT], ["p888_51_sn637.toml"]),
    ("identify-empty", ["identify", "transducer", "bad/empty.csv"], ["bad/empty.csv"]),
    ("linearize-missing", ["linearize", "plants/none.toml"], ["plants/none.toml", "no such file"]),
    ("linearize-serial-missing", ["linearize", PLANT, "--serials", "plants/none.toml"],
     ["--serials plants/none.toml", "no such file"]),
    ("linearize-serial-dir", ["linearize", PLANT, "--serials", "plants"], ["--serials plants", "is a folder"]),
    ("linearize-controller-missing", ["linearize", PLANT, "--controller", "controllers/none.json"],
     ["--controller controllers/none.json", "no such file"]),
    ("linearize-controller-binary", ["linearize", PLANT, "--controller", "bad/binary.json"],
     ["bad/binary.json", "binary"]),
    ("verify-plant-missing", ["verify", "plants/none.toml", "--controller", CTRL], ["plants/none.toml"]),
    ("verify-controller-missing", ["verify", CREEP, "--controller", "controllers/none.json"],
     ["controllers/none.json", "no such file"]),
    ("verify-controller-dir", ["verify", CREEP, "--controller", "bad/dir.json"], ["bad/dir.json", "is a folder"]),
    ("verify-controller-latin1", ["verify", CREEP, "--controller", "bad/latin1.json"],
     ["bad/latin1.json", "line 1, column 14"]),
    ("verify-controller-not-json", ["verify", CREEP, "--controller", "bad/not_json.json"],
     ["bad/not_json.json", "line 1, column 1", "not valid JSON"]),
    ("linearize-controller-not-json", ["linearize", PLANT, "--controller", "bad/not_json.json"],
     ["bad/not_json.json", "line 1, column 1"]),
    ("verify-controller-binary", ["verify", CREEP, "--controller", "bad/binary.json"], ["bad/binary.json", "binary"]),
    ("bench-plant-missing", ["bench", "--plant", "plants/none.toml"], ["--plant plants/none.toml", "no such file"]),
    ("bench-controller-missing", ["bench", "--controller", "controllers/none.json"],
     ["--controller controllers/none.json", "no such file"]),
    ("bench-controller-dir", ["bench", "--controller", "controllers"], ["--controller controllers", "is a folder"]),
    ("study-missing", ["study", "studies/none.toml", "--out", "{out}"], ["studies/none.toml", "no such file"]),
    ("study-dir", ["study", "studies", "--out", "{out}"], ["studies", "is a folder"]),
    ("study-latin1", ["study", "bad/latin1_study.toml", "--out", "{out}"], ["bad/latin1_study.toml", "line 1"]),
    ("study-binary", ["study", "bad/binary.toml", "--out", "{out}"], ["bad/binary.toml", "binary"]),
    ("sweep-missing", ["sweep", "studies/none.toml", "--out", "{out}"], ["studies/none.toml", "no such file"]),
    ("sweep-controller-missing", ["sweep", STUDY, "--controller", "controllers/none.json", "--out", "{out}"],
     ["controllers/none.json", "no such file"]),
    ("calibrate-record-missing", ["calibrate", "data/none.csv", "--plant", PLANT], ["data/none.csv", "no such file"]),
    ("calibrate-record-dir", ["calibrate", "bad/dir.csv", "--plant", PLANT], ["bad/dir.csv", "is a folder"]),
    ("calibrate-record-binary", ["calibrate", "bad/binary.csv", "--plant", PLANT], ["bad/binary.csv", "binary"]),
    ("calibrate-record-latin1", ["calibrate", "bad/latin1_table.csv", "--plant", PLANT], ["bad/latin1_table.csv",
                                                                                          "not UTF-8"]),
    ("calibrate-record-semicolon", ["calibrate", "bad/semicolon.csv", "--plant", PLANT],
     ["bad/semicolon.csv", "line 1", "semicolons"]),
    ("identify-table-tabs", ["identify", "transducer", "bad/tabs.csv"], ["bad/tabs.csv", "line 2", "tabs"]),
    ("calibrate-plant-missing", ["calibrate", RECORD, "--plant", "plants/none.toml"],
     ["--plant plants/none.toml", "no such file"]),
    ("calibrate-plant-dir", ["calibrate", RECORD, "--plant", "plants"], ["--plant plants", "is a folder"]),
    ("selfsense-missing", ["selfsense", "plants/none.toml"], ["plants/none.toml"]),
    ("selfsense-controller-missing", ["selfsense", CREEP, "--controller", "controllers/none.json"],
     ["controllers/none.json", "no such file"]),
    ("selfsense-latin1", ["selfsense", "bad/latin1.toml"], ["bad/latin1.toml", "line 3"]),
    # ---- outputs: onto an input, onto a folder, under a file, --out a file ----------------------------------
    ("gauge-json-onto-plant", ["gauge", PLANT, "--json", PLANT], [PLANT, "is the input plant"]),
    ("gauge-json-onto-plant-dotted", ["gauge", PLANT, "--json", "plants/../" + PLANT],
     ["is the input plant"]),
    ("gauge-json-dir", ["gauge", PLANT, "--json", "{out}"], ["--json", "is a folder"]),
    ("gauge-json-under-file", ["gauge", PLANT, "--json", "bad/a_file/g.json"], ["bad/a_file", "is a file"]),
    ("synth-out-onto-plant", ["synth", PLANT, "--out", PLANT], ["--out", "is the input plant"]),
    ("synth-out-dir", ["synth", PLANT, "--out", "{out}"], ["--out", "is a folder"]),
    ("synth-out-under-file", ["synth", PLANT, "--out", "bad/a_file/r.csv"], ["bad/a_file", "is a file"]),
    ("synth-out-equals-json", ["synth", PLANT, "--out", "{out}/r.csv", "--json", "{out}/r.csv"],
     ["two outputs cannot share a path"]),
    ("synth-json-onto-plant", ["synth", PLANT, "--out", "{out}/r.csv", "--json", PLANT], ["is the input plant"]),
    ("calibrate-json-onto-record", ["calibrate", RECORD, "--plant", PLANT, "--json", RECORD],
     [RECORD, "is the input record"]),
    ("calibrate-json-onto-plant", ["calibrate", RECORD, "--plant", PLANT, "--json", PLANT],
     [PLANT, "is the input --plant"]),
    ("calibrate-out-file", ["calibrate", RECORD, "--plant", PLANT, "--out", "bad/a_file"],
     ["--out bad/a_file", "is a file"]),
    ("calibrate-out-onto-record", ["calibrate", RECORD, "--plant", PLANT, "--out", RECORD],
     ["is the input record"]),
    ("identify-json-onto-table", ["identify", "transducer", TABLE, "--json", TABLE], ["is the input table"]),
    ("freefree-out-file", ["freefree", PLANT, "--out", "bad/a_file"], ["--out bad/a_file", "is a file"]),
    ("freefree-out-under-file", ["freefree", PLANT, "--out", "bad/a_file/ff"], ["bad/a_file", "is a file"]),
    ("freefree-json-dir", ["freefree", PLANT, "--json", "{out}"], ["--json", "is a folder"]),
    ("linearize-out-file", ["linearize", PLANT, "--out", "bad/a_file"], ["--out bad/a_file", "is a file"]),
    ("linearize-json-onto-serial", ["linearize", PLANT, "--serials", "plants/p888_51_sn629.toml", "--json",
                                    "plants/p888_51_sn629.toml"], ["is the input --serials"]),
    ("linearize-json-onto-controller", ["linearize", PLANT, "--controller", CTRL, "--json", CTRL],
     ["is the input --controller"]),
    ("study-out-file", ["study", STUDY, "--out", "bad/a_file"], ["--out bad/a_file", "is a file"]),
    ("study-out-under-file", ["study", STUDY, "--out", "bad/a_file/study"], ["bad/a_file", "is a file"]),
    ("study-json-dir", ["study", STUDY, "--out", "{out}", "--json", "studies"], ["--json studies", "is a folder"]),
    ("study-json-under-file", ["study", STUDY, "--out", "{out}", "--json", "bad/a_file/s.json"],
     ["bad/a_file", "is a file"]),
    ("study-json-onto-study", ["study", STUDY, "--out", "{out}", "--json", STUDY], ["is the input study"]),
    ("study-json-onto-its-plant", ["study", STUDY, "--out", "{out}", "--json", CREEP],
     [CREEP, "is the input studies/sn637_servo.toml: plant"]),
    ("sweep-table-onto-a-serial", ["sweep", STUDY, "--out", "{out}", "--table", "plants/p888_51_sn618.toml"],
     ["is the input studies/sn637_servo.toml: serials[1]"]),
    ("study-json-onto-report", ["study", STUDY, "--out", "{out}", "--json", "{out}/report.md"],
     ["report.md", "its own"]),
    ("verify-json-onto-report", ["verify", CREEP, "--controller", CTRL, "--out", "{out}", "--json", "{out}/report.md"],
     ["report.md", "its own"]),
    ("verify-out-file", ["verify", CREEP, "--controller", CTRL, "--out", "bad/a_file"], ["--out bad/a_file", "is a file"]),
    ("verify-json-onto-controller", ["verify", CREEP, "--controller", CTRL, "--json", CTRL],
     ["is the input --controller"]),
    ("verify-json-dir", ["verify", CREEP, "--controller", CTRL, "--json", "{out}"], ["--json", "is a folder"]),
    ("sweep-table-onto-study", ["sweep", STUDY, "--out", "{out}", "--table", STUDY], ["is the input study"]),
    ("sweep-table-dir", ["sweep", STUDY, "--out", "{out}", "--table", "{out}"], ["--table", "is a folder"]),
    ("sweep-out-file", ["sweep", STUDY, "--out", "bad/a_file"], ["--out bad/a_file", "is a file"]),
    ("selfsense-out-file", ["selfsense", CREEP, "--out", "bad/a_file"], ["bad/a_file", "file"]),
    ("selfsense-json-onto-plant", ["selfsense", CREEP, "--json", CREEP], ["is the input plant"]),
    ("demo-out-file", ["demo", "--out", "bad/a_file"], ["--out bad/a_file", "is a file"]),
    ("demo-json-dir", ["demo", "--out", "{out}", "--json", "plants"], ["--json plants", "is a folder"]),
    ("bench-json-onto-plant", ["bench", "--json", CREEP], ["is the input --plant"]),
    # ---- study files: sections, export folder and name, the validators' own cases --------------------------
    ("study-family-scalar", ["study", "studies/family_scalar.toml", "--out", "{out}"],
     ["family_scalar.toml", "[family]", "not a section"]),
    ("study-targets-array", ["study", "studies/targets_array.toml", "--out", "{out}"],
     ["targets_array.toml", "[targets]", "array of tables"]),
    ("sweep-family-scalar", ["sweep", "studies/family_scalar.toml", "--out", "{out}"],
     ["family_scalar.toml", "[family]"]),
    ("study-export-absolute", ["study", "studies/export_absolute.toml", "--out", "{out}"],
     ["export_absolute.toml", "[export.directory]", "outside the output folder"]),
    ("study-export-escape", ["study", "studies/export_escape.toml", "--out", "{out}"],
     ["export_escape.toml", "[export.directory]"]),
    ("study-export-name-slash", ["study", "studies/export_name_slash.toml", "--out", "{out}"],
     ["export_name_slash.toml", "[export.name]"]),
    ("study-export-name-empty", ["study", "studies/export_name_empty.toml", "--out", "{out}"],
     ["export_name_empty.toml", "[export.name]"]),
    ("study-unknown-section", ["study", "studies/unknown_section.toml", "--out", "{out}"],
     ["unknown_section.toml", "[famly]", "unknown section"]),
    ("study-unknown-key", ["study", "studies/unknown_key.toml", "--out", "{out}"],
     ["unknown_key.toml", "[family.bias_mv]"]),
    ("study-bad-schema", ["study", "studies/bad_schema.toml", "--out", "{out}"], ["bad_schema.toml", "[schema]"]),
    ("study-missing-plant", ["study", "studies/missing_plant.toml", "--out", "{out}"],
     ["missing_plant.toml", "[plant]"]),
    ("study-freq-reversed", ["study", "studies/freq_reversed.toml", "--out", "{out}"],
     ["freq_reversed.toml", "[family.freq_max_hz]"]),
    ("study-amplitude-negative", ["study", "studies/amplitude_negative.toml", "--out", "{out}"],
     ["amplitude_negative.toml", "[family.amplitudes_v[0]]"]),
    ("study-limits-reversed", ["study", "studies/limits_reversed.toml", "--out", "{out}"],
     ["limits_reversed.toml", "[export.output_limits_v]"]),
    ("study-bad-toml", ["study", "studies/bad_toml.toml", "--out", "{out}"], ["bad_toml.toml", "[syntax]"]),
    ("study-string-number", ["study", "studies/string_number.toml", "--out", "{out}"],
     ["string_number.toml", "[family.freq_points]"]),
    ("study-missing-section", ["study", "studies/missing_section.toml", "--out", "{out}"],
     ["missing_section.toml", "[hinf]"]),
    # ---- plant files: the plant validator's cases -----------------------------------------------------------
    ("gauge-plant-neg-cp", ["gauge", "bad/plant_neg_capacitance.toml"],
     ["plant_neg_capacitance.toml", "working_capacitance_f"]),
    ("gauge-plant-unknown-key", ["gauge", "bad/plant_unknown_key.toml"], ["plant_unknown_key.toml", "voltage_mid_v"]),
    ("gauge-plant-nan", ["gauge", "bad/plant_nan_value.toml"], ["plant_nan_value.toml", "series_resistor_ohm"]),
    ("gauge-plant-limits-reversed", ["gauge", "bad/plant_limits_reversed.toml"],
     ["plant_limits_reversed.toml", "voltage_m"]),
    ("freefree-plant-neg-cp", ["freefree", "bad/plant_neg_capacitance.toml"], ["plant_neg_capacitance.toml"]),
    ("gauge-study-as-plant", ["gauge", STUDY], ["sn637_servo.toml"]),
    # ---- flags: range, unit, finite; long runs bounded -------------------------------------------------------
    ("gauge-x0-1km", ["gauge", PLANT, "--x0", "1km"], ["--x0", "um", "out of range", "stroke"]),
    ("gauge-x0-negative", ["gauge", PLANT, "--x0=-1mm"], ["--x0", "out of range"]),
    ("gauge-x0-inf", ["gauge", PLANT, "--x0", "1e400m"], ["--x0", "finite"]),
    ("gauge-x0-unit", ["gauge", PLANT, "--x0", "7.5parsec"], ["--x0", "'m'"]),
    ("gauge-x0-text", ["gauge", PLANT, "--x0", "nan"], ["--x0", "cannot read"]),
    ("freefree-freq-1ghz", ["freefree", PLANT, "--freq", "1GHz"], ["--freq", "Hz", "out of range", "gauge samples"]),
    ("freefree-freq-0", ["freefree", PLANT, "--freq", "0Hz"], ["--freq", "out of range"]),
    ("freefree-freq-negative", ["freefree", PLANT, "--freq=-1Hz"], ["--freq", "out of range"]),
    ("freefree-vpeak-500", ["freefree", PLANT, "--v-peak", "500V"], ["--v-peak", "out of range"]),
    ("freefree-vpeak-0", ["freefree", PLANT, "--v-peak", "0V"], ["--v-peak", "out of range"]),
    ("freefree-cycles-1e6", ["freefree", PLANT, "--cycles", "1000000"], ["--cycles", "estimated", "memory"]),
    ("freefree-cycles-1e6-force", ["freefree", PLANT, "--cycles", "1000000", "--force"],
     ["--cycles", "more than this machine"]),
    ("freefree-cycles-0", ["freefree", PLANT, "--cycles", "0"], ["--cycles", ">= 1"]),
    ("linearize-freq-points-1e5", ["linearize", PLANT, "--freq-points", "100000"],
     ["--freq-points", "estimated", "days"]),
    ("linearize-freq-points-1", ["linearize", PLANT, "--freq-points", "1"], ["--freq-points", "out of range"]),
    ("linearize-freq-reversed", ["linearize", PLANT, "--freq-min", "1kHz", "--freq-max", "10Hz"], ["must be below"]),
    ("linearize-freq-max-1ghz", ["linearize", PLANT, "--freq-max", "1GHz"], ["--freq-max", "out of range"]),
    ("linearize-amplitude-0", ["linearize", PLANT, "--amplitudes", "0V"], ["--amplitudes", "out of range"]),
    ("linearize-amplitude-1kv", ["linearize", PLANT, "--amplitudes", "1kV"], ["--amplitudes", "out of range"]),
    ("linearize-bias-500", ["linearize", PLANT, "--bias", "500V"], ["--bias", "out of range"]),
    ("linearize-bias-unit", ["linearize", PLANT, "--bias", "5A"], ["--bias", "'V'"]),
    ("linearize-cp-tolerance", ["linearize", PLANT, "--cp-tolerance", "1.5"], ["--cp-tolerance", "out of range"]),
    ("linearize-cp-tolerance-nan", ["linearize", PLANT, "--cp-tolerance", "nan"], ["--cp-tolerance", "finite"]),
    ("linearize-imbalance-negative", ["linearize", PLANT, "--imbalance-tolerance=-1ohm"],
     ["--imbalance-tolerance", "ohm", "out of range"]),
    ("linearize-imbalance-huge", ["linearize", PLANT, "--imbalance-tolerance", "1kohm"],
     ["--imbalance-tolerance", "out of range"]),
    ("verify-hold-0", ["verify", CREEP, "--controller", CTRL, "--hold", "0s"], ["--hold", "s", "out of range"]),
    ("verify-hold-1ms", ["verify", CREEP, "--controller", CTRL, "--hold", "1ms"], ["--hold", "out of range"]),
    ("verify-hold-negative", ["verify", CREEP, "--controller", CTRL, "--hold=-5s"], ["--hold", "out of range"]),
    ("verify-hold-1e12", ["verify", CREEP, "--controller", CTRL, "--hold", "1e12s"],
     ["--hold", "estimated", "--force"]),
    ("verify-hold-unit", ["verify", CREEP, "--controller", CTRL, "--hold", "5m"], ["--hold", "'s'"]),
    ("selfsense-duration-1e12", ["selfsense", CREEP, "--duration", "1e12s"], ["--duration", "estimated"]),
    ("selfsense-duration-short", ["selfsense", CREEP, "--duration", "10s"], ["--duration", "out of range"]),
    ("selfsense-duration-negative", ["selfsense", CREEP, "--duration=-5s"], ["--duration", "out of range"]),
    ("calibrate-max-ratio-nan", ["calibrate", RECORD, "--plant", PLANT, "--max-ratio", "nan"],
     ["--max-ratio", "finite"]),
    ("calibrate-max-ratio-negative", ["calibrate", RECORD, "--plant", PLANT, "--max-ratio=-1"],
     ["--max-ratio", "out of range"]),
    ("calibrate-max-ratio-2", ["calibrate", RECORD, "--plant", PLANT, "--max-ratio", "2"],
     ["--max-ratio", "out of range"]),
    ("calibrate-train-cycles-0", ["calibrate", RECORD, "--plant", PLANT, "--train-cycles", "0"],
     ["--train-cycles", "out of range"]),
    ("calibrate-train-cycles-inf", ["calibrate", RECORD, "--plant", PLANT, "--train-cycles", "inf"],
     ["--train-cycles", "finite"]),
    ("synth-seed-negative", ["synth", PLANT, "--out", "{out}/r.csv", "--seed=-1"], ["--seed", "out of range"]),
    ("sweep-amplitude-negative", ["sweep", STUDY, "--out", "{out}", "--amplitudes=-1V"],
     ["--amplitudes", "out of range"]),
    ("sweep-amplitude-1kv", ["sweep", STUDY, "--out", "{out}", "--amplitudes", "1kV"],
     ["--amplitudes", "out of range"]),
    ("sweep-workers-0", ["sweep", STUDY, "--out", "{out}", "--workers", "0"], ["--workers", ">= 1"]),
    ("bench-steps-0", ["bench", "--steps", "0"], ["--steps", ">= 1"]),
    ("bench-memory-negative", ["bench", "--memory-periods=-1"], ["--memory-periods", ">= 0"]),
    ("identify-stiffness-0", ["identify", "transducer", TABLE, "--stiffness", "0N/m"],
     ["--stiffness", "out of range"]),
    ("identify-stiffness-negative", ["identify", "transducer", TABLE, "--stiffness=-2e8"],
     ["--stiffness", "out of range"]),
    ("verify-form-hanus", ["verify", CREEP, "--controller", CTRL, "--form", "hanus"], ["hanus"]),
    ("verify-scenario-unknown", ["verify", CREEP, "--controller", CTRL, "--scenario", "ramp"], ["--scenario"]),
    ("synth-effect-unknown", ["synth", PLANT, "--out", "{out}/r.csv", "--effect", "magic"], ["--effect"]),
    ("calibrate-split-unknown", ["calibrate", RECORD, "--plant", PLANT, "--split", "halves"], ["--split"]),
    ("gauge-no-plant", ["gauge"], ["plant"]),
    # ---- the outside pass (README "Bad input"): cases its authors' suite did not have ----------------------
    ("gauge-plant-bom", ["gauge", "bad/bom.toml"], ["bad/bom.toml", "line 1, column 1", "byte-order mark"]),
    ("verify-controller-bom", ["verify", CREEP, "--controller", "bad/bom.json"], ["bad/bom.json", "byte-order mark"]),
    # a folder whose permission bits allow writing but where nothing can be created (a virtual file system)
    ("gauge-json-proc", ["gauge", PLANT, "--json", "/proc/g.json"], ["--json /proc/g.json", "nothing can be written"]),
    ("identify-table-kn", ["identify", "transducer", "bad/table_kn.csv"], ["bad/table_kn.csv", "T_em = 6.5",
                                                                              "outside (0, 10000] N/V", "units"]),
    ("identify-table-zero-force", ["identify", "transducer", "bad/table_zero_force.csv"],
     ["bad/table_zero_force.csv", "outside (0, 10000] N/V"]),
    ("identify-stiffness-1e30", ["identify", "transducer", TABLE, "--stiffness", "1e30N/m"],
     ["--stiffness", "out of range (0, 1e+12] N/m"]),
    ("verify-seed-negative", ["verify", CREEP, "--controller", CTRL, "--seed=-1"], ["--seed", "out of range"]),
    # outputs onto a file the command reads by default (no argument names it, so nothing protected it)
    ("demo-json-onto-its-plant", ["demo", "--out", "{out}", "--json", PLANT], [PLANT, "is the input file the demo reads"]),
    ("sweep-table-onto-its-default-controller", ["sweep", STUDY, "--out", "{out}", "--table", "./" + CTRL],
     ["--table", "is the input controller (the sweep's default)"]),
    ("selfsense-json-onto-default-fused-controller",
     ["selfsense", CREEP, "--fused", "--json", str(ROOT / "controllers" / "sn637_fused_loopshape.json")],
     ["is the input --fused-controller (default)"]),
    ("linearize-freq-points-2", ["linearize", PLANT, "--freq-points", "2", "--amplitudes", "1V"],
     ["--freq-points", "out of range [3, 100000]"]),
    # an empty path is the current folder: `--out "$OUT"` with OUT unset wrote the study into ./ (replacing
    # ./controllers/sn637_loopshape.json and its .csv/.h/.mat)
    ("study-out-empty", ["study", STUDY, "--out", ""], ["--out", "an empty path ''"]),
    ("gauge-json-empty", ["gauge", PLANT, "--json", ""], ["--json", "an empty path ''"]),
    ("synth-out-blank", ["synth", PLANT, "--out", " "], ["--out", "an empty path ' '"]),
    ("gauge-plant-empty", ["gauge", ""], ["plant", "an empty path ''"]),
    # a study value given by --set is checked like the file's, before the design work
    ("study-set-export-name", ["study", STUDY, "--out", "{out}", "--set", "export.name=../x"],
     ["[export.name]", "'../x'"]),
    # a free-free sine whose stroke is under the gauge noise (22 nm RMS in the plant file): C_p came out as
    # -10.9 uF at 1 nV and +102 % at 100 mV, with exit 0
    ("freefree-vpeak-1nv", ["freefree", PLANT, "--v-peak", "1nV"], ["--v-peak", "under the gauge noise 22 nm RMS"]),
    ("freefree-vpeak-100mv", ["freefree", PLANT, "--v-peak", "100mV"], ["--v-peak", "out of range",
                                                                      "under the gauge noise 22 nm RMS"]),
    ("study-cache-dir-file", ["study", STUDY, "--out", "{out}", "--cache-dir", "bad/a_file"],
     ["--cache-dir bad/a_file", "is a file"]),
    # a force step beyond the blocked force k_p x stroke (200 N/um x ~18 um: ~3.7 kN) ran, reporting a 5 m squeeze
    ("selfsense-step-force-1e9", ["selfsense", CREEP, "--force", "--step-force", "1e9N"],
     ["--step-force", "out of range", "blocked force"]),
    ("calibrate-record-unit-slip", ["calibrate", "bad/um_label.csv", "--plant", PLANT, "--out", "{out}"],
     ["bad/um_label.csv", "1e-06 times", "unit slip", "displacement column's unit"]),
    # python-control's reference loop at ~5600 steps/s: 1e12 steps ran unbounded (no estimate, no bound)
    ("bench-reference-steps-1e12", ["bench", "--reference-steps", "1000000000000"],
     ["--reference-steps 1000000000000", "estimated", "--force"]),
    # the table's format is its suffix: a .txt table failed after the whole sweep
    ("sweep-table-txt", ["sweep", STUDY, "--out", "{out}", "--table", "{out}/t.txt"],
     ["--table", "t.txt", "suffix must be one of .csv, .parquet"]),
    # sos cells written as text were read as numbers, while a text gain is refused
    ("verify-controller-sos-text", ["verify", CREEP, "--controller", "bad/ctrl_sos_text.json"],
     ["ctrl_sos_text.json", "[sos]", "of numbers", "without quotes"]),
    ("freefree-out-proc", ["freefree", PLANT, "--out", "/proc/ff"], ["--out /proc/ff", "nothing can be written"]),
    ("verify-no-controller", ["verify", CREEP], ["--controller"]),
    # ---- issue 17's last four (fuzz2) -----------------------------------------------------------------------
    # synth writes a CSV whatever the name: a record under rec.toml was written as CSV
    ("synth-out-toml", ["synth", PLANT, "--out", "{out}/rec.toml"], ["--out", "rec.toml", "suffix must be one of .csv"]),
    # one force cell of -1e300 in an R_in row: the run was only flagged and T_em printed, exit 0
    ("identify-table-force-1e300", ["identify", "transducer", "bad/table_force_1e300.csv"],
     ["bad/table_force_1e300.csv", "line 12, column 6 (force)", "beyond 1e+12 N/m", "impossible"]),
    # a time column 1000 times off: calibrate answered "no effect", exit 0
    ("calibrate-record-time-s-under-ms", ["calibrate", "bad/time_s_under_ms.csv", "--plant", PLANT, "--out", "{out}"],
     ["bad/time_s_under_ms.csv", "charge", "likely 1000 times too small (s under time[ms])", "time column's unit"]),
    ("calibrate-record-time-ms-under-s", ["calibrate", "bad/time_ms_under_s.csv", "--plant", PLANT, "--out", "{out}"],
     ["bad/time_ms_under_s.csv", "charge", "likely 1000 times too large (ms under time[s])", "time column's unit"]),
    # s22_outsider A5: |charge scale| was tested, so a reversed current passed; a charge column had no check
    ("calibrate-record-current-sign", ["calibrate", "bad/current_flipped.csv", "--plant", PLANT, "--out", "{out}"],
     ["bad/current_flipped.csv", "the current column", "falls as the terminal voltage rises", "negate the current"]),
    ("calibrate-record-current-as-charge", ["calibrate", "bad/current_as_charge.csv", "--plant", PLANT, "--out",
                                            "{out}"],
     ["bad/current_as_charge.csv", "the charge column follows the plant's current", "write current[A]"]),
    # the last line cut mid-write ("...,-1.234567e-07" -> "...,-1."): read as -1 m
    ("calibrate-record-current-convention", ["calibrate", "bad/current_word.csv", "--plant", PLANT, "--out", "{out}"],
     ["bad/current_word.csv, line 1", "current 'integrating' is not one of sampled, averaged",
      "'# current: averaged'"]),
    ("calibrate-record-cut-last-line", ["calibrate", "bad/cut_last_line.csv", "--plant", PLANT, "--out", "{out}"],
     ["bad/cut_last_line.csv", "line 2001, column 4 (displacement[m])", "no line end", "cut"]),
]

# cases for another engineer's validator (issue 17 item 2: controllers; records): in the suite when they
# already pass, listed in the report otherwise
OTHERS = [
    ("verify-controller-no-sos", ["verify", CREEP, "--controller", "bad/ctrl_no_sos.json"], ["ctrl_no_sos.json", "[sos]"]),
    ("verify-controller-other-rate", ["verify", CREEP, "--controller", "bad/ctrl_rate20k.json"],
     ["ctrl_rate20k.json", "20000 Hz differs from the servo rate 10000 Hz"]),
    ("verify-json-onto-targets", ["verify", CREEP, "--controller", CTRL, "--targets-from", STUDY, "--json", STUDY],
     [STUDY]),
    # controller contents, through every command that takes one: refused by the one loader before the work
    *[(f"{cmd}-controller-{kind}", [cmd, *pre, "--controller", f"bad/ctrl_{kind}.json", *post],
       [f"ctrl_{kind}.json", key])
      for cmd, pre, post in (("verify", [CREEP], []), ("linearize", [PLANT], []), ("bench", [], []))
      for kind, key in (("rate0", "sample_rate_hz"), ("one_limit", "output_limits_v"),
                        ("limits_reversed", "output_limits_v"), ("unstable", "sos"), ("nan", "sos"))],
    # fixed-point clamp limits of +/-3e5 V at the file's 22 fraction bits: words of 1.26e12, which ran (int64)
    # while the C header's int32 clamp cannot hold them
    ("verify-controller-limit-words", ["verify", CREEP, "--controller", "bad/ctrl_limit_words.json"],
     ["ctrl_limit_words.json", "[fixed_point.output.limits_v]", "outside +/-(2^31 - 1)", "below 512.0 V"]),
    # the input clamp +/-1e6 V at the file's input fraction bits: a word beyond int32 (the header's INT32_C)
    ("verify-controller-input-words", ["verify", CREEP, "--controller", "bad/ctrl_input_words.json"],
     ["ctrl_input_words.json", "[fixed_point.input.range_v]", "outside +/-(2^31 - 1)", "give a range below"]),
    ("calibrate-record-header-only", ["calibrate", "bad/header_only.csv", "--plant", PLANT], ["header_only.csv"]),
    ("calibrate-record-empty", ["calibrate", "bad/empty.csv", "--plant", PLANT], ["empty.csv"]),
]

# the third outside pass (fuzz3, README "Bad input"): the sensor block's startup fields, the MIMO controller's
# iff block, mirror studies, selfsense --force, outputs onto files a mirror reads
_VS = ["--sensor", "fused", "--hold", "3s", "--out", "{out}"]
FUZZ3 = [
    # ---- the sensor block (export/sensor.py, controller.py): NaN / negative / text / huge / misspelt ----------
    # 1e300 s and 1e9 s of open loop: "Maximum allowed dimension exceeded" and a MemoryError traceback after ~35 s
    ("verify-fused-wait-1e300", ["verify", CREEP, "--controller", "bad/f_wait_1e300.json", *_VS],
     ["bad/f_wait_1e300.json: [sensor.startup_wait_s] 1e+300 s of open loop", "more than this machine"]),
    ("verify-fused-wait-1e9", ["verify", CREEP, "--controller", "bad/f_wait_1e9.json", *_VS],
     ["[sensor.startup_wait_s] 1e+09 s", "40 TB of memory"]),
    ("verify-fused-wait-negative", ["verify", CREEP, "--controller", "bad/f_wait_neg.json", *_VS],
     ["bad/f_wait_neg.json: [sensor.startup_wait_s]", ">= 0 s"]),
    ("verify-fused-wait-text", ["verify", CREEP, "--controller", "bad/f_wait_text.json", *_VS],
     ["[sensor.startup_wait_s] must be a number; got '4.7'"]),
    ("verify-fused-wait-nan", ["verify", CREEP, "--controller", "bad/f_wait_nan.json", *_VS],
     ["[sensor.startup_wait_s] must be a finite number"]),
    # a lead of 1e3 s and 1e300 s and a curvature of +-1e6..1e300 1/m ran the loops on garbage references/readings
    ("verify-fused-lead-1e3", ["verify", CREEP, "--controller", "bad/f_lead_1e3.json", *_VS],
     ["bad/f_lead_1e3.json: [sensor.ref_lead_s] 1000 s", "1/K_v = 0.00040", "larger ramp error than no lead"]),
    ("verify-fused-lead-1e300", ["verify", CREEP, "--controller", "bad/f_lead_1e300.json", *_VS],
     ["[sensor.ref_lead_s] 1e+300 s"]),
    ("verify-fused-lead-inf", ["verify", CREEP, "--controller", "bad/f_lead_inf.json", *_VS],
     ["[sensor.ref_lead_s] must be a finite number"]),
    ("verify-fused-curvature-1e300", ["verify", CREEP, "--controller", "bad/f_curv_1e300.json", *_VS],
     ["bad/f_curv_1e300.json: [sensor.gauge_curvature_per_m] 1e+300 1/m", "curves by -25.3", "[-50.61, 0] 1/m"]),
    ("verify-fused-curvature-m1e9", ["verify", CREEP, "--controller", "bad/f_curv_m1e9.json", *_VS],
     ["[sensor.gauge_curvature_per_m] -1e+09 1/m"]),
    ("verify-fused-curvature-sign", ["verify", CREEP, "--controller", "bad/f_curv_sign.json", *_VS],
     ["[sensor.gauge_curvature_per_m] 25.3 1/m", "more than the linear calibration"]),
    # the gauge scenarios read a carried curvature too (verify/closed_loop.py)
    ("verify-fused-curvature-gauge-scenario", ["verify", CREEP, "--controller", "bad/f_curv_1e6.json",
                                               "--scenario", "small_step", "--out", "{out}"],
     ["[sensor.gauge_curvature_per_m] 1e+06 1/m"]),
    ("bench-fused-curvature", ["bench", "--controller", "bad/f_curv_1e300.json", "--steps", "10"],
     ["[sensor.gauge_curvature_per_m] 1e+300"]),
    ("sweep-fused-curvature", ["sweep", "studies/sn637_fused_servo.toml", "--controller", "bad/f_curv_1e300.json",
                               "--out", "{out}"], ["bad/f_curv_1e300.json: [sensor.gauge_curvature_per_m] 1e+300"]),
    # a misspelt key dropped firmware's setting without a word (the harness computed its own wait)
    ("verify-fused-typo-key", ["verify", CREEP, "--controller", "bad/f_typo_key.json", *_VS],
     ["bad/f_typo_key.json: [sensor.startup_wait_ms] unknown key", "startup_wait_s"]),
    ("verify-fused-blend-typo-key", ["verify", CREEP, "--controller", "bad/f_blend_typo.json", *_VS],
     ["[sensor.blend.kk] unknown key"]),
    ("verify-fused-kind-case", ["verify", CREEP, "--controller", "bad/f_kind_case.json", *_VS],
     ["[sensor.kind] must be one of gauge, charge, fused; got 'Fused'"]),
    # selfsense --fused read its --fused-controller only after ~30 s of identification
    ("selfsense-fused-controller-lead-1e3", ["selfsense", CREEP, "--fused", "--fused-controller", "bad/f_lead_1e3.json",
                                             "--hold", "3s"], ["bad/f_lead_1e3.json: [sensor.ref_lead_s] 1000 s"]),
    ("selfsense-fused-controller-nan", ["selfsense", CREEP, "--fused", "--fused-controller", "bad/f_wait_nan.json",
                                        "--hold", "3s"], ["bad/f_wait_nan.json: [sensor.startup_wait_s]"]),
    ("selfsense-fused-controller-mimo", ["selfsense", CREEP, "--fused", "--fused-controller", "controllers/mimo.json",
                                         "--hold", "3s"], ["controllers/mimo.json: [schema] is a MIMO mirror controller"]),
    ("verify-fused-sensor-gauge-strict", ["verify", CREEP, "--controller", FUSED, "--sensor", "gauge", "--hold", "3s",
                                          "--strict"], [FUSED, "--sensor gauge", "'fused'"]),
    # ---- the MIMO controller's iff block (export/mimo.py) against the mirror it runs on -------------------------
    # alpha 0.5 / 1, headroom 1e300 V / 1e-30 V and a 1e300 Hz or 88 Hz bridge corner: ran to exit 0
    *[(f"verify-mirror-{name}", ["verify", FSM, "--controller", f"bad/m_{name}.json", "--out", "{out}"],
       [f"bad/m_{name}.json: [{key}]", frag])
      for name, key, frag in (("alpha_off", "iff.stack_window.alpha", "not the current-limit window of the stacks"),
                              ("alpha_one", "iff.stack_window.alpha", "0.102146"),
                              ("head_1e300", "iff.stack_window.headroom_v", "each stack's range"),
                              ("head_tiny", "iff.stack_window.headroom_v", "re-export"),
                              ("head_inf", "iff.stack_window.headroom_v", "finite"),
                              ("alpha_two", "iff.stack_window.alpha", "three numbers"),
                              ("corner_1e300", "iff.bridge.corner_hz", "Nyquist"),
                              ("corner_off", "iff.bridge.corner_hz", "not the cascades'"),
                              ("noise_1e300", "iff.bridge.out_noise_v_rms", "ADC range 10 V"),
                              # issue 17's leftover: a range whose one step is above the bridge's largest reading
                              ("adc_1e300", "iff.bridge.adc_range_v", "the whole reading spans at most one step"),
                              ("typo_key", "iff.stack_windows", "unknown key"),
                              ("bridge_typo", "iff.bridge.corner", "unknown key"),
                              ("iff_null", "iff", "must be a table"),
                              ("sw_missing", "iff.stack_window", "needs alpha and headroom_v"))],
    # a mirror controller where a single-stack one is needed, and the reverse
    ("verify-stack-with-mimo", ["verify", CREEP, "--controller", "controllers/mimo.json", "--out", "{out}"],
     ["controllers/mimo.json: [schema] is a MIMO mirror controller", "single-stack plant"]),
    ("verify-mirror-with-fused", ["verify", FSM, "--controller", FUSED, "--out", "{out}"],
     [FUSED, "[schema] is not a MIMO controller"]),
    ("verify-mirror-with-an-iff-cascade", ["verify", FSM, "--controller", "controllers/mimo_iff_iff_stack0.json"],
     ["mimo_iff_iff_stack0.json: [schema] is not a MIMO controller"]),
    ("linearize-with-mimo", ["linearize", PLANT, "--controller", "controllers/mimo.json"],
     ["controllers/mimo.json: [schema] is a MIMO mirror controller", "single-stack controller"]),
    ("bench-with-mimo", ["bench", "--controller", "controllers/mimo.json"], ["[schema] is a MIMO mirror controller"]),
    ("selfsense-with-mimo", ["selfsense", CREEP, "--controller", "controllers/mimo.json"],
     ["[schema] is a MIMO mirror controller"]),
    # ---- outputs onto files a mirror reads: its stack files and the creep file beside them ----------------------
    ("verify-mirror-json-onto-a-stack-file", ["verify", FSM, "--controller", "controllers/mimo.json", "--json", PLANT],
     [PLANT, "is the input plants/fsm_p888_51.toml: stacks.files[0]"]),
    ("verify-mirror-json-onto-its-creep-file", ["verify", FSM, "--controller", "controllers/mimo.json", "--json", CREEP],
     [CREEP, "the creep plant beside it"]),
    ("study-mirror-json-onto-a-stack-file", ["study", "studies/fsm_servo.toml", "--out", "{out}", "--json",
                                             "plants/p888_51_sn618.toml"], ["stacks.files[2]"]),
    ("verify-mirror-out-under-file", ["verify", FSM, "--controller", "controllers/mimo.json", "--out", "bad/a_file/v"],
     ["bad/a_file", "is a file"]),
    # ---- mirror and stack studies ------------------------------------------------------------------------------
    ("study-stack-design-iff", ["study", "studies/stack_iff.toml", "--out", "{out}"], ["stack_iff.toml", "[design]"]),
    ("study-stack-set-design-iff", ["study", STUDY, "--out", "{out}", "--set", "design.iff=true"], ["design.iff"]),
    ("study-mirror-iff-text", ["study", "studies/fsm_iff_text.toml", "--out", "{out}"],
     ["fsm_iff_text.toml: [design.iff] got 'yes'"]),
    ("study-mirror-iff-corner-key", ["study", "studies/fsm_iff_corner.toml", "--out", "{out}"],
     ["fsm_iff_corner.toml", "iff_corner_hz"]),
    ("study-mirror-fc-reversed", ["study", "studies/fsm_fc_reversed.toml", "--out", "{out}"],
     ["fsm_fc_reversed.toml: [design.fc_min_hz]"]),
    ("study-mirror-plant-is-a-stack", ["study", "studies/fsm_plant_stack.toml", "--out", "{out}"],
     ["fsm_plant_stack.toml", "[plant]"]),
    # ---- selfsense --force ---------------------------------------------------------------------------------------
    ("selfsense-force-json-onto-table1", ["selfsense", CREEP, "--force", "--json", str(ROOT / TABLE)],
     ["is the input Table 1 the --force study reads"]),
    ("selfsense-force-step-nan", ["selfsense", CREEP, "--force", "--step-force", "nan"], ["--step-force"]),
    # a 1 pN step ran, reported as a "+0 N step" missing its target by 12 orders
    ("selfsense-force-step-1pn", ["selfsense", CREEP, "--force", "--step-force", "1pN"],
     ["--step-force 1e-12 N", "under 0.768 N", "one ADC step"]),
    ("selfsense-force-step-unit", ["selfsense", CREEP, "--force", "--step-force", "10kg"], ["--step-force", "'N'"]),
    ("selfsense-force-and-fused", ["selfsense", CREEP, "--force", "--fused"], ["give one of them"]),
    ("selfsense-force-out-under-file", ["selfsense", CREEP, "--force", "--out", "bad/a_file/x"], ["bad/a_file"]),
    ("selfsense-force-mirror-file", ["selfsense", FSM, "--force"], ["fsm_p888_51.toml"]),
    # ---- Table 1 read by identify (the force study's table checks: tests/selfsense/test_force_table.py) ----------
    ("identify-table-back-emf-mv", ["identify", "transducer", "bad/t_back_emf_mv.csv"],
     ["bad/t_back_emf_mv.csv", "outside (0, 10000] N/V"]),
    ("identify-table-r-in-only", ["identify", "transducer", "bad/t_r_in_only.csv"], ["bad/t_r_in_only.csv", "R_out"]),
    ("identify-mirror-file", ["identify", "transducer", FSM], ["fsm_p888_51.toml: is a .toml file, not a Table 1"]),
    ("identify-controller-file", ["identify", "transducer", "controllers/mimo.json"], ["is a .json file, not a Table 1"]),
    # ---- session 32, the outside user's pass (issue 17 claimed 0 accepted-but-wrong) -------------------------------
    # a bare 200 read as N/m: T_em 65.87 N/V, 6 orders from the R_in runs' 258.6 N/um, unflagged
    ("identify-stiffness-bare-number", ["identify", "transducer", TABLE, "--stiffness", "200"],
     ["--stiffness", "200 N/m", "R_in runs", "unit slip", "200N/um"]),
    ("identify-stiffness-one-prefix-off", ["identify", "transducer", TABLE, "--stiffness", "200N/mm"],
     ["--stiffness", "200000 N/m", "R_in runs"]),
    # linearize refused 200V, sweep ran it ("DF A=200 V"): one home for the amplifier's span
    ("sweep-amplitude-over-the-span", ["sweep", STUDY, "--out", "{out}", "--amplitudes", "200V"],
     ["--amplitudes 200 V", "(0, 140] V", "-20..120 V"]),
    ("selfsense-strict-controller-for-another-plant",
     ["selfsense", "plants/p888_51_sn618.toml", "--controller", CTRL, "--strict", "--out", "{out}"],
     ["sn637_loopshape.json", "p888_51_sn618.toml", "--strict", "trim_scale"]),
    # messages: the flag that gave the value, what the file is, the right schema, the right suffix
    ("study-set-named-not-the-file", ["study", STUDY, "--out", "{out}", "--set", "targets.phase_margin_deg=500"],
     ["--set targets.phase_margin_deg=500", "got 500", "the file is not modified"]),
    ("study-set-plant-value-named", ["study", STUDY, "--out", "{out}", "--set", "electrical.current_limit_source_a=20"],
     ["--set electrical.current_limit_source_a=20", "got 20"]),
    ("study-set-export-name-named", ["study", STUDY, "--out", "{out}", "--set", "export.name=../y"],
     ["--set export.name=../y", "file stem"]),
    ("study-set-deg-key-other-unit", ["study", STUDY, "--out", "{out}", "--set", "targets.phase_margin_deg=50dB"],
     ["--set targets.phase_margin_deg=50dB", "(deg)", "50deg"]),
    ("study-given-a-plant-file", ["study", PLANT, "--out", "{out}"],
     ["p888_51_sn637.toml", "plant file (workbench.plant/1)", "study file"]),
    ("sweep-given-a-plant-file", ["sweep", PLANT, "--out", "{out}"],
     ["p888_51_sn637.toml", "plant file (workbench.plant/1)", "study file"]),
    ("study-given-a-mirror-file", ["study", FSM, "--out", "{out}"],
     ["fsm_p888_51.toml", "mirror file (workbench.fsm/1)", "studies/fsm_servo.toml"]),
    ("study-mirror-workers-schema", ["study", "studies/fsm_servo.toml", "--out", "{out}", "--workers", "1"],
     ["workbench.fsm_study/1", "--workers"]),
    ("synth-out-folder-suggests-csv", ["synth", PLANT, "--out", "{out}/"], ["is a folder", "result.csv"]),
    ("bench-steps-not-integer-valued", ["bench", "--steps", "2.5"], ["'2.5' is not an integer"]),
]


def _run(argv, ws, out, capsys, monkeypatch):
    monkeypatch.chdir(ws)
    argv = [a.replace("{out}", str(out)) for a in argv]
    try:
        code = main(argv)
    except SystemExit as err:          # argparse's own errors
        code = err.code
    cap = capsys.readouterr()
    return code, cap.err


@pytest.mark.parametrize("argv, fragments", [c[1:] for c in CASES + OTHERS + FUZZ3],
                         ids=[c[0] for c in CASES + OTHERS + FUZZ3])
def test_bad_input(argv, fragments, ws, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    before = _hashes(ws)
    code, err = _run(argv, ws, out, capsys, monkeypatch)
    assert code == 2, err
    assert "Traceback" not in err
    assert len([line for line in err.splitlines() if "error:" in line]) == 1, err
    assert "[#" not in err and "[...." not in err, "work (a progress bar) started before the input was refused"
    for fragment in fragments:
        assert fragment.replace("{out}", str(out)) in err, (fragment, err)
    after = _hashes(ws)
    assert after == before, "an input file changed or a file appeared in the workspace"
    assert list(out.iterdir()) == [], "a failed run left output"


def test_enough_cases():
    assert len(CASES) + len(OTHERS) >= 100
    assert len({c[0] for c in CASES + OTHERS + FUZZ3}) == len(CASES) + len(OTHERS) + len(FUZZ3)


@pytest.mark.parametrize("argv, fragment", [
    (["gauge", "bad/latin1.toml"], "line 3"),
    (["verify", CREEP, "--controller", CTRL, "--hold", "1e12s"], "estimated"),
])
def test_bad_input_subprocess(argv, fragment, ws):
    # as a user runs it: the installed entry point, a real process, its exit status
    before = _hashes(ws)
    done = subprocess.run([sys.executable, "-m", "workbench", *argv], cwd=ws, capture_output=True, text=True,
                          check=False, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 2, done.stderr
    assert fragment in done.stderr and "Traceback" not in done.stderr
    assert _hashes(ws) == before


@pytest.mark.parametrize("existing", [False, True])
def test_a_failed_run_writes_nothing(existing, ws, tmp_path, capsys, monkeypatch):
    """A command that fails after writing some of its outputs leaves the output folder as it found it."""
    import workbench.cli as cli
    from workbench.errors import WorkbenchError
    from workbench.report import write_json
    from workbench.report.output import write_text

    def fails_late(args):
        write_text(Path(args.out) / "freefree.png", "half a figure")
        write_json(Path(args.out) / "sub" / "part.json", {"a": 1})
        raise WorkbenchError("the fit diverged")

    monkeypatch.setattr(cli, "cmd_freefree", fails_late)
    out = tmp_path / "ff"
    if existing:
        out.mkdir()
        (out / "earlier.txt").write_text("a previous run's file\n", encoding="utf-8")
    code, err = _run(["freefree", PLANT, "--out", str(out), "--json", str(tmp_path / "ff.json")], ws, out,
                     capsys, monkeypatch)
    assert code == 2 and "the fit diverged" in err
    assert not (tmp_path / "ff.json").exists()
    if existing:
        assert [p.name for p in out.iterdir()] == ["earlier.txt"]
        assert (out / "earlier.txt").read_text(encoding="utf-8") == "a previous run's file\n"
    else:
        assert not out.exists()


def test_writers_never_replace_an_input(ws, tmp_path):
    """Inside a run, every atomic writer refuses an input path however it is spelled."""
    from workbench.report.output import OutputOntoInputError, protect_inputs, write_json, write_text
    plant = ws / PLANT
    before = plant.read_bytes()
    link = tmp_path / "link.toml"
    link.symlink_to(plant)
    with protect_inputs([("plant", plant)]):
        for spelling in (plant, ws / "plants" / ".." / PLANT, link):
            with pytest.raises(OutputOntoInputError, match="is the input plant"):
                write_text(spelling, "overwritten")
        with pytest.raises(OutputOntoInputError):
            write_json(plant, {"a": 1})
        write_text(tmp_path / "other.toml", "fine")      # anything else is written
    assert plant.read_bytes() == before
    write_text(tmp_path / "again.toml", "x")              # the guard ends with the run
    assert (tmp_path / "other.toml").read_text(encoding="utf-8") == "fine"


def test_sweep_writes_its_table_when_no_case_has_a_margin(tmp_path, capsys, monkeypatch):
    """The README's `sweep ... --amplitudes 1V 20V`: every member slews at crossover, so no case has a
    phase margin; the sweep still writes its table (issue 17 rejected it after running every case).
    The cases' rows are those of a slewing loop (margins NaN, the reason in slews_at_crossover)."""
    import csv
    import math

    import workbench.verify.sweep_job as job

    def slewing_rows(fn, cases, **kw):
        return [{**c.key, "slews_at_crossover": True, "phase_margin_deg": math.nan, "gain_margin_db": math.nan,
                 "crossover_hz": math.nan, "triangle_error_percent": 0.05, "step_overshoot_percent": 0.1,
                 "step_settling_s": 0.02, "ok": True, "error": ""} for c in cases]

    monkeypatch.setattr(job, "run_cases", slewing_rows)
    monkeypatch.chdir(ROOT)
    out = tmp_path / "sweep"
    assert main(["sweep", STUDY, "--amplitudes", "1V", "20V", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "no case has a phase_margin_deg: 18 of 18 slew at crossover" in text
    with open(out / "sweep.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    # 3 serials x C_p (1 - tol, 1, 1 + tol) x 2 amplitudes, each with its reason
    assert len(rows) == 18 and all(r["slews_at_crossover"] == "True" and r["phase_margin_deg"] == "" for r in rows)
    assert sorted({float(r["amplitude_v"]) for r in rows}) == [1.0, 20.0]


def test_force_runs_beyond_the_time_bound_but_not_beyond_memory(capsys, monkeypatch):
    """--force lifts the time bound (the run is stated first), never the memory the machine lacks."""
    from workbench import preflight
    from workbench.cli import build_parser
    monkeypatch.chdir(ROOT)
    parse = build_parser().parse_args
    hold = ["verify", CREEP, "--controller", CTRL, "--hold", "1e8s"]    # 1e12 periods: days, little memory
    with pytest.raises(preflight.FlagRangeError, match="--force"):
        preflight._check_size(parse(hold))
    preflight._check_size(parse(hold + ["--force"]))
    err = capsys.readouterr().err
    assert "--hold 1e+08 s" in err and "estimated" in err
    cycles = ["freefree", PLANT, "--cycles", "1000000", "--force"]      # 1e11 samples of ~120 B each
    with pytest.raises(preflight.FlagRangeError, match="more than this machine"):
        preflight._check_size(parse(cycles))


def test_selfsense_size_bound_is_lifted_by_its_own_flag(monkeypatch):
    """selfsense's --force is the force study (issue 16): the size bound's override there is another flag,
    and a refusal names the flag that works on that command."""
    from workbench import preflight
    from workbench.cli import build_parser
    monkeypatch.chdir(ROOT)
    parse = build_parser().parse_args
    ss = parse(["selfsense", CREEP, "--force"])
    assert ss.force is True and ss.force_size is False                  # the force study, not the override
    assert parse(["selfsense", CREEP, "--allow-long-run"]).force_size is True
    assert parse(["verify", CREEP, "--controller", CTRL, "--force"]).force_size is True
    assert preflight.size_flag("selfsense") == "--allow-long-run" and preflight.size_flag("verify") == "--force"


def test_free_free_floor_is_the_voltage_whose_stroke_is_the_gauge_noise():
    """The --v-peak floor is where the quasi-static stroke from rest reaches the gauge noise of the plant file."""
    from workbench import preflight
    from workbench.plant import load_plant
    for name in ("p888_51_sn637", "p888_51_sn629", "p888_51_sn618"):
        plant = load_plant(ROOT / "plants" / f"{name}.toml")
        noise = plant.gauge.noise_rms_m
        v_min = preflight._v_for_stroke(plant.pzt, noise)
        assert 0 < v_min < plant.pzt.voltage_max_v
        assert preflight._stroke_from_rest_m(plant.pzt, v_min) == pytest.approx(noise, rel=1e-9)
        assert preflight._stroke_from_rest_m(plant.pzt, 0.99 * v_min) < noise


# ---------------------------------------------------------------------------------------------
# accepted input: legal records next to a validator's boundary must pass (review 3, item 17)

def _sine_record_text(fs_hz=1e4, f_hz=10.0, n=2000, v_bias=50.0, v_amp=40.0, preamble=""):
    """A quasi-static sine record of the calibrate format: time[s], voltage[V], displacement[m]."""
    t = np.arange(n) / fs_hz
    v = v_bias + v_amp * np.sin(2 * np.pi * f_hz * t)
    x = 1e-7 * v                                   # 0.1 um/V, the order of SN637's gain
    rows = "\n".join(f"{a:.9g},{b:.9g},{c:.9g}" for a, b, c in zip(t, v, x))
    return preamble + "time[s],voltage[V],displacement[m]\n" + rows + "\n"


def _preflight_calibrate(data, tmp_path):
    from workbench.cli import build_parser
    from workbench.preflight import preflight
    args = build_parser().parse_args(["calibrate", str(data), "--plant", str(ROOT / PLANT),
                                      "--out", str(tmp_path / "out")])
    with preflight(args):
        pass


@pytest.mark.parametrize("suffix", [".txt", ".csv", ".dat"])
def test_a_bom_record_is_accepted_whatever_its_suffix(suffix, tmp_path):
    """The record reader skips a BOM (record.py), so the file check must not refuse one (review 3, bug 1)."""
    from workbench.calibrate.record import read_record
    path = tmp_path / f"rec{suffix}"
    path.write_bytes(b"\xef\xbb\xbf" + _sine_record_text().encode("utf-8"))
    _preflight_calibrate(path, tmp_path)
    rec = read_record(path)
    assert len(rec.t_s) == 2000


def test_a_bom_toml_is_still_refused(tmp_path):
    """The TOML reader takes a BOM as text: the refusal stays for .toml and .json."""
    from workbench.paths import FileArgumentError, check_text_file
    path = tmp_path / "plant.toml"
    path.write_bytes(b"\xef\xbb\xbf" + (ROOT / PLANT).read_bytes())
    with pytest.raises(FileArgumentError, match="byte-order mark"):
        check_text_file(path)


def test_step_force_compression_and_tension_are_bounded_apart():
    """The force step's range lives in the library (review 3, items 9 and 11): a compressive preload step of the
    blocked force or several times it is legal (the linear model holds), a tension beyond the 15 MPa preload share
    of seed 000 is not (the ceramic breaks in tension); the numbers come from the plant file."""
    from workbench.errors import FlagRangeError
    from workbench.plant import load_plant
    from workbench.selfsense.force import check_step_force, step_force_range_n
    pzt = load_plant(ROOT / CREEP).pzt
    lo, hi, f_block = step_force_range_n(pzt)
    stroke = float(pzt.quasi_static_x_m([0.0, pzt.voltage_max_v])[-1])
    assert f_block == pytest.approx(pzt.stiffness_n_per_m * stroke, rel=1e-12)
    assert 3000.0 < f_block < 4500.0                      # seed 000: "a blocking force of up to 3600 Newtons"
    assert hi < f_block < -lo
    for ok in (-100.0, -f_block, -5 * f_block, lo, 100.0, hi):     # accepted: no error
        check_step_force(pzt, ok)
    for bad, why in ((1.01 * lo, "outside the linear model"), (1.01 * hi, "a tension"), (f_block, "a tension"),
                     (1e9, "a tension"),
                     (0.0, "nonzero"), (float("nan"), "nonzero")):
        with pytest.raises(FlagRangeError, match=why):
            check_step_force(pzt, bad, name="--step-force")


def test_the_library_refuses_a_seed_numpy_cannot_take():
    """verify() checks its seed itself (review 3, item 9); the CLI's --seed check is the same function."""
    from workbench.errors import FlagRangeError
    from workbench.fields import check_seed
    from workbench.verify.run import verify
    for ok in (0, 2, 2 ** 63 - 1, np.int64(5)):
        check_seed(ok)                                        # accepted: no error
    for bad in (-1, 2 ** 63, 1.5, True, "3"):
        with pytest.raises(FlagRangeError, match="seed"):
            check_seed(bad)
    with pytest.raises(FlagRangeError, match="seed -1"):
        verify(ROOT / CREEP, ROOT / CTRL, seed=-1)


def _accepted_record(tmp_path, name, t, v, x, preamble=""):
    rows = "\n".join(f"{a:.12g},{b:.9g},{c:.9g}" for a, b, c in zip(t, v, x))
    path = tmp_path / name
    path.write_text(preamble + "time[s],voltage[V],displacement[m]\n" + rows + "\n", encoding="utf-8")
    return path


def _calibrate_checks(path, tmp_path):
    """What calibrate checks before fitting: the file (preflight), the reader, the voltage range and the stroke."""
    from workbench.calibrate.record import read_record
    from workbench.calibrate.run import _check_displacement_scale, _check_range
    from workbench.plant import load_plant
    _preflight_calibrate(path, tmp_path)
    rec = read_record(path)
    pzt = load_plant(ROOT / PLANT).pzt
    _check_range(path, rec.channels["voltage_v"], pzt.voltage_min_v, pzt.voltage_max_v, "test")
    _check_displacement_scale(path, rec, pzt, PLANT)
    return rec


def test_legal_records_next_to_the_boundaries_are_accepted(tmp_path):
    """Review 3 item 12/17: records a user may legally bring pass every check calibrate runs first:
    the resistor out (R = 0), a 1 MHz record of a 200 kHz drive whose stroke is half the quasi-static one
    (above the R C corner), a bipolar drive over the plant's whole range, a 1 V sine on a 50 V bias under
    10 mV of voltage noise and the gauge's 22 nm of displacement noise."""
    from workbench.plant import load_plant
    pzt = load_plant(ROOT / PLANT).pzt
    rng = np.random.default_rng(17)

    def qs(v):
        return pzt.quasi_static_x_m(np.r_[0.0, v])[1:]
    cases = []
    t = np.arange(2000) / 1e4
    v = 50.0 + 40.0 * np.sin(2 * np.pi * 10.0 * t)
    cases.append(("r0.csv", t, v, qs(v), "# series_resistor_ohm: 0\n"))
    t = np.arange(4000) / 1e6
    v = 50.0 + 40.0 * np.sin(2 * np.pi * 2e5 * t)
    cases.append(("mhz.csv", t, v, 0.5 * qs(v), ""))
    t = np.arange(2000) / 1e4
    v = 0.5 * (pzt.voltage_min_v + pzt.voltage_max_v) + 0.5 * (pzt.voltage_max_v - pzt.voltage_min_v) * \
        np.sin(2 * np.pi * 5.0 * t)
    cases.append(("bipolar.csv", t, v, qs(v), ""))
    v = 50.0 + 1.0 * np.sin(2 * np.pi * 5.0 * t) + 0.01 * rng.standard_normal(t.size)
    cases.append(("small.csv", t, v, qs(v) + 22e-9 * rng.standard_normal(t.size), ""))
    for name, t_, v_, x_, pre in cases:
        rec = _calibrate_checks(_accepted_record(tmp_path, name, t_, v_, x_, pre), tmp_path)
        assert len(rec.t_s) == t_.size
    assert float(_calibrate_checks(tmp_path / "r0.csv", tmp_path).metadata["series_resistor_ohm"]) == 0.0


@pytest.mark.parametrize("argv, fragment", [
    (["verify", CREEP, "--controller", CTRL, "--scenario", "bogus"], "invalid choice: 'bogus'"),
    (["linearize", PLANT, "--cp-tolerance", "20%"], "--cp-tolerance"),
    (["calibrate", RECORD], "--plant"),
    (["bogus"], "invalid choice"),
])
def test_argparse_errors_are_one_line(argv, fragment, ws, capsys, monkeypatch):
    """argparse's usage errors printed the usage and the error (5-11 lines); the README says one line on
    stderr, exit status 2 (session 32, the outside pass)."""
    monkeypatch.chdir(ws)
    with pytest.raises(SystemExit) as info:
        main(argv)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert info.value.code == 2 and len(lines) == 1 and fragment in lines[0] and "--help" in lines[0], err
