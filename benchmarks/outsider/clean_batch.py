"""Clean records (no effect) outside the benchmark's draws: any effect named is a wrong answer.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/clean_batch.py [--seeds 1 2] [--only SUBSTR]
"""
import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from harness import multisine, run_case, sine, steps, triangle  # noqa: E402
import numpy as np  # noqa: E402

P = "plants/p888_51_sn637.toml"


def cases(seed):
    yield "sn618 tri 2.5k 10s 0.5Hz", "plants/p888_51_sn618.toml", triangle(2.5e3, 10.0, 0.5)
    yield "sn629 tri 2.5k 10s 0.5Hz", "plants/p888_51_sn629.toml", triangle(2.5e3, 10.0, 0.5)
    yield "flexure(no mode) msine 10k 3s", "plants/p888_51_sn637_on_flexure.toml", multisine(1e4, 3.0, 0.5, 50, seed=seed)
    yield "250Hz tri 60s 0.1Hz", P, triangle(250.0, 60.0, 0.1)
    yield "250Hz msine 40s", P, multisine(250.0, 40.0, 0.05, 20, seed=seed)
    yield "2.5k msine 8s", P, multisine(2.5e3, 8.0, 0.3, 100, seed=seed)
    yield "48k tri 2s 1.5Hz", P, triangle(48e3, 2.0, 1.5)
    yield "200k sine 0.25s 12Hz 0-60V", P, sine(2e5, 0.25, 12.0, 0, 60)
    yield "bipolar sine 1k 10s -20..120", P, sine(1e3, 10.0, 0.4, -20, 120)
    yield "not-from-rest sine 1k 10s 40-100", P, sine(1e3, 10.0, 0.5, 40, 100, phase=0.0)
    yield "short 3cyc sine 10k 3s 1Hz", P, sine(1e4, 3.0, 1.0)
    yield "short 4cyc tri 10k 4s 1Hz", P, triangle(1e4, 4.0, 1.0, rest=0.0)
    yield "steps random 1k 20s", P, steps(1e3, 20.0, list(np.random.default_rng(seed).uniform(0, 110, 10)))
    yield "small 0-8V sine 10k 4s", P, sine(1e4, 4.0, 1.0, 0, 8)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--only", default=None)
    a = ap.parse_args()
    n = wrong = err = 0
    for s in a.seeds:
        for name, plant, (t, v) in cases(s):
            if a.only and a.only not in name:
                continue
            _, cls, _, _ = run_case(plant, "none", t, v, s, 1.0, f"s{s} {name}")
            n += 1
            wrong += cls == "WRONG"
            err += cls == "error"
    print(f"clean records: {n}, wrong {wrong}, errors {err}")
