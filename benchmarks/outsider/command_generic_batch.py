"""Clean SN637 records logged as an amplifier command (`# input: command`: the voltage column is the command,
(V_amp - offset) / gain, lagged by a first-order filter whose lag the record does not say), and the same records
calibrated against plants/generic_stack.toml (voltage -> displacement only). No effect: any named is wrong.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/command_generic_batch.py [--seeds 1 2 3]
"""
import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

sys.path.insert(0, str(Path(__file__).parent))
from harness import TMP, multisine, sine, summary, triangle  # noqa: E402
from workbench.calibrate.run import run_calibrate  # noqa: E402
from workbench.calibrate.synthetic import plant_with_effect, simulate_record, write_record  # noqa: E402
from workbench.plant import load_plant  # noqa: E402

P = "plants/p888_51_sn637.toml"
DETAIL = False


def one(tag, t, v_amp, seed, plant_file, command, effect="none", size=1.0):
    rng = np.random.default_rng(seed)
    plant, truth = plant_with_effect(load_plant(P), effect, seed, duration_s=float(t[-1]), size=size)
    r = simulate_record(plant, t, v_amp, seed=seed)
    meta, rec = {}, {k: r[k] for k in ("time_s", "voltage_v", "current_a", "displacement_m", "gauge_v")}
    if command:
        gain, offset = rng.uniform(8, 30), rng.uniform(-3, 3)
        lag = rng.uniform(0.2e-3, 5e-3)            # s: the command leads the amplifier's output by this lag
        # the logged command u is such that the amplifier (gain, offset, 1st-order lag) outputs v_amp: we log u
        # as v_amp advanced (a causal model of the amplifier run backwards is ill-posed), so instead simulate the
        # plant on the amplifier's output of the command: u = drive / gain, v_amp = lag(u) * gain + offset
        rate = 1.0 / (t[1] - t[0])
        u = (v_amp - v_amp.min()) / gain
        a = 1.0 - np.exp(-1.0 / (rate * lag))
        v_out = gain * lfilter([a], [1.0, a - 1.0], u, zi=[(1.0 - a) * u[0]])[0] + offset
        r = simulate_record(plant, t, v_out, seed=seed)
        rec = {"time_s": t, "voltage_v": u + 1e-4 * rng.standard_normal(t.size),
               "current_a": r["current_a"], "displacement_m": r["displacement_m"], "gauge_v": r["gauge_v"]}
        meta = {"input": "command"}
        truth = dict(truth, gain=gain, offset=offset, lag_s=lag)
    if plant_file.endswith("generic_stack.toml"):
        rec = {k: rec[k] for k in ("time_s", "voltage_v", "displacement_m")}
    path = write_record(TMP / f"{tag.replace(' ', '_')}.csv", rec, meta)
    try:
        res = run_calibrate(path, plant_file, figures=False)
        res["s"] = 0.0
        named = [s["effect"] for s in res["stages"]]
        cls = "none" if not named else ("WRONG" if effect == "none" or any(n != effect for n in named) else "right")
        line = summary(res)
    except Exception as e:  # noqa: BLE001
        cls, line = "error", f"{type(e).__name__}: {e}"[:300]
    print(f"{tag:<44} {effect:<10} -> {cls:<5} {line}", flush=True)
    if DETAIL and cls != "error":
        print("   truth", truth, "\n   params", res.get("parameters"), "\n   reason", res.get("reason"),
              "\n   command_map", res["base_fit"].get("command_map"), "\n   vsrc", res["base_fit"].get("voltage_source"),
              "\n   split", res.get("split"), "\n   top", [(c["name"], c["channel"], round(c["score"], 3)) for c in res["candidates"][:4]],
              "\n   warnings", res["base_fit"]["warnings"], flush=True)
    return cls


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--only", default=None, help="run the records whose tag contains this")
    ap.add_argument("--detail", action="store_true")
    a = ap.parse_args()
    DETAIL = a.detail
    out = {}
    for s in a.seeds:
        for dname, (t, v) in [("sine 1k 10s 0.5Hz", sine(1e3, 10.0, 0.5, 0, 110)),
                              ("msine 2.5k 8s", multisine(2.5e3, 8.0, 0.3, 30, seed=s, hi=110)),
                              ("tri 1k 12s 0.4Hz", triangle(1e3, 12.0, 0.4, 0, 110))]:
            for pf, cmd in ((P, True), ("plants/generic_stack.toml", False), ("plants/generic_stack.toml", True)):
                tag = f"s{s} {dname} {'cmd' if cmd else 'term'} {Path(pf).stem}"
                if a.only and a.only not in tag:
                    continue
                c = one(tag, t, v, s, pf, cmd)
                out[c] = out.get(c, 0) + 1
    print("classes:", out)
