"""Wall and CPU time of `workbench study` on the shipped study: cold, warm, and the old path as reference.

Issue 14 targets (2 cores): cold (family computed, every design) <= 30 s; warm (cached family,
new targets, ``--only loopshape``) <= 10 s. The machine is shared, so each run also reports
its CPU time (this process's children) and the 1-minute load average before it: on a loaded
machine compare CPU seconds and the ratios, not the wall time.

    python benchmarks/study_speed.py [--skip-reference]

The reference is the study as it ran before the cache (``--no-cache --workers 1``: the family in
one process, every comparison design): the speed-up ratios are taken in the same run.
"""

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "studies" / "sn637_servo.toml"


def _run(args, env):
    exe = Path(sys.executable).with_name("workbench")
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run([str(exe), "study", str(STUDY), *args], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if out.returncode != 0:
        raise SystemExit(f"study failed ({out.returncode}): {out.stderr.strip()[-400:]}")
    return wall, cpu, load, out.stdout.strip().splitlines()


def main(skip_reference):
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "WORKBENCH_CACHE_DIR": str(Path(tmp) / "cache")}
        runs = [("cold (family computed, all designs)", ["--out", f"{tmp}/cold"]),
                ("warm (cached family, PM target 50 deg, --only loopshape)",
                 ["--out", f"{tmp}/warm", "--only", "loopshape", "--set", "targets.phase_margin_deg=50"]),
                ("warm (cached family, all designs)", ["--out", f"{tmp}/warm_all"])]
        if not skip_reference:
            runs.append(("reference (no cache, 1 process, all designs)",
                         ["--out", f"{tmp}/ref", "--no-cache", "--workers", "1"]))
        print(f"machine: {os.cpu_count()} cores; times: wall s / CPU s (children) / 1-min load before")
        results = {}
        for name, args in runs:
            wall, cpu, load, lines = _run(args, env)
            results[name] = (wall, cpu)
            print(f"{name:58s} {wall:6.1f} s wall {cpu:6.1f} s CPU  load {load:4.1f}")
            print("    " + lines[1] if len(lines) > 1 else "")
        if not skip_reference:
            ref = results[runs[-1][0]]
            for name, _ in runs[:-1]:
                w, c = results[name]
                print(f"{name:58s} {ref[0] / w:5.1f}x faster wall, {ref[1] / c:5.1f}x less CPU than the reference")


if __name__ == "__main__":
    main("--skip-reference" in sys.argv[1:])
