"""Finding: a clean 250 Hz multisine record (40 s, 12 tones 0.05-20 Hz, random phases; no effect drawn) is
named a drift 4 of 5, with the held-out displacement error cut to ~0.2x.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/repro_msine_drift.py [SEED ...]
(default seed 210958: effect_batch.py --seed 1 record #6's clean twin)
"""
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from harness import calibrate, multisine, simulate, summary  # noqa: E402
from workbench.plant import load_plant  # noqa: E402

P = "plants/p888_51_sn637.toml"
for seed in [int(a) for a in sys.argv[1:]] or [210958]:
    phases = int(np.random.default_rng(seed).integers(1000))      # as effect_batch.drives draws them
    t, v = multisine(250.0, 40.0, 0.05, 20, seed=phases)
    r, _ = simulate(load_plant(P), "none", t, v, seed, 1.0)
    res = calibrate(r, P, f"msine{seed}")
    print(seed, summary(res))
    print("  params", json.dumps(res.get("parameters"), default=str)[:300])
    c = res["base_fit"]["channels"]["displacement"]
    print("  base test rms %.3g m, noise floor %.3g, line %.3g" % (c["rms"], c["noise_floor"], res["base_fit"]["line"]["displacement"]["rms"]))
    print("  train range", res["base_fit"]["train_range_v"], "beyond", res["base_fit"]["held_out_beyond_training_fraction"])
    print("  v range %.2f..%.2f, v[0]=%.3f" % (v.min(), v.max(), v[0]))
    print("  top", [(c["name"], c["channel"], round(c["score"], 3)) for c in res["candidates"][:4]])
