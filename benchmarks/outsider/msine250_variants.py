"""The clean 250 Hz multisine named drift (finding 4): the same 40 s, 12-tone records with the lowest tone at
0.05 Hz (as drawn) and at 0.2 Hz, and 40 s at 2.5 kHz, over seeds: which carries the wrong drift.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/msine250_variants.py --seeds 11 12 ...
"""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from harness import multisine, run_case  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--seeds", type=int, nargs="+", default=[11])
a = ap.parse_args()
tally = {}
for s in a.seeds:
    ph = int(np.random.default_rng(s).integers(1000))
    for name, (rate, f0) in {"250 Hz f0 0.05": (250.0, 0.05), "250 Hz f0 0.2": (250.0, 0.2),
                             "2.5 kHz f0 0.05": (2.5e3, 0.05)}.items():
        t, v = multisine(rate, 40.0, f0, 20, seed=ph)
        _, cls, _, _ = run_case("plants/p888_51_sn637.toml", "none", t, v, s, 1.0, f"{name} seed={s}")
        tally.setdefault(name, {}).setdefault(cls, 0)
        tally[name][cls] += 1
print(tally)
