"""Finding 1: a clean triangle record (no effect) is named a resonance, 5 of 5, and the reported error
after is ~36x the error before.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/repro_triangle_resonance.py [RATE F DUR]
"""
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from harness import TMP, calibrate, simulate, triangle  # noqa: E402
from workbench.plant import load_plant  # noqa: E402

rate, f, dur = (float(a) for a in sys.argv[1:4]) if len(sys.argv) > 3 else (2.5e3, 0.5, 10.0)
seed = int(sys.argv[4]) if len(sys.argv) > 4 else 1
plant = "plants/p888_51_sn637.toml"
t, v = triangle(rate, dur, f)
r, _ = simulate(load_plant(plant), "none", t, v, seed, 1.0)
res = calibrate(r, plant, "tri")
print("effect", res["effect"], "agreement", res["agreement"], "channel", res["channel"])
for k in ("error_before", "error_after", "error_after_source", "error_after_model", "updated_plant_error",
          "updated_plant_error_reason", "parameters", "reason"):
    print(k, json.dumps(res.get(k), default=str)[:600])
for s in res.get("stages", []):
    print("stage", s["effect"], s.get("agreement"), s.get("error_before"), s.get("error_after"))
print("warnings", res["base_fit"]["warnings"])
print("notes", *res["base_fit"]["notes"], sep="\n  ")
print("line", json.dumps(res["base_fit"]["line"]["displacement"]))
print("top candidates", [(c["name"], c["channel"], round(c["score"], 3)) for c in res["candidates"][:5]])
