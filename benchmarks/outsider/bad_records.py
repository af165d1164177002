"""Bad and odd record files for the CLI: each should exit 2 with a clear message, or give a sound answer.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/bad_records.py OUTDIR
writes OUTDIR/*.csv from one clean simulated record (SN637, 1 kHz, 6 s, 0.5 Hz sine, seed 5).
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from harness import simulate, sine  # noqa: E402
from workbench.calibrate.synthetic import write_record  # noqa: E402
from workbench.plant import load_plant  # noqa: E402

out = Path(sys.argv[1])
out.mkdir(parents=True, exist_ok=True)
t, v = sine(1e3, 6.0, 0.5)
r, _ = simulate(load_plant("plants/p888_51_sn637.toml"), "none", t, v, 5, 1.0)
K = ("time_s", "voltage_v", "current_a", "displacement_m", "gauge_v")
base = {k: r[k].copy() for k in K}


def w(name, rec, meta=None):
    write_record(out / f"{name}.csv", rec, meta)


w("ok", base)
x = {k: a.copy() for k, a in base.items()}; x["displacement_m"][1000] = np.nan; w("nan_cell", x)
x = {k: a.copy() for k, a in base.items()}; x["gauge_v"][:] = 1.234; w("constant_gauge", x)
x = {k: a.copy() for k, a in base.items()}; x["time_s"][2000], x["time_s"][2001] = x["time_s"][2001], x["time_s"][2000]; w("time_swap", x)
x = {k: np.insert(a, 3000, a[3000]) for k, a in base.items()}; w("dup_row", x)
x = {k: a.copy() for k, a in base.items()}; x["displacement_m"] = x["displacement_m"] * 1e6; w("disp_in_um_labelled_m", x)
x = {k: a.copy() for k, a in base.items()}; x["current_a"] = -x["current_a"]; w("current_sign_flipped", x)
x = {k: a.copy() for k, a in base.items()}; x["displacement_m"] = -x["displacement_m"]; w("displacement_sign_flipped", x)
x = {k: a.copy() for k, a in base.items()}; x["displacement_m"] = x["displacement_m"][::-1].copy(); w("displacement_reversed", x)
x = {k: a.copy() for k, a in base.items()}; x["displacement_m"] = np.random.default_rng(0).standard_normal(t.size) * 1e-6; w("displacement_pure_noise", x)
x = {k: a.copy() for k, a in base.items()}; x["time_s"] = x["time_s"] * 1e-3; w("time_in_ms_labelled_s", x)
x = {k: a.copy() for k, a in base.items()}; x["time_s"] = x["time_s"] + 1e9; w("time_offset_1e9", x)
x = {k: a[:40].copy() for k, a in base.items()}; w("forty_rows", x)
x = {k: a.copy() for k, a in base.items()}; x["voltage_v"] = x["voltage_v"] * 0 + 50 + 1e-3 * np.random.default_rng(1).standard_normal(t.size); w("constant_voltage_noise", x)
x = {k: a.copy() for k, a in base.items()}; x["gauge_v"] = x["gauge_v"][np.random.default_rng(2).permutation(t.size)]; w("gauge_shuffled", x)
x = {"time_s": base["time_s"], "voltage_v": base["voltage_v"], "current_a": base["current_a"]}; w("current_only", x)
x = {"time_s": base["time_s"], "voltage_v": base["voltage_v"], "gauge_v": base["gauge_v"]}; w("gauge_only", x)
x = {k: a.copy() for k, a in base.items()}; w("current_declared_sampled", x, {"current": "sampled"})
x = {k: a.copy() for k, a in base.items()}; w("series_resistor_zero_meta", x, {"series_resistor_ohm": 0})
x = {k: a.copy() for k, a in base.items()}; w("input_command_meta_but_terminal", x, {"input": "command"})
x = {k: a.copy() for k, a in base.items()}; x["displacement_m"][2500:] += 5e-7; w("displacement_jump_500nm", x)
x = {k: a.copy() for k, a in base.items()}; x["voltage_v"] = x["voltage_v"] * 10; w("voltage_x10_out_of_range", x)
x = {k: a.copy() for k, a in base.items()}; x["voltage_v"][3000:3100] = x["voltage_v"][2999]; w("voltage_dropout_flat", x)
x = {k: a.copy() for k, a in base.items()}; x["gauge_v"] = np.clip(x["gauge_v"], -np.inf, np.percentile(x["gauge_v"], 60)); w("gauge_clipped_at_60pct", x)
print("written", len(list(out.glob('*.csv'))))
