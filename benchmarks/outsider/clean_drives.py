"""Clean records (no effect) on effect_batch.py's six drives at many seeds: any effect named is wrong.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/clean_drives.py --seeds 1 2 3 ... [--drives 0 5]
The drive's own draws come from default_rng(seed) as in effect_batch.drives.
"""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from effect_batch import P, drives  # noqa: E402
from harness import run_case  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--seeds", type=int, nargs="+", default=[1])
ap.add_argument("--drives", type=int, nargs="*", default=None)
a = ap.parse_args()
tally = {}
for s in a.seeds:
    for d, (name, (t, v)) in enumerate(drives(np.random.default_rng(s))):
        if a.drives is not None and d not in a.drives:
            continue
        _, cls, _, _ = run_case(P, "none", t, v, s, 1.0, f"clean {name} seed={s}")
        tally.setdefault(name, {}).setdefault(cls, 0)
        tally[name][cls] += 1
for k, c in tally.items():
    print(f"{k:<28} {c}")
