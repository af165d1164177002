"""s38_wrong probe: on one record, ask every drift row the periodic-drive rule (periodic_mode_test) and print what
it keeps; print the drift term's and the base residual's per-cycle structure.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/logs/s38_wrong/probe_drift.py REC.csv PLANT.toml
"""
import sys
import numpy as np
from workbench.calibrate import tracing, run

seen = []
_orig = tracing._score_stage


def spy(cands, probs, nulls, extra, split, penalty, noise_factor, infos, found, min_share):
    res = _orig(cands, probs, nulls, extra, split, penalty, noise_factor, infos, found, min_share)
    if seen:
        return res
    drive = infos.get("drive")
    t = infos["t"]
    print("drive", None if drive is None else (drive.f_hz, drive.start, drive.change_v, drive.level_v))
    for r in res["rows"]:
        print(f"  {r['name']:12s} {r['channel']:12s} {str(r.get('variant')):8s} passes={sum(r['passes'])} "
              f"score={r['score']:.3f} periodic={r.get('periodic')}")
        if r["name"] == "drift":
            print("     ratios", np.round(r["ratios"], 3), "holds", {k: v for k, v in (r.get("holds") or {}).items()
                                                                  if k != "note"})
    for r in res["rows"]:
        if r["name"] != "drift" or drive is None:
            continue
        key = r["key"]
        prob = probs[key]
        floor = noise_factor * infos[r["channel"]]["noise_floor"]
        rr = dict(r)
        rr["befores"] = res["befores"][key]
        # the rows' own passes before any rule
        LOUD.append(1)
        p, info = tracing.periodic_mode_test(rr, prob, extra[key], split, drive, t, floor, res["null_gain"][key],
                                             penalty, min_share)
        LOUD.clear()
        after = [q * b / (1 + penalty * r["n_params"]) for q, b in zip(r["ratios"], rr["befores"])]
        print("    after(term alone)", np.round(after, 10))
        print("    floor", floor, "null", np.sqrt(res["null_gain"][key]), "befores", rr["befores"], "ratios", r["ratios"],
              "params", {k: v for k, v in r["params"].items()})
        print(f"  ASKED drift {r['channel']} {r.get('variant')}: passes {r['passes']} -> {p} {info}")
        for a in r.get("alt", []):
            aa = dict(a)
            aa["befores"] = res["befores"][key]
            p, info = tracing.periodic_mode_test(aa, prob, extra[key], split, drive, t, floor,
                                                 res["null_gain"][key], penalty, min_share)
            print(f"  ASKED alt drift {a['channel']} {a.get('variant')}: passes {a['passes']} -> {p} {info}")
    seen.append(1)
    return res


tracing._score_stage = spy
import os
if os.environ.get("PROBE_MAIN") and hasattr(tracing, "PERIODIC_ASKED"):
    tracing.PERIODIC_ASKED = tracing.PERIODIC_DRIVERS      # the rows as main scores them; the rule asked below
_ft = tracing._fold_test
LOUD = []


def loud_fold_test(b, a, n_params, penalty, floor, null_gain, min_share):
    out = _ft(b, a, n_params, penalty, floor, null_gain, min_share)
    if LOUD:
        print(f"      harmonics-model b={b:.3g} +term a={a:.3g} gain/b2={(b * b - a * a) / b / b:.3f} "
              f"floor2/b2={floor ** 2 / b / b:.3f} null/b2={null_gain / b / b:.3f} -> {out}")
    return out


tracing._fold_test = loud_fold_test
import workbench.calibrate.stages as st
if hasattr(st, "_score_stage"):
    st._score_stage = spy
out = run._run_calibrate(sys.argv[1], sys.argv[2], figures=False)
print("ANSWER", out["effect"], out["channel"], out["agreement"], "before", out["error_before"]["rms"],
      "after", out["error_after"]["rms"])
