"""Wall and CPU time of `workbench calibrate` on protocol records (issue 13: at most 20 s each on one core).

Simulates the 35.5 s, 10 kHz calibration protocol (355,000 rows, 5 columns) with one effect
drawn per record, writes it as CSV, and times the whole command (read, base fit, every
candidate over the folds, figures, report, updated plant) in a fresh process. Prints the wall
time and the child's CPU time (user + system; on a shared machine the wall time also counts
the other processes' share of the cores: the machine's load is printed first).

The calibration limits BLAS to one thread itself (``run_calibrate(blas_threads=1)``): nothing
to export; every ``*_NUM_THREADS`` variable is removed from the children's environment.
``--threads`` also runs ``wb.calibrate_record`` (figures and report included, no CLI) with the
limit (``blas_threads=1``) and without it (``blas_threads=None``: OpenBLAS's own thread count,
one per core) for comparison.

    python benchmarks/calibrate_speed.py [--threads] [effect ...]
"""

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from workbench.calibrate.protocol import calibration_protocol  # noqa: E402
from workbench.calibrate.synthetic import plant_with_effect, simulate_record, write_record  # noqa: E402
from workbench.plant import load_plant  # noqa: E402


def _timed(cmd, env):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return out, wall, cpu


def main(args):
    threads = "--threads" in args
    effects = [a for a in args if not a.startswith("--")] or ["none", "creep", "resonance"]
    plant_file = ROOT / "plants" / "p888_51_sn637.toml"
    base = load_plant(plant_file)
    t, v = calibration_protocol()
    env = {k: x for k, x in os.environ.items() if not k.endswith("_NUM_THREADS")}
    # the checkout's own code (an installed `workbench` script may import another copy)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    api = ("import sys; from workbench.calibrate.run import run_calibrate; "
           "d = run_calibrate(sys.argv[1], sys.argv[2], out_dir=sys.argv[3], blas_threads={}); "
           "print('effect', d['effect'])")
    modes = [("workbench calibrate", None)]
    if threads:
        modes += [("API, blas_threads=1", "1"), ("API, blas_threads=None", "None")]
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}, "
          f"{os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        for k, effect in enumerate(effects):
            plant, _ = plant_with_effect(base, effect, 100 + k)
            data = write_record(Path(tmp) / f"{effect}.csv", simulate_record(plant, t, v, seed=100 + k))
            for label, limit in modes:
                cmd = [sys.executable, "-m", "workbench", "calibrate", str(data), "--plant", str(plant_file),
                       "--out", str(Path(tmp) / effect)] \
                    if limit is None else [sys.executable, "-c", api.format(limit), str(data), str(plant_file),
                                           str(Path(tmp) / effect)]
                out, wall, cpu = _timed(cmd, env)
                first = out.stdout.splitlines()[0] if out.stdout else out.stderr.strip()
                print(f"{effect:10s} {wall:6.1f} s wall {cpu:6.1f} s CPU  {t.size} rows  [{label}]  "
                      f"{first.split(': ', 1)[-1]}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
