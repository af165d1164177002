"""Write one clean simulated record as the CLI's CSV.

    PYTHONPATH=. python benchmarks/outsider/write_one.py OUT.csv PLANT DRIVE RATE DUR F [LO HI] [--seed S] [--effect E --size X]
DRIVE: tri | sine | msine
"""
import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from harness import multisine, simulate, sine, triangle  # noqa: E402
from workbench.calibrate.synthetic import write_record  # noqa: E402
from workbench.plant import load_plant  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("out"); ap.add_argument("plant"); ap.add_argument("drive"); ap.add_argument("rate", type=float)
ap.add_argument("dur", type=float); ap.add_argument("f", type=float); ap.add_argument("lo", type=float, nargs="?", default=0.0)
ap.add_argument("hi", type=float, nargs="?", default=100.0); ap.add_argument("--seed", type=int, default=1)
ap.add_argument("--effect", default="none"); ap.add_argument("--size", type=float, default=1.0)
a = ap.parse_args()
if a.drive == "tri":
    t, v = triangle(a.rate, a.dur, a.f, a.lo, a.hi)
elif a.drive == "sine":
    t, v = sine(a.rate, a.dur, a.f, a.lo, a.hi)
else:
    t, v = multisine(a.rate, a.dur, a.f / 10, a.f * 10, lo=a.lo, hi=a.hi, seed=a.seed)
eff = a.effect if "+" not in a.effect else tuple(a.effect.split("+"))
r, truth = simulate(load_plant(a.plant), eff, t, v, a.seed, a.size)
write_record(a.out, {k: r[k] for k in ("time_s", "voltage_v", "current_a", "displacement_m", "gauge_v")})
print(a.out, truth)
