"""CPU time of `workbench calibrate` from two checkouts on one identical protocol record, in alternating pairs
(issue 13's "<= 20 s per 355,000-row record on one core", judged on another machine by its ratio to a reference).

The record (the 35.5 s, 10 kHz calibration protocol, 355,000 rows, EFFECT drawn with seed 100) is simulated once
by this checkout; each run is a fresh `python -m workbench calibrate` process with PYTHONPATH set to its tree and
that tree's own plant file. After one warm-up run each (numba's caches), NPAIRS pairs alternate the order (A B,
B A, ...). Prints each run's wall and CPU time (user + system of the child) and the load, then the medians and
the per-pair ratios B/A. A floor measured on another machine against tree A's figure there transfers as
(that figure) x (median B/A). Session 33: A = eda8f4c (session 27's final, 21.1 s median on its machine).

    python benchmarks/calibrate_speed_pairs.py TREE_A TREE_B NPAIRS [EFFECT]
"""
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
if len(sys.argv) not in (4, 5):
    sys.exit(__doc__)
A, B, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
effect = sys.argv[4] if len(sys.argv) == 5 else "creep"
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from workbench.calibrate.protocol import calibration_protocol
from workbench.calibrate.synthetic import plant_with_effect, simulate_record, write_record
from workbench.plant import load_plant
plant_file = ROOT / "plants" / "p888_51_sn637.toml"
base = load_plant(plant_file)
t, v = calibration_protocol()
tmp = Path(tempfile.mkdtemp())
plant, _ = plant_with_effect(base, effect, 100)
data = write_record(tmp / f"{effect}.csv", simulate_record(plant, t, v, seed=100))
def run(tree, k):
    env = {k2: x for k2, x in os.environ.items() if not k2.endswith("_NUM_THREADS")}
    env["PYTHONPATH"] = tree
    cmd = [sys.executable, "-m", "workbench", "calibrate", str(data), "--plant", f"{tree}/plants/p888_51_sn637.toml", "--out", str(tmp / f"o{k}")]
    b = resource.getrusage(resource.RUSAGE_CHILDREN); t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tree)
    w = time.perf_counter() - t0; a = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = a.ru_utime - b.ru_utime + a.ru_stime - b.ru_stime
    first = (out.stdout.splitlines() or [out.stderr.strip()[-200:]])[0]
    print(f"{time.strftime('%H:%M:%S')} load {os.getloadavg()[0]:.2f} {Path(tree).name:8s} {w:6.1f} s wall {cpu:6.1f} s CPU  {first}", flush=True)
    return cpu
print("warm-up"); run(A, "wa"); run(B, "wb")
ra, rb = [], []
for k in range(n):
    (ra.append(run(A, f"a{k}")), rb.append(run(B, f"b{k}"))) if k % 2 == 0 else (rb.append(run(B, f"b{k}")), ra.append(run(A, f"a{k}")))
import statistics as st
print("A", [round(x, 1) for x in ra], "median", round(st.median(ra), 2))
print("B", [round(x, 1) for x in rb], "median", round(st.median(rb), 2))
print("B/A per pair", [round(b / a, 3) for a, b in zip(ra, rb)], "median", round(st.median([b / a for a, b in zip(ra, rb)]), 3))
