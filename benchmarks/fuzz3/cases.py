CREEP = "plants/p888_51_sn637_creep.toml"; PLANT = "plants/p888_51_sn637.toml"; FSM = "plants/fsm_p888_51.toml"
FUSED = "controllers/sn637_fused_loopshape.json"; CTRL = "controllers/sn637_loopshape.json"
MIMO = "controllers/mimo.json"; MIFF = "controllers/mimo_iff.json"
TABLE = "plants/data/p888_51_instron_table1.csv"
V = lambda c, *more: ["verify", CREEP, "--controller", c, "--sensor", "fused", "--hold", "3s", "--out", "{out}", *more]
VM = lambda c, *more: ["verify", FSM, "--controller", c, "--out", "{out}", *more]
S = lambda s, *more: ["study", s, "--out", "{out}", *more]
I = lambda t, *more: ["identify", "transducer", t, *more]
CASES = []
for f in ("wait_nan", "wait_neg", "wait_str", "wait_bool", "wait_1e300", "wait_1e9", "wait_list", "wait_inf",
          "lead_nan", "lead_neg", "lead_1e300", "lead_1e3", "lead_str", "curv_nan", "curv_1e300", "curv_m1e9",
          "curv_1e6", "curv_minf", "curv_str", "kind_case", "kind_missing", "kind_null", "typo_key", "lsb_zero",
          "lsb_1", "lsb_tiny", "vpm_neg", "xover_nyq", "xover_nan", "blend_list", "k_off", "es_wrong", "es_str",
          "sensor_str", "sensor_null"):
    CASES.append((f"verify-fused-{f}", V(f"bad/f_{f}.json")))
CASES += [
    ("verify-fused-wait0-legal", V("bad/f_wait_zero.json")),
    ("verify-gauge-ctrl-wait-1e300", ["verify", CREEP, "--controller", "bad/g_wait_1e300.json", "--scenario", "small_step", "--out", "{out}"]),
    ("verify-fused-sensor-gauge", ["verify", CREEP, "--controller", FUSED, "--sensor", "gauge", "--hold", "3s", "--out", "{out}", "--strict"]),
    ("verify-fused-as-gauge-sensor-fused", V("bad/f_as_gauge.json")),
    ("verify-fused-as-charge-on-plant-no-charge", ["verify", PLANT, "--controller", "bad/f_as_charge.json", "--sensor", "charge", "--hold", "3s", "--out", "{out}"]),
    ("linearize-fused-wait-1e300", ["linearize", PLANT, "--controller", "bad/f_wait_1e300.json", "--amplitudes", "1V", "--freq-points", "3"]),
    ("selfsense-fused-ctrl-wait-1e300", ["selfsense", CREEP, "--fused", "--fused-controller", "bad/f_wait_1e300.json", "--hold", "3s"]),
    ("selfsense-fused-ctrl-mimo", ["selfsense", CREEP, "--fused", "--fused-controller", MIMO, "--hold", "3s"]),
    ("selfsense-fused-ctrl-lead-nan", ["selfsense", CREEP, "--fused", "--fused-controller", "bad/f_lead_nan.json", "--hold", "3s"]),
    ("bench-fused-curv-1e300", ["bench", "--controller", "bad/f_curv_1e300.json", "--steps", "10", "--reference-steps", "10", "--memory-periods", "0"]),
    # MIMO controllers
    *[(f"verify-mirror-{n}", VM(f"bad/m_{n}.json")) for n in (
        "alpha_zero", "alpha_big", "alpha_nan", "alpha_two", "alpha_str", "alpha_scalar", "alpha_one", "alpha_off",
        "head_inf", "head_1e300", "head_neg", "head_100", "head_tiny", "sw_missing", "sw_list", "iff_null",
        "iff_list", "iff_empty", "corner_1e300", "gain_nan", "adc_bits_0", "adc_bits_64", "adc_range_1e300",
        "noise_1e300", "cref_str", "iff_rate", "iff_ctrl_list", "iff_stack0_sensor", "iff_on_notch", "rate_20k",
        "unknown_key", "axes_sensor")],
    ("verify-stack-with-mimo", ["verify", CREEP, "--controller", MIMO, "--scenario", "small_step", "--out", "{out}"]),
    ("verify-stack-with-mimo-iff", ["verify", PLANT, "--controller", MIFF, "--out", "{out}"]),
    ("verify-mirror-with-siso", VM(CTRL)),
    ("verify-mirror-with-fused", VM(FUSED)),
    ("verify-mirror-with-iff-subcascade", VM("controllers/mimo_iff_iff_stack0.json")),
    ("verify-mirror-with-axis-cascade", VM("controllers/mimo_tip.json")),
    ("linearize-with-mimo", ["linearize", PLANT, "--controller", MIMO]),
    ("bench-with-mimo", ["bench", "--controller", MIMO, "--steps", "10"]),
    ("selfsense-with-mimo", ["selfsense", CREEP, "--controller", MIMO]),
    ("sweep-with-mimo", ["sweep", "studies/sn637_servo.toml", "--controller", MIMO, "--out", "{out}"]),
    ("verify-stack-with-mirror-plant-as-targets", ["verify", CREEP, "--controller", CTRL, "--targets-from", FSM, "--scenario", "small_step"]),
    ("verify-mirror-json-onto-controller", VM(MIFF, "--json", MIFF)),
    ("verify-mirror-json-onto-stack-file", VM(MIMO, "--json", PLANT)),
    ("verify-mirror-json-onto-creep-file", VM(MIMO, "--json", CREEP)),
    ("verify-mirror-out-under-file", ["verify", FSM, "--controller", MIMO, "--out", "bad/a_file/v"]),
    ("verify-mirror-plant-stack-missing", ["verify", "plants/fsm_stack_missing.toml", "--controller", MIMO, "--out", "{out}"]),
    ("verify-mirror-plant-stack-self", ["verify", "plants/fsm_stack_self.toml", "--controller", MIMO, "--out", "{out}"]),
    ("verify-mirror-plant-two-stacks", ["verify", "plants/fsm_two_stacks.toml", "--controller", MIMO, "--out", "{out}"]),
    ("verify-mirror-seed-neg", VM(MIMO, "--seed=-1")),
    # mirror studies
    *[(f"study-{n}", S(f"studies/{n}.toml")) for n in (
        "fsm_iff_str", "fsm_iff_int", "fsm_iff_corner", "fsm_fc_nan", "fsm_fc_rev", "fsm_fc_huge", "fsm_plant_stack",
        "fsm_plant_missing", "fsm_bias_neg", "fsm_notch_neg", "fsm_iff_section", "fsm_design_scalar",
        "fsm_export_dir_dots", "stack_schema_fsm", "stack_iff_key")],
    ("study-stack-set-design-iff", S("studies/sn637_servo.toml", "--set", "design.iff=true")),
    ("study-stack-set-iff-corner", S("studies/sn637_servo.toml", "--set", "design.iff_corner_hz=8.8Hz")),
    ("study-fsm-set-iff", S("studies/fsm_servo.toml", "--set", "design.iff=true")),
    ("study-fsm-json-onto-stack-file", S("studies/fsm_servo.toml", "--json", PLANT)),
    ("study-fsm-json-onto-mirror", S("studies/fsm_servo.toml", "--json", FSM)),
    ("study-fsm-out-under-file", ["study", "studies/fsm_servo.toml", "--out", "bad/a_file/s"]),
    ("study-fsm-only", S("studies/fsm_servo.toml", "--only", "loopshape")),
    ("study-fsm-json-onto-report", S("studies/fsm_servo.toml", "--json", "{out}/report.md")),
    # selfsense --force
    ("selfsense-force-step-nan", ["selfsense", CREEP, "--force", "--step-force", "nan"]),
    ("selfsense-force-step-inf", ["selfsense", CREEP, "--force", "--step-force", "inf N"]),
    ("selfsense-force-step-nounit", ["selfsense", CREEP, "--force", "--step-force", "100"]),
    ("selfsense-force-step-kg", ["selfsense", CREEP, "--force", "--step-force", "10kg"]),
    ("selfsense-force-step-tiny", ["selfsense", CREEP, "--force", "--step-force", "1e-12N"]),
    ("selfsense-force-and-fused", ["selfsense", CREEP, "--force", "--fused"]),
    ("selfsense-force-and-dynamics", ["selfsense", CREEP, "--force", "--dynamics"]),
    ("selfsense-force-duration-ignored", ["selfsense", CREEP, "--force", "--duration", "1e12s"]),
    ("selfsense-force-json-onto-table", ["selfsense", CREEP, "--force", "--json", "@ROOT/" + TABLE]),
    ("selfsense-force-json-onto-plant", ["selfsense", CREEP, "--force", "--json", CREEP]),
    ("selfsense-force-out-file", ["selfsense", CREEP, "--force", "--out", "bad/a_file"]),
    ("selfsense-force-out-under-file", ["selfsense", CREEP, "--force", "--out", "bad/a_file/x"]),
    ("selfsense-force-mirror-plant", ["selfsense", FSM, "--force"]),
    ("selfsense-force-generic-plant", ["selfsense", "plants/generic_stack.toml", "--force"]),
    ("selfsense-force-seed-neg", ["selfsense", CREEP, "--force", "--seed=-1"]),
    ("selfsense-mirror-plant", ["selfsense", FSM, "--duration", "100s"]),
    # Table 1 variants (identify, the CLI's way to a table)
    *[(f"identify-table-{n}", I(f"bad/t_{n}.csv")) for n in (
        "missing_col", "swapped_units", "one_row", "latin1", "dir", "nan_cell", "empty_cell", "dup_col",
        "bad_config", "unknown_serial", "mV", "no_rout", "crlf", "dup_row", "emf_zero")],
    ("identify-json-onto-table-dotted", I(TABLE, "--json", "plants/../" + TABLE)),
    ("identify-json-under-file", I(TABLE, "--json", "bad/a_file/t.json")),
    ("identify-mirror-file", I(FSM)),
    ("identify-mimo-json", I(MIMO)),
    # other odd outputs
    ("verify-fused-json-onto-fused", V(FUSED, "--json", FUSED)),
    ("verify-out-equals-json", ["verify", CREEP, "--controller", CTRL, "--out", "{out}/x", "--json", "{out}/x"]),
    ("verify-json-onto-mirror-files-stack-from-stack-verify", ["verify", CREEP, "--controller", CTRL, "--json", "plants/p888_51_sn637_creep.toml"]),
]
