"""More clean records outside the draws: minor loops off a bias, a downward start, a long slow record, a 1 MHz
triangle, a sine with a DC ramp (a bias moving during the record). Any effect named is wrong.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/clean_more.py [--seeds 1 2]
"""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from harness import run_case, sine, triangle  # noqa: E402

P = "plants/p888_51_sn637.toml"


def cases(seed):
    t, v = sine(1e3, 10.0, 1.0, 50, 70, phase=0.0)
    yield "minor loops 50-70 V, 1 kHz 10 s", (t, v)
    t, v = sine(1e3, 10.0, 0.5, 0, 100, phase=np.pi / 2)
    yield "starts at 100 V going down, 1 kHz 10 s", (t, v)
    t, v = sine(250.0, 200.0, 0.05, 0, 100)
    yield "long slow sine 250 Hz 200 s 0.05 Hz", (t, v)
    t, v = triangle(1e6, 0.1, 40.0, 0, 10)
    yield "1 MHz triangle 0.1 s 40 Hz 0-10 V", (t, v)
    t = np.arange(10_000) / 1e3
    yield "sine 1 Hz on a 20->80 V ramp, 1 kHz 10 s", (t, 20 + 6 * t + 15 * np.sin(2 * np.pi * 1.0 * t))
    rng = np.random.default_rng(seed)
    t = np.arange(20_000) / 2e3
    x = np.cumsum(rng.standard_normal(t.size)); x = np.convolve(x, np.ones(200) / 200, "same")
    yield "band-limited random walk 2 kHz 10 s", (t, 100 * (x - x.min()) / np.ptp(x))


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    a = ap.parse_args()
    n = wrong = 0
    for s in a.seeds:
        for name, (t, v) in cases(s):
            _, cls, _, _ = run_case(P, "none", t, v, s, 1.0, f"s{s} {name}")
            n += 1
            wrong += cls == "WRONG"
    print(f"clean records: {n}, wrong {wrong}")
