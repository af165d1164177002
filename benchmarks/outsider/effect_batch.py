"""Effects (one and two, pairs not in the benchmark) on drives outside the benchmark's protocols.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/effect_batch.py --seed S [--n N]

Each record: drive, effect(s) and size multiplier drawn from default_rng(1000 + S) before any run; the size
printed is measured against the clean twin (harness.run_case).
"""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from harness import multisine, run_case, sine, steps, triangle  # noqa: E402

P = "plants/p888_51_sn637.toml"
SINGLE = ("creep", "dielectric_absorption", "leakage", "resonance", "delay", "drift", "gauge_nonlinearity")
PAIRS = (("leakage", "resonance"), ("delay", "drift"), ("dielectric_absorption", "delay"), ("creep", "drift"),
         ("creep", "leakage"), ("resonance", "gauge_nonlinearity"))


def drives(rng):
    s = int(rng.integers(1000))
    return [("msine 2.5k 8s", multisine(2.5e3, 8.0, 0.3, 100, seed=s)),
            ("bipolar sine 1k 12s", sine(1e3, 12.0, 0.4, -20, 120)),
            ("nfr sine 5k 6s 40-100", sine(5e3, 6.0, 0.8, 40, 100, phase=0.0)),
            ("tri 48k 2s 1.5Hz", triangle(48e3, 2.0, 1.5)),
            ("steps 1k 20s", steps(1e3, 20.0, list(rng.uniform(0, 110, 10)))),
            ("msine 250Hz 40s", multisine(250.0, 40.0, 0.05, 20, seed=s))]


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--index", type=int, nargs="*", default=None, help="rerun these records (1-based)")
    ap.add_argument("--detail", action="store_true", help="print the folds, candidates and reason")
    ap.add_argument("--clean", action="store_true", help="calibrate only the clean twin of each record")
    a = ap.parse_args()
    rng = np.random.default_rng(1000 + a.seed)
    plan = []
    for k in range(a.n):
        d = int(rng.integers(6))
        eff = SINGLE[int(rng.integers(len(SINGLE)))] if rng.uniform() < 0.6 else PAIRS[int(rng.integers(len(PAIRS)))]
        size = float(np.exp(rng.uniform(np.log(0.03), np.log(30.0))))
        plan.append((d, eff, size, int(rng.integers(1 << 20))))
    counts = {}
    for k, (d, eff, size, s) in enumerate(plan, 1):
        if a.index and k not in a.index:
            continue
        name, (t, v) = drives(np.random.default_rng(s))[d]
        if a.clean:
            run_case(P, "none", t, v, s, size, f"#{k} clean twin {name} seed={s}")
            continue
        res, cls, sizes, truth = run_case(P, eff, t, v, s, size, f"#{k} {name} x{size:.2g} seed={s}")
        if a.detail and "error" not in res:
            print("   truth", truth, "\n   reason", res.get("reason"), "\n   folds", res.get("fold_winners"),
                  "\n   top", [(c["name"], c["channel"], round(c["score"], 3), c.get("passes")) for c in res["candidates"][:5]],
                  "\n   warnings", res["base_fit"]["warnings"])
        big = bool(sizes) and max(x or 0 for x in sizes) >= 3
        counts[(cls, big)] = counts.get((cls, big), 0) + 1
    print("classes (class, any size >= 3):", counts)
